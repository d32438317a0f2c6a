"""The photographic look: turn a raster frame into a photograph-like one.

:func:`photographic_look` post-processes a :class:`~cam2sim.render.raster.RasterRenderer` frame
(colours and labels of one pass) into textured asphalt, paving, grass, plaster facades, a cloudy
sky, lens blur, colour grading, vignetting and sensor noise. The demo recording is rendered with
it, and so is the ``truth`` camera (:mod:`cam2sim.render.truth`), so closed-loop runs in the
ground-truth world see exactly the recording's look.

Determinism: the world textures depend on ``seed`` only; the sensor noise is drawn from the
``rng`` given (none when ``rng`` is None: the noise-free image, e.g. to score a model against).
:func:`frame_noise_rng` derives that generator from the seed and the camera pose, so one pose
renders the same image every time, in the recording and in a closed-loop run.
"""

from __future__ import annotations

import functools
import zlib
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from cam2sim.render.meshes import Label

if TYPE_CHECKING:
    import numpy.typing as npt

__all__ = ["frame_noise_rng", "photographic_look"]

_POSE_DECIMALS = 3
"""Poses are rounded to millimetres (and 1e-3 of rotation) before they seed the noise."""

_GRAIN_M = 0.03
"""Texel of the fine grain (asphalt, paving, grass), metres."""

_PATCH_M = 0.25
"""Texel of the coarse patches (asphalt repairs, grass tufts), metres."""


def frame_noise_rng(seed: int, T_world_cam: npt.NDArray[np.float64]) -> np.random.Generator:
    """The sensor-noise generator of one frame: from the look's seed and the camera pose.

    The same seed and pose (to a millimetre) give the same noise; any other pose gives
    independent noise.
    """
    pose = np.round(np.asarray(T_world_cam, dtype=np.float64)[:3], _POSE_DECIMALS) + 0.0
    return np.random.default_rng([int(seed) & 0xFFFFFFFF, zlib.crc32(pose.tobytes())])


_MIP_LEVELS = 8
"""Pre-filtered copies of each texture tile: level ``k`` is averaged over ``2**k`` texels."""


@dataclass(frozen=True)
class _Textures:
    fine: npt.NDArray[np.float32]  # [levels, n, n], see _pyramid
    coarse: npt.NDArray[np.float32]


def _pyramid(tile: npt.NDArray[np.float32]) -> npt.NDArray[np.float32]:
    """``tile`` low-passed for footprints of 1, 2, 4, ... texels (a Gaussian of 0.4 footprint).

    Blurred as a wrapped copy, so every level still tiles seamlessly.
    """
    import cv2  # noqa: PLC0415

    levels = [tile]
    for k in range(1, _MIP_LEVELS):
        sigma = 0.4 * 2.0**k
        pad = min(int(3 * sigma) + 1, tile.shape[0])
        wrapped = np.pad(tile, pad, mode="wrap")
        blurred = np.asarray(cv2.GaussianBlur(wrapped, (0, 0), sigma), np.float32)
        levels.append(blurred[pad:-pad, pad:-pad])
    return np.stack(levels)


@functools.lru_cache(maxsize=4)
def _textures(seed: int, size: int = 256) -> _Textures:
    import cv2  # noqa: PLC0415

    rng = np.random.default_rng(seed)

    def noise(sigma: float) -> npt.NDArray[np.float32]:
        pad = int(4 * sigma) + 1  # blur a wrapped copy so the tile repeats seamlessly
        wrapped = np.pad(rng.normal(size=(size, size)).astype(np.float32), pad, mode="wrap")
        tile = np.asarray(cv2.GaussianBlur(wrapped, (0, 0), sigma), np.float32)[pad:-pad, pad:-pad]
        out: npt.NDArray[np.float32] = (tile - tile.mean()) / (tile.std() + 1e-6)
        return out

    return _Textures(fine=_pyramid(noise(0.7)), coarse=_pyramid(noise(8.0)))


def _lookup(tile: npt.NDArray[np.float32], u: npt.NDArray[Any], v: npt.NDArray[Any]) -> Any:
    n = tile.shape[0]
    return tile[np.floor(v).astype(np.int64) % n, np.floor(u).astype(np.int64) % n]


def _filtered(
    levels: npt.NDArray[np.float32],
    u: npt.NDArray[Any],
    v: npt.NDArray[Any],
    footprint: npt.NDArray[Any],
) -> npt.NDArray[np.float32]:
    """Texture at texel coordinates ``(u, v)`` averaged over ``footprint`` texels per pixel.

    Blends the two pyramid levels around ``log2(footprint)`` (trilinear mip-mapping without
    the bilinear part), as a camera integrates what one pixel sees: a texture far away or at a
    grazing angle averages out instead of aliasing into a pattern that changes with every pose.
    """
    level = np.clip(np.log2(np.maximum(footprint, 1.0)), 0.0, len(levels) - 1.0)
    low = np.floor(level).astype(np.int64)
    high = np.minimum(low + 1, len(levels) - 1)
    t = (level - low).astype(np.float32)
    n = levels[0].shape[0]
    iu, iv = np.floor(u).astype(np.int64) % n, np.floor(v).astype(np.int64) % n
    out: npt.NDArray[np.float32] = (1.0 - t) * levels[low, iv, iu] + t * levels[high, iv, iu]
    return out


def photographic_look(
    rgb: npt.NDArray[np.uint8],
    labels: npt.NDArray[np.uint8],
    T_world_cam: npt.NDArray[np.float64],
    K: npt.NDArray[np.float64],
    *,
    rng: np.random.Generator | None,
    seed: int = 0,
) -> npt.NDArray[np.uint8]:
    """Turn a raster frame into a photograph-like one.

    Textures anchored in the world (asphalt grain and patches on the road, paving joints on the
    sidewalks, grass on the verge, clouds in the sky), plaster-coloured facades, warm colour
    grading, vignetting, a slight lens blur and sensor noise. Ground textures are averaged over
    each pixel's footprint (mip-mapped), as a camera integrates them: the same road seen from
    two nearby poses looks the same, with no aliasing pattern that changes from frame to frame
    (only the sensor noise does).

    Args:
        rgb: ``(H, W, 3)`` raster colours.
        labels: ``(H, W)`` raster labels (:class:`~cam2sim.render.meshes.Label`).
        T_world_cam: The camera pose (optical axes).
        K: The intrinsics.
        rng: Draws the sensor noise; None renders without it (everything else unchanged).
        seed: Seeds the world textures (keep it fixed over a recording).
    """
    tex = _textures(seed)
    h, w = labels.shape
    img = rgb.astype(np.float32) / 255.0
    pix, vignette = _pixel_grid(h, w)
    rays = pix @ (T_world_cam[:3, :3] @ np.linalg.inv(K)).T
    rays /= np.linalg.norm(rays, axis=-1, keepdims=True)
    road = labels == Label.ROAD
    walk = labels == Label.SIDEWALK
    verge = labels == Label.BACKGROUND
    ground = road | walk | verge
    # Everything below is computed per pixel on the pixels of its class only (the ground's
    # textures, the facades' plaster, the sky): the same values as over the whole frame.
    g_rays = rays[ground]
    cam = T_world_cam[:3, 3]
    down = g_rays[:, 2] < -1e-3
    # Range to the ground plane (floored: a camera at or below the road sees it at 1 mm).
    dist = np.where(down, np.maximum(-cam[2] / np.where(down, g_rays[:, 2], -1.0), 1e-3), 1e3)
    g_x = cam[0] + dist * g_rays[:, 0]
    g_y = cam[1] + dist * g_rays[:, 1]
    near = np.clip(10.0 / dist, 0.15, 1.0).astype(np.float32)  # fine grain fades with range
    # Ground seen by one pixel, metres: its angular size times the range, stretched by the
    # grazing angle (the long axis of the pixel's footprint on the road).
    focal = 0.5 * (K[0, 0] + K[1, 1])
    g_foot = dist / (focal * np.maximum(np.abs(g_rays[:, 2]), 0.02))
    grain = _filtered(tex.fine, g_x / _GRAIN_M, g_y / _GRAIN_M, g_foot / _GRAIN_M) * near
    patches = _filtered(tex.coarse, g_x / _PATCH_M, g_y / _PATCH_M, g_foot / _PATCH_M)
    is_road, is_walk, is_verge = road[ground], walk[ground], verge[ground]

    asphalt = 1.0 + 0.15 * grain[is_road] + 0.12 * patches[is_road]
    img[road] *= (asphalt[:, None] * np.array([1.03, 1.0, 0.96], np.float32)).astype(np.float32)

    w_x, w_y, w_foot = g_x[is_walk], g_y[is_walk], g_foot[is_walk]
    fx, fy = np.abs((w_x / 0.4) % 1.0 - 0.5), np.abs((w_y / 0.4) % 1.0 - 0.5)
    joints = np.where(np.maximum(fx, fy) > 0.46, 0.75, 1.0)
    # Joints thinner than a pixel blend into their average shade (8 % of a 0.4 m slab each way).
    blend = np.clip(w_foot / (0.08 * 0.4), 0.0, 1.0)
    joints = (1.0 - blend) * joints + blend * (1.0 - 0.25 * (1.0 - 0.92**2))
    paving = joints * (1.0 + 0.08 * grain[is_walk])
    img[walk] *= paving[:, None].astype(np.float32)

    grass = 1.0 + 0.35 * grain[is_verge] + 0.15 * patches[is_verge]
    img[verge] = (np.array([0.33, 0.40, 0.22], np.float32) * grass[:, None]).astype(np.float32)

    facade = labels == Label.BUILDING
    walls = img[facade]
    shade = walls.mean(axis=-1, keepdims=True) / (138.0 / 255.0)
    img[facade] = 0.3 * walls + 0.7 * (np.array([0.80, 0.70, 0.57], np.float32) * shade)

    sky = labels == Label.SKY
    img[sky] = _sky(rays[sky], tex).astype(np.float32)
    img = _lens_and_sensor(img, vignette, rng)
    out: npt.NDArray[np.uint8] = np.clip(img * 255.0 + 0.5, 0, 255).astype(np.uint8)
    return out


@functools.lru_cache(maxsize=8)
def _pixel_grid(h: int, w: int) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float32]]:
    """Each pixel's ``(u, v, 1)`` (``(h, w, 3)``), and the vignetting (``(h, w, 1)``); read-only."""
    u, v = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
    pix = np.stack([u, v, np.ones_like(u)], axis=-1)
    r2 = ((u - w / 2) / (w / 2)) ** 2 + ((v - h / 2) / (h / 2)) ** 2
    vignette = (1.0 - 0.18 * r2)[..., None].astype(np.float32)
    pix.flags.writeable = vignette.flags.writeable = False
    return pix, vignette


def _sky(rays: npt.NDArray[np.float64], tex: _Textures) -> npt.NDArray[np.float64]:
    """Sky colours along ``rays``: a blue gradient with clouds anchored in direction."""
    elev = np.clip(rays[..., 2], 0.0, 1.0)
    azim = np.arctan2(rays[..., 1], rays[..., 0])
    base = (1 - np.sqrt(elev))[..., None] * np.array([0.87, 0.90, 0.94]) + np.sqrt(elev)[
        ..., None
    ] * np.array([0.33, 0.53, 0.84])
    cloud = _lookup(tex.coarse[0], azim * 60.0, elev * 120.0)
    cover = np.clip((cloud - 0.2) / 0.8, 0.0, 1.0)[..., None]
    out: npt.NDArray[np.float64] = (1 - 0.8 * cover) * base + 0.8 * cover * np.array(
        [0.95, 0.95, 0.96]
    )
    return out


def _lens_and_sensor(
    img: npt.NDArray[np.float32],
    vignette: npt.NDArray[np.float32],
    rng: np.random.Generator | None,
) -> npt.NDArray[np.float32]:
    """Lens and sensor: blur, warm grade with a soft S-curve, vignetting, noise (``rng``)."""
    import cv2  # noqa: PLC0415

    img = np.asarray(cv2.GaussianBlur(img, (0, 0), 0.6), np.float32)
    img = np.clip(img * 1.05, 0.0, 1.0) ** 0.9
    img = 0.5 + (img - 0.5) * 1.12
    img *= np.array([1.05, 1.0, 0.93], np.float32)
    img *= vignette
    if rng is not None:
        img += rng.normal(0.0, 0.015, img.shape).astype(np.float32)
    return img
