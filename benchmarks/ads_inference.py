"""Single-image DAVE-2 inference speed with ONNX, in process (issue 9).

Exports a freshly initialised DAVE-2 (weights do not change the speed) to ONNX, then times
``--calls`` single-image predictions through :class:`cam2sim.ads.policy.ModelPolicy` on a
``--width`` x ``--height`` RGB camera frame: the full path (resize to 800x503, crop, resize to
200x66, onnxruntime) and the model alone (onnxruntime on a ready input). The CPU time other
processes used meanwhile is printed too (``others_cores``), since this machine is shared.

Target (issue 9): single-image inference <= 2 ms in process with ONNX on the 2-core machine.

Run from the repository root::

    python benchmarks/ads_inference.py [--calls 500] [--width 800] [--height 503] [--threads 0]
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
import time
from pathlib import Path

import numpy as np
import onnxruntime as ort
import torch

from cam2sim.ads.dave2 import Dave2Config, build_dave2, preprocess
from cam2sim.ads.export import export_onnx
from cam2sim.ads.policy import ModelPolicy, Observation
from cam2sim.sim.interface import VehicleState


def _cpu_total() -> float:
    with Path("/proc/stat").open() as f:
        parts = f.readline().split()[1:]
    busy = sum(int(p) for i, p in enumerate(parts) if i not in (3, 4))
    return busy / os.sysconf("SC_CLK_TCK")


def _stats(seconds: list[float]) -> dict[str, float]:
    ms = np.asarray(seconds) * 1e3
    return {
        "mean_ms": float(ms.mean()),
        "median_ms": float(np.median(ms)),
        "p95_ms": float(np.percentile(ms, 95)),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--calls", type=int, default=500)
    parser.add_argument("--width", type=int, default=800)
    parser.add_argument("--height", type=int, default=503)
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args()

    torch.manual_seed(0)
    rng = np.random.default_rng(0)
    frame = rng.integers(0, 256, (args.height, args.width, 3), dtype=np.uint8)
    state = VehicleState(
        t=0.0, x=0.0, y=0.0, z=0.0, heading=0.0, speed=5.0, wheel_angle=0.0, steering=0.0,
        rear_axle=(0.0, 0.0),
    )  # fmt: skip
    obs = Observation(0.0, frame, state)
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "dave2.onnx"
        export_onnx(build_dave2().eval(), Dave2Config(), path)
        policy = ModelPolicy(path)
        session = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
        x = preprocess(frame)
        for _ in range(20):  # warm-up
            policy.predict(obs)
            session.run(["steering"], {"image": x})
        cpu0, wall0 = _cpu_total(), time.perf_counter()
        own0 = time.process_time()
        full, model, prep = [], [], []
        for _ in range(args.calls):
            t0 = time.perf_counter()
            policy.predict(obs)
            t1 = time.perf_counter()
            session.run(["steering"], {"image": x})
            t2 = time.perf_counter()
            preprocess(frame)
            t3 = time.perf_counter()
            full.append(t1 - t0)
            model.append(t2 - t1)
            prep.append(t3 - t2)
        wall = time.perf_counter() - wall0
        others = (_cpu_total() - cpu0 - (time.process_time() - own0)) / wall
    result = {
        "frame": f"{args.width}x{args.height}",
        "calls": args.calls,
        "with_preprocessing": _stats(full),
        "model_only": _stats(model),
        "preprocessing_only": _stats(prep),
        "onnxruntime": ort.__version__,
        "cpu_count": os.cpu_count(),
        "others_cores": round(max(others, 0.0), 2),
    }
    print(json.dumps(result, indent=2))
    if args.json is not None:
        args.json.write_text(json.dumps(result, indent=2) + "\n", encoding="utf-8")


if __name__ == "__main__":
    main()
