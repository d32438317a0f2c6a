"""A small Gaussian model with live Adam state, for the densification operations' tests."""

from __future__ import annotations

import torch

from cam2sim.splat import model as gm
from cam2sim.splat.raster import RasterOutput


def model_and_adam(
    n: int = 6, means: torch.Tensor | None = None
) -> tuple[gm.GaussianModel, dict[str, torch.optim.Optimizer]]:
    """``n`` Gaussians (at ``means`` if given) and an Adam per parameter, after one step."""
    xyz = torch.rand(n, 3) if means is None else means
    model = gm.GaussianModel.from_points(xyz, torch.rand(len(xyz), 3), sh_degree=1)
    opts: dict[str, torch.optim.Optimizer] = {
        k: torch.optim.Adam([p], lr=0.01) for k, p in model.params.items()
    }
    torch.autograd.backward(torch.stack([p.sum() for p in model.params.values()]).sum())
    for opt in opts.values():
        opt.step()
    return model, opts


def check_aligned(model: gm.GaussianModel, opts: dict[str, torch.optim.Optimizer]) -> None:
    """Every parameter has one row per Gaussian, its optimizer holds it, moments of its shape."""
    n = len(model)
    for name, p in model.params.items():
        assert p.shape[0] == n
        assert opts[name].param_groups[0]["params"][0] is p
        state = opts[name].state[p]
        assert state["exp_avg"].shape == p.shape
        assert state["exp_avg_sq"].shape == p.shape


def one_view_output(n: int, grad: torch.Tensor | None = None) -> RasterOutput:
    """A gsplat-like raster output of one 2x2 view that sees all ``n`` Gaussians.

    ``grad`` (``[1, n, 2]``) becomes the screen positions' gradient (zero if not given).
    """
    means2d = torch.zeros(1, n, 2, requires_grad=True)
    means2d.grad = torch.zeros(1, n, 2) if grad is None else grad
    return RasterOutput(
        colors=torch.zeros(1, 2, 2, 3),
        alphas=torch.zeros(1, 2, 2, 1),
        means2d=means2d,
        radii=torch.ones(1, n, 2, dtype=torch.int32),
        depths=torch.full((1, n), 5.0),
        info={"width": 2, "height": 2, "n_cameras": 1},
        backend="gsplat",
    )
