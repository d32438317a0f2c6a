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
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from cam2sim import __version__
from cam2sim.core.errors import Cam2SimError
from cam2sim.core.files import write_text_atomic
from cam2sim.core.footprint import footprint_corners
from cam2sim.core.native import native_stderr_silenced
from cam2sim.core.plots import pyplot
from cam2sim.core.progress import ProgressCallback, no_progress
from cam2sim.core.run_record import RunEvents, RunRecord
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
from cam2sim.report.exports import ExportedTable, write_tables
from cam2sim.report.pieces import data_uri, esc, html_table
from cam2sim.report.splat_figures import envelope_figure, training_figure
from cam2sim.scenario.model import Scenario
from cam2sim.splat.chunk_header import ChunkHeader, outliers_path, pose_correction_sizes
from cam2sim.splat.evaluate import SplatEval

if TYPE_CHECKING:
    from collections.abc import Callable, Iterable, Sequence

    import numpy.typing as npt

    from cam2sim.core.workspace import Manifest, Workspace
    from cam2sim.map.report import SourceReport
    from cam2sim.metrics.drive_io import DriveRun
    from cam2sim.metrics.summary import MetricSummary
    from cam2sim.splat.scores import TruthScore

__all__ = ["SECTION_IDS", "VIDEO_CAP_BYTES", "write_report"]

#: The ids of the report's sections, in page order.
SECTION_IDS = ("summary", "map", "behaviour", "runs", "splat", "frames", "semantic", "images")
_VIDEO_FRAMES = 300  # frames of a run's clip in the report
_VIDEO_WIDTH = 640
#: A run's clip (WebM made from its frames) is embedded only up to this size.
VIDEO_CAP_BYTES = 8 * 1024 * 1024
_CHOSEN_FRAMES = 4
_STRIP_FRAMES = 8
_FRAME_WIDTH = 1280
_STRIP_WIDTH = 320
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


@dataclass
class _Context:
    """What a report build found and the warnings it collected."""

    ws: Workspace
    warnings: list[str] = field(default_factory=list)
    scenario: Scenario | None = None
    runs: list[Path] = field(default_factory=list)
    meta: dict[str, RunRecord] = field(default_factory=dict)
    drives: dict[str, DriveRun] = field(default_factory=dict)
    metrics: DriveMetrics | None = None
    exported: list[ExportedTable] = field(default_factory=list)

    def table(
        self, name: str, headers: Sequence[str], rows: Sequence[Sequence[object]], caption: str
    ) -> str:
        """The HTML of a table that is also exported as ``report/tables/<name>.csv|.tex``."""
        table = ExportedTable.of(name, headers, rows, caption)
        self.exported.append(table)
        return html_table(table.headers, table.rows, caption)


# -- small HTML helpers ---------------------------------------------------------------------------
def _img(data: bytes, alt: str, *, mime: str = "image/png", cls: str = "fig") -> str:
    return f'<img class="{cls}" alt="{esc(alt)}" src="{data_uri(data, mime)}">'


def _na(what: str, command: str) -> str:
    return f'<p class="na">{esc(what)} not available: run <code>{esc(command)}</code></p>'


def _fmt(value: float | None, spec: str) -> str:
    return "-" if value is None else format(value, spec)


def _section(sid: str, title: str, body: str) -> str:
    return f'<section id="{sid}"><h2>{esc(title)}</h2>{body}</section>'


# -- gathering ----------------------------------------------------------------------------------
def _gather(ctx: _Context) -> None:
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


def _drives(ctx: _Context) -> list[str]:
    """Names of the closed-loop runs (as the metrics name them), oldest first."""
    return [ctx.drives[p.name].name for p in ctx.runs if ctx.meta[p.name].kind != "replay"]


def _evaluate_command(ctx: _Context) -> str:
    return f"cam2sim evaluate workspace {ctx.ws.root}"


def _read_metrics(ctx: _Context) -> str | None:
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
        ctx.warnings.append(
            "no real drives given (--real or WS/real/) and no run in the ground-truth world: the "
            "scenario's recorded trajectory is the only reference, so the corridor has zero width"
        )
    return None


# -- sections -----------------------------------------------------------------------------------
def _pipeline_steps(ctx: _Context, manifest: Manifest) -> list[tuple[str, ...]]:
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


def _inputs(ctx: _Context, manifest: Manifest) -> list[tuple[str, str]]:
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


def _summary(ctx: _Context) -> str:
    manifest = ctx.ws.read_manifest()
    created = manifest.created.strftime("%Y-%m-%d %H:%M UTC")
    intro = (
        f"<p>Workspace <code>{esc(ctx.ws.root)}</code>, cam2sim {esc(manifest.tool_version)}, "
        f"created {esc(created)}.</p>"
    )
    parts = [intro]
    inputs = _inputs(ctx, manifest)
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
        parts.append(_na("Stage timings", f"cam2sim extract {ctx.ws.root}"))
    if ctx.scenario is not None:
        ctx.warnings += [f"left out {r.id}: {'; '.join(r.reasons)}" for r in ctx.scenario.rejected]
    if ctx.warnings:
        items = "".join(f"<li>{esc(w)}</li>" for w in ctx.warnings)
        parts.append(f'<h3>Warnings</h3><ul class="warn">{items}</ul>')
    else:
        parts.append("<h3>Warnings</h3><p>none</p>")
    return "".join(parts)


def _figure_bytes(fig: Any) -> bytes:
    import io  # noqa: PLC0415

    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=110, bbox_inches="tight")
    pyplot().close(fig)
    return buffer.getvalue()


def _map(ctx: _Context) -> str:
    if ctx.scenario is None:
        return _na("The map", f"cam2sim scenario {ctx.ws.root}")
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
    note = "" if ctx.runs else _na("Run trajectories", f"cam2sim drive {ctx.ws.root}")
    return _img(_figure_bytes(fig), "map with route, parked cars and runs") + note


def _behaviour(ctx: _Context, why: str | None) -> str:
    m = ctx.metrics
    if m is None:
        command = _evaluate_command(ctx) if _drives(ctx) else f"cam2sim drive {ctx.ws.root}"
        return _na(f"Behaviour metrics ({why or 'no runs'}):", command)

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
        f"{m.corridor_mean_width_m:.2f} m. Averages over successful runs; jitter over all "
        "runs. Failure types: OR out of road, CC collision, OS oversteer, US understeer.</p>"
    )
    parts.append(note)
    parts.append(_headline_context(ctx, m))
    parts.append(_dave2_training(ctx))
    return "".join(parts)


def _dave2_training(ctx: _Context) -> str:
    """DAVE-2's training curve against a constant prediction (``ads/train_report.png``)."""
    figure = ctx.ws.ads_files.train_figure
    if not figure.is_file():
        return ""
    alt = "DAVE-2 training: training and validation error by epoch, and predictions"
    note = (
        '<p class="note">The system under test, DAVE-2, as trained on the recorded frames: '
        "its training and validation error by epoch against the validation variance (the error "
        "of always predicting the mean steering; a model above that line learned nothing), and "
        "its predictions on the validation frames.</p>"
    )
    return "<h3>The system under test</h3>" + note + _img(figure.read_bytes(), alt)


def _headline_context(ctx: _Context, m: DriveMetrics) -> str:
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


def _runs(ctx: _Context) -> str:
    if not ctx.runs:
        return _na("Runs", f"cam2sim drive {ctx.ws.root}")
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
            _fmt(m.completion if m else None, ".2f"), (m.failure or "ok") if m else "-",
            _splat_cell(meta),
        ))  # fmt: skip
    headers = ["run", "kind", "method", "policy", "steps", "seconds", "events", "completion",
               "outcome", "splat gate (coverage mean / max)"]  # fmt: skip
    parts = [html_table(headers, rows, "Runs")]
    # The evaluate stage's figures (its trajectories figure is the map section's job).
    figures = [ctx.ws.drive_eval_dir / f"{name}.png" for name in ("lateral_offset", "steering")]
    if ctx.metrics is None or not all(f.is_file() for f in figures):
        command = _evaluate_command(ctx) if _drives(ctx) else f"cam2sim drive {ctx.ws.root}"
        parts.append(_na("Lateral offset and steering plots", command))
        return "".join(parts)
    parts += [_img(p.read_bytes(), p.stem.replace("_", " ")) for p in figures]
    return "".join(parts)


def _splat_cell(meta: RunRecord) -> str:
    """A run's splat gate verdict and driven coverage; "-" for runs without the splat camera."""
    quality, gate = meta.splat_quality, meta.splat_gate
    if quality is None or gate is None:
        return "-"
    verdict = "fit" if gate.get("fit") else "unfit"
    mean, top = quality.get("coverage_mean"), quality.get("coverage_max")
    return f"{verdict} ({_fmt(mean, '.2f')} / {_fmt(top, '.2f')})"


def _evenly(items: Sequence[Path], n: int) -> list[Path]:
    if len(items) <= n:
        return list(items)
    return [items[int(i)] for i in np.linspace(0, len(items) - 1, n).round()]


def _jpeg(path: Path, width: int) -> bytes:
    import cv2  # noqa: PLC0415

    image: npt.NDArray[Any] | None = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if image is None:
        msg = f"{path} is not a readable image"
        raise OSError(msg)
    h, w = image.shape[:2]
    if w > width:
        image = cv2.resize(
            image, (width, max(1, round(h * width / w))), interpolation=cv2.INTER_AREA
        )
    ok, buf = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, 85])
    if not ok:
        msg = f"cannot encode {path}"
        raise OSError(msg)
    return bytes(buf.tobytes())


def _frame_folder(run: Path) -> Path | None:
    if any(run_paths(run).side_by_side_dir.glob("*.png")):
        return run_paths(run).side_by_side_dir
    for folder in sorted((run / "frames").glob("*")):
        if any(folder.glob("*.png")):
            return folder
    return None


def _frames(ctx: _Context) -> str:
    """The latest replay side by side, and the first kept drive of each camera (method).

    A drive that ended in a failure also shows its last frame before it.
    """
    found = [(run, f) for run in ctx.runs if (f := _frame_folder(run)) is not None]
    if not found:
        return _na("Frames", f"cam2sim replay {ctx.ws.root} --camera both")
    replays = [(r, f) for r, f in found if ctx.meta[r.name].kind == "replay"]
    chosen = replays[-1:]
    by_camera: dict[str, tuple[Path, Path]] = {}
    for run, folder in found:
        meta = ctx.meta[run.name]
        if meta.kind == "drive" and meta.camera and meta.camera not in by_camera:
            by_camera[meta.camera] = (run, folder)
    chosen += [by_camera[c] for c in sorted(by_camera, key=_camera_order)]
    parts = []
    for run, folder in chosen:
        files = sorted(folder.glob("*.png"))
        meta = ctx.meta[run.name]
        if meta.kind == "replay":
            cams = meta.cameras or [meta.camera or "?"]
            labels = [CAMERA_LABELS.get(str(c), str(c)) for c in cams]
            panels = " | ".join(["recorded (left, where there is a recorded frame)", *labels])
            what = f"replay, side by side: {panels}"
        else:
            label = CAMERA_LABELS.get(meta.camera or "", meta.camera or "?")
            what = f"closed loop, {label}: what DAVE-2 saw (seed {meta.seed})"
        parts.append(f"<h3>{esc(run.name)}</h3><p class='note'>{esc(what)}</p>")
        try:
            for f in _evenly(files, _CHOSEN_FRAMES):
                img = _img(_jpeg(f, _FRAME_WIDTH), f"frame {f.stem}", mime="image/jpeg")
                parts.append(f"<figure>{img}<figcaption>frame {esc(f.stem)}</figcaption></figure>")
            failure = _failure(run)
            if failure is not None and files:
                img = _img(_jpeg(files[-1], _FRAME_WIDTH), "the last frame", mime="image/jpeg")
                caption = f"the last frame before it failed: {failure}"
                parts.append(f"<figure>{img}<figcaption>{esc(caption)}</figcaption></figure>")
            strip = "".join(
                _img(_jpeg(f, _STRIP_WIDTH), f"strip {f.stem}", mime="image/jpeg", cls="strip")
                for f in _evenly(files, _STRIP_FRAMES)
            )
        except OSError as err:
            ctx.warnings.append(f"frames of {run.name}: {err}")
            continue
        parts.append(f'<p class="note">Video strip</p><div class="strip">{strip}</div>')
        if meta.kind != "replay":
            continue  # one clip: the replay's
        clip = _webm(files[:_VIDEO_FRAMES])
        if clip is not None and len(clip) <= VIDEO_CAP_BYTES:
            src = data_uri(clip, "video/webm")
            parts.append(f'<video controls muted loop width="640" src="{src}"></video>')
        elif run_paths(run).video.is_file():
            parts.append(f'<p class="note">the run\'s video: {esc(str(run_paths(run).video))}</p>')
    return "".join(parts)


def _camera_order(camera: str) -> int:
    """Real (truth), splat, Sim (raster), then the others: the behaviour table's order."""
    order = ("truth", "splat", "raster", "carla")
    return order.index(camera) if camera in order else len(order)


def _failure(run: Path) -> str | None:
    """``collision at 12.3 s: hit parked vehicle pv_3`` for a run that failed, else None."""
    path = run_paths(run).events_json
    if not path.is_file():
        return None
    try:
        events = RunEvents.load(path).events
    except Cam2SimError:
        return None
    for event in events:
        if event.kind in ("collision", "off_road", "stuck", "timeout"):
            reason = f": {event.reason}" if event.reason else ""
            return f"{event.kind} at {event.t:.1f} s{reason}"
    return None


def _webm(files: list[Path], fps: float = 10.0) -> bytes | None:
    """The frames as a VP8 WebM clip (browsers play it; OpenCV's MP4 is not H.264), or None."""
    import tempfile  # noqa: PLC0415

    import cv2  # noqa: PLC0415

    if not files:
        return None
    first = cv2.imread(str(files[0]), cv2.IMREAD_COLOR)
    if first is None:
        return None
    h, w = first.shape[:2]
    size = (_VIDEO_WIDTH, max(2, round(h * _VIDEO_WIDTH / w) // 2 * 2))
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "clip.webm"
        with native_stderr_silenced():  # FFmpeg's "tag 'VP80' is not supported" (it is)
            writer = cv2.VideoWriter(str(out), cv2.VideoWriter.fourcc(*"VP80"), fps, size)
        if not writer.isOpened():
            return None
        try:
            for f in files:  # one encode per frame
                bgr = cv2.imread(str(f), cv2.IMREAD_COLOR)
                if bgr is not None:
                    writer.write(cv2.resize(bgr, size, interpolation=cv2.INTER_AREA))
        finally:
            writer.release()
        return out.read_bytes() if out.stat().st_size else None


def _stats_rows(rows: Iterable[tuple[str, MetricSummary, str]]) -> list[tuple[str, str, str, int]]:
    return [(n, _fmt(s.mean, f), _fmt(s.std, f), s.n) for n, s, f in rows]


def _found(ctx: _Context, name: str) -> list[Path]:
    if not ctx.ws.report_dir.is_dir():
        return []
    return sorted(p for p in ctx.ws.report_dir.rglob(name) if not p.name.startswith("."))


def _semantic(ctx: _Context) -> str:
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
            picked = _evenly(pictures, 3)
            parts.append(
                '<p class="note">Labels side by side (real | where they differ, in white | '
                f"simulated), {len(picked)} of {len(pictures)} frames:</p>"
            )
            parts += [
                f"<figure>{_img(_jpeg(f, _FRAME_WIDTH), f'labels {f.stem}', mime='image/jpeg')}"
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
        return _na(
            "Semantic IoU", f"cam2sim evaluate semantic REAL SIM -o {ctx.ws.report_dir}/semantic"
        )
    return "".join(parts)


def _images(ctx: _Context) -> str:
    results = []
    for path in _found(ctx, "images.json"):
        try:
            results.append((path, ImageQualityResult.load(path)))
        except Cam2SimError as err:
            ctx.warnings.append(f"{path}: {err}")
    if not results:
        return _na(
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
    parts = [html_table(["metric (mean ± std)", *names], rows, "Against the recorded frames")]
    if not any(res.lpips_net for _, res in results):
        parts.append('<p class="note">LPIPS skipped: its weights are not on this machine.</p>')
    where = ", ".join(str(path.relative_to(ctx.ws.root)) for path, _ in results)
    cap = f"PSNR is capped at {PSNR_CAP_DB:g} dB"
    parts.append(f'<p class="note">From {esc(where)}; {cap}.</p>')
    return "".join(parts)


#: Column names of the image-quality table, by the folder name of the compared images.
_IMAGE_COLUMNS = CAMERA_LABELS


def _image_column(path: Path, report_dir: Path) -> str:
    folder = path.parent.name if path.parent != report_dir / "images" else "images"
    return _IMAGE_COLUMNS.get(folder, folder)


def _stats_cell(stats: MetricSummary | None, spec: str) -> str:
    if stats is None or stats.mean is None:
        return "-"
    return f"{format(stats.mean, spec)} ± {_fmt(stats.std, spec)}"


def _summary_rows(
    rows: Iterable[tuple[str, MetricSummary, str]],
) -> list[tuple[str, str, str, str, int]]:
    return [(n, _fmt(s.mean, f), _fmt(s.p10, f), _fmt(s.p90, f), s.n) for n, s, f in rows]


def _splat(ctx: _Context) -> str:
    """Held-out scores, the envelope against the ground truth (table and plot), the gate."""
    path = ctx.ws.splat_files.eval_json
    if not path.is_file():
        return _na("Splat quality (WS/splat/eval.json)", f"cam2sim splat {ctx.ws.root}")
    try:
        ev = SplatEval.load(path)
    except Cam2SimError as err:
        ctx.warnings.append(f"{path}: {err}")
        return _na("Splat quality (eval.json unreadable)", f"cam2sim splat {ctx.ws.root} --force")
    held = [("PSNR dB", ev.psnr_db, ".2f"), ("SSIM", ev.ssim, ".3f"), ("LPIPS", ev.lpips, ".3f")]
    caption = f"Held out: {ev.n_held_out} recorded frames never trained on"
    headers = ["metric", "mean", "p10", "p90", "frames"]
    parts = [ctx.table("splat_held_out", headers, _summary_rows(held), caption)]
    parts.append(_held_out_pictures(ctx, ev))
    if ev.truth is None:
        parts.append(
            '<p class="note">Not scored against a ground truth: the workspace has no '
            "WS/truth/world.json (cam2sim demo writes one), so the validity envelope is "
            "measured only relative to the on-path renders (eval.json offsets).</p>"
        )
    else:
        rows = [
            (
                _pose_words(row), _fmt(row.psnr_db.mean, ".2f"), _fmt(row.ssim.mean, ".3f"),
                _fmt(row.lpips.mean, ".3f"), _fmt(row.coverage.mean, ".2f"), row.ssim.n,
            )
            for row in ev.truth.scores
        ]  # fmt: skip
        headers = ["pose", "PSNR dB", "SSIM", "LPIPS", "coverage", "frames"]
        caption = "Validity envelope, measured: splat vs the ground truth without sensor noise"
        parts.append(ctx.table("splat_envelope", headers, rows, caption))
        fig = envelope_figure(
            ev.truth, min_psnr_db=gate.TRUTH_MIN_PSNR_DB, min_ssim=gate.TRUTH_MIN_SSIM
        )
        parts.append(_img(_figure_bytes(fig), "splat vs ground truth by lateral offset and yaw"))
        parts.append(
            f'<p class="note">Means over the same {len(ev.truth.frames)} held-out frames at each '
            "pose (of the held-out frames above): the recorded pose (on path), moved sideways or "
            "turned about the vertical. Coverage: 0 on a training view, toward 1 far from all."
            "</p>"
        )
    if ev.rig:
        rig_rows = [
            (
                row.label(), _fmt(row.psnr_db.mean, ".2f"), _fmt(row.ssim.mean, ".3f"),
                _fmt(row.coverage.mean, ".2f"), row.ssim.n,
            )
            for row in ev.rig
        ]  # fmt: skip
        on_path = ev.truth.on_path() if ev.truth is not None else None
        headers = ["camera", "PSNR dB", "SSIM", "coverage", "frames"]
        caption = (
            "Validity envelope at real pixels: the splat at the rig's other cameras, scored "
            "against what they recorded (the front camera's held-out poses moved to them)"
        )
        parts.append(ctx.table("splat_rig", headers, rig_rows, caption))
        beside = (
            f" On the path, against the ground truth: {_fmt(on_path.psnr_db.mean, '.2f')} dB."
            if on_path is not None
            else ""
        )
        parts.append(
            '<p class="note">Compare with the held-out PSNR above (the front camera, on the '
            f"path): how much the splat loses where the car was never driven.{beside}</p>"
        )
    parts += [f'<p class="note">{esc(note)}</p>' for note in ev.notes]
    parts.append(_splat_training(ctx))
    rule = (
        f"The splat quality gate: held-out PSNR &ge; {gate.HELD_OUT_MIN_PSNR_DB:g} dB and SSIM "
        f"&ge; {gate.HELD_OUT_MIN_SSIM:.2f}; against the ground truth on the path (when there is "
        f"one) PSNR &ge; {gate.TRUTH_MIN_PSNR_DB:g} dB and SSIM &ge; {gate.TRUTH_MIN_SSIM:.2f}; "
        f"at most {gate.MAX_BEYOND_ENVELOPE:.0%} of a run's frames beyond the validated envelope "
        "(docs/metrics.md)."
    )
    parts.append(f'<p class="note">{rule}</p>')
    verdicts = ctx.metrics.splat_gate if ctx.metrics is not None else []
    for v in verdicts:
        name = METHOD_LABELS.get(v.method, v.method)
        text = (
            f"{name}: unfit ({v.unfit_runs}/{v.runs} runs): {v.reason}"
            if not v.fit
            else (f"{name}: fit ({v.runs} runs)")
        )
        cls = "note" if v.fit else "warn"
        parts.append(f'<p class="{cls}"><b>{esc(text)}</b>. {esc(v.evidence)}.</p>')
    if not verdicts:
        parts.append('<p class="note">No drive with the splat camera recorded its quality.</p>')
    return "".join(parts)


def _held_out_pictures(ctx: _Context, ev: SplatEval) -> str:
    """The best, median and worst held-out frame: the real frame above the splat's render."""
    prep = ctx.ws.splat_files.prep_images_dir
    renders = ctx.ws.splat_files.renders_dir
    scored = sorted(
        (
            f
            for f in ev.frames
            if f.psnr_db is not None and (renders / f"{f.index:06d}.webp").is_file()
        ),
        key=lambda f: f.psnr_db or 0.0,
    )
    if not scored or not prep.is_dir():
        return ""
    picks = {"worst": scored[0], "median": scored[len(scored) // 2], "best": scored[-1]}
    intro = (
        '<p class="note">Held-out frames, never trained on: the recorded frame (left) and the '
        "splat's render at its pose (right), the worst, median and best by PSNR.</p>"
    )
    parts = [intro]
    for name, frame in picks.items():
        real = prep / f"{frame.index:06d}.png"
        render = renders / f"{frame.index:06d}.webp"
        try:
            pair = _side_by_side(real, render)
        except OSError as err:
            ctx.warnings.append(f"held-out frame {frame.index}: {err}")
            continue
        caption = f"{name}: frame {frame.index}, {frame.psnr_db:.1f} dB"
        img = _img(pair, caption, mime="image/jpeg")
        parts.append(f"<figure>{img}<figcaption>{esc(caption)}</figcaption></figure>")
    return "".join(parts)


def _side_by_side(left: Path, right: Path) -> bytes:
    """Two images of one size side by side, as a JPEG ``_FRAME_WIDTH`` wide."""
    import cv2  # noqa: PLC0415

    a = cv2.imread(str(left), cv2.IMREAD_COLOR)
    b = cv2.imread(str(right), cv2.IMREAD_COLOR)
    if a is None or b is None:
        msg = f"cannot read {left if a is None else right}"
        raise OSError(msg)
    if b.shape != a.shape:
        b = cv2.resize(b, (a.shape[1], a.shape[0]), interpolation=cv2.INTER_AREA)
    both = np.concatenate([a, np.full((a.shape[0], 6, 3), 255, np.uint8), b], axis=1)
    height = round(both.shape[0] * _FRAME_WIDTH / both.shape[1])
    small = cv2.resize(both, (_FRAME_WIDTH, height), interpolation=cv2.INTER_AREA)
    ok, data = cv2.imencode(".jpg", small, [cv2.IMWRITE_JPEG_QUALITY, 85])
    if not ok:
        msg = f"cannot encode {left.name} beside {right.name}"
        raise OSError(msg)
    return bytes(data.tobytes())


def _pose_words(row: TruthScore) -> str:
    """``on path``, ``1 m left``, ``0.5 m right``, ``turned 5° left``: no sign to decode."""
    if row.lateral_m:
        return f"{abs(row.lateral_m):g} m {'right' if row.lateral_m > 0 else 'left'}"
    if row.yaw_deg:
        return f"turned {abs(row.yaw_deg):g}° {'left' if row.yaw_deg > 0 else 'right'}"
    return "on path"


def _splat_training(ctx: _Context) -> str:
    """Per chunk model: its training, training curve, pose corrections and left-out pixels.

    Read from the headers (``chunk_XX.json``) and ``chunk_XX_outliers.jpg`` beside them.
    """
    models = ctx.ws.splat_files.models_dir
    rows, pictures, headers = [], [], []
    for path in sorted(models.glob("chunk_*.json")):
        try:
            header = ChunkHeader.load(path)
        except Cam2SimError as err:
            ctx.warnings.append(f"{path}: {err}")
            continue
        headers.append(header)
        sizes = pose_correction_sizes(header)
        poses = (
            "off"
            if sizes is None
            else f"{sizes[0]:.3g} / {sizes[1]:.3g} units, {sizes[2]:.2f} / {sizes[3]:.2f}°"
        )
        rows.append(
            (
                header.chunk_id, f"{header.steps:,}", header.stopped or "-",
                f"{header.n_gaussians:,}",
                "; ".join([*header.notes, "antialiased" if header.antialiased else "classic"]),
                poses,
            )
        )  # fmt: skip
        picture = outliers_path(path.with_suffix(".pt"))
        if picture.is_file():
            alt = f"chunk {header.chunk_id}: pixels the robust weighting left out (red)"
            pictures.append(
                f"<p class='note'>{esc(alt)}</p>"
                + _img(picture.read_bytes(), alt, mime="image/jpeg")
            )
    if not rows:
        return ""
    columns = ["chunk", "steps", "stopped", "Gaussians", "training", "pose corrections"]
    caption = (
        "Training, per chunk model (WS/splat/models/chunk_XX.json); pose corrections: mean / "
        "largest shift and turn of the training views' learned corrections, when refined"
    )
    table = html_table(columns, rows, caption)
    if any(h.val_history for h in headers):
        alt = "held-in PSNR and SSIM over the training steps, per chunk model"
        table += _img(_figure_bytes(training_figure(headers)), alt)
    return table + "".join(pictures)


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
    ctx = _Context(ws)
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
         lambda: _splat(ctx)),
        ("frames", "Frames, side by side", lambda: _frames(ctx)),
        ("semantic", "Semantic IoU", lambda: _semantic(ctx)),
        ("images", "Image quality", lambda: _images(ctx)),
    )  # fmt: skip
    for k, (sid, title, build) in enumerate(steps, start=2):
        body[sid] = _section(sid, title, build())
        report("report", k, total)
    body["summary"] = _section("summary", "Pipeline summary", _summary(ctx))
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
