"""Benchmark: images-only SfM of the 300 real Udacity frames (640x480 JPEG, no intrinsics/poses).

Target (issue 4): under 5 minutes on the 2-core machine with all 300 frames registered. Reports
wall time per phase, registered frames, mean reprojection error, points and the final camera, for
each mapper asked for.

    python benchmarks/sfm.py [--mapper incremental global] [--frames 300] [--window 10]
    python benchmarks/sfm.py --data ../shared/data/images/udacity-ch2-curves --mapper incremental \
        --camera-model RADIAL
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import logging
import os
import platform
import time
from pathlib import Path

from cam2sim.splat.sfm import FeatureOptions, SfmOptions, sfm_images_only

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "images" / "udacity-ch2"
TARGET_S = 300.0


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--mapper", nargs="+", default=["incremental", "global"])
    parser.add_argument("--data", type=Path, default=DATA, help="folder of JPEG frames")
    parser.add_argument("--camera-model", default=None, help="COLMAP model (SIMPLE_RADIAL...)")
    parser.add_argument("--refine-focal", action="store_true", help="refine the focal too")
    parser.add_argument("--frames", type=int, default=300)
    parser.add_argument("--window", type=int, default=None, help="sequential overlap")
    parser.add_argument("--max-image-size", type=int, default=None)
    parser.add_argument("--features", type=int, default=None, help="SIFT features per image")
    parser.add_argument("--first-octave", type=int, default=None)
    parser.add_argument("--threads", type=int, default=None)
    parser.add_argument("--json", type=Path, default=None, help="append results as JSON lines")
    parser.add_argument("-v", "--verbose", action="store_true")
    args = parser.parse_args()
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING)
    files = sorted(args.data.glob("*.jpg"))[: args.frames]
    if not files:
        msg = f"no frames at {args.data}"
        raise SystemExit(msg)
    base = SfmOptions().features
    changes = {
        "window": args.window,
        "max_image_size": args.max_image_size,
        "max_num_features": args.features,
        "first_octave": args.first_octave,
        "num_threads": args.threads,
    }
    features = dataclasses.replace(base, **{k: v for k, v in changes.items() if v is not None})
    cpu = platform.processor() or platform.machine()
    load = os.getloadavg()[0]
    print(f"# {len(files)} frames, {os.cpu_count()} cores, {cpu}, load {load:.1f}; {features}")
    extra: dict[str, object] = {"refine_focal": args.refine_focal}
    if args.camera_model:
        extra["camera_model"] = args.camera_model
    for mapper in args.mapper:
        result = run(files, mapper, features, extra)
        print(json.dumps(result))
        if args.json is not None:
            with args.json.open("a", encoding="utf-8") as handle:
                handle.write(json.dumps(result) + "\n")


def run(
    files: list[Path], mapper: str, features: FeatureOptions, extra: dict[str, object]
) -> dict[str, object]:
    options = SfmOptions(mapper=mapper, features=features, **extra)  # type: ignore[arg-type]
    load_before = os.getloadavg()[0]
    start = time.perf_counter()
    result = sfm_images_only(files, options=options)
    seconds = time.perf_counter() - start
    return {
        "mapper": mapper,
        "data": files[0].parent.name,
        "options": {k: str(v) for k, v in extra.items()},
        "frames": len(files),
        "seconds": round(seconds, 1),
        "phases_s": {k: round(v, 1) for k, v in result.seconds.items()},
        "registered": result.registered,
        "mean_reprojection_error_px": round(result.mean_reprojection_error_px, 3),
        "points": len(result.points),
        "camera": [result.camera.model, [round(p, 4) for p in result.camera.params]],
        "meets_target": seconds < TARGET_S and result.registered == len(files),
        "load_before": round(load_before, 2),
        "load_after": round(os.getloadavg()[0], 2),
    }


if __name__ == "__main__":
    main()
