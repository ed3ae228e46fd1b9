"""The funrec robot protocol (``funrec-robot/2``): newline-delimited JSON over TLS, and the checks a robot
endpoint makes on a plan before it accepts it. docs/robot_protocol.md is the prose description.

Every message is one UTF-8 JSON object on one line. Requests carry ``"id"`` and ``"op"``; the endpoint
answers each with ``{"type": "reply", "id": ..., "ok": true|false, ...}`` (``"error"`` when not ok), and
pushes ``{"type": "state", ...}`` and ``{"type": "event", ...}`` messages unasked.
"""

from __future__ import annotations

import json
import math
import socket
from dataclasses import dataclass
from typing import Any

import numpy as np

from funrec.errors import FunrecError
from funrec_robot.plan_file import Plan
from funrec_robot.robot import RobotDescription

PROTOCOL = "funrec-robot/2"
"""Protocol name and version, exchanged in ``hello`` (2: TLS, authentication, lease, signed check records)."""
OPS = ("hello", "auth", "acquire", "release", "upload", "start", "stop", "estop", "reset", "subscribe", "heartbeat", "status")
"""Request operations."""
STATUSES = ("idle", "ready", "running", "done", "stopped", "fault")
"""Endpoint states: nothing uploaded, plan uploaded, executing, finished, stopped on request, stopped by a fault."""
MAX_LINE_BYTES = 4 << 20
"""Longest accepted message, bytes (a 60 s plan at 100 Hz is about 2 MB)."""
MAX_UNAUTHENTICATED_LINE_BYTES = 64 << 10
"""Longest message accepted before a client has authenticated, bytes."""
DEFAULT_PORT = 47300
"""Port of ``funrec-robot serve-sim`` unless told otherwise."""


class ProtocolError(FunrecError):
    """A malformed message, a refused request or a lost connection; the message says which."""


@dataclass(frozen=True)
class LimitMargins:
    """How far a plan may exceed the endpoint's own limits (sampling and servo round-off)."""

    position: float = 1e-3
    """Excess over a joint's position limits, m or rad."""
    velocity: float = 0.05
    """Excess over a speed limit, fraction."""
    acceleration: float = 0.05
    """Excess over an acceleration limit, fraction (finite differences of the sampled velocities; funrec plans
    re-check their limits densely after toppra, so they reach 1.0 at most)."""
    max_period: float = 0.05
    """Longest gap between two samples, s (the endpoint interpolates linearly between them)."""

    def __post_init__(self) -> None:
        for name in ("position", "velocity", "acceleration", "max_period"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or value < 0.0:
                raise FunrecError(f"margins-{name.replace('_', '-')} {value!r}: expected a finite number >= 0")


def validate_plan(plan: Plan, robot: RobotDescription, margins: LimitMargins = LimitMargins()) -> list[str]:
    """Problems of a plan against a robot's own limits (empty: acceptable).

    Checks the joint names (same order), sample times (from 0, increasing, gaps at most
    ``max_period``), finite values, position, velocity and acceleration limits, and gripper commands
    between the robot's open and closed values.
    """
    problems: list[str] = []
    if tuple(plan.joint_names) != tuple(robot.joint_names):
        return [f"joints {list(plan.joint_names)} are not this robot's {list(robot.joint_names)}"]
    t, q, qd = plan.t, plan.q, plan.qd
    if not (np.all(np.isfinite(t)) and np.all(np.isfinite(q)) and np.all(np.isfinite(qd)) and np.all(np.isfinite(plan.gripper_command))):
        return ["non-finite values in t, q, qd or gripper_command"]
    if len(t) < 2 or abs(t[0]) > 1e-9 or np.any(np.diff(t) <= 0.0):
        return ["sample times must start at 0 and increase"]
    dt = np.diff(t)
    if dt.max() > margins.max_period:
        problems.append(f"sample gap {dt.max():.3f} s > {margins.max_period} s")
    for j, name in enumerate(robot.joint_names):
        low, high = robot.q_min[j] - margins.position, robot.q_max[j] + margins.position
        bad = np.flatnonzero((q[:, j] < low) | (q[:, j] > high))
        if bad.size:
            k = int(bad[0])
            problems.append(f"{name}: position {q[k, j]:.4f} at {t[k]:.2f} s outside [{robot.q_min[j]:.4f}, {robot.q_max[j]:.4f}]")
        v = float(np.max(np.abs(qd[:, j])))
        if v > robot.v_max[j] * (1.0 + margins.velocity):
            problems.append(f"{name}: speed {v:.3f} > limit {robot.v_max[j]:.3f}")
        a = float(np.max(np.abs(np.diff(qd[:, j]) / dt)))
        if a > robot.a_max[j] * (1.0 + margins.acceleration):
            problems.append(f"{name}: acceleration {a:.3f} > limit {robot.a_max[j]:.3f}")
    low, high = sorted((robot.gripper.open, robot.gripper.closed))
    if np.any(plan.gripper_command < low - 1e-6) or np.any(plan.gripper_command > high + 1e-6):
        problems.append(f"gripper command outside [{low}, {high}]")
    for name, value in (("grasp", plan.grasp_command), ("open", plan.gripper_open), ("closed", plan.gripper_closed)):
        if not np.isfinite(value) or not low - 1e-6 <= value <= high + 1e-6:
            problems.append(f"gripper {name} command {value} outside [{low}, {high}]")
    return problems


def encode(message: dict[str, Any]) -> bytes:
    """One protocol line."""
    return (json.dumps(message, separators=(",", ":")) + "\n").encode()


def decode_line(line: bytes) -> dict[str, Any]:
    """One message from one line's bytes.

    Raises:
        ProtocolError: not UTF-8, not JSON (NaN and Infinity included) or not an object.
    """
    try:
        message = json.loads(line.decode("utf-8"), parse_constant=_refuse_constant)
    except UnicodeDecodeError as exc:
        raise ProtocolError(f"not UTF-8: {exc.reason} at byte {exc.start}") from None
    except (json.JSONDecodeError, RecursionError) as exc:
        raise ProtocolError(f"not JSON: {str(exc)[:200]}") from None
    if not isinstance(message, dict):
        raise ProtocolError(f"expected a JSON object, got {type(message).__name__}")
    return message


def _refuse_constant(name: str) -> Any:
    raise json.JSONDecodeError(f"{name} is not JSON", name, 0)


class LineReader:
    """Reads newline-delimited JSON objects from a blocking socket, in time linear in the bytes read."""

    def __init__(self, sock: socket.socket, max_bytes: int = MAX_LINE_BYTES) -> None:
        self._sock = sock
        self._buffer = bytearray()
        self._scanned = 0
        self.max_bytes = max_bytes

    def read(self) -> dict[str, Any] | None:
        """The next message, or None when the peer closed the connection.

        Raises:
            ProtocolError: a line longer than ``max_bytes`` or not a JSON object.
        """
        while True:
            end = self._buffer.find(b"\n", self._scanned)
            if end >= 0:
                break
            self._scanned = len(self._buffer)
            if len(self._buffer) > self.max_bytes:
                raise ProtocolError(f"message longer than {self.max_bytes} bytes")
            chunk = self._sock.recv(1 << 16)
            if not chunk:
                return None
            self._buffer += chunk
        line = bytes(self._buffer[:end])
        del self._buffer[: end + 1]
        self._scanned = 0
        if len(line) > self.max_bytes:
            raise ProtocolError(f"message longer than {self.max_bytes} bytes")
        return decode_line(line)


def parse_address(address: str, default_port: int = DEFAULT_PORT) -> tuple[str, int]:
    """``host:port``, ``tcp://host:port`` or ``host`` as (host, port).

    Raises:
        ProtocolError: a port that is not a number.
    """
    text = address.removeprefix("tcp://")
    host, _, port = text.rpartition(":") if ":" in text else (text, "", str(default_port))
    try:
        return host or "127.0.0.1", int(port)
    except ValueError:
        raise ProtocolError(f"address {address!r}: expected host:port") from None


__all__ = [
    "DEFAULT_PORT",
    "MAX_LINE_BYTES",
    "OPS",
    "PROTOCOL",
    "STATUSES",
    "LimitMargins",
    "LineReader",
    "MAX_UNAUTHENTICATED_LINE_BYTES",
    "decode_line",
    "ProtocolError",
    "encode",
    "parse_address",
    "validate_plan",
]
