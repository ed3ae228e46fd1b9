"""Exceptions raised by funrec_robot; every message names the file and lists the valid choices."""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path

from funrec.errors import PlanningError

_MAX_LISTED = 40
"""Longest list of valid names quoted in a message; longer lists are cut with a count."""


def format_names(names: Iterable[str]) -> str:
    """Quote names for an error message: ``'a', 'b', 'c'`` (cut after ``_MAX_LISTED``)."""
    listed = [f"'{name}'" for name in names]
    if not listed:
        return "(none)"
    if len(listed) > _MAX_LISTED:
        return ", ".join(listed[:_MAX_LISTED]) + f", ... ({len(listed) - _MAX_LISTED} more)"
    return ", ".join(listed)


class RobotDescriptionError(PlanningError):
    """A robot YAML file, or the model file it points to, is missing something or is inconsistent.

    The message names the YAML (or model) file and the key, and lists the valid names, the way
    mink's ``InvalidFrame`` does:
    ``robots/fetch.yaml: arm_joints: joint 'shoulder' not in the model; valid joints: 'robot0:slide0', ...``.
    """

    def __init__(self, path: str | Path, problem: str) -> None:
        self.path = Path(path)
        self.problem = problem
        super().__init__(f"{self.path}: {problem}")


class UnknownNameError(RobotDescriptionError):
    """A name in a robot YAML file is not an element of the expected kind in the model."""

    def __init__(self, path: str | Path, key: str, kind: str, name: str, valid: Iterable[str]) -> None:
        self.key = key
        self.name = name
        self.valid = tuple(valid)
        plural = "bodies" if kind == "body" else f"{kind}s"
        super().__init__(path, f"{key}: {kind} '{name}' not in the model; valid {plural}: {format_names(self.valid)}")


class Refusal(PlanningError):
    """The robot cannot do the task at all, decided before any optimisation: the handle is outside its reach
    band (``reach.reach_refusal``), no grasp tilt lets its gripper take the handle, or every tilt puts the
    handle path's wrist targets beyond the arm's reach above or below its shoulder. The bench counts such a
    part as refused, not as a failure among the parts the robot accepts."""


__all__ = ["Refusal", "RobotDescriptionError", "UnknownNameError", "format_names"]
