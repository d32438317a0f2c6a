"""Semantic IoU between real and simulated segmentations (road, car, background, ...).

Both segmentations are colour images. A :class:`Palette` maps colours to classes (Cityscapes road
and car by default); every pixel whose colour matches no class is background. Per frame and per
class, IoU = (pixels of the class in both images) / (pixels of the class in either image), over
the pixels not excluded. A class absent from both images has no IoU (None) and is left out of that
frame's mIoU and of the class's mean, instead of counting as 0. Images are compared at their own
size: a size mismatch is an error, never a resize. The ego hood is excluded from the comparison
(bottom rows or a mask), not painted.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Final

import numpy as np

from cam2sim.core.files import write_bytes_atomic
from cam2sim.core.labels import RGB, Palette, SemanticClass
from cam2sim.core.progress import ProgressCallback, no_progress
from cam2sim.core.schema import Artifact
from cam2sim.metrics.image_quality import (
    ImagePair,
    check_pair_sizes,
    exclusion_mask,
    pair_images_by_stem,
    read_mask,
    read_rgb,
)
from cam2sim.metrics.summary import MetricSummary, summarise

if TYPE_CHECKING:
    from collections.abc import Iterable, Sequence

    import numpy.typing as npt

__all__ = [
    "RGB",
    "FrameIoU",
    "Palette",
    "SemanticClass",
    "SemanticFrame",
    "SemanticOptions",
    "SemanticResult",
    "SemanticSummary",
    "comparison_image",
    "evaluate_semantic_folders",
    "labels_from_rgb",
    "semantic_iou",
    "write_comparison_image",
]

_log = logging.getLogger(__name__)

_EXCLUDED_RGB: Final = (128, 128, 128)
_MISMATCH_RGB: Final = (255, 255, 255)
_AGREE_DIM: Final = 0.35
_GAP_PX: Final = 4


def labels_from_rgb(image: npt.NDArray[np.uint8], palette: Palette) -> npt.NDArray[np.int32]:
    """Turn a colour segmentation into labels (0 = background, ``i + 1`` = ``palette.classes[i]``).

    Args:
        image: ``(H, W, 3)`` uint8 RGB.
        palette: The class colours.

    Returns:
        ``(H, W)`` int32 labels.
    """
    if image.ndim != 3 or image.shape[2] != 3 or image.dtype != np.uint8:
        msg = f"expected an (H, W, 3) uint8 RGB image, got {image.shape} {image.dtype}"
        raise ValueError(msg)
    labels = np.zeros(image.shape[:2], dtype=np.int32)
    if palette.tolerance == 0:
        for label, cls in enumerate(palette.classes, start=1):
            for rgb in cls.colors:
                labels[np.all(image == np.asarray(rgb, np.uint8), axis=2)] = label
        return labels
    best = np.full(image.shape[:2], palette.tolerance + 1, dtype=np.int16)
    pixels = image.astype(np.int16)
    for label, cls in enumerate(palette.classes, start=1):
        for rgb in cls.colors:
            dist = np.abs(pixels - np.asarray(rgb, np.int16)).max(axis=2)
            closer = dist < best
            labels[closer] = label
            best[closer] = dist[closer]
    return labels


@dataclass(frozen=True)
class FrameIoU:
    """IoU of one frame.

    Attributes:
        iou: Per class name, IoU in ``[0, 1]``, or None when the class is in neither image.
        miou: Mean of the IoUs that are not None; None when no class is present.
        pixels: Pixels compared (not excluded).
    """

    iou: dict[str, float | None]
    miou: float | None
    pixels: int


def semantic_iou(
    real_labels: npt.NDArray[np.integer],
    sim_labels: npt.NDArray[np.integer],
    *,
    classes: Sequence[str],
    exclude: npt.NDArray[np.bool_] | None = None,
) -> FrameIoU:
    """Return per-class IoU and mIoU of two label images.

    Args:
        real_labels: ``(H, W)`` integer labels in ``[0, len(classes))``.
        sim_labels: Same shape as ``real_labels``.
        classes: Class names by label.
        exclude: ``(H, W)`` bool, True where a pixel is left out, or None.

    Returns:
        The IoUs; a class in neither image (after exclusion) gets None.
    """
    if real_labels.shape != sim_labels.shape or real_labels.ndim != 2:
        msg = (
            "expected two (H, W) label images of one shape: "
            f"{real_labels.shape}, {sim_labels.shape}"
        )
        raise ValueError(msg)
    k = len(classes)
    real = real_labels.astype(np.int64)
    sim = sim_labels.astype(np.int64)
    if exclude is not None:
        real, sim = real[~exclude], sim[~exclude]
    for arr in (real, sim):
        if arr.size and (arr.min() < 0 or arr.max() >= k):
            msg = f"labels must lie in [0, {k}) for classes {list(classes)}"
            raise ValueError(msg)
    confusion = np.bincount(real.ravel() * k + sim.ravel(), minlength=k * k).reshape(k, k)
    tp = np.diag(confusion)
    union = confusion.sum(axis=0) + confusion.sum(axis=1) - tp
    iou = {
        name: (float(tp[i] / union[i]) if union[i] > 0 else None) for i, name in enumerate(classes)
    }
    present = [v for v in iou.values() if v is not None]
    return FrameIoU(iou=iou, miou=float(np.mean(present)) if present else None, pixels=real.size)


@dataclass(frozen=True)
class SemanticFrame:
    """The IoU of one real/simulated pair (see :class:`FrameIoU`)."""

    stem: str
    real: str
    sim: str
    iou: dict[str, float | None]
    miou: float | None
    pixels: int


@dataclass(frozen=True)
class SemanticSummary:
    """Per class and for mIoU: mean, population std and count over the frames that have a value."""

    classes: dict[str, MetricSummary]
    miou: MetricSummary

    @classmethod
    def from_frames(
        cls, frames: Iterable[SemanticFrame], classes: Sequence[str]
    ) -> SemanticSummary:
        """Summarise frames; a frame where a class is absent does not count for that class."""
        items = list(frames)
        return cls(
            classes={c: summarise(f.iou.get(c) for f in items) for c in classes},
            miou=summarise(f.miou for f in items),
        )


@dataclass(frozen=True)
class SemanticOptions:
    """How to read and what to exclude when comparing segmentation folders.

    Attributes:
        palette: Class colours (default Cityscapes road and car, exact match).
        hood_rows: Bottom rows excluded in every frame (ego hood).
        hood_mask: One mask image (nonzero = excluded) applied to every frame, or None.
    """

    palette: Palette = field(default_factory=Palette.cityscapes)
    hood_rows: int = 0
    hood_mask: Path | None = None


class SemanticResult(Artifact):
    """``semantic.json``: per-frame IoU and its summary."""

    real_dir: str
    sim_dir: str
    classes: tuple[str, ...]
    palette: dict[str, tuple[RGB, ...]]
    tolerance: int
    hood_rows: int
    hood_mask: str | None
    frames: tuple[SemanticFrame, ...]
    summary: SemanticSummary
    real_only: tuple[str, ...]
    sim_only: tuple[str, ...]


def comparison_image(
    real_labels: npt.NDArray[np.integer],
    sim_labels: npt.NDArray[np.integer],
    palette: Palette,
    *,
    exclude: npt.NDArray[np.bool_] | None = None,
) -> npt.NDArray[np.uint8]:
    """Draw real | difference | simulated side by side.

    The outer panels show each label image in the palette's colours (background black). The middle
    panel shows agreeing pixels in their class colour, dimmed, and disagreeing pixels white.
    Excluded pixels are grey in all three panels.

    Returns:
        ``(H, 3 W + 8, 3)`` uint8 RGB.
    """
    colors = palette.display_colors()
    real_rgb = colors[real_labels]
    sim_rgb = colors[sim_labels]
    agree = real_labels == sim_labels
    diff = np.where(agree[..., None], (real_rgb * _AGREE_DIM).astype(np.uint8), _MISMATCH_RGB)
    panels = [real_rgb, diff.astype(np.uint8), sim_rgb]
    if exclude is not None:
        for panel in panels:
            panel[exclude] = _EXCLUDED_RGB
    gap = np.full((real_labels.shape[0], _GAP_PX, 3), 255, dtype=np.uint8)
    return np.concatenate([panels[0], gap, panels[1], gap, panels[2]], axis=1)


def write_comparison_image(path: Path, image: npt.NDArray[np.uint8]) -> None:
    """Write an RGB image as PNG atomically."""
    from cam2sim.recording.image import encode_image_file  # noqa: PLC0415 -- lazy: imports cv2

    write_bytes_atomic(Path(path), encode_image_file(image, "png"))


def _frame(
    pair: ImagePair, opts: SemanticOptions, hood: npt.NDArray[np.bool_] | None
) -> tuple[
    SemanticFrame, npt.NDArray[np.int32], npt.NDArray[np.int32], npt.NDArray[np.bool_] | None
]:
    real_rgb, sim_rgb = read_rgb(pair.real), read_rgb(pair.sim)
    check_pair_sizes(pair, real_rgb, sim_rgb)
    masks = [(opts.hood_mask, hood)] if opts.hood_mask is not None and hood is not None else []
    exclude = exclusion_mask(real_rgb.shape[:2], hood_rows=opts.hood_rows, masks=masks)
    real = labels_from_rgb(real_rgb, opts.palette)
    sim = labels_from_rgb(sim_rgb, opts.palette)
    scores = semantic_iou(real, sim, classes=opts.palette.names, exclude=exclude)
    frame = SemanticFrame(
        stem=pair.stem,
        real=str(pair.real),
        sim=str(pair.sim),
        iou=scores.iou,
        miou=scores.miou,
        pixels=scores.pixels,
    )
    return frame, real, sim, exclude


def evaluate_semantic_folders(
    real_dir: Path,
    sim_dir: Path,
    *,
    options: SemanticOptions | None = None,
    comparison_dir: Path | None = None,
    progress: ProgressCallback = no_progress,
) -> SemanticResult:
    """Compare every pair of same-stem segmentation images of two folders.

    Args:
        real_dir: Folder of real segmentations (colour images).
        sim_dir: Folder of simulated segmentations of the same size.
        options: Palette and exclusions.
        comparison_dir: Folder for one ``<stem>.png`` comparison image per pair, or None.
        progress: Called as ``progress("segmentation pairs", done, total)``.

    Returns:
        Per-frame IoU and the summary.

    Raises:
        WorkspaceError: A folder or image is missing or unreadable.
        StageError: No pairs, or sizes differ within a pair or from the hood mask.
    """
    opts = options or SemanticOptions()
    pairing = pair_images_by_stem(real_dir, sim_dir)
    hood = read_mask(opts.hood_mask) if opts.hood_mask is not None else None
    frames = []
    total = len(pairing.pairs)
    progress("segmentation pairs", 0, total)
    for done, pair in enumerate(pairing.pairs, start=1):
        frame, real, sim, exclude = _frame(pair, opts, hood)
        frames.append(frame)
        if comparison_dir is not None:
            image = comparison_image(real, sim, opts.palette, exclude=exclude)
            write_comparison_image(Path(comparison_dir) / f"{pair.stem}.png", image)
        progress("segmentation pairs", done, total)
    _log.info(
        "compared %d segmentation pairs (%d real-only, %d simulated-only stems)",
        len(frames),
        len(pairing.real_only),
        len(pairing.sim_only),
    )
    names = opts.palette.names
    return SemanticResult(
        real_dir=str(real_dir),
        sim_dir=str(sim_dir),
        classes=names,
        palette={c.name: c.colors for c in opts.palette.classes},
        tolerance=opts.palette.tolerance,
        hood_rows=opts.hood_rows,
        hood_mask=str(opts.hood_mask) if opts.hood_mask is not None else None,
        frames=tuple(frames),
        summary=SemanticSummary.from_frames(frames, names),
        real_only=pairing.real_only,
        sim_only=pairing.sim_only,
    )
