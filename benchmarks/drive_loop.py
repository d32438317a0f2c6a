"""Speed of the closed loop (issue 8): builtin simulator + raster camera + pure-pursuit.

A synthetic curved street (radius 80 m, 400 m, 6 parked cars; ``cam2sim.scenario.synthetic``)
is written into a temporary workspace and driven with ``cam2sim.stages.runs.drive`` exactly as
``cam2sim drive`` runs it, the raster camera rendering at a policy-input size (200x66 by default)
whenever the policy is asked. Two settings: the policy every step (a camera frame per step) and
every 3rd step (the published tool's rate). Reported: steps per second of the whole loop, the
render and policy milliseconds per decision (from each run's ``run.json``).

Target: >= 200 steps/s on the 2-core machine.

Run from the repository root::

    python benchmarks/drive_loop.py [--size 200x66] [--length 400]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import tempfile
from pathlib import Path

from cam2sim.core.config import Config, RecordingConfig
from cam2sim.core.workspace import Workspace
from cam2sim.scenario.synthetic import StreetSpec, synthetic_street
from cam2sim.stages.runs import DriveOptions, drive

TARGET = 200.0


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--size", default="200x66")
    parser.add_argument("--length", type=float, default=400.0)
    args = parser.parse_args()
    w, h = (int(v) for v in args.size.split("x"))
    spec = StreetSpec(
        length_m=args.length,
        radius_m=80.0,
        parked=tuple((40.0 + 50.0 * k, -4.75 if k % 2 else 4.75, 0.0) for k in range(6)),
    )
    print(
        f"machine: {platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}"
    )
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp) / "ws"
        ws = Workspace.create(root, Config(recording=RecordingConfig(bags=[str(root / "none")])))
        scenario, xodr = synthetic_street(spec)
        ws.map_dir.mkdir(parents=True)
        (ws.map_dir / "map.xodr").write_text(xodr, encoding="utf-8")
        ws.scenario_dir.mkdir(parents=True)
        scenario.save(ws.scenario_dir / "scenario.json")
        for every in (1, 3):
            opts = DriveOptions(camera="raster", image_size=(w, h), policy_every=every)
            (run,) = drive(ws, options=opts)
            meta = json.loads((run.folder / "run.json").read_text())
            rate = run.steps / run.seconds
            verdict = "met" if rate >= TARGET else "NOT met"
            ends = ", ".join(e["kind"] for e in run.events)
            print(
                f"policy every {every} step(s), raster {w}x{h}: {run.steps} steps in "
                f"{run.seconds:.2f} s = {rate:.0f} steps/s (target >= {TARGET:.0f}: {verdict}); "
                f"render {meta['render_ms']:.2f} ms, policy {meta['policy_ms']:.3f} ms per "
                f"decision; ended by {ends}"
            )


if __name__ == "__main__":
    main()
