"""MPAIL2 on the 2-D point mass: the quickest end-to-end run (about two minutes on 2 CPU cores).

    python examples/point_mass.py
"""
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from _common import run  # noqa: E402

if __name__ == "__main__":
    run("point_mass", __doc__)
