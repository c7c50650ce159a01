"""`pbdyn batch --shard I/N`: parsing the option and the block of the enumeration (trials and maps) a shard flies.

A shard takes a contiguous block of maps with all of their trials, so the shards' stores join with `pbdyn merge`
(pbdyn.experiments.merge; docs/experiments.md).
"""

from __future__ import annotations

from pbdyn.errors import ConfigError


def shard_range(trials, total: int, shard: tuple[int, int] | None) -> tuple[int, int, range]:
    """(start, stop, map indices) of shard (i, n) of the first ``total`` trials: the maps they touch are cut into n
    contiguous blocks of (nearly) equal size and shard i takes the i-th block with all of its trials (a map's trials
    and its metrics stay in one shard; a shard can be empty when n exceeds the maps). None: everything."""
    maps = trials.map_range(total)
    if shard is None:
        return 0, total, maps
    i, n = shard
    m_lo, m_hi = (i - 1) * len(maps) // n, i * len(maps) // n
    per = trials.per_map
    return min(m_lo * per, total), min(m_hi * per, total), range(m_lo, m_hi)


def parse_shard(text) -> tuple[int, int]:
    """"I/N" (1 <= I <= N) -> (I, N); ConfigError naming --shard otherwise."""
    if isinstance(text, tuple) and len(text) == 2:
        i, n = text
    else:
        parts = str(text).split("/")
        try:
            i, n = (int(p) for p in parts) if len(parts) == 2 else (None, None)
        except ValueError:
            i = n = None
    if not (isinstance(i, int) and isinstance(n, int) and not isinstance(i, bool) and not isinstance(n, bool)
            and 1 <= i <= n):
        raise ConfigError("shard", "must be I/N with integers 1 <= I <= N (e.g. 3/8)", text)
    return i, n
