"""A small workspace for the LiDAR overview and editor tests, written as stage extract would.

The car drives 80 m east along y = -1.75 (the right lane of a straight map road from x = -10 to
90). Parked cars stand in the parking lanes at y = -4.75 (right) and y = +4.75 (left). Every
10 m the roof LiDAR (1.8 m up, yawed 0.3 rad, so the pose transform matters) sees the cars'
sides and a flat road.
"""

from __future__ import annotations

import datetime as dt
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from cam2sim.core.config import Config
from cam2sim.core.dataset import (
    LIDAR_COLUMNS,
    POSE_PRECISION,
    TRAJECTORY_COLUMNS,
    DatasetCounts,
    DatasetInfo,
)
from cam2sim.core.frames.rotation import quat_from_yaw, quat_to_matrix
from cam2sim.core.table import write_table
from cam2sim.core.workspace import Workspace, WorldFrameRecord, dataset_paths
from cam2sim.detect.vehicles import ParkedVehicle, ParkedVehicles, parked_vehicles_path

ROUTE_Y = -1.75
SENSOR_HEIGHT = 1.8
SENSOR_YAW = 0.3
SCAN_X = np.arange(0.0, 81.0, 10.0)
T0 = 1_700_000_000_000_000_000

XODR = """<?xml version="1.0"?>
<OpenDRIVE><header revMajor="1" revMinor="4"/>
  <road name="street" length="100" id="1" junction="-1">
    <planView><geometry s="0" x="-10" y="0" hdg="0" length="100"><line/></geometry></planView>
    <lanes><laneSection s="0">
      <left>
        <lane id="3" type="sidewalk"><width sOffset="0" a="2" b="0" c="0" d="0"/></lane>
        <lane id="2" type="parking"><width sOffset="0" a="2.5" b="0" c="0" d="0"/></lane>
        <lane id="1" type="driving"><width sOffset="0" a="3.5" b="0" c="0" d="0"/></lane>
      </left>
      <center><lane id="0" type="none"/></center>
      <right>
        <lane id="-1" type="driving"><width sOffset="0" a="3.5" b="0" c="0" d="0"/></lane>
        <lane id="-2" type="parking"><width sOffset="0" a="2.5" b="0" c="0" d="0"/></lane>
        <lane id="-3" type="sidewalk"><width sOffset="0" a="2" b="0" c="0" d="0"/></lane>
      </right>
    </laneSection></lanes>
  </road>
</OpenDRIVE>
"""


def vehicle(vid: str, x: float, y: float, yaw: float = 0.0, **kw: object) -> ParkedVehicle:
    fields: dict[str, object] = {
        "id": vid,
        "position": (x, y, 0.0),
        "yaw": yaw,
        "size": (4.5, 1.8, 1.5),
        "confidence": 0.9,
        "hits": 5,
        "side": "left" if y > 0 else "right",
        "orientation": "parallel",
        "source": "lidar",
    }
    return ParkedVehicle.model_validate(fields | kw)


VEHICLES = (
    vehicle("pv_001", 15.0, -4.75),
    vehicle("pv_002", 30.0, -4.75, 3.1),
    vehicle("pv_003", 45.0, 4.75),
    vehicle("pv_004", 60.0, -4.75, 0.05),
)


@dataclass(frozen=True)
class LidarTruth:
    """The world points of every scan, for reference checks."""

    world: list[np.ndarray]
    sensor: np.ndarray


def _car_points(rng: np.random.Generator, v: ParkedVehicle, n: int) -> np.ndarray:
    """Points on the four vertical sides of a box, 0.3-1.4 m above the ground."""
    u = rng.uniform(-0.5, 0.5, n)
    side = rng.integers(0, 4, n)
    length, width, _ = v.size
    a = np.where(side < 2, u * length, np.where(side == 2, length / 2, -length / 2))
    b = np.where(side == 0, width / 2, np.where(side == 1, -width / 2, u * width))
    c, s = np.cos(v.yaw), np.sin(v.yaw)
    x = v.position[0] + a * c - b * s
    y = v.position[1] + a * s + b * c
    return np.column_stack([x, y, rng.uniform(0.3, 1.4, n)])


def write_lidar(ws: Workspace, vehicles: tuple[ParkedVehicle, ...] = VEHICLES) -> LidarTruth:
    """Scans every 10 m of cars near the sensor plus road points at z = 0, sensor frame."""
    paths = dataset_paths(ws.dataset_dir)
    paths.lidar_dir.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(7)
    n = len(SCAN_X)
    sensor = np.column_stack([SCAN_X, np.full(n, ROUTE_Y), np.full(n, SENSOR_HEIGHT)])
    quat = quat_from_yaw(np.full(n, SENSOR_YAW))
    R = quat_to_matrix(quat)
    world_scans = []
    for i in range(n):
        near = [v for v in vehicles if abs(v.position[0] - SCAN_X[i]) < 25]
        cars = [_car_points(rng, v, 300) for v in near]
        road = np.column_stack(
            [rng.uniform(-20, 20, 500) + SCAN_X[i], rng.uniform(-8, 8, 500), np.zeros(500)]
        )
        world = np.concatenate([*cars, road])
        local = (world - sensor[i]) @ R[i]  # R.T applied to row vectors
        scan = np.zeros(len(local), dtype=[(k, "<f4") for k in ("x", "y", "z", "intensity")])
        scan["x"], scan["y"], scan["z"] = local.T
        np.save(paths.lidar_file(i), scan)
        world_scans.append(local.astype(np.float32).astype(np.float64) @ R[i].T + sensor[i])
    stamps = T0 + np.arange(n, dtype=np.int64) * 1_000_000_000
    cols: dict[str, np.ndarray] = {
        "scan": np.arange(n),
        "stamp_ns": stamps,
        "t": (stamps - T0) / 1e9,
    }
    cols |= dict(zip(("x", "y", "z"), sensor.T, strict=True))
    cols |= dict(zip(("qx", "qy", "qz", "qw"), quat.T, strict=True))
    cols["points"] = np.array([len(w) for w in world_scans])
    assert tuple(cols) == LIDAR_COLUMNS
    write_table(paths.lidar_csv, cols, precision=POSE_PRECISION)
    return LidarTruth(world_scans, sensor)


def make_workspace(
    root: Path,
    *,
    lidar: bool = True,
    road_map: bool = True,
    vehicles: tuple[ParkedVehicle, ...] | None = VEHICLES,
) -> Workspace:
    """The workspace described in the module docstring; the extract stage is recorded done."""
    ws = Workspace.create(root, Config())
    paths = dataset_paths(ws.dataset_dir)
    x = np.arange(0.0, 80.01, 0.5)
    n = len(x)
    stamps = T0 + np.arange(n, dtype=np.int64) * 100_000_000
    cols: dict[str, np.ndarray] = {"stamp_ns": stamps, "t": (stamps - T0) / 1e9}
    cols |= {"x": x, "y": np.full(n, ROUTE_Y), "z": np.zeros(n)}
    cols |= {"qx": np.zeros(n), "qy": np.zeros(n), "qz": np.zeros(n), "qw": np.ones(n)}
    cols |= {"heading": np.zeros(n), "speed": np.full(n, 5.0)}
    assert tuple(cols) == TRAJECTORY_COLUMNS
    write_table(paths.trajectory_csv, cols, precision=POSE_PRECISION)
    scans = 0
    if lidar:
        scans = len(write_lidar(ws).sensor)
    DatasetInfo(
        kind="bag",
        sources=(),
        time_base="header",
        counts=DatasetCounts(frames=0, pose_samples=n, lidar_scans=scans),
        start_ns=int(stamps[0]),
        end_ns=int(stamps[-1]),
        duration_s=float(stamps[-1] - stamps[0]) / 1e9,
        frame_format="png",
        world=WorldFrameRecord(proj_string=None),
    ).save(paths.dataset_json)
    now = dt.datetime.now(dt.UTC)
    ws.record_stage("extract", state="done", started=now, inputs_hash="sha256:dataset-1")
    if road_map:
        ws.map_dir.mkdir(parents=True, exist_ok=True)
        (ws.map_dir / "map.xodr").write_text(XODR, encoding="utf-8")
    if vehicles is not None:
        ParkedVehicles(
            source="lidar",
            detector="geometric",
            frames_used=scans,
            detections=20,
            min_hits=2,
            vehicles=vehicles,
        ).save(parked_vehicles_path(ws.detections_dir))
    return ws
