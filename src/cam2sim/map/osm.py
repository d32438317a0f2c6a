"""OpenStreetMap input: read ``.osm``/``.osm.bz2``/``.osm.gz``, ``.osm.pbf`` and Overpass JSON.

Every source is read into one in-memory form, :class:`OsmData` (nodes as numpy arrays, ways and
relations as small records), which can be cropped to a box and written back as OSM XML, the only
input CARLA's converter takes. JOSM edits are honoured: elements marked ``action="delete"`` (and
history elements with ``visible="false"``) are dropped.
"""

from __future__ import annotations

import bz2
import functools
import gzip
import json
import logging
import math
import xml.parsers.expat
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any
from xml.sax.saxutils import quoteattr

import numpy as np

from cam2sim.core.errors import BackendUnavailableError, StageError

if TYPE_CHECKING:
    from collections.abc import Iterable, Mapping

    import numpy.typing as npt

__all__ = [
    "BBox",
    "OsmData",
    "OsmRelation",
    "OsmWay",
    "parse_osm_xml",
    "parse_overpass_json",
    "read_osm",
]

logger = logging.getLogger(__name__)

_REEXPORT_HINT = "export the area again (JOSM, openstreetmap.org Export, or Overpass)"


@dataclass(frozen=True)
class BBox:
    """A latitude/longitude box (degrees WGS84).

    Attributes:
        south: Minimum latitude.
        west: Minimum longitude.
        north: Maximum latitude.
        east: Maximum longitude.
    """

    south: float
    west: float
    north: float
    east: float

    def __post_init__(self) -> None:
        vals = (self.south, self.west, self.north, self.east)
        if not all(math.isfinite(v) for v in vals) or not (
            -90.0 <= self.south <= self.north <= 90.0 and -180.0 <= self.west <= self.east <= 180.0
        ):
            msg = (
                f"invalid box south={self.south!r} west={self.west!r} north={self.north!r} "
                f"east={self.east!r}; expected degrees with south <= north and west <= east"
            )
            raise ValueError(msg)

    @classmethod
    def around(cls, lat_deg: npt.ArrayLike, lon_deg: npt.ArrayLike) -> BBox:
        """Return the smallest box holding every point."""
        lat = np.asarray(lat_deg, dtype=np.float64)
        lon = np.asarray(lon_deg, dtype=np.float64)
        if lat.size == 0:
            msg = "cannot build a box around zero points"
            raise ValueError(msg)
        return cls(float(lat.min()), float(lon.min()), float(lat.max()), float(lon.max()))

    def contains(self, lat_deg: npt.ArrayLike, lon_deg: npt.ArrayLike) -> npt.NDArray[np.bool_]:
        """Return ``(N,)`` whether each point lies inside the box (edges included)."""
        lat = np.asarray(lat_deg, dtype=np.float64)
        lon = np.asarray(lon_deg, dtype=np.float64)
        return (lat >= self.south) & (lat <= self.north) & (lon >= self.west) & (lon <= self.east)

    def covers(self, other: BBox) -> bool:
        """Whether ``other`` lies entirely inside this box."""
        return (
            self.south <= other.south
            and self.west <= other.west
            and self.north >= other.north
            and self.east >= other.east
        )

    def intersection(self, other: BBox) -> BBox | None:
        """The overlap of two boxes, or None when they do not overlap."""
        south, north = max(self.south, other.south), min(self.north, other.north)
        west, east = max(self.west, other.west), min(self.east, other.east)
        if south > north or west > east:
            return None
        return BBox(south, west, north, east)

    def overpass(self) -> str:
        """The box in Overpass QL order: ``south,west,north,east``."""
        return f"{self.south:.7f},{self.west:.7f},{self.north:.7f},{self.east:.7f}"

    def __str__(self) -> str:
        return (
            f"lat {self.south:.6f}..{self.north:.6f}, lon {self.west:.6f}..{self.east:.6f} "
            "(degrees WGS84)"
        )


@dataclass(frozen=True, eq=False)
class OsmWay:
    """An OSM way.

    Attributes:
        id: OSM id (negative for new elements of an editor).
        refs: ``(K,)`` int64 node ids in order.
        tags: Key-value tags.
    """

    id: int
    refs: npt.NDArray[np.int64]
    tags: Mapping[str, str]


@dataclass(frozen=True, eq=False)
class OsmRelation:
    """An OSM relation.

    Attributes:
        id: OSM id.
        members: ``(type, ref, role)`` per member, in order.
        tags: Key-value tags.
    """

    id: int
    members: tuple[tuple[str, int, str], ...]
    tags: Mapping[str, str]


@dataclass(frozen=True, eq=False)
class OsmData:
    """OSM elements of one source, with deleted elements already dropped.

    Attributes:
        node_id: ``(N,)`` int64 node ids.
        lat_deg: ``(N,)`` float64 latitudes.
        lon_deg: ``(N,)`` float64 longitudes.
        node_tags: Tags of the nodes that have any, by node id.
        ways: The ways.
        relations: The relations.
        bounds: The ``<bounds>`` the source declares, if any.
        source: Where the data came from (a path or a URL), for messages.
        dropped_deleted: How many ``action="delete"`` / ``visible="false"`` elements were dropped.
    """

    node_id: npt.NDArray[np.int64]
    lat_deg: npt.NDArray[np.float64]
    lon_deg: npt.NDArray[np.float64]
    node_tags: Mapping[int, Mapping[str, str]]
    ways: tuple[OsmWay, ...]
    relations: tuple[OsmRelation, ...]
    bounds: BBox | None
    source: str
    dropped_deleted: int = 0

    @functools.cached_property
    def _sorted_ids(self) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.int64]]:
        order = np.argsort(self.node_id, kind="stable")
        return self.node_id[order], order

    def extent(self) -> BBox:
        """The declared bounds, or the box around all nodes when the source declares none.

        Raises:
            StageError: The data holds no node.
        """
        if self.bounds is not None:
            return self.bounds
        if self.node_id.size == 0:
            msg = f"{self.source} holds no OSM node; {_REEXPORT_HINT}"
            raise StageError(msg)
        return BBox.around(self.lat_deg, self.lon_deg)

    def node_indices(self, refs: npt.ArrayLike) -> npt.NDArray[np.int64]:
        """Return the row of each node id in the node arrays (-1 where unknown)."""
        ref = np.asarray(refs, dtype=np.int64)
        ids, order = self._sorted_ids
        if ids.size == 0:
            return np.full(ref.shape, -1, dtype=np.int64)
        pos = np.minimum(np.searchsorted(ids, ref), ids.size - 1)
        return np.where(ids[pos] == ref, order[pos], -1)

    def way_coords(self, way: OsmWay) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
        """Return ``(lat, lon)`` ``(K,)`` arrays of a way's known nodes, in order."""
        idx = self.node_indices(way.refs)
        idx = idx[idx >= 0]
        return self.lat_deg[idx], self.lon_deg[idx]

    def highways(self, types: Iterable[str]) -> tuple[OsmWay, ...]:
        """Return the ways whose ``highway`` tag is one of ``types``."""
        wanted = set(types)
        return tuple(w for w in self.ways if w.tags.get("highway") in wanted)

    def crop(self, box: BBox) -> OsmData:
        """Keep the ways with a node inside ``box`` (whole, with all their nodes), as Overpass does.

        Tagged nodes inside the box are kept too; relations keep their members that survive and
        are dropped when none does. The declared bounds become the overlap of ``box`` and the
        data's extent.
        """
        inside = box.contains(self.lat_deg, self.lon_deg)
        tagged = np.fromiter(self.node_tags, dtype=np.int64, count=len(self.node_tags))
        keep_node = inside & np.isin(self.node_id, tagged)
        ways = []
        for way in self.ways:
            idx = self.node_indices(way.refs)
            idx = idx[idx >= 0]
            if idx.size and inside[idx].any():
                ways.append(way)
                keep_node[idx] = True
        kept_nodes = set(self.node_id[keep_node].tolist())
        kept = {"node": kept_nodes, "way": {w.id for w in ways}}
        relations = []
        for rel in self.relations:
            members = tuple(m for m in rel.members if m[1] in kept.get(m[0], ()))
            if members:
                relations.append(OsmRelation(rel.id, members, rel.tags))
        tags = {n: t for n, t in self.node_tags.items() if n in kept_nodes}
        return OsmData(
            node_id=self.node_id[keep_node],
            lat_deg=self.lat_deg[keep_node],
            lon_deg=self.lon_deg[keep_node],
            node_tags=tags,
            ways=tuple(ways),
            relations=tuple(relations),
            bounds=box.intersection(self.extent()) if self.node_id.size else box,
            source=self.source,
            dropped_deleted=self.dropped_deleted,
        )

    def to_xml(self) -> str:
        """Write the data as OSM XML 0.6 (the input of CARLA's converter)."""
        out = [
            "<?xml version='1.0' encoding='UTF-8'?>",
            "<osm version='0.6' generator='cam2sim'>",
        ]
        if self.bounds is not None:
            b = self.bounds
            out.append(
                f"  <bounds minlat='{b.south:.7f}' minlon='{b.west:.7f}' "
                f"maxlat='{b.north:.7f}' maxlon='{b.east:.7f}'/>"
            )
        for nid, lat, lon in zip(
            self.node_id.tolist(), self.lat_deg.tolist(), self.lon_deg.tolist(), strict=True
        ):
            tags = self.node_tags.get(nid)
            head = f"  <node id='{nid}' visible='true' version='1' lat='{lat:.9f}' lon='{lon:.9f}'"
            if tags:
                out.append(head + ">")
                out.extend(_tag_lines(tags))
                out.append("  </node>")
            else:
                out.append(head + "/>")
        for way in self.ways:
            out.append(f"  <way id='{way.id}' visible='true' version='1'>")
            out.extend(f"    <nd ref='{r}'/>" for r in way.refs.tolist())
            out.extend(_tag_lines(way.tags))
            out.append("  </way>")
        for rel in self.relations:
            out.append(f"  <relation id='{rel.id}' visible='true' version='1'>")
            out.extend(
                f"    <member type={quoteattr(t)} ref='{r}' role={quoteattr(role)}/>"
                for t, r, role in rel.members
            )
            out.extend(_tag_lines(rel.tags))
            out.append("  </relation>")
        out.append("</osm>")
        return "\n".join(out) + "\n"


def _tag_lines(tags: Mapping[str, str]) -> list[str]:
    return [f"    <tag k={quoteattr(k)} v={quoteattr(v)}/>" for k, v in tags.items()]


# -- XML ----------------------------------------------------------------------------------------
class _XmlBuilder:
    """Expat callbacks collecting OSM elements with the line of each one, for messages."""

    def __init__(self, parser: xml.parsers.expat.XMLParserType, source: str) -> None:
        self.parser = parser
        self.source = source
        self.ids: list[int] = []
        self.lats: list[float] = []
        self.lons: list[float] = []
        self.node_tags: dict[int, dict[str, str]] = {}
        self.ways: list[OsmWay] = []
        self.relations: list[OsmRelation] = []
        self.bounds: BBox | None = None
        self.dropped = 0
        self.root_seen = False
        # The element being read: kind, id, tags, refs or members, deleted.
        self.kind: str | None = None
        self.elem_id = 0
        self.tags: dict[str, str] = {}
        self.refs: list[int] = []
        self.members: list[tuple[str, int, str]] = []
        self.deleted = False

    def _fail(self, what: str) -> StageError:
        line = self.parser.CurrentLineNumber
        msg = f"{self.source}, line {line}: {what}; fix the element or {_REEXPORT_HINT}"
        return StageError(msg)

    def _int(self, attrs: dict[str, str], key: str, elem: str) -> int:
        try:
            return int(attrs[key])
        except (KeyError, ValueError):
            msg = f"<{elem}> has no integer {key}= ({attrs.get(key)!r})"
            raise self._fail(msg) from None

    def _float(self, attrs: dict[str, str], key: str, elem: str) -> float:
        try:
            value = float(attrs[key])
        except (KeyError, ValueError):
            value = math.nan
        if not math.isfinite(value):
            msg = f"<{elem} id={attrs.get('id')!r}> has no valid {key}="
            raise self._fail(msg)
        return value

    def start(self, name: str, attrs: dict[str, str]) -> None:
        if not self.root_seen:
            if name != "osm":
                msg = f"the root element is <{name}>, expected <osm>"
                raise self._fail(msg)
            self.root_seen = True
            return
        if name in ("node", "way", "relation"):
            self._start_element(name, attrs)
        elif name == "tag" and self.kind is not None:
            self.tags[attrs.get("k", "")] = attrs.get("v", "")
        elif name == "nd" and self.kind == "way":
            self.refs.append(self._int(attrs, "ref", "nd"))
        elif name == "member" and self.kind == "relation":
            self.members.append(
                (attrs.get("type", ""), self._int(attrs, "ref", "member"), attrs.get("role", ""))
            )
        elif name == "bounds":
            try:
                self.bounds = BBox(
                    float(attrs["minlat"]),
                    float(attrs["minlon"]),
                    float(attrs["maxlat"]),
                    float(attrs["maxlon"]),
                )
            except (KeyError, ValueError) as err:
                msg = f"<bounds> is malformed ({err})"
                raise self._fail(msg) from None

    def _start_element(self, name: str, attrs: dict[str, str]) -> None:
        self.kind = name
        self.elem_id = self._int(attrs, "id", name)
        self.tags = {}
        self.refs = []
        self.members = []
        self.deleted = attrs.get("action") == "delete" or attrs.get("visible") == "false"
        if name == "node" and not self.deleted:
            lat = self._float(attrs, "lat", name)
            lon = self._float(attrs, "lon", name)
            if not (-90.0 <= lat <= 90.0 and -180.0 <= lon <= 180.0):
                msg = f"<node id='{self.elem_id}'> lies outside lat/lon range"
                raise self._fail(msg)
            self.ids.append(self.elem_id)
            self.lats.append(lat)
            self.lons.append(lon)

    def end(self, name: str) -> None:
        if name != self.kind:
            return
        if self.deleted:
            self.dropped += 1
        elif name == "node":
            if self.tags:
                self.node_tags[self.elem_id] = self.tags
        elif name == "way":
            refs = np.asarray(self.refs, dtype=np.int64)
            self.ways.append(OsmWay(self.elem_id, refs, self.tags))
        else:
            self.relations.append(OsmRelation(self.elem_id, tuple(self.members), self.tags))
        self.kind = None


def parse_osm_xml(data: bytes, *, source: str) -> OsmData:
    """Parse OSM XML (API 0.6, JOSM, Osmosis, Overpass ``out:xml``).

    Args:
        data: The file's bytes.
        source: The file or URL, named in messages.

    Returns:
        The elements, without deleted ones and with way references to missing nodes removed.

    Raises:
        StageError: The XML is malformed or an element lacks a required attribute; the message
            names the file and line.
    """
    parser = xml.parsers.expat.ParserCreate()
    builder = _XmlBuilder(parser, source)
    parser.StartElementHandler = builder.start
    parser.EndElementHandler = builder.end
    parser.buffer_text = True
    try:
        parser.Parse(data, True)  # noqa: FBT003 - expat takes isfinal positionally
    except xml.parsers.expat.ExpatError as err:
        msg = (
            f"{source}, line {err.lineno}, column {err.offset + 1}: malformed XML "
            f"({xml.parsers.expat.errors.messages[err.code]}); fix the file or {_REEXPORT_HINT}"
        )
        raise StageError(msg) from None
    if not builder.root_seen:
        msg = f"{source} is empty; expected an <osm> document"
        raise StageError(msg)
    return _finish(
        source,
        builder.ids,
        builder.lats,
        builder.lons,
        builder.node_tags,
        builder.ways,
        builder.relations,
        builder.bounds,
        builder.dropped,
    )


def _finish(  # noqa: PLR0913, PLR0917 - the parts of one result, collected by the readers
    source: str,
    ids: list[int],
    lats: list[float],
    lons: list[float],
    node_tags: dict[int, dict[str, str]],
    ways: list[OsmWay],
    relations: list[OsmRelation],
    bounds: BBox | None,
    dropped: int,
) -> OsmData:
    node_id = np.asarray(ids, dtype=np.int64)
    data = OsmData(
        node_id=node_id,
        lat_deg=np.asarray(lats, dtype=np.float64),
        lon_deg=np.asarray(lons, dtype=np.float64),
        node_tags=node_tags,
        ways=(),
        relations=(),
        bounds=bounds,
        source=source,
        dropped_deleted=dropped,
    )
    # Drop references to nodes that are not in the file (deleted, or outside an extract).
    clean: list[OsmWay] = []
    missing = 0
    for way in ways:
        idx = data.node_indices(way.refs)
        ok = idx >= 0
        missing += int((~ok).sum())
        if ok.sum() >= 2:
            clean.append(way if ok.all() else OsmWay(way.id, way.refs[ok], way.tags))
    kept_ways = {w.id for w in clean}
    known = {"node": set(ids), "way": kept_ways}
    rels = []
    for rel in relations:
        members = tuple(
            m for m in rel.members if m[0] == "relation" or m[1] in known.get(m[0], set())
        )
        if members:
            rels.append(OsmRelation(rel.id, members, rel.tags))
    if missing:
        logger.debug("%s: dropped %d references to absent nodes", source, missing)
    if dropped:
        logger.info("%s: dropped %d deleted elements (JOSM action=delete)", source, dropped)
    return OsmData(
        node_id=data.node_id,
        lat_deg=data.lat_deg,
        lon_deg=data.lon_deg,
        node_tags=node_tags,
        ways=tuple(clean),
        relations=tuple(rels),
        bounds=bounds,
        source=source,
        dropped_deleted=dropped,
    )


# -- Overpass JSON ------------------------------------------------------------------------------
def _json_tags(elem: Mapping[str, Any]) -> dict[str, str]:
    tags = elem.get("tags") or {}
    return {str(k): str(v) for k, v in tags.items()}


def parse_overpass_json(data: bytes, *, source: str) -> OsmData:
    """Parse an Overpass API JSON answer (``[out:json]``, ``out body``).

    Raises:
        StageError: Not JSON, or not an Overpass answer; the message names the element.
    """
    try:
        doc = json.loads(data)
    except (json.JSONDecodeError, UnicodeDecodeError) as err:
        msg = f"{source}: not valid JSON ({err}); pass an Overpass [out:json] answer or OSM XML"
        raise StageError(msg) from None
    elements = doc.get("elements") if isinstance(doc, dict) else None
    if not isinstance(elements, list):
        msg = f"{source}: no 'elements' list; expected an Overpass API [out:json] answer"
        raise StageError(msg)
    ids: list[int] = []
    lats: list[float] = []
    lons: list[float] = []
    node_tags: dict[int, dict[str, str]] = {}
    ways: list[OsmWay] = []
    relations: list[OsmRelation] = []
    for i, elem in enumerate(elements):
        try:
            kind = elem["type"]
            eid = int(elem["id"])
            if kind == "node":
                lat, lon = float(elem["lat"]), float(elem["lon"])
                ids.append(eid)
                lats.append(lat)
                lons.append(lon)
                if elem.get("tags"):
                    node_tags[eid] = _json_tags(elem)
            elif kind == "way":
                refs = np.asarray([int(n) for n in elem["nodes"]], dtype=np.int64)
                ways.append(OsmWay(eid, refs, _json_tags(elem)))
            elif kind == "relation":
                members = tuple(
                    (str(m["type"]), int(m["ref"]), str(m.get("role", "")))
                    for m in elem.get("members", ())
                )
                relations.append(OsmRelation(eid, members, _json_tags(elem)))
        except (KeyError, TypeError, ValueError) as err:
            msg = (
                f"{source}: elements[{i}] ({str(elem)[:80]}) is malformed ({err!r}); query "
                "Overpass with 'out body;' (not 'out geom') or pass OSM XML"
            )
            raise StageError(msg) from None
    bounds = None
    if isinstance(doc.get("bounds"), dict):
        b = doc["bounds"]
        bounds = BBox(b["minlat"], b["minlon"], b["maxlat"], b["maxlon"])
    return _finish(source, ids, lats, lons, node_tags, ways, relations, bounds, 0)


# -- PBF ----------------------------------------------------------------------------------------
def _read_pbf(path: Path) -> OsmData:
    try:
        import osmium  # noqa: PLC0415
    except ImportError as err:
        msg = "reading .osm.pbf needs pyosmium; install it with: pip install cam2sim[map]"
        raise BackendUnavailableError(msg) from err
    ids: list[int] = []
    lats: list[float] = []
    lons: list[float] = []
    node_tags: dict[int, dict[str, str]] = {}
    ways: list[OsmWay] = []
    relations: list[OsmRelation] = []
    try:
        reader = osmium.io.Reader(str(path))
        header = reader.header()
        box = header.box()
        bounds = None
        if box.valid():
            bl, tr = box.bottom_left, box.top_right
            bounds = BBox(bl.lat, bl.lon, tr.lat, tr.lon)
        reader.close()
        for obj in osmium.FileProcessor(str(path)):
            if isinstance(obj, osmium.osm.Node):
                if not obj.location.valid():
                    continue
                ids.append(obj.id)
                lats.append(obj.location.lat)
                lons.append(obj.location.lon)
                if len(obj.tags):
                    node_tags[obj.id] = {t.k: t.v for t in obj.tags}
            elif isinstance(obj, osmium.osm.Way):
                refs = np.asarray([n.ref for n in obj.nodes], dtype=np.int64)
                ways.append(OsmWay(obj.id, refs, {t.k: t.v for t in obj.tags}))
            elif isinstance(obj, osmium.osm.Relation):
                members = tuple((_PBF_TYPES[m.type], m.ref, m.role) for m in obj.members)
                relations.append(OsmRelation(obj.id, members, {t.k: t.v for t in obj.tags}))
    except RuntimeError as err:
        msg = f"{path}: cannot read as OSM PBF ({err}); {_REEXPORT_HINT}"
        raise StageError(msg) from None
    return _finish(str(path), ids, lats, lons, node_tags, ways, relations, bounds, 0)


_PBF_TYPES = {"n": "node", "w": "way", "r": "relation"}


# -- dispatch -----------------------------------------------------------------------------------
def read_osm(path: Path) -> OsmData:
    """Read an OSM file of any supported kind, chosen by suffix and content.

    ``.osm``/``.xml`` (optionally ``.bz2`` or ``.gz`` compressed), ``.pbf`` and Overpass JSON
    (``.json``, optionally ``.gz``) are read; a file whose content starts with ``{`` is read as
    JSON whatever its name.

    Raises:
        StageError: The file is missing, unreadable or malformed (message names file and line).
        BackendUnavailableError: A ``.pbf`` file and pyosmium is not installed.
    """
    path = Path(path)
    if not path.is_file():
        msg = f"OSM file {path} does not exist; pass an existing .osm, .osm.pbf or Overpass JSON"
        raise StageError(msg)
    name = path.name.lower()
    if name.endswith(".pbf"):
        return _read_pbf(path)
    try:
        raw = path.read_bytes()
        if name.endswith(".bz2"):
            raw = bz2.decompress(raw)
        elif name.endswith(".gz"):
            raw = gzip.decompress(raw)
    except (OSError, EOFError, ValueError) as err:
        msg = f"{path}: cannot decompress ({err}); {_REEXPORT_HINT}"
        raise StageError(msg) from None
    if raw.lstrip()[:1] == b"{":
        return parse_overpass_json(raw, source=str(path))
    return parse_osm_xml(raw, source=str(path))
