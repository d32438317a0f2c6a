"""Plan the demo worlds of real OSM extracts and draw them from above (``cam2sim demo --osm``).

For each file: how long picking the route and building the world takes, the route (length,
bends), the street (lanes, speed, parked cars) and the buildings (real footprints kept, plain
facades added), printed as a table; and one picture with a panel per file: the extract's
drivable ways (grey), the drawn street's kerbs (black), the driven lane (blue), the OSM way the
route follows (red, dashed), the buildings and the parked cars.

Usage:
    python benchmarks/osm_worlds.py [FILES...] [--out docs/results/osm-worlds.png]

Without FILES it uses munich.osm, tram_crossing.osm, West-Oakland.osm.bz2 and
aguascalientes.osm.pbf from ../shared/data/osm/.
"""

from __future__ import annotations

import argparse
import math
import time
from pathlib import Path

import numpy as np

from cam2sim.core.plots import pyplot, save_figure
from cam2sim.demo.osm_world import osm_demo_world

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "osm"
FILES = ("munich.osm", "tram_crossing.osm", "West-Oakland.osm.bz2", "aguascalientes.osm.pbf")


def main() -> int:
    """Plan every world, print the table, draw the picture."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("files", nargs="*", type=Path)
    parser.add_argument("--out", type=Path, default=Path("docs/results/osm-worlds.png"))
    args = parser.parse_args()
    files = args.files or [DATA / f for f in FILES]
    fig, axes = pyplot().subplots(1, len(files), figsize=(5.0 * len(files), 5.2), squeeze=False)
    print("file | seconds | route | bends | lanes | km/h | cars | real buildings | facades")
    for ax, path in zip(axes[0], files, strict=True):
        started = time.perf_counter()
        plan = osm_demo_world(path)
        seconds = time.perf_counter() - started
        world, street = plan.world, plan.world.street
        real = sum(1 for b in world.buildings if len(b.xy) != 4)
        bends = ", ".join(f"{math.degrees(t):+.0f}°" for _, _, t in street.route.bend_turns())
        print(
            f"{path.name} | {seconds:.1f} | {street.length_m:.0f} m | {bends or 'none'} | "
            f"{street.lane_m:.2f} m | {street.speed_mps * 3.6:.0f} | {len(world.cars)} | "
            f"{real} | {len(world.buildings) - real}"
        )
        for note in plan.notes:
            print(f"    {note}")
        s = np.arange(-street.lead_m, street.length_m + street.lead_m, 1.0)
        half = street.lane_m / 2.0
        outer = street.lane_m + street.parking_m + street.sidewalk_m
        for lateral in (half + outer, half - outer):
            xy, _ = street.route_points(s, lateral)
            ax.plot(*xy.T, color="k", lw=0.8)
        xy, _ = street.route_points(s)
        ax.plot(*xy.T, color="tab:blue", lw=1.0)
        ax.plot(*plan.route.xy.T, color="tab:red", ls="--", lw=0.8)
        for b in world.buildings:
            ring = np.asarray(b.xy)
            ax.fill(*np.vstack([ring, ring[:1]]).T, color="tan", alpha=0.8, lw=0)
        cars = np.array([[c.x, c.y] for c in world.cars]).reshape(-1, 2)
        ax.plot(*cars.T, "s", ms=2.5, color="tab:green")
        lo, hi = xy.min(axis=0) - 60.0, xy.max(axis=0) + 60.0
        ax.set_xlim(lo[0], hi[0])
        ax.set_ylim(lo[1], hi[1])
        ax.set_aspect("equal")
        ax.set_title(street.title, fontsize=8)
        ax.set_xlabel(f"m east ({street.crs})", fontsize=7)
    fig.tight_layout()
    save_figure(fig, args.out, dpi=110)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
