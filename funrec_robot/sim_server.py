"""``funrec-robot serve-sim``: a reference robot endpoint that speaks ``funrec-robot/1`` over TCP and executes
plans in MuJoCo in real time.

It behaves like a robot controller: it validates an uploaded plan against its own robot file's limits (and
its check record's hash), runs it on the robot's servos only after ``start``, streams the measured state,
stops and holds on ``stop``, and stops and holds by itself when no client has sent anything (a heartbeat or
any request) for ``heartbeat_timeout`` while a plan runs. One plan runs at a time.
"""

from __future__ import annotations

import hashlib
import json
import logging
import socketserver
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import mujoco
import numpy as np

from funrec.errors import FunrecError
from funrec_robot.plan_file import Plan, plan_from_json, release_offset
from funrec_robot.protocol import PROTOCOL, LimitMargins, LineReader, ProtocolError, encode, validate_plan
from funrec_robot.robot import RobotDescription
from funrec_robot.sim_model import build_mujoco_model, gripper_position, reset_to_home, robot_indices

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class SimServerConfig:
    """Settings of the simulated robot endpoint."""

    host: str = "127.0.0.1"
    """Address to listen on (localhost: the endpoint takes motion commands, keep it off open networks)."""
    port: int = 47300
    """TCP port; 0 picks a free one."""
    heartbeat_timeout: float = 1.0
    """A running plan stops when its client sends nothing for this long, s."""
    real_time_factor: float = 1.0
    """Simulated seconds per wall-clock second (1: real time)."""
    require_check: bool = True
    """Refuse plans without a passing check record of their exact bytes."""
    margins: LimitMargins = field(default_factory=LimitMargins)
    """Tolerances of the plan validation."""


class SimRobot:
    """The simulated robot: a MuJoCo model stepped in real time by a thread while a plan runs."""

    def __init__(self, robot: RobotDescription, scene_xml: str | Path | None, config: SimServerConfig) -> None:
        self.robot, self.config = robot, config
        self.model = build_mujoco_model(robot, scene_xml)
        self.data = mujoco.MjData(self.model)
        self.indices = robot_indices(robot, self.model)
        reset_to_home(robot, self.model, self.data)
        self.lock = threading.RLock()
        self.status, self.detail = "idle", ""
        self.plans: dict[str, Plan] = {}
        self.plan: Plan | None = None
        self.plan_time = 0.0
        self.last_heartbeat = time.monotonic()
        self.listeners: list[Any] = []
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def upload(self, message: dict[str, Any]) -> dict[str, Any]:
        text = message.get("plan_text")
        if not isinstance(text, str):
            raise ProtocolError("upload needs 'plan_text': the plan.json file's text")
        plan_id = hashlib.sha256(text.encode()).hexdigest()
        if self.config.require_check:
            record = message.get("check")
            if not isinstance(record, dict) or record.get("plan_sha256") != plan_id or record.get("passed") is not True:
                raise ProtocolError("refused: no passing check record of this exact plan (sha256) came with it")
        plan = plan_from_json(json.loads(text), "<uploaded plan>")
        problems = validate_plan(plan, self.robot, self.config.margins)
        if problems:
            raise ProtocolError("refused: " + "; ".join(problems[:5]))
        with self.lock:
            self.plans[plan_id] = plan
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
            start_gap = np.abs(self.data.qpos[self.indices.qpos] - plan.q[0])
            if self.status in ("done", "stopped", "fault") and start_gap.max() > 0.05:
                reset_to_home(self.robot, self.model, self.data)  # a new episode: the simulated robot is put back
            self.data.qpos[self.indices.qpos] = plan.q[0]  # the simulation starts where the plan does
            self.data.qvel[:] = 0.0
            mujoco.mj_forward(self.model, self.data)
            self.plan, self.plan_time, self.status, self.detail = plan, 0.0, "running", ""
            self.last_heartbeat = time.monotonic()
            self._stop.clear()
            self._thread = threading.Thread(target=self._run, name="funrec-sim", daemon=True)
            self._thread.start()
        return {"status": "running"}

    def stop(self, detail: str = "stop requested", status: str = "stopped") -> dict[str, Any]:
        with self.lock:
            if self.status == "running":
                self._halt(status, detail)
        return {"status": self.status}

    def _halt(self, status: str, detail: str) -> None:
        """Hold the current position (caller holds the lock)."""
        self.data.ctrl[self.indices.actuators] = self.data.qpos[self.indices.qpos]
        self.status, self.detail = status, detail
        self._stop.set()
        self._event(status, detail)

    def _event(self, event: str, detail: str) -> None:
        for listener in list(self.listeners):
            listener.push({"type": "event", "event": event, "detail": detail, "plan_time": round(self.plan_time, 4)})

    def state(self) -> dict[str, Any]:
        with self.lock:
            q = self.data.qpos[self.indices.qpos]
            qd = self.data.qvel[self.indices.dof]
            gripper = self.data.ctrl[self.indices.gripper_actuators]
            return {
                "type": "state",
                "status": self.status,
                "sim_time": round(float(self.data.time), 4),
                "plan_time": round(self.plan_time, 4),
                "joint_names": list(self.robot.joint_names),
                "q": np.round(q, 6).tolist(),
                "qd": np.round(qd, 6).tolist(),
                "gripper_command": float(gripper[0]) if gripper.size else None,
            }

    def _run(self) -> None:
        """Step the model so that simulated time keeps pace with the wall clock (times the real-time factor)."""
        model, data, plan = self.model, self.data, self.plan
        assert plan is not None
        dt = model.opt.timestep
        grip_offset: float | None = None
        started = time.monotonic()
        while not self._stop.is_set():
            wall = (time.monotonic() - started) * self.config.real_time_factor
            with self.lock:
                if self.status != "running":
                    return
                if time.monotonic() - self.last_heartbeat > self.config.heartbeat_timeout:
                    self._halt("fault", f"no heartbeat for {self.config.heartbeat_timeout} s: stopped and holding")
                    return
                while self.plan_time < wall and self.plan_time <= plan.duration:
                    t = self.plan_time
                    data.ctrl[self.indices.actuators] = [np.interp(t, plan.t, plan.q[:, j]) for j in range(plan.q.shape[1])]
                    if t >= plan.release_start and grip_offset is None:
                        grip_offset = release_offset(plan, gripper_position(self.indices, data))
                    data.ctrl[self.indices.gripper_actuators] = np.interp(t, plan.t, plan.gripper_command) + (grip_offset or 0.0)
                    mujoco.mj_step(model, data)
                    self.plan_time += dt
                if self.plan_time > plan.duration:
                    self.status, self.detail = "done", f"plan finished after {plan.duration:.2f} s"
                    self._event("done", self.detail)
                    return
            time.sleep(0.002)


class _Handler(socketserver.StreamRequestHandler):
    """One client connection: requests in, replies, states and events out."""

    server: _Server

    def setup(self) -> None:
        super().setup()
        self._write_lock = threading.Lock()
        self._streaming = threading.Event()
        self._closed = False

    def push(self, message: dict[str, Any]) -> None:
        if self._closed:
            return
        try:
            with self._write_lock:
                self.connection.sendall(encode(message))
        except OSError:
            self._closed = True

    def _stream(self, rate_hz: float) -> None:
        while self._streaming.is_set() and not self._closed:
            self.push(self.server.sim.state())
            time.sleep(1.0 / rate_hz)

    def handle(self) -> None:
        sim = self.server.sim
        sim.listeners.append(self)
        reader = LineReader(self.connection)
        try:
            while True:
                try:
                    message = reader.read()
                except (ProtocolError, OSError) as exc:
                    self.push({"type": "reply", "id": None, "ok": False, "error": str(exc)})
                    break
                if message is None:
                    break
                with sim.lock:
                    sim.last_heartbeat = time.monotonic()  # any message from a client shows it is alive
                reply: dict[str, Any] = {"type": "reply", "id": message.get("id"), "ok": True}
                try:
                    reply.update(self._dispatch(message))
                except (FunrecError, ValueError) as exc:
                    reply.update(ok=False, error=str(exc))
                self.push(reply)
        finally:
            self._streaming.clear()
            self._closed = True
            sim.listeners.remove(self)

    def _dispatch(self, message: dict[str, Any]) -> dict[str, Any]:
        sim, op = self.server.sim, message.get("op")
        if op == "hello":
            robot = sim.robot
            return {"protocol": PROTOCOL, "robot": robot.name, "joint_names": list(robot.joint_names),
                    "q_min": robot.q_min.tolist(), "q_max": robot.q_max.tolist(), "v_max": robot.v_max.tolist(),
                    "a_max": robot.a_max.tolist(), "heartbeat_timeout": sim.config.heartbeat_timeout}
        if op == "upload":
            return sim.upload(message)
        if op == "start":
            return sim.start(str(message.get("plan_id", "")))
        if op == "stop":
            return sim.stop()
        if op == "heartbeat":
            return {"status": sim.status}
        if op == "status":
            return {"status": sim.status, "detail": sim.detail, "state": sim.state()}
        if op == "subscribe":
            rate = float(message.get("rate_hz", 20.0))
            if not 0.0 < rate <= 200.0:
                raise ProtocolError(f"rate_hz {rate}: expected 0 < rate <= 200")
            if not self._streaming.is_set():
                self._streaming.set()
                threading.Thread(target=self._stream, args=(rate,), daemon=True).start()
            return {"rate_hz": rate}
        raise ProtocolError(f"unknown op {op!r}; ops: hello, upload, start, stop, subscribe, heartbeat, status")


class _Server(socketserver.ThreadingTCPServer):
    daemon_threads = True
    allow_reuse_address = True

    def __init__(self, address: tuple[str, int], sim: SimRobot) -> None:
        self.sim = sim
        super().__init__(address, _Handler)


def make_sim_server(robot: RobotDescription, scene_xml: str | Path | None = None, config: SimServerConfig | None = None) -> _Server:
    """A bound (not yet serving) endpoint; ``server.server_address`` is where it listens. Call
    ``serve_forever()`` (e.g. in a thread) and ``shutdown()`` / ``server_close()`` to end it."""
    config = SimServerConfig() if config is None else config
    return _Server((config.host, config.port), SimRobot(robot, scene_xml, config))


__all__ = ["SimRobot", "SimServerConfig", "make_sim_server"]
