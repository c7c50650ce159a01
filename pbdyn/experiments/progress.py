"""The batch's progress line on stderr (Progress): trials done of the total, trials per second and the ETA.

A batch makes its own Progress over its pending trials. A caller that runs several batches as one job (`pbdyn bench`:
one batch per suite part) makes one Progress over all of them and passes it as BatchOptions.progress, so that one
line counts every trial of the job with one ETA.
"""

from __future__ import annotations

import sys
import time


class Progress:
    """A progress line on stderr: done/total, trials per second and ETA; per finished trial on a terminal, every
    5 s otherwise. ``label`` starts the line (the command's name)."""

    def __init__(self, total: int, enabled: bool, label: str = "pbdyn batch"):
        self.total, self.enabled = total, enabled and total > 0
        self.label = label
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
        total = max(self.total, self.done)
        if self.tty or now - self.last >= 5.0 or self.done == total:
            self.last = now
            rate = self.done / max(now - self.t0, 1e-9)
            eta = (total - self.done) / rate if rate > 0 else float("inf")
            line = f"{self.label}: {self.done}/{total} trials, {rate:.2f}/s, ETA {_fmt_s(eta)}"
            sys.stderr.write(("\r" + line) if self.tty else line + "\n")
            if self.tty and self.done == total:
                sys.stderr.write("\n")
            sys.stderr.flush()


def _fmt_s(s: float) -> str:
    if s == float("inf"):
        return "?"
    s = int(round(s))
    return f"{s // 3600}:{s // 60 % 60:02d}:{s % 60:02d}"
