"""How the driving model answers each camera at and beside the recorded path, open loop.

Why a splat run's closed-loop line can lie further from the recorded one than a Real run's
(the CPU suite's Min-Fréchet ratio, docs/benchmarks.md): at recorded trajectory samples the
vehicle is set on the path and moved sideways by each offset (metres, positive to the left),
every camera renders what the drive would show it there (the same poses, renderers and rows as
:func:`cam2sim.stages.cameras.vehicle_view`) and the workspace's DAVE-2 steers. Per camera it
prints the mean steering at each offset, the restoring slope (steering units per metre of
offset: how strongly the model comes back, from a least-squares line per sample), and against
the first camera the bias on the path (mean and by fifth of the route) and the offset it is
worth (bias / slope: where a car held by that slope settles). A plot of the steering along the
route goes to ``--plot``::

    python benchmarks/dave2_offset_response.py WS --cameras truth,splat --every 6 \
        --plot /tmp/response.png
"""

from __future__ import annotations

import argparse
import math
import time
from pathlib import Path
from typing import Any

import numpy as np

from cam2sim.ads.policy import load_policy
from cam2sim.core.plots import pyplot, save_figure
from cam2sim.core.polyline import arc_length
from cam2sim.core.vehicle import VehicleState
from cam2sim.core.workspace import Workspace
from cam2sim.sim.interface import Observation
from cam2sim.stages.cameras import (
    Cameras,
    load_run_context,
    policy_band,
    run_camera,
    vehicle_camera_pose,
)


def vehicle_at(x: float, y: float, heading: float) -> VehicleState:
    """The car standing at ``(x, y)`` with ``heading``, as a policy's observation carries it."""
    return VehicleState(
        t=0.0, x=x, y=y, z=0.0, heading=heading, speed=5.0, wheel_angle=0.0, steering=0.0,
        rear_axle=(x, y), progress_m=0.0,
    )  # fmt: skip


def _args() -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("workspace", type=Path)
    parser.add_argument("--cameras", default="truth,splat", help="the first is the reference")
    parser.add_argument("--offsets", default="-0.6,-0.3,0,0.3,0.6", help="metres, + = left")
    parser.add_argument("--every", type=int, default=6, help="every n-th trajectory sample")
    parser.add_argument("--policy", default=None, help="default: the workspace's DAVE-2")
    parser.add_argument("--plot", type=Path, default=None)
    parser.add_argument("--npz", type=Path, default=None, help="save the raw steering here")
    return parser.parse_args()


def _answers(
    ctx: Any, policy: Any, names: tuple[str, ...], samples: np.ndarray, offsets: np.ndarray
) -> np.ndarray:
    """``(cameras, samples, offsets)`` steering of ``policy`` on each camera's view."""
    sc = ctx.scenario
    camera = run_camera(sc, None)
    centre = np.asarray(sc.trajectory.center, np.float64)
    heading = np.asarray(sc.trajectory.heading, np.float64)
    steer = np.zeros((len(names), len(samples), len(offsets)))
    start = time.perf_counter()
    with Cameras(ctx, names) as cams:
        for c, name in enumerate(names):
            band = policy_band(policy, cams, name, camera.height, keep_frames=False)
            for j, i in enumerate(samples):
                h = heading[i]
                for k, e in enumerate(offsets):
                    x = centre[i, 0] - math.sin(h) * e
                    y = centre[i, 1] + math.cos(h) * e
                    T = vehicle_camera_pose(sc, x, y, h, recorded=name == "splat")
                    if band is None:
                        image = cams.render(name, T, camera)
                    else:  # the rows DAVE-2 reads, as a drive renders them
                        image = np.zeros((camera.height, camera.width, 3), np.uint8)
                        image[band[0] : band[1]] = cams.render(name, T, camera, rows=band)
                    steer[c, j, k] = policy.predict(Observation(0.0, image, vehicle_at(x, y, h)))
            print(f"{name}: {len(samples)} samples x {len(offsets)} offsets "
                  f"({time.perf_counter() - start:.0f} s)", flush=True)  # fmt: skip
    return steer


def _table(
    names: tuple[str, ...], offsets: np.ndarray, steer: np.ndarray, slope: np.ndarray
) -> None:
    on = int(np.argmin(np.abs(offsets)))
    header = " | ".join(f"{e:+.1f} m" for e in offsets)
    print(f"| camera | {header} | slope units/m (median) |")
    for c, name in enumerate(names):
        cells = " | ".join(f"{v:+.3f}" for v in steer[c].mean(axis=0))
        print(f"| {name} | {cells} | {np.median(slope[c]):+.3f} |")
    fifths = np.array_split(np.arange(steer.shape[1]), 5)
    for c in range(1, len(names)):
        d = steer[c, :, on] - steer[0, :, on]
        k = np.median(slope[c])
        parts = ", ".join(f"{d[f].mean():+.3f}" for f in fifths)
        print(
            f"{names[c]} - {names[0]} on the path: mean {d.mean():+.3f} units "
            f"(|d| {np.abs(d).mean():.3f}; by fifth {parts}); worth {-d.mean() / k:+.3f} m "
            f"at {names[c]}'s slope (+ = left)"
        )


def _plot(
    path: Path, title: str, names: tuple[str, ...], s: np.ndarray, on_path: np.ndarray,
    slope: np.ndarray,
) -> None:  # fmt: skip
    plt = pyplot()
    fig, ax = plt.subplots(2, 1, figsize=(10, 6), sharex=True)
    for c, name in enumerate(names):
        ax[0].plot(s, on_path[c], label=name)
        ax[1].plot(s, slope[c], label=name)
    ax[0].set_ylabel("steering on the path")
    ax[1].set_ylabel("slope, steering units per m to the left")
    ax[1].set_xlabel("route, m")
    ax[0].legend()
    ax[0].set_title(title)
    save_figure(fig, path, dpi=100)


def main() -> None:
    args = _args()
    ws = Workspace.open(args.workspace)
    ctx = load_run_context(ws)
    sc = ctx.scenario
    names = tuple(args.cameras.split(","))
    offsets = np.array([float(o) for o in args.offsets.split(",")])
    spec = args.policy or str(ws.ads_files.onnx)
    policy = load_policy(
        spec,
        route_xy=np.asarray(sc.trajectory.rear_axle, np.float64)[:, :2],
        wheelbase_m=sc.vehicle.wheelbase_m,
        calibration=sc.steering_calibration,
    )
    centre = np.asarray(sc.trajectory.center, np.float64)
    # Leave the first and last 2 s: the start and the stop are not where drives differ.
    samples = np.arange(20, len(centre) - 20, args.every)
    s = arc_length(centre[:, :2])[samples]
    try:
        steer = _answers(ctx, policy, names, samples, offsets)
    finally:
        policy.close()
    # Least-squares slope per sample (units per metre of offset to the left).
    dx = offsets - offsets.mean()
    slope = ((steer - steer.mean(axis=2, keepdims=True)) * dx).sum(axis=2) / (dx**2).sum()
    print(f"\n{ws.root}: {len(samples)} samples over {s[-1] - s[0]:.0f} m, policy {spec}")
    _table(names, offsets, steer, slope)
    if args.npz is not None:
        np.savez(args.npz, names=np.array(names), offsets=offsets, s=s, steer=steer)
    if args.plot is not None:
        on = int(np.argmin(np.abs(offsets)))
        _plot(args.plot, str(ws.root), names, s, steer[:, :, on], slope)


if __name__ == "__main__":
    main()
