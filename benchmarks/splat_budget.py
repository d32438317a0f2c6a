"""How closely splat training keeps to a time budget (issue 4): ``TrainOptions.time_budget_s``.

Trains every chunk of a prepared scene (``--prep WS/splat/prep``, or ``--synthetic``: the test
suite's street, three chunks) under ``--budget`` seconds, once per ``--concurrency`` level
(chunks trained at a time: 1 = one interleaved loop, more = worker processes), with a step cap
and ``min_steps`` so high that only the budget can end training. Reports per chunk its share of
the budget, the seconds it trained, its steps and why it stopped, and for the run the slowest
round's training time against the budget (start-up and gsplat's build are not budgeted).
Runs on the CPU (``--device cpu``) or a CUDA GPU.

Run from the repository root::

    PYTHONPATH=src:benchmarks python benchmarks/splat_budget.py --synthetic --device cpu \
        --resize 200x150 --budget 60 --concurrency 1,2 --out budget.json
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from cam2sim.splat.scene import SceneRecord
from cam2sim.splat.train import time_share, train_scene
from splat_gpu import _environment, _prepared, train_options  # beside this file


def run_level(prep: Path, args: argparse.Namespace, in_flight: int, out: Path) -> dict[str, Any]:
    """Train all chunks with the budget, ``in_flight`` at a time; per-chunk and total figures."""
    options = dataclasses.replace(
        train_options(args), time_budget_s=args.budget, concurrent_chunks=in_flight
    )
    n_chunks = len(SceneRecord.load(prep / "scene.json").chunks)
    share = time_share(args.budget, n_chunks, in_flight)
    assert share is not None
    t0 = time.perf_counter()
    result = train_scene(prep, options=options, models_dir=out)
    wall = time.perf_counter() - t0
    chunks = [
        {
            "chunk": c.chunk_id,
            "share_s": share,
            "train_seconds": c.train_seconds,
            "over_share_s": c.train_seconds - share,
            "steps": c.steps,
            "stopped": c.stopped,
            "validations": len(c.val_history),
            "last_psnr_db": c.val_history[-1][1] if c.val_history else None,
        }
        for c in result.chunks
    ]
    rounds = -(-n_chunks // min(in_flight, n_chunks))
    return {
        "concurrent_chunks": in_flight,
        "budget_s": args.budget,
        "rounds": rounds,
        "chunks": chunks,
        "wall_s": wall,
        "most_over_share_s": max(c["over_share_s"] for c in chunks),
    }


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--prep", help="WS/splat/prep of a prepared scene")
    parser.add_argument("--synthetic", action="store_true", help="the test suite's street")
    parser.add_argument("--synthetic-frames", type=int, default=30)
    parser.add_argument("--resize", help="train on a copy resized to WxH")
    parser.add_argument("--resized-dir", help="where the resized copy goes (reused)")
    parser.add_argument("--budget", type=float, default=60.0, help="seconds for all chunks")
    parser.add_argument("--concurrency", default="1", help="levels, e.g. 1,2")
    parser.add_argument("--set", action="append", help="TrainOptions KEY=VALUE")
    parser.add_argument("--device", default="cpu", help="cpu (default) or cuda")
    parser.add_argument("--out", default="splat_budget.json")
    args = parser.parse_args()
    # What train_options reads: only the budget may end training.
    args.max_steps = args.min_steps = 10_000_000
    args.downscale = 1
    work = Path(tempfile.mkdtemp(prefix="splat_budget_"))
    prep = _prepared(args, work)
    if prep is None:
        print("error: give --prep DIR or --synthetic", file=sys.stderr)
        return 2
    levels = [
        run_level(prep, args, int(n), work / f"models-{n}") for n in args.concurrency.split(",")
    ]
    for level in levels:
        print(
            f"concurrent_chunks={level['concurrent_chunks']}: budget {level['budget_s']:.0f} s, "
            f"{level['rounds']} round(s), wall {level['wall_s']:.1f} s (start-up included)"
        )
        for c in level["chunks"]:
            print(
                f"  chunk {c['chunk']}: share {c['share_s']:.1f} s, trained "
                f"{c['train_seconds']:.1f} s ({c['over_share_s']:+.2f} s), {c['steps']} steps, "
                f"stopped: {c['stopped']}, last held-in PSNR {c['last_psnr_db']:.2f} dB"
            )
    report = {"environment": _environment(), "args": vars(args), "levels": levels}
    Path(args.out).write_text(json.dumps(report, indent=2, default=str))
    return 0


if __name__ == "__main__":
    sys.exit(main())
