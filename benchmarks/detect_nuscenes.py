"""Precision and recall of the geometric LiDAR detector (issue 6) on a real nuScenes sweep.

Data: ``../shared/data/lidar/nuscenes-sample/``, one ``LIDAR_TOP`` sweep (float32 x, y, z,
intensity, ring; x right, y forward, z up) and its mmdetection3d v2 info ``.pkl``, whose
``instances`` hold ``bbox_3d`` = x, y, z (box centre), length, width, height, yaw in the same
LiDAR frame, and ``bbox_label_3d`` (0 = car).

Protocol (the test ``tests/detect/test_lidar.py`` uses the same):

* recall: annotated cars whose centre lies within ``--range`` (40 m, xy) and that hold at least
  ``--min-points`` (10) LiDAR points; a car is found when a box centre lies within ``--match``
  (1 m, xy) of its centre;
* precision: boxes within the range; a box within 1 m of any annotated car (whatever its point
  count) is right; a box in (or within 1 m of) the footprint of an annotated truck, trailer, bus
  or construction vehicle is not counted (those are vehicles, but no cars); any other box is
  false.

Also reported: recall over every annotated car in range (however few points), centre and yaw
errors of the matches, and the time of one ``detect`` call. A bird's-eye PNG (points coloured
by height, annotated boxes, detected boxes with their scores) is written to ``--out``.

Run from the repository root::

    python benchmarks/detect_nuscenes.py [--out bev.png] [--range 40] [--min-points 10]
"""

from __future__ import annotations

import argparse
import math
import pickle
import platform
import time
from pathlib import Path
from typing import Any

import numpy as np

from cam2sim.detect.lidar import GeometricDetector

REPO = Path(__file__).resolve().parents[1]
DATA = REPO.parent / "shared" / "data" / "lidar" / "nuscenes-sample"
CAR, OTHER_VEHICLES = 0, (1, 2, 3, 4)  # car; truck, trailer, bus, construction vehicle


def footprint(box: np.ndarray) -> np.ndarray:
    """``(5, 2)`` closed outline of the footprint of ``x y z l w h yaw`` (metres)."""
    c, s = math.cos(box[6]), math.sin(box[6])
    corners = np.array([[1, 1], [1, -1], [-1, -1], [-1, 1], [1, 1]]) * (box[3:5] / 2)
    out: np.ndarray = corners @ np.array([[c, s], [-s, c]]) + box[:2]
    return out


def inside(xy: np.ndarray, box: np.ndarray, margin: float) -> bool:
    """Whether ``xy`` lies in the footprint of ``box`` grown by ``margin`` metres."""
    c, s = math.cos(box[6]), math.sin(box[6])
    dx, dy = xy[0] - box[0], xy[1] - box[1]
    along, across = abs(c * dx + s * dy), abs(-s * dx + c * dy)
    return bool(along <= box[3] / 2 + margin and across <= box[4] / 2 + margin)


def evaluate(
    det: np.ndarray, gt: np.ndarray, labels: np.ndarray, n_points: np.ndarray, args: Any
) -> dict[str, Any]:
    """Counts, precision and recall of detections ``det`` (``x y z l w h yaw`` rows)."""
    cars = labels == CAR
    in_range = np.hypot(gt[:, 0], gt[:, 1]) <= args.range
    targets = np.flatnonzero(cars & in_range & (n_points >= args.min_points))
    all_cars = np.flatnonzero(cars & in_range)
    det = det[np.hypot(det[:, 0], det[:, 1]) <= args.range]

    def nearest(xy: np.ndarray) -> tuple[int, float]:
        d = np.hypot(*(det[:, :2] - xy).T) if len(det) else np.array([np.inf])
        return int(np.argmin(d)), float(np.min(d))

    matches = []
    for k in all_cars:  # a few annotated cars
        j, d = nearest(gt[k, :2])
        if d <= args.match:
            yaw = (det[j, 6] - gt[k, 6]) % math.pi
            matches.append((int(k), j, d, math.degrees(min(yaw, math.pi - yaw))))
    found = {k for k, *_ in matches}
    right = wrong = ignored = 0
    for row in det:  # a few boxes
        if np.hypot(*(gt[cars, :2] - row[:2]).T).min() <= args.match:
            right += 1
        elif any(
            inside(row[:2], gt[k], args.match)
            for k in np.flatnonzero(np.isin(labels, OTHER_VEHICLES))
        ):
            ignored += 1
        else:
            wrong += 1
    return {
        "targets": len(targets),
        "targets_found": len(found & set(targets.tolist())),
        "cars_in_range": len(all_cars),
        "cars_in_range_found": len(found),
        "boxes": len(det),
        "right": right,
        "wrong": wrong,
        "ignored": ignored,
        "recall": len(found & set(targets.tolist())) / len(targets) if len(targets) else 1.0,
        "recall_all_in_range": len(found) / len(all_cars) if len(all_cars) else 1.0,
        "precision": right / (right + wrong) if right + wrong else 1.0,
        "matches": matches,
    }


def plot(
    points: np.ndarray,
    gt: np.ndarray,
    labels: np.ndarray,
    det: np.ndarray,
    score: np.ndarray,
    rng: float,
    out: Path,
) -> None:
    import matplotlib as mpl  # noqa: PLC0415

    mpl.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415

    near = np.hypot(points[:, 0], points[:, 1]) <= rng + 5
    fig, ax = plt.subplots(figsize=(11, 11))
    ax.scatter(
        points[near, 0],
        points[near, 1],
        s=0.3,
        c=points[near, 2],
        cmap="viridis",
        vmin=-2.5,
        vmax=1.0,
    )
    for box, label in zip(gt, labels, strict=True):
        colour = "red" if label == CAR else ("orange" if label in OTHER_VEHICLES else "lightgray")
        ax.plot(*footprint(box).T, color=colour, lw=1.2 if label in (CAR, *OTHER_VEHICLES) else 0.6)
    for box, s in zip(det, score, strict=True):
        ax.plot(*footprint(box).T, color="black", lw=2)
        ax.text(box[0] + 0.5, box[1] + 0.5, f"{s:.2f}", fontsize=8)
    circle = np.linspace(0.0, 2.0 * math.pi, 181)
    ax.plot(rng * np.cos(circle), rng * np.sin(circle), ls="--", color="gray", lw=0.8)
    ax.set_xlim(-rng - 5, rng + 5)
    ax.set_ylim(-rng - 5, rng + 5)
    ax.set_aspect("equal")
    ax.set_title("nuScenes LIDAR_TOP: cars (red), other vehicles (orange), detections (black)")
    ax.set_xlabel("x (m, right)")
    ax.set_ylabel("y (m, forward)")
    fig.savefig(out, dpi=90, bbox_inches="tight")
    plt.close(fig)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data", type=Path, default=DATA)
    parser.add_argument("--out", type=Path, default=Path("detect_nuscenes_bev.png"))
    parser.add_argument("--range", type=float, default=40.0, help="evaluation radius, m")
    parser.add_argument("--min-points", type=int, default=10, help="LiDAR points of a target car")
    parser.add_argument("--match", type=float, default=1.0, help="centre match distance, m")
    args = parser.parse_args()
    infos = sorted(args.data.glob("*.pkl"))
    sweeps = sorted(args.data.glob("*LIDAR_TOP*.pcd.bin"))
    if not infos or not sweeps:
        msg = f"needs a nuScenes info .pkl and a LIDAR_TOP .pcd.bin in {args.data}"
        raise SystemExit(msg)
    with infos[0].open("rb") as f:
        info = pickle.load(f)  # a local mmdet3d info file
    instances = info["data_list"][0]["instances"]
    gt = np.array([i["bbox_3d"] for i in instances], dtype=np.float64)
    labels = np.array([i["bbox_label_3d"] for i in instances])
    n_points = np.array([i["num_lidar_pts"] for i in instances])
    raw = np.fromfile(sweeps[0], dtype=np.float32).reshape(-1, 5)
    points = np.ascontiguousarray(raw[:, :4])

    detector = GeometricDetector()
    detector.detect(points)  # warm-up: imports scipy.ndimage
    times = []
    for _ in range(5):
        t = time.perf_counter()
        boxes = detector.detect(points)
        times.append(time.perf_counter() - t)
    det = np.column_stack([boxes.center, boxes.size, boxes.yaw])
    r = evaluate(det, gt, labels, n_points, args)

    print(f"machine: {platform.processor() or platform.machine()}, {platform.python_version()}")
    print(f"sweep: {sweeps[0].name}, {len(points)} points; {len(gt)} annotated boxes")
    print(f"detect: {1e3 * min(times):.1f} ms (best of 5), {len(boxes)} boxes")
    print(
        f"protocol: cars within {args.range:g} m with >= {args.min_points} LiDAR points, "
        f"match within {args.match:g} m (xy)"
    )
    print(f"annotated cars in range: {r['cars_in_range']}, of which targets: {r['targets']}")
    print(
        f"detections in range: {r['boxes']} (right {r['right']}, false {r['wrong']}, "
        f"on other vehicles {r['ignored']})"
    )
    print(f"recall    {r['recall']:.2f} ({r['targets_found']}/{r['targets']})")
    print(f"precision {r['precision']:.2f} ({r['right']}/{r['right'] + r['wrong']})")
    print(
        f"recall over all annotated cars in range: {r['recall_all_in_range']:.2f} "
        f"({r['cars_in_range_found']}/{r['cars_in_range']})"
    )
    for k, j, d, yaw in r["matches"]:
        print(
            f"  car at ({gt[k, 0]:.1f}, {gt[k, 1]:.1f}), {n_points[k]} points: box {d:.2f} m "
            f"off, yaw {yaw:.1f} deg off, size {det[j, 3]:.2f} x {det[j, 4]:.2f} x {det[j, 5]:.2f}"
        )
    plot(points, gt, labels, det, boxes.score, args.range, args.out)
    print(f"bird's-eye view written to {args.out}")


if __name__ == "__main__":
    main()
