"""Differentiable 3D Gaussian rasterization in plain PyTorch, with gsplat 1.5's conventions.

The CPU (and any-device) fallback of :func:`cam2sim.splat.raster.rasterize`. It follows what
gsplat's CUDA kernels do in ``rasterize_mode="classic"``, step by step, so both give the same
image for the same Gaussians and camera:

1. **World to camera**: ``x_c = R x + t`` with ``viewmat = [R | t] = inverse(T_world_cam)``,
   ``Sigma_c = R Sigma R^T`` with ``Sigma = (R_q S)(R_q S)^T`` from the normalised quaternion
   ``(w, x, y, z)`` and the scales.
2. **EWA projection**: the pinhole Jacobian at the centre, its x/y clamped to 1.3 times the
   field of view as gsplat does; ``Sigma_2d = J Sigma_c J^T + eps2d I`` (the 0.3-pixel
   low-pass dilation); the conic is ``inverse(Sigma_2d)``.
3. **Culling and extents**: culled when z is outside ``[near, far]``, the 2-D covariance is
   singular, the opacity is below 1/255, or the box lies off the image. The box half-extent is
   ``ceil(k sqrt(Sigma_2d[i, i]))`` pixels with ``k = min(3.33, sqrt(2 ln(255 opacity)))``
   (gsplat's opacity-aware bound: outside it every alpha is below 1/255).
4. **Tile binning**: 16 x 16 pixel tiles; each Gaussian goes to every tile its box touches;
   per tile the Gaussians are sorted by depth (ties by index).
5. **Compositing**, front to back per pixel (centre ``(j + 0.5, i + 0.5)``):
   ``alpha = min(0.999, o exp(-q/2))`` with the conic's quadratic form ``q``; an alpha below
   1/255 is skipped; ``C += c alpha T``, ``T *= 1 - alpha``; a Gaussian that would bring ``T``
   to 1e-4 or below ends the pixel and is not drawn. The background adds ``T * background``.

Step 5 runs on batches of tiles at once: every (tile, Gaussian, pixel) triple of a batch is one
tensor element, the transmittance is a cumulative product along the Gaussians, and autograd
gives the gradients. Memory per batch is bounded by ``max_elements``.

Colours may be spherical-harmonics coefficients (degree 0 to 3, the real SH basis and signs of
3DGS and gsplat, ``rgb = max(sh(d) + 0.5, 0)`` with ``d`` the unit direction camera -> Gaussian).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import partial
from typing import TYPE_CHECKING, Any, Final, Literal

import torch
from torch.nn import functional as tnf

from cam2sim.splat import raster_cpu, sh_cpu
from cam2sim.splat.raster_output import RasterOutput, row_window
from cam2sim.splat.sh_constants import SH_C0, SH_C1, SH_C2, SH_C3

if TYPE_CHECKING:
    from collections.abc import Callable

__all__ = [
    "ALPHA_MAX",
    "ALPHA_THRESHOLD",
    "SH_C0",
    "SH_C1",
    "SH_C2",
    "SH_C3",
    "TILE_SIZE",
    "TRANSMITTANCE_MIN",
    "Projection",
    "project_gaussians",
    "quats_to_rotmats",
    "rasterization",
    "rgb_from_sh",
    "row_window",
    "sh_basis",
    "tile_boxes",
]

TILE_SIZE: Final = 16
"""Tile edge, pixels (gsplat's default)."""

ALPHA_THRESHOLD: Final = 1.0 / 255.0
"""Alphas below this are skipped."""

ALPHA_MAX: Final = 0.999
"""Alphas are clamped to at most this (gsplat's kernels; 3DGS uses 0.99)."""

TRANSMITTANCE_MIN: Final = 1e-4
"""A pixel ends before the Gaussian that would bring its transmittance to this or below."""

_EXTEND: Final = 3.33
_MAX_ELEMENTS: Final = 1 << 22


# ---------------------------------------------------------------------------------- geometry


def quats_to_rotmats(quats: torch.Tensor) -> torch.Tensor:
    """Turn ``[..., 4]`` quaternions ``(w, x, y, z)`` (normalised here) into ``[..., 3, 3]``."""
    w, x, y, z = tnf.normalize(quats, dim=-1).unbind(-1)
    rows = (
        1 - 2 * (y * y + z * z),
        2 * (x * y - w * z),
        2 * (x * z + w * y),
        2 * (x * y + w * z),
        1 - 2 * (x * x + z * z),
        2 * (y * z - w * x),
        2 * (x * z - w * y),
        2 * (y * z + w * x),
        1 - 2 * (x * x + y * y),
    )
    return torch.stack(rows, dim=-1).reshape((*quats.shape[:-1], 3, 3))


@dataclass(frozen=True)
class Projection:
    """Screen-space Gaussians for ``C`` cameras (culled ones: zeros and radii 0).

    Attributes:
        means2d: ``[C, N, 2]`` centres, pixels.
        conics: ``[C, N, 3]`` inverse 2-D covariance ``(a, b, c)``: ``q = a dx^2 + 2 b dx dy +
            c dy^2``.
        depths: ``[C, N]`` camera z, metres.
        radii: ``[C, N, 2]`` int32 box half-extents, pixels.
        compensations: ``[C, N]`` Mip-Splatting's opacity factor ``sqrt(det(Sigma) /
            det(Sigma + eps2d I))`` (gsplat's ``rasterize_mode="antialiased"``), or None.
    """

    means2d: torch.Tensor
    conics: torch.Tensor
    depths: torch.Tensor
    radii: torch.Tensor
    compensations: torch.Tensor | None = None


def project_gaussians(  # noqa: PLR0913 -- the projection needs every camera and Gaussian input
    means: torch.Tensor,
    quats: torch.Tensor,
    scales: torch.Tensor,
    opacities: torch.Tensor,
    viewmats: torch.Tensor,
    Ks: torch.Tensor,
    width: int,
    height: int,
    *,
    eps2d: float = 0.3,
    near_plane: float = 0.01,
    far_plane: float = 1e10,
    compensate: bool = False,
) -> Projection:
    """Project ``N`` Gaussians into ``C`` pinhole cameras (steps 1 to 3 of the module doc).

    Args:
        means: ``[N, 3]`` world positions.
        quats: ``[N, 4]`` ``(w, x, y, z)``.
        scales: ``[N, 3]`` standard deviations.
        opacities: ``[N]`` in ``[0, 1]`` (only used for culling and the box extent).
        viewmats: ``[C, 4, 4]`` world -> camera.
        Ks: ``[C, 3, 3]`` intrinsics.
        width: Image width, pixels.
        height: Image height, pixels.
        eps2d: Dilation added to the 2-D covariance diagonal.
        near_plane: Minimum camera z.
        far_plane: Maximum camera z.
        compensate: Also return Mip-Splatting's opacity compensation (antialiased mode).

    Returns:
        The screen-space Gaussians.
    """
    rot = viewmats[:, :3, :3]
    means_c = torch.einsum("cij,nj->cni", rot, means) + viewmats[:, None, :3, 3]
    # The camera's rows of W R S (W the camera rotation, R S the Gaussian's): its covariance
    # in the camera is M M^T, M = W R S.
    rows = torch.einsum("cij,njk->cnik", rot, quats_to_rotmats(quats) * scales[..., None, :])
    x, y, z = means_c.unbind(-1)
    in_depth = (z >= near_plane) & (z <= far_plane)
    z_safe = torch.where(in_depth, z, torch.ones_like(z))

    fx, fy = Ks[:, 0, 0, None], Ks[:, 1, 1, None]
    cx, cy = Ks[:, 0, 2, None], Ks[:, 1, 2, None]
    lim_x_pos = (width - cx) / fx + 0.3 * (0.5 * width / fx)
    lim_x_neg = cx / fx + 0.3 * (0.5 * width / fx)
    lim_y_pos = (height - cy) / fy + 0.3 * (0.5 * height / fy)
    lim_y_neg = cy / fy + 0.3 * (0.5 * height / fy)
    rz = 1.0 / z_safe
    tx = z_safe * torch.minimum(lim_x_pos, torch.maximum(-lim_x_neg, x * rz))
    ty = z_safe * torch.minimum(lim_y_pos, torch.maximum(-lim_y_neg, y * rz))
    # The screen covariance J M M^T J^T with the projection's Jacobian J = [[fx/z, 0, -fx tx/z^2],
    # [0, fy/z, -fy ty/z^2]], written out element by element: (J M)'s two rows u and v, then
    # their dot products (a third of the time of [N, 3, 3] batched matmuls on a CPU, and
    # symmetric by construction).
    r0, r1, r2 = rows.unbind(-2)
    u = (fx * rz)[..., None] * r0 - (fx * tx * rz * rz)[..., None] * r2
    v = (fy * rz)[..., None] * r1 - (fy * ty * rz * rz)[..., None] * r2
    cov_xx, cov_xy, cov_yy = (u * u).sum(-1), (u * v).sum(-1), (v * v).sum(-1)
    means2d = torch.stack((fx * x * rz + cx, fy * y * rz + cy), dim=-1)

    a = cov_xx + eps2d
    b = cov_xy
    c = cov_yy + eps2d
    det = a * c - b * b
    ok_det = det > 0
    det_safe = torch.where(ok_det, det, torch.ones_like(det))
    conics = torch.stack((c / det_safe, -b / det_safe, a / det_safe), dim=-1)

    with torch.no_grad():
        opac = opacities.detach()[None, :].expand_as(z)
        ok_opac = opac >= ALPHA_THRESHOLD
        log_ratio = torch.log(torch.clamp(opac / ALPHA_THRESHOLD, min=1.0))
        extend = torch.clamp(torch.sqrt(2.0 * log_ratio), max=_EXTEND)
        rx = torch.ceil(extend * torch.sqrt(torch.clamp(a.detach(), min=0.0)))
        ry = torch.ceil(extend * torch.sqrt(torch.clamp(c.detach(), min=0.0)))
        mx, my = means2d.detach().unbind(-1)
        on_screen = (mx + rx > 0) & (mx - rx < width) & (my + ry > 0) & (my - ry < height)
        valid = in_depth & ok_det & ok_opac & ((rx > 0) | (ry > 0)) & on_screen
        radii = torch.where(valid[..., None], torch.stack((rx, ry), dim=-1), 0.0).to(torch.int32)

    compensations = None
    if compensate:
        # det(Sigma) / det(Sigma + eps2d I): the share of the footprint that is the Gaussian's
        # own, not the dilation's (tiny, far Gaussians fade instead of bloating to a pixel).
        det_raw = cov_xx * cov_yy - b * b
        ratio = torch.clamp(det_raw / det_safe, min=0.0)
        compensations = torch.where(valid, torch.sqrt(ratio + 1e-12), 0.0)
    keep = valid[..., None]
    return Projection(
        means2d=torch.where(keep, means2d, 0.0),
        conics=torch.where(keep, conics, 0.0),
        depths=torch.where(valid, z, 0.0),
        radii=radii,
        compensations=compensations,
    )


# ------------------------------------------------------------------------ spherical harmonics


def sh_basis(degree: int, dirs: torch.Tensor) -> torch.Tensor:
    """Evaluate the real SH basis of 3DGS up to ``degree`` (0-3) at ``[..., 3]`` unit directions.

    Returns:
        ``[..., (degree + 1) ** 2]``.
    """
    if not 0 <= degree <= 3:
        msg = f"SH degree must be 0 to 3, got {degree}"
        raise ValueError(msg)
    x, y, z = dirs.unbind(-1)
    out = [torch.full_like(x, SH_C0)]
    if degree >= 1:
        out += [-SH_C1 * y, SH_C1 * z, -SH_C1 * x]
    if degree >= 2:
        xx, yy, zz = x * x, y * y, z * z
        c2 = SH_C2
        out += [
            c2[0] * x * y,
            c2[1] * y * z,
            c2[2] * (2 * zz - xx - yy),
            c2[3] * x * z,
            c2[4] * (xx - yy),
        ]
    if degree >= 3:
        c3 = SH_C3
        out += [
            c3[0] * y * (3 * xx - yy),
            c3[1] * x * y * z,
            c3[2] * y * (4 * zz - xx - yy),
            c3[3] * z * (2 * zz - 3 * xx - 3 * yy),
            c3[4] * x * (4 * zz - xx - yy),
            c3[5] * z * (xx - yy),
            c3[6] * x * (xx - 3 * yy),
        ]
    return torch.stack(out, dim=-1)


def rgb_from_sh(coeffs: torch.Tensor, dirs: torch.Tensor, degree: int) -> torch.Tensor:
    """Return ``max(sum_k basis_k(d) coeffs_k + 0.5, 0)``, as gsplat's ``rasterization`` does.

    Args:
        coeffs: ``[..., K, 3]`` SH coefficients, ``K >= (degree + 1) ** 2``.
        dirs: ``[..., 3]`` view directions (camera -> Gaussian), any length.
        degree: SH degree to use.

    Returns:
        ``[..., 3]`` colours.
    """
    n_basis = (degree + 1) ** 2
    if coeffs.shape[-2] < n_basis:
        msg = f"degree {degree} needs {n_basis} SH coefficients, got {coeffs.shape[-2]}"
        raise ValueError(msg)
    basis = sh_basis(degree, tnf.normalize(dirs, dim=-1))
    rgb = (basis[..., None] * coeffs[..., :n_basis, :]).sum(dim=-2)
    return torch.clamp_min(rgb + 0.5, 0.0)


# ------------------------------------------------------------------------- tiles, composite


def tile_boxes(
    means2d: torch.Tensor,
    radii: torch.Tensor,
    tiles_x: int,
    tiles_y: int,
    tile_size: int = TILE_SIZE,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """The tiles each Gaussian's box covers: ``(x0, x1, y0, y1)``, int64, ends exclusive.

    Args:
        means2d: ``[N, 2]`` centres, pixels.
        radii: ``[N, 2]`` box half-extents, pixels.
        tiles_x: Tiles per row (the box is clipped to the image's tiles).
        tiles_y: Tile rows.
        tile_size: Tile side, pixels.
    """
    centre = means2d / tile_size
    extent = radii.to(means2d.dtype) / tile_size
    lo = torch.floor(centre - extent).to(torch.int64)
    hi = torch.ceil(centre + extent).to(torch.int64)
    x0, x1 = lo[:, 0].clamp(0, tiles_x), hi[:, 0].clamp(0, tiles_x)
    y0, y1 = lo[:, 1].clamp(0, tiles_y), hi[:, 1].clamp(0, tiles_y)
    return x0, x1, y0, y1


def _tile_intersections(
    means2d: torch.Tensor,
    radii: torch.Tensor,
    depths: torch.Tensor,
    tiles_x: int,
    tiles_y: int,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Return ``(tile_ids, gauss_ids)`` of every (tile, Gaussian) pair, sorted by tile then depth.

    Args:
        means2d: ``[N, 2]`` pixels.
        radii: ``[N, 2]`` int32 (0 = culled).
        depths: ``[N]``.
        tiles_x: Tiles per row.
        tiles_y: Tile rows.
    """
    with torch.no_grad():
        device = means2d.device
        visible = torch.nonzero((radii > 0).all(dim=-1)).flatten()
        x0, x1, y0, y1 = tile_boxes(means2d[visible], radii[visible], tiles_x, tiles_y)
        w = x1 - x0
        counts = w * (y1 - y0)
        total = int(counts.sum())
        if total == 0:
            empty = torch.zeros(0, dtype=torch.int64, device=device)
            return empty, empty
        owner = torch.repeat_interleave(torch.arange(len(visible), device=device), counts)
        first = torch.cumsum(counts, 0) - counts
        local = torch.arange(total, device=device) - first[owner]
        w_own = w[owner]
        tile_ids = (y0[owner] + local // w_own) * tiles_x + x0[owner] + local % w_own
        gauss_ids = visible[owner]
        # Rank by depth, ties by index (a stable sort), then order by (tile, rank).
        by_depth = torch.sort(depths, stable=True).indices
        rank = torch.empty_like(by_depth)
        rank[by_depth] = torch.arange(len(depths), device=device)
        order = torch.argsort(tile_ids * len(depths) + rank[gauss_ids])
        return tile_ids[order], gauss_ids[order]


def _tile_batches(counts: list[int], pixels: int, max_elements: int) -> list[tuple[int, int]]:
    """Split tiles sorted by ascending Gaussian count into ``[start, end)`` batches.

    A batch pads every tile to its longest list, so a batch ends where padding would waste
    much (a list over 1.5 times the first plus 32) or the element budget would be exceeded.
    """
    batches = []
    start = 0
    while start < len(counts):
        end = start + 1
        limit = 1.5 * counts[start] + 32
        while (
            end < len(counts)
            and counts[end] <= limit
            and (end + 1 - start) * counts[end] * pixels <= max_elements
        ):
            end += 1
        batches.append((start, end))
        start = end
    return batches


def _composite(  # noqa: PLR0913 -- the per-image compositing state, kept explicit
    means2d: torch.Tensor,
    conics: torch.Tensor,
    opacities: torch.Tensor,
    colors: torch.Tensor,
    tile_ids: torch.Tensor,
    gauss_ids: torch.Tensor,
    *,
    tiles_x: int,
    tiles_y: int,
    max_elements: int,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Composite one image tile by tile (step 5 of the module doc).

    Returns:
        ``[tiles_y * 16, tiles_x * 16, D]`` colours without background, and
        ``[tiles_y * 16, tiles_x * 16]`` accumulated alpha.
    """
    device, dtype = means2d.device, means2d.dtype
    n, d = colors.shape
    n_tiles = tiles_x * tiles_y
    pixels = TILE_SIZE * TILE_SIZE
    counts = torch.bincount(tile_ids, minlength=n_tiles)
    starts = torch.cumsum(counts, 0) - counts
    busy = torch.nonzero(counts).flatten()
    busy = busy[torch.argsort(counts[busy], stable=True)]

    # The quadratic form q/2 of a Gaussian over a tile's pixels, in tile-local coordinates
    # (u, v) = mean - tile origin and (lx, ly) = pixel centre - tile origin, is
    #   A (u - lx)^2 + B (u - lx)(v - ly) + C (v - ly)^2   with A = a/2, B = b, C = c/2,
    # a polynomial in the pixel monomials (1, lx, ly, lx^2, lx ly, ly^2). One matmul of six
    # per-Gaussian coefficients by six per-pixel monomials gives it for every pixel; -log(o)
    # joins the constant so that exp(-result) is o exp(-q/2). The conic is positive definite,
    # so the form is never negative (gsplat's "sigma < 0" test cannot fire); rounding is
    # clamped. Index n is a padding Gaussian whose constant term makes its alpha 0.
    local = torch.arange(pixels, device=device)
    lx = (local % TILE_SIZE).to(dtype) + 0.5
    ly = (local // TILE_SIZE).to(dtype) + 0.5
    monomials = torch.stack((torch.ones_like(lx), lx, ly, lx * lx, lx * ly, ly * ly))
    half_a, b, half_c = 0.5 * conics[:, 0], conics[:, 1], 0.5 * conics[:, 2]
    neg_log_opac = -torch.log(opacities.clamp_min(1e-30))
    pad = means2d.new_zeros(1)
    mx_p, my_p = torch.cat((means2d[:, 0], pad)), torch.cat((means2d[:, 1], pad))
    a_p, b_p, c_p = torch.cat((half_a, pad)), torch.cat((b, pad)), torch.cat((half_c, pad))
    const_p = torch.cat((neg_log_opac, pad + 1e4))
    colors_p = torch.cat((colors, colors.new_zeros(1, d)))

    done_tiles, done_rgb, done_acc = [], [], []
    busy_counts = counts[busy].tolist()
    for start, end in _tile_batches(busy_counts, pixels, max_elements):
        tiles = busy[start:end]
        k = torch.arange(busy_counts[end - 1], device=device)
        slot = starts[tiles, None] + k
        g = torch.where(k < counts[tiles, None], gauss_ids[slot.clamp(max=len(gauss_ids) - 1)], n)
        u = mx_p[g] - ((tiles % tiles_x) * TILE_SIZE).to(dtype)[:, None]
        v = my_p[g] - ((tiles // tiles_x) * TILE_SIZE).to(dtype)[:, None]
        qa, qb, qc = a_p[g], b_p[g], c_p[g]
        coeffs = torch.stack(
            (
                qa * u * u + qb * u * v + qc * v * v + const_p[g],
                -2.0 * qa * u - qb * v,
                -qb * u - 2.0 * qc * v,
                qa,
                qb,
                qc,
            ),
            dim=-1,
        )
        exponent = coeffs @ monomials
        # Beyond 60 the alpha is far below 1/255; the clamp also keeps exp() out of the
        # denormal range, which is many times slower on CPUs.
        alpha = torch.clamp(torch.exp(-torch.clamp(exponent, 0.0, 60.0)), max=ALPHA_MAX)
        alpha = torch.where(alpha >= ALPHA_THRESHOLD, alpha, 0.0)
        after = torch.cumprod(1.0 - alpha, dim=1)
        before = torch.cat((torch.ones_like(after[:, :1]), after[:, :-1]), dim=1)
        weight = torch.where(after > TRANSMITTANCE_MIN, alpha * before, 0.0)
        done_rgb.append(torch.einsum("tkp,tkd->tpd", weight, colors_p[g]))
        done_acc.append(weight.sum(dim=1))
        done_tiles.append(tiles)

    rgb = torch.zeros((n_tiles, pixels, d), device=device, dtype=colors.dtype)
    acc = torch.zeros((n_tiles, pixels), device=device, dtype=dtype)
    if done_tiles:
        index = torch.cat(done_tiles)
        rgb = rgb.index_copy(0, index, torch.cat(done_rgb))
        acc = acc.index_copy(0, index, torch.cat(done_acc))
    shape = (tiles_y, tiles_x, TILE_SIZE, TILE_SIZE)
    rgb = rgb.reshape((*shape, d)).permute(0, 2, 1, 3, 4).reshape(tiles_y * TILE_SIZE, -1, d)
    acc = acc.reshape(shape).permute(0, 2, 1, 3).reshape(tiles_y * TILE_SIZE, -1)
    return rgb, acc


def _check_inputs(
    means: torch.Tensor,
    quats: torch.Tensor,
    scales: torch.Tensor,
    opacities: torch.Tensor,
    viewmats: torch.Tensor,
    Ks: torch.Tensor,
) -> None:
    n = means.shape[0]
    problems = []
    if means.shape != (n, 3):
        problems.append(f"means {tuple(means.shape)} (expected [N, 3])")
    if quats.shape != (n, 4):
        problems.append(f"quats {tuple(quats.shape)} (expected [{n}, 4])")
    if scales.shape != (n, 3):
        problems.append(f"scales {tuple(scales.shape)} (expected [{n}, 3])")
    if opacities.shape != (n,):
        problems.append(f"opacities {tuple(opacities.shape)} (expected [{n}])")
    if viewmats.ndim != 3 or viewmats.shape[1:] != (4, 4):
        problems.append(f"viewmats {tuple(viewmats.shape)} (expected [C, 4, 4])")
    if Ks.shape != (viewmats.shape[0], 3, 3):
        problems.append(f"Ks {tuple(Ks.shape)} (expected [C, 3, 3])")
    if problems:
        msg = "rasterization inputs have wrong shapes: " + ", ".join(problems)
        raise ValueError(msg)


def _view_colours(
    means: torch.Tensor, colors: torch.Tensor, viewmats: torch.Tensor, sh_degree: int | None
) -> torch.Tensor:
    """``[C, N, D]``: each Gaussian's colour as each camera sees it (SH evaluated towards it)."""
    n_cams, n = viewmats.shape[0], means.shape[0]
    if sh_degree is not None:
        if colors.ndim != 3 or colors.shape[0] != n or colors.shape[2] != 3:
            msg = f"SH colours must be [N, K, 3] with N={n}, got {tuple(colors.shape)}"
            raise ValueError(msg)
        campos = torch.linalg.inv(viewmats)[:, :3, 3]
        dirs = means[None, :, :] - campos[:, None, :]
        if sh_cpu.applies(dirs, colors):
            return sh_cpu.colors(colors[:, :1], colors[:, 1:], dirs, sh_degree)
        return rgb_from_sh(colors[None].expand(n_cams, -1, -1, -1), dirs, sh_degree)
    if colors.ndim == 2 and colors.shape[0] == n:
        return colors[None].expand(n_cams, -1, -1)
    if colors.ndim == 3 and colors.shape[:2] == (n_cams, n):
        return colors
    msg = f"colours must be [N, D] or [C, N, D] with C={n_cams}, N={n}, got {colors.shape}"
    raise ValueError(msg)


def _compositor(
    compositing: Literal["auto", "compiled", "torch"],
    means: torch.Tensor,
    max_elements: int,
    tiles: tuple[int, int],
) -> Callable[..., tuple[torch.Tensor, torch.Tensor]]:
    """Step 5 as asked, its tile grid bound (``auto``: compiled for float32 on a numba CPU)."""
    compiled = compositing == "compiled" or (
        compositing == "auto"
        and means.device.type == "cpu"
        and means.dtype == torch.float32
        and raster_cpu.available()
    )
    step = raster_cpu.composite if compiled else partial(_composite, max_elements=max_elements)
    return partial(step, tiles_x=tiles[0], tiles_y=tiles[1])


def _composite_views(
    proj: Projection,
    view_opacities: torch.Tensor,
    per_cam: torch.Tensor,
    composite: Callable[..., tuple[torch.Tensor, torch.Tensor]],
    band: tuple[int, int],
    width: int,
    backgrounds: torch.Tensor | None,
) -> tuple[list[torch.Tensor], list[torch.Tensor]]:
    """Each camera's image and alpha over the rows ``band`` (steps 4 and 5 of the module doc).

    ``composite`` is step 5 with its tile grid bound (``tiles_x``, ``tiles_y`` keywords).
    """
    first, stop = band
    tiles_x, tiles_y = math.ceil(width / TILE_SIZE), math.ceil((stop - first) / TILE_SIZE)
    # Pixels of the band are the image's rows shifted by ``first``: so are the centres.
    shift = torch.tensor([0.0, float(first)], dtype=proj.means2d.dtype, device=per_cam.device)
    images, alphas = [], []
    for cam in range(per_cam.shape[0]):
        means2d = proj.means2d[cam] - shift if first else proj.means2d[cam]
        tile_ids, gauss_ids = _tile_intersections(
            means2d, proj.radii[cam], proj.depths[cam], tiles_x, tiles_y
        )
        rgb, acc = composite(
            means2d, proj.conics[cam], view_opacities[cam], per_cam[cam], tile_ids, gauss_ids
        )
        rgb, acc = rgb[: stop - first, :width], acc[: stop - first, :width]
        if backgrounds is not None:
            rgb = rgb + (1.0 - acc)[..., None] * backgrounds[cam]
        images.append(rgb)
        alphas.append(acc[..., None])
    return images, alphas


def _screen_info(
    proj: Projection,
    view_opacities: torch.Tensor,
    width: int,
    height: int,
    tiles_x: int,
    tiles_y: int,
) -> dict[str, Any]:
    """The screen-space meta of a rasterization, with gsplat's keys (densification reads it)."""
    return {
        "means2d": proj.means2d,
        "radii": proj.radii,
        "depths": proj.depths,
        "conics": proj.conics,
        "opacities": view_opacities,
        "width": width,
        "height": height,
        "n_cameras": view_opacities.shape[0],
        "tile_size": TILE_SIZE,
        "tile_width": tiles_x,
        "tile_height": tiles_y,
        "gaussian_ids": None,
        "camera_ids": None,
        "batch_ids": None,
    }


def rasterization(  # noqa: PLR0913, PLR0917 -- mirrors gsplat.rasterization's signature on purpose
    means: torch.Tensor,
    quats: torch.Tensor,
    scales: torch.Tensor,
    opacities: torch.Tensor,
    colors: torch.Tensor,
    viewmats: torch.Tensor,
    Ks: torch.Tensor,
    width: int,
    height: int,
    *,
    near_plane: float = 0.01,
    far_plane: float = 1e10,
    eps2d: float = 0.3,
    sh_degree: int | None = None,
    backgrounds: torch.Tensor | None = None,
    max_elements: int = _MAX_ELEMENTS,
    compositing: Literal["auto", "compiled", "torch"] = "auto",
    rows: tuple[int, int] | None = None,
    antialiased: bool = False,
) -> RasterOutput:
    """Render Gaussians into ``C`` images (see :func:`cam2sim.splat.raster.rasterize`).

    Args:
        means: ``[N, 3]`` world positions.
        quats: ``[N, 4]`` ``(w, x, y, z)``.
        scales: ``[N, 3]`` standard deviations.
        opacities: ``[N]`` in ``[0, 1]``.
        colors: ``[N, D]`` or ``[C, N, D]`` colours, or ``[N, K, 3]`` SH coefficients when
            ``sh_degree`` is given.
        viewmats: ``[C, 4, 4]`` world -> camera.
        Ks: ``[C, 3, 3]`` intrinsics.
        width: Image width, pixels.
        height: Image height, pixels.
        near_plane: Minimum camera z.
        far_plane: Maximum camera z.
        eps2d: 2-D dilation, pixels squared.
        sh_degree: SH degree, or None for plain colours.
        backgrounds: ``[C, D]`` background colours, or None (zeros).
        max_elements: Bound on (tile, Gaussian, pixel) elements per compositing batch.
        compositing: Step 5 on the CPU: ``"compiled"`` (:mod:`cam2sim.splat.raster_cpu`,
            numba, float32; several times faster), ``"torch"`` (this module's batched
            tensors, any device and dtype) or ``"auto"`` (compiled for float32 on the CPU
            when numba is installed).
        rows: Composite only rows ``[first, stop)`` of the ``width`` x ``height`` image; the
            projection is the whole image's (the same covariances, the same pixels), only
            fewer pixels are composited. The images are ``stop - first`` rows high.
        antialiased: Scale each Gaussian's opacity by its compensation in each view
            (gsplat's ``rasterize_mode="antialiased"``, Mip-Splatting's 2-D filter).

    Returns:
        Images, alphas and screen-space data (``backend="torch"``).
    """
    _check_inputs(means, quats, scales, opacities, viewmats, Ks)
    n_cams = viewmats.shape[0]
    proj = project_gaussians(
        means,
        quats,
        scales,
        opacities,
        viewmats,
        Ks,
        width,
        height,
        eps2d=eps2d,
        near_plane=near_plane,
        far_plane=far_plane,
        compensate=antialiased,
    )
    # [C, N] opacities as each view composites them (compensated in antialiased mode).
    view_opacities = (
        opacities[None] * proj.compensations
        if proj.compensations is not None
        else opacities[None].expand(n_cams, -1)
    )
    per_cam = _view_colours(means, colors, viewmats, sh_degree)

    first, stop = row_window(rows, height)
    tiles_x = math.ceil(width / TILE_SIZE)
    tiles_y = math.ceil((stop - first) / TILE_SIZE)
    composite = _compositor(compositing, means, max_elements, (tiles_x, tiles_y))
    images, alphas = _composite_views(
        proj, view_opacities, per_cam, composite, (first, stop), width, backgrounds
    )
    info = _screen_info(proj, view_opacities, width, height, tiles_x, tiles_y)
    return RasterOutput(
        colors=torch.stack(images),
        alphas=torch.stack(alphas),
        means2d=proj.means2d,
        radii=proj.radii,
        depths=proj.depths,
        info=info,
        backend="torch",
    )
