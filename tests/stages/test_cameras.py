"""The camera registry: renderers by name, plugged in and opened for a run."""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
import pytest

from cam2sim.core.camera import PinholeCamera
from cam2sim.core.errors import StageError
from cam2sim.stages import cameras
from cam2sim.stages.cameras import Cameras, camera_names, register_camera


@dataclass
class _Frame:
    rgb: np.ndarray


@dataclass
class _Flat:
    """A renderer that paints every pixel one colour and records that it was closed."""

    colour: int
    closed: list[str] = field(default_factory=list)

    def render(self, T: Any, camera: PinholeCamera) -> _Frame:
        return _Frame(np.full((camera.height, camera.width, 3), self.colour, np.uint8))

    def close(self) -> None:
        self.closed.append("closed")


@pytest.fixture
def registry(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(cameras, "_CAMERAS", dict(cameras._CAMERAS))


@pytest.mark.usefixtures("registry")
def test_a_registered_camera_renders_and_closes() -> None:
    flat = _Flat(7)
    register_camera("flat", lambda ctx: flat)
    assert {"raster", "splat", "truth", "carla", "flat"} <= set(camera_names())
    with Cameras(None, ("flat", "carla", "none")) as cams:  # type: ignore[arg-type]
        image = cams.render("flat", np.eye(4), PinholeCamera.from_K(np.eye(3), 8, 4))
        assert set(cams.renderers) == {"flat"}  # carla: rendered by the simulator
    assert image.shape == (4, 8, 3)
    assert (image == 7).all()
    assert flat.closed == ["closed"]


@pytest.mark.usefixtures("registry")
def test_an_unknown_camera_lists_the_cameras() -> None:
    with pytest.raises(StageError, match="no camera fisheye; the cameras are carla, raster"):
        Cameras(None, ("fisheye",))  # type: ignore[arg-type]


@pytest.mark.usefixtures("registry")
def test_a_camera_that_cannot_open_closes_those_already_open() -> None:
    first = _Flat(1)

    def broken(ctx: object) -> _Flat:
        msg = "no models"
        raise StageError(msg)

    register_camera("first", lambda ctx: first)
    register_camera("broken", broken)
    with pytest.raises(StageError, match="no models"):
        Cameras(None, ("first", "broken"))  # type: ignore[arg-type]
    assert first.closed == ["closed"]


@dataclass
class _Rays:
    """A renderer whose pixel shows where its ray points (x, y of the ray at z = 1, scaled)."""

    seen: list[PinholeCamera] = field(default_factory=list)

    def render(self, T: Any, camera: PinholeCamera) -> _Frame:
        camera.require_undistorted("the test renderer")
        self.seen.append(camera)
        u, v = np.meshgrid(np.arange(camera.width), np.arange(camera.height))
        x = (u - camera.cx) / camera.fx
        y = (v - camera.cy) / camera.fy
        rgb = np.stack([128 + 100 * x, 128 + 100 * y, np.full_like(x, 50.0)], axis=-1)
        return _Frame(np.clip(rgb, 0, 255).astype(np.uint8))

    def close(self) -> None:
        pass


@pytest.mark.usefixtures("registry")
def test_a_camera_with_a_lens_sees_what_that_lens_records() -> None:
    import cv2

    lens = PinholeCamera(
        300.0, 300.0, 159.5, 99.5, 320, 200, (-0.274231, 0.034838, 0.00226, -0.000972, 0.0)
    )
    rays = _Rays()
    register_camera("rays", lambda ctx: rays)
    with Cameras(None, ("rays",)) as cams:  # type: ignore[arg-type]
        image = cams.render("rays", np.eye(4), lens).astype(float)
        band = cams.render("rays", np.eye(4), lens, rows=(80, 120))
        pinhole = cams.render("rays", np.eye(4), replace(lens, distortion=()))
    # Drawn through the pinhole camera of the lens (the renderer never sees the distortion) ...
    assert rays.seen[0].distortion == ()
    assert rays.seen[0].size != lens.size
    assert image.shape == (200, 320, 3)
    # ... and laid out as the lens records it: each pixel shows its own ray.
    u, v = np.array([5.0, 300.0, 160.0, 40.0]), np.array([5.0, 190.0, 100.0, 150.0])
    pixels = np.stack([u, v], axis=-1)[:, None, :]
    ray = cv2.undistortPoints(pixels, lens.K(), np.asarray(lens.distortion)).reshape(-1, 2)
    shown = image[v.astype(int), u.astype(int)]
    np.testing.assert_allclose(shown[:, 0], 128 + 100 * ray[:, 0], atol=1.5)
    np.testing.assert_allclose(shown[:, 1], 128 + 100 * ray[:, 1], atol=1.5)
    # Barrel distortion: the corner sees a wider ray than the pinhole camera's corner does.
    assert abs(ray[0, 0]) > abs((5.0 - lens.cx) / lens.fx)
    assert not np.array_equal(image.astype(np.uint8), pinhole)
    # A band of rows is cut from the whole recorded image.
    np.testing.assert_array_equal(band, image[80:120].astype(np.uint8))


def test_runs_see_through_the_recorded_lens_and_comparisons_through_a_pinhole() -> None:
    from types import SimpleNamespace

    from cam2sim.core.config import IntrinsicsConfig

    intrinsics = IntrinsicsConfig(
        width=800, height=503, fx=772.9, fy=777.6, cx=425.0, cy=258.5,
        distortion=[-0.274231, 0.034838, 0.00226, -0.000972, 0.0],
    )  # fmt: skip
    scenario = SimpleNamespace(camera=intrinsics)
    run = cameras.run_camera(scenario, (320, 200))  # type: ignore[arg-type]
    assert run.size == (320, 200)
    assert run.distortion == tuple(intrinsics.distortion)
    flat = cameras.scaled_intrinsics(scenario, (320, 200))  # type: ignore[arg-type]
    assert flat.distortion == ()
    assert flat.K().tolist() == run.K().tolist()


@pytest.mark.usefixtures("registry")
def test_a_grey_recordings_cameras_render_grey() -> None:
    @dataclass
    class _Red:
        def render(self, T: Any, camera: PinholeCamera) -> _Frame:
            image = np.zeros((camera.height, camera.width, 3), np.uint8)
            image[..., 0] = 200
            return _Frame(image)

        def close(self) -> None:
            pass

    register_camera("red", lambda ctx: _Red())
    grey_camera = type("Intrinsics", (), {"grey": True})()
    ctx = type("Ctx", (), {"scenario": type("Sc", (), {"camera": grey_camera})()})()
    camera = PinholeCamera.from_K(np.eye(3), 8, 4)
    with Cameras(ctx, ("red",)) as cams:  # type: ignore[arg-type]
        image = cams.render("red", np.eye(4), camera)
    assert (image == round(0.299 * 200)).all()  # the luma of pure red, in every channel
    with Cameras(None, ("red",)) as cams:  # type: ignore[arg-type]
        assert (cams.render("red", np.eye(4), camera)[..., 0] == 200).all()


def test_the_runs_splat_camera_takes_vehicle_poses(
    tmp_path: Any, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Replays and drives render the splat for a planar vehicle: the views' height and tilt."""
    from types import SimpleNamespace

    seen: list[str] = []

    def opened(models: Any, *, options: Any) -> _Flat:
        seen.append(options.pose_frame)
        return _Flat(0)

    monkeypatch.setattr(cameras, "SplatRenderer", opened)
    models = tmp_path / "models"
    ctx = SimpleNamespace(
        ws=SimpleNamespace(root=tmp_path, splat_files=SimpleNamespace(models_dir=models))
    )
    with pytest.raises(StageError, match="no splat models"):
        cameras._CAMERAS["splat"](ctx)  # type: ignore[arg-type]
    models.mkdir()
    cameras._CAMERAS["splat"](ctx)  # type: ignore[arg-type]
    assert seen == ["vehicle"]
