"""A separate inference process for the system under test: the wire protocol and the server.

The protocol is the published tool's (``communicator.py``), so its model server and ours are
interchangeable, plus two extensions that a published client never sends.

Framing, both directions: a 4-byte big-endian unsigned length, then that many payload bytes.
One connection carries any number of request/reply pairs, in order; closing it ends the session.

Request payloads (recognised by their first bytes):

- JPEG (``FF D8 FF``) or PNG (``89 50 4E 47 0D 0A 1A 0A``): an encoded RGB image, decoded with
  ``cv2.imdecode`` (the published client sends JPEG, quality 75). PNG is lossless.
- Raw (lossless, no codec cost): :data:`RAW_MAGIC` ``b"C2SR"``, uint16 width, uint16 height,
  uint8 channels (always 3), all big-endian (9 bytes), then ``height * width * 3`` bytes of
  row-major RGB. ``C`` cannot start a JPEG or a PNG, so neither is ever taken for it.
- Control (per-connection state): :data:`CONTROL_MAGIC` ``b"C2SC"`` then a UTF-8 JSON object
  with any of ``"reset": true`` (forget the smoothing state, and reset the connection's own
  policy when the server builds one per connection) and ``"smoothing": A`` (an EMA factor in
  ``[0, 1)``, or ``null`` for none). Smoothing is off on every new connection. Reply: ``ok``.

Reply payload: UTF-8 ``"<steering>,<throttle>"`` (Python ``repr`` of the floats, so values
round-trip exactly). Throttle is the policy's when it has a ``predict_controls(obs) ->
(steering, throttle)`` method, else the server's constant. With smoothing ``A`` the steering is
``s_t = A * s_{t-1} + (1 - A) * p_t`` (the first prediction after a reset is not smoothed), then
clipped to ``[-clip, clip]`` when the server has a clip (the published server: ``A = 0.85``,
clip 9, one EMA for its whole life). When the policy fails on a well-formed image the reply is
``"error: <message>"`` and the connection stays open.

A message that is truncated, longer than the server's ``max_message_bytes``, or not one of the
forms above (an undecodable image, a bad header or JSON) is logged at WARNING, and that
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
import struct
import threading
import time
from dataclasses import dataclass
from typing import TYPE_CHECKING, Final, Literal, Self, cast

import numpy as np

from cam2sim.ads.policy import Observation, SteeringPolicy, load_policy
from cam2sim.core.errors import ConfigError, StageError
from cam2sim.core.vehicle import SteeringCalibration, VehicleState

if TYPE_CHECKING:
    from collections.abc import Callable
    from types import TracebackType

    import numpy.typing as npt

__all__ = [
    "CONTROL_MAGIC",
    "DEFAULT_MAX_MESSAGE_BYTES",
    "DEFAULT_PORT",
    "ENCODINGS",
    "RAW_MAGIC",
    "Encoding",
    "PolicyServer",
    "ProtocolError",
    "control_message",
    "decode_image",
    "encode_image",
    "frame",
    "parse_reply",
    "recv_message",
    "serve",
]

_log = logging.getLogger(__name__)

Encoding = Literal["png", "jpeg", "raw"]
"""Request image encodings: ``png`` and ``raw`` are lossless, ``jpeg`` is the published one."""
ENCODINGS: Final[tuple[str, ...]] = ("png", "jpeg", "raw")

DEFAULT_PORT: Final = 5090
"""The published server's port (:func:`serve`'s default)."""
DEFAULT_MAX_MESSAGE_BYTES: Final = 16 << 20
"""Largest request payload a server accepts, bytes (16 MiB)."""
RAW_MAGIC: Final = b"C2SR"
CONTROL_MAGIC: Final = b"C2SC"
JPEG_QUALITY: Final = 75
"""JPEG quality of requests (PIL's default, what the published client sends)."""

_LENGTH: Final = struct.Struct(">I")
_RAW: Final = struct.Struct(">4sHHB")
_JPEG_MAGIC: Final = b"\xff\xd8\xff"
_PNG_MAGIC: Final = b"\x89PNG\r\n\x1a\n"
_PNG_SIZE: Final = struct.Struct(">II")  # IHDR width, height at bytes 16..24
_MAX_PIXELS: Final = 1 << 26
"""Largest decoded image, pixels (a small PNG may declare a huge one)."""
_LOOPBACK_NAMES: Final = frozenset({"localhost"})
_ZERO_STATE: Final = VehicleState(0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, (0.0, 0.0))


class ProtocolError(StageError):
    """A message breaks the wire protocol (truncated, oversized or malformed)."""


# --------------------------------------------------------------------------------------------
# Wire format


def frame(payload: bytes) -> bytes:
    """``payload`` with its 4-byte big-endian length in front."""
    return _LENGTH.pack(len(payload)) + payload


def _recv_exact(sock: socket.socket, n: int) -> bytes:
    buf = bytearray(n)
    view, got = memoryview(buf), 0
    while got < n:
        k = sock.recv_into(view[got:], n - got)
        if k == 0:
            msg = f"connection closed after {got} of {n} bytes of a message"
            raise ProtocolError(msg)
        got += k
    return bytes(buf)


def recv_message(sock: socket.socket, limit: int) -> bytes | None:
    """The next payload from ``sock``; None when the peer closed between messages.

    Raises:
        ProtocolError: The message is truncated or longer than ``limit`` bytes.
        TimeoutError: The socket's timeout ran out.
    """
    first = sock.recv(_LENGTH.size)
    if not first:
        return None
    head = first + (_recv_exact(sock, _LENGTH.size - len(first)) if len(first) < 4 else b"")
    (n,) = _LENGTH.unpack(head)
    if n > limit:
        msg = f"message of {n} bytes exceeds the limit of {limit}"
        raise ProtocolError(msg)
    return _recv_exact(sock, n)


def encode_image(image: npt.NDArray[np.uint8], encoding: Encoding) -> bytes:
    """The request payload for an ``(H, W, 3)`` uint8 RGB ``image``."""
    img = np.asarray(image)
    if img.ndim != 3 or img.shape[2] != 3 or img.dtype != np.uint8 or min(img.shape[:2]) < 1:
        msg = f"image must be (H, W, 3) uint8 RGB; got {img.dtype} {img.shape}"
        raise ValueError(msg)
    if encoding not in ENCODINGS:
        msg = f"unknown image encoding {encoding!r}; use one of {', '.join(ENCODINGS)}"
        raise ConfigError(msg)
    h, w = img.shape[:2]
    if encoding == "raw":
        if max(h, w) > 0xFFFF:
            msg = f"raw requests carry at most 65535x65535 pixels, got {w}x{h}"
            raise ValueError(msg)
        return _RAW.pack(RAW_MAGIC, w, h, 3) + np.ascontiguousarray(img).tobytes()
    import cv2  # noqa: PLC0415  (heavy; only codecs need it)

    bgr = cv2.cvtColor(img, cv2.COLOR_RGB2BGR)
    if encoding == "png":
        ok, buf = cv2.imencode(".png", bgr, [cv2.IMWRITE_PNG_COMPRESSION, 0])  # speed
    else:
        ok, buf = cv2.imencode(".jpg", bgr, [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])
    if not ok:
        msg = f"cannot encode a {w}x{h} image as {encoding}"
        raise ValueError(msg)
    return bytes(buf)


def decode_image(payload: bytes) -> npt.NDArray[np.uint8]:
    """The ``(H, W, 3)`` uint8 RGB image of a JPEG, PNG or raw request payload.

    Raises:
        ProtocolError: The payload is none of them, or does not decode.
    """
    if payload.startswith(RAW_MAGIC):
        if len(payload) < _RAW.size:
            msg = f"raw image header of {len(payload)} bytes, expected {_RAW.size}"
            raise ProtocolError(msg)
        _, w, h, c = _RAW.unpack_from(payload)
        if c != 3 or w * h == 0 or len(payload) != _RAW.size + w * h * 3:
            msg = (
                f"raw image header says {w}x{h}x{c} but {len(payload) - _RAW.size} pixel bytes "
                "follow (expected width*height*3, channels 3)"
            )
            raise ProtocolError(msg)
        return np.frombuffer(payload, np.uint8, offset=_RAW.size).reshape(h, w, 3)
    if payload.startswith(_PNG_MAGIC) and len(payload) >= 24:
        w, h = _PNG_SIZE.unpack_from(payload, 16)
        if w * h > _MAX_PIXELS:
            msg = f"PNG of {w}x{h} pixels exceeds the limit of {_MAX_PIXELS}"
            raise ProtocolError(msg)
    elif not payload.startswith(_JPEG_MAGIC):
        msg = f"payload starting {payload[:8]!r} is not a JPEG, PNG, raw or control message"
        raise ProtocolError(msg)
    import cv2  # noqa: PLC0415  (heavy; only codecs need it)

    bgr = cv2.imdecode(np.frombuffer(payload, np.uint8), cv2.IMREAD_COLOR)
    if bgr is None:
        msg = f"the {len(payload)}-byte image does not decode"
        raise ProtocolError(msg)
    return np.asarray(cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB), dtype=np.uint8)


def control_message(*, reset: bool = False, smoothing: float | None = None) -> bytes:
    """A control payload: ``reset`` and/or set ``smoothing`` (None: leave it as it is)."""
    body: dict[str, object] = {}
    if reset:
        body["reset"] = True
    if smoothing is not None:
        body["smoothing"] = _check_smoothing(smoothing)
    return CONTROL_MAGIC + json.dumps(body).encode()


def parse_reply(payload: bytes) -> tuple[float, float]:
    """``(steering, throttle)`` of a reply.

    Raises:
        ProtocolError: The reply is an ``error:`` or not two comma-separated numbers.
    """
    text = payload.decode("utf-8", errors="replace")
    if text.startswith("error:"):
        msg = f"the policy server failed: {text.removeprefix('error:').strip()}"
        raise ProtocolError(msg)
    parts = text.split(",")
    try:
        if len(parts) == 2:
            return float(parts[0]), float(parts[1])
    except ValueError:
        pass
    msg = f"reply {text[:80]!r} is not 'steering,throttle'"
    raise ProtocolError(msg)


def _check_smoothing(value: object) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not 0 <= value < 1:
        msg = f"smoothing must be a number in [0, 1) (0.85: the published server), got {value!r}"
        raise ConfigError(msg)
    return float(value)


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
        if max_message_bytes < _RAW.size:
            msg = f"max_message_bytes must be at least {_RAW.size}, got {max_message_bytes}"
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
                session.smoothing = None if value is None else _check_smoothing(value)
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
