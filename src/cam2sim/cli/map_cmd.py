"""``cam2sim map``: build the workspace's OpenDRIVE road map from OpenStreetMap."""

from __future__ import annotations

from enum import StrEnum
from pathlib import Path  # noqa: TC003 - typer reads annotations at run time
from typing import TYPE_CHECKING, Annotated

import typer

from cam2sim.cli.display import console, progress_bars
from cam2sim.cli.options import comma_list
from cam2sim.core.workspace import Workspace
from cam2sim.map.convert import CARLA_ROAD_TYPES, ConvertOptions
from cam2sim.map.overpass import DEFAULT_URL, OverpassOptions

if TYPE_CHECKING:
    from cam2sim.stages.map import MapResult

__all__ = ["RoadChoice", "SidewalkChoice", "map_"]


class RoadChoice(StrEnum):
    """Where the road comes from."""

    AUTO = "auto"
    OSM = "osm"
    TRAJECTORY = "trajectory"


class SidewalkChoice(StrEnum):
    """How OSM sidewalks appear in the map."""

    KERB = "kerb"
    PARKING = "parking"


def _road_types(text: str | None) -> tuple[str, ...] | None:
    return None if text is None else comma_list(text)


def map_(
    workspace: Annotated[Path, typer.Argument(help="The workspace folder.")],
    *,
    osm: Annotated[
        Path | None,
        typer.Option(
            "--osm",
            help="Local OSM file (.osm, .osm.bz2, .osm.pbf, Overpass .json); "
            "without it the Overpass API is queried.",
        ),
    ] = None,
    road: Annotated[
        RoadChoice,
        typer.Option(
            help="auto: OSM, or the driven path when the poses have no CRS or Overpass is "
            "unreachable; osm: OSM or fail; trajectory: a road along the driven path.",
        ),
    ] = RoadChoice.AUTO,
    xodr: Annotated[
        Path | None,
        typer.Option("--xodr", help="Use this OpenDRIVE map as it is (no OSM)."),
    ] = None,
    lanes: Annotated[
        int,
        typer.Option(
            "--lanes", min=1, max=4, help="Driving lanes each way of a road along the path."
        ),
    ] = 1,
    margin: Annotated[
        float, typer.Option("--margin", min=0.0, help="Margin around the route's box, metres.")
    ] = 100.0,
    road_types: Annotated[
        str | None,
        typer.Option(
            "--road-types",
            help="Comma-separated OSM highway values to convert (default: CARLA's list, "
            "motorway ... residential; add service,living_street for yards).",
        ),
    ] = None,
    lane_width: Annotated[
        float, typer.Option("--lane-width", help="Lane width where OSM gives none, metres.")
    ] = 3.35,
    sidewalks: Annotated[
        SidewalkChoice,
        typer.Option(help="Sidewalks as a raised kerb, or as flat parking lanes cars park on."),
    ] = SidewalkChoice.KERB,
    traffic_lights: Annotated[
        bool, typer.Option("--traffic-lights/--no-traffic-lights", help="Generate signals.")
    ] = False,
    overpass_url: Annotated[
        str, typer.Option("--overpass-url", help="Overpass API interpreter endpoint.")
    ] = DEFAULT_URL,
    overpass_timeout: Annotated[
        float, typer.Option("--overpass-timeout", min=1.0, help="Seconds per Overpass request.")
    ] = 60.0,
    overpass_retries: Annotated[
        int, typer.Option("--overpass-retries", min=0, help="Retries after a failed request.")
    ] = 3,
    refresh_osm: Annotated[
        bool, typer.Option("--refresh-osm", help="Ignore the cached Overpass answer.")
    ] = False,
    force: Annotated[bool, typer.Option(help="Rebuild even if up to date.")] = False,
) -> None:
    """Build WS/map/ (map.xodr, map_report.json, map.png) around the whole recorded route.

    Without OSM (poses without a CRS, or offline without --osm) the road is built along the
    driven path: one road, --lanes lanes each way, the car in the outermost of its direction.

    Example: cam2sim map ws --osm area.osm.pbf --margin 150 --sidewalks parking
    """
    from cam2sim.map.trajectory_road import TrajectoryRoadOptions  # noqa: PLC0415 -- lazy: numpy
    from cam2sim.stages.map import MapOptions, build_map  # noqa: PLC0415 -- lazy: imports shapely

    options = MapOptions(
        osm=osm,
        road=road.value,
        xodr=xodr,
        trajectory=TrajectoryRoadOptions(lanes=lanes),
        margin_m=margin,
        convert=ConvertOptions(
            road_types=_road_types(road_types) or CARLA_ROAD_TYPES,
            lane_width_m=lane_width,
            sidewalks=sidewalks.value,
            traffic_lights=traffic_lights,
        ),
        overpass=OverpassOptions(
            url=overpass_url,
            timeout_s=overpass_timeout,
            retries=overpass_retries,
            refresh=refresh_osm,
        ),
    )
    ws = Workspace.open(workspace)
    with progress_bars() as sink:
        result = build_map(ws, options=options, force=force, progress=sink)
    _print_summary(result)


def _print_summary(result: MapResult) -> None:
    """What the map is: its roads and junctions, and how the recorded route lies on it."""
    report = result.report
    if result.skipped:
        console.print("map is up to date (use --force to rebuild)")
    route = report.route
    covered = "-" if route.covered_fraction is None else f"{route.covered_fraction:.1%}"
    offset = route.lateral_offset
    console.print(
        f"{result.xodr_path}: {report.roads.roads} roads, {report.roads.junctions} junctions; "
        f"route {route.length_m:.0f} m, {covered} on a driving lane, "
        f"{route.off_map_stretch_count} stretches off the map; lateral offset mean "
        f"{offset.mean_m or 0.0:.2f} m, p95 {offset.p95_m or 0.0:.2f} m",
        highlight=False,
    )
