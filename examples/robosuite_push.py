"""MPAIL2 on the Block Push task (push a cube past a line in -y) from scripted demonstrations.

    python examples/robosuite_push.py
    python examples/robosuite_push.py --env robosuite/PushMirrored --init-from runs/<push run>/checkpoints/best --transfer world-model
"""
from torchrl_mpail2.train import main

if __name__ == "__main__":
    main(default_preset="push_state", description=__doc__)
