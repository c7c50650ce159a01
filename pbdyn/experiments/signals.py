"""SIGTERM and SIGINT during a batch, a merge or `pbdyn generate`: BatchInterrupted and the stop_on_signals block that
raises it.

The batch runner (pbdyn.experiments.runner) and `pbdyn merge` (pbdyn.experiments.merge) run their work inside
stop_on_signals(), commit or roll back what they hold when BatchInterrupted arrives, and re-raise it with a message
saying what was kept; the command line exits with its ``exit_status`` (docs/experiments.md).
"""

from __future__ import annotations

import contextlib
import os
import signal
import threading
from collections.abc import Iterator


class BatchInterrupted(KeyboardInterrupt):
    """SIGTERM or SIGINT stopped a batch; committed rows are kept. ``exit_status`` = 128 + the signal number."""

    def __init__(self, signum: int, message: str = ""):
        self.signum = signum
        self.exit_status = 128 + signum
        super().__init__(message or f"stopped by {signal.Signals(signum).name}")


@contextlib.contextmanager
def stop_on_signals() -> Iterator[None]:
    """Within the block, the first SIGTERM or SIGINT raises BatchInterrupted (later ones are ignored while the
    batch cleans up); the previous handlers are restored after it. A no-op outside the main thread."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    fired: list[int] = []

    def handler(signum, frame):
        if not fired:
            fired.append(signum)
            raise BatchInterrupted(signum)

    old = {sig: signal.signal(sig, handler) for sig in (signal.SIGTERM, signal.SIGINT)}
    try:
        yield
    finally:
        for sig, h in old.items():
            signal.signal(sig, h)


@contextlib.contextmanager
def merge_signals(out) -> Iterator[None]:
    """The whole of `pbdyn merge` under stop_on_signals, its checks of the inputs included (the merge itself
    re-raises with what it kept): a signal before anything is written says so, "merge stopped by SIGTERM: nothing
    written to OUT" (pbdyn.experiments.merge)."""
    with stop_on_signals():
        try:
            yield
        except BatchInterrupted as exc:
            if str(exc).startswith("merge stopped"):
                raise
            raise BatchInterrupted(exc.signum, f"merge stopped by {signal.Signals(exc.signum).name}: "
                                   f"nothing written to {os.path.basename(os.fspath(out))}") from None
