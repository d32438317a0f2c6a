"""Times as pose files, GPS tracks and signal tables write them, as int64 nanoseconds."""

from __future__ import annotations

import re
from datetime import UTC, datetime
from typing import Final

__all__ = ["UNIT_NS", "is_time_of_day", "iso_ns", "stamp_ns_from_text"]

UNIT_NS: Final = {
    "s": 1_000_000_000,
    "sec": 1_000_000_000,
    "ms": 1_000_000,
    "us": 1_000,
    "µs": 1_000,
    "ns": 1,
}
"""Nanoseconds in a unit a table's header may name (``time [ms]``, ``stamp_ns``)."""

_EPOCH_DIGITS: Final = ((10**17, 1), (10**14, 1_000), (10**11, 1_000_000))
"""A whole number this large is an epoch time in ns, us or ms: seconds since 1970 are ten
digits until 2286, and no relative time in seconds reaches 10**11 (3,000 years)."""

_TIME_OF_DAY = re.compile(r"(\d{1,2}):(\d{2}):(\d{2})(\.\d+)?")


def is_time_of_day(text: str) -> bool:
    """Whether ``text`` is a bare time of day (``13:02:25.5``), which counts from midnight."""
    return _TIME_OF_DAY.fullmatch(text.strip()) is not None


def stamp_ns_from_text(text: str, unit: str | None = None) -> int:
    """Nanoseconds of a time in seconds (or ``unit``), an ISO 8601 date, or a time of day.

    A whole number of 12 or more digits is an epoch time in ms, us or ns by its size (seconds
    since 1970 have ten); ``unit`` (``s``, ``ms``, ``us``, ``ns``) overrides that. A date and
    time (``2011-09-26 13:02:25.964``, ``2011/09/26 ...``, ``...T...Z``) without a zone is UTC,
    every fractional digit kept; a bare time of day (``13:02:25.5``) counts from midnight.

    Raises:
        ValueError: The text is none of these, or ``unit`` is not a time unit.
    """
    text = text.strip()
    if len(text) >= 19 and text[4] in "-/" and text[7] in "-/" and text[10] in " T":
        return iso_ns(text[:10].replace("/", "-") + text[10:])
    if (clock := _TIME_OF_DAY.fullmatch(text)) is not None:
        h, m, s, frac = clock.groups()
        whole = (int(h) * 3600 + int(m) * 60 + int(s)) * 1_000_000_000
        return whole + int(((frac or ".")[1:] + "000000000")[:9])
    if unit is not None and unit != "s":
        if unit not in UNIT_NS:
            msg = f"unknown time unit {unit!r}; use one of {', '.join(UNIT_NS)}"
            raise ValueError(msg)
        digits, dot, _ = text.partition(".")
        if not dot:
            return int(digits) * UNIT_NS[unit]  # exact for whole numbers
        return round(float(text) * UNIT_NS[unit])
    sec, _, frac = text.partition(".")
    if not frac and unit is None:
        whole = int(sec)
        for size, scale in _EPOCH_DIGITS:
            if abs(whole) >= size:
                return whole * scale
    return int(sec) * 1_000_000_000 + int((frac + "000000000")[:9]) * (
        -1 if sec.startswith("-") else 1
    )


def iso_ns(text: str) -> int:
    """Nanoseconds since the epoch of an ISO 8601 date and time (UTC when it names no zone)."""
    head, frac, tail = text[:19], "", text[19:]
    if tail.startswith("."):
        digits = len(tail) - len(tail[1:].lstrip("0123456789"))
        frac, tail = tail[1:digits], tail[digits:]
    moment = datetime.fromisoformat(head.replace(" ", "T") + tail)
    if moment.tzinfo is None:
        moment = moment.replace(tzinfo=UTC)
    seconds = int(moment.timestamp())
    return seconds * 1_000_000_000 + int((frac + "000000000")[:9])
