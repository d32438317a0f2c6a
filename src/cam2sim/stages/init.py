"""``cam2sim init``: create a workspace and a starter config guessed from the recording."""

from __future__ import annotations

import logging
import re
from dataclasses import dataclass
from typing import TYPE_CHECKING

from cam2sim.core.config import (
    Config,
    PoseConfig,
    RecordingConfig,
    SignalConfig,
    TopicsConfig,
)
from cam2sim.core.workspace import Workspace
from cam2sim.recording.bag import Recording, TopicInfo
from cam2sim.recording.pose import NAVSATFIX, POSE_MSGTYPES

if TYPE_CHECKING:
    from collections.abc import Sequence
    from pathlib import Path

__all__ = ["InitResult", "config_from_topics", "init_workspace"]

logger = logging.getLogger(__name__)

_CAMERA_TYPES = ("sensor_msgs/msg/Image", "sensor_msgs/msg/CompressedImage")
_SCALAR_TYPES = tuple(
    f"std_msgs/msg/{t}"
    for t in (
        "Float32",
        "Float64",
        "Int8",
        "Int16",
        "Int32",
        "Int64",
        "UInt8",
        "UInt16",
        "UInt32",
        "UInt64",
    )
)
_CAMERA_HINTS = ("front", "center", "narrow", "rgb", "color")
_DEPRIORITISED = ("depth", "ir", "mask", "seg", "debug", "thumb")


@dataclass(frozen=True)
class InitResult:
    """The new workspace and what was guessed, with notes for the user."""

    workspace: Workspace
    config: Config
    notes: tuple[str, ...]


def _camera_score(t: TopicInfo) -> tuple[int, int, int, int]:
    name = t.name.lower()
    hint = sum(h in name for h in _CAMERA_HINTS)
    bad = sum(h in name for h in _DEPRIORITISED)
    raw = t.msgtype.endswith("/Image")
    return (-bad, hint, int(raw), t.count)


def _signal_name(topic: str, taken: set[str]) -> str:
    base = re.sub(r"[^A-Za-z0-9_]", "_", topic.strip("/").split("/")[-1]) or "signal"
    name, i = base, 2
    while name in taken:
        name, i = f"{base}_{i}", i + 1
    return name


def config_from_topics(
    topics: dict[str, TopicInfo], bags: Sequence[str]
) -> tuple[Config, list[str]]:
    """Guess camera, pose, LiDAR and scalar topics from message types.

    Returns:
        The starter config and notes saying what was guessed and what to check.
    """
    notes: list[str] = []
    cams = sorted((t for t in topics.values() if t.msgtype in _CAMERA_TYPES), key=_camera_score)
    camera = cams[-1].name if cams else None
    if len(cams) > 1:
        others = ", ".join(t.name for t in cams[:-1])
        notes.append(f"camera: chose {camera}; other camera topics: {others}")
    elif not cams:
        notes.append("camera: no Image or CompressedImage topic; set topics.camera")
    infos = [t for t in topics.values() if t.msgtype == "sensor_msgs/msg/CameraInfo"]
    camera_info = None
    if infos and camera:
        prefix = camera.rsplit("/", 1)[0]
        same = [t for t in infos if t.name.startswith(prefix)]
        camera_info = (same or infos)[0].name
    rank = {m: i for i, m in enumerate(POSE_MSGTYPES)}
    poses = sorted(
        (t for t in topics.values() if t.msgtype in rank), key=lambda t: (rank[t.msgtype], -t.count)
    )
    pose = poses[0].name if poses else None
    pose_cfg = PoseConfig()
    if pose is None:
        if "/tf" in topics:
            notes.append("pose: no pose topic; set pose.source: tf and pose.tf {parent, child}")
        else:
            notes.append("pose: no pose topic; extraction needs one (or use cam2sim import)")
    elif poses[0].msgtype == NAVSATFIX:
        pose_cfg = PoseConfig(heading="motion")
        notes.append(f"pose: {pose} is NavSatFix; heading comes from motion")
    else:
        notes.append(
            f"pose: {pose}; set pose.crs if its positions are geographic (e.g. EPSG:32632 for "
            "UTM 32N odometry) and pose.axis_convention if its x axis is not forward"
        )
    clouds = sorted(
        (t for t in topics.values() if t.msgtype == "sensor_msgs/msg/PointCloud2"),
        key=lambda t: t.count,
    )
    lidar = clouds[-1].name if clouds else None
    signals: dict[str, SignalConfig] = {}
    for t in topics.values():
        if t.msgtype in _SCALAR_TYPES:
            signals[_signal_name(t.name, set(signals))] = SignalConfig(topic=t.name, field="data")
    if signals:
        hint = (
            ""
            if "steering" in signals
            else " (name the steering one 'steering': DAVE-2 trains on it)"
        )
        notes.append(f"signals: {', '.join(signals)}{hint}")
    config = Config(
        recording=RecordingConfig(bags=list(bags)),
        topics=TopicsConfig(
            camera=camera, camera_info=camera_info, pose=pose, lidar=lidar, signals=signals
        ),
        pose=pose_cfg,
    )
    return config, notes


def init_workspace(root: Path, bags: Sequence[Path], *, force: bool = False) -> InitResult:
    """Create a workspace for a recording with a starter ``config.yaml``.

    Args:
        root: The workspace folder to create.
        bags: The recording's bag files or folders.
        force: Overwrite the config of an existing workspace.

    Raises:
        RecordingError: A bag cannot be read.
        WorkspaceError: ``root`` is already a workspace and ``force`` is false.
    """
    with Recording(bags) as rec:
        topics = rec.topics()
    config, notes = config_from_topics(topics, [str(p.absolute()) for p in bags])
    comment = "Guessed by cam2sim init:\n" + "\n".join(f"  - {n}" for n in notes)
    ws = Workspace.create(root, config, comment=comment, force=force)
    logger.info("init: workspace %s with %d topics guessed", ws.root, len(topics))
    return InitResult(workspace=ws, config=config, notes=tuple(notes))
