"""GPS fixes from photos' EXIF tags: a phone's or action camera's geotagged frames.

A camera that geotags writes each photo's fix into its EXIF GPS directory (``GPSLatitude``
with ``GPSLatitudeRef``, ``GPSLongitude``, ``GPSAltitude``, ``GPSDateStamp`` and
``GPSTimeStamp`` in UTC) and when it was taken into its Exif directory
(``DateTimeOriginal``, ``SubSecTimeOriginal``, ``OffsetTimeOriginal``). :func:`read_exif_track`
reads them for every image into a GPS track, each fix at its photo's time: the capture time
to the sub-second where the camera wrote one (phones write the GPS time in whole seconds),
moved to UTC by its offset (local time taken as UTC without one), else the GPS time.
"""

from __future__ import annotations

from datetime import UTC, datetime, timedelta
from typing import TYPE_CHECKING, Any

import numpy as np

from cam2sim.core.errors import RecordingError
from cam2sim.recording.gps_track import GpsTrack

if TYPE_CHECKING:
    from pathlib import Path

__all__ = ["has_exif_gps", "read_exif_track"]

_GPS_IFD, _EXIF_IFD = 0x8825, 0x8769
_LAT_REF, _LAT, _LON_REF, _LON, _ALT_REF, _ALT, _GPS_TIME, _GPS_DATE = 1, 2, 3, 4, 5, 6, 7, 29
_TAKEN, _SUBSEC, _OFFSET = 0x9003, 0x9291, 0x9011


def has_exif_gps(path: Path) -> bool:
    """Whether ``path`` (a JPEG, TIFF or PNG) carries an EXIF GPS position (False: unreadable)."""
    try:
        gps, _ = _tags(path)
    except RecordingError:
        return False
    return _LAT in gps and _LON in gps


def read_exif_track(files: list[Path]) -> GpsTrack:
    """The fix of every photo, at its photo's time (see the module's docstring).

    Raises:
        RecordingError: A photo has no GPS position or no time; the message names it.
    """
    stamps, rows = [], []
    for path in files:
        gps, exif = _tags(path)
        if _LAT not in gps or _LON not in gps:
            msg = (
                f"{path} has no EXIF GPS position; geotag every frame, or give the poses in a "
                "file (--poses)"
            )
            raise RecordingError(msg)
        lat = _degrees(path, gps[_LAT]) * (-1.0 if _text(gps.get(_LAT_REF)) == "S" else 1.0)
        lon = _degrees(path, gps[_LON]) * (-1.0 if _text(gps.get(_LON_REF)) == "W" else 1.0)
        alt = float(gps.get(_ALT, 0.0)) * (-1.0 if _below_sea(gps.get(_ALT_REF)) else 1.0)
        stamps.append(_taken_ns(path, gps, exif))
        rows.append((lat, lon, alt))
    return GpsTrack(np.asarray(stamps, dtype=np.int64), np.asarray(rows, dtype=np.float64))


def _tags(path: Path) -> tuple[dict[int, Any], dict[int, Any]]:
    from PIL import Image, UnidentifiedImageError  # noqa: PLC0415 -- lazy: only geotagged frames

    try:
        with Image.open(path) as image:
            exif = image.getexif()
            return dict(exif.get_ifd(_GPS_IFD)), {**dict(exif), **dict(exif.get_ifd(_EXIF_IFD))}
    except (OSError, UnidentifiedImageError) as err:
        msg = f"{path}: cannot read its EXIF tags ({err})"
        raise RecordingError(msg) from None


def _degrees(path: Path, value: Any) -> float:
    """Degrees, minutes, seconds (three rationals) as degrees."""
    try:
        d, m, s = (float(v) for v in value)
    except (TypeError, ValueError, ZeroDivisionError):
        msg = f"{path}: EXIF GPS coordinate {value!r} is not degrees, minutes, seconds"
        raise RecordingError(msg) from None
    return d + m / 60.0 + s / 3600.0


def _text(value: Any) -> str:
    return value.decode(errors="replace").strip("\x00 ") if isinstance(value, bytes) else str(value)


def _below_sea(value: Any) -> bool:
    return (value[:1] == b"\x01") if isinstance(value, bytes) else value == 1


def _taken_ns(path: Path, gps: dict[int, Any], exif: dict[int, Any]) -> int:
    """The photo's time: its capture time (sub-second, to UTC by its offset), else GPS time."""
    taken = exif.get(_TAKEN) or exif.get(0x0132)  # DateTimeOriginal, else DateTime
    if taken:
        try:
            when = datetime.strptime(_text(taken), "%Y:%m:%d %H:%M:%S").replace(tzinfo=UTC)
        except ValueError:
            when = None
        if when is not None:
            sub = _text(exif.get(_SUBSEC, "")).strip()
            fraction = float(f"0.{sub}") if sub.isdigit() else 0.0
            offset = _text(exif.get(_OFFSET, "")).strip()
            if len(offset) == 6 and offset[0] in "+-" and offset[3] == ":":
                sign = -1 if offset[0] == "-" else 1
                when -= sign * timedelta(hours=int(offset[1:3]), minutes=int(offset[4:6]))
            return round((when.timestamp() + fraction) * 1e9)
    if _GPS_DATE in gps and _GPS_TIME in gps:
        try:
            day = datetime.strptime(_text(gps[_GPS_DATE]), "%Y:%m:%d").replace(tzinfo=UTC)
            h, m, s = (float(v) for v in gps[_GPS_TIME])
        except (TypeError, ValueError, ZeroDivisionError):
            day = None
        if day is not None:
            return round((day.timestamp() + h * 3600.0 + m * 60.0 + s) * 1e9)
    msg = f"{path}: no EXIF capture time (DateTimeOriginal) or GPS time; its fix has no time"
    raise RecordingError(msg)
