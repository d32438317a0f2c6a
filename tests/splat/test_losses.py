"""Training losses, the phase timer, and the fast paths of the trainer against their references.

The ``requires_cuda`` tests compare gsplat's SH kernel and the densifier's statistics with the
torch SH and gsplat's own ``DefaultStrategy`` bookkeeping; run them on a GPU machine with
``pytest -m requires_cuda tests/splat/test_losses.py`` (gsplat 1.5.3 installed).
"""

from __future__ import annotations

import pytest

pytest.importorskip("torch")

import torch

from cam2sim.splat import losses, profiling
from cam2sim.splat import model as gm
from cam2sim.splat.raster import RasterOutput, has_gsplat

pytestmark = pytest.mark.usefixtures("one_torch_thread")


def _images(seed: int, h: int = 40, w: int = 52) -> tuple[torch.Tensor, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    x = torch.rand((h, w, 3), generator=g, dtype=torch.float64)
    y = (x + 0.2 * torch.rand((h, w, 3), generator=g, dtype=torch.float64)).clamp(0, 1)
    return x, y


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_separable_ssim_matches_the_full_window(seed: int) -> None:
    x, y = _images(seed)
    x.requires_grad_()
    fast = losses.ssim(x, y)
    (grad_fast,) = torch.autograd.grad(fast, x)
    ref = losses.ssim_reference(x, y)
    (grad_ref,) = torch.autograd.grad(ref, x)
    torch.testing.assert_close(fast, ref, rtol=1e-10, atol=1e-12)
    torch.testing.assert_close(grad_fast, grad_ref, rtol=1e-8, atol=1e-12)
    assert float(losses.ssim(y, y)) == pytest.approx(1.0)


def test_photometric_loss_is_the_masked_l1_ssim_mix() -> None:
    x, y = _images(3)
    mask = torch.zeros(x.shape[:2], dtype=torch.bool)
    mask[5:30, 4:40] = True
    sky = torch.zeros_like(mask)
    sky[:10] = True
    share = torch.rand(mask.shape, dtype=torch.float64, generator=torch.Generator().manual_seed(4))
    n = mask.sum()
    sky_px, street_px = sky & mask, ~sky & mask
    weights = (sky_px / sky_px.sum(), street_px / street_px.sum())
    loss = losses.photometric_loss(
        x, y, mask, 1.0 / (3 * n), 0.2, (share, *weights), sky_weight=0.05
    )
    l1 = (x - y).abs()[mask].mean()
    ssim = losses.ssim_reference(torch.where(mask[..., None], x, y), y)
    sky_terms = (1 - share)[sky_px].mean() + share[street_px].mean()
    expected = 0.8 * l1 + 0.2 * (1 - ssim) + 0.05 * sky_terms
    torch.testing.assert_close(loss, expected, rtol=1e-6, atol=1e-9)


def test_apply_affine_is_a_matrix_and_an_offset() -> None:
    rgb = torch.rand(6, 7, 3)
    affine = torch.rand(3, 4)
    expected = rgb @ affine[:, :3].T + affine[:, 3]
    torch.testing.assert_close(losses.apply_affine(rgb, affine), expected)
    torch.testing.assert_close(losses.apply_affine(rgb[..., :3], torch.eye(3, 4)), rgb)


def test_phase_timer_sums_host_time_per_phase() -> None:
    timer = profiling.PhaseTimer(enabled=True, device="cpu")
    for _ in range(3):
        timer.begin()
        timer.mark("render")
        timer.mark("loss")
        timer.end()
    summary = timer.summary()
    assert summary["steps"] == 3.0
    assert {"step_ms", "render.host_ms", "loss.host_ms"} <= set(summary)
    assert not any(key.endswith("device_ms") for key in summary)
    off = profiling.PhaseTimer(enabled=False, device="cpu")
    off.begin()
    off.mark("render")
    off.end()
    assert off.summary() == {}


def test_profiling_is_requested_by_option_or_environment(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv(profiling.ENV_VAR, raising=False)
    assert not profiling.profiling_requested(option=False)
    assert profiling.profiling_requested(option=True)
    monkeypatch.setenv(profiling.ENV_VAR, "1")
    assert profiling.profiling_requested(option=False)


# --------------------------------------------------------------------------------- CUDA only


def _random_model(n: int, degree: int, seed: int, device: str) -> gm.GaussianModel:
    g = torch.Generator().manual_seed(seed)
    model = gm.GaussianModel.from_points(
        torch.randn((n, 3), generator=g) * 5.0,
        torch.rand((n, 3), generator=g),
        sh_degree=degree,
        scales=torch.full((n,), 0.1),
    ).to(device)
    with torch.no_grad():
        model.params["shN"].normal_(0.0, 0.2)
    return model


@pytest.mark.requires_cuda
@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA GPU")
@pytest.mark.parametrize("degree", [0, 1, 3])
def test_gsplat_sh_colours_match_the_torch_sh(degree: int) -> None:
    if not has_gsplat():
        pytest.skip("gsplat is not installed (pip install 'cam2sim[splat-cuda]')")
    street = _random_model(5_000, 3, 0, "cuda")
    sky = _random_model(300, 0, 1, "cuda")
    campos = torch.tensor([[0.5, -1.0, 0.2]], device="cuda")
    results = []
    for backend in ("torch", "gsplat"):
        for model in (street, sky):
            for p in model.params.values():
                p.grad = None
        inputs = gm.gather_splats(street, sky, campos, degree, backend=backend)
        weights = torch.linspace(-1, 1, inputs.colors.numel(), device="cuda")
        (inputs.colors.flatten() * weights).sum().backward()
        grads = [
            torch.zeros_like(p) if p.grad is None else p.grad.clone()
            for p in (street.params[k] for k in ("means", "sh0", "shN"))
        ]
        results.append((inputs.colors.detach(), grads))
    (colors_t, grads_t), (colors_g, grads_g) = results
    torch.testing.assert_close(colors_g, colors_t, rtol=1e-5, atol=1e-5)
    for ours, theirs in zip(grads_g, grads_t, strict=True):
        torch.testing.assert_close(ours, theirs, rtol=1e-4, atol=1e-5)


@pytest.mark.requires_cuda
@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA GPU")
def test_dense_densify_statistics_match_gsplat_strategy() -> None:
    if not has_gsplat():
        pytest.skip("gsplat is not installed (pip install 'cam2sim[splat-cuda]')")
    from cam2sim.splat.densify import Densifier
    from cam2sim.splat.train import DensifyOptions

    n, n_street = 4_000, 3_500
    g = torch.Generator(device="cuda").manual_seed(0)
    densifier = Densifier(DensifyOptions(), 10.0, use_gsplat=True)
    reference = densifier.strategy.initialize_state(scene_scale=10.0)
    model = _random_model(n_street, 1, 2, "cuda")
    for _ in range(3):
        means2d = torch.randn((1, n, 2), device="cuda", generator=g).requires_grad_()
        means2d.grad = torch.randn((1, n, 2), device="cuda", generator=g)
        radii = torch.randint(-1, 4, (1, n, 2), device="cuda", generator=g).clamp_min(0)
        info = {"width": 480, "height": 360, "n_cameras": 1}
        out = RasterOutput(
            colors=torch.zeros(1), alphas=torch.zeros(1), means2d=means2d, radii=radii,
            depths=torch.zeros(1), info=info, backend="gsplat",
        )  # fmt: skip
        densifier._accumulate(out, n_street, n_street)
        proxy = means2d.detach()[:, :n_street]
        proxy.grad = means2d.grad[:, :n_street]
        gs_info = {**info, "means2d": proxy, "radii": radii[:, :n_street], "gaussian_ids": None}
        densifier.strategy._update_state(model.params, reference, gs_info, packed=False)
    torch.testing.assert_close(densifier.state["grad2d"], reference["grad2d"])
    torch.testing.assert_close(densifier.state["count"], reference["count"])


def test_adam_step_matches_each_fused_adam_step() -> None:
    from cam2sim.splat.optim import adam_step

    g = torch.Generator().manual_seed(5)
    shapes = {"a": (50, 3), "b": (50,), "c": (7, 0, 3), "d": (4, 3, 4)}
    lrs = {"a": 1e-2, "b": 5e-2, "c": 1e-3, "d": 1e-2}
    start = {k: torch.randn(s, generator=g) for k, s in shapes.items()}
    runs = []
    for together in (False, True):
        params = {k: torch.nn.Parameter(v.clone()) for k, v in start.items()}
        opts = [
            torch.optim.Adam([params["a"]], lr=lrs["a"], eps=1e-15, fused=True),
            torch.optim.Adam(
                [{"params": [params["b"]], "lr": lrs["b"]}, {"params": [params["c"]]}],
                lr=lrs["c"],
                eps=1e-15,
                fused=True,
            ),
            torch.optim.Adam([params["d"]], lr=lrs["d"], fused=True),
            torch.optim.SGD([torch.nn.Parameter(torch.zeros(2))], lr=0.1),
        ]
        for step in range(4):
            gen = torch.Generator().manual_seed(step)
            loss = sum((p * torch.randn(p.shape, generator=gen)).sum() for p in params.values())
            torch.autograd.backward(torch.as_tensor(loss))
            if step == 2:
                params["a"].grad = None  # skipped, as Adam.step skips it
            if together:
                adam_step(opts)
            else:
                for opt in opts:
                    opt.step()
                    opt.zero_grad(set_to_none=True)
        assert all(p.grad is None for p in params.values())
        runs.append((params, opts))
    (ref, ref_opts), (ours, our_opts) = runs
    for k in shapes:
        torch.testing.assert_close(ours[k], ref[k], rtol=0, atol=0)
    for ref_opt, our_opt in zip(ref_opts[:3], our_opts[:3], strict=True):
        for p_ref, p_ours in zip(ref_opt.state.values(), our_opt.state.values(), strict=True):
            for key in ("step", "exp_avg", "exp_avg_sq"):
                torch.testing.assert_close(p_ours[key], p_ref[key], rtol=0, atol=0)


def test_adam_step_skips_a_step_with_non_finite_gradients_and_counts_it() -> None:
    from cam2sim.splat.optim import adam_step

    a = torch.nn.Parameter(torch.ones(4, 3))
    c = torch.nn.Parameter(torch.ones(2))
    b = torch.nn.Parameter(torch.ones(5))
    opts = [
        torch.optim.Adam([a], lr=0.1, eps=1e-15, fused=True),
        torch.optim.Adam([c], lr=0.1, eps=1e-15, fused=True),
        torch.optim.SGD([b], lr=0.1),  # stepped by its own step(): non-finite values zeroed
    ]
    counter = torch.zeros((), dtype=torch.int64)
    a.grad = torch.full((4, 3), 2.0)
    a.grad[1, 2] = float("nan")
    c.grad = torch.ones(2)
    b.grad = torch.tensor([1.0, float("-inf"), 1.0, 1.0, float("nan")])
    adam_step(opts, finite=True, non_finite_steps=counter)
    assert int(counter) == 1
    # The fused optimizers skipped the step: parameters, moments and step counts as before.
    torch.testing.assert_close(a.detach(), torch.ones(4, 3))
    torch.testing.assert_close(c.detach(), torch.ones(2))
    for p in (a, c):
        state = opts[0 if p is a else 1].state[p]
        assert float(state["step"]) == 0.0
        assert not state["exp_avg"].any()
        assert not state["exp_avg_sq"].any()
    torch.testing.assert_close(b.detach(), torch.tensor([0.9, 1.0, 0.9, 0.9, 1.0]))
    assert all(p.grad is None for p in (a, b, c))
    a.grad, c.grad = torch.ones(4, 3), torch.ones(2)
    adam_step(opts, finite=True, non_finite_steps=counter)
    assert int(counter) == 1  # a finite step is stepped, and not counted
    assert float(a.detach()[0, 0]) == pytest.approx(0.9)  # Adam's first step: lr, downhill
    assert float(opts[0].state[a]["step"]) == 1.0
    a.grad = torch.full((4, 3), float("nan"))
    adam_step(opts[:1])  # without finite: as Adam does, NaN goes in
    assert torch.isnan(a).all()


def test_the_mcmc_regulariser_weighs_mean_opacity_and_mean_scale() -> None:
    import math

    import torch

    from cam2sim.splat.losses import mcmc_regulariser

    logits = torch.tensor([0.0, 0.0], requires_grad=True)  # opacity 0.5 each
    log_scales = torch.log(torch.tensor([[1.0, 2.0, 3.0]])).requires_grad_(True)  # mean 2
    value = mcmc_regulariser(logits, log_scales, 0.01, 0.1)
    assert float(value.detach()) == pytest.approx(0.01 * 0.5 + 0.1 * 2.0)
    value.backward()
    assert logits.grad is not None
    assert float(logits.grad[0]) == pytest.approx(0.01 * 0.25 / 2)  # sigmoid' = 1/4, mean of 2
    assert math.isfinite(float(log_scales.grad.sum()))  # type: ignore[union-attr]
