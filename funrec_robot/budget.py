"""The hard CPU-time limit of one plan, seen by every planning stage.

:func:`funrec_robot.plan.plan_interaction` opens a :func:`plan_time_limit`; the loops of every stage (the
handle path's collision and gravity scans, base placement, whole-body IK at each path state and iteration,
the timing of each move) call :func:`check_time_limit` with their name, which raises a
:class:`~funrec.errors.PlanningError` naming the stage once the limit is spent. CPU time, not wall time, as
the search budget (``PlanConfig.time_budget``): the same plan must not pass or fail by machine load. Outside
a plan (a stage called on its own) there is no limit.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from contextlib import contextmanager
from contextvars import ContextVar

from funrec.errors import PlanningError


class TimeLimitSpent(PlanningError):
    """The plan's CPU-time limit is spent: never a failed attempt to try another way round, the plan ends."""


_LIMIT: ContextVar[tuple[float, float] | None] = ContextVar("funrec_robot_plan_time_limit", default=None)
"""(process CPU time at which the limit is spent, the limit in seconds), or None."""


@contextmanager
def plan_time_limit(seconds: float) -> Iterator[None]:
    """Limit the CPU time of the planning inside the block to ``seconds``."""
    token = _LIMIT.set((time.process_time() + seconds, seconds))
    try:
        yield
    finally:
        _LIMIT.reset(token)


def remaining_time() -> float | None:
    """CPU seconds left of the current plan's limit (None: no limit)."""
    limit = _LIMIT.get()
    return None if limit is None else max(limit[0] - time.process_time(), 0.0)


def check_time_limit(stage: str) -> None:
    """Raise when the current plan's CPU-time limit is spent.

    Raises:
        PlanningError: naming the stage that was running and the limit.
    """
    limit = _LIMIT.get()
    if limit is not None and time.process_time() > limit[0]:
        raise TimeLimitSpent(f"planning time limit of {limit[1]:g} s CPU spent during {stage}; "
                            "the plan was abandoned (raise --time-limit, or check the twin's parts and ranges)")


__all__ = ["TimeLimitSpent", "check_time_limit", "plan_time_limit", "remaining_time"]
