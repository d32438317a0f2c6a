"""Fetch OSM road data for a box from an Overpass API server, with retries and a disk cache."""

from __future__ import annotations

import hashlib
import logging
import socket
import time
import urllib.error
import urllib.parse
import urllib.request
from dataclasses import dataclass
from pathlib import Path  # noqa: TC003 - a dataclass field type
from typing import TYPE_CHECKING

from cam2sim import __version__
from cam2sim.core.errors import ConfigError, StageError
from cam2sim.core.files import write_bytes_atomic

if TYPE_CHECKING:
    from cam2sim.map.osm import BBox

__all__ = [
    "OverpassOptions",
    "OverpassResult",
    "OverpassUnreachableError",
    "cache_name",
    "fetch_overpass",
    "overpass_query",
]

logger = logging.getLogger(__name__)

DEFAULT_URL = "https://overpass-api.de/api/interpreter"
_RETRY_STATUS = frozenset({429, 500, 502, 503, 504})
_ERROR_REMARK = b"runtime error"


@dataclass(frozen=True)
class OverpassOptions:
    """How to reach the Overpass API.

    Attributes:
        url: Interpreter endpoint (``.../api/interpreter``).
        timeout_s: Network timeout of one request, seconds (the server gets the same budget).
        retries: Further attempts after a failed one (connection errors, 429 and 5xx answers).
        backoff_s: Wait before the first retry, doubled for each further one, seconds.
        refresh: Ignore a cached answer and ask the server again.
    """

    url: str = DEFAULT_URL
    timeout_s: float = 60.0
    retries: int = 3
    backoff_s: float = 2.0
    refresh: bool = False

    def __post_init__(self) -> None:
        scheme = urllib.parse.urlsplit(self.url).scheme
        if scheme not in ("http", "https"):
            msg = f"Overpass URL {self.url!r} is not http(s); give e.g. {DEFAULT_URL}"
            raise ConfigError(msg)
        if not (self.timeout_s > 0 and self.retries >= 0 and self.backoff_s >= 0):
            msg = (
                f"Overpass timeout_s={self.timeout_s!r}, retries={self.retries!r}, "
                f"backoff_s={self.backoff_s!r}; expected a positive timeout and non-negative rest"
            )
            raise ConfigError(msg)


@dataclass(frozen=True)
class OverpassResult:
    """An Overpass answer.

    Attributes:
        data: The OSM XML bytes.
        query: The Overpass QL that was sent.
        url: The server.
        cache_file: Where the answer is cached, if a cache folder was given.
        from_cache: Whether the answer came from the cache (no network).
    """

    data: bytes
    query: str
    url: str
    cache_file: Path | None
    from_cache: bool


def overpass_query(box: BBox, timeout_s: float = 60.0) -> str:
    """Return the Overpass QL for every highway way in ``box`` with all its nodes.

    Whole ways are returned, also their nodes outside the box, so roads crossing the box edge
    are not cut.
    """
    server_timeout = max(1, int(timeout_s))
    return (
        f'[out:xml][timeout:{server_timeout}];(way["highway"]({box.overpass()}););(._;>;);out body;'
    )


def cache_name(url: str, query: str) -> str:
    """File name of the cached answer of ``query`` at ``url``."""
    digest = hashlib.sha256(f"{url}\n{query}".encode()).hexdigest()[:16]
    return f"overpass-{digest}.osm"


def _request(url: str, query: str, timeout_s: float) -> bytes:
    body = urllib.parse.urlencode({"data": query}).encode()
    req = urllib.request.Request(  # noqa: S310 - scheme checked in OverpassOptions
        url,
        data=body,
        headers={
            "User-Agent": f"cam2sim/{__version__} (map stage)",
            "Content-Type": "application/x-www-form-urlencoded",
        },
        method="POST",
    )
    with urllib.request.urlopen(req, timeout=timeout_s) as resp:  # noqa: S310
        data: bytes = resp.read()
    return data


class OverpassUnreachableError(StageError):
    """The Overpass API could not be reached or kept failing (offline, say)."""


class _RetryableError(Exception):
    """A failure worth another attempt."""


class _NoNameError(Exception):
    """The server's name cannot be resolved: offline (or a typo); no attempt would fare better."""


def _attempt(options: OverpassOptions, query: str) -> bytes:
    try:
        data = _request(options.url, query, options.timeout_s)
    except urllib.error.HTTPError as err:
        if err.code in _RETRY_STATUS:
            msg = f"HTTP {err.code} {err.reason}"
            raise _RetryableError(msg) from None
        detail = err.read()[:300].decode("utf-8", "replace")
        msg = f"Overpass at {options.url} rejected the query: HTTP {err.code} ({detail.strip()})"
        raise StageError(msg) from None
    except (urllib.error.URLError, TimeoutError, ConnectionError, OSError) as err:
        reason = getattr(err, "reason", err)
        if isinstance(reason, socket.gaierror):
            raise _NoNameError(str(reason)) from None
        raise _RetryableError(str(reason)) from None
    if _ERROR_REMARK in data[-2000:]:
        msg = "the server answered with a runtime error (query timeout or too much data)"
        raise _RetryableError(msg)
    return data


def fetch_overpass(
    box: BBox, *, options: OverpassOptions | None = None, cache_dir: Path | None = None
) -> OverpassResult:
    """Fetch every highway way in ``box`` as OSM XML, from the cache when there.

    Args:
        box: The box to query.
        options: Server, timeouts and retries.
        cache_dir: Folder of cached answers; a fresh answer is written there.

    Returns:
        The answer.

    Raises:
        StageError: The server cannot be reached, or keeps failing, after every retry; the
            message says to pass ``--osm FILE`` instead.
    """
    options = options or OverpassOptions()
    query = overpass_query(box, options.timeout_s)
    cache_file = cache_dir / cache_name(options.url, query) if cache_dir is not None else None
    if cache_file is not None and cache_file.is_file() and not options.refresh:
        logger.info("using cached Overpass answer %s", cache_file)
        return OverpassResult(
            cache_file.read_bytes(), query, options.url, cache_file, from_cache=True
        )
    last = ""
    for attempt in range(options.retries + 1):
        if attempt:
            wait = options.backoff_s * 2 ** (attempt - 1)
            logger.info("Overpass attempt %d failed (%s); retrying in %.1f s", attempt, last, wait)
            time.sleep(wait)
        try:
            data = _attempt(options, query)
        except _RetryableError as err:
            last = str(err)
            continue
        except _NoNameError as err:  # no DNS: retrying only waits
            last = f"{err}: no name resolution, offline?"
            break
        logger.info("fetched %d bytes of OSM data from %s", len(data), options.url)
        if cache_file is not None:
            write_bytes_atomic(cache_file, data)
        return OverpassResult(data, query, options.url, cache_file, from_cache=False)
    msg = (
        f"cannot get OSM data from the Overpass API at {options.url} after "
        f"{attempt + 1} attempt{'s' if attempt else ''} ({last}); when offline, pass --osm "
        f"FILE with an OSM extract covering {box} (export it from openstreetmap.org or JOSM)"
    )
    raise OverpassUnreachableError(msg)
