"""Wall seconds by stage of a loop, as TorchRL's ``timeit`` keeps them for ``sac.py``: one ``with`` line per stage."""
from __future__ import annotations

import contextlib
import time
from collections.abc import Iterator

__all__ = ["StageTimer"]


class StageTimer:
    """Sums the wall seconds spent in each named stage over a loop's iterations.

    Examples:
        >>> timer = StageTimer()
        >>> with timer("update"):
        ...     pass
        >>> timer.add("env", 0.5)
        >>> sorted(timer.seconds), timer.seconds["env"]
        (['env', 'update'], 0.5)
    """

    def __init__(self):
        #: stage name -> wall seconds, in the order the stages first ran
        self.seconds: dict[str, float] = {}

    @contextlib.contextmanager
    def __call__(self, stage: str) -> Iterator[None]:
        """Times the ``with`` block under ``stage`` (an exception leaving the block is timed too)."""
        tick = time.perf_counter()
        try:
            yield
        finally:
            self.add(stage, time.perf_counter() - tick)

    def add(self, stage: str, seconds: float) -> None:
        """Adds ``seconds`` measured elsewhere (e.g. acting timed inside the collector) to ``stage``."""
        self.seconds[stage] = self.seconds.get(stage, 0.0) + seconds
