"""numba kernels of :mod:`cam2sim.splat.raster_cpu` (imported only there, as it imports numba).

Module-level functions, so that numba's on-disk cache keeps them between processes.
"""

from __future__ import annotations

from typing import Any, Final

import numba
import numpy as np

_TILE: Final = 16
_ALPHA_MAX: Final = 0.999
_ALPHA_MIN: Final = 1.0 / 255.0
_T_MIN: Final = 1e-4
_SIGMA_MAX: Final = 5.6
"""Above this ``o exp(-sigma)`` is below 1/255 for any opacity ``o <= 1``: skipped early."""

_jit = numba.njit(parallel=True, fastmath=False, cache=True, nogil=True)
_jit_serial = numba.njit(cache=True, nogil=True)


@_jit_serial
def gather(  # noqa: PLR0913, PLR0917 -- flat arrays are what numba takes
    means2d: Any, conics: Any, opac: Any, ids: Any, s0: int, s1: int, ox: int, oy: int,
    local: Any, rows: Any, row_len: Any,
) -> None:  # fmt: skip
    """Gather one tile's Gaussians (front to back) into local columns.

    Per tile row, ``rows`` lists the positions of the Gaussians whose extent (where
    ``o exp(-sigma) >= 1/255``) reaches that row.
    """
    row_len[:] = 0
    for k in range(s1 - s0):
        g = ids[s0 + k]
        ca, cb, cc, o = conics[g, 0], conics[g, 1], conics[g, 2], opac[g]
        local[k, 0] = means2d[g, 0]
        local[k, 1] = means2d[g, 1]
        local[k, 2] = ca
        local[k, 3] = cb
        local[k, 4] = cc
        local[k, 5] = o
        det = ca * cc - cb * cb
        level = np.log(max(o, np.float32(_ALPHA_MIN)) * np.float32(255.0))
        if det <= 0.0 or level <= 0.0:
            continue  # never reaches alpha 1/255
        half_y = np.sqrt(2.0 * level * ca / det) + 1.0  # + 1: pixel-centre slack
        half_x = np.sqrt(2.0 * level * cc / det) + 1.0
        local[k, 6] = means2d[g, 0] - half_x - ox
        local[k, 7] = means2d[g, 0] + half_x - ox
        lo = max(0, int(np.floor(means2d[g, 1] - half_y - oy)))
        hi = min(_TILE - 1, int(np.ceil(means2d[g, 1] + half_y - oy)))
        for ly in range(lo, hi + 1):
            rows[ly, row_len[ly]] = k
            row_len[ly] += 1


@_jit_serial
def tile_locals(
    means2d: Any, conics: Any, opac: Any, ids: Any, s0: int, s1: int, tile: int, tiles_x: int
) -> tuple[int, int, Any, Any, Any]:
    """A tile's pixel origin and its gathered Gaussians (:func:`gather`), freshly allocated."""
    ox = (tile % tiles_x) * _TILE
    oy = (tile // tiles_x) * _TILE
    n = s1 - s0
    local = np.zeros((n, 8), np.float32)
    rows = np.empty((_TILE, n), np.int32)
    row_len = np.zeros(_TILE, np.int32)
    gather(means2d, conics, opac, ids, s0, s1, ox, oy, local, rows, row_len)
    return ox, oy, local, rows, row_len


@_jit_serial
def _columns(local: Any, k: int) -> tuple[int, int]:
    """The tile columns ``[lo, hi]`` whose pixel centres may lie in Gaussian ``k``'s extent.

    A superset by at most float rounding: the kernels test each centre against the extent
    again, as a loop over every column would.
    """
    lo = max(0, int(np.ceil(local[k, 6] - np.float32(0.5))))
    hi = min(_TILE - 1, int(np.floor(local[k, 7] - np.float32(0.5))))
    return lo, hi


@_jit
def forward(  # noqa: PLR0913, PLR0917 -- flat arrays are what numba takes
    means2d: Any, conics: Any, opac: Any, colors: Any, starts: Any, ids: Any,
    tiles_x: int, n_tiles: int, out_rgb: Any, out_t: Any, out_last: Any,
) -> None:  # fmt: skip
    """Front to back, a tile row at a time: each Gaussian of the row over the columns it covers.

    Each pixel meets the same Gaussians in the same order, with the same arithmetic (its
    transmittance in float64), as a loop over the row's Gaussians for every pixel would, so the
    images are the same bit for bit; a Gaussian's extent is found once for the 16 pixels of a
    row instead of tested at each (about a third less time on the demo's views). The row ends
    once all 16 pixels have run out of transmittance.
    """
    d = colors.shape[1]
    for tile in numba.prange(n_tiles):
        acc = np.zeros((_TILE, d), np.float32)
        trans = np.ones(_TILE, np.float64)
        last = np.zeros(_TILE, np.int32)
        done = np.zeros(_TILE, np.bool_)
        _forward_tile(
            means2d, conics, opac, colors, starts, ids, tile, tiles_x, out_rgb, out_t,
            out_last, acc, trans, last, done,
        )  # fmt: skip


@_jit_serial
def _forward_tile(  # noqa: PLR0913, PLR0917
    means2d: Any, conics: Any, opac: Any, colors: Any, starts: Any, ids: Any, tile: int,
    tiles_x: int, out_rgb: Any, out_t: Any, out_last: Any, acc: Any, trans: Any, last: Any,
    done: Any,
) -> None:  # fmt: skip
    """One tile of :func:`forward`, with its thread's row buffers."""
    d = colors.shape[1]
    s0, s1 = starts[tile], starts[tile + 1]
    if s0 == s1:
        return
    ox, oy, local, rows, row_len = tile_locals(means2d, conics, opac, ids, s0, s1, tile, tiles_x)
    n = s1 - s0
    for ly in range(_TILE):
        py = oy + ly + np.float32(0.5)
        acc[:, :] = 0.0
        trans[:] = 1.0
        last[:] = n
        done[:] = False
        n_done = 0
        for r in range(row_len[ly]):
            k = rows[ly, r]
            lo, hi = _columns(local, k)
            ca, cb, cc, o = local[k, 2], local[k, 3], local[k, 4], local[k, 5]
            dy = local[k, 1] - py
            g = ids[s0 + k]
            for lx in range(lo, hi + 1):
                fx = lx + np.float32(0.5)
                if done[lx] or fx < local[k, 6] or fx > local[k, 7]:
                    continue
                dx = local[k, 0] - (ox + fx)
                sigma = np.float32(0.5) * (ca * dx * dx + cc * dy * dy) + cb * dx * dy
                if sigma < 0.0 or sigma > _SIGMA_MAX:
                    continue
                alpha = min(np.float32(_ALPHA_MAX), o * np.exp(-sigma))
                if alpha < _ALPHA_MIN:
                    continue
                t = trans[lx]
                nt = t * (np.float32(1.0) - alpha)
                if nt <= _T_MIN:
                    last[lx] = k
                    done[lx] = True
                    n_done += 1
                    continue
                w = alpha * t
                for c in range(d):
                    acc[lx, c] += colors[g, c] * w
                trans[lx] = nt
            if n_done == _TILE:
                break
        y = oy + ly
        for lx in range(_TILE):
            for c in range(d):
                out_rgb[y, ox + lx, c] = acc[lx, c]
            out_t[y, ox + lx] = trans[lx]
            out_last[y, ox + lx] = last[lx]


@_jit
def backward(  # noqa: PLR0912, PLR0913, PLR0915, PLR0917 -- the chain rule, kept inline
    means2d: Any, conics: Any, opac: Any, colors: Any, starts: Any, ids: Any,
    tiles_x: int, n_tiles: int, out_t: Any, out_last: Any, g_rgb: Any, g_acc: Any,
    v_means: Any, v_conics: Any, v_opac: Any, v_colors: Any,
) -> None:  # fmt: skip
    """Back to front from each pixel's stop, a tile row at a time, as :func:`forward` runs.

    A Gaussian's gradients gather over the pixels of a row in the order a loop pixel by pixel
    adds them (rows, then columns), so the sums are the same bit for bit.
    """
    d = colors.shape[1]
    groups = v_means.shape[0]
    for grp in numba.prange(groups):
        buf = np.zeros((_TILE, d), np.float32)
        trans = np.zeros(_TILE, np.float64)
        for tile in range(grp, n_tiles, groups):
            s0, s1 = starts[tile], starts[tile + 1]
            if s0 == s1:
                continue
            ox, oy, local, rows, row_len = tile_locals(
                means2d, conics, opac, ids, s0, s1, tile, tiles_x
            )
            for ly in range(_TILE):
                y = oy + ly
                py = y + np.float32(0.5)
                buf[:, :] = 0.0
                top = 0
                for lx in range(_TILE):
                    trans[lx] = out_t[y, ox + lx]
                    top = max(top, out_last[y, ox + lx])
                for r in range(row_len[ly] - 1, -1, -1):
                    k = rows[ly, r]
                    if k >= top:
                        continue  # behind every pixel's stop
                    lo, hi = _columns(local, k)
                    ca, cb, cc, o = local[k, 2], local[k, 3], local[k, 4], local[k, 5]
                    dy = local[k, 1] - py
                    g = ids[s0 + k]
                    for lx in range(lo, hi + 1):
                        x = ox + lx
                        fx = lx + np.float32(0.5)
                        if k >= out_last[y, x] or fx < local[k, 6] or fx > local[k, 7]:
                            continue
                        dx = local[k, 0] - (x + np.float32(0.5))
                        sigma = np.float32(0.5) * (ca * dx * dx + cc * dy * dy) + cb * dx * dy
                        if sigma < 0.0 or sigma > _SIGMA_MAX:
                            continue
                        vis = np.exp(-sigma)
                        raw = o * vis
                        alpha = min(np.float32(_ALPHA_MAX), raw)
                        if alpha < _ALPHA_MIN:
                            continue
                        ra = np.float32(1.0) / (np.float32(1.0) - alpha)
                        t = trans[lx] * ra  # transmittance in front of this Gaussian
                        trans[lx] = t
                        w = alpha * t
                        v_alpha = g_acc[y, x] * out_t[y, x] * ra
                        for c in range(d):
                            gc = g_rgb[y, x, c]
                            v_colors[grp, g, c] += w * gc
                            v_alpha += (colors[g, c] * t - buf[lx, c] * ra) * gc
                            buf[lx, c] += colors[g, c] * w
                        if raw > _ALPHA_MAX:
                            continue  # clamped: no gradient through alpha
                        v_opac[grp, g] += vis * v_alpha
                        v_sigma = -raw * v_alpha
                        v_conics[grp, g, 0] += np.float32(0.5) * dx * dx * v_sigma
                        v_conics[grp, g, 1] += dx * dy * v_sigma
                        v_conics[grp, g, 2] += np.float32(0.5) * dy * dy * v_sigma
                        v_means[grp, g, 0] += (ca * dx + cb * dy) * v_sigma
                        v_means[grp, g, 1] += (cb * dx + cc * dy) * v_sigma
