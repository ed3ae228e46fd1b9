"""A :class:`funrec_robot.driver.RobotDriver` for ROS 2 robots: control_msgs FollowJointTrajectory actions
(ros2_control's joint_trajectory_controller) for the arm and, if the robot has one, a trajectory-following
base controller, and a GripperCommand action for the gripper.

Used by ``funrec-robot send plan.json --to ros2://NAMESPACE`` when rclpy is importable (source a ROS 2
installation, e.g. ``source /opt/ros/jazzy/setup.bash``, in the shell that runs funrec-robot; rclpy is not
on PyPI). Action names and joint renaming come from :class:`Ros2Config`. The pure conversion
(:func:`trajectory_points`) is tested without ROS; the action plumbing is not tested here.
"""

from __future__ import annotations

import hashlib
import json
import queue
import threading
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from funrec.typed import FloatArray
from funrec_robot.check_record import CheckPolicy, verify_check_record
from funrec_robot.keys import TrustError, trusted_keys
from funrec_robot.plan_file import Plan, plan_from_json, release_offset
from funrec_robot.protocol import ProtocolError


@dataclass(frozen=True)
class Ros2Config:
    """Where the robot's ROS 2 controllers are (relative names get the address's namespace)."""

    arm_action: str = "arm_controller/follow_joint_trajectory"
    """FollowJointTrajectory action of the arm joints."""
    base_action: str | None = "base_controller/follow_joint_trajectory"
    """FollowJointTrajectory action of the planar base joints (x, y, yaw in the plan's world frame, which
    the robot's controller must share, e.g. its odometry frame after localisation); None: no base motion
    allowed (the plan's base columns must stay constant)."""
    gripper_action: str | None = "gripper_controller/gripper_cmd"
    """control_msgs GripperCommand action; None to leave the gripper alone."""
    joint_names: dict[str, str] = field(default_factory=dict)
    """Plan joint name -> the robot's joint name, where they differ."""
    max_effort: float = 60.0
    """GripperCommand max_effort, N."""
    point_stride: int = 5
    """Send every this many plan samples (100 Hz plans -> 20 Hz points; the controller interpolates)."""
    policy: CheckPolicy = field(default_factory=CheckPolicy)
    """The loosest check whose records this adapter accepts."""


def trajectory_points(plan: Plan, columns: list[int], stride: int) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Times (P,), positions and velocities (P, len(columns)) of a plan's samples every ``stride``, always
    including the last one (JointTrajectoryPoint time_from_start, positions, velocities)."""
    keep = np.unique(np.r_[np.arange(0, len(plan.t), max(1, stride)), len(plan.t) - 1])
    return plan.t[keep], plan.q[np.ix_(keep, columns)], plan.qd[np.ix_(keep, columns)]


def gripper_switches(plan: Plan) -> list[tuple[float, float]]:
    """(time s, command): the first command, then at the start of each change of the plan's gripper command
    the value it changes to (a GripperCommand goal moves the fingers there itself)."""
    command = plan.gripper_command
    moving = np.abs(np.diff(command)) > 1e-9
    out = [(float(plan.t[0]), float(command[0]))]
    k = 0
    while k < len(moving):
        if not moving[k]:
            k += 1
            continue
        end = k
        while end + 1 < len(moving) and moving[end + 1]:
            end += 1
        out.append((float(plan.t[k]), float(command[end + 1])))
        k = end + 1
    return out


class Ros2Driver:
    """FollowJointTrajectory driver (see the module docstring). Raises ProtocolError without rclpy."""

    def __init__(self, namespace: str, timeout: float = 10.0, config: Ros2Config = Ros2Config()) -> None:
        try:
            import rclpy
            from rclpy.action import ActionClient
            from rclpy.executors import MultiThreadedExecutor
        except ImportError:
            raise ProtocolError(
                "ros2:// addresses need rclpy: source a ROS 2 installation (e.g. /opt/ros/jazzy/setup.bash) with "
                "control_msgs in the shell that runs funrec-robot"
            ) from None
        from control_msgs.action import FollowJointTrajectory, GripperCommand

        self.config, self.timeout, self.namespace = config, timeout, namespace.strip("/")
        self._msgs = (FollowJointTrajectory, GripperCommand)
        if not rclpy.ok():
            rclpy.init()
        self._node = rclpy.create_node("funrec_robot_send", namespace=self.namespace or None)
        self._executor = MultiThreadedExecutor()
        self._executor.add_node(self._node)
        threading.Thread(target=self._executor.spin, daemon=True).start()
        self._arm = ActionClient(self._node, FollowJointTrajectory, config.arm_action)
        self._base = None if config.base_action is None else ActionClient(self._node, FollowJointTrajectory, config.base_action)
        self._gripper = None if config.gripper_action is None else ActionClient(self._node, GripperCommand, config.gripper_action)
        self._plans: dict[str, Plan] = {}
        self._goals: list[Any] = []
        self._events: queue.Queue = queue.Queue()

    def hello(self) -> dict[str, Any]:
        for client in (self._arm, self._base, self._gripper):
            if client is not None and not client.wait_for_server(timeout_sec=self.timeout):
                raise ProtocolError(f"ros2://{self.namespace}: action server {client._action_name} not available")
        return {"robot": f"ros2://{self.namespace}", "joint_names": []}

    def upload(self, plan_text: str, check_record: dict[str, Any]) -> str:
        plan_id = hashlib.sha256(plan_text.encode()).hexdigest()
        try:  # the robot side's own verification: signed by a trusted key, passing, of these bytes, not loosened
            verify_check_record(check_record, plan_id, trusted_keys(), self.config.policy)
        except TrustError as exc:
            raise ProtocolError(f"refused: {exc}") from None
        plan = plan_from_json(json.loads(plan_text), "<plan>")
        self._plans[plan_id] = plan
        return plan_id

    def _trajectory_goal(self, plan: Plan, columns: list[int]) -> Any:
        from builtin_interfaces.msg import Duration
        from trajectory_msgs.msg import JointTrajectoryPoint

        goal = self._msgs[0].Goal()
        goal.trajectory.joint_names = [self.config.joint_names.get(plan.joint_names[j], plan.joint_names[j]) for j in columns]
        for t, q, qd in zip(*trajectory_points(plan, columns, self.config.point_stride)):
            point = JointTrajectoryPoint(positions=q.tolist(), velocities=qd.tolist())
            point.time_from_start = Duration(sec=int(t), nanosec=int(round((t - int(t)) * 1e9)))
            goal.trajectory.points.append(point)
        return goal

    def start(self, plan_id: str) -> None:
        plan = self._plans.get(plan_id)
        if plan is None:
            raise ProtocolError(f"no uploaded plan {plan_id[:12]}...")
        n_base = sum(1 for name in plan.joint_names if name.startswith("base"))
        base, arm = list(range(n_base)), list(range(n_base, len(plan.joint_names)))
        if base and self._base is None and np.ptp(plan.q[:, base], axis=0).max() > 1e-6:
            raise ProtocolError("the plan moves the base but Ros2Config.base_action is None")
        pending = [(self._arm, self._trajectory_goal(plan, arm))]
        if base and self._base is not None:
            pending.append((self._base, self._trajectory_goal(plan, base)))
        remaining = [len(pending)]

        def finished(future: Any) -> None:
            status = future.result().status
            remaining[0] -= 1
            if status != 4:  # action_msgs GoalStatus.STATUS_SUCCEEDED
                self._events.put({"event": "fault", "detail": f"trajectory goal ended with status {status}"})
            elif remaining[0] == 0:
                self._events.put({"event": "done", "detail": "all trajectory goals succeeded"})

        for client, goal in pending:
            client.send_goal_async(goal).add_done_callback(lambda f: self._accepted(f, finished))
        if self._gripper is not None:
            stopped_at = [plan.grasp_command]  # where the last gripper goal left the fingers (its result)
            for t, command in gripper_switches(plan):
                relative = t >= plan.release_start
                threading.Timer(t, self._send_gripper, args=(plan, command, relative, stopped_at)).start()

    def _send_gripper(self, plan: Plan, command: float, relative: bool, stopped_at: list[float]) -> None:
        """Send one GripperCommand goal; a release is offset by where the fingers stopped on the handle
        (``release_offset``), read from the previous goal's result."""
        goal = self._msgs[1].Goal()
        goal.command.position = command + (release_offset(plan, stopped_at[0]) if relative else 0.0)
        goal.command.max_effort = self.config.max_effort

        def record(result_future: Any) -> None:
            stopped_at[0] = float(result_future.result().result.position)

        future = self._gripper.send_goal_async(goal)
        future.add_done_callback(lambda f: f.result().get_result_async().add_done_callback(record))

    def _accepted(self, future: Any, finished: Any) -> None:
        handle = future.result()
        if not handle.accepted:
            self._events.put({"event": "fault", "detail": "a trajectory goal was rejected by its controller"})
            return
        self._goals.append(handle)
        handle.get_result_async().add_done_callback(finished)

    def stop(self) -> None:
        for handle in self._goals:
            handle.cancel_goal_async()
        self._events.put({"event": "stopped", "detail": "goals cancelled"})

    def heartbeat(self) -> None:
        """FollowJointTrajectory has no heartbeat: the controllers' own tolerances and timeouts guard execution."""

    def wait_event(self, timeout: float) -> dict[str, Any] | None:
        try:
            return self._events.get(timeout=timeout)
        except queue.Empty:
            return None

    def close(self) -> None:
        self._executor.shutdown()
        self._node.destroy_node()


__all__ = ["Ros2Config", "Ros2Driver", "gripper_switches", "trajectory_points"]
