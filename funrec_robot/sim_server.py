"""``funrec-robot serve-sim``: a reference robot endpoint that speaks ``funrec-robot/2`` (see
:mod:`funrec_robot.endpoint`) and executes plans in MuJoCo in real time.

It behaves like a robot controller: it accepts an uploaded plan only with a signed, trusted, passing check
record of its exact bytes and validates it against its own robot file's limits; it runs it on the robot's
servos only after ``start`` by the client holding the lease, if the plan starts where the robot is; it
streams the measured state; it stops and holds on ``stop``, on an E-Stop, when the lease holder's heartbeats
cease, when a command would leave its range, when the simulation goes non-finite or resets, and when the
execution overruns the plan's duration. One plan runs at a time.
"""

from __future__ import annotations

import bisect
import hashlib
import json
import logging
import math
import threading
import time
from collections import OrderedDict
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import mujoco
import numpy as np

from funrec.errors import FunrecError
from funrec_robot.check_record import CheckPolicy, verify_check_record
from funrec_robot.keys import TrustError, trusted_keys
from funrec_robot.plan_file import Plan, plan_from_json, release_offset, sha256_file
from funrec_robot.protocol import LimitMargins, ProtocolError, validate_plan
from funrec_robot.robot import RobotDescription
from funrec_robot.sim_model import apply_couplings, build_mujoco_model, gripper_position, reset_to_home, robot_indices

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class SimServerConfig:
    """Settings of the simulated robot endpoint; every number must be finite and positive."""

    host: str = "127.0.0.1"
    """Address to listen on."""
    port: int = 47300
    """TCP port; 0 picks a free one."""
    heartbeat_timeout: float = 1.0
    """A running plan stops, and the lease lapses, when its holder sends nothing for this long, s (at most 60)."""
    real_time_factor: float = 1.0
    """Simulated seconds per wall-clock second (1: real time; at most 10)."""
    require_check: bool = True
    """Refuse plans without a signed, trusted, passing check record of their exact bytes."""
    margins: LimitMargins = field(default_factory=LimitMargins)
    """Tolerances of the plan validation."""
    start_tolerance: float = 0.05
    """Largest gap between the plan's first sample and the robot's state at ``start``, rad or m."""
    end_tolerance: float = 0.1
    """Largest gap between the plan's last sample and the robot's state when it ends, rad or m (else a fault)."""
    spawn_at_first_plan: bool = True
    """A fresh simulation (or one after ``reset``) puts the robot at its first plan's first sample, as a real
    robot's own navigation would bring it there; every later plan must start within ``start_tolerance``."""
    duration_margin: float = 2.0
    """An execution still running this long after the plan's duration (wall clock, times the real-time factor)
    is a fault, s."""
    auth: bool = True
    """TLS with token or client-certificate authentication (False: plain TCP, anyone local may move the robot)."""
    unauthenticated_beyond_loopback: bool = False
    """With auth False, allow a non-loopback host: anyone who reaches the port can move the robot."""
    client_ca: str = ""
    """PEM of a CA whose client certificates authenticate (empty: tokens only)."""
    max_connections: int = 16
    """Connections served at once; more are told so and closed."""
    idle_timeout: float = 60.0
    """An authenticated connection that sends nothing for this long is closed, s (10 s before authenticating)."""
    max_plans: int = 4
    """Uploaded plans kept; the oldest not running is evicted."""
    max_send_buffer: int = 1 << 20
    """A client with more than this many bytes waiting to be sent to it is dropped (it does not read), bytes."""
    max_message_rate: float = 200.0
    """Messages a second read from one connection (a tenth of it before authenticating); more wait their turn."""

    def __post_init__(self) -> None:
        bounded = {"heartbeat_timeout": 60.0, "real_time_factor": 10.0, "start_tolerance": 10.0, "end_tolerance": 10.0,
                   "duration_margin": 3600.0, "idle_timeout": 86400.0, "max_message_rate": 1e6}
        for name, largest in bounded.items():
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or not 0.0 < value <= largest:
                raise FunrecError(f"{name.replace('_', '-')} {value!r}: expected a finite number in (0, {largest:g}]")
        for name in ("max_connections", "max_plans", "max_send_buffer"):
            if int(getattr(self, name)) < 1:
                raise FunrecError(f"{name.replace('_', '-')} {getattr(self, name)!r}: expected at least 1")
        if not 0 <= int(self.port) <= 65535:
            raise FunrecError(f"port {self.port}: expected 0-65535")


class SimRobot:
    """The simulated robot: a MuJoCo model stepped in real time by a thread while a plan runs.

    Thread safety: every method takes ``lock``; ``notify`` (set by the endpoint) is called with it held and
    must not block.
    """

    def __init__(self, robot: RobotDescription, scene_xml: str | Path | None, config: SimServerConfig) -> None:
        self.robot, self.config = robot, config
        self.model = build_mujoco_model(robot, scene_xml)
        self.data = mujoco.MjData(self.model)
        self.indices = robot_indices(robot, self.model)
        reset_to_home(robot, self.model, self.data)
        self.robot_sha256 = sha256_file(robot.yaml_path)
        self.trusted: dict[str, str] | None = None
        """Trusted signing keys; None: read trusted_keys.txt at every upload (so `keys --trust` needs no restart)."""
        self.policy = CheckPolicy()
        self.lock = threading.RLock()
        self.status, self.detail = "idle", ""
        self.placed = False
        self.plans: OrderedDict[str, Plan] = OrderedDict()
        self.plan: Plan | None = None
        self.plan_id = ""
        self.plan_time = 0.0
        self.last_heartbeat = time.monotonic()
        self.last_halt: dict[str, Any] | None = None
        """The last stop of a running plan: its status, detail and ``latency_s``, from its cause (the request read,
        the heartbeat deadline, the hang-up seen) to the hold command (None where the cause has no time)."""
        self.notify: Callable[[dict[str, Any]], None] = lambda message: None
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._last_state: dict[str, Any] = {}
        self._times: list[float] = []
        self._release_start = math.inf
        low, high = sorted((robot.gripper.open, robot.gripper.closed))
        self._gripper_range = (low - 1e-6, high + 1e-6)
        self.state()

    def upload(self, message: dict[str, Any]) -> dict[str, Any]:
        """Verify, validate and store a plan (see the module docstring)."""
        text = message.get("plan_text")
        if not isinstance(text, str):
            raise ProtocolError("upload needs 'plan_text': the plan.json file's text")
        plan_id = hashlib.sha256(text.encode("utf-8", "surrogatepass")).hexdigest()
        if self.config.require_check:
            try:
                trusted = trusted_keys() if self.trusted is None else self.trusted
                verify_check_record(message.get("check"), plan_id, trusted, self.policy, self.robot_sha256)
            except TrustError as exc:
                raise ProtocolError(f"refused: {exc}") from None
        try:
            data = json.loads(text, parse_constant=_no_constant)
        except (ValueError, RecursionError) as exc:
            raise ProtocolError(f"refused: plan_text is not JSON: {str(exc)[:200]}") from None
        try:
            plan = plan_from_json(data, "<uploaded plan>")
        except (TypeError, ValueError, AttributeError) as exc:
            raise ProtocolError(f"refused: malformed plan: {str(exc)[:200]}") from None
        problems = validate_plan(plan, self.robot, self.config.margins)
        if problems:
            raise ProtocolError("refused: " + "; ".join(problems[:5]))
        with self.lock:
            self.plans[plan_id] = plan
            self.plans.move_to_end(plan_id)
            while len(self.plans) > self.config.max_plans:
                oldest = next(k for k in self.plans if k != self.plan_id or self.status != "running")
                del self.plans[oldest]
            if self.status in ("idle", "done", "stopped"):
                self.status = "ready"
        return {"plan_id": plan_id, "duration": plan.duration, "samples": len(plan.t)}

    def start(self, plan_id: str) -> dict[str, Any]:
        with self.lock:
            if self.status == "running":
                raise ProtocolError("a plan is already running; stop it first")
            plan = self.plans.get(plan_id)
            if plan is None:
                raise ProtocolError(f"no uploaded plan {plan_id[:12]}...; upload it first")
            q = self.data.qpos[self.indices.qpos]
            if self.placed or not self.config.spawn_at_first_plan:
                gap = np.abs(q - plan.q[0])
                j = int(np.argmax(gap))
                if gap[j] > self.config.start_tolerance:
                    raise ProtocolError(
                        f"refused: the plan starts {gap[j]:.3f} from the robot's state at joint {self.robot.joint_names[j]} "
                        f"(plan {plan.q[0, j]:.3f}, robot {q[j]:.3f}; tolerance {self.config.start_tolerance}); "
                        "bring the robot to the plan's start first"
                    )
            else:  # a fresh simulation: spawn the robot where its first plan starts
                self.data.qpos[self.indices.qpos] = plan.q[0]
                apply_couplings(self.indices, self.data.qpos)
                self.data.qvel[:] = 0.0
                mujoco.mj_forward(self.model, self.data)
            self.placed = True
            self.plan, self.plan_id, self.plan_time, self.status, self.detail = plan, plan_id, 0.0, "running", ""
            self.last_heartbeat = time.monotonic()
            self._stop.clear()
            self._thread = threading.Thread(target=self._run, name="funrec-sim", daemon=True)
            self._thread.start()
        return {"status": "running"}

    def heartbeat(self) -> None:
        self.last_heartbeat = time.monotonic()  # one attribute store: no lock, the network loop never waits

    def stop(self, detail: str = "stop requested", status: str = "stopped", cause_time: float | None = None) -> dict[str, Any]:
        """Hold a running plan's current position; ``cause_time`` (monotonic) is when the stop was called for."""
        with self.lock:
            if self.status == "running":
                self._halt(status, detail, cause_time)
        return {"status": self.status}

    def estop(self, who: str, cause_time: float | None = None) -> dict[str, Any]:
        """Stop and hold whatever runs; the status becomes ``fault`` (an E-Stop is never a normal end)."""
        with self.lock:
            if self.status == "running":
                self._halt("fault", f"E-Stop by {who}: stopped and holding", cause_time)
            else:
                self.status, self.detail = "fault", f"E-Stop by {who}"
        return {"status": self.status}

    def reset(self) -> dict[str, Any]:
        """Simulation only: the robot back home and unplaced (the next plan spawns it)."""
        with self.lock:
            if self.status == "running":
                raise ProtocolError("reset while running; stop first")
            reset_to_home(self.robot, self.model, self.data)
            self.placed, self.status, self.detail, self.plan_time = False, "ready" if self.plans else "idle", "", 0.0
        return {"status": self.status}

    def _halt(self, status: str, detail: str, cause_time: float | None = None) -> None:
        """Hold the current position (caller holds the lock)."""
        q = self.data.qpos[self.indices.qpos]
        if np.all(np.isfinite(q)):
            self.data.ctrl[self.indices.actuators] = q
        latency = None if cause_time is None else round(max(time.monotonic() - cause_time, 0.0), 4)
        self.last_halt = {"status": status, "detail": detail, "latency_s": latency}
        self.status, self.detail = status, detail
        self._stop.set()
        self.notify({"type": "event", "event": status, "detail": detail, "plan_time": round(self.plan_time, 4)})

    def state(self) -> dict[str, Any]:
        """The measured state; never waits for the simulation thread (the network loop calls it): while that
        thread holds the lock, the state it last left is returned."""
        if not self.lock.acquire(blocking=False):
            return dict(self._last_state, status=self.status)
        try:
            q = self.data.qpos[self.indices.qpos]
            qd = self.data.qvel[self.indices.dof]
            gripper = self.data.ctrl[self.indices.gripper_actuators]
            self._last_state = {
                "type": "state",
                "status": self.status,
                "sim_time": _json_number(self.data.time),
                "plan_time": round(self.plan_time, 4),
                "joint_names": list(self.robot.joint_names),
                "q": [_json_number(v) for v in q],
                "qd": [_json_number(v) for v in qd],
                "gripper_command": _json_number(gripper[0]) if gripper.size else None,
            }
            return self._last_state
        finally:
            self.lock.release()

    def _step_once(self, plan: Plan, grip_offset: float | None) -> tuple[float | None, str]:
        """Command the plan at ``plan_time`` (linear interpolation between samples) and step once; returns the
        release offset and a fault ('' if none)."""
        model, data, t = self.model, self.data, self.plan_time
        k = min(max(bisect.bisect_right(self._times, t) - 1, 0), len(self._times) - 2)
        w = min(max((t - self._times[k]) / (self._times[k + 1] - self._times[k]), 0.0), 1.0)
        data.ctrl[self.indices.actuators] = plan.q[k] + w * (plan.q[k + 1] - plan.q[k])
        if grip_offset is None and t >= self._release_start:
            grip_offset = release_offset(plan, gripper_position(self.indices, data))
        g = plan.gripper_command
        command = float(g[k] + w * (g[k + 1] - g[k])) + (grip_offset or 0.0)
        if self.indices.gripper_actuators.size:
            if not self._gripper_range[0] <= command <= self._gripper_range[1]:
                return grip_offset, f"gripper command {command:.4f} at {t:.2f} s outside [{self._gripper_range[0]:.4f}, {self._gripper_range[1]:.4f}]"
            data.ctrl[self.indices.gripper_actuators] = command
        before = data.time
        mujoco.mj_step(model, data)
        if not (math.isfinite(float(data.qpos.sum())) and math.isfinite(float(data.qvel.sum()))) or data.time <= before:
            return grip_offset, f"simulation became unstable or reset at {t:.2f} s"
        self.plan_time += model.opt.timestep
        return grip_offset, ""

    def _run(self) -> None:
        """Step the model so that simulated time keeps pace with the wall clock (times the real-time factor)."""
        plan = self.plan
        assert plan is not None
        self._times, self._release_start = plan.t.tolist(), plan.release_start
        grip_offset: float | None = None
        started = time.monotonic()
        deadline = plan.duration + self.config.duration_margin
        while not self._stop.is_set():
            wall = (time.monotonic() - started) * self.config.real_time_factor
            with self.lock:
                if self.status != "running":
                    return
                deadline = self.last_heartbeat + self.config.heartbeat_timeout
                if time.monotonic() > deadline:
                    self._halt("fault", f"no heartbeat from the lease holder for {self.config.heartbeat_timeout} s: stopped and holding",
                               deadline)
                    return
                if wall > deadline:
                    self._halt("fault", f"execution overran the plan's {plan.duration:.2f} s by more than {self.config.duration_margin} s")
                    return
            while self.plan_time < wall and self.plan_time <= plan.duration:
                with self.lock:  # one step at a time: stop and state never wait for a whole catch-up
                    if self.status != "running":
                        return
                    grip_offset, fault = self._step_once(plan, grip_offset)
                    if fault:
                        self._halt("fault", fault + ": stopped and holding")
                        return
            with self.lock:
                if self.status != "running":
                    return
                if self.plan_time > plan.duration:
                    self._finish(plan)
                    return
                self.state()  # refresh the state the network loop reads while this thread steps
            time.sleep(0.002)

    def _finish(self, plan: Plan) -> None:
        gap = np.abs(self.data.qpos[self.indices.qpos] - plan.q[-1])
        j = int(np.argmax(gap))
        if gap[j] > self.config.end_tolerance:
            self._halt("fault", f"plan ended {gap[j]:.3f} from its last sample at joint {self.robot.joint_names[j]} "
                                f"(tolerance {self.config.end_tolerance}): stopped and holding")
            return
        self.status, self.detail = "done", f"plan finished after {plan.duration:.2f} s"
        self.notify({"type": "event", "event": "done", "detail": self.detail, "plan_time": round(self.plan_time, 4)})


def _json_number(value: float) -> float | None:
    value = float(value)
    return round(value, 6) if math.isfinite(value) else None


def _no_constant(name: str) -> Any:
    raise ValueError(f"{name} is not JSON")


def make_sim_server(robot: RobotDescription, scene_xml: str | Path | None = None, config: SimServerConfig | None = None) -> Any:
    """A bound (not yet serving) endpoint; ``server.server_address`` is where it listens. Call
    ``serve_forever()`` (e.g. in a thread) and ``shutdown()`` / ``server_close()`` to end it."""
    from funrec_robot.endpoint import Endpoint

    config = SimServerConfig() if config is None else config
    return Endpoint(SimRobot(robot, scene_xml, config), config)


__all__ = ["SimRobot", "SimServerConfig", "make_sim_server"]
