"""MPAIL2 on the Block Push task (push a cube past a line in -y) from scripted demonstrations.

    python examples/robosuite_push.py
    python examples/robosuite_push.py --env robosuite/PushMirrored --init-from runs/<push run>/checkpoints/best --transfer world-model
"""
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from _common import run  # noqa: E402

if __name__ == "__main__":
    run("push_state", __doc__)
