"""The header of a chunk model, ``chunk_XX.json``: what the model covers and how it was trained.

Apart from :mod:`cam2sim.splat.model` (which needs torch), so that readers of the header alone
(the report, the CLI) load no torch; :mod:`cam2sim.splat.model` re-exports both records.
"""

from __future__ import annotations

from pathlib import Path

import pydantic

from cam2sim.core.schema import Artifact

__all__ = ["ChunkHeader", "ViewRecord", "outliers_path", "pose_correction_sizes"]


class ViewRecord(pydantic.BaseModel):
    """A training view of a chunk (for chunk choice, colour interpolation and coverage)."""

    model_config = pydantic.ConfigDict(extra="forbid", frozen=True)

    index: int = pydantic.Field(description="Frame index in the prepared scene")
    progress_m: float
    position: list[float] = pydantic.Field(description="Camera centre, world metres")
    forward: list[float] = pydantic.Field(description="Optical axis (camera +z), world, unit")
    down: list[float] | None = pydantic.Field(
        None,
        description="Image-down axis (camera +y), world, unit; None in models written before "
        "it was kept (the closed loop then takes only the views' height, not their tilt)",
    )
    correction: list[float] | None = pydantic.Field(
        None,
        description="Learned pose correction (omega, t) of this view, when pose refinement ran "
        "(cam2sim.splat.pose_refine); position, forward and down are already corrected",
    )
    from_recorded: list[float] | None = pydantic.Field(
        None,
        description="The correction from a recorded pose near this view to the model's, when "
        "the preparation adjusted the poses (cam2sim.splat.scene.FrameRecord.from_recorded)",
    )


class ChunkHeader(Artifact):
    """``chunk_XX.json``: what a chunk model covers and how it was trained."""

    chunk_id: int
    start_m: float
    end_m: float
    sh_degree: int
    n_gaussians: int
    n_sky: int
    scene_scale: float = pydantic.Field(
        description="Scale of the learning rate and densification (TrainOptions.scene_scale)"
    )
    sky_radius_m: float
    background: list[float] = pydantic.Field(description="RGB behind everything, [0, 1]")
    train_views: list[ViewRecord] = pydantic.Field(
        description="Training views, in the order of the appearance table"
    )
    steps: int = 0
    best_val_psnr_db: float | None = None
    val_history: list[tuple[int, float, float]] = pydantic.Field(
        default_factory=list,
        description="(step, held-in PSNR dB, SSIM) of every validation on training views",
    )
    backend: str = ""
    stopped: str = ""
    notes: list[str] = pydantic.Field(default_factory=list)
    antialiased: bool = pydantic.Field(
        default=False,
        description="Trained with Mip-Splatting's 2-D filter; render it with the same "
        "(cam2sim.splat.raster.rasterize antialiased)",
    )


def outliers_path(model_path: Path) -> Path:
    """``chunk_XX_outliers.jpg`` beside ``chunk_XX.pt``: what the robust weighting left out."""
    model_path = Path(model_path)
    return model_path.with_name(f"{model_path.stem}_outliers.jpg")


def pose_correction_sizes(header: ChunkHeader) -> tuple[float, float, float, float] | None:
    """Mean and largest translation and rotation of ``header``'s learned pose corrections.

    Translation in scene units, rotation in degrees; None when pose refinement did not run.
    """
    from cam2sim.splat.pose_refine import correction_sizes  # noqa: PLC0415 -- lazy: numpy

    rows = [v.correction for v in header.train_views if v.correction is not None]
    return correction_sizes(rows) if rows else None
