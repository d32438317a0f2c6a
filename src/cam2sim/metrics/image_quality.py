"""Image quality of simulated frames against the real ones: PSNR, SSIM and LPIPS.

Two folders are paired by file stem (``000123.png`` with ``000123.jpg``). Each pair is scored
with PSNR (dB), SSIM (Wang et al. 2004, Gaussian window) and LPIPS (:mod:`cam2sim.metrics.lpips`),
optionally over part of the image only: a per-frame mask folder (sky masks) and an ego-hood mask
(bottom rows or one mask image) exclude pixels from every metric. The per-image scores and their
summary (mean, population std, count) are written as a schema-versioned JSON artifact and a CSV.

This module also holds the folder and mask helpers that :mod:`cam2sim.metrics.semantic` shares.
"""

from __future__ import annotations

import csv
import io
import logging
import math
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Final

import numpy as np

from cam2sim.core.errors import StageError, WorkspaceError
from cam2sim.core.files import write_text_atomic
from cam2sim.core.images import read_mask, read_rgb
from cam2sim.core.machine import available_cpus
from cam2sim.core.progress import ProgressCallback, no_progress
from cam2sim.core.schema import Artifact
from cam2sim.metrics.lpips import load_lpips
from cam2sim.metrics.summary import MetricSummary, summarise

if TYPE_CHECKING:
    from collections.abc import Iterable, Iterator

    import numpy.typing as npt

    from cam2sim.metrics.lpips import Lpips, LpipsNet

__all__ = [
    "IMAGE_SUFFIXES",
    "PSNR_CAP_DB",
    "ImagePair",
    "ImageQualityOptions",
    "ImageQualityResult",
    "ImageScores",
    "Pairing",
    "check_pair_sizes",
    "evaluate_image_folders",
    "exclusion_mask",
    "pair_images_by_stem",
    "psnr",
    "read_mask",
    "read_rgb",
    "ssim",
    "ssim_map",
    "write_image_quality",
]

_log = logging.getLogger(__name__)

IMAGE_SUFFIXES: Final = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".webp")
"""File suffixes (any case) taken as images when pairing folders."""

PSNR_CAP_DB: Final = 100.0
"""PSNR is reported as at most this many dB; identical images (infinite PSNR) get exactly this."""

_SSIM_WIN: Final = 11
_SSIM_SIGMA: Final = 1.5
_SSIM_K1: Final = 0.01
_SSIM_K2: Final = 0.03
_DATA_RANGE: Final = 255.0


# --------------------------------------------------------------------------------- folders, I/O


@dataclass(frozen=True)
class ImagePair:
    """A real image and the simulated image of the same stem."""

    stem: str
    real: Path
    sim: Path


@dataclass(frozen=True)
class Pairing:
    """Result of pairing two folders: the pairs (sorted by stem) and the stems left unmatched."""

    pairs: tuple[ImagePair, ...]
    real_only: tuple[str, ...]
    sim_only: tuple[str, ...]


def _images_by_stem(folder: Path, role: str) -> dict[str, Path]:
    if not folder.is_dir():
        msg = f"{role} folder {folder} does not exist or is not a folder"
        raise WorkspaceError(msg)
    found: dict[str, Path] = {}
    for path in sorted(folder.iterdir()):
        if not path.is_file() or path.suffix.lower() not in IMAGE_SUFFIXES:
            continue
        if path.stem in found:
            msg = f"{role} folder has two images of stem {path.stem!r}: {found[path.stem]}, {path}"
            raise WorkspaceError(msg)
        found[path.stem] = path
    return found


def pair_images_by_stem(real_dir: Path, sim_dir: Path) -> Pairing:
    """Pair the images of two folders by file stem (the name without its suffix).

    Args:
        real_dir: Folder of real images.
        sim_dir: Folder of simulated images.

    Returns:
        The pairs sorted by stem, and the stems found in one folder only.

    Raises:
        WorkspaceError: A folder is missing, or holds two images of one stem.
        StageError: No stem is shared by the two folders.
    """
    real = _images_by_stem(Path(real_dir), "real")
    sim = _images_by_stem(Path(sim_dir), "simulated")
    stems = sorted(real.keys() & sim.keys())
    if not stems:
        msg = (
            f"no image pairs: {real_dir} has {len(real)} images and {sim_dir} has {len(sim)}, "
            "but no file stem is in both; name paired images alike (000001.png <-> 000001.jpg)"
        )
        raise StageError(msg)
    return Pairing(
        pairs=tuple(ImagePair(s, real[s], sim[s]) for s in stems),
        real_only=tuple(sorted(real.keys() - sim.keys())),
        sim_only=tuple(sorted(sim.keys() - real.keys())),
    )


def exclusion_mask(
    shape: tuple[int, int],
    *,
    hood_rows: int = 0,
    masks: Iterable[tuple[Path, npt.NDArray[np.bool_]]] = (),
) -> npt.NDArray[np.bool_] | None:
    """Combine the exclusions of one frame into one ``(H, W)`` bool mask (True = excluded).

    Args:
        shape: ``(H, W)`` of the frame.
        hood_rows: Number of bottom rows to exclude (the ego hood).
        masks: ``(source path, mask)`` pairs to add; each must be ``(H, W)``.

    Returns:
        The mask, or None when nothing is excluded.

    Raises:
        StageError: A mask's size differs from the frame's.
        ValueError: ``hood_rows`` is negative.
    """
    if hood_rows < 0:
        msg = f"hood_rows must be >= 0, got {hood_rows}"
        raise ValueError(msg)
    out: npt.NDArray[np.bool_] | None = None
    if hood_rows:
        out = np.zeros(shape, dtype=np.bool_)
        out[max(shape[0] - hood_rows, 0) :] = True
    for path, mask in masks:
        if mask.shape != shape:
            msg = (
                f"mask {path} is {mask.shape[1]}x{mask.shape[0]} but the image is "
                f"{shape[1]}x{shape[0]} (width x height); masks must match the images"
            )
            raise StageError(msg)
        out = mask.copy() if out is None else out | mask
    return out


def check_pair_sizes(
    pair: ImagePair, real: npt.NDArray[np.uint8], sim: npt.NDArray[np.uint8]
) -> None:
    """Raise :class:`StageError` naming both files and sizes when the two images differ in size."""
    if real.shape != sim.shape:
        msg = (
            f"image sizes differ: {pair.real} is {real.shape[1]}x{real.shape[0]} but {pair.sim} "
            f"is {sim.shape[1]}x{sim.shape[0]} (width x height); cam2sim does not resize, render "
            "or crop the simulated images to the real size"
        )
        raise StageError(msg)


# ------------------------------------------------------------------------------------ statistics


# ------------------------------------------------------------------------------------- metrics


def _check_images(real: npt.NDArray[np.uint8], sim: npt.NDArray[np.uint8]) -> None:
    if real.shape != sim.shape or real.ndim not in (2, 3):
        msg = f"expected two (H, W[, C]) images of one shape, got {real.shape} and {sim.shape}"
        raise ValueError(msg)


def psnr(
    real: npt.NDArray[np.uint8],
    sim: npt.NDArray[np.uint8],
    *,
    exclude: npt.NDArray[np.bool_] | None = None,
    data_range: float = _DATA_RANGE,
) -> float | None:
    """Return the PSNR in dB, ``10 log10(range^2 / MSE)``, capped at :data:`PSNR_CAP_DB`.

    The MSE is taken over every channel of the pixels not excluded.

    Args:
        real: ``(H, W)`` or ``(H, W, C)`` image.
        sim: Same shape as ``real``.
        exclude: ``(H, W)`` bool, True where a pixel is left out, or None.
        data_range: Largest minus smallest possible value (255 for 8-bit).

    Returns:
        The PSNR, or None when every pixel is excluded.
    """
    _check_images(real, sim)
    diff = real.astype(np.float64) - sim.astype(np.float64)
    if exclude is not None:
        diff = diff[~exclude]
        if diff.size == 0:
            return None
    mse = float(np.mean(diff * diff))
    if mse == 0.0:
        return PSNR_CAP_DB
    return min(10.0 * math.log10(data_range * data_range / mse), PSNR_CAP_DB)


def ssim_map(
    real: npt.NDArray[np.uint8], sim: npt.NDArray[np.uint8], *, data_range: float = _DATA_RANGE
) -> npt.NDArray[np.float64]:
    """Return the SSIM map (Wang et al. 2004), averaged over channels.

    Local means, variances and the covariance are Gaussian-weighted (11x11 window, sigma 1.5,
    population moments); ``C1 = (0.01 L)^2``, ``C2 = (0.03 L)^2``. Only positions where the
    whole window lies inside the image are returned, so the map is ``(H - 10, W - 10)``.

    Args:
        real: ``(H, W)`` or ``(H, W, C)`` image, at least 11x11.
        sim: Same shape as ``real``.
        data_range: ``L``, largest minus smallest possible value (255 for 8-bit).

    Returns:
        ``(H - 10, W - 10)`` float64.
    """
    import cv2  # noqa: PLC0415

    _check_images(real, sim)
    if min(real.shape[:2]) < _SSIM_WIN:
        msg = f"SSIM needs images of at least {_SSIM_WIN}x{_SSIM_WIN} pixels, got {real.shape}"
        raise ValueError(msg)
    a = real.astype(np.float64)
    b = sim.astype(np.float64)

    def blur(x: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
        return np.asarray(cv2.GaussianBlur(x, (_SSIM_WIN, _SSIM_WIN), _SSIM_SIGMA), np.float64)

    mu_a, mu_b = blur(a), blur(b)
    var_a = blur(a * a) - mu_a * mu_a
    var_b = blur(b * b) - mu_b * mu_b
    cov = blur(a * b) - mu_a * mu_b
    c1 = (_SSIM_K1 * data_range) ** 2
    c2 = (_SSIM_K2 * data_range) ** 2
    full = ((2 * mu_a * mu_b + c1) * (2 * cov + c2)) / (
        (mu_a * mu_a + mu_b * mu_b + c1) * (var_a + var_b + c2)
    )
    r = _SSIM_WIN // 2
    valid = full[r:-r, r:-r]
    return valid.mean(axis=2) if valid.ndim == 3 else valid


def ssim(
    real: npt.NDArray[np.uint8],
    sim: npt.NDArray[np.uint8],
    *,
    exclude: npt.NDArray[np.bool_] | None = None,
    data_range: float = _DATA_RANGE,
) -> float | None:
    """Return the mean SSIM (see :func:`ssim_map`) over the pixels not excluded.

    Args:
        real: ``(H, W)`` or ``(H, W, C)`` image, at least 11x11.
        sim: Same shape as ``real``.
        exclude: ``(H, W)`` bool, True where a pixel is left out, or None. A kept pixel's window
            may still reach into excluded pixels.
        data_range: Largest minus smallest possible value.

    Returns:
        The SSIM, or None when no pixel of the valid region is kept.
    """
    smap = ssim_map(real, sim, data_range=data_range)
    if exclude is None:
        return float(smap.mean())
    r = _SSIM_WIN // 2
    kept = smap[~exclude[r:-r, r:-r]]
    return float(kept.mean()) if kept.size else None


# ---------------------------------------------------------------------------- folder evaluation


@dataclass(frozen=True)
class ImageQualityOptions:
    """What to exclude and which LPIPS to run when scoring two image folders.

    Attributes:
        mask_dir: Folder of per-frame mask images paired by stem (sky masks), or None. Every pair
            needs a mask.
        mask_keeps_nonzero: False: nonzero mask pixels are excluded. True: nonzero pixels are
            kept (nerfstudio convention, 255 = keep).
        hood_rows: Bottom rows excluded in every frame (ego hood).
        hood_mask: One mask image (nonzero = excluded) applied to every frame, or None.
        lpips_net: LPIPS backbone, or None to skip LPIPS.
        lpips_weights: Where the LPIPS weights are (see :func:`cam2sim.metrics.lpips.load_lpips`).
        batch_size: Pairs per LPIPS batch.
    """

    mask_dir: Path | None = None
    mask_keeps_nonzero: bool = False
    hood_rows: int = 0
    hood_mask: Path | None = None
    lpips_net: LpipsNet | None = "alex"
    lpips_weights: Path | None = None
    batch_size: int = 4


@dataclass(frozen=True)
class ImageScores:
    """The scores of one image pair; a metric is None when every pixel was excluded."""

    stem: str
    real: str
    sim: str
    psnr_db: float | None
    ssim: float | None
    lpips: float | None
    excluded_fraction: float


class ImageQualityResult(Artifact):
    """``images.json``: per-image PSNR/SSIM/LPIPS and their summary."""

    real_dir: str
    sim_dir: str
    psnr_cap_db: float = PSNR_CAP_DB
    lpips_net: str | None
    lpips_weights: str | None
    hood_rows: int
    hood_mask: str | None
    mask_dir: str | None
    mask_keeps_nonzero: bool
    images: tuple[ImageScores, ...]
    summary: dict[str, MetricSummary]
    real_only: tuple[str, ...]
    sim_only: tuple[str, ...]


@dataclass(frozen=True, eq=False)
class _Scored:
    """One pair read and scored on the CPU, waiting for LPIPS."""

    pair: ImagePair
    real: npt.NDArray[np.uint8]
    sim: npt.NDArray[np.uint8]
    exclude: npt.NDArray[np.bool_] | None
    psnr_db: float | None
    ssim: float | None


def _batches(scored: Iterable[_Scored], size: int) -> Iterator[list[_Scored]]:
    """Group consecutive pairs into batches of at most ``size`` images of one shape."""
    batch: list[_Scored] = []
    for item in scored:
        if batch and (len(batch) >= size or batch[0].real.shape != item.real.shape):
            yield batch
            batch = []
        batch.append(item)
    if batch:
        yield batch


def _with_lpips(batch: list[_Scored], model: Lpips | None) -> list[ImageScores]:
    """The batch's scores, with LPIPS when there is a model (one batch through the network)."""
    lpips_values: tuple[float | None, ...] = (None,) * len(batch)
    if model is not None:
        stacked = None
        if any(b.exclude is not None for b in batch):
            shape = batch[0].real.shape[:2]
            stacked = np.stack(
                [np.zeros(shape, np.bool_) if b.exclude is None else b.exclude for b in batch]
            )
        lpips_values = model.distance_from_images(
            np.stack([b.real for b in batch]), np.stack([b.sim for b in batch]), exclude=stacked
        )
    return [
        ImageScores(
            stem=b.pair.stem,
            real=str(b.pair.real),
            sim=str(b.pair.sim),
            psnr_db=b.psnr_db,
            ssim=b.ssim,
            lpips=lp,
            excluded_fraction=float(b.exclude.mean()) if b.exclude is not None else 0.0,
        )
        for b, lp in zip(batch, lpips_values, strict=True)
    ]


def evaluate_image_folders(
    real_dir: Path,
    sim_dir: Path,
    *,
    options: ImageQualityOptions | None = None,
    lpips_model: Lpips | None = None,
    progress: ProgressCallback = no_progress,
) -> ImageQualityResult:
    """Score every pair of same-stem images of two folders with PSNR, SSIM and LPIPS.

    Args:
        real_dir: Folder of real images.
        sim_dir: Folder of simulated images of the same size.
        options: Masks and LPIPS settings (defaults: no mask, LPIPS alex from the cache).
        lpips_model: An LPIPS network to use instead of loading ``options.lpips_net``.
        progress: Called as ``progress("image pairs", done, total)``.

    Returns:
        The per-image scores and their summary.

    Raises:
        WorkspaceError: A folder or image is missing or unreadable.
        StageError: No pairs, sizes differ within a pair or from a mask, missing masks, or the
            LPIPS weights cannot be had.
    """
    opts = options or ImageQualityOptions()
    pairing = pair_images_by_stem(real_dir, sim_dir)
    masks = _mask_files(pairing, opts.mask_dir)
    hood = read_mask(opts.hood_mask) if opts.hood_mask is not None else None
    model = lpips_model
    if model is None and opts.lpips_net is not None:
        model = load_lpips(opts.lpips_net, weights=opts.lpips_weights)

    def score(pair: ImagePair) -> _Scored:
        """Read one pair and score it on the CPU (PSNR, SSIM): runs in a worker thread."""
        real, sim = read_rgb(pair.real), read_rgb(pair.sim)
        check_pair_sizes(pair, real, sim)
        if min(real.shape[:2]) < _SSIM_WIN:
            msg = f"{pair.real} is smaller than {_SSIM_WIN}x{_SSIM_WIN} pixels; cannot score it"
            raise StageError(msg)
        extra = [(opts.hood_mask, hood)] if hood is not None and opts.hood_mask else []
        if pair.stem in masks:
            path = masks[pair.stem]
            extra.append((path, read_mask(path, keep_nonzero=opts.mask_keeps_nonzero)))
        exclude = exclusion_mask(real.shape[:2], hood_rows=opts.hood_rows, masks=extra)
        return _Scored(
            pair,
            real,
            sim,
            exclude,
            psnr(real, sim, exclude=exclude),
            ssim(real, sim, exclude=exclude),
        )

    rows: list[ImageScores] = []
    total = len(pairing.pairs)
    progress("image pairs", 0, total)
    # OpenCV and numpy let go of the GIL in the heavy work: pairs are read and scored in threads,
    # a few per CPU at a time (bounded memory); LPIPS takes them in batches in this thread.
    workers = available_cpus()
    window = max(opts.batch_size, 2 * workers)
    with ThreadPoolExecutor(max_workers=workers) as pool:
        for start in range(0, total, window):
            scored = list(pool.map(score, pairing.pairs[start : start + window]))
            for batch in _batches(scored, max(opts.batch_size, 1)):
                rows.extend(_with_lpips(batch, model))
            progress("image pairs", len(rows), total)
    _log.info(
        "scored %d image pairs (%d real-only, %d simulated-only stems)",
        len(rows),
        len(pairing.real_only),
        len(pairing.sim_only),
    )
    return ImageQualityResult(
        real_dir=str(real_dir),
        sim_dir=str(sim_dir),
        lpips_net=model.net if model is not None else None,
        lpips_weights=model.source if model is not None else None,
        hood_rows=opts.hood_rows,
        hood_mask=str(opts.hood_mask) if opts.hood_mask is not None else None,
        mask_dir=str(opts.mask_dir) if opts.mask_dir is not None else None,
        mask_keeps_nonzero=opts.mask_keeps_nonzero,
        images=tuple(rows),
        summary={
            "psnr_db": summarise(r.psnr_db for r in rows),
            "ssim": summarise(r.ssim for r in rows),
            "lpips": summarise(r.lpips for r in rows),
        },
        real_only=pairing.real_only,
        sim_only=pairing.sim_only,
    )


def _mask_files(pairing: Pairing, mask_dir: Path | None) -> dict[str, Path]:
    """Return the mask of every paired stem, or raise naming the stems without one."""
    if mask_dir is None:
        return {}
    found = _images_by_stem(Path(mask_dir), "mask")
    missing = [p.stem for p in pairing.pairs if p.stem not in found]
    if missing:
        shown = ", ".join(missing[:5]) + (", ..." if len(missing) > 5 else "")
        msg = f"{len(missing)} image pairs have no mask in {mask_dir}: {shown}"
        raise StageError(msg)
    return found


def _cell(value: float | None) -> str:
    return "" if value is None else f"{value:.6f}"


def write_image_quality(result: ImageQualityResult, out_dir: Path) -> tuple[Path, Path]:
    """Write ``images.json`` (the artifact) and ``images.csv`` (one row per pair) to ``out_dir``.

    Returns:
        The paths of the JSON and the CSV file.
    """
    out = Path(out_dir)
    json_path, csv_path = out / "images.json", out / "images.csv"
    buffer = io.StringIO()
    writer = csv.writer(buffer, lineterminator="\n")
    writer.writerow(["stem", "psnr_db", "ssim", "lpips", "excluded_fraction", "real", "sim"])
    for r in result.images:
        writer.writerow(
            [
                r.stem,
                _cell(r.psnr_db),
                _cell(r.ssim),
                _cell(r.lpips),
                _cell(r.excluded_fraction),
                r.real,
                r.sim,
            ]
        )
    result.save(json_path)
    write_text_atomic(csv_path, buffer.getvalue())
    return json_path, csv_path
