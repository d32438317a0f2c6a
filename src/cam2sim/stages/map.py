"""Stage map: a geo-referenced OpenDRIVE road map of the recorded street into ``WS/map/``.

The OSM roads around the *whole* recorded route (its bounding box plus a margin) come from a
local file (``--osm``) or an Overpass API query (cached in ``WS/map/overpass/``). CARLA's
converter turns them into OpenDRIVE in the workspace's own projection, so map coordinates are
world coordinates. The route is then fitted onto the map (``map_report.json``, ``map.png``).

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

import numpy as np
import numpy.typing as npt

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
from cam2sim.map.overpass import OverpassOptions, fetch_overpass, overpass_query
from cam2sim.map.query import DRIVING, RoadMap
from cam2sim.map.report import (
    AlignmentReport,
    MapReport,
    SourceReport,
    fit_route,
    plot_map,
    road_counts,
    route_warnings,
)
from cam2sim.stages._runner import stage_run

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
    """

    osm: Path | None = None
    margin_m: float = 100.0
    convert: ConvertOptions = field(default_factory=ConvertOptions)
    overpass: OverpassOptions = field(default_factory=OverpassOptions)

    def __post_init__(self) -> None:
        if not (math.isfinite(self.margin_m) and 0.0 <= self.margin_m <= _MAX_MARGIN_M):
            msg = f"--margin {self.margin_m!r} m is out of range; give 0 to {_MAX_MARGIN_M:.0f} m"
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


def _world_frame(ws: Workspace) -> WorldFrame:
    record = ws.world_frame()
    if record is None:
        msg = f"{ws.root} has no world frame yet; run `cam2sim extract {ws.root}` first"
        raise StageError(msg)
    if record.origin_lat_deg is None or record.origin_lon_deg is None:
        msg = (
            "the workspace's world frame is not geo-referenced (the poses have no CRS), so no "
            "map can be placed in it; set pose.crs in config.yaml and re-run cam2sim extract"
        )
        raise StageError(msg)
    frame = WorldFrame(record.origin_lat_deg, record.origin_lon_deg, record.origin_alt_m)
    if record.proj_string is not None and record.proj_string != frame.proj_string:
        msg = (
            f"workspace.json world.proj_string {record.proj_string!r} disagrees with its origin; "
            "re-run cam2sim extract --force"
        )
        raise StageError(msg)
    return frame


def _read_route(ws: Workspace, frame: WorldFrame) -> _Route:
    path = dataset_paths(ws.dataset_dir).trajectory_csv
    if not path.is_file():
        msg = f"{path} does not exist; run `cam2sim extract {ws.root}` first"
        raise StageError(msg)
    table = read_table(path)
    missing = [c for c in ("t", "x", "y") if c not in table]
    if missing:
        msg = f"{path} lacks columns {missing}; re-run cam2sim extract"
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
        msg = f"{path} holds no poses or non-finite ones; re-run cam2sim extract"
        raise StageError(msg)
    heading = table["heading"].astype(np.float64) if "heading" in table else None
    geo = frame.to_wgs84(xyz)
    return _Route(xyz, table["t"].astype(np.float64), heading, geo.lat_deg, geo.lon_deg)


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


def _source_key(options: MapOptions, box: BBox) -> dict[str, object]:
    if options.osm is not None:
        if not options.osm.is_file():
            msg = f"--osm {options.osm} does not exist; give an .osm, .osm.pbf or Overpass JSON"
            raise StageError(msg)
        return {"osm": str(options.osm.resolve()), "fingerprint": file_fingerprint(options.osm)}
    return {"url": options.overpass.url, "query": overpass_query(box, options.overpass.timeout_s)}


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
    box = route_box(frame, route.xyz, options.margin_m)
    inputs_hash = hash_inputs(
        {
            "source": _source_key(options, box),
            "margin_m": options.margin_m,
            "convert": options.convert.as_dict(),
            "proj_string": frame.proj_string,
            "trajectory": file_fingerprint(dataset_paths(ws.dataset_dir).trajectory_csv),
        }
    )
    if not force and ws.is_up_to_date(STAGE, inputs_hash):
        cached = _cached_report(ws)
        if cached is not None:
            logger.info("map: up to date; skipping (use force to rebuild)")
            return MapResult(ws.map_dir, cached, skipped=True)
    with stage_run(ws, STAGE, inputs_hash=inputs_hash, config=None):
        progress("map", 0, 5)
        osm, source = _load_source(ws, options, box, route)
        osm = osm.crop(box)
        _require_roads(osm, box, options.convert)
        osm_xml = osm.to_xml()
        progress("map", 1, 5)
        xodr = osm_to_xodr(osm_xml, frame.proj_string, options.convert)
        progress("map", 2, 5)
        road_map = RoadMap.from_xodr(xodr)
        if not road_map.lane_indices(DRIVING).size:
            count = len(osm.highways(options.convert.road_types))
            msg = (
                f"the converter made no driving lane from {count} roads in {box}; add road "
                "types with --road-types or check the OSM data"
            )
            raise StageError(msg)
        fit = fit_route(road_map, route.xyz[:, :2], route.t, route.heading)
        alignment = osm_alignment(osm, road_map, frame, options.convert.road_types)
        progress("map", 3, 5)
        report = MapReport(
            proj_string=frame.proj_string,
            box=(box.south, box.west, box.north, box.east),
            margin_m=options.margin_m,
            options=options.convert.as_dict(),
            source=source,
            roads=road_counts(road_map),
            route=fit.report,
            osm_alignment=AlignmentReport.from_alignment(alignment),
            warnings=route_warnings(fit.report),
        )
        cache = ws.map_dir / MAP_FILES["cache"]
        with atomic_folder(ws.map_dir) as tmp:
            write_text_atomic(tmp / MAP_FILES["source"], osm_xml)
            write_text_atomic(tmp / MAP_FILES["xodr"], xodr)
            report.save(tmp / MAP_FILES["report"])
            covered = fit.report.covered_fraction
            plot_map(
                road_map,
                route.xyz[:, :2],
                fit.on_lane,
                tmp / MAP_FILES["picture"],
                title=(
                    f"{report.roads.roads} roads, {report.roads.junctions} junctions; "
                    f"route on a driving lane: {covered:.1%}"
                    if covered is not None
                    else f"{report.roads.roads} roads, {report.roads.junctions} junctions"
                ),
            )
            if cache.is_dir():
                shutil.copytree(cache, tmp / MAP_FILES["cache"])
            progress("map", 4, 5)
    progress("map", 5, 5)
    logger.info(
        "map: %d roads, %d junctions; %.1f%% of the route on a driving lane",
        report.roads.roads,
        report.roads.junctions,
        100.0 * (fit.report.covered_fraction or 0.0),
    )
    for text in report.warnings:
        warnings.warn(text, stacklevel=2)
    return MapResult(ws.map_dir, report, skipped=False)


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
    return building_footprints(read_osm(path), _world_frame(ws), default_height_m=default_height_m)
