"""The policy server's wire protocol: framing, request images, control messages, replies.

The protocol is the published tool's (``communicator.py``), so its model server and ours are
interchangeable, plus two extensions that a published client never sends. Both ends use this
module: the server (:mod:`cam2sim.ads.serve`) and the client
(:class:`~cam2sim.ads.policy.RemotePolicy`).

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
"""

from __future__ import annotations

import json
import struct
from typing import TYPE_CHECKING, Final, Literal

import numpy as np

from cam2sim.core.errors import ConfigError, StageError

if TYPE_CHECKING:
    import socket

    import numpy.typing as npt

__all__ = [
    "CONTROL_MAGIC",
    "ENCODINGS",
    "JPEG_QUALITY",
    "RAW_HEADER_BYTES",
    "RAW_MAGIC",
    "Encoding",
    "ProtocolError",
    "check_smoothing",
    "control_message",
    "decode_image",
    "encode_image",
    "frame",
    "parse_reply",
    "recv_message",
]

Encoding = Literal["png", "jpeg", "raw"]
"""Request image encodings: ``png`` and ``raw`` are lossless, ``jpeg`` is the published one."""
ENCODINGS: Final[tuple[str, ...]] = ("png", "jpeg", "raw")

RAW_MAGIC: Final = b"C2SR"
CONTROL_MAGIC: Final = b"C2SC"
JPEG_QUALITY: Final = 75
"""JPEG quality of requests (PIL's default, what the published client sends)."""

_LENGTH: Final = struct.Struct(">I")
_RAW: Final = struct.Struct(">4sHHB")
RAW_HEADER_BYTES: Final = _RAW.size
"""Size of a raw request's header, bytes (the smallest well-formed request)."""
_JPEG_MAGIC: Final = b"\xff\xd8\xff"
_PNG_MAGIC: Final = b"\x89PNG\r\n\x1a\n"
_PNG_SIZE: Final = struct.Struct(">II")  # IHDR width, height at bytes 16..24
_MAX_PIXELS: Final = 1 << 26
"""Largest decoded image, pixels (a small PNG may declare a huge one)."""


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
        body["smoothing"] = check_smoothing(smoothing)
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


def check_smoothing(value: object) -> float:
    """``value`` as an EMA smoothing factor in ``[0, 1)``.

    Raises:
        ConfigError: It is not a number in ``[0, 1)``.
    """
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not 0 <= value < 1:
        msg = f"smoothing must be a number in [0, 1) (0.85: the published server), got {value!r}"
        raise ConfigError(msg)
    return float(value)
