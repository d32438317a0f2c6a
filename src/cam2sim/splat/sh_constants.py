"""The real SH basis constants of 3DGS and gsplat, for the torch and the compiled evaluations.

Torch-free, so that :mod:`cam2sim.splat.raster_torch` and the numba kernels
(:mod:`cam2sim.splat._sh_kernels`) share them without importing each other.
"""

from __future__ import annotations

from typing import Final

__all__ = ["SH_C0", "SH_C1", "SH_C2", "SH_C3"]

SH_C0: Final = 0.28209479177387814
"""Degree-0 real SH basis constant: ``rgb = SH_C0 * sh0 + 0.5``."""

SH_C1: Final = 0.4886025119029199
"""Degree-1 constant of the real SH basis (SH_C2, SH_C3: degrees 2 and 3, one per function)."""
SH_C2: Final = (
    1.0925484305920792,
    -1.0925484305920792,
    0.31539156525252005,
    -1.0925484305920792,
    0.5462742152960396,
)
SH_C3: Final = (
    -0.5900435899266435,
    2.890611442640554,
    -0.4570457994644658,
    0.3731763325901154,
    -0.4570457994644658,
    1.445305721320277,
    -0.5900435899266435,
)
