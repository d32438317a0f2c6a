"""Training views of one chunk on the training device, and per-view constants of the loss.

:func:`load_views` reads the chunk's images, masks and sky masks from ``WS/splat/prep`` once and
keeps them on the device (uint8/bool); :class:`LossConstants` holds what the loss would otherwise
recompute every step (pixel counts, the sky and street pixel sets). torch and OpenCV are imported
inside the functions.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from cam2sim.core.errors import StageError
from cam2sim.core.images import read_rgb

if TYPE_CHECKING:
    from pathlib import Path

    import numpy.typing as npt
    import torch

    from cam2sim.splat.scene import FrameRecord

__all__ = [
    "LossConstants",
    "TrainViews",
    "downsample_views",
    "load_views",
    "loss_constants",
    "sky_colour",
]


@dataclass(frozen=True)
class TrainViews:
    """The training views of one chunk, on the training device."""

    frames: tuple[FrameRecord, ...]
    images: torch.Tensor  # [M, H, W, 3] uint8
    masks: torch.Tensor  # [M, H, W] bool, True = use
    sky: torch.Tensor | None  # [M, H, W] bool, True = sky
    viewmats: torch.Tensor  # [M, 4, 4] world -> camera
    Ks: torch.Tensor  # [M, 3, 3]
    campos: torch.Tensor  # [M, 3]
    width: int
    height: int


def _read_mask(path: Path, shape: tuple[int, int]) -> npt.NDArray[np.uint8] | None:
    import cv2  # noqa: PLC0415

    if not path.is_file():
        return None
    mask = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    if mask is None or mask.shape != shape:
        msg = f"mask {path} is unreadable or not {shape[1]}x{shape[0]}; re-run splat preparation"
        raise StageError(msg)
    return np.asarray(mask, dtype=np.uint8)


def load_views(
    prep_dir: Path, frames: list[FrameRecord], downscale: int, device: str
) -> TrainViews:
    """Read ``frames`` (one image size) from ``prep_dir``, downscaled, onto ``device``.

    Raises:
        StageError: Mixed image sizes, or an image or mask of the wrong size.
    """
    import cv2  # noqa: PLC0415
    import torch  # noqa: PLC0415

    sizes = {(f.width, f.height) for f in frames}
    if len(sizes) != 1:
        msg = f"training views of one chunk must share one image size, found {sorted(sizes)}"
        raise StageError(msg)
    (w0, h0) = sizes.pop()
    w, h = max(1, w0 // downscale), max(1, h0 // downscale)
    images, masks, skies, viewmats, ks = [], [], [], [], []
    any_sky = False
    for f in frames:
        stem = f"{f.index:06d}.png"
        rgb = read_rgb(prep_dir / "images" / stem)
        if rgb.shape[:2] != (h0, w0):
            msg = f"{prep_dir / 'images' / stem} is {rgb.shape[1]}x{rgb.shape[0]}, not {w0}x{h0}"
            raise StageError(msg)
        mask = _read_mask(prep_dir / "masks" / stem, (h0, w0))
        sky = _read_mask(prep_dir / "sky" / stem, (h0, w0))
        mask = np.full((h0, w0), 255, np.uint8) if mask is None else mask
        any_sky = any_sky or sky is not None
        sky = np.zeros((h0, w0), np.uint8) if sky is None else sky
        if (w, h) != (w0, h0):
            rgb = np.asarray(cv2.resize(rgb, (w, h), interpolation=cv2.INTER_AREA), np.uint8)
            mask = np.asarray(cv2.resize(mask, (w, h), interpolation=cv2.INTER_AREA), np.uint8)
            sky = np.asarray(cv2.resize(sky, (w, h), interpolation=cv2.INTER_AREA), np.uint8)
        images.append(rgb)
        masks.append(mask > 254)
        skies.append(sky > 127)
        viewmats.append(np.linalg.inv(f.T()))
        ks.append(f.camera().scaled(w, h, convention="corners").K())
    viewmat_t = torch.tensor(np.stack(viewmats), dtype=torch.float32, device=device)
    return TrainViews(
        frames=tuple(frames),
        images=torch.from_numpy(np.stack(images)).to(device),
        masks=torch.from_numpy(np.stack(masks)).to(device),
        sky=torch.from_numpy(np.stack(skies)).to(device) if any_sky else None,
        viewmats=viewmat_t,
        Ks=torch.tensor(np.stack(ks), dtype=torch.float32, device=device),
        campos=torch.tensor(
            np.stack([f.T()[:3, 3] for f in frames]), dtype=torch.float32, device=device
        ),
        width=w,
        height=h,
    )


def downsample_views(views: TrainViews, factor: int, *, batch: int = 64) -> TrainViews:
    """``views`` at ``1/factor`` of their size, on their device (coarse training steps).

    Images are averaged over ``factor x factor`` blocks (a right or bottom remainder is cut
    off, which leaves the intrinsics of the kept pixels exact: ``f' = f / factor``,
    ``c' = c / factor``); a coarse pixel is used only where all its pixels are, and is sky
    where most of them are.
    """
    import torch  # noqa: PLC0415
    import torch.nn.functional as F  # noqa: N812, PLC0415

    if factor < 1:
        msg = f"downsample factor {factor} (need >= 1)"
        raise ValueError(msg)
    if factor == 1:
        return views
    w, h = views.width // factor, views.height // factor
    if w < 1 or h < 1:
        msg = f"{views.width}x{views.height} views cannot be downsampled {factor}x"
        raise StageError(msg)

    def pool(stack: torch.Tensor) -> torch.Tensor:
        # [M, H, W, C] -> [M, h, w, C] block means, in batches to bound the float copy.
        parts = []
        for start in range(0, stack.shape[0], batch):
            chunk = stack[start : start + batch, : h * factor, : w * factor].float()
            pooled = F.avg_pool2d(chunk.permute(0, 3, 1, 2), factor)
            parts.append(pooled.permute(0, 2, 3, 1))
        return torch.cat(parts)

    images = pool(views.images).round().clamp(0, 255).to(torch.uint8)
    masks = pool(views.masks[..., None])[..., 0] > 1.0 - 1e-6
    sky = None if views.sky is None else pool(views.sky[..., None])[..., 0] > 0.5
    ks = views.Ks.clone()
    ks[:, :2] /= factor
    return TrainViews(
        frames=views.frames,
        images=images,
        masks=masks,
        sky=sky,
        viewmats=views.viewmats,
        Ks=ks,
        campos=views.campos,
        width=w,
        height=h,
    )


def sky_colour(views: TrainViews) -> list[float]:
    """Mean colour of sky pixels, or of the top tenth of the images without sky masks."""
    if views.sky is not None and bool(views.sky.any()):
        pixels = views.images[views.sky]
    else:
        top = max(1, views.height // 10)
        pixels = views.images[:, :top].reshape(-1, 3)
    return (pixels.float().mean(dim=0) / 255.0).tolist()


@dataclass(frozen=True)
class LossConstants:
    """Per-view constants of :func:`cam2sim.splat.losses.photometric_loss`.

    Attributes:
        l1_scale: ``[M]`` ``1 / (3 max(1, used pixels))``.
        sky_pixels: ``[M, H, W]`` bool, sky and used, or None without sky masks.
        street_pixels: ``[M, H, W]`` bool, not sky and used, or None.
        sky_scale: ``[M]`` ``1 / max(1, sky pixels)``, or None.
        street_scale: ``[M]`` ``1 / max(1, street pixels)``, or None.
    """

    l1_scale: torch.Tensor
    sky_pixels: torch.Tensor | None
    street_pixels: torch.Tensor | None
    sky_scale: torch.Tensor | None
    street_scale: torch.Tensor | None


def loss_constants(views: TrainViews) -> LossConstants:
    """Compute :class:`LossConstants` of ``views`` once, on their device."""
    used = views.masks.sum(dim=(1, 2)).float().clamp_min(1.0)
    if views.sky is None:
        return LossConstants(1.0 / (3.0 * used), None, None, None, None)
    sky = views.sky & views.masks
    street = ~views.sky & views.masks
    return LossConstants(
        l1_scale=1.0 / (3.0 * used),
        sky_pixels=sky,
        street_pixels=street,
        sky_scale=1.0 / sky.sum(dim=(1, 2)).float().clamp_min(1.0),
        street_scale=1.0 / street.sum(dim=(1, 2)).float().clamp_min(1.0),
    )
