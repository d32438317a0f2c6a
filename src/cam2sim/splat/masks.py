"""Image masks for splat training: the ego hood (never part of the scene) and the sky.

Masks here are boolean ``(H, W)`` arrays where ``True`` marks the named region (hood or sky).
:mod:`cam2sim.splat.prepare` turns them into the on-disk convention of ``WS/splat/prep/``.

Hood masks come from the config (a number of bottom rows, or a polygon in pixels) or are detected
from the frames themselves: the hood is the part of the image that stays constant while the scene
moves (:func:`detect_hood_mask`).

Sky masks come from a SegFormer model when one is given (:func:`sky_mask_segformer`, a local path
or a hub id; weights are the user's input, none ship with cam2sim), else from a classical colour and
texture heuristic (:func:`sky_mask_classical`) whose limits are documented there.
"""

from __future__ import annotations

import logging
from typing import TYPE_CHECKING, Any

import numpy as np
import numpy.typing as npt

from cam2sim.core.errors import BackendUnavailableError

if TYPE_CHECKING:
    from collections.abc import Sequence

__all__ = [
    "CITYSCAPES_SKY_ID",
    "detect_hood_mask",
    "hood_mask_from_polygon",
    "hood_mask_from_rows",
    "sky_label_id",
    "sky_mask_classical",
    "sky_mask_segformer",
]

logger = logging.getLogger(__name__)

CITYSCAPES_SKY_ID = 10
_CITYSCAPES_CLASSES = 19
_TEXTURE_WINDOW = 7


def hood_mask_from_rows(h: int, w: int, rows: int) -> npt.NDArray[np.bool_]:
    """Return a hood mask covering the bottom ``rows`` rows.

    Args:
        h: Image height, pixels.
        w: Image width, pixels.
        rows: Number of bottom rows that show the hood (0 = no hood).

    Returns:
        ``(h, w)`` bool, True = hood.

    Raises:
        ValueError: A size is not positive or ``rows`` is outside ``[0, h]``.
    """
    _check_size(h, w)
    if not 0 <= rows <= h:
        msg = f"hood rows must lie in [0, {h}] for a {w}x{h} image, got {rows}"
        raise ValueError(msg)
    mask = np.zeros((h, w), dtype=bool)
    mask[h - rows :] = True
    return mask


def hood_mask_from_polygon(
    h: int, w: int, polygon_px: Sequence[tuple[float, float]] | npt.ArrayLike
) -> npt.NDArray[np.bool_]:
    """Return a hood mask filled inside a polygon.

    Args:
        h: Image height, pixels.
        w: Image width, pixels.
        polygon_px: ``(K, 2)`` vertices ``(x, y)`` in pixels (x right, y down), ``K >= 3``.

    Returns:
        ``(h, w)`` bool, True = hood.

    Raises:
        ValueError: A size is not positive or the polygon is not ``(K >= 3, 2)`` finite values.
    """
    import cv2  # noqa: PLC0415

    _check_size(h, w)
    poly = np.asarray(polygon_px, dtype=np.float64)
    if poly.ndim != 2 or poly.shape[1] != 2 or poly.shape[0] < 3 or not np.isfinite(poly).all():
        msg = f"hood polygon must be (K >= 3, 2) finite pixel vertices (x, y), got {poly.shape}"
        raise ValueError(msg)
    canvas = np.zeros((h, w), dtype=np.uint8)
    cv2.fillPoly(canvas, [np.round(poly).astype(np.int32)], 1)
    return canvas.astype(bool)


def _check_size(h: int, w: int) -> None:
    if h <= 0 or w <= 0:
        msg = f"image size must be positive, got {w}x{h}"
        raise ValueError(msg)


def _gray_stack(images: Sequence[npt.NDArray[np.generic]]) -> npt.NDArray[np.float32]:
    import cv2  # noqa: PLC0415

    out = []
    for image in images:
        arr = np.asarray(image)
        if arr.ndim == 3:
            arr = cv2.cvtColor(arr[..., :3], cv2.COLOR_RGB2GRAY)
        if arr.dtype == np.uint16:
            arr = arr / 257.0
        out.append(arr.astype(np.float32))
    shapes = {a.shape for a in out}
    if len(shapes) != 1:
        msg = f"all frames must have one size, got {sorted(shapes)}"
        raise ValueError(msg)
    return np.stack(out)


def detect_hood_mask(
    images: Sequence[npt.NDArray[np.generic]],
    *,
    max_frames: int = 30,
    static_ratio: float = 0.15,
    min_scene_std: float = 6.0,
    min_area: float = 0.005,
    max_area: float = 0.5,
) -> npt.NDArray[np.bool_] | None:
    """Detect the ego hood: the region that stays constant while the scene moves.

    Up to ``max_frames`` frames spread evenly over ``images`` are converted to grey; a pixel is
    static when its temporal standard deviation is below ``static_ratio`` times the median
    deviation of the image. Static pixels are cleaned with a morphological opening and closing,
    only the connected regions that touch the bottom border are kept, and each column is filled
    from its topmost hood pixel down to the border (a hood has no holes).

    Args:
        images: Frames ``(H, W, 3)`` RGB or ``(H, W)`` grey, uint8 (uint16 is scaled), all one
            size, in recording order; at least 3.
        max_frames: Frames used, spread over the sequence.
        static_ratio: Static threshold relative to the median temporal deviation.
        min_scene_std: Median temporal deviation (grey levels) below which the scene is taken
            as not moving; then nothing can be told apart and None is returned.
        min_area: Smallest hood, as a fraction of the image.
        max_area: Largest hood, as a fraction of the image; a larger static region means the
            vehicle stood still, and None is returned.

    Returns:
        ``(H, W)`` bool, True = hood, or None when no hood is found.

    Raises:
        ValueError: Fewer than 3 frames or frames of different sizes.
    """
    import cv2  # noqa: PLC0415

    if len(images) < 3:
        msg = f"hood detection needs at least 3 frames, got {len(images)}"
        raise ValueError(msg)
    pick = np.unique(np.linspace(0, len(images) - 1, min(max_frames, len(images))).astype(int))
    stack = _gray_stack([images[int(i)] for i in pick])
    std = stack.std(axis=0)
    scene = float(np.median(std))
    if scene < min_scene_std:
        logger.info("hood detection: scene barely moves (median std %.1f); no hood", scene)
        return None
    static = (std < static_ratio * scene).astype(np.uint8)
    h, w = static.shape
    k = max(3, (min(h, w) // 100) | 1)
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (k, k))
    static = cv2.morphologyEx(static, cv2.MORPH_OPEN, kernel)
    static = cv2.morphologyEx(static, cv2.MORPH_CLOSE, kernel)
    _, labels = cv2.connectedComponents(static, connectivity=8)
    bottom = np.unique(labels[-1][labels[-1] > 0])
    region = np.isin(labels, bottom)
    # Fill each column from its topmost hood pixel down to the bottom border.
    filled: npt.NDArray[np.bool_] = np.maximum.accumulate(region, axis=0) & region[-1][None, :]
    area = float(filled.mean())
    if area < min_area or area > max_area:
        logger.info("hood detection: static bottom region covers %.1f%%; no hood", 100 * area)
        return None
    logger.info("hood detection: hood covers %.1f%% of the image", 100 * area)
    return filled


def sky_mask_classical(
    image: npt.NDArray[np.uint8],
    *,
    horizon_fraction: float = 0.6,
    min_value: int = 110,
    max_saturation: int = 70,
    max_texture: float = 3.0,
) -> npt.NDArray[np.bool_]:
    """Find the sky with a colour and texture heuristic (no model needed).

    A pixel is a sky candidate when it is bright (HSV value >= ``min_value``), either blue
    (hue 85-135 on OpenCV's 0-180 scale, blue above red) or unsaturated (saturation <=
    ``max_saturation``: white or grey cloud, overcast), and smooth (mean gradient magnitude in a
    7x7 window <= ``max_texture`` grey levels per pixel), and lies above the horizon row estimate
    (``horizon_fraction`` of the height). Only candidate regions connected to the top border are
    kept; they are grown back by the texture window into sky-coloured pixels (the window blurs
    the skyline), and small holes (wires, thin branches) are closed.

    Limits: it misses dark skies (dusk, night, strong backlight below ``min_value``), cut-up sky
    seen through foliage where each gap is textured at the window size, and sky below the
    horizon estimate (a camera pitched down far or driving over a crest). It takes smooth, bright,
    grey or blue surfaces that touch the top border as sky (a white building facade filling the
    top of the frame, a tunnel ceiling, an overcast sky reflected in a glass front). Pass a
    SegFormer model (:func:`sky_mask_segformer`) where that matters.

    Args:
        image: ``(H, W, 3)`` RGB uint8.
        horizon_fraction: The sky never reaches below this fraction of the height.
        min_value: Smallest HSV value (brightness, 0-255) of sky.
        max_saturation: Largest HSV saturation (0-255) of grey/white sky.
        max_texture: Largest local mean gradient magnitude (grey levels per pixel).

    Returns:
        ``(H, W)`` bool, True = sky.

    Raises:
        ValueError: ``image`` is not ``(H, W, 3)`` uint8.
    """
    import cv2  # noqa: PLC0415

    arr = np.asarray(image)
    if arr.ndim != 3 or arr.shape[2] != 3 or arr.dtype != np.uint8:
        msg = f"sky_mask_classical needs an (H, W, 3) uint8 RGB image, got {arr.shape} {arr.dtype}"
        raise ValueError(msg)
    h, w = arr.shape[:2]
    hsv = cv2.cvtColor(arr, cv2.COLOR_RGB2HSV)
    hue, sat, val = hsv[..., 0], hsv[..., 1], hsv[..., 2]
    blue = (hue >= 85) & (hue <= 135) & (arr[..., 2] > arr[..., 0])
    colour = (val >= min_value) & (blue | (sat <= max_saturation))
    gray = cv2.cvtColor(arr, cv2.COLOR_RGB2GRAY).astype(np.float32)
    gx = cv2.Sobel(gray, cv2.CV_32F, 1, 0, ksize=3, scale=0.125)
    gy = cv2.Sobel(gray, cv2.CV_32F, 0, 1, ksize=3, scale=0.125)
    texture = cv2.blur(np.hypot(gx, gy), (_TEXTURE_WINDOW, _TEXTURE_WINDOW))
    above = np.zeros((h, w), dtype=bool)
    above[: round(horizon_fraction * h)] = True
    candidate = colour & (texture <= max_texture) & above
    _, labels = cv2.connectedComponents(candidate.astype(np.uint8), connectivity=4)
    top = np.unique(labels[0][labels[0] > 0])
    sky = np.isin(labels, top)
    # The texture window eats a band along the skyline: grow back into sky-coloured pixels.
    window = np.ones((_TEXTURE_WINDOW, _TEXTURE_WINDOW), np.uint8)
    sky |= (cv2.dilate(sky.astype(np.uint8), window) > 0) & colour & above
    k = max(3, (min(h, w) // 80) | 1)
    closed = cv2.morphologyEx(
        sky.astype(np.uint8), cv2.MORPH_CLOSE, cv2.getStructuringElement(cv2.MORPH_RECT, (k, k))
    )
    return np.asarray(closed, dtype=bool)


def sky_label_id(id2label: dict[int, str] | dict[str, str], num_labels: int) -> int:
    """Return the class id of "sky" in a segmentation model's label map.

    Looks for a label named ``sky`` (case-insensitive, ignoring surrounding whitespace, as in
    Cityscapes and ADE20K); a model with 19 classes and generic names is taken as Cityscapes
    (sky = 10).

    Raises:
        ValueError: No sky class in the label map.
    """
    for key, name in id2label.items():
        if str(name).strip().lower() == "sky":
            return int(key)
    if num_labels == _CITYSCAPES_CLASSES:
        return CITYSCAPES_SKY_ID
    names = ", ".join(sorted(str(v) for v in id2label.values())[:20])
    msg = (
        f"the segmentation model has no 'sky' class (labels: {names}); use a Cityscapes- or "
        "ADE20K-trained SegFormer, or leave splat.segformer unset for the classical sky mask"
    )
    raise ValueError(msg)


def sky_mask_segformer(
    images: Sequence[npt.NDArray[np.uint8]],
    model: str,
    *,
    device: str = "cpu",
    batch_size: int = 4,
) -> list[npt.NDArray[np.bool_]]:
    """Segment the sky with a SegFormer model (transformers), from a local path or a hub id.

    The model's own image processor (when its folder has one, else the SegFormer defaults) does
    the resizing and normalisation; logits are upsampled to each image's size before the argmax.
    The sky class comes from ``config.id2label`` (:func:`sky_label_id`).

    Args:
        images: ``(H, W, 3)`` RGB uint8 frames (sizes may differ).
        model: Local folder of a saved ``SegformerForSemanticSegmentation`` or a hub id
            (e.g. ``nvidia/segformer-b0-finetuned-cityscapes-512-1024``).
        device: torch device string (``cpu``, ``cuda``, ``cuda:1``).
        batch_size: Frames per forward pass.

    Returns:
        One ``(H, W)`` bool mask per image, True = sky.

    Raises:
        BackendUnavailableError: transformers or torch is not installed.
        ValueError: The model has no sky class.
    """
    try:
        import torch  # noqa: PLC0415
        import transformers  # noqa: PLC0415
    except ImportError as err:
        msg = (
            f"SegFormer sky masks need torch and transformers ({err}); `pip install transformers` "
            "(and a CPU or CUDA torch), or leave splat.segformer unset for the classical sky mask"
        )
        raise BackendUnavailableError(msg) from err

    # transformers' typing of from_pretrained(...).to() is too narrow for mypy; the model is Any.
    net: Any = transformers.SegformerForSemanticSegmentation.from_pretrained(model)
    net = net.to(device).eval()
    processor = _segformer_processor(transformers, model)
    sky_id = sky_label_id(net.config.id2label, int(net.config.num_labels))
    masks: list[npt.NDArray[np.bool_]] = []
    for start in range(0, len(images), batch_size):
        batch = [np.asarray(im)[..., :3] for im in images[start : start + batch_size]]
        inputs = processor(images=batch, return_tensors="pt")
        with torch.inference_mode():
            logits = net(pixel_values=inputs["pixel_values"].to(device)).logits
        for im, logit in zip(batch, logits, strict=True):
            up = torch.nn.functional.interpolate(
                logit[None], size=im.shape[:2], mode="bilinear", align_corners=False
            )
            masks.append((up[0].argmax(0) == sky_id).cpu().numpy())
    logger.info("segformer sky: %d frames with %s (sky class %d)", len(masks), model, sky_id)
    return masks


def _segformer_processor(transformers: Any, model: str) -> Any:
    """Return the model's image processor (its defaults when the folder has none).

    ``transformers`` is passed as the module object (untyped third-party API, hence Any). The
    PIL-based processor is preferred: the default one wants torchvision, which must not be
    installed beside CPU torch (docs/architecture.md).
    """
    cls = getattr(transformers, "SegformerImageProcessorPil", None) or (
        transformers.SegformerImageProcessor
    )
    try:
        return cls.from_pretrained(model)
    except OSError:
        logger.info("%s has no preprocessor config; using SegFormer defaults", model)
        return cls()
