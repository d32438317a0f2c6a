"""Recovery views: the warp against views rendered from the displaced camera, and the labels."""

from __future__ import annotations

import math

import numpy as np
import pytest

from cam2sim.ads.dave2 import Dave2Config, preprocess
from cam2sim.ads.recovery import RecoveryGeometry, recovery_label, source_pixels

torch = pytest.importorskip("torch")

W, H = 320, 200
K = ((200.0, 0.0, 159.5), (0.0, 200.0, 99.5), (0.0, 0.0, 1.0))
CAM_HEIGHT = 1.4


def _render(lateral_m: float, yaw_rad: float, pitch_rad: float) -> np.ndarray:
    """A flat street seen from a camera ``lateral_m`` left of the lane centre, turned left.

    Vehicle axes x forward, y left, z up; the camera is ``CAM_HEIGHT`` over the ground, pitched
    down by ``pitch_rad``. The ground has lane lines at y = +-1.75 m, dashes on the centre line
    and a checker texture; the sky's colour varies with azimuth so that turns show.
    """
    u, v = np.meshgrid(np.arange(W, dtype=np.float64), np.arange(H, dtype=np.float64))
    d = np.stack([(u - K[0][2]) / K[0][0], (v - K[1][2]) / K[1][1], np.ones_like(u)], -1)
    c, s = math.cos(pitch_rad), math.sin(pitch_rad)
    basis = np.array([[0.0, -1.0, 0.0], [-s, 0.0, -c], [c, 0.0, -s]]).T  # optical -> vehicle
    cy, sy = math.cos(yaw_rad), math.sin(yaw_rad)
    yaw = np.array([[cy, -sy, 0.0], [sy, cy, 0.0], [0.0, 0.0, 1.0]])
    ray = d @ (yaw @ basis).T
    down = ray[..., 2] < -1e-6
    t = np.where(down, CAM_HEIGHT / np.where(down, -ray[..., 2], 1.0), 0.0)
    gx, gy = t * ray[..., 0], lateral_m + t * ray[..., 1]
    checker = ((np.floor(gx / 2.0) + np.floor(gy / 2.0)) % 2) * 30 + 80
    line = (np.abs(np.abs(gy) - 1.75) < 0.12) | ((np.abs(gy) < 0.08) & (gx % 6 < 3))
    ground = np.where(line, 230.0, checker)
    azimuth = np.arctan2(ray[..., 1], ray[..., 0])
    sky = 150 + 60 * np.sin(6 * azimuth)
    gray = np.where(down, ground, sky)
    return np.repeat(gray[..., None], 3, -1).clip(0, 255).astype(np.uint8)


# The published crop (frames resized to 800x503), and a crop of centre columns at the camera's
# own size (what Dave2Config.for_camera gives a wide camera).
CROPS = {
    "published": Dave2Config(),
    "centre columns": Dave2Config(source_size=(W, H), crop_rows=(81, 186), crop_cols=(60, 260)),
}


@pytest.mark.parametrize("crop", list(CROPS))
@pytest.mark.parametrize("pitch_deg", [0.0, 4.0])
@pytest.mark.parametrize(("lateral", "yaw_deg"), [(0.6, 0.0), (-0.6, 0.0), (0.0, 4.0), (0.5, -3.0)])
def test_warp_matches_the_displaced_camera(
    lateral: float, yaw_deg: float, pitch_deg: float, crop: str
) -> None:
    from cam2sim.ads.recovery import recovery_views

    cfg = CROPS[crop]
    pitch = math.radians(pitch_deg)
    geometry = RecoveryGeometry(K, W, H, CAM_HEIGHT, pitch, 0.022)
    base = preprocess(_render(0.0, 0.0, pitch)[None], cfg).astype(np.float32)
    truth = preprocess(_render(lateral, math.radians(yaw_deg), pitch)[None], cfg)
    yaw = [math.radians(yaw_deg)]
    warped = recovery_views(torch.from_numpy(base), geometry, cfg, [lateral], yaw)
    inner = np.s_[..., 10:-10]  # the edge columns repeat the border
    err = np.abs(warped.numpy() - truth)[inner].mean()
    before = np.abs(base - truth)[inner].mean()
    assert err < 0.25 * before
    assert err < 6.0


@pytest.mark.parametrize("crop", list(CROPS))
def test_no_displacement_is_the_identity(crop: str) -> None:
    cfg = CROPS[crop]
    geometry = RecoveryGeometry(K, W, H, CAM_HEIGHT, 0.05, 0.022)
    src = source_pixels(geometry, cfg, [0.0], [0.0])[0]
    w, h = cfg.input_size
    u, v = np.meshgrid(np.arange(w), np.arange(h))
    np.testing.assert_allclose(src[..., 0], u, atol=1e-6)
    np.testing.assert_allclose(src[..., 1], v, atol=1e-6)


@pytest.mark.parametrize("crop", list(CROPS))
def test_the_batch_warp_samples_where_source_pixels_says(crop: str) -> None:
    """recovery_views samples each output pixel at source_pixels' float64 position (its grid
    conversion and its precision on the batch): a ramp image shows where it sampled."""
    from cam2sim.ads.recovery import recovery_views

    cfg = CROPS[crop]
    geometry = RecoveryGeometry(K, W, H, CAM_HEIGHT, 0.05, 0.022)
    w, h = cfg.input_size
    u, v = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
    ramp = torch.from_numpy(np.stack([u, v, u + v])[None].repeat(3, 0))  # (3, 3, h, w) float64
    lateral, yaw = [0.6, -0.4, 0.0], [0.0, math.radians(3.0), math.radians(-4.0)]
    warped = recovery_views(ramp, geometry, cfg, lateral, yaw).numpy()
    src = source_pixels(geometry, cfg, lateral, yaw)
    inside = (
        (src[..., 0] >= 0) & (src[..., 0] <= w - 1) & (src[..., 1] >= 0) & (src[..., 1] <= h - 1)
    )
    assert inside.mean() > 0.5
    np.testing.assert_allclose(warped[:, 0][inside], src[..., 0][inside], atol=1e-6)
    np.testing.assert_allclose(warped[:, 1][inside], src[..., 1][inside], atol=1e-6)


def test_labels_steer_back_and_are_damped() -> None:
    k, look = 0.022, 10.0
    # Left of the path or turned left: steer right (negative); the recorded turn is kept.
    assert recovery_label(0.3, 0.5, 0.0, lookahead_m=look, curvature_per_unit=k) < 0.3
    assert recovery_label(0.3, 0.0, 0.05, lookahead_m=look, curvature_per_unit=k) < 0.3
    assert recovery_label(0.3, 0.0, 0.0, lookahead_m=look, curvature_per_unit=k) == 0.3
    # Follow the labels on a straight path from 0.6 m left: back within 5 cm, overshoot < 10 %.
    e, psi, ds, trace = 0.6, 0.0, 0.05, []
    for _ in range(int(80 / ds)):
        kappa = k * float(recovery_label(0.0, e, psi, lookahead_m=look, curvature_per_unit=k))
        psi += kappa * ds
        e += math.sin(psi) * ds
        trace.append(e)
    assert abs(trace[-1]) < 0.05
    assert min(trace) > -0.1 * 0.6


def test_geometry_is_checked() -> None:
    with pytest.raises(ValueError, match="camera height"):
        RecoveryGeometry(K, W, H, 0.0, 0.0, 0.022)
    with pytest.raises(ValueError, match="curvature_per_unit"):
        RecoveryGeometry(K, W, H, 1.4, 0.0, 0.0)
