"""Local worker pools and a script without ``if __name__ == "__main__":``.

pbdyn's worker processes start with multiprocessing's "spawn" method (pbdyn.experiments.pool, generate): each
new process imports the parent's main script again, as the module ``__mp_main__``, before it does any work. A
script that calls run_batch (or calibrate, generate_maps, bench: anything that starts a local pool) at its top level,
not under ``if __name__ == "__main__":``, therefore calls it again in every worker while that worker is still
starting; multiprocessing refuses to start processes from there, the worker dies, and the pool is restarted over
and over, printing a traceback each time.

This module turns that into one line. In a worker that is importing the main script, check_not_reimported() ends
the worker at once and quietly, leaving what was called in a report file whose path the pool's owner passed down in
the environment (REPORT_ENV); the owner (PoolGuard) reads the report when its pool breaks and raises
MainGuardError. A MainGuardError is a ConfigError, and also a SystemExit: uncaught, it ends the script with its
one line on stderr and exit status 1 instead of a traceback. A worker started by someone else's pool (no report
path) raises the MainGuardError itself.
"""

from __future__ import annotations

import os
import secrets
import sys
import tempfile
from pathlib import Path

from pbdyn.errors import ConfigError

REPORT_ENV = "PBDYN_POOL_REPORT"
"""Environment variable naming the file a worker that re-imports the main script leaves its explanation in."""
_REIMPORT_NAME = "__mp_main__"   # multiprocessing's name for the parent's main module re-imported in a child


class MainGuardError(ConfigError, SystemExit):
    """A local worker pool was started from a script's top level without ``if __name__ == "__main__":``. A
    ConfigError (a ValueError); uncaught, it ends the script like SystemExit with its one line (exit status 1)."""

    def __init__(self, what: str, script: str | None = None):
        where = f" of {script}" if script else ""
        ConfigError.__init__(self, what, f"was called at the top level{where}, which every worker process runs again "
                             "when it starts (multiprocessing's spawn start method): put the call under "
                             "`if __name__ == \"__main__\":`", None, show_value=False)
        self.code = f"pbdyn: error: {self}"     # what the interpreter prints when it ends the script with it


def _main_script() -> str | None:
    main = sys.modules.get("__main__")
    path = getattr(main, "__file__", None)
    return str(path) if path else None


def reimporting_main() -> bool:
    """True in a worker process while it imports the parent's main script (multiprocessing's bootstrap)."""
    multiprocessing = sys.modules.get("multiprocessing")
    if multiprocessing is None:     # a worker has it loaded before it runs anything: this is no worker
        return False
    process = multiprocessing.current_process()
    if getattr(process, "_inheriting", False):
        return True
    if multiprocessing.parent_process() is None:
        return False
    frame = sys._getframe(1)
    while frame is not None:
        if frame.f_code.co_name == "<module>" and frame.f_globals.get("__name__") == _REIMPORT_NAME:
            return True
        frame = frame.f_back
    return False


def check_not_reimported(what: str) -> None:
    """Called first by everything that starts a local worker pool (``what``: its name, e.g. "run_batch"). In a
    worker importing the main script (reimporting_main): leave the report for the pool's owner and end this
    process quietly, or raise MainGuardError where no owner asked for a report. Elsewhere: nothing."""
    if not reimporting_main():
        return
    error = MainGuardError(what, _main_script())
    report = os.environ.get(REPORT_ENV)
    if report:
        try:        # a new file only (O_EXCL: never through a link someone planted); a sibling may have made it
            fd = os.open(report, os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_CLOEXEC", 0), 0o600)
            with os.fdopen(fd, "w", encoding="utf-8") as fh:
                fh.write(what + "\n")
        except FileExistsError:
            pass
        except OSError:
            raise error from None
        sys.stderr.flush()
        os._exit(1)
    raise error


class PoolGuard:
    """Owned by whoever starts a local pool (``what``: its name): while it is open, the pool's workers find a
    report path in the environment (REPORT_ENV: a new, unpredictable name in the temp folder that only a reporting
    worker creates); after the pool broke, check() raises the MainGuardError a worker reported, if one did.
    close() restores the environment and removes the report."""

    def __init__(self, what: str):
        self.what = what
        # Named, not made: only a worker that has something to report creates it (nothing is left behind otherwise)
        self.path = Path(tempfile.gettempdir()) / f"pbdyn-pool-{os.getpid()}-{secrets.token_hex(12)}"
        self._saved = os.environ.get(REPORT_ENV)
        os.environ[REPORT_ENV] = str(self.path)

    def reported(self) -> str | None:
        """What a worker reported being called at the main script's top level (e.g. "run_batch"; this guard's own
        ``what`` while the report is still being written), or None: no report."""
        try:
            return self.path.read_text(encoding="utf-8").strip() or self.what
        except FileNotFoundError:
            return None
        except OSError:
            return self.what if self.path.exists() else None

    def check(self) -> None:
        """Raise MainGuardError (with the main script's name) if a worker reported re-importing the main script."""
        what = self.reported()
        if what is not None:
            raise MainGuardError(what, _main_script()) from None

    def close(self) -> None:
        if os.environ.get(REPORT_ENV) == str(self.path):
            if self._saved is None:
                os.environ.pop(REPORT_ENV, None)
            else:
                os.environ[REPORT_ENV] = self._saved
        try:
            self.path.unlink(missing_ok=True)
        except OSError:
            pass
