"""Reading driven runs for evaluation: real drives, our runs, and the published tool's runs.

Every loader returns a :class:`DriveRun` whose positions are given in a named CRS (a pyproj
string), with the body reference point stated. :func:`runs_in_frame` then expresses a set of runs
in one local, true-metre frame (a transverse Mercator centred on the reference run), so that
distances carry no projection scale error.

Formats:
- real drives (reference CSV): ``trajectoryN.csv`` ``timestamp,x,y,z,yaw`` (UTM by default, yaw in
  the odometry convention) with ``steering_cmd_N.txt`` (preferred) or ``steering_N.txt``
  (``t, value`` lines, ``#`` comments);
- our run folders (``WS/runs/<id>/``): ``trajectory.csv`` (``t, x, y, z, heading, speed, steering,
  wheel_angle``), ``steering.csv`` (the policy's decisions ``t, value``), ``events.json``,
  ``run.json`` (method, proj string of the world frame);
- the published tool's simulated run JSON ``[{frame, x, y, z, yaw, steer_raw, ...}]`` in CARLA
  coordinates, georeferenced through its ``map.xodr`` (``<geoReference>`` and ``<offset>``).
"""

from __future__ import annotations

import json
import math
import re
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import numpy.typing as npt

from cam2sim.core.errors import WorkspaceError
from cam2sim.core.run_record import RunEvents, RunRecord
from cam2sim.core.schema import format_validation_error
from cam2sim.core.workspace import run_paths
from cam2sim.metrics.splat_gate import SplatPathQuality

if TYPE_CHECKING:
    from cam2sim.core import frames

__all__ = [
    "LEGACY_ACTOR_OFFSET_M",
    "DriveRun",
    "RunEvent",
    "load_legacy_run",
    "load_real_drive",
    "load_run_dir",
    "load_runs",
    "runs_in_frame",
    "xodr_projection",
]

#: The published tool's simulated positions are the CARLA actor centre, which its stage 3 puts
#: 1.393 m ahead of the odometry point and stage 5 moves back 0.13 m: 1.263 m ahead in all.
LEGACY_ACTOR_OFFSET_M = 1.263
_LEGACY_FPS = 30.0
_LEGACY_POLICY_STRIDE = 3


@dataclass(frozen=True)
class RunEvent:
    """Something that happened in a run (collision, off_road, route_completed, stuck, timeout)."""

    kind: str
    t: float
    reason: str = ""


@dataclass(frozen=True)
class DriveRun:
    """One driven run, real or simulated.

    Attributes:
        name: Unique label, e.g. ``real/trajectory1`` or ``splat/run3``.
        method: Group it belongs to (``real``, ``splat``, ``sim``, a legacy method name).
        real: Whether this is a real drive (a reference) or a simulated one.
        t: ``(N,)`` seconds.
        xy: ``(N, 2)`` positions of the vehicle reference point, metres, in ``crs``.
        crs: pyproj CRS of ``xy`` (e.g. ``EPSG:32632``, a ``+proj=tmerc`` string).
        steering_t: ``(K,)`` seconds of steering decisions (the model's commands).
        steering: ``(K,)`` steering values, in the model's own units.
        steering_dt: Fixed decision interval in seconds when decision times are not recorded
            (legacy runs), else None.
        events: Events recorded by the simulator (empty for real drives).
        source: File or folder it came from.
        splat_quality: The splat's quality along the run (``run.json``'s ``splat_quality``,
            runs with the splat camera); None for other runs and older run folders.
        seed: The drive's seed (``run.json``), None where unknown (recorded drives): runs of
            one seed start from the same drawn pose whatever their camera.
    """

    name: str
    method: str
    real: bool
    t: npt.NDArray[np.float64]
    xy: npt.NDArray[np.float64]
    crs: str | None
    steering_t: npt.NDArray[np.float64] = field(default_factory=lambda: np.zeros(0))
    steering: npt.NDArray[np.float64] = field(default_factory=lambda: np.zeros(0))
    steering_dt: float | None = None
    events: tuple[RunEvent, ...] = ()
    source: str = ""
    splat_quality: SplatPathQuality | None = None
    seed: int | None = None

    def __len__(self) -> int:
        return int(self.t.shape[0])


def _read_text_series(path: Path) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    rows = []
    for line in path.read_text(encoding="utf-8").splitlines():
        text = line.strip()
        if not text or text.startswith("#"):
            continue
        parts = [p for p in re.split(r"[,\s]+", text) if p]
        try:
            rows.append((float(parts[0]), float(parts[1])))
        except (IndexError, ValueError):
            msg = f"{path}: cannot read {line!r}; expected 't, value' lines"
            raise WorkspaceError(msg) from None
    arr = np.asarray(rows, dtype=np.float64).reshape(-1, 2)
    return arr[:, 0], arr[:, 1]


def _read_csv_columns(path: Path) -> dict[str, npt.NDArray[np.float64]]:
    try:
        lines = [ln for ln in path.read_text(encoding="utf-8").splitlines() if ln.strip()]
    except (OSError, UnicodeDecodeError) as err:
        msg = f"{path}: cannot read ({err})"
        raise WorkspaceError(msg) from None
    if not lines:
        msg = f"{path} is empty; expected a header line and rows"
        raise WorkspaceError(msg)
    names = [n.strip() for n in lines[0].lstrip("#").split(",")]
    try:
        data = np.array([[float(v) for v in ln.split(",")] for ln in lines[1:]], dtype=np.float64)
    except ValueError as err:
        msg = f"{path}: a value is not a number ({err})"
        raise WorkspaceError(msg) from None
    data = data.reshape(-1, len(names))
    return {n: data[:, i] for i, n in enumerate(names)}


def load_real_drive(path: Path, *, crs: str = "EPSG:32632", method: str = "real") -> DriveRun:
    """Load a real drive in the reference CSV format, with its steering commands if present."""
    path = Path(path)
    cols = _read_csv_columns(path)
    missing = [c for c in ("timestamp", "x", "y") if c not in cols]
    if missing:
        msg = f"{path}: missing column(s) {missing}; expected timestamp,x,y,z,yaw"
        raise WorkspaceError(msg)
    number = re.sub(r"\D", "", path.stem)
    steering_t = steering = np.zeros(0)
    for candidate in (f"steering_cmd_{number}.txt", f"steering_{number}.txt"):
        f = path.with_name(candidate)
        if number and f.is_file():
            steering_t, steering = _read_text_series(f)
            break
    return DriveRun(
        name=f"{method}/{path.stem}",
        method=method,
        real=True,
        t=cols["timestamp"],
        xy=np.stack([cols["x"], cols["y"]], -1),
        crs=crs,
        steering_t=steering_t,
        steering=steering,
        source=str(path),
    )


def load_run_dir(path: Path, *, method: str | None = None) -> DriveRun:
    """Load one of our run folders (``WS/runs/<id>/``).

    Raises:
        WorkspaceError: A file of the run is broken (the message names it and the fix).
        SchemaVersionError: A newer cam2sim wrote the run.
    """
    path = Path(path)
    files = run_paths(path)
    meta = RunRecord.load(files.run_json) if files.run_json.is_file() else RunRecord()
    cols = _read_csv_columns(files.trajectory_csv)
    steer_t = steer = np.zeros(0)
    if files.steering_csv.is_file():
        sc = _read_csv_columns(files.steering_csv)
        steer_t, steer = sc["t"], sc["value"]
    events: list[RunEvent] = []
    if files.events_json.is_file():
        events = [
            RunEvent(kind=e.kind, t=e.t, reason=e.reason)
            for e in RunEvents.load(files.events_json).events
        ]
    label = method or meta.label
    return DriveRun(
        name=f"{label}/{path.name}",
        method=label,
        real=False,
        t=cols["t"],
        xy=np.stack([cols["x"], cols["y"]], -1),
        crs=meta.proj_string,
        steering_t=steer_t,
        steering=steer,
        events=tuple(events),
        source=str(path),
        splat_quality=_splat_quality(path, meta),
        seed=meta.seed,
    )


def _splat_quality(path: Path, meta: RunRecord) -> SplatPathQuality | None:
    """``run.json``'s ``splat_quality`` block, if it has one."""
    import pydantic  # noqa: PLC0415

    if meta.splat_quality is None:
        return None
    try:
        return SplatPathQuality.model_validate(meta.splat_quality)
    except pydantic.ValidationError as err:
        msg = format_validation_error(err, source=f"{run_paths(path).run_json} splat_quality")
        raise WorkspaceError(msg) from None


def xodr_projection(xodr: Path) -> tuple[str, float, float]:
    """Return the ``<geoReference>`` proj string and the ``<offset>`` (x, y) of an OpenDRIVE map.

    A bare ``+proj=tmerc`` is expanded as CARLA does (centred on latitude 0, longitude 0).
    """
    try:
        root = ET.parse(xodr).getroot()  # noqa: S314 - a local file the user points at
    except (OSError, ET.ParseError) as err:
        msg = f"{xodr}: cannot read the OpenDRIVE map ({err})"
        raise WorkspaceError(msg) from None
    geo = root.find("header/geoReference")
    text = (geo.text or "").strip() if geo is not None else ""
    if not text:
        msg = f"{xodr}: no <geoReference> in the header; the map is not geo-referenced"
        raise WorkspaceError(msg)
    if text == "+proj=tmerc":
        text = "+proj=tmerc +lat_0=0 +lon_0=0 +k=1 +x_0=0 +y_0=0 +datum=WGS84"
    offset = root.find("header/offset")
    ox = float(offset.get("x", 0.0)) if offset is not None else 0.0
    oy = float(offset.get("y", 0.0)) if offset is not None else 0.0
    return text, ox, oy


def load_legacy_run(
    path: Path, *, xodr: Path, actor_offset_m: float = LEGACY_ACTOR_OFFSET_M
) -> DriveRun:
    """Load a published-tool simulated run (CARLA coordinates) back into true metres.

    CARLA (x, y) -> OpenDRIVE local (x, -y) -> projected (local - offset) in the map's
    ``<geoReference>`` projection. The CARLA actor centre is moved back ``actor_offset_m`` along
    the heading to the odometry point the real drives were recorded at. Steering is ``steer_raw``
    (else ``steering`` x 3 pi), one decision every third frame at 30 fps.
    """
    path = Path(path)
    try:
        rows = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, json.JSONDecodeError) as err:
        msg = f"{path}: cannot read the run JSON ({err})"
        raise WorkspaceError(msg) from None
    if not isinstance(rows, list) or not rows or not all("x" in r and "y" in r for r in rows):
        msg = f"{path}: expected a non-empty JSON list of {{frame, x, y, yaw, ...}} objects"
        raise WorkspaceError(msg)
    proj, ox, oy = xodr_projection(xodr)
    x = np.array([float(r["x"]) for r in rows])
    y = -np.array([float(r["y"]) for r in rows]) - oy
    x = x - ox
    yaw_carla = np.array([float(r.get("yaw", 0.0)) for r in rows])
    heading = -np.radians(yaw_carla)
    # Headings are on the map grid; the offset is a short vector, grid distortion is negligible.
    xy = np.stack([x, y], -1) - actor_offset_m * np.stack([np.cos(heading), np.sin(heading)], -1)
    frame = np.array([float(r.get("frame", i)) for i, r in enumerate(rows)])
    t = (frame - frame[0]) / _LEGACY_FPS
    if all("steer_raw" in r for r in rows):
        raw = np.array([float(r["steer_raw"]) for r in rows])
    elif all("steering" in r for r in rows):
        raw = np.array([float(r["steering"]) for r in rows]) * 3 * math.pi
    else:
        raw = np.zeros(0)
    steer_t = t[::_LEGACY_POLICY_STRIDE] if raw.size else np.zeros(0)
    match = re.match(r"^([A-Za-z][A-Za-z0-9_]*)_run(\d+)_trajectory$", path.stem)
    method = match.group(1) if match else "legacy"
    return DriveRun(
        name=f"{method}/{path.stem}",
        method=method,
        real=False,
        t=t,
        xy=xy,
        crs=proj,
        steering_t=steer_t,
        steering=raw[::_LEGACY_POLICY_STRIDE] if raw.size else raw,
        steering_dt=_LEGACY_POLICY_STRIDE / _LEGACY_FPS,
        source=str(path),
    )


def load_runs(
    paths: list[Path], *, real: bool, crs: str = "EPSG:32632", xodr: Path | None = None
) -> list[DriveRun]:
    """Load every run found in files or folders.

    Real: ``trajectory*.csv`` files (or folders holding them). Simulated: our run folders (with
    ``trajectory.csv``), folders of them, or published-tool ``*_trajectory.json`` files (these
    need ``xodr``).
    """
    runs: list[DriveRun] = []
    for p in map(Path, paths):
        if not p.exists():
            msg = f"{p} does not exist"
            raise WorkspaceError(msg)
        if real:
            files = sorted(p.glob("trajectory*.csv")) if p.is_dir() else [p]
            runs += [load_real_drive(f, crs=crs) for f in files]
        elif p.is_dir() and run_paths(p).trajectory_csv.is_file():
            runs.append(load_run_dir(p))
        elif p.is_dir():
            for sub in sorted(p.iterdir()):
                if run_paths(sub).trajectory_csv.is_file():
                    runs.append(load_run_dir(sub))
            for f in sorted(p.glob("*_trajectory.json")):
                runs.append(_legacy(f, xodr))
        else:
            runs.append(_legacy(p, xodr))
    if not runs:
        kind = "real trajectory*.csv" if real else "simulated run"
        msg = f"no {kind} found in {', '.join(map(str, paths))}"
        raise WorkspaceError(msg)
    return runs


def _legacy(path: Path, xodr: Path | None) -> DriveRun:
    if xodr is None:
        msg = f"{path} is a published-tool run in CARLA coordinates; pass --xodr map.xodr"
        raise WorkspaceError(msg)
    return load_legacy_run(path, xodr=xodr)


def runs_in_frame(runs: list[DriveRun], world: frames.WorldFrame) -> list[DriveRun]:
    """Express every run's positions in one local true-metre frame."""
    out = []
    for run in runs:
        if run.crs is None:
            out.append(run)
            continue
        xyz = np.column_stack([run.xy, np.zeros(len(run))])
        xy = world.from_crs(run.crs, xyz)[:, :2] if len(run) else run.xy
        out.append(replace(run, xy=xy, crs=world.proj_string))
    return out
