"""A training that is asked to stop (SIGTERM from a scheduler, SIGINT from Ctrl-C) ends its episode, saves
``checkpoints/last`` and returns, instead of losing the episodes since the last save."""
from __future__ import annotations

import logging
import signal
import threading

log = logging.getLogger(__name__)

#: The signals that ask a training to stop at the next episode boundary.
STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)


class StopOnSignal:
    """Context manager: the first :data:`STOP_SIGNALS` signal sets :attr:`requested` (its name); a second one
    raises ``KeyboardInterrupt`` at once. Handlers are installed only in the main thread (Python allows no
    other) and the previous ones are restored on exit.

    Examples:
        >>> with StopOnSignal() as stop:
        ...     stop.requested is None
        True
    """

    def __init__(self):
        self.requested: str | None = None
        self._previous: dict = {}

    def _handle(self, signum, frame) -> None:
        if self.requested is not None:
            raise KeyboardInterrupt(f"{signal.Signals(signum).name} twice: stopping without saving")
        self.requested = signal.Signals(signum).name
        log.warning("%s: stopping after this episode and saving checkpoints/last (send it again to stop at once)",
                    self.requested)

    def __enter__(self) -> "StopOnSignal":
        if threading.current_thread() is threading.main_thread():
            self._previous = {sig: signal.signal(sig, self._handle) for sig in STOP_SIGNALS}
        return self

    def __exit__(self, *exc) -> None:
        for sig, handler in self._previous.items():
            signal.signal(sig, handler)
        self._previous = {}
