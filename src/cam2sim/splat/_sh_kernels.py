"""numba kernels of :mod:`cam2sim.splat.sh_cpu` (imported only there, as it imports numba).

The real SH basis of 3DGS (:func:`cam2sim.splat.raster_torch.sh_basis`) and its derivatives,
written out per Gaussian. Module-level functions, so that numba's on-disk cache keeps them.
"""

from __future__ import annotations

from typing import Any, Final

import numba
import numpy as np

from cam2sim.splat.sh_constants import SH_C0, SH_C1, SH_C2, SH_C3

_EPS: Final = 1e-12
"""``torch.nn.functional.normalize``'s floor on the norm."""

_BLOCK: Final = 1024
"""Gaussians a parallel iteration takes (its scratch arrays allocated once for them)."""

_jit = numba.njit(parallel=True, fastmath=False, cache=True, nogil=True)
_jit_serial = numba.njit(cache=True, nogil=True)


@_jit_serial
def basis(x: float, y: float, z: float, degree: int, out: Any) -> None:
    """The ``(degree + 1) ** 2`` basis values at the unit direction ``(x, y, z)`` into ``out``."""
    out[0] = SH_C0
    if degree < 1:
        return
    out[1] = -SH_C1 * y
    out[2] = SH_C1 * z
    out[3] = -SH_C1 * x
    if degree < 2:
        return
    xx, yy, zz = x * x, y * y, z * z
    out[4] = SH_C2[0] * x * y
    out[5] = SH_C2[1] * y * z
    out[6] = SH_C2[2] * (2.0 * zz - xx - yy)
    out[7] = SH_C2[3] * x * z
    out[8] = SH_C2[4] * (xx - yy)
    if degree < 3:
        return
    out[9] = SH_C3[0] * y * (3.0 * xx - yy)
    out[10] = SH_C3[1] * x * y * z
    out[11] = SH_C3[2] * y * (4.0 * zz - xx - yy)
    out[12] = SH_C3[3] * z * (2.0 * zz - 3.0 * xx - 3.0 * yy)
    out[13] = SH_C3[4] * x * (4.0 * zz - xx - yy)
    out[14] = SH_C3[5] * z * (xx - yy)
    out[15] = SH_C3[6] * x * (xx - 3.0 * yy)


@_jit_serial
def basis_grad(x: float, y: float, z: float, degree: int, v_b: Any, out: Any) -> None:
    """``sum_k v_b[k] d basis_k / d(x, y, z)`` into ``out[0:3]`` (the polynomials' gradients)."""
    gx = gy = gz = 0.0
    if degree >= 1:
        gx -= SH_C1 * v_b[3]
        gy -= SH_C1 * v_b[1]
        gz += SH_C1 * v_b[2]
    if degree >= 2:
        c2 = SH_C2
        gx += c2[0] * y * v_b[4] - 2.0 * c2[2] * x * v_b[6] + c2[3] * z * v_b[7]
        gx += 2.0 * c2[4] * x * v_b[8]
        gy += c2[0] * x * v_b[4] + c2[1] * z * v_b[5] - 2.0 * c2[2] * y * v_b[6]
        gy -= 2.0 * c2[4] * y * v_b[8]
        gz += c2[1] * y * v_b[5] + 4.0 * c2[2] * z * v_b[6] + c2[3] * x * v_b[7]
    if degree >= 3:
        c3 = SH_C3
        xx, yy, zz = x * x, y * y, z * z
        gx += 6.0 * c3[0] * x * y * v_b[9] + c3[1] * y * z * v_b[10]
        gx += -2.0 * c3[2] * x * y * v_b[11] - 6.0 * c3[3] * x * z * v_b[12]
        gx += c3[4] * (4.0 * zz - 3.0 * xx - yy) * v_b[13] + 2.0 * c3[5] * x * z * v_b[14]
        gx += c3[6] * (3.0 * xx - 3.0 * yy) * v_b[15]
        gy += c3[0] * (3.0 * xx - 3.0 * yy) * v_b[9] + c3[1] * x * z * v_b[10]
        gy += c3[2] * (4.0 * zz - xx - 3.0 * yy) * v_b[11] - 6.0 * c3[3] * y * z * v_b[12]
        gy += -2.0 * c3[4] * x * y * v_b[13] - 2.0 * c3[5] * y * z * v_b[14]
        gy += -6.0 * c3[6] * x * y * v_b[15]
        gz += c3[1] * x * y * v_b[10] + 8.0 * c3[2] * y * z * v_b[11]
        gz += c3[3] * (6.0 * zz - 3.0 * xx - 3.0 * yy) * v_b[12] + 8.0 * c3[4] * x * z * v_b[13]
        gz += c3[5] * (xx - yy) * v_b[14]
    out[0], out[1], out[2] = gx, gy, gz


@_jit
def forward(dirs: Any, sh0: Any, shn: Any, degree: int, out: Any) -> None:
    """``out[c, i] = max(sum_k basis_k(dirs[c, i] / |dirs[c, i]|) coeff_k + 0.5, 0)``.

    ``sh0``: ``[N, 3]`` degree-0 coefficients; ``shn``: ``[N, J, 3]`` the higher ones
    (``J >= (degree + 1) ** 2 - 1``).
    """
    n_cams, n = dirs.shape[0], dirs.shape[1]
    n_basis = (degree + 1) ** 2
    for blk in numba.prange((n + _BLOCK - 1) // _BLOCK):
        b = np.empty(16, np.float64)
        for i in range(blk * _BLOCK, min(n, (blk + 1) * _BLOCK)):
            for c in range(n_cams):
                dx, dy, dz = dirs[c, i, 0], dirs[c, i, 1], dirs[c, i, 2]
                norm = max(np.sqrt(dx * dx + dy * dy + dz * dz), _EPS)
                basis(dx / norm, dy / norm, dz / norm, degree, b)
                for ch in range(3):
                    v = b[0] * sh0[i, ch]
                    for k in range(1, n_basis):
                        v += b[k] * shn[i, k - 1, ch]
                    out[c, i, ch] = max(v + 0.5, 0.0)


@_jit
def backward(  # noqa: PLR0913, PLR0917 -- flat arrays are what numba takes
    dirs: Any, sh0: Any, shn: Any, degree: int, out: Any, g_out: Any,
    v_dirs: Any, v_sh0: Any, v_shn: Any,
) -> None:  # fmt: skip
    """Gradients of :func:`forward` (``out`` its result) for the output gradient ``g_out``.

    ``v_sh0`` and ``v_shn`` are summed over the cameras (zero beyond the degree's bands);
    ``v_dirs`` gets each camera's own.
    """
    n_cams, n = dirs.shape[0], dirs.shape[1]
    n_basis = (degree + 1) ** 2
    for blk in numba.prange((n + _BLOCK - 1) // _BLOCK):
        b = np.empty(16, np.float64)
        v_b = np.empty(16, np.float64)
        v_u = np.empty(3, np.float64)
        g = np.empty(3, np.float64)
        for i in range(blk * _BLOCK, min(n, (blk + 1) * _BLOCK)):
            for c in range(n_cams):
                dx, dy, dz = dirs[c, i, 0], dirs[c, i, 1], dirs[c, i, 2]
                raw = np.sqrt(dx * dx + dy * dy + dz * dz)
                norm = max(raw, _EPS)
                x, y, z = dx / norm, dy / norm, dz / norm
                basis(x, y, z, degree, b)
                for ch in range(3):  # no gradient where the colour was clamped to 0
                    g[ch] = g_out[c, i, ch] if out[c, i, ch] > 0.0 else 0.0
                for ch in range(3):
                    v_sh0[i, ch] += b[0] * g[ch]
                    for k in range(1, n_basis):
                        v_shn[i, k - 1, ch] += b[k] * g[ch]
                for k in range(n_basis):
                    v_b[k] = (
                        g[0] * (sh0[i, 0] if k == 0 else shn[i, k - 1, 0])
                        + g[1] * (sh0[i, 1] if k == 0 else shn[i, k - 1, 1])
                        + g[2] * (sh0[i, 2] if k == 0 else shn[i, k - 1, 2])
                    )
                basis_grad(x, y, z, degree, v_b, v_u)
                if raw > _EPS:  # through the normalisation: (I - u u^T) / |d|
                    dot = x * v_u[0] + y * v_u[1] + z * v_u[2]
                    v_dirs[c, i, 0] = (v_u[0] - x * dot) / raw
                    v_dirs[c, i, 1] = (v_u[1] - y * dot) / raw
                    v_dirs[c, i, 2] = (v_u[2] - z * dot) / raw
                else:  # below the floor the direction is d / eps, linear in d
                    v_dirs[c, i, 0] = v_u[0] / _EPS
                    v_dirs[c, i, 1] = v_u[1] / _EPS
                    v_dirs[c, i, 2] = v_u[2] / _EPS
