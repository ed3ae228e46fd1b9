"""Plan and check every articulated part of a folder of synthetic captures (their ground-truth scenes)."""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from funrec.errors import FunrecError
from funrec.ground_truth import read_ground_truth
from funrec_robot.check import CheckConfig, check_plan
from funrec_robot.plan import PlanConfig, plan_interaction
from funrec_robot.plan_file import write_plan
from funrec_robot.retime import retime_path
from funrec_robot.robot import load_robot
from funrec_robot.sim_model import build_mujoco_model
from funrec_robot.task_sources import task_from_ground_truth


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


def bench_suite(
    suite: str | Path,
    robot_path: str | Path,
    target: str = "open",
    only: Sequence[str] = (),
    plan_config: PlanConfig | None = None,
    check_config: CheckConfig | None = None,
    plans_dir: str | Path | None = None,
    progress: Callable[[BenchRow], None] | None = None,
) -> tuple[BenchRow, ...]:
    """Plan and check each part of each capture under ``suite`` that has ground truth.

    Args:
        suite: folder of capture folders (each with gt/gt.json and gt/scene.xml).
        robot_path: robot YAML file.
        target: target of every plan ('open', 'close' or a state).
        only: capture names to restrict to (empty: all).
        plans_dir: write each plan as ``<case>_<part>.json`` here.
        progress: called with each row as it is done.
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
        for gt_part in gt.parts:
            name = gt_part.part.name
            clock, cpu = time.perf_counter(), time.process_time()
            try:
                model = build_mujoco_model(robot, gt.scene_xml)
                task = task_from_ground_truth(gt.root, name, model)
                plan = plan_interaction(robot, gt.scene_xml, task, target, config=plan_config, model=model)
            except FunrecError as exc:
                row = BenchRow(case, name, gt_part.part.joint_type, False, False, str(exc), time.perf_counter() - clock,
                               time.process_time() - cpu, np.nan, 0, np.nan, 0, 0.0)
            else:
                plan_time, plan_cpu = time.perf_counter() - clock, time.process_time() - cpu
                if plans_dir is not None:
                    write_plan(Path(plans_dir) / f"{case}_{name}.json", plan)
                report = check_plan(plan, robot, gt.scene_xml, config=check_config)
                failure = "; ".join(f"{f.criterion} at {f.time:.2f} s: {f.detail}" for f in report.failures)
                row = BenchRow(case, name, plan.joint_type, True, report.passed, failure, plan_time, plan_cpu,
                               report.peak_handle_force, len(report.collisions), report.target_error,
                               len(plan.base_poses), plan.duration)
            rows.append(row)
            if progress is not None:
                progress(row)
    return tuple(rows)


def summarize(rows: Sequence[BenchRow]) -> dict[str, Any]:
    """Success rate, median plan time, handle forces and collisions over bench rows."""
    planned = [r for r in rows if r.planned]
    forces = np.array([r.peak_handle_force for r in planned]) if planned else np.zeros(0)
    return {
        "parts": len(rows),
        "planned": len(planned),
        "passed": sum(r.passed for r in rows),
        "success_rate": sum(r.passed for r in rows) / max(len(rows), 1),
        "median_plan_time_s": float(np.median([r.plan_time for r in rows])) if rows else float("nan"),
        "median_plan_cpu_time_s": float(np.median([r.plan_cpu_time for r in rows])) if rows else float("nan"),
        "median_plan_time_passed_s": float(np.median([r.plan_time for r in rows if r.passed])) if any(r.passed for r in rows) else float("nan"),
        "median_peak_handle_force_N": float(np.median(forces)) if len(forces) else float("nan"),
        "max_peak_handle_force_N": float(np.max(forces)) if len(forces) else float("nan"),
        "plans_with_collisions": sum(r.collisions > 0 for r in planned),
        "rows": [asdict(r) for r in rows],
    }


__all__ = ["BenchRow", "bench_suite", "summarize"]
