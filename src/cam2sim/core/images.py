"""Reading images and masks the way every package compares them: 8-bit RGB, boolean masks.

One reader for the evaluation (:mod:`cam2sim.metrics.image_quality`), the splat training views
and the splat evaluation, and one lossless writer; errors name the file.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from cam2sim.core.errors import WorkspaceError

if TYPE_CHECKING:
    from pathlib import Path

    import numpy.typing as npt

__all__ = ["as_grey", "frames_are_grey", "read_mask", "read_rgb", "write_rgb"]


def read_rgb(path: Path) -> npt.NDArray[np.uint8]:
    """Read an 8-bit image as ``(H, W, 3)`` uint8 RGB (grey is repeated, alpha is dropped).

    Raises:
        WorkspaceError: The file cannot be decoded, or is not 8-bit.
    """
    import cv2  # noqa: PLC0415

    image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if image is None:
        msg = f"cannot read image {path}: missing, empty or not an image format OpenCV decodes"
        raise WorkspaceError(msg)
    if image.dtype != np.uint8:
        msg = f"{path} is {image.dtype}; only 8-bit images are compared (convert it first)"
        raise WorkspaceError(msg)
    if image.ndim == 2:
        return np.ascontiguousarray(np.repeat(image[:, :, None], 3, axis=2))
    code = cv2.COLOR_BGRA2RGB if image.shape[2] == 4 else cv2.COLOR_BGR2RGB
    return np.asarray(cv2.cvtColor(image, code), dtype=np.uint8)


def read_mask(path: Path, *, keep_nonzero: bool = False) -> npt.NDArray[np.bool_]:
    """Read a mask image as ``(H, W)`` bool, True where a pixel is excluded.

    Args:
        path: Mask image; a colour mask counts a pixel as nonzero if any channel is.
        keep_nonzero: False (default): nonzero pixels are excluded. True: nonzero pixels are kept
            and zero pixels excluded (nerfstudio-style masks: 255 = keep, 0 = ignore).

    Raises:
        WorkspaceError: The file cannot be decoded.
    """
    import cv2  # noqa: PLC0415

    image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if image is None:
        msg = f"cannot read mask {path}: missing, empty or not an image format OpenCV decodes"
        raise WorkspaceError(msg)
    nonzero = image != 0 if image.ndim == 2 else np.any(image != 0, axis=2)
    return np.asarray(~nonzero if keep_nonzero else nonzero, dtype=np.bool_)


def write_rgb(path: Path, image: npt.NDArray[np.uint8]) -> None:
    """Write ``(H, W, 3)`` uint8 RGB losslessly, atomically: PNG, or WebP for a ``.webp`` path.

    Lossless WebP is about a third of the PNG's size for camera frames, and reads back to the
    same pixels (:func:`read_rgb`).

    Raises:
        WorkspaceError: The image is not ``(H, W, 3)`` uint8, or cannot be encoded.
    """
    import cv2  # noqa: PLC0415

    from cam2sim.core.files import write_bytes_atomic  # noqa: PLC0415

    if image.dtype != np.uint8 or image.ndim != 3 or image.shape[2] != 3:
        msg = f"cannot write {path}: need (H, W, 3) uint8 RGB, got {image.shape} {image.dtype}"
        raise WorkspaceError(msg)
    suffix = path.suffix.lower()
    params = [cv2.IMWRITE_WEBP_QUALITY, 101] if suffix == ".webp" else []
    ok, data = cv2.imencode(suffix or ".png", np.ascontiguousarray(image[..., ::-1]), params)
    if not ok:
        msg = f"cannot encode {path} as {suffix or '.png'}; use .png or .webp"
        raise WorkspaceError(msg)
    write_bytes_atomic(path, data.tobytes())


def frames_are_grey(paths: list[Path], *, samples: int = 5) -> bool:
    """Whether a recording's frames are grey: one channel, or three equal ones.

    Up to ``samples`` frames spread over ``paths`` are read; all must be grey. False for no
    frames.
    """
    import cv2  # noqa: PLC0415

    if not paths:
        return False
    pick = np.unique(np.linspace(0, len(paths) - 1, min(samples, len(paths))).astype(int))
    for k in pick:
        image = cv2.imread(str(paths[int(k)]), cv2.IMREAD_UNCHANGED)
        if image is None:
            return False
        if image.ndim == 3 and image.shape[2] >= 3:
            rgb = image[..., :3]
            same = np.array_equal(rgb[..., 0], rgb[..., 1])
            if not (same and np.array_equal(rgb[..., 1], rgb[..., 2])):
                return False
    return True


def as_grey(rgb: npt.NDArray[np.uint8]) -> npt.NDArray[np.uint8]:
    """``(..., H, W, 3)`` RGB as a grey camera records it: luma (BT.601) in all three channels.

    The weights are OpenCV's ``COLOR_RGB2GRAY``, the conversion a grey sensor's frames are
    compared with elsewhere.
    """
    luma = rgb[..., 0] * 0.299 + rgb[..., 1] * 0.587 + rgb[..., 2] * 0.114
    grey = np.clip(np.rint(luma), 0, 255).astype(np.uint8)
    return np.repeat(grey[..., None], 3, axis=-1)
