"""Import from what dash cameras, GPS loggers and SLAM write: videos, GPX, NMEA, TUM poses."""

from __future__ import annotations

from datetime import UTC, datetime
from functools import reduce
from typing import TYPE_CHECKING

import cv2
import numpy as np
import pyproj
import pytest

from cam2sim.core import frames
from cam2sim.core.errors import RecordingError
from cam2sim.core.table import read_table
from cam2sim.core.workspace import DatasetPaths
from cam2sim.recording.pose_file import read_pose_file
from cam2sim.stages.image_import import ImportOptions, import_images

if TYPE_CHECKING:
    from pathlib import Path

UTM10N = "EPSG:32610"
T0 = datetime(2026, 5, 1, 23, 59, 58, tzinfo=UTC)  # the drive crosses midnight
T0_NS = int(T0.timestamp()) * 10**9


def _arc(n: int, dt: float = 0.1) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Times (s), UTM 10N positions and headings of a drive: straight 2 s, then a left turn."""
    t = np.arange(n) * dt
    heading = 0.4 + 0.15 * np.clip(t - 2.0, 0.0, None)
    step = 8.0 * dt * np.stack([np.cos(heading), np.sin(heading)], -1)
    xy = np.cumsum(step, axis=0) - step[0] + [551_000.0, 4_175_000.0]
    return t, xy, heading


def _lat_lon(xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    to = pyproj.Transformer.from_crs(UTM10N, "EPSG:4326", always_xy=True)
    lon, lat = to.transform(xy[:, 0], xy[:, 1])
    return np.asarray(lat), np.asarray(lon)


def _iso(t: float) -> str:
    return datetime.fromtimestamp(T0.timestamp() + t, tz=UTC).isoformat().replace("+00:00", "Z")


def _gpx(path: Path, t: np.ndarray, lat: np.ndarray, lon: np.ndarray) -> Path:
    """A GPX 1.1 track of two segments (the second written first: order comes from the times)."""

    def seg(idx: range) -> str:
        pts = "".join(
            f'<trkpt lat="{lat[i]:.9f}" lon="{lon[i]:.9f}"><ele>{12.5 + 0.01 * i:.2f}</ele>'
            f"<time>{_iso(t[i])}</time></trkpt>\n"
            for i in idx
        )
        return f"<trkseg>\n{pts}</trkseg>\n"

    half = len(t) // 2
    path.write_text(
        '<?xml version="1.0" encoding="UTF-8"?>\n'
        '<gpx version="1.1" creator="test" xmlns="http://www.topografix.com/GPX/1/1">\n'
        f"<trk><name>drive</name>{seg(range(half, len(t)))}{seg(range(half))}</trk></gpx>\n"
    )
    return path


def _nmea_sentence(body: str) -> str:
    check = reduce(lambda a, c: a ^ ord(c), body, 0)
    return f"${body}*{check:02X}"


def _ddmm(value: float, pos: str, neg: str, width: int) -> tuple[str, str]:
    a = abs(value)
    deg = int(a)
    return f"{deg:0{width}d}{(a - deg) * 60:09.6f}", pos if value >= 0 else neg


def _nmea(path: Path, t: np.ndarray, lat: np.ndarray, lon: np.ndarray, *, rmc: bool = True) -> Path:
    """An NMEA log: RMC + GGA a fix (a logger's time prefix), one bad checksum, one lost fix."""
    lines = []
    for i, ti in enumerate(t):
        moment = datetime.fromtimestamp(T0.timestamp() + ti, tz=UTC)
        hms = moment.strftime("%H%M%S") + f".{moment.microsecond // 10000:02d}"
        la, ns = _ddmm(lat[i], "N", "S", 2)
        lo, ew = _ddmm(lon[i], "E", "W", 3)
        if rmc:
            dmy = moment.strftime("%d%m%y")
            lines.append(_nmea_sentence(f"GNRMC,{hms},A,{la},{ns},{lo},{ew},15.5,22.9,{dmy},,,A"))
        lines.append(
            f"{1000 + i}," + _nmea_sentence(f"GPGGA,{hms},{la},{ns},{lo},{ew},1,09,0.9,12.5,M,,M,,")
        )
    lines.insert(3, "$GPGGA,000000.00,3746.0,N,12224.0,W,1,09,0.9,12.5,M,,M,,*00")  # bad sum
    lines.insert(5, _nmea_sentence("GPGGA,235959.99,,,,,0,00,,,M,,M,,"))  # no fix
    lines.insert(0, _nmea_sentence("GPGSV,3,1,11,01,40,083,46"))  # other sentences: ignored
    path.write_text("\n".join(lines) + "\n")
    return path


def _frames(folder: Path, n: int) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    for k in range(n):
        assert cv2.imwrite(str(folder / f"{k:04d}.png"), np.full((12, 16, 3), k % 250, np.uint8))
    return folder


def _trajectory(root: Path) -> dict[str, np.ndarray]:
    return read_table(DatasetPaths(root / "dataset").trajectory_csv)


def test_gpx_and_nmea_give_the_fixes_of_the_drive_in_time_order(tmp_path: Path) -> None:
    t, xy, _ = _arc(40)
    lat, lon = _lat_lon(xy)
    gpx = read_pose_file(_gpx(tmp_path / "drive.gpx", t, lat, lon))
    assert gpx.geographic
    assert gpx.kind == "gpx"
    assert gpx.quat is None  # the import heads the car where it travels
    np.testing.assert_array_equal(gpx.stamp_ns, T0_NS + np.round(t * 1e9).astype(np.int64))
    np.testing.assert_allclose(gpx.xyz[:, 0], lat, atol=1e-9)
    np.testing.assert_allclose(gpx.xyz[:, 1], lon, atol=1e-9)
    np.testing.assert_allclose(gpx.xyz[:, 2], 12.5 + 0.01 * np.arange(40), atol=1e-9)

    nmea = read_pose_file(_nmea(tmp_path / "drive.nmea", t, lat, lon))
    assert nmea.kind == "nmea"
    np.testing.assert_array_equal(nmea.stamp_ns, gpx.stamp_ns)  # RMC's dates cross midnight
    np.testing.assert_allclose(nmea.xyz[:, :2], gpx.xyz[:, :2], atol=1e-7)  # 6 decimal minutes
    np.testing.assert_allclose(nmea.xyz[:, 2], 12.5)
    assert any("1 (bad checksum)" in n and "1 (no fix)" in n for n in nmea.notes)


def test_nmea_without_rmc_counts_from_1970_and_rolls_over_midnight(tmp_path: Path) -> None:
    t, xy, _ = _arc(40)
    lat, lon = _lat_lon(xy)
    table = read_pose_file(_nmea(tmp_path / "gga.log", t, lat, lon, rmc=False))
    assert np.all(np.diff(table.stamp_ns) > 0)  # 23:59:58 -> 00:00:01.9, one day later
    np.testing.assert_allclose(
        (table.stamp_ns - table.stamp_ns[0]) / 1e9, t, atol=1e-6
    )  # the clock of day carries on past midnight
    assert table.stamp_ns[0] < 86_400 * 10**9
    assert any("1970" in n for n in table.notes)


def test_a_gps_track_imports_like_the_csv_of_the_same_fixes(tmp_path: Path) -> None:
    """Frames named 0000.png... (no dates) meet the GPX's dates at its first fix."""
    t, xy, _ = _arc(40)
    lat, lon = _lat_lon(xy)
    csv = tmp_path / "fixes.csv"
    csv.write_text(
        "timestamp,lat,lon\n"
        + "".join(f"{_iso(t[i])},{lat[i]:.9f},{lon[i]:.9f}\n" for i in range(40))
    )
    images = _frames(tmp_path / "images", 40)
    track = _gpx(tmp_path / "d.gpx", t, lat, lon)
    gpx = import_images(tmp_path / "a", images, options=ImportOptions(fps=10.0, poses=track))
    import_images(tmp_path / "b", images, options=ImportOptions(fps=10.0, poses=csv))
    assert any("first pose's time" in n for n in gpx.notes)  # and it says so
    a, b = _trajectory(tmp_path / "a"), _trajectory(tmp_path / "b")
    assert len(a["x"]) == 40
    np.testing.assert_array_equal(a["stamp_ns"], b["stamp_ns"])
    for col in ("x", "y", "heading"):
        np.testing.assert_allclose(a[col], b[col], atol=1e-6)


def test_start_places_the_first_frame_on_the_poses_clock(tmp_path: Path) -> None:
    t, xy, _ = _arc(40)
    lat, lon = _lat_lon(xy)
    gpx = _gpx(tmp_path / "d.gpx", t, lat, lon)
    images = _frames(tmp_path / "images", 20)
    opts = ImportOptions(fps=10.0, poses=gpx, start=_iso(1.5))  # frames began 1.5 s in
    result = import_images(tmp_path / "ws", images, options=opts)
    assert not result.notes or all("first pose's time" not in n for n in result.notes)
    traj = _trajectory(tmp_path / "ws")
    assert traj["stamp_ns"][0] == T0_NS + 1_500_000_000
    # frame 0 stands where the drive was at 1.5 s: 12 m down the straight from the first fix
    assert np.hypot(traj["x"][0], traj["y"][0]) == pytest.approx(12.0, abs=0.05)
    with pytest.raises(RecordingError, match="--start"):
        import_images(tmp_path / "bad", images, options=ImportOptions(poses=gpx, start="soon"))


def test_tum_poses_of_a_camera_or_a_body_give_the_same_drive(tmp_path: Path) -> None:
    """Visual SLAM writes camera poses (z forward) in its first camera's frame (y down)."""
    t, xy, heading = _arc(40)
    local = xy - xy[0]
    rows_body, rows_cam = [], []
    # the SLAM world: the first camera's optical frame; the car's (x fwd, y left, z up) in it
    opt_from_body = np.array([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]])
    first = frames.quat_to_matrix(frames.quat_from_yaw(heading[0]))
    for i in range(40):
        r_body = frames.quat_to_matrix(frames.quat_from_yaw(heading[i]))
        p = np.array([local[i, 0], local[i, 1], 1.6])
        qb = frames.quat_from_matrix(r_body)
        rows_body.append(
            f"{t[i]:.3f} {p[0]:.6f} {p[1]:.6f} {p[2]:.6f} " + " ".join(f"{v:.9f}" for v in qb)
        )
        # camera = body turned to optical axes; world = first camera's optical frame
        w = opt_from_body @ first.T
        r_cam = w @ r_body @ opt_from_body.T
        pc = w @ (p - [0.0, 0.0, 1.6])
        qc = frames.quat_from_matrix(r_cam)
        rows_cam.append(
            f"{t[i]:.3f} {pc[0]:.6f} {pc[1]:.6f} {pc[2]:.6f} " + " ".join(f"{v:.9f}" for v in qc)
        )
    (tmp_path / "body.txt").write_text(
        "# timestamp tx ty tz qx qy qz qw\n" + "\n".join(rows_body) + "\n"
    )
    (tmp_path / "cam.txt").write_text("\n".join(rows_cam) + "\n")
    body = read_pose_file(tmp_path / "body.txt")
    cam = read_pose_file(tmp_path / "cam.txt")
    assert (body.kind, cam.kind) == ("tum", "tum camera")
    assert any("z up" in n for n in cam.notes)
    # The camera's drive is the body's, turned so it starts along +x (the first camera's view).
    yaw_b = frames.yaw_from_quat(body.quat) - heading[0]
    assert cam.quat is not None
    np.testing.assert_allclose(frames.yaw_from_quat(cam.quat), yaw_b, atol=1e-6)
    turn = frames.quat_to_matrix(frames.quat_from_yaw(-heading[0]))
    np.testing.assert_allclose(cam.xyz, (turn @ (body.xyz - body.xyz[0]).T).T, atol=1e-5)
    # Upright (pitch and roll 0): the z-up world keeps the car level.
    up = np.einsum("nij,j->ni", frames.quat_to_matrix(cam.quat), [0.0, 0.0, 1.0])
    np.testing.assert_allclose(up, np.tile([0.0, 0.0, 1.0], (40, 1)), atol=1e-6)


def test_a_video_imports_at_the_frame_rate_asked_with_its_own_times(tmp_path: Path) -> None:
    video = tmp_path / "dashcam.mp4"
    writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"mp4v"), 30.0, (64, 48))
    for k in range(90):  # 3 s at 30 fps; frame k is grey level 2k
        writer.write(np.full((48, 64, 3), 2 * k, np.uint8))
    writer.release()
    t, xy, _ = _arc(40)
    lat, lon = _lat_lon(xy)
    opts = ImportOptions(poses=_gpx(tmp_path / "d.gpx", t, lat, lon), video_fps=10.0)
    result = import_images(tmp_path / "ws", video, options=opts)
    assert result.info.counts.frames == 30
    traj = _trajectory(tmp_path / "ws")
    np.testing.assert_allclose(np.diff(traj["stamp_ns"]) / 1e9, 0.1, atol=1e-3)
    assert traj["stamp_ns"][0] == T0_NS
    paths = DatasetPaths(tmp_path / "ws" / "dataset")
    levels = [
        float(cv2.imread(str(paths.frame_file(i, "png")), cv2.IMREAD_GRAYSCALE).mean())
        for i in (0, 1, 29)
    ]
    np.testing.assert_allclose(levels, [0.0, 6.0, 174.0], atol=3.0)  # frames 0, 3, 87
    assert not (tmp_path / "ws" / ".video_frames.partial").exists()  # no scratch left behind


def test_bad_tracks_and_videos_say_what_to_fix(tmp_path: Path) -> None:
    no_time = tmp_path / "no_time.gpx"
    no_time.write_text('<gpx><trk><trkseg><trkpt lat="1" lon="2"/></trkseg></trk></gpx>')
    with pytest.raises(RecordingError, match=r"track point 1 has no <time>"):
        read_pose_file(no_time)
    routes = tmp_path / "route.gpx"
    routes.write_text('<gpx><rte><rtept lat="1" lon="2"/></rte></gpx>')
    with pytest.raises(RecordingError, match="no <trkpt>"):
        read_pose_file(routes)
    broken = tmp_path / "broken.gpx"
    broken.write_text("<gpx><trk>")
    with pytest.raises(RecordingError, match="not a readable GPX"):
        read_pose_file(broken)
    lost = tmp_path / "lost.nmea"
    lost.write_text(_nmea_sentence("GPGGA,120000.00,,,,,0,00,,,M,,M,,") + "\n")
    with pytest.raises(
        RecordingError, match=r"no GGA or RMC sentence with a fix \(skipped: no fix: 1\)"
    ):
        read_pose_file(lost)
    still = tmp_path / "still.txt"
    still.write_text("0 0 0 0 0 0 0 1\n1 0 0 0 0 0 0 1\n2 0 0 0 0 0 0 1\n")
    with pytest.raises(RecordingError, match="travel along neither"):
        read_pose_file(still)
    not_video = tmp_path / "clip.mp4"
    not_video.write_bytes(b"not a video")
    with pytest.raises(RecordingError, match="cannot be opened as a video"):
        import_images(tmp_path / "ws", not_video)


def test_kitti_03_as_a_tum_trajectory_imports_as_its_poses_txt(
    tmp_path: Path, shared_data: Path
) -> None:
    """KITTI's poses are a camera's, in its first camera's frame: what visual SLAM writes."""
    kitti = shared_data / "posed" / "kitti-odometry-03"
    m = np.loadtxt(kitti / "poses.txt").reshape(-1, 3, 4)[:40]
    quat = frames.quat_from_matrix(m[:, :, :3])
    lines = [
        f"{k / 10:.1f} " + " ".join(f"{v:.9f}" for v in (*m[k, :, 3], *quat[k])) for k in range(40)
    ]
    (tmp_path / "tum.txt").write_text("# KITTI 03 in TUM format\n" + "\n".join(lines) + "\n")
    for name, poses in (("kitti", kitti / "poses.txt"), ("tum", tmp_path / "tum.txt")):
        opts = ImportOptions(poses=poses, calibration=kitti / "K.txt", fps=10.0)
        import_images(tmp_path / name, kitti / "images", options=opts)
    a, b = _trajectory(tmp_path / "kitti"), _trajectory(tmp_path / "tum")
    assert a["x"][-1] > 30.0  # it drove ahead, along +x
    for col in ("x", "y", "z", "heading", "speed"):
        np.testing.assert_allclose(b[col], a[col], atol=1e-5)


def test_fov_gives_a_dash_camera_a_pinhole_k(tmp_path: Path) -> None:
    from cam2sim.core.dataset import Calibration

    images = _frames(tmp_path / "images", 3)  # 16 x 12
    import_images(tmp_path / "ws", images, options=ImportOptions(fov_deg=90.0))
    cam = Calibration.load(DatasetPaths(tmp_path / "ws" / "dataset").calibration_json).camera
    assert cam is not None
    assert (cam.width, cam.height) == (16, 12)
    np.testing.assert_allclose(cam.K, [[8.0, 0.0, 7.5], [0.0, 8.0, 5.5], [0.0, 0.0, 1.0]])
    assert "--fov 90" in cam.source
    both = ImportOptions(fov_deg=90.0, calibration=tmp_path / "K.txt")
    with pytest.raises(RecordingError, match="not both"):
        import_images(tmp_path / "ws2", images, options=both)
    with pytest.raises(RecordingError, match="10 to 170"):
        import_images(tmp_path / "ws3", images, options=ImportOptions(fov_deg=180.0))


def test_a_1_hz_track_poses_every_frame_and_a_dropout_is_said(tmp_path: Path) -> None:
    """Phones and dash cameras log GPS once a second; the frames come 10 times as often."""
    t, xy, _ = _arc(60)
    lat, lon = _lat_lon(xy)
    fixes = list(range(0, 60, 10))  # 1 Hz: t = 0, 1, ..., 5 s
    images = _frames(tmp_path / "images", 51)  # 0 to 5.0 s at 10 fps
    track = _gpx(tmp_path / "slow.gpx", t[fixes], lat[fixes], lon[fixes])
    import_images(tmp_path / "ws", images, options=ImportOptions(fps=10.0, poses=track))
    slow = _trajectory(tmp_path / "ws")
    assert len(slow["x"]) == 51  # every frame, not only those at a fix
    full = _gpx(tmp_path / "full.gpx", t[:51], lat[:51], lon[:51])
    import_images(tmp_path / "ref", images, options=ImportOptions(fps=10.0, poses=full))
    ref = _trajectory(tmp_path / "ref")
    # the turn between the fixes is followed, not cut by straight chords
    gap = np.hypot(slow["x"] - ref["x"], slow["y"] - ref["y"])
    assert gap.max() < 0.1
    # a receiver that lost the sky for 3 s: those frames have no pose, and the import says so
    lost = [i for i in fixes if i not in (20, 30)]
    track = _gpx(tmp_path / "lost.gpx", t[lost], lat[lost], lon[lost])
    result = import_images(tmp_path / "ws2", images, options=ImportOptions(fps=10.0, poses=track))
    assert result.info.counts.frames == 51 - 29  # 1.1 to 3.9 s
    assert any("29 of 51 frames have no pose (29 pose gap)" in n for n in result.notes)


def test_an_undated_nmea_log_meets_frames_counted_from_zero_at_its_first_fix(
    tmp_path: Path,
) -> None:
    t, xy, _ = _arc(40)
    lat, lon = _lat_lon(xy)
    log = _nmea(tmp_path / "gga.nmea", t, lat, lon, rmc=False)  # times of day only
    images = _frames(tmp_path / "images", 30)
    result = import_images(tmp_path / "ws", images, options=ImportOptions(fps=10.0, poses=log))
    assert result.info.counts.frames == 30
    assert any("1970" in n for n in result.notes)  # no date in the log
    assert any("first pose's time" in n for n in result.notes)
