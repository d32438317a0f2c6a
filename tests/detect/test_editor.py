"""The parked-vehicle editor: its JSON API over HTTP, and the page in headless Chromium."""

from __future__ import annotations

import _thread
import http.client
import json
import math
import re
import signal
import threading
import urllib.error
import urllib.request
from pathlib import Path
from typing import TYPE_CHECKING, Any

import pytest
from editor_fixtures import VEHICLES, make_workspace

from cam2sim.core.config import Config
from cam2sim.core.errors import ConfigError, WorkspaceError
from cam2sim.core.workspace import Workspace
from cam2sim.detect.editor import EditorServer, serve_editor
from cam2sim.detect.vehicles import ParkedVehicles, parked_vehicles_path
from conftest import launch_chromium, playwright_with_chromium

if TYPE_CHECKING:
    from collections.abc import Iterator

    from playwright.sync_api import Dialog, Page

JSON = Any  # decoded JSON of the editor's API

EMPTY_SAVE = '{"vehicles": []}'


@pytest.fixture
def ws(tmp_path: Path) -> Workspace:
    return make_workspace(tmp_path / "ws")


@pytest.fixture
def server(ws: Workspace) -> Iterator[EditorServer]:
    with EditorServer(ws) as srv:
        srv.start()
        yield srv


def _request(url: str, *, body: object = None) -> tuple[int, JSON]:
    data = None if body is None else json.dumps(body).encode()
    req = urllib.request.Request(url, data=data)
    if data is not None:
        req.add_header("Content-Type", "application/json")
    try:
        with urllib.request.urlopen(req, timeout=30) as resp:
            return resp.status, json.loads(resp.read())
    except urllib.error.HTTPError as err:
        with err:
            return err.code, json.loads(err.read())


def _raw(
    server: EditorServer,
    method: str,
    path: str,
    *,
    body: str | None = None,
    headers: dict[str, str] | None = None,
) -> int:
    """Send a request whose target and Host go out verbatim (urllib normalises ``..``)."""
    headers = {"Host": f"127.0.0.1:{server.port}"} | (headers or {})
    if body is not None:
        headers |= {"Content-Type": "application/json", "Content-Length": str(len(body))}
    conn = http.client.HTTPConnection("127.0.0.1", server.port, timeout=30)
    try:
        conn.putrequest(method, path, skip_host=True, skip_accept_encoding=True)
        for key, value in headers.items():
            conn.putheader(key, value)
        conn.endheaders(None if body is None else body.encode())
        resp = conn.getresponse()
        resp.read()
        return resp.status
    finally:
        conn.close()


def _scene(server: EditorServer) -> JSON:
    status, scene = _request(server.url + "api/scene")
    assert status == 200
    return scene


def _history(ws: Workspace) -> list[Path]:
    return sorted((ws.detections_dir / "history").glob("parked_vehicles.*.json"))


# -- API ---------------------------------------------------------------------------------------
def test_scene_holds_route_lanes_lidar_overview_and_vehicles(server: EditorServer) -> None:
    scene = _scene(server)
    route = scene["route"]
    assert isinstance(route, list)
    assert 70 <= len(route) <= 90  # 80 m at about one point per metre
    assert route[0] == [0.0, -1.75, 0.0]
    assert route[-1] == [80.0, -1.75, 0.0]
    lanes = scene["lanes"]
    assert isinstance(lanes, list)
    kinds = sorted((lane["type"], lane["kind"]) for lane in lanes)
    assert kinds == [
        ("driving", "drivable"),
        ("driving", "drivable"),
        ("parking", "parking"),
        ("parking", "parking"),
        ("sidewalk", "sidewalk"),
        ("sidewalk", "sidewalk"),
    ]
    parking = [lane for lane in lanes if lane["type"] == "parking"]
    ys = sorted(min(p[1] for p in lane["rings"][0]) for lane in parking)
    assert ys == pytest.approx([-6.0, 3.5])  # right lane from -6 to -3.5, left from 3.5 to 6
    bev = scene["bev"]
    assert isinstance(bev, dict)
    assert bev["url"] == "/bev.png"
    assert bev["x_min"] <= -20.0
    assert bev["x_max"] >= 100.0
    assert [v["id"] for v in scene["vehicles"]] == [v.id for v in VEHICLES]
    assert scene["exists"] is True
    with urllib.request.urlopen(server.url + "bev.png", timeout=30) as resp:
        assert resp.headers["Content-Type"] == "image/png"
        assert resp.read().startswith(b"\x89PNG")
    with urllib.request.urlopen(server.url, timeout=30) as resp:
        page = resp.read().decode()
    assert 'data-testid="map-canvas"' in page
    assert "/editor.js" in page


def test_save_assigns_ids_recomputes_side_and_keeps_the_previous_version(
    server: EditorServer, ws: Workspace
) -> None:
    path = parked_vehicles_path(ws.detections_dir)
    before = path.read_bytes()
    scene = _scene(server)
    vehicles = scene["vehicles"]
    assert isinstance(vehicles, list)
    moved = dict(vehicles[0], position=[15.0, 4.75, 0.0], yaw=math.pi / 2 + 2 * math.pi)
    untouched = vehicles[1]
    silently_moved = dict(vehicles[2], position=[46.0, 4.75, 0.0])  # edited stays false
    new = {"id": "new_1", "position": [70.0, -4.6, 0.0], "yaw": 0.0, "size": [4.5, 1.8, 1.5]}
    body = {"vehicles": [moved, untouched, silently_moved, new], "revision": scene["revision"]}
    status, reply = _request(server.url + "api/save", body=body)
    assert status == 200, reply
    assert isinstance(reply, dict)
    assert reply["id_map"] == {"new_1": "pv_005"}
    saved = ParkedVehicles.load(path)
    assert [v.id for v in saved.vehicles] == ["pv_001", "pv_002", "pv_003", "pv_005"]
    first, second, third, inserted = saved.vehicles
    assert (first.edited, first.side, first.orientation) == (True, "left", "perpendicular")
    assert first.yaw == pytest.approx(math.pi / 2)
    assert second == VEHICLES[1]
    assert third.edited
    assert third.position == (46.0, 4.75, 0.0)
    assert (inserted.source, inserted.edited, inserted.side) == ("manual", True, "right")
    assert inserted.confidence == 1.0
    assert saved.source == "lidar"  # the header is kept
    assert saved.min_hits == 2
    history = _history(ws)
    assert len(history) == 1
    assert history[0].read_bytes() == before
    assert reply["history"] == history[0].relative_to(ws.root).as_posix()
    assert _scene(server)["revision"] == reply["revision"]


def test_every_save_keeps_one_more_history_file(server: EditorServer, ws: Workspace) -> None:
    path = parked_vehicles_path(ws.detections_dir)
    versions = []
    for n in (3, 2, 1):
        versions.append(path.read_bytes())
        status, _ = _request(
            server.url + "api/save", body={"vehicles": _scene(server)["vehicles"][:n]}
        )
        assert status == 200
    assert [p.read_bytes() for p in _history(ws)] == versions
    assert len(ParkedVehicles.load(path).vehicles) == 1


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"size": [4.5, -1.0, 1.5]}, r"vehicles\[1\] \(id 'pv_002'\): size"),
        ({"yaw": "north"}, r"vehicles\[1\] \(id 'pv_002'\): yaw"),
        ({"colour": "red"}, r"vehicles\[1\] \(id 'pv_002'\): colour"),
        ({"id": "pv_001"}, r"repeated: pv_001"),
    ],
)
def test_malformed_edit_is_refused_and_nothing_is_written(
    server: EditorServer, ws: Workspace, change: dict[str, object], message: str
) -> None:
    path = parked_vehicles_path(ws.detections_dir)
    before = path.read_bytes()
    vehicles = _scene(server)["vehicles"]
    assert isinstance(vehicles, list)
    vehicles[1] = dict(vehicles[1], **change)
    status, reply = _request(server.url + "api/save", body={"vehicles": vehicles})
    assert status == 400
    assert isinstance(reply, dict)
    assert re.search(message, reply["error"]), reply["error"]
    assert path.read_bytes() == before
    assert _history(ws) == []


def test_save_after_the_file_changed_on_disk_is_a_conflict(
    server: EditorServer, ws: Workspace
) -> None:
    scene = _scene(server)
    path = parked_vehicles_path(ws.detections_dir)
    ParkedVehicles.load(path).model_copy(update={"vehicles": VEHICLES[:1]}).save(path)
    changed = path.read_bytes()
    body = {"vehicles": scene["vehicles"], "revision": scene["revision"]}
    status, reply = _request(server.url + "api/save", body=body)
    assert status == 409
    assert "reload" in reply["error"]
    assert path.read_bytes() == changed


@pytest.mark.parametrize(
    ("method", "path", "body"),
    [
        ("GET", "/../workspace.json", None),
        ("GET", "/%2e%2e/%2e%2e/etc/passwd", None),
        ("GET", "//etc/passwd", None),
        ("POST", "/api/save?file=../../outside.json", EMPTY_SAVE),
        ("POST", "/api/save", '{"vehicles": [], "path": "/tmp/outside.json"}'),
        ("POST", "/api/save", '{"vehicles": [{"id": "x", "file": "../x.json"}]}'),
    ],
)
def test_requests_naming_a_path_are_forbidden(
    server: EditorServer, ws: Workspace, method: str, path: str, body: str | None
) -> None:
    before = parked_vehicles_path(ws.detections_dir).read_bytes()
    assert _raw(server, method, path, body=body) == 403
    assert parked_vehicles_path(ws.detections_dir).read_bytes() == before
    assert _history(ws) == []


@pytest.mark.parametrize(
    "headers",
    [
        {"Host": "evil.example"},
        {"Host": "evil.example:80"},
        {"Host": "127.0.0.1:1"},
        {"Origin": "http://evil.example"},
        {"Origin": "null"},
        {"Sec-Fetch-Site": "cross-site"},
    ],
)
def test_foreign_host_or_origin_is_forbidden(
    server: EditorServer, ws: Workspace, headers: dict[str, str]
) -> None:
    for method, path, body in (("GET", "/api/scene", None), ("POST", "/api/save", EMPTY_SAVE)):
        assert _raw(server, method, path, body=body, headers=headers) == 403, (method, headers)
    assert len(ParkedVehicles.load(parked_vehicles_path(ws.detections_dir)).vehicles) == 4


def test_localhost_and_same_origin_are_accepted(server: EditorServer) -> None:
    local = {"Host": f"localhost:{server.port}", "Origin": f"http://localhost:{server.port}"}
    assert _raw(server, "GET", "/api/scene", headers=local) == 200
    assert _raw(server, "POST", "/api/save", body=EMPTY_SAVE, headers=local) == 200
    assert _raw(server, "POST", "/api/save", body="[", headers=local) == 400


def test_editor_starts_from_an_empty_list_without_a_vehicle_file(tmp_path: Path) -> None:
    ws = make_workspace(tmp_path / "ws", lidar=False, road_map=False, vehicles=None)
    with EditorServer(ws) as srv:
        srv.start()
        scene = _scene(srv)
        assert (scene["exists"], scene["vehicles"], scene["bev"], scene["lanes"]) == (
            False,
            [],
            None,
            [],
        )
        new = {"id": "new_1", "position": [10.0, 3.0, 0.0], "yaw": 0.1, "size": [4.5, 1.8, 1.5]}
        status, _ = _request(srv.url + "api/save", body={"vehicles": [new]})
        assert status == 200
    saved = ParkedVehicles.load(parked_vehicles_path(ws.detections_dir))
    assert (saved.source, saved.detector) == ("manual", "manual")
    assert [(v.id, v.side, v.source) for v in saved.vehicles] == [("pv_001", "left", "manual")]
    assert _history(ws) == []


def test_editor_without_a_dataset_says_to_extract_first(tmp_path: Path) -> None:
    ws = Workspace.create(tmp_path / "ws", Config())
    with pytest.raises(WorkspaceError, match="cam2sim extract"):
        EditorServer(ws)


@pytest.mark.parametrize(("host", "port"), [("0.0.0.0", 0), ("192.168.1.2", 0), ("::", 0)])
def test_editor_refuses_to_listen_beyond_this_machine(ws: Workspace, host: str, port: int) -> None:
    with pytest.raises(ConfigError, match="127.0.0.1 or localhost"):
        EditorServer(ws, host=host, port=port)


@pytest.fixture
def ctrl_c_raises() -> Iterator[None]:
    """Python's own Ctrl-C handler for the test: a background shell starts jobs with SIGINT
    ignored, and then ``interrupt_main()`` does nothing and the server never stops."""
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    yield
    signal.signal(signal.SIGINT, previous)


@pytest.mark.usefixtures("ctrl_c_raises")
def test_serve_editor_blocks_until_ctrl_c(ws: Workspace) -> None:
    urls: list[str] = []
    scenes: list[object] = []

    def fetch_then_interrupt(url: str) -> None:
        scenes.append(_request(url + "api/scene")[0])
        _thread.interrupt_main()

    def on_ready(url: str) -> None:
        urls.append(url)
        threading.Thread(target=fetch_then_interrupt, args=(url,)).start()

    serve_editor(ws, on_ready=on_ready)
    assert scenes == [200]
    assert urls[0].startswith("http://127.0.0.1:")


# -- the page ----------------------------------------------------------------------------------
def _at(page: Page, x: float, y: float) -> tuple[float, float]:
    """Viewport pixels of world point ``(x, y)``."""
    p = page.evaluate("([x, y]) => window.editor.worldToScreen(x, y)", [x, y])
    return p["x"], p["y"]


def _drag(page: Page, start: tuple[float, float], end: tuple[float, float]) -> None:
    page.mouse.move(*start)
    page.mouse.down()
    page.mouse.move(*end, steps=6)
    page.mouse.up()


def _vehicles(page: Page) -> dict[str, JSON]:
    return {v["id"]: v for v in page.evaluate("window.editor.vehicles()")}


def _edit_on_the_page(page: Page) -> None:
    """Move pv_001, rotate pv_002, insert one, delete pv_004, undo a stray drag, save."""
    assert page.get_by_test_id("vehicle-count").inner_text() == "4"
    _drag(page, _at(page, 15.0, -4.75), _at(page, 18.0, -4.25))  # move by (+3, +0.5) m
    assert page.evaluate("window.editor.selectedId()") == "pv_001"
    page.mouse.click(*_at(page, 30.0, -4.75))
    handle = page.evaluate("window.editor.rotateHandle()")
    _drag(page, (handle["x"], handle["y"]), _at(page, 30.0, 5.0))  # handle points north
    page.keyboard.press("q")  # and 5 degrees more
    page.get_by_test_id("btn-insert").click()
    page.mouse.click(*_at(page, 52.0, 4.6))
    assert page.evaluate("window.editor.selectedId()") == "new_1"
    page.mouse.click(*_at(page, 60.0, -4.75))
    page.keyboard.press("Delete")
    _drag(page, _at(page, 45.0, 4.75), _at(page, 40.0, 0.0))  # a stray drag of pv_003 ...
    assert _vehicles(page)["pv_003"]["edited"] is True
    page.keyboard.press("Control+z")  # ... undone
    assert _vehicles(page)["pv_003"]["position"] == [45.0, 4.75, 0.0]
    assert page.get_by_test_id("vehicle-count").inner_text() == "4"
    assert page.get_by_test_id("dirty").is_visible()
    page.keyboard.press("Control+s")
    page.wait_for_selector("#status[data-state=saved]", timeout=15_000)
    assert not page.get_by_test_id("dirty").is_visible()
    assert sorted(_vehicles(page)) == ["pv_001", "pv_002", "pv_003", "pv_005"]


def _failed_save_and_leaving_warn(page: Page, path: Path) -> None:
    """A save refused by the server says so; leaving with unsaved edits asks first."""
    changed = path.read_bytes() + b"\n"  # the file changes on disk behind the editor
    path.write_bytes(changed)
    page.keyboard.press("e")
    page.get_by_test_id("btn-save").click()
    page.wait_for_selector("#status[data-state=error]", timeout=15_000)
    assert "reload" in page.get_by_test_id("status").inner_text()
    assert path.read_bytes() == changed
    dialogs: list[str] = []

    def dismiss(dialog: Dialog) -> None:
        dialogs.append(dialog.type)
        dialog.dismiss()

    page.on("dialog", dismiss)
    page.evaluate("location.reload()")
    page.wait_for_function("window.editor.isDirty()")  # dismissed: the page and edit stay
    assert dialogs == ["beforeunload"]


def test_page_moves_rotates_inserts_deletes_undoes_and_saves(
    server: EditorServer, ws: Workspace, tmp_path: Path
) -> None:
    sync_api = playwright_with_chromium()
    path = parked_vehicles_path(ws.detections_dir)
    before = path.read_bytes()
    with sync_api.sync_playwright() as pw:
        browser = launch_chromium(pw)
        try:
            page = browser.new_page(viewport={"width": 1280, "height": 800})
            errors: list[str] = []
            page.on("pageerror", lambda err: errors.append(str(err)))
            page.goto(server.url)
            page.wait_for_selector("body[data-ready=true]", timeout=15_000)
            _edit_on_the_page(page)
            page.screenshot(path=str(tmp_path / "editor.png"))
            saved = {v.id: v for v in ParkedVehicles.load(path).vehicles}
            _failed_save_and_leaving_warn(page, path)
            assert errors == []
        finally:
            browser.close()

    assert sorted(saved) == ["pv_001", "pv_002", "pv_003", "pv_005"]
    first = saved["pv_001"]
    assert first.position[:2] == pytest.approx((18.0, -4.25), abs=0.15)
    assert (first.edited, first.side, first.yaw) == (True, "right", 0.0)
    second = saved["pv_002"]
    assert second.yaw == pytest.approx(math.radians(95.0), abs=0.03)
    assert (second.edited, second.orientation) == (True, "perpendicular")
    assert second.position == VEHICLES[1].position
    assert saved["pv_003"] == VEHICLES[2]
    new = saved["pv_005"]
    assert new.position[:2] == pytest.approx((52.0, 4.6), abs=0.15)
    assert new.yaw == pytest.approx(0.0, abs=1e-6)
    assert new.size == (4.5, 1.8, 1.5)
    assert (new.source, new.edited, new.side, new.orientation) == (
        "manual",
        True,
        "left",
        "parallel",
    )
    history = _history(ws)
    assert len(history) == 1
    assert history[0].read_bytes() == before
