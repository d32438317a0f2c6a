"""Training a DAVE-2 steering network on a workspace's dataset.

:func:`assemble` pairs every camera frame (``poses.csv``, or ``frames.csv`` of a pose-less
dataset) with a steering signal (``signals/<name>.csv``) interpolated at the frame's stamp;
frames outside the signal's time span are dropped. :func:`split_by_time` holds out
``val_fraction`` of the drive, as blocks of ``block_s`` seconds spread over it (or its end), and
drops the training frames within ``gap_s`` of them, so neighbouring, nearly identical frames do
not leak into validation. :func:`train_dave2` trains
with Adam and MSE, augmenting every batch on the device (:func:`augment`; with the camera's
geometry, a share of it seen from beside the recorded path with labels that steer back,
:mod:`cam2sim.ads.recovery`), stops early when the validation loss stops improving and keeps the
best epoch.

Files (written by :func:`save_training`, each atomically) in ``WS/ads/``:

- ``dave2.pt``: the state dict (``torch.save``); ``dave2.json``: :class:`Dave2ModelInfo`;
- ``train_report.json``: :class:`TrainReport`; ``train_report.png``: loss curves and
  predicted vs recorded steering over the validation frames.

This module imports torch: import it lazily.
"""

from __future__ import annotations

import io
import logging
import math
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any, Final, Literal

import cv2
import numpy as np
import pydantic
import torch

from cam2sim.ads.dave2 import Dave2Config, build_dave2, preprocess
from cam2sim.ads.recovery import RecoveryGeometry, recovery_label, recovery_views
from cam2sim.ads.train_options import TrainOptions
from cam2sim.core.errors import StageError
from cam2sim.core.files import write_bytes_atomic
from cam2sim.core.plots import pyplot, save_figure
from cam2sim.core.progress import ProgressCallback, no_progress
from cam2sim.core.schema import Artifact
from cam2sim.core.table import read_table

if TYPE_CHECKING:
    from collections.abc import Callable
    from pathlib import Path

    import numpy.typing as npt

    from cam2sim.core.workspace import DatasetPaths

__all__ = [
    "MODEL_FILE",
    "MODEL_INFO_FILE",
    "REPORT_FIGURE",
    "REPORT_FILE",
    "Dave2ModelInfo",
    "EpochRecord",
    "SteeringData",
    "TrainReport",
    "TrainedModel",
    "assemble",
    "augment",
    "load_model",
    "save_training",
    "split_by_time",
    "train_dave2",
]

logger = logging.getLogger(__name__)
MODEL_FILE: Final = "dave2.pt"
MODEL_INFO_FILE: Final = "dave2.json"
REPORT_FILE: Final = "train_report.json"
REPORT_FIGURE: Final = "train_report.png"
_LOAD_CHUNK: Final = 64


@dataclass(frozen=True)
class SteeringData:
    """Frames and labels, in time order.

    Attributes:
        frame: ``(N,)`` frame indices.
        t: ``(N,)`` seconds since the first frame.
        steering: ``(N,)`` float32 signal values at the frames.
        images: ``(N, 3, h, w)`` uint8 preprocessed network inputs.
    """

    frame: npt.NDArray[np.int64]
    t: npt.NDArray[np.float64]
    steering: npt.NDArray[np.float32]
    images: npt.NDArray[np.uint8]

    def take(self, rows: npt.NDArray[np.int64]) -> SteeringData:
        """The subset ``rows``."""
        return SteeringData(self.frame[rows], self.t[rows], self.steering[rows], self.images[rows])


class EpochRecord(pydantic.BaseModel):
    """Losses of one epoch (MSE in the signal's unit squared)."""

    model_config = pydantic.ConfigDict(frozen=True, extra="forbid")

    epoch: int
    train_loss: float
    val_loss: float | None
    """None when nothing was held out (:attr:`TrainReport.validated` False)."""
    seconds: float


class RecoveryRecord(pydantic.BaseModel):
    """How the recovery views were made (:mod:`cam2sim.ads.recovery`)."""

    model_config = pydantic.ConfigDict(extra="forbid", frozen=True)

    camera_height_m: float
    pitch_deg: float
    curvature_per_unit: float
    max_lateral_m: float
    max_yaw_deg: float
    lookahead_m: float
    share: float


class TrainReport(Artifact):
    """``train_report.json``: what was trained on and how well it fits the held-out frames.

    ``baseline_mse`` is the validation variance (the MSE of always predicting the mean), so a
    useful model has ``val_mse`` well below it. Without a validated run (``validated`` False)
    those figures are None.
    """

    signal: str
    device: str
    train_frames: int
    val_frames: int
    best_epoch: int
    epochs: tuple[EpochRecord, ...]
    val_mse: float | None
    val_rmse: float | None
    val_mae: float | None
    val_correlation: float | None
    baseline_mse: float | None
    shift_steering_per_px: float
    recovery: RecoveryRecord | None = None
    refit_all_frames: bool = False
    """The kept network was trained again on every frame for ``best_epoch`` epochs
    (:attr:`TrainOptions.refit_all`); the validation figures are the validated run's."""
    validated: bool = True
    """False: no run was validated (:attr:`TrainOptions.validate`); the ``val_*`` figures and
    ``baseline_mse`` are None, and so is each epoch's ``val_loss``."""


class Dave2ModelInfo(Artifact):
    """``dave2.json``: what ``dave2.pt`` needs to be rebuilt."""

    config: Dave2Config
    signal: str


@dataclass(frozen=True)
class TrainedModel:
    """A trained network, its report and what the report plot needs."""

    model: torch.nn.Module
    info: Dave2ModelInfo
    report: TrainReport
    val_t: npt.NDArray[np.float64]
    val_true: npt.NDArray[np.float32]
    val_pred: npt.NDArray[np.float32]


# --------------------------------------------------------------------------------------------
# Data


def _frame_times(paths: DatasetPaths) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.int64]]:
    source = paths.poses_csv if paths.poses_csv.is_file() else paths.frames_csv
    if not source.is_file():
        msg = f"the dataset at {paths.root} has no camera frames (no poses.csv or frames.csv)"
        raise StageError(msg)
    table = read_table(source)
    return table["frame"].astype(np.int64), table["stamp_ns"].astype(np.int64)


def _signal_at(
    paths: DatasetPaths, name: str, stamps: npt.NDArray[np.int64]
) -> npt.NDArray[np.float64]:
    path = paths.signal_file(name)
    if not path.is_file():
        have = sorted(p.stem for p in paths.signals_dir.glob("*.csv"))
        msg = (
            f"the dataset has no steering signal {name!r}; available: "
            f"{', '.join(have) or 'none'}. Pick one with --signal NAME, or map the steering "
            "topic in config.yaml (topics.signals) and re-run `cam2sim extract`"
        )
        raise StageError(msg)
    table = read_table(path)
    sig_ns, value = table["stamp_ns"].astype(np.int64), table["value"].astype(np.float64)
    order = np.argsort(sig_ns, kind="stable")
    sig_ns, value = sig_ns[order], value[order]
    ok = np.isfinite(value)
    if ok.sum() < 2:
        msg = f"signal {name!r} has fewer than 2 finite samples; it cannot label frames"
        raise StageError(msg)
    t0 = int(min(sig_ns[0], stamps.min()))
    st, vt = (sig_ns[ok] - t0).astype(np.float64), value[ok]
    x = (stamps - t0).astype(np.float64)
    out = np.interp(x, st, vt)
    out[(x < st[0]) | (x > st[-1])] = np.nan
    return out


def assemble(
    paths: DatasetPaths,
    frame_format: str,
    options: TrainOptions,
    progress: ProgressCallback = no_progress,
) -> SteeringData:
    """Every frame with the steering signal at its stamp, preprocessed, in time order.

    Raises:
        StageError: No frames, no such signal (the message lists the available ones), a frame
            that cannot be read, or fewer than 10 labelled frames.
    """
    frame, stamps = _frame_times(paths)
    order = np.argsort(stamps, kind="stable")
    frame, stamps = frame[order], stamps[order]
    value = _signal_at(paths, options.signal, stamps)
    keep = np.isfinite(value)
    if keep.sum() < 10:
        msg = (
            f"only {int(keep.sum())} frames lie within the time span of signal "
            f"{options.signal!r}; training needs at least 10"
        )
        raise StageError(msg)
    if not keep.all():
        logger.info("%d frames lie outside the signal's span; dropped", int((~keep).sum()))
    frame, stamps, value = frame[keep], stamps[keep], value[keep]

    def load(i: int) -> npt.NDArray[np.uint8]:
        path = paths.frame_file(int(i), frame_format)
        bgr = cv2.imread(str(path), cv2.IMREAD_COLOR)
        if bgr is None:
            msg = f"cannot read frame {path}; re-run `cam2sim extract`"
            raise StageError(msg)
        return np.asarray(cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB), dtype=np.uint8)

    def chunk(start: int) -> npt.NDArray[np.uint8]:
        rgb = np.stack([load(i) for i in frame[start : start + _LOAD_CHUNK]])
        return preprocess(rgb, options.dave2).astype(np.uint8)

    n = len(frame)
    starts = range(0, n, _LOAD_CHUNK)
    images = []
    progress("loading frames", 0, n)
    with ThreadPoolExecutor(max_workers=options.workers) as pool:
        for start, part in zip(starts, pool.map(chunk, starts), strict=True):
            images.append(part)
            progress("loading frames", min(start + _LOAD_CHUNK, n), n)
    return SteeringData(
        frame,
        (stamps - stamps[0]).astype(np.float64) / 1e9,
        value.astype(np.float32),
        np.concatenate(images),
    )


def split_by_time(
    t: npt.NDArray[np.float64],
    val_fraction: float,
    gap_s: float,
    *,
    split: Literal["blocks", "tail"] = "tail",
    block_s: float = 4.0,
) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.int64]]:
    """Training and validation rows, with a gap between them.

    Args:
        t: ``(N,)`` increasing times, seconds.
        val_fraction: Share of the frames held out.
        gap_s: Training frames within this many seconds of a validation frame are dropped.
        split: ``tail``: the last ``val_fraction`` of the frames validates. ``blocks``: the
            drive is cut into blocks of ``block_s`` seconds and every ``k``-th block validates
            (``k = round(1 / val_fraction)``, starting with block ``k // 2``); a drive too
            short for one such block falls back to ``tail``.
        block_s: Block length, seconds.

    Raises:
        StageError: Fewer than 2 frames remain on either side.
    """
    n = len(t)
    is_val = np.zeros(n, dtype=bool)
    if split == "blocks" and n:
        k = max(2, round(1.0 / val_fraction))
        block = np.floor((t - t[0]) / block_s).astype(np.int64)
        is_val = block % k == k // 2
    if not is_val.any():
        is_val[min(n - 1, max(1, round(n * (1.0 - val_fraction)))) :] = True
    val = np.flatnonzero(is_val).astype(np.int64)
    # Time from each frame to the nearest validation frame (the one before it or after it).
    vt = t[val] if len(val) else np.array([np.inf])
    after = np.minimum(np.searchsorted(vt, t), len(vt) - 1)
    near = np.minimum(np.abs(t - vt[np.maximum(after - 1, 0)]), np.abs(t - vt[after]))
    train = np.flatnonzero(~is_val & (near > gap_s)).astype(np.int64)
    if len(train) < 2 or len(val) < 2:
        msg = (
            f"{n} frames leave {len(train)} for training and {len(val)} for validation "
            f"(val_fraction {val_fraction}, split {split}, gap {gap_s} s); record more or "
            "lower the gap"
        )
        raise StageError(msg)
    return train, val


# --------------------------------------------------------------------------------------------
# Augmentation


def augment(
    x: torch.Tensor,
    y: torch.Tensor,
    generator: torch.Generator,
    *,
    shift_px: int,
    steering_per_px: float,
    flip: bool,
    blur_px: float = 0.0,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Randomly brightened, shadowed, shifted (flipped, softened) copies of a batch.

    Args:
        x: ``(B, 3, h, w)`` float pixels in ``[0, 255]``.
        y: ``(B,)`` steering.
        generator: Random source (on ``x``'s device).
        shift_px: Largest horizontal shift, pixels (edges are repeated).
        steering_per_px: Label change per pixel of shift to the right (sign included).
        flip: Mirror half the images and negate their steering.
        blur_px: Largest blur sigma (pixels) of half the images, which also lose up to 40 %
            of their contrast; 0: none.

    Returns:
        The augmented ``x`` and ``y``.
    """
    b, _, h, w = x.shape
    dev = x.device

    def uniform(lo: float, hi: float, *shape: int) -> torch.Tensor:
        return lo + (hi - lo) * torch.rand(*shape, generator=generator, device=dev)

    # Brightness: one gain per image.
    x = x * uniform(0.6, 1.3, b, 1, 1, 1)
    # Shadow: a slanted band (edges from x1 at the top to x2 at the bottom), darkened, on half.
    rows = torch.linspace(0.0, 1.0, h, device=dev).view(1, h, 1)
    cols = torch.arange(w, device=dev, dtype=x.dtype).view(1, 1, w)
    x1, x2 = uniform(0, w, b, 1, 1), uniform(0, w, b, 1, 1)
    left = x1 + (x2 - x1) * rows
    inside = (cols >= left) & (cols < left + uniform(0.15 * w, 0.5 * w, b, 1, 1))
    shade = torch.where(uniform(0, 1, b, 1, 1) < 0.5, uniform(0.4, 0.8, b, 1, 1), 1.0)
    x = x * torch.where(inside, shade, 1.0).unsqueeze(1)
    # Shift: content moves right by d pixels; the label follows.
    if shift_px > 0:
        d = torch.randint(-shift_px, shift_px + 1, (b,), generator=generator, device=dev)
        src = (torch.arange(w, device=dev).view(1, w) - d.view(b, 1)).clamp(0, w - 1)
        x = torch.gather(x, 3, src.view(b, 1, 1, w).expand(b, 3, h, w))
        y = y + steering_per_px * d.to(y.dtype)
    if flip:
        mirror = uniform(0, 1, b) < 0.5
        x = torch.where(mirror.view(b, 1, 1, 1), x.flip(3), x)
        y = torch.where(mirror, -y, y)
    if blur_px > 0:
        soft = uniform(0, 1, b) < 0.5
        x = torch.where(soft.view(b, 1, 1, 1), _soften(x, uniform, blur_px), x)
    return x.clamp(0.0, 255.0), y


_BLUR_LEVELS: Final = 4
"""Blur sigmas drawn per batch: each image gets one of this many, evenly up to the largest."""


def _soften(x: torch.Tensor, uniform: Callable[..., torch.Tensor], blur_px: float) -> torch.Tensor:
    """``x`` blurred (one of a few sigmas up to ``blur_px`` each) and its contrast cut."""
    import torch.nn.functional as F  # noqa: N812, PLC0415

    b, c, h, w = x.shape
    level = (uniform(0, 1, b) * _BLUR_LEVELS).long().clamp(max=_BLUR_LEVELS - 1)
    out = x.clone()
    for k in range(1, _BLUR_LEVELS):  # a few kernel sizes, each applied to its images at once
        rows = torch.nonzero(level == k).view(-1)
        if len(rows) == 0:
            continue
        sigma = blur_px * k / (_BLUR_LEVELS - 1)
        radius = max(1, math.ceil(2.5 * sigma))
        taps = torch.arange(-radius, radius + 1, device=x.device, dtype=x.dtype)
        kernel = torch.exp(-0.5 * (taps / sigma) ** 2)
        kernel = kernel / kernel.sum()
        part = x[rows].reshape(-1, 1, h, w)
        part = F.conv2d(
            F.pad(part, (radius, radius, 0, 0), mode="replicate"), kernel.view(1, 1, 1, -1)
        )
        part = F.conv2d(
            F.pad(part, (0, 0, radius, radius), mode="replicate"), kernel.view(1, 1, -1, 1)
        )
        out[rows] = part.reshape(len(rows), c, h, w)
    mean = out.mean(dim=(1, 2, 3), keepdim=True)
    return mean + (out - mean) * uniform(0.6, 1.0, b, 1, 1, 1)


# --------------------------------------------------------------------------------------------
# Training


def _device(name: str | None) -> torch.device:
    if name is not None:
        return torch.device(name)
    return torch.device("cuda" if torch.cuda.is_available() else "cpu")


def _predict(
    model: torch.nn.Module, images: npt.NDArray[np.uint8], device: torch.device, batch: int
) -> npt.NDArray[np.float32]:
    model.eval()
    out = []
    with torch.inference_mode():
        for s in range(0, len(images), batch):
            x = torch.from_numpy(images[s : s + batch]).to(device, torch.float32)
            out.append(model(x).view(-1).cpu().numpy())
    return np.concatenate(out).astype(np.float32)


def _mse(pred: npt.NDArray[np.float32], true: npt.NDArray[np.float32]) -> float:
    return float(np.mean((pred.astype(np.float64) - true) ** 2))


def train_dave2(
    data: SteeringData,
    options: TrainOptions | None = None,
    progress: ProgressCallback = no_progress,
    *,
    geometry: RecoveryGeometry | None = None,
) -> TrainedModel:
    """Train DAVE-2 on ``data`` (time-ordered) with a time split, augmentation, early stopping.

    With the camera ``geometry`` (and ``options.recovery_m > 0``), a share of every batch is
    shown from beside and askew of the recorded path with labels that steer back
    (:mod:`cam2sim.ads.recovery`) instead of the horizontal shift.

    Raises:
        StageError: Too few frames for the split, or constant steering.
    """
    opts = options or TrainOptions()
    torch.manual_seed(opts.seed)
    device = _device(opts.device)
    train, val = data, None  # without validation: only the network the refit would keep
    if opts.validate:
        train_rows, val_rows = split_by_time(
            data.t, opts.val_fraction, opts.gap_s, split=opts.split, block_s=opts.block_s
        )
        train, val = data.take(train_rows), data.take(val_rows)
    spread = float(np.std(train.steering))
    if not spread > 0:
        msg = f"signal {opts.signal!r} is constant over the training frames; nothing to learn"
        raise StageError(msg)
    # Tiny gradients turn subnormal on CPU and slow every step ~10x; flush them while training.
    flush = device.type == "cpu" and torch.set_flush_denormal(True)
    try:
        recovery = geometry if opts.uses_recovery else None
        if val is None:
            kept = _fit_every_frame(data, opts, opts.epochs, device, progress, recovery)
            return _not_validated(kept, train_frames=len(data.t))
        model = build_dave2(opts.dave2).to(device)
        model.get_buffer("output_scale").fill_(spread)
        trained = _fit(model, train, val, opts, device, progress, recovery)
        if not opts.refit_all:
            return trained
        return _refit(trained, data, opts, device, progress, recovery)
    finally:
        if flush:
            torch.set_flush_denormal(False)  # the default


def _fit(
    model: torch.nn.Module,
    train: SteeringData,
    val: SteeringData,
    opts: TrainOptions,
    device: torch.device,
    progress: ProgressCallback,
    recovery: RecoveryGeometry | None,
) -> TrainedModel:
    spread = float(np.std(train.steering))
    per_px = opts.shift_steering_per_px
    if per_px is None:
        per_px = 0.004 * float(np.percentile(np.abs(train.steering), 95))
    rng = np.random.default_rng(opts.seed)
    n_train = len(train.frame)
    optimizer = torch.optim.Adam(
        model.parameters(), lr=opts.learning_rate, weight_decay=opts.weight_decay
    )
    generator = torch.Generator(device=device).manual_seed(opts.seed)
    x_all = torch.from_numpy(train.images).to(device)
    y_all = torch.from_numpy(train.steering).to(device)
    records: list[EpochRecord] = []
    best = (math.inf, 0, {k: v.clone() for k, v in model.state_dict().items()})
    progress("training DAVE-2", 0, opts.epochs)
    for epoch in range(1, opts.epochs + 1):
        started = _now()
        model.train()
        total = 0.0
        order = epoch_order(train.steering, opts.balance, rng)
        for rows in np.array_split(order, max(1, n_train // opts.batch_size)):
            idx = torch.from_numpy(rows).to(device)
            x, y = x_all[idx].to(torch.float32), y_all[idx]
            if recovery is not None:
                x, y = _displace(x, y, rng, recovery, opts)
            if opts.augment:
                shift = 0 if recovery is not None else opts.shift_px
                x, y = augment(
                    x, y, generator, shift_px=shift, steering_per_px=-per_px, flip=opts.flip,
                    blur_px=opts.blur_px,
                )  # fmt: skip
            loss = torch.nn.functional.mse_loss(model(x).view(-1) / spread, y / spread)
            optimizer.zero_grad(set_to_none=True)
            loss.backward()  # type: ignore[no-untyped-call]
            optimizer.step()
            total += float(loss.detach()) * len(rows)
        val_loss = _mse(_predict(model, val.images, device, opts.batch_size), val.steering)
        records.append(
            EpochRecord(
                epoch=epoch,
                train_loss=total / n_train * spread**2,
                val_loss=val_loss,
                seconds=_now() - started,
            )
        )
        logger.info("epoch %d: train %.4g, val %.4g", epoch, records[-1].train_loss, val_loss)
        progress("training DAVE-2", epoch, opts.epochs)
        if val_loss < best[0] or opts.keep == "last":
            best = (val_loss, epoch, {k: v.clone() for k, v in model.state_dict().items()})
        elif epoch - best[1] >= opts.patience:
            logger.info("validation loss stalled for %d epochs; stopping", opts.patience)
            break
    model.load_state_dict(best[2])
    model.eval()
    pred = _predict(model, val.images, device, opts.batch_size)
    report = _report(opts, str(device), records, best[1], pred, val.steering, n_train)
    update: dict[str, Any] = {"shift_steering_per_px": 0.0 if recovery else per_px}
    if recovery is not None:
        update["recovery"] = RecoveryRecord(
            camera_height_m=recovery.height_m,
            pitch_deg=math.degrees(recovery.pitch_rad),
            curvature_per_unit=recovery.curvature_per_unit,
            max_lateral_m=opts.recovery_m,
            max_yaw_deg=opts.recovery_deg,
            lookahead_m=opts.recovery_lookahead_m,
            share=opts.recovery_share,
        )
    report = report.model_copy(update=update)
    info = Dave2ModelInfo(config=opts.dave2, signal=opts.signal)
    return TrainedModel(model.cpu(), info, report, val.t, val.steering, pred)


BALANCE_BINS = 15
"""Equal-width bins of the training steering's range that :attr:`TrainOptions.balance` evens."""


def epoch_order(
    steering: npt.NDArray[np.floating[Any]], balance: float, rng: np.random.Generator
) -> npt.NDArray[np.int64]:
    """The frames of one epoch: a permutation, or with ``balance`` a draw favouring rare steering.

    The draw has as many frames as there are, with replacement, each frame weighted by
    ``count(its bin) ** -balance`` over :data:`BALANCE_BINS` equal bins of the range.
    """
    n = len(steering)
    if balance <= 0 or n < 2 or not np.ptp(steering) > 0:
        return rng.permutation(n).astype(np.int64)
    edges = np.linspace(float(np.min(steering)), float(np.max(steering)), BALANCE_BINS + 1)
    bins = np.clip(np.searchsorted(edges, steering, side="right") - 1, 0, BALANCE_BINS - 1)
    counts = np.bincount(bins, minlength=BALANCE_BINS).astype(np.float64)
    weights = counts[bins] ** -balance
    return rng.choice(n, size=n, replace=True, p=weights / weights.sum()).astype(np.int64)


def _refit(
    trained: TrainedModel,
    data: SteeringData,
    opts: TrainOptions,
    device: torch.device,
    progress: ProgressCallback,
    recovery: RecoveryGeometry | None,
) -> TrainedModel:
    """A fresh network trained on every frame for the validated run's kept epochs."""
    refit = _fit_every_frame(data, opts, trained.report.best_epoch, device, progress, recovery)
    report = trained.report.model_copy(update={"refit_all_frames": True})
    return replace(
        refit,
        report=report,
        val_t=trained.val_t,
        val_true=trained.val_true,
        val_pred=trained.val_pred,
    )


def _fit_every_frame(
    data: SteeringData,
    opts: TrainOptions,
    epochs: int,
    device: torch.device,
    progress: ProgressCallback,
    recovery: RecoveryGeometry | None,
) -> TrainedModel:
    """A fresh network (seeded as the first) trained on every frame for ``epochs``, the last kept.

    Its report's validation figures come from a token set of two frames and mean nothing.
    """
    torch.manual_seed(opts.seed)
    model = build_dave2(opts.dave2).to(device)
    model.get_buffer("output_scale").fill_(float(np.std(data.steering)))
    again = replace(opts, epochs=epochs, keep="last")

    def report_all(task: str, completed: int, total: int | None) -> None:
        del task  # one name for the training on every frame
        progress("training DAVE-2 on every frame", completed, total)

    some = data.take(np.arange(min(2, len(data.t))))  # no frame is held out: a token set
    return _fit(model, data, some, again, device, report_all, recovery)


def _not_validated(kept: TrainedModel, *, train_frames: int) -> TrainedModel:
    """``kept`` with a report that says nothing was validated (no figures pretend it was)."""
    epochs = tuple(r.model_copy(update={"val_loss": None}) for r in kept.report.epochs)
    report = kept.report.model_copy(
        update={
            "train_frames": train_frames,
            "val_frames": 0,
            "epochs": epochs,
            "val_mse": None,
            "val_rmse": None,
            "val_mae": None,
            "val_correlation": None,
            "baseline_mse": None,
            "refit_all_frames": True,
            "validated": False,
        }
    )
    empty = np.zeros(0)
    return replace(
        kept,
        report=report,
        val_t=empty,
        val_true=empty.astype(np.float32),
        val_pred=empty.astype(np.float32),
    )


def _displace(
    x: torch.Tensor,
    y: torch.Tensor,
    rng: np.random.Generator,
    geometry: RecoveryGeometry,
    opts: TrainOptions,
) -> tuple[torch.Tensor, torch.Tensor]:
    """A random ``recovery_share`` of the batch seen displaced, with steer-back labels."""
    pick = np.flatnonzero(rng.random(len(y)) < opts.recovery_share)
    if len(pick) == 0:
        return x, y
    lateral = rng.uniform(-opts.recovery_m, opts.recovery_m, len(pick))
    yaw = np.radians(rng.uniform(-opts.recovery_deg, opts.recovery_deg, len(pick)))
    rows = torch.from_numpy(pick).to(x.device)
    x, y = x.clone(), y.clone()
    x[rows] = recovery_views(x[rows], geometry, opts.dave2, lateral, yaw)
    label = recovery_label(
        y[rows].cpu().numpy(),
        lateral,
        yaw,
        lookahead_m=opts.recovery_lookahead_m,
        curvature_per_unit=geometry.curvature_per_unit,
    )
    y[rows] = torch.from_numpy(label).to(y)
    return x, y


def _now() -> float:
    import time  # noqa: PLC0415

    return time.perf_counter()


def _report(
    opts: TrainOptions,
    device: str,
    records: list[EpochRecord],
    best_epoch: int,
    pred: npt.NDArray[np.float32],
    true: npt.NDArray[np.float32],
    n_train: int,
) -> TrainReport:
    err = pred.astype(np.float64) - true
    mse = float(np.mean(err**2))
    corr = None
    if np.std(pred) > 0 and np.std(true) > 0:
        corr = float(np.corrcoef(pred, true)[0, 1])
    return TrainReport(
        signal=opts.signal,
        device=device,
        train_frames=n_train,
        val_frames=len(true),
        best_epoch=best_epoch,
        epochs=tuple(records),
        val_mse=mse,
        val_rmse=math.sqrt(mse),
        val_mae=float(np.mean(np.abs(err))),
        val_correlation=corr,
        baseline_mse=float(np.var(true.astype(np.float64))),
        shift_steering_per_px=0.0,
    )


# --------------------------------------------------------------------------------------------
# Files


def save_training(trained: TrainedModel, ads_dir: Path) -> None:
    """Write the model, its info, the report and the report figure into ``ads_dir``."""
    buffer = io.BytesIO()
    torch.save(trained.model.state_dict(), buffer)
    write_bytes_atomic(ads_dir / MODEL_FILE, buffer.getvalue())
    trained.info.save(ads_dir / MODEL_INFO_FILE)
    trained.report.save(ads_dir / REPORT_FILE)
    _figure(trained, ads_dir / REPORT_FIGURE)


def load_model(ads_dir: Path) -> tuple[torch.nn.Module, Dave2ModelInfo]:
    """The trained network (eval mode, CPU) and its info from ``ads_dir``.

    Raises:
        StageError: No trained model there.
    """
    weights, info_path = ads_dir / MODEL_FILE, ads_dir / MODEL_INFO_FILE
    if not weights.is_file() or not info_path.is_file():
        msg = f"no trained model in {ads_dir}; run `cam2sim ads train` first"
        raise StageError(msg)
    info = Dave2ModelInfo.load(info_path)
    model = build_dave2(info.config)
    try:
        state = torch.load(io.BytesIO(weights.read_bytes()), map_location="cpu", weights_only=True)
        model.load_state_dict(state)
    except (RuntimeError, ValueError, KeyError) as err:
        msg = f"cannot load {weights} ({err}); re-run `cam2sim ads train --force`"
        raise StageError(msg) from err
    return model.eval(), info


def _figure(trained: TrainedModel, path: Path) -> None:
    plt = pyplot()
    report = trained.report
    if not report.validated:
        fig, ax = plt.subplots(figsize=(9, 3.5))
        epochs = [r.epoch for r in report.epochs]
        ax.plot(epochs, [r.train_loss for r in report.epochs], "o-", label="training")
        ax.set(
            xlabel="epoch",
            ylabel=f"MSE ({report.signal} unit²)",
            title="DAVE-2 trained on every frame (not validated: no frame held out)",
        )
        ax.set_yscale("log")
        ax.legend()
        fig.tight_layout()
        save_figure(fig, path)
        return
    fig, (ax_loss, ax_val) = plt.subplots(2, 1, figsize=(9, 7))
    epochs = [r.epoch for r in report.epochs]
    ax_loss.plot(epochs, [r.train_loss for r in report.epochs], "o-", label="training")
    # A validated report has every validation figure (None only when validated is False).
    assert report.baseline_mse is not None
    assert report.val_rmse is not None
    assert report.val_mae is not None
    val_loss = [math.nan if r.val_loss is None else r.val_loss for r in report.epochs]
    ax_loss.plot(epochs, val_loss, "o-", label="validation")
    ax_loss.axhline(report.baseline_mse, color="grey", ls="--", label="validation variance")
    ax_loss.axvline(report.best_epoch, color="k", lw=0.8, ls=":", label="kept epoch")
    ax_loss.set(xlabel="epoch", ylabel=f"MSE ({report.signal} unit²)", title="DAVE-2 training")
    ax_loss.set_yscale("log")
    ax_loss.legend()
    ax_val.plot(trained.val_t, trained.val_true, label="recorded", lw=1.2)
    ax_val.plot(trained.val_t, trained.val_pred, label="predicted", lw=1.2)
    ax_val.set(
        xlabel="time since the first frame (s)",
        ylabel=report.signal,
        title=f"validation frames: RMSE {report.val_rmse:.3g}, MAE {report.val_mae:.3g}",
    )
    ax_val.legend()
    fig.tight_layout()
    save_figure(fig, path)
