"""Speed of the demo recording (the truth world's bag: camera look, LiDAR, odometry).

Builds the recording of the built-in street, or of a route picked from an OSM extract
(``--osm FILE --pick N``, as the benchmark suites pick them), into a temporary folder and
prints its wall time and the bag's digest; ``--save FILE`` / ``--check FILE`` compare the
digest with one written before (a faster recording must write the same bytes). Then the
photographic look's and the LiDAR's own cost per frame and scan, on 20 poses along the route.

Run from the repository root::

    python benchmarks/demo_recording.py [--osm ../shared/data/osm/munich.osm --pick 1]
"""

from __future__ import annotations

import argparse
import hashlib
import tempfile
import time
from pathlib import Path

import numpy as np

from cam2sim.demo import bag
from cam2sim.demo.lidar import LidarModel
from cam2sim.demo.recording import build_demo_recording
from cam2sim.demo.rig import LIDAR_AZIMUTHS, LIDAR_BEAMS, demo_camera
from cam2sim.demo.world import demo_world
from cam2sim.render.raster import RasterRenderer


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--osm", type=Path)
    parser.add_argument("--pick", type=int, default=0)
    parser.add_argument("--save", type=Path)
    parser.add_argument("--check", type=Path)
    args = parser.parse_args()
    if args.osm is None:
        world = demo_world(0)
    else:
        from cam2sim.demo.osm_world import osm_demo_world  # noqa: PLC0415

        world = osm_demo_world(args.osm, route=None, seed=0, pick=args.pick).world
    street = world.street
    print(f"{street.title}: {street.length_m:.0f} m, {len(world.cars)} cars")
    with tempfile.TemporaryDirectory() as tmp:
        started = time.perf_counter()
        recording = build_demo_recording(Path(tmp), seed=0, street=street, world=world)
        seconds = time.perf_counter() - started
        digest = hashlib.sha256(recording.bag.joinpath("bag.mcap").read_bytes()).hexdigest()
    print(f"recording: {recording.camera_frames} frames in {seconds:.1f} s; bag digest {digest}")
    stations = np.linspace(5.0, street.length_m - 5.0, 20)
    scene = world.lidar_scene()
    lidar = LidarModel(beams=LIDAR_BEAMS, azimuths=LIDAR_AZIMUTHS)
    started = time.perf_counter()
    for i, station in enumerate(stations):
        bag._scan(scene, lidar, street, float(station), i)  # noqa: SLF001 -- the unit timed
    scan_ms = 1e3 * (time.perf_counter() - started) / len(stations)
    camera = demo_camera()
    with RasterRenderer(world.raster_scene()) as renderer:
        poses = [street.camera_pose(float(s)) for s in stations]
        started = time.perf_counter()
        frames = [renderer.render(pose, camera) for pose in poses]
        render_ms = 1e3 * (time.perf_counter() - started) / len(stations)
    started = time.perf_counter()
    for frame, pose in zip(frames, poses, strict=True):
        bag._look(frame, pose, camera.K(), 0)  # noqa: SLF001 -- the unit timed
    look_ms = 1e3 * (time.perf_counter() - started) / len(stations)
    print(
        f"per scan {scan_ms:.1f} ms; per frame: render {render_ms:.1f} ms, "
        f"look and JPEG {look_ms:.1f} ms"
    )
    if args.save:
        args.save.write_text(digest + "\n")
    if args.check:
        same = args.check.read_text().strip() == digest
        print("the same bytes as" if same else "DIFFERENT bytes from", args.check)
        raise SystemExit(0 if same else 1)


if __name__ == "__main__":
    main()
