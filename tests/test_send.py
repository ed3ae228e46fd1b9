"""send, serve-sim and the funrec-robot/1 protocol, driven over localhost; the ROS 2 adapter's pure conversion."""

from __future__ import annotations

import time

import numpy as np
import pytest

from funrec.errors import FunrecError, PlanningError
from funrec_robot.check_record import require_passing_record
from funrec_robot.driver import TcpDriver, send_plan
from funrec_robot.keys import TrustError
from funrec_robot.plan_file import read_plan, sha256_file, write_plan
from funrec_robot.protocol import ProtocolError, parse_address, validate_plan
from funrec_robot.ros2_driver import gripper_switches, trajectory_points
from tests.helpers.robot_plans import DT, checked_plan, read_check_record, swing_plan


def test_send_refuses_unchecked_changed_and_failed_plans(robot, tmp_path) -> None:
    path = tmp_path / "plan.json"
    write_plan(path, swing_plan(robot))
    with pytest.raises(PlanningError, match=r"plan\.json: no check record .*plan\.check\.json; run `funrec-robot check"):
        send_plan(path, "127.0.0.1:1")
    checked_plan(path, swing_plan(robot))
    write_plan(path, swing_plan(robot, swing=0.3))  # changed after its check
    with pytest.raises(TrustError, match=r"check record .* is of another plan .*edited after its check"):
        require_passing_record(path)
    checked_plan(path, swing_plan(robot), passed=False)
    with pytest.raises(TrustError, match=r"the check failed \(target\)"):
        send_plan(path, "127.0.0.1:1")


def test_serve_sim_runs_a_plan_in_real_time_and_streams_state(robot, endpoint, tmp_path) -> None:
    server, address = endpoint
    path = checked_plan(tmp_path / "plan.json", swing_plan(robot))
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
    fast = swing_plan(robot, duration=0.2, swing=1.5)  # 1.5 rad in 0.2 s: far beyond any arm joint's speed limit
    assert validate_plan(fast, robot)
    path = checked_plan(tmp_path / "fast.json", fast)
    driver = TcpDriver(address)
    driver.hello()
    with pytest.raises(ProtocolError, match=r"upload: refused: arm_joint1: speed .* > limit"):
        driver.upload(path.read_text(), read_check_record(path))
    with pytest.raises(ProtocolError, match="refused: .*not a signed check record"):
        driver.upload(path.read_text(), {"format": "funrec-check/1", "plan_sha256": sha256_file(path), "passed": True})
    slow = checked_plan(tmp_path / "slow.json", swing_plan(robot, duration=3.0))
    plan_id = driver.upload(slow.read_text(), read_check_record(slow))
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
    plan = swing_plan(robot)
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
    write_plan(path, swing_plan(robot))
    assert main(["send", str(path), "--to", "127.0.0.1:1"]) == 2
    assert "no check record" in capsys.readouterr().err
