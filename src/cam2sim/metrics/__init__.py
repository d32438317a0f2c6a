"""Metrics: how close simulated images and segmentations come to the real drive.

:mod:`~cam2sim.metrics.image_quality` scores paired image folders with PSNR, SSIM and LPIPS;
:mod:`~cam2sim.metrics.lpips` is the LPIPS network (torch, loaded lazily);
:mod:`~cam2sim.metrics.semantic` compares segmentations class by class (IoU, mIoU);
:mod:`~cam2sim.metrics.drive_quality` scores driven runs against the real drives (segment,
completion, Min-Fréchet, corridor, jitter, failure types), reading runs with
:mod:`~cam2sim.metrics.drive_io` and measuring along :mod:`~cam2sim.core.polyline` (the path
geometry every package shares).
Definitions are in ``docs/metrics.md``.
"""

from __future__ import annotations

from cam2sim.metrics.drive_io import DriveRun, RunEvent, load_runs
from cam2sim.metrics.drive_quality import (
    DriveEvaluation,
    DriveMetrics,
    DriveOptions,
    Segment,
    evaluate_drives,
)
from cam2sim.metrics.frechet import discrete_frechet
from cam2sim.metrics.image_quality import (
    PSNR_CAP_DB,
    ImageQualityOptions,
    ImageQualityResult,
    ImageScores,
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
from cam2sim.metrics.summary import MetricSummary

__all__ = [
    "PSNR_CAP_DB",
    "DriveEvaluation",
    "DriveMetrics",
    "DriveOptions",
    "DriveRun",
    "FrameIoU",
    "ImageQualityOptions",
    "ImageQualityResult",
    "ImageScores",
    "Lpips",
    "MetricSummary",
    "Palette",
    "RunEvent",
    "Segment",
    "SemanticOptions",
    "SemanticResult",
    "SemanticSummary",
    "discrete_frechet",
    "evaluate_drives",
    "evaluate_image_folders",
    "evaluate_semantic_folders",
    "labels_from_rgb",
    "load_lpips",
    "load_runs",
    "pair_images_by_stem",
    "psnr",
    "semantic_iou",
    "ssim",
    "write_image_quality",
]
