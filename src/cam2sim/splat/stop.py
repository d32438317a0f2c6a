"""When a chunk's training stops: its held-in plateau, its time share, its step cap.

The trainer validates every ``val_every`` steps and stops a chunk once it has trained
``min_steps`` and :func:`plateau_reached` says its held-in PSNR and SSIM trends fall below their
minimum gains, at ``max_steps`` otherwise, or when its share of a time budget
(:func:`time_share`) is spent: :func:`steps_that_fit` turns that share into a step cap at the
chunk's recent pace. A chunk whose training has diverged (:func:`diverged`) stops with an error
instead, and nothing is written for it.
"""

from __future__ import annotations

import numpy as np

__all__ = ["DIVERGED_SHARE", "diverged", "plateau_reached", "steps_that_fit", "time_share"]

DIVERGED_SHARE = 0.5
"""A chunk whose gradients were NaN or inf on more than this share of its steps has diverged.
Such steps are kept out of the model (a stray one is harmless, :mod:`cam2sim.splat.optim`);
on most of them, the model is no longer learning from its frames."""


def diverged(non_finite_steps: int, steps: int, psnr_db: float) -> bool:
    """Whether training has diverged: mostly non-finite gradients, or a non-finite PSNR.

    Args:
        non_finite_steps: Steps so far whose gradients had NaN or inf values.
        steps: Steps so far.
        psnr_db: The latest held-in PSNR.
    """
    return not np.isfinite(psnr_db) or non_finite_steps > DIVERGED_SHARE * max(steps, 1)


def plateau_reached(
    history: list[tuple[int, float, float]],
    patience: int,
    min_gain_db: float,
    min_gain_ssim: float,
) -> bool:
    """Whether held-in quality has plateaued: the stopping rule of training.

    Args:
        history: ``(step, psnr_db, ssim)`` of the validations so far, in order.
        patience: Validation intervals in the trend; fewer than ``patience + 1`` validations
            never plateau.
        min_gain_db: PSNR trend (least-squares slope, dB per 1,000 steps) that still counts as
            progress.
        min_gain_ssim: SSIM trend per 1,000 steps that still counts as progress.

    Returns:
        True when neither the PSNR nor the SSIM trend over the last ``patience + 1``
        validations reaches its minimum gain.
    """
    window = history[-(patience + 1) :]
    if len(window) < max(patience + 1, 2):  # a trend needs two points
        return False
    steps = np.array([w[0] for w in window], dtype=np.float64) / 1000.0
    psnr_trend = float(np.polyfit(steps, [w[1] for w in window], 1)[0])
    ssim_trend = float(np.polyfit(steps, [w[2] for w in window], 1)[0])
    return psnr_trend < min_gain_db and ssim_trend < min_gain_ssim


def time_share(
    budget_s: float | None, n_chunks: int, slots: int, *, per_chunk: bool = False
) -> float | None:
    """Seconds each of ``n_chunks`` chunks may train so that all end within ``budget_s``.

    The chunks train ``slots`` at a time, a new one starting when one ends; with chunks of about
    equal cost they run in ``ceil(n_chunks / slots)`` rounds, and each gets one round's share.

    Args:
        budget_s: Seconds for all of them, or None (no budget).
        n_chunks: Chunks to train.
        slots: Chunks trained at the same time (1 = one after another or interleaved).
        per_chunk: ``budget_s`` is already each chunk's (``TrainOptions.budget_per_chunk``).

    Returns:
        Each chunk's seconds, or None without a budget.
    """
    if budget_s is None or per_chunk:
        return budget_s
    rounds = -(-max(1, n_chunks) // max(1, min(slots, n_chunks)))
    return budget_s / rounds


def steps_that_fit(step: int, seconds: float, share_s: float, mark: tuple[int, float]) -> int:
    """The step at which a chunk's time share runs out, at its pace since ``mark``.

    Args:
        step: Steps done.
        seconds: Seconds spent in them.
        share_s: The chunk's time share.
        mark: ``(step, seconds)`` at the start of the interval that sets the pace (the last
            validation): the pace of a step grows with the Gaussians, so the recent one counts.

    Returns:
        The last step that fits (at least ``step + 1``; the caller stops on a spent share).
    """
    steps, spent = step - mark[0], seconds - mark[1]
    if steps <= 0 or spent <= 0:
        return step + 1
    return step + max(1, int((share_s - seconds) * steps / spent))
