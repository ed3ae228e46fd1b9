"""Sending checked plans to robots: the :class:`RobotDriver` interface, its ``funrec-robot/2`` client
(:class:`TcpDriver`, e.g. for ``serve-sim``) and :func:`send_plan`, which refuses a plan without a signed,
trusted, passing check record of its exact bytes.

Addresses: ``host:port`` or ``tcp://host:port`` (a ``funrec-robot/2`` endpoint); ``ros2://NAMESPACE``
(:class:`funrec_robot.ros2_driver.Ros2Driver`, FollowJointTrajectory actions; needs rclpy).
"""

from __future__ import annotations

import itertools
import json
import logging
import queue
import select
import socket
import ssl
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

from funrec.errors import FormatError
from funrec_robot.check_record import require_passing_record
from funrec_robot.protocol import PROTOCOL, LineReader, ProtocolError, encode, parse_address

log = logging.getLogger(__name__)


class RobotDriver(Protocol):
    """What ``send`` needs of a robot: implement it to drive a real robot.

    A driver validates nothing itself: the endpoint (controller) checks plans against its own limits.
    """

    def hello(self) -> dict[str, Any]:
        """The endpoint's robot: at least ``robot`` and ``joint_names``."""
        ...

    def upload(self, plan_text: str, check_record: dict[str, Any]) -> str:
        """Hand over plan.json's text with its check record; returns the plan id. Raises on refusal."""
        ...

    def start(self, plan_id: str) -> None:
        """Start executing an uploaded plan."""
        ...

    def stop(self) -> None:
        """Stop and hold position."""
        ...

    def heartbeat(self) -> None:
        """Tell the endpoint the sender is alive (it stops a running plan when these cease)."""
        ...

    def wait_event(self, timeout: float) -> dict[str, Any] | None:
        """The next event (``done``, ``stopped``, ``fault``) within ``timeout`` s, or None."""
        ...

    def close(self) -> None:
        """Release the connection."""
        ...


class TcpDriver:
    """Client of a ``funrec-robot/2`` endpoint (see :mod:`funrec_robot.protocol`): TLS pinned to the endpoint's
    certificate and a bearer token (default: this machine's, under ``$XDG_CONFIG_HOME/funrec-robot/``).

    One thread reads; requests write. The TLS socket is never used by two threads at once (OpenSSL forbids
    it): reads poll with a short timeout under the same lock as writes.
    """

    POLL_S = 0.01
    """Longest a request waits for the reader to let go of the socket, s."""

    def __init__(
        self,
        address: str,
        timeout: float = 10.0,
        on_state: Callable[[dict[str, Any]], None] | None = None,
        tls: bool = True,
        server_cert: str | Path | None = None,
        token: str | None = None,
        authenticate: bool = True,
        client_cert: str | Path | None = None,
        client_key: str | Path | None = None,
    ) -> None:
        host, port = parse_address(address)
        context = None
        if tls:
            from funrec_robot.tls import client_context, client_token

            context = client_context(None if server_cert is None else Path(server_cert),
                                     None if client_cert is None else Path(client_cert), None if client_key is None else Path(client_key))
            token = client_token() if token is None and authenticate else token
        self.token = token if authenticate else None
        try:
            raw = socket.create_connection((host, port), timeout=timeout)
            self._sock = raw if context is None else context.wrap_socket(raw, server_hostname=None)
        except ssl.SSLError as exc:
            raise ProtocolError(f"{host}:{port}: TLS failed ({exc.reason}): not the endpoint whose certificate is trusted, "
                                "or not a funrec-robot/2 endpoint") from None
        except OSError as exc:
            raise ProtocolError(f"{host}:{port}: cannot connect: {exc}") from None
        self._sock.settimeout(self.POLL_S)
        self.timeout = timeout
        self.on_state = on_state
        self.latest_state: dict[str, Any] | None = None
        self._ids = itertools.count(1)
        self._replies: dict[int, queue.Queue] = {}
        self._events: queue.Queue = queue.Queue()
        self._lock = threading.Lock()
        self._closed = False
        self.unsolicited_errors: list[str] = []
        """Errors the endpoint sent without a request id (a line it could not read), oldest first."""
        self._reader = threading.Thread(target=self._read, name="funrec-driver", daemon=True)
        self._reader.start()
        self.info = self.hello()

    def _recv(self, size: int) -> bytes:
        """Poll the socket under the lock; returns b'' at end of stream (raises when closed by us)."""
        while not self._closed:
            pending = isinstance(self._sock, ssl.SSLSocket) and self._sock.pending() > 0
            if not pending and not select.select([self._sock], [], [], 0.05)[0]:
                continue  # wait for bytes without holding the lock, so requests are written at once
            with self._lock:
                try:
                    return self._sock.recv(size)
                except (TimeoutError, ssl.SSLWantReadError):
                    pass
        raise OSError("closed")

    def _read(self) -> None:
        reader = LineReader(_Polled(self._recv))
        while True:
            try:
                message = reader.read()
            except (ProtocolError, OSError, ValueError) as exc:
                message = None
                log.debug("connection ended: %s", exc)
            if message is None:
                why = "connection to the endpoint closed" + (f" ({self.unsolicited_errors[-1]})" if self.unsolicited_errors else "")
                self._events.put({"type": "event", "event": "fault", "detail": why})
                for waiting in list(self._replies.values()):
                    waiting.put({"ok": False, "error": why})
                return
            kind = message.get("type")
            if kind == "reply" and message.get("id") in self._replies:
                self._replies[message["id"]].put(message)
            elif kind == "reply" and message.get("id") is None and not message.get("ok"):
                self.unsolicited_errors.append(str(message.get("error")))  # e.g. a line the endpoint could not parse
            elif kind == "state":
                self.latest_state = message
                if self.on_state is not None:
                    self.on_state(message)
            elif kind == "event":
                self._events.put(message)

    def send_raw(self, data: bytes) -> None:
        """Write bytes as they are (tests of the endpoint's handling of malformed input)."""
        with self._lock:
            self._sock.settimeout(self.timeout)
            try:
                self._sock.sendall(data)
            finally:
                self._sock.settimeout(self.POLL_S)

    def request(self, op: str, **fields: Any) -> dict[str, Any]:
        """Send one request and wait for its reply.

        Raises:
            ProtocolError: the endpoint refused (its reason), did not answer within ``timeout`` or closed.
        """
        ident = next(self._ids)
        box: queue.Queue = queue.Queue()
        self._replies[ident] = box
        try:
            self.send_raw(encode({"id": ident, "op": op, **fields}))
            reply = box.get(timeout=self.timeout)
        except queue.Empty:
            raise ProtocolError(f"{op}: no reply within {self.timeout} s") from None
        except OSError as exc:
            raise ProtocolError(f"{op}: connection failed: {exc}") from None
        finally:
            self._replies.pop(ident, None)
        if not reply.get("ok"):
            error = str(reply.get("error", "refused"))
            raise ProtocolError(error if error.startswith(f"{op}:") else f"{op}: {error}")
        return reply

    def hello(self) -> dict[str, Any]:
        """Protocol handshake, then authenticate if the endpoint asks for it."""
        reply = self.request("hello", protocol=PROTOCOL)
        if reply.get("protocol") != PROTOCOL:
            raise ProtocolError(f"endpoint speaks {reply.get('protocol')!r}, expected {PROTOCOL!r}")
        if not reply.get("authenticated") and self.token is not None:
            self.request("auth", token=self.token)
        return reply

    def acquire(self) -> None:
        """Take the lease (exclusive control)."""
        self.request("acquire")

    def upload(self, plan_text: str, check_record: dict[str, Any]) -> str:
        self.acquire()  # (again: a lease lapses after heartbeat_timeout of silence)
        return str(self.request("upload", plan_text=plan_text, check=check_record)["plan_id"])

    def start(self, plan_id: str) -> None:
        self.request("start", plan_id=plan_id)

    def stop(self) -> None:
        self.request("stop")

    def estop(self) -> None:
        self.request("estop")

    def heartbeat(self) -> None:
        self.request("heartbeat")

    def subscribe(self, rate_hz: float) -> None:
        self.request("subscribe", rate_hz=rate_hz)

    def wait_event(self, timeout: float) -> dict[str, Any] | None:
        try:
            return self._events.get(timeout=timeout)
        except queue.Empty:
            return None

    def close(self) -> None:
        self._closed = True
        with self._lock:
            try:
                self._sock.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass
            self._sock.close()


class _Polled:
    """A socket-like object whose ``recv`` is the driver's locked poll (for :class:`LineReader`)."""

    def __init__(self, recv: Callable[[int], bytes]) -> None:
        self.recv = recv


def open_driver(address: str, timeout: float = 10.0) -> RobotDriver:
    """A driver for an address: ``ros2://NAMESPACE`` (needs rclpy), else a ``funrec-robot/2`` endpoint."""
    if address.startswith("ros2://"):
        from funrec_robot.ros2_driver import Ros2Driver

        return Ros2Driver(address.removeprefix("ros2://"), timeout=timeout)
    return TcpDriver(address, timeout=timeout)


@dataclass(frozen=True)
class SendResult:
    """How an execution ended."""

    event: str
    """'done', 'stopped' or 'fault'."""
    detail: str
    """The endpoint's explanation."""
    plan_id: str
    """The endpoint's id of the plan (its sha256)."""
    wall_time: float
    """Seconds from start to the event."""


def send_plan(
    plan_path: str | Path,
    address: str,
    heartbeat_period: float = 0.2,
    timeout: float | None = None,
    driver: RobotDriver | None = None,
) -> SendResult:
    """Send a checked plan to a robot endpoint, start it and keep it alive until it ends.

    Args:
        plan_path: plan.json; its check record (``plan.check.json``) must have passed on these exact bytes.
        address: the endpoint (see the module docstring).
        heartbeat_period: seconds between heartbeats while the plan runs.
        timeout: give up (and stop the robot) after this many seconds; default the plan's duration + 30 s.
        driver: an already open driver (else one is opened for ``address`` and closed at the end).

    Raises:
        PlanningError: no passing check record of this plan. ProtocolError: the endpoint refused or vanished.
    """
    plan_path = Path(plan_path)
    record = require_passing_record(plan_path)
    try:
        plan_text = plan_path.read_bytes().decode("utf-8")  # the exact bytes the record hashed (no newline translation)
    except UnicodeDecodeError as exc:
        raise FormatError(plan_path, f"not UTF-8 text: {exc.reason} at byte {exc.start}") from None
    duration = float(json.loads(plan_text)["t"][-1])
    own = driver is None
    driver = open_driver(address) if driver is None else driver
    try:
        info = driver.hello()
        log.info("endpoint %s: robot %s", address, info.get("robot"))
        plan_id = driver.upload(plan_text, record)
        started = time.monotonic()
        driver.start(plan_id)
        limit = duration + 30.0 if timeout is None else timeout
        while True:
            event = driver.wait_event(heartbeat_period)
            if event is not None:
                return SendResult(str(event.get("event")), str(event.get("detail", "")), plan_id, time.monotonic() - started)
            if time.monotonic() - started > limit:
                driver.stop()
                return SendResult("stopped", f"no end of execution after {limit:.0f} s: stopped by the sender", plan_id, time.monotonic() - started)
            driver.heartbeat()
    finally:
        if own:
            driver.close()


__all__ = ["RobotDriver", "SendResult", "TcpDriver", "open_driver", "send_plan"]
