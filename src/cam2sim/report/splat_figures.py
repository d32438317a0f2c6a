"""The splat's figures: the validity envelope against the truth, the chunks' training curves."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from cam2sim.core.plots import pyplot

if TYPE_CHECKING:
    from collections.abc import Sequence

    from cam2sim.splat.chunk_header import ChunkHeader
    from cam2sim.splat.evaluate import MetricSummary, TruthEnvelope

__all__ = ["envelope_figure", "training_figure"]


def envelope_figure(
    envelope: TruthEnvelope, *, min_psnr_db: float | None = None, min_ssim: float | None = None
) -> Any:  # a matplotlib Figure (matplotlib is imported lazily)
    """PSNR, SSIM (and LPIPS when measured) against the truth, one panel each.

    Lateral offsets are a line (mean, with the p10-p90 band), yaw turns triangles beside
    offset 0 pointing the way they turn, the gate's thresholds dashed lines.

    Args:
        envelope: ``eval.json``'s ``truth`` section.
        min_psnr_db: The gate's PSNR threshold (drawn when given).
        min_ssim: The gate's SSIM threshold (drawn when given).
    """
    import numpy as np  # noqa: PLC0415

    metrics: list[tuple[str, str, float | None]] = [
        ("psnr_db", "PSNR (dB)", min_psnr_db),
        ("ssim", "SSIM", min_ssim),
    ]
    if any(row.lpips.mean is not None for row in envelope.scores):
        metrics.append(("lpips", "LPIPS (lower is better)", None))
    # Drawn with + = left, as every lateral offset in the reports (eval.json keeps + = right).
    lateral = sorted((r for r in envelope.scores if r.yaw_deg == 0.0), key=lambda r: -r.lateral_m)
    turns = [r for r in envelope.scores if r.yaw_deg != 0.0]
    fig, axes = pyplot().subplots(1, len(metrics), figsize=(4.0 * len(metrics), 3.2))
    for ax, (key, title, threshold) in zip(np.atleast_1d(axes), metrics, strict=True):
        stats: list[MetricSummary] = [getattr(r, key) for r in lateral]
        x = [-r.lateral_m for r in lateral]
        mean = [np.nan if s.mean is None else s.mean for s in stats]
        low = [np.nan if s.p10 is None else s.p10 for s in stats]
        high = [np.nan if s.p90 is None else s.p90 for s in stats]
        ax.fill_between(x, low, high, color="#9ecae1", alpha=0.5, lw=0, label="p10-p90")
        ax.plot(x, mean, "o-", color="#08519c", label="lateral offset (mean)")
        for row in turns:  # a left turn (+) points left, beside the on-path point
            value = getattr(row, key).mean
            left = row.yaw_deg > 0
            if value is not None:
                ax.plot(
                    [0.1 if left else -0.1], [value], ">" if left else "<", color="#d94801",
                    ms=8, label=row.label(),
                )  # fmt: skip
        if threshold is not None:
            ax.axhline(threshold, color="0.4", ls="--", lw=1, label="gate")
        ax.set_title(title, fontsize=10)
        ax.set_xlabel("lateral offset (m), + = left of the path")
        ax.grid(alpha=0.3)
    np.atleast_1d(axes)[0].legend(fontsize=7, loc="best")
    fig.suptitle(
        f"Splat vs ground truth (no sensor noise), {len(envelope.frames)} of the held-out frames",
        fontsize=10,
    )
    fig.tight_layout()
    return fig


def training_figure(headers: Sequence[ChunkHeader]) -> Any:  # a matplotlib Figure
    """Held-in PSNR and SSIM over the training steps, a line per chunk model.

    From each header's ``val_history`` (the validations on training views); chunks without one
    (models trained before it was recorded) are left out. A curve still rising at its end
    wants more steps; one that jumps about late in the run, lower learning rates there.
    """
    fig, axes = pyplot().subplots(1, 2, figsize=(8.0, 3.2))
    for header in headers:
        if not header.val_history:
            continue
        steps, psnr, ssim = zip(*header.val_history, strict=True)
        label = f"chunk {header.chunk_id}"
        axes[0].plot(steps, psnr, ".-", lw=1, ms=3, label=label)
        axes[1].plot(steps, ssim, ".-", lw=1, ms=3, label=label)
    for ax, title in zip(axes, ("held-in PSNR (dB)", "held-in SSIM"), strict=True):
        ax.set_title(title, fontsize=10)
        ax.set_xlabel("training step")
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=7, loc="lower right")
    fig.suptitle("Training: validation on training views, per chunk model", fontsize=10)
    fig.tight_layout()
    return fig
