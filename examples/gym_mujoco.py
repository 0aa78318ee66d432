"""MPAIL2 on gymnasium MuJoCo tasks (Hopper-v5, Ant-v5, Humanoid-v5), terminations kept.

    python examples/gym_mujoco.py --env gym/Hopper-v5 train.demos=PATH

Demonstrations come from a trained expert (``python -m torchrl_mpail2.experts.sac``) or your own recordings.
"""
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from _common import run  # noqa: E402

if __name__ == "__main__":
    run("hopper", __doc__, env="gym/Hopper-v5")
