"""``WS/scenario/scenario.json``: what a simulator needs to replay or drive the recorded street.

Everything is in the workspace's world frame (x east, y north, z up, metres; headings in
radians counter-clockwise from east), which is also the OpenDRIVE map's inertial frame: the
map's ``<geoReference>`` is the world frame's projection string.
"""

from __future__ import annotations

from typing import Literal

import pydantic

from cam2sim.core.dataset import CameraIntrinsics, MountRecord
from cam2sim.core.schema import Artifact
from cam2sim.core.vehicle import SteeringCalibration
from cam2sim.core.workspace import WorldFrameRecord

__all__ = [
    "BodyPoint",
    "HeroStart",
    "Rejection",
    "Scenario",
    "ScenarioTrajectory",
    "ScenarioVehicle",
    "SizeClass",
    "VehicleGeometry",
]

BodyPoint = Literal["reference", "center", "rear_axle"]
SizeClass = Literal["small", "medium", "large", "van"]

_Model = pydantic.ConfigDict(extra="forbid", frozen=True)


class VehicleGeometry(pydantic.BaseModel):
    """The ego vehicle (from ``config.yaml``'s ``vehicle`` block).

    Points are in the vehicle frame: origin at the centre of the footprint on the ground, x
    forward, y left, z up.
    """

    model_config = _Model

    length_m: float
    width_m: float
    height_m: float
    wheelbase_m: float
    reference_xyz: tuple[float, float, float] = pydantic.Field(
        description="the recorded pose's point (e.g. the rear axle) in the vehicle frame"
    )
    rear_axle_xyz: tuple[float, float, float]


class ScenarioTrajectory(pydantic.BaseModel):
    """The recorded drive at every kept camera frame, at three body points.

    ``reference`` is the recorded pose itself; ``center`` and ``rear_axle`` follow from the
    vehicle geometry. All three share ``heading`` (the vehicle is rigid).
    """

    model_config = _Model

    heading_source: Literal["orientation", "motion"]
    frame: tuple[int, ...] = pydantic.Field(description="dataset frame index per sample")
    stamp_ns: tuple[int, ...]
    t: tuple[float, ...] = pydantic.Field(description="seconds since the first sample")
    heading: tuple[float, ...]
    speed: tuple[float, ...] = pydantic.Field(description="m/s")
    reference: tuple[tuple[float, float, float], ...]
    center: tuple[tuple[float, float, float], ...]
    rear_axle: tuple[tuple[float, float, float], ...]
    roll: tuple[float, ...] | None = pydantic.Field(
        default=None,
        description="recorded roll of the vehicle, rad (ROS ZYX); None: not recorded (level)",
    )
    pitch: tuple[float, ...] | None = pydantic.Field(
        default=None,
        description="recorded pitch of the vehicle, rad (ROS ZYX, positive nose down); None: "
        "not recorded (level)",
    )

    @pydantic.model_validator(mode="after")
    def _same_length(self) -> ScenarioTrajectory:
        n = len(self.frame)
        columns = ("stamp_ns", "t", "heading", "speed", "reference", "center", "rear_axle")
        lengths = {
            k: len(getattr(self, k))
            for k in (*columns, "roll", "pitch")
            if getattr(self, k) is not None
        }
        bad = {k: v for k, v in lengths.items() if v != n}
        if bad:
            msg = f"trajectory columns must all have {n} samples; got {bad}"
            raise ValueError(msg)
        if n < 2:
            msg = "a scenario trajectory needs at least two samples"
            raise ValueError(msg)
        return self

    def points(self, body_point: BodyPoint) -> tuple[tuple[float, float, float], ...]:
        """The positions of one body point."""
        out: tuple[tuple[float, float, float], ...] = getattr(self, body_point)
        return out


class HeroStart(pydantic.BaseModel):
    """Where the ego vehicle starts: its centre on the road surface and its heading."""

    model_config = _Model

    position: tuple[float, float, float] = pydantic.Field(
        description="vehicle centre on the road surface (z of the map's plan view, 0)"
    )
    heading: float
    speed: float = pydantic.Field(description="recorded speed at the start, m/s")


class ScenarioVehicle(pydantic.BaseModel):
    """A parked vehicle to spawn (stationary)."""

    model_config = _Model

    id: str
    position: tuple[float, float, float] = pydantic.Field(description="bottom centre, world")
    heading: float
    size: tuple[float, float, float] = pydantic.Field(description="length, width, height")
    size_class: SizeClass
    side: Literal["left", "right"]
    orientation: Literal["parallel", "perpendicular"]


class Rejection(pydantic.BaseModel):
    """A parked vehicle left out of the scenario, and why."""

    model_config = _Model

    id: str
    reasons: tuple[str, ...]


class Scenario(Artifact):
    """``scenario.json``."""

    map_file: str | None = pydantic.Field(
        description="OpenDRIVE map, relative to the workspace (null without a map)"
    )
    world: WorldFrameRecord
    vehicle: VehicleGeometry
    trajectory: ScenarioTrajectory
    hero_start: HeroStart
    parked: tuple[ScenarioVehicle, ...]
    rejected: tuple[Rejection, ...] = ()
    camera: CameraIntrinsics | None = None
    camera_mount: MountRecord = pydantic.Field(
        description="camera pose relative to the recorded reference point (optical axes)"
    )
    steering_calibration: SteeringCalibration = pydantic.Field(
        default_factory=SteeringCalibration,
        description="steering command unit -> path curvature (fitted from the recording)",
    )
