"""Benchmark of stage map (issue 5): converting munich.osm and writing the report.

Builds a workspace whose route runs along Straßbergerstraße in ``../shared/data/osm/munich.osm``
with a margin wide enough for the box to hold the whole extract (about 1 km², 1.9 MB), then
measures:

* the whole stage (``build_map``) in a fresh Python process, as ``cam2sim map`` runs it (module
  imports included, interpreter start excluded), best of ``--repeat``;
* the same stage warm, in this process (second and later runs);
* its phases: reading the OSM file, cropping and writing OSM XML, CARLA's converter (its own
  process), OpenDRIVE parsing and lane sampling, route fit, OSM alignment check, picture;
* the query module against ``carla.Map``: building lane geometry (numpy evaluation of the plan
  view vs carla.Map load + ``generate_waypoints`` + lane polygons from waypoint widths), and a
  batch of 10,000 nearest-lane and on-lane queries; with the largest distance between CARLA's
  waypoints and our lane centre lines (the exactness check).

Run from the repository root::

    python benchmarks/map.py [--repeat 3] [--out DIR]
"""

from __future__ import annotations

import argparse
import datetime as dt
import itertools
import json
import math
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np
import pyproj
import shapely

from cam2sim.core.config import Config
from cam2sim.core.dataset import POSE_PRECISION
from cam2sim.core.frames.projection import WorldFrame
from cam2sim.core.table import read_table, write_table
from cam2sim.core.workspace import Workspace, WorldFrameRecord, dataset_paths
from cam2sim.map.check import osm_alignment
from cam2sim.map.convert import CARLA_ROAD_TYPES, osm_to_xodr
from cam2sim.map.osm import read_osm
from cam2sim.map.query import RoadMap
from cam2sim.map.report import fit_route, plot_map
from cam2sim.stages.map import MapOptions, build_map, route_box

REPO = Path(__file__).resolve().parents[1]
SRC = REPO / "src"

OSM = REPO.parent / "shared" / "data" / "osm" / "munich.osm"
ROUTE_WAY = 19722634  # Straßbergerstraße, two-way, 445 m
MARGIN_M = 700.0  # the box then holds all of munich.osm


def make_workspace(root: Path) -> Path:

    osm = read_osm(OSM)
    way = next(w for w in osm.ways if w.id == ROUTE_WAY)
    lat, lon = osm.way_coords(way)
    frame = WorldFrame(float(lat[0]), float(lon[0]))
    xy = frame.from_wgs84(lat, lon)[:, :2]
    s = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(xy, axis=0).T))])
    si = np.arange(0.0, s[-1], 0.33)  # 30 Hz at 10 m/s
    pts = np.stack([np.interp(si, s, xy[:, 0]), np.interp(si, s, xy[:, 1])], axis=-1)
    d = np.gradient(pts, axis=0)
    heading = np.arctan2(d[:, 1], d[:, 0])
    pts += 1.675 * np.stack([np.sin(heading), -np.cos(heading)], axis=-1)
    ws = Workspace.create(root, Config())
    ws.record_stage(
        "extract",
        state="done",
        started=dt.datetime.now(dt.UTC),
        world=WorldFrameRecord(
            proj_string=frame.proj_string,
            origin_lat_deg=frame.origin_lat_deg,
            origin_lon_deg=frame.origin_lon_deg,
            source_crs="EPSG:4326",
        ),
    )
    n = len(si)
    write_table(
        dataset_paths(ws.dataset_dir).trajectory_csv,
        {
            "stamp_ns": (si / 10.0 * 1e9).astype(np.int64),
            "t": si / 10.0,
            "x": pts[:, 0],
            "y": pts[:, 1],
            "z": np.zeros(n),
            "qx": np.zeros(n),
            "qy": np.zeros(n),
            "qz": np.sin(heading / 2),
            "qw": np.cos(heading / 2),
            "heading": heading,
            "speed": np.full(n, 10.0),
        },
        precision=POSE_PRECISION,
    )
    return root


CHILD = """
import sys, time, json
from pathlib import Path
t0 = time.perf_counter()
from cam2sim.core.workspace import Workspace
from cam2sim.stages.map import MapOptions, build_map
r = build_map(Workspace.open(Path(sys.argv[1])), options=MapOptions(osm=Path(sys.argv[2]),
              margin_m=float(sys.argv[3])), force=True)
print(json.dumps({"stage_s": time.perf_counter() - t0, "roads": r.report.roads.roads}))
"""


def cold_stage(ws: Path, repeat: int) -> dict[str, float]:
    env = {**os.environ, "PYTHONPATH": str(SRC)}
    stage, wall = [], []
    for _ in range(repeat):
        t = time.perf_counter()
        out = subprocess.run(
            [sys.executable, "-c", CHILD, str(ws), str(OSM), str(MARGIN_M)],
            capture_output=True,
            text=True,
            check=True,
            env=env,
        )
        wall.append(time.perf_counter() - t)
        stage.append(json.loads(out.stdout.strip().splitlines()[-1])["stage_s"])
    return {"stage_s": min(stage), "process_wall_s": min(wall)}


def phases(ws_root: Path) -> dict[str, float]:

    ws = Workspace.open(ws_root)
    world = ws.world_frame()
    assert world is not None
    assert world.origin_lat_deg is not None
    assert world.origin_lon_deg is not None
    frame = WorldFrame(world.origin_lat_deg, world.origin_lon_deg)
    table = read_table(dataset_paths(ws.dataset_dir).trajectory_csv)
    xy = np.stack([table["x"], table["y"]], axis=-1).astype(np.float64)
    box = route_box(frame, xy, MARGIN_M)
    out: dict[str, float] = {}
    t = time.perf_counter()
    osm = read_osm(OSM)
    out["read_osm_s"] = time.perf_counter() - t
    t = time.perf_counter()
    osm = osm.crop(box)
    xml = osm.to_xml()
    out["crop_and_xml_s"] = time.perf_counter() - t
    t = time.perf_counter()
    xodr = osm_to_xodr(xml, frame.proj_string)
    out["convert_s"] = time.perf_counter() - t
    t = time.perf_counter()
    road_map = RoadMap.from_xodr(xodr)
    out["parse_and_sample_lanes_s"] = time.perf_counter() - t
    t = time.perf_counter()
    fit = fit_route(road_map, xy, table["t"], table["heading"])
    out["route_fit_s"] = time.perf_counter() - t
    t = time.perf_counter()
    osm_alignment(osm, road_map, frame, CARLA_ROAD_TYPES)
    out["osm_alignment_s"] = time.perf_counter() - t
    with tempfile.TemporaryDirectory() as tmp:
        t = time.perf_counter()
        plot_map(road_map, xy, fit.on_lane, Path(tmp) / "map.png")
        out["picture_s"] = time.perf_counter() - t
    out["xodr_bytes"] = float(len(xodr))
    out["roads"] = float(sum(not r.in_junction for r in road_map.opendrive.roads))
    out["junctions"] = float(len(road_map.opendrive.junctions))
    out["lanes"] = float(len(road_map.lanes))
    return out


def queries(xodr: str) -> dict[str, float]:

    out: dict[str, float] = {}
    t = time.perf_counter()
    road_map = RoadMap.from_xodr(xodr)
    road_map.lane_polygons()
    out["numpy_lanes_and_polygons_s"] = time.perf_counter() - t
    os.environ.setdefault("PROJ_LIB", pyproj.datadir.get_data_dir())
    import carla  # noqa: PLC0415 - needs PROJ_LIB set first

    t = time.perf_counter()
    cmap = carla.Map("bench", xodr)
    waypoints = cmap.generate_waypoints(0.5)
    rows = np.array(
        [
            (
                w.road_id,
                w.section_id,
                w.lane_id,
                w.s,
                w.transform.location.x,
                -w.transform.location.y,
                -math.radians(w.transform.rotation.yaw),
                w.lane_width,
            )
            for w in waypoints
        ]
    )
    order = np.lexsort((rows[:, 3], rows[:, 2], rows[:, 1], rows[:, 0]))
    rows = rows[order]
    _, first = np.unique(rows[:, :3], axis=0, return_index=True)
    bounds = np.append(np.sort(first), len(rows))
    polys = []
    for a, b in itertools.pairwise(bounds):
        g = rows[a:b]
        if len(g) < 2:
            continue
        n = np.stack([-np.sin(g[:, 6]), np.cos(g[:, 6])], axis=-1) * (g[:, 7:8] / 2)
        polys.append(shapely.Polygon(np.concatenate([g[:, 4:6] + n, (g[:, 4:6] - n)[::-1]])))
    out["carla_map_driving_lanes_and_polygons_s"] = time.perf_counter() - t
    out["carla_waypoints"] = float(len(waypoints))
    near = road_map.nearest_lane(rows[:, 4:6])
    out["carla_vs_numpy_centre_max_m"] = float(near.distance.max())
    out["carla_vs_numpy_centre_p99_m"] = float(np.percentile(near.distance, 99))
    rng = np.random.default_rng(0)
    centres = np.concatenate([ln.centre for ln in road_map.lanes if ln.type == "driving"])
    pts = centres[rng.integers(0, len(centres), 10_000)] + rng.normal(0.0, 1.0, (10_000, 2))
    road_map.nearest_lane(pts[:10])
    road_map.on_lane(pts[:10])
    t = time.perf_counter()
    road_map.nearest_lane(pts)
    out["nearest_lane_10k_s"] = time.perf_counter() - t
    t = time.perf_counter()
    road_map.on_lane(pts)
    out["on_lane_10k_s"] = time.perf_counter() - t
    t = time.perf_counter()
    for p in pts[:1000]:
        cmap.get_waypoint(carla.Location(float(p[0]), float(-p[1]), 0.0))
    out["carla_get_waypoint_1k_loop_s"] = time.perf_counter() - t
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--out", type=Path, default=None)
    args = parser.parse_args()
    if not OSM.is_file():
        sys.exit(f"needs {OSM}")
    out_dir = args.out or Path(tempfile.mkdtemp(prefix="cam2sim-bench-map-"))
    ws = make_workspace(out_dir / "ws")

    results: dict[str, Any] = {
        "machine": {"python": platform.python_version(), "cpus": os.cpu_count()},
        "osm": {"file": OSM.name, "bytes": OSM.stat().st_size},
    }
    results["cold_stage"] = cold_stage(ws, args.repeat)
    warm = []
    for _ in range(args.repeat):
        t = time.perf_counter()
        result = build_map(
            Workspace.open(ws), options=MapOptions(osm=OSM, margin_m=MARGIN_M), force=True
        )
        warm.append(time.perf_counter() - t)
    results["warm_stage_s"] = min(warm)
    results["route"] = {
        "poses": result.report.route.poses,
        "covered_fraction": result.report.route.covered_fraction,
        "box": result.report.box,
    }
    results["phases"] = phases(ws)
    results["queries"] = queries(result.xodr_path.read_text(encoding="utf-8"))
    (out_dir / "map_benchmark.json").write_text(json.dumps(results, indent=2))
    print(json.dumps(results, indent=2))
    print(f"written to {out_dir / 'map_benchmark.json'}")


if __name__ == "__main__":
    main()
