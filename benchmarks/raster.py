"""Speed of the ``raster`` camera renderer (issue 8): RGB + labels per frame.

A straight 100 m two-way street (driving, parking and sidewalk lanes on each side), 20 parked
cars and 10 buildings, seen from 1.5 m above the right driving lane, the camera moving along the
road. Each size is rendered ``--frames`` times after one warm-up frame; the figure is the mean
wall time of :meth:`RasterRenderer.render` (draw, read-back and the copies of both images).

Target (issue 8): 512x512 RGB + labels in under 10 ms on the 2-core machine.

Then the runs' camera of the reference car (800x503 calibration with its plumb-bob lens, scaled
to DAVE-2's 320x200) through :meth:`cam2sim.stages.cameras.Cameras.render`: without the lens
(the calibrated K as a pinhole camera) and with it (the lens's pinhole camera rendered, then
remapped into the lens's pixels): what seeing through the recorded lens costs a frame.

Run from the repository root::

    python benchmarks/raster.py [--frames 200]
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

from cam2sim.core.camera import PinholeCamera
from cam2sim.map.query import RoadMap
from cam2sim.render.raster import BuildingFootprint, RasterRenderer, RasterScene
from cam2sim.scenario.model import ScenarioVehicle
from cam2sim.stages import cameras

# The reference car's camera (../shared/data/reference-drives/camera.json), scaled for DAVE-2.
REFERENCE = PinholeCamera(
    772.906855, 777.596896, 424.980372, 258.452509, 800, 503,
    (-0.274231, 0.034838, 0.00226, -0.000972, 0.0),
).scaled(320, 200)  # fmt: skip

_LANES = "".join(
    f'<lane id="{i}" type="{t}"><width sOffset="0" a="{w}" b="0" c="0" d="0"/></lane>'
    for i, t, w in ((3, "sidewalk", 2), (2, "parking", 2.5), (1, "driving", 3.5))
)
_RIGHT = "".join(
    f'<lane id="{i}" type="{t}"><width sOffset="0" a="{w}" b="0" c="0" d="0"/></lane>'
    for i, t, w in ((-1, "driving", 3.5), (-2, "parking", 2.5), (-3, "sidewalk", 2))
)
XODR = f"""<?xml version="1.0"?>
<OpenDRIVE><header revMajor="1" revMinor="4"/>
  <road name="street" length="100" id="1" junction="-1">
    <planView><geometry s="0" x="0" y="0" hdg="0" length="100"><line/></geometry></planView>
    <lanes><laneSection s="0"><left>{_LANES}</left><center><lane id="0" type="none"/></center>
      <right>{_RIGHT}</right></laneSection></lanes>
  </road>
</OpenDRIVE>
"""


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=200)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "map.xodr"
        path.write_text(XODR, encoding="utf-8")
        road_map = RoadMap.from_xodr(path)
    cars = [
        ScenarioVehicle(
            id=f"car{i}",
            position=(8.0 + 9.0 * (i // 2), 4.75 if i % 2 else -4.75, 0.0),
            heading=0.0,
            size=(4.5, 1.8, 1.5),
            size_class="medium",
            side="left" if i % 2 else "right",
            orientation="parallel",
        )
        for i in range(20)
    ]
    rect = np.array([[0.0, 0.0], [15.0, 0.0], [15.0, 8.0], [0.0, 8.0]])
    buildings = [
        BuildingFootprint(rect + np.array([20.0 * (i // 2), 10.0 if i % 2 else -18.0]), 9.0 + i)
        for i in range(10)
    ]
    t0 = time.perf_counter()
    scene = RasterScene(road_map, cars, buildings)
    print(f"scene: {len(scene.mesh) // 3} triangles, built in {time.perf_counter() - t0:.3f} s")
    R = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
    with RasterRenderer(scene) as renderer:
        for width, height in ((512, 512), (200, 66)):
            K = np.array([[0.5 * width, 0, (width - 1) / 2], [0, 0.5 * width, (height - 1) / 2]])
            camera = PinholeCamera.from_K(np.vstack([K, [0.0, 0.0, 1.0]]), width, height)
            poses = np.repeat(np.eye(4)[None], args.frames, axis=0)
            poses[:, :3, :3] = R
            poses[:, :3, 3] = np.column_stack(
                [
                    np.linspace(2.0, 60.0, args.frames),
                    np.full(args.frames, -1.75),
                    np.full(args.frames, 1.5),
                ]
            )
            renderer.render(poses[0], camera)
            t0 = time.perf_counter()
            for pose in poses:
                renderer.render(pose, camera)
            ms = 1000.0 * (time.perf_counter() - t0) / args.frames
            print(f"{width}x{height}: {ms:.2f} ms/frame over {args.frames} frames")
        cameras.register_camera("bench", lambda _ctx: renderer)
        runs = cameras.Cameras(None, ("bench",))  # type: ignore[arg-type]
        flat = PinholeCamera.from_K(REFERENCE.K(), REFERENCE.width, REFERENCE.height)
        for label, camera in (("pinhole", flat), ("through the lens", REFERENCE)):
            runs.render("bench", poses[0], camera)  # builds the remap tables once
            t0 = time.perf_counter()
            for pose in poses:
                runs.render("bench", pose, camera)
            ms = 1000.0 * (time.perf_counter() - t0) / args.frames
            print(f"reference camera 320x200, {label}: {ms:.2f} ms/frame")


if __name__ == "__main__":
    main()
