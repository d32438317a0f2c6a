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


@_jit
def forward(  # noqa: PLR0913, PLR0917 -- flat arrays are what numba takes
    means2d: Any, conics: Any, opac: Any, colors: Any, starts: Any, ids: Any,
    tiles_x: int, n_tiles: int, out_rgb: Any, out_t: Any, out_last: Any,
) -> None:  # fmt: skip
    d = colors.shape[1]
    for tile in numba.prange(n_tiles):
        s0, s1 = starts[tile], starts[tile + 1]
        if s0 == s1:
            continue
        ox, oy, local, rows, row_len = tile_locals(
            means2d, conics, opac, ids, s0, s1, tile, tiles_x
        )
        n = s1 - s0
        acc = np.zeros(d, np.float32)
        for ly in range(_TILE):
            py = oy + ly + np.float32(0.5)
            for lx in range(_TILE):
                px = ox + lx + np.float32(0.5)
                fx = lx + np.float32(0.5)
                t = np.float32(1.0)
                acc[:] = 0.0
                last = n
                for r in range(row_len[ly]):
                    k = rows[ly, r]
                    if fx < local[k, 6] or fx > local[k, 7]:
                        continue
                    dx = local[k, 0] - px
                    dy = local[k, 1] - py
                    sigma = (
                        np.float32(0.5) * (local[k, 2] * dx * dx + local[k, 4] * dy * dy)
                        + local[k, 3] * dx * dy
                    )
                    if sigma < 0.0 or sigma > _SIGMA_MAX:
                        continue
                    alpha = min(np.float32(_ALPHA_MAX), local[k, 5] * np.exp(-sigma))
                    if alpha < _ALPHA_MIN:
                        continue
                    nt = t * (np.float32(1.0) - alpha)
                    if nt <= _T_MIN:
                        last = k
                        break
                    w = alpha * t
                    g = ids[s0 + k]
                    for c in range(d):
                        acc[c] += colors[g, c] * w
                    t = nt
                y, x = oy + ly, ox + lx
                for c in range(d):
                    out_rgb[y, x, c] = acc[c]
                out_t[y, x] = t
                out_last[y, x] = last


@_jit
def backward(  # noqa: PLR0913, PLR0917 -- one pixel's chain rule, kept inline
    means2d: Any, conics: Any, opac: Any, colors: Any, starts: Any, ids: Any,
    tiles_x: int, n_tiles: int, out_t: Any, out_last: Any, g_rgb: Any, g_acc: Any,
    v_means: Any, v_conics: Any, v_opac: Any, v_colors: Any,
) -> None:  # fmt: skip
    d = colors.shape[1]
    groups = v_means.shape[0]
    for grp in numba.prange(groups):
        buf = np.zeros(d, np.float32)
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
                for lx in range(_TILE):
                    x = ox + lx
                    px = x + np.float32(0.5)
                    fx = lx + np.float32(0.5)
                    t_final = out_t[y, x]
                    t = t_final
                    ga = g_acc[y, x]
                    last = out_last[y, x]
                    buf[:] = 0.0
                    for r in range(row_len[ly] - 1, -1, -1):
                        k = rows[ly, r]
                        if k >= last or fx < local[k, 6] or fx > local[k, 7]:
                            continue
                        dx = local[k, 0] - px
                        dy = local[k, 1] - py
                        ca, cb, cc = local[k, 2], local[k, 3], local[k, 4]
                        sigma = np.float32(0.5) * (ca * dx * dx + cc * dy * dy) + cb * dx * dy
                        if sigma < 0.0 or sigma > _SIGMA_MAX:
                            continue
                        vis = np.exp(-sigma)
                        raw = local[k, 5] * vis
                        alpha = min(np.float32(_ALPHA_MAX), raw)
                        if alpha < _ALPHA_MIN:
                            continue
                        g = ids[s0 + k]
                        ra = np.float32(1.0) / (np.float32(1.0) - alpha)
                        t = t * ra  # transmittance in front of this Gaussian
                        w = alpha * t
                        v_alpha = ga * t_final * ra
                        for c in range(d):
                            gc = g_rgb[y, x, c]
                            v_colors[grp, g, c] += w * gc
                            v_alpha += (colors[g, c] * t - buf[c] * ra) * gc
                            buf[c] += colors[g, c] * w
                        if raw > _ALPHA_MAX:
                            continue  # clamped: no gradient through alpha
                        v_opac[grp, g] += vis * v_alpha
                        v_sigma = -raw * v_alpha
                        v_conics[grp, g, 0] += np.float32(0.5) * dx * dx * v_sigma
                        v_conics[grp, g, 1] += dx * dy * v_sigma
                        v_conics[grp, g, 2] += np.float32(0.5) * dy * dy * v_sigma
                        v_means[grp, g, 0] += (ca * dx + cb * dy) * v_sigma
                        v_means[grp, g, 1] += (cb * dx + cc * dy) * v_sigma
