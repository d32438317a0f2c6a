"""Compiled CPU compositing for the pure-torch rasterizer (numba, one thread per tile group).

:func:`cam2sim.splat.raster_torch.rasterization` does steps 1-4 of its module doc (projection,
culling, tile binning) in torch; step 5, compositing, is where a CPU training step spent its
time: the torch version pads every tile's Gaussian list to a common length and evaluates every
(tile, Gaussian, pixel) triple as one tensor element, with autograd keeping them all for the
backward pass (about 0.6 s of a 0.9 s step on the demo's 160x100 views with 40k Gaussians).

This module composites the same way gsplat's CUDA kernels do, per pixel and front to back,
stopping where the transmittance runs out, and computes the gradients in a second pass back to
front from the forward pass's final transmittance and stop position (no per-element storage);
the kernels take a tile row at a time, each Gaussian over the columns it covers:

- forward: ``alpha = min(0.999, o exp(-sigma))`` with ``sigma = a dx^2 / 2 + b dx dy +
  c dy^2 / 2`` (``dx = mean - pixel centre``), alphas below 1/255 skipped, a pixel ends before
  the Gaussian that would bring its transmittance to 1e-4 or below;
- backward: gradients of the colours, opacities, conics and 2-D means (the last is what
  densification reads) from the gradients of the image and its accumulated alpha.

The results equal the torch version's to float32 rounding (``tests/splat/test_raster_cpu.py``
checks images and gradients against it). Kernels are compiled on first use (a few seconds,
cached next to this module when the folder is writable). :func:`available` says whether numba
is installed; ``CAM2SIM_SPLAT_COMPOSITE=torch`` turns the compiled path off.
"""

from __future__ import annotations

import functools
import os
from typing import TYPE_CHECKING, Any, Final

import numpy as np

if TYPE_CHECKING:
    import torch

__all__ = ["ENV_VAR", "available", "composite"]

ENV_VAR: Final = "CAM2SIM_SPLAT_COMPOSITE"
"""``torch`` forces the torch compositing on the CPU; anything else lets this module run."""

_TILE: Final = 16


def available() -> bool:
    """Whether the compiled compositing can run (numba installed, not turned off)."""
    if os.environ.get(ENV_VAR, "").strip().lower() == "torch":
        return False
    try:
        import numba  # noqa: F401, PLC0415
    except ImportError:
        return False
    return True


@functools.cache
def _kernels() -> tuple[Any, Any]:
    """The forward and backward kernels (compiled on first use, or loaded from numba's cache)."""
    from cam2sim.splat import _composite_kernels as k  # noqa: PLC0415 -- lazy: imports numba

    return k.forward, k.backward


def _numpy(t: torch.Tensor) -> np.ndarray[Any, Any]:
    import torch  # noqa: PLC0415

    return np.ascontiguousarray(t.detach().to(torch.float32).numpy())


@functools.cache
def _function() -> Any:  # Any: built on first use so that torch loads lazily
    import torch  # noqa: PLC0415

    class Composite(torch.autograd.Function):
        """Front-to-back compositing of binned Gaussians with a back-to-front backward."""

        @staticmethod
        def forward(  # noqa: PLR0913, PLR0917
            ctx: Any,
            means2d: torch.Tensor,
            conics: torch.Tensor,
            opacities: torch.Tensor,
            colors: torch.Tensor,
            starts: torch.Tensor,
            gauss_ids: torch.Tensor,
            tiles_x: int,
            tiles_y: int,
        ) -> tuple[torch.Tensor, torch.Tensor]:
            forward_kernel, _ = _kernels()
            arrays = (_numpy(means2d), _numpy(conics), _numpy(opacities), _numpy(colors))
            st, ids = starts.numpy(), gauss_ids.numpy()
            h, w = tiles_y * _TILE, tiles_x * _TILE
            rgb = np.zeros((h, w, arrays[3].shape[1]), np.float32)
            t = np.ones((h, w), np.float32)
            last = np.zeros((h, w), np.int32)
            forward_kernel(*arrays, st, ids, tiles_x, tiles_x * tiles_y, rgb, t, last)
            ctx.arrays, ctx.bins, ctx.state = arrays, (st, ids, tiles_x, tiles_y), (t, last)
            ctx.dtype = colors.dtype
            return torch.from_numpy(rgb), torch.from_numpy(1.0 - t)

        @staticmethod
        def backward(ctx: Any, grad_rgb: torch.Tensor, grad_acc: torch.Tensor) -> tuple[Any, ...]:
            import numba  # noqa: PLC0415

            _, backward_kernel = _kernels()
            means2d, conics, opac, colors = ctx.arrays
            st, ids, tiles_x, tiles_y = ctx.bins
            t, last = ctx.state
            n, d = colors.shape
            groups = max(1, min(numba.get_num_threads(), tiles_x * tiles_y))
            v_means = np.zeros((groups, n, 2), np.float32)
            v_conics = np.zeros((groups, n, 3), np.float32)
            v_opac = np.zeros((groups, n), np.float32)
            v_colors = np.zeros((groups, n, d), np.float32)
            g_rgb = np.zeros((*t.shape, d), np.float32) if grad_rgb is None else _numpy(grad_rgb)
            g_acc = np.zeros(t.shape, np.float32) if grad_acc is None else _numpy(grad_acc)
            backward_kernel(
                means2d, conics, opac, colors, st, ids, tiles_x, tiles_x * tiles_y, t, last,
                g_rgb, g_acc, v_means, v_conics, v_opac, v_colors,
            )  # fmt: skip
            dtype = ctx.dtype
            out = (
                torch.from_numpy(v_means.sum(0)).to(dtype),
                torch.from_numpy(v_conics.sum(0)).to(dtype),
                torch.from_numpy(v_opac.sum(0)).to(dtype),
                torch.from_numpy(v_colors.sum(0)).to(dtype),
            )
            return (*out, None, None, None, None)

    return Composite


def composite(
    means2d: torch.Tensor,
    conics: torch.Tensor,
    opacities: torch.Tensor,
    colors: torch.Tensor,
    tile_ids: torch.Tensor,
    gauss_ids: torch.Tensor,
    *,
    tiles_x: int,
    tiles_y: int,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Composite one image on the CPU (compiled), with autograd.

    Args:
        means2d: ``[N, 2]`` pixel positions.
        conics: ``[N, 3]`` ``(a, b, c)`` of the inverse 2-D covariance ``[[a, b], [b, c]]``.
        opacities: ``[N]``.
        colors: ``[N, D]``.
        tile_ids: ``[M]`` tile of each (tile, Gaussian) pair, ascending.
        gauss_ids: ``[M]`` Gaussian of each pair, front to back within a tile.
        tiles_x: Tiles per row.
        tiles_y: Tile rows.

    Returns:
        ``[tiles_y * 16, tiles_x * 16, D]`` colours without background and
        ``[tiles_y * 16, tiles_x * 16]`` accumulated alpha, as
        :func:`cam2sim.splat.raster_torch.rasterization`'s compositing returns them.
    """
    import torch  # noqa: PLC0415

    n_tiles = tiles_x * tiles_y
    counts = torch.bincount(tile_ids, minlength=n_tiles)
    starts = torch.zeros(n_tiles + 1, dtype=torch.int64)
    starts[1:] = torch.cumsum(counts, 0)
    rgb, acc = _function().apply(
        means2d, conics, opacities, colors, starts, gauss_ids.to(torch.int64).contiguous(),
        tiles_x, tiles_y,
    )  # fmt: skip
    return rgb, acc
