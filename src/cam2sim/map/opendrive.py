"""Read OpenDRIVE and evaluate its geometry with numpy: reference lines and lane boundaries.

The plan view (line, arc, spiral, poly3, paramPoly3), the lane offset and the lane widths are
evaluated analytically at any station ``s``; only the curves without a closed form (spiral,
poly3 and paramPoly3 arc length) are integrated numerically on a fine grid (sub-millimetre).
Elevation and superelevation are ignored: everything here is the 2-D plan view.
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from cam2sim.core.errors import StageError

if TYPE_CHECKING:
    import numpy.typing as npt

__all__ = [
    "Geometry",
    "Junction",
    "LaneDef",
    "LaneSection",
    "OpenDrive",
    "Poly3",
    "Road",
    "lane_borders",
    "lane_offset",
    "parse_opendrive",
    "reference_line",
    "road_half_width",
    "station_grid",
]

_FINE_STEP_M = 0.1  # integration step of the curves without closed form (arc error < 1e-4)
_MIN_FINE = 32
_MIN_RADIUS_M = 0.5  # radius floor for lanes wider than the curve radius (folded borders)
_MIN_STEP_M = 0.02


@dataclass(frozen=True)
class Poly3:
    """A cubic ``a + b·ds + c·ds² + d·ds³`` valid from station ``s`` on."""

    s: float
    a: float
    b: float
    c: float
    d: float


@dataclass(frozen=True)
class Geometry:
    """One plan-view record.

    Attributes:
        s: Start station, metres.
        x: Start x, metres.
        y: Start y, metres.
        hdg: Start heading, radians.
        length: Length, metres.
        kind: ``line``, ``arc``, ``spiral``, ``poly3`` or ``paramPoly3``.
        params: The kind's numbers: arc ``(curvature,)``; spiral ``(curvStart, curvEnd)``; poly3
            ``(a, b, c, d)``; paramPoly3 ``(aU, bU, cU, dU, aV, bV, cV, dV)``.
        normalized: paramPoly3 ``pRange="normalized"`` (else ``arcLength``).
    """

    s: float
    x: float
    y: float
    hdg: float
    length: float
    kind: str
    params: tuple[float, ...] = ()
    normalized: bool = True


@dataclass(frozen=True)
class LaneDef:
    """A lane of a lane section.

    Attributes:
        id: OpenDRIVE lane id: > 0 left of the reference line, < 0 right.
        type: OpenDRIVE lane type (``driving``, ``sidewalk``, ``parking``, ``shoulder``, ...).
        widths: Width records; ``s`` is relative to the section start.
        border: The records give the outer border's t instead of the width.
    """

    id: int
    type: str
    widths: tuple[Poly3, ...]
    border: bool = False


@dataclass(frozen=True)
class LaneSection:
    """Lanes valid from station ``s`` on (left lanes and right lanes, no centre lane)."""

    s: float
    lanes: tuple[LaneDef, ...]


@dataclass(frozen=True)
class Road:
    """An OpenDRIVE road.

    Attributes:
        id: Road id.
        name: Road name (the OSM street name for converted maps).
        length: Length of the reference line, metres.
        junction: Id of the junction this connecting road belongs to, or ``"-1"``.
        geometries: Plan view, sorted by ``s``.
        lane_offsets: ``laneOffset`` records (absolute ``s``).
        sections: Lane sections, sorted by ``s``.
    """

    id: str
    name: str
    length: float
    junction: str
    geometries: tuple[Geometry, ...]
    lane_offsets: tuple[Poly3, ...]
    sections: tuple[LaneSection, ...]

    @property
    def in_junction(self) -> bool:
        """Whether this is a connecting road inside a junction."""
        return self.junction != "-1"


@dataclass(frozen=True)
class Junction:
    """An OpenDRIVE junction: its id, name and connecting roads."""

    id: str
    name: str
    connecting_roads: tuple[str, ...]


@dataclass(frozen=True)
class OpenDrive:
    """A parsed OpenDRIVE document.

    Attributes:
        geo_reference: The ``<geoReference>`` PROJ string, if any.
        offset: Header ``<offset>`` ``(x, y, z, hdg)`` (local = projected + offset), zeros if none.
        roads: Roads in file order.
        junctions: Junctions in file order.
        rev: ``(revMajor, revMinor)``.
    """

    geo_reference: str | None
    offset: tuple[float, float, float, float]
    roads: tuple[Road, ...]
    junctions: tuple[Junction, ...]
    rev: tuple[int, int]


# -- parsing -----------------------------------------------------------------------------------
def _f(elem: ET.Element, key: str, default: float | None = None) -> float:
    raw = elem.get(key)
    if raw is None:
        if default is None:
            msg = f"<{elem.tag}> has no {key}="
            raise ValueError(msg)
        return default
    return float(raw)


def _poly(elem: ET.Element, s_key: str) -> Poly3:
    return Poly3(_f(elem, s_key), _f(elem, "a"), _f(elem, "b"), _f(elem, "c"), _f(elem, "d"))


_PARAMS = {
    "line": (),
    "arc": ("curvature",),
    "spiral": ("curvStart", "curvEnd"),
    "poly3": ("a", "b", "c", "d"),
    "paramPoly3": ("aU", "bU", "cU", "dU", "aV", "bV", "cV", "dV"),
}


def _geometry(elem: ET.Element) -> Geometry:
    shape = next(iter(elem), None)
    if shape is None or shape.tag not in _PARAMS:
        kind = "nothing" if shape is None else f"<{shape.tag}>"
        msg = f"<geometry s={elem.get('s')!r}> holds {kind}; expected {', '.join(_PARAMS)}"
        raise ValueError(msg)
    params = tuple(_f(shape, k) for k in _PARAMS[shape.tag])
    return Geometry(
        s=_f(elem, "s"),
        x=_f(elem, "x"),
        y=_f(elem, "y"),
        hdg=_f(elem, "hdg"),
        length=_f(elem, "length"),
        kind=shape.tag,
        params=params,
        normalized=shape.get("pRange", "normalized") != "arcLength",
    )


def _lane(elem: ET.Element) -> LaneDef:
    widths = tuple(_poly(w, "sOffset") for w in elem.findall("width"))
    border = False
    if not widths:
        widths = tuple(_poly(w, "sOffset") for w in elem.findall("border"))
        border = bool(widths)
    widths = tuple(sorted(widths, key=lambda p: p.s))
    return LaneDef(int(elem.get("id", "0")), elem.get("type", "none"), widths, border)


def _road(elem: ET.Element) -> Road:
    plan = elem.find("planView")
    lanes = elem.find("lanes")
    if plan is None or lanes is None:
        msg = "has no <planView> or no <lanes>"
        raise ValueError(msg)
    geoms = tuple(sorted((_geometry(g) for g in plan.findall("geometry")), key=lambda g: g.s))
    if not geoms:
        msg = "has an empty <planView>"
        raise ValueError(msg)
    offsets = tuple(sorted((_poly(o, "s") for o in lanes.findall("laneOffset")), key=lambda p: p.s))
    sections = []
    for sec in lanes.findall("laneSection"):
        defs = [_lane(ln) for side in ("left", "right") for ln in sec.findall(f"{side}/lane")]
        sections.append(LaneSection(_f(sec, "s"), tuple(d for d in defs if d.id != 0)))
    sections.sort(key=lambda sec: sec.s)
    return Road(
        id=elem.get("id", ""),
        name=elem.get("name", ""),
        length=_f(elem, "length"),
        junction=elem.get("junction", "-1") or "-1",
        geometries=geoms,
        lane_offsets=offsets,
        sections=tuple(sections),
    )


def parse_opendrive(text: str, *, source: str = "<map.xodr>") -> OpenDrive:
    """Parse OpenDRIVE text (1.4 to 1.8) into plan-view records.

    Raises:
        StageError: Malformed XML, or a road with a missing or malformed element (message names
            the source and the road).
    """
    try:
        root = ET.fromstring(text)  # noqa: S314 - our own converter's output or a user map
    except ET.ParseError as err:
        line, col = err.position
        msg = f"{source}, line {line}, column {col + 1}: malformed OpenDRIVE XML ({err})"
        raise StageError(msg) from None
    if root.tag != "OpenDRIVE":
        msg = f"{source}: the root element is <{root.tag}>, expected <OpenDRIVE>"
        raise StageError(msg)
    header = root.find("header")
    geo = None
    offset = (0.0, 0.0, 0.0, 0.0)
    rev = (1, 4)
    if header is not None:
        rev = (int(header.get("revMajor", "1")), int(header.get("revMinor", "4")))
        g = header.find("geoReference")
        if g is not None and g.text and g.text.strip():
            geo = g.text.strip()
        o = header.find("offset")
        if o is not None:
            offset = (_f(o, "x", 0.0), _f(o, "y", 0.0), _f(o, "z", 0.0), _f(o, "hdg", 0.0))
    roads = []
    for elem in root.findall("road"):
        try:
            roads.append(_road(elem))
        except ValueError as err:
            msg = f"{source}: <road id={elem.get('id')!r}> {err}; regenerate the map"
            raise StageError(msg) from None
    junctions = []
    for j in root.findall("junction"):
        conns = tuple(dict.fromkeys(c.get("connectingRoad", "") for c in j.findall("connection")))
        junctions.append(Junction(j.get("id", ""), j.get("name", ""), conns))
    return OpenDrive(geo, offset, tuple(roads), tuple(junctions), rev)


# -- evaluation ----------------------------------------------------------------------------------
def _poly_eval(records: tuple[Poly3, ...], s: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    """Evaluate piecewise cubics at ``s`` (0 where no record applies yet)."""
    out = np.zeros_like(s)
    if not records:
        return out
    starts = np.array([r.s for r in records])
    idx = np.searchsorted(starts, s, side="right") - 1
    coef = np.array([(r.a, r.b, r.c, r.d) for r in records])
    valid = idx >= 0
    i = np.clip(idx, 0, None)
    ds = s - starts[i]
    a, b, c, d = coef[i].T
    out[valid] = (a + ds * (b + ds * (c + ds * d)))[valid]
    return out


def _arc_length(
    fx: npt.NDArray[np.float64], fy: npt.NDArray[np.float64]
) -> npt.NDArray[np.float64]:
    """Cumulative arc length along a finely sampled curve."""
    return np.concatenate([[0.0], np.cumsum(np.hypot(np.diff(fx), np.diff(fy)))])


def _local_curve(
    g: Geometry, ds: npt.NDArray[np.float64]
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """Return local ``(u, v, heading)`` at stations ``ds`` (from the geometry start)."""
    if g.kind == "line":
        return ds, np.zeros_like(ds), np.zeros_like(ds)
    if g.kind == "arc":
        k = g.params[0]
        theta = k * ds
        if abs(k) < 1e-12:
            return ds, np.zeros_like(ds), theta
        return np.sin(theta) / k, (1.0 - np.cos(theta)) / k, theta
    n = max(_MIN_FINE, math.ceil(g.length / _FINE_STEP_M) + 1)
    if g.kind == "spiral":
        c0, c1 = g.params
        t = np.linspace(0.0, g.length, n)
        theta_f = c0 * t + (c1 - c0) * t**2 / (2.0 * g.length if g.length > 0 else 1.0)
        ct, st = np.cos(theta_f), np.sin(theta_f)
        h = np.diff(t)
        u_f = np.concatenate([[0.0], np.cumsum(h * (ct[1:] + ct[:-1]) / 2.0)])
        v_f = np.concatenate([[0.0], np.cumsum(h * (st[1:] + st[:-1]) / 2.0)])
        return np.interp(ds, t, u_f), np.interp(ds, t, v_f), np.interp(ds, t, theta_f)
    if g.kind == "poly3":
        a, b, c, d = g.params
        p = np.linspace(0.0, max(g.length, 1e-9), n)

        def uv(q: npt.NDArray[np.float64]) -> tuple[npt.NDArray[np.float64], ...]:
            return q, a + q * (b + q * (c + q * d)), np.ones_like(q), b + q * (2 * c + 3 * d * q)

    else:
        au, bu, cu, du, av, bv, cv, dv = g.params
        p = np.linspace(0.0, 1.0 if g.normalized else g.length, n)

        def uv(q: npt.NDArray[np.float64]) -> tuple[npt.NDArray[np.float64], ...]:
            return (
                au + q * (bu + q * (cu + q * du)),
                av + q * (bv + q * (cv + q * dv)),
                bu + q * (2 * cu + 3 * du * q),
                bv + q * (2 * cv + 3 * dv * q),
            )

    fu, fv, _, _ = uv(p)
    arc = _arc_length(fu, fv)
    # poly3 is sampled over u in [0, length], which runs past the curve's end: ds maps as is.
    # paramPoly3 spans exactly the geometry, so the numeric length is scaled to the declared one.
    scale = arc[-1] / g.length if g.length > 0 and g.kind != "poly3" else 1.0
    q = np.interp(ds * scale, arc, p)
    u, v, du_, dv_ = uv(q)
    return u, v, np.arctan2(dv_, du_)


def reference_line(
    road: Road, s: npt.NDArray[np.float64]
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """Evaluate a road's reference line at stations ``s``.

    Args:
        road: The road.
        s: ``(N,)`` stations, metres (clamped to ``[0, length]``).

    Returns:
        ``(x, y, hdg)``, each ``(N,)``: positions in metres and headings in radians.
    """
    s = np.clip(np.asarray(s, dtype=np.float64), 0.0, road.length)
    starts = np.array([g.s for g in road.geometries])
    gi = np.clip(np.searchsorted(starts, s, side="right") - 1, 0, len(road.geometries) - 1)
    x = np.empty_like(s)
    y = np.empty_like(s)
    hdg = np.empty_like(s)
    for i in np.unique(gi):
        g = road.geometries[int(i)]
        sel = gi == i
        ds = s[sel] - g.s
        if g.kind not in ("line", "arc"):  # tabulated curves end where they are defined;
            ds = np.clip(ds, 0.0, max(g.length, 0.0))  # lines and arcs run on to the road end
        else:
            ds = np.maximum(ds, 0.0)
        u, v, h = _local_curve(g, ds)
        ch, sh = math.cos(g.hdg), math.sin(g.hdg)
        x[sel] = g.x + u * ch - v * sh
        y[sel] = g.y + u * sh + v * ch
        hdg[sel] = g.hdg + h
    return x, y, hdg


def lane_offset(road: Road, s: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    """Lateral shift of the centre lane (``laneOffset``) at stations ``s``, metres."""
    return _poly_eval(road.lane_offsets, np.asarray(s, dtype=np.float64))


def lane_borders(
    section: LaneSection, s_rel: npt.NDArray[np.float64], offset: npt.NDArray[np.float64]
) -> dict[int, tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]]:
    """Lateral positions ``(inner t, outer t)`` of every lane of a section.

    Args:
        section: The lane section.
        s_rel: ``(N,)`` stations relative to the section start.
        offset: ``(N,)`` lane offset at those stations.

    Returns:
        Lane id to ``(inner, outer)`` ``(N,)`` arrays of t (metres, left of the reference line
        positive). Widths below zero count as zero.
    """
    out: dict[int, tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]] = {}
    for side in (1, -1):
        lanes = sorted(
            (ln for ln in section.lanes if np.sign(ln.id) == side), key=lambda ln: abs(ln.id)
        )
        inner = offset.copy()
        for ln in lanes:
            if ln.border:
                outer = offset + _poly_eval(ln.widths, s_rel)
            else:
                outer = inner + side * np.maximum(_poly_eval(ln.widths, s_rel), 0.0)
            out[ln.id] = (inner, outer)
            inner = outer
    return out


def _max_curvature(g: Geometry) -> float:
    """Largest curvature of a plan-view record, 1/metres (poly3 curves: on 33 samples)."""
    if g.kind == "line" or g.length <= 0:
        return 0.0
    if g.kind == "arc":
        return abs(g.params[0])
    if g.kind == "spiral":
        return max(abs(g.params[0]), abs(g.params[1]))
    if g.kind == "poly3":
        _, b, c, d = g.params
        p = np.linspace(0.0, g.length, 33)
        du, dv = np.ones_like(p), b + p * (2 * c + 3 * d * p)
        ddu, ddv = np.zeros_like(p), 2 * c + 6 * d * p
    else:
        _, bu, cu, du_, _, bv, cv, dv_ = g.params
        p = np.linspace(0.0, 1.0 if g.normalized else g.length, 33)
        du, dv = bu + p * (2 * cu + 3 * du_ * p), bv + p * (2 * cv + 3 * dv_ * p)
        ddu, ddv = 2 * cu + 6 * du_ * p, 2 * cv + 6 * dv_ * p
    speed = np.maximum(np.hypot(du, dv), 1e-12)
    return float(np.max(np.abs(du * ddv - dv * ddu) / speed**3))


def road_half_width(road: Road) -> float:
    """Largest lateral extent of a road's lanes from its reference line, metres (approximate)."""
    offset = max((abs(o.a) for o in road.lane_offsets), default=0.0)
    widest = 0.0
    for sec in road.sections:
        for side in (1, -1):
            total = sum(
                max(w.a for w in ln.widths)
                for ln in sec.lanes
                if ln.widths and np.sign(ln.id) == side
            )
            widest = max(widest, total)
    return offset + widest


def station_grid(
    road: Road,
    start: float,
    end: float,
    step_m: float,
    *,
    chord_tolerance_m: float | None = None,
    lateral_m: float = 0.0,
) -> npt.NDArray[np.float64]:
    """Stations from ``start`` to ``end``, with every geometry start in between.

    Args:
        road: The road.
        start: First station, metres.
        end: Last station, metres.
        step_m: Largest step, metres.
        chord_tolerance_m: On curved geometries, shorten the step so that a chord departs from
            the curve by at most this much, also on a line ``lateral_m`` inside the curve (a lane
            boundary). None keeps ``step_m`` everywhere.
        lateral_m: Lateral distance from the reference line that the tolerance must hold at.

    Returns:
        ``(K,)`` increasing stations, ``K >= 2``.
    """
    parts = [np.array([start, end])]
    for i, g in enumerate(road.geometries):
        g_end = road.geometries[i + 1].s if i + 1 < len(road.geometries) else road.length
        lo, hi = max(g.s, start), min(g_end, end)
        if hi <= lo:
            continue
        step = step_m
        if chord_tolerance_m is not None and g.kind != "line":
            kappa = _max_curvature(g)
            if kappa > 0:
                radius = max(1.0 / kappa - lateral_m, _MIN_RADIUS_M)
                step = min(step_m, max(math.sqrt(8.0 * radius * chord_tolerance_m), _MIN_STEP_M))
        parts.append(np.linspace(lo, hi, max(2, math.ceil((hi - lo) / step) + 1)))
    return np.unique(np.concatenate(parts))
