"""The demo recording's bag: the reference drive through the demo world as ROS2 MCAP.

:func:`write_bag` drives the world's street (:meth:`~cam2sim.demo.world.DemoStreet.drive_points`:
the route plus the driver's weave) at the street's speed and writes odometry (in the street's
CRS, x-left axes) and steering at 50 Hz, a ray-cast LiDAR at 5 Hz and the photographic camera
(JPEG) with its camera info at :data:`~cam2sim.demo.rig.CAMERA_HZ`.
"""

from __future__ import annotations

import collections
import math
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any, Final

import numpy as np

from cam2sim.core.frames import Pose
from cam2sim.core.machine import available_cpus
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
    from cam2sim.recording.image import CompressedImageFields

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


@dataclass(frozen=True)
class _Event:
    """One message time of the drive: odometry (with steering), a LiDAR scan or a frame."""

    stamp: int
    kind: str
    index: int
    station: float
    job: Future[Any] | None = None  # the scan's points or the frame's JPEG fields


def write_bag(path: Path, world: DemoWorld, *, seed: int, progress: ProgressCallback) -> int:
    """Write the demo drive through ``world`` as a ROS2 MCAP bag; return the camera frames.

    The LiDAR scans and the camera's look and JPEG run on a thread pool (NumPy and OpenCV
    release the GIL); the OpenGL frames render in this thread, and the bag is written in time
    order, the same bytes as one thread writes.
    """
    street = world.street
    duration = street.duration_s
    odom_t = np.arange(0.0, duration, 1.0 / ODOM_HZ)
    cam_t = np.arange(0.05, duration, 1.0 / CAMERA_HZ)
    lidar_t = np.arange(0.02, duration, 1.0 / LIDAR_HZ)
    steer = _steering(street, odom_t)
    odom_xy, odom_heading = street.drive_points(street.speed_mps * odom_t)  # all at once
    times = [(float(t), 0, "odom", i) for i, t in enumerate(odom_t)]
    times += [(float(t), 1, "lidar", i) for i, t in enumerate(lidar_t)]
    times += [(float(t), 2, "camera", i) for i, t in enumerate(cam_t)]
    times.sort()
    scene = world.lidar_scene()
    lidar = LidarModel(beams=LIDAR_BEAMS, azimuths=LIDAR_AZIMUTHS)
    camera = demo_camera()
    k = camera.K()
    pending: collections.deque[_Event] = collections.deque()
    workers = available_cpus()
    with (
        RasterRenderer(world.raster_scene()) as renderer,
        BagWriter(path, "mcap") as bag,
        ThreadPoolExecutor(workers, thread_name_prefix="demo-bag") as pool,
    ):
        for t, _, kind, i in times:
            event = _Event(_T0_NS + round(t * 1e9), kind, i, street.speed_mps * t)
            if kind == "lidar":
                job = pool.submit(_scan, scene, lidar, street, event.station, seed * 100_003 + i)
                event = replace(event, job=job)
            elif kind == "camera":
                pose_cam = street.camera_pose(event.station)
                frame = renderer.render(pose_cam, camera)
                event = replace(event, job=pool.submit(_look, frame, pose_cam, k, seed))
            pending.append(event)
            while len(pending) > 4 * workers:  # a bounded window of frames in flight
                _write(bag, street, pending.popleft(), (odom_xy, odom_heading, steer))
            if kind == "camera":
                progress("demo frames", i + 1, len(cam_t))  # rendered
        while pending:
            _write(bag, street, pending.popleft(), (odom_xy, odom_heading, steer))
    progress("demo frames", len(cam_t), len(cam_t))
    return len(cam_t)


def _scan(
    scene: Any, lidar: LidarModel, street: DemoStreet, station: float, seed: int
) -> npt.NDArray[Any]:
    """The LiDAR's points at ``station`` along the drive."""
    xy, heading = street.drive_points([station])
    body = body_pose(xy[0], float(heading[0]))
    position = body[:3, :3] @ np.asarray(LIDAR_MOUNT) + body[:3, 3]
    q = _quat_z(float(heading[0]))
    sensor = Pose(position, np.array([q["x"], q["y"], q["z"], q["w"]]))
    points: npt.NDArray[Any] = scan_scene(scene, sensor, lidar=lidar, seed=seed).points
    return points


def _look(
    frame: Any, pose_cam: npt.NDArray[np.float64], k: npt.NDArray[np.float64], seed: int
) -> CompressedImageFields:
    """The photographic camera's JPEG of a rendered frame."""
    from cam2sim.recording.image import compressed_image_fields  # noqa: PLC0415 -- lazy: cv2

    rng = frame_noise_rng(seed, pose_cam)  # per pose, as the truth camera draws it
    image = photographic_look(frame.rgb, frame.labels, pose_cam, k, rng=rng, seed=seed)
    return compressed_image_fields(image, "jpeg", quality=88)


def _write(
    bag: BagWriter,
    street: DemoStreet,
    event: _Event,
    odometry: tuple[npt.NDArray[np.float64], npt.NDArray[np.float64], npt.NDArray[np.float64]],
) -> None:
    """Write ``event``'s messages (waiting for its job).

    ``odometry``: every odometry time's position, heading and steering, computed at once.
    """
    stamp = event.stamp
    if event.kind == "odom":
        xy, heading, steer = odometry
        pose = {
            "position": {
                "x": street.origin[0] + xy[event.index, 0],
                "y": street.origin[1] + xy[event.index, 1],
            },
            # The reference car's axes: x to the left, so yaw = heading + 90 degrees.
            "orientation": _quat_z(float(heading[event.index]) + math.pi / 2.0),
        }
        odom = {
            "header": {"stamp": stamp, "frame_id": "utm"},
            "child_frame_id": "base_link",
            "pose": {"pose": pose},
            "twist": {"twist": {"linear": {"y": street.speed_mps}}},
        }
        bag.write_fields(TOPICS["pose"], "nav_msgs/msg/Odometry", odom, receive_ns=stamp)
        value = {"data": float(steer[event.index])}
        bag.write_fields(TOPICS["steering"], "std_msgs/msg/Float64", value, receive_ns=stamp)
    elif event.kind == "lidar":
        assert event.job is not None
        bag.write_point_cloud(TOPICS["lidar"], stamp, event.job.result())
    else:
        assert event.job is not None
        msg = {"header": {"stamp": stamp, "frame_id": "camera_optical"}, **event.job.result()}
        bag.write_fields(TOPICS["camera"], "sensor_msgs/msg/CompressedImage", msg, receive_ns=stamp)
        info = _camera_info(stamp)
        bag.write_fields(
            TOPICS["camera_info"], "sensor_msgs/msg/CameraInfo", info, receive_ns=stamp
        )
