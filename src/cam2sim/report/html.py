"""The workspace report: one self-contained HTML page (``WS/report/report.html``).

Everything is embedded: figures and frames as base64 data URIs, the run video as a base64
``<video>`` source when it is small enough, plain HTML and inline CSS, no script and no external
resource. Every section is always present; a section whose inputs are missing says which command
makes them. Every string read from files is escaped. The report only reads artifacts: the drive
metrics and figures come from the evaluate stage (``WS/report/drive/``,
:mod:`cam2sim.stages.evaluate`), never from scoring runs here.

Sections (stable ids): ``summary`` (inputs, stage timings, warnings), ``map`` (route, parked cars,
every run's trajectory), ``behaviour`` (drive metrics per method, the paper's layout; a splat
that fails the splat quality gate is labelled unfit, with the reason), ``runs`` (per-run table,
lateral offset and steering plots), ``splat`` (held-out scores, the validity envelope measured
against the ground truth with a plot, how each chunk model was trained with its pose
corrections and the robust weighting's left-out pixels, the gate's verdict), ``frames``
(side-by-side frames at chosen points, a video strip), ``semantic`` (IoU tables) and
``images`` (PSNR, SSIM, LPIPS tables).
"""

from __future__ import annotations

import datetime as dt
from typing import TYPE_CHECKING

import numpy as np

from cam2sim import __version__
from cam2sim.core.errors import Cam2SimError
from cam2sim.core.files import write_text_atomic
from cam2sim.core.footprint import footprint_corners
from cam2sim.core.plots import pyplot
from cam2sim.core.progress import ProgressCallback, no_progress
from cam2sim.core.run_record import RunRecord
from cam2sim.core.workspace import dataset_paths, run_paths
from cam2sim.metrics import splat_gate as gate
from cam2sim.metrics.behaviour import (
    CAMERA_LABELS,
    METHOD_COLOURS,
    METHOD_LABELS,
    REAL_METHOD,
    behaviour_table,
)
from cam2sim.metrics.drive_io import load_run_dir
from cam2sim.metrics.drive_quality import DriveMetrics
from cam2sim.metrics.image_quality import PSNR_CAP_DB, ImageQualityResult
from cam2sim.metrics.semantic import SemanticResult
from cam2sim.metrics.steering_agreement import SteeringAgreement
from cam2sim.report.context import ReportContext
from cam2sim.report.exports import write_tables
from cam2sim.report.frames_section import frames_section
from cam2sim.report.pieces import (
    FRAME_WIDTH,
    esc,
    evenly,
    figure_bytes,
    fmt,
    html_table,
    img,
    jpeg,
    not_available,
    section,
)
from cam2sim.report.splat_section import splat_cell, splat_section
from cam2sim.scenario.model import Scenario
from cam2sim.splat.chunk_header import ChunkHeader
from cam2sim.splat.evaluate import SplatEval

if TYPE_CHECKING:
    from collections.abc import Callable, Iterable
    from pathlib import Path

    from cam2sim.core.workspace import Manifest, Workspace
    from cam2sim.map.report import SourceReport
    from cam2sim.metrics.summary import MetricSummary

__all__ = ["SECTION_IDS", "write_report"]

#: The ids of the report's sections, in page order.
SECTION_IDS = ("summary", "map", "behaviour", "runs", "splat", "frames", "semantic", "images")
_LANE_COLOUR = {"driving": "0.85", "parking": "#cfe3f7", "sidewalk": "#f3e3c8"}

_CSS = """
body{font-family:system-ui,sans-serif;margin:0;color:#222;background:#fafafa}
header{background:#23395d;color:#fff;padding:14px 24px}
header h1{margin:0;font-size:22px}
nav{padding:6px 24px;background:#e8edf4}
nav a{margin-right:14px;color:#23395d}
section{background:#fff;margin:16px 24px;padding:8px 20px 16px;border:1px solid #ddd;
border-radius:6px}
h2{border-bottom:1px solid #ddd;padding-bottom:4px}
table{border-collapse:collapse;margin:8px 0;font-size:13px}
th,td{border:1px solid #ccc;padding:3px 8px;text-align:right}
th{background:#eef1f5}
td:first-child,th:first-child{text-align:left}
caption{font-weight:600;text-align:left;padding:4px 0}
img.fig{max-width:100%;height:auto;display:block;margin:8px 0}
.strip{display:flex;gap:4px;overflow-x:auto}
.strip img{height:90px;width:auto}
.na{color:#8a6d00;background:#fff8db;padding:6px 10px;border-left:4px solid #e0b400}
.warn{color:#8b1a1a}
.note{color:#555;font-size:13px}
figure{margin:8px 0}
figcaption{font-size:12px;color:#555}
"""


# -- small HTML helpers ---------------------------------------------------------------------------


# -- gathering ----------------------------------------------------------------------------------
def _gather(ctx: ReportContext) -> None:
    path = ctx.ws.scenario_path
    if path.is_file():
        try:
            ctx.scenario = Scenario.load(path)
        except Cam2SimError as err:
            ctx.warnings.append(f"scenario.json unreadable: {err}")
    for run in ctx.ws.iter_runs():
        if not run_paths(run).trajectory_csv.is_file():
            continue
        try:
            files = run_paths(run)
            meta = RunRecord.load(files.run_json) if files.run_json.is_file() else RunRecord()
            ctx.drives[run.name] = load_run_dir(run)
        except (OSError, ValueError, Cam2SimError) as err:
            ctx.warnings.append(f"run {run.name} unreadable: {err}")
            continue
        ctx.runs.append(run)
        ctx.meta[run.name] = meta


def _drives(ctx: ReportContext) -> list[str]:
    """Names of the closed-loop runs (as the metrics name them), oldest first."""
    return [ctx.drives[p.name].name for p in ctx.runs if ctx.meta[p.name].kind != "replay"]


def _evaluate_command(ctx: ReportContext) -> str:
    return f"cam2sim evaluate workspace {ctx.ws.root}"


def _read_metrics(ctx: ReportContext) -> str | None:
    """Read the evaluate stage's ``metrics.json``; return why there is none, or None."""
    if not _drives(ctx):
        return "no closed-loop run"
    path = ctx.ws.report_files.metrics_json
    if not path.is_file():
        return "the drives are not evaluated"
    try:
        ctx.metrics = DriveMetrics.load(path)
    except Cam2SimError as err:
        ctx.warnings.append(f"drive metrics unreadable: {err}")
        return "metrics.json unreadable"
    m = ctx.metrics
    scored = {r.name for r in m.runs}
    missing = [name for name in _drives(ctx) if name not in scored]
    if missing:
        ctx.warnings.append(
            f"{len(missing)} drive run(s) not in {path} (it scores the runs it was run on, e.g. "
            f"{missing[-1]}): run `{_evaluate_command(ctx)}` to score them all"
        )
    if [r.name for r in m.runs if r.real] == [f"{REAL_METHOD}/recorded"]:
        width = (
            f"so the corridor is that line +- the lane's margin ({m.corridor_rule})"
            if m.corridor_rule != "envelope"
            else "so the corridor has zero width"
        )
        ctx.warnings.append(
            "no real drives given (--real or WS/real/) and no run in the ground-truth world: the "
            f"scenario's recorded trajectory is the only reference, {width}"
        )
    return None


# -- sections -----------------------------------------------------------------------------------
def _pipeline_steps(ctx: ReportContext, manifest: Manifest) -> list[tuple[str, ...]]:
    """Each step's latest outcome of ``cam2sim run`` (the manifest); failures become warnings."""
    rows: list[tuple[str, ...]] = []
    for name, rec in manifest.steps.items():
        finished = rec.finished.strftime("%Y-%m-%d %H:%M:%S")
        rows.append((name, rec.state, finished, f"{rec.seconds:.1f}", rec.message))
        if rec.state == "failed":
            ctx.warnings.insert(0, f"step {name} failed: {rec.message or 'no message'}")
    return rows


def _as_text(value: object) -> str:
    """A config value as a person reads it: lists joined by commas, no JSON quotes."""
    if isinstance(value, list | tuple):
        return ", ".join(_as_text(v) for v in value)
    if isinstance(value, dict):
        return ", ".join(f"{k} {_as_text(v)}" for k, v in value.items())
    return str(value)


def _inputs(ctx: ReportContext, manifest: Manifest) -> list[tuple[str, str]]:
    """What the workspace was made from: the recording or imported files, and the map's OSM."""
    from cam2sim.core.dataset import DatasetInfo  # noqa: PLC0415
    from cam2sim.map.report import MapReport  # noqa: PLC0415

    inputs: list[tuple[str, str]] = []
    dataset = dataset_paths(ctx.ws.dataset_dir).dataset_json
    info = DatasetInfo.load(dataset) if dataset.is_file() else None
    if info is not None and info.kind == "images":
        inputs += [("imported", _as_text([src.path for src in info.sources]))]
    else:
        config = manifest.config
        if not config and ctx.ws.config_path.is_file():  # no stage ran yet: config.yaml
            config = ctx.ws.load_config().model_dump(mode="json")
        recording = (config or {}).get("recording")
        if isinstance(recording, dict):
            inputs += [(f"recording {k}", _as_text(v)) for k, v in recording.items() if v]
    report = ctx.ws.map_files.report_json
    if report.is_file():
        source = MapReport.load(report).source
        inputs.append(_MAP_SOURCES[source.kind](source))
    return inputs


_MAP_SOURCES: dict[str, Callable[[SourceReport], tuple[str, str]]] = {
    "file": lambda src: ("map from OSM", str(src.path)),
    "overpass": lambda src: ("map from OSM", f"Overpass ({src.url})"),
    "trajectory": lambda src: ("map", f"the driven path ({src.path}): no OSM"),
    "xodr": lambda src: ("map", f"the user's OpenDRIVE ({src.path})"),
}
"""The report's line for each map source: where the road came from."""


def _summary(ctx: ReportContext) -> str:
    manifest = ctx.ws.read_manifest()
    created = manifest.created.strftime("%Y-%m-%d %H:%M UTC")
    intro = (
        f"<p>Workspace <code>{esc(ctx.ws.root)}</code>, cam2sim {esc(manifest.tool_version)}, "
        f"created {esc(created)}.</p>"
    )
    parts = [intro]
    inputs = _inputs(ctx, manifest)
    if ctx.ws.truth_world_json.is_file():  # a demo's or a benchmark's world: what it is
        from cam2sim.render.truth import TruthWorld  # noqa: PLC0415 -- lazy: numpy

        world = TruthWorld.load(ctx.ws.truth_world_json)
        inputs += [("ground-truth world", world.title)] if world.title else []
        inputs += [("world note", note) for note in world.notes]
    if ctx.scenario is not None:
        sc = ctx.scenario
        inputs += [
            ("scenario", f"{len(sc.trajectory.t)} samples, {sc.trajectory.t[-1]:.1f} s"),
            ("parked vehicles", f"{len(sc.parked)} placed, {len(sc.rejected)} left out"),
            ("world frame", sc.world.proj_string or "local (not geo-referenced)"),
        ]
    inputs.append(("runs", str(len(ctx.runs))))
    parts.append(html_table(["input", "value"], inputs, "Inputs"))
    rows = []
    for name, rec in manifest.stages.items():
        seconds = (rec.finished - rec.started).total_seconds()
        rows.append((name, rec.state, rec.started.strftime("%H:%M:%S"), f"{seconds:.1f}",
                     rec.message or ""))  # fmt: skip
        if rec.state == "failed":
            ctx.warnings.insert(0, f"stage {name} failed: {rec.message or 'no message'}")
    steps = _pipeline_steps(ctx, manifest)
    if steps:  # one table: the latest cam2sim run's steps (each stage's own record is in it)
        parts.append(html_table(["step", "state", "finished", "seconds", "message"], steps,
                            "Pipeline steps (the latest cam2sim run)"))  # fmt: skip
    elif rows:
        parts.append(
            html_table(["stage", "state", "started", "seconds", "message"], rows, "Stages")
        )
    else:
        parts.append(not_available("Stage timings", f"cam2sim extract {ctx.ws.root}"))
    if ctx.scenario is not None:
        ctx.warnings += [f"left out {r.id}: {'; '.join(r.reasons)}" for r in ctx.scenario.rejected]
    if ctx.warnings:
        items = "".join(f"<li>{esc(w)}</li>" for w in ctx.warnings)
        parts.append(f'<h3>Warnings</h3><ul class="warn">{items}</ul>')
    else:
        parts.append("<h3>Warnings</h3><p>none</p>")
    return "".join(parts)


def _map(ctx: ReportContext) -> str:
    if ctx.scenario is None:
        return not_available("The map", f"cam2sim scenario {ctx.ws.root}")
    from matplotlib.patches import Polygon  # noqa: PLC0415

    sc = ctx.scenario
    fig, ax = pyplot().subplots(figsize=(10, 8))
    xodr = ctx.ws.map_xodr_path
    if xodr.is_file():
        from cam2sim.map.query import RoadMap  # noqa: PLC0415 -- lazy: imports shapely

        try:
            road_map = RoadMap.from_xodr(xodr)
        except Cam2SimError as err:
            ctx.warnings.append(f"map.xodr unreadable: {err}")
        else:
            for lane_type, colour in _LANE_COLOUR.items():
                for poly in road_map.lane_polygons(lane_type):
                    for part in getattr(poly, "geoms", [poly]):
                        ring = np.asarray(part.exterior.coords)
                        ax.fill(ring[:, 0], ring[:, 1], color=colour, lw=0, zorder=0)
    route = np.asarray(sc.trajectory.reference)
    ax.plot(route[:, 0], route[:, 1], color="black", lw=2.5, ls="--", label="recorded route")
    if sc.parked:
        quads = footprint_corners(
            [v.position[:2] for v in sc.parked],
            [v.heading for v in sc.parked],
            [v.size[0] for v in sc.parked],
            [v.size[1] for v in sc.parked],
        )
        for quad in quads:
            ax.add_patch(Polygon(quad, closed=True, facecolor="#4292c6", edgecolor="k", zorder=3))
        ax.plot([], [], "s", color="#4292c6", label=f"parked ({len(sc.parked)})")
    cmap = pyplot().get_cmap("tab10")
    seen: list[str] = []  # one colour and one legend entry per method
    for run in ctx.runs:
        drv = ctx.drives[run.name]
        label = "Real" if drv.real else METHOD_LABELS.get(drv.method, drv.method)
        colour = METHOD_COLOURS.get(label) or cmap(len(seen) % 10)
        ax.plot(
            drv.xy[:, 0], drv.xy[:, 1], color=colour, lw=1.2, zorder=4,
            label=None if label in seen else label,
        )  # fmt: skip
        seen += [] if label in seen else [label]
    ax.set_aspect("equal")
    ax.set_xlabel("east (m)")
    ax.set_ylabel("north (m)")
    ax.legend(loc="best", fontsize=7)
    note = "" if ctx.runs else not_available("Run trajectories", f"cam2sim drive {ctx.ws.root}")
    return img(figure_bytes(fig), "map with route, parked cars and runs") + note


def _behaviour(ctx: ReportContext, why: str | None) -> str:
    m = ctx.metrics
    if m is None:
        command = _evaluate_command(ctx) if _drives(ctx) else f"cam2sim drive {ctx.ws.root}"
        return not_available(f"Behaviour metrics ({why or 'no runs'}):", command)

    paper = behaviour_table(m)
    parts = [
        ctx.table(
            "behaviour",
            ["metric", *paper.columns],
            [(name, *values) for name, values in paper.rows],
            "Behaviour per method (the paper's layout)",
        )
    ]
    parts += [f'<p class="warn"><b>{esc(note)}</b></p>' for note in paper.notes]
    unfit = {g.method: g for g in m.splat_gate if not g.fit}
    ctx.warnings += [
        f"{METHOD_LABELS.get(g.method, g.method)}: its runs fail the splat quality gate "
        f"({g.reason})"
        for g in unfit.values()
    ]
    meaning = {
        "Real": "the recorded drive and the closed-loop runs in the ground-truth world (the "
        "truth camera; completed ones are references, scored leave-one-out)",
        "splat": "the splat camera in the reconstructed world",
        "Sim": "the simulator's raster camera in the reconstructed world",
    }
    glossary = "; ".join(f"{k}: {v}" for k, v in meaning.items() if k in paper.columns)
    note = (
        f'<p class="note">{esc(glossary)}. Segment {m.segment.length_m:.1f} m '
        f"(reference {esc(m.segment.reference_run)}), corridor mean width "
        f"{m.corridor_mean_width_m:.2f} m"
        + (f" ({esc(m.corridor_rule)}: the lane's margin)" if m.corridor_rule != "envelope" else "")
        + ". Averages over successful runs; jitter over all "
        "runs. Failure types: OR out of road, CC collision, OS oversteer, US understeer.</p>"
    )
    parts.append(note)
    parts.append(_headline_context(ctx, m))
    parts.append(_dave2_training(ctx))
    return "".join(parts)


def _dave2_training(ctx: ReportContext) -> str:
    """DAVE-2's training curve against a constant prediction (``ads/train_report.png``)."""
    figure = ctx.ws.ads_files.train_figure
    if not figure.is_file():
        return ""
    alt = "DAVE-2 training: training and validation error by epoch, and predictions"
    note = (
        '<p class="note">The system under test, DAVE-2, as trained on the recorded frames: '
        "its training and validation error by epoch against the validation variance (the error "
        "of always predicting the mean steering; a model above that line learned nothing), and "
        "its predictions on the validation frames. A network trained without a validated run "
        "(<code>ads train --same-street --no-validate</code>, as the street benchmark trains "
        "it) shows its training error only.</p>"
    )
    return "<h3>The system under test</h3>" + note + img(figure.read_bytes(), alt)


def _headline_context(ctx: ReportContext, m: DriveMetrics) -> str:
    """What the columns hold: run counts, what Real is here, what the splat got (and warnings)."""
    counts = ", ".join(f"{METHOD_LABELS.get(s.method, s.method)} {s.runs}" for s in m.methods)
    truth = ctx.ws.truth_world_json.is_file()
    real = (
        "the demo's ground-truth world: the recorded drive through it and DAVE-2's closed-loop "
        "runs in it (the truth camera)"
        if truth
        else "the recorded drive (and any further recorded drives given with --real); no "
        "closed-loop run can drive in reality"
    )
    first = (
        f"Runs per column: {counts}. Real has one run more than the closed-loop columns: the "
        f"recorded drive. Real in this workspace is {real}."
    )
    lines = [first]
    headers = []
    for path in sorted(ctx.ws.splat_files.models_dir.glob("chunk_*.json")):
        try:
            headers.append(ChunkHeader.load(path))
        except Cam2SimError:
            continue  # the splat section says which file is unreadable
    if headers:
        steps = "/".join(f"{h.steps:,}" for h in headers)
        stops = "/".join(sorted({h.stopped or "-" for h in headers}))
        lines.append(
            f"The splat: {len(headers)} chunk(s) trained with {headers[0].backend or '?'}, "
            f"{steps} steps, stopped by {stops}."
        )
        timed = [h.chunk_id for h in headers if h.stopped == "time"]
        if timed:
            ctx.warnings.append(
                f"splat chunk(s) {', '.join(map(str, timed))} stopped on their time budget, "
                "not on their own plateau: train longer (cam2sim splat --force on a GPU)"
            )
    ev_path = ctx.ws.splat_files.eval_json
    if ev_path.is_file():
        try:
            ev = SplatEval.load(ev_path)
        except Cam2SimError:
            ev = None
        if ev is not None and ev.psnr_db.mean is not None:
            raw = ev.psnr_db_raw.mean if ev.psnr_db_raw is not None else None
            with_raw = f", {raw:.1f} dB without its colour transform" if raw is not None else ""
            lines.append(f"Held out: {ev.psnr_db.mean:.1f} dB{with_raw}.")
            if raw is not None and raw < gate.HELD_OUT_MIN_PSNR_DB:
                ctx.warnings.append(
                    f"without its per-view colour transform the splat scores {raw:.1f} dB held "
                    f"out, under the gate's {gate.HELD_OUT_MIN_PSNR_DB:g} dB: the transform, not "
                    "the model, makes up the difference"
                )
    return '<p class="note">' + " ".join(esc(line) for line in lines) + "</p>"


def _runs(ctx: ReportContext) -> str:
    if not ctx.runs:
        return not_available("Runs", f"cam2sim drive {ctx.ws.root}")
    per_run = {r.name: r for r in ctx.metrics.runs} if ctx.metrics else {}
    rows = []
    for run in ctx.runs:
        meta = ctx.meta[run.name]
        drv = ctx.drives[run.name]
        kinds = ", ".join(e.kind for e in drv.events) or "-"
        m = per_run.get(drv.name)
        rows.append((
            run.name, meta.kind or "?", drv.method, meta.policy or "-",
            len(drv), f"{meta.seconds or 0.0:.2f}", kinds,
            fmt(m.completion if m else None, ".2f"), (m.failure or "ok") if m else "-",
            splat_cell(meta),
        ))  # fmt: skip
    headers = ["run", "kind", "method", "policy", "steps", "seconds", "events", "completion",
               "outcome", "splat gate (coverage mean / max)"]  # fmt: skip
    parts = [html_table(headers, rows, "Runs")]
    # The evaluate stage's figures (its trajectories figure is the map section's job).
    figures = [ctx.ws.drive_eval_dir / f"{name}.png" for name in ("lateral_offset", "steering")]
    if ctx.metrics is None or not all(f.is_file() for f in figures):
        command = _evaluate_command(ctx) if _drives(ctx) else f"cam2sim drive {ctx.ws.root}"
        parts.append(not_available("Lateral offset and steering plots", command))
        return "".join(parts)
    parts += [img(p.read_bytes(), p.stem.replace("_", " ")) for p in figures]
    return "".join(parts)


def _stats_rows(rows: Iterable[tuple[str, MetricSummary, str]]) -> list[tuple[str, str, str, int]]:
    return [(n, fmt(s.mean, f), fmt(s.std, f), s.n) for n, s, f in rows]


def _found(ctx: ReportContext, name: str) -> list[Path]:
    if not ctx.ws.report_dir.is_dir():
        return []
    return sorted(p for p in ctx.ws.report_dir.rglob(name) if not p.name.startswith("."))


def _semantic(ctx: ReportContext) -> str:
    parts = []
    for path in _found(ctx, "semantic.json"):
        try:
            res = SemanticResult.load(path)
        except Cam2SimError as err:
            ctx.warnings.append(f"{path}: {err}")
            continue
        s = res.summary
        rows = [(f"IoU {c}", s.classes[c], ".4f") for c in res.classes]
        rows.append(("mIoU", s.miou, ".4f"))
        caption = f"{path.relative_to(ctx.ws.root)}: {len(res.frames)} segmentation pairs"
        name = "semantic" if path.parent.name == "semantic" else f"semantic_{path.parent.name}"
        table = ctx.table(name, ["metric", "mean", "std", "n"], _stats_rows(rows), caption)
        parts.append(table)
        pictures = sorted((path.parent / "comparison").glob("*.png"))
        if pictures:
            picked = evenly(pictures, 3)
            parts.append(
                '<p class="note">Labels side by side (real | where they differ, in white | '
                f"simulated), {len(picked)} of {len(pictures)} frames:</p>"
            )
            parts += [
                f"<figure>{img(jpeg(f, FRAME_WIDTH), f'labels {f.stem}', mime='image/jpeg')}"
                f"<figcaption>frame {esc(f.stem)}</figcaption></figure>"
                for f in picked
            ]
        if (path.parent / "real").is_dir() and (path.parent / "sim").is_dir():
            parts.append(
                '<p class="note">Labels of the ground-truth world (real) against the simulated '
                "world built from the recording (map, detected parked cars, OSM buildings), "
                "both rendered at recorded poses.</p>"
            )
    if not parts:
        return not_available(
            "Semantic IoU", f"cam2sim evaluate semantic REAL SIM -o {ctx.ws.report_dir}/semantic"
        )
    return "".join(parts)


def _images(ctx: ReportContext) -> str:
    results = []
    for path in _found(ctx, "images.json"):
        try:
            results.append((path, ImageQualityResult.load(path)))
        except Cam2SimError as err:
            ctx.warnings.append(f"{path}: {err}")
    if not results:
        return not_available(
            "Image quality", f"cam2sim evaluate images REAL SIM -o {ctx.ws.report_dir}/images"
        )
    rank = list(_IMAGE_COLUMNS)  # splat before the simulator, as the paper's columns
    results.sort(key=lambda r: rank.index(f) if (f := r[0].parent.name) in rank else len(rank))
    names = [_image_column(path, ctx.ws.report_dir) for path, _ in results]
    nets = sorted({res.lpips_net for _, res in results if res.lpips_net})
    lpips = f"LPIPS ({', '.join(nets)})" if nets else "LPIPS"
    metrics = [("PSNR dB", "psnr_db", ".2f"), ("SSIM", "ssim", ".4f"), (lpips, "lpips", ".4f")]
    rows: list[list[str]] = []
    for label, key, spec in metrics:
        cells = [
            _stats_cell(res.summary.get(key), spec) if key != "lpips" or res.lpips_net else "-"
            for _, res in results
        ]
        rows.append([label, *cells])
    rows.append(["image pairs", *(str(len(res.images)) for _, res in results)])
    steering = _steering_rows(ctx, [path.parent / "steering.json" for path, _ in results])
    parts = [
        html_table(["metric (mean ± std)", *names], rows + steering, "Against the recorded frames")
    ]
    if steering:
        parts.append(
            '<p class="note">DAVE-2 rows: the driving model is shown each rendered frame and the '
            "recorded frame of the same pose; the gap is its steering on the first minus on the "
            "second (open loop, no ground truth needed). A renderer that makes it act as reality "
            "does has small gaps and a correlation near 1; the spread of its steering on the "
            "recorded frames is the scale. Never-trained frames: the splat's held-out views."
            "</p>"
        )
    if not any(res.lpips_net for _, res in results):
        parts.append('<p class="note">LPIPS skipped: its weights are not on this machine.</p>')
    where = ", ".join(str(path.relative_to(ctx.ws.root)) for path, _ in results)
    cap = f"PSNR is capped at {PSNR_CAP_DB:g} dB"
    parts.append(f'<p class="note">From {esc(where)}; {cap}.</p>')
    return "".join(parts)


def _steering_rows(ctx: ReportContext, paths: list[Path]) -> list[list[str]]:
    """DAVE-2 on each camera's frames against the recorded ones (``steering.json``), if any."""
    found: list[SteeringAgreement | None] = []
    for path in paths:
        try:
            found.append(SteeringAgreement.load(path) if path.is_file() else None)
        except Cam2SimError as err:
            ctx.warnings.append(f"{path}: {err}")
            found.append(None)
    if not any(found):
        return []

    def cells(text: Callable[[SteeringAgreement], str]) -> list[str]:
        return [text(a) if a is not None else "-" for a in found]

    return [
        ["DAVE-2 steering gap |rendered - recorded|, mean (units)",
         *cells(lambda a: f"{a.mean_abs_gap:.3f}")],
        ["steering gap: 95th percentile / largest (frame)",
         *cells(lambda a: f"{a.p95_abs_gap:.3f} / {a.max_abs_gap:.3f} ({a.max_gap_frame})")],
        ["steering correlation with the recorded frames' (their spread)",
         *cells(lambda a: f"{fmt(a.correlation, '.3f')} ({a.recorded_std:.3f})")],
        ["frames never trained on: mean gap, correlation (frames)",
         *cells(lambda a: f"{fmt(a.held_out_mean_abs_gap, '.3f')}, "
                          f"{fmt(a.held_out_correlation, '.3f')} ({a.held_out_frames})"
                if a.held_out_frames else "-")],
    ]  # fmt: skip


#: Column names of the image-quality table, by the folder name of the compared images.
_IMAGE_COLUMNS = CAMERA_LABELS


def _image_column(path: Path, report_dir: Path) -> str:
    folder = path.parent.name if path.parent != report_dir / "images" else "images"
    return _IMAGE_COLUMNS.get(folder, folder)


def _stats_cell(stats: MetricSummary | None, spec: str) -> str:
    if stats is None or stats.mean is None:
        return "-"
    return f"{format(stats.mean, spec)} ± {fmt(stats.std, spec)}"


# -- the page -----------------------------------------------------------------------------------
def write_report(
    ws: Workspace,
    *,
    out: Path | None = None,
    progress: ProgressCallback | None = None,
) -> Path:
    """Build the self-contained HTML report of a workspace and write it atomically.

    The report only reads what the stages wrote: the drive metrics and figures of the evaluate
    stage (``WS/report/drive/``; ``cam2sim evaluate workspace`` or ``cam2sim run`` write them),
    the runs, the splat's ``eval.json``, the image and semantic metrics. A section whose inputs
    are missing says which command writes them.

    Args:
        ws: The workspace.
        out: Output file; default ``WS/report/report.html``.
        progress: Called as ``progress("report", done, total)``.

    Returns:
        The path written.
    """
    report = progress or no_progress
    ctx = ReportContext(ws)
    total = len(SECTION_IDS) + 1
    _gather(ctx)
    why = _read_metrics(ctx)
    report("report", 1, total)
    body: dict[str, str] = {}
    steps: tuple[tuple[str, str, Callable[[], str]], ...] = (
        ("map", "Map, route and trajectories", lambda: _map(ctx)),
        ("behaviour", "Behaviour", lambda: _behaviour(ctx, why)),
        ("runs", "Runs", lambda: _runs(ctx)),
        ("splat", "Splat quality: held out, against the ground truth, the gate",
         lambda: splat_section(ctx)),
        ("frames", "Frames, side by side", lambda: frames_section(ctx)),
        ("semantic", "Semantic IoU", lambda: _semantic(ctx)),
        ("images", "Image quality", lambda: _images(ctx)),
    )  # fmt: skip
    for k, (sid, title, build) in enumerate(steps, start=2):
        body[sid] = section(sid, title, build())
        report("report", k, total)
    body["summary"] = section("summary", "Pipeline summary", _summary(ctx))
    report("report", total, total)
    nav = "".join(f'<a href="#{sid}">{sid}</a>' for sid in SECTION_IDS)
    stamp = dt.datetime.now(dt.UTC).strftime("%Y-%m-%d %H:%M UTC")
    page = (
        '<!DOCTYPE html><html lang="en"><head><meta charset="utf-8">'
        f"<title>cam2sim report: {esc(ws.root.name)}</title><style>{_CSS}</style></head><body>"
        f"<header><h1>cam2sim report: {esc(ws.root.name)}</h1>"
        f"<div>generated {stamp} by cam2sim {esc(__version__)}</div></header><nav>{nav}</nav>"
        + "".join(body[sid] for sid in SECTION_IDS)
        + "</body></html>\n"
    )
    path = out if out is not None else ws.report_files.html
    write_tables(path.parent / "tables", ctx.exported)
    write_text_atomic(path, page)
    return path
