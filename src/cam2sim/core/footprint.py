"""Footprints: the rectangle a vehicle or a box covers on the ground plane.

The simulator checks the ego's footprint against the road and parked cars with it, the scenario
checks spawns, the report draws boxes.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

__all__ = ["footprint_corners"]


def footprint_corners(
    xy: npt.ArrayLike, yaw: npt.ArrayLike, length: npt.ArrayLike, width: npt.ArrayLike
) -> npt.NDArray[np.float64]:
    """``(N, 4, 2)`` rectangle corners: front-left, front-right, rear-right, rear-left."""
    c = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
    yaw_a = np.asarray(yaw, dtype=np.float64).reshape(-1)
    hl = np.asarray(length, dtype=np.float64).reshape(-1) / 2.0
    hw = np.asarray(width, dtype=np.float64).reshape(-1) / 2.0
    fwd = np.stack([np.cos(yaw_a), np.sin(yaw_a)], -1)
    left = np.stack([-np.sin(yaw_a), np.cos(yaw_a)], -1)
    signs = np.array([[1.0, 1.0], [1.0, -1.0], [-1.0, -1.0], [-1.0, 1.0]])
    corners: npt.NDArray[np.float64] = (
        c[:, None, :]
        + signs[None, :, 0:1] * (hl[:, None, None] * fwd[:, None, :])
        + signs[None, :, 1:2] * (hw[:, None, None] * left[:, None, :])
    )
    return corners
