"""Ground seeds: starting Gaussians on the ground under the cameras, where SfM leaves it bare.

Structure from motion finds few points on the road and verges right in front of a car (little
texture, fast image motion), so a chunk model starts with almost nothing there and the near
ground, which sweeps across the lower image, is drawn by a few large Gaussians. A driving camera
rides at a fixed height over the ground it sees in its lower image, so that ground can be seeded
without depth:

- :func:`camera_height`: the world's down direction is the mean of the cameras' image-down
  axes (OpenCV convention: x right, y down, z forward); the camera's height is the median,
  along it, of the points that the views see in the lower middle of their images (the road
  ahead), measured from the camera that sees them. It is in the scene's units, so scale-ambiguous
  (images-only) scenes work as metric ones do.
- :func:`ground_points`: in each view, pixels the loss uses (mask, not sky) whose ray meets the
  plane at that height under the camera within ``reach`` camera heights; a random share of
  them, placed there with the pixel's colour. The plane is each camera's own, so the seeds follow
  the road's slope. What stands on the ground (cars, trunks) is seeded behind it, and training
  moves or prunes those.

numpy only; the trainer calls it with the views it loaded.
"""

from __future__ import annotations

import logging
from typing import TYPE_CHECKING

import numpy as np

from cam2sim.core.camera import project_points

if TYPE_CHECKING:
    import numpy.typing as npt

__all__ = ["camera_height", "ground_points"]

_log = logging.getLogger(__name__)

MIN_ROAD_POINTS = 20
"""Fewer road points than this under the cameras: no height, no ground seeds."""


def _down(poses: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    down = np.asarray(poses[:, :3, 1].mean(axis=0), dtype=np.float64)
    return down / max(float(np.linalg.norm(down)), 1e-12)


def camera_height(
    xyz: npt.NDArray[np.floating],
    poses: npt.NDArray[np.float64],
    Ks: npt.NDArray[np.float64],
    usable: npt.NDArray[np.bool_],
) -> float | None:
    """The cameras' height over the ground ahead, in scene units (module doc), or None.

    Args:
        xyz: ``(N, 3)`` scene points.
        poses: ``(M, 4, 4)`` ``T_world_cam`` of the views.
        Ks: ``(M, 3, 3)`` intrinsics at the size of ``usable``.
        usable: ``(M, H, W)`` pixels that show the scene (not the ego hood, not sky).
    """
    down = _down(poses)
    pts = np.asarray(xyz, dtype=np.float64)
    _, h, w = usable.shape
    heights = []
    for pose, K, use in zip(poses, Ks, usable, strict=True):
        u, v, front = project_points(pts, pose, K)
        ahead = front & (v >= 0.75 * h) & (v < h) & (np.abs(u - 0.5 * w) < 0.25 * w)
        if not ahead.any():
            continue
        ui, vi = u[ahead].astype(np.int64), v[ahead].astype(np.int64)
        below = (pts[ahead] - pose[:3, 3])[use[vi, ui]] @ down
        heights.append(below[below > 0])
    found = np.concatenate(heights) if heights else np.zeros(0)
    if len(found) < MIN_ROAD_POINTS:
        return None
    return float(np.median(found))


def ground_points(  # noqa: PLR0913 -- the views' arrays, then keywords
    xyz: npt.NDArray[np.floating],
    poses: npt.NDArray[np.float64],
    Ks: npt.NDArray[np.float64],
    images: npt.NDArray[np.uint8],
    usable: npt.NDArray[np.bool_],
    *,
    count: int,
    reach: float = 12.0,
    seed: int = 0,
    height: float | None = None,
) -> tuple[npt.NDArray[np.float32], npt.NDArray[np.uint8]]:
    """About ``count`` points on the ground under the cameras with their pixels' colours.

    Args:
        xyz: ``(N, 3)`` scene points (they give the camera height, :func:`camera_height`).
        poses: ``(M, 4, 4)`` ``T_world_cam`` of the views.
        Ks: ``(M, 3, 3)`` intrinsics at the images' size.
        images: ``(M, H, W, 3)`` uint8 views.
        usable: ``(M, H, W)`` pixels that show the scene (not the ego hood, not sky).
        count: Points wanted, spread evenly over the views.
        reach: Farthest seed, in camera heights from the camera.
        seed: Seeds the choice of pixels.
        height: The cameras' height when the caller has it (:func:`camera_height` of the same
            points and views); None = found here.

    Returns:
        ``(K, 3)`` float32 points and ``(K, 3)`` uint8 colours; none when no camera height is
        found (fewer than :data:`MIN_ROAD_POINTS` points on the road ahead).
    """
    none = (np.zeros((0, 3), np.float32), np.zeros((0, 3), np.uint8))
    if count > 0 and height is None:
        height = camera_height(xyz, poses, Ks, usable)
    if count <= 0 or height is None:
        if count > 0:
            _log.info("no ground seeds: too few scene points on the road ahead of the cameras")
        return none
    down = _down(poses)
    rng = np.random.default_rng(seed)
    m, h, w = usable.shape
    per_view = int(np.ceil(count / m))
    vv, uu = np.mgrid[
        0:h, 0:w
    ]  # pixel (i, j) is drawn at (j + 0.5, i + 0.5), as the rasterizers do
    pix = np.stack([uu + 0.5, vv + 0.5, np.ones_like(uu)], axis=-1).reshape(-1, 3).astype(float)
    # A pixel's ray in the camera, scaled to depth 1, is Kinv @ pix; in the world R @ Kinv @ pix.
    # How far down it goes per unit of depth is down . (R Kinv pix) = pix . (Kinv^T R^T down): one
    # 3-vector a view. Its length is the camera ray's (R keeps lengths): one array per K. The ray
    # meets the plane `height` below the camera at depth height / drop, within reach camera
    # heights when its length < reach * drop. Only the picked pixels' rays are made in the world
    # (12x faster than making every pixel's: 1.5 s for a KITTI chunk's 189 views).
    lengths: dict[bytes, npt.NDArray[np.float64]] = {}
    out_xyz, out_rgb = [], []
    for pose, K, image, use in zip(poses, Ks, images, usable, strict=True):
        k_inv = np.linalg.inv(K)
        key = np.asarray(K, dtype=np.float64).tobytes()
        if key not in lengths:
            lengths[key] = np.linalg.norm(pix @ k_inv.T, axis=1)
        drop = pix @ (k_inv.T @ (pose[:3, :3].T @ down))
        ok = np.flatnonzero(use.reshape(-1) & (drop > 1e-6) & (lengths[key] < reach * drop))
        if len(ok) == 0:
            continue
        pick = rng.choice(ok, size=min(per_view, len(ok)), replace=False)
        rays = pix[pick] @ k_inv.T @ pose[:3, :3].T
        out_xyz.append(pose[:3, 3] + (height / drop[pick])[:, None] * rays)
        out_rgb.append(image.reshape(-1, 3)[pick])
    if not out_xyz:
        return none
    return np.concatenate(out_xyz).astype(np.float32), np.concatenate(out_rgb).astype(np.uint8)
