"""MPAIL2 on robosuite Lift (Panda) from 10 scripted observation-only demonstrations.

    python examples/robosuite_lift.py                      # state observations, CPU preset
    python examples/robosuite_lift.py --preset lift_pixels # two 64x64 cameras + proprioception, latent 512
    python examples/robosuite_lift.py train.total_episodes=50 planner.num_candidates=128
"""
from torchrl_mpail2.train import main

if __name__ == "__main__":
    main(default_preset="lift_state", description=__doc__)
