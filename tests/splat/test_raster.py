"""The pure-torch rasterizer against a brute-force reference, its gradients, the backend switch.

The ``requires_cuda`` tests compare it with gsplat's CUDA kernels; run them on a GPU machine with
``pytest -m requires_cuda tests/splat/test_raster.py`` (gsplat 1.5.3 installed).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest

pytest.importorskip("torch")

import torch

from cam2sim.core.errors import BackendUnavailableError
from cam2sim.splat import raster, raster_torch
from cam2sim.splat.raster_torch import rasterization, rgb_from_sh

W, H = 32, 24


pytestmark = pytest.mark.usefixtures("one_torch_thread")


def _cuda_gsplat() -> bool:
    return raster.has_gsplat()


# ------------------------------------------------------------------------------ references


def _rotmats(quats: np.ndarray) -> np.ndarray:
    w, x, y, z = (quats / np.linalg.norm(quats, axis=1, keepdims=True)).T
    return np.stack(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    ).transpose(2, 0, 1)


def reference_image(
    scene: dict[str, np.ndarray], cam: int, *, near: float = 0.01, far: float = 1e10
) -> tuple[np.ndarray, np.ndarray]:
    """Every pixel against every Gaussian, front to back, in float64 (gsplat's rules)."""
    means, colors, opac = scene["means"], scene["colors"], scene["opacities"]
    m = _rotmats(scene["quats"]) * scene["scales"][:, None, :]
    cov = m @ m.transpose(0, 2, 1)
    viewmat, k = scene["viewmats"][cam], scene["Ks"][cam]
    rot, t = viewmat[:3, :3], viewmat[:3, 3]
    fx, fy, cx, cy = k[0, 0], k[1, 1], k[0, 2], k[1, 2]
    splats = []
    for i in range(len(means)):
        x, y, z = rot @ means[i] + t
        if not near <= z <= far or opac[i] < 1 / 255:
            continue
        lim_x = ((W - cx) / fx + 0.15 * W / fx, cx / fx + 0.15 * W / fx)
        lim_y = ((H - cy) / fy + 0.15 * H / fy, cy / fy + 0.15 * H / fy)
        tx = z * min(lim_x[0], max(-lim_x[1], x / z))
        ty = z * min(lim_y[0], max(-lim_y[1], y / z))
        jac = np.array([[fx / z, 0, -fx * tx / z**2], [0, fy / z, -fy * ty / z**2]])
        cov2d = jac @ rot @ cov[i] @ rot.T @ jac.T + 0.3 * np.eye(2)
        if np.linalg.det(cov2d) <= 0:
            continue
        centre = np.array([fx * x / z + cx, fy * y / z + cy])
        splats.append((z, i, centre, np.linalg.inv(cov2d)))
    splats.sort(key=lambda s: (s[0], s[1]))
    image = np.zeros((H, W, colors.shape[-1]))
    alpha_out = np.zeros((H, W))
    bg = scene["backgrounds"][cam]
    for row in range(H):
        for col in range(W):
            p = np.array([col + 0.5, row + 0.5])
            trans, acc = 1.0, np.zeros(colors.shape[-1])
            for _, i, centre, conic in splats:
                d = centre - p
                q = d @ conic @ d
                alpha = min(0.999, opac[i] * math.exp(-0.5 * q))
                if alpha < 1 / 255:
                    continue
                if trans * (1 - alpha) <= 1e-4:
                    break
                acc += colors[i] * alpha * trans
                trans *= 1 - alpha
            image[row, col] = acc + trans * bg
            alpha_out[row, col] = 1 - trans
    return image, alpha_out


def _look_at(eye: np.ndarray, target: np.ndarray) -> np.ndarray:
    """World -> camera of an OpenCV camera at ``eye`` looking at ``target`` (world z up)."""
    z = target - eye
    z /= np.linalg.norm(z)
    x = np.cross(z, [0.0, 0.0, 1.0])
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    t_world_cam = np.eye(4)
    t_world_cam[:3, :3] = np.stack([x, y, z], axis=1)
    t_world_cam[:3, 3] = eye
    return np.linalg.inv(t_world_cam)


def make_scene(n: int = 12, *, seed: int = 0, channels: int = 3) -> dict[str, np.ndarray]:
    """``n`` random Gaussians in front of two cameras (one partly clipped by the image edge)."""
    rng = np.random.default_rng(seed)
    return {
        "means": rng.uniform([-1.2, 3.0, -0.8], [1.2, 6.0, 0.8], (n, 3)),
        "quats": rng.normal(size=(n, 4)),
        "scales": rng.uniform(0.05, 0.5, (n, 3)),
        "opacities": rng.uniform(0.05, 1.0, n),
        "colors": rng.uniform(0.0, 1.0, (n, channels)),
        "viewmats": np.stack(
            [
                _look_at(np.array([0.0, 0.0, 0.0]), np.array([0.0, 4.0, 0.0])),
                _look_at(np.array([1.0, 0.5, 0.4]), np.array([-0.5, 4.5, 0.0])),
            ]
        ),
        "Ks": np.array([[[30.0, 0, 16.0], [0, 30.0, 12.0], [0, 0, 1]]] * 2),
        "backgrounds": rng.uniform(0.0, 1.0, (2, channels)),
    }


def _tensors(
    scene: dict[str, np.ndarray], dtype: torch.dtype, device: str = "cpu"
) -> dict[str, torch.Tensor]:
    return {k: torch.tensor(v, dtype=dtype, device=device) for k, v in scene.items()}


def _render(t: dict[str, torch.Tensor], **kwargs: Any) -> raster.RasterOutput:
    return rasterization(
        t["means"],
        t["quats"],
        t["scales"],
        t["opacities"],
        t["colors"],
        t["viewmats"],
        t["Ks"],
        W,
        H,
        backgrounds=t["backgrounds"],
        **kwargs,
    )


# ----------------------------------------------------------------------------------- tests


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_torch_rasterizer_matches_brute_force_reference(seed: int) -> None:
    scene = make_scene(seed=seed)
    out = _render(_tensors(scene, torch.float64))
    for cam in range(2):
        image, alpha = reference_image(scene, cam)
        np.testing.assert_allclose(out.colors[cam].numpy(), image, atol=1e-5, rtol=0)
        np.testing.assert_allclose(out.alphas[cam, ..., 0].numpy(), alpha, atol=1e-5, rtol=0)


def test_float32_stays_close_to_reference() -> None:
    scene = make_scene(seed=3)
    out = _render(_tensors(scene, torch.float32))
    image, _ = reference_image(scene, 0)
    assert np.abs(out.colors[0].numpy() - image).max() < 1e-4


def test_tile_batches_do_not_change_the_image() -> None:
    t = _tensors(make_scene(n=30, seed=4), torch.float64)
    whole = _render(t).colors
    tiny = _render(t, max_elements=256).colors
    torch.testing.assert_close(whole, tiny, atol=1e-12, rtol=0)


def test_culled_gaussians_do_not_draw() -> None:
    scene = make_scene(n=3, seed=5)
    scene["means"][0] = [0.0, -2.0, 0.0]  # behind camera 0
    scene["opacities"][1] = 0.5 / 255  # too transparent
    t = _tensors(scene, torch.float64)
    out = _render(t)
    assert out.radii[0, 0].tolist() == [0, 0]
    assert out.radii[:, 1].eq(0).all()
    alone = {k: (v[2:] if v.shape[0] == 3 else v) for k, v in t.items()}
    torch.testing.assert_close(out.colors[0], _render(alone).colors[0])


def test_antialiased_mode_scales_opacity_by_the_mip_filter_compensation() -> None:
    scene = make_scene(n=2, seed=7)
    # Camera 0 looks along +y from the origin at (0, 4, 0): a round Gaussian there projects to
    # a round footprint of variance v = (f s / z)^2, and its compensation is v / (v + eps2d).
    scene["means"] = np.array([[0.0, 4.0, 0.0], [0.0, 4.0, 0.0]])
    scene["quats"] = np.array([[1.0, 0.0, 0.0, 0.0]] * 2)
    scene["scales"] = np.array([[0.5, 0.5, 0.5], [0.001, 0.001, 0.001]])
    t = _tensors(scene, torch.float64)
    big = {k: (v[:1] if v.shape[0] == 2 and k not in {"viewmats", "Ks", "backgrounds"} else v)
           for k, v in t.items()}  # fmt: skip
    variance = (30.0 * 0.5 / 4.0) ** 2
    scaled = dict(big, opacities=big["opacities"] * variance / (variance + 0.3))
    torch.testing.assert_close(
        _render(big, antialiased=True).colors[0], _render(scaled).colors[0], atol=1e-9, rtol=0
    )
    # A Gaussian far below a pixel fades instead of being dilated to one.
    tiny = {k: (v[1:] if v.shape[0] == 2 and k not in {"viewmats", "Ks", "backgrounds"} else v)
            for k, v in t.items()}  # fmt: skip
    assert float(_render(tiny).alphas[0].max()) > 0.02
    assert float(_render(tiny, antialiased=True).alphas[0].max()) < 1e-3
    # Gradients reach the opacities through the compensation.
    t["opacities"].requires_grad_()
    _render(t, antialiased=True).colors.sum().backward()
    assert t["opacities"].grad is not None
    assert torch.isfinite(t["opacities"].grad).all()


def test_spherical_harmonics_follow_the_3dgs_basis() -> None:
    rng = np.random.default_rng(6)
    dirs = rng.normal(size=(50, 3))
    unit = dirs / np.linalg.norm(dirs, axis=1, keepdims=True)
    x, y, z = unit.T
    coeffs = rng.normal(size=(50, 16, 3)) * 0.3
    basis = np.stack(
        [
            np.full_like(x, 0.28209479177387814),
            -0.4886025119029199 * y,
            0.4886025119029199 * z,
            -0.4886025119029199 * x,
            1.0925484305920792 * x * y,
            -1.0925484305920792 * y * z,
            0.31539156525252005 * (3 * z * z - 1),
            -1.0925484305920792 * x * z,
            0.5462742152960396 * (x * x - y * y),
            -0.5900435899266435 * y * (3 * x * x - y * y),
            2.890611442640554 * x * y * z,
            -0.4570457994644658 * y * (5 * z * z - 1),
            0.3731763325901154 * z * (5 * z * z - 3),
            -0.4570457994644658 * x * (5 * z * z - 1),
            1.445305721320277 * z * (x * x - y * y),
            -0.5900435899266435 * x * (x * x - 3 * y * y),
        ],
        axis=1,
    )
    expected = np.maximum((basis[:, :, None] * coeffs).sum(axis=1) + 0.5, 0.0)
    got = rgb_from_sh(torch.tensor(coeffs), torch.tensor(dirs * 3.0), 3)
    np.testing.assert_allclose(got.numpy(), expected, atol=1e-12)


def test_sh_colours_equal_precomputed_colours() -> None:
    scene = make_scene(seed=7)
    t = _tensors(scene, torch.float64)
    coeffs = torch.tensor(np.random.default_rng(7).normal(size=(12, 16, 3)) * 0.3)
    with_sh = _render({**t, "colors": coeffs}, sh_degree=3)
    campos = torch.linalg.inv(t["viewmats"])[:, :3, 3]
    per_cam = rgb_from_sh(coeffs[None].expand(2, -1, -1, -1), t["means"][None] - campos[:, None], 3)
    torch.testing.assert_close(with_sh.colors, _render({**t, "colors": per_cam}).colors)


def test_gradients_match_finite_differences() -> None:
    scene = make_scene(n=5, seed=8)
    scene["opacities"] = np.clip(scene["opacities"], 0.2, 0.9)
    t = _tensors(scene, torch.float64)
    weights = torch.tensor(np.random.default_rng(8).uniform(size=(2, H, W, 3)))

    def loss(
        means: torch.Tensor,
        quats: torch.Tensor,
        scales: torch.Tensor,
        opacities: torch.Tensor,
        colors: torch.Tensor,
    ) -> torch.Tensor:
        out = _render(
            {**t, "means": means, "quats": quats, "scales": scales, "opacities": opacities}
            | {"colors": colors}
        )
        return (out.colors * weights).sum()

    inputs = tuple(
        t[k].clone().requires_grad_() for k in ("means", "quats", "scales", "opacities", "colors")
    )
    assert torch.autograd.gradcheck(loss, inputs, eps=1e-6, atol=1e-5, rtol=1e-4)


def test_means2d_gradient_is_retained_for_densification() -> None:
    t = _tensors(make_scene(seed=9), torch.float32)
    t["means"].requires_grad_()
    out = _render(t)
    out.means2d.retain_grad()
    torch.autograd.backward(out.colors.sum())
    assert out.means2d.grad is not None
    seen = (out.radii > 0).all(dim=-1)
    assert out.means2d.grad[seen].abs().sum() > 0
    assert out.means2d.grad[~seen].abs().sum() == 0
    assert out.info["width"] == W
    assert out.info["n_cameras"] == 2


def test_wrong_shapes_raise() -> None:
    t = _tensors(make_scene(seed=10), torch.float32)
    with pytest.raises(ValueError, match="quats"):
        _render({**t, "quats": t["quats"][:, :3]})
    with pytest.raises(ValueError, match="colours"):
        _render({**t, "colors": t["colors"][:3]})


def test_auto_backend_is_torch_without_cuda(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    raster.has_gsplat.cache_clear()
    try:
        assert raster.resolve_backend("auto", "cpu") == "torch"
        t = _tensors(make_scene(seed=11), torch.float32)
        out = raster.rasterize(
            t["means"], t["quats"], t["scales"], t["opacities"], t["colors"], t["viewmats"],
            t["Ks"], W, H, backend="auto",
        )  # fmt: skip
        assert out.backend == "torch"
        with pytest.raises(BackendUnavailableError, match=r"cam2sim\[splat-cuda\]"):
            raster.resolve_backend("gsplat", "cuda")
        with pytest.raises(BackendUnavailableError, match="CUDA device"):
            raster.resolve_backend("gsplat", "cpu")
        with pytest.raises(ValueError, match="unknown rasterizer backend"):
            raster.resolve_backend("vulkan", "cpu")  # type: ignore[arg-type]
    finally:
        raster.has_gsplat.cache_clear()


def test_import_cam2sim_splat_raster_does_not_load_torch() -> None:
    import subprocess
    import sys

    code = (
        "import sys, cam2sim.splat.raster, cam2sim.splat.train, cam2sim.splat.render, "
        "cam2sim.splat.evaluate; print('torch' in sys.modules, 'gsplat' in sys.modules)"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.split() == ["False", "False"]


# ----------------------------------------------------------------------- CUDA parity (gsplat)


def _parity_scene(n: int, seed: int) -> dict[str, np.ndarray]:
    """``n`` Gaussians of mixed sizes filling a street-like frustum, an 800x503 camera."""
    rng = np.random.default_rng(seed)
    depth = rng.uniform(2.0, 60.0, n)
    means = np.stack(
        [rng.uniform(-0.8, 0.8, n) * depth, rng.uniform(-0.5, 0.5, n) * depth, depth], axis=1
    )
    return {
        "means": means,
        "quats": rng.normal(size=(n, 4)),
        "scales": np.exp(rng.uniform(np.log(0.01), np.log(0.6), (n, 3))),
        "opacities": rng.uniform(0.0, 1.0, n),
        "colors": rng.uniform(0.0, 1.0, (n, 3)),
        "viewmats": np.eye(4)[None],
        "Ks": np.array([[[560.0, 0.0, 400.0], [0.0, 560.0, 251.5], [0.0, 0.0, 1.0]]]),
        "backgrounds": np.array([[0.2, 0.3, 0.4]]),
    }


def _both_backends(
    scene: dict[str, np.ndarray], sh_degree: int | None = None
) -> tuple[raster.RasterOutput, raster.RasterOutput]:
    t = _tensors(scene, torch.float32, "cuda")
    if sh_degree is not None:
        rng = np.random.default_rng(1)
        coeffs = rng.normal(size=(len(scene["means"]), (sh_degree + 1) ** 2, 3)) * 0.2
        t["colors"] = torch.tensor(coeffs, dtype=torch.float32, device="cuda")
    outputs = [
        raster.rasterize(
            t["means"],
            t["quats"],
            t["scales"],
            t["opacities"],
            t["colors"],
            t["viewmats"],
            t["Ks"],
            800,
            503,
            backgrounds=t["backgrounds"],
            sh_degree=sh_degree,
            backend=backend,
        )
        for backend in ("torch", "gsplat")
    ]
    return outputs[0], outputs[1]


@pytest.mark.parametrize("sh_degree", [None, 3])
@pytest.mark.requires_cuda
@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA GPU")
def test_torch_rasterizer_matches_gsplat_cuda(sh_degree: int | None) -> None:
    if not _cuda_gsplat():
        pytest.skip("gsplat is not installed (pip install 'cam2sim[splat-cuda]')")
    ours, theirs = _both_backends(_parity_scene(20_000, seed=0), sh_degree)
    assert theirs.backend == "gsplat"
    diff = (ours.colors - theirs.colors).abs()
    assert float(diff.mean()) < 1.0 / 255.0, float(diff.mean())
    torch.testing.assert_close(ours.radii, theirs.radii, atol=1, rtol=0)
    assert float((ours.alphas - theirs.alphas).abs().mean()) < 1.0 / 255.0


@pytest.mark.requires_cuda
@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA GPU")
def test_torch_gradients_agree_with_gsplat_cuda() -> None:
    if not _cuda_gsplat():
        pytest.skip("gsplat is not installed (pip install 'cam2sim[splat-cuda]')")
    scene = _parity_scene(3_000, seed=2)
    grads = []
    for backend in ("torch", "gsplat"):
        t = _tensors(scene, torch.float32, "cuda")
        for key in ("means", "colors", "opacities"):
            t[key].requires_grad_()
        out = raster.rasterize(
            t["means"], t["quats"], t["scales"], t["opacities"], t["colors"], t["viewmats"],
            t["Ks"], 800, 503, backgrounds=t["backgrounds"], backend=backend,
        )  # fmt: skip
        target = torch.linspace(0, 1, out.colors.numel(), device="cuda").reshape(out.colors.shape)
        torch.autograd.backward(((out.colors - target) ** 2).sum())
        keys = ("means", "colors", "opacities")
        grads.append([torch.as_tensor(t[k].grad).flatten() for k in keys])
    for ours, theirs in zip(*grads, strict=True):
        cosine = torch.nn.functional.cosine_similarity(ours, theirs, dim=0)
        assert float(cosine) > 0.99, float(cosine)


def test_module_constants_follow_gsplat() -> None:
    assert raster_torch.TILE_SIZE == 16
    assert raster_torch.ALPHA_MAX == 0.999
    assert raster_torch.ALPHA_THRESHOLD == 1 / 255
    assert raster_torch.TRANSMITTANCE_MIN == 1e-4
