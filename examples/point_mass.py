"""MPAIL2 on the 2-D point mass: the quickest end-to-end run (about two minutes on 2 CPU cores).

    python examples/point_mass.py
"""
from torchrl_mpail2.train import main

if __name__ == "__main__":
    main(default_preset="point_mass", description=__doc__)
