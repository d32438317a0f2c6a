"""Where ground seeds land on a prepared scene, against the SfM points (issue 22).

Computes the cameras' height over the road ahead and the ground seeds of the scene's training
views (:mod:`cam2sim.splat.ground`), then draws one frame three times: as recorded; with every
seed from all views that falls in it, in the seed's colour (on a flat or gently sloped road the
lane markings of other views' pixels must line up with this frame's); and with the SfM points
that it sees, in green (where the starting model has nothing). Prints the height, the camera
step and the counts.

    python3 benchmarks/ground_seeds.py --prep WS/splat/prep --frame 100 --count 100000 \\
        --downscale 3 --out ground.jpg
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "src"))

from cam2sim.core.camera import project_points
from cam2sim.splat.ground import camera_height, ground_points
from cam2sim.splat.scene import SceneRecord, load_points
from cam2sim.splat.views import load_views


def _project(
    pts: np.ndarray, pose: np.ndarray, K: np.ndarray, size: tuple[int, int]
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Pixel columns, rows and the mask of ``pts`` that fall inside the image."""
    u, v, front = project_points(pts, pose, K, min_depth=1e-3)
    w, h = size
    inside = front & (u >= 0) & (u < w) & (v >= 0) & (v < h)
    return u[inside].astype(int), v[inside].astype(int), inside


def main() -> int:
    import cv2  # noqa: PLC0415

    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--prep", required=True, help="prepared scene (WS/splat/prep)")
    parser.add_argument("--frame", type=int, default=100, help="n-th training view to draw")
    parser.add_argument("--count", type=int, default=100_000, help="ground seeds wanted")
    parser.add_argument("--downscale", type=int, default=1, help="views read at 1/N size")
    parser.add_argument("--out", default="ground.jpg")
    args = parser.parse_args()
    prep = Path(args.prep)
    scene = SceneRecord.load(prep / "scene.json")
    frames = [f for f in scene.frames if not f.held_out]
    views = load_views(prep, frames, args.downscale, "cpu")
    xyz, _, _ = load_points(prep / "points.npz")
    poses = np.stack([f.T() for f in frames])
    Ks = views.Ks.double().numpy()
    usable = views.masks.numpy()
    if views.sky is not None:
        usable &= ~views.sky.numpy()
    height = camera_height(xyz, poses, Ks, usable)
    step = float(np.median(np.linalg.norm(np.diff(poses[:, :3, 3], axis=0), axis=1)))
    seeds, colours = ground_points(xyz, poses, Ks, views.images.numpy(), usable, count=args.count)
    print(f"{len(xyz)} SfM points; camera height {height} scene units; camera step {step:.4f}")
    print(f"{len(seeds)} ground seeds from {len(frames)} training views")
    frame = frames[args.frame]
    image = cv2.imread(str(prep / "images" / f"{frame.index:06d}.png"))
    size = (image.shape[1], image.shape[0])
    with_seeds = image.copy()
    u, v, inside = _project(seeds, frame.T(), frame.K(), size)
    with_seeds[v, u] = colours[inside][:, ::-1]
    with_sfm = image.copy()
    u, v, _ = _project(np.asarray(xyz, np.float64), frame.T(), frame.K(), size)
    for a, b in zip(u, v, strict=True):
        cv2.circle(with_sfm, (int(a), int(b)), 2, (0, 255, 0), -1)
    cv2.imwrite(args.out, np.concatenate([image, with_seeds, with_sfm], axis=1))
    print(f"wrote {args.out}: frame {frame.index} | ground seeds | SfM points")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
