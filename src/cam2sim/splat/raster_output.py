"""What a rasterization returns, and the band of rows a render may be limited to.

Shared by the backend switch (:mod:`cam2sim.splat.raster`) and the plain-torch rasterizer
(:mod:`cam2sim.splat.raster_torch`), which imports torch; this module imports neither, so the
switch can name the torch rasterizer's output without importing it.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Literal

if TYPE_CHECKING:
    import torch

__all__ = ["RasterOutput", "row_window"]


@dataclass(frozen=True)
class RasterOutput:
    """What one rasterization returns.

    Attributes:
        colors: ``[C, H, W, D]`` composited colours (background included).
        alphas: ``[C, H, W, 1]`` accumulated opacity, ``1 - T`` after the last Gaussian.
        means2d: ``[C, N, 2]`` projected centres in pixels; part of the autograd graph, so its
            ``.grad`` (after ``retain_grad()`` and ``backward()``) drives densification.
        radii: ``[C, N, 2]`` int32 pixel half-extents of the screen boxes; 0 = culled.
        depths: ``[C, N]`` camera-space z of each centre, metres.
        info: The backend's own metadata (gsplat's ``meta`` dict on ``"gsplat"``, the same keys
            that ``gsplat.strategy.DefaultStrategy`` reads on ``"torch"``).
        backend: The backend that ran.
    """

    colors: torch.Tensor
    alphas: torch.Tensor
    means2d: torch.Tensor
    radii: torch.Tensor
    depths: torch.Tensor
    # Any: gsplat's meta dict holds tensors, ints and None side by side.
    info: dict[str, Any]
    backend: Literal["gsplat", "torch"]


def row_window(rows: tuple[int, int] | None, height: int) -> tuple[int, int]:
    """``rows`` checked against an image ``height`` rows high; None = all rows."""
    if rows is None:
        return 0, height
    first, stop = rows
    if not 0 <= first < stop <= height:
        msg = f"rows {rows} must satisfy 0 <= first < stop <= height ({height})"
        raise ValueError(msg)
    return first, stop
