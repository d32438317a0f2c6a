"""The NVIDIA DAVE-2 steering network and its published preprocessing.

Preprocessing (:func:`preprocess`, the reference system's ``system_under_test``): resize the
camera frame to the source size (800x503, bilinear), keep rows 204..468 (800x264), resize to the
network input (200x66, bilinear), and hand the network float32 values in ``[0, 255]``, channels
first. :meth:`Dave2Config.for_camera` fits these to another camera: its own size as the source
size (no resize), the same share of its rows and, as the published preprocessing, every column
(a wider camera is squashed into 200x66: the road's edges at the sides are what the network
steers by); for an 800x503 camera it is the published preprocessing. Normalisation
(``x / 127.5 - 1``) is the network's first layer, so exported models take raw pixel values.

Network (Bojarski et al. 2016, "End to End Learning for Self-Driving Cars"): normalisation, five
convolutions (24, 36, 48 filters 5x5 stride 2; 64, 64 filters 3x3 stride 1) with ELU, flatten,
dropout, fully connected 100-50-10 with ELU and a linear output times a fixed ``output_scale``
(a buffer: the training labels' spread). The output is steering only, ``(N, 1)``, in the
recording's steering unit: the reference model's throttle output was never used.

This module imports without torch: :func:`preprocess` and :class:`Dave2Config` serve the
inference path (:class:`~cam2sim.ads.policy.ModelPolicy`) too; :func:`build_dave2` imports torch.
"""

from __future__ import annotations

import functools
import json
import math
from typing import TYPE_CHECKING, Any, Final

import cv2
import numpy as np
import pydantic

from cam2sim.core.errors import ConfigError

if TYPE_CHECKING:
    import numpy.typing as npt
    import torch

__all__ = ["METADATA_KEY", "Dave2Config", "build_dave2", "preprocess"]

METADATA_KEY: Final = "cam2sim.dave2"
"""ONNX metadata key holding the :class:`Dave2Config` JSON of an exported model."""


class Dave2Config(pydantic.BaseModel):
    """Preprocessing and layer sizes of a DAVE-2 network.

    Attributes:
        source_size: ``(width, height)`` every frame is first resized to (the training size of
            the published model).
        crop_rows: ``(top, bottom)`` rows kept of the source-size frame, bottom exclusive.
        crop_cols: ``(left, right)`` columns kept, right exclusive; None keeps every column.
        input_size: ``(width, height)`` of the network input.
        dropout: Dropout probability before the fully connected layers (training only).
    """

    model_config = pydantic.ConfigDict(frozen=True, extra="forbid")

    source_size: tuple[int, int] = (800, 503)
    crop_rows: tuple[int, int] = (204, 468)
    crop_cols: tuple[int, int] | None = None
    input_size: tuple[int, int] = (200, 66)
    dropout: float = pydantic.Field(default=0.2, ge=0.0, lt=1.0)

    @pydantic.model_validator(mode="after")
    def _check(self) -> Dave2Config:
        top, bottom = self.crop_rows
        if min(*self.source_size, *self.input_size) < 1 or not 0 <= top < bottom:
            msg = f"DAVE-2 sizes must be positive and crop rows 0 <= top < bottom; got {self!r}"
            raise ValueError(msg)
        if bottom > self.source_size[1]:
            msg = f"crop rows {self.crop_rows} reach below the source height {self.source_size[1]}"
            raise ValueError(msg)
        if self.crop_cols is not None:
            left, right = self.crop_cols
            if not 0 <= left < right <= self.source_size[0]:
                msg = f"crop columns {self.crop_cols} must satisfy 0 <= left < right <= width"
                raise ValueError(msg)
        w, h = self.input_size
        if _conv_out(w) < 1 or _conv_out(h) < 1:
            msg = f"input_size {self.input_size} is too small for five convolutions (>= 61x61)"
            raise ValueError(msg)
        return self

    @classmethod
    def for_camera(cls, width: int, height: int) -> Dave2Config:
        """The published preprocessing fitted to a ``width`` x ``height`` camera.

        The source size is the camera's (frames are not resized first), the crop keeps the same
        share of the rows as the published 204..468 of 503 and every column, as the published
        crop keeps every column of its camera; a wider camera's crop is squashed into the
        network input. On KITTI 03 (1242x375) the centre 597 columns alone, unsquashed, left
        out the kerbs: DAVE-2 trained on them steered on the splat camera's frames with a
        correlation of 0.09 with the recorded steering, every column 0.48-0.54
        (docs/benchmarks.md). ``for_camera(800, 503)`` is ``Dave2Config()``.
        """
        if width < 1 or height < 1:
            msg = f"camera size must be positive, got {width}x{height}"
            raise ConfigError(msg)
        base = cls()
        top, bottom = base.crop_rows
        source_h = base.source_size[1]
        rows = (round(top * height / source_h), round(bottom * height / source_h))
        return cls(source_size=(width, height), crop_rows=rows)

    def rows_read(self, height: int) -> tuple[int, int]:
        """Rows ``[first, stop)`` of a frame ``height`` rows high that :func:`preprocess` reads.

        The frame is first resized to :attr:`source_size` bilinearly (OpenCV's two-tap
        ``INTER_LINEAR`` in both directions): source row ``y`` samples the frame at
        ``(y + 0.5) * height / source_height - 0.5`` from the two rows around it. Rows outside
        the returned range never reach the network, so a camera may leave them unrendered
        (``cam2sim drive`` does for the splat camera) and the input stays bit for bit the same.
        """
        if height < 1:
            msg = f"frame height must be positive, got {height}"
            raise ValueError(msg)
        top, bottom = self.crop_rows
        source_h = self.source_size[1]
        if height == source_h:
            return top, bottom
        scale = height / source_h
        first = math.floor((top + 0.5) * scale - 0.5)
        last = math.floor((bottom - 0.5) * scale - 0.5) + 1
        return max(0, first), min(height, last + 1)

    def to_json(self) -> str:
        """Compact JSON (the ONNX metadata value and ``dave2.json``)."""
        return self.model_dump_json()

    @classmethod
    def from_json(cls, text: str) -> Dave2Config:
        """Parse :meth:`to_json` output; ConfigError when it is not a DAVE-2 config."""
        try:
            return cls.model_validate(json.loads(text))
        except (ValueError, TypeError) as err:
            msg = f"not a DAVE-2 configuration ({err}); re-export the model with cam2sim"
            raise ConfigError(msg) from err


def _conv_out(n: int) -> int:
    for _ in range(3):
        n = (n - 5) // 2 + 1
    return n - 4


def preprocess(
    images: npt.NDArray[np.uint8], config: Dave2Config | None = None
) -> npt.NDArray[np.float32]:
    """Network inputs of RGB frames: resize (bilinear), crop, resize (bilinear), channels first.

    Args:
        images: ``(N, H, W, 3)`` (or one ``(H, W, 3)``) uint8 RGB frames, all the same size.
        config: Sizes; the published ones by default.

    Returns:
        ``(N, 3, h, w)`` float32 in ``[0, 255]`` (``(w, h)`` = ``config.input_size``).
    """
    cfg = config or Dave2Config()
    x = np.asarray(images)
    if x.ndim == 3:
        x = x[None]
    if x.ndim != 4 or x.shape[3] != 3 or x.dtype != np.uint8 or min(x.shape[1:3]) < 1:
        msg = f"images must be (N, H, W, 3) uint8 RGB; got {x.dtype} {x.shape}"
        raise ValueError(msg)
    h, w = x.shape[1:3]
    sw, sh = cfg.source_size
    top, bottom = cfg.crop_rows
    left, right = cfg.crop_cols or (0, sw)
    iw, ih = cfg.input_size
    # One cv2 call per image and step: faster than stacking the batch along channels (OpenCV's
    # resize has SIMD paths for 1-4 channels only) and bit-identical to the reference.
    out = np.empty((x.shape[0], ih, iw, 3), np.uint8)
    for k, image in enumerate(x):
        src = image if (w, h) == (sw, sh) else _resize(image, (sw, sh))
        out[k] = _resize(src[top:bottom, left:right], (iw, ih))
    return np.ascontiguousarray(out.transpose(0, 3, 1, 2), dtype=np.float32)


def _resize(image: npt.NDArray[np.uint8], size: tuple[int, int]) -> npt.NDArray[np.uint8]:
    return np.asarray(cv2.resize(image, size, interpolation=cv2.INTER_LINEAR), dtype=np.uint8)


def build_dave2(config: Dave2Config | None = None) -> torch.nn.Module:
    """A fresh DAVE-2 network (torch): ``(N, 3, h, w)`` float32 in ``[0, 255]`` -> ``(N, 1)``."""
    model: torch.nn.Module = _dave2_class()(config or Dave2Config())
    return model


@functools.cache
def _dave2_class() -> Any:  # Any: the class is built on first use so torch loads lazily
    import torch  # noqa: PLC0415
    from torch import nn  # noqa: PLC0415

    class Dave2(nn.Module):
        """DAVE-2: normalisation, 5 convolutions, flatten, FC 100-50-10-1."""

        output_scale: torch.Tensor

        def __init__(self, config: Dave2Config) -> None:
            super().__init__()
            self.config = config
            w, h = config.input_size
            self.features = nn.Sequential(
                nn.Conv2d(3, 24, 5, stride=2),
                nn.ELU(),
                nn.Conv2d(24, 36, 5, stride=2),
                nn.ELU(),
                nn.Conv2d(36, 48, 5, stride=2),
                nn.ELU(),
                nn.Conv2d(48, 64, 3),
                nn.ELU(),
                nn.Conv2d(64, 64, 3),
                nn.ELU(),
                nn.Flatten(),
            )
            self.head = nn.Sequential(
                nn.Dropout(config.dropout),
                nn.Linear(64 * _conv_out(w) * _conv_out(h), 100),
                nn.ELU(),
                nn.Linear(100, 50),
                nn.ELU(),
                nn.Linear(50, 10),
                nn.ELU(),
                nn.Linear(10, 1),
            )
            # The steering unit's scale (training sets it to the labels' spread), so the
            # layers work on values near 1 whatever the recording's unit.
            self.register_buffer("output_scale", torch.ones(()))

        def forward(self, image: torch.Tensor) -> torch.Tensor:
            """``(N, 3, h, w)`` pixels in ``[0, 255]`` -> ``(N, 1)`` steering."""
            x: torch.Tensor = self.head(self.features(image / 127.5 - 1.0))
            return x * self.output_scale

    return Dave2
