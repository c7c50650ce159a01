"""What a bench cost (the card's "cost"): wall time and CPU seconds summed over the invocations that worked in a
bench folder, kept in a small ledger there (LEDGER, written atomically) so that a resumed bench adds up.

CPU seconds are this process's and its child processes' (resource.getrusage RUSAGE_SELF + RUSAGE_CHILDREN): the
local worker processes of the batch runner are children that end -- and are waited for -- when each part's batch
closes its pool, so their CPU time is counted once the part is flown. Workers of a Dask cluster are other
machines' processes: with a scheduler only this process's CPU time is counted (docs/benchmark.md).

An invocation is recorded only if it flew a task or drew (or began) a replay: a fully resumed bench adds nothing.
One that is interrupted (Ctrl-C, SIGTERM) while flying or drawing is recorded with what it spent.
"""

from __future__ import annotations

import json
import math
import time
from datetime import datetime, timezone
from pathlib import Path

from pbdyn.errors import ConfigError

LEDGER = "cost.json"
LEDGER_FORMAT = "pbdyn-bench-cost/1"
MAX_LEDGER_BYTES = 16 << 20
"""Largest ledger read (an entry is ~150 bytes)."""


def cpu_seconds() -> float:
    """User + system CPU seconds of this process and of its ended (waited-for) child processes, so far."""
    import resource

    total = 0.0
    for who in (resource.RUSAGE_SELF, resource.RUSAGE_CHILDREN):
        r = resource.getrusage(who)
        total += r.ru_utime + r.ru_stime
    return total


def read_ledger(out: Path) -> list[dict]:
    """The entries of the bench folder's ledger ([] if it has none); ConfigError naming --out's ledger file if it is
    not one (damaged, or not written by pbdyn)."""
    path = Path(out) / LEDGER
    if not path.exists():
        return []
    problem = None
    try:
        if not path.is_file() or path.stat().st_size > MAX_LEDGER_BYTES:
            raise ValueError("not a ledger file")
        doc = json.loads(path.read_text(encoding="utf-8"))
        runs = doc.get("runs") if isinstance(doc, dict) and doc.get("format") == LEDGER_FORMAT else None
        if not isinstance(runs, list) or not all(_entry_ok(r) for r in runs):
            raise ValueError("not a ledger")
        return runs
    except (OSError, UnicodeDecodeError, ValueError) as exc:
        problem = type(exc).__name__
    raise ConfigError("out", f"holds a cost ledger {LEDGER} that is not a {LEDGER_FORMAT} document ({problem}); "
                      f"remove it (the card's cost then counts from the next bench on) or use another `out` folder",
                      str(path))


def _entry_ok(r) -> bool:
    return (isinstance(r, dict) and all(isinstance(r.get(k), (int, float)) and not isinstance(r.get(k), bool)
                                        and math.isfinite(r[k]) and r[k] >= 0
                                        for k in ("wall_s", "cpu_s", "flown", "replays")))


def totals(runs: list[dict]) -> dict:
    """The card's "cost": wall and CPU seconds summed over the ledger's entries, and their count."""
    return {"wall_s": round(sum(float(r["wall_s"]) for r in runs), 3),
            "cpu_s": round(sum(float(r["cpu_s"]) for r in runs), 3), "runs": len(runs)}


class Meter:
    """Measures one invocation's work in a bench folder (wall time, CPU seconds of this process and its children)
    from its creation; ``record`` appends it to the folder's ledger."""

    def __init__(self, out: Path):
        self.out = Path(out)
        self.runs = read_ledger(self.out)
        self.t0 = time.perf_counter()
        self.cpu0 = cpu_seconds()
        self.recorded = False

    def record(self, flown: int, replays: int) -> list[dict]:
        """Append this invocation (if it flew a task or drew a replay; once) to the ledger, written atomically;
        returns the ledger's entries."""
        if self.recorded or (flown <= 0 and replays <= 0):
            return self.runs
        self.recorded = True
        entry = {"wall_s": round(time.perf_counter() - self.t0, 3), "cpu_s": round(cpu_seconds() - self.cpu0, 3),
                 "flown": int(flown), "replays": int(replays),
                 "date": datetime.now(timezone.utc).replace(microsecond=0).isoformat()}
        self.runs = [*self.runs, entry]
        from pbdyn.files import atomic_write_text

        atomic_write_text(self.out / LEDGER, json.dumps({"format": LEDGER_FORMAT, "runs": self.runs}, indent=1,
                                                        sort_keys=True) + "\n")
        return self.runs
