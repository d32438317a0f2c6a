"""Decode and encode camera images as ROS ``sensor_msgs`` carry them.

:func:`decode_image` turns a raw ``sensor_msgs/Image`` (as deserialised by rosbags) into an
RGB ``(H, W, 3) uint8`` array, or a ``(H, W)`` mono array; :func:`decode_compressed_image` does the
same for ``sensor_msgs/CompressedImage``. The ``*_fields`` functions are the inverses: they build
the message fields from an array, for writing test bags and the demo recording.
:func:`encode_image_file` encodes a frame for writing to disk.

Conventions follow ``cv_bridge``: ``yuv422`` is UYVY byte order, ``yuv422_yuy2`` is YUYV, both
BT.601 limited ("video") range unless ``yuv_range="full"`` is given; Bayer patterns are named by the
colour of the top-left 2x2 block, row by row (``bayer_rggb8``: R at (0, 0), B at (1, 1)).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Final, Literal, TypedDict, cast

import cv2
import numpy as np

from cam2sim.core.errors import RecordingError

if TYPE_CHECKING:
    import numpy.typing as npt

__all__ = [
    "SUPPORTED_ENCODINGS",
    "CompressedImageFields",
    "ImageFields",
    "YuvRange",
    "compressed_image_fields",
    "decode_compressed_image",
    "decode_image",
    "encode_image_file",
    "image_message_fields",
]

YuvRange = Literal["limited", "full"]
"""YUV sample quantisation: ``limited`` is BT.601 video range (Y 16-235), as cv_bridge assumes."""


class ImageFields(TypedDict):
    """Fields of a ``sensor_msgs/Image`` (without ``header``); ``data`` is 1-D uint8."""

    height: int
    width: int
    encoding: str
    is_bigendian: int
    step: int
    data: npt.NDArray[np.uint8]


class CompressedImageFields(TypedDict):
    """Fields of a ``sensor_msgs/CompressedImage`` (without ``header``); ``data`` is 1-D uint8."""

    format: str
    data: npt.NDArray[np.uint8]


@dataclass(frozen=True)
class _Layout:
    """How one raw encoding lays out a pixel."""

    kind: Literal["colour", "mono", "bayer", "yuv"]
    bytes_per_pixel: int
    channels: tuple[int, ...] = ()  # colour: byte index of R, G, B inside a pixel
    pattern: str = ""  # bayer: colours of the 2x2 block, row-major; yuv: byte order


_LAYOUTS: Final[dict[str, _Layout]] = {
    "rgb8": _Layout("colour", 3, (0, 1, 2)),
    "bgr8": _Layout("colour", 3, (2, 1, 0)),
    "8UC3": _Layout("colour", 3, (2, 1, 0)),
    "rgba8": _Layout("colour", 4, (0, 1, 2)),
    "bgra8": _Layout("colour", 4, (2, 1, 0)),
    "mono8": _Layout("mono", 1),
    "8UC1": _Layout("mono", 1),
    "mono16": _Layout("mono", 2),
    "16UC1": _Layout("mono", 2),
    "bayer_rggb8": _Layout("bayer", 1, pattern="rggb"),
    "bayer_bggr8": _Layout("bayer", 1, pattern="bggr"),
    "bayer_gbrg8": _Layout("bayer", 1, pattern="gbrg"),
    "bayer_grbg8": _Layout("bayer", 1, pattern="grbg"),
    "yuv422": _Layout("yuv", 2, pattern="uyvy"),
    "uyvy": _Layout("yuv", 2, pattern="uyvy"),
    "yuv422_yuy2": _Layout("yuv", 2, pattern="yuyv"),
    "yuyv": _Layout("yuv", 2, pattern="yuyv"),
}
_BY_LOWER: Final = {name.lower(): name for name in _LAYOUTS}

SUPPORTED_ENCODINGS: Final[tuple[str, ...]] = tuple(sorted(_LAYOUTS))
"""Raw ``sensor_msgs/Image`` encodings that :func:`decode_image` understands."""

# OpenCV's two-letter Bayer names describe the 2x2 block starting at (1, 1), ROS names the one at
# (0, 0), so bayer_rggb8 is OpenCV's "BG". The values are the same in OpenCV 4 and 5; the mapping is
# proven by decoding flat-colour mosaics in tests/recording/test_image.py.
_BAYER_TO_RGB: Final = {
    "rggb": cv2.COLOR_BayerBG2RGB,
    "bggr": cv2.COLOR_BayerRG2RGB,
    "gbrg": cv2.COLOR_BayerGR2RGB,
    "grbg": cv2.COLOR_BayerGB2RGB,
}
_YUV_TO_RGB: Final = {"uyvy": cv2.COLOR_YUV2RGB_UYVY, "yuyv": cv2.COLOR_YUV2RGB_YUYV}
_CHANNEL: Final = {"r": 0, "g": 1, "b": 2}
# Byte positions of U, Y0, V, Y1 inside one 4-byte pixel pair.
_YUV_POSITIONS: Final = {"uyvy": (0, 1, 2, 3), "yuyv": (1, 0, 3, 2)}

# BT.601 luma weights and chroma scales (R', G', B' and Y' in 0..255).
_KR, _KB = 0.299, 0.114
_KG = 1.0 - _KR - _KB
_PNG_MAGIC: Final = b"\x89PNG"


def _check_yuv_range(yuv_range: str) -> None:
    """Raise unless ``yuv_range`` is a :data:`YuvRange`."""
    if yuv_range not in {"limited", "full"}:
        msg = f"yuv_range must be 'limited' or 'full', got {yuv_range!r}."
        raise RecordingError(msg)


def _layout_for(encoding: str) -> tuple[str, _Layout]:
    """Return the canonical name and layout of ``encoding``, or raise listing what is known."""
    name = _BY_LOWER.get(encoding.strip().lower())
    if name is None:
        msg = (
            f"image encoding {encoding!r} is not supported; supported encodings are "
            f"{', '.join(SUPPORTED_ENCODINGS)}. Convert the topic to one of these (e.g. with "
            "image_proc) or open an issue asking for it."
        )
        raise RecordingError(msg)
    return name, _LAYOUTS[name]


def _pixel_rows(msg: Any, layout: _Layout, encoding: str) -> npt.NDArray[np.uint8]:
    """Return the ``(H, W, bytes_per_pixel)`` pixel bytes of ``msg`` without the row padding."""
    height, width, step = int(msg.height), int(msg.width), int(msg.step)
    data = np.frombuffer(msg.data, dtype=np.uint8)
    row_bytes = width * layout.bytes_per_pixel
    if height <= 0 or width <= 0:
        msg_ = f"image message is empty ({width}x{height} {encoding}); drop it from the topic."
        raise RecordingError(msg_)
    if step < row_bytes or data.size < step * height:
        msg_ = (
            f"image message is truncated or corrupt: {width}x{height} {encoding} needs step >= "
            f"{row_bytes} and at least step*height bytes, got step={step} and {data.size} bytes "
            f"(need {step * height}). Check the recording or drop the damaged message."
        )
        raise RecordingError(msg_)
    rows = data[: step * height].reshape(height, step)[:, :row_bytes]
    return rows.reshape(height, width, layout.bytes_per_pixel)


def decode_image(
    msg: Any,  # rosbags message classes are generated at runtime; read by attribute
    *,
    yuv_range: YuvRange = "limited",
) -> npt.NDArray[np.uint8] | npt.NDArray[np.uint16]:
    """Decode a raw ``sensor_msgs/Image`` into an RGB or mono array.

    Args:
        msg: A deserialised ``sensor_msgs/Image`` (needs ``height``, ``width``, ``encoding``,
            ``is_bigendian``, ``step`` and ``data``). Row padding (``step`` beyond the pixels) is
            skipped.
        yuv_range: Quantisation of ``yuv422``/``yuv422_yuy2`` data; ``limited`` matches cv_bridge.

    Returns:
        ``(H, W, 3) uint8`` RGB for colour, Bayer and YUV encodings (alpha dropped); ``(H, W)``
        uint8 for ``mono8``; ``(H, W)`` native-endian uint16 for ``mono16``/``16UC1``.

    Raises:
        RecordingError: The encoding is not in :data:`SUPPORTED_ENCODINGS`, or the data is shorter
            than the header promises.
    """
    name, layout = _layout_for(str(msg.encoding))
    pixels = _pixel_rows(msg, layout, name)
    if layout.kind == "colour":
        identity = tuple(layout.channels) == tuple(range(pixels.shape[2]))
        # rgb8 needs no reordering: no copy when the rows are already contiguous.
        return np.ascontiguousarray(pixels if identity else pixels[:, :, layout.channels])
    if layout.kind == "mono" and layout.bytes_per_pixel == 1:
        return pixels[:, :, 0].copy()
    if layout.kind == "mono":
        order = ">" if msg.is_bigendian else "<"
        return np.ascontiguousarray(pixels).view(f"{order}u2")[:, :, 0].astype(np.uint16)
    if layout.kind == "bayer":
        mosaic = np.ascontiguousarray(pixels[:, :, 0])
        return np.asarray(cv2.cvtColor(mosaic, _BAYER_TO_RGB[layout.pattern]), dtype=np.uint8)
    if pixels.shape[1] % 2:
        msg_ = (
            f"{name} image has odd width {pixels.shape[1]}, but YUV 4:2:2 needs an even width; "
            "the message is corrupt. Check the camera driver's output settings."
        )
        raise RecordingError(msg_)
    _check_yuv_range(yuv_range)
    if yuv_range == "limited":
        packed = np.ascontiguousarray(pixels)
        return np.asarray(cv2.cvtColor(packed, _YUV_TO_RGB[layout.pattern]), dtype=np.uint8)
    return _yuv_full_to_rgb(pixels, layout.pattern)


def _yuv_full_to_rgb(pixels: npt.NDArray[np.uint8], order: str) -> npt.NDArray[np.uint8]:
    """Convert ``(H, W, 2)`` full-range UYVY/YUYV bytes to ``(H, W, 3)`` RGB (BT.601)."""
    height, width = pixels.shape[:2]
    quads = pixels.reshape(height, width // 2, 4).astype(np.float32)
    u, y0, v, y1 = (quads[..., i] for i in _YUV_POSITIONS[order])
    luma = np.stack((y0, y1), axis=-1).reshape(height, width)
    cb = np.repeat(u - 128.0, 2, axis=1)
    cr = np.repeat(v - 128.0, 2, axis=1)
    rgb = np.stack(
        (
            luma + 2 * (1 - _KR) * cr,
            luma - (2 * _KB * (1 - _KB) * cb + 2 * _KR * (1 - _KR) * cr) / _KG,
            luma + 2 * (1 - _KB) * cb,
        ),
        axis=-1,
    )
    return np.clip(np.rint(rgb), 0, 255).astype(np.uint8)


def _rgb_to_yuv422(
    rgb: npt.NDArray[np.uint8], order: str, yuv_range: YuvRange
) -> npt.NDArray[np.uint8]:
    """Convert ``(H, W, 3)`` RGB to ``(H, W, 2)`` UYVY/YUYV bytes, averaging chroma over pairs."""
    height, width = rgb.shape[:2]
    r, g, b = (rgb[..., i].astype(np.float64) for i in range(3))
    luma = _KR * r + _KG * g + _KB * b
    cb = (b - luma) / (2 * (1 - _KB))
    cr = (r - luma) / (2 * (1 - _KR))
    cb = (cb[:, 0::2] + cb[:, 1::2]) / 2
    cr = (cr[:, 0::2] + cr[:, 1::2]) / 2
    if yuv_range == "limited":
        luma, cb, cr = 16 + luma * (219 / 255), cb * (224 / 255), cr * (224 / 255)
    pairs = luma.reshape(height, width // 2, 2)
    quads = np.empty((height, width // 2, 4), dtype=np.float64)
    quads[..., list(_YUV_POSITIONS[order])] = np.stack(
        (cb + 128, pairs[..., 0], cr + 128, pairs[..., 1]), axis=-1
    )
    return np.clip(np.rint(quads), 0, 255).astype(np.uint8).reshape(height, width, 2)


def _check_image(
    image: npt.NDArray[np.generic], *, mono: bool, dtype: type[np.generic], what: str
) -> None:
    """Raise unless ``image`` is ``(H, W)`` (mono) or ``(H, W, 3)`` with ``dtype``."""
    shape_ok = image.ndim == 2 if mono else image.ndim == 3 and image.shape[2] == 3
    if not shape_ok or image.dtype != dtype or image.size == 0:
        want = "(H, W)" if mono else "(H, W, 3) RGB"
        msg = (
            f"{what} needs a non-empty {want} {np.dtype(dtype).name} array, got shape "
            f"{image.shape} {image.dtype}; convert the image first."
        )
        raise RecordingError(msg)


def image_message_fields(
    image: npt.NDArray[np.uint8] | npt.NDArray[np.uint16],
    encoding: str,
    *,
    row_padding: int = 0,
    is_bigendian: bool = False,
    yuv_range: YuvRange = "limited",
) -> ImageFields:
    """Build ``sensor_msgs/Image`` fields that :func:`decode_image` turns back into ``image``.

    Args:
        image: ``(H, W, 3) uint8`` RGB for colour, Bayer and YUV encodings; ``(H, W) uint8`` for
            ``mono8``/``8UC1``; ``(H, W) uint16`` for ``mono16``/``16UC1``.
        encoding: Target encoding, one of :data:`SUPPORTED_ENCODINGS`. Bayer encodings keep one
            channel per pixel; YUV encodings average chroma over horizontal pixel pairs.
        row_padding: Zero bytes appended to every row (``step = width * bpp + row_padding``).
        is_bigendian: Byte order of 16-bit samples; stored in the message for every encoding.
        yuv_range: Quantisation of YUV samples.

    Returns:
        The message fields; ``data`` is a 1-D uint8 array of ``step * height`` bytes.

    Raises:
        RecordingError: Unknown encoding, an image of the wrong shape or dtype, negative padding,
            or an odd width for a YUV encoding.
    """
    name, layout = _layout_for(encoding)
    is_mono = layout.kind == "mono"
    dtype = np.uint16 if layout.bytes_per_pixel == 2 and is_mono else np.uint8
    _check_image(image, mono=is_mono, dtype=dtype, what=f"encoding {name!r}")
    if row_padding < 0:
        msg = f"row_padding must be >= 0, got {row_padding}."
        raise RecordingError(msg)
    height, width = image.shape[:2]
    if layout.kind == "colour":
        pixels = np.full((height, width, layout.bytes_per_pixel), 255, dtype=np.uint8)
        pixels[:, :, list(layout.channels)] = image
    elif is_mono and dtype == np.uint16:
        swapped = image.astype(">u2" if is_bigendian else "<u2")
        pixels = swapped.view(np.uint8).reshape(height, width, 2)
    elif is_mono:
        pixels = image.reshape(height, width, 1).astype(np.uint8)
    elif layout.kind == "bayer":
        pixels = np.empty((height, width, 1), dtype=np.uint8)
        for i, colour in enumerate(layout.pattern):  # four sites of the 2x2 block
            dy, dx = divmod(i, 2)
            pixels[dy::2, dx::2, 0] = image[dy::2, dx::2, _CHANNEL[colour]]
    else:
        if width % 2:
            msg = f"{name} needs an even image width, got {width}; crop or pad the image."
            raise RecordingError(msg)
        _check_yuv_range(yuv_range)
        pixels = _rgb_to_yuv422(image.astype(np.uint8), layout.pattern, yuv_range)
    step = width * layout.bytes_per_pixel + row_padding
    rows = np.zeros((height, step), dtype=np.uint8)
    rows[:, : width * layout.bytes_per_pixel] = pixels.reshape(height, -1)
    return {
        "height": int(height),
        "width": int(width),
        "encoding": name,
        "is_bigendian": int(is_bigendian),
        "step": int(step),
        "data": rows.reshape(-1),
    }


def decode_compressed_image(
    msg: Any,  # rosbags message classes are generated at runtime; read by attribute
) -> npt.NDArray[np.uint8] | npt.NDArray[np.uint16]:
    """Decode a ``sensor_msgs/CompressedImage`` (JPEG or PNG) into an RGB or mono array.

    Args:
        msg: A deserialised ``sensor_msgs/CompressedImage`` (``format`` and ``data``). The format
            string is informational; the codec is detected from the data. A ``compressedDepth``
            message's 12-byte header is skipped.

    Returns:
        ``(H, W, 3)`` RGB for colour data (alpha dropped), ``(H, W)`` for gray data; uint8, or
        uint16 for 16-bit PNG.

    Raises:
        RecordingError: The data is empty or cannot be decoded.
    """
    fmt = str(msg.format)
    data = np.frombuffer(msg.data, dtype=np.uint8)
    if "compresseddepth" in fmt.lower() and data[:4].tobytes() != _PNG_MAGIC:
        data = data[12:]
    decoded = cv2.imdecode(data, cv2.IMREAD_UNCHANGED) if data.size else None
    if decoded is None:
        msg_ = (
            f"compressed image ({fmt!r}, {data.size} bytes) cannot be decoded; the message is "
            "corrupt or not JPEG/PNG. Check the recording or drop the damaged message."
        )
        raise RecordingError(msg_)
    image = np.asarray(decoded)
    if image.ndim == 3 and image.shape[2] == 1:
        image = image[:, :, 0]
    if image.ndim == 3:
        image = np.ascontiguousarray(image[:, :, 2::-1])  # BGR(A) -> RGB
    if image.dtype == np.uint16:
        return image.astype(np.uint16, copy=False)
    return image.astype(np.uint8, copy=False)


def encode_image_file(
    image: npt.NDArray[np.uint8] | npt.NDArray[np.uint16],
    fmt: Literal["png", "jpeg"],
    *,
    jpeg_quality: int = 95,
) -> bytes:
    """Encode an RGB or mono image as PNG or JPEG file bytes.

    Args:
        image: ``(H, W, 3)`` RGB or ``(H, W)`` mono; uint8, or uint16 for PNG.
        fmt: ``"png"`` (lossless) or ``"jpeg"``.
        jpeg_quality: JPEG quality, 0-100.

    Returns:
        The encoded file contents.

    Raises:
        RecordingError: Wrong shape or dtype, uint16 with JPEG, an unknown format or a failed
            encode.
    """
    if fmt not in {"png", "jpeg"}:
        msg = f"image file format {fmt!r} is not supported; use 'png' or 'jpeg'."
        raise RecordingError(msg)
    if image.dtype == np.uint16 and fmt == "jpeg":
        msg = "JPEG cannot store 16-bit images; use fmt='png' for uint16 images."
        raise RecordingError(msg)
    is_mono = image.ndim == 2
    _check_image(image, mono=is_mono, dtype=image.dtype.type, what=f"{fmt} encoding")
    if image.dtype not in {np.dtype(np.uint8), np.dtype(np.uint16)}:
        msg = f"{fmt} encoding needs uint8 or uint16 pixels, got {image.dtype}; convert first."
        raise RecordingError(msg)
    bgr = cast(
        "npt.NDArray[np.uint8] | npt.NDArray[np.uint16]",
        image if is_mono else cv2.cvtColor(np.ascontiguousarray(image), cv2.COLOR_RGB2BGR),
    )
    params = [cv2.IMWRITE_JPEG_QUALITY, int(jpeg_quality)] if fmt == "jpeg" else []
    ok, buffer = cv2.imencode(".jpg" if fmt == "jpeg" else ".png", bgr, params)
    if not ok:
        msg = f"OpenCV failed to encode a {image.shape} {image.dtype} image as {fmt}."
        raise RecordingError(msg)
    return bytes(np.asarray(buffer, dtype=np.uint8).tobytes())


def compressed_image_fields(
    image: npt.NDArray[np.uint8] | npt.NDArray[np.uint16],
    fmt: Literal["jpeg", "png"] = "jpeg",
    *,
    quality: int = 95,
) -> CompressedImageFields:
    """Build ``sensor_msgs/CompressedImage`` fields, as ``image_transport`` writes them.

    Args:
        image: ``(H, W, 3)`` RGB or ``(H, W)`` mono; uint8, or uint16 mono/RGB for PNG.
        fmt: ``"jpeg"`` or ``"png"``.
        quality: JPEG quality, 0-100 (ignored for PNG).

    Returns:
        ``format`` (e.g. ``"rgb8; jpeg compressed bgr8"``) and ``data`` (1-D uint8).

    Raises:
        RecordingError: See :func:`encode_image_file`.
    """
    encoded = encode_image_file(image, fmt, jpeg_quality=quality)
    bits = 16 if image.dtype == np.uint16 else 8
    source, packed = (
        (f"mono{bits}", f"mono{bits}") if image.ndim == 2 else (f"rgb{bits}", f"bgr{bits}")
    )
    return {
        "format": f"{source}; {fmt} compressed {packed}",
        "data": np.frombuffer(encoded, dtype=np.uint8).copy(),
    }
