"""``WS/detections/parked_vehicles.json``: the fused, hand-editable list of parked vehicles.

Positions are in the workspace's world frame (metres east/north/up of the world origin, see
:mod:`cam2sim.core.frames.projection`); ``yaw`` is the heading of the vehicle's length axis,
counter-clockwise from east, in ``(-pi, pi]``. A parked car has no front or back that the
detectors can tell reliably, so ``yaw`` and ``yaw + pi`` describe the same box.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Literal

import pydantic

from cam2sim.core.files import write_bytes_atomic
from cam2sim.core.schema import Artifact

if TYPE_CHECKING:
    from pathlib import Path

__all__ = [
    "HISTORY_DIR",
    "PARKED_VEHICLES_FILE",
    "Orientation",
    "ParkedVehicle",
    "ParkedVehicles",
    "Side",
    "VehicleSource",
    "parked_vehicles_path",
    "save_parked_vehicles",
]

PARKED_VEHICLES_FILE = "parked_vehicles.json"

Side = Literal["left", "right"]
Orientation = Literal["parallel", "perpendicular"]
VehicleSource = Literal["lidar", "camera", "manual"]


class ParkedVehicle(pydantic.BaseModel):
    """One parked vehicle."""

    model_config = pydantic.ConfigDict(extra="forbid", frozen=True)

    id: str = pydantic.Field(min_length=1, description="stable identifier, e.g. pv_003")
    position: tuple[float, float, float] = pydantic.Field(
        description="bottom centre of the box in the world frame, metres"
    )
    yaw: float = pydantic.Field(ge=-3.2, le=3.2, description="heading of the length axis, rad")
    size: tuple[float, float, float] = pydantic.Field(description="length, width, height in metres")
    confidence: float = pydantic.Field(ge=0.0, le=1.0)
    hits: int = pydantic.Field(ge=0, description="detections fused into this vehicle")
    side: Side = pydantic.Field(description="side of the route (its driving direction)")
    orientation: Orientation = pydantic.Field(description="relative to the route")
    source: VehicleSource
    edited: bool = pydantic.Field(default=False, description="changed or inserted by hand")

    @pydantic.field_validator("size")
    @classmethod
    def _positive_size(cls, v: tuple[float, float, float]) -> tuple[float, float, float]:
        if min(v) <= 0 or max(v) > 30:
            msg = f"size must be three lengths in (0, 30] metres, got {v}"
            raise ValueError(msg)
        return v


class ParkedVehicles(Artifact):
    """Every parked vehicle of the workspace, with how they were found."""

    source: VehicleSource = pydantic.Field(description="detector source of the fused list")
    detector: str = pydantic.Field(description="detector name, e.g. geometric or a model path")
    frames_used: int = pydantic.Field(ge=0, description="scans or images run through it")
    detections: int = pydantic.Field(ge=0, description="per-frame boxes before fusion")
    min_hits: int = pydantic.Field(ge=1)
    snapped: bool = pydantic.Field(default=False, description="snapped to the map's road edge")
    vehicles: tuple[ParkedVehicle, ...]

    @pydantic.model_validator(mode="after")
    def _unique_ids(self) -> ParkedVehicles:
        ids = [v.id for v in self.vehicles]
        if len(set(ids)) != len(ids):
            dup = sorted({i for i in ids if ids.count(i) > 1})
            msg = f"vehicle ids must be unique; repeated: {', '.join(dup)}"
            raise ValueError(msg)
        return self


def parked_vehicles_path(detections_dir: Path) -> Path:
    """Where the fused list lives inside ``WS/detections``."""
    return detections_dir / PARKED_VEHICLES_FILE


HISTORY_DIR = "history"


def save_parked_vehicles(doc: ParkedVehicles, detections_dir: Path) -> Path | None:
    """Write ``parked_vehicles.json`` atomically, keeping the version it replaces.

    The current file, if any, is first copied to
    ``history/parked_vehicles.<UTC time>.json``; then the new one replaces it in one rename.
    Nothing saved is ever lost, and a crash leaves either the old or the new file.

    Returns:
        The path of the archived previous version, or None when there was none.
    """
    import datetime as dt  # noqa: PLC0415

    path = parked_vehicles_path(detections_dir)
    archived = None
    if path.is_file():
        stamp = dt.datetime.now(dt.UTC).strftime("%Y%m%dT%H%M%S.%fZ")
        folder = detections_dir / HISTORY_DIR
        archived = folder / f"parked_vehicles.{stamp}.json"
        n = 1
        while archived.exists():
            archived = folder / f"parked_vehicles.{stamp}-{n}.json"
            n += 1
        folder.mkdir(parents=True, exist_ok=True)
        write_bytes_atomic(archived, path.read_bytes())
    path.parent.mkdir(parents=True, exist_ok=True)
    doc.save(path)
    return archived
