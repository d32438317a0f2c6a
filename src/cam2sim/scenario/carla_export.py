"""The scenario in CARLA's frame, in the files the published tool's scripts read.

CARLA's frame is the world frame with y flipped (left-handed) and yaw in degrees clockwise
(:mod:`cam2sim.core.frames.carla`). No scale and no grid convergence enter: the OpenDRIVE map
CARLA loads uses the world frame's own projection.

Files (``WS/scenario/carla/``):

- ``trajectory_center.json``, ``trajectory_rear_axle.json``, ``trajectory_reference.json``: one
  entry per frame, ``{"frame_id", "timestamp", "transform": {"location": {"x", "y", "z"},
  "rotation": {"pitch", "yaw", "roll"}}}``. A CARLA vehicle's actor location is its centre, so
  ``trajectory_center.json`` is the one to ``set_transform`` a vehicle to (the published tool's
  ``trajectory_positions_rear_odom_yaw.json`` meant the same thing, reached by two offsets);
- ``vehicle_data.json``: ``hero_car`` (the first centre pose), ``dist``, ``spawn_positions``
  (one per parked vehicle: ``cluster_id``, ``side``, ``mode``, ``start``, ``end``, ``heading``,
  plus ``size`` and ``size_class``) and ``offset``, as the published tool's ``3B`` writes it.
"""

from __future__ import annotations

import json
from typing import TYPE_CHECKING, Any

import numpy as np

from cam2sim.core.files import write_text_atomic
from cam2sim.core.frames import (
    carla_to_world,
    carla_yaw_deg_to_heading,
    heading_to_carla_yaw_deg,
    world_to_carla,
)

if TYPE_CHECKING:
    from pathlib import Path

    import numpy.typing as npt

    from cam2sim.scenario.model import BodyPoint, Scenario

__all__ = ["carla_trajectory", "trajectory_from_carla", "write_carla_files"]

_DECIMALS = 6  # micrometres: the round trip stays far inside 1 mm


def carla_trajectory(
    frame: npt.ArrayLike, t: npt.ArrayLike, position: npt.ArrayLike, heading: npt.ArrayLike
) -> list[dict[str, Any]]:
    """Trajectory entries in CARLA's frame from world positions and headings."""
    loc = world_to_carla(np.asarray(position, dtype=np.float64).reshape(-1, 3))
    yaw = np.asarray(heading_to_carla_yaw_deg(np.asarray(heading, dtype=np.float64)))
    return [
        {
            "frame_id": int(f),
            "timestamp": round(float(s), _DECIMALS),
            "transform": {
                "location": {
                    "x": round(float(p[0]), _DECIMALS),
                    "y": round(float(p[1]), _DECIMALS),
                    "z": round(float(p[2]), _DECIMALS),
                },
                "rotation": {"pitch": 0.0, "yaw": round(float(y), _DECIMALS), "roll": 0.0},
            },
        }
        for f, s, p, y in zip(
            np.asarray(frame).tolist(), np.asarray(t).tolist(), loc, yaw.tolist(), strict=True
        )
    ]


def trajectory_from_carla(
    entries: list[dict[str, Any]],
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """World positions ``(N, 3)`` and headings ``(N,)`` back from CARLA trajectory entries."""
    loc = np.array(
        [[e["transform"]["location"][k] for k in ("x", "y", "z")] for e in entries],
        dtype=np.float64,
    ).reshape(-1, 3)
    yaw = np.array([e["transform"]["rotation"]["yaw"] for e in entries], dtype=np.float64)
    return carla_to_world(loc), np.asarray(carla_yaw_deg_to_heading(yaw))


def _pose_dict(position: tuple[float, float, float], heading: float) -> dict[str, Any]:
    loc = world_to_carla(np.asarray(position, dtype=np.float64))
    return {
        "location": {k: round(float(v), _DECIMALS) for k, v in zip("xyz", loc, strict=True)},
        "rotation": {
            "pitch": 0.0,
            "yaw": round(float(heading_to_carla_yaw_deg(heading)), _DECIMALS),
            "roll": 0.0,
        },
    }


def write_carla_files(scenario: Scenario, out_dir: Path) -> list[Path]:
    """Write the CARLA-frame files of ``scenario`` into ``out_dir``; the paths written."""
    out_dir.mkdir(parents=True, exist_ok=True)
    tr = scenario.trajectory
    written = []
    points: tuple[BodyPoint, ...] = ("center", "rear_axle", "reference")
    for point in points:
        entries = carla_trajectory(tr.frame, tr.t, tr.points(point), tr.heading)
        path = out_dir / f"trajectory_{point}.json"
        write_text_atomic(path, json.dumps(entries, indent=1) + "\n")
        written.append(path)
    spawns = []
    for v in scenario.parked:
        start = world_to_carla(np.asarray(v.position, dtype=np.float64))
        spawns.append(
            {
                "cluster_id": v.id,
                "side": v.side,
                "street_id": None,
                "mode": v.orientation,
                "start": [round(float(c), _DECIMALS) for c in start],
                "end": [round(float(c) + 1e-4 * (i < 2), _DECIMALS) for i, c in enumerate(start)],
                "heading": round(float(heading_to_carla_yaw_deg(v.heading)), _DECIMALS),
                "size": list(v.size),
                "size_class": v.size_class,
            }
        )
    hero = scenario.hero_start
    data = {
        "hero_car": _pose_dict(hero.position, hero.heading),
        "dist": 200,
        "spawn_positions": spawns,
        "offset": {"x": 0.0, "y": 0.0, "heading": 0.0},
    }
    path = out_dir / "vehicle_data.json"
    write_text_atomic(path, json.dumps(data, indent=1) + "\n")
    written.append(path)
    return written
