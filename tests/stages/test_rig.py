"""A camera rig: imported beside the front camera, and the splat scored at its real frames."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest

from cam2sim.core.camera import PinholeCamera
from cam2sim.core.dataset import DatasetInfo, RigCamera
from cam2sim.core.errors import RecordingError
from cam2sim.core.workspace import DatasetPaths
from cam2sim.splat.envelope import RigView, rig_scores
from cam2sim.splat.scene import FrameRecord
from cam2sim.stages.image_import import ImportOptions, import_images
from cam2sim.stages.rig import read_rig, rig_offset

W, H = 64, 24


def _frames(folder: Path, n: int, level: int) -> None:
    folder.mkdir(parents=True)
    for i in range(n):
        image = np.full((H, W, 3), (level + 7 * i) % 255, np.uint8)
        cv2.imwrite(str(folder / f"{i:06d}.png"), image)


def _rig_file(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "rig.yaml"
    path.write_text(text, encoding="utf-8")
    return path


def test_a_stereo_rig_is_imported_with_its_pose_on_the_front_camera(tmp_path: Path) -> None:
    _frames(tmp_path / "left", 5, 10)
    _frames(tmp_path / "right", 5, 90)
    rig = _rig_file(
        tmp_path,
        "cameras:\n  right:\n    images: right/\n    offset_m: [0.0, -0.54, 0.0]\n",
    )
    (tmp_path / "K.txt").write_text("50 0 31.5\n0 50 11.5\n0 0 1\n", encoding="utf-8")
    opts = ImportOptions(calibration=tmp_path / "K.txt", rig=rig, fps=10.0)
    info = import_images(tmp_path / "ws", tmp_path / "left", options=opts).info
    assert info.rig == ("right",)
    paths = DatasetPaths(tmp_path / "ws" / "dataset")
    record = RigCamera.load(paths.rig_camera_json("right"))
    # 0.54 m to the vehicle's right is +0.54 m along the front camera's optical x.
    np.testing.assert_allclose(record.T()[:3, 3], [0.54, 0.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(record.T()[:3, :3], np.eye(3), atol=1e-12)
    assert rig_offset(record) == pytest.approx((0.54, 0.0))
    assert record.intrinsics.K[0][0] == 50.0  # the front camera's, none given
    second = cv2.imread(str(paths.rig_frame_file("right", 1, "png")))
    assert int(second[0, 0, 0]) == 97  # the right camera's frame 1, not the left's
    assert DatasetInfo.load(paths.dataset_json).rig == ("right",)


def test_a_rig_turned_left_has_a_positive_yaw(tmp_path: Path) -> None:
    rig = _rig_file(tmp_path, "cameras:\n  side:\n    images: s/\n    rpy_deg: [0, 0, 90]\n")
    (spec,) = read_rig(rig)
    T = spec.T_front_cam()
    record = RigCamera(
        name="side",
        intrinsics={
            "width": W,
            "height": H,
            "K": ((50, 0, 31.5), (0, 50, 11.5), (0, 0, 1)),
            "source": "test",
        },
        T_front_cam=tuple(tuple(r) for r in T),
        source="test",
    )
    assert rig_offset(record)[1] == pytest.approx(90.0)


def test_bad_rigs_say_what_is_wrong(tmp_path: Path) -> None:
    _frames(tmp_path / "left", 5, 10)
    _frames(tmp_path / "right", 4, 90)
    with pytest.raises(RecordingError, match=r"cameras.right: unknown keys \['offset'\]"):
        read_rig(_rig_file(tmp_path, "cameras:\n  right:\n    images: right/\n    offset: 1\n"))
    with pytest.raises(RecordingError, match=r"offset_m: give three numbers"):
        read_rig(_rig_file(tmp_path, "cameras:\n  right:\n    images: r/\n    offset_m: [1]\n"))
    rig = _rig_file(tmp_path, "cameras:\n  right:\n    images: right/\n")
    (tmp_path / "K.txt").write_text("50 0 31.5\n0 50 11.5\n0 0 1\n", encoding="utf-8")
    opts = ImportOptions(calibration=tmp_path / "K.txt", rig=rig)
    with pytest.raises(RecordingError, match=r"holds 4 images but the front camera has 5"):
        import_images(tmp_path / "ws", tmp_path / "left", options=opts)
    assert not (tmp_path / "ws" / "dataset").exists()  # nothing half written


@dataclass
class _Rendered:
    rgb: np.ndarray
    coverage: float | None = 0.5


class _Street:
    """A 'splat' whose image is a ramp set by where the camera stands across the street."""

    def render(self, T: np.ndarray, camera: PinholeCamera, **_: Any) -> _Rendered:
        return _Rendered(_street_view(float(T[0, 3]), camera))


def _street_view(x_m: float, camera: PinholeCamera) -> np.ndarray:
    cols = np.arange(camera.width, dtype=np.float64)
    row = np.clip(40 + 2.0 * cols + 60.0 * x_m, 0, 255)
    return np.repeat(np.repeat(row[None, :, None], camera.height, 0), 3, 2).astype(np.uint8)


def test_the_splat_is_scored_at_the_second_cameras_real_frames(tmp_path: Path) -> None:
    """A synthetic stereo rig: the right camera's frames are what stands 0.54 m to the right."""
    full = PinholeCamera.from_K(np.array([[50.0, 0, 63.5], [0, 50.0, 23.5], [0, 0, 1]]), 128, 48)
    T_front_cam = np.eye(4)
    T_front_cam[0, 3] = 0.54
    frames = []
    for k in range(4):
        T = np.eye(4)
        T[2, 3] = 2.0 * k  # driving along the optical z; the rig camera is at x = 0.54
        frames.append(
            FrameRecord(
                index=k,
                dataset_frame=k,
                stamp_ns=k,
                T_world_cam=T.tolist(),
                fx=25.0,
                fy=25.0,
                cx=31.5,
                cy=11.5,
                width=64,
                height=24,
                held_out=True,
            )
        )
        # The right camera records at full size what the street looks like from x = 0.54 m.
        cv2.imwrite(str(tmp_path / f"{k:06d}.png"), _street_view(0.54, full.scaled(64, 24)))
        big = cv2.resize(cv2.imread(str(tmp_path / f"{k:06d}.png")), (128, 48))
        cv2.imwrite(str(tmp_path / f"{k:06d}.png"), big)

    def view(T: np.ndarray) -> RigView:
        return RigView(
            name="right", T_front_cam=T, camera=full, front_width=128,
            frame_file=lambda i: tmp_path / f"{i:06d}.png", lateral_m=0.54,
        )  # fmt: skip

    (row,) = rig_scores(_Street(), [view(T_front_cam)], frames, lpips=None)  # type: ignore[arg-type]
    assert row.psnr_db.mean is not None
    assert row.psnr_db.mean > 35.0  # the splat seen from where the right camera was
    assert row.label() == "camera right (+0.54 m)"
    assert len(row.frames) == 4
    (wrong,) = rig_scores(_Street(), [view(np.eye(4))], frames, lpips=None)  # type: ignore[arg-type]
    assert wrong.psnr_db.mean is not None
    assert wrong.psnr_db.mean < row.psnr_db.mean - 10.0  # a rig pose left out shows


def test_the_splat_stage_finds_the_rigs_cameras(tmp_path: Path) -> None:
    from cam2sim.core.workspace import Workspace
    from cam2sim.stages.splat import _rig_views

    _frames(tmp_path / "left", 3, 10)
    _frames(tmp_path / "right", 3, 90)
    rig = _rig_file(
        tmp_path, "cameras:\n  right:\n    images: right/\n    offset_m: [0, -0.5, 0]\n"
    )
    (tmp_path / "K.txt").write_text("50 0 31.5\n0 50 11.5\n0 0 1\n", encoding="utf-8")
    import_images(tmp_path / "ws", tmp_path / "left", options=ImportOptions(
        calibration=tmp_path / "K.txt", rig=rig))  # fmt: skip
    (view,) = _rig_views(Workspace.open(tmp_path / "ws"))
    assert view.name == "right"
    assert view.lateral_m == pytest.approx(0.5)
    assert view.front_width == W
    assert view.frame_file(2).is_file()
