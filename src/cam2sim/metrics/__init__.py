"""Metrics: how close simulated images and segmentations come to the real drive.

:mod:`~cam2sim.metrics.image_quality` scores paired image folders with PSNR, SSIM and LPIPS;
:mod:`~cam2sim.metrics.lpips` is the LPIPS network (torch, loaded lazily);
:mod:`~cam2sim.metrics.semantic` compares segmentations class by class (IoU, mIoU).
Definitions are in ``docs/metrics.md``.
"""

from __future__ import annotations

from cam2sim.metrics.image_quality import (
    PSNR_CAP_DB,
    ImageQualityOptions,
    ImageQualityResult,
    ImageScores,
    MetricStats,
    evaluate_image_folders,
    pair_images_by_stem,
    psnr,
    ssim,
    write_image_quality,
)
from cam2sim.metrics.lpips import Lpips, load_lpips
from cam2sim.metrics.semantic import (
    FrameIoU,
    Palette,
    SemanticOptions,
    SemanticResult,
    SemanticSummary,
    evaluate_semantic_folders,
    labels_from_rgb,
    semantic_iou,
)

__all__ = [
    "PSNR_CAP_DB",
    "FrameIoU",
    "ImageQualityOptions",
    "ImageQualityResult",
    "ImageScores",
    "Lpips",
    "MetricStats",
    "Palette",
    "SemanticOptions",
    "SemanticResult",
    "SemanticSummary",
    "evaluate_image_folders",
    "evaluate_semantic_folders",
    "labels_from_rgb",
    "load_lpips",
    "pair_images_by_stem",
    "psnr",
    "semantic_iou",
    "ssim",
    "write_image_quality",
]
