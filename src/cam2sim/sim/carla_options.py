"""The CARLA backend's settings and its parked-vehicle blueprint choice (no carla import).

:class:`CarlaOptions` is the ``carla`` block of ``config.yaml`` and the backend's options;
:func:`select_blueprint` picks each parked vehicle's blueprint from an allow-list per size
class. Both are read without the CARLA client installed (config validation, tests); the
backend itself is :mod:`cam2sim.sim.carla_backend`, which re-exports them.
"""

from __future__ import annotations

import hashlib
from typing import TYPE_CHECKING, Literal

import pydantic

from cam2sim.core.errors import ConfigError
from cam2sim.core.vehicle import SteeringCalibration
from cam2sim.sim.control import EpisodeRuleOptions, VehicleControlOptions

if TYPE_CHECKING:
    from collections.abc import Mapping, Sequence

    from cam2sim.scenario.model import SizeClass

__all__ = ["DEFAULT_BLUEPRINTS", "CarlaOptions", "select_blueprint"]

# Gen-1/2 four-wheelers of CARLA 0.9.16 outside the published tool's exclusion list (van: the
# two vans it excluded, since a van must look like one).
DEFAULT_BLUEPRINTS: dict[str, tuple[str, ...]] = {
    "small": ("vehicle.citroen.c3", "vehicle.mini.cooper_s", "vehicle.nissan.micra"),
    "medium": (
        "vehicle.bmw.grandtourer",
        "vehicle.mercedes.coupe",
        "vehicle.seat.leon",
        "vehicle.toyota.prius",
    ),
    "large": ("vehicle.nissan.patrol", "vehicle.nissan.patrol_2021"),
    "van": ("vehicle.mercedes.sprinter", "vehicle.volkswagen.t2"),
}


class CarlaOptions(VehicleControlOptions, EpisodeRuleOptions):
    """Settings of the CARLA backend (defaults in the field descriptions).

    The control and episode settings are the ones every backend shares
    (:class:`~cam2sim.sim.control.VehicleControlOptions`,
    :class:`~cam2sim.sim.control.EpisodeRuleOptions`).
    """

    model_config = pydantic.ConfigDict(extra="forbid", frozen=True)

    host: str = "localhost"
    port: int = pydantic.Field(2000, ge=1, le=65535)
    timeout_s: float = pydantic.Field(40.0, gt=0, description="client RPC timeout, s")
    # generate_opendrive_world mesh parameters (the published tool's values)
    vertex_distance: float = pydantic.Field(0.1, gt=0, description="mesh vertex spacing, m")
    max_road_length: float = pydantic.Field(500.0, gt=0, description="mesh chunk length, m")
    wall_height: float = pydantic.Field(0.0, ge=0, description="road-edge walls, m")
    additional_width: float = pydantic.Field(0.6, ge=0, description="junction lane widening, m")
    smooth_junctions: bool = True
    enable_mesh_visibility: bool = True
    blueprints: dict[str, tuple[str, ...]] = pydantic.Field(
        default_factory=lambda: dict(DEFAULT_BLUEPRINTS),
        description="allowed parked-vehicle blueprints per size class",
    )
    hero_blueprint: str = "vehicle.tesla.model3"
    spawn_lift_m: float = pydantic.Field(
        0.1, ge=0, description="the hero is spawned this far above the road surface"
    )
    speed_control: Literal["pid", "carla"] = "pid"
    image_size: tuple[int, int] | None = pydantic.Field(
        None, description="camera (width, height) px; None: the scenario camera's size"
    )
    image_timeout_s: float = pydantic.Field(2.0, gt=0, description="wait for a tick's images")
    # the control and episode settings come from the shared bases (sim.control)
    calibration: SteeringCalibration | None = pydantic.Field(
        None, description="None: the scenario's steering calibration"
    )
    offroad_markings: tuple[str, ...] = pydantic.Field(
        ("Curb", "Grass"), description="carla.LaneMarkingType names whose crossing is off-road"
    )
    episode_timeout_s: float | None = pydantic.Field(
        None, gt=0, description="None: twice the recorded duration plus 10 s"
    )


def select_blueprint(
    size_class: SizeClass | str,
    vehicle_id: str,
    available_ids: Sequence[str],
    allow: Mapping[str, Sequence[str]],
) -> str:
    """Pick the blueprint of a parked vehicle, deterministically.

    The candidates are the allowed blueprints of ``size_class`` that the server offers, sorted;
    the pick is indexed by a SHA-256 of ``vehicle_id`` (stable across runs and processes).

    Raises:
        ConfigError: No allowed blueprint of that size class is available.
    """
    allowed = allow.get(size_class, ())
    candidates = sorted(set(allowed) & set(available_ids))
    if not candidates:
        msg = (
            f"no blueprint for parked vehicle {vehicle_id!r} of size class {size_class!r}: the "
            f"allow-list has {sorted(allowed)} and the server offers none of them; add one of "
            "the server's vehicle.* blueprints to sim.carla.blueprints."
            f"{size_class}"
        )
        raise ConfigError(msg)
    digest = hashlib.sha256(vehicle_id.encode("utf-8")).digest()
    return candidates[int.from_bytes(digest[:8], "big") % len(candidates)]
