"""Stage map: a geo-referenced OpenDRIVE road map of the recorded street into ``WS/map/``.

The OSM roads around the *whole* recorded route (its bounding box plus a margin) come from a
local file (``--osm``) or an Overpass API query (cached in ``WS/map/overpass/``). CARLA's
converter turns them into OpenDRIVE in the workspace's own projection, so map coordinates are
world coordinates. The route is then fitted onto the map (``map_report.json``, ``map.png``).

Where no OSM can be had, the road is built from the driven path
(:mod:`cam2sim.map.trajectory_road`): always when the poses are not geo-referenced (no CRS),
and with ``road="auto"`` when the Overpass API cannot be reached and no ``--osm`` was given
(a warning in the report says so). ``road="trajectory"`` asks for it; ``xodr`` takes the
user's own OpenDRIVE file instead. ``map_report.json`` says which (``source.kind``) and
whether the map is geo-referenced.

Writes ``WS/map/``: ``source.osm`` (the OSM data converted), ``map.xodr``, ``map_report.json``,
``map.png`` and the Overpass cache. The folder is built beside the old one and swapped in at the
end: a failed run leaves the previous map as it was.
"""

from __future__ import annotations

import dataclasses
import hashlib
import logging
import math
import shutil
import warnings
from dataclasses import dataclass, field
from pathlib import Path  # noqa: TC003 - dataclass field types
from typing import TYPE_CHECKING, Literal

import numpy as np
import numpy.typing as npt

from cam2sim.core.dataset import DatasetInfo
from cam2sim.core.errors import ConfigError, StageError
from cam2sim.core.files import atomic_folder, file_fingerprint, write_text_atomic
from cam2sim.core.frames.projection import WorldFrame
from cam2sim.core.progress import ProgressCallback, no_progress
from cam2sim.core.table import read_table
from cam2sim.core.workspace import Workspace, dataset_paths, hash_inputs
from cam2sim.map.buildings import Building, building_footprints
from cam2sim.map.check import osm_alignment
from cam2sim.map.convert import ConvertOptions, osm_to_xodr
from cam2sim.map.osm import BBox, OsmData, parse_osm_xml, read_osm
from cam2sim.map.overpass import (
    OverpassOptions,
    OverpassUnreachableError,
    fetch_overpass,
    overpass_query,
)
from cam2sim.map.query import DRIVING, RoadMap
from cam2sim.map.report import (
    AlignmentReport,
    MapReport,
    RouteFit,
    SourceReport,
    fit_route,
    plot_map,
    road_counts,
    route_warnings,
)
from cam2sim.map.road_room import RecordedBody
from cam2sim.map.trajectory_road import TrajectoryRoadOptions, trajectory_road
from cam2sim.scenario.body import vehicle_geometry
from cam2sim.stages._runner import stage_run

if TYPE_CHECKING:
    from cam2sim.scenario.model import VehicleGeometry

__all__ = [
    "MAP_FILES",
    "MapOptions",
    "MapResult",
    "build_map",
    "load_buildings",
    "load_road_map",
    "route_box",
]

logger = logging.getLogger(__name__)

STAGE = "map"
MAP_FILES = {
    "source": "source.osm",
    "xodr": "map.xodr",
    "report": "map_report.json",
    "picture": "map.png",
    "cache": "overpass",
}
_MAX_MARGIN_M = 5000.0


@dataclass(frozen=True)
class MapOptions:
    """What the map stage reads and how it converts.

    Attributes:
        osm: A local OSM file (``.osm``, ``.osm.bz2``, ``.osm.pbf``, Overpass JSON); None queries
            the Overpass API for the route's box.
        margin_m: Margin around the route's bounding box, metres.
        convert: Road types, lane width, sidewalk mode, traffic lights.
        overpass: Server, timeouts, retries and cache refresh of the Overpass query.
        road: ``auto`` (OSM when the poses are geo-referenced, falling back to the driven path
            when the Overpass API is unreachable), ``osm`` (OSM or fail), ``trajectory`` (the
            road along the driven path).
        xodr: The user's own OpenDRIVE map, used as it is (the other options are ignored).
        trajectory: Lanes and widths of the road along the driven path (its lane width is
            ``convert.lane_width_m``).
    """

    osm: Path | None = None
    margin_m: float = 100.0
    convert: ConvertOptions = field(default_factory=ConvertOptions)
    overpass: OverpassOptions = field(default_factory=OverpassOptions)
    road: Literal["auto", "osm", "trajectory"] = "auto"
    xodr: Path | None = None
    trajectory: TrajectoryRoadOptions = field(default_factory=TrajectoryRoadOptions)

    def __post_init__(self) -> None:
        if not (math.isfinite(self.margin_m) and 0.0 <= self.margin_m <= _MAX_MARGIN_M):
            msg = f"--margin {self.margin_m!r} m is out of range; give 0 to {_MAX_MARGIN_M:.0f} m"
            raise ConfigError(msg)
        if self.road not in ("auto", "osm", "trajectory"):
            msg = f"road={self.road!r}; choose auto, osm or trajectory"
            raise ConfigError(msg)
        if self.road == "trajectory" and self.osm is not None:
            msg = "--road trajectory builds the road from the driven path; drop --osm"
            raise ConfigError(msg)
        if self.xodr is not None and self.osm is not None:
            msg = "give --osm or --xodr, not both"
            raise ConfigError(msg)


@dataclass(frozen=True)
class MapResult:
    """What :func:`build_map` did.

    Attributes:
        map_dir: ``WS/map``.
        report: The map report (also in ``map_report.json``).
        skipped: The map was up to date and left alone.
    """

    map_dir: Path
    report: MapReport
    skipped: bool

    @property
    def xodr_path(self) -> Path:
        """``WS/map/map.xodr``."""
        return self.map_dir / MAP_FILES["xodr"]


@dataclass(frozen=True, eq=False)
class _Route:
    xyz: npt.NDArray[np.float64]
    t: npt.NDArray[np.float64]
    heading: npt.NDArray[np.float64] | None
    lat: npt.NDArray[np.float64]
    lon: npt.NDArray[np.float64]


def _world_frame(ws: Workspace) -> WorldFrame | None:
    """The workspace's world frame; None when the poses are not geo-referenced."""
    record = ws.world_frame()
    if record is None:
        msg = f"{ws.root} has no world frame yet; run `cam2sim extract {ws.root}` first"
        raise StageError(msg)
    if record.origin_lat_deg is None or record.origin_lon_deg is None:
        return None
    frame = WorldFrame(record.origin_lat_deg, record.origin_lon_deg, record.origin_alt_m)
    if record.proj_string is not None and record.proj_string != frame.proj_string:
        msg = (
            f"workspace.json world.proj_string {record.proj_string!r} disagrees with its origin; "
            "re-run cam2sim extract --force"
        )
        raise StageError(msg)
    return frame


def _geo_frame(ws: Workspace) -> WorldFrame:
    """The world frame where a map must be placed on the Earth (OSM buildings)."""
    frame = _world_frame(ws)
    if frame is None:
        _geo_frame_error()
    assert frame is not None  # _geo_frame_error raised
    return frame


def _read_route(ws: Workspace, frame: WorldFrame | None) -> _Route:
    path = dataset_paths(ws.dataset_dir).trajectory_csv
    if not path.is_file():
        msg = f"{path} does not exist; {_redo(ws)}"
        raise StageError(msg)
    table = read_table(path)
    missing = [c for c in ("t", "x", "y") if c not in table]
    if missing:
        msg = f"{path} lacks columns {missing}; {_redo(ws)}"
        raise StageError(msg)
    xyz = np.stack(
        [
            table["x"].astype(np.float64),
            table["y"].astype(np.float64),
            table["z"].astype(np.float64) if "z" in table else np.zeros(len(table["x"])),
        ],
        axis=-1,
    )
    if xyz.shape[0] == 0 or not np.all(np.isfinite(xyz[:, :2])):
        msg = f"{path} holds no poses or non-finite ones; {_redo(ws)}"
        raise StageError(msg)
    heading = table["heading"].astype(np.float64) if "heading" in table else None
    if frame is None:
        nan = np.full(len(xyz), np.nan)
        return _Route(xyz, table["t"].astype(np.float64), heading, nan, nan)
    geo = frame.to_wgs84(xyz)
    return _Route(xyz, table["t"].astype(np.float64), heading, geo.lat_deg, geo.lon_deg)


def _redo(ws: Workspace) -> str:
    """What re-makes the trajectory: extract for a recording, import for images and poses."""
    info = dataset_paths(ws.dataset_dir).dataset_json
    if info.is_file() and DatasetInfo.load(info).kind == "images":
        return f"re-run `cam2sim import {ws.root} --images DIR --poses FILE`"
    return f"run `cam2sim extract {ws.root}` first"


def route_box(frame: WorldFrame, xy: npt.ArrayLike, margin_m: float) -> BBox:
    """Return the latitude/longitude box of the route's world-frame box grown by ``margin_m``.

    The metric box's corners and edge midpoints are projected, so the margin holds on every
    side whatever the route's length.
    """
    pts = np.asarray(xy, dtype=np.float64)[:, :2]
    (x0, y0), (x1, y1) = pts.min(axis=0) - margin_m, pts.max(axis=0) + margin_m
    xs = np.array([x0, (x0 + x1) / 2, x1])
    gx, gy = np.meshgrid(xs, np.array([y0, (y0 + y1) / 2, y1]))
    ring = np.stack([gx.ravel(), gy.ravel(), np.zeros(gx.size)], axis=-1)
    geo = frame.to_wgs84(ring)
    return BBox.around(geo.lat_deg, geo.lon_deg)


def _source_key(options: MapOptions, box: BBox | None, mode: str) -> dict[str, object]:
    if mode == "xodr":
        assert options.xodr is not None  # the mode says so
        if not options.xodr.is_file():
            msg = f"--xodr {options.xodr} does not exist; give an OpenDRIVE (.xodr) file"
            raise StageError(msg)
        return {"xodr": str(options.xodr.resolve()), "fingerprint": file_fingerprint(options.xodr)}
    if mode == "trajectory":
        return {"trajectory": dataclasses.asdict(options.trajectory)}
    if options.osm is not None:
        if not options.osm.is_file():
            msg = f"--osm {options.osm} does not exist; give an .osm, .osm.pbf or Overpass JSON"
            raise StageError(msg)
        return {"osm": str(options.osm.resolve()), "fingerprint": file_fingerprint(options.osm)}
    assert box is not None  # OSM needs a geo-referenced frame
    return {"url": options.overpass.url, "query": overpass_query(box, options.overpass.timeout_s)}


def _road_mode(options: MapOptions, frame: WorldFrame | None) -> str:
    """Where the road comes from: ``xodr``, ``osm`` or ``trajectory``."""
    if options.xodr is not None:
        return "xodr"
    if options.road == "trajectory":
        return "trajectory"
    if frame is None:
        if options.road == "osm" or options.osm is not None:
            _geo_frame_error()
        return "trajectory"
    return "osm"


def _geo_frame_error() -> None:
    msg = (
        "the workspace's world frame is not geo-referenced (the poses have no CRS), so no "
        "OSM data can be placed in it; set pose.crs in config.yaml and re-run cam2sim "
        "extract (or import with --crs), or drop --osm: the road is then built from the "
        "driven path"
    )
    raise StageError(msg)


def _check_covers(osm: OsmData, route: _Route) -> None:
    extent = osm.extent()
    inside = extent.contains(route.lat, route.lon)
    if inside.all():
        return
    outside = int((~inside).sum())
    msg = (
        f"{osm.source} covers {extent}, but {outside} of {inside.size} recorded poses "
        f"({outside / inside.size:.1%}) lie outside it (the route spans "
        f"{BBox.around(route.lat, route.lon)}); export an OSM extract covering the whole route "
        "plus a margin, or omit --osm to download it from the Overpass API"
    )
    raise StageError(msg)


def _load_source(
    ws: Workspace, options: MapOptions, box: BBox, route: _Route
) -> tuple[OsmData, SourceReport]:
    if options.osm is not None:
        osm = read_osm(options.osm)
        _check_covers(osm, route)
        digest = hashlib.sha256(options.osm.read_bytes()).hexdigest()
        source = SourceReport(
            kind="file",
            path=str(options.osm),
            sha256=digest,
            nodes=int(osm.node_id.size),
            ways=len(osm.ways),
            deleted_dropped=osm.dropped_deleted,
        )
        return osm, source
    answer = fetch_overpass(
        box, options=options.overpass, cache_dir=ws.map_dir / MAP_FILES["cache"]
    )
    osm = parse_osm_xml(answer.data, source=f"Overpass answer from {answer.url}")
    if osm.bounds is None:
        osm = dataclasses.replace(osm, bounds=box)
    source = SourceReport(
        kind="overpass",
        url=answer.url,
        query=answer.query,
        from_cache=answer.from_cache,
        sha256=hashlib.sha256(answer.data).hexdigest(),
        nodes=int(osm.node_id.size),
        ways=len(osm.ways),
        deleted_dropped=osm.dropped_deleted,
    )
    return osm, source


def _require_roads(osm: OsmData, box: BBox, options: ConvertOptions) -> None:
    roads = osm.highways(options.road_types)
    if roads:
        return
    present = sorted({w.tags["highway"] for w in osm.ways if "highway" in w.tags})
    msg = (
        f"no drivable roads (highway={','.join(options.road_types)}) in {box} of {osm.source}; "
        f"highway types present: {', '.join(present) or 'none'}. Widen --margin, add types "
        "with --road-types, or pass an OSM file that covers the route"
    )
    raise StageError(msg)


def _cached_report(ws: Workspace) -> MapReport | None:
    path = ws.map_dir / MAP_FILES["report"]
    if not (path.is_file() and (ws.map_dir / MAP_FILES["xodr"]).is_file()):
        return None
    return MapReport.load(path)


@dataclass(frozen=True, eq=False)
class _Place:
    """Where the route is.

    The world frame (None: local), its OSM box, the route itself, and the recorded car.
    """

    frame: WorldFrame | None
    box: BBox | None
    route: _Route
    body: RecordedBody


def _recorded_body(ws: Workspace, route: _Route, vehicle: VehicleGeometry) -> RecordedBody:
    """The recorded car for the road's room: its footprint and, when recorded, its headings.

    A heading from motion (GPS fixes) is the noisy path's own: the car is then put along the
    smoothed path instead.
    """
    path = dataset_paths(ws.dataset_dir).dataset_json
    from_motion = path.is_file() and DatasetInfo.load(path).heading_from_motion
    heading = route.heading
    usable = heading is not None and np.all(np.isfinite(heading)) and not from_motion
    return RecordedBody(
        length_m=vehicle.length_m,
        width_m=vehicle.width_m,
        reference_xy=(float(vehicle.reference_xyz[0]), float(vehicle.reference_xyz[1])),
        heading=heading if usable else None,
    )


def _road_source(
    ws: Workspace,
    options: MapOptions,
    mode: str,
    place: _Place,
    road_options: TrajectoryRoadOptions,
) -> tuple[str, SourceReport, OsmData | None, str | None, list[str]]:
    """The OpenDRIVE text and where it came from: OSM, the driven path, or the user's file.

    Returns ``(xodr, source, osm, osm_xml, notes)``; ``osm`` and ``osm_xml`` only from OSM.
    """
    frame, box, route = place.frame, place.box, place.route
    notes: list[str] = []
    if mode == "osm":
        assert frame is not None
        assert box is not None
        try:
            osm, source = _load_source(ws, options, box, route)
        except OverpassUnreachableError as err:
            if options.road != "auto":
                raise
            notes.append(
                f"no OSM data could be had ({err}); the road was built from the driven path. "
                f"Online, `cam2sim map {ws.root} --force` uses OSM instead"
            )
        else:
            osm = osm.crop(box)
            _require_roads(osm, box, options.convert)
            osm_xml = osm.to_xml()
            xodr = osm_to_xodr(osm_xml, frame.proj_string, options.convert)
            return xodr, source, osm, osm_xml, notes
    if mode == "xodr":
        assert options.xodr is not None  # the mode says so
        return (
            options.xodr.read_text(encoding="utf-8"),
            _file_source("xodr", options.xodr),
            None,
            None,
            notes,
        )
    road = trajectory_road(
        route.xyz,
        road_options,
        proj_string=frame.proj_string if frame is not None else None,
        body=place.body,
    )
    widened = (
        f"; widened by up to {road.widened_m:.2f} m over {road.widened_length_m:.0f} m where "
        f"the recorded car swept within {road_options.room_m:.1f} m of the edge"
        if road.widened_m > 0.01
        else ""
    )
    notes.append(
        f"the road follows the driven path ({road.length_m:.0f} m, "
        f"{road_options.lanes} lane(s) each way of {road_options.lane_width_m:.2f} m{widened}; "
        f"smoothing moved the path by up to {road.smoothing_m:.2f} m): no junctions, "
        "side streets or buildings"
    )
    trajectory_csv = dataset_paths(ws.dataset_dir).trajectory_csv
    return road.xodr, _file_source("trajectory", trajectory_csv), None, None, notes


def _write_map_folder(
    map_dir: Path,
    report: MapReport,
    xodr: str,
    osm_xml: str | None,
    road_map: RoadMap,
    route_xyz: npt.NDArray[np.float64],
    fit: RouteFit,
) -> None:
    """Replace ``map_dir`` as a whole, keeping its download cache.

    The OSM source (when there is one), the OpenDRIVE map, the report and the picture.
    """
    cache = map_dir / MAP_FILES["cache"]
    with atomic_folder(map_dir) as tmp:
        if osm_xml is not None:
            write_text_atomic(tmp / MAP_FILES["source"], osm_xml)
        write_text_atomic(tmp / MAP_FILES["xodr"], xodr)
        report.save(tmp / MAP_FILES["report"])
        covered = fit.report.covered_fraction
        title = f"{report.roads.roads} roads, {report.roads.junctions} junctions"
        if covered is not None:
            title += f"; route on a driving lane: {covered:.1%}"
        plot_map(road_map, route_xyz[:, :2], fit.on_lane, tmp / MAP_FILES["picture"], title=title)
        if cache.is_dir():
            shutil.copytree(cache, tmp / MAP_FILES["cache"])


def build_map(
    ws: Workspace,
    *,
    options: MapOptions | None = None,
    force: bool = False,
    progress: ProgressCallback | None = None,
) -> MapResult:
    """Build ``WS/map/`` for the workspace's recorded route.

    Args:
        ws: The workspace (needs a geo-referenced world frame and ``dataset/trajectory.csv``).
        options: OSM source, margin, conversion and Overpass options.
        force: Rebuild even when the inputs did not change.
        progress: Optional progress callback (task ``"map"``, 5 steps).

    Returns:
        :class:`MapResult` with the report.

    Raises:
        StageError: No world frame or trajectory yet; an OSM file that is malformed or does not
            cover the route; no drivable roads in the box; Overpass unreachable (pass --osm);
            the converter failed.
        BackendUnavailableError: carla (or pyosmium for .pbf) is not installed.
    """
    options = options or MapOptions()
    progress = progress or no_progress
    frame = _world_frame(ws)
    route = _read_route(ws, frame)
    mode = _road_mode(options, frame)
    box = route_box(frame, route.xyz, options.margin_m) if frame is not None else None
    trajectory_csv = dataset_paths(ws.dataset_dir).trajectory_csv
    vehicle = vehicle_geometry(ws.load_config().vehicle)
    road_options = dataclasses.replace(
        options.trajectory,
        lane_width_m=options.convert.lane_width_m,
        pose_height_m=float(vehicle.reference_xyz[2]),
    )
    inputs_hash = hash_inputs(
        {
            "source": _source_key(options, box, mode),
            "road": options.road,
            "road_options": dataclasses.asdict(road_options),
            "vehicle": vehicle.model_dump() if mode == "trajectory" else None,
            "margin_m": options.margin_m,
            "convert": options.convert.as_dict(),
            "proj_string": frame.proj_string if frame is not None else None,
            "trajectory": file_fingerprint(trajectory_csv),
        }
    )
    if not force and ws.is_up_to_date(STAGE, inputs_hash):
        cached = _cached_report(ws)
        if cached is not None:
            logger.info("map: up to date; skipping (use force to rebuild)")
            return MapResult(ws.map_dir, cached, skipped=True)
    with stage_run(ws, STAGE, inputs_hash=inputs_hash, config=None):
        progress("map", 0, 5)
        place = _Place(frame, box, route, _recorded_body(ws, route, vehicle))
        made = _road_source(ws, options, mode, place, road_options)
        xodr, source, osm, osm_xml, notes = made
        if frame is None:
            notes.append(
                "the map is not geo-referenced: the poses have no CRS (import with --crs, or "
                "set pose.crs, to place it on the Earth)"
            )
        progress("map", 2, 5)
        road_map = _road_map(xodr, source)
        fit = fit_route(road_map, route.xyz[:, :2], route.t, route.heading)
        alignment: AlignmentReport | None = None
        if osm is not None:
            assert frame is not None  # OSM needs it
            aligned = osm_alignment(osm, road_map, frame, options.convert.road_types)
            alignment = AlignmentReport.from_alignment(aligned)
        progress("map", 3, 5)
        report = MapReport(
            proj_string=frame.proj_string if frame is not None else None,
            georeferenced=frame is not None,
            box=(box.south, box.west, box.north, box.east) if box is not None else None,
            margin_m=options.margin_m,
            options=options.convert.as_dict(),
            source=source,
            roads=road_counts(road_map),
            route=fit.report,
            osm_alignment=alignment,
            warnings=[*notes, *route_warnings(fit.report)],
        )
        _write_map_folder(ws.map_dir, report, xodr, osm_xml, road_map, route.xyz, fit)
        progress("map", 4, 5)
    progress("map", 5, 5)
    logger.info(
        "map (%s): %d roads, %d junctions; %.1f%% of the route on a driving lane",
        source.kind,
        report.roads.roads,
        report.roads.junctions,
        100.0 * (fit.report.covered_fraction or 0.0),
    )
    for text in report.warnings:
        warnings.warn(text, stacklevel=2)
    return MapResult(ws.map_dir, report, skipped=False)


def _file_source(kind: Literal["trajectory", "xodr"], path: Path) -> SourceReport:
    data = path.read_bytes()
    return SourceReport(
        kind=kind,
        path=str(path),
        sha256=hashlib.sha256(data).hexdigest(),
        nodes=0,
        ways=0,
        deleted_dropped=0,
    )


def _road_map(xodr: str, source: SourceReport) -> RoadMap:
    """The map's roads, with at least one driving lane."""
    where = source.path or source.kind
    try:
        road_map = RoadMap.from_xodr(xodr)
    except StageError as err:
        msg = f"{where}: not a readable OpenDRIVE map ({err})"
        raise StageError(msg) from None
    if not road_map.lane_indices(DRIVING).size:
        msg = (
            f"{where}: the map has no driving lane; add road types with --road-types, check "
            "the OSM data, or give a map with driving lanes"
        )
        raise StageError(msg)
    return road_map


def load_road_map(ws: Workspace) -> RoadMap:
    """Load the workspace's map (``WS/map/map.xodr``) for queries by later stages.

    Raises:
        StageError: The map stage has not run yet.
    """
    path = ws.map_xodr_path
    if not path.is_file():
        msg = f"{path} does not exist; run `cam2sim map {ws.root}` first"
        raise StageError(msg)
    return RoadMap.from_xodr(path)


def load_buildings(ws: Workspace, *, default_height_m: float = 10.0) -> list[Building]:
    """The buildings of the map's OSM source (``WS/map/source.osm``) in the world frame.

    Empty when the map stage kept no OSM source.
    """
    path = ws.map_dir / MAP_FILES["source"]
    if not path.is_file():
        return []
    return building_footprints(read_osm(path), _geo_frame(ws), default_height_m=default_height_m)
