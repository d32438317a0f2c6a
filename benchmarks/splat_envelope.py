"""What the splat evaluation against the ground truth costs (issue 19, item 4).

Runs the splat stage's evaluation on a workspace that has trained models and a ground-truth
world (``cam2sim demo`` makes one: ``DIR/ws``), as the stage runs it, and reports the seconds of
its two parts: the held-out evaluation with the relative offsets (what the stage did before),
and the truth envelope (held-out poses, +-0.5/1/2 m, +-5 degrees against the noise-free truth
camera). The result is written to a temporary file: the workspace's ``eval.json`` is left alone.

Run from the repository root (the demo target: the truth part under about 40 s on 2 cores)::

    PYTHONPATH=src python benchmarks/splat_envelope.py /tmp/demo/ws --offsets -1,1 --threads 2
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path
from typing import Any

import torch

from cam2sim.core.workspace import Workspace
from cam2sim.splat.envelope import TruthEnvelopeOptions
from cam2sim.splat.evaluate import EvalOptions, evaluate_splat
from cam2sim.splat.scene import SceneRecord
from cam2sim.stages.splat import SplatStageOptions, _truth_reference


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("workspace", type=Path)
    parser.add_argument("--offsets", default="-1,1", help="relative offsets, m (the demo's)")
    parser.add_argument("--max-frames", type=int, default=12, help="held-out frames, truth")
    parser.add_argument("--threads", type=int, default=2, help="torch threads")
    parser.add_argument("--no-lpips", action="store_true")
    parser.add_argument("--out", type=Path, help="write the figures as JSON here")
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    ws = Workspace.open(args.workspace)
    prep = ws.splat_dir / "prep"
    scene = SceneRecord.load(prep / "scene.json")
    stage = SplatStageOptions(truth=TruthEnvelopeOptions(max_frames=args.max_frames))
    marks: dict[str, float] = {}

    def progress(task: str, _done: int, _total: int | None) -> None:
        marks.setdefault(task, time.perf_counter())
        marks[f"{task} end"] = time.perf_counter()

    notes: list[str] = []
    offsets = tuple(float(o) for o in args.offsets.split(",") if o)
    with (
        tempfile.TemporaryDirectory() as tmp,
        _truth_reference(ws, stage, scene, notes) as truth,
    ):
        if truth is None:
            msg = f"{ws.root}: no ground-truth world to score against ({notes})"
            raise SystemExit(msg)
        started = time.perf_counter()
        ev = evaluate_splat(
            prep,
            ws.splat_dir / "models",
            offsets=offsets,
            options=EvalOptions(lpips=not args.no_lpips),
            out_path=Path(tmp) / "eval.json",
            truth=truth,
            progress=progress,
        )
        ended = time.perf_counter()
    held_s = marks["splat eval frames end"] - started
    truth_s = ended - marks["splat eval frames end"]
    assert ev.truth is not None
    result: dict[str, Any] = {
        "held_out_frames": ev.n_held_out,
        "truth_frames": len(ev.truth.frames),
        "truth_poses": len(ev.truth.scores),
        "held_out_and_offsets_s": round(held_s, 2),
        "truth_envelope_s": round(truth_s, 2),
        "threads": args.threads,
        "lpips": ev.truth.lpips_net,
        "rows": {
            row.label(): [row.psnr_db.mean, row.ssim.mean, row.lpips.mean, row.coverage.mean]
            for row in ev.truth.scores
        },
    }
    print(json.dumps(result, indent=1))
    if args.out is not None:
        args.out.write_text(json.dumps(result, indent=1) + "\n", encoding="utf-8")


if __name__ == "__main__":
    main()
