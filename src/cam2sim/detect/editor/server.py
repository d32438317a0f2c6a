"""The parked-vehicle editor's local web server (``cam2sim refine WS``).

A stdlib :class:`~http.server.ThreadingHTTPServer` bound to ``127.0.0.1`` serves one page
(``static/``) and a small JSON API:

- ``GET /``: the editor page (``/editor.js`` and ``/editor.css`` beside it);
- ``GET /api/scene``: route polyline, map lanes by type, the LiDAR overview's URL and extent, and
  the vehicles of ``WS/detections/parked_vehicles.json`` (an empty list when it does not exist);
- ``GET /bev.png``: the LiDAR overview (:mod:`cam2sim.detect.bev`);
- ``POST /api/save``: ``{"vehicles": [...], "revision": "..."}``, the whole edited list; a
  ``revision`` (from the scene) that no longer matches the file on disk is refused with 409.

Saving validates every vehicle with :class:`~cam2sim.detect.vehicles.ParkedVehicle` (HTTP 400
naming the element, nothing written). A posted vehicle whose ``id`` is not in the file is new: it
gets a fresh ``pv_NNN`` id (the reply maps the page's temporary id to it), ``source="manual"``
and ``edited=True``. A known vehicle whose geometry changed is marked ``edited`` too, and the
``side`` and ``orientation`` of every edited vehicle are recomputed from the route. The previous
file is copied to ``WS/detections/history/parked_vehicles.<UTC time>.json`` before the new one
replaces it atomically, so no saved version is ever lost.

Besides that file and its history, the server writes only the LiDAR overview cache
(``WS/detections/bev.png`` and ``bev.json``) when it starts. Requests whose ``Host`` or
``Origin`` is not this server on ``127.0.0.1``/``localhost`` get 403 (DNS rebinding, cross-site
posts), and so do URLs or bodies naming a path (``..``, absolute paths, ``file``/``path`` fields).
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import logging
import math
import re
import socket
import socketserver
import threading
import warnings
from http import HTTPStatus
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from importlib import resources
from typing import TYPE_CHECKING
from urllib.parse import parse_qsl, unquote, urlsplit

import numpy as np
import pydantic

from cam2sim.core.errors import Cam2SimError, ConfigError, WorkspaceError
from cam2sim.core.files import process_lock
from cam2sim.core.polyline import resample_indices
from cam2sim.core.schema import format_validation_error
from cam2sim.core.table import read_table
from cam2sim.core.workspace import dataset_paths
from cam2sim.detect.bev import BEV_PNG, BevInfo, load_or_build_bev
from cam2sim.detect.route import Route
from cam2sim.detect.vehicles import (
    HISTORY_DIR,
    ParkedVehicle,
    ParkedVehicles,
    parked_vehicles_path,
    save_parked_vehicles,
)

if TYPE_CHECKING:
    from collections.abc import Callable
    from types import TracebackType
    from typing import Self

    import numpy.typing as npt

    from cam2sim.core.workspace import Workspace

__all__ = ["HISTORY_DIR", "EditorServer", "serve_editor"]

logger = logging.getLogger(__name__)

NEW_VEHICLE_SIZE_M = (4.5, 1.8, 1.5)
_LOCAL_HOSTS = ("127.0.0.1", "localhost")
_POLL_S = 0.1  # how soon serve_forever notices close()
_MAX_BODY_BYTES = 16 << 20
_ROUTE_SPACING_M = 1.0
_ROUTE_MAX_POINTS = 5000
_LANE_SIMPLIFY_M = 0.05
_STATIC = {
    "/": ("index.html", "text/html; charset=utf-8"),
    "/index.html": ("index.html", "text/html; charset=utf-8"),
    "/editor.js": ("editor.js", "text/javascript; charset=utf-8"),
    "/editor.css": ("editor.css", "text/css; charset=utf-8"),
}
_LANE_KINDS = {
    "driving": "drivable",
    "entry": "drivable",
    "exit": "drivable",
    "onRamp": "drivable",
    "offRamp": "drivable",
    "bidirectional": "drivable",
    "parking": "parking",
    "sidewalk": "sidewalk",
    "walking": "sidewalk",
    "shoulder": "shoulder",
    "biking": "biking",
}
_PATH_KEYS = frozenset({"file", "path", "filename", "dir", "folder"})
_ID_NUMBER = re.compile(r"^pv_(\d+)$")


class _HttpError(Exception):
    """A request the editor answers with ``status`` and a JSON ``{"error": message}``."""

    def __init__(self, status: HTTPStatus, message: str) -> None:
        super().__init__(message)
        self.status = status
        self.message = message


# -- scene ---------------------------------------------------------------------------------------
def _route_xyz(ws: Workspace) -> npt.NDArray[np.float64]:
    """The driven positions ``(N, 3)``, world frame, from ``trajectory.csv`` or ``poses.csv``."""
    paths = dataset_paths(ws.dataset_dir)
    if not paths.dataset_json.is_file():
        msg = (
            f"{ws.root} has no dataset ({paths.dataset_json} is missing); run "
            f"`cam2sim extract {ws.root}` (or `cam2sim import`) before editing parked vehicles"
        )
        raise WorkspaceError(msg)
    for table in (paths.trajectory_csv, paths.poses_csv):
        if table.is_file():
            cols = read_table(table)
            xyz = np.column_stack([cols["x"], cols["y"], cols["z"]]).astype(np.float64)
            xyz = xyz[np.isfinite(xyz).all(axis=1)]
            if len(xyz) >= 2:
                return xyz
    msg = (
        f"{paths.root} holds no ego poses (trajectory.csv or poses.csv with two or more rows); "
        "the editor places vehicles along the driven route, so extract a dataset with poses"
    )
    raise WorkspaceError(msg)


def _route_polyline(xyz: npt.NDArray[np.float64]) -> list[list[float]]:
    """The route downsampled to about one point per metre (at most 5000 points), rounded."""
    spacing = _ROUTE_SPACING_M
    idx = resample_indices(xyz[:, :2], spacing)
    while len(idx) > _ROUTE_MAX_POINTS:
        spacing *= 2.0
        idx = resample_indices(xyz[:, :2], spacing)
    rounded: list[list[float]] = np.round(xyz[idx], 3).tolist()
    return rounded


def _lanes(ws: Workspace) -> list[dict[str, object]]:
    """The map's lane outlines by type, simplified; empty without ``WS/map/map.xodr``."""
    import shapely  # noqa: PLC0415

    from cam2sim.map.query import RoadMap  # noqa: PLC0415 -- lazy: imports shapely

    if not ws.map_xodr_path.is_file():
        return []
    try:
        road_map = RoadMap.from_xodr(ws.map_xodr_path)
    except Cam2SimError as err:
        msg = f"{err}; the editor shows no lanes. Rebuild the map with `cam2sim map {ws.root}`"
        warnings.warn(msg, stacklevel=3)
        return []
    polys = shapely.simplify(road_map.lane_polygons(), _LANE_SIMPLIFY_M)
    out: list[dict[str, object]] = []
    for lane, poly in zip(road_map.lanes, polys, strict=True):
        rings = [
            np.round(shapely.get_coordinates(shapely.get_exterior_ring(part)), 2).tolist()
            for part in shapely.get_parts(poly)
            if isinstance(part, shapely.Polygon) and not part.is_empty
        ]
        if rings:
            kind = _LANE_KINDS.get(lane.type, "other")
            out.append({"type": lane.type, "kind": kind, "rings": rings})
    return out


def _revision(data: bytes | None) -> str:
    return "none" if data is None else hashlib.sha256(data).hexdigest()[:16]


# -- edits ---------------------------------------------------------------------------------------
def _refuse_paths(obj: dict[str, object], where: str) -> None:
    named = sorted(_PATH_KEYS & set(obj))
    if named:
        msg = (
            f"{where} names a file ({', '.join(named)}); the editor writes only "
            "WS/detections/parked_vehicles.json and takes no paths"
        )
        raise _HttpError(HTTPStatus.FORBIDDEN, msg)


def _wrap_yaw(data: dict[str, object]) -> None:
    yaw = data.get("yaw")
    if isinstance(yaw, int | float) and not isinstance(yaw, bool) and math.isfinite(yaw):
        data["yaw"] = math.atan2(math.sin(yaw), math.cos(yaw))


class _IdMaker:
    """Fresh ``pv_NNN`` ids above every numbered id in use."""

    def __init__(self, used: set[str]) -> None:
        self.used = set(used)
        numbers = [int(m.group(1)) for u in used if (m := _ID_NUMBER.match(u))]
        self.next = max(numbers, default=0) + 1

    def __call__(self) -> str:
        while (vid := f"pv_{self.next:03d}") in self.used:
            self.next += 1
        self.used.add(vid)
        return vid


def _merge_edits(
    items: list[object], known: dict[str, ParkedVehicle], route: Route
) -> tuple[list[ParkedVehicle], dict[str, str]]:
    """Validate the posted vehicles; give new ones ids and recompute side/orientation of edits.

    Returns:
        The vehicles to save, and the new id of each posted vehicle that was not known.
    """
    posted_ids = {i.get("id") for i in items if isinstance(i, dict)}
    make_id = _IdMaker(set(known) | {v for v in posted_ids if isinstance(v, str)})
    out: list[ParkedVehicle] = []
    id_map: dict[str, str] = {}
    for i, item in enumerate(items):
        if not isinstance(item, dict):
            msg = f"vehicles[{i}] is {type(item).__name__}, not an object"
            raise _HttpError(HTTPStatus.BAD_REQUEST, msg)
        _refuse_paths(item, f"vehicles[{i}]")
        data: dict[str, object] = dict(item)
        vid = data.get("id")
        if not (isinstance(vid, str) and vid in known):
            new_id = make_id()
            if isinstance(vid, str) and vid:
                id_map[vid] = new_id
            data |= {"id": new_id, "source": "manual", "edited": True}
            for key, value in (("confidence", 1.0), ("hits", 0), ("side", "right")):
                data.setdefault(key, value)
            data.setdefault("orientation", "parallel")
        _wrap_yaw(data)
        try:
            vehicle = ParkedVehicle.model_validate(data)
        except pydantic.ValidationError as err:
            where = f"vehicles[{i}] (id {vid!r})"
            raise _HttpError(
                HTTPStatus.BAD_REQUEST, format_validation_error(err, source=where)
            ) from None
        old = known.get(vehicle.id)
        if old is not None and not vehicle.edited and _moved(vehicle, old):
            vehicle = vehicle.model_copy(update={"edited": True})
        out.append(vehicle)
    edited = [i for i, v in enumerate(out) if v.edited]
    if edited:
        xy = np.array([out[i].position[:2] for i in edited], dtype=np.float64)
        yaw = np.array([out[i].yaw for i in edited], dtype=np.float64)
        sides, orients = route.side(xy), route.orientation(xy, yaw)
        for k, i in enumerate(edited):
            out[i] = out[i].model_copy(update={"side": sides[k], "orientation": orients[k]})
    return out, id_map


def _moved(new: ParkedVehicle, old: ParkedVehicle) -> bool:
    a = np.array([*new.position, new.yaw, *new.size])
    b = np.array([*old.position, old.yaw, *old.size])
    return not np.allclose(a, b, rtol=0.0, atol=1e-6)


class _Editor:
    """The editor's state: the workspace, its static layers and the save lock."""

    def __init__(self, ws: Workspace, *, bev_resolution_m: float) -> None:
        self.ws = ws
        self.path = parked_vehicles_path(ws.detections_dir)
        xyz = _route_xyz(ws)
        self.route = Route.from_xy(xyz[:, :2])
        self.route_polyline = _route_polyline(xyz)
        self.lanes = _lanes(ws)
        self.bev: BevInfo | None = load_or_build_bev(ws, resolution_m=bev_resolution_m)
        self.lock = threading.Lock()
        logger.info(
            "editor: route of %d points, %d lanes, LiDAR overview %s",
            len(self.route_polyline),
            len(self.lanes),
            "yes" if self.bev else "no",
        )

    def _read(self) -> tuple[ParkedVehicles | None, bytes | None]:
        try:
            data = self.path.read_bytes()
        except FileNotFoundError:
            return None, None
        return ParkedVehicles.load(self.path), data

    def scene(self) -> dict[str, object]:
        current, data = self._read()
        header = (
            current.model_dump(mode="json", exclude={"vehicles"}) if current is not None else None
        )
        bev = None
        if self.bev is not None:
            bev = {"url": "/" + BEV_PNG} | self.bev.model_dump(
                mode="json", include={"x_min", "y_min", "x_max", "y_max", "resolution_m"}
            )
        vehicles = [] if current is None else [v.model_dump(mode="json") for v in current.vehicles]
        return {
            "workspace": self.ws.root.name,
            "file": "detections/" + self.path.name,
            "exists": current is not None,
            "revision": _revision(data),
            "header": header,
            "route": self.route_polyline,
            "lanes": self.lanes,
            "bev": bev,
            "vehicles": vehicles,
            "defaults": {"size": list(NEW_VEHICLE_SIZE_M)},
        }

    def save(self, body: object) -> dict[str, object]:
        if not isinstance(body, dict):
            msg = 'the body must be a JSON object {"vehicles": [...]}'
            raise _HttpError(HTTPStatus.BAD_REQUEST, msg)
        _refuse_paths(body, "the request")
        unknown = sorted(set(body) - {"vehicles", "revision"})
        if unknown:
            msg = f"unknown fields {unknown}; send only vehicles and revision"
            raise _HttpError(HTTPStatus.BAD_REQUEST, msg)
        items = body.get("vehicles")
        if not isinstance(items, list):
            msg = "vehicles must be a list of vehicle objects"
            raise _HttpError(HTTPStatus.BAD_REQUEST, msg)
        with self.lock:
            current, old = self._read()
            revision = body.get("revision")
            if revision is not None and revision != _revision(old):
                msg = (
                    f"{self.path.name} changed on disk since the editor loaded it; reload the "
                    "page (your edits would overwrite the new file)"
                )
                raise _HttpError(HTTPStatus.CONFLICT, msg)
            known = {v.id: v for v in current.vehicles} if current is not None else {}
            vehicles, id_map = _merge_edits(items, known, self.route)
            header = (
                current.model_dump(exclude={"vehicles", "schema_version"})
                if current is not None
                else {"source": "manual", "detector": "manual", "frames_used": 0}
                | {"detections": 0, "min_hits": 1}
            )
            try:
                artifact = ParkedVehicles.model_validate(header | {"vehicles": vehicles})
            except pydantic.ValidationError as err:
                msg = format_validation_error(err, source=self.path.name)
                raise _HttpError(HTTPStatus.BAD_REQUEST, msg) from None
            history = save_parked_vehicles(artifact, self.ws.detections_dir)
            data = self.path.read_bytes()
        logger.info("editor: saved %d vehicles to %s", len(vehicles), self.path)
        return {
            "saved": len(vehicles),
            "revision": _revision(data),
            "id_map": id_map,
            "history": None if history is None else history.relative_to(self.ws.root).as_posix(),
            "vehicles": [v.model_dump(mode="json") for v in artifact.vehicles],
        }


# -- HTTP ----------------------------------------------------------------------------------------
_Request = socket.socket | tuple[bytes, socket.socket]


class _HttpServer(ThreadingHTTPServer):
    """Threads per request; closes every open connection on :meth:`close_connections`."""

    daemon_threads = False
    block_on_close = True

    def __init__(self, port: int, editor: _Editor) -> None:
        self.editor = editor
        self._open: set[socket.socket] = set()
        self._open_lock = threading.Lock()
        super().__init__(("127.0.0.1", port), _Handler)

    def server_bind(self) -> None:
        """Bind without the reverse DNS lookup of :class:`~http.server.HTTPServer`."""
        socketserver.TCPServer.server_bind(self)
        self.server_name = "127.0.0.1"
        self.server_port = int(self.server_address[1])

    def process_request(self, request: _Request, client_address: object) -> None:
        if isinstance(request, socket.socket):
            with self._open_lock:
                self._open.add(request)
        super().process_request(request, client_address)

    def shutdown_request(self, request: _Request) -> None:
        if isinstance(request, socket.socket):
            with self._open_lock:
                self._open.discard(request)
        super().shutdown_request(request)

    def close_connections(self) -> None:
        """Unblock handler threads still waiting on idle (pre-)connections."""
        with self._open_lock:
            pending = list(self._open)
        for sock in pending:
            with contextlib.suppress(OSError):
                sock.shutdown(socket.SHUT_RDWR)

    def handle_error(self, request: object, client_address: object) -> None:  # noqa: ARG002
        # socketserver calls this inside its except block: exc_info is the handler's error
        logger.debug("editor: connection from %s failed", client_address, exc_info=True)  # noqa: LOG014


class _Handler(BaseHTTPRequestHandler):
    server: _HttpServer
    timeout = 60
    server_version = "cam2sim-editor"

    def log_message(self, format: str, *args: object) -> None:  # noqa: A002 - stdlib name
        logger.debug("editor: " + format, *args)  # noqa: G003 - format comes from the stdlib

    # -- guards --------------------------------------------------------------------------
    def _local(self, value: str | None, *, with_scheme: bool) -> bool:
        if value is None:
            return False
        parts = urlsplit(value if with_scheme else f"//{value}")
        if with_scheme and parts.scheme != "http":
            return False
        try:
            port = parts.port
        except ValueError:
            return False
        return parts.hostname in _LOCAL_HOSTS and port == self.server.server_address[1]

    def _guard(self) -> str:
        """Check Host, Origin and the path; return the decoded path."""
        if not self._local(self.headers.get("Host"), with_scheme=False):
            msg = "the editor answers only requests to 127.0.0.1 or localhost on its own port"
            raise _HttpError(HTTPStatus.FORBIDDEN, msg)
        origin = self.headers.get("Origin")
        if origin is not None and not self._local(origin, with_scheme=True):
            msg = f"cross-origin request from {origin!r} refused; open the editor's own URL"
            raise _HttpError(HTTPStatus.FORBIDDEN, msg)
        if self.headers.get("Sec-Fetch-Site", "same-origin") not in {"same-origin", "none"}:
            msg = "cross-site request refused; open the editor's own URL"
            raise _HttpError(HTTPStatus.FORBIDDEN, msg)
        # the target as sent: http.server already folds a leading "//" of self.path into "/"
        words = self.requestline.split()
        target = words[1] if len(words) >= 2 else self.path
        parts = urlsplit(self.path)
        path = unquote(parts.path)
        values = [unquote(v) for _, v in parse_qsl(parts.query, keep_blank_values=True)]
        keys = {k for k, _ in parse_qsl(parts.query, keep_blank_values=True)}
        bad = (
            not target.startswith("/")
            or target.startswith("//")
            or path.startswith("//")
            or "\\" in path
            or "\x00" in path
            or ".." in path.split("/")
            or any(".." in v or v.startswith(("/", "\\")) for v in values)
            or bool(keys & _PATH_KEYS)
        )
        if bad:
            msg = f"{target!r} names a path outside the editor; it serves and writes no files"
            raise _HttpError(HTTPStatus.FORBIDDEN, msg)
        return path

    # -- responses -----------------------------------------------------------------------
    def _send(self, status: HTTPStatus, body: bytes, content_type: str) -> None:
        self.send_response(status)
        self.send_header("Content-Type", content_type)
        self.send_header("Content-Length", str(len(body)))
        self.send_header("Cache-Control", "no-store")
        self.send_header("X-Content-Type-Options", "nosniff")
        self.send_header("Referrer-Policy", "no-referrer")
        self.send_header(
            "Content-Security-Policy", "default-src 'self'; img-src 'self' data:; object-src 'none'"
        )
        self.end_headers()
        if self.command != "HEAD":
            self.wfile.write(body)

    def _send_json(self, status: HTTPStatus, payload: object) -> None:
        body = json.dumps(payload, separators=(",", ":"), allow_nan=False).encode()
        self._send(status, body, "application/json")

    def _dispatch(self, action: Callable[[str], None]) -> None:
        try:
            action(self._guard())
        except _HttpError as err:
            self._send_json(err.status, {"error": err.message})
        except Cam2SimError as err:
            logger.warning("editor: %s", err)
            self._send_json(HTTPStatus.INTERNAL_SERVER_ERROR, {"error": str(err)})
        except (ConnectionError, TimeoutError):
            logger.debug("editor: client went away", exc_info=True)
        except Exception:
            logger.exception("editor: internal error")
            msg = "internal error of the editor; see the terminal running `cam2sim refine`"
            self._send_json(HTTPStatus.INTERNAL_SERVER_ERROR, {"error": msg})

    def do_GET(self) -> None:
        """Serve the page, the scene and the LiDAR overview."""
        self._dispatch(self._get)

    def do_HEAD(self) -> None:
        """Like GET, without the body."""
        self._dispatch(self._get)

    def do_POST(self) -> None:
        """Save the edited vehicles."""
        self._dispatch(self._post)

    def _get(self, path: str) -> None:
        editor = self.server.editor
        if path in _STATIC:
            name, content_type = _STATIC[path]
            body = resources.files(__package__).joinpath("static", name).read_bytes()
            self._send(HTTPStatus.OK, body, content_type)
        elif path == "/api/scene":
            self._send_json(HTTPStatus.OK, editor.scene())
        elif path == "/" + BEV_PNG and editor.bev is not None:
            self._send(
                HTTPStatus.OK, (editor.ws.detections_dir / BEV_PNG).read_bytes(), "image/png"
            )
        else:
            raise _HttpError(HTTPStatus.NOT_FOUND, f"{path!r} not found")

    def _post(self, path: str) -> None:
        if path != "/api/save":
            raise _HttpError(HTTPStatus.NOT_FOUND, f"POST {path!r} not found; post to /api/save")
        if self.headers.get_content_type() != "application/json":
            msg = "send the vehicles as Content-Type: application/json"
            raise _HttpError(HTTPStatus.UNSUPPORTED_MEDIA_TYPE, msg)
        try:
            length = int(self.headers.get("Content-Length", ""))
        except ValueError:
            raise _HttpError(HTTPStatus.LENGTH_REQUIRED, "Content-Length is required") from None
        if not 0 <= length <= _MAX_BODY_BYTES:
            msg = f"body of {length} bytes refused; the limit is {_MAX_BODY_BYTES}"
            raise _HttpError(HTTPStatus.REQUEST_ENTITY_TOO_LARGE, msg)
        try:
            body = json.loads(self.rfile.read(length))
        except (json.JSONDecodeError, UnicodeDecodeError) as err:
            raise _HttpError(HTTPStatus.BAD_REQUEST, f"the body is not JSON: {err}") from None
        self._send_json(HTTPStatus.OK, self.server.editor.save(body))


class EditorServer:
    """The editor's web server for one workspace; a context manager.

    Args:
        ws: The workspace; it needs a dataset with ego poses. ``parked_vehicles.json`` may be
            missing: the editor then starts from an empty list.
        host: ``127.0.0.1`` or ``localhost``; the server always binds to ``127.0.0.1``.
        port: TCP port; 0 picks a free one (read it from :attr:`url`).
        bev_resolution_m: Cell size of the LiDAR overview, metres.

    Raises:
        ConfigError: ``host`` is not local or ``port`` is out of range.
        WorkspaceError: The workspace has no dataset with poses, or its vehicle file is malformed.
    """

    def __init__(
        self,
        ws: Workspace,
        *,
        host: str = "127.0.0.1",
        port: int = 0,
        bev_resolution_m: float = 0.2,
    ) -> None:
        if host not in _LOCAL_HOSTS:
            msg = (
                f"host {host!r} refused; the editor serves only this machine "
                "(127.0.0.1 or localhost). Forward the port with ssh -L to edit remotely"
            )
            raise ConfigError(msg)
        if not 0 <= port <= 65535:
            msg = f"port {port!r} is out of range; give 1-65535, or 0 for a free port"
            raise ConfigError(msg)
        editor = _Editor(ws, bev_resolution_m=bev_resolution_m)
        editor.scene()  # fail now, not in the browser, when parked_vehicles.json is malformed
        self._httpd = _HttpServer(port, editor)
        self._thread: threading.Thread | None = None
        self._serving = False
        self._closed = False

    @property
    def port(self) -> int:
        """The TCP port the server listens on."""
        return int(self._httpd.server_address[1])

    @property
    def url(self) -> str:
        """The editor page's URL, ``http://127.0.0.1:<port>/``."""
        return f"http://127.0.0.1:{self.port}/"

    def serve_forever(self) -> None:
        """Serve requests in this thread until :meth:`close` (from another thread) or Ctrl-C."""
        self._serving = True
        self._httpd.serve_forever(poll_interval=_POLL_S)

    def start(self) -> None:
        """Serve requests in a background thread."""
        if self._thread is not None:
            return
        self._serving = True
        self._thread = threading.Thread(
            target=self._httpd.serve_forever,
            kwargs={"poll_interval": _POLL_S},
            name="cam2sim-editor",
            daemon=True,
        )
        self._thread.start()

    def close(self) -> None:
        """Stop serving, close open connections and the socket; idempotent."""
        if self._closed:
            return
        self._closed = True
        if self._serving:
            self._httpd.shutdown()
        self._httpd.close_connections()
        self._httpd.server_close()
        if self._thread is not None:
            self._thread.join()

    def __enter__(self) -> Self:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()


def serve_editor(
    ws: Workspace,
    *,
    port: int = 0,
    open_browser: bool = False,
    on_ready: Callable[[str], None] | None = None,
) -> None:
    """Serve the parked-vehicle editor of ``ws`` on 127.0.0.1 until Ctrl-C.

    Args:
        ws: The workspace (see :class:`EditorServer`).
        port: TCP port; 0 picks a free one.
        open_browser: Open the page in the default browser once the server listens.
        on_ready: Called with the page's URL once the server listens (e.g. to print it).

    Raises:
        WorkspaceError: Another editor is open on ``ws``.
    """
    busy = (
        f"another cam2sim editor is open on {ws.root}; use that one (two would overwrite "
        "each other's edits) or stop it first"
    )
    with (
        process_lock(ws.detection_files.editor_lock, busy=busy),
        EditorServer(ws, port=port) as server,
    ):
        logger.info("editor: serving %s at %s", ws.root, server.url)
        if on_ready is not None:
            on_ready(server.url)
        if open_browser:
            import webbrowser  # noqa: PLC0415

            webbrowser.open(server.url)
        with contextlib.suppress(KeyboardInterrupt):
            server.serve_forever()
