"""A rotating multi-beam LiDAR that scans a ground-truth world (:mod:`cam2sim.core.scene`).

The demo records its LiDAR with it; tests and benchmarks of the detector scan streets of their
own. The scene (:class:`~cam2sim.core.scene.StreetScene`) lives in a world frame (x, y
horizontal, z up, metres): a ground made of a road plane (optionally sloped) with kerbs and
raised sidewalks along the world x axis, static boxes (buildings, walls) and parked cars. Cars
are oriented boxes (their ground-truth boxes); the scanner draws each as a body plus a
narrower, shorter cabin, with the ground visible under the body, so the returns have the
profile of a real car rather than of a brick.

The LiDAR is a grid of ``beams x azimuths`` rays from one origin (no motion during the sweep),
cast at every surface at once with numpy: ray-plane intersections for the ground, slab tests for
the boxes. Each box only tests the rays inside its angular extent as seen from the sensor, so a
scan of ~150,000 rays takes a fraction of a second. Points come back in the sensor frame with
Gaussian range noise.

Example::

    scene = parked_street(seed=0)
    scan = scan_scene(scene, Pose.from_xyz_rpy([0.0, 0.0, 1.8], [0.0, 0.0, 0.3]))
    scan.points  # (N, 4) float32 x, y, z, intensity in the sensor frame
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Final

import numpy as np

from cam2sim.core.frames.rotation import quat_rotate
from cam2sim.core.scene import Ground, SceneBox, StreetScene, car_on_ground

if TYPE_CHECKING:
    from collections.abc import Sequence

    import numpy.typing as npt

    from cam2sim.core.frames.pose import Pose

__all__ = [
    "LABEL_GROUND",
    "LABEL_STRUCTURE",
    "LidarModel",
    "SyntheticScan",
    "parked_street",
    "scan_scene",
]

LABEL_GROUND = -1
"""Label of returns from the road, the kerbs and the sidewalks."""
LABEL_STRUCTURE = -2
"""Label of returns from buildings and walls."""

_REFLECTIVITY = {LABEL_GROUND: 0.15, LABEL_STRUCTURE: 0.35}
_CAR_REFLECTIVITY = 0.6
_RAY_BLOCK = 65_536  # rays per block when casting against the ground (bounds temporaries)


@dataclass(frozen=True)
class LidarModel:
    """A rotating multi-beam LiDAR (defaults: a Velodyne HDL-32E as on nuScenes).

    Attributes:
        beams: Number of lasers, spread evenly over ``elevation_deg``. Default 32.
        azimuths: Firings per revolution (rays per beam). Default 1800 (0.2 degrees).
        elevation_deg: ``(lowest, highest)`` beam elevation, degrees. Default (-30.67, 10.67).
        max_range_m: Returns beyond this range are dropped, metres. Default 100.
        range_noise_m: Standard deviation of the Gaussian range noise, metres. Default 0.02.
    """

    beams: int = 32
    azimuths: int = 1800
    elevation_deg: tuple[float, float] = (-30.67, 10.67)
    max_range_m: float = 100.0
    range_noise_m: float = 0.02

    def directions(self) -> npt.NDArray[np.float64]:
        """``(beams, azimuths, 3)`` unit ray directions in the sensor frame (x at azimuth 0)."""
        el = np.deg2rad(np.linspace(*self.elevation_deg, self.beams))[:, None]
        az = (2.0 * math.pi / self.azimuths) * np.arange(self.azimuths)[None, :]
        return np.stack(
            np.broadcast_arrays(np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)),
            axis=-1,
        )


@dataclass(frozen=True, eq=False)
class SyntheticScan:
    """One synthetic sweep.

    Attributes:
        points: ``(N, 4)`` float32 x, y, z (metres, sensor frame) and intensity in ``[0, 1]``.
        labels: ``(N,)`` int32: :data:`LABEL_GROUND`, :data:`LABEL_STRUCTURE`, or the index of
            the car in :attr:`StreetScene.cars` that the return hit.
    """

    points: npt.NDArray[np.float32]
    labels: npt.NDArray[np.int32]

    def car_hits(self, n_cars: int) -> npt.NDArray[np.int64]:
        """``(n_cars,)`` number of returns on each car."""
        cars = self.labels[self.labels >= 0]
        return np.bincount(cars, minlength=n_cars).astype(np.int64)


def _car_parts(car: SceneBox) -> list[SceneBox]:
    """Body (0.25 m clearance to 60% of the height) and cabin (the rest) of a car."""
    length, width, height = car.size
    bottom = car.center[2] - height / 2.0
    clearance = min(0.25, 0.2 * height)
    body_top = bottom + 0.6 * height
    top = bottom + height
    c, s = math.cos(car.yaw), math.sin(car.yaw)
    back = -0.05 * length  # the cabin sits a little behind the middle
    return [
        SceneBox(
            (car.center[0], car.center[1], (bottom + clearance + body_top) / 2.0),
            (length, width, body_top - bottom - clearance),
            car.yaw,
        ),
        SceneBox(
            (car.center[0] + c * back, car.center[1] + s * back, (body_top + top) / 2.0),
            (0.55 * length, 0.92 * width, top - body_top),
            car.yaw,
        ),
    ]


def _ground_hits(
    ground: Ground, origin: npt.NDArray[np.float64], dirs: npt.NDArray[np.float64]
) -> npt.NDArray[np.float64]:
    """Range along each ray (``(R, 3)`` world directions) to the road/kerb/sidewalk; inf if none."""
    gx, gy = ground.slope
    half, kerb = ground.road_half_width_m, ground.kerb_height_m
    out = np.full(dirs.shape[0], np.inf)
    for start in range(0, dirs.shape[0], _RAY_BLOCK):
        d = dirs[start : start + _RAY_BLOCK]
        best = np.full(d.shape[0], np.inf)
        denom = d[:, 2] - gx * d[:, 0] - gy * d[:, 1]
        base = origin[2] - gx * origin[0] - gy * origin[1] - ground.height_m
        with np.errstate(divide="ignore", invalid="ignore"):
            for offset, on_road in ((0.0, True), (kerb, False)):
                t = -(base - offset) / denom
                y = origin[1] + t * d[:, 1]
                ok = (t > 0) & ((np.abs(y) <= half) == on_road)
                best = np.where(ok & (t < best), t, best)
            if kerb > 0:
                for side in (-half, half):
                    t = (side - origin[1]) / d[:, 1]
                    p = origin[None, :] + t[:, None] * d
                    road = ground.height_m + gx * p[:, 0] + gy * p[:, 1]
                    ok = (t > 0) & (p[:, 2] >= road) & (p[:, 2] <= road + kerb)
                    best = np.where(ok & (t < best), t, best)
        out[start : start + _RAY_BLOCK] = best
    return out


_CORNER_SIGNS: Final = np.array(
    [[i, j, k] for i in (-1, 1) for j in (-1, 1) for k in (-1, 1)], dtype=float
)
"""The eight corners of a box, as signs of its half sizes."""


def _angular_windows(
    boxes: Sequence[SceneBox], T_sensor_world: Pose, lidar: LidarModel
) -> list[tuple[npt.NDArray[np.int64], npt.NDArray[np.int64]] | None]:
    """Per box, the beam rows and azimuth columns whose rays may hit it (``None`` when none can).

    ``T_sensor_world``: the sensor pose's inverse (computed once a scan). Every box's corners
    move into the sensor frame in one call, and the boxes out of range are dropped before any
    per-box work: on a street of 165 buildings and 66 cars (132 parts) a scan spent 80 % of its
    48 ms in this test one box at a time (docs/benchmarks.md). Each element is computed as
    the one-box test did, so the windows (and the scans' bytes) are the same.
    """
    if not boxes:
        return []
    centers = np.array([b.center for b in boxes], dtype=np.float64)  # (B, 3)
    sizes = np.array([b.size for b in boxes], dtype=np.float64)
    c = np.array([math.cos(b.yaw) for b in boxes])[:, None]
    s = np.array([math.sin(b.yaw) for b in boxes])[:, None]
    half = 0.5 * sizes[:, None, :] * _CORNER_SIGNS  # (B, 8, 3)
    corners = np.stack(
        [
            centers[:, 0:1] + c * half[..., 0] - s * half[..., 1],
            centers[:, 1:2] + s * half[..., 0] + c * half[..., 1],
            centers[:, 2:3] + half[..., 2],
        ],
        axis=-1,
    )
    local = T_sensor_world.apply(corners)  # (B, 8, 3)
    dist = np.linalg.norm(local, axis=-1)
    near = dist.min(axis=-1) <= lidar.max_range_m + sizes.max(axis=-1)
    out: list[tuple[npt.NDArray[np.int64], npt.NDArray[np.int64]] | None] = [None] * len(boxes)
    idx = np.flatnonzero(near)
    if idx.size == 0:
        return out
    local, dist, sizes = local[idx], dist[idx], sizes[idx]
    centre = T_sensor_world.apply(centers[idx])  # (N, 3)
    heading = np.array([math.atan2(y, x) for x, y in centre[:, :2].tolist()])
    az = np.arctan2(local[..., 1], local[..., 0])
    rel = np.angle(np.exp(1j * (az - heading[:, None])))
    rel_min, rel_max, spread = rel.min(axis=-1), rel.max(axis=-1), np.ptp(rel, axis=-1)
    inside = np.hypot(centre[:, 0], centre[:, 1]) < 0.5 * np.array(
        [math.hypot(x, y) for x, y in sizes[:, :2].tolist()]
    )
    el = np.rad2deg(np.arcsin(np.clip(local[..., 2] / np.maximum(dist, 1e-9), -1.0, 1.0)))
    el_min, el_max = el.min(axis=-1), el.max(axis=-1)
    step = 2.0 * math.pi / lidar.azimuths
    lo, hi = lidar.elevation_deg
    el_step = (hi - lo) / max(lidar.beams - 1, 1)
    for k, box in enumerate(idx.tolist()):
        if inside[k] or spread[k] > math.pi:
            cols = np.arange(lidar.azimuths)
        else:
            first = math.floor((heading[k] + rel_min[k]) / step) - 1
            last = math.ceil((heading[k] + rel_max[k]) / step) + 1
            cols = np.arange(first, last + 1) % lidar.azimuths
        if inside[k]:
            rows = np.arange(lidar.beams)
        else:
            first_row = max(math.floor((el_min[k] - lo) / el_step) - 1, 0)
            last_row = min(math.ceil((el_max[k] - lo) / el_step) + 1, lidar.beams - 1)
            if first_row > last_row:
                continue
            rows = np.arange(first_row, last_row + 1)
        out[box] = (rows, cols)
    return out


def _box_hits(
    box: SceneBox, origin: npt.NDArray[np.float64], dirs: npt.NDArray[np.float64]
) -> npt.NDArray[np.float64]:
    """Range along each ray (``(..., 3)`` world directions) to ``box`` (slab test); inf if none."""
    c, s = math.cos(box.yaw), math.sin(box.yaw)
    rot = np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])  # world -> box axes
    o = rot @ (origin - np.asarray(box.center))
    d = dirs @ rot.T
    half = 0.5 * np.asarray(box.size)
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / d
        t1 = (-half - o) * inv
        t2 = (half - o) * inv
    near = np.fmax.reduce(np.fmin(t1, t2), axis=-1)
    far = np.fmin.reduce(np.fmax(t1, t2), axis=-1)
    hit = (near <= far) & (near > 0)
    return np.where(hit, near, np.inf)


def scan_scene(
    scene: StreetScene,
    T_world_sensor: Pose,
    *,
    lidar: LidarModel | None = None,
    seed: int = 0,
) -> SyntheticScan:
    """Cast every ray of ``lidar`` from ``T_world_sensor`` into ``scene``.

    Args:
        scene: What to scan (world frame).
        T_world_sensor: Pose of the LiDAR in the world (sensor x is azimuth 0, z up).
        lidar: The sensor model; :class:`LidarModel` defaults when ``None``.
        seed: Seed of the range and intensity noise.

    Returns:
        The returns within ``lidar.max_range_m``, in the sensor frame, with their labels.
    """
    lidar = lidar or LidarModel()
    rng = np.random.default_rng(seed)
    dirs_sensor = lidar.directions()
    dirs = quat_rotate(T_world_sensor.quat, dirs_sensor)
    origin = np.asarray(T_world_sensor.position, dtype=np.float64)
    t_best = _ground_hits(scene.ground, origin, dirs.reshape(-1, 3)).reshape(dirs.shape[:2])
    label = np.full(t_best.shape, LABEL_GROUND, dtype=np.int32)
    objects = [(box, LABEL_STRUCTURE) for box in scene.structures]
    objects += [(part, k) for k, car in enumerate(scene.cars) for part in _car_parts(car)]
    windows = _angular_windows([box for box, _ in objects], T_world_sensor.inverse(), lidar)
    for (box, tag), window in zip(objects, windows, strict=True):
        # one vectorised slab test per box in range, over its angular window
        if window is None:
            continue
        rows, cols = window
        grid = np.ix_(rows, cols)
        t = _box_hits(box, origin, dirs[grid])
        closer = t < t_best[grid]
        t_best[grid] = np.where(closer, t, t_best[grid])
        label[grid] = np.where(closer, tag, label[grid])
    keep = t_best < lidar.max_range_m
    t = t_best[keep] + rng.normal(0.0, lidar.range_noise_m, size=int(keep.sum()))
    xyz = dirs_sensor[keep] * t[:, None]
    labels = label[keep]
    reflect = np.where(labels >= 0, _CAR_REFLECTIVITY, _REFLECTIVITY[LABEL_STRUCTURE])
    reflect = np.where(labels == LABEL_GROUND, _REFLECTIVITY[LABEL_GROUND], reflect)
    intensity = np.clip(reflect + rng.normal(0.0, 0.05, size=labels.shape), 0.0, 1.0)
    points = np.concatenate([xyz, intensity[:, None]], axis=1).astype(np.float32)
    return SyntheticScan(points=points, labels=labels.astype(np.int32))


def parked_street(
    *,
    seed: int = 0,
    length_m: float = 120.0,
    ground: Ground | None = None,
    perpendicular_fraction: float = 0.0,
    sidewalk_m: float = 3.0,
    occupancy: float = 0.7,
) -> StreetScene:
    """A straight street along world x with parked cars on both kerbs and buildings behind.

    Cars stand along the kerbs of ``ground`` (parallel, or perpendicular with probability
    ``perpendicular_fraction``), facing either way, with random sizes (length 3.8-5.0 m, width
    1.7-1.95 m, height 1.4-1.75 m), gaps of 0.8-3 m and empty slots (``1 - occupancy``).
    Building blocks of 6-25 m with alleys between them line both sidewalks.

    Args:
        seed: Seed of every random choice.
        length_m: Street length, centred on the world origin, metres.
        ground: The road; a flat :class:`Ground` with kerbs by default.
        perpendicular_fraction: Share of cars parked across the kerb, in ``[0, 1]``.
        sidewalk_m: Sidewalk width between kerb and facades, metres.
        occupancy: Chance that a parking slot holds a car, in ``[0, 1]``.

    Returns:
        The scene (cars listed in order of x, left kerb first).
    """
    rng = np.random.default_rng(seed)
    ground = ground or Ground()
    half = ground.road_half_width_m
    cars: list[SceneBox] = []
    structures: list[SceneBox] = []
    for side in (1.0, -1.0):
        x = -length_m / 2.0 + rng.uniform(0.0, 3.0)
        while x < length_m / 2.0:
            size = (rng.uniform(3.8, 5.0), rng.uniform(1.7, 1.95), rng.uniform(1.4, 1.75))
            # Perpendicular only where the car leaves 2.5 m of road to the centre line.
            across = rng.random() < perpendicular_fraction and half - 0.25 - size[0] >= 2.5
            extent = size[1] if across else size[0]
            depth = size[0] if across else size[1]
            if rng.random() < occupancy:
                yaw = (math.pi / 2 if across else 0.0) + rng.normal(0.0, 0.03)
                yaw += math.pi * float(rng.integers(0, 2))
                centre = (x + extent / 2.0, side * (half - 0.25 - depth / 2.0))
                cars.append(car_on_ground(ground, centre, yaw, size))
            x += extent + rng.uniform(0.8, 3.0)
        x = -length_m / 2.0 - 10.0
        while x < length_m / 2.0 + 10.0:
            width = rng.uniform(6.0, 25.0)
            height = rng.uniform(6.0, 15.0)
            depth = 10.0
            centre_xy = (x + width / 2.0, side * (half + sidewalk_m + depth / 2.0))
            z = float(ground.height_at(np.asarray(centre_xy)))
            structures.append(
                SceneBox((*centre_xy, z + (height - 3.0) / 2.0), (width, depth, height + 3.0), 0.0)
            )
            x += width + (rng.uniform(2.0, 6.0) if rng.random() < 0.4 else 0.0)
    return StreetScene(ground=ground, cars=tuple(cars), structures=tuple(structures))
