"""The check record of a plan: the check report bound to the exact bytes of the plan it judged.

``PLAN.check.json`` is the report of :func:`funrec_robot.check.check_plan` plus ``"format":
"funrec-check/1"``, ``plan_file`` and ``plan_sha256`` (sha256 of plan.json's bytes). ``send`` accepts a
plan only with a record whose hash matches the plan's current bytes and that passed.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from funrec.errors import FormatError, PlanningError
from funrec.formats.twin import read_json_object
from funrec_robot.check import CheckReport
from funrec_robot.plan_file import sha256_file

CHECK_FORMAT = "funrec-check/1"
"""Format tag written into and required from a check record."""


def record_path(plan_path: str | Path) -> Path:
    """Default check record beside a plan: ``plan.json`` -> ``plan.check.json``."""
    return Path(plan_path).with_suffix(".check.json")


def write_check_record(report: CheckReport, plan_path: str | Path, path: str | Path | None = None) -> Path:
    """Write the report of a check of the plan file ``plan_path``, bound to its sha256."""
    path = record_path(plan_path) if path is None else Path(path)
    data = {"format": CHECK_FORMAT, "plan_file": str(Path(plan_path).resolve()), "plan_sha256": sha256_file(plan_path)}
    data.update(report.to_json())
    path.write_text(json.dumps(data, indent=1) + "\n")
    return path


def require_passing_record(plan_path: str | Path, path: str | Path | None = None) -> dict[str, Any]:
    """The check record of a plan, if it exists, is of these bytes and passed.

    Raises:
        PlanningError: no record, a record of other bytes (the plan was changed or another plan was
            checked), or a failed check; the message says which and what to run.
    """
    plan_path = Path(plan_path)
    path = record_path(plan_path) if path is None else Path(path)
    if not path.is_file():
        raise PlanningError(f"{plan_path}: no check record {path}; run `funrec-robot check {plan_path}` first")
    record = read_json_object(path)
    if record.get("format") != CHECK_FORMAT:
        raise FormatError(path, f"not a check record (expected \"format\": \"{CHECK_FORMAT}\")")
    digest = sha256_file(plan_path)
    if record.get("plan_sha256") != digest:
        raise PlanningError(
            f"{plan_path}: its check record {path} is of another plan (sha256 {str(record.get('plan_sha256'))[:12]}..., "
            f"this plan {digest[:12]}...); check this plan again"
        )
    if record.get("passed") is not True:
        failed = ", ".join(record.get("failed_criteria", [])) or "unknown criteria"
        raise PlanningError(f"{plan_path}: its check failed ({failed}, see {path}); a failed plan is never sent")
    return record


__all__ = ["CHECK_FORMAT", "record_path", "require_passing_record", "write_check_record"]
