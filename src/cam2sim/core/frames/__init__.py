"""Frames, units and rotations: the one owner of every coordinate convention in cam2sim.

Conventions (see ``docs/architecture.md``, "Frames and units"):

* Quaternions are float64 arrays ``(..., 4)`` in ROS order ``(x, y, z, w)``, composed with the
  Hamilton product. Rotations are active: ``q`` rotates body vectors into the parent frame.
* Angles are radians unless the name ends in ``_deg``. Euler angles follow ROS (ZYX):
  ``R = Rz(yaw) @ Ry(pitch) @ Rx(roll)``.
* The world frame of a workspace is local, right-handed and metric: x east, y north, z up. It is a
  transverse Mercator projection centred on the workspace origin (:class:`WorldFrame`); the same
  projection string goes into the OpenDRIVE ``<geoReference>``, so map and world coordinates agree.
* Heading is the angle of the vehicle forward axis in the world frame, CCW from +x, radians.
* CARLA's left-handed Unreal frame (y flipped, yaw in degrees clockwise) appears only through
  :func:`world_to_carla`, :func:`pose_to_carla` and their inverses.

Every function broadcasts over leading dimensions and is vectorised with numpy.
"""

from cam2sim.core.frames.carla import (
    CarlaTransform,
    carla_to_world,
    carla_yaw_deg_to_heading,
    heading_to_carla_yaw_deg,
    pose_from_carla,
    pose_to_carla,
    world_to_carla,
)
from cam2sim.core.frames.pose import (
    Pose,
    PoseSamples,
    camera_poses,
    interpolate_poses,
)
from cam2sim.core.frames.projection import (
    GridFrame,
    Wgs84Points,
    WorldFrame,
    enu_from_ecef_rotation,
    utm_crs_for,
    wgs84_from_ecef,
)
from cam2sim.core.frames.rotation import (
    EulerAngles,
    angle_difference,
    circular_mean,
    euler_from_quat,
    quat_angle_between,
    quat_conjugate,
    quat_from_euler,
    quat_from_matrix,
    quat_from_rotvec,
    quat_from_yaw,
    quat_inverse,
    quat_multiply,
    quat_normalize,
    quat_rotate,
    quat_to_matrix,
    rotvec_from_quat,
    slerp,
    unwrap_angles,
    wrap_angle,
    yaw_from_quat,
)

__all__ = [
    "CarlaTransform",
    "EulerAngles",
    "GridFrame",
    "Pose",
    "PoseSamples",
    "Wgs84Points",
    "WorldFrame",
    "angle_difference",
    "camera_poses",
    "carla_to_world",
    "carla_yaw_deg_to_heading",
    "circular_mean",
    "enu_from_ecef_rotation",
    "euler_from_quat",
    "heading_to_carla_yaw_deg",
    "interpolate_poses",
    "pose_from_carla",
    "pose_to_carla",
    "quat_angle_between",
    "quat_conjugate",
    "quat_from_euler",
    "quat_from_matrix",
    "quat_from_rotvec",
    "quat_from_yaw",
    "quat_inverse",
    "quat_multiply",
    "quat_normalize",
    "quat_rotate",
    "quat_to_matrix",
    "rotvec_from_quat",
    "slerp",
    "unwrap_angles",
    "utm_crs_for",
    "wgs84_from_ecef",
    "world_to_carla",
    "wrap_angle",
    "yaw_from_quat",
]
