"""Running foreign code at pbdyn's boundary: user motion functions and planner plug-ins (docs/scenarios.md "Imported worlds",
"Benchmark your planner").

pbdyn's stdout belongs to its results (``--json`` prints one JSON document there and nothing else), so user code's
prints go to stderr: ``user_stdout()`` points ``sys.stdout`` at ``sys.stderr`` (cheap: per planner call),
``stdout_fd_to(2)`` also points file descriptor 1 at descriptor 2 (C-level writes, PyBullet's chatter; a few
system calls: around imports and whole loops). ``time_budget(seconds)`` bounds the wall-clock time of a block of
user calls (a motion function over a rollout: USER_CODE_TIMEOUT_S; a plug-in planner pair's decision:
PLANNER_CALL_TIMEOUT_S): in the main thread of a POSIX process an interval timer (SIGALRM) interrupts a call that hangs; elsewhere
(worker threads, platforms without SIGALRM) the budget is checked after each call (``budget.check()``), which
catches slow code but cannot stop one call that never returns. Both raise ``UserCodeTimeout``.

This module imports nothing from pbdyn (it is the bottom layer, under pbdyn.errors); callers turn UserCodeTimeout
and user exceptions into ConfigErrors naming the field.
"""

from __future__ import annotations

import contextlib
import ctypes
import os
import signal
import sys
import threading
import time
from collections.abc import Iterator

USER_CODE_TIMEOUT_S = 10.0
"""Wall-clock budget (s) of one body's motion function over a whole rollout (all its calls together)."""

PLANNER_CALL_TIMEOUT_S = 60.0
"""Wall-clock budget (s) of one decision of a trial whose planner pair includes a plug-in: its ``replan_check``,
``plan`` and ``yaw_rate`` calls of one step together (pbdyn.sim.agent.Agent.act). A decision past it ends the trial
as an error naming the budget (a batch's ``error`` row; the batch goes on). Built-in pairs have no budget and pay
nothing for it. Within pbdyn.sim.trial.fly_trials one interval timer (decision_watchdog) serves every decision of the
loop, and a decision costs a clock read (about 0.1 us); elsewhere each decision arms a time_budget of its own
(about 12 us). Interrupts Python code (loops, sleeps, waits) in a process's main thread -- local batch workers,
``pbdyn run`` --, not one C call that never returns, and not on Dask workers (threads), where a decision is not
bounded."""

_RETRY_S = 0.5
"""After the budget is spent, the timer fires again every _RETRY_S s (user code that swallows the first
interruption with ``except BaseException`` is interrupted again)."""


class UserCodeTimeout(BaseException):
    """User code ran past its time budget. A BaseException, so ``except Exception`` in user code cannot swallow
    it; callers turn it into a ConfigError."""

    def __init__(self, seconds: float):
        self.seconds = seconds
        super().__init__(f"did not return within {seconds:g} s")


# ------------------------------------------------------------------------------------------------ stdout
def flush_c_stdout() -> None:
    """Flush the C runtime's stdio buffers (printf output of extensions) so they land where fd 1 points now."""
    try:
        ctypes.CDLL(None).fflush(None)
    except (OSError, AttributeError):  # pragma: no cover - platforms without a C runtime handle
        pass


@contextlib.contextmanager
def stdout_fd_to(fd: int | None) -> Iterator[None]:
    """Point file descriptor 1 at ``fd`` (None: /dev/null) for the duration; Python's and the C runtime's stdout
    buffers are flushed on both sides, so nothing printed inside the block can reach the real stdout later."""
    sys.stdout.flush()
    flush_c_stdout()
    try:
        saved = os.dup(1)
    except OSError:  # no fd 1 at all: nothing to protect
        yield
        return
    devnull = os.open(os.devnull, os.O_WRONLY) if fd is None else None
    try:
        os.dup2(devnull if fd is None else fd, 1)
        yield
    finally:
        try:
            sys.stdout.flush()
        except Exception:  # user code may have closed or replaced sys.stdout; fd 1 is restored regardless
            pass
        flush_c_stdout()
        os.dup2(saved, 1)
        os.close(saved)
        if devnull is not None:
            os.close(devnull)


_lock = threading.Lock()
_depth = 0
_saved_stdout = None


class user_stdout:
    """Context manager: ``sys.stdout`` is ``sys.stderr`` for the duration (Python-level writes of user code: print,
    sys.stdout.write). Re-entrant and safe across threads (the first entry saves sys.stdout, the last exit restores
    it); the cost is a lock and two assignments, so it can wrap every planner call. ``sys.stdout`` is restored
    even if user code replaced it."""

    __slots__ = ()

    def __enter__(self) -> None:
        global _depth, _saved_stdout
        with _lock:
            if _depth == 0:
                _saved_stdout = sys.stdout
                sys.stdout = sys.stderr
            _depth += 1

    def __exit__(self, *exc) -> None:
        global _depth, _saved_stdout
        with _lock:
            _depth -= 1
            if _depth == 0:
                sys.stdout = _saved_stdout
                _saved_stdout = None


@contextlib.contextmanager
def quiet_user_code(fd_level: bool = True) -> Iterator[None]:
    """Python-level (and with ``fd_level``, file-descriptor-level) stdout of the block goes to stderr."""
    if fd_level:
        with stdout_fd_to(2), user_stdout():
            yield
    else:
        with user_stdout():
            yield


# ------------------------------------------------------------------------------------------------ time
class time_budget:
    """Context manager bounding the wall-clock time of a block of user calls to ``seconds``.

    With SIGALRM in the main thread, an interval timer raises UserCodeTimeout wherever the block is when the
    budget runs out (a call that sleeps, loops or waits), and again every 0.5 s if user code swallows it. An outer
    interval timer (pytest-timeout, a caller's own budget) keeps working: its handler runs when its own deadline
    comes, and the remaining time is re-armed on exit. Elsewhere ``check()`` after each call raises once the
    budget is spent. ``check()`` is cheap and always valid to call."""

    def __init__(self, seconds: float = USER_CODE_TIMEOUT_S):
        self.seconds = float(seconds)
        self._armed = False

    def __enter__(self) -> "time_budget":
        self._t0 = time.monotonic()
        self._deadline = self._t0 + self.seconds
        self._armed = (hasattr(signal, "SIGALRM") and hasattr(signal, "setitimer")
                       and threading.current_thread() is threading.main_thread())
        if self._armed:
            try:
                self._old_handler = signal.getsignal(signal.SIGALRM)
                if self._old_handler is None:  # installed outside Python: the best we can restore is the default
                    self._old_handler = signal.SIG_DFL
                old_delay, old_interval = signal.setitimer(signal.ITIMER_REAL, 0.0)
            except (ValueError, OSError):  # pragma: no cover - signals unavailable here after all
                self._armed = False
                return self
            self._outer = (self._t0 + old_delay, old_interval) if old_delay > 0 else None
            signal.signal(signal.SIGALRM, self._on_alarm)
            self._arm(time.monotonic())
        return self

    def _arm(self, now: float) -> None:
        nxt = self._deadline
        if self._outer is not None:
            nxt = min(nxt, self._outer[0])
        signal.setitimer(signal.ITIMER_REAL, max(nxt - now, 1e-4), _RETRY_S)

    def _on_alarm(self, signum, frame) -> None:
        now = time.monotonic()
        if self._outer is not None and now >= self._outer[0]:
            deadline, interval = self._outer
            self._outer = (deadline + interval, interval) if interval > 0 else None
            if now < self._deadline:
                self._arm(now)
            if callable(self._old_handler):
                self._old_handler(signum, frame)
            elif self._old_handler == signal.SIG_DFL:  # the default action of SIGALRM ends the process
                signal.signal(signal.SIGALRM, signal.SIG_DFL)
                os.kill(os.getpid(), signal.SIGALRM)
            if now < self._deadline:
                return
        if now >= self._deadline:
            raise UserCodeTimeout(self.seconds)
        self._arm(now)  # an early wake-up (e.g. the outer timer's interval): wait on

    def check(self) -> None:
        """Raise UserCodeTimeout if the budget is spent (the fallback where no timer can interrupt)."""
        if time.monotonic() >= self._deadline:
            raise UserCodeTimeout(self.seconds)

    def __exit__(self, *exc) -> None:
        if not self._armed:
            return
        try:
            signal.setitimer(signal.ITIMER_REAL, 0.0)
        finally:
            signal.signal(signal.SIGALRM, self._old_handler)
            if self._outer is not None:
                deadline, interval = self._outer
                signal.setitimer(signal.ITIMER_REAL, max(deadline - time.monotonic(), 1e-4), interval)


_watchdog: "decision_watchdog | None" = None


def watchdog() -> "decision_watchdog | None":
    """The decision_watchdog armed in this process (None: none is; decisions then arm a time_budget each)."""
    return _watchdog


class decision_watchdog:
    """Context manager: one interval timer for many short, budgeted calls of a loop (plug-in planners' decisions in
    pbdyn.sim.trial.fly_trials), armed once. A call marks its start (``started = time.monotonic()``) and clears it
    (``started = None``) when it returns; the timer ticks every min(1 s, seconds / 4) and raises UserCodeTimeout in
    a call that has run ``seconds`` or more (again at each tick if user code swallows it), so a call costs a clock
    read instead of the timer and handler calls of a time_budget. It arms only in the main thread of a POSIX
    process, with no other watchdog armed and no interval timer running (pytest-timeout, a caller's time_budget);
    otherwise ``armed`` is False and callers fall back to a time_budget per call."""

    def __init__(self, seconds: float):
        self.seconds = float(seconds)
        self.started: float | None = None
        self.armed = False

    def __enter__(self) -> "decision_watchdog":
        global _watchdog
        if (_watchdog is not None or not hasattr(signal, "SIGALRM") or not hasattr(signal, "setitimer")
                or threading.current_thread() is not threading.main_thread()):
            return self
        try:
            if signal.getitimer(signal.ITIMER_REAL)[0] > 0:     # someone else's timer runs: leave it alone
                return self
            self._old_handler = signal.getsignal(signal.SIGALRM)
            if self._old_handler is None:
                self._old_handler = signal.SIG_DFL
            signal.signal(signal.SIGALRM, self._on_alarm)
            tick = min(1.0, self.seconds / 4.0)
            signal.setitimer(signal.ITIMER_REAL, tick, tick)
        except (ValueError, OSError):  # pragma: no cover - signals unavailable here after all
            return self
        self.armed = True
        _watchdog = self
        return self

    def _on_alarm(self, signum, frame) -> None:
        started = self.started
        if started is not None and time.monotonic() - started >= self.seconds:
            raise UserCodeTimeout(self.seconds)

    def __exit__(self, *exc) -> None:
        global _watchdog
        if not self.armed:
            return
        self.armed = False
        _watchdog = None
        try:
            signal.setitimer(signal.ITIMER_REAL, 0.0)
        finally:
            signal.signal(signal.SIGALRM, self._old_handler)
