"""Gaussian rasterization behind one switch: gsplat on CUDA, pure PyTorch everywhere else.

:func:`rasterize` takes the arguments of ``gsplat.rasterization`` (3D Gaussians in the world, one
or more pinhole cameras) and returns a :class:`RasterOutput`. The backend is chosen by name:

- ``"gsplat"``: ``gsplat.rasterization`` (CUDA kernels, JIT-built on first use);
- ``"torch"``: :func:`cam2sim.splat.raster_torch.rasterization`, differentiable plain torch on
  any device, slower, same conventions and results (see that module);
- ``"auto"``: gsplat when :func:`has_gsplat` (CUDA present and gsplat imports), else torch.

Conventions (both backends): ``viewmats`` are world -> camera (``inverse(T_world_cam)``, OpenCV
optical axes: x right, y down, z forward); ``Ks`` are pixel intrinsics with the image's top-left
corner at (0, 0) and pixel ``(i, j)`` centred at ``(j + 0.5, i + 0.5)``; quaternions are
``(w, x, y, z)``, normalised inside; ``scales`` are standard deviations in metres (already
exponentiated); ``opacities`` in ``[0, 1]`` (already through the sigmoid).

torch is imported only inside the functions; gsplat only when its backend is used.
"""

from __future__ import annotations

import functools
import importlib
import logging
from typing import TYPE_CHECKING, Literal

from cam2sim.core.errors import BackendUnavailableError
from cam2sim.splat.raster_output import RasterOutput, row_window

if TYPE_CHECKING:
    import torch

__all__ = [
    "GSPLAT_TILE",
    "INSTALL_HINT",
    "RasterBackend",
    "RasterOutput",
    "build_gsplat",
    "has_cuda",
    "has_gsplat",
    "rasterize",
    "resolve_backend",
    "resolve_device",
]

_log = logging.getLogger(__name__)

RasterBackend = Literal["auto", "gsplat", "torch"]
"""Name of a rasterizer backend (see the module doc)."""

GSPLAT_TILE = 8
"""gsplat's tile side, pixels. Each tile is one thread block that walks the tile's depth-sorted
Gaussians for all its pixels, so a Gaussian a few pixels wide costs the whole tile's threads.
Street scenes are mostly such Gaussians (on the 1,500-frame route, 52 % of the tile pairs are
Gaussians under 4 px, 57 % lie beyond 25 m): 8x8 tiles take the forward and backward pass from
19.8 to 12.2 ms a view and a chunk's training from 93 to 64 s (``docs/benchmarks.md``). The
images are the same for every size."""

INSTALL_HINT = "pip install 'cam2sim[splat-cuda]' on a machine with an NVIDIA GPU and CUDA"
"""What to install for the gsplat backend."""


def has_cuda() -> bool:
    """Whether torch is installed and sees a CUDA device."""
    try:
        import torch  # noqa: PLC0415
    except ImportError:
        return False
    return bool(torch.cuda.is_available())


@functools.cache
def has_gsplat() -> bool:
    """Whether the gsplat backend can run here: a CUDA device and an importable gsplat.

    Importing gsplat 1.5.x builds nothing; its CUDA extension is compiled (or loaded from the
    torch extension cache) on the first rasterization.
    """
    if not has_cuda():
        return False
    try:
        importlib.import_module("gsplat")
    except ImportError as err:
        _log.debug("gsplat does not import: %s", err)
        return False
    return True


def build_gsplat() -> None:
    """Build (or load) gsplat's CUDA extension now rather than inside a first training step.

    gsplat compiles its extension on first use (about a minute on a fresh machine); built here,
    that minute does not count as training time, and worker processes spawned afterwards load it.

    Raises:
        BackendUnavailableError: The extension does not build or load.
    """
    try:
        extension = importlib.import_module("gsplat.cuda._backend")
    except ImportError as err:
        msg = f"gsplat's CUDA extension does not build or load ({err}); check nvcc and "
        msg += "TORCH_EXTENSIONS_DIR, or train with backend 'torch'"
        raise BackendUnavailableError(msg) from err
    if getattr(extension, "_C", None) is None:
        msg = "gsplat's CUDA extension did not build (see the log above); check nvcc and "
        msg += "MAX_JOBS, or train with backend 'torch'"
        raise BackendUnavailableError(msg)


def resolve_backend(
    backend: RasterBackend, device: torch.device | str
) -> Literal["gsplat", "torch"]:
    """Return the concrete backend for ``backend`` on ``device``.

    Raises:
        ValueError: Unknown backend name.
        BackendUnavailableError: ``"gsplat"`` was asked for but CUDA or gsplat is missing, or the
            device is not a CUDA device.
    """
    import torch  # noqa: PLC0415

    if backend not in ("auto", "gsplat", "torch"):
        msg = f"unknown rasterizer backend {backend!r}; use 'auto', 'gsplat' or 'torch'"
        raise ValueError(msg)
    on_cuda = torch.device(device).type == "cuda"
    if backend == "torch":
        return "torch"
    if backend == "auto":
        return "gsplat" if on_cuda and has_gsplat() else "torch"
    if not on_cuda:
        msg = f"the gsplat backend needs a CUDA device, got {str(device)!r}; use device 'cuda'"
        raise BackendUnavailableError(msg)
    if not has_gsplat():
        msg = f"the gsplat backend needs CUDA and the gsplat package; {INSTALL_HINT}"
        raise BackendUnavailableError(msg)
    return "gsplat"


def resolve_device(device: str) -> str:
    """Return ``device`` with ``"auto"`` turned into ``"cuda"`` or ``"cpu"``.

    Raises:
        BackendUnavailableError: A CUDA device was asked for but torch sees none.
    """
    import torch  # noqa: PLC0415

    if device == "auto":
        return "cuda" if torch.cuda.is_available() else "cpu"
    if device.startswith("cuda") and not torch.cuda.is_available():
        msg = f"device {device!r} asked for, but torch sees no CUDA device; use device 'cpu'"
        raise BackendUnavailableError(msg)
    return device


def rasterize(  # noqa: PLR0913, PLR0917 -- mirrors gsplat.rasterization's signature on purpose
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
    backend: RasterBackend = "auto",
    absgrad: bool = False,
    rows: tuple[int, int] | None = None,
    tile_size: int = GSPLAT_TILE,
    antialiased: bool = False,
) -> RasterOutput:
    """Render Gaussians into ``C`` images with the chosen backend.

    Args:
        means: ``[N, 3]`` world positions, metres.
        quats: ``[N, 4]`` rotations ``(w, x, y, z)`` (need not be normalised).
        scales: ``[N, 3]`` standard deviations, metres.
        opacities: ``[N]`` in ``[0, 1]``.
        colors: ``[N, D]`` or ``[C, N, D]`` colours when ``sh_degree`` is None, else ``[N, K, 3]``
            SH coefficients (``K >= (sh_degree + 1) ** 2``).
        viewmats: ``[C, 4, 4]`` world -> camera.
        Ks: ``[C, 3, 3]`` intrinsics, pixels.
        width: Image width, pixels.
        height: Image height, pixels.
        near_plane: Gaussians with camera z below this (metres) are culled.
        far_plane: Gaussians with camera z above this are culled.
        eps2d: Low-pass dilation added to the 2-D covariance diagonal, pixels squared.
        sh_degree: SH degree to evaluate, or None for plain colours.
        backgrounds: ``[C, D]`` colour behind the Gaussians, or None (zeros).
        backend: ``"auto"``, ``"gsplat"`` or ``"torch"``.
        absgrad: Also accumulate the absolute per-pixel gradients of the projected centres
            into ``means2d.absgrad`` during ``backward()`` (AbsGS densification; gsplat only).
        rows: Only rows ``[first, stop)`` of the ``width`` x ``height`` image (None = all):
            the images are ``stop - first`` rows high and show what the whole image shows
            there. The torch backend composites only those rows (the cost of a CPU frame is
            mostly compositing); gsplat renders the whole image and keeps them.
        tile_size: gsplat's square tile, pixels (one thread block each; the images are the
            same for every size, only the work differs); the torch backend ignores it.
        antialiased: Mip-Splatting's 2-D filter (gsplat's ``rasterize_mode="antialiased"``):
            each Gaussian's opacity in a view is scaled by ``sqrt(det(Sigma) / det(Sigma +
            eps2d I))``, so Gaussians smaller than a pixel fade instead of being dilated to one.
            A model trained with it must be rendered with it (``ChunkHeader.antialiased``).

    Returns:
        The images and per-Gaussian screen-space data.

    Raises:
        ValueError: Inconsistent shapes, unknown backend, or ``absgrad`` on the torch backend.
        BackendUnavailableError: ``"gsplat"`` asked for where it cannot run.
    """
    chosen = resolve_backend(backend, means.device)
    if absgrad and chosen == "torch":
        msg = "absgrad needs the gsplat backend (CUDA); the torch rasterizer has none"
        raise ValueError(msg)
    args = (means, quats, scales, opacities, colors, viewmats, Ks, width, height)
    options = {
        "near_plane": near_plane,
        "far_plane": far_plane,
        "eps2d": eps2d,
        "sh_degree": sh_degree,
        "backgrounds": backgrounds,
    }
    if chosen == "torch":
        from cam2sim.splat import raster_torch  # noqa: PLC0415 -- lazy: imports torch

        return raster_torch.rasterization(*args, **options, rows=rows, antialiased=antialiased)  # type: ignore[arg-type]
    gsplat = importlib.import_module("gsplat")
    render_colors, render_alphas, meta = gsplat.rasterization(
        *args,
        **options,
        packed=False,
        rasterize_mode="antialiased" if antialiased else "classic",
        absgrad=absgrad,
        tile_size=tile_size,
    )
    if rows is not None:
        first, stop = row_window(rows, height)
        render_colors, render_alphas = render_colors[:, first:stop], render_alphas[:, first:stop]
    return RasterOutput(
        colors=render_colors,
        alphas=render_alphas,
        means2d=meta["means2d"],
        radii=meta["radii"],
        depths=meta["depths"],
        info=meta,
        backend="gsplat",
    )
