"""The demo recording's bag: the reference drive through the demo world as ROS2 MCAP.

:func:`write_bag` drives the world's street (:meth:`~cam2sim.demo.world.DemoStreet.drive_points`:
the route plus the driver's weave) at the street's speed and writes odometry (in the street's
CRS, x-left axes) and steering at 50 Hz, a ray-cast LiDAR at 5 Hz and the photographic camera
(JPEG) with its camera info at :data:`~cam2sim.demo.rig.CAMERA_HZ`.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any, Final

import numpy as np

from cam2sim.core.frames import Pose
from cam2sim.demo.lidar import LidarModel, scan_scene
from cam2sim.demo.rig import (
    CAMERA_HZ,
    CAMERA_SIZE,
    CURVATURE_PER_STEERING,
    LIDAR_AZIMUTHS,
    LIDAR_BEAMS,
    LIDAR_HZ,
    LIDAR_MOUNT,
    ODOM_HZ,
    TOPICS,
    body_pose,
    camera_matrix,
    demo_camera,
)
from cam2sim.recording.bagwriter import BagWriter
from cam2sim.render.look import frame_noise_rng, photographic_look
from cam2sim.render.raster import RasterRenderer

if TYPE_CHECKING:
    from pathlib import Path

    import numpy.typing as npt

    from cam2sim.core.progress import ProgressCallback
    from cam2sim.demo.world import DemoStreet, DemoWorld

__all__ = ["write_bag"]

_T0_NS: Final = 1_717_000_000_000_000_000


def _quat_z(yaw: float) -> dict[str, float]:
    return {"x": 0.0, "y": 0.0, "z": math.sin(yaw / 2.0), "w": math.cos(yaw / 2.0)}


def _steering(street: DemoStreet, t: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    """The driver's steering at times ``t``: the driven path's curvature, eased over 1 s."""
    fine = np.arange(-1.0, t[-1] + 1.0, 0.01)
    kappa = street.drive_curvature(street.speed_mps * fine)
    window = np.ones(101) / 101.0
    smooth = np.convolve(kappa, window, mode="same")
    out: npt.NDArray[np.float64] = np.interp(t, fine, smooth) / CURVATURE_PER_STEERING
    return out


def _camera_info(stamp: int) -> dict[str, Any]:
    k = camera_matrix()
    w, h = CAMERA_SIZE
    return {
        "header": {"stamp": stamp, "frame_id": "camera_optical"},
        "height": h,
        "width": w,
        "distortion_model": "plumb_bob",
        "d": np.zeros(5),
        "k": k.ravel(),
        "r": np.eye(3).ravel(),
        "p": np.column_stack([k, np.zeros(3)]).ravel(),
    }


def write_bag(path: Path, world: DemoWorld, *, seed: int, progress: ProgressCallback) -> int:
    """Write the demo drive through ``world`` as a ROS2 MCAP bag; return the camera frames."""
    from cam2sim.recording.image import compressed_image_fields  # noqa: PLC0415 -- lazy: imports cv2

    street = world.street
    origin = street.origin
    duration = street.duration_s
    odom_t = np.arange(0.0, duration, 1.0 / ODOM_HZ)
    cam_t = np.arange(0.05, duration, 1.0 / CAMERA_HZ)
    lidar_t = np.arange(0.02, duration, 1.0 / LIDAR_HZ)
    steer = _steering(street, odom_t)
    events = [(float(t), 0, "odom", i) for i, t in enumerate(odom_t)]
    events += [(float(t), 1, "lidar", i) for i, t in enumerate(lidar_t)]
    events += [(float(t), 2, "camera", i) for i, t in enumerate(cam_t)]
    events.sort()
    scene = world.lidar_scene()
    lidar = LidarModel(beams=LIDAR_BEAMS, azimuths=LIDAR_AZIMUTHS)
    camera = demo_camera()
    k = camera.K()
    with RasterRenderer(world.raster_scene()) as renderer, BagWriter(path, "mcap") as bag:
        for t, _, kind, i in events:
            stamp = _T0_NS + round(t * 1e9)
            station = street.speed_mps * t
            if kind == "odom":
                xy, heading = street.drive_points([station])
                pose = {
                    "position": {"x": origin[0] + xy[0, 0], "y": origin[1] + xy[0, 1]},
                    # The reference car's axes: x to the left, so yaw = heading + 90 degrees.
                    "orientation": _quat_z(float(heading[0]) + math.pi / 2.0),
                }
                twist = {"linear": {"y": street.speed_mps}}
                odom = {
                    "header": {"stamp": stamp, "frame_id": "utm"},
                    "child_frame_id": "base_link",
                    "pose": {"pose": pose},
                    "twist": {"twist": twist},
                }
                bag.write_fields(TOPICS["pose"], "nav_msgs/msg/Odometry", odom, receive_ns=stamp)
                value = {"data": float(steer[i])}
                bag.write_fields(
                    TOPICS["steering"], "std_msgs/msg/Float64", value, receive_ns=stamp
                )
            elif kind == "lidar":
                xy, heading = street.drive_points([station])
                body = body_pose(xy[0], float(heading[0]))
                position = body[:3, :3] @ np.asarray(LIDAR_MOUNT) + body[:3, 3]
                q = _quat_z(float(heading[0]))
                sensor = Pose(position, np.array([q["x"], q["y"], q["z"], q["w"]]))
                points = scan_scene(scene, sensor, lidar=lidar, seed=seed * 100_003 + i).points
                bag.write_point_cloud(TOPICS["lidar"], stamp, points)
            else:
                pose_cam = street.camera_pose(station)
                frame = renderer.render(pose_cam, camera)
                rng = frame_noise_rng(seed, pose_cam)  # per pose, as the truth camera draws it
                image = photographic_look(frame.rgb, frame.labels, pose_cam, k, rng=rng, seed=seed)
                msg: dict[str, object] = {
                    "header": {"stamp": stamp, "frame_id": "camera_optical"},
                    **compressed_image_fields(image, "jpeg", quality=88),
                }
                bag.write_fields(
                    TOPICS["camera"], "sensor_msgs/msg/CompressedImage", msg, receive_ns=stamp
                )
                bag.write_fields(
                    TOPICS["camera_info"],
                    "sensor_msgs/msg/CameraInfo",
                    _camera_info(stamp),
                    receive_ns=stamp,
                )
                progress("demo frames", i + 1, len(cam_t))
    return len(cam_t)
