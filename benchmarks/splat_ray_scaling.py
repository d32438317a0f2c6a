"""Splat training across GPUs through Ray (issue 41): the same chunks on 1, 2, 4... GPUs.

``cam2sim splat WS --ray local`` trains every chunk as its own Ray task with one GPU
(:func:`cam2sim.splat.distributed.train_scene_on_ray`). This script times exactly that on a
prepared scene (``WS/splat/prep``) whose chunk ``--chunk`` is copied ``--replicate`` times (the
same frames, each copy its own chunk id and seed: independent jobs of equal size, so the ideal
speed-up is the GPU count), once per ``--gpus`` level. Each level runs in its own process with
``CUDA_VISIBLE_DEVICES`` set to its first GPUs, so its local Ray instance sees only those.
Every chunk trains exactly ``--steps`` steps (no plateau stop, no time budget), so the levels
do the same work; each chunk's best validation PSNR is compared across the levels::

    python benchmarks/splat_ray_scaling.py WS/splat/prep --gpus 1,2,4 --replicate 8 \
        --steps 3000 --out ray_scaling.json

Writes the JSON after each level: per level the wall time, the speed-up over the first level,
the efficiency (speed-up / GPUs) and each chunk's steps, seconds and PSNR; at the end the
largest PSNR difference of a chunk between levels. ``--device cpu`` runs the same code path on
CPU workers (a smoke test: one chunk per CPU).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from cam2sim.splat.distributed import train_scene_on_ray
from cam2sim.splat.scene import SceneRecord
from cam2sim.splat.train import TrainOptions

sys.path.insert(0, str(Path(__file__).parent))
from splat_concurrency import replicate_chunk  # beside this file


def _level(args: argparse.Namespace, gpus: int) -> dict[str, Any]:
    """Train the replicated scene on a local Ray instance limited to ``gpus`` GPUs."""
    device = {"device": args.device} if args.device else {}
    options = TrainOptions(
        max_steps=args.steps, min_steps=args.steps, val_every=max(1, args.steps // 2), **device
    )  # fmt: skip
    models = Path(args.work) / f"models-{gpus}"
    started = time.perf_counter()
    trained = train_scene_on_ray(Path(args.scene), address="local", options=options,
                                 models_dir=models)  # fmt: skip
    wall = time.perf_counter() - started
    return {
        "gpus": gpus,
        "chunks": len(trained.chunks),
        "wall_s": wall,
        "per_chunk": [
            {
                "chunk_id": c.chunk_id,
                "steps": c.steps,
                "seconds": c.train_seconds,
                "best_val_psnr_db": c.best_val_psnr_db,
            }
            for c in trained.chunks
        ],
    }


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("prep", type=Path, help="a prepared scene, WS/splat/prep")
    parser.add_argument("--gpus", default="1,2", help="GPU counts, comma-separated")
    parser.add_argument("--replicate", type=int, default=8, help="copies of the chunk")
    parser.add_argument("--chunk", type=int, default=None, help="chunk id (default: the first)")
    parser.add_argument("--steps", type=int, default=3000)
    parser.add_argument("--device", default=None, help="cpu for a CPU smoke run")
    parser.add_argument("--out", default="ray_scaling.json")
    parser.add_argument("--level", type=int, default=None, help=argparse.SUPPRESS)
    parser.add_argument("--scene", default=None, help=argparse.SUPPRESS)
    parser.add_argument("--work", default=None, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.level is not None:  # a child: one level, its row on the last line
        print(json.dumps(_level(args, args.level)))
        return 0
    work = Path(tempfile.mkdtemp(prefix="ray-scaling-"))
    chunk = args.chunk
    if chunk is None:
        chunk = SceneRecord.load(args.prep / "scene.json").chunks[0].id
    scene = replicate_chunk(args.prep.resolve(), work / "scene", chunk, args.replicate)
    results: dict[str, Any] = {"args": {k: str(v) for k, v in vars(args).items()}, "levels": []}
    for gpus in (int(v) for v in args.gpus.split(",")):
        env = dict(os.environ)
        if args.device != "cpu":
            env["CUDA_VISIBLE_DEVICES"] = ",".join(str(i) for i in range(gpus))
        cmd = [sys.executable, __file__, str(args.prep), "--level", str(gpus), "--scene",
               str(scene), "--work", str(work), "--steps", str(args.steps)]  # fmt: skip
        if args.device:
            cmd += ["--device", args.device]
        done = subprocess.run(cmd, env=env, capture_output=True, text=True, check=False)
        if done.returncode != 0:
            print(done.stdout[-3000:], done.stderr[-3000:], file=sys.stderr)
            return done.returncode
        row = json.loads(done.stdout.strip().splitlines()[-1])
        first = results["levels"][0] if results["levels"] else row
        row["speedup"] = first["wall_s"] / row["wall_s"] * 1.0
        row["efficiency"] = row["speedup"] * first["gpus"] / gpus
        results["levels"].append(row)
        print(f"{gpus} GPU(s): {row['wall_s']:.1f} s, speed-up {row['speedup']:.2f}x "
              f"({row['efficiency']:.0%} of ideal)", flush=True)  # fmt: skip
        Path(args.out).write_text(json.dumps(results, indent=2) + "\n")
    psnr = [
        {c["chunk_id"]: c["best_val_psnr_db"] for c in r["per_chunk"]} for r in results["levels"]
    ]
    spread = max((max(p[c] for p in psnr) - min(p[c] for p in psnr) for c in psnr[0]), default=0.0)
    results["max_psnr_difference_db"] = spread
    Path(args.out).write_text(json.dumps(results, indent=2) + "\n")
    print(f"largest PSNR difference of a chunk between levels: {spread:.3f} dB -> {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
