"""Compiled SH colours for CPU training (numba), with autograd: gsplat's SH kernel for the CPU.

:meth:`cam2sim.splat.model.GaussianModel.colors` evaluated the SH colours of every Gaussian
with about a hundred small torch operations (:func:`cam2sim.splat.raster_torch.rgb_from_sh`)
after a copy of the coefficients joined into one tensor: forward and backward at 110k
Gaussians 7.7 ms at degree 0, 19.1 at degree 1 (the CPU preset's two) and 38.4 at degree 3.
This evaluates them in one pass per Gaussian (:mod:`cam2sim.splat._sh_kernels`), forward and
backward, from the degree-0 and higher coefficients as the model keeps them: 4.3, 5.9 and
9.9 ms. The function is the same, ``rgb = max(sum_k basis_k(d / |d|) coeff_k + 0.5, 0)``,
with gradients for the coefficients and the directions (``tests/splat/test_sh_cpu.py`` checks
both against the torch version). :func:`applies` says whether it runs (numba installed,
float32 on the CPU, not turned off with ``CAM2SIM_SPLAT_COMPOSITE=torch``, as the compiled
compositing).
"""

from __future__ import annotations

import functools
from typing import TYPE_CHECKING, Any

import numpy as np

from cam2sim.splat import raster_cpu

if TYPE_CHECKING:
    import torch

__all__ = ["applies", "colors"]


def applies(*tensors: torch.Tensor) -> bool:
    """Whether the compiled colours run for these tensors (float32 on the CPU, numba there)."""
    import torch  # noqa: PLC0415

    return raster_cpu.available() and all(
        t.device.type == "cpu" and t.dtype == torch.float32 for t in tensors
    )


@functools.cache
def _kernels() -> tuple[Any, Any]:
    from cam2sim.splat import _sh_kernels as k  # noqa: PLC0415 -- lazy: imports numba

    return k.forward, k.backward


def _numpy(t: torch.Tensor) -> np.ndarray[Any, Any]:
    """A view of ``t`` (strided where ``t`` is: the kernels read slices without a copy)."""
    return t.detach().numpy()


@functools.cache
def _function() -> Any:  # Any: built on first use so that torch loads lazily
    import torch  # noqa: PLC0415

    class ShColours(torch.autograd.Function):
        """SH colours of ``[C, N, 3]`` directions from ``[N, 1, 3]`` and ``[N, J, 3]``."""

        @staticmethod
        def forward(
            ctx: Any, dirs: torch.Tensor, sh0: torch.Tensor, shn: torch.Tensor, degree: int
        ) -> torch.Tensor:
            forward_kernel, _ = _kernels()
            arrays = (_numpy(dirs), _numpy(sh0[:, 0, :]), _numpy(shn))
            out = np.empty(arrays[0].shape, np.float32)
            forward_kernel(*arrays, degree, out)
            ctx.arrays, ctx.out, ctx.degree = arrays, out, degree
            return torch.from_numpy(out)

        @staticmethod
        def backward(ctx: Any, grad: torch.Tensor) -> tuple[Any, ...]:
            _, backward_kernel = _kernels()
            dirs, sh0, shn = ctx.arrays
            v_dirs = np.zeros(dirs.shape, np.float32)
            v_sh0 = np.zeros(sh0.shape, np.float32)
            v_shn = np.zeros(shn.shape, np.float32)
            backward_kernel(dirs, sh0, shn, ctx.degree, ctx.out, _numpy(grad), v_dirs, v_sh0, v_shn)
            return (
                torch.from_numpy(v_dirs),
                torch.from_numpy(v_sh0)[:, None, :],
                torch.from_numpy(v_shn),
                None,
            )

    return ShColours


def colors(sh0: torch.Tensor, shn: torch.Tensor, dirs: torch.Tensor, degree: int) -> torch.Tensor:
    """``[C, N, 3]`` colours of the Gaussians seen along ``dirs`` (camera -> Gaussian).

    Args:
        sh0: ``[N, 1, 3]`` degree-0 coefficients.
        shn: ``[N, J, 3]`` the higher ones, ``J >= (degree + 1) ** 2 - 1``.
        dirs: ``[C, N, 3]`` directions, any length.
        degree: SH degree to use (0-3).

    Raises:
        ValueError: A degree outside 0-3 or too few coefficients for it.
    """
    if not 0 <= degree <= 3:
        msg = f"SH degree must be 0 to 3, got {degree}"
        raise ValueError(msg)
    if shn.shape[1] < (degree + 1) ** 2 - 1:
        msg = f"degree {degree} needs {(degree + 1) ** 2} SH coefficients, got {1 + shn.shape[1]}"
        raise ValueError(msg)
    out: torch.Tensor = _function().apply(dirs, sh0, shn, degree)
    return out
