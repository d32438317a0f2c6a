"""Robust photometric weighting: pixels of things that move (or flicker) are left out of the loss.

A street recording holds transient objects: oncoming and parked-then-moving cars, pedestrians,
leaves in the wind, shadows of clouds. No static scene explains them, so a plain L1/SSIM loss
bends the static Gaussians towards them (floaters, ghosting, smeared colour) and the model fits
even its own training views poorly. Pretrained segmenters would need weights; this needs none.

It follows RobustNeRF (Sabour et al., CVPR 2023) and SpotLessSplats (Sabour et al., 2024): a
pixel is an outlier candidate when its residual (detached, mean over RGB) lies above the
``quantile`` of the view's used pixels. Outliers worth leaving out come as blobs, fine texture
as isolated pixels, so the candidates are judged in their neighbourhood: a pixel is kept when
most of its 3x3 neighbourhood is inlier, or when its ``patch`` x ``patch`` block is mostly
(``patch_inlier``) inlier. What remains out is a blob of high residuals inside a patch that is
mostly outlier, such as a car that was in this view and nowhere else.

The weighting starts after a warm-up (:attr:`RobustLoss.after_steps`), when the static scene
is roughly in place; before it every residual is large. All tensor operations, no host sync.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    import numpy as np
    import numpy.typing as npt
    import torch

__all__ = ["RobustLoss", "outlier_montage", "robust_keep"]


@dataclass(frozen=True)
class RobustLoss:
    """Settings of the robust weighting.

    Attributes:
        quantile: Residual quantile above which a pixel is an outlier candidate (0 = off;
            RobustNeRF uses 0.8).
        after_steps: Steps of plain loss first.
        patch: Side of the blocks judged together, pixels (at the training size).
        patch_inlier: Share of inlier pixels that keeps a whole block.
    """

    quantile: float = 0.0
    after_steps: int = 2_000
    patch: int = 16
    patch_inlier: float = 0.6

    def __post_init__(self) -> None:
        if not 0.0 <= self.quantile < 1.0 or self.after_steps < 0 or self.patch < 1:
            msg = (
                "robust loss needs 0 <= quantile < 1, after_steps >= 0 and patch >= 1; got "
                f"{self.quantile}, {self.after_steps}, {self.patch}"
            )
            raise ValueError(msg)
        if not 0.0 < self.patch_inlier <= 1.0:
            msg = f"robust patch_inlier must lie in (0, 1], got {self.patch_inlier}"
            raise ValueError(msg)

    def active(self, step: int) -> bool:
        """Whether the weighting applies at training step ``step``."""
        return self.quantile > 0.0 and step >= self.after_steps


def robust_keep(
    rgb: torch.Tensor, target: torch.Tensor, mask: torch.Tensor, options: RobustLoss
) -> torch.Tensor:
    """``[H, W]`` bool: the used pixels (``mask``) that are not transient outliers.

    Args:
        rgb: ``[H, W, 3]`` render (its gradient is not used).
        target: ``[H, W, 3]`` image in ``[0, 1]``.
        mask: ``[H, W]`` bool, the pixels the loss uses at all.
        options: Quantile and neighbourhood rules.
    """
    import torch  # noqa: PLC0415
    import torch.nn.functional as F  # noqa: N812, PLC0415

    h, w = mask.shape
    residual = (rgb.detach() - target).abs().mean(dim=-1)
    used = torch.where(mask, residual, torch.full_like(residual, float("nan")))
    threshold = torch.nanquantile(used.reshape(-1), options.quantile)
    inlier = ((residual <= threshold) | ~mask).to(residual.dtype)[None, None]
    near = F.avg_pool2d(inlier, 3, stride=1, padding=1, count_include_pad=False) >= 0.5
    p = options.patch
    padded = F.pad(inlier, (0, (-w) % p, 0, (-h) % p), value=1.0)
    share = F.avg_pool2d(padded, p, stride=p)
    block = (
        F.interpolate(share, scale_factor=p, mode="nearest")[..., :h, :w] >= options.patch_inlier
    )
    keep: torch.Tensor = (near | block)[0, 0] & mask
    return keep


def outlier_montage(
    frames: list[npt.NDArray[np.uint8]],
    left_out: list[npt.NDArray[np.bool_]],
    labels: list[str],
) -> npt.NDArray[np.uint8]:
    """One RGB picture of recorded frames with the pixels the weighting left out tinted red.

    Args:
        frames: ``[H, W, 3]`` uint8 frames, all of one size.
        left_out: ``[H, W]`` bool per frame: used pixels that the weighting dropped.
        labels: A caption per frame (written on its top-left corner).

    Returns:
        The frames in rows of two (a black tile fills an odd last row).
    """
    import cv2  # noqa: PLC0415
    import numpy as np  # noqa: PLC0415

    tiles = []
    red = np.array([255.0, 0.0, 0.0])
    for frame, out, label in zip(frames, left_out, labels, strict=True):
        tile = frame.astype(np.float64)
        tile[out] = 0.45 * tile[out] + 0.55 * red
        tile = np.ascontiguousarray(tile.astype(np.uint8))
        cv2.putText(tile, label, (6, 18), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (255, 255, 255), 1)
        tiles.append(tile)
    if len(tiles) % 2:
        tiles.append(np.zeros_like(tiles[0]))
    rows = [np.concatenate(tiles[i : i + 2], axis=1) for i in range(0, len(tiles), 2)]
    return np.concatenate(rows, axis=0)
