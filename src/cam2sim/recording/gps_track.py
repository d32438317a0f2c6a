"""GPS tracks as loggers, phones and dash cameras write them: GPX files and NMEA 0183 logs.

Both read into the same WGS84 fixes a GPS CSV gives (:class:`~cam2sim.recording.pose_file.
PoseTable` with ``geographic``: latitude, longitude in degrees, altitude in metres, UTC times
in nanoseconds, no orientation: the import heads the car where it travels).

- GPX 1.0/1.1: every ``<trkpt>`` of every track and segment, in time order, with its ``<ele>``
  (0 where absent) and ``<time>`` (required: a track without times cannot be matched to images).
- NMEA 0183: ``GGA`` (position, fix quality, altitude) and ``RMC`` (position, status, date)
  sentences of any talker (``$GP``, ``$GN``, ``$GL``...), checksums verified when present, a
  logger's prefix before the ``$`` ignored. Sentences without a fix (GGA quality 0, RMC status
  ``V``) are skipped; a GGA takes the date of the last RMC, and a log without any RMC counts
  from midnight of 1970-01-01 (the times then only order the fixes: give ``--start``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from datetime import UTC, date, datetime, timedelta
from typing import TYPE_CHECKING

import numpy as np

from cam2sim.core.errors import RecordingError
from cam2sim.recording.timestamps import stamp_ns_from_text

if TYPE_CHECKING:
    from pathlib import Path

    import numpy.typing as npt

__all__ = ["GpsTrack", "is_nmea", "read_gpx", "read_nmea"]

_DAY_NS = 86_400 * 1_000_000_000


@dataclass(frozen=True)
class GpsTrack:
    """Fixes of a GPS track, in time order.

    Attributes:
        stamp_ns: ``(N,)`` int64 UTC times, nanoseconds since the epoch.
        lat_lon_alt: ``(N, 3)`` WGS84 latitude, longitude (degrees), altitude (metres).
        skipped: Why records were left out, and how many (``{"no fix": 3}``).
        dated: Whether the times carry a date (False: an NMEA log without RMC sentences).
    """

    stamp_ns: npt.NDArray[np.int64]
    lat_lon_alt: npt.NDArray[np.float64]
    skipped: dict[str, int] = field(default_factory=dict)
    dated: bool = True


def _local(tag: str) -> str:
    """An XML tag without its namespace (``{http://www.topografix.com/GPX/1/1}trkpt``)."""
    return tag.rsplit("}", 1)[-1]


def read_gpx(path: Path) -> GpsTrack:
    """Every track point of a GPX file, in time order.

    Raises:
        RecordingError: Not GPX XML, no track points, a point without a time or with a bad
            coordinate (the message names the point).
    """
    from xml.etree import ElementTree as ET  # noqa: PLC0415 -- lazy: only GPX needs it

    try:
        root = ET.parse(path).getroot()  # noqa: S314 -- a local file the user gives
    except ET.ParseError as err:
        msg = f"{path}: not a readable GPX (XML) file ({err}); export the track again as GPX"
        raise RecordingError(msg) from None
    if _local(root.tag) != "gpx":
        msg = f"{path}: the XML root is <{_local(root.tag)}>, not <gpx>; give a GPX track"
        raise RecordingError(msg)
    rows: list[tuple[int, float, float, float]] = []
    for k, point in enumerate(e for e in root.iter() if _local(e.tag) == "trkpt"):
        children = {_local(c.tag): (c.text or "").strip() for c in point}
        where = f"{path}: track point {k + 1}"
        if not children.get("time"):
            msg = (
                f"{where} has no <time>; a track without times cannot be matched to the images "
                "(record it with times, or give a CSV with an image column)"
            )
            raise RecordingError(msg)
        try:
            lat, lon = float(point.attrib["lat"]), float(point.attrib["lon"])
            alt = float(children["ele"]) if children.get("ele") else 0.0
            stamp = stamp_ns_from_text(children["time"])
        except KeyError:
            msg = f"{where} lacks its lat or lon attribute"
            raise RecordingError(msg) from None
        except ValueError as err:
            msg = f"{where}: {err}; fix that point"
            raise RecordingError(msg) from None
        rows.append((stamp, lat, lon, alt))
    if not rows:
        msg = f"{path}: no <trkpt> track points (routes and waypoints have no times); give a track"
        raise RecordingError(msg)
    return _track(rows, {}, dated=True, path=path)


def is_nmea(lines: list[str]) -> bool:
    """Whether the first non-empty lines look like NMEA sentences (``$GPGGA,...``)."""
    head = [ln for ln in lines[:20] if ln.strip()]
    return bool(head) and sum("$" in ln and "," in ln for ln in head) >= max(1, len(head) // 2)


def _checksum_ok(sentence: str) -> bool:
    """An NMEA sentence's ``*hh`` checksum (XOR of the characters between ``$`` and ``*``)."""
    body, star, given = sentence[1:].partition("*")
    if not star:
        return True  # some loggers drop it
    value = 0
    for ch in body.encode("ascii", "replace"):
        value ^= ch
    try:
        return value == int(given[:2], 16)
    except ValueError:
        return False


def _degrees(value: str, hemisphere: str) -> float:
    """NMEA's ``(d)ddmm.mmmm`` and ``N/S/E/W`` as signed degrees."""
    raw = float(value)
    deg = math.floor(raw / 100.0)
    out = deg + (raw - 100.0 * deg) / 60.0
    return -out if hemisphere in ("S", "W") else out


def _time_of_day_ns(hhmmss: str) -> int:
    """NMEA's ``hhmmss(.sss)`` as nanoseconds since midnight."""
    whole, _, frac = hhmmss.partition(".")
    h, m, s = int(whole[0:2]), int(whole[2:4]), int(whole[4:6])
    return ((h * 60 + m) * 60 + s) * 1_000_000_000 + int((frac + "000000000")[:9])


@dataclass
class _NmeaState:
    """What reading an NMEA log has gathered so far.

    ``day`` is the date of the fixes being read: the first RMC's before it is met (found
    ahead), each RMC's after, one more when the time of day jumps back past midnight.
    """

    day: date
    last_tod: int | None = None
    fixes: dict[int, tuple[float, float, float | None]] = field(default_factory=dict)
    skipped: dict[str, int] = field(default_factory=dict)

    def skip(self, why: str) -> None:
        self.skipped[why] = self.skipped.get(why, 0) + 1

    def stamp(self, tod: int) -> int:
        """Nanoseconds since the epoch of a time of day on :attr:`day`."""
        if self.last_tod is not None and tod < self.last_tod - _DAY_NS // 2:
            self.day += timedelta(days=1)  # past midnight before an RMC says so
        self.last_tod = tod
        midnight = datetime(self.day.year, self.day.month, self.day.day, tzinfo=UTC)
        return int(midnight.timestamp()) * 1_000_000_000 + tod


def _rmc_date(f: list[str]) -> date | None:
    """The date of an RMC sentence's fields (``ddmmyy``), or None: not an RMC or no date."""
    if len(f[0]) != 6 or f[0][3:] != "RMC" or len(f) < 10 or len(f[9]) != 6:
        return None
    try:
        return date(2000 + int(f[9][4:6]), int(f[9][2:4]), int(f[9][0:2]))
    except ValueError:
        return None


def _sentence(line: str) -> list[str] | None:
    """The comma fields of the NMEA sentence in ``line`` (prefix and checksum removed)."""
    start = line.find("$")
    if start < 0:
        return None
    sentence = line[start:].strip()
    if not _checksum_ok(sentence):
        return []
    return sentence.partition("*")[0].split(",")


def _read_rmc(f: list[str], st: _NmeaState) -> None:
    # $--RMC,hhmmss.ss,A,llll.ll,a,yyyyy.yy,a,speed,course,ddmmyy,...
    day = _rmc_date(f)
    if not f[1] or day is None:
        st.skip("RMC without time or date")
        return
    st.day, st.last_tod = day, None
    if f[2] != "A" or not f[3] or not f[5]:
        st.skip("no fix")
        return
    stamp = st.stamp(_time_of_day_ns(f[1]))
    old = st.fixes.get(stamp)
    alt = old[2] if old is not None else None  # a GGA of the same second keeps its altitude
    st.fixes[stamp] = (_degrees(f[3], f[4]), _degrees(f[5], f[6]), alt)


def _read_gga(f: list[str], st: _NmeaState) -> None:
    # $--GGA,hhmmss.ss,llll.ll,a,yyyyy.yy,a,quality,sats,hdop,alt,M,...
    if len(f) < 10 or not f[1]:
        st.skip("GGA without time")
        return
    if f[6] in ("", "0") or not f[2] or not f[4]:
        st.skip("no fix")
        return
    stamp = st.stamp(_time_of_day_ns(f[1]))
    st.fixes[stamp] = (_degrees(f[2], f[3]), _degrees(f[4], f[5]), float(f[9]) if f[9] else 0.0)


def read_nmea(path: Path, lines: list[str]) -> GpsTrack:
    """The fixes of an NMEA 0183 log (GGA and RMC sentences), one per time, in time order.

    Raises:
        RecordingError: No GGA or RMC sentence with a fix (the message counts what was
            skipped), or a field that is not a number (the message names the line).
    """
    sentences = [(n, _sentence(line)) for n, line in enumerate(lines, 1)]
    first_day = next((d for _, f in sentences if f and (d := _rmc_date(f))), None)
    st = _NmeaState(day=first_day or date(1970, 1, 1))
    for n, f in sentences:
        if f is None:
            continue
        if not f:
            st.skip("bad checksum")
            continue
        kind = f[0][3:] if len(f[0]) == 6 else ""
        try:
            if kind == "RMC":
                _read_rmc(f, st)
            elif kind == "GGA":
                _read_gga(f, st)
        except (ValueError, IndexError) as err:
            msg = f"{path}:{n}: not a valid {kind} sentence ({err}); fix or remove that line"
            raise RecordingError(msg) from None
    if not st.fixes:
        seen = ", ".join(f"{k}: {v}" for k, v in st.skipped.items()) or "none"
        msg = (
            f"{path}: no GGA or RMC sentence with a fix (skipped: {seen}); give the log of a "
            "drive the receiver had a fix for"
        )
        raise RecordingError(msg)
    rows = [(s, lat, lon, alt or 0.0) for s, (lat, lon, alt) in st.fixes.items()]
    return _track(rows, st.skipped, dated=first_day is not None, path=path)


def _track(
    rows: list[tuple[int, float, float, float]],
    skipped: dict[str, int],
    *,
    dated: bool,
    path: Path,
) -> GpsTrack:
    """Rows ``(stamp, lat, lon, alt)`` as a track in time order, checked."""
    stamps = np.array([r[0] for r in rows], dtype=np.int64)
    lla = np.array([r[1:] for r in rows], dtype=np.float64).reshape(-1, 3)
    order = np.argsort(stamps, kind="stable")
    stamps, lla = stamps[order], lla[order]
    if (np.diff(stamps) == 0).any():
        msg = f"{path}: two fixes share a time; remove the duplicates"
        raise RecordingError(msg)
    bad = ~(np.isfinite(lla).all(axis=1) & (np.abs(lla[:, 0]) < 90) & (np.abs(lla[:, 1]) <= 180))
    if bad.any():
        msg = (
            f"{path}: {int(bad.sum())} fix(es) outside +-90 degrees latitude or +-180 longitude "
            f"(first at {lla[bad][0, 0]:.6f}, {lla[bad][0, 1]:.6f}); fix or remove them"
        )
        raise RecordingError(msg)
    return GpsTrack(stamps, lla, skipped, dated)
