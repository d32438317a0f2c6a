"""Times as users' tables write them: seconds, epoch ms/us/ns, dates, times of day, units."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import pytest

from cam2sim.core.errors import RecordingError
from cam2sim.recording.pose_file import read_pose_file, table_stamps
from cam2sim.recording.timestamps import stamp_ns_from_text

if TYPE_CHECKING:
    from pathlib import Path

NS = 1_500_000_000_500_000_000  # 2017-07-14 02:40:00.5 UTC


@pytest.mark.parametrize(
    ("text", "unit", "want"),
    [
        ("1500000000.5", None, NS),
        ("1500000000500", None, NS),  # epoch milliseconds, told by their 13 digits
        ("1500000000500000", None, NS),  # microseconds
        ("1500000000500000000", None, NS),  # nanoseconds
        ("2017-07-14 02:40:00.5", None, NS),
        ("2017/07/14 02:40:00.5", None, NS),
        ("2017-07-14T04:40:00.5+02:00", None, NS),
        ("02:40:00.5", None, (2 * 3600 + 40 * 60) * 10**9 + 5 * 10**8),  # from midnight
        ("100", "ms", 100_000_000),  # a relative time whose unit the header gave
        ("0.25", "ms", 250_000),
        ("12", None, 12 * 10**9),  # small whole numbers stay seconds
    ],
)
def test_a_time_in_any_of_its_usual_forms(text: str, unit: str | None, want: int) -> None:
    assert stamp_ns_from_text(text, unit) == want


def test_a_time_unit_that_is_none_says_so() -> None:
    with pytest.raises(ValueError, match="unknown time unit 'min'"):
        stamp_ns_from_text("3", "min")


def test_the_column_name_or_header_gives_the_unit_and_times_of_day_cross_midnight() -> None:
    rows = [{"time_ms": "0"}, {"time_ms": "100"}]
    np.testing.assert_array_equal(table_stamps(rows, "time_ms"), [0, 100_000_000])
    rows = [{"t": "0"}, {"t": "100"}]
    np.testing.assert_array_equal(table_stamps(rows, "t", "ms"), [0, 100_000_000])
    night = [{"time": "23:59:59.5"}, {"time": "00:00:00.0"}, {"time": "00:00:00.5"}]
    stamps = table_stamps(night, "time")
    np.testing.assert_array_equal(np.diff(stamps), [500_000_000, 500_000_000])


def test_a_gps_csv_with_units_in_its_header(tmp_path: Path) -> None:
    path = tmp_path / "log.csv"
    path.write_text(
        "Time [ms],Latitude (deg),Longitude (deg),Altitude (m)\n"
        "0,48.1,11.5,500\n100,48.10001,11.5,500\n200,48.10002,11.5,500\n"
    )
    table = read_pose_file(path)
    assert table.geographic
    np.testing.assert_array_equal(table.stamp_ns, [0, 100_000_000, 200_000_000])
    np.testing.assert_allclose(table.xyz[:, 2], 500.0)


@pytest.mark.parametrize(
    "header",
    ["datetime,gps_lat,gps_lng,elevation", "utc,latitude_deg,longitude_deg,height",
     "unix_time,lat,long,ele"],
)  # fmt: skip
def test_a_gps_csv_under_other_loggers_column_names(tmp_path: Path, header: str) -> None:
    path = tmp_path / "log.csv"
    first = "2026-05-01T10:00:00.000Z" if header.startswith("datetime") else "1777629600.0"
    second = "2026-05-01T10:00:00.100Z" if header.startswith("datetime") else "1777629600.1"
    path.write_text(f"{header}\n{first},48.1,11.5,500\n{second},48.10001,11.5,501\n")
    table = read_pose_file(path)
    assert table.geographic
    assert table.stamp_ns[1] - table.stamp_ns[0] == 100_000_000
    np.testing.assert_allclose(table.xyz[:, 1], 11.5)
    np.testing.assert_allclose(table.xyz[:, 2], [500.0, 501.0])


def test_milliseconds_written_as_seconds_stop_the_import(tmp_path: Path) -> None:
    """8 m/s with times in ms and no unit: 0.008 m/s, which no car drives for 100 m."""
    import cv2

    from cam2sim.stages.image_import import ImportOptions, import_images

    rows = ["t,x,y"] + [f"{k * 100},{0.8 * k:.3f},0" for k in range(130)]
    (tmp_path / "poses.csv").write_text("\n".join(rows) + "\n")
    (tmp_path / "images").mkdir()
    for k in range(3):
        cv2.imwrite(str(tmp_path / "images" / f"{k:03d}.png"), np.zeros((8, 8, 3), np.uint8))
    opts = ImportOptions(poses=tmp_path / "poses.csv", fps=0.01)
    with pytest.raises(RecordingError, match=r"0.008 m/s.*not in seconds.*time_ms"):
        import_images(tmp_path / "ws", tmp_path / "images", options=opts)


def test_a_repeated_fix_is_kept_once_and_different_poses_at_one_time_are_refused(
    tmp_path: Path,
) -> None:
    path = tmp_path / "log.csv"
    path.write_text(
        "t,lat,lon\n0.0,48.1,11.5\n0.1,48.10001,11.5\n0.1,48.10001,11.5\n0.2,48.10002,11.5\n"
    )
    table = read_pose_file(path)  # the logger repeated its fix at 0.1 s until a new one came
    np.testing.assert_array_equal(table.stamp_ns, [0, 100_000_000, 200_000_000])
    path.write_text("t,lat,lon\n0,48.1,11.5\n0,48.10001,11.5\n1,48.10002,11.5\n")
    with pytest.raises(
        RecordingError,
        match=r"two different poses share the timestamp 0\.0+;.*"
        r"whole seconds",
    ):
        read_pose_file(path)
