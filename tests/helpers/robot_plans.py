"""Hand-made robot plans with signed check records: the builders of the sending, trust and
endpoint-load tests (which test sending, not planning or checking). The ``robot`` and ``endpoint``
fixtures they use are in tests/conftest.py.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from funrec_robot import default_robot_path
from funrec_robot.check_record import write_signed_record
from funrec_robot.plan_file import Plan, Segment, sha256_file, write_plan

DT = 0.01
"""Sample period of the fixture plans, s (the planner's)."""


def swing_plan(robot, duration: float = 1.0, swing: float = 0.2, speed_scale: float = 1.0) -> Plan:
    """A hand-made plan (test fixture, not planner output): the first arm joint swings by ``swing`` rad from
    home along a smooth cosine; the gripper closes halfway."""
    t = np.arange(int(round(duration / DT)) + 1) * DT
    s = 0.5 - 0.5 * np.cos(np.pi * t / duration)
    sd = 0.5 * np.pi / duration * np.sin(np.pi * t / duration) * speed_scale
    j = len(robot.base_joints)
    q = np.tile(robot.q_home, (len(t), 1))
    qd = np.zeros_like(q)
    q[:, j] += swing * s
    qd[:, j] = swing * sd
    gripper = np.where(t < duration / 2, robot.gripper.open, robot.gripper.closed)
    n = len(t) - 1
    segments = (Segment("approach", 0, n // 2, 0.0, float(t[n // 2])), Segment("grasp", n // 2, n, float(t[n // 2]), float(t[-1])))
    return Plan(robot.name, robot.joint_names, (), robot.gripper.open, robot.gripper.closed, robot.gripper.closed, t, q, qd,
                gripper, np.zeros(len(t)), segments, "part_0", "revolute", np.array([0.0, 0.0, 1.0]), np.zeros(3), (0.0, 1.0),
                0.0, 0.5, np.eye(4), np.zeros(3), 0, np.zeros((1, 3)), {"robot_file": str(robot.yaml_path)})


def attested(path: Path, passed: bool = True, **settings) -> dict:
    """What a passing `funrec-robot check` attests of the plan at ``path`` (a fixture: these tests are of
    sending, not checking), with check settings overridden by ``settings``."""
    from funrec_robot.check import CRITERIA, CheckConfig
    from funrec_robot.check_record import _settings

    return {
        "plan_sha256": sha256_file(path),
        "plan_file": str(path),
        "robot": {"file": str(default_robot_path()), "sha256": sha256_file(default_robot_path())},
        "scene": {"file": "scene.xml", "folder_sha256": "0" * 64},
        "joint": "part_0",
        "passed": passed,
        "criteria": [{"name": c, "threshold": 1.0, "unit": "", "measured": 0.0, "passed": passed or c != "target"} for c in CRITERIA],
        "settings": {**_settings(CheckConfig()), **settings},
        "funrec_version": "test",
        "checked_at": "2026-11-26T00:00:00+00:00",
    }


def checked_plan(path: Path, plan: Plan, passed: bool = True, key=None, **settings) -> Path:
    """plan.json with a signed check record of its bytes (this user's key unless ``key``)."""
    write_plan(path, plan)
    write_signed_record(attested(path, passed, **settings), path.with_suffix(".check.json"), key)
    return path


def read_check_record(path: Path) -> dict:
    return json.loads(path.with_suffix(".check.json").read_text())
