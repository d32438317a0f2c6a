"""The splat camera on a hill: on the recorded path it stands and leans as the recorded camera.

A recording on a sloping road (KITTI 03 climbs 43 m with the car pitched up to 7.7 degrees) is
trained into a splat at the recorded camera poses. A closed-loop or replay camera that stood
level at the recorded height would look past the road: its horizon moves by about the focal
length times the pitch (97 px on KITTI). These tests import a drive up a banked hill as KITTI
poses and check that the camera the runs render from is the recorded one.
"""

from __future__ import annotations

import math
import warnings
from pathlib import Path

import cv2
import numpy as np
import pytest

from cam2sim.core.dataset import Calibration
from cam2sim.core.table import read_table
from cam2sim.core.workspace import DatasetPaths, Workspace
from cam2sim.splat.geometry import camera_poses as recorded_camera_poses
from cam2sim.stages.image_import import ImportOptions, import_images

_B = np.array([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]])  # vehicle axes, optical


def _rot(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """``Rz(yaw) @ Ry(pitch) @ Rx(roll)`` (ROS ZYX: positive pitch is nose down)."""
    cr, sr, cp, sp, cy, sy = (f(a) for a in (roll, pitch, yaw) for f in (math.cos, math.sin))
    rz = np.array([[cy, -sy, 0.0], [sy, cy, 0.0], [0.0, 0.0, 1.0]])
    ry = np.array([[cp, 0.0, sp], [0.0, 1.0, 0.0], [-sp, 0.0, cp]])
    rx = np.array([[1.0, 0.0, 0.0], [0.0, cr, -sr], [0.0, sr, cr]])
    rot: np.ndarray = rz @ ry @ rx
    return rot


def _hill(tmp_path: Path, n: int = 40) -> Path:
    """A KITTI poses.txt of a camera on a car climbing a 12 % grade, banked 2 degrees, turning."""
    s = np.arange(n) * 1.0
    heading = np.where(s > 10, (s - 10) * 0.03, 0.0)
    grade = 0.12 * np.clip(s / 10.0, 0.0, 1.0)  # level at the start, then climbing
    pitch = -np.arctan(grade)  # nose up
    roll = np.radians(2.0) * np.clip(s / 20.0, 0.0, 1.0)
    xy = np.cumsum(np.stack([np.cos(heading), np.sin(heading)], -1), axis=0)
    z = np.cumsum(grade)
    lines = []
    for k in range(n):
        r_wc = _B @ _rot(roll[k], pitch[k], heading[k]) @ _B.T  # KITTI world = first camera
        m = np.hstack([r_wc, (_B @ np.array([xy[k, 0], xy[k, 1], z[k]]))[:, None]])
        lines.append(" ".join(f"{v:.9e}" for v in m.ravel()))
    poses = tmp_path / "poses.txt"
    poses.write_text("\n".join(lines) + "\n", encoding="utf-8")
    (tmp_path / "K.txt").write_text("20 0 8\n0 20 6\n0 0 1\n", encoding="utf-8")
    images = tmp_path / "images"
    images.mkdir()
    rng = np.random.default_rng(0)
    for k in range(n):
        cv2.imwrite(str(images / f"{k:06d}.png"), rng.integers(0, 255, (12, 16), np.uint8))
    return tmp_path


def _replay_splat_poses(ws: Workspace, monkeypatch: pytest.MonkeyPatch) -> np.ndarray:
    """The camera poses a replay renders the splat from (a stand-in renderer records them)."""
    from cam2sim.stages import cameras
    from cam2sim.stages.runs import ReplayOptions, replay

    poses: list[np.ndarray] = []

    class _Recorder:
        def render(self, T_world_cam: np.ndarray, camera: object) -> object:
            poses.append(np.array(T_world_cam))
            rgb = np.zeros((12, 16, 3), np.uint8)
            return type("Frame", (), {"rgb": rgb})()

        def close(self) -> None:
            pass

    monkeypatch.setitem(cameras._CAMERAS, "splat", lambda _ctx: _Recorder())
    replay(ws, options=ReplayOptions(cameras=("splat",), video=False))
    return np.stack(poses)


def test_the_splat_camera_on_the_recorded_path_is_the_recorded_camera(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    pytest.importorskip("carla", reason="the scenario's checks need carla (cam2sim[map])")
    from cam2sim.stages.cameras import recorded_ground_at, vehicle_camera_pose
    from cam2sim.stages.map import build_map
    from cam2sim.stages.scenario import run_scenario

    src = _hill(tmp_path)
    opts = ImportOptions(
        poses=src / "poses.txt",
        calibration=src / "K.txt",
        fps=10.0,
        pose_offset_m=(0.8, 0.0, 1.65),  # KITTI's poses are the camera's
    )
    import_images(tmp_path / "ws", src / "images", options=opts)
    ws = Workspace.open(tmp_path / "ws")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the map from the path warns what it lacks
        build_map(ws)
    sc = run_scenario(ws).scenario
    assert sc is not None
    assert sc.trajectory.pitch is not None
    # What the splat was trained on: the recorded camera poses of the dataset.
    paths = DatasetPaths(ws.dataset_dir)
    table = read_table(paths.poses_csv)
    position = np.stack([table[c] for c in ("x", "y", "z")], 1)
    quat = np.stack([table[c] for c in ("qx", "qy", "qz", "qw")], 1)
    recorded = recorded_camera_poses(
        position, quat, Calibration.load(paths.calibration_json).camera_mount
    )
    centre = np.asarray(sc.trajectory.center)
    for i in (0, 15, 25, 39):
        ground = recorded_ground_at(sc, position[i, :2])
        assert math.degrees(abs(ground.pitch)) == pytest.approx(
            math.degrees(math.atan(0.12 * min(i / 10.0, 1.0))), abs=0.01
        )
        run = vehicle_camera_pose(
            sc, centre[i, 0], centre[i, 1], sc.trajectory.heading[i], recorded=True
        )
        np.testing.assert_allclose(run[:3, 3], recorded[i][:3, 3], atol=0.02)
        cos = (np.trace(run[:3, :3].T @ recorded[i][:3, :3]) - 1.0) / 2.0
        assert math.degrees(math.acos(min(cos, 1.0))) < 0.05
    # A replay poses the splat camera the same way at every recorded sample.
    seen = _replay_splat_poses(ws, monkeypatch)
    np.testing.assert_allclose(seen[:, :3, 3], recorded[:, :3, 3], atol=0.02)
    np.testing.assert_allclose(seen[:, :3, :3], recorded[:, :3, :3], atol=1e-3)
    # The raster world is flat: its camera stays level at the mount height.
    flat = vehicle_camera_pose(
        sc, centre[39, 0], centre[39, 1], sc.trajectory.heading[39], recorded=False
    )
    assert flat[2, 3] == pytest.approx(1.65, abs=1e-6)
    assert abs(flat[2, 2]) < 1e-9  # the optical axis is horizontal


def test_tilt_columns_are_optional_and_must_match_the_samples() -> None:
    from cam2sim.scenario.model import ScenarioTrajectory

    traj = ScenarioTrajectory(
        heading_source="motion",
        frame=(0, 1),
        stamp_ns=(0, 100),
        t=(0.0, 0.1),
        heading=(0.0, 0.0),
        speed=(1.0, 1.0),
        reference=((0.0, 0.0, 1.0), (1.0, 0.0, 1.1)),
        center=((0.0, 0.0, 0.0), (1.0, 0.0, 0.1)),
        rear_axle=((-1.0, 0.0, 0.0), (0.0, 0.0, 0.1)),
    )
    assert traj.pitch is None
    assert traj.roll is None
    with pytest.raises(ValueError, match="pitch"):
        ScenarioTrajectory(**{**traj.model_dump(), "pitch": (0.0,), "roll": (0.0, 0.0)})
