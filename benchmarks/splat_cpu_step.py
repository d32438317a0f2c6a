"""Time a CPU splat training step on a prepared workspace: compiled vs torch compositing.

Builds one chunk trainer of ``WS/splat/prep`` with the demo's CPU preset (or ``--set``
overrides), then reports
- the compositing alone (forward and backward, best of ``--repeat``) with the compiled
  (numba, :mod:`cam2sim.splat.raster_cpu`) and the torch version, on one real view;
- whole training steps (mean of ``--steps`` after two warm-up steps) with each, split into
  phases (:class:`cam2sim.splat.profiling.PhaseTimer`).

Usage:
    python benchmarks/splat_cpu_step.py WS [--chunk 0] [--steps 20] [--set key=value ...]
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path
from typing import Any

import torch

from cam2sim.splat import raster_cpu, raster_torch
from cam2sim.splat.chunk_trainer import ChunkTrainer
from cam2sim.splat.profiling import PhaseTimer
from cam2sim.splat.scene import SceneRecord, load_points
from cam2sim.stages.splat import SplatStageOptions
from splat_gpu import _parse_value, options_from


def _trainer(ws: Path, chunk: int, settings: dict[str, Any]) -> ChunkTrainer:
    prep = ws / "splat" / "prep"
    scene = SceneRecord.load(prep / "scene.json")
    xyz, rgb, _ = load_points(prep / "points.npz")
    preset = SplatStageOptions.demo().train
    assert preset is not None
    base = {
        k: getattr(preset, k)
        for k in ("downscale", "max_init_points", "sky_points", "init_opacity", "n_val_views")
    }
    settings = {"densify.enabled": preset.densify.enabled, **settings}
    opts = options_from(
        settings, **base, max_steps=10_000, min_steps=10_000, val_every=10_000, device="cpu"
    )
    known = {c.id: c for c in scene.chunks}
    return ChunkTrainer(known[chunk], scene, prep, (xyz, rgb), opts, "cpu", "torch", None)


def _composite_ms(trainer: ChunkTrainer, repeat: int) -> dict[str, tuple[float, float]]:
    captured: dict[str, Any] = {}
    real = raster_cpu.composite

    def grab(*args: Any, **kwargs: Any) -> Any:
        captured["args"] = [a.detach() if torch.is_tensor(a) else a for a in args]
        captured["kwargs"] = kwargs
        return real(*args, **kwargs)

    raster_cpu.composite = grab  # type: ignore[assignment]
    try:
        trainer._render(0, 0)  # noqa: SLF001 -- a benchmark of the trainer's own render
    finally:
        raster_cpu.composite = real  # type: ignore[assignment]
    args, kwargs = captured["args"], captured["kwargs"]
    out = {}
    for name, fn, extra in (
        ("compiled", real, {}),
        ("torch", raster_torch._composite, {"max_elements": 1 << 22}),  # noqa: SLF001
    ):
        best_f = best_b = float("inf")
        for _ in range(repeat):
            leaves = [a.clone().requires_grad_() if a.is_floating_point() else a for a in args]
            t0 = time.perf_counter()
            rgb, acc = fn(*leaves, **kwargs, **extra)
            t1 = time.perf_counter()
            (rgb.sum() + acc.sum()).backward()
            t2 = time.perf_counter()
            best_f, best_b = min(best_f, t1 - t0), min(best_b, t2 - t1)
        out[name] = (1e3 * best_f, 1e3 * best_b)
    return out


def _step_ms(trainer: ChunkTrainer, steps: int) -> dict[str, float]:
    for _ in range(2):
        trainer.step()
    trainer.timer = PhaseTimer(enabled=True, device="cpu")
    for _ in range(steps):
        trainer.step()
    return trainer.timer.summary()


def main() -> int:
    """Print the compositing and step timings."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("ws", type=Path)
    parser.add_argument("--chunk", type=int, default=0)
    parser.add_argument("--steps", type=int, default=20)
    parser.add_argument("--repeat", type=int, default=5)
    parser.add_argument("--set", action="append", default=[])
    args = parser.parse_args()
    settings = {k: _parse_value(v) for k, _, v in (s.partition("=") for s in args.set)}
    torch.set_num_threads(os.cpu_count() or 1)
    trainer = _trainer(args.ws, args.chunk, settings)
    size = f"{trainer.views.width}x{trainer.views.height}"
    print(f"chunk {args.chunk}: {len(trainer.street)} Gaussians, {size} views, ", end="")
    print(f"{torch.get_num_threads()} threads")
    for name, (fwd, bwd) in _composite_ms(trainer, args.repeat).items():
        print(f"compositing {name:8s}: forward {fwd:6.1f} ms, backward {bwd:6.1f} ms")
    for mode in ("compiled", "torch"):
        os.environ[raster_cpu.ENV_VAR] = "auto" if mode == "compiled" else "torch"
        phases = _step_ms(_trainer(args.ws, args.chunk, settings), args.steps)
        parts = ", ".join(
            f"{k.split('.')[0]} {v:.0f}" for k, v in phases.items() if k.endswith("host_ms")
        )
        print(f"step {mode:8s}: {phases['step_ms']:6.1f} ms ({parts})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
