"""Stage extract: a recording (bags) into ``WS/dataset/``.

Two streaming passes over the recording. The first gathers the small streams (poses, /tf,
signals, camera_info) and fixes the ego trajectory in the world frame; the second streams camera
frames and LiDAR scans, gives each the interpolated pose at its time, and writes them out. Memory
stays bounded by a few frames whatever the bag length. The whole dataset folder is built beside
the old one and swapped in at the end, so an interrupted or failed run leaves the workspace as it
was.
"""

from __future__ import annotations

import logging
import math
import warnings
from collections import Counter
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from cam2sim.core import frames
from cam2sim.core.camera import PinholeCamera
from cam2sim.core.config import AXIS_CONVENTION_YAW_OFFSET, Config, MountConfig
from cam2sim.core.dataset import (
    POSE_PRECISION,
    Calibration,
    CameraIntrinsics,
    DatasetCounts,
    DatasetInfo,
    MountRecord,
    SourceRecord,
)
from cam2sim.core.errors import ConfigError, RecordingError
from cam2sim.core.files import (
    atomic_folder,
    atomic_write,
    file_fingerprint,
    write_bytes_atomic,
)
from cam2sim.core.images import frames_are_grey
from cam2sim.core.progress import ProgressCallback, no_progress
from cam2sim.core.table import write_table
from cam2sim.core.trajectory import (
    Trajectory,
    densify_positions,
    gap_limit_s,
    orientation_from_motion,
    smooth_positions,
)
from cam2sim.core.workspace import DatasetPaths, Workspace, WorldFrameRecord, hash_inputs
from cam2sim.recording.bag import BagMessage, Recording
from cam2sim.recording.calibration_file import model_named
from cam2sim.recording.intrinsics import intrinsics_from_file
from cam2sim.recording.pointcloud import decode_pointcloud
from cam2sim.recording.pose import (
    ORIENTATION_MSGTYPES,
    POSE_MSGTYPES,
    PoseSample,
    PoseTrack,
    pose_sample,
    pose_track_from_samples,
    yaw_offset_quat,
)
from cam2sim.recording.signal import SignalSeries, value_at_path
from cam2sim.recording.tf import TF_MSGTYPE, TfTree
from cam2sim.stages._runner import stage_run

__all__ = ["ExtractResult", "extract", "world_trajectory_from_track"]

logger = logging.getLogger(__name__)

STAGE = "extract"
IMAGE = "sensor_msgs/msg/Image"
COMPRESSED = "sensor_msgs/msg/CompressedImage"
CAMERA_MSGTYPES = (IMAGE, COMPRESSED)
CAMERA_INFO = "sensor_msgs/msg/CameraInfo"
POINTCLOUD2 = "sensor_msgs/msg/PointCloud2"
TF_TOPICS = ("/tf", "/tf_static")
# Rotation from a camera optical frame (x right, y down, z forward) to a link frame
# (x forward, y left, z up): columns are the optical axes in link coordinates.
R_LINK_OPTICAL = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
_PENDING_FRAMES = 8


@dataclass(frozen=True)
class ExtractResult:
    """What :func:`extract` did."""

    dataset_dir: Path
    info: DatasetInfo
    skipped: bool


# -- inputs ------------------------------------------------------------------------------------
def _bag_paths(ws: Workspace, config: Config) -> list[Path]:
    if not config.recording.bags:
        msg = f"{ws.config_path}: recording.bags is empty; list the bag files of the recording"
        raise ConfigError(msg)
    return [ws.resolve(b) for b in config.recording.bags]


def _fingerprints(paths: list[Path]) -> list[SourceRecord]:
    out: list[SourceRecord] = []
    for path in paths:
        files = sorted(p for p in path.rglob("*") if p.is_file()) if path.is_dir() else [path]
        out.extend(SourceRecord(path=str(f), fingerprint=file_fingerprint(f)) for f in files)
    return out


def _inputs_hash(config: Config, sources: list[SourceRecord]) -> str:
    return hash_inputs(
        {
            # The vehicle block only feeds later stages: editing it must not re-extract.
            "config": config.model_dump(mode="json", exclude={"vehicle"}),
            "sources": [s.fingerprint for s in sources],
        }
    )


# -- pass 1: poses, tf, signals, camera_info ----------------------------------------------------
@dataclass
class _SmallStreams:
    pose_messages: list[PoseSample]
    orientation_messages: list[PoseSample]
    tf: TfTree
    signals: dict[str, SignalSeries]
    camera_info: Any


def _needs_tf(config: Config) -> bool:
    return (
        config.pose.source == "tf"
        or config.camera.mount.tf_frame is not None
        or (config.topics.lidar is not None and config.lidar.mount.tf_frame is not None)
    )


def _wanted_topics(rec: Recording, config: Config) -> dict[str, str]:
    """Check the small-stream topics exist; return topic -> role."""
    topics = config.topics
    wanted: dict[str, str] = {}
    if config.pose.source == "message":
        if topics.pose is None:
            msg = "topics.pose is not set; name the pose topic (cam2sim inspect lists them)"
            raise ConfigError(msg)
        rec.require_topic(topics.pose, key="topics.pose", msgtypes=POSE_MSGTYPES)
        wanted[topics.pose] = "pose"
    if config.pose.orientation_topic:
        rec.require_topic(
            config.pose.orientation_topic,
            key="pose.orientation_topic",
            msgtypes=ORIENTATION_MSGTYPES,
        )
        wanted[config.pose.orientation_topic] = "orientation"
    present = rec.topics()
    if _needs_tf(config):
        tf_topics = [t for t in TF_TOPICS if t in present]
        if not tf_topics:
            msg = "config needs /tf or /tf_static (pose.source: tf or a mount tf_frame), "
            msg += "but the recording has neither; give the mount as xyz/rpy_deg instead"
            raise RecordingError(msg)
        for t in tf_topics:
            rec.require_topic(t, key="tf", msgtypes=(TF_MSGTYPE,))
            wanted[t] = "tf"
    for name, sig in topics.signals.items():
        rec.require_topic(sig.topic, key=f"topics.signals.{name}.topic")
    if topics.camera_info:
        rec.require_topic(topics.camera_info, key="topics.camera_info", msgtypes=(CAMERA_INFO,))
        wanted[topics.camera_info] = "camera_info"
    return wanted


def _read_small_streams(rec: Recording, config: Config) -> _SmallStreams:
    topics = config.topics
    wanted = _wanted_topics(rec, config)
    signal_topics = {s.topic for s in topics.signals.values()}

    streams = _SmallStreams([], [], TfTree(), {}, None)
    rows_by_name: dict[str, list[tuple[int, float]]] = {n: [] for n in topics.signals}
    tf_messages: list[BagMessage] = []
    for m in rec.messages(set(wanted) | signal_topics, time_base=config.recording.time_base):
        role = wanted.get(m.topic)
        if role == "pose":
            streams.pose_messages.append(pose_sample(m))
        elif role == "orientation":
            streams.orientation_messages.append(pose_sample(m))
        elif role == "tf":
            tf_messages.append(m)
        elif role == "camera_info" and streams.camera_info is None:
            streams.camera_info = m.msg
        if m.topic in signal_topics:
            for name, sig in topics.signals.items():
                if sig.topic == m.topic:
                    rows_by_name[name].append((m.stamp_ns, value_at_path(m.msg, sig.field)))
    streams.tf.add_messages(tf_messages, static_topics={"/tf_static"})
    for name, rows in rows_by_name.items():
        streams.signals[name] = SignalSeries(
            stamp_ns=np.asarray([r[0] for r in rows], dtype=np.int64),
            value=np.asarray([r[1] for r in rows], dtype=np.float64),
        )
    return streams


# -- the trajectory in the world frame -----------------------------------------------------------
def _world_record(
    track: PoseTrack, config: Config, existing: WorldFrameRecord | None
) -> WorldFrameRecord:
    crs = "EPSG:4326" if track.geographic else config.pose.crs
    if existing is not None and existing.source_crs == crs:
        return existing
    if existing is not None:
        logger.warning("pose CRS changed (%s -> %s); the world frame is redefined", existing, crs)
    if crs is None:
        return WorldFrameRecord(proj_string=None, source_crs=None)
    first = track.position[0]
    if track.geographic:
        wf = frames.WorldFrame(float(first[0]), float(first[1]), float(first[2]))
    else:
        wf = frames.WorldFrame.at_crs_point(crs, float(first[0]), float(first[1]), float(first[2]))
    return WorldFrameRecord(
        proj_string=wf.proj_string,
        origin_lat_deg=wf.origin_lat_deg,
        origin_lon_deg=wf.origin_lon_deg,
        origin_alt_m=wf.origin_alt_m,
        source_crs=crs,
    )


def _world_frame(record: WorldFrameRecord) -> frames.WorldFrame | None:
    if record.origin_lat_deg is None or record.origin_lon_deg is None:
        return None
    return frames.WorldFrame(record.origin_lat_deg, record.origin_lon_deg, record.origin_alt_m)


def world_trajectory_from_track(
    track: PoseTrack,
    config: Config,
    world: WorldFrameRecord,
    *,
    orientation: PoseTrack | None = None,
) -> Trajectory:
    """Convert a pose track into the world frame with the body axis convention applied.

    Args:
        track: Poses in the recording's coordinates.
        config: The recording config (pose conventions, sync windows).
        world: The workspace world frame.
        orientation: Separate orientation samples (ENU) for NavSatFix tracks.
    """
    wf = _world_frame(world)
    if wf is None:
        position = track.position.copy()
    elif track.geographic:
        position = wf.from_wgs84(track.position[:, 0], track.position[:, 1], track.position[:, 2])
    else:
        assert world.source_crs is not None
        position = wf.from_crs(world.source_crs, track.position)
    pose_cfg = config.pose
    stamp_ns = track.stamp_ns
    if pose_cfg.heading == "motion" or (track.quat is None and orientation is None):
        # Jitter smoothed away (it reaches the heading, the speed and the derived steering),
        # then slow fixes (1 Hz GPS) follow a cubic through them, not straight chords.
        gap = gap_limit_s(stamp_ns, config.sync.max_pose_gap_s)
        position, moved = smooth_positions(stamp_ns, position, max_gap_s=gap)
        logger.info("positions smoothed for a heading from motion: moved %.3f m RMS", moved)
        stamp_ns, position = densify_positions(stamp_ns, position, max_gap_s=gap)
        quat = orientation_from_motion(
            stamp_ns,
            position,
            window_s=config.sync.heading_window_s,
            min_speed_mps=config.sync.min_motion_speed_mps,
            pitch_window_m=config.sync.pitch_window_m,
        )
    else:
        if track.quat is not None:
            quat = track.quat
            if wf is not None and not track.geographic and world.source_crs is not None:
                quat = wf.quats_from_crs(world.source_crs, track.position[:, :2], quat)
        else:
            assert orientation is not None
            assert orientation.quat is not None
            inside = (track.stamp_ns >= orientation.stamp_ns[0]) & (
                track.stamp_ns <= orientation.stamp_ns[-1]
            )
            if inside.sum() < 2:
                msg = "pose.orientation_topic does not overlap the pose topic in time"
                raise RecordingError(msg)
            track = PoseTrack(
                track.stamp_ns[inside],
                track.position[inside],
                None,
                track.geographic,
                track.frame_id,
                track.child_frame_id,
                track.dropped,
            )
            position = position[inside]
            quat = frames.interpolate_poses(
                orientation.stamp_ns,
                np.zeros((len(orientation), 3)),
                orientation.quat,
                track.stamp_ns,
            ).quats
        offset = AXIS_CONVENTION_YAW_OFFSET[pose_cfg.axis_convention]
        quat = frames.quat_normalize(frames.quat_multiply(quat, yaw_offset_quat(offset)))
        stamp_ns = track.stamp_ns
    return Trajectory(stamp_ns=stamp_ns, position=position, quat=quat)


def _read_trajectory(
    streams: _SmallStreams, config: Config, existing: WorldFrameRecord | None
) -> tuple[Trajectory, WorldFrameRecord, PoseTrack]:
    on_invalid = config.pose.on_invalid
    if config.pose.source == "tf":
        assert config.pose.tf is not None
        chain = streams.tf.chain(config.pose.tf.parent, config.pose.tf.child)
        if chain.static:
            msg = f"the tf chain {config.pose.tf.parent} -> {config.pose.tf.child} never changes"
            raise RecordingError(msg + "; choose frames connected by a dynamic /tf edge")
        track = PoseTrack(
            stamp_ns=chain.stamp_ns,
            position=chain.position,
            quat=chain.quat,
            geographic=False,
            frame_id=config.pose.tf.parent,
            child_frame_id=config.pose.tf.child,
            dropped={},
        )
    else:
        assert config.topics.pose is not None
        track = pose_track_from_samples(
            streams.pose_messages, topic=config.topics.pose, on_invalid=on_invalid
        )
    orientation = None
    if streams.orientation_messages:
        assert config.pose.orientation_topic is not None
        orientation = pose_track_from_samples(
            streams.orientation_messages,
            topic=config.pose.orientation_topic,
            on_invalid=on_invalid,
            kind="orientation",
        )
    if track.quat is None and orientation is None and config.pose.heading == "orientation":
        warnings.warn(
            "the pose topic carries no orientation (NavSatFix) and pose.orientation_topic is "
            "unset: heading is taken from motion; set pose.heading: motion to silence this",
            stacklevel=3,
        )
    world = _world_record(track, config, existing)
    traj = world_trajectory_from_track(track, config, world, orientation=orientation)
    return traj, world, track


# -- calibration ----------------------------------------------------------------------------------
_CALIBRATION_HINT = (
    "give the camera's calibration file (cam2sim run --calibration FILE) or set "
    "camera.intrinsics in config.yaml"
)


def _intrinsics(
    config: Config, camera_info: Any, size: tuple[int, int] | None
) -> CameraIntrinsics | None:
    """The camera's intrinsics: from config.yaml, a calibration file or the topic.

    ``camera.intrinsics``, else ``camera.calibration`` (fitted to the frames' ``size``), else
    the ``camera_info`` topic's (:class:`~cam2sim.core.config.CameraConfig`).
    """
    cfg = config.camera.intrinsics
    if cfg is not None:
        return CameraIntrinsics.from_camera(cfg.camera(), "config")
    if config.camera.calibration is not None:
        try:
            return intrinsics_from_file(Path(config.camera.calibration), size)[0]
        except RecordingError as err:
            msg = f"camera.calibration in config.yaml: {err}"
            raise RecordingError(msg) from None
    if camera_info is None:
        return None
    k = np.asarray(getattr(camera_info, "k", getattr(camera_info, "K", None)), dtype=float)
    d = np.asarray(getattr(camera_info, "d", getattr(camera_info, "D", ())), dtype=float)
    if k.size != 9 or not np.isfinite(k).all() or k[0] <= 0:
        msg = f"topics.camera_info has no valid K matrix; {_CALIBRATION_HINT}"
        raise RecordingError(msg)
    where = f"topics.camera_info {config.topics.camera_info}"
    model = model_named(where, camera_info.distortion_model) if d.any() else "plumb_bob"
    try:
        camera = PinholeCamera.from_K(
            k, int(camera_info.width), int(camera_info.height), d.tolist(), distortion_model=model
        )
    except ConfigError as err:
        msg = f"topics.camera_info: {err}; {_CALIBRATION_HINT}"
        raise RecordingError(msg) from None
    return CameraIntrinsics.from_camera(camera, f"camera_info topic {config.topics.camera_info}")


def _mount(
    cfg: MountConfig,
    *,
    want_axes: str,
    tf: TfTree,
    body_frame: str | None,
    config: Config,
    key: str,
) -> MountRecord:
    if cfg.tf_frame is not None:
        if not body_frame:
            msg = f"{key}.tf_frame is set but the body frame is unknown; set pose.body_frame"
            raise ConfigError(msg)
        T = tf.static_transform(body_frame, cfg.tf_frame)
        # /tf mounts are relative to the pose frame; turn them into the body frame (x forward).
        offset = AXIS_CONVENTION_YAW_OFFSET[config.pose.axis_convention]
        q_off_inv = frames.quat_conjugate(yaw_offset_quat(offset))
        translation = frames.quat_rotate(q_off_inv, T.position)
        quat = frames.quat_multiply(q_off_inv, T.quat)
        source = f"tf_static {body_frame} -> {cfg.tf_frame}"
    else:
        translation = np.asarray(cfg.xyz, dtype=float)
        roll, pitch, yaw = (math.radians(v) for v in cfg.rpy_deg)
        quat = frames.quat_from_euler(roll, pitch, yaw)
        source = "config"
    if cfg.axes == "link" and want_axes == "optical":
        quat = frames.quat_multiply(quat, frames.quat_from_matrix(R_LINK_OPTICAL))
    elif cfg.axes == "optical" and want_axes == "link":
        quat = frames.quat_multiply(quat, frames.quat_from_matrix(R_LINK_OPTICAL.T))
    quat = frames.quat_normalize(quat)
    t3 = tuple(float(v) for v in np.ravel(translation))
    q4 = tuple(float(v) for v in np.ravel(quat))
    return MountRecord(
        translation_m=(t3[0], t3[1], t3[2]),
        quat_xyzw=(q4[0], q4[1], q4[2], q4[3]),
        axes=want_axes,
        source=source,
    )


# -- pass 2: camera frames and LiDAR scans ----------------------------------------------------
@dataclass
class _SensorRows:
    stamp_ns: list[int]
    index: list[int]
    points: list[int] = field(default_factory=list)

    def add(self, index: int, stamp_ns: int, points: int = 0) -> None:
        """Record one kept sample."""
        self.index.append(index)
        self.stamp_ns.append(stamp_ns)
        self.points.append(points)


@dataclass(frozen=True)
class _SensorOutput:
    camera: _SensorRows
    lidar: _SensorRows
    dropped: dict[str, Counter[str]]
    frame_size: tuple[int, int] | None


class _FrameWriter:
    """Decode, encode and write camera frames on worker threads (OpenCV releases the GIL)."""

    def __init__(self, paths: DatasetPaths, config: Config) -> None:
        self.paths = paths
        self.fmt = config.frames.format
        self.quality = config.frames.jpeg_quality
        self.pool = ThreadPoolExecutor(max_workers=2, thread_name_prefix="cam2sim-frames")
        self.pending: list[Future[tuple[int, int]]] = []
        self.size: tuple[int, int] | None = None

    def _work(self, index: int, msgtype: str, msg: Any) -> tuple[int, int]:
        from cam2sim.recording.image import (  # noqa: PLC0415 -- lazy: imports cv2
            decode_compressed_image,
            decode_image,
            encode_image_file,
        )

        image = decode_compressed_image(msg) if msgtype == COMPRESSED else decode_image(msg)
        data = encode_image_file(image, self.fmt, jpeg_quality=self.quality)
        write_bytes_atomic(self.paths.frame_file(index, self.fmt), data)
        return int(image.shape[1]), int(image.shape[0])

    def submit(self, index: int, msgtype: str, msg: Any) -> None:
        self.pending.append(self.pool.submit(self._work, index, msgtype, msg))
        if len(self.pending) >= _PENDING_FRAMES:
            self._collect(self.pending.pop(0))

    def _collect(self, fut: Future[tuple[int, int]]) -> None:
        size = fut.result()
        if self.size is None:
            self.size = size
        elif size != self.size:
            msg = f"camera frame size changed from {self.size} to {size} within the recording"
            raise RecordingError(msg)

    def finish(self) -> None:
        try:
            for fut in self.pending:
                self._collect(fut)
        finally:
            self.pending.clear()
            self.pool.shutdown(wait=True, cancel_futures=True)


def _stream_sensors(
    rec: Recording,
    config: Config,
    traj: Trajectory,
    paths: DatasetPaths,
    progress: ProgressCallback,
    *,
    max_gap_s: float,
) -> _SensorOutput:
    topics = config.topics
    assert topics.camera is not None
    cam_info = rec.require_topic(topics.camera, key="topics.camera", msgtypes=CAMERA_MSGTYPES)
    wanted = [topics.camera]
    total = cam_info.count
    if topics.lidar:
        lidar_info = rec.require_topic(topics.lidar, key="topics.lidar", msgtypes=(POINTCLOUD2,))
        wanted.append(topics.lidar)
        total += lidar_info.count
    dropped: dict[str, Counter[str]] = {"camera": Counter(), "lidar": Counter()}
    cam_rows, lidar_rows = _SensorRows([], []), _SensorRows([], [])
    writer = _FrameWriter(paths, config)
    seen_camera = 0
    done = 0
    try:
        for m in rec.messages(wanted, time_base=config.recording.time_base):
            done += 1
            if done % 16 == 0:
                progress("frames and scans", done, total)
            query = np.array([m.stamp_ns], dtype=np.int64)
            if m.topic == topics.camera:
                seen_camera += 1
                if (seen_camera - 1) % config.frames.every:
                    continue
                s = traj.sample(query, max_gap_s=max_gap_s)
                if not s.valid[0]:
                    dropped["camera"][str(s.reason[0])] += 1
                    continue
                index = len(cam_rows.index)
                writer.submit(index, m.msgtype, m.msg)
                cam_rows.add(index, m.stamp_ns)
            else:
                s = traj.sample(query, max_gap_s=max_gap_s)
                if not s.valid[0]:
                    dropped["lidar"][str(s.reason[0])] += 1
                    continue
                points = decode_pointcloud(m.msg, drop_invalid=config.lidar.drop_invalid_points)
                if points.shape[0] == 0:
                    dropped["lidar"]["empty_scan"] += 1
                    continue
                index = len(lidar_rows.index)
                _save_npy(paths.lidar_file(index), points)
                lidar_rows.add(index, m.stamp_ns, int(points.shape[0]))
    finally:
        writer.finish()
    progress("frames and scans", done, total)
    return _SensorOutput(cam_rows, lidar_rows, dropped, writer.size)


def _save_npy(path: Path, array: npt.NDArray[Any]) -> None:
    with atomic_write(path) as handle:
        np.save(handle, array, allow_pickle=False)


# -- tables -----------------------------------------------------------------------------------
def _pose_columns(
    traj: Trajectory, stamps: npt.NDArray[np.int64], config: Config
) -> dict[str, npt.NDArray[Any]]:
    s = traj.sample(stamps, max_gap_s=math.inf, speed_window_s=config.sync.speed_window_s)
    return {
        "stamp_ns": stamps,
        "t": stamps / 1e9,
        "x": s.position[:, 0],
        "y": s.position[:, 1],
        "z": s.position[:, 2],
        "qx": s.quat[:, 0],
        "qy": s.quat[:, 1],
        "qz": s.quat[:, 2],
        "qw": s.quat[:, 3],
        "heading": s.heading,
        "speed": s.speed,
    }


def _write_tables(
    paths: DatasetPaths,
    traj: Trajectory,
    config: Config,
    cam: _SensorRows,
    lidar: _SensorRows,
    lidar_mount: MountRecord | None,
    signals: dict[str, SignalSeries],
) -> None:
    cam_stamps = np.asarray(cam.stamp_ns, dtype=np.int64)
    cols = {"frame": np.asarray(cam.index, dtype=np.int64)}
    cols.update(_pose_columns(traj, cam_stamps, config))
    write_table(paths.poses_csv, cols, precision=POSE_PRECISION)
    write_table(
        paths.trajectory_csv, _pose_columns(traj, traj.stamp_ns, config), precision=POSE_PRECISION
    )
    if config.topics.lidar and lidar_mount is not None:
        stamps = np.asarray(lidar.stamp_ns, dtype=np.int64)
        body = _pose_columns(traj, stamps, config)
        q_body = np.stack([body["qx"], body["qy"], body["qz"], body["qw"]], -1)
        p_body = np.stack([body["x"], body["y"], body["z"]], -1)
        mount_q = np.asarray(lidar_mount.quat_xyzw)
        p = p_body + frames.quat_rotate(q_body, np.asarray(lidar_mount.translation_m))
        q = frames.quat_multiply(q_body, mount_q) if len(stamps) else np.zeros((0, 4))
        points = lidar.points
        write_table(
            paths.lidar_csv,
            {
                "scan": np.asarray(lidar.index, dtype=np.int64),
                "stamp_ns": stamps,
                "t": stamps / 1e9,
                "x": p[:, 0] if len(stamps) else np.zeros(0),
                "y": p[:, 1] if len(stamps) else np.zeros(0),
                "z": p[:, 2] if len(stamps) else np.zeros(0),
                "qx": q[:, 0],
                "qy": q[:, 1],
                "qz": q[:, 2],
                "qw": q[:, 3],
                "points": np.asarray(points, dtype=np.int64),
            },
            precision=POSE_PRECISION,
        )
    for name, series in signals.items():
        write_table(
            paths.signal_file(name),
            {"stamp_ns": series.stamp_ns, "t": series.stamp_ns / 1e9, "value": series.value},
            precision=POSE_PRECISION,
        )


def _check_overlap(traj: Trajectory, cam: _SensorRows, dropped: Counter[str], topic: str) -> None:
    if cam.index:
        return
    total = sum(dropped.values())
    span = f"{traj.stamp_ns[0] / 1e9:.3f}-{traj.stamp_ns[-1] / 1e9:.3f} s"
    if total == 0:
        msg = f"camera topic {topic} has no messages; choose another camera topic"
    else:
        reasons = ", ".join(f"{n} {r}" for r, n in dropped.items())
        msg = (
            f"no camera frame of {topic} has a pose: {reasons} (poses cover {span}). The camera "
            "and pose topics do not overlap in time: check the topics, or try "
            "recording.time_base: receive if one sensor's header clock is off; raise "
            "sync.max_pose_gap_s if poses have long gaps"
        )
    raise RecordingError(msg)


def extract(
    ws: Workspace, *, force: bool = False, progress: ProgressCallback | None = None
) -> ExtractResult:
    """Extract the configured topics of the workspace's recording into ``WS/dataset/``.

    Args:
        ws: The workspace (``config.yaml`` says which bags and topics).
        force: Re-extract even when the inputs did not change.
        progress: Optional progress callback.

    Returns:
        :class:`ExtractResult` with the dataset description.

    Raises:
        ConfigError: The config lacks a needed topic or is inconsistent.
        RecordingError: The recording cannot be read as configured (missing topic, corrupt bag,
            NaN poses, clock running backwards, no overlap between camera and poses).
    """
    progress = progress or no_progress
    config = ws.load_config()
    if config.topics.camera is None:
        msg = "topics.camera is not set in config.yaml; name the camera topic (cam2sim inspect)"
        raise ConfigError(msg)
    bag_paths = _bag_paths(ws, config)
    calibration = [Path(config.camera.calibration)] if config.camera.calibration else []
    sources = _fingerprints([p for p in [*bag_paths, *calibration] if p.exists()])
    inputs_hash = _inputs_hash(config, sources)
    if not force and ws.is_up_to_date(STAGE, inputs_hash):
        logger.info("extract: dataset is up to date; skipping (use force to redo)")
        return ExtractResult(
            ws.dataset_dir,
            DatasetInfo.load(DatasetPaths(ws.dataset_dir).dataset_json),
            skipped=True,
        )
    with (
        stage_run(ws, STAGE, inputs_hash=inputs_hash, config=config) as run,
        Recording(bag_paths) as rec,
        atomic_folder(ws.dataset_dir) as tmp,
    ):
        paths = DatasetPaths(tmp)
        progress("poses and signals", 0, None)
        streams = _read_small_streams(rec, config)
        traj, world, track = _read_trajectory(streams, config, ws.world_frame())
        progress("poses and signals", len(traj), len(traj))
        body_frame = config.pose.body_frame or (
            config.pose.tf.child if config.pose.tf else track.child_frame_id
        )
        camera_mount = _mount(
            config.camera.mount,
            want_axes="optical",
            tf=streams.tf,
            body_frame=body_frame,
            config=config,
            key="camera.mount",
        )
        lidar_mount = (
            _mount(
                config.lidar.mount,
                want_axes="link",
                tf=streams.tf,
                body_frame=body_frame,
                config=config,
                key="lidar.mount",
            )
            if config.topics.lidar
            else None
        )
        gap = gap_limit_s(track.stamp_ns, config.sync.max_pose_gap_s)  # 1 Hz GPS: 2.5 s
        out = _stream_sensors(rec, config, traj, paths, progress, max_gap_s=gap)
        cam, lidar, dropped, size = out.camera, out.lidar, out.dropped, out.frame_size
        _check_overlap(traj, cam, dropped["camera"], config.topics.camera)
        _write_tables(paths, traj, config, cam, lidar, lidar_mount, streams.signals)
        intrinsics = _intrinsics(config, streams.camera_info, size)
        if intrinsics is None:
            warnings.warn(
                "no camera intrinsics: give the camera's calibration file (cam2sim run "
                "--calibration FILE), or set camera.intrinsics or topics.camera_info in "
                "config.yaml (the splat stage can estimate them, other stages need them)",
                stacklevel=2,
            )
        elif size is not None and (intrinsics.width, intrinsics.height) != size:
            warnings.warn(
                f"camera intrinsics are for {intrinsics.width}x{intrinsics.height} but frames "
                f"are {size[0]}x{size[1]}; fix camera.intrinsics",
                stacklevel=2,
            )
        if intrinsics is not None:  # a grey camera's simulated views are made grey too
            frames = sorted(paths.frames_dir.glob("*")) if paths.frames_dir.is_dir() else []
            intrinsics = intrinsics.model_copy(update={"grey": frames_are_grey(frames)})
        Calibration(camera=intrinsics, camera_mount=camera_mount, lidar_mount=lidar_mount).save(
            paths.calibration_json
        )
        info = _dataset_info(config, sources, traj, out, track, streams, world)
        info.save(paths.dataset_json)
        run.world = world
    logger.info(
        "extract: %d frames, %d pose samples, %d LiDAR scans",
        len(cam.index),
        len(traj),
        len(lidar.index),
    )
    return ExtractResult(ws.dataset_dir, info, skipped=False)


def _dataset_info(
    config: Config,
    sources: list[SourceRecord],
    traj: Trajectory,
    out: _SensorOutput,
    track: PoseTrack,
    streams: _SmallStreams,
    world: WorldFrameRecord,
) -> DatasetInfo:
    topics = config.topics
    roles = {"camera": topics.camera, "pose": topics.pose, "lidar": topics.lidar}
    roles.update({f"signal:{k}": v.topic for k, v in topics.signals.items()})
    cam, lidar = out.camera, out.lidar
    all_dropped = {k: dict(v) for k, v in out.dropped.items() if v}
    if track.dropped:
        all_dropped["pose"] = dict(track.dropped)
    start, end = cam.stamp_ns[0], cam.stamp_ns[-1]
    return DatasetInfo(
        kind="bag",
        sources=tuple(sources),
        time_base=config.recording.time_base,
        topics={k: v for k, v in roles.items() if v},
        counts=DatasetCounts(
            frames=len(cam.index),
            pose_samples=len(traj),
            lidar_scans=len(lidar.index),
            signals={k: int(v.stamp_ns.shape[0]) for k, v in streams.signals.items()},
        ),
        start_ns=int(start),
        end_ns=int(end),
        duration_s=(end - start) / 1e9,
        dropped=all_dropped,
        frame_format=config.frames.format,
        world=world,
        heading_from_motion=config.pose.heading == "motion"
        or (track.quat is None and not config.pose.orientation_topic),
    )
