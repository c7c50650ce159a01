"""Frozen benchmark suites, their reference results and score cards (`pbdyn bench`; docs/benchmark.md)."""
