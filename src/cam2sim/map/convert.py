"""OSM XML to OpenDRIVE with CARLA's own converter, in the workspace's projection.

``carla.Osm2Odr`` (PyPI ``carla`` 0.9.16) works without a CARLA server. It is given the world
frame's PROJ string and ``center_map = False``, so the OpenDRIVE coordinates it writes *are*
world coordinates: no ``<offset>``, no shift, and a ``<geoReference>`` equal to the workspace's
projection (checked after every conversion). The published tool left the default ``+proj=tmerc``
(centred on longitude 0), which at Munich scales the map by 0.91 % and rotates it by 8.7°.

Each conversion runs in a fresh Python process (see ``_osm2odr_worker.py``): the converter keeps
global state that breaks every call after a failed one, and prints to the C-level stdout; the
child's output is logged at DEBUG here.
"""

from __future__ import annotations

import importlib.util
import json
import logging
import math
import os
import re
import subprocess
import sys
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

from cam2sim.core.errors import BackendUnavailableError, ConfigError, StageError

__all__ = [
    "CARLA_ROAD_TYPES",
    "DRIVABLE_HIGHWAY_TYPES",
    "ConvertOptions",
    "SidewalkMode",
    "has_carla",
    "osm_to_xodr",
]

logger = logging.getLogger(__name__)

SidewalkMode = Literal["kerb", "parking"]

# CARLA's own default list (Osm2OdrSettings), which the published tool also used.
CARLA_ROAD_TYPES: tuple[str, ...] = (
    "motorway",
    "motorway_link",
    "trunk",
    "trunk_link",
    "primary",
    "primary_link",
    "secondary",
    "secondary_link",
    "tertiary",
    "tertiary_link",
    "unclassified",
    "residential",
)
# Every highway value that SUMO's OSM import turns into a road a car may use.
DRIVABLE_HIGHWAY_TYPES: tuple[str, ...] = (
    *CARLA_ROAD_TYPES,
    "living_street",
    "service",
    "road",
    "track",
)
_INSTALL_HINT = "install it with: pip install cam2sim[map]"
_WORKER = Path(__file__).with_name("_osm2odr_worker.py")
_DEFAULT_TIMEOUT_S = 600.0
_SIDEWALK_LANE = re.compile(r'(<lane\b[^>]*\btype=)"sidewalk"')
_GEOREF = re.compile(r"<geoReference>\s*<!\[CDATA\[(.*?)\]\]>\s*</geoReference>", re.DOTALL)
_OFFSET = re.compile(r"<offset\s[^>]*>")


@dataclass(frozen=True)
class ConvertOptions:
    """How OSM ways become OpenDRIVE roads.

    Attributes:
        road_types: OSM ``highway=*`` values converted into roads (default: CARLA's list, which
            leaves out ``service`` and ``living_street``; add them for car parks and yards).
        lane_width_m: Width of every lane whose width OSM does not give, metres (CARLA 0.9.16's
            default 3.35).
        sidewalks: ``"kerb"`` keeps SUMO's sidewalk lanes as OpenDRIVE ``sidewalk`` (CARLA builds
            them as a raised kerb); ``"parking"`` turns them into flat ``parking`` lanes at road
            level, where vehicles may park (what the published tool's fix-up script did).
        traffic_lights: Generate traffic lights at signalled OSM junctions (off by default:
            recorded drives rarely match simulated signal timing).
        timeout_s: Limit for one conversion, seconds.
    """

    road_types: tuple[str, ...] = CARLA_ROAD_TYPES
    lane_width_m: float = 3.35
    sidewalks: SidewalkMode = "kerb"
    traffic_lights: bool = False
    timeout_s: float = field(default=_DEFAULT_TIMEOUT_S, compare=False)

    def __post_init__(self) -> None:
        types = tuple(self.road_types)
        object.__setattr__(self, "road_types", types)
        unknown = sorted(set(types) - set(DRIVABLE_HIGHWAY_TYPES))
        if not types or unknown:
            msg = (
                f"road types {unknown or list(types)!r} are not drivable OSM highway values; "
                f"choose from {', '.join(DRIVABLE_HIGHWAY_TYPES)}"
            )
            raise ConfigError(msg)
        if not (math.isfinite(self.lane_width_m) and 1.5 <= self.lane_width_m <= 6.0):
            msg = f"lane width {self.lane_width_m!r} m is out of range; give 1.5 to 6.0 metres"
            raise ConfigError(msg)
        if self.sidewalks not in ("kerb", "parking"):
            msg = f"sidewalks={self.sidewalks!r}; choose 'kerb' or 'parking'"
            raise ConfigError(msg)

    def as_dict(self) -> dict[str, object]:
        """The options that change the output, for input hashes and the report."""
        return {
            "road_types": list(self.road_types),
            "lane_width_m": self.lane_width_m,
            "sidewalks": self.sidewalks,
            "traffic_lights": self.traffic_lights,
        }


def has_carla() -> bool:
    """Whether the ``carla`` Python package (the OSM converter) is installed."""
    return importlib.util.find_spec("carla") is not None


def _proj_data_dir() -> str:
    import pyproj.datadir  # noqa: PLC0415

    return str(pyproj.datadir.get_data_dir())


def _run_worker(request: dict[str, object], timeout_s: float) -> None:
    """Run the converter process on ``request``; raise StageError with its message on failure."""
    env = dict(os.environ)
    # libcarla bundles PROJ 7, which looks for proj.db through PROJ_LIB (newer PROJ reads
    # PROJ_DATA); pyproj's data folder serves both. Set before carla is imported in the child.
    data_dir = _proj_data_dir()
    env.setdefault("PROJ_LIB", data_dir)
    env.setdefault("PROJ_DATA", data_dir)
    with tempfile.TemporaryDirectory(prefix="cam2sim-osm2odr-") as tmp:
        req_path = Path(tmp) / "request.json"
        req_path.write_text(json.dumps(request), encoding="utf-8")
        try:
            proc = subprocess.run(  # noqa: S603 - our own worker file, run by this interpreter
                [sys.executable, str(_WORKER), str(req_path)],
                capture_output=True,
                text=True,
                errors="replace",
                timeout=timeout_s,
                env=env,
                check=False,
            )
        except subprocess.TimeoutExpired:
            msg = (
                f"the OSM converter ran longer than {timeout_s:.0f} s; pass a smaller OSM extract "
                "or a smaller --margin"
            )
            raise StageError(msg) from None
    output = (proc.stdout + "\n" + proc.stderr).strip()
    lines = [ln for ln in output.splitlines() if ln.strip()]
    warnings_count = sum(ln.startswith("Warning:") for ln in lines)
    logger.debug("osm2odr output (%d lines):\n%s", len(lines), output)
    if proc.returncode == 3:
        msg = f"the carla package cannot be imported in a subprocess; {_INSTALL_HINT}"
        raise BackendUnavailableError(msg)
    if proc.returncode != 0:
        errors = [ln.removeprefix("osm2odr error: ") for ln in lines if "error" in ln.lower()]
        reason = errors[-1] if errors else (lines[-1] if lines else f"exit code {proc.returncode}")
        msg = (
            f"CARLA's OSM converter failed: {reason}; check that the OSM data holds roads of the "
            "chosen types (--road-types) inside the box"
        )
        raise StageError(msg)
    logger.info("osm2odr finished with %d converter warnings", warnings_count)


def _check_georeference(xodr: str, proj_string: str) -> None:
    match = _GEOREF.search(xodr)
    found = match.group(1).strip() if match else None
    if found != proj_string.strip():
        msg = (
            f"the converter wrote geoReference {found!r}, expected {proj_string!r}; the carla "
            "package may be too old (cam2sim needs carla 0.9.16: pip install cam2sim[map])"
        )
        raise StageError(msg)
    for tag in _OFFSET.findall(xodr[: match.end() + 400 if match else 0]):
        values = [float(v) for v in re.findall(r'\b[xyz]="([-0-9.eE+]+)"', tag)]
        if any(abs(v) > 0.0 for v in values):
            msg = f"the converter wrote {tag} although center_map is off; report this as a bug"
            raise StageError(msg)


def osm_to_xodr(osm_xml: str, proj_string: str, options: ConvertOptions | None = None) -> str:
    """Convert OSM XML to OpenDRIVE 1.4 whose coordinates are those of ``proj_string``.

    Args:
        osm_xml: OSM XML text (see :meth:`cam2sim.map.osm.OsmData.to_xml`).
        proj_string: The workspace world frame's PROJ string; OpenDRIVE x/y are metres in it.
        options: Road types, lane width, sidewalk mode, traffic lights.

    Returns:
        The OpenDRIVE text, with ``<geoReference>`` equal to ``proj_string`` and no offset.

    Raises:
        BackendUnavailableError: carla is not installed.
        StageError: The converter failed (no roads of the chosen types, malformed input, time
            limit) or wrote a different projection.
    """
    options = options or ConvertOptions()
    if not has_carla():
        msg = f"converting OSM to OpenDRIVE needs CARLA's Python package; {_INSTALL_HINT}"
        raise BackendUnavailableError(msg)
    with tempfile.TemporaryDirectory(prefix="cam2sim-map-") as tmp:
        osm_path = Path(tmp) / "source.osm"
        xodr_path = Path(tmp) / "map.xodr"
        osm_path.write_text(osm_xml, encoding="utf-8")
        request: dict[str, object] = {
            "osm_path": str(osm_path),
            "xodr_path": str(xodr_path),
            "proj_string": proj_string,
            "lane_width_m": options.lane_width_m,
            "traffic_lights": options.traffic_lights,
            "all_junctions_traffic_lights": False,
            "road_types": list(options.road_types),
        }
        _run_worker(request, options.timeout_s)
        xodr = xodr_path.read_text(encoding="utf-8")
    _check_georeference(xodr, proj_string)
    if options.sidewalks == "parking":
        xodr = _SIDEWALK_LANE.sub(r'\1"parking"', xodr)
    return xodr
