"""The CARLA boundary: world (right-handed ENU) <-> CARLA/Unreal (left-handed)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, overload

import numpy as np

from cam2sim.core.frames._common import _FLIP_Y, _as_float, _as_vectors
from cam2sim.core.frames.pose import Pose
from cam2sim.core.frames.rotation import _wrap_period, euler_from_quat, quat_from_euler

if TYPE_CHECKING:
    import numpy.typing as npt

__all__ = [
    "CarlaTransform",
    "carla_to_world",
    "carla_yaw_deg_to_heading",
    "heading_to_carla_yaw_deg",
    "pose_from_carla",
    "pose_to_carla",
    "world_to_carla",
]

# --------------------------------------------------------------------------------------------
# CARLA boundary
# --------------------------------------------------------------------------------------------


def world_to_carla(xyz: npt.ArrayLike) -> npt.NDArray[np.float64]:
    """Convert ``(..., 3)`` world points (x east, y north, z up; metres) to CARLA (y flipped)."""
    return _as_vectors(xyz, 3, "xyz") * _FLIP_Y


def carla_to_world(xyz_carla: npt.ArrayLike) -> npt.NDArray[np.float64]:
    """Convert ``(..., 3)`` CARLA locations (left-handed, metres) to world points."""
    return _as_vectors(xyz_carla, 3, "xyz_carla") * _FLIP_Y


@overload
def heading_to_carla_yaw_deg(heading: float) -> float: ...
@overload
def heading_to_carla_yaw_deg(heading: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]: ...
def heading_to_carla_yaw_deg(
    heading: float | npt.NDArray[np.float64],
) -> float | npt.NDArray[np.float64]:
    """Convert world headings (rad, CCW) to CARLA yaw (degrees, clockwise) in ``[-180, 180)``."""
    out = _wrap_period(-np.degrees(_as_float(heading, "heading")), 180.0)
    return float(out) if np.ndim(heading) == 0 else out


@overload
def carla_yaw_deg_to_heading(yaw_deg: float) -> float: ...
@overload
def carla_yaw_deg_to_heading(yaw_deg: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]: ...
def carla_yaw_deg_to_heading(
    yaw_deg: float | npt.NDArray[np.float64],
) -> float | npt.NDArray[np.float64]:
    """Convert CARLA yaw (degrees, clockwise) to world headings (rad, CCW) in ``[-π, π)``."""
    out = _wrap_period(-np.radians(_as_float(yaw_deg, "yaw_deg")), math.pi)
    return float(out) if np.ndim(yaw_deg) == 0 else out


@dataclass(frozen=True, eq=False)
class CarlaTransform:
    """A pose in CARLA's terms (the fields of ``carla.Transform``).

    Attributes:
        location: ``(3,)`` float64 metres in CARLA's left-handed frame (y = -world y).
        pitch_deg: Nose up positive, in ``[-90, 90]``.
        yaw_deg: Clockwise seen from above, in ``[-180, 180)``.
        roll_deg: Right side down positive (UE4 ``FRotator``), in ``[-180, 180]``.
    """

    location: npt.NDArray[np.float64]
    pitch_deg: float
    yaw_deg: float
    roll_deg: float


def pose_to_carla(pose: Pose) -> CarlaTransform:
    """Convert a world pose to a CARLA transform.

    Derivation: UE4's ``FRotationMatrix(pitch p, yaw y, roll r)`` has rows forward
    ``(cp*cy, cp*sy, sp)``, right ``(sr*sp*cy - cr*sy, sr*sp*sy + cr*cy, -sr*cp)`` and up
    ``(-(cr*sp*cy + sr*sy), cy*sr - cr*sp*sy, cr*cp)`` in CARLA coordinates (UE uses row
    vectors, so the rows are the body axes). Flipping y on both the parent and the body
    (world left = -CARLA right) turns it into ``Rz(-y) @ Ry(-p) @ Rx(r)`` in the world frame.
    Hence ROS roll = UE roll, ROS pitch = -UE pitch, ROS yaw = -UE yaw.
    """
    e = euler_from_quat(pose.quat)
    return CarlaTransform(
        location=world_to_carla(pose.position),
        pitch_deg=float(-np.degrees(e.pitch)),
        yaw_deg=heading_to_carla_yaw_deg(float(e.yaw)),
        roll_deg=float(np.degrees(e.roll)),
    )


def pose_from_carla(t: CarlaTransform) -> Pose:
    """Convert a CARLA transform to a world pose (inverse of :func:`pose_to_carla`)."""
    quat = quat_from_euler(
        math.radians(t.roll_deg), -math.radians(t.pitch_deg), -math.radians(t.yaw_deg)
    )
    return Pose(carla_to_world(t.location), quat)
