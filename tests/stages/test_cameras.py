"""The camera registry: renderers by name, plugged in and opened for a run."""

from __future__ import annotations

from dataclasses import dataclass, field
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
