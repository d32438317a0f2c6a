"""The recording config (``WS/config.yaml``): YAML validated with pydantic.

The config says which topics hold what, in which conventions, and how to cut and synchronise the
recording. ``cam2sim init`` writes a starter file guessed from the bag; the user edits it. Errors
name the key, the value found and the fix.
"""

from __future__ import annotations

import difflib
import math
from enum import StrEnum
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal, Self

import pydantic
import yaml

from cam2sim.core.errors import ConfigError
from cam2sim.core.files import write_text_atomic

if TYPE_CHECKING:
    from cam2sim.core.camera import PinholeCamera

__all__ = [
    "AXIS_CONVENTION_YAW_OFFSET",
    "AxisConvention",
    "CameraConfig",
    "Config",
    "FramesConfig",
    "IntrinsicsConfig",
    "LidarConfig",
    "MountConfig",
    "PoseConfig",
    "RecordingConfig",
    "SignalConfig",
    "SyncConfig",
    "TfLink",
    "TopicsConfig",
    "config_to_yaml",
    "load_config",
    "read_yaml",
    "save_config",
]

CONFIG_SCHEMA_VERSION = 1


class AxisConvention(StrEnum):
    """Which way the pose frame's x axis points on the vehicle.

    The vehicle's forward axis is the pose frame's x axis turned about its z axis by
    :data:`AXIS_CONVENTION_YAW_OFFSET`. The reference car's odometry has x to the left, so its
    heading is yaw - 90 degrees.
    """

    X_FORWARD = "x_forward"
    X_LEFT = "x_left"
    X_RIGHT = "x_right"
    X_BACKWARD = "x_backward"


AXIS_CONVENTION_YAW_OFFSET: dict[AxisConvention, float] = {
    AxisConvention.X_FORWARD: 0.0,
    AxisConvention.X_LEFT: -math.pi / 2,
    AxisConvention.X_RIGHT: math.pi / 2,
    AxisConvention.X_BACKWARD: math.pi,
}


class _Model(pydantic.BaseModel):
    model_config = pydantic.ConfigDict(extra="forbid", frozen=True)


class RecordingConfig(_Model):
    """Where the recording is and which clock to trust."""

    bags: list[str] = pydantic.Field(
        default_factory=list,
        description="Bag files or folders (ROS1 .bag, ROS2 folder, .mcap), relative to the "
        "workspace or absolute. Several files are read as one recording.",
    )
    time_base: Literal["header", "receive"] = pydantic.Field(
        "header",
        description="header: message header.stamp (the sensor's time). receive: the bag's record "
        "time (arrives in bursts; use only when headers are unset).",
    )


class SignalConfig(_Model):
    """A scalar signal: any numeric field of any message type."""

    topic: str
    field: str = pydantic.Field("data", description="Dotted field path, e.g. data or drive.speed")


class TopicsConfig(_Model):
    """Which topic holds what."""

    camera: str | None = None
    camera_info: str | None = None
    pose: str | None = None
    lidar: str | None = None
    signals: dict[str, SignalConfig] = pydantic.Field(default_factory=dict)


class TfLink(_Model):
    """Two frames of the /tf tree: the transform maps child coordinates into parent ones."""

    parent: str
    child: str


class PoseConfig(_Model):
    """How ego poses are read and which conventions they use."""

    source: Literal["message", "tf"] = pydantic.Field(
        "message",
        description="message: the topics.pose topic (Odometry, PoseStamped, "
        "PoseWithCovarianceStamped, NavSatFix). tf: the chain tf.parent -> tf.child in /tf.",
    )
    crs: str | None = pydantic.Field(
        None,
        description="CRS of the pose positions, e.g. EPSG:32632 when odometry is UTM 32N. "
        "null: a local metric frame without geo-reference. NavSatFix is always WGS84.",
    )
    axis_convention: AxisConvention = AxisConvention.X_FORWARD
    tf: TfLink | None = None
    heading: Literal["orientation", "motion"] = pydantic.Field(
        "orientation",
        description="orientation: from the message's quaternion (or orientation_topic for "
        "NavSatFix). motion: from the direction of travel.",
    )
    orientation_topic: str | None = pydantic.Field(
        None, description="For NavSatFix: a topic with an ENU orientation (Imu, Odometry, Pose)."
    )
    on_invalid: Literal["error", "drop"] = pydantic.Field(
        "error", description="What to do with NaN/inf poses or NavSatFix without a fix."
    )
    body_frame: str | None = pydantic.Field(
        None,
        description="tf frame of the vehicle reference point (for mounts from /tf_static); "
        "defaults to the odometry child_frame_id or tf.child.",
    )


class SyncConfig(_Model):
    """How sensor samples are matched to poses."""

    max_pose_gap_s: float = pydantic.Field(
        0.5,
        gt=0,
        description="Drop frames inside a pose gap longer than this (and than 2.5 of the pose "
        "source's own median interval: a 1 Hz GPS's missing fix is bridged).",
    )
    speed_window_s: float = pydantic.Field(
        0.2, gt=0, description="Speed = distance travelled over this window / window."
    )
    min_motion_speed_mps: float = pydantic.Field(
        0.5, ge=0, description="Heading from motion is held below this speed."
    )
    heading_window_s: float = pydantic.Field(
        1.0,
        gt=0,
        description="Heading from motion = direction of the chord over this window, centred "
        "on the pose. A centred chord of a steady turn is parallel to its tangent, so a long "
        "window costs little in turns and averages GPS noise (0.1 m of noise: 0.9 degrees "
        "with 1 s, 4.4 with 0.2 s at 8 m/s).",
    )
    pitch_window_m: float = pydantic.Field(
        15.0,
        gt=0,
        description="Pitch from motion (poses without orientation) = the path's grade over a "
        "chord of this many metres of travel, centred on the pose: a car pitches with its "
        "road, and the splat camera leans with the recorded pitch (0.1 m of height noise: "
        "0.5 degrees).",
    )


class IntrinsicsConfig(_Model):
    """Pinhole intrinsics and lens distortion (OpenCV plumb-bob order k1, k2, p1, p2, k3)."""

    fx: float = pydantic.Field(gt=0)
    fy: float = pydantic.Field(gt=0)
    cx: float
    cy: float
    width: int = pydantic.Field(gt=0)
    height: int = pydantic.Field(gt=0)
    distortion: list[float] = pydantic.Field(default_factory=list)
    model: Literal["plumb_bob", "equidistant"] = "plumb_bob"

    def camera(self) -> PinholeCamera:
        """These intrinsics as the one camera type."""
        from cam2sim.core.camera import PinholeCamera  # noqa: PLC0415 -- lazy: imports numpy (keeps --help fast)

        return PinholeCamera(
            fx=self.fx,
            fy=self.fy,
            cx=self.cx,
            cy=self.cy,
            width=self.width,
            height=self.height,
            distortion=tuple(self.distortion),
            distortion_model=self.model,
        )


class MountConfig(_Model):
    """Where a sensor sits relative to the vehicle reference point (the pose's origin).

    Either ``xyz`` (metres) and ``rpy_deg`` in the vehicle frame (x forward, y left, z up), or
    ``tf_frame``: read from /tf_static between the body frame and this frame. ``axes`` says
    whether the sensor frame is a link frame (x forward, y left, z up) or an optical camera frame
    (x right, y down, z forward).
    """

    xyz: tuple[float, float, float] = (0.0, 0.0, 0.0)
    rpy_deg: tuple[float, float, float] = (0.0, 0.0, 0.0)
    tf_frame: str | None = None
    axes: Literal["link", "optical"] = "link"


class CameraConfig(_Model):
    """Camera calibration: intrinsics (or topics.camera_info) and mount."""

    intrinsics: IntrinsicsConfig | None = None
    calibration: str | None = pydantic.Field(
        None,
        description="a calibration file as a tool wrote it (ROS camera_info or OpenCV YAML, "
        "Kalibr, COLMAP cameras.txt, a K.txt...), read by extract for the frames' size; "
        "intrinsics, when given, come first, then this, then topics.camera_info",
    )
    mount: MountConfig = MountConfig()


class LidarConfig(_Model):
    """LiDAR mount and decoding options."""

    mount: MountConfig = MountConfig()
    drop_invalid_points: bool = True


class VehicleConfig(_Model):
    """The ego vehicle's geometry: where the recorded pose sits on the car.

    Vehicle frame: origin at the centre of the vehicle's footprint on the ground, x forward, y
    left, z up. The recorded pose (odometry, base_link) is the ``reference`` point; the
    scenario stage derives the centre and the rear axle from it with these numbers, once.
    Defaults: CARLA's ``vehicle.tesla.model3`` (the published tool's hero), whose rear axle is
    1.393 m behind its centre, and a recorded pose on the rear axle (ROS ``base_link``).
    """

    length_m: float = pydantic.Field(4.79, gt=0)
    width_m: float = pydantic.Field(2.16, gt=0)
    height_m: float = pydantic.Field(1.49, gt=0)
    wheelbase_m: float = pydantic.Field(2.875, gt=0)
    rear_axle_x_m: float = pydantic.Field(
        -1.393, description="rear axle position along x from the centre (negative: behind)"
    )
    reference: Literal["rear_axle", "center", "offset"] = pydantic.Field(
        "rear_axle", description="which point of the car the recorded pose is"
    )
    reference_offset_m: tuple[float, float, float] = pydantic.Field(
        (0.0, 0.0, 0.0),
        description="reference point in the vehicle frame when reference is 'offset'",
    )

    def reference_xyz(self) -> tuple[float, float, float]:
        """The recorded reference point in the vehicle (centre) frame, metres."""
        if self.reference == "rear_axle":
            return (self.rear_axle_x_m, 0.0, 0.0)
        if self.reference == "center":
            return (0.0, 0.0, 0.0)
        return self.reference_offset_m

    def reference_ahead_of_rear_axle_m(self) -> float:
        """How far ahead of the rear axle the recorded reference point sits, metres."""
        return self.reference_xyz()[0] - self.rear_axle_x_m


class FramesConfig(_Model):
    """How camera frames are written."""

    format: Literal["png", "jpeg"] = "png"
    jpeg_quality: int = pydantic.Field(95, ge=1, le=100)
    every: int = pydantic.Field(1, ge=1, description="Keep every n-th camera frame.")


class Config(_Model):
    """The whole recording config of a workspace."""

    schema_version: int = CONFIG_SCHEMA_VERSION
    recording: RecordingConfig = RecordingConfig()
    topics: TopicsConfig = TopicsConfig()
    pose: PoseConfig = PoseConfig()
    sync: SyncConfig = SyncConfig()
    camera: CameraConfig = CameraConfig()
    lidar: LidarConfig = LidarConfig()
    frames: FramesConfig = FramesConfig()
    vehicle: VehicleConfig = VehicleConfig()
    carla: dict[str, Any] = pydantic.Field(
        default_factory=dict,
        description="CARLA backend options (host, port, timeout_s, mesh, blueprints, ...); "
        "see cam2sim.sim.carla_backend.CarlaOptions",
    )

    @pydantic.model_validator(mode="after")
    def _check_consistency(self) -> Self:
        if self.pose.source == "tf" and self.pose.tf is None:
            msg = (
                "pose.source is 'tf' but pose.tf is not set; add pose.tf: {parent: ..., child: ...}"
            )
            raise ValueError(msg)
        return self

    def section_dict(self, *names: str) -> dict[str, object]:
        """Return the named top-level sections as plain data (for input hashing)."""
        data = self.model_dump(mode="json")
        return {name: data[name] for name in names}


def _fields_at(loc: tuple[int | str, ...]) -> set[str]:
    """Return the field names of the config section at ``loc`` (for spelling suggestions)."""
    model: type[pydantic.BaseModel] = Config
    for part in loc:
        field = model.model_fields.get(str(part))
        annotation = field.annotation if field else None
        candidates = [a for a in getattr(annotation, "__args__", (annotation,)) if a]
        nested = [
            c for c in candidates if isinstance(c, type) and issubclass(c, pydantic.BaseModel)
        ]
        if not nested:
            return set()
        model = nested[0]
    return set(model.model_fields)


def _error_message(err: pydantic.ValidationError, source: str) -> str:
    parts = []
    for item in err.errors():
        loc = ".".join(str(p) for p in item["loc"])
        text = f"{loc or '<root>'}: {item['msg']}"
        if item["type"] == "extra_forbidden":
            last = str(item["loc"][-1])
            candidates = _fields_at(item["loc"][:-1])
            close = difflib.get_close_matches(last, candidates, n=1)
            text = f"{loc}: unknown key" + (f" (did you mean {close[0]!r}?)" if close else "")
            text += "; remove it or fix its spelling"
        elif "input" in item and item["type"] != "missing":
            text += f" (found {item['input']!r})"
        parts.append(text)
    return f"{source}: invalid config: " + "; ".join(parts)


def read_yaml(path: Path, *, missing: str) -> Any:
    """The YAML document in ``path`` (None when it is empty).

    Raises:
        ConfigError: The file is missing (the message ends with ``missing``, what to do) or is
            not YAML (the message points at the line).
    """
    try:
        return yaml.safe_load(Path(path).read_text(encoding="utf-8"))
    except FileNotFoundError:
        msg = f"{path} does not exist; {missing}"
        raise ConfigError(msg) from None
    except yaml.YAMLError as err:
        msg = f"{path}: not valid YAML ({err}); fix the syntax at the line shown"
        raise ConfigError(msg) from None


def load_config(path: Path) -> Config:
    """Read and validate a ``config.yaml``.

    Raises:
        ConfigError: The file is missing, not YAML, or a key is invalid; the message names the
            key and the fix.
    """
    path = Path(path)
    raw = read_yaml(path, missing="create the workspace with `cam2sim init WS --bag BAG`")
    if raw is None:
        raw = {}
    if not isinstance(raw, dict):
        msg = f"{path}: expected a mapping of sections at the top level, found {type(raw).__name__}"
        raise ConfigError(msg)
    version = raw.get("schema_version", CONFIG_SCHEMA_VERSION)
    if isinstance(version, int) and version > CONFIG_SCHEMA_VERSION:
        msg = (
            f"{path}: schema_version {version} is newer than this cam2sim understands "
            f"({CONFIG_SCHEMA_VERSION}); upgrade cam2sim"
        )
        raise ConfigError(msg)
    try:
        return Config.model_validate(raw)
    except pydantic.ValidationError as err:
        raise ConfigError(_error_message(err, str(path))) from None


_HEADER = """\
# cam2sim recording config. Edit it, then run `cam2sim extract WS`.
# Paths are relative to this workspace folder. Units: metres, seconds, degrees where the key
# says _deg. Conventions:
#   pose.crs: CRS of the pose positions (EPSG:32632 for UTM 32N odometry); null = local frame.
#   pose.axis_convention: where the pose frame's x axis points on the car (x_forward, x_left,
#     x_right, x_backward). The reference car's odometry has x to the left: x_left.
#   camera.mount / lidar.mount: sensor position (xyz, m) and rpy_deg relative to the pose's
#     reference point, in the vehicle frame (x forward, y left, z up); or tf_frame to read it
#     from /tf_static.
#   vehicle: the ego car's size and where the recorded pose sits on it (reference: rear_axle,
#     center, or offset with reference_offset_m); rear_axle_x_m is the rear axle's position
#     from the car's centre (negative = behind). Used by `cam2sim scenario`.
#   carla: the CARLA server and world for `--sim carla` (host, port, timeout_s, vertex_distance,
#     blueprints per size class, ...); empty = defaults (localhost:2000).
"""


class _ConfigDumper(yaml.SafeDumper):
    """Block style for sections, flow style for short lists such as ``xyz: [0, 0, 1.5]``."""


def _represent_list(dumper: yaml.SafeDumper, data: list[object]) -> yaml.Node:
    return dumper.represent_sequence("tag:yaml.org,2002:seq", data, flow_style=True)


_ConfigDumper.add_representer(list, _represent_list)


def config_to_yaml(config: Config, *, comment: str = "") -> str:
    """Render a config as commented YAML (the format ``cam2sim init`` writes)."""
    body = yaml.dump(
        config.model_dump(mode="json"), Dumper=_ConfigDumper, sort_keys=False, width=100
    )
    extra = "".join(f"# {line}\n" for line in comment.splitlines())
    return _HEADER + extra + body


def save_config(config: Config, path: Path, *, comment: str = "") -> None:
    """Write a config atomically as commented YAML."""
    write_text_atomic(Path(path), config_to_yaml(config, comment=comment))
