"""The network side of a ``funrec-robot/2`` endpoint: TLS, authentication, the lease, per-client queued
delivery, and a reply for every message. One asyncio loop serves every client; the robot (e.g.
:class:`funrec_robot.sim_server.SimRobot`) runs in its own thread.

No client can starve the others: lines are read in linear time and capped (64 KiB before authenticating,
4 MiB after), each client's outgoing messages queue in its own transport and a client that lets more than
``max_send_buffer`` bytes pile up is dropped, each connection handles one message per turn of the loop and
at most ``max_message_rate`` a second, lines over 64 KiB are decoded off the loop, and connections are capped
in number and closed when idle.

Stopping never waits for other work: an authenticated client's ``stop`` and ``estop`` skip the rate limit,
and a guard thread of its own, independent of the loop's backlog, stops a running plan within
``GUARD_PERIOD_S`` when the lease holder's socket closes or its heartbeats cease.
"""

from __future__ import annotations

import asyncio
import ipaddress
import itertools
import logging
import os
import select
import socket
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from funrec.errors import FunrecError
from funrec_robot.protocol import (
    MAX_LINE_BYTES,
    MAX_UNAUTHENTICATED_LINE_BYTES,
    OPS,
    PROTOCOL,
    ProtocolError,
    decode_line,
    encode,
)

log = logging.getLogger(__name__)

UNAUTHENTICATED_IDLE_S = 10.0
"""A connection that has not authenticated is closed after this long without a message, s."""
SEND_SOCKET_BUFFER = 256 << 10
"""Kernel send buffer of each client socket, bytes (the kernel's autotuning would let megabytes queue)."""
MAX_AUTH_FAILURES = 3
"""Wrong tokens before a connection is closed."""
OPEN_OPS = ("hello", "auth")
"""Operations allowed before authenticating."""
LEASE_OPS = ("upload", "start", "stop", "reset", "release")
"""Operations that need the lease (``estop`` never does)."""
URGENT_OPS = ("stop", "estop")
"""Operations an authenticated client's connection serves at once, outside its rate limit."""
URGENT_LINE_BYTES = 1024
"""Lines up to this long are decoded before the rate limit, to find urgent operations, bytes."""
OFF_LOOP_DECODE_BYTES = 64 << 10
"""Lines longer than this are decoded in a worker thread, so that one client's large message does not hold up
the loop (and every other client's ``stop``), bytes."""
GUARD_PERIOD_S = 0.01
"""How often the guard thread looks at the lease holder's socket and heartbeats, s."""
_HANGUP = select.POLLHUP | select.POLLERR | select.POLLNVAL | getattr(select, "POLLRDHUP", 0x2000)


@dataclass
class _Client:
    ident: int
    peer: str
    writer: asyncio.StreamWriter
    reader: asyncio.StreamReader
    authenticated: bool = False
    name: str = ""
    failures: int = 0
    last_seen: float = field(default_factory=time.monotonic)
    streaming: asyncio.Task | None = None
    closed: bool = False
    busy: bool = False
    """A request of this client is being carried out (e.g. a large upload being verified)."""
    watch_fd: int = -1
    """A duplicate of the socket's descriptor that the guard thread polls for a hang-up (-1: none)."""


def return_large_buffers_to_the_os() -> None:
    """glibc only, process-wide: serve every allocation over 128 KiB from its own mapping, freed at once.

    Lines of up to 4 MiB come and go; with glibc's default (a threshold that rises after such frees) they
    end up in heap arenas that never shrink, and a long flood ratchets the resident memory up (measured on
    serve-sim: 177 -> 501 MB in a 30 s flood; with this alone 174 -> 447 MB; with this and closed streams'
    buffers freed at once (``_handle``) 175 -> 255 MB, flat). A no-op elsewhere.
    """
    import ctypes
    import ctypes.util

    name = ctypes.util.find_library("c")
    try:
        libc = ctypes.CDLL(name) if name else None
        if libc is not None and hasattr(libc, "mallopt"):
            libc.mallopt(-3, 128 * 1024)  # M_MMAP_THRESHOLD (fixing it also stops its dynamic rise)
    except OSError:
        pass


READ_CHUNK_BYTES = 32 << 10
"""Bytes a connection's transport reads (and decrypts) per turn of the loop (asyncio's default: 256 KiB)."""


def short_turns() -> None:
    """Process-wide, for a process that only serves an endpoint (``serve-sim`` calls it; an endpoint inside
    another program need not): keep each turn of the loop short, so that a
    ``stop`` waits little behind other clients' bytes.

    - Each connection reads at most ``READ_CHUNK_BYTES`` a turn: 16 flooding connections at asyncio's 256 KiB
      cost ~16 ms of CPU a turn in TLS decryption alone, and under CPU contention (two other busy processes)
      turns took up to 440 ms of wall time; at 32 KiB the longest measured was 130-170 ms, the holder's
      heartbeat round trip at p99 16-60 ms instead of 160 ms (``tests/test_endpoint_load.py``'s flood).
    - Every object alive at start-up (the robot model, numpy, the imports) is moved out of the cyclic garbage
      collector's view (``gc.freeze``): a full collection then walks only what serving allocates, instead of
      stalling the loop for tens of milliseconds.
    """
    import asyncio.selector_events
    import asyncio.sslproto
    import gc

    asyncio.sslproto.SSLProtocol.max_size = READ_CHUNK_BYTES
    asyncio.selector_events._SelectorSocketTransport.max_size = READ_CHUNK_BYTES  # noqa: SLF001 (no public setting)
    gc.collect()
    gc.freeze()


def _urgent(line: bytes) -> dict[str, Any] | None:
    """The message of a short line whose op is urgent (``stop``, ``estop``), else None (decoded later)."""
    if len(line) > URGENT_LINE_BYTES or b"stop" not in line:
        return None
    try:
        message = decode_line(line)
    except FunrecError:
        return None
    return message if message.get("op") in URGENT_OPS else None


def _is_loopback(host: str) -> bool:
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


class Endpoint:
    """A bound ``funrec-robot/2`` server around a robot object (``upload``, ``start``, ``stop(detail, status,
    cause_time=)``, ``estop(who, cause_time=)``, ``reset``, ``heartbeat``, ``state``, ``lock``, ``status``,
    ``detail``, ``last_heartbeat``, ``last_halt``, ``notify``; see :class:`funrec_robot.sim_server.SimRobot`).

    Raises:
        FunrecError: without authentication on a non-loopback address unless the config names the risk.
    """

    def __init__(self, sim: Any, config: Any) -> None:
        self.sim, self.config = sim, config
        self.ssl = None
        self.accepted_tokens: frozenset[str] = frozenset()
        if config.auth:
            from funrec_robot.tls import authorized_hashes, client_token, endpoint_certificate, server_context

            client_token()  # this machine's user is authorized on first use
            self.accepted_tokens = authorized_hashes()
            cert, key = endpoint_certificate()
            self.certificate = cert
            self.ssl = server_context(cert, key, Path(config.client_ca) if config.client_ca else None)
        elif not _is_loopback(config.host) and not config.unauthenticated_beyond_loopback:
            raise FunrecError(
                f"refusing to listen on {config.host} without authentication: anyone who reaches it could move "
                "the robot; keep auth on, or pass --unauthenticated-beyond-loopback to accept that risk"
            )
        family = socket.AF_INET6 if ":" in config.host else socket.AF_INET
        self._socket = socket.socket(family, socket.SOCK_STREAM)
        self._socket.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            self._socket.bind((config.host, config.port))
        except OSError as exc:
            self._socket.close()
            raise FunrecError(f"cannot listen on {config.host}:{config.port}: {exc}") from None
        self._socket.listen(128)
        self.server_address = self._socket.getsockname()
        self.clients: dict[int, _Client] = {}
        self.holder: int | None = None
        self.internal_errors = 0
        self.dropped_slow = 0
        self.loop_lag_max = 0.0
        """Longest the loop's 50 ms watch tick came late, s: how long a message may wait behind others."""
        self._ids = itertools.count(1)
        self._loop: asyncio.AbstractEventLoop | None = None
        self._done: asyncio.Event | None = None
        self._started = threading.Event()
        sim.notify = self._notify_threadsafe

    # -- life cycle -------------------------------------------------------------------------------------------
    def serve_forever(self) -> None:
        """Serve until :meth:`shutdown` (blocks)."""
        asyncio.run(self._serve())

    async def _serve(self) -> None:
        self._loop = asyncio.get_running_loop()
        self._done = asyncio.Event()
        server = await asyncio.start_server(
            self._handle, sock=self._socket, ssl=self.ssl, limit=MAX_UNAUTHENTICATED_LINE_BYTES,
            ssl_handshake_timeout=10.0 if self.ssl else None,
        )
        watchdog = asyncio.create_task(self._watch())
        guard_done = threading.Event()
        guard = threading.Thread(target=self._guard, args=(guard_done,), name="funrec-endpoint-guard", daemon=True)
        guard.start()
        self._started.set()
        try:
            await self._done.wait()
        finally:
            guard_done.set()
            watchdog.cancel()
            server.close()
            for client in list(self.clients.values()):
                self._close(client)
            await asyncio.sleep(0.05)  # handlers end on their closed streams rather than by cancellation
            with self.sim.lock:
                if self.sim.status == "running":
                    self.sim.stop("endpoint shut down", "fault")

    def shutdown(self) -> None:
        if self._loop is not None and self._done is not None:
            self._loop.call_soon_threadsafe(self._done.set)

    def server_close(self) -> None:
        self._socket.close()

    # -- outgoing -----------------------------------------------------------------------------------------
    def _notify_threadsafe(self, message: dict[str, Any]) -> None:
        if self._loop is not None:
            self._loop.call_soon_threadsafe(self._broadcast, message)

    def _broadcast(self, message: dict[str, Any]) -> None:
        data = encode(message)
        for client in list(self.clients.values()):
            self._send(client, data)

    def _send(self, client: _Client, data: bytes) -> None:
        """Queue bytes to a client without blocking; drop a client that does not read."""
        if client.closed:
            return
        transport = client.writer.transport
        if transport.is_closing():
            return
        transport.write(data)
        if transport.get_write_buffer_size() > self.config.max_send_buffer:
            self.dropped_slow += 1
            log.info("client %d (%s): dropped, %d bytes unread", client.ident, client.peer, transport.get_write_buffer_size())
            self._close(client)

    def _close(self, client: _Client) -> None:
        if not client.closed:
            client.closed = True
            client.writer.transport.abort()

    async def _stream(self, client: _Client, rate_hz: float) -> None:
        period = 1.0 / rate_hz
        while not client.closed:
            self._send(client, encode(self.sim.state()))
            await asyncio.sleep(period)

    def _guard(self, done: threading.Event) -> None:
        """Every ``GUARD_PERIOD_S``, in a thread of its own (the loop may be busy): stop a running plan whose lease
        holder's socket has hung up or whose heartbeats have ceased. The loop lapses the lease afterwards."""
        poller_fd = -1
        while not done.wait(GUARD_PERIOD_S):
            try:
                if self.sim.status != "running":
                    continue
                ident = self.holder
                holder = self.clients.get(ident) if ident is not None else None
                fd = -1 if holder is None or holder.closed else holder.watch_fd
                if fd >= 0 and fd != poller_fd:
                    poller, poller_fd = select.poll(), fd
                    poller.register(fd, _HANGUP)
                if holder is None or holder.closed or (fd >= 0 and any(mask & _HANGUP for _, mask in poller.poll(0))):
                    why = "no client holds the lease" if ident is None else f"lease lapsed (the holder, client {ident}, disconnected)"
                    self.sim.stop(f"{why}: stopped and holding", "fault", cause_time=time.monotonic())
                    continue
                deadline = self.sim.last_heartbeat + self.config.heartbeat_timeout
                if time.monotonic() > deadline:
                    self.sim.stop(f"no heartbeat from the lease holder for {self.config.heartbeat_timeout} s: stopped and holding",
                                  "fault", cause_time=deadline)
            except Exception:  # the guard must outlive any bug: log and keep watching
                log.exception("endpoint guard")

    async def _watch(self) -> None:
        """Lapse a silent holder's lease and close idle connections, every 50 ms."""
        while True:
            before = time.monotonic()
            await asyncio.sleep(0.05)
            now = time.monotonic()
            self.loop_lag_max = max(self.loop_lag_max, now - before - 0.05)
            holder = self.clients.get(self.holder) if self.holder is not None else None
            if (holder is not None and not holder.busy and now - self.sim.last_heartbeat > self.config.heartbeat_timeout
                    and self.sim.status != "running"):
                self._lapse(f"no heartbeat from the lease holder for {self.config.heartbeat_timeout} s")
            for client in list(self.clients.values()):
                limit = self.config.idle_timeout if client.authenticated else UNAUTHENTICATED_IDLE_S
                if now - client.last_seen > limit:
                    self._send(client, encode({"type": "event", "event": "closed", "detail": f"idle for {limit:g} s"}))
                    self._close(client)

    def _lapse(self, why: str) -> None:
        """Release the lease; a running plan stops and holds (a fault)."""
        self.holder = None
        with self.sim.lock:
            if self.sim.status == "running":
                self.sim.stop(f"lease lapsed ({why}): stopped and holding", "fault", cause_time=time.monotonic())

    # -- incoming -----------------------------------------------------------------------------------------
    async def _handle(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        peer = str(writer.get_extra_info("peername"))
        client = _Client(next(self._ids), peer, writer, reader)
        if len(self.clients) >= self.config.max_connections:
            writer.write(encode({"type": "reply", "id": None, "ok": False,
                                 "error": f"too many connections (at most {self.config.max_connections}); try later"}))
            writer.transport.close()
            return
        sock = writer.get_extra_info("socket")
        if sock is not None:  # bounded kernel buffering per client: one that does not read is found (and dropped) soon
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, SEND_SOCKET_BUFFER)
            client.watch_fd = os.dup(sock.fileno())  # the guard's own handle: never a reused descriptor number
        certificate = writer.get_extra_info("peercert")
        if certificate:
            subject = dict(item[0] for item in certificate.get("subject", ()))
            client.authenticated, client.name = True, f"certificate {subject.get('commonName', '?')}"
            reader._limit = MAX_LINE_BYTES  # noqa: SLF001 (asyncio has no public setter for a stream's line limit)
        self.clients[client.ident] = client
        try:
            await self._serve_client(client)
        finally:
            self.clients.pop(client.ident, None)
            client.closed = True
            if client.streaming is not None:
                client.streaming.cancel()
            if self.holder == client.ident:
                self._lapse(f"the holder, client {client.ident}, disconnected")
            writer.transport.abort()
            if client.watch_fd >= 0:
                os.close(client.watch_fd)
            # A closed stream's exception keeps its frames, and so its buffer (up to 8 MiB), alive in reference
            # cycles until the cyclic collector runs, which large buffers do not trigger: free the bytes now.
            reader._buffer.clear()  # noqa: SLF001

    async def _serve_client(self, client: _Client) -> None:
        allowance, last = 1.0, time.monotonic()
        while not client.closed:
            try:
                line = await client.reader.readuntil(b"\n")
            except asyncio.IncompleteReadError:
                return
            except asyncio.LimitOverrunError:
                limit = MAX_LINE_BYTES if client.authenticated else MAX_UNAUTHENTICATED_LINE_BYTES
                self._reply(client, None, error=f"message longer than {limit} bytes; connection closed")
                await asyncio.sleep(0.01)
                return
            except (ConnectionError, OSError):
                return
            client.last_seen = time.monotonic()
            message = _urgent(line) if client.authenticated else None
            if message is None:
                # token bucket: at most max_message_rate messages a second from one connection (a tenth before
                # authenticating); a faster client waits before its message is served, and TCP holds its further
                # bytes back. An authenticated client's stop and estop do not wait.
                rate = self.config.max_message_rate * (1.0 if client.authenticated else 0.1)
                while True:  # a late wake-up keeps its credit: a loaded machine does not lower the rate
                    now = time.monotonic()
                    allowance, last = min(allowance + (now - last) * rate, max(1.0, rate / 10.0)), now
                    if allowance >= 1.0:
                        break
                    await asyncio.sleep((1.0 - allowance) / rate)
                allowance -= 1.0
            await self._answer(client, line, message, client.last_seen)
            await asyncio.sleep(0)  # one message per connection per turn: a flooding client cannot starve the others

    def _reply(self, client: _Client, ident: Any, error: str | None = None, fields: dict[str, Any] | None = None) -> None:
        ident = ident if isinstance(ident, (int, str)) and not isinstance(ident, bool) and len(str(ident)) <= 64 else None
        message: dict[str, Any] = {**(fields or {}), "type": "reply", "id": ident, "ok": error is None}
        if error is not None:
            message["error"] = error
        self._send(client, encode(message))

    async def _answer(self, client: _Client, line: bytes, message: dict[str, Any] | None, received: float) -> None:
        ident = None
        client.busy = True
        try:
            if message is None:
                if len(line) > OFF_LOOP_DECODE_BYTES:
                    message = await asyncio.get_running_loop().run_in_executor(None, decode_line, line)
                else:
                    message = decode_line(line)
            ident = message.get("id")
            self._reply(client, ident, fields=await self._dispatch(client, message, received))
        except FunrecError as exc:
            self._reply(client, ident, error=str(exc))
        except Exception as exc:  # a bug must cost a reply, never the connection or the server
            self.internal_errors += 1
            log.exception("client %d: internal error", client.ident)
            self._reply(client, ident, error=f"internal error ({type(exc).__name__}); the request was not carried out")
        finally:
            client.busy = False
            if self.holder == client.ident:
                self.sim.heartbeat()  # a long request (an upload) ends: the holder's silence counts from here

    def _hello(self, client: _Client) -> dict[str, Any]:
        robot = self.sim.robot
        auth = (["token"] + (["client_certificate"] if self.config.client_ca else [])) if self.config.auth else []
        return {"protocol": PROTOCOL, "robot": robot.name, "joint_names": list(robot.joint_names),
                "q_min": robot.q_min.tolist(), "q_max": robot.q_max.tolist(), "v_max": robot.v_max.tolist(),
                "a_max": robot.a_max.tolist(), "heartbeat_timeout": self.config.heartbeat_timeout,
                "auth": auth, "authenticated": client.authenticated or not self.config.auth, "client": client.ident}

    def _auth(self, client: _Client, message: dict[str, Any]) -> dict[str, Any]:
        from funrec_robot.tls import authorized_hashes, token_accepted

        if not self.config.auth or client.authenticated:
            return {"authenticated": True}
        if not token_accepted(message.get("token"), self.accepted_tokens | authorized_hashes()):
            client.failures += 1
            if client.failures >= MAX_AUTH_FAILURES:
                self._close(client)
            raise ProtocolError("auth: token not accepted")
        client.authenticated, client.name = True, "token"
        client.reader._limit = MAX_LINE_BYTES  # noqa: SLF001 (asyncio has no public setter for a stream's line limit)
        return {"authenticated": True}

    def _lease(self, client: _Client, op: str) -> None:
        if self.holder != client.ident:
            who = "nobody" if self.holder is None else f"client {self.holder}"
            raise ProtocolError(f"{op}: refused: this client does not hold the lease ({who} does); send 'acquire' first")

    async def _dispatch(self, client: _Client, message: dict[str, Any], received: float) -> dict[str, Any]:
        sim, op = self.sim, message.get("op")
        if not isinstance(op, str) or op not in OPS:
            raise ProtocolError(f"unknown op {op!r}; ops: {', '.join(OPS)}")
        if op == "hello":
            return self._hello(client)
        if op == "auth":
            return self._auth(client, message)
        if self.config.auth and not client.authenticated:
            raise ProtocolError(f"{op}: refused: not authenticated; send 'auth' with a token first (see 'hello')")
        if self.holder == client.ident:
            sim.heartbeat()  # only the lease holder's messages keep its plan alive
        if op in LEASE_OPS:
            self._lease(client, op)
        if op == "acquire":
            if self.holder not in (None, client.ident) and self.holder in self.clients:
                raise ProtocolError(f"acquire: refused: client {self.holder} holds the lease; it lapses "
                                    f"{self.config.heartbeat_timeout} s after its last heartbeat")
            self.holder = client.ident
            sim.heartbeat()
            return {"lease": True, "client": client.ident}
        if op == "release":
            self._lapse(f"released by client {client.ident}")
            return {"lease": False}
        if op == "upload":
            return await asyncio.get_running_loop().run_in_executor(None, sim.upload, message)
        if op == "start":
            plan_id = message.get("plan_id")
            if not isinstance(plan_id, str):
                raise ProtocolError("start needs 'plan_id' (a string from upload)")
            return sim.start(plan_id)
        if op == "stop":
            return sim.stop(cause_time=received)
        if op == "estop":
            return sim.estop(f"client {client.ident} ({client.peer})", cause_time=received)
        if op == "reset":
            return sim.reset()
        if op == "heartbeat":
            if self.holder != client.ident:
                raise ProtocolError("heartbeat: refused: only the lease holder's heartbeats keep a plan alive")
            return {"status": sim.status}
        if op == "status":
            return {"status": sim.status, "detail": sim.detail, "state": sim.state(), "lease": self.holder,
                    "timing": {"last_halt": sim.last_halt, "loop_lag_max_s": round(self.loop_lag_max, 4)}}
        return self._subscribe(client, message)

    def _subscribe(self, client: _Client, message: dict[str, Any]) -> dict[str, Any]:
        rate = message.get("rate_hz", 20.0)
        if isinstance(rate, bool) or not isinstance(rate, (int, float)) or not 0.0 < rate <= 200.0:
            raise ProtocolError(f"rate_hz {str(rate)[:40]}: expected a number, 0 < rate <= 200")
        if client.streaming is None:
            client.streaming = asyncio.get_running_loop().create_task(self._stream(client, float(rate)))
        return {"rate_hz": rate}


__all__ = ["Endpoint", "return_large_buffers_to_the_os", "short_turns"]
