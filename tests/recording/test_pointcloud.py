from __future__ import annotations

import struct
from types import SimpleNamespace
from typing import TYPE_CHECKING, Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from rosbags.typesys import Stores, get_typestore

from cam2sim.core.errors import RecordingError
from cam2sim.recording.pointcloud import (
    decode_pointcloud,
    pointcloud_dtype,
    pointcloud_message_fields,
    xyz_from_points,
)

if TYPE_CHECKING:
    from collections.abc import Mapping, Sequence

    import numpy.typing as npt

XYZI = [("x", "f4"), ("y", "f4"), ("z", "f4"), ("intensity", "f4")]
VELODYNE = [*XYZI, ("ring", "u2"), ("time", "f4")]
ALL_TYPES = [
    ("x", "f4"),
    ("y", "f4"),
    ("z", "f4"),
    ("i8", "i1"),
    ("u8", "u1"),
    ("i16", "i2"),
    ("u16", "u2"),
    ("i32", "i4"),
    ("u32", "u4"),
    ("f64", "f8"),
]
STRUCT_CODES = {1: "b", 2: "B", 3: "h", 4: "H", 5: "i", 6: "I", 7: "f", 8: "d"}


def make_points(
    layout: Sequence[tuple[object, ...]], n: int = 50, seed: int = 0
) -> npt.NDArray[np.void]:
    """Structured points with random values that every field type can hold exactly."""
    rng = np.random.default_rng(seed)
    points = np.zeros(n, dtype=np.dtype(list(layout)))
    for name in points.dtype.names or ():
        column = points[name]
        if column.dtype.kind == "f":
            column[...] = rng.normal(0, 50, column.shape)
        else:
            info = np.iinfo(column.dtype)
            column[...] = rng.integers(info.min, info.max, column.shape, endpoint=True)
    return points


def as_message(fields: Mapping[str, Any]) -> SimpleNamespace:
    """A rosbags-like PointCloud2: attribute access, PointFields as objects."""
    values = dict(fields)
    values["fields"] = [SimpleNamespace(**spec) for spec in values["fields"]]
    return SimpleNamespace(**values)


def reference_decode(msg: SimpleNamespace) -> dict[str, list[tuple[float | int, ...]]]:
    """Decode point by point with struct: slow, obviously correct."""
    order = ">" if msg.is_bigendian else "<"
    data = bytes(np.asarray(msg.data, dtype=np.uint8))
    out: dict[str, list[tuple[float | int, ...]]] = {f.name: [] for f in msg.fields if f.name}
    for row in range(msg.height):
        for col in range(msg.width):
            base = row * msg.row_step + col * msg.point_step
            for f in msg.fields:
                if f.name:
                    code = f"{order}{max(f.count, 1)}{STRUCT_CODES[f.datatype]}"
                    out[f.name].append(struct.unpack_from(code, data, base + f.offset))
    return out


def assert_points_equal(actual: npt.NDArray[np.void], expected: npt.NDArray[np.void]) -> None:
    assert actual.dtype.names == expected.dtype.names
    assert actual.shape == expected.shape
    for name in expected.dtype.names or ():
        np.testing.assert_array_equal(actual[name], expected[name], err_msg=name)


@pytest.mark.parametrize(
    ("layout", "options"),
    [
        (XYZI, {}),
        (VELODYNE, {}),
        (VELODYNE, {"point_step": 32}),
        ([("x", "f8"), ("y", "f8"), ("z", "f8")], {}),
        (VELODYNE, {"is_bigendian": True}),
        (ALL_TYPES, {"is_bigendian": True, "point_step": 40}),
        (ALL_TYPES, {}),
        ([*XYZI, ("normal", "f4", (3,)), ("rgb", "u1", (3,))], {}),
        (VELODYNE, {"height": 5, "row_padding": 7}),
        (VELODYNE, {"height": 10, "point_step": 24, "row_padding": 3, "is_bigendian": True}),
    ],
    ids=[
        "packed-xyzi",
        "velodyne-22",
        "velodyne-padded-32",
        "float64-xyz",
        "big-endian",
        "all-types-big-endian-padded",
        "all-types",
        "count-gt-1",
        "organised-row-padding",
        "organised-everything",
    ],
)
def test_pointcloud_round_trips_exactly(
    layout: Sequence[tuple[object, ...]], options: dict[str, Any]
) -> None:
    points = make_points(layout)
    fields = pointcloud_message_fields(points, **options)
    decoded = decode_pointcloud(as_message(fields))
    assert_points_equal(decoded, points)


def test_message_fields_describe_the_layout() -> None:
    fields = pointcloud_message_fields(make_points(VELODYNE, n=12), point_step=32, height=3)
    assert fields["fields"][4] == {"name": "ring", "offset": 16, "datatype": 4, "count": 1}
    assert [f["datatype"] for f in fields["fields"]] == [7, 7, 7, 7, 4, 7]
    assert (fields["height"], fields["width"]) == (3, 4)
    assert (fields["point_step"], fields["row_step"]) == (32, 128)
    assert fields["data"].dtype == np.uint8
    assert fields["data"].size == 3 * 128
    assert fields["is_dense"] is True


def test_decoded_points_are_packed_and_native_endian() -> None:
    points = make_points(VELODYNE)
    fields = pointcloud_message_fields(points, point_step=32, is_bigendian=True)
    decoded = decode_pointcloud(as_message(fields))
    assert decoded.dtype.itemsize == 22
    assert decoded.flags.c_contiguous
    for name in decoded.dtype.names or ():
        assert decoded.dtype.fields is not None
        assert decoded.dtype.fields[name][0].isnative


def test_decode_matches_a_point_by_point_reference() -> None:
    points = make_points([*VELODYNE, ("rgb", "u1", (3,))], n=24)
    msg = as_message(
        pointcloud_message_fields(points, height=4, row_padding=5, point_step=30, is_bigendian=True)
    )
    decoded = decode_pointcloud(msg)
    for name, values in reference_decode(msg).items():
        expected = np.array(values)
        np.testing.assert_array_equal(decoded[name].reshape(expected.shape), expected)


@given(
    order=st.permutations(list(range(len(ALL_TYPES)))),
    extra_step=st.integers(0, 9),
    height=st.sampled_from([1, 2, 3, 6]),
    row_padding=st.integers(0, 11),
    is_bigendian=st.booleans(),
    seed=st.integers(0, 1000),
)
@settings(max_examples=40, deadline=None)
def test_any_layout_round_trips_and_matches_the_reference(
    order: list[int],
    extra_step: int,
    height: int,
    row_padding: int,
    is_bigendian: bool,
    seed: int,
) -> None:
    points = make_points([ALL_TYPES[i] for i in order], n=12, seed=seed)
    fields = pointcloud_message_fields(
        points,
        point_step=points.dtype.itemsize + extra_step,
        height=height,
        row_padding=row_padding,
        is_bigendian=is_bigendian,
    )
    msg = as_message(fields)
    decoded = decode_pointcloud(msg)
    assert_points_equal(decoded, points)
    for name, values in reference_decode(msg).items():
        np.testing.assert_array_equal(decoded[name], np.array(values)[:, 0])


def test_fields_declared_out_of_offset_order_keep_their_values_and_order() -> None:
    points = make_points(XYZI, n=9)
    wire = pointcloud_message_fields(points)
    specs = wire["fields"]
    msg = as_message({**wire, "fields": [specs[3], specs[0], specs[2], specs[1]]})
    decoded = decode_pointcloud(msg)
    assert decoded.dtype.names == ("intensity", "x", "z", "y")
    for name in ("x", "y", "z", "intensity"):
        np.testing.assert_array_equal(decoded[name], points[name])


def test_fields_with_empty_names_are_skipped() -> None:
    points = make_points(XYZI, n=5)
    wire = pointcloud_message_fields(points, point_step=20)
    pad = {"name": "", "offset": 16, "datatype": 7, "count": 1}
    decoded = decode_pointcloud(as_message({**wire, "fields": [*wire["fields"], pad]}))
    assert_points_equal(decoded, points)


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
@pytest.mark.parametrize("axis", ["x", "y", "z"])
def test_non_finite_points_are_dropped_by_default(bad: float, axis: str) -> None:
    points = make_points(VELODYNE, n=20)
    points[axis][[3, 7, 19]] = bad
    fields = pointcloud_message_fields(points, point_step=32)
    assert fields["is_dense"] is False
    decoded = decode_pointcloud(as_message(fields))
    assert_points_equal(decoded, np.delete(points, [3, 7, 19]))


def test_non_finite_points_are_kept_on_request() -> None:
    points = make_points(VELODYNE, n=20)
    points["x"][5] = np.nan
    decoded = decode_pointcloud(as_message(pointcloud_message_fields(points)), drop_invalid=False)
    assert decoded.shape == (20,)
    assert np.isnan(decoded["x"][5])
    np.testing.assert_array_equal(np.delete(decoded, 5)["x"], np.delete(points, 5)["x"])


def test_non_finite_points_are_dropped_from_organised_clouds() -> None:
    points = make_points(VELODYNE, n=24)
    points["z"][[0, 13]] = np.nan
    fields = pointcloud_message_fields(points, height=4, row_padding=6, is_bigendian=True)
    assert_points_equal(decode_pointcloud(as_message(fields)), np.delete(points, [0, 13]))


def test_clouds_without_xyz_decode_without_dropping() -> None:
    points = make_points([("intensity", "f4"), ("ring", "u2")], n=6)
    points["intensity"][2] = np.nan
    decoded = decode_pointcloud(as_message(pointcloud_message_fields(points)))
    assert decoded.shape == (6,)
    with pytest.raises(RecordingError, match=r"no x/y/z field; fields present: \['intensity'"):
        xyz_from_points(decoded)


def test_xyz_from_points_gives_float64_columns() -> None:
    points = make_points(VELODYNE, n=8)
    xyz = xyz_from_points(decode_pointcloud(as_message(pointcloud_message_fields(points))))
    assert xyz.shape == (8, 3)
    assert xyz.dtype == np.float64
    np.testing.assert_array_equal(xyz[:, 1], points["y"].astype(np.float64))


def test_xyz_from_points_names_the_missing_axis() -> None:
    with pytest.raises(RecordingError, match=r"no z field.*\['x', 'y'\]"):
        xyz_from_points(make_points([("x", "f4"), ("y", "f4")]))


def test_empty_cloud_decodes_to_empty_array() -> None:
    points = make_points(VELODYNE, n=0)
    decoded = decode_pointcloud(as_message(pointcloud_message_fields(points)))
    assert decoded.shape == (0,)
    assert decoded.dtype.names == points.dtype.names


def test_pointcloud_dtype_has_offsets_and_itemsize() -> None:
    specs = [
        SimpleNamespace(name="x", offset=0, datatype=7, count=1),
        SimpleNamespace(name="ring", offset=20, datatype=4, count=1),
        SimpleNamespace(name="rgb", offset=8, datatype=2, count=3),
    ]
    dtype = pointcloud_dtype(specs, point_step=24, is_bigendian=True)
    assert dtype.itemsize == 24
    assert dtype.fields is not None
    assert dtype.fields["ring"] == (np.dtype(">u2"), 20)
    assert dtype.fields["rgb"][0].shape == (3,)


def test_unknown_datatype_names_the_field() -> None:
    msg = as_message(pointcloud_message_fields(make_points(XYZI)))
    msg.fields[3].datatype = 9
    with pytest.raises(RecordingError, match="'intensity' has unknown datatype 9"):
        decode_pointcloud(msg)


def test_field_beyond_point_step_is_rejected() -> None:
    msg = as_message(pointcloud_message_fields(make_points(XYZI)))
    msg.fields[3].offset = 14
    with pytest.raises(RecordingError, match=r"'intensity' .*does not fit in point_step=16"):
        decode_pointcloud(msg)


def test_truncated_data_raises_with_the_numbers() -> None:
    fields = pointcloud_message_fields(make_points(XYZI, n=10))
    msg = as_message({**fields, "data": fields["data"][:-3]})
    with pytest.raises(RecordingError, match=r"truncated or corrupt.*160 bytes, got .*157 bytes"):
        decode_pointcloud(msg)


def test_row_step_shorter_than_a_row_raises() -> None:
    fields = pointcloud_message_fields(make_points(XYZI, n=10), height=2)
    msg = as_message({**fields, "row_step": 70})
    with pytest.raises(RecordingError, match=r"need row_step >= 80.*got row_step=70"):
        decode_pointcloud(msg)


def test_decode_accepts_bytes_data() -> None:
    points = make_points(VELODYNE)
    fields = pointcloud_message_fields(points)
    decoded = decode_pointcloud(as_message({**fields, "data": fields["data"].tobytes()}))
    assert_points_equal(decoded, points)


@pytest.mark.parametrize(
    ("layout", "match"),
    [
        ([("x", "f4"), ("flag", "?")], r"'flag' has dtype bool"),
        ([("x", "f4"), ("t", "i8")], r"'t' has dtype int64"),
        ([("x", "f4"), ("m", "f4", (2, 2))], r"'m' has dtype"),
    ],
)
def test_message_fields_reject_unstorable_dtypes(
    layout: Sequence[tuple[object, ...]], match: str
) -> None:
    with pytest.raises(RecordingError, match=match):
        pointcloud_message_fields(np.zeros(3, dtype=np.dtype(list(layout))))


def test_message_fields_reject_inconsistent_layout() -> None:
    points = make_points(XYZI, n=10)
    with pytest.raises(RecordingError, match=r"point_step=12 \(packed size 16\)"):
        pointcloud_message_fields(points, point_step=12)
    with pytest.raises(RecordingError, match="height=3 for 10 points"):
        pointcloud_message_fields(points, height=3)
    with pytest.raises(RecordingError, match="1-D structured array"):
        pointcloud_message_fields(np.zeros(4, np.float32))


def test_fields_build_a_rosbags_pointcloud_that_survives_serialisation() -> None:
    store = get_typestore(Stores.ROS2_HUMBLE)
    cloud_type = store.types["sensor_msgs/msg/PointCloud2"]
    field_type = store.types["sensor_msgs/msg/PointField"]
    header = store.types["std_msgs/msg/Header"](
        stamp=store.types["builtin_interfaces/msg/Time"](sec=1, nanosec=2), frame_id="lidar"
    )
    points = make_points(VELODYNE, n=30)
    fields = pointcloud_message_fields(points, point_step=32, height=3, row_padding=4)
    specs = [field_type(**spec) for spec in fields["fields"]]
    message = cloud_type(header=header, **{**fields, "fields": specs})  # type: ignore[arg-type]
    raw = store.serialize_cdr(message, cloud_type.__msgtype__)
    assert_points_equal(
        decode_pointcloud(store.deserialize_cdr(raw, cloud_type.__msgtype__)), points
    )
