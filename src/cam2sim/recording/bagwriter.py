"""Writing ROS1 ``.bag``, ROS2 sqlite3 and MCAP recordings with rosbags.

Used by the tests and benchmarks to build real bags, and by the demo to write its recording.
Messages are built from plain nested mappings: :func:`BagWriter.message` fills every field the
mapping leaves out with the type's zero value, so callers only state what matters.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal, Self

import numpy as np

from cam2sim.core.errors import RecordingError
from cam2sim.recording.pointcloud import pointcloud_message_fields

if TYPE_CHECKING:
    from collections.abc import Mapping, Sequence
    from types import TracebackType

    import numpy.typing as npt

__all__ = ["BagFormat", "BagWriter", "stamp_fields"]

BagFormat = Literal["ros1", "sqlite3", "mcap"]

_NUMPY_BASE = {
    "bool": np.bool_,
    "byte": np.uint8,
    "char": np.uint8,
    "int8": np.int8,
    "uint8": np.uint8,
    "int16": np.int16,
    "uint16": np.uint16,
    "int32": np.int32,
    "uint32": np.uint32,
    "int64": np.int64,
    "uint64": np.uint64,
    "float32": np.float32,
    "float64": np.float64,
}


def _receive(stamp_ns: int, receive_ns: int | None) -> int:
    return stamp_ns if receive_ns is None else receive_ns


def stamp_fields(stamp_ns: int) -> dict[str, int]:
    """Return a ``builtin_interfaces/Time`` mapping for integer nanoseconds."""
    return {"sec": stamp_ns // 1_000_000_000, "nanosec": stamp_ns % 1_000_000_000}


class BagWriter:
    """Write messages to a new bag.

    Args:
        path: ``.bag`` file (ros1), bag folder (sqlite3) or bag folder holding an ``.mcap``.
        fmt: ``ros1``, ``sqlite3`` or ``mcap``.
    """

    def __init__(self, path: Path, fmt: BagFormat) -> None:
        from rosbags.typesys import Stores, get_typestore  # noqa: PLC0415

        self.path = Path(path)
        self.fmt = fmt
        store = Stores.ROS1_NOETIC if fmt == "ros1" else Stores.ROS2_HUMBLE
        self.typestore: Any = get_typestore(store)
        self._writer: Any = None
        self._connections: dict[str, Any] = {}

    def __enter__(self) -> Self:
        if self.fmt == "ros1":
            from rosbags.rosbag1 import Writer as Writer1  # noqa: PLC0415

            self._writer = Writer1(self.path)
        else:
            from rosbags.rosbag2 import StoragePlugin  # noqa: PLC0415
            from rosbags.rosbag2 import Writer as Writer2  # noqa: PLC0415

            plugin = StoragePlugin.MCAP if self.fmt == "mcap" else StoragePlugin.SQLITE3
            self._writer = Writer2(self.path, version=9, storage_plugin=plugin)
        self._writer.open()
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        if self._writer is not None:
            self._writer.close()
            self._writer = None

    def message(self, msgtype: str, fields: Mapping[str, Any] | None = None) -> Any:
        """Build a message of ``msgtype``; omitted fields take their zero value.

        ``header.stamp`` may be given as integer nanoseconds (``{"header": {"stamp": 12}}``).
        """
        return self._build(msgtype, dict(fields or {}))

    def write(self, topic: str, msg: Any, *, receive_ns: int) -> None:
        """Serialise and write ``msg`` on ``topic`` at bag time ``receive_ns``."""
        assert self._writer is not None, "use BagWriter as a context manager"
        msgtype = msg.__msgtype__
        conn = self._connections.get(topic)
        if conn is None:
            conn = self._writer.add_connection(topic, msgtype, typestore=self.typestore)
            self._connections[topic] = conn
        if self.fmt == "ros1":
            data = self.typestore.serialize_ros1(msg, msgtype)
        else:
            data = self.typestore.serialize_cdr(msg, msgtype)
        self._writer.write(conn, int(receive_ns), data)

    def write_fields(
        self, topic: str, msgtype: str, fields: Mapping[str, Any], *, receive_ns: int
    ) -> None:
        """Build a message from ``fields`` and write it (see :meth:`message`)."""
        self.write(topic, self.message(msgtype, fields), receive_ns=receive_ns)

    def write_odometry(
        self,
        topic: str,
        stamp_ns: int,
        position: Sequence[float],
        quat_xyzw: Sequence[float] = (0.0, 0.0, 0.0, 1.0),
        *,
        receive_ns: int | None = None,
        frame_id: str = "utm",
        child_frame_id: str = "base_link",
    ) -> None:
        """Write a ``nav_msgs/Odometry`` pose (``position`` x, y[, z]) stamped ``stamp_ns``."""
        xyz = dict(zip("xyz", (float(v) for v in position), strict=False))
        quat = dict(zip("xyzw", (float(v) for v in quat_xyzw), strict=True))
        fields = {
            "header": {"stamp": stamp_ns, "frame_id": frame_id},
            "child_frame_id": child_frame_id,
            "pose": {"pose": {"position": xyz, "orientation": quat}},
        }
        self.write_fields(
            topic, "nav_msgs/msg/Odometry", fields, receive_ns=_receive(stamp_ns, receive_ns)
        )

    def write_point_cloud(
        self,
        topic: str,
        stamp_ns: int,
        points: npt.NDArray[Any],
        *,
        receive_ns: int | None = None,
        frame_id: str = "lidar",
    ) -> None:
        """Write a ``sensor_msgs/PointCloud2``.

        Args:
            topic: Topic name.
            stamp_ns: Header stamp.
            points: ``(N,)`` structured array (its fields become the cloud's), or ``(N, 4)``
                x, y, z, intensity (float32 fields).
            receive_ns: Bag time; None: the stamp.
            frame_id: Header frame.
        """
        cloud = points
        if points.dtype.names is None:
            names = ("x", "y", "z", "intensity")
            cloud = np.zeros(points.shape[0], dtype=[(n, "<f4") for n in names])
            for k, name in enumerate(names):
                cloud[name] = points[:, k]
        fields: dict[str, Any] = dict(pointcloud_message_fields(cloud))
        fields["fields"] = [self.message("sensor_msgs/msg/PointField", f) for f in fields["fields"]]
        self.write_fields(
            topic,
            "sensor_msgs/msg/PointCloud2",
            {"header": {"stamp": stamp_ns, "frame_id": frame_id}, **fields},
            receive_ns=_receive(stamp_ns, receive_ns),
        )

    # -- message construction ---------------------------------------------------------------
    def _build(self, msgtype: str, fields: dict[str, Any]) -> Any:
        if msgtype not in self.typestore.fielddefs:
            msg = f"unknown message type {msgtype!r} for a {self.fmt} bag"
            raise RecordingError(msg)
        _, defs = self.typestore.fielddefs[msgtype]
        names = {name for name, _ in defs}
        unknown = set(fields) - names
        if unknown:
            msg = f"{msgtype} has no field(s) {sorted(unknown)}; fields: {sorted(names)}"
            raise RecordingError(msg)
        kwargs = {name: self._value(desc, fields.get(name)) for name, desc in defs}
        return self.typestore.types[msgtype](**kwargs)

    def _value(self, desc: Any, value: Any) -> Any:
        from rosbags.interfaces import Nodetype  # noqa: PLC0415

        kind, detail = desc
        if kind == Nodetype.NAME:
            return self._named_value(detail, value)
        if kind == Nodetype.BASE:
            base = detail[0]
            if base == "string":
                return "" if value is None else str(value)
            return _NUMPY_BASE[base](0 if value is None else value).item()
        sub, length = detail
        sub_kind, sub_detail = sub
        fixed = kind == Nodetype.ARRAY
        if sub_kind == Nodetype.BASE and sub_detail[0] != "string":
            dtype = _NUMPY_BASE[sub_detail[0]]
            if value is None:
                return np.zeros(length if fixed else 0, dtype=dtype)
            return np.ascontiguousarray(value, dtype=dtype)
        items = list(value or [])
        if fixed and not items:
            items = [None] * length
        return [self._value(sub, item) for item in items]

    def _named_value(self, msgtype: str, value: Any) -> Any:
        if msgtype == "builtin_interfaces/msg/Time" and isinstance(value, int | np.integer):
            value = stamp_fields(int(value))
        if value is None or isinstance(value, dict):
            return self._build(msgtype, value or {})
        return value
