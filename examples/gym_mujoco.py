"""MPAIL2 on gymnasium MuJoCo tasks (Hopper-v5, Ant-v5, Humanoid-v5), terminations kept.

    python examples/gym_mujoco.py --env gym/Hopper-v5 train.demos=PATH

Demonstrations come from a trained expert (``python -m torchrl_mpail2.experts.sac``) or your own recordings.
"""
from torchrl_mpail2.train import main

if __name__ == "__main__":
    main(default_preset="hopper", description=__doc__)
