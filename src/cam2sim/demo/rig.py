"""The demo car's sensor rig: camera, LiDAR, odometry, steering and their topics.

What the demo recording (:mod:`cam2sim.demo.bag`) writes and its config
(:func:`cam2sim.demo.world.demo_config`) declares. Mounts are in the body frame (x forward,
y left, z up, metres, from the recorded reference point).
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Final

import numpy as np

from cam2sim.core.camera import PinholeCamera

if TYPE_CHECKING:
    import numpy.typing as npt

__all__ = [
    "CAMERA_FOCAL_PX",
    "CAMERA_HZ",
    "CAMERA_MOUNT",
    "CAMERA_SIZE",
    "CURVATURE_PER_STEERING",
    "LIDAR_AZIMUTHS",
    "LIDAR_BEAMS",
    "LIDAR_HZ",
    "LIDAR_MOUNT",
    "ODOM_HZ",
    "TOPICS",
    "body_pose",
    "camera_matrix",
    "demo_camera",
]

CURVATURE_PER_STEERING: Final = 0.022
"""The steering calibration: curvature (1/m) = steering * this."""
CAMERA_SIZE: Final = (320, 200)
CAMERA_FOCAL_PX: Final = 200.0
CAMERA_MOUNT: Final = (1.6, 0.0, 1.4)
LIDAR_MOUNT: Final = (1.0, 0.0, 1.9)
CAMERA_HZ: Final = 20
ODOM_HZ: Final = 50
LIDAR_HZ: Final = 5
LIDAR_BEAMS: Final = 16
LIDAR_AZIMUTHS: Final = 720
TOPICS: Final = {
    "camera": "/camera/image_raw/compressed",
    "camera_info": "/camera/camera_info",
    "pose": "/odom",
    "lidar": "/lidar/points",
    "steering": "/vehicle/steering",
}


def demo_camera() -> PinholeCamera:
    """The demo camera: no distortion, the principal point at the image centre."""
    w, h = CAMERA_SIZE
    return PinholeCamera(CAMERA_FOCAL_PX, CAMERA_FOCAL_PX, (w - 1) / 2.0, (h - 1) / 2.0, w, h)


def camera_matrix() -> npt.NDArray[np.float64]:
    """The demo camera's ``(3, 3)`` intrinsics."""
    return demo_camera().K()


def body_pose(xy: npt.NDArray[np.float64], heading: float) -> npt.NDArray[np.float64]:
    """The ``(4, 4)`` body -> world transform at ``xy`` (metres) and ``heading`` (radians)."""
    c, s = math.cos(heading), math.sin(heading)
    pose = np.eye(4)
    pose[:2, :2] = [[c, -s], [s, c]]
    pose[:2, 3] = xy
    return pose
