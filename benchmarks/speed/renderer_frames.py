"""The learner's camera frames with the light renderer beside robosuite's full renderer, for the same states.

    python -m benchmarks.speed.renderer_frames [--out docs/figures/renderers.png]

Lift and Push reset from seed 3 with the light renderer; the same simulator state is then rendered by an env with
robosuite's full renderer (shadows, reflections, skybox, 4x multisampling). One row per task: the external and wrist
cameras, full then light, 64 x 64 as the learner sees them.
"""
from __future__ import annotations

import argparse
from pathlib import Path

from benchmarks.records import ROOT

CAMERAS = ("external_image", "wrist_image")


def frames(task: str, seed: int = 3) -> dict:
    """``{renderer: [external, wrist]}`` HWC uint8 frames of the same state."""
    from torchrl_mpail2.envs.robosuite_env import RobosuiteEnv

    light, full = RobosuiteEnv(task, obs="pixels", seed=seed), RobosuiteEnv(task, obs="pixels", seed=seed, renderer="full")
    try:
        light.set_seed(seed)
        seen = light.reset()
        full.reset()
        again = full.observe_state(light.sim_env.sim.get_state().flatten())
        return {name: [td[key].permute(1, 2, 0).numpy() for key in CAMERAS] for name, td in (("full", again), ("light", seen))}
    finally:
        light.close(), full.close()


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--out", type=Path, default=ROOT / "docs" / "figures" / "renderers.png")
    args = p.parse_args()
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    tasks = ("Lift", "Push")
    fig, axes = plt.subplots(len(tasks), 4, figsize=(8, 2.2 * len(tasks)))
    for row, task in enumerate(tasks):
        shown = frames(task)
        for col, (renderer, camera) in enumerate([(r, c) for r in ("full", "light") for c in range(2)]):
            ax = axes[row, col]
            ax.imshow(shown[renderer][camera])
            ax.set_xticks([]), ax.set_yticks([])
            if row == 0:
                ax.set_title(f"{CAMERAS[camera].split('_')[0]}, {renderer}", fontsize=9)
        axes[row, 0].set_ylabel(task)
    fig.tight_layout()
    args.out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(args.out, dpi=110)
    print(args.out)


if __name__ == "__main__":
    main()
