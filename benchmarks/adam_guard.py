"""What the trainer's NaN guard costs a step: ``adam_step`` with and without ``finite``.

The trainer steps a chunk's optimizers with :func:`cam2sim.splat.optim.adam_step` and
``finite=True``: one fused reduction over every gradient a step, and the fused Adam's
``found_inf`` (``docs/benchmarks.md``, the NaN guard of 2026-11-27). This times that call alone
on a street model of N Gaussians with SH degree 3 (the parameters and optimizers the trainer
builds: means, scales, quats, opacities, sh0, shN; fused Adam on CUDA), with and without the
guard, and with a NaN in one gradient (the skipped step), as the median over repeats.

    python3 benchmarks/adam_guard.py --gaussians 1000000 --device cuda --out adam_guard.json

On the CPU (``--device cpu``, unfused Adam as the trainer uses there) the guard zeroes the
non-finite values instead; use a smaller N.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "src"))

from cam2sim.core.files import write_text_atomic
from cam2sim.splat.optim import adam_step

SHAPES = {
    "means": (3,),
    "scales": (3,),
    "quats": (4,),
    "opacities": (),
    "sh0": (1, 3),
    "shN": (15, 3),
}


def _interleaved(calls: dict[str, Any], sync: Any, repeats: int) -> dict[str, float]:
    """Median milliseconds of each call, the calls taking turns so that drift hits all alike."""
    times: dict[str, list[float]] = {name: [] for name in calls}
    for _ in range(repeats):
        for name, call in calls.items():
            sync()
            t = time.perf_counter()
            call()
            sync()
            times[name].append(time.perf_counter() - t)
    return {name: 1000.0 * statistics.median(ts) for name, ts in times.items()}


def main() -> int:
    import torch  # noqa: PLC0415

    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--gaussians", type=int, default=1_000_000)
    parser.add_argument("--device", default="cuda")
    parser.add_argument("--repeats", type=int, default=200)
    parser.add_argument("--out", help="JSON path for the figures")
    args = parser.parse_args()
    device = torch.device(args.device)
    cuda = device.type == "cuda"
    sync = torch.cuda.synchronize if cuda else (lambda: None)
    n = args.gaussians
    params = {k: torch.nn.Parameter(torch.randn((n, *s), device=device)) for k, s in SHAPES.items()}
    optimizers = [torch.optim.Adam([p], lr=1e-3, eps=1e-15, fused=cuda) for p in params.values()]
    grads = {k: torch.randn_like(p) for k, p in params.items()}
    counter = torch.zeros((), dtype=torch.int64, device=device)

    def step(*, finite: bool, nan: bool = False) -> None:
        for k, p in params.items():
            p.grad = grads[k].clone()
        if nan:
            params["scales"].grad[n // 2, 1] = float("nan")
        adam_step(optimizers, finite=finite, non_finite_steps=counter if finite else None)

    for finite in (False, True):  # warm-up: kernels, optimizer state
        for _ in range(5):
            step(finite=finite)
    ms = _interleaved(
        {
            "clone": lambda: [grads[k].clone() for k in params],  # in every call: subtracted
            "plain": lambda: step(finite=False),
            "guarded": lambda: step(finite=True),
            "guarded_nan": lambda: step(finite=True, nan=True),
        },
        sync,
        args.repeats,
    )
    record: dict[str, Any] = {
        "device": torch.cuda.get_device_name(device) if cuda else "cpu",
        "gaussians": n,
        "repeats": args.repeats,
        **{f"{k}_ms": v - ms["clone"] for k, v in ms.items() if k != "clone"},
    }
    record["guard_ms"] = record["guarded_ms"] - record["plain_ms"]
    record["skipped_steps_counted"] = int(counter)
    print(json.dumps(record, indent=1))
    if args.out:
        write_text_atomic(Path(args.out), json.dumps(record, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
