"""The batch's progress line on stderr (Progress): trials done of the total, trials per second and the ETA."""

from __future__ import annotations

import sys
import time


class Progress:
    """A progress line on stderr: done/total, trials per second and ETA; per finished trial on a terminal, every
    5 s otherwise."""

    def __init__(self, total: int, enabled: bool):
        self.total, self.enabled = total, enabled and total > 0
        self.done = 0
        self.t0 = time.perf_counter()
        self.tty = sys.stderr.isatty()
        self.last = 0.0

    def step(self, n: int = 1) -> None:
        """Count ``n`` more finished trials and print the line when it is due."""
        self.done += n
        if not self.enabled:
            return
        now = time.perf_counter()
        if self.tty or now - self.last >= 5.0 or self.done == self.total:
            self.last = now
            rate = self.done / max(now - self.t0, 1e-9)
            eta = (self.total - self.done) / rate if rate > 0 else float("inf")
            line = f"pbdyn batch: {self.done}/{self.total} trials, {rate:.2f}/s, ETA {_fmt_s(eta)}"
            sys.stderr.write(("\r" + line) if self.tty else line + "\n")
            if self.tty and self.done == self.total:
                sys.stderr.write("\n")
            sys.stderr.flush()


def _fmt_s(s: float) -> str:
    if s == float("inf"):
        return "?"
    s = int(round(s))
    return f"{s // 3600}:{s // 60 % 60:02d}:{s % 60:02d}"
