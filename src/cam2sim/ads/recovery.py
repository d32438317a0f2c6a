"""Recovery views: the recorded frames seen from beside and askew of the recorded path.

A policy trained only on where the recorded car was never sees the car off its path, so it
cannot learn to come back (Bojarski et al. 2016 trained DAVE-2 on side cameras and on views
shifted by "viewpoint transformation" for this reason). :func:`recovery_views` makes such views
from the frames alone: the camera is moved ``e`` metres sideways and turned ``psi`` about the
vertical, everything below the horizon is taken to lie on a flat ground plane ``height_m`` under
the camera and everything above it to lie far away, so each output pixel has one source pixel
(a homography below the horizon, a rotation above). :func:`recovery_label` gives the steering
that brings the displaced car back: pure pursuit of the recorded path ``lookahead_m`` ahead,

    kappa = kappa_recorded - 2 e / L^2 - 2 psi / L     (e, psi positive to the left),

whose error dynamics ``e'' + (2/L) e' + (2/L^2) e = 0`` are damped (ratio 1/sqrt(2)), so the
labels teach a return to the path, not the undamped oscillation of a weave.

The warp works on the network's preprocessed inputs (:func:`~cam2sim.ads.dave2.preprocess`:
resize, crop rows, resize), whose pixels map to the camera frame by one axis-aligned affine
map; sources outside the crop repeat its edge.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    import numpy.typing as npt
    import torch

    from cam2sim.ads.dave2 import Dave2Config

__all__ = ["RecoveryGeometry", "recovery_label", "recovery_views"]


@dataclass(frozen=True)
class RecoveryGeometry:
    """What the warp and the labels need to know about the camera and the car.

    Attributes:
        K: ``(3, 3)`` intrinsics of the camera frames (before preprocessing).
        width: Frame width, pixels.
        height: Frame height, pixels.
        height_m: Camera height over the ground, metres.
        pitch_rad: Camera pitch, positive looking down.
        curvature_per_unit: Path curvature (1/m, positive left) per steering unit.
    """

    K: tuple[tuple[float, float, float], ...]
    width: int
    height: int
    height_m: float
    pitch_rad: float
    curvature_per_unit: float

    def __post_init__(self) -> None:
        k = np.asarray(self.K, dtype=np.float64)
        if k.shape != (3, 3) or not (k[0, 0] > 0 and k[1, 1] > 0):
            msg = f"K must be a 3x3 intrinsics matrix with positive focal lengths, got {self.K}"
            raise ValueError(msg)
        if not (self.height_m > 0 and self.width > 0 and self.height > 0):
            msg = (
                f"camera height {self.height_m} m and frame size {self.width}x{self.height} "
                "must be positive"
            )
            raise ValueError(msg)
        if self.curvature_per_unit == 0:
            msg = "curvature_per_unit must not be 0 (steering would not turn the car)"
            raise ValueError(msg)


def recovery_label(
    steering: npt.ArrayLike,
    lateral_m: npt.ArrayLike,
    yaw_rad: npt.ArrayLike,
    *,
    lookahead_m: float,
    curvature_per_unit: float,
) -> npt.NDArray[np.float64]:
    """Steering that returns a car ``lateral_m`` left of, and ``yaw_rad`` left of, its path.

    Args:
        steering: The recorded steering at the frame (the path's own turn).
        lateral_m: Offset of the displaced car to the left of the recorded pose, metres.
        yaw_rad: Heading of the displaced car to the left of the recorded heading, radians.
        lookahead_m: Pure-pursuit look-ahead distance ``L``.
        curvature_per_unit: Curvature per steering unit (positive left).
    """
    e = np.asarray(lateral_m, dtype=np.float64)
    psi = np.asarray(yaw_rad, dtype=np.float64)
    dk = -2.0 * e / lookahead_m**2 - 2.0 * psi / lookahead_m
    out: npt.NDArray[np.float64] = np.asarray(steering, dtype=np.float64) + dk / curvature_per_unit
    return out


def _net_to_frame(config: Dave2Config, width: int, height: int) -> tuple[float, ...]:
    """``(sx, ox, sy, oy)``: frame pixel = ``s * net pixel + o`` (pixel centres)."""
    sw, sh = config.source_size
    top, bottom = config.crop_rows
    left, right = config.crop_cols or (0, sw)
    nw, nh = config.input_size
    # net -> source-size frame (crop) -> camera frame, each a scale between pixel centres.
    ax, bx = (right - left) / nw, left + 0.5 * (right - left) / nw - 0.5
    ay, by = (bottom - top) / nh, top + 0.5 * (bottom - top) / nh - 0.5
    cx, dx = width / sw, 0.5 * width / sw - 0.5
    cy, dy = height / sh, 0.5 * height / sh - 0.5
    return (cx * ax, cx * bx + dx, cy * ay, cy * by + dy)


def _rotations_about(
    axis: npt.NDArray[np.float64], angle: npt.NDArray[np.float64]
) -> npt.NDArray[np.float64]:
    """``(B, 3, 3)`` rotations by ``angle`` (radians, right-handed) about the unit ``axis``."""
    a = axis / np.linalg.norm(axis)
    cross = np.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])
    c, s = np.cos(angle)[:, None, None], np.sin(angle)[:, None, None]
    rot: npt.NDArray[np.float64] = c * np.eye(3) + s * cross + (1 - c) * np.outer(a, a)
    return rot


@functools.lru_cache(maxsize=8)
def _rays(
    geometry: RecoveryGeometry, config: Dave2Config
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """The network-input pixels' rays, their ground depth and the ground's normal.

    ``(rays (P, 3), 1/depth on the ground (P,), downward normal (3,))``, pixels row by row: the
    same for every batch, so computed once (read only: callers must not write into them).
    """
    nw, nh = config.input_size
    sx, ox, sy, oy = _net_to_frame(config, geometry.width, geometry.height)
    k = np.asarray(geometry.K, dtype=np.float64)
    u, v = np.meshgrid(np.arange(nw) * sx + ox, np.arange(nh) * sy + oy)
    pix = np.stack([u, v, np.ones_like(u)], -1).reshape(-1, 3)
    rays = pix @ np.linalg.inv(k).T  # (P, 3) camera rays of the displaced view
    # Optical axes (x right, y down, z forward); the ground's normal, pointing down.
    down = np.array([0.0, math.cos(geometry.pitch_rad), math.sin(geometry.pitch_rad)])
    ground = np.clip(rays @ down, 0.0, None) / geometry.height_m
    return rays, ground, down


def _sources(
    geometry: RecoveryGeometry,
    config: Dave2Config,
    lateral_m: npt.ArrayLike,
    yaw_rad: npt.ArrayLike,
    like: torch.Tensor,
) -> torch.Tensor:
    """``(B, P, 2)`` source ``(x, y)`` network-input pixels, on ``like``'s device and dtype."""
    import torch  # noqa: PLC0415

    e = torch.as_tensor(np.atleast_1d(np.asarray(lateral_m, dtype=np.float64))).to(like)
    psi = np.atleast_1d(np.asarray(yaw_rad, dtype=np.float64))
    sx, ox, sy, oy = _net_to_frame(config, geometry.width, geometry.height)
    k = np.asarray(geometry.K, dtype=np.float64)
    rays_np, ground_np, down = _rays(geometry, config)
    rays, ground = torch.from_numpy(rays_np).to(like), torch.from_numpy(ground_np).to(like)
    rot = torch.from_numpy(_rotations_about(-down, psi)).to(like)  # turns left, about the vertical
    src = torch.einsum("bij,pj->bpi", rot, rays)
    moved = src[..., 0] - e[:, None] * ground[None, :]  # the camera moved left: -x, by 1/depth
    z = src[..., 2].clamp(min=1e-6)
    fx = (float(k[0, 0]) * moved + float(k[0, 1]) * src[..., 1]) / z + float(k[0, 2])
    fy = float(k[1, 1]) * src[..., 1] / z + float(k[1, 2])
    return torch.stack([(fx - ox) / sx, (fy - oy) / sy], -1)


def source_pixels(
    geometry: RecoveryGeometry,
    config: Dave2Config,
    lateral_m: npt.ArrayLike,
    yaw_rad: npt.ArrayLike,
) -> npt.NDArray[np.float64]:
    """Where each network-input pixel of each displaced view comes from.

    Args:
        geometry: The camera.
        config: The network's preprocessing.
        lateral_m: ``(B,)`` offsets to the left, metres.
        yaw_rad: ``(B,)`` turns to the left, radians.

    Returns:
        ``(B, h, w, 2)`` source ``(x, y)`` in network-input pixels (may lie outside the input).
    """
    import torch  # noqa: PLC0415

    nw, nh = config.input_size
    src = _sources(geometry, config, lateral_m, yaw_rad, torch.zeros((), dtype=torch.float64))
    out: npt.NDArray[np.float64] = src.numpy().reshape(-1, nh, nw, 2)
    return out


def recovery_views(
    x: torch.Tensor,
    geometry: RecoveryGeometry,
    config: Dave2Config,
    lateral_m: npt.ArrayLike,
    yaw_rad: npt.ArrayLike,
) -> torch.Tensor:
    """The batch ``x`` (``(B, 3, h, w)`` network inputs) seen from the displaced cameras.

    The warp of :func:`source_pixels`, computed on ``x``'s device in its precision: on a GPU a
    training batch costs no host work (the per-pixel NumPy version this replaced took 22 ms a
    batch of 32 on one laptop core, where a whole training batch on an H100 took about 80 ms;
    ``docs/benchmarks.md``, "Host work beside the GPU").
    """
    import torch  # noqa: PLC0415

    b, h, w = x.shape[0], *x.shape[2:]
    src = _sources(geometry, config, lateral_m, yaw_rad, x)
    # Source pixel (network input) -> grid_sample's [-1, 1] (align_corners=False).
    grid = torch.stack([(2 * src[..., 0] + 1) / w - 1, (2 * src[..., 1] + 1) / h - 1], -1)
    return torch.nn.functional.grid_sample(
        x, grid.view(b, h, w, 2), mode="bilinear", padding_mode="border", align_corners=False
    )
