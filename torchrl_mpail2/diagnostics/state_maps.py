r"""What an agent makes of a set of states at rest, shared by the maps over positions (:mod:`.arena_map` for the point
mass, :mod:`.cube_map` for Push): the reward of staying :math:`r_\theta(z, z)`, the policy mean's first action and
the value of the policy's plan :math:`Q_\zeta(z, \pi_\phi(z)_0)` (the mean over all heads), and their picture."""
from __future__ import annotations

import json
from pathlib import Path

import torch
from tensordict import TensorDictBase

from torchrl_mpail2.diagnostics.figures import save_figure

__all__ = ["draw_reward_value_maps", "report_map", "staying_reward_and_value"]


@torch.no_grad()
def staying_reward_and_value(modules, observations: TensorDictBase) -> dict[str, torch.Tensor]:
    """``observations [N]`` -> ``z [N, Z]``, ``reward [N]``, ``action [N, A]``, ``value [N]`` (one encode for all)."""
    z = modules.encode(observations)
    action = modules.pi(z, deterministic=True)[0][:, 0]
    return {"z": z, "reward": modules.rewards(torch.stack([z, z]))[0], "action": action,
            "value": modules.q(z, action).mean(0)}


def draw_reward_value_maps(result: dict, path: Path, extent: tuple[float, float, float, float], title: str = "",
                           labels: tuple[str, str] = ("x", "y"), decorate=None) -> Path:
    """``result["reward_of_staying"]`` and ``result["value"]`` (``[rows, columns]``, the first row at the top of
    ``extent``) side by side; ``decorate(axes)`` draws what a map adds (the goal, the line, the actions)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(9, 4))
    for ax, key, label in zip(axes, ("reward_of_staying", "value"), ("reward of staying r(z, z)", "Q(z, pi(z))")):
        im = ax.imshow(torch.tensor(result[key]), extent=extent, cmap="viridis", aspect="auto")
        fig.colorbar(im, ax=ax, shrink=0.8)
        ax.set_xlabel(labels[0])
        ax.set_ylabel(labels[1])
        ax.set_title(label, fontsize=9)
    if decorate is not None:
        decorate(axes)
    fig.suptitle(title, fontsize=9)
    return save_figure(fig, path)


def report_map(result: dict, out: Path | None, plot: Path | None, draw) -> dict:
    """A map command's output: ``result`` to the JSON file ``out``, ``draw(result, plot, title)`` to the PNG ``plot``
    (each when given), its scalars printed; returns ``result``."""
    if out is not None:
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(json.dumps(result, indent=1))
    if plot is not None:
        print(f"wrote {draw(result, plot, str(result['checkpoint']))}")
    print(json.dumps({k: v for k, v in result.items() if not isinstance(v, list)}, indent=2))
    return result
