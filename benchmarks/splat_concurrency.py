"""Chunks trained side by side on one GPU (``TrainOptions.concurrent_chunks``), per level.

Run through ``benchmarks/splat_gpu.py --concurrency 1,2,3`` (see its doc): the scene's chunks,
or with ``--replicate-chunk K`` one chunk K times (ids 0..K-1, same frames, own seeds), trained
at each level: 1 = one interleaved loop in this process, N > 1 = N worker processes at a time.
Per level: wall time, combined ms/step (all steps over the wall time, and in the steady state
between 20 % and 80 % of the steps), each chunk's ms/step (and, with ``--set profile=true``,
its host and device milliseconds a step by phase). No evaluation.
"""

from __future__ import annotations

import dataclasses
import json
import sys
import tempfile
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

import torch

from cam2sim.splat.scene import SceneRecord
from cam2sim.splat.train import train_scene

if TYPE_CHECKING:
    import argparse


def replicate_chunk(src: Path, dst: Path, chunk_id: int, copies: int) -> Path:
    """A prepared scene at ``dst`` whose chunks are ``copies`` copies of ``src``'s ``chunk_id``.

    Images, masks, sky masks and points are linked, not copied.
    """
    scene = SceneRecord.load(src / "scene.json")
    chunk = next(c for c in scene.chunks if c.id == chunk_id)
    chunks = [chunk.model_copy(update={"id": i}) for i in range(copies)]
    members = set(chunk.frames)
    frames = [
        f.model_copy(update={"chunks": list(range(copies)) if f.index in members else []})
        for f in scene.frames
    ]
    dst.mkdir(parents=True, exist_ok=True)
    for name in ("images", "masks", "sky", "points.npz"):
        if (src / name).exists() and not (dst / name).exists():
            (dst / name).symlink_to((src / name).resolve())
    scene.model_copy(update={"frames": frames, "chunks": chunks}).save(dst / "scene.json")
    return dst


def _steady_ms_per_step(marks: list[tuple[float, int]], cap: int) -> float | None:
    """Combined ms/step between 20 % and 80 % of ``cap`` steps (start-up and tail left out)."""
    inside = [(t, d) for t, d in marks if 0.2 * cap <= d <= 0.8 * cap]
    if len(inside) < 2 or inside[-1][1] <= inside[0][1]:
        return None
    (t0, d0), (t1, d1) = inside[0], inside[-1]
    return 1e3 * (t1 - t0) / (d1 - d0)


def run_concurrency(
    args: argparse.Namespace, prep: Path | None, environment: dict[str, Any]
) -> int:
    """Train the same chunks at each ``--concurrency`` level; write the JSON after each."""
    from splat_gpu import train_options  # noqa: PLC0415 -- beside this file

    if args.device.startswith("cuda") and not torch.cuda.is_available():
        print("error: no CUDA device; use --device cpu", file=sys.stderr)
        return 2
    if prep is None:
        print("error: --concurrency needs --prep or --synthetic", file=sys.stderr)
        return 2
    if args.device.startswith("cuda"):  # build gsplat before any level is timed
        import gsplat.cuda._backend  # noqa: F401, PLC0415
    work = Path(tempfile.mkdtemp(prefix="splat-concurrency-"))
    chunk_ids = tuple(int(c) for c in args.chunks.split(",")) if args.chunks else None
    if args.replicate_chunk:
        first = chunk_ids[0] if chunk_ids else SceneRecord.load(prep / "scene.json").chunks[0].id
        prep = replicate_chunk(prep, work / "replicated", first, args.replicate_chunk)
        chunk_ids = None
    results: dict[str, Any] = {"environment": environment, "args": vars(args), "levels": []}
    print(json.dumps(results["environment"]))
    for level in (int(v) for v in args.concurrency.split(",")):
        options = dataclasses.replace(train_options(args), concurrent_chunks=level)
        marks: list[tuple[float, int]] = []

        def mark(_task: str, done: int, _total: int | None, marks: list[Any] = marks) -> None:
            marks.append((time.perf_counter(), done))

        t0 = time.perf_counter()
        trained = train_scene(
            prep, options=options, models_dir=work / f"models-{level}", chunk_ids=chunk_ids,
            progress=mark,
        )  # fmt: skip
        wall = time.perf_counter() - t0
        steps = sum(c.steps for c in trained.chunks)
        row = {
            "concurrent_chunks": level,
            "chunks": len(trained.chunks),
            "wall_seconds": wall,
            "total_steps": steps,
            "wall_ms_per_step_combined": 1e3 * wall / steps,
            "steady_ms_per_step_combined": _steady_ms_per_step(
                [(t - t0, d) for t, d in marks], len(trained.chunks) * options.max_steps
            ),
            "peak_gpu_memory_gib_one_process": (trained.peak_memory_bytes or 0) / 2**30,
            "per_chunk": [
                {
                    "chunk_id": c.chunk_id,
                    "steps": c.steps,
                    "seconds": c.train_seconds,
                    "ms_per_step": 1e3 * c.train_seconds / max(1, c.steps),
                    "n_gaussians": c.n_gaussians,
                    "best_val_psnr_db": c.best_val_psnr_db,
                    "phase_ms": c.phase_ms,  # with --set profile=true
                }
                for c in trained.chunks
            ],
        }
        results["levels"].append(row)
        print("concurrency:", json.dumps(row))
        Path(args.out).write_text(json.dumps(results, indent=2, default=str) + "\n")
        if args.device.startswith("cuda"):
            torch.cuda.empty_cache()
    print(f"results -> {args.out}")
    return 0
