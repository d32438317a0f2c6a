"""The bird's-eye picture of a detection run: route, map lanes, per-frame boxes, vehicles."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from cam2sim.core.footprint import footprint_corners
from cam2sim.core.plots import pyplot, save_figure

if TYPE_CHECKING:
    from pathlib import Path

    from cam2sim.detect.fusion import WorldBoxes
    from cam2sim.detect.route import Route
    from cam2sim.detect.vehicles import ParkedVehicles
    from cam2sim.map.query import RoadMap

__all__ = ["plot_parked_vehicles"]

_SIDE_COLOUR = {"left": "tab:green", "right": "tab:purple"}
_LANE_COLOUR = {"driving": "0.85", "parking": "#cfe3f7", "sidewalk": "#f3e3c8"}


def plot_parked_vehicles(
    path: Path,
    doc: ParkedVehicles,
    boxes: WorldBoxes | None,
    route: Route,
    road_map: RoadMap | None = None,
    background: tuple[Path, tuple[float, float, float, float]] | None = None,
) -> None:
    """Draw the detection result from above and write it to ``path`` (PNG).

    Args:
        path: Output PNG.
        doc: The fused vehicles.
        boxes: The per-frame boxes in the world frame (drawn as score-shaded dots).
        route: The driven route.
        road_map: The map, whose driving, parking and sidewalk lanes are drawn underneath.
        background: An RGBA image (the LiDAR bird's-eye density) and its world extent
            ``(x_min, x_max, y_min, y_max)``, drawn under everything.
    """
    plt = pyplot()
    from matplotlib.patches import Polygon  # noqa: PLC0415

    xy = route.path.xy
    fig, ax = plt.subplots(figsize=(10, 8))
    if background is not None:
        ax.imshow(plt.imread(background[0]), extent=background[1], origin="upper", zorder=0.5)
    if road_map is not None:
        for lane_type, colour in _LANE_COLOUR.items():
            for poly in road_map.lane_polygons(lane_type):
                for part in getattr(poly, "geoms", [poly]):
                    ring = np.asarray(part.exterior.coords)
                    ax.fill(ring[:, 0], ring[:, 1], color=colour, lw=0, zorder=0)
    ax.plot(xy[:, 0], xy[:, 1], color="tab:red", lw=1.5, label="route", zorder=2)
    ax.annotate("start", xy[0], color="tab:red", fontsize=8)
    if boxes is not None and len(boxes):
        sc = ax.scatter(
            boxes.bottom[:, 0],
            boxes.bottom[:, 1],
            s=3,
            c=boxes.score,
            cmap="Greys",
            vmin=0.0,
            vmax=1.0,
            alpha=0.6,
            zorder=1,
            label=f"per-frame boxes ({len(boxes)})",
        )
        fig.colorbar(sc, ax=ax, shrink=0.6, label="box score")
    vs = doc.vehicles
    if vs:
        corners = footprint_corners(
            [v.position[:2] for v in vs],
            [v.yaw for v in vs],
            [v.size[0] for v in vs],
            [v.size[1] for v in vs],
        )
        for v, quad in zip(vs, corners, strict=True):
            ax.add_patch(
                Polygon(
                    quad,
                    closed=True,
                    facecolor=_SIDE_COLOUR[v.side],
                    alpha=0.35 + 0.5 * v.confidence,
                    edgecolor="black",
                    hatch="//" if v.edited else None,
                    lw=0.6,
                    zorder=3,
                )
            )
            ax.annotate(v.id.removeprefix("pv_"), v.position[:2], fontsize=6, zorder=4)
    for side, colour in _SIDE_COLOUR.items():
        ax.plot([], [], "s", color=colour, label=f"vehicle, {side} side")
    ax.set_aspect("equal")
    ax.set_xlabel("east (m)")
    ax.set_ylabel("north (m)")
    ax.set_title(
        f"{len(vs)} parked vehicles from {doc.detections} {doc.source} boxes in "
        f"{doc.frames_used} frames ({doc.detector}, >= {doc.min_hits} hits)"
    )
    ax.legend(loc="best", fontsize=8)
    save_figure(fig, path)
