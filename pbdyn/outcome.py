"""How a trial ends (thesis 2-5): an enum with readable reasons; the only list of outcome names.

Consumers (analysis, store rows, demo, tools) iterate over Outcome / OUTCOMES rather than writing names, so a new
outcome needs only a member and its reason here.
"""

from __future__ import annotations

from enum import Enum


class Outcome(str, Enum):
    """Trial outcome. The value is the name stored in results; ``reason`` explains it."""

    SUCCESS = "success"
    STATIC_COLLISION = "static_collision"
    DYNAMIC_COLLISION = "dynamic_collision"
    FREEZING = "freezing"
    DEADLOCK = "deadlock"
    INVALID_PLAN = "invalid_plan"
    ERROR = "error"

    @property
    def reason(self) -> str:
        """A readable explanation of the outcome."""
        return _REASONS[self]


OUTCOMES: tuple[str, ...] = tuple(o.value for o in Outcome)
"""Every outcome name as stored in results, in enum order."""

FAILURES: tuple[Outcome, ...] = tuple(o for o in Outcome if o not in (Outcome.SUCCESS, Outcome.ERROR))
"""Outcomes of a flown trial that did not reach the goal ("error" marks a trial that raised, not a flight)."""

_REASONS = {
    Outcome.SUCCESS: "reached the goal ball",
    Outcome.STATIC_COLLISION: "touched a wall or a static obstacle",
    Outcome.DYNAMIC_COLLISION: "touched a moving obstacle",
    Outcome.FREEZING: "did not reach the goal within the time limit",
    Outcome.DEADLOCK: "planning failed repeatedly with the MAV at rest",
    Outcome.INVALID_PLAN: "the planner returned a plan that breaks the plan contract",
    Outcome.ERROR: "the trial raised an exception",
}
