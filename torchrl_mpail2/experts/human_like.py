"""Per-episode variation that makes a scripted expert move less like a machine.

The scripted experts are noiseless: every demonstration takes the same path at the same speed and then hovers
still, which lets a WGAN critic memorise the demonstrations instead of learning what makes them expert-like.
Human teleoperators (the paper's 27-30 demonstrations) vary their speed from one episode to the next, take
different approach paths, drift and correct, and pause. :class:`HumanLikeMotion` draws such a style at every
reset and applies it to the expert's position commands; the expert's closed-loop phases do the recovering.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: Ranges of the per-episode style, in action units (1 = the env's 5 cm per step) unless stated.
SPEED_RANGE = (0.35, 1.0)  # cap on each axis of the position command
GAIN_RANGE = (0.6, 1.6)  # multiplier of the expert's proportional command: the approach tempo
DRIFT_STD_RANGE = (0.03, 0.2)  # stationary std of the correlated drift added to the command
DRIFT_CORRELATION = 0.85  # AR(1) coefficient of the drift per step (about 7 steps of memory)
VIA_OFFSET_MAX = 0.06  # metres: horizontal offset of the via point the approach passes through
PAUSE_PROBABILITY = 0.02  # per step: the chance that a pause starts
PAUSE_STEPS = (2, 6)  # length of a pause, in steps (upper bound excluded)
CAREFUL_DRIFT = 0.25  # share of the drift kept while grasping and holding (a teleoperator slows down there)


@dataclass
class HumanLikeStyle:
    """One episode's style."""

    speed: float
    gain: float
    drift_std: float
    via_offset: np.ndarray
    """Horizontal offset (metres) of a via point that the approach passes before aligning with the target."""

    @classmethod
    def draw(cls, rng: np.random.Generator) -> "HumanLikeStyle":
        radius = VIA_OFFSET_MAX * np.sqrt(rng.uniform())
        angle = rng.uniform(0.0, 2 * np.pi)
        return cls(speed=rng.uniform(*SPEED_RANGE), gain=rng.uniform(*GAIN_RANGE), drift_std=rng.uniform(*DRIFT_STD_RANGE),
                   via_offset=radius * np.array([np.cos(angle), np.sin(angle)]))


class HumanLikeMotion:
    """Applies a :class:`HumanLikeStyle` to position commands, step by step; :meth:`reset` draws a new style.

    Args:
        rng (np.random.Generator): source of the styles, drifts and pauses.
    """

    def __init__(self, rng: np.random.Generator):
        self.rng = rng
        self.reset()

    def reset(self) -> None:
        self.style = HumanLikeStyle.draw(self.rng)
        self._drift = np.zeros(3)
        self._pause_left = 0
        self.via_pending = True

    def via_point(self, target_xy: np.ndarray, eef_xy: np.ndarray, reached: float = 0.015) -> np.ndarray:
        """The horizontal target of an approach: the via point until the hand first comes within ``reached``."""
        via = target_xy + self.style.via_offset
        if self.via_pending and np.linalg.norm(via - eef_xy) < reached:
            self.via_pending = False
        return via if self.via_pending else target_xy

    def shape(self, command: np.ndarray, careful: bool = False) -> np.ndarray:
        """``command [3]`` (position, action units) -> the same with this episode's tempo, drift and pauses.

        ``careful`` (grasping, holding): a fraction of the drift, no new pauses.
        """
        s = self.style
        innovation = s.drift_std * np.sqrt(1.0 - DRIFT_CORRELATION**2) * self.rng.standard_normal(3)
        self._drift = DRIFT_CORRELATION * self._drift + innovation
        if careful:
            self._pause_left = 0
            return np.clip(s.gain * command, -s.speed, s.speed) + CAREFUL_DRIFT * self._drift
        if self._pause_left == 0 and self.rng.uniform() < PAUSE_PROBABILITY:
            self._pause_left = int(self.rng.integers(*PAUSE_STEPS))
        if self._pause_left > 0:
            self._pause_left -= 1
            return self._drift.copy()  # a pause still trembles a little
        return np.clip(s.gain * command, -s.speed, s.speed) + self._drift
