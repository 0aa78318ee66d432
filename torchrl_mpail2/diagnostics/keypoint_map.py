r"""Where the keypoints of a checkpoint's image coders (``model.image_head=keypoints``) sit on the camera frames, and
whether they follow the cube or the arm.

    python -m torchrl_mpail2.diagnostics keypoint_map CKPT [--resets 100] [--episodes 1] [--plot FILE] [--out FILE]

Two sets of states, as :mod:`~torchrl_mpail2.diagnostics.latent_content` draws them: ``--resets`` initial states of
held-out evaluation seeds (the cube placed anew, the arm about still) and ``--episodes`` fixed evaluation episodes
played by the checkpoint's agent (the arm moves). Per camera and set: each keypoint's spread (the std of its image
position over the states, in pixels, averaged over x and y) and how well a probe reads the cube's and the hand's
positions from that camera's keypoints alone (``held_out_r2``, as in ``latent_content``; None where the target moved
less than :data:`STILL_M` over the set, as the cube does in an episode that never touches it). A camera whose keypoints
do not move over the resets does not see the cube; over played states they may follow the arm. ``--plot`` draws
frames of both sets with each camera's keypoints on them, one colour per keypoint.

A keypoint's coordinates are the soft-argmax over the last feature map's cells (:mod:`torchrl_mpail2.modules.keypoints`);
:func:`keypoint_pixels` places them at the cells' receptive-field centres, which for a 64 x 64 frame span pixels
15-47: a keypoint of an object nearer the border sits at the nearest cell's centre.
"""
from __future__ import annotations

import argparse
from pathlib import Path

import torch
from tensordict import TensorDictBase
from torch import Tensor

from torchrl_mpail2.diagnostics.figures import save_figure
from torchrl_mpail2.diagnostics.latent_content import add_state_set_arguments, state_sets, write_result
from torchrl_mpail2.diagnostics.latent_probe import fit_latent_probe
from torchrl_mpail2.modules.encoder import _CNN_KERNEL, _CNN_STRIDES, ImageCoder


#: A target whose std over a set of states is below this (metres) stays still there: no probe score.
STILL_M = 1e-3


def keypoint_coders(agent) -> dict[str, ImageCoder]:
    """The agent's image coders that end in keypoints, by observation key.

    Raises:
        ValueError: none does (the message names ``model.image_head``).
    """
    net = agent.modules.encoder.net
    coders = {key: coder for key, coder in net.coders.items()
              if isinstance(coder, ImageCoder) and coder.head == "keypoints"}
    if not coders:
        raise ValueError("keypoint_map needs image coders with keypoints (model.image_head=keypoints); this "
                         f"checkpoint's image head is {agent.modules.cfg.image_head!r}")
    return coders


def keypoint_pixels(coords: Tensor, map_size: int) -> Tensor:
    """Soft-argmax coordinates in [-1, 1] over a ``map_size``-cell feature map -> pixel coordinates of the input frame,
    the cells' receptive-field centres of the coder's valid convolutions (:data:`~torchrl_mpail2.modules.encoder._CNN_STRIDES`).

    Examples:
        >>> keypoint_pixels(torch.tensor([-1.0, 0.0, 1.0]), map_size=5)  # a 64 x 64 frame's last map is 5 x 5
        tensor([15., 31., 47.])
    """
    def centre(cell: float) -> float:
        for stride in reversed(_CNN_STRIDES):
            cell = stride * cell + (_CNN_KERNEL - 1) / 2
        return cell

    first, last = centre(0), centre(map_size - 1)
    return first + (coords + 1) / 2 * (last - first)


def keypoint_motion(agent, observations: TensorDictBase, targets: dict[str, Tensor], seed: int = 0) -> dict:
    """Per keypoint camera: the keypoints' spread in pixels over ``observations`` and the probes' ``held_out_r2`` of
    each target read from that camera's keypoints alone (see the module docstring)."""
    out = {}
    for key, coder in keypoint_coders(agent).items():
        with torch.no_grad():
            pixels = keypoint_pixels(coder.keypoints(observations[key]), coder.map_size)  # [N, K, 2]
        spread = pixels.std(0).mean(-1)  # [K]
        flat = pixels.flatten(1)
        standardised = (flat - flat.mean(0)) / flat.std(0).clamp_min(1e-6)
        out[key] = {"keypoints": int(pixels.shape[1]), "mean_spread_px": float(spread.mean()),
                    "max_spread_px": float(spread.max()), "spread_px": [round(float(v), 3) for v in spread],
                    **{name: (fit_latent_probe(standardised, y.clone(), seed=seed)[1]["held_out_r2"]
                              if float(y.std(0).max()) >= STILL_M else None) for name, y in targets.items()}}
    return out


def draw_keypoints(agent, frames: list[TensorDictBase], titles: list[str], path: str | Path) -> Path:
    """One row per keypoint camera, one column per frame, the keypoints drawn on the frames; writes ``path``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    coders = keypoint_coders(agent)
    fig, axes = plt.subplots(len(coders), len(frames), figsize=(2.4 * len(frames), 2.5 * len(coders)), squeeze=False)
    for row, (key, coder) in enumerate(coders.items()):
        for col, (frame, title) in enumerate(zip(frames, titles)):
            image = frame[key]
            with torch.no_grad():
                points = keypoint_pixels(coder.keypoints(image), coder.map_size)
            ax = axes[row][col]
            ax.imshow(image.permute(1, 2, 0).numpy() if image.dtype == torch.uint8 else image.permute(1, 2, 0).clamp(0, 1).numpy())
            ax.scatter(points[:, 0], points[:, 1], c=range(points.shape[0]), cmap="hsv", s=14, edgecolors="k",
                       linewidths=0.4)
            ax.set_xticks([])
            ax.set_yticks([])
            ax.set_title(f"{key}: {title}" if col == 0 else title, fontsize=7)
    return save_figure(fig, path)


def main(argv: list[str] | None = None) -> dict:
    from torchrl_mpail2.agents import MPAIL2Agent

    p = argparse.ArgumentParser(prog="python -m torchrl_mpail2.diagnostics keypoint_map", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    add_state_set_arguments(p, resets=100, episodes=1)
    p.add_argument("--plot", type=Path, default=None, help="draw frames with their keypoints to this PNG")
    args = p.parse_args(argv)
    agent = MPAIL2Agent.from_checkpoint(args.checkpoint)
    try:
        keypoint_coders(agent)
    except ValueError as error:
        raise SystemExit(f"{args.checkpoint}: {error}") from None
    at_reset, played = state_sets(agent, args.resets, args.episodes)
    result = {"checkpoint": str(args.checkpoint), "resets": args.resets, "episodes": args.episodes}
    frames, titles = [], []
    if at_reset is not None:
        result["at_reset"] = keypoint_motion(agent, *at_reset)
        frames += [at_reset[0][i] for i in range(min(2, len(at_reset[0])))]
        titles += [f"reset {i}" for i in range(len(frames))]
    if played:
        observations = torch.cat([o for o, _ in played])
        targets = {key: torch.cat([t[key] for _, t in played]) for key in played[0][1]}
        result["played"] = keypoint_motion(agent, observations, targets)
        steps = played[0][0].shape[0]
        for step in sorted({0, steps // 2, steps - 1}):
            frames.append(played[0][0][step])
            titles.append(f"played, step {step}")
    if args.plot is not None:
        result["plot"] = str(draw_keypoints(agent, frames, titles, args.plot))
    return write_result(result, args.out)
