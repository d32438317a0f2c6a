from __future__ import annotations

from types import SimpleNamespace
from typing import TYPE_CHECKING, Literal

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from rosbags.typesys import Stores, get_typestore

from cam2sim.core.errors import RecordingError
from cam2sim.recording.image import (
    SUPPORTED_ENCODINGS,
    compressed_image_fields,
    decode_compressed_image,
    decode_image,
    encode_image_file,
    image_message_fields,
)

if TYPE_CHECKING:
    import numpy.typing as npt

COLOUR_ENCODINGS = ["rgb8", "bgr8", "8UC3", "rgba8", "bgra8"]
BAYER_ENCODINGS = ["bayer_rggb8", "bayer_bggr8", "bayer_gbrg8", "bayer_grbg8"]
YUV_ENCODINGS = ["yuv422", "uyvy", "yuv422_yuy2", "yuyv"]
FLAT_COLOURS = [(200, 100, 30), (10, 240, 120), (90, 20, 250), (255, 0, 0), (0, 0, 255), (7, 7, 7)]
KR, KB = 0.299, 0.114
KG = 1 - KR - KB


def rgb_image(height: int = 12, width: int = 16, seed: int = 0) -> npt.NDArray[np.uint8]:
    image: npt.NDArray[np.uint8] = np.random.default_rng(seed).integers(
        0, 256, (height, width, 3), dtype=np.uint8
    )
    return image


def smooth_image(height: int = 64, width: int = 96) -> npt.NDArray[np.uint8]:
    yy, xx = np.mgrid[0:height, 0:width].astype(np.float64)
    planes = (xx / width * 255, yy / height * 255, 128 + 100 * np.sin(xx / 15) * np.cos(yy / 11))
    image: npt.NDArray[np.uint8] = np.clip(np.rint(np.stack(planes, axis=-1)), 0, 255).astype(
        np.uint8
    )
    return image


def message(fields: dict[str, object]) -> SimpleNamespace:
    return SimpleNamespace(**fields)


def psnr(a: npt.NDArray[np.uint8], b: npt.NDArray[np.uint8]) -> float:
    mse = float(np.mean((a.astype(np.float64) - b.astype(np.float64)) ** 2))
    return float(10 * np.log10(255.0**2 / mse))


def bayer_sites(pattern: str) -> list[tuple[int, int, int]]:
    """(dy, dx, channel) of the 2x2 block of a ROS pattern name like 'rggb'."""
    return [(i // 2, i % 2, "rgb".index(c)) for i, c in enumerate(pattern)]


def yuv_reference(
    image: npt.NDArray[np.uint8], yuv_range: Literal["limited", "full"]
) -> npt.NDArray[np.uint8]:
    """BT.601 in float: per-pixel luma, chroma averaged over pixel pairs, no quantisation."""
    rgb = image.astype(np.float64)
    luma = rgb @ np.array([KR, KG, KB])
    cb = (rgb[..., 2] - luma) / (2 * (1 - KB))
    cr = (rgb[..., 0] - luma) / (2 * (1 - KR))
    cb = np.repeat((cb[:, 0::2] + cb[:, 1::2]) / 2, 2, axis=1)
    cr = np.repeat((cr[:, 0::2] + cr[:, 1::2]) / 2, 2, axis=1)
    if yuv_range == "limited":  # quantise like the wire format does, then expand back
        luma = (np.rint(16 + luma * 219 / 255) - 16) * 255 / 219
        cb = np.rint(cb * 224 / 255) * 255 / 224
        cr = np.rint(cr * 224 / 255) * 255 / 224
    r = luma + 2 * (1 - KR) * cr
    b = luma + 2 * (1 - KB) * cb
    g = (luma - KR * r - KB * b) / KG
    rgb_out: npt.NDArray[np.uint8] = np.clip(np.rint(np.stack((r, g, b), axis=-1)), 0, 255).astype(
        np.uint8
    )
    return rgb_out


def yuv_decode_reference(
    pixels: npt.NDArray[np.uint8], order: str, yuv_range: Literal["limited", "full"]
) -> npt.NDArray[np.uint8]:
    """Decode (H, W, 2) UYVY/YUYV bytes with the textbook BT.601 formulas."""
    height, width = pixels.shape[:2]
    quads = pixels.reshape(height, width // 2, 4).astype(np.float64)
    pos = {"uyvy": (0, 1, 2, 3), "yuyv": (1, 0, 3, 2)}[order]
    u, y0, v, y1 = (quads[..., i] for i in pos)
    luma = np.stack((y0, y1), axis=-1).reshape(height, width)
    cb = np.repeat(u, 2, axis=1) - 128
    cr = np.repeat(v, 2, axis=1) - 128
    if yuv_range == "limited":
        luma, cb, cr = (luma - 16) * 255 / 219, cb * 255 / 224, cr * 255 / 224
    r = luma + 1.402 * cr
    g = luma - 0.344136 * cb - 0.714136 * cr
    b = luma + 1.772 * cb
    rgb_out: npt.NDArray[np.uint8] = np.clip(np.rint(np.stack((r, g, b), axis=-1)), 0, 255).astype(
        np.uint8
    )
    return rgb_out


def test_supported_encodings_are_sorted_and_cover_every_family() -> None:
    assert list(SUPPORTED_ENCODINGS) == sorted(SUPPORTED_ENCODINGS)
    expected = {*COLOUR_ENCODINGS, *BAYER_ENCODINGS, *YUV_ENCODINGS, "mono8", "mono16", "16UC1"}
    assert expected <= set(SUPPORTED_ENCODINGS)


@pytest.mark.parametrize("encoding", COLOUR_ENCODINGS)
def test_colour_encodings_round_trip_exactly(encoding: str) -> None:
    image = rgb_image()
    fields = image_message_fields(image, encoding)
    decoded = decode_image(message(dict(fields)))
    assert decoded.dtype == np.uint8
    np.testing.assert_array_equal(decoded, image)


@pytest.mark.parametrize(("encoding", "rgb_index"), [("rgb8", 0), ("bgr8", 2), ("8UC3", 2)])
def test_colour_encodings_put_red_at_the_right_byte(encoding: str, rgb_index: int) -> None:
    image = np.zeros((1, 1, 3), np.uint8)
    image[0, 0, 0] = 200
    fields = image_message_fields(image, encoding)
    assert fields["data"][rgb_index] == 200


@pytest.mark.parametrize("encoding", ["rgba8", "bgra8"])
def test_alpha_is_dropped(encoding: str) -> None:
    image = rgb_image()
    fields = image_message_fields(image, encoding)
    data = fields["data"].reshape(12, 16, 4)
    data[..., 3] = 17  # alpha must not leak into the result
    np.testing.assert_array_equal(decode_image(message(dict(fields))), image)


@pytest.mark.parametrize("encoding", ["mono8", "8UC1"])
def test_mono8_round_trips_exactly(encoding: str) -> None:
    image = rgb_image()[..., 0]
    decoded = decode_image(message(dict(image_message_fields(image, encoding))))
    assert decoded.shape == image.shape
    assert decoded.dtype == np.uint8
    np.testing.assert_array_equal(decoded, image)


@pytest.mark.parametrize("encoding", ["mono16", "16UC1"])
@pytest.mark.parametrize("is_bigendian", [False, True])
def test_mono16_round_trips_exactly_in_both_byte_orders(encoding: str, is_bigendian: bool) -> None:
    image = np.random.default_rng(1).integers(0, 65536, (7, 9), dtype=np.uint16)
    fields = image_message_fields(image, encoding, is_bigendian=is_bigendian, row_padding=3)
    decoded = decode_image(message(dict(fields)))
    assert decoded.dtype == np.uint16
    assert decoded.dtype.isnative
    np.testing.assert_array_equal(decoded, image)


def test_big_endian_mono16_is_read_most_significant_byte_first() -> None:
    msg = SimpleNamespace(
        height=1,
        width=2,
        encoding="mono16",
        is_bigendian=1,
        step=4,
        data=np.array([0x12, 0x34, 0xAB, 0xCD], np.uint8),
    )
    np.testing.assert_array_equal(decode_image(msg), [[0x1234, 0xABCD]])
    msg.is_bigendian = 0
    np.testing.assert_array_equal(decode_image(msg), [[0x3412, 0xCDAB]])


@pytest.mark.parametrize("encoding", ["rgb8", "bgra8", "mono8", "mono16", "bayer_grbg8", "yuv422"])
def test_row_padding_is_skipped(encoding: str) -> None:
    image: npt.NDArray[np.uint8] | npt.NDArray[np.uint16] = rgb_image(10, 12)
    if encoding == "mono8":
        image = rgb_image(10, 12)[..., 1]
    if encoding == "mono16":
        image = rgb_image(10, 12)[..., 1].astype(np.uint16) * 257
    plain = image_message_fields(image, encoding)
    padded = image_message_fields(image, encoding, row_padding=5)
    assert padded["step"] == plain["step"] + 5
    assert padded["data"].size == padded["step"] * 10
    padded["data"].reshape(10, -1)[:, plain["step"] :] = 99  # garbage in the padding
    np.testing.assert_array_equal(
        decode_image(message(dict(padded))), decode_image(message(dict(plain)))
    )


@given(
    height=st.integers(1, 9),
    width=st.integers(1, 9),
    padding=st.integers(0, 7),
    encoding=st.sampled_from([*COLOUR_ENCODINGS, "mono8", "mono16"]),
    seed=st.integers(0, 2**16),
)
@settings(max_examples=60, deadline=None)
def test_any_size_and_padding_round_trips_exactly(
    height: int, width: int, padding: int, encoding: str, seed: int
) -> None:
    image: npt.NDArray[np.uint8] | npt.NDArray[np.uint16] = rgb_image(height, width, seed)
    if encoding == "mono8":
        image = image[..., 0].copy()
    if encoding == "mono16":
        image = image[..., 0].astype(np.uint16) * 251
    fields = image_message_fields(image, encoding, row_padding=padding)
    np.testing.assert_array_equal(decode_image(message(dict(fields))), image)


@pytest.mark.parametrize("encoding", BAYER_ENCODINGS)
@pytest.mark.parametrize("colour", FLAT_COLOURS)
def test_bayer_flat_colour_decodes_to_that_colour(encoding: str, colour: tuple[int, ...]) -> None:
    image = np.broadcast_to(np.array(colour, np.uint8), (12, 14, 3)).copy()
    decoded = decode_image(message(dict(image_message_fields(image, encoding))))
    assert decoded.shape == image.shape
    np.testing.assert_array_equal(decoded[2:-2, 2:-2], image[2:-2, 2:-2])


@pytest.mark.parametrize("encoding", BAYER_ENCODINGS)
def test_bayer_mosaic_samples_the_named_pattern(encoding: str) -> None:
    image = rgb_image(6, 8)
    mosaic = image_message_fields(image, encoding)["data"].reshape(6, 8)
    for dy, dx, channel in bayer_sites(encoding.removeprefix("bayer_").removesuffix("8")):
        np.testing.assert_array_equal(mosaic[dy::2, dx::2], image[dy::2, dx::2, channel])


@pytest.mark.parametrize("encoding", BAYER_ENCODINGS)
def test_bayer_demosaic_keeps_raw_samples_at_their_sites(encoding: str) -> None:
    image = rgb_image(20, 24, seed=3)
    decoded = decode_image(message(dict(image_message_fields(image, encoding))))
    inner = np.zeros(image.shape[:2], dtype=bool)
    inner[2:-2, 2:-2] = True
    for dy, dx, channel in bayer_sites(encoding.removeprefix("bayer_").removesuffix("8")):
        site = np.zeros_like(inner)
        site[dy::2, dx::2] = True
        mask = site & inner
        np.testing.assert_array_equal(decoded[mask, channel], image[mask, channel])


@pytest.mark.parametrize("encoding", YUV_ENCODINGS)
@pytest.mark.parametrize("yuv_range", ["limited", "full"])
def test_yuv_round_trip_matches_bt601_reference(
    encoding: str, yuv_range: Literal["limited", "full"]
) -> None:
    image = rgb_image(10, 16, seed=5)
    fields = image_message_fields(image, encoding, yuv_range=yuv_range)
    decoded = decode_image(message(dict(fields)), yuv_range=yuv_range)
    reference = yuv_reference(image, yuv_range)
    assert np.abs(decoded.astype(int) - reference).max() <= 2


@pytest.mark.parametrize("encoding", YUV_ENCODINGS)
def test_yuv_full_range_gray_round_trips_exactly(encoding: str) -> None:
    gray = np.repeat(np.arange(256, dtype=np.uint8).reshape(16, 16), 3).reshape(16, 16, 3)
    fields = image_message_fields(gray, encoding, yuv_range="full")
    np.testing.assert_array_equal(decode_image(message(dict(fields)), yuv_range="full"), gray)


@pytest.mark.parametrize("encoding", YUV_ENCODINGS)
def test_yuv_limited_range_gray_round_trips_within_one_level(encoding: str) -> None:
    gray = np.repeat(np.arange(256, dtype=np.uint8).reshape(16, 16), 3).reshape(16, 16, 3)
    decoded = decode_image(message(dict(image_message_fields(gray, encoding))))
    assert np.abs(decoded.astype(int) - gray).max() <= 1
    assert (decoded[..., 0] == decoded[..., 1]).all()
    assert (decoded[..., 1] == decoded[..., 2]).all()
    assert decoded[0, 0, 0] == 0
    assert decoded[-1, -1, 0] == 255


@pytest.mark.parametrize(
    ("encoding", "expected"),
    [
        ("yuv422", [128, 235, 128, 235]),
        ("uyvy", [128, 235, 128, 235]),
        ("yuv422_yuy2", [235, 128, 235, 128]),
        ("yuyv", [235, 128, 235, 128]),
    ],
)
def test_yuv_byte_order_follows_ros(encoding: str, expected: list[int]) -> None:
    white = np.full((1, 2, 3), 255, np.uint8)
    np.testing.assert_array_equal(image_message_fields(white, encoding)["data"], expected)


@pytest.mark.parametrize("encoding", YUV_ENCODINGS)
@pytest.mark.parametrize("yuv_range", ["limited", "full"])
def test_yuv_decode_matches_textbook_formulas(
    encoding: str, yuv_range: Literal["limited", "full"]
) -> None:
    order = "uyvy" if encoding in {"yuv422", "uyvy"} else "yuyv"
    rng = np.random.default_rng(7)
    raw = rng.integers(0, 256, (8, 12, 2), dtype=np.uint8)
    if yuv_range == "limited":  # legal video range: Y 16-235, Cb/Cr 16-240 (OpenCV clips Y < 16)
        raw = rng.integers(16, 236, (8, 12, 2), dtype=np.uint8)
    msg = SimpleNamespace(
        height=8, width=12, encoding=encoding, is_bigendian=0, step=24, data=raw.reshape(-1)
    )
    decoded = decode_image(msg, yuv_range=yuv_range)
    reference = yuv_decode_reference(raw, order, yuv_range)
    assert np.abs(decoded.astype(int) - reference).max() <= 1


def test_yuv_rejects_odd_width() -> None:
    with pytest.raises(RecordingError, match="even image width"):
        image_message_fields(rgb_image(4, 5), "yuv422")
    msg = SimpleNamespace(
        height=1, width=3, encoding="yuv422", is_bigendian=0, step=6, data=np.zeros(6, np.uint8)
    )
    with pytest.raises(RecordingError, match="odd width 3"):
        decode_image(msg)


def test_truncated_data_raises_with_the_numbers() -> None:
    fields = dict(image_message_fields(rgb_image(4, 5), "rgb8"))
    fields["data"] = fields["data"][:-1]  # type: ignore[index]
    with pytest.raises(RecordingError, match=r"truncated or corrupt.*59 bytes \(need 60\)"):
        decode_image(message(fields))


def test_step_smaller_than_a_row_raises() -> None:
    fields = dict(image_message_fields(rgb_image(4, 5), "rgb8"))
    fields["step"] = 14
    with pytest.raises(RecordingError, match=r"needs step >= 15.*step=14"):
        decode_image(message(fields))


def test_unknown_encoding_lists_the_supported_ones() -> None:
    msg = SimpleNamespace(
        height=1, width=1, encoding="32FC1", is_bigendian=0, step=4, data=np.zeros(4, np.uint8)
    )
    with pytest.raises(RecordingError, match=r"'32FC1' is not supported.*bgr8.*open an issue"):
        decode_image(msg)
    with pytest.raises(RecordingError, match="is not supported"):
        image_message_fields(rgb_image(), "nv12")


def test_message_fields_reject_wrong_image_shape_or_dtype() -> None:
    with pytest.raises(RecordingError, match=r"\(H, W, 3\) RGB uint8"):
        image_message_fields(rgb_image()[..., 0], "rgb8")
    with pytest.raises(RecordingError, match=r"\(H, W\) uint16"):
        image_message_fields(rgb_image()[..., 0], "mono16")


def test_decode_accepts_bytes_data() -> None:
    fields = dict(image_message_fields(rgb_image(), "bgr8"))
    fields["data"] = fields["data"].tobytes()  # type: ignore[attr-defined]
    np.testing.assert_array_equal(decode_image(message(fields)), rgb_image())


def test_fields_build_a_rosbags_image_that_survives_serialisation() -> None:
    store = get_typestore(Stores.ROS2_HUMBLE)
    image_type = store.types["sensor_msgs/msg/Image"]
    header = store.types["std_msgs/msg/Header"](
        stamp=store.types["builtin_interfaces/msg/Time"](sec=1, nanosec=2), frame_id="cam"
    )
    fields = image_message_fields(rgb_image(), "bayer_rggb8", row_padding=4)
    raw = store.serialize_cdr(image_type(header=header, **fields), image_type.__msgtype__)
    msg = store.deserialize_cdr(raw, image_type.__msgtype__)
    np.testing.assert_array_equal(decode_image(msg), decode_image(message(dict(fields))))


@pytest.mark.parametrize(
    "image",
    [
        rgb_image(),
        rgb_image()[..., 0].copy(),
        np.random.default_rng(2).integers(0, 65536, (6, 5), dtype=np.uint16),
    ],
    ids=["rgb8", "mono8", "mono16"],
)
def test_png_round_trips_exactly(image: npt.NDArray[np.uint8] | npt.NDArray[np.uint16]) -> None:
    fields = compressed_image_fields(image, "png")
    assert "png compressed" in fields["format"]
    decoded = decode_compressed_image(message(dict(fields)))
    assert decoded.dtype == image.dtype
    np.testing.assert_array_equal(decoded, image)


def test_compressed_format_string_follows_image_transport() -> None:
    assert compressed_image_fields(rgb_image())["format"] == "rgb8; jpeg compressed bgr8"
    assert compressed_image_fields(rgb_image()[..., 0], "png")["format"] == (
        "mono8; png compressed mono8"
    )


def test_jpeg_round_trip_is_close_on_a_smooth_image() -> None:
    image = smooth_image()
    decoded = decode_compressed_image(message(dict(compressed_image_fields(image, "jpeg"))))
    assert decoded.shape == image.shape
    assert psnr(decoded, image) > 35  # type: ignore[arg-type]


def test_corrupt_compressed_data_raises() -> None:
    data = compressed_image_fields(smooth_image(), "png")["data"][:40]
    with pytest.raises(RecordingError, match=r"cannot be decoded.*corrupt"):
        decode_compressed_image(SimpleNamespace(format="png", data=data))
    with pytest.raises(RecordingError, match="0 bytes"):
        decode_compressed_image(SimpleNamespace(format="jpeg", data=np.zeros(0, np.uint8)))


def test_compressed_depth_header_is_skipped() -> None:
    depth = np.random.default_rng(4).integers(0, 65536, (6, 5), dtype=np.uint16)
    png = compressed_image_fields(depth, "png")["data"]
    data = np.concatenate([np.zeros(12, np.uint8), png])
    msg = SimpleNamespace(format="16UC1; compressedDepth png", data=data)
    np.testing.assert_array_equal(decode_compressed_image(msg), depth)


def test_encode_image_file_writes_rgb_in_the_right_order() -> None:
    image = rgb_image()
    png = encode_image_file(image, "png")
    assert png.startswith(b"\x89PNG")
    decoded = decode_compressed_image(SimpleNamespace(format="png", data=png))
    np.testing.assert_array_equal(decoded, image)
    assert encode_image_file(smooth_image(), "jpeg", jpeg_quality=80).startswith(b"\xff\xd8")


def test_encode_image_file_rejects_16_bit_jpeg() -> None:
    with pytest.raises(RecordingError, match="use fmt='png'"):
        encode_image_file(np.zeros((4, 4), np.uint16), "jpeg")


def test_encode_image_file_rejects_unsupported_arrays() -> None:
    with pytest.raises(RecordingError, match="uint8 or uint16"):
        encode_image_file(np.zeros((4, 4), np.float32), "png")  # type: ignore[arg-type]
    with pytest.raises(RecordingError, match=r"\(H, W, 3\) RGB"):
        encode_image_file(np.zeros((4, 4, 4), np.uint8), "png")


def test_empty_image_message_raises() -> None:
    msg = SimpleNamespace(
        height=0, width=4, encoding="rgb8", is_bigendian=0, step=12, data=np.zeros(0, np.uint8)
    )
    with pytest.raises(RecordingError, match="image message is empty"):
        decode_image(msg)


def test_unknown_yuv_range_raises() -> None:
    fields = image_message_fields(rgb_image(), "yuv422")
    with pytest.raises(RecordingError, match="yuv_range must be 'limited' or 'full'"):
        decode_image(message(dict(fields)), yuv_range="tv")  # type: ignore[arg-type]
