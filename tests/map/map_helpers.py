"""Helpers of the map tests: real OSM extracts, workspaces on real streets, a fake Overpass."""

from __future__ import annotations

import datetime as dt
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import pytest

from cam2sim.core.config import Config
from cam2sim.core.dataset import POSE_PRECISION, TRAJECTORY_COLUMNS
from cam2sim.core.frames.projection import WorldFrame
from cam2sim.core.table import write_table
from cam2sim.core.workspace import Workspace, WorldFrameRecord, dataset_paths
from cam2sim.map.convert import has_carla

if TYPE_CHECKING:
    from cam2sim.map.osm import OsmData

OSM_DIR = Path(__file__).resolve().parents[2].parent / "shared" / "data" / "osm"
MUNICH = OSM_DIR / "munich.osm"
# Straßbergerstraße: a two-way residential street of munich.osm (11 nodes, 445 m).
ROUTE_WAY = 19722634
LANE_WIDTH = 3.35

requires_carla = pytest.mark.skipif(
    not has_carla(), reason="needs carla (pip install cam2sim[map])"
)


def osm_file(name: str) -> Path:
    """A real OSM extract; skips the test when shared data is absent."""
    path = OSM_DIR / name
    if not path.is_file():
        pytest.skip(f"real OSM data not found at {path}")
    if name.endswith(".pbf"):
        pytest.importorskip("osmium", reason="reading .pbf needs pyosmium (cam2sim[map])")
    return path


@dataclass(frozen=True)
class Route:
    """A drive along a real street, in the world frame."""

    frame: WorldFrame
    xy: np.ndarray
    t: np.ndarray
    heading: np.ndarray


def route_along_way(osm: OsmData, way_id: int, *, right_offset: float = LANE_WIDTH / 2) -> Route:
    """Drive along an OSM way at 10 m/s, 1 m apart, ``right_offset`` right of its centre line.

    The world frame's origin is the way's first node.
    """
    way = next(w for w in osm.ways if w.id == way_id)
    lat, lon = osm.way_coords(way)
    frame = WorldFrame(float(lat[0]), float(lon[0]))
    xy = frame.from_wgs84(lat, lon)[:, :2]
    seg = np.hypot(*np.diff(xy, axis=0).T)
    s = np.concatenate([[0.0], np.cumsum(seg)])
    si = np.arange(0.0, s[-1], 1.0)
    pts = np.stack([np.interp(si, s, xy[:, 0]), np.interp(si, s, xy[:, 1])], axis=-1)
    d = np.gradient(pts, axis=0)
    heading = np.arctan2(d[:, 1], d[:, 0])
    right = np.stack([np.sin(heading), -np.cos(heading)], axis=-1)
    return Route(frame, pts + right_offset * right, si / 10.0, heading)


def make_workspace(root: Path, route: Route) -> Workspace:
    """A workspace with a geo-referenced world frame and ``dataset/trajectory.csv``."""
    ws = Workspace.create(root, Config())
    frame = route.frame
    ws.record_stage(
        "extract",
        state="done",
        started=dt.datetime.now(dt.UTC),
        world=WorldFrameRecord(
            proj_string=frame.proj_string,
            origin_lat_deg=frame.origin_lat_deg,
            origin_lon_deg=frame.origin_lon_deg,
            origin_alt_m=frame.origin_alt_m,
            source_crs="EPSG:4326",
        ),
    )
    n = route.xy.shape[0]
    half = route.heading / 2
    columns = {
        "stamp_ns": (route.t * 1e9).astype(np.int64) + 1_700_000_000_000_000_000,
        "t": route.t,
        "x": route.xy[:, 0],
        "y": route.xy[:, 1],
        "z": np.zeros(n),
        "qx": np.zeros(n),
        "qy": np.zeros(n),
        "qz": np.sin(half),
        "qw": np.cos(half),
        "heading": route.heading,
        "speed": np.full(n, 10.0),
    }
    assert tuple(columns) == TRAJECTORY_COLUMNS
    write_table(dataset_paths(ws.dataset_dir).trajectory_csv, columns, precision=POSE_PRECISION)
    return ws


class FakeOverpass:
    """A local HTTP server standing in for the Overpass API (127.0.0.1 only).

    ``answers`` is a list of ``(status, body)`` served in order; the last one repeats.
    ``requests`` collects the form data of every POST.
    """

    def __init__(self, answers: list[tuple[int, bytes]]) -> None:
        import http.server
        import threading
        import urllib.parse

        self.answers = list(answers)
        self.requests: list[dict[str, list[str]]] = []
        fake = self

        class Handler(http.server.BaseHTTPRequestHandler):
            def do_POST(self) -> None:
                length = int(self.headers.get("Content-Length", "0"))
                body = self.rfile.read(length).decode()
                fake.requests.append(urllib.parse.parse_qs(body))
                status, data = fake.answers[0] if len(fake.answers) == 1 else fake.answers.pop(0)
                self.send_response(status)
                self.send_header("Content-Type", "application/osm3s+xml")
                self.send_header("Content-Length", str(len(data)))
                self.end_headers()
                self.wfile.write(data)

            def log_message(self, format: str, *args: object) -> None:  # noqa: A002
                del format, args

        self.server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self.thread = threading.Thread(
            target=self.server.serve_forever, kwargs={"poll_interval": 0.02}, daemon=True
        )
        self.thread.start()

    @property
    def url(self) -> str:
        host, port = self.server.server_address[:2]
        return f"http://{host}:{port}/api/interpreter"

    def close(self) -> None:
        self.server.shutdown()
        self.server.server_close()
        self.thread.join(timeout=5)


def closed_port_url() -> str:
    """A loopback URL where nothing listens (connection refused)."""
    import socket

    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        port = sock.getsockname()[1]
    return f"http://127.0.0.1:{port}/api/interpreter"
