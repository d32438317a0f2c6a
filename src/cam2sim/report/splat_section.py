"""The report's ``splat`` section: how good the splat is, and where.

Held-out scores and pictures, the validity envelope against the ground truth and at a rig's
other cameras, each chunk model's training, the splat quality gate's verdict.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from cam2sim.core.errors import Cam2SimError
from cam2sim.metrics import splat_gate as gate
from cam2sim.metrics.behaviour import (
    METHOD_LABELS,
)
from cam2sim.report.pieces import esc, html_table
from cam2sim.report.splat_figures import envelope_figure, training_figure
from cam2sim.splat.chunk_header import ChunkHeader, outliers_path, pose_correction_sizes
from cam2sim.splat.evaluate import SplatEval

if TYPE_CHECKING:
    from collections.abc import Iterable
    from pathlib import Path

    from cam2sim.core.run_record import RunRecord
    from cam2sim.metrics.summary import MetricSummary
    from cam2sim.report.context import ReportContext
    from cam2sim.splat.scores import TruthScore

from cam2sim.report.pieces import FRAME_WIDTH, figure_bytes, fmt, img, not_available

__all__ = ["splat_cell", "splat_section"]


def splat_cell(meta: RunRecord) -> str:
    """A run's splat gate verdict and driven coverage; "-" for runs without the splat camera."""
    quality, gate = meta.splat_quality, meta.splat_gate
    if quality is None or gate is None:
        return "-"
    verdict = "fit" if gate.get("fit") else "unfit"
    mean, top = quality.get("coverage_mean"), quality.get("coverage_max")
    return f"{verdict} ({fmt(mean, '.2f')} / {fmt(top, '.2f')})"


def _summary_rows(
    rows: Iterable[tuple[str, MetricSummary, str]],
) -> list[tuple[str, str, str, str, int]]:
    return [(n, fmt(s.mean, f), fmt(s.p10, f), fmt(s.p90, f), s.n) for n, s, f in rows]


def splat_section(ctx: ReportContext) -> str:
    """Held-out scores, the envelope against the ground truth (table and plot), the gate."""
    path = ctx.ws.splat_files.eval_json
    if not path.is_file():
        return not_available("Splat quality (WS/splat/eval.json)", f"cam2sim splat {ctx.ws.root}")
    try:
        ev = SplatEval.load(path)
    except Cam2SimError as err:
        ctx.warnings.append(f"{path}: {err}")
        return not_available(
            "Splat quality (eval.json unreadable)", f"cam2sim splat {ctx.ws.root} --force"
        )
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
                _pose_words(row), fmt(row.psnr_db.mean, ".2f"), fmt(row.ssim.mean, ".3f"),
                fmt(row.lpips.mean, ".3f"), fmt(row.coverage.mean, ".2f"), row.ssim.n,
            )
            for row in ev.truth.scores
        ]  # fmt: skip
        headers = ["pose", "PSNR dB", "SSIM", "LPIPS", "coverage", "frames"]
        caption = "Validity envelope, measured: splat vs the ground truth without sensor noise"
        parts.append(ctx.table("splat_envelope", headers, rows, caption))
        fig = envelope_figure(
            ev.truth, min_psnr_db=gate.TRUTH_MIN_PSNR_DB, min_ssim=gate.TRUTH_MIN_SSIM
        )
        parts.append(img(figure_bytes(fig), "splat vs ground truth by lateral offset and yaw"))
        parts.append(
            f'<p class="note">Means over the same {len(ev.truth.frames)} held-out frames at each '
            "pose (of the held-out frames above): the recorded pose (on path), moved sideways or "
            "turned about the vertical. Coverage: 0 on a training view, toward 1 far from all."
            "</p>"
        )
    if ev.rig:
        rig_rows = [
            (
                row.label(), fmt(row.psnr_db.mean, ".2f"), fmt(row.ssim.mean, ".3f"),
                fmt(row.coverage.mean, ".2f"), row.ssim.n,
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
            f" On the path, against the ground truth: {fmt(on_path.psnr_db.mean, '.2f')} dB."
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


def _held_out_pictures(ctx: ReportContext, ev: SplatEval) -> str:
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
        tag = img(pair, caption, mime="image/jpeg")
        parts.append(f"<figure>{tag}<figcaption>{esc(caption)}</figcaption></figure>")
    return "".join(parts)


def _side_by_side(left: Path, right: Path) -> bytes:
    """Two images of one size side by side, as a JPEG ``FRAME_WIDTH`` wide."""
    import cv2  # noqa: PLC0415

    a = cv2.imread(str(left), cv2.IMREAD_COLOR)
    b = cv2.imread(str(right), cv2.IMREAD_COLOR)
    if a is None or b is None:
        msg = f"cannot read {left if a is None else right}"
        raise OSError(msg)
    if b.shape != a.shape:
        b = cv2.resize(b, (a.shape[1], a.shape[0]), interpolation=cv2.INTER_AREA)
    both = np.concatenate([a, np.full((a.shape[0], 6, 3), 255, np.uint8), b], axis=1)
    height = round(both.shape[0] * FRAME_WIDTH / both.shape[1])
    small = cv2.resize(both, (FRAME_WIDTH, height), interpolation=cv2.INTER_AREA)
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


def _splat_training(ctx: ReportContext) -> str:
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
                + img(picture.read_bytes(), alt, mime="image/jpeg")
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
        table += img(figure_bytes(training_figure(headers)), alt)
    return table + "".join(pictures)
