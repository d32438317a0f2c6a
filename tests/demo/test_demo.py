"""``cam2sim demo``: the synthetic recording, and the fast pipeline steps on it."""

from __future__ import annotations

from dataclasses import replace
from typing import TYPE_CHECKING

import numpy as np
import pytest

from cam2sim.demo.recording import DemoRecording, build_demo_recording, load_demo_recording
from cam2sim.demo.rig import TOPICS, demo_camera
from cam2sim.demo.world import L_STREET, demo_world
from cam2sim.map.convert import has_carla

if TYPE_CHECKING:
    from pathlib import Path

FAST = ("extract", "map", "detect", "scenario", "drive", "evaluate")


@pytest.fixture(scope="module")
def recording(tmp_path_factory: pytest.TempPathFactory) -> DemoRecording:
    return build_demo_recording(tmp_path_factory.mktemp("demo"))


def test_the_bag_has_every_topic_at_its_rate(recording: DemoRecording) -> None:
    from cam2sim.recording.summary import summarize_recording

    summary = summarize_recording([recording.bag])
    topics = {t.name: t for t in summary.topics}
    assert set(topics) == set(TOPICS.values())
    duration = recording.duration_s
    expected = {"camera": 20, "camera_info": 20, "pose": 50, "steering": 50, "lidar": 5}
    for key, hz in expected.items():
        t = topics[TOPICS[key]]
        assert abs(t.count - hz * duration) <= 2, (key, t.count)
        assert t.max_gap_s < 1.5 / hz
    assert topics[TOPICS["camera"]].msgtype == "sensor_msgs/msg/CompressedImage"
    assert topics[TOPICS["pose"]].msgtype == "nav_msgs/msg/Odometry"
    assert topics[TOPICS["lidar"]].msgtype == "sensor_msgs/msg/PointCloud2"
    assert topics[TOPICS["steering"]].msgtype == "std_msgs/msg/Float64"
    assert load_demo_recording(recording.root) == recording


def test_odometry_is_utm_with_x_to_the_left_and_steering_follows_the_bend(
    recording: DemoRecording,
) -> None:
    from cam2sim.recording.bag import Recording

    with Recording([recording.bag]) as rec:
        odom = [m.msg for m in rec.messages([TOPICS["pose"]])]
        steer = np.array([m.msg.data for m in rec.messages([TOPICS["steering"]])])
    first = odom[0].pose.pose
    assert first.position.x == pytest.approx(691_000.0)
    assert first.position.y == pytest.approx(5_336_000.0)
    # Heading east = x-left yaw of +90 degrees.
    yaw = 2 * np.arctan2(first.orientation.z, first.orientation.w)
    assert yaw == pytest.approx(np.pi / 2)
    assert abs(steer[0]) < 1e-6
    # 50 Hz: the middle of the bend (9-13 s) steers its 40 m radius on average, and the driver's
    # weave about the lane centre steers both ways on the straights.
    bend = steer[9 * 50 : 13 * 50]
    assert bend.mean() == pytest.approx(1 / 40 / 0.022, rel=0.15)
    assert steer[: 7 * 50].min() < -0.2
    assert steer[: 7 * 50].max() > 0.2


def test_the_osm_file_has_the_street_and_buildings(recording: DemoRecording) -> None:
    from cam2sim.map.osm import read_osm

    data = read_osm(recording.osm)
    roads = data.highways(["residential"])
    assert len(roads) == 1
    assert roads[0].tags["lanes"] == "2"
    buildings = [w for w in data.ways if w.tags.get("building") == "yes"]
    assert len(buildings) == len(recording.buildings) >= 10
    assert all(w.refs[0] == w.refs[-1] and "building:levels" in w.tags for w in buildings)
    lat, lon = data.way_coords(roads[0])
    assert 48.0 < lat.min() < lat.max() < 48.3
    assert 11.4 < lon.min() < lon.max() < 11.8


def test_the_camera_does_not_look_like_the_raster_renderer(recording: DemoRecording) -> None:
    from cam2sim.recording.bag import Recording
    from cam2sim.recording.image import decode_compressed_image
    from cam2sim.render.meshes import Label
    from cam2sim.render.raster import RasterRenderer

    with Recording([recording.bag]) as rec:
        msg = next(iter(rec.messages([TOPICS["camera"]]))).msg
    photo = decode_compressed_image(msg).astype(np.float64)
    pose = L_STREET.camera_pose(L_STREET.speed_mps * 0.05)
    with RasterRenderer(demo_world().raster_scene()) as renderer:
        frame = renderer.render(pose, demo_camera())
    raster = frame.rgb.astype(np.float64)
    assert photo.shape == raster.shape
    assert np.abs(photo - raster).mean() > 8.0
    # The raster road is flat colour; the photographic one is textured and noisy.
    road = frame.labels == Label.ROAD
    assert road.sum() > 1000
    both = road[:, 1:] & road[:, :-1]

    def grain(img: np.ndarray) -> float:
        return float(np.abs(np.diff(img, axis=1))[both].mean())

    assert grain(raster) < 1.0
    assert grain(photo) > 3.0 * grain(raster) + 1.0


def test_the_truth_camera_renders_what_the_recording_saw(recording: DemoRecording) -> None:
    from cam2sim.recording.bag import Recording
    from cam2sim.recording.image import decode_compressed_image
    from cam2sim.render.truth import TruthRenderer, TruthWorld

    with Recording([recording.bag]) as rec:
        messages = rec.messages([TOPICS["camera"]])
        photos = [decode_compressed_image(next(messages).msg) for _ in range(3)]
    world = TruthWorld.load(recording.truth_world)
    other = world.model_copy(update={"look": world.look.model_copy(update={"seed": 99})})

    def error(view: np.ndarray, photo: np.ndarray) -> float:
        return float(np.abs(view.astype(np.float64) - photo).mean())

    with TruthRenderer(world, None) as camera, TruthRenderer(other, None) as wrong:
        for k, photo in enumerate(photos):
            pose = L_STREET.camera_pose(L_STREET.speed_mps * (0.05 + 0.05 * k))
            same = error(camera.render(pose, demo_camera()).rgb, photo)
            seeded = error(wrong.render(pose, demo_camera()).rgb, photo)
            # The same pixels but for JPEG (which smooths the sensor noise); another look seed
            # (other textures and noise) is much farther off.
            assert same < 4.0
            assert seeded > same + 2.0


@pytest.mark.skipif(not has_carla(), reason="the map step needs carla")
def test_the_fast_pipeline_steps_run_on_the_demo(tmp_path: Path, recording: DemoRecording) -> None:
    from cam2sim.core.config import load_config
    from cam2sim.core.workspace import Workspace
    from cam2sim.stages.pipeline import PipelineOptions, run_pipeline

    ws = Workspace.create(tmp_path / "ws", load_config(recording.config))
    options = replace(PipelineOptions(osm=recording.osm, steps=FAST, cameras=("none",)), runs=1)
    result = run_pipeline(ws, options=options)
    states = {o.name: o.state for o in result.outcomes}
    assert not result.failed, result.outcomes
    assert {states[s] for s in FAST} == {"done"}, result.outcomes
    assert (ws.report_dir / "drive" / "metrics.json").is_file()
    # The demo's driver holds one speed: its runs hold it too (a real drive's follow it).
    drive = next(o for o in result.outcomes if o.name == "drive")
    assert "recorded speed" not in drive.message


def test_the_demo_report_opens_in_chromium_with_every_section_and_image(
    tmp_path: Path, recording: DemoRecording
) -> None:
    """The demo's own report (its fast steps, replay and the report) in a real browser."""
    from conftest import has_egl, launch_chromium, playwright_with_chromium

    if not has_egl():
        pytest.skip("the replay's raster camera needs headless OpenGL (EGL)")
    sync_api = playwright_with_chromium()
    from cam2sim.core.config import load_config
    from cam2sim.core.workspace import Workspace
    from cam2sim.report.html import SECTION_IDS
    from cam2sim.stages.pipeline import PipelineOptions, run_pipeline

    ws = Workspace.create(tmp_path / "ws", load_config(recording.config))
    steps = (*FAST[:4], "replay", *FAST[4:], "report")
    options = PipelineOptions(
        osm=recording.osm, steps=steps, cameras=("raster",), runs=1, replay_every=10
    )
    result = run_pipeline(ws, options=options)
    assert not result.failed, result.outcomes
    report = ws.report_files.html
    assert report.stat().st_size < 30 * 2**20  # one self-contained file under 30 MB
    with sync_api.sync_playwright() as pw:
        browser = launch_chromium(pw)
        try:
            page = browser.new_page(viewport={"width": 1280, "height": 900})
            errors: list[str] = []
            page.on("pageerror", lambda err: errors.append(str(err)))
            page.goto(report.as_uri(), wait_until="load")
            visible = [page.locator(f"section#{sid}").is_visible() for sid in SECTION_IDS]
            images = page.evaluate("document.images.length")
            loaded = page.evaluate(
                "Array.from(document.images).every(i => i.complete && i.naturalWidth > 0)"
            )
        finally:
            browser.close()
    assert all(visible)
    assert errors == []
    assert images >= 8  # map, behaviour plots, frames of the replay and the drive, strips
    assert loaded
