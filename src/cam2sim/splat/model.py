"""Gaussian models of one route chunk: parameters, initialisation, densification, files.

A chunk model (:class:`ChunkModel`) is two sets of 3D Gaussians plus a colour correction:

- ``gaussians``: the street, initialised from ``points.npz`` and densified while training;
- ``sky``: far Gaussians on a large sphere around the chunk (positions fixed, SH degree 0), so
  the sky and far background have their own primitives and are not smeared into the street;
- ``appearance``: one affine colour transform per training view, ``rgb' = A rgb + b``
  (``[M, 3, 4]``, identity at the start), for exposure and white-balance changes.

Parameters follow gsplat's names and activations (so ``gsplat.strategy`` works on them):
``means`` ``[N, 3]`` world metres, ``scales`` ``[N, 3]`` log standard deviations, ``quats``
``[N, 4]`` ``(w, x, y, z)`` unnormalised, ``opacities`` ``[N]`` logits, ``sh0`` ``[N, 1, 3]`` and
``shN`` ``[N, K - 1, 3]`` SH coefficients (``K = (degree + 1) ** 2``; ``rgb = SH_C0 sh0 + 0.5``).

Files: ``chunk_XX.pt`` (torch, tensors and the header as JSON text) and ``chunk_XX.json`` (the
:class:`ChunkHeader` alone, readable without torch; the renderer reads it to pick chunks before
loading any tensor). :func:`export_ply` writes the standard 3DGS ``.ply`` layout for viewers.
"""

from __future__ import annotations

import io
import json
import logging
import math
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Final, Literal

import numpy as np
import torch

from cam2sim.core.camera import project_points
from cam2sim.core.errors import WorkspaceError
from cam2sim.core.files import write_bytes_atomic
from cam2sim.splat import sh_cpu
from cam2sim.splat.chunk_header import ChunkHeader, ViewRecord, outliers_path
from cam2sim.splat.raster_torch import SH_C0, quats_to_rotmats, rgb_from_sh

if TYPE_CHECKING:
    from cam2sim.splat.scene import FrameRecord

if TYPE_CHECKING:
    from collections.abc import Callable, Mapping, Sequence

    import numpy.typing as npt

__all__ = [
    "PARAM_NAMES",
    "ChunkHeader",
    "ChunkModel",
    "GaussianModel",
    "SeedOptions",
    "SeededModels",
    "SplatInputs",
    "ViewRecord",
    "append_copies",
    "chunk_model_path",
    "copy_moments",
    "duplicate",
    "export_ply",
    "gather_splats",
    "load_chunk_header",
    "load_chunk_model",
    "make_transparent",
    "nearest_neighbour_distances",
    "outliers_path",
    "quench_non_finite",
    "remove",
    "reset_opacity",
    "save_chunk_model",
    "seed_models",
    "sky_sphere_points",
    "split",
    "visible_points",
    "zero_moments",
]

_log = logging.getLogger(__name__)

PARAM_NAMES: Final = ("means", "scales", "quats", "opacities", "sh0", "shN")
"""Parameter names of a :class:`GaussianModel`, in file order."""

_FORMAT: Final = "cam2sim-splat-chunk"
_FORMAT_VERSION: Final = 1


def _logit(p: float) -> float:
    return math.log(p / (1.0 - p))


class GaussianModel:
    """A set of 3D Gaussians as trainable tensors (running state, mutated by densification).

    Attributes:
        params: gsplat-style parameters by name (see the module doc); densification replaces
            entries, so read them through this dict rather than keeping references.
        sh_degree: Highest SH degree the coefficients hold.
    """

    def __init__(self, params: Mapping[str, torch.Tensor], *, sh_degree: int) -> None:
        missing = [name for name in PARAM_NAMES if name not in params]
        if missing:
            msg = f"Gaussian parameters lack {missing}; expected {list(PARAM_NAMES)}"
            raise ValueError(msg)
        n = params["means"].shape[0]
        k = (sh_degree + 1) ** 2 - 1
        expected = {
            "means": (n, 3),
            "scales": (n, 3),
            "quats": (n, 4),
            "opacities": (n,),
            "sh0": (n, 1, 3),
            "shN": (n, k, 3),
        }
        wrong = [
            f"{key}: {tuple(params[key].shape)} != {shape}"
            for key, shape in expected.items()
            if params[key].shape != shape
        ]
        if wrong:
            msg = f"Gaussian parameters have wrong shapes ({', '.join(wrong)})"
            raise ValueError(msg)
        self.sh_degree = sh_degree
        self.params: dict[str, torch.nn.Parameter] = {
            name: torch.nn.Parameter(params[name].detach().clone()) for name in PARAM_NAMES
        }

    def __len__(self) -> int:
        return int(self.params["means"].shape[0])

    def __repr__(self) -> str:
        return f"GaussianModel(n={len(self)}, sh_degree={self.sh_degree})"

    @property
    def device(self) -> torch.device:
        """Device of the parameters."""
        return self.params["means"].device

    @classmethod
    def from_points(
        cls,
        xyz: torch.Tensor,
        rgb: torch.Tensor,
        *,
        sh_degree: int,
        opacity: float = 0.1,
        scale_factor: float = 1.0,
        scales: torch.Tensor | None = None,
    ) -> GaussianModel:
        """Make one isotropic Gaussian per point.

        Args:
            xyz: ``[N, 3]`` positions, metres (their device is the model's).
            rgb: ``[N, 3]`` colours in ``[0, 1]``.
            sh_degree: SH degree of the model (higher bands start at zero).
            opacity: Initial opacity of every Gaussian.
            scale_factor: Multiplies the initial scales.
            scales: ``[N]`` initial standard deviations; None: the mean distance to the three
                nearest neighbours (:func:`nearest_neighbour_distances`).

        Returns:
            The model.
        """
        n = xyz.shape[0]
        if n == 0:
            msg = "cannot make a Gaussian model from zero points"
            raise ValueError(msg)
        dist = nearest_neighbour_distances(xyz) if scales is None else scales
        log_scale = torch.log(torch.clamp_min(dist * scale_factor, 1e-7))
        quats = torch.zeros((n, 4), dtype=xyz.dtype, device=xyz.device)
        quats[:, 0] = 1.0
        params = {
            "means": xyz,
            "scales": log_scale[:, None].repeat(1, 3),
            "quats": quats,
            "opacities": torch.full((n,), _logit(opacity), dtype=xyz.dtype, device=xyz.device),
            "sh0": ((rgb - 0.5) / SH_C0)[:, None, :],
            "shN": torch.zeros(
                (n, (sh_degree + 1) ** 2 - 1, 3), dtype=xyz.dtype, device=xyz.device
            ),
        }
        return cls(params, sh_degree=sh_degree)

    def colors(
        self, campos: torch.Tensor, degree: int, *, backend: Literal["gsplat", "torch"] = "torch"
    ) -> torch.Tensor:
        """Return ``[C, N, 3]`` colours seen from camera centres ``campos`` ``[C, 3]``.

        ``backend="gsplat"`` evaluates the SH with gsplat's CUDA kernel (one launch forward and
        one backward instead of about a hundred small torch operations); ``"torch"`` uses
        its CPU counterpart for float32 on the CPU (:mod:`cam2sim.splat.sh_cpu`), else
        :func:`cam2sim.splat.raster_torch.rgb_from_sh`. All compute the same function.
        """
        degree = min(degree, self.sh_degree)
        means = self.params["means"]
        dirs = means[None, :, :] - campos[:, None, :]
        sh0, shn = self.params["sh0"], self.params["shN"]
        if backend == "torch" and sh_cpu.applies(dirs, sh0, shn):
            return sh_cpu.colors(sh0, shn, dirs, degree)
        coeffs = torch.cat((sh0, shn), dim=1)
        shs = coeffs[None].expand(campos.shape[0], -1, -1, -1)
        if backend == "gsplat":
            from gsplat import spherical_harmonics  # noqa: PLC0415

            return torch.clamp_min(spherical_harmonics(degree, dirs, shs) + 0.5, 0.0)
        return rgb_from_sh(shs, dirs, degree)

    def state_dict(self) -> dict[str, torch.Tensor]:
        """Return the parameters as detached CPU tensors."""
        return {name: p.detach().cpu() for name, p in self.params.items()}

    def to(self, device: torch.device | str) -> GaussianModel:
        """Return a copy on ``device``."""
        return GaussianModel(
            {k: v.detach().to(device) for k, v in self.params.items()}, sh_degree=self.sh_degree
        )


def nearest_neighbour_distances(xyz: torch.Tensor, *, k: int = 3) -> torch.Tensor:
    """Return ``[N]`` mean distance of each point to its ``k`` nearest other points (metres).

    Uses scipy's KD-tree when scipy is installed, else torch ``cdist`` in blocks of rows.
    A lone point gets 1 cm.
    """
    n = xyz.shape[0]
    if n < 2:
        return torch.full((n,), 0.01, dtype=xyz.dtype, device=xyz.device)
    k = min(k, n - 1)
    try:
        from scipy.spatial import cKDTree  # noqa: PLC0415
    except ImportError:
        cKDTree = None
    if cKDTree is not None:
        points = xyz.detach().cpu().numpy().astype(np.float64)
        dist, _ = cKDTree(points).query(points, k=k + 1)
        mean = torch.from_numpy(np.asarray(dist)[:, 1:].mean(axis=1))
        return mean.to(device=xyz.device, dtype=xyz.dtype)
    out = []
    block = max(1, (1 << 24) // n)
    for start in range(0, n, block):
        d = torch.cdist(xyz[start : start + block], xyz)
        out.append(torch.topk(d, k + 1, largest=False).values[:, 1:].mean(dim=1))
    return torch.cat(out)


def sky_sphere_points(
    centre: npt.NDArray[np.float64], radius: float, count: int
) -> npt.NDArray[np.float64]:
    """Return ``(count, 3)`` points spread evenly on a sphere (a Fibonacci lattice), metres."""
    i = np.arange(count, dtype=np.float64) + 0.5
    z = 1.0 - 2.0 * i / count
    r = np.sqrt(np.clip(1.0 - z * z, 0.0, None))
    phi = i * math.pi * (3.0 - math.sqrt(5.0))
    unit = np.stack((r * np.cos(phi), r * np.sin(phi), z), axis=1)
    return np.asarray(centre, dtype=np.float64)[None, :] + radius * unit


@dataclass(frozen=True)
class SplatInputs:
    """Street and sky Gaussians joined for one rasterization (activated values).

    Attributes:
        means: ``[N, 3]``.
        quats: ``[N, 4]``.
        scales: ``[N, 3]`` standard deviations.
        opacities: ``[N]``.
        colors: ``[C, N, 4]``: RGB and a sky indicator (0 street, 1 sky), whose composite is
            the share of each pixel drawn by sky Gaussians.
        n_street: The first ``n_street`` Gaussians are the street model's.
    """

    means: torch.Tensor
    quats: torch.Tensor
    scales: torch.Tensor
    opacities: torch.Tensor
    colors: torch.Tensor
    n_street: int


def gather_splats(
    street: GaussianModel,
    sky: GaussianModel,
    campos: torch.Tensor,
    sh_degree: int,
    *,
    backend: Literal["gsplat", "torch"] = "torch",
) -> SplatInputs:
    """Join ``street`` and ``sky`` into one set of activated Gaussians seen from ``campos``.

    Args:
        street: The street model.
        sky: The sky model (SH degree 0).
        campos: ``[C, 3]`` camera centres, world metres.
        sh_degree: SH degree to evaluate for the street model.
        backend: Who evaluates the SH colours (see :meth:`GaussianModel.colors`).

    Returns:
        The joined inputs; gradients flow back to both models.
    """
    parts = (street, sky)
    street_rgb = street.colors(campos, sh_degree, backend=backend)
    sky_rgb = sky.colors(campos, 0, backend=backend)
    flag = torch.cat(
        (
            torch.zeros_like(street_rgb[..., :1]),
            torch.ones_like(sky_rgb[..., :1]),
        ),
        dim=1,
    )
    return SplatInputs(
        means=torch.cat([m.params["means"] for m in parts]),
        quats=torch.cat([m.params["quats"] for m in parts]),
        scales=torch.exp(torch.cat([m.params["scales"] for m in parts])),
        opacities=torch.sigmoid(torch.cat([m.params["opacities"] for m in parts])),
        colors=torch.cat((torch.cat((street_rgb, sky_rgb), dim=1), flag), dim=-1),
        n_street=len(street),
    )


# ------------------------------------------------------------------------- densification ops

Optimizers = dict[str, torch.optim.Optimizer]


def _rebuild(
    model: GaussianModel,
    optimizers: Optimizers,
    new_param: Callable[[str, torch.Tensor], torch.Tensor],
    new_state: Callable[[torch.Tensor], torch.Tensor],
) -> None:
    """Replace every parameter and carry its optimizer state through ``new_state``."""
    for name in PARAM_NAMES:
        old = model.params[name]
        fresh = torch.nn.Parameter(new_param(name, old.detach()), requires_grad=old.requires_grad)
        opt = optimizers.get(name)
        if opt is not None:
            state = opt.state.pop(old, {})
            for key, value in list(state.items()):
                if key != "step" and isinstance(value, torch.Tensor) and value.shape == old.shape:
                    state[key] = new_state(value)
            opt.param_groups[0]["params"] = [fresh]
            opt.state[fresh] = state
        model.params[name] = fresh


def duplicate(model: GaussianModel, optimizers: Optimizers, mask: torch.Tensor) -> None:
    """Append a copy of every Gaussian where ``mask`` (``[N]`` bool) is set."""
    append_copies(model, optimizers, mask)


def append_copies(
    model: GaussianModel,
    optimizers: Optimizers,
    rows: torch.Tensor,
    *,
    inherit_moments: bool = False,
) -> None:
    """Append copies of the Gaussians ``rows`` selects, with zero Adam moments.

    ``rows`` is a ``[N]`` bool mask or indices (which may repeat: one copy per occurrence).
    With ``inherit_moments`` each copy starts with its original's moments instead.
    """
    _rebuild(
        model,
        optimizers,
        lambda _, p: torch.cat((p, p[rows])),
        (
            (lambda s: torch.cat((s, s[rows])))
            if inherit_moments
            else (lambda s: torch.cat((s, torch.zeros_like(s[rows]))))
        ),
    )


def split(
    model: GaussianModel,
    optimizers: Optimizers,
    mask: torch.Tensor,
    *,
    generator: torch.Generator | None = None,
) -> None:
    """Replace every Gaussian where ``mask`` is set by two smaller ones sampled inside it.

    The children are drawn from the parent's own distribution and get scales divided by 1.6
    (as 3DGS does); the other parameters are copied.
    """
    params = model.params
    scales = torch.exp(params["scales"].detach()[mask])
    rot = quats_to_rotmats(params["quats"].detach()[mask])
    noise = torch.randn(
        (2, *scales.shape), generator=generator, device=scales.device, dtype=scales.dtype
    )
    offsets = torch.einsum("nij,bnj->bni", rot, scales * noise).reshape(-1, 3)
    keep = ~mask

    def grown(name: str, p: torch.Tensor) -> torch.Tensor:
        if name == "means":
            children = (p[mask][None] + offsets.reshape(2, -1, 3)).reshape(-1, 3)
        elif name == "scales":
            children = torch.log(scales / 1.6).repeat(2, 1)
        else:
            children = p[mask].repeat((2,) + (1,) * (p.ndim - 1))
        return torch.cat((p[keep], children))

    n_new = 2 * int(mask.sum())
    _rebuild(
        model,
        optimizers,
        grown,
        lambda s: torch.cat((s[keep], s.new_zeros((n_new, *s.shape[1:])))),
    )


def remove(model: GaussianModel, optimizers: Optimizers, mask: torch.Tensor) -> None:
    """Delete every Gaussian where ``mask`` is set."""
    keep = ~mask
    _rebuild(model, optimizers, lambda _, p: p[keep], lambda s: s[keep])


def reset_opacity(model: GaussianModel, optimizers: Optimizers, value: float) -> None:
    """Clamp every opacity to at most ``value`` and clear the opacity optimizer's moments."""
    old = model.params["opacities"]
    fresh = torch.nn.Parameter(torch.clamp_max(old.detach(), _logit(value)))
    opt = optimizers.get("opacities")
    if opt is not None:
        state = opt.state.pop(old, {})
        zero_moments(state, old)
        opt.param_groups[0]["params"] = [fresh]
        opt.state[fresh] = state
    model.params["opacities"] = fresh


DEAD_OPACITY_LOGIT: Final = -30.0
"""The opacity logit :func:`quench_non_finite` gives a broken Gaussian (opacity about 1e-13)."""

DEAD_LOG_SCALE: Final = -7.0
"""The log-scale :func:`make_transparent` gives a non-finite scale (about 1e-3 scene units)."""


def quench_non_finite(model: GaussianModel, optimizers: Optimizers) -> int:
    """Make every Gaussian with a non-finite parameter (NaN or inf) transparent; return how many.

    In place: such a Gaussian's non-finite values become 0, its opacity logit
    :data:`DEAD_OPACITY_LOGIT`, and its Adam moments 0 in every optimizer, so the next
    refinement prunes it (3DGS rules) or relocates it onto a live one (MCMC, whose draw over
    the live opacities fails on a NaN), and until then it draws nothing.
    """
    params = model.params
    bad = torch.zeros(len(model), dtype=torch.bool, device=params["means"].device)
    for p in params.values():
        bad |= ~torch.isfinite(p.detach()).reshape(len(p), -1).all(dim=1)
    return make_transparent(model, optimizers, bad)


def make_transparent(model: GaussianModel, optimizers: Optimizers, rows: torch.Tensor) -> int:
    """Make the Gaussians ``rows`` (``[N]`` bool) selects transparent; return how many.

    In place: their opacity logit becomes :data:`DEAD_OPACITY_LOGIT`, their rotation the
    identity, non-finite scales :data:`DEAD_LOG_SCALE` and other non-finite values 0, and their
    Adam moments 0 in every optimizer, so the next refinement prunes them (3DGS rules) or
    relocates them onto live ones (MCMC), and until then they draw nothing and stay finite.
    (A zero quaternion, what NaN ones became before, is NaN in gsplat's kernels, which
    normalise by ``rsqrt`` of its norm, and in MCMC's position noise: each such Gaussian then
    drew NaN into its pixels at every step, and after the last relocation for good.)
    """
    n = int(rows.sum())  # one host sync per call: call it at refinement steps only
    if n == 0:
        return 0
    with torch.no_grad():
        for name, p in model.params.items():
            fill = DEAD_LOG_SCALE if name == "scales" else 0.0
            p[rows] = torch.nan_to_num(p[rows], nan=fill, posinf=fill, neginf=fill)
            if name == "opacities":
                p[rows] = DEAD_OPACITY_LOGIT
            elif name == "quats":
                p[rows] = torch.tensor([1.0, 0.0, 0.0, 0.0], dtype=p.dtype, device=p.device)
            opt = optimizers.get(name)
            if opt is not None:
                zero_moments(opt.state.get(p, {}), p, rows)
    return n


def copy_moments(
    state: dict[str, Any], param: torch.Tensor, source: torch.Tensor, target: torch.Tensor
) -> None:
    """Copy rows ``source`` of the Adam moments in ``state`` of ``param`` to rows ``target``.

    Only the moments of ``param``'s shape are copied (not the step counter).
    """
    for key, v in state.items():
        if key != "step" and isinstance(v, torch.Tensor) and v.shape == param.shape:
            v[target] = v[source]


def zero_moments(
    state: dict[str, Any], param: torch.Tensor, rows: torch.Tensor | None = None
) -> None:
    """Zero the Adam moments in ``state`` of ``param`` (those of its shape), or their ``rows``."""
    for key, v in state.items():
        if key != "step" and isinstance(v, torch.Tensor) and v.shape == param.shape:
            if rows is None:
                v.zero_()
            else:
                v[rows] = 0.0


# ---------------------------------------------------------------------------- initialisation


def visible_points(
    xyz: npt.NDArray[np.float32], frames: Sequence[FrameRecord]
) -> npt.NDArray[np.bool_]:
    """Return ``(N,)`` True where a point lies in front of and inside at least one view.

    A point seen once is not projected again: the points still unseen are gathered anew once
    a fifth of them has been seen since the last gathering (a chunk's views see 25-95 % of a
    route's LiDAR points; 1.3-10 times faster than projecting every point into every view).
    """
    seen = np.zeros(len(xyz), dtype=bool)
    todo = np.arange(len(xyz))
    points = np.asarray(xyz, dtype=np.float64)  # converted once, not in every view
    newly = 0
    for f in frames:
        u, v, front = project_points(points, f.T(), f.K(), min_depth=1e-3)
        hit = front & (u >= 0) & (u < f.width) & (v >= 0) & (v < f.height) & ~seen[todo]
        seen[todo[hit]] = True
        newly += int(hit.sum())
        if newly > 0.2 * len(todo):
            unseen = ~seen[todo]
            todo, points, newly = todo[unseen], points[unseen], 0
    return seen


def screen_density_keep(
    xyz: npt.NDArray[np.float32], centres: npt.NDArray[np.float64], budget: int
) -> npt.NDArray[np.float64]:
    """Keep probabilities of points so that about ``budget`` remain, thinned with distance.

    A point at distance ``d`` from the nearest camera is kept with probability
    ``min(1, (r0 / d) ** 2)``, ``r0`` chosen so the probabilities sum to ``budget``: a
    surface sampled evenly in space then stays about evenly sampled on screen, where a
    Gaussian's footprint shrinks with ``d ** 2``. Along a street this keeps the road and kerbs
    next to the path whole and thins facades and far ground, where a uniform random subset
    thins everything alike (on the demo, 40k of 180k points kept a fifth of the road).
    """
    from scipy.spatial import cKDTree  # noqa: PLC0415 -- lazy: only seeding needs it

    dist, _ = cKDTree(np.asarray(centres, dtype=np.float64)).query(np.asarray(xyz, np.float64))
    d2 = np.maximum(np.asarray(dist, dtype=np.float64) ** 2, 1e-6)
    # sum(min(1, r2 / d2)) = (points with d2 <= r2) + r2 * (sum of 1 / d2 over the others):
    # with d2 sorted and the tail sums of 1 / d2 each trial r2 costs a binary search.
    order = np.sort(d2)
    tail = np.concatenate((np.cumsum((1.0 / order)[::-1])[::-1], [0.0]))
    lo, hi = 0.0, float(order[-1])  # r0 ** 2 between these
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        whole = int(np.searchsorted(order, mid, side="right"))
        if whole + mid * tail[whole] < budget:
            lo = mid
        else:
            hi = mid
    out: npt.NDArray[np.float64] = np.minimum(1.0, hi / d2)
    return out


@dataclass(frozen=True)
class SeedOptions:
    """How :func:`seed_models` starts a chunk model.

    Attributes:
        sh_degree: SH degree of the street model.
        opacity: Initial street opacity.
        sky_points: Sky Gaussians (0: one invisible placeholder).
        sky_radius_m: Sky sphere radius; None: 3 times the 99th-percentile point distance from
            the camera centroid, at least 10 scene scales.
        max_points: About this many of the visible points, thinned with the distance from the
            cameras (:func:`screen_density_keep`); None = all.
        seed: Seeds the subset.
    """

    sh_degree: int = 3
    opacity: float = 0.1
    sky_points: int = 10_000
    sky_radius_m: float | None = None
    max_points: int | None = None
    seed: int = 0


@dataclass(frozen=True)
class SeededModels:
    """Street and sky models at the start of training, and the sizes derived on the way."""

    street: GaussianModel
    sky: GaussianModel
    scene_scale: float
    """1.1 times the largest camera distance from the camera centroid (at least 5 % of the
    99th-percentile point distance), metres."""
    sky_radius_m: float


def seed_models(
    xyz: npt.NDArray[np.float32],
    rgb: npt.NDArray[np.uint8],
    frames: Sequence[FrameRecord],
    *,
    sky_rgb: Sequence[float],
    options: SeedOptions,
    device: torch.device | str,
) -> SeededModels | None:
    """Start a chunk's street model from the points its views see, and its sky sphere.

    Args:
        xyz: ``(N, 3)`` world points, metres.
        rgb: ``(N, 3)`` uint8 colours.
        frames: The chunk's training views.
        sky_rgb: Initial sky colour, ``[0, 1]``.
        options: Initial values.
        device: torch device of the models.

    Returns:
        The models, or None when no point is seen by any view.
    """
    keep = visible_points(xyz, frames)
    xyz, rgb = xyz[keep], rgb[keep]
    if len(xyz) == 0:
        return None
    centres = np.stack([f.T()[:3, 3] for f in frames])
    centre = centres.mean(axis=0)
    dist = np.linalg.norm(xyz - centre, axis=1)
    far = float(np.percentile(dist, 99))
    spread = float(np.linalg.norm(centres - centre, axis=1).max()) * 1.1
    scene_scale = max(spread, 0.05 * far, 1e-3)
    radius = float(options.sky_radius_m or max(3.0 * far, 10.0 * scene_scale))
    inside = dist < 0.8 * radius
    xyz, rgb = xyz[inside], rgb[inside]
    if options.max_points is not None and len(xyz) > options.max_points:
        keep_p = screen_density_keep(xyz, centres, options.max_points)
        pick = np.random.default_rng(options.seed).random(len(xyz)) < keep_p
        xyz, rgb = xyz[pick], rgb[pick]
    street = GaussianModel.from_points(
        torch.tensor(xyz, dtype=torch.float32, device=device),
        torch.tensor(rgb, dtype=torch.float32, device=device) / 255.0,
        sh_degree=options.sh_degree,
        opacity=options.opacity,
    )
    n_sky = max(options.sky_points, 1)
    spacing = radius * math.sqrt(4.0 * math.pi / n_sky)
    sky = GaussianModel.from_points(
        torch.tensor(sky_sphere_points(centre, radius, n_sky), dtype=torch.float32, device=device),
        torch.tensor([list(sky_rgb)], dtype=torch.float32, device=device).expand(n_sky, 3),
        sh_degree=0,
        opacity=0.8 if options.sky_points > 0 else 1e-3,
        scales=torch.full((n_sky,), 0.5 * spacing, device=device),
    )
    sky.params["means"].requires_grad = False
    if options.sky_points == 0:
        for p in sky.params.values():
            p.requires_grad = False
    return SeededModels(street=street, sky=sky, scene_scale=scene_scale, sky_radius_m=radius)


# --------------------------------------------------------------------------------- files


@dataclass(frozen=True)
class ChunkModel:
    """One trained chunk: street and sky Gaussians, appearance table, header."""

    header: ChunkHeader
    gaussians: GaussianModel
    sky: GaussianModel
    appearance: torch.Tensor
    """``[M, 3, 4]`` affine colour transforms, one per ``header.train_views`` entry."""


def chunk_model_path(models_dir: Path, chunk_id: int) -> Path:
    """Return ``models_dir/chunk_XX.pt``."""
    return Path(models_dir) / f"chunk_{chunk_id:02d}.pt"


def save_chunk_model(model: ChunkModel, path: Path) -> None:
    """Write ``path`` (``.pt``) and its ``.json`` header, each atomically."""
    path = Path(path)
    payload = {
        "format": _FORMAT,
        "format_version": _FORMAT_VERSION,
        "header": model.header.model_dump_json(),
        "street_sh_degree": model.gaussians.sh_degree,
        "gaussians": model.gaussians.state_dict(),
        "sky": model.sky.state_dict(),
        "appearance": model.appearance.detach().cpu(),
    }
    buffer = io.BytesIO()
    torch.save(payload, buffer)
    write_bytes_atomic(path, buffer.getvalue())
    model.header.save(path.with_suffix(".json"))


def load_chunk_header(path: Path) -> ChunkHeader:
    """Read the ``.json`` header beside a ``chunk_XX.pt`` (no tensors are loaded)."""
    return ChunkHeader.load(Path(path).with_suffix(".json"))


def load_chunk_model(path: Path, *, device: torch.device | str = "cpu") -> ChunkModel:
    """Read a chunk model written by :func:`save_chunk_model`.

    Raises:
        WorkspaceError: The file is missing or not a cam2sim chunk model.
    """
    path = Path(path)
    if not path.is_file():
        msg = f"{path} does not exist; train the chunk first (cam2sim splat)"
        raise WorkspaceError(msg)
    try:
        payload = torch.load(path, map_location=device, weights_only=True)
    except (RuntimeError, OSError, EOFError) as err:
        msg = f"cannot read chunk model {path} ({err}); delete it and train again"
        raise WorkspaceError(msg) from None
    if not isinstance(payload, dict) or payload.get("format") != _FORMAT:
        msg = f"{path} is not a cam2sim splat chunk model"
        raise WorkspaceError(msg)
    if int(payload["format_version"]) > _FORMAT_VERSION:
        msg = f"{path} has format version {payload['format_version']}; upgrade cam2sim"
        raise WorkspaceError(msg)
    header = ChunkHeader.model_validate(json.loads(payload["header"]))
    return ChunkModel(
        header=header,
        gaussians=GaussianModel(payload["gaussians"], sh_degree=int(payload["street_sh_degree"])),
        sky=GaussianModel(payload["sky"], sh_degree=0),
        appearance=payload["appearance"],
    )


def export_ply(model: GaussianModel, path: Path, *, extra: GaussianModel | None = None) -> None:
    """Write the standard 3DGS ``.ply`` (binary little-endian, one vertex per Gaussian).

    Properties: ``x y z nx ny nz f_dc_0..2 f_rest_0.. opacity scale_0..2 rot_0..3`` with
    ``f_rest`` channel-major (all red coefficients, then green, then blue), logit opacities,
    log scales and ``(w, x, y, z)`` quaternions, as 3DGS viewers expect.

    Args:
        model: The Gaussians to write.
        path: Destination ``.ply``.
        extra: More Gaussians (the sky) appended; their higher SH bands are written as zero.
    """
    parts = [model] if extra is None else [model, extra]
    n_rest = (model.sh_degree + 1) ** 2 - 1
    columns: dict[str, list[npt.NDArray[np.float32]]] = {}
    for part in parts:
        s = part.state_dict()
        n = len(part)
        rest = torch.zeros((n, n_rest, 3))
        k = min(n_rest, s["shN"].shape[1])
        rest[:, :k] = s["shN"][:, :k]
        values: dict[str, torch.Tensor] = {
            "x": s["means"][:, 0],
            "y": s["means"][:, 1],
            "z": s["means"][:, 2],
            "nx": torch.zeros(n),
            "ny": torch.zeros(n),
            "nz": torch.zeros(n),
        }
        values.update({f"f_dc_{c}": s["sh0"][:, 0, c] for c in range(3)})
        flat = rest.permute(0, 2, 1).reshape(n, -1)
        values.update({f"f_rest_{i}": flat[:, i] for i in range(flat.shape[1])})
        values["opacity"] = s["opacities"]
        values.update({f"scale_{i}": s["scales"][:, i] for i in range(3)})
        values.update({f"rot_{i}": s["quats"][:, i] for i in range(4)})
        for key, v in values.items():
            columns.setdefault(key, []).append(v.numpy().astype(np.float32))
    names = list(columns)
    table = np.empty(sum(len(p) for p in parts), dtype=[(k, "<f4") for k in names])
    for key in names:
        table[key] = np.concatenate(columns[key])
    header = ["ply", "format binary_little_endian 1.0", f"element vertex {len(table)}"]
    header += [f"property float {k}" for k in names]
    header += ["end_header", ""]
    write_bytes_atomic(Path(path), "\n".join(header).encode("ascii") + table.tobytes())
