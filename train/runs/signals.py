"""Stop a training run cleanly on Ctrl-C (SIGINT) or SIGTERM.

The first signal asks the run to stop: it finishes the episode batch in progress (compiled code cannot
be interrupted half way without losing the batch), writes a checkpoint and returns, so `mjx-push train
--resume` continues exactly where it stopped. A second signal interrupts at once (KeyboardInterrupt),
as a second Ctrl-C does elsewhere. Cluster schedulers send SIGTERM before they kill a job, so a
preempted run keeps its progress too.
"""

from __future__ import annotations

import signal
import sys
import threading

SIGNALS = (signal.SIGINT, signal.SIGTERM)


class StopOnSignal:
    """Context manager: while active, SIGINT / SIGTERM set `requested` (the signal's name) instead of
    killing the process. Outside the main thread (where Python cannot install handlers) it does nothing."""

    def __init__(self, signals: tuple[int, ...] = SIGNALS):
        self.signals = signals
        self.requested: str | None = None
        self._previous: dict[int, object] = {}

    def _handle(self, signum, frame) -> None:
        if self.requested is not None:
            raise KeyboardInterrupt
        self.requested = signal.Signals(signum).name
        sys.stderr.write(
            f"\nmjx-push: {self.requested} received: stopping after this batch with a checkpoint "
            "(send it again to stop at once, losing the batch)\n"
        )
        sys.stderr.flush()

    def __enter__(self) -> StopOnSignal:
        if threading.current_thread() is threading.main_thread():
            for s in self.signals:
                self._previous[s] = signal.signal(s, self._handle)
        return self

    def __exit__(self, *exc) -> None:
        for s, handler in self._previous.items():
            signal.signal(s, handler)
        self._previous.clear()
