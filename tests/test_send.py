"""send, serve-sim and the funrec-robot/1 protocol, driven over localhost; the ROS 2 adapter's pure conversion."""

from __future__ import annotations

import json
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from funrec.errors import FunrecError, PlanningError
from funrec_robot import default_robot_path, load_robot
from funrec_robot.check_record import require_passing_record, write_signed_record
from funrec_robot.driver import TcpDriver, send_plan
from funrec_robot.keys import TrustError
from funrec_robot.plan_file import Plan, Segment, read_plan, sha256_file, write_plan
from funrec_robot.protocol import ProtocolError, parse_address, validate_plan
from funrec_robot.ros2_driver import gripper_switches, trajectory_points
from funrec_robot.sim_server import SimServerConfig, make_sim_server

DT = 0.01
"""Sample period of the fixture plans, s (the planner's)."""


@pytest.fixture(scope="module")
def robot():
    return load_robot(default_robot_path())


def _plan(robot, duration: float = 1.0, swing: float = 0.2, speed_scale: float = 1.0) -> Plan:
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


def _attested(path: Path, passed: bool = True, **settings) -> dict:
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


def _checked(path: Path, plan: Plan, passed: bool = True, key=None, **settings) -> Path:
    """plan.json with a signed check record of its bytes (this user's key unless ``key``)."""
    write_plan(path, plan)
    write_signed_record(_attested(path, passed, **settings), path.with_suffix(".check.json"), key)
    return path


def _record(path: Path) -> dict:
    return json.loads(path.with_suffix(".check.json").read_text())


@pytest.fixture()
def endpoint(robot):
    server = make_sim_server(robot, None, SimServerConfig(port=0, heartbeat_timeout=0.5))
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    host, port = server.server_address[:2]
    yield server, f"{host}:{port}"
    server.shutdown()
    thread.join(5.0)
    server.server_close()


def test_send_refuses_unchecked_changed_and_failed_plans(robot, tmp_path) -> None:
    path = tmp_path / "plan.json"
    write_plan(path, _plan(robot))
    with pytest.raises(PlanningError, match=r"plan\.json: no check record .*plan\.check\.json; run `funrec-robot check"):
        send_plan(path, "127.0.0.1:1")
    _checked(path, _plan(robot))
    write_plan(path, _plan(robot, swing=0.3))  # changed after its check
    with pytest.raises(TrustError, match=r"check record .* is of another plan .*edited after its check"):
        require_passing_record(path)
    _checked(path, _plan(robot), passed=False)
    with pytest.raises(TrustError, match=r"the check failed \(target\)"):
        send_plan(path, "127.0.0.1:1")


def test_serve_sim_runs_a_plan_in_real_time_and_streams_state(robot, endpoint, tmp_path) -> None:
    server, address = endpoint
    path = _checked(tmp_path / "plan.json", _plan(robot))
    states: list[dict] = []
    driver = TcpDriver(address, on_state=states.append)
    driver.subscribe(50.0)
    result = send_plan(path, address, heartbeat_period=0.05, driver=driver)
    driver.close()
    assert result.event == "done", result.detail
    # real time: a 1 s plan takes at least 1 s of wall clock, and not much more on an idle-ish 2-core machine
    assert 0.95 <= result.wall_time <= 3.0
    assert any(s["status"] == "running" for s in states)
    plan = read_plan(path)
    q_end = np.asarray(server.sim.state()["q"])
    # servo tracking of a 0.2 rad swing that ends at rest: within 0.01 rad of the last sample
    np.testing.assert_allclose(q_end, plan.q[-1], atol=0.01)


def test_serve_sim_validates_against_its_own_limits_and_stops_without_heartbeat(robot, endpoint, tmp_path) -> None:
    _, address = endpoint
    fast = _plan(robot, duration=0.2, swing=1.5)  # 1.5 rad in 0.2 s: far beyond any arm joint's speed limit
    assert validate_plan(fast, robot)
    path = _checked(tmp_path / "fast.json", fast)
    driver = TcpDriver(address)
    driver.hello()
    with pytest.raises(ProtocolError, match=r"upload: refused: arm_joint1: speed .* > limit"):
        driver.upload(path.read_text(), _record(path))
    with pytest.raises(ProtocolError, match="refused: .*not a signed check record"):
        driver.upload(path.read_text(), {"format": "funrec-check/1", "plan_sha256": sha256_file(path), "passed": True})
    slow = _checked(tmp_path / "slow.json", _plan(robot, duration=3.0))
    plan_id = driver.upload(slow.read_text(), _record(slow))
    driver.start(plan_id)
    started = time.monotonic()
    # no heartbeats sent: the 0.5 s watchdog must fire well before the 3 s plan ends (the fixture's timeout is
    # not tighter: a busy machine may starve a well-behaved sender for 0.3 s)
    event = driver.wait_event(2.0)
    assert event is not None and event["event"] == "fault" and "no heartbeat" in event["detail"]
    assert time.monotonic() - started < 1.5
    assert driver.request("status")["status"] == "fault"
    with pytest.raises(ProtocolError, match="unknown op 'fly'"):
        driver.request("fly")
    driver.close()


def test_ros2_conversion_keeps_the_last_sample_and_gripper_switches(robot) -> None:
    plan = _plan(robot)
    t, q, qd = trajectory_points(plan, [3, 4], 7)
    assert t[0] == 0.0 and t[-1] == plan.t[-1] and np.all(np.diff(t) > 0)
    np.testing.assert_array_equal(q[-1], plan.q[-1, [3, 4]])
    assert q.shape == qd.shape == (len(t), 2)
    switches = gripper_switches(plan)
    assert [c for _, c in switches] == [robot.gripper.open, robot.gripper.closed]
    assert abs(switches[1][0] - 0.49) < DT + 1e-9  # the command changes at the first sample past half the plan


def test_addresses_parse_and_ros2_needs_rclpy() -> None:
    assert parse_address("tcp://10.0.0.2:5000") == ("10.0.0.2", 5000)
    assert parse_address("localhost") == ("localhost", 47300)
    with pytest.raises(ProtocolError, match="expected host:port"):
        parse_address("host:abc")
    try:
        import rclpy  # noqa: F401
    except ImportError:
        from funrec_robot.driver import open_driver

        with pytest.raises(FunrecError, match="ros2:// addresses need rclpy"):
            open_driver("ros2://robot")


def test_cli_send_exits_2_and_says_why_without_a_check(robot, tmp_path, capsys) -> None:
    from funrec_robot.cli import main

    path = tmp_path / "plan.json"
    write_plan(path, _plan(robot))
    assert main(["send", str(path), "--to", "127.0.0.1:1"]) == 2
    assert "no check record" in capsys.readouterr().err
