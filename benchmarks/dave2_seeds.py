"""Does DAVE-2 drive for good reasons? Train it with several seeds, drive each many times.

Issue 21 item 3: DAVE-2 trained with 3 training seeds must complete the Real world (the
ground-truth camera, ``truth``) in at least 9 of 10 runs each. This script takes a workspace in
which ``cam2sim demo`` (or ``cam2sim run`` with a ground-truth world) has run, trains DAVE-2 on
its dataset with each training seed (as the demo does: 30 epochs, batch 32, the last epoch kept,
on the CPU, recovery views from the workspace's camera), exports it to ONNX beside the
workspace, and drives it ``--runs`` times per camera with the demo's steering noise and run
variation (run seeds 10, 11, ...). It prints one line per run and a summary per training seed
and camera, and writes them as JSON.

Usage:
    python benchmarks/dave2_seeds.py WS [--train-seeds 0,1,2] [--runs 10] [--cameras truth]
        [--preset demo|same-street] [--set recovery_m=1.0 --set recovery_share=0.75]
        [--signal steering_from_poses] [--recorded-speed] [--tag NAME] [--json result.json]

``--preset demo`` trains as the demo and the street benchmark do (:func:`demo_train_options`);
``--preset same-street`` trains as ``cam2sim run`` does on a real drive
(:meth:`TrainOptions.same_street`, without its validated run: the network kept is the same);
``--set`` changes one training option (repeatable), e.g. a real drive's recovery views.
``--recorded-speed`` drives at the recorded speed along the route (``cam2sim run``'s default on
a drive that changes speed). The runs are written into ``WS/runs/`` like any drive; the models
go to ``WS/ads/seeds/`` (``dave2_<tag>_seed<N>.onnx``).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import tempfile
import time
from pathlib import Path
from typing import Any

from cam2sim.ads.export import export_onnx
from cam2sim.ads.train_options import TrainOptions
from cam2sim.core.workspace import Workspace
from cam2sim.scenario.model import Scenario
from cam2sim.sim.builtin import BuiltinOptions
from cam2sim.stages.ads import train_model
from cam2sim.stages.evaluate import evaluate_workspace_drives
from cam2sim.stages.experiment import DEMO_STEERING_NOISE, demo_train_options
from cam2sim.stages.runs import DriveOptions, default_judge, drive
from cam2sim.stages.variation import DEMO_RUN_VARIATION
from splat_gpu import _parse_value


def _options(preset: str, signal: str | None, changes: dict[str, Any], seed: int) -> TrainOptions:
    """The training options: the demo's and the bench's, or a real drive's (``cam2sim run``).

    Both without the validated run: the network kept is the same.
    """
    if preset == "same-street":
        opts = TrainOptions.same_street(validate=False, device="cpu", seed=seed)
    else:
        opts = dataclasses.replace(demo_train_options(validate=False), seed=seed)
    if signal is not None:
        changes = {"signal": signal, **changes}
    return dataclasses.replace(opts, **changes)


def _train(ws: Workspace, opts: TrainOptions, out: Path) -> dict[str, Any]:
    seed = opts.seed
    started = time.perf_counter()
    trained = train_model(ws, opts)
    export_onnx(trained.model, trained.info.config, out)
    rep = trained.report
    return {
        "seed": seed,
        "model": str(out),
        "seconds": round(time.perf_counter() - started, 1),
        "val_correlation": rep.val_correlation,
        "recovery": rep.recovery is not None,
    }


def _drive(
    ws: Workspace, model: Path, cameras: list[str], run_seeds: list[int], *, recorded: bool
) -> list[dict[str, Any]]:
    scenario = Scenario.load(ws.scenario_path)
    sim = BuiltinOptions(
        calibration=scenario.steering_calibration, steering_noise_std=DEMO_STEERING_NOISE
    )
    # Judged as the pipeline judges: in the ground-truth world where the workspace has one (the
    # demo's and the bench's worlds), else on the map (whose junctions may round the route).
    judge = default_judge(ws)
    camera_of: dict[str, str] = {}
    for camera in cameras:
        for seed in run_seeds:
            opts = DriveOptions(
                policy=str(model), camera=camera, runs=1, seed=seed, sim=sim,  # type: ignore[arg-type]
                variation=DEMO_RUN_VARIATION, recorded_speed=recorded, judge=judge,
            )  # fmt: skip
            camera_of |= {r.run_id: camera for r in drive(ws, options=opts)}
    with tempfile.TemporaryDirectory() as tmp:
        evaluate_workspace_drives(ws, list(camera_of), Path(tmp))
        metrics = json.loads((Path(tmp) / "metrics.json").read_text(encoding="utf-8"))
    out = []
    for run in metrics["runs"]:
        folder = run["name"].split("/")[-1]
        if folder in camera_of:
            out.append(
                {
                    "run": folder,
                    "camera": camera_of[folder],
                    "completion": run["completion"],
                    "success": run["success"],
                    "min_frechet_m": run["min_frechet_m"],
                    "failure": run.get("failure"),
                }
            )
    return out


def main() -> int:
    """Train, drive, print, write."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("workspace", type=Path)
    parser.add_argument("--train-seeds", default="0,1,2")
    parser.add_argument("--runs", type=int, default=10)
    parser.add_argument("--cameras", default="truth")
    parser.add_argument("--preset", choices=("demo", "same-street"), default="demo")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")
    parser.add_argument("--signal", default=None)
    parser.add_argument("--recorded-speed", action="store_true")
    parser.add_argument("--tag", default=None, help="name of the models (default: the preset)")
    parser.add_argument("--json", type=Path)
    args = parser.parse_args()
    changes: dict[str, Any] = {}
    for item in args.set:
        key, sep, text = item.partition("=")
        if not sep:
            parser.error(f"--set {item}: give KEY=VALUE, e.g. recovery_m=1.0")
        changes[key.strip()] = _parse_value(text)
    tag = args.tag or args.preset
    ws = Workspace.open(args.workspace)
    cameras = args.cameras.split(",")
    run_seeds = list(range(10, 10 + args.runs))
    (ws.ads_dir / "seeds").mkdir(parents=True, exist_ok=True)
    result: dict[str, Any] = {
        "workspace": str(ws.root), "preset": args.preset, "changes": changes, "models": [],
        "runs": {},
    }  # fmt: skip
    for seed in (int(s) for s in args.train_seeds.split(",")):
        model = ws.ads_dir / "seeds" / f"dave2_{tag}_seed{seed}.onnx"
        info = _train(ws, _options(args.preset, args.signal, changes, seed), model)
        result["models"].append(info)
        print(f"training seed {seed}: {info['seconds']} s, held-out correlation "
              f"{info['val_correlation']}")  # fmt: skip
        runs = _drive(ws, model, cameras, run_seeds, recorded=args.recorded_speed)
        result["runs"][str(seed)] = runs
        for r in runs:
            print(
                f"  {r['run']}: completion {r['completion']:.3f}, Min-Fréchet "
                f"{r['min_frechet_m']}, failure {r['failure']}"
            )
        for camera in cameras:
            mine = [r for r in runs if r["camera"] == camera]
            done = sum(bool(r["success"]) for r in mine)
            print(f"training seed {seed}, {camera}: {done}/{len(mine)} complete")
    if args.json:
        args.json.write_text(json.dumps(result, indent=1) + "\n", encoding="utf-8")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
