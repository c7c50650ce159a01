"""A suite's difficulty levels (docs/benchmark.md "The suites", "Levels"): level k holds the maps whose reference
panel success falls in the k-th band between LEVEL_EDGES. Which flights measure that success (a v1 suite's own
tasks, a v2 suite's held-out tasks) is the suite's (pbdyn.benchmark.suite); a manifest records its maps' levels."""

LEVEL_EDGES = (1.0, 0.85, 0.75, 0.65, 0.55, 0.45, 0.35, 0.25, 0.15, 0.0)
"""Reference-success edges of the levels: level 1 = [0.85, 1], ..., level 9 = [0, 0.15)."""


def level_of(success: float) -> int:
    """The level of a map whose reference success is ``success`` (the hardest when it is below every edge)."""
    return next((k for k in range(1, len(LEVEL_EDGES)) if success >= LEVEL_EDGES[k]), len(LEVEL_EDGES) - 1)


def level_ranges() -> list[dict]:
    """A manifest's levels: number and reference-success range [lo, hi]."""
    return [{"level": k, "success_range": [LEVEL_EDGES[k], LEVEL_EDGES[k - 1]]} for k in range(1, len(LEVEL_EDGES))]
