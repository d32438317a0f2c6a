"""What smoothing GPS fixes buys: jitter, speed and derived steering, on real paths.

Real paths written as a 10 Hz GPS logger would log them (no orientation, the ``gps`` error of
``benchmarks/pose_noise.py``: a slow drift and 0.1 m of jitter), taken as the import takes
them, once as logged and once through ``core.trajectory.smooth_positions``:

- KITTI 03's ground-truth poses (``--kitti``: its ``poses.txt``): the jitter left (error minus
  its 2 s mean), the speed error over 0.2 s, and the steering derived from the fixes against
  the steering derived from the ground-truth poses;
- the three reference drives (``../shared/data/reference-drives``): the derived steering
  against the car's measured steering (also ``tests/sim/test_builtin.py``).

    PYTHONPATH=src python benchmarks/gps_smoothing.py --kitti KITTI/ground-truth.txt

KITTI is CC BY-NC-SA 3.0: keep its poses out of the repository.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "src"))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from cam2sim.core.trajectory import Trajectory, heading_from_motion, smooth_positions
from cam2sim.core.vehicle import SteeringCalibration
from cam2sim.scenario.calibration import steering_from_poses
from pose_noise import add_noise

DRIVES = Path(__file__).resolve().parents[2] / "shared" / "data" / "reference-drives"
MOTION_WINDOW_M = 3.0  # stages/ads.py's MOTION_STEERING_WINDOW_M


def _speed(t: np.ndarray, xy: np.ndarray) -> np.ndarray:
    ns = np.round((t - t[0]) * 1e9).astype(np.int64)
    p = np.c_[xy, np.zeros(len(xy))]
    return Trajectory(ns, p, np.tile([0.0, 0.0, 0.0, 1.0], (len(p), 1))).speed_at(ns, window_s=0.2)


def _steering(t: np.ndarray, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Steering derived from positions alone, as ``cam2sim ads`` derives it for GPS fixes."""
    ns = np.round((t - t[0]) * 1e9).astype(np.int64)
    heading = heading_from_motion(ns, np.c_[xy, np.zeros(len(xy))], window_s=1.0, min_speed_mps=0.5)
    return steering_from_poses(
        t, xy, heading, _speed(t, xy), SteeringCalibration(), window_m=MOTION_WINDOW_M
    )


def _smoothed(t: np.ndarray, xy: np.ndarray) -> np.ndarray:
    return smooth_positions(np.round((t - t[0]) * 1e9).astype(np.int64), xy, max_gap_s=0.5)[0]


def kitti(poses: Path, seeds: int) -> None:
    rows = np.loadtxt(poses).reshape(-1, 3, 4)
    pose = np.tile(np.eye(4), (len(rows), 1, 1))
    pose[:, :3, :] = rows
    t = np.arange(len(pose)) * 0.1
    truth = pose[:, [0, 2], 3]  # KITTI's camera axes: x right, z forward -> east, north
    heading = np.unwrap(np.arctan2(pose[:, 2, 2], pose[:, 0, 2]))
    ts, want = steering_from_poses(t, truth, heading, _speed(t, truth), SteeringCalibration())
    inner = (ts > 2) & (ts < ts[-1] - 2)
    print(
        "KITTI 03 as 10 Hz fixes | seed | jitter left m (per axis) | speed error m/s | "
        "steering vs truth"
    )
    for seed in range(seeds):
        noisy = add_noise(pose, "gps", seed)[:, [0, 2], 3]
        for name, xy in (("as logged", noisy), ("smoothed", _smoothed(t, noisy))):
            err = xy - truth
            kernel = np.ones(21) / 21
            mean = np.stack([np.convolve(err[:, k], kernel, mode="same") for k in (0, 1)], -1)
            jitter = np.sqrt(np.mean((err - mean)[10:-10] ** 2))  # per axis
            speed = np.sqrt(np.mean((_speed(t, xy) - _speed(t, truth)) ** 2))
            tg, got = _steering(t, xy)
            corr = np.corrcoef(np.interp(ts, tg, got)[inner], want[inner])[0, 1]
            print(f"{name:>10} | {seed} | {jitter:.3f} | {speed:.2f} | {corr:.3f}")


def reference_drives(seeds: int) -> None:
    from scipy.signal import lfilter  # noqa: PLC0415 -- lazy: only this part needs it

    out: dict[str, list[float]] = {"as logged": [], "smoothed": []}
    for n in (1, 2, 3):
        tr = np.genfromtxt(DRIVES / f"trajectory{n}.csv", delimiter=",", names=True)
        st = np.loadtxt(DRIVES / f"steering_{n}.txt", delimiter=",", comments="#")
        g = np.arange(tr["timestamp"][0], tr["timestamp"][-1], 0.1)
        fixes = np.stack([np.interp(g, tr["timestamp"], tr[c]) for c in ("x", "y")], -1)
        for seed in range(seeds):
            rng = np.random.default_rng(seed)
            a = math.exp(-0.1 / 20.0)  # a drift of 0.5 m with a 20 s memory
            drift = lfilter(
                [0.5 * math.sqrt(1 - a * a)], [1, -a], rng.normal(size=fixes.shape), axis=0
            )
            noisy = fixes + drift + rng.normal(0, 0.1, fixes.shape)
            for name, xy in (("as logged", noisy), ("smoothed", _smoothed(g, noisy))):
                ts, got = _steering(g, xy)
                inside = (ts > st[0, 0]) & (ts < st[-1, 0])
                measured = np.interp(ts[inside], st[:, 0], st[:, 1])
                out[name].append(float(np.corrcoef(got[inside], measured)[0, 1]))
    print("reference drives as 10 Hz fixes: steering vs measured (3 drives x seeds)")
    for name, corr in out.items():
        print(f"{name:>10}: mean {np.mean(corr):.3f}, worst {min(corr):.3f}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--kitti", type=Path, help="KITTI 03's poses.txt (skipped without)")
    parser.add_argument("--seeds", type=int, default=3)
    args = parser.parse_args()
    if args.kitti is not None:
        kitti(args.kitti, args.seeds)
    if DRIVES.is_dir():
        reference_drives(args.seeds)


if __name__ == "__main__":
    main()
