"""Time a splat chunk's start-up (views loaded, Gaussians seeded) with the GPU demo's preset.

Takes a workspace with a dataset (a `cam2sim demo` or bench world's `ws/`), prepares its splat
scene with the GPU demo preset's preparation into ``WS/splat/prep`` when there is none yet, then
builds each chunk's trainer on the CPU (the seeding is NumPy and SciPy there either way) and
prints the seconds of its views and its seeding. Workers on a GPU machine do this while
others train or load; this is the work alone.

Run from the repository root::

    python benchmarks/splat_seeding.py WS
    python benchmarks/splat_seeding.py WS --prepare   # time the preparation too, every time

``--prepare`` prepares again even when a prepared scene is there and prints the SHA-256 of its
points (``points.npz``): a change to the preparation that must not change the points keeps it.
"""

from __future__ import annotations

import argparse
import dataclasses
import hashlib
import time
from pathlib import Path

from cam2sim.core.workspace import Workspace
from cam2sim.splat.chunk_trainer import ChunkTrainer
from cam2sim.splat.prepare import prepare_scene
from cam2sim.splat.scene import SceneRecord, load_points
from cam2sim.stages.splat import SplatStageOptions


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("workspace", type=Path)
    parser.add_argument("--prepare", action="store_true", help="prepare again and time it")
    args = parser.parse_args()
    ws = Workspace.open(args.workspace)
    preset = SplatStageOptions.demo(cuda=True)
    prep = ws.root / "splat" / "prep"
    if args.prepare or not (prep / "scene.json").exists():
        started = time.perf_counter()
        prepare_scene(ws, options=preset.prepare)
        digest = hashlib.sha256((prep / "points.npz").read_bytes()).hexdigest()[:16]
        print(f"prepared {prep} in {time.perf_counter() - started:.1f} s; points {digest}")
    scene = SceneRecord.load(prep / "scene.json")
    points = load_points(prep / "points.npz")[:2]
    assert preset.train is not None
    options = dataclasses.replace(preset.train, device="cpu", backend="torch")
    print(f"{len(points[0])} points, {len(scene.chunks)} chunks")
    for chunk in scene.chunks:
        started = time.perf_counter()
        trainer = ChunkTrainer(chunk, scene, prep, points, options, "cpu", "torch", 300.0)
        total = time.perf_counter() - started
        views, seeding = trainer.setup_s["views"], trainer.setup_s["seeding"]
        print(
            f"chunk {chunk.id}: {len(trainer.views.frames)} views, {trainer.n_initial} Gaussians:"
            f" views {views:.1f} s, seeding {seeding:.1f} s, trainer {total:.1f} s"
        )


if __name__ == "__main__":
    main()
