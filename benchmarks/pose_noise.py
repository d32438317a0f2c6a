"""Benchmark: can bundle adjustment in the splat's preparation repair noisy recorded poses?

A real drive's poses come from odometry, SLAM or GPS, each with its own error; the splat is
trained at them and blurs what they misplace (KITTI 03's ground-truth poses: pose refinement
in training gained 0.029 held-out SSIM, docs/benchmarks.md). This takes a stretch of a posed
drive (KITTI odometry: frames and its ``poses.txt``), adds a GPS-like error to the poses (a slow
drift and a white jitter in position, a slow error in heading and pitch; seeded), triangulates
the frames at those poses with and without the bundle adjustment of
``PrepareOptions.refine_poses`` (:func:`cam2sim.splat.sfm.triangulate_known_poses`; ``free``:
the adjusted chain mapped back onto the recorded poses by one similarity, a number: every
centre held to its recorded position with that standard deviation, metres), and scores
the poses it trains at against the ground truth: centre error and rotation error after the
best similarity (the frame the splat lives in is the recording's, any common offset is
harmless), the frame-to-frame error (what blurs a chunk), the points and their reprojection
error, and the time.

    python benchmarks/pose_noise.py --images KITTI/images --poses KITTI/ground-truth.txt \\
        --calibration KITTI/K.txt --frames 0:120 --noise none gps --adjust off free 0.05 1 \\
        --out pose_noise.json

KITTI is CC BY-NC-SA 3.0: keep its frames out of the repository (docs/real-recordings.md).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
from scipy.ndimage import gaussian_filter1d
from scipy.spatial.transform import Rotation

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "src"))

from cam2sim.core.files import write_text_atomic
from cam2sim.splat.geometry import similarity_from_poses
from cam2sim.splat.sfm import KnownView, PoseAdjustment, triangulate_known_poses

NOISE = {
    # name: (position drift sigma m, position jitter sigma m, heading/pitch drift sigma deg)
    "none": (0.0, 0.0, 0.0),
    "odometry": (0.05, 0.01, 0.1),
    "gps": (0.5, 0.1, 0.5),
}
"""Error models: a slow drift (a Gaussian-filtered walk, 3 s at 10 Hz) and a white jitter in
position, a slow error in heading and pitch. ``gps``: a good consumer receiver fused with
its IMU; ``odometry``: a visual or wheel odometry over a short stretch."""


def load_kitti(poses: Path, calibration: Path, frames: slice) -> tuple[Any, Any]:
    """``(N, 4, 4)`` camera -> world poses of ``frames`` and the 3x3 K."""
    rows = np.loadtxt(poses, dtype=np.float64).reshape(-1, 3, 4)[frames]
    T = np.tile(np.eye(4), (len(rows), 1, 1))
    T[:, :3, :] = rows
    K = np.loadtxt(calibration, dtype=np.float64).reshape(3, 3)
    return T, K


def add_noise(T: npt.NDArray[np.float64], model: str, seed: int) -> npt.NDArray[np.float64]:
    """``T`` with the error ``model`` of :data:`NOISE` (positions and camera orientations)."""
    drift_m, jitter_m, drift_deg = NOISE[model]
    rng = np.random.default_rng(seed)
    n = len(T)

    def slow(sigma: float, dims: int) -> npt.NDArray[np.float64]:
        walk = gaussian_filter1d(rng.normal(size=(n, dims)), 30.0, axis=0, mode="nearest")
        scale = walk.std(axis=0, keepdims=True)
        return np.asarray(sigma * walk / np.where(scale > 0, scale, 1.0), dtype=np.float64)

    out = T.copy()
    out[:, :3, 3] += slow(drift_m, 3) + rng.normal(scale=jitter_m, size=(n, 3))
    # KITTI's camera axes: x right, y down, z forward; heading turns about y, pitch about x.
    angles = np.radians(slow(drift_deg, 2))
    turn = Rotation.from_rotvec(np.stack([angles[:, 1], angles[:, 0], np.zeros(n)], axis=1))
    out[:, :3, :3] = T[:, :3, :3] @ turn.as_matrix()
    return out


def pose_errors(T: npt.NDArray[np.float64], truth: npt.NDArray[np.float64]) -> dict[str, float]:
    """Centre and rotation errors of ``T`` against ``truth`` after the best similarity."""
    S = similarity_from_poses(T, truth)
    aligned = np.einsum("ij,njk->nik", S, T)
    scale = float(np.cbrt(np.linalg.det(S[:3, :3])))
    aligned[:, :3, :3] /= scale
    centre = np.linalg.norm(aligned[:, :3, 3] - truth[:, :3, 3], axis=1)
    rel = np.einsum("nji,njk->nik", aligned[:, :3, :3], truth[:, :3, :3])
    rot = np.degrees(Rotation.from_matrix(rel).magnitude())
    step = np.diff(aligned[:, :3, 3], axis=0) - np.diff(truth[:, :3, 3], axis=0)
    return {
        "centre_rms_m": float(np.sqrt((centre**2).mean())),
        "centre_max_m": float(centre.max()),
        "rotation_mean_deg": float(rot.mean()),
        "rotation_max_deg": float(rot.max()),
        "step_rms_m": float(np.sqrt((np.linalg.norm(step, axis=1) ** 2).mean())),
        "scale": scale,
    }


def run(images: list[Path], T: Any, K: Any, *, adjust: str) -> dict[str, Any]:
    """Triangulate at ``T`` (``adjust``: off, free or a prior in metres); the poses and scores."""
    with tempfile.TemporaryDirectory(prefix="pose-noise-") as tmp:
        links = []
        for i, image in enumerate(images):
            link = Path(tmp) / f"{i:06d}{image.suffix}"
            link.symlink_to(image.resolve())
            links.append(link)
        views = [KnownView(K=K, T_world_cam=t) for t in T]
        start = time.perf_counter()
        prior = None if adjust in {"off", "free"} else float(adjust)
        refine = PoseAdjustment(prior_m=prior) if adjust != "off" else False
        result = triangulate_known_poses(links, views, refine=refine)
        seconds = time.perf_counter() - start
    return {
        "poses": result.T_world_cam,
        "points": len(result.points.xyz),
        "mean_reprojection_error_px": result.mean_reprojection_error_px,
        "seconds": round(seconds, 1),
        "phases": {k: round(v, 1) for k, v in result.seconds.items()},
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--images", type=Path, required=True, help="the frames, one per pose")
    parser.add_argument("--poses", type=Path, required=True, help="KITTI poses.txt")
    parser.add_argument("--calibration", type=Path, required=True, help="a bare 3x3 K")
    parser.add_argument("--frames", default="0:120", help="START:STOP of the stretch")
    parser.add_argument("--noise", nargs="+", default=["none", "gps"], choices=sorted(NOISE))
    parser.add_argument(
        "--adjust", nargs="+", default=["off", "free"], help="off, free or a prior in metres"
    )
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, default=None)
    args = parser.parse_args()
    start, stop = (int(v) for v in args.frames.split(":"))
    frames = slice(start, stop)
    truth, K = load_kitti(args.poses, args.calibration, frames)
    images = sorted(p for p in args.images.iterdir() if p.suffix.lower() in {".png", ".jpg"})
    images = images[frames]
    if len(images) != len(truth):
        msg = f"{len(images)} frames for {len(truth)} poses in {args.frames}"
        raise SystemExit(msg)
    record: dict[str, Any] = {
        "machine": f"{platform.processor() or platform.machine()}, {os.cpu_count()} cores",
        "frames": args.frames,
        "seed": args.seed,
        "runs": [],
    }
    for model in args.noise:
        noisy = add_noise(truth, model, args.seed)
        given = pose_errors(noisy, truth)
        for adjust in args.adjust:
            out = run(images, noisy, K, adjust=adjust)
            row = {
                "noise": model,
                "bundle_adjustment": adjust,
                "given": given,
                "trained_at": pose_errors(out.pop("poses"), truth),
                **out,
            }
            record["runs"].append(row)
            print(
                f"{model:9s} BA={adjust:5s} "
                f"centres {row['trained_at']['centre_rms_m']:.3f} m rms "
                f"(given {given['centre_rms_m']:.3f}), "
                f"rotation {row['trained_at']['rotation_mean_deg']:.3f} deg "
                f"(given {given['rotation_mean_deg']:.3f}), "
                f"step {row['trained_at']['step_rms_m'] * 100:.1f} cm, "
                f"{row['points']} points at {row['mean_reprojection_error_px']:.2f} px, "
                f"{row['seconds']} s",
                flush=True,
            )
    if args.out is not None:
        write_text_atomic(args.out, json.dumps(record, indent=1) + "\n")


if __name__ == "__main__":
    main()
