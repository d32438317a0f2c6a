"""Time ``cam2sim demo`` end to end (recording + every pipeline step) and print per-step times.

Usage: python benchmarks/demo.py [OUT]   (default: a fresh temporary folder)
"""

from __future__ import annotations

import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path


def main() -> None:
    """Build the demo recording, run the pipeline, print the times."""
    from cam2sim.cli.run_pipeline_cmd import _workspace  # noqa: PLC0415
    from cam2sim.demo.world import build_demo_recording  # noqa: PLC0415
    from cam2sim.stages.pipeline import PipelineOptions, run_pipeline  # noqa: PLC0415

    out = Path(sys.argv[1]) if len(sys.argv) > 1 else Path(tempfile.mkdtemp(prefix="demo-"))
    started = time.perf_counter()
    rec = build_demo_recording(out)
    built = time.perf_counter() - started
    print(f"recording: {built:7.1f} s  ({rec.camera_frames} frames)")
    ws = _workspace(out / "ws", [], rec.config)
    result = run_pipeline(ws, options=replace(PipelineOptions(osm=rec.osm), runs=1))
    for o in result.outcomes:
        print(f"{o.name:9s}: {o.seconds:7.1f} s  {o.state:14s} {o.message[:70]}")
    print(f"total    : {time.perf_counter() - started:7.1f} s; failed: {result.failed}")


if __name__ == "__main__":
    main()
