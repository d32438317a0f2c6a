"""What a camera of the runs is: world-frame camera poses in, images out.

Every renderer (``raster``, ``truth``, ``splat``) satisfies :class:`CameraRenderer`; the runs
open them by name (``stages.cameras``: the registry, since opening one reads the workspace) and
hand the closed loop a camera function of the vehicle state
(:func:`cam2sim.sim.episode.run_episode`).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Protocol

if TYPE_CHECKING:
    import numpy as np
    import numpy.typing as npt

    from cam2sim.core.camera import PinholeCamera

__all__ = ["CameraRenderer", "RenderedFrame"]


class RenderedFrame(Protocol):
    """What a renderer returns: at least the RGB image."""

    @property
    def rgb(self) -> npt.NDArray[np.uint8]:
        """``(H, W, 3)`` uint8."""
        ...


class CameraRenderer(Protocol):
    """A camera of runs: renders world-frame camera poses; closed once at the end."""

    def render(self, T_world_cam: npt.NDArray[np.float64], camera: PinholeCamera) -> RenderedFrame:
        """The view from ``T_world_cam`` (camera -> world, optical axes) of ``camera``.

        ``camera`` has no lens distortion: runs render undistorted pinhole images.
        """
        ...

    def close(self) -> None:
        """Release the renderer's resources."""
        ...
