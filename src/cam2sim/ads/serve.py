"""A separate inference process for the system under test: the policy server.

It speaks the published tool's protocol (``communicator.py``) plus two extensions, defined in
:mod:`cam2sim.ads.wire`, so its model server and ours are interchangeable.

A message that is truncated, longer than the server's ``max_message_bytes``, or not one of the
protocol's forms (an undecodable image, a bad header or JSON) is logged at WARNING, and that
connection is closed; the server keeps serving everyone else.

Served policies see only the image: :class:`~cam2sim.ads.policy.Observation` ``t`` is seconds
since the connection's last reset and ``state`` is all zeros.
"""

from __future__ import annotations

import contextlib
import ipaddress
import json
import logging
import math
import socket
import socketserver
import threading
import time
from dataclasses import dataclass
from typing import TYPE_CHECKING, Final, Self, cast

from cam2sim.ads.policy import Observation, SteeringPolicy, load_policy
from cam2sim.ads.wire import (
    CONTROL_MAGIC,
    RAW_HEADER_BYTES,
    ProtocolError,
    check_smoothing,
    decode_image,
    frame,
    recv_message,
)
from cam2sim.core.errors import ConfigError, StageError
from cam2sim.core.vehicle import SteeringCalibration, VehicleState

if TYPE_CHECKING:
    from collections.abc import Callable
    from types import TracebackType


__all__ = [
    "DEFAULT_MAX_MESSAGE_BYTES",
    "DEFAULT_PORT",
    "PolicyServer",
    "serve",
]

_log = logging.getLogger(__name__)

DEFAULT_PORT: Final = 5090
"""The published server's port (:func:`serve`'s default)."""
DEFAULT_MAX_MESSAGE_BYTES: Final = 16 << 20
"""Largest request payload a server accepts, bytes (16 MiB)."""
_LOOPBACK_NAMES: Final = frozenset({"localhost"})
_ZERO_STATE: Final = VehicleState(0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, (0.0, 0.0))


# --------------------------------------------------------------------------------------------
# Server


@dataclass(slots=True)
class _Session:
    """Per-connection state."""

    policy: SteeringPolicy
    lock: threading.Lock | None
    owned: bool
    smoothing: float | None = None
    ema: float | None = None
    t0: float = 0.0


class _Server(socketserver.ThreadingTCPServer):
    allow_reuse_address = True
    daemon_threads = False
    block_on_close = True

    def __init__(self, address: tuple[str, int], owner: PolicyServer) -> None:
        self.owner = owner
        family = socket.AF_INET6 if ":" in address[0] else socket.AF_INET
        self.address_family = family
        super().__init__(address, _Handler)


class _Handler(socketserver.BaseRequestHandler):
    def handle(self) -> None:
        owner = cast("_Server", self.server).owner
        owner._serve_connection(cast("socket.socket", self.request), self.client_address)  # noqa: SLF001


class PolicyServer:
    """Serves a steering policy over the wire protocol (module doc), many clients at once.

    Binds on construction (``port=0`` picks a free port; read :attr:`port`). :meth:`start`
    serves in a background thread, :meth:`serve_forever` in the calling one; :meth:`close` (or
    leaving the ``with`` block) stops serving, drops every open connection and waits for their
    threads. Each connection runs in its own thread with its own smoothing state.

    Args:
        policy: A policy, shared by all connections behind a lock (it is not closed: it belongs
            to the caller), or a zero-argument factory called once per connection (that
            policy is closed with its connection).
        host: Interface to bind; the default serves this machine only.
        port: TCP port; 0 picks a free one.
        max_message_bytes: Largest request payload; a longer one closes its connection.
        clip: Steering limit ``|s| <= clip`` applied to replies (9.0: the published server).
        throttle: Throttle replied when the policy has no ``predict_controls``.
        allow_remote: Bind a non-loopback ``host`` (anyone who reaches it may use the policy).
    """

    def __init__(
        self,
        policy: SteeringPolicy | Callable[[], SteeringPolicy],
        host: str = "127.0.0.1",
        port: int = 0,
        *,
        max_message_bytes: int = DEFAULT_MAX_MESSAGE_BYTES,
        clip: float | None = None,
        throttle: float = 0.0,
        allow_remote: bool = False,
    ) -> None:
        if not allow_remote and not _is_loopback(host):
            msg = (
                f"refusing to serve the policy on {host!r}, which is not a loopback address; "
                "pass allow_remote=True (cam2sim ads serve --allow-remote) to expose it"
            )
            raise ConfigError(msg)
        if max_message_bytes < RAW_HEADER_BYTES:
            msg = f"max_message_bytes must be at least {RAW_HEADER_BYTES}, got {max_message_bytes}"
            raise ConfigError(msg)
        if clip is not None and not (math.isfinite(clip) and clip > 0):
            msg = f"clip must be a positive finite steering limit or None, got {clip!r}"
            raise ConfigError(msg)
        if isinstance(policy, SteeringPolicy) and not isinstance(policy, type):
            self._shared: SteeringPolicy | None = policy
            self._factory: Callable[[], SteeringPolicy] | None = None
        else:
            self._shared, self._factory = None, policy
        self.host = host
        self.max_message_bytes = int(max_message_bytes)
        self.clip = clip
        self.throttle = float(throttle)
        self._lock = threading.Lock()
        self._shared_lock = threading.Lock()
        self._serving = 0
        self._open: set[socket.socket] = set()
        self._closing = threading.Event()
        self._thread: threading.Thread | None = None
        try:
            self._server = _Server((host, port), self)
        except OSError as err:
            msg = f"cannot serve the policy on {host}:{port} ({err}); choose another port"
            raise StageError(msg) from err

    @property
    def port(self) -> int:
        """The bound TCP port."""
        return int(self._server.server_address[1])

    @property
    def address(self) -> str:
        """``tcp://HOST:PORT``, the spec a :class:`~cam2sim.ads.policy.RemotePolicy` takes."""
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"tcp://{host}:{self.port}"

    def start(self) -> Self:
        """Serve in a background thread; returns self."""
        if self._thread is None:
            self._thread = threading.Thread(
                target=self.serve_forever, name=f"policy-server-{self.port}"
            )
            self._thread.start()
        return self

    def serve_forever(self) -> None:
        """Serve in the calling thread until :meth:`close` (from another thread) or Ctrl-C."""
        with self._lock:
            if self._closing.is_set():
                return
            self._serving += 1
        try:
            self._server.serve_forever(0.1)
        finally:
            with self._lock:
                self._serving -= 1

    def close(self) -> None:
        """Stop serving, drop every open connection, wait for their threads."""
        if self._closing.is_set():
            return
        with self._lock:
            self._closing.set()
            serving = self._serving > 0
        if serving:
            self._server.shutdown()  # returns once serve_forever has stopped
        if self._thread is not None:
            self._thread.join()
            self._thread = None
        with self._lock:
            for sock in self._open:
                with contextlib.suppress(OSError):
                    sock.shutdown(socket.SHUT_RDWR)
        self._server.server_close()  # joins the connection threads

    def __enter__(self) -> Self:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()

    # -- one connection ------------------------------------------------------------------------

    def _serve_connection(self, sock: socket.socket, peer: tuple[str, int]) -> None:
        with self._lock:
            if self._closing.is_set():
                return
            self._open.add(sock)
        session: _Session | None = None
        try:
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            session = self._session()
            while (reply := self._answer(sock, session)) is not None:
                sock.sendall(frame(reply))
        except ProtocolError as err:
            if not self._closing.is_set():
                _log.warning("policy server: closing the connection from %s: %s", peer, err)
        except OSError as err:
            if not self._closing.is_set():
                _log.info("policy server: connection from %s lost (%s)", peer, err)
        except Exception:  # noqa: BLE001  (a bad client never takes the server down)
            _log.exception("policy server: closing the connection from %s", peer)
        finally:
            with self._lock:
                self._open.discard(sock)
            if session is not None and session.owned:
                session.policy.close()

    def _session(self) -> _Session:
        if self._factory is not None:
            return _Session(self._factory(), None, owned=True, t0=time.monotonic())
        policy = cast("SteeringPolicy", self._shared)
        return _Session(policy, self._shared_lock, owned=False, t0=time.monotonic())

    def _answer(self, sock: socket.socket, session: _Session) -> bytes | None:
        payload = recv_message(sock, self.max_message_bytes)
        if payload is None:
            return None
        if payload.startswith(CONTROL_MAGIC):
            self._control(session, payload[len(CONTROL_MAGIC) :])
            return b"ok"
        image = decode_image(payload)
        obs = Observation(time.monotonic() - session.t0, image, _ZERO_STATE)
        try:
            steering, throttle = self._predict(session, obs)
        except Exception as err:  # noqa: BLE001  (any policy failure goes back to the client)
            _log.warning("policy server: %s failed: %s", session.policy.name, err)
            return f"error: {type(err).__name__}: {err}".encode()
        if session.smoothing is not None and session.ema is not None:
            steering = session.smoothing * session.ema + (1.0 - session.smoothing) * steering
        session.ema = steering
        if self.clip is not None:
            steering = min(max(steering, -self.clip), self.clip)
        return f"{steering!r},{throttle!r}".encode()

    def _predict(self, session: _Session, obs: Observation) -> tuple[float, float]:
        controls = getattr(session.policy, "predict_controls", None)
        with session.lock or contextlib.nullcontext():
            if callable(controls):
                s, t = controls(obs)
                return float(s), float(t)
            return float(session.policy.predict(obs)), self.throttle

    @staticmethod
    def _control(session: _Session, body: bytes) -> None:
        try:
            data = json.loads(body)
        except (UnicodeDecodeError, json.JSONDecodeError) as err:
            msg = f"control message is not UTF-8 JSON ({err})"
            raise ProtocolError(msg) from err
        if not isinstance(data, dict) or not set(data) <= {"reset", "smoothing"}:
            msg = f"control message {data!r} must be an object with 'reset' and/or 'smoothing'"
            raise ProtocolError(msg)
        if "smoothing" in data:
            try:
                value = data["smoothing"]
                session.smoothing = None if value is None else check_smoothing(value)
            except ConfigError as err:
                raise ProtocolError(str(err)) from err
        if data.get("reset") is True:
            session.ema, session.t0 = None, time.monotonic()
            if session.owned:
                session.policy.reset()


def _is_loopback(host: str) -> bool:
    if host in _LOOPBACK_NAMES:
        return True
    try:
        return ipaddress.ip_address(host.strip("[]")).is_loopback
    except ValueError:
        return False


def serve(
    source: SteeringPolicy | Callable[[], SteeringPolicy] | str,
    *,
    host: str = "127.0.0.1",
    port: int = DEFAULT_PORT,
    allow_remote: bool = False,
    max_message_bytes: int = DEFAULT_MAX_MESSAGE_BYTES,
    clip: float | None = None,
    throttle: float = 0.0,
    on_ready: Callable[[PolicyServer], None] | None = None,
) -> None:
    """Serve a policy in this thread until interrupted (Ctrl-C) or ``server.close()``.

    Args:
        source: A policy (shared), a per-connection factory, or a policy spec such as a model
            file or ``constant:VALUE`` (loaded once and shared; see
            :func:`~cam2sim.ads.policy.load_policy`).
        host: Interface to bind (loopback unless ``allow_remote``).
        port: TCP port (default: the published server's 5090; 0 picks a free one).
        allow_remote: Allow a non-loopback ``host``.
        max_message_bytes: Largest request payload.
        clip: Steering limit of replies (None: no clip).
        throttle: Throttle replied for policies without one.
        on_ready: Called with the bound server before serving starts (e.g. to print its port).
    """
    owned = isinstance(source, str)
    policy = (
        load_policy(source, route_xy=None, wheelbase_m=1.0, calibration=SteeringCalibration())
        if isinstance(source, str)
        else source
    )
    try:
        with PolicyServer(
            policy,
            host,
            port,
            max_message_bytes=max_message_bytes,
            clip=clip,
            throttle=throttle,
            allow_remote=allow_remote,
        ) as server:
            _log.info("serving a steering policy on %s", server.address)
            if on_ready is not None:
                on_ready(server)
            with contextlib.suppress(KeyboardInterrupt):
                server.serve_forever()
    finally:
        if owned:
            cast("SteeringPolicy", policy).close()
