"""The bird's-eye picture of a scenario: map, route, hero start, parked cars, cars left out."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from cam2sim.core.footprint import footprint_corners
from cam2sim.core.plots import pyplot, save_figure

if TYPE_CHECKING:
    from collections.abc import Sequence
    from pathlib import Path

    from cam2sim.detect.vehicles import ParkedVehicle
    from cam2sim.map.query import RoadMap
    from cam2sim.scenario.model import Scenario

__all__ = ["plot_scenario"]

_LANE_COLOUR = {"driving": "0.85", "parking": "#cfe3f7", "sidewalk": "#f3e3c8"}
_CLASS_COLOUR = {"small": "#9ecae1", "medium": "#4292c6", "large": "#08519c", "van": "#6a51a3"}


def plot_scenario(
    path: Path,
    scenario: Scenario,
    conflicts: dict[str, list[str]],
    road_map: RoadMap | None,
    left_out: Sequence[ParkedVehicle] = (),
) -> None:
    """Draw the scenario from above and write it to ``path`` (PNG).

    Vehicles left out by the checks (``left_out``) are drawn hatched in red and listed under the
    plot with their reasons.
    """
    plt = pyplot()
    from matplotlib.patches import FancyArrow, Polygon  # noqa: PLC0415

    fig, ax = plt.subplots(figsize=(10, 9))
    if road_map is not None:
        for lane_type, colour in _LANE_COLOUR.items():
            for poly in road_map.lane_polygons(lane_type):
                for part in getattr(poly, "geoms", [poly]):
                    ring = np.asarray(part.exterior.coords)
                    ax.fill(ring[:, 0], ring[:, 1], color=colour, lw=0, zorder=0)
    centre = np.asarray(scenario.trajectory.center)
    ax.plot(centre[:, 0], centre[:, 1], color="tab:red", lw=1.5, label="route (vehicle centre)")
    hero = scenario.hero_start
    length = scenario.vehicle.length_m
    ax.add_patch(
        FancyArrow(
            hero.position[0],
            hero.position[1],
            length * np.cos(hero.heading),
            length * np.sin(hero.heading),
            width=0.6,
            color="tab:red",
            zorder=5,
        )
    )
    ax.plot([], [], ">", color="tab:red", label="hero start")
    parked = scenario.parked
    if parked:
        corners = footprint_corners(
            [v.position[:2] for v in parked],
            [v.heading for v in parked],
            [v.size[0] for v in parked],
            [v.size[1] for v in parked],
        )
        for v, quad in zip(parked, corners, strict=True):
            hatch = "xx" if v.id in conflicts else None
            ax.add_patch(
                Polygon(
                    quad,
                    closed=True,
                    facecolor=_CLASS_COLOUR[v.size_class],
                    edgecolor="tab:red" if hatch else "black",
                    hatch=hatch,
                    lw=0.6,
                    zorder=3,
                )
            )
    if left_out:
        quads = footprint_corners(
            [v.position[:2] for v in left_out],
            [v.yaw for v in left_out],
            [v.size[0] for v in left_out],
            [v.size[1] for v in left_out],
        )
        for gone, quad in zip(left_out, quads, strict=True):
            ax.add_patch(
                Polygon(quad, closed=True, fill=False, edgecolor="tab:red", hatch="xx", zorder=4)
            )
            ax.annotate(gone.id, gone.position[:2], color="tab:red", fontsize=7, zorder=6)
    for name, colour in _CLASS_COLOUR.items():
        ax.plot([], [], "s", color=colour, label=f"parked, {name}")
    lines = [f"{r.id}: {'; '.join(r.reasons)}" for r in scenario.rejected]
    if lines:
        ax.plot([], [], "s", color="white", markeredgecolor="tab:red", label="left out (below)")
        ax.annotate(
            "Left out:\n" + "\n".join(lines),
            xy=(0.0, -0.25),
            xycoords="axes fraction",
            va="top",
            fontsize=7,
            annotation_clip=False,
        )
    ax.set_aspect("equal")
    ax.set_xlabel("east (m)")
    ax.set_ylabel("north (m)")
    ax.set_title(
        f"scenario: {len(parked)} parked vehicles, {len(scenario.rejected)} left out, "
        f"{scenario.trajectory.t[-1]:.0f} s of route"
    )
    ax.legend(loc="best", fontsize=8)
    save_figure(fig, path)
