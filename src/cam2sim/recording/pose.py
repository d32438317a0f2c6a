"""Ego poses from pose messages: Odometry, PoseStamped, PoseWithCovarianceStamped, NavSatFix.

Messages are gathered into a :class:`PoseTrack` in the recording's own coordinates (a CRS, a
local frame, or WGS84 for NavSatFix). Conversion to the world frame happens once, in the extract
stage, through :mod:`cam2sim.core.frames`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, NamedTuple

import numpy as np
import numpy.typing as npt

from cam2sim.core.errors import RecordingError

if TYPE_CHECKING:
    from collections.abc import Iterable

    from cam2sim.recording.bag import BagMessage

__all__ = [
    "NAVSATFIX",
    "ORIENTATION_MSGTYPES",
    "POSE_MSGTYPES",
    "PoseSample",
    "PoseTrack",
    "orientation_track_from_messages",
    "pose_sample",
    "pose_track_from_messages",
    "pose_track_from_samples",
    "require_increasing",
]

ODOMETRY = "nav_msgs/msg/Odometry"
POSE_STAMPED = "geometry_msgs/msg/PoseStamped"
POSE_COV_STAMPED = "geometry_msgs/msg/PoseWithCovarianceStamped"
NAVSATFIX = "sensor_msgs/msg/NavSatFix"
IMU = "sensor_msgs/msg/Imu"
POSE_MSGTYPES = (ODOMETRY, POSE_STAMPED, POSE_COV_STAMPED, NAVSATFIX)
ORIENTATION_MSGTYPES = (ODOMETRY, POSE_STAMPED, POSE_COV_STAMPED, IMU)


@dataclass(frozen=True)
class PoseTrack:
    """Pose samples of one topic, sorted by time, in the recording's coordinates.

    Attributes:
        stamp_ns: ``(N,)`` int64 nanoseconds, strictly increasing.
        position: ``(N, 3)`` float64; x, y, z in the pose CRS, or latitude, longitude (degrees)
            and altitude (m) when ``geographic``.
        quat: ``(N, 4)`` float64 (x, y, z, w) orientation of the pose frame, or None (NavSatFix).
        geographic: Whether ``position`` holds WGS84 latitude, longitude, altitude.
        frame_id: ``header.frame_id`` of the first message.
        child_frame_id: ``child_frame_id`` of the first Odometry message, else "".
        dropped: Reason -> number of messages dropped.
    """

    stamp_ns: npt.NDArray[np.int64]
    position: npt.NDArray[np.float64]
    quat: npt.NDArray[np.float64] | None
    geographic: bool
    frame_id: str
    child_frame_id: str
    dropped: dict[str, int]

    def __len__(self) -> int:
        return int(self.stamp_ns.shape[0])


def _pose_of(msgtype: str, msg: Any) -> tuple[tuple[float, ...], tuple[float, ...] | None, bool]:
    """Return (position, quaternion or None, valid) of one message."""
    if msgtype == NAVSATFIX:
        position = (float(msg.latitude), float(msg.longitude), float(msg.altitude))
        return position, None, int(msg.status.status) >= 0
    if msgtype in (ODOMETRY, POSE_COV_STAMPED):
        pose = msg.pose.pose
    elif msgtype == POSE_STAMPED:
        pose = msg.pose
    elif msgtype == IMU:
        o = msg.orientation
        return (0.0, 0.0, 0.0), (o.x, o.y, o.z, o.w), True
    else:
        msg_ = f"unsupported pose message type {msgtype}; use one of {', '.join(POSE_MSGTYPES)}"
        raise RecordingError(msg_)
    p, o = pose.position, pose.orientation
    return (p.x, p.y, p.z), (o.x, o.y, o.z, o.w), True


def require_increasing(stamp_ns: npt.NDArray[np.int64], *, topic: str) -> npt.NDArray[np.bool_]:
    """Check that times never go backwards; return a mask keeping the first of equal stamps.

    Raises:
        RecordingError: A time goes backwards.
    """
    if stamp_ns.shape[0] < 2:
        return np.ones(stamp_ns.shape[0], dtype=bool)
    steps = np.diff(stamp_ns)
    back = np.flatnonzero(steps < 0)
    if back.size:
        i = int(back[0]) + 1
        msg = (
            f"timestamps on {topic} go backwards at message {i} ({stamp_ns[i] / 1e9:.6f} s after "
            f"{stamp_ns[i - 1] / 1e9:.6f} s; {back.size} times in all). Fix the recording's "
            "clock, or set recording.time_base: receive in config.yaml to use bag record times"
        )
        raise RecordingError(msg)
    return np.concatenate([[True], steps > 0])


class PoseSample(NamedTuple):
    """What a pose message contributes, without the message (a few hundred bytes, not KB)."""

    stamp_ns: int
    msgtype: str
    position: tuple[float, ...]
    quat: tuple[float, ...] | None
    valid: bool
    frame_id: str
    child_frame_id: str


def pose_sample(m: BagMessage) -> PoseSample:
    """Reduce a pose (or orientation) message to a :class:`PoseSample` as it streams in."""
    position, quat, ok = _pose_of(m.msgtype, m.msg)
    return PoseSample(
        stamp_ns=m.stamp_ns,
        msgtype=m.msgtype,
        position=position,
        quat=quat,
        valid=ok,
        frame_id=str(getattr(getattr(m.msg, "header", None), "frame_id", "")),
        child_frame_id=str(getattr(m.msg, "child_frame_id", "")),
    )


def _collect(samples: Iterable[PoseSample], *, topic: str, on_invalid: str, kind: str) -> PoseTrack:
    stamps: list[int] = []
    positions: list[tuple[float, ...]] = []
    quats: list[tuple[float, ...] | None] = []
    valid: list[bool] = []
    frame_id = child = ""
    msgtype = ""
    for m in samples:
        if not stamps:
            msgtype = m.msgtype
            frame_id = m.frame_id
            child = m.child_frame_id
        stamps.append(m.stamp_ns)
        positions.append(m.position)
        quats.append(m.quat)
        valid.append(m.valid)
    if not stamps:
        msg = f"{kind} topic {topic} has no messages; choose a topic that has (cam2sim inspect)"
        raise RecordingError(msg)
    stamp_ns = np.asarray(stamps, dtype=np.int64)
    pos = np.asarray(positions, dtype=np.float64)
    has_quat = quats[0] is not None
    q = np.asarray(quats, dtype=np.float64) if has_quat else None
    no_fix = ~np.asarray(valid)
    finite = np.isfinite(pos).all(axis=1)
    if q is not None:
        norms = np.linalg.norm(q, axis=1)
        finite &= np.isfinite(q).all(axis=1) & (norms > 1e-9)
    bad = ~finite
    dropped: dict[str, int] = {}
    if bad.any() or no_fix.any():
        if on_invalid == "error":
            first = int(np.flatnonzero(bad | no_fix)[0])
            what = "NaN/inf or zero-quaternion" if bool(np.asarray(bad)[first]) else "no fix"
            msg = (
                f"{kind} topic {topic} has {int(bad.sum())} NaN/inf poses and {int(no_fix.sum())}"
                f" no-fix messages (first: message {first}, {what}). Set pose.on_invalid: drop "
                "in config.yaml to skip them"
            )
            raise RecordingError(msg)
        dropped = {k: int(v) for k, v in (("invalid", bad.sum()), ("no_fix", no_fix.sum())) if v}
    keep = finite & ~no_fix
    # Messages arrive in receive order; a header clock that runs backwards is an error.
    unique = require_increasing(stamp_ns[keep], topic=topic)
    if (~unique).any():
        dropped["duplicate_stamp"] = int((~unique).sum())
    sel = np.flatnonzero(keep)[unique]
    if q is not None:
        q = q[sel] / np.linalg.norm(q[sel], axis=1, keepdims=True)
    if sel.size < 2:
        msg = f"{kind} topic {topic} has fewer than 2 valid poses; it cannot be interpolated"
        raise RecordingError(msg)
    return PoseTrack(
        stamp_ns=stamp_ns[sel],
        position=pos[sel],
        quat=q,
        geographic=msgtype == NAVSATFIX,
        frame_id=frame_id,
        child_frame_id=child,
        dropped=dropped,
    )


def pose_track_from_messages(
    messages: Iterable[BagMessage], *, topic: str, on_invalid: str = "error"
) -> PoseTrack:
    """Gather the pose messages of one topic into a :class:`PoseTrack`.

    Args:
        messages: Deserialised messages of the pose topic, in receive order.
        topic: The topic name (for messages).
        on_invalid: ``error`` or ``drop`` for NaN poses and NavSatFix without a fix.

    Raises:
        RecordingError: No messages, invalid poses with ``on_invalid="error"``, or a clock
            running backwards.
    """
    return pose_track_from_samples(map(pose_sample, messages), topic=topic, on_invalid=on_invalid)


def pose_track_from_samples(
    samples: Iterable[PoseSample], *, topic: str, on_invalid: str = "error", kind: str = "pose"
) -> PoseTrack:
    """Gather reduced pose samples of one topic into a :class:`PoseTrack` (see above)."""
    return _collect(samples, topic=topic, on_invalid=on_invalid, kind=kind)


def orientation_track_from_messages(
    messages: Iterable[BagMessage], *, topic: str, on_invalid: str = "error"
) -> PoseTrack:
    """Gather orientation samples (Imu, Odometry, Pose) of one topic; positions are ignored."""
    return _collect(
        map(pose_sample, messages), topic=topic, on_invalid=on_invalid, kind="orientation"
    )


def yaw_offset_quat(offset_rad: float) -> npt.NDArray[np.float64]:
    """Return the quaternion turning the pose frame into the body frame (x forward)."""
    half = offset_rad / 2
    return np.array([0.0, 0.0, math.sin(half), math.cos(half)])


__all__ += ["yaw_offset_quat"]
