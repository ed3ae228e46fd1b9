"""Plan and check every articulated part of a folder of synthetic captures: on their ground-truth scenes,
or on reconstructed twins of them with each plan checked in the ground-truth scene."""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from funrec.errors import FunrecError
from funrec.formats.ground_truth import read_ground_truth
from funrec_robot.check import CheckConfig, T_scene_plan_from_gt, check_plan
from funrec_robot.errors import Refusal
from funrec_robot.plan import PlanConfig, plan_interaction
from funrec_robot.plan_file import write_plan
from funrec_robot.retime import retime_path
from funrec_robot.robot import load_robot
from funrec_robot.sim_model import build_mujoco_model
from funrec_robot.task_sources import task_from_ground_truth, task_from_twin

log = logging.getLogger(__name__)

DEFAULT_FAMILY = "textured"
"""Family of a capture whose gt.json names none (the textured bench predates families)."""


@dataclass(frozen=True)
class BenchRow:
    """Outcome for one part."""

    case: str
    """Capture folder name."""
    part: str
    """Part name."""
    joint_type: str
    """"revolute" or "prismatic"."""
    planned: bool
    """A plan was made."""
    passed: bool
    """The plan passed the check."""
    failure: str
    """Why not: the planning error, or the failed criteria with their first details; '' if passed."""
    plan_time: float
    """Wall-clock planning time (model build, task, plan), s."""
    plan_cpu_time: float
    """CPU time of the same, s."""
    peak_handle_force: float
    """Peak handle force in the check, N (nan if not planned)."""
    collisions: int
    """Forbidden robot-scene contacts recorded in the check (up to 20)."""
    target_error: float
    """Final joint error, rad or m (nan if not planned)."""
    base_stops: int
    """Base stops of the plan (0 if not planned)."""
    duration: float
    """Plan duration, s."""
    refused: bool = False
    """The robot refused the part before any optimisation (``errors.Refusal``: out of its reach band, or a
    handle its gripper cannot take); the other rows are the parts it accepts."""
    family: str = DEFAULT_FAMILY
    """Bench family of the capture (``generator.spec.family`` in its gt.json)."""


def bench_suite(
    suite: str | Path,
    robot_path: str | Path,
    target: str = "open",
    only: Sequence[str] = (),
    plan_config: PlanConfig | None = None,
    check_config: CheckConfig | None = None,
    plans_dir: str | Path | None = None,
    progress: Callable[[BenchRow], None] | None = None,
    twins: str | Path | None = None,
) -> tuple[BenchRow, ...]:
    """Plan and check each part of each capture under ``suite`` that has ground truth.

    With ``twins``, plans are made on the reconstructed twin ``twins/<case>`` (its twin.xml, articulation.json
    and affordances.json) and checked in the capture's ground-truth scene, mapped through camera 0
    (FORMATS.md section 4). Each true part gets one row: the twin part whose contact point is nearest its
    handle is planned; a true part no twin part maps to is a failure row ("not in the twin"), as is a case
    without a twin.

    Args:
        suite: folder of capture folders (each with gt/gt.json and gt/scene.xml).
        robot_path: robot YAML file.
        target: target of every plan ('open', 'close' or a state).
        only: capture names to restrict to (empty: all).
        plans_dir: write each plan as ``<case>_<part>.json`` here.
        progress: called with each row as it is done.
        twins: folder of twin folders named as the captures (e.g. ``bench_report/twins/funrec``).
    """
    plan_config = PlanConfig() if plan_config is None else plan_config
    check_config = CheckConfig() if check_config is None else check_config
    robot = load_robot(robot_path)
    if plans_dir is not None:
        Path(plans_dir).mkdir(parents=True, exist_ok=True)
    retime_path([[0.0], [1.0]], [1.0], [1.0])  # pays toppra's one-time import before any plan is timed
    rows = []
    for gt_json in sorted(Path(suite).glob("*/gt/gt.json")):
        case = gt_json.parent.parent.name
        if only and case not in only:
            continue
        gt = read_ground_truth(gt_json.parent)
        family = _family(gt.extra)
        case_rows = (_ground_truth_rows if twins is None else _twin_rows)(
            case, gt, robot, target, plan_config, check_config, plans_dir, None if twins is None else Path(twins) / case)
        for row in _isolated(case, gt, case_rows):
            row = replace(row, family=family)
            rows.append(row)
            if progress is not None:
                progress(row)
    return tuple(rows)


def _isolated(case: str, gt: Any, case_rows: Iterator[BenchRow]) -> Iterator[BenchRow]:
    """The rows of one case; an unexpected exception (a bug, not a ``FunrecError``) ends only that case: each of its
    true parts not yet reported becomes a failure row naming the exception (its traceback logged with -v)."""
    done: set[str] = set()
    clock, cpu = time.perf_counter(), time.process_time()
    try:
        for row in case_rows:
            done.add(row.part)
            yield row
            clock, cpu = time.perf_counter(), time.process_time()
    except Exception as exc:  # noqa: BLE001 - one part's bug must not end the bench
        why = _unexpected(case, exc)
        for gt_part in gt.parts:
            if gt_part.part.name not in done:
                yield _not_planned(case, gt_part.part.name, gt_part.part.joint_type, why, clock, cpu)


def _unexpected(case: str, exc: Exception) -> str:
    """A failure's text for an unexpected exception, logged (with its traceback when debugging)."""
    why = f"unexpected error: {type(exc).__name__}: {exc}"
    log.error("%s: %s", case, why, exc_info=log.isEnabledFor(logging.DEBUG))
    return why


def _family(extra: dict[str, Any]) -> str:
    """The bench family a ground truth's generator spec names (``DEFAULT_FAMILY`` if none)."""
    generator = extra.get("generator")
    spec = generator.get("spec") if isinstance(generator, dict) else None
    family = spec.get("family") if isinstance(spec, dict) else None
    return family if isinstance(family, str) and family else DEFAULT_FAMILY


def _not_planned(case: str, part: str, joint_type: str, why: str, clock: float, cpu: float, refused: bool = False) -> BenchRow:
    return BenchRow(case, part, joint_type, False, False, why, time.perf_counter() - clock, time.process_time() - cpu,
                    np.nan, 0, np.nan, 0, 0.0, refused)


def _checked(case: str, part: str, plan: Any, report: Any, clock: float, cpu: float) -> BenchRow:
    failure = "; ".join(f"{f.criterion} at {f.time:.2f} s: {f.detail}" for f in report.failures)
    return BenchRow(case, part, plan.joint_type, True, report.passed, failure, clock, cpu, report.peak_handle_force,
                    len(report.collisions), report.target_error, len(plan.base_poses), plan.duration)


def _ground_truth_rows(case, gt, robot, target, plan_config, check_config, plans_dir, _twin):  # noqa: ANN001, ANN202
    """One row per true part, planned and checked in the ground-truth scene."""
    for gt_part in gt.parts:
        name = gt_part.part.name
        clock, cpu = time.perf_counter(), time.process_time()
        try:
            model = build_mujoco_model(robot, gt.scene_xml, textures=False)
            task = task_from_ground_truth(gt.root, name, model)
            plan = plan_interaction(robot, gt.scene_xml, task, target, config=plan_config, model=model)
        except FunrecError as exc:
            yield _not_planned(case, name, gt_part.part.joint_type, str(exc), clock, cpu, isinstance(exc, Refusal))
            continue
        plan_time, plan_cpu = time.perf_counter() - clock, time.process_time() - cpu
        if plans_dir is not None:
            write_plan(Path(plans_dir) / f"{case}_{name}.json", plan)
        report = check_plan(plan, robot, gt.scene_xml, config=check_config)
        yield _checked(case, name, plan, report, plan_time, plan_cpu)


def _twin_rows(case, gt, robot, target, plan_config, check_config, plans_dir, twin):  # noqa: ANN001, ANN202
    """One row per true part: the nearest twin part planned on the twin and checked in the true scene."""
    from funrec.formats.twin import read_articulation
    from funrec_robot.replay import nearest_gt_joint

    true_types = {p.part.name: p.part.joint_type for p in gt.parts}
    done: set[str] = set()
    errors: list[tuple[str, bool]] = []  # (why, refused) per twin part that was not planned
    clock, cpu = time.perf_counter(), time.process_time()
    try:
        twin_parts = [p.name for p in read_articulation(twin).parts]
        twin_xml = twin / "twin.xml"
        model = build_mujoco_model(robot, twin_xml, textures=False) if twin_parts else None
    except (FunrecError, OSError) as exc:
        twin_parts, why = [], f"no usable twin: {exc}"
    else:
        why = "not in the twin"
    for name in twin_parts:
        clock, cpu = time.perf_counter(), time.process_time()
        try:
            task = task_from_twin(twin, name)
            plan = plan_interaction(robot, twin_xml, task, target, config=plan_config, model=model)
            T_scene_plan = T_scene_plan_from_gt(plan, gt.root)
            joint = nearest_gt_joint(gt.root, T_scene_plan, task.p_world_contact)
        except FunrecError as exc:
            errors.append((f"twin {name}: {exc}", isinstance(exc, Refusal)))
            continue  # judged below as its true part's failure, if no other twin part succeeds
        except Exception as exc:  # noqa: BLE001 - a bug planning one twin part leaves the others to be tried
            errors.append((f"twin {name}: {_unexpected(case, exc)}", False))
            continue
        if joint in done:
            continue
        plan_time, plan_cpu = time.perf_counter() - clock, time.process_time() - cpu
        if plans_dir is not None:
            write_plan(Path(plans_dir) / f"{case}_{name}.json", plan)
        report = check_plan(plan, robot, gt.scene_xml, joint, T_scene_plan, check_config)
        done.add(joint)
        yield _checked(case, joint, plan, report, plan_time, plan_cpu)
    for name, joint_type in true_types.items():
        if name not in done:
            yield _not_planned(case, name, joint_type, "; ".join(e for e, _ in errors) or why, clock, cpu, _all_refused(errors))


def _all_refused(errors: Sequence[tuple[str, bool]]) -> bool:
    """A true part none of whose twin parts was planned counts as refused when the robot refused every one of them
    (out of its reach band, a handle its gripper cannot take, measured on the twin), as on ground truth; any other
    error (a twin unfit to plan in, a failed optimisation) makes it a failure."""
    return bool(errors) and all(refused for _, refused in errors)


def summarize(rows: Sequence[BenchRow]) -> dict[str, Any]:
    """Success rate, plan times, handle forces and collisions over bench rows, overall and per family."""
    out = _summary(rows)
    out["families"] = {family: _summary([r for r in rows if r.family == family]) for family in sorted({r.family for r in rows})}
    out["rows"] = [asdict(r) for r in rows]
    return out


def _summary(rows: Sequence[BenchRow]) -> dict[str, Any]:
    planned = [r for r in rows if r.planned]
    forces = np.array([r.peak_handle_force for r in planned]) if planned else np.zeros(0)
    cpu = np.array([r.plan_cpu_time for r in rows])
    accepted = sum(not r.refused for r in rows)
    passed = sum(r.passed for r in rows)
    return {
        "parts": len(rows),
        "refused": len(rows) - accepted,
        "accepted": accepted,
        "planned": len(planned),
        "passed": passed,
        "success_rate": passed / max(len(rows), 1),
        "success_rate_accepted": passed / max(accepted, 1),
        "median_plan_time_s": float(np.median([r.plan_time for r in rows])) if rows else float("nan"),
        "median_plan_cpu_time_s": float(np.median(cpu)) if rows else float("nan"),
        "p95_plan_cpu_time_s": float(np.percentile(cpu, 95)) if rows else float("nan"),
        "median_plan_time_passed_s": float(np.median([r.plan_time for r in rows if r.passed])) if any(r.passed for r in rows) else float("nan"),
        "median_peak_handle_force_N": float(np.median(forces)) if len(forces) else float("nan"),
        "max_peak_handle_force_N": float(np.max(forces)) if len(forces) else float("nan"),
        "plans_with_collisions": sum(r.collisions > 0 for r in planned),
    }


__all__ = ["BenchRow", "bench_suite", "summarize"]
