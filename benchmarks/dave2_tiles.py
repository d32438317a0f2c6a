"""Which parts of a camera's image move DAVE-2 away from its answer on the truth image.

At recorded route positions (metres along the recorded centre line) the truth and the other
camera render the same pose as a drive would (:func:`cam2sim.stages.cameras.vehicle_camera_pose`);
each tile of the rows DAVE-2 reads (``--grid`` rows x columns) is copied from the other camera
into the truth image alone and DAVE-2 answers again. Per position it prints the two answers and
the change each tile makes (steering units, + = left), and draws the truth image with the tiles
tinted by their change (red: to the left, blue: to the right; full tint at ``--scale`` units)
beside the other camera's image::

    python benchmarks/dave2_tiles.py WS --at 55,65,75 --out /tmp/tiles.png
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

import numpy as np

from cam2sim.ads.policy import load_policy
from cam2sim.core.images import write_rgb
from cam2sim.core.polyline import arc_length
from cam2sim.core.workspace import Workspace
from cam2sim.sim.interface import Observation
from cam2sim.stages.cameras import Cameras, load_run_context, run_camera, vehicle_camera_pose

sys.path.insert(0, str(Path(__file__).parent))
from dave2_offset_response import vehicle_at


def _args() -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("workspace", type=Path)
    parser.add_argument("--at", required=True, help="route positions, metres: 55,65,75")
    parser.add_argument("--camera", default="splat", help="the camera set against the truth")
    parser.add_argument("--grid", default="4x8", help="tiles: rows x columns of the crop")
    parser.add_argument("--scale", type=float, default=0.1, help="units of full tint")
    parser.add_argument("--out", type=Path, required=True, help="PNG of every position")
    return parser.parse_args()


def _tinted(
    image: np.ndarray, grid: np.ndarray, ys: np.ndarray, xs: np.ndarray, scale: float
) -> np.ndarray:
    out = image.astype(np.float64)
    for a in range(grid.shape[0]):
        for b in range(grid.shape[1]):
            k = 0.6 * min(1.0, abs(grid[a, b]) / scale)
            colour = np.array((255.0, 0.0, 0.0) if grid[a, b] > 0 else (0.0, 0.0, 255.0))
            tile = out[ys[a] : ys[a + 1], xs[b] : xs[b + 1]]
            out[ys[a] : ys[a + 1], xs[b] : xs[b + 1]] = tile * (1 - k) + colour * k
    return out.astype(np.uint8)


def _tiles(policy: Any, truth: np.ndarray, other: np.ndarray, state: Any, shape: tuple[int, int],
           ) -> tuple[float, float, np.ndarray, np.ndarray, np.ndarray]:  # fmt: skip
    height, width = truth.shape[:2]
    rows = policy.image_rows(height) or (0, height)
    ys = np.linspace(rows[0], rows[1], shape[0] + 1).astype(int)
    xs = np.linspace(0, width, shape[1] + 1).astype(int)
    base = policy.predict(Observation(0.0, truth, state))
    whole = policy.predict(Observation(0.0, other, state))
    grid = np.zeros(shape)
    for a in range(shape[0]):
        for b in range(shape[1]):
            mixed = truth.copy()
            cut = (slice(ys[a], ys[a + 1]), slice(xs[b], xs[b + 1]))
            mixed[cut] = other[cut]
            grid[a, b] = policy.predict(Observation(0.0, mixed, state)) - base
    return base, whole, grid, ys, xs


def main() -> None:
    args = _args()
    ws = Workspace.open(args.workspace)
    ctx = load_run_context(ws)
    sc = ctx.scenario
    policy = load_policy(
        str(ws.ads_files.onnx),
        route_xy=None,
        wheelbase_m=sc.vehicle.wheelbase_m,
        calibration=sc.steering_calibration,
    )
    camera = run_camera(sc, None)
    shape = tuple(int(v) for v in args.grid.split("x"))
    centre = np.asarray(sc.trajectory.center, np.float64)
    heading = np.asarray(sc.trajectory.heading, np.float64)
    s = arc_length(centre[:, :2])
    panels = []
    with Cameras(ctx, ("truth", args.camera)) as cams:
        for at in (float(v) for v in args.at.split(",")):
            i = int(np.argmin(np.abs(s - at)))
            x, y, h = centre[i, 0], centre[i, 1], heading[i]
            views = {
                name: cams.render(name, vehicle_camera_pose(sc, x, y, h, recorded=name == "splat"),
                                  camera)
                for name in ("truth", args.camera)
            }  # fmt: skip
            base, whole, grid, ys, xs = _tiles(
                policy,
                views["truth"],
                views[args.camera],
                vehicle_at(x, y, h),
                (shape[0], shape[1]),
            )
            print(f"s = {s[i]:.0f} m: truth {base:+.3f}, {args.camera} {whole:+.3f} "
                  f"(difference {whole - base:+.3f}; the tiles one at a time add up to "
                  f"{grid.sum():+.3f})")  # fmt: skip
            print(np.array2string(grid, precision=3, suppress_small=True))
            tinted = _tinted(views["truth"], grid, ys, xs, args.scale)
            panels.append(np.hstack([tinted, views[args.camera]]))
    policy.close()
    write_rgb(args.out, np.vstack(panels))


if __name__ == "__main__":
    main()
