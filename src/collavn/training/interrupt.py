"""Stopping a training run on SIGINT or SIGTERM without losing it.

The first signal asks the run to stop: the trainer finishes the update in progress,
keeps going to the next checkpoint *sync point* (at most ``checkpoint_interval``
updates; see :mod:`collavn.training.trainer`), writes its checkpoint there and returns,
so that ``--resume`` continues exactly like the uninterrupted run would have. The
command then exits with ``128 + signal`` (130 for SIGINT, 143 for SIGTERM). A second
signal stops at once by raising :class:`~collavn.errors.Interrupted`: nothing more is
written, and a checkpoint write in progress is abandoned by
:func:`~collavn.files.atomic_write`, so the last good checkpoint stays as it was.
"""

from __future__ import annotations

import signal
import sys
import threading
from pathlib import Path
from types import FrameType, TracebackType
from typing import Any

from collavn.errors import Interrupted

#: The signals a run stops on.
STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)


class StopRequest:
    """Signal handlers for the duration of a ``with`` block (main thread only).

    Args:
        checkpoint: The file a second signal leaves as it was (named in its message).
        interval: Updates until the next sync point (named in the first signal's notice).
        notice: What the run does after the first signal, if not the trainer's
            "finish the update, checkpoint at the next sync point".

    Attributes:
        signum: The first signal received, or ``None``.
    """

    def __init__(self, checkpoint: Path, interval: int, notice: str | None = None) -> None:
        self.checkpoint, self.interval = checkpoint, interval
        self.notice = notice or (f"finishing the current update, then stopping with a "
                                 f"checkpoint at the next sync point (within {interval} "
                                 f"updates)")
        self.signum: int | None = None
        self._previous: dict[int, Any] = {}

    @property
    def requested(self) -> bool:
        """A signal arrived: stop at the next sync point."""
        return self.signum is not None

    def __enter__(self) -> StopRequest:
        if threading.current_thread() is threading.main_thread():
            for s in STOP_SIGNALS:
                self._previous[s] = signal.signal(s, self._handle)
        return self

    def __exit__(self, kind: type[BaseException] | None, error: BaseException | None,
                 tb: TracebackType | None) -> None:
        for s, handler in self._previous.items():
            signal.signal(s, handler)
        self._previous.clear()

    def _handle(self, signum: int, frame: FrameType | None) -> None:
        name = signal.Signals(signum).name
        if self.signum is not None:
            raise Interrupted(signum, f"second {name}: stopped at once without saving; the "
                              f"last checkpoint ({self.checkpoint}) is as it was")
        self.signum = signum
        print(f"\ncollavn: {name}: {self.notice}; send it again to stop at once without "
              f"saving", file=sys.stderr, flush=True)
