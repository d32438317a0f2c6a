"""The space the vehicle drove through is empty: Gaussians found there are floaters.

The recording's camera rode inside a car, so nothing of the street lies within the car's body
around the camera's path. A Gaussian there sits right in front of every pose near the path,
which is where a closed-loop drive puts the simulated camera, yet the training views pay little
for it: a view passes it at once, or sees it from behind, or culls it at the near plane. Such
floaters showed up in held-out views between training views (one frame of a winding stretch
scored 18.7 dB against 26.5-27.4 dB in every other run, docs/benchmarks.md).

- :func:`path_distance`: each point's distance to the polyline through the training cameras'
  centres in recording order (vectorised over segments, in chunks of points).
- :func:`clear_path`: the Gaussians whose centres lie within a radius of it made transparent
  (:func:`cam2sim.splat.model.make_transparent`), so the next refinement prunes them (3DGS
  rules) or relocates them onto live ones (MCMC).

The radius is a share of the cameras' height over the road (:func:`cam2sim.splat.ground.
camera_height`), so it is in the scene's units, metric or not; half of it keeps well inside a
car's body around its camera. torch is imported at module level: only the trainer imports this
module, inside a function.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import torch

from cam2sim.splat.model import make_transparent

if TYPE_CHECKING:
    from cam2sim.splat.model import GaussianModel, Optimizers

__all__ = ["clear_path", "path_distance"]

_CHUNK = 1 << 14
"""Points per block of :func:`path_distance` (a block holds points x segments x 3 floats)."""


def path_distance(points: torch.Tensor, path: torch.Tensor) -> torch.Tensor:
    """``[N]`` distance of each of ``points`` (``[N, 3]``) to the polyline ``path`` (``[M, 3]``).

    One point for ``path`` is a point; consecutive repeated points are fine (zero-length
    segments count as their point).
    """
    a = path[:-1] if len(path) > 1 else path
    b = path[1:] if len(path) > 1 else path
    ab = b - a
    length2 = (ab * ab).sum(dim=-1).clamp_min(torch.finfo(path.dtype).tiny)
    out = torch.empty(len(points), dtype=points.dtype, device=points.device)
    for start in range(0, len(points), _CHUNK):
        p = points[start : start + _CHUNK, None, :]  # [n, 1, 3]
        t = (((p - a) * ab).sum(dim=-1) / length2).clamp(0.0, 1.0)  # [n, S]
        nearest = a + t[..., None] * ab
        out[start : start + _CHUNK] = torch.linalg.vector_norm(p - nearest, dim=-1).amin(dim=1)
    return out


def clear_path(
    model: GaussianModel, optimizers: Optimizers, path: torch.Tensor, radius: float
) -> int:
    """Make the Gaussians whose centres lie within ``radius`` of ``path`` transparent.

    Returns how many. ``path``: ``[M, 3]`` camera centres in recording order, on the model's
    device. Only the centres inside the path's box grown by ``radius`` are measured.
    """
    means = model.params["means"].detach()
    lo = path.amin(dim=0) - radius
    hi = path.amax(dim=0) + radius
    near = ((means >= lo) & (means <= hi)).all(dim=1)
    rows = near.nonzero(as_tuple=True)[0]
    if len(rows) == 0:
        return 0
    inside = torch.zeros_like(near)
    inside[rows] = path_distance(means[rows], path.to(means.dtype)) < radius
    return make_transparent(model, optimizers, inside)
