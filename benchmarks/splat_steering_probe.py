"""What in the splat's views moves the drives' policy (issue 37): probes at chosen stations.

For a benchmark or demo workspace (a scenario, splat models, the ground-truth world and the
drives' DAVE-2 at ``WS/ads/dave2.onnx``) it renders, at each ``--stations`` metre of the
recorded path, the splat and the truth views of the same pose, asks the policy for its
steering on both, and on views mixed from the two:

- the truth rendered ``--shifts`` metres behind and ahead of the pose (is the splat shifted
  along the route?), with each one's PSNR against the splat;
- the splat's upper rows (sky, facades) or its road rows (from ``--horizon`` down) pasted on the
  truth;
- the truth blurred (Gaussian, 2 px); the splat's structure above 2 px with the truth's finer
  detail; the truth with the splat's colour statistics; the truth without its sensor noise
  (the world's textures only: what a splat can learn).

Optionally writes the truth, the splat and their difference (x3) side by side (``--image``).
Run from the repository root::

    PYTHONPATH=src python benchmarks/splat_steering_probe.py BENCH/worlds/LABEL/ws \
        --stations 100,110,290,300 --image bends.jpg
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import TYPE_CHECKING

import cv2
import numpy as np

from cam2sim.core.workspace import Workspace
from cam2sim.metrics.image_quality import psnr
from cam2sim.stages import route_profile as rp
from cam2sim.stages.cameras import (
    TRUTH_CAMERA,
    Cameras,
    first_decision,
    load_run_context,
    run_camera,
    view_policy,
)

if TYPE_CHECKING:
    import numpy.typing as npt


def _low(image: npt.NDArray[np.float32], sigma: float) -> npt.NDArray[np.float32]:
    return cv2.GaussianBlur(image, (0, 0), sigma)


def main() -> None:
    """Print one row of probes per station."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("ws", type=Path)
    parser.add_argument("--stations", required=True, help="metres along the path, e.g. 100,290")
    parser.add_argument("--shifts", default="-1.5,-1,-0.5,0,0.5,1,1.5")
    parser.add_argument("--horizon", type=float, default=0.45, help="share of rows above the road")
    parser.add_argument("--image", type=Path, help="write truth | splat | difference x3 here")
    args = parser.parse_args()
    ws = Workspace.open(args.ws)
    ctx = load_run_context(ws)
    sc = ctx.scenario
    s_all = rp._stations(sc)  # noqa: SLF001 -- the profile's own stations and poses
    ref = np.asarray(sc.trajectory.reference, dtype=np.float64)[:, :2]
    heading = np.asarray(sc.trajectory.heading, dtype=np.float64)
    camera = run_camera(sc, rp._small(sc))  # noqa: SLF001
    policy = view_policy(str(ws.root / "ads" / "dave2.onnx"), sc)

    def pose(s: float, *, splat: bool) -> npt.NDArray[np.float64]:
        i = min(int(np.searchsorted(s_all, s)), len(s_all) - 1)
        return rp._pose(sc, ref[i], heading[i], 0.0, splat=splat)  # noqa: SLF001

    def steer(image: npt.NDArray[np.floating] | npt.NDArray[np.uint8]) -> float:
        return first_decision(policy, np.clip(image, 0, 255).astype(np.uint8))

    shifts = [float(x) for x in args.shifts.split(",")]
    road = slice(int(args.horizon * camera.height), camera.height)
    sky = slice(0, road.start)
    rows = []
    print(
        "| s m | truth | splat | truth shifted (m: steering, PSNR vs splat) | splat sky | "
        "splat road | truth blurred 2 px | splat > 2 px + truth detail | splat colours | "
        "truth without sensor noise |"
    )
    print("| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |")
    with Cameras(ctx, ("splat", TRUTH_CAMERA)) as cams:
        for s in (float(x) for x in args.stations.split(",")):
            splat = cams.render("splat", pose(s, splat=True), camera)
            truth = cams.render(TRUTH_CAMERA, pose(s, splat=False), camera)
            shifted = []
            for d in shifts:
                moved = cams.render(TRUTH_CAMERA, pose(s + d, splat=False), camera)
                shifted.append(f"{d:+g}: {steer(moved):+.2f}, {psnr(moved, splat) or 0:.1f}")
            t, p = truth.astype(np.float32), splat.astype(np.float32)
            with_sky, with_road = t.copy(), t.copy()
            with_sky[sky], with_road[road] = p[sky], p[road]
            structure = _low(p, 2.0) + (t - _low(t, 2.0))
            colours = (t - t.mean((0, 1))) / t.std((0, 1)) * p.std((0, 1)) + p.mean((0, 1))
            renderer = cams.renderers[TRUTH_CAMERA]
            clean = renderer.render(pose(s, splat=False), camera, sensor_noise=False).rgb
            print(
                f"| {s:.0f} | {steer(truth):+.2f} | {steer(splat):+.2f} | {'; '.join(shifted)} | "
                f"{steer(with_sky):+.2f} | {steer(with_road):+.2f} | "
                f"{steer(_low(t, 2.0)):+.2f} | {steer(structure):+.2f} | {steer(colours):+.2f} | "
                f"{steer(clean):+.2f} |"
            )
            diff = np.clip(np.abs(t - p) * 3, 0, 255).astype(np.uint8)
            rows.append(np.concatenate([truth, splat, diff], axis=1))
    if args.image is not None:
        picture = cv2.cvtColor(np.concatenate(rows, axis=0), cv2.COLOR_RGB2BGR)
        cv2.imwrite(str(args.image), picture, [cv2.IMWRITE_JPEG_QUALITY, 85])


if __name__ == "__main__":
    main()
