"""Times as pose files, GPS tracks and signal tables write them, as int64 nanoseconds."""

from __future__ import annotations

from datetime import UTC, datetime

__all__ = ["iso_ns", "stamp_ns_from_text"]


def stamp_ns_from_text(text: str) -> int:
    """Nanoseconds of a time in seconds, or of an ISO 8601 date and time.

    A 16+ digit integer is taken as nanoseconds; a date and time (``2011-09-26 13:02:25.964``,
    ``...T...Z``) without a zone as UTC, every fractional digit kept.

    Raises:
        ValueError: The text is neither.
    """
    text = text.strip()
    if len(text) >= 19 and text[4] == "-" and text[10] in " T":
        return iso_ns(text)
    sec, _, frac = text.partition(".")
    if not frac and abs(int(sec)) > 10**15:
        return int(sec)
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
