"""Geotagged photos: each frame's own EXIF GPS fix and capture time (`--poses exif`)."""

from __future__ import annotations

import math
from datetime import UTC, datetime, timedelta
from pathlib import Path

import numpy as np
import pytest
from PIL import ExifTags, Image

from cam2sim.core.errors import RecordingError
from cam2sim.core.table import read_table
from cam2sim.core.workspace import DatasetPaths
from cam2sim.recording.exif_gps import has_exif_gps, read_exif_track
from cam2sim.stages.image_import import ImportOptions, import_images

LAT0, LON0 = 48.1085, 11.5004  # Munich
START = datetime(2026, 5, 1, 9, 30, 2, tzinfo=UTC)


def _dms(value: float) -> tuple[float, float, float]:
    d = math.floor(value)
    m = math.floor((value - d) * 60.0)
    return float(d), float(m), (value - d - m / 60.0) * 3600.0


def _photo(path: Path, lat: float, lon: float, when: datetime, *, south_west: bool = False) -> None:
    """A JPEG as a phone writes it: capture time with sub-seconds and offset (local +02:00),
    the GPS time in whole seconds."""
    exif = Image.Exif()
    gps = exif.get_ifd(ExifTags.IFD.GPSInfo)
    gps[1], gps[2] = ("S" if south_west else "N"), _dms(abs(lat))
    gps[3], gps[4] = ("W" if south_west else "E"), _dms(abs(lon))
    gps[5], gps[6] = 0, 512.5
    gps[7], gps[29] = (float(when.hour), float(when.minute), float(when.second)), "2026:05:01"
    local = when + timedelta(hours=2)
    tags = exif.get_ifd(ExifTags.IFD.Exif)
    tags[0x9003] = local.strftime("%Y:%m:%d %H:%M:%S")
    tags[0x9291] = f"{when.microsecond // 1000:03d}"
    tags[0x9011] = "+02:00"
    rng = np.random.default_rng(len(path.name))
    pixels = rng.integers(0, 256, size=(12, 16, 3), dtype=np.uint8)
    Image.fromarray(pixels).save(path, exif=exif)


def _drive(folder: Path, n: int = 12) -> list[Path]:
    """Photos every 0.5 s along a straight road heading north-east at 10 m/s."""
    folder.mkdir()
    files = []
    for i in range(n):
        north = east = 10.0 * 0.5 * i / math.sqrt(2.0)
        lat = LAT0 + north / 111_195.0
        lon = LON0 + east / (111_195.0 * math.cos(math.radians(LAT0)))
        path = folder / f"IMG_{i:04d}.jpg"
        _photo(path, lat, lon, START + timedelta(seconds=0.5 * i))
        files.append(path)
    return files


def test_a_photos_fix_and_its_sub_second_capture_time(tmp_path: Path) -> None:
    files = _drive(tmp_path / "photos", n=3)
    track = read_exif_track(files)
    np.testing.assert_allclose(track.lat_lon_alt[0], [LAT0, LON0, 512.5], atol=1e-7)
    # 11:30:02.000 local at +02:00 is 09:30:02 UTC; the next photo 0.5 s later, which the
    # GPS time (whole seconds) could not tell
    assert track.stamp_ns[0] == round(START.timestamp() * 1e9)
    np.testing.assert_array_equal(np.diff(track.stamp_ns), 500_000_000)
    assert has_exif_gps(files[0])


def test_south_and_west_are_negative(tmp_path: Path) -> None:
    path = tmp_path / "rio.jpg"
    _photo(path, -22.9068, -43.1729, START, south_west=True)
    lat, lon, _ = read_exif_track([path]).lat_lon_alt[0]
    assert (lat, lon) == (pytest.approx(-22.9068, abs=1e-7), pytest.approx(-43.1729, abs=1e-7))


def test_import_with_poses_exif_places_every_photo_at_its_fix(tmp_path: Path) -> None:
    _drive(tmp_path / "photos")
    opts = ImportOptions(poses=Path("exif"))
    result = import_images(tmp_path / "ws", tmp_path / "photos", options=opts)
    assert result.info.world.georeferenced
    assert result.info.counts.frames == 12
    trajectory = read_table(DatasetPaths(tmp_path / "ws" / "dataset").trajectory_csv)
    step = np.hypot(np.diff(trajectory["x"]), np.diff(trajectory["y"]))
    np.testing.assert_allclose(step.sum(), 10.0 * 0.5 * 11, rtol=0.01)
    heading = np.degrees(np.arctan2(np.diff(trajectory["y"]), np.diff(trajectory["x"])))
    np.testing.assert_allclose(heading, 45.0, atol=1.0)  # north-east, in the ENU world


def test_photos_without_gps_or_with_whole_second_times_say_what_to_do(tmp_path: Path) -> None:
    folder = tmp_path / "plain"
    folder.mkdir()
    Image.fromarray(np.zeros((12, 16, 3), np.uint8)).save(folder / "a.jpg")
    with pytest.raises(RecordingError, match=r"a.jpg has no EXIF GPS position; geotag every"):
        import_images(tmp_path / "ws", folder, options=ImportOptions(poses=Path("exif")))
    burst = tmp_path / "burst"
    burst.mkdir()
    for i in range(2):  # two photos in one second, no sub-seconds written
        _photo(burst / f"b{i}.jpg", LAT0 + i * 1e-5, LON0, START)
    with pytest.raises(RecordingError, match=r"2 photos share an EXIF time .* whole seconds"):
        import_images(tmp_path / "ws2", burst, options=ImportOptions(poses=Path("exif")))


def test_an_import_without_poses_says_the_photos_are_geotagged(tmp_path: Path) -> None:
    _drive(tmp_path / "photos", n=3)
    result = import_images(tmp_path / "ws", tmp_path / "photos")
    assert any("--poses exif" in note for note in result.notes)
