"""MPAIL2 on robosuite Lift (Panda) from 10 scripted observation-only demonstrations.

    python examples/robosuite_lift.py                      # state observations, CPU preset
    python examples/robosuite_lift.py --obs pixels         # two 64x64 cameras + proprioception
    python examples/robosuite_lift.py train.total_episodes=50 planner.num_candidates=128
"""
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from _common import run  # noqa: E402

if __name__ == "__main__":
    run("lift_state", __doc__)
