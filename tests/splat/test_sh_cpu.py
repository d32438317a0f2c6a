"""The compiled SH colours equal the torch ones, values and gradients."""

from __future__ import annotations

import pytest

torch = pytest.importorskip("torch")
pytest.importorskip("numba")

from cam2sim.splat import sh_cpu  # noqa: E402
from cam2sim.splat.raster_torch import rgb_from_sh  # noqa: E402


def _inputs(n: int, cams: int, seed: int) -> tuple[torch.Tensor, ...]:
    gen = torch.Generator().manual_seed(seed)
    sh0 = torch.randn(n, 1, 3, generator=gen) * 0.8
    shn = torch.randn(n, 15, 3, generator=gen) * 0.3
    dirs = torch.randn(cams, n, 3, generator=gen) * 5.0
    return sh0, shn, dirs


@pytest.mark.parametrize("degree", [0, 1, 2, 3])
@pytest.mark.parametrize("cams", [1, 2])
def test_values_and_gradients_match_the_torch_version(degree: int, cams: int) -> None:
    sh0, shn, dirs = _inputs(500, cams, seed=degree + 10 * cams)
    grad = torch.randn(cams, 500, 3, generator=torch.Generator().manual_seed(3))
    results = []
    for compiled in (True, False):
        leaves = [t.clone().requires_grad_() for t in (sh0, shn, dirs)]
        a, b, d = leaves
        if compiled:
            rgb = sh_cpu.colors(a, b, d, degree)
        else:
            coeffs = torch.cat((a, b), dim=1)
            rgb = rgb_from_sh(coeffs[None].expand(cams, -1, -1, -1), d, degree)
        (rgb * grad).sum().backward()
        # Unused inputs (degree 0: the directions, the higher bands) get no gradient: zeros.
        grads = (torch.zeros_like(t) if t.grad is None else t.grad for t in leaves)
        results.append((rgb.detach(), *grads))
    # Some colours fall below zero and are clamped: the gradients must stop there too.
    assert (results[1][0] == 0).any()
    for mine, ref in zip(results[0], results[1], strict=True):
        torch.testing.assert_close(mine, ref, rtol=1e-4, atol=1e-5)


def test_the_higher_bands_get_no_gradient_beyond_the_degree() -> None:
    sh0, shn, dirs = _inputs(50, 1, seed=0)
    shn.requires_grad_()
    sh_cpu.colors(sh0, shn, dirs, 1).sum().backward()
    assert shn.grad is not None
    assert shn.grad[:, 3:].abs().max() == 0
    assert shn.grad[:, :3].abs().max() > 0


def test_a_degree_the_coefficients_cannot_hold_is_refused() -> None:
    sh0, shn, dirs = _inputs(5, 1, seed=0)
    with pytest.raises(ValueError, match="needs 16 SH coefficients, got 9"):
        sh_cpu.colors(sh0, shn[:, :8], dirs, 3)
    with pytest.raises(ValueError, match="0 to 3"):
        sh_cpu.colors(sh0, shn, dirs, 4)


def test_float64_and_a_turned_off_switch_keep_the_torch_path(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    sh0, shn, dirs = _inputs(5, 1, seed=0)
    assert sh_cpu.applies(sh0, shn, dirs)
    assert not sh_cpu.applies(sh0.double(), shn, dirs)
    monkeypatch.setenv("CAM2SIM_SPLAT_COMPOSITE", "torch")
    assert not sh_cpu.applies(sh0, shn, dirs)
