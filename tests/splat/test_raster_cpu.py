"""The compiled CPU compositing (numba) against the torch compositing it replaces."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("numba")
torch = pytest.importorskip("torch")

from cam2sim.splat import raster_cpu  # noqa: E402
from cam2sim.splat.raster_torch import rasterization  # noqa: E402

W, H = 70, 45  # not multiples of the 16-pixel tile


def _scene(n: int, seed: int, channels: int) -> dict[str, torch.Tensor]:
    rng = np.random.default_rng(seed)
    opac = rng.uniform(0.05, 1.0, n)
    opac[: n // 4] = 1.0  # the 0.999 alpha clamp and early pixel termination both happen
    scene = {
        "means": rng.uniform([-1.5, -1.0, 3.0], [1.5, 1.0, 8.0], (n, 3)),
        "quats": rng.normal(size=(n, 4)),
        "scales": rng.uniform(0.02, 0.4, (n, 3)),
        "opacities": opac,
        "colors": rng.uniform(0.0, 1.0, (n, channels)),
        "viewmats": np.eye(4)[None],
        "Ks": np.array([[[40.0, 0, 35.0], [0, 40.0, 22.0], [0, 0, 1]]]),
        "backgrounds": rng.uniform(0.0, 1.0, (1, channels)),
    }
    return {k: torch.tensor(v, dtype=torch.float32) for k, v in scene.items()}


def _run(
    t: dict[str, torch.Tensor], compositing: str, weights: torch.Tensor
) -> dict[str, torch.Tensor]:
    leaves = {
        k: t[k].clone().requires_grad_()
        for k in ("means", "quats", "scales", "opacities", "colors")
    }
    out = rasterization(
        leaves["means"], leaves["quats"], leaves["scales"], leaves["opacities"], leaves["colors"],
        t["viewmats"], t["Ks"], W, H, backgrounds=t["backgrounds"], compositing=compositing,  # type: ignore[arg-type]
    )  # fmt: skip
    out.means2d.retain_grad()
    loss = (out.colors * weights).sum() + 0.7 * out.alphas.sum()
    loss.backward()
    grads = {f"d_{k}": v.grad for k, v in leaves.items()}
    return {
        "colors": out.colors.detach(),
        "alphas": out.alphas.detach(),
        "d_means2d": out.means2d.grad,
        **grads,
    }


@pytest.mark.parametrize(("n", "seed", "channels"), [(40, 0, 3), (300, 1, 4), (800, 2, 3)])
def test_compiled_compositing_matches_torch(n: int, seed: int, channels: int) -> None:
    t = _scene(n, seed, channels)
    weights = torch.tensor(
        np.random.default_rng(seed).uniform(-1, 1, (1, H, W, channels)), dtype=torch.float32
    )
    ref = _run(t, "torch", weights)
    got = _run(t, "compiled", weights)
    assert float(ref["alphas"].max()) > 0.99  # the scene covers pixels opaquely
    for key, want in ref.items():
        scale = float(want.abs().max()) + 1e-6
        err = float((got[key] - want).abs().max())
        assert err <= 2e-4 * scale + 1e-6, f"{key}: max error {err:.3g} (scale {scale:.3g})"


def test_auto_uses_the_compiled_path_for_float32_on_cpu(monkeypatch: pytest.MonkeyPatch) -> None:
    calls = []
    real = raster_cpu.composite
    monkeypatch.setattr(raster_cpu, "composite", lambda *a, **k: calls.append(1) or real(*a, **k))
    t = _scene(20, 3, 3)
    rasterization(
        t["means"],
        t["quats"],
        t["scales"],
        t["opacities"],
        t["colors"],
        t["viewmats"],
        t["Ks"],
        W,
        H,
    )
    assert calls == [1]
    t64 = {k: v.double() for k, v in t.items()}  # float64 (gradcheck tests): the torch path
    rasterization(
        t64["means"],
        t64["quats"],
        t64["scales"],
        t64["opacities"],
        t64["colors"],
        t64["viewmats"],
        t64["Ks"],
        W,
        H,
    )
    assert calls == [1]


def test_environment_turns_the_compiled_path_off(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv(raster_cpu.ENV_VAR, "torch")
    assert not raster_cpu.available()
    monkeypatch.delenv(raster_cpu.ENV_VAR)
    assert raster_cpu.available()


@pytest.mark.parametrize("compositing", ["compiled", "torch"])
@pytest.mark.parametrize("rows", [(0, 20), (13, 38), (30, H)])
def test_a_band_of_rows_is_those_rows_of_the_whole_image(
    compositing: str, rows: tuple[int, int]
) -> None:
    t = _scene(300, 3, 3)
    args = [t[k] for k in ("means", "quats", "scales", "opacities", "colors", "viewmats", "Ks")]
    kwargs = {"backgrounds": t["backgrounds"], "compositing": compositing}
    whole = rasterization(*args, W, H, **kwargs)  # type: ignore[arg-type]
    band = rasterization(*args, W, H, rows=rows, **kwargs)  # type: ignore[arg-type]
    first, stop = rows
    assert band.colors.shape == (1, stop - first, W, 3)
    # Gaussians centred outside the band (large ones reach in) keep the whole image's shapes.
    np.testing.assert_allclose(band.colors, whole.colors[:, first:stop], atol=1e-5)
    np.testing.assert_allclose(band.alphas, whole.alphas[:, first:stop], atol=1e-5)
    with pytest.raises(ValueError, match="rows"):
        rasterization(*args, W, H, rows=(10, H + 1), **kwargs)  # type: ignore[arg-type]
