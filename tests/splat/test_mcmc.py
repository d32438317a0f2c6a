"""MCMC densification's own operations: the error-weighted draw, relocation and growth."""

from __future__ import annotations

import math

import numpy as np
import pytest

pytest.importorskip("torch")

from typing import TYPE_CHECKING

import torch
from gaussian_fixtures import model_and_adam, one_view_output

from cam2sim.splat.densify import (
    RELOCATION_MAX_COPIES,
    Densifier,
    _draw,
    add_copies,
    mcmc_weights,
    relocate,
    relocation_split,
)
from cam2sim.splat.raster import RasterOutput
from cam2sim.splat.train import DensifyOptions, LearningRates, TrainOptions

if TYPE_CHECKING:
    from cam2sim.splat import model as gm

pytestmark = pytest.mark.usefixtures("one_torch_thread")


def _moments(opts: dict[str, torch.optim.Optimizer], model: gm.GaussianModel, name: str):
    return opts[name].state[model.params[name]]["exp_avg"]


@pytest.mark.parametrize("opacity", [0.05, 0.5, 0.95, 0.999])
@pytest.mark.parametrize("copies", [1, 2, 3, 8, 20])
def test_relocation_split_keeps_what_the_gaussian_draws(opacity: float, copies: int) -> None:
    o = torch.tensor([opacity])
    s = torch.tensor([[0.2, 0.5, 1.0]])
    new_o, new_s = relocation_split(o, s, torch.tensor([copies]))
    # N layers of the new opacity are as opaque as the old one.
    assert 1.0 - (1.0 - float(new_o[0])) ** copies == pytest.approx(opacity, rel=1e-6)
    # And the N layers' coverage, integrated along an axis, is the old one's:
    # integral of 1 - (1 - o' g'(x))**N equals o * integral of g(x) (the paper's eq. 9).
    x = np.linspace(-12.0, 12.0, 200_001)
    ratio = float(new_s[0, 0] / s[0, 0])
    assert torch.allclose(new_s / s, torch.full((1, 3), ratio))  # one factor for all axes
    layered = 1.0 - (1.0 - float(new_o[0]) * np.exp(-(x**2) / (2 * ratio**2))) ** copies
    integral = float(np.sum(layered) * (x[1] - x[0]))
    assert integral == pytest.approx(opacity * math.sqrt(2 * math.pi), rel=1e-4)
    if copies == 1:
        assert float(new_o[0]) == pytest.approx(opacity)
        assert ratio == pytest.approx(1.0)


def test_relocation_split_caps_the_copies_it_counts() -> None:
    o, s = torch.tensor([0.9, 0.9]), torch.ones(2, 3)
    new_o, _ = relocation_split(o, s, torch.tensor([RELOCATION_MAX_COPIES, 500]))
    assert float(new_o[0]) == pytest.approx(float(new_o[1]))
    assert torch.isfinite(new_o).all()


def test_the_draw_follows_the_weights() -> None:
    torch.manual_seed(0)
    weights = torch.tensor([0.0, 1.0, 3.0, float("nan"), 6.0])
    idx = _draw(weights, 200_000)
    share = torch.bincount(idx, minlength=5).double() / len(idx)
    assert share[0] == 0
    assert share[3] == 0
    torch.testing.assert_close(
        share[[1, 2, 4]], torch.tensor([0.1, 0.3, 0.6]).double(), atol=5e-3, rtol=0
    )
    uniform = torch.bincount(_draw(torch.zeros(4), 40_000), minlength=4).double() / 40_000
    torch.testing.assert_close(uniform, torch.full((4,), 0.25).double(), atol=1e-2, rtol=0)


def test_error_weights_mix_opacity_and_the_relative_gradient() -> None:
    model, _ = model_and_adam(4)
    with torch.no_grad():
        model.params["opacities"][:] = 0.0  # opacity 0.5 each
    grad2d = torch.tensor([1.0, 3.0, 0.0, 8.0])
    count = torch.tensor([1.0, 1.0, 0.0, 2.0])  # mean gradients 1, 3, (unseen), 4
    torch.testing.assert_close(mcmc_weights(model, grad2d, count, 0.0), torch.full((4,), 0.5))
    full = mcmc_weights(model, grad2d, count, 1.0)
    torch.testing.assert_close(full, 0.5 * torch.tensor([1.0, 3.0, 0.0, 4.0]) / (8.0 / 3.0))
    half = mcmc_weights(model, grad2d, count, 0.5)
    torch.testing.assert_close(half, 0.5 * (0.5 + 0.5 * torch.tensor([1.0, 3.0, 0.0, 4.0]) * 3 / 8))


def test_relocation_moves_the_faded_onto_drawn_live_gaussians() -> None:
    model, opts = model_and_adam(6)
    with torch.no_grad():
        model.params["opacities"][:] = torch.logit(torch.tensor([0.8, 0.001, 0.6, 0.002, 0.9, 0.7]))
    dead = torch.sigmoid(model.params["opacities"].detach()) <= 0.005
    weights = torch.tensor([0.0, 0.0, 0.0, 0.0, 1.0, 0.0])  # only Gaussian 4 can be drawn
    means = model.params["means"].detach().clone()
    assert relocate(model, opts, dead, weights, 0.005) == 2
    torch.testing.assert_close(model.params["means"].detach()[[1, 3]], means[[4, 4]])
    opacity = torch.sigmoid(model.params["opacities"].detach())
    # Gaussian 4 and its two copies are together as opaque as it was.
    assert 1.0 - float((1.0 - opacity[[1, 3, 4]]).prod()) == pytest.approx(0.9, rel=1e-5)
    torch.testing.assert_close(opacity[[0, 2, 5]], torch.tensor([0.8, 0.6, 0.7]))
    for name in ("means", "opacities", "sh0"):
        moments = _moments(opts, model, name)
        assert moments[[1, 3, 4]].abs().sum() == 0  # restarted
        assert moments[[0, 2, 5]].abs().sum() > 0  # kept
    assert len(model) == 6


def test_growth_appends_copies_of_drawn_gaussians_with_aligned_state() -> None:
    model, opts = model_and_adam(5)
    with torch.no_grad():
        model.params["opacities"][:] = torch.logit(torch.tensor([0.5, 0.5, 0.9, 0.5, 0.5]))
    add_copies(model, opts, 3, torch.tensor([0.0, 0.0, 1.0, 0.0, 0.0]), 0.005)
    assert len(model) == 8
    for name, p in model.params.items():
        assert opts[name].param_groups[0]["params"][0] is p
        assert opts[name].state[p]["exp_avg"].shape == p.shape
    torch.testing.assert_close(
        model.params["means"].detach()[5:], model.params["means"].detach()[[2, 2, 2]]
    )
    opacity = torch.sigmoid(model.params["opacities"].detach())
    assert 1.0 - float((1.0 - opacity[[2, 5, 6, 7]]).prod()) == pytest.approx(0.9, rel=1e-5)


def test_error_weights_follow_the_densifiers_gradient_statistics() -> None:
    # The draw uses the statistics the 3DGS rules grow by (here unweighted by footprint):
    # a Gaussian with twice the screen gradient is drawn twice as often, an unseen one never.
    options = DensifyOptions(strategy="simple", pixel_weighted=False, near_damping=0.0)
    densifier = Densifier(options, scene_scale=1.0, use_gsplat=False)
    means2d = torch.zeros(1, 3, 2, requires_grad=True)
    means2d.grad = torch.tensor([[[1.0, 0.0], [0.0, 2.0], [0.0, 0.0]]])
    out = RasterOutput(
        colors=torch.zeros(1, 2, 2, 3),
        alphas=torch.zeros(1, 2, 2, 1),
        means2d=means2d,
        radii=torch.tensor([[[1, 1], [1, 1], [0, 0]]], dtype=torch.int32),
        depths=torch.full((1, 3), 5.0),
        info={"width": 2, "height": 2, "n_cameras": 1},
        backend="torch",
    )
    densifier._accumulate(out, 3, 3)
    model, _ = model_and_adam(3)
    with torch.no_grad():
        model.params["opacities"][:] = 0.0
    w = mcmc_weights(model, densifier.state["grad2d"], densifier.state["count"], 1.0)
    assert float(w[2]) == 0.0
    assert float(w[1]) == pytest.approx(2.0 * float(w[0]))


def test_invalid_mcmc_and_tail_options_are_refused() -> None:
    with pytest.raises(ValueError, match="mcmc_error_weight=1.5"):
        TrainOptions(densify=DensifyOptions(mcmc_error_weight=1.5))
    with pytest.raises(ValueError, match="lr.tail=0"):
        TrainOptions(lr=LearningRates(tail=0.0))


@pytest.fixture
def gsplat_stand_in(monkeypatch: pytest.MonkeyPatch) -> list[float]:
    """Stand-ins for what gsplat (CUDA) gives MCMC: its strategy record and position noise.

    Returns the list the noise calls' scalers are appended to.
    """
    import sys
    import types
    from dataclasses import dataclass

    @dataclass
    class StandIn:
        cap_max: int
        min_opacity: float
        refine_start_iter: int
        refine_stop_iter: int
        refine_every: int
        noise_lr: float = 5e5

        def initialize_state(self) -> dict[str, object]:
            return {"binoms": torch.zeros(1)}

    noise_calls: list[float] = []
    strategy = types.ModuleType("gsplat.strategy")
    strategy.MCMCStrategy = StandIn  # type: ignore[attr-defined]
    ops = types.ModuleType("gsplat.strategy.ops")
    ops.inject_noise_to_position = lambda **kw: noise_calls.append(kw["scaler"])  # type: ignore[attr-defined]
    monkeypatch.setitem(sys.modules, "gsplat", types.ModuleType("gsplat"))
    monkeypatch.setitem(sys.modules, "gsplat.strategy", strategy)
    monkeypatch.setitem(sys.modules, "gsplat.strategy.ops", ops)
    return noise_calls


def test_error_weighted_refinement_relocates_and_grows_with_aligned_state(
    gsplat_stand_in: list[float],
) -> None:
    # The refinement step itself, on the CPU, with the stand-ins for gsplat.
    noise_calls = gsplat_stand_in
    options = DensifyOptions(
        strategy="mcmc",
        refine_start=0,
        refine_every=10,
        refine_stop=100,
        mcmc_cap=25,
        mcmc_error_weight=1.0,
        pixel_weighted=False,
        near_damping=0.0,
    )
    densifier = Densifier(options, scene_scale=1.0, use_gsplat=True)
    model, opts = model_and_adam(20)
    with torch.no_grad():
        model.params["opacities"][:] = 2.0
        model.params["opacities"][:4] = -8.0  # four faded ones
    means = model.params["means"].detach().clone()

    def out(n: int) -> RasterOutput:
        grad = torch.zeros(1, n, 2)
        grad[0, 10, 0] = 1.0  # only Gaussian 10 has an image error
        return one_view_output(n, grad)

    for step in range(1, 11):
        densifier.post_backward(
            step, model, opts, out(len(model)), len(model), torch.Generator(), means_lr=1e-4
        )
    assert noise_calls == [pytest.approx(1e-4 * 5e5)] * 10  # noise on every step
    assert len(model) == 21  # grown by 5 %, up to the cap
    means_now = model.params["means"].detach()
    # Every faded Gaussian and the new one are copies of the one with the error.
    torch.testing.assert_close(means_now[[0, 1, 2, 3, 20]], means[[10] * 5])
    torch.testing.assert_close(means_now[4:10], means[4:10])
    opacity = torch.sigmoid(model.params["opacities"].detach())
    assert 1.0 - float((1.0 - opacity[[0, 1, 2, 3, 10, 20]]).prod()) == pytest.approx(
        float(torch.sigmoid(torch.tensor(2.0))), rel=1e-5
    )
    for name, p in model.params.items():
        assert opts[name].param_groups[0]["params"][0] is p
        assert opts[name].state[p]["exp_avg"].shape == p.shape
    assert densifier.state["grad2d"] is None  # statistics restart after each refinement


def _state(opts: dict[str, torch.optim.Optimizer], model: gm.GaussianModel, name: str, key: str):
    return opts[name].state[model.params[name]][key]


def test_relocation_can_keep_the_drawn_gaussians_moments_and_hand_them_on() -> None:
    model, opts = model_and_adam(6)
    with torch.no_grad():
        model.params["opacities"][:] = torch.logit(torch.tensor([0.8, 0.001, 0.6, 0.002, 0.9, 0.7]))
    before = {
        (name, key): _state(opts, model, name, key).clone()
        for name in ("means", "opacities", "sh0")
        for key in ("exp_avg", "exp_avg_sq")
    }
    dead = torch.sigmoid(model.params["opacities"].detach()) <= 0.005
    weights = torch.tensor([0.0, 0.0, 0.0, 0.0, 1.0, 0.0])
    assert relocate(model, opts, dead, weights, 0.005, inherit_moments=True) == 2
    for (name, key), old in before.items():
        now = _state(opts, model, name, key)
        assert old[4].abs().sum() > 0
        torch.testing.assert_close(now[[1, 3, 4]], old[[4, 4, 4]])  # kept, and handed on
        torch.testing.assert_close(now[[0, 2, 5]], old[[0, 2, 5]])


def test_growth_can_hand_the_drawn_gaussians_moments_to_their_copies() -> None:
    model, opts = model_and_adam(5)
    before = _state(opts, model, "means", "exp_avg_sq").clone()
    add_copies(model, opts, 3, torch.tensor([0.0, 0.0, 1.0, 0.0, 0.0]), 0.005, inherit_moments=True)
    now = _state(opts, model, "means", "exp_avg_sq")
    assert now.shape == (8, 3)
    torch.testing.assert_close(now[:5], before)
    torch.testing.assert_close(now[5:], before[[2, 2, 2]])
    add_copies(model, opts, 1, torch.tensor([0.0] * 7 + [1.0]), 0.005)  # gsplat's way: restart
    now = _state(opts, model, "means", "exp_avg_sq")
    assert now[[7, 8]].abs().sum() == 0


def test_mcmc_refinement_with_inherited_moments_draws_by_opacity(
    gsplat_stand_in: list[float],
) -> None:
    # Done here rather than by gsplat's strategy: no gradient statistics, the paper's draw by
    # opacity, moments handed on, noise on every step.
    options = DensifyOptions(
        strategy="mcmc", refine_start=0, refine_every=10, refine_stop=100, mcmc_cap=25,
        mcmc_inherit_moments=True,
    )  # fmt: skip
    densifier = Densifier(options, scene_scale=1.0, use_gsplat=True)
    model, opts = model_and_adam(20)
    with torch.no_grad():
        model.params["opacities"][:] = -8.0  # all faded but Gaussian 7
        model.params["opacities"][7] = 2.0
    means = model.params["means"].detach().clone()
    moments = _state(opts, model, "means", "exp_avg").clone()
    for step in range(1, 11):
        n = len(model)
        out = one_view_output(n)  # no image error anywhere: the draw is by opacity alone
        densifier.post_backward(step, model, opts, out, n, torch.Generator(), means_lr=1e-4)
    assert densifier.state["grad2d"] is None  # no statistics kept
    assert len(gsplat_stand_in) == 10
    assert len(model) == 21
    torch.testing.assert_close(model.params["means"].detach(), means[[7] * 21])
    torch.testing.assert_close(_state(opts, model, "means", "exp_avg"), moments[[7] * 21])
    opacity = torch.sigmoid(model.params["opacities"].detach())
    assert 1.0 - float((1.0 - opacity).prod()) == pytest.approx(
        float(torch.sigmoid(torch.tensor(2.0))), rel=1e-4
    )


def test_a_gaussian_the_relocation_breaks_is_made_transparent_at_once(
    gsplat_stand_in: list[float],
) -> None:
    # gsplat's relocation may leave a NaN scale (its float32 split of an opacity of 1 among
    # many copies): the refinement step quenches it before the next step renders it.
    options = DensifyOptions(strategy="mcmc", refine_start=0, refine_every=10, refine_stop=100)
    densifier = Densifier(options, scene_scale=1.0, use_gsplat=True)
    model, opts = model_and_adam(8)

    def relocation(params: dict[str, torch.Tensor], *args: object, **kwargs: object) -> None:
        with torch.no_grad():
            params["scales"][3, 1] = float("nan")

    densifier.strategy.step_post_backward = relocation  # type: ignore[attr-defined]
    out = one_view_output(8)
    densifier.post_backward(9, model, opts, out, 8, torch.Generator())  # not a refinement step
    assert densifier.n_non_finite == 0
    assert not torch.isfinite(model.params["scales"]).all()
    densifier.post_backward(10, model, opts, out, 8, torch.Generator())
    assert densifier.n_non_finite == 2  # the one from step 9 before, the new one after
    for p in model.params.values():
        assert torch.isfinite(p).all()
    assert float(torch.sigmoid(model.params["opacities"].detach()).flatten()[3]) < 1e-12


def _gsplat_split_factor_float32(opacity: float, copies: int) -> float:
    """The scale factor gsplat 1.5.3's relocation kernel computes, with its float32 order."""
    f32 = np.float32
    o = f32(opacity)
    new_o = f32(1.0) - np.power(f32(1.0) - o, f32(1.0) / f32(copies))
    denom = f32(0.0)
    for i in range(1, copies + 1):
        for k in range(i):
            term = (f32((-1) ** k) / np.sqrt(f32(k + 1))) * np.power(new_o, f32(k + 1))
            denom = f32(denom + f32(math.comb(i - 1, k)) * term)
    return float(o / denom)


def test_mcmc_keeps_opacities_off_1_where_gsplats_relocation_breaks(
    gsplat_stand_in: list[float],
) -> None:
    from cam2sim.splat.densify import MAX_OPACITY_LOGIT

    # Why: at an opacity of exactly 1 (float32), 40 copies give a negative scale factor...
    assert _gsplat_split_factor_float32(1.0, 40) < 0.0
    # ...while at the clamp's opacity every number of copies gives the float64 value.
    edge = float(torch.sigmoid(torch.tensor(MAX_OPACITY_LOGIT)))
    assert edge < 1.0
    for copies in (2, 10, 30, 40, 51):
        exact = relocation_split(
            torch.tensor([edge], dtype=torch.float64),
            torch.ones(1, 3, dtype=torch.float64),
            torch.tensor([copies]),
        )[1][0, 0]
        assert _gsplat_split_factor_float32(edge, copies) == pytest.approx(float(exact), rel=1e-3)
    # So the densifier clamps the logits before every relocation.
    options = DensifyOptions(strategy="mcmc", refine_start=0, refine_every=10, refine_stop=100)
    densifier = Densifier(options, scene_scale=1.0, use_gsplat=True)
    model, opts = model_and_adam(4)
    with torch.no_grad():
        model.params["opacities"][:] = torch.tensor([30.0, 16.0, 2.0, -3.0])
    seen: list[torch.Tensor] = []
    densifier.strategy.step_post_backward = (  # type: ignore[attr-defined]
        lambda params, *a, **k: seen.append(params["opacities"].detach().clone())
    )
    out = one_view_output(4)
    densifier.post_backward(10, model, opts, out, 4, torch.Generator())
    torch.testing.assert_close(seen[0].flatten(), torch.tensor([15.0, 15.0, 2.0, -3.0]))
