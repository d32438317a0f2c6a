"""Overpass fetching against a local fake server: query, cache, retries, clear failures."""

from __future__ import annotations

import urllib.parse
from pathlib import Path

import pytest

from cam2sim.core.errors import ConfigError, StageError
from cam2sim.map.osm import BBox
from cam2sim.map.overpass import OverpassOptions, cache_name, fetch_overpass, overpass_query

from .map_helpers import closed_port_url

BOX = BBox(48.18, 11.54, 48.19, 11.56)
ANSWER = b"<?xml version='1.0'?><osm version='0.6'><node id='1' lat='48.185' lon='11.55'/></osm>"


def fast(url: str, **kwargs: object) -> OverpassOptions:
    return OverpassOptions(url=url, timeout_s=5.0, backoff_s=0.0, **kwargs)  # type: ignore[arg-type]


def test_query_asks_for_whole_highway_ways_in_the_box() -> None:
    q = overpass_query(BOX, timeout_s=30.0)
    assert '(way["highway"](48.1800000,11.5400000,48.1900000,11.5600000););' in q
    assert "(._;>;);" in q
    assert q.startswith("[out:xml][timeout:30];")


def test_fetch_posts_the_query_and_caches_the_answer(tmp_path: Path, fake_overpass) -> None:
    server = fake_overpass([(200, ANSWER)])
    result = fetch_overpass(BOX, options=fast(server.url), cache_dir=tmp_path)
    assert result.data == ANSWER
    assert not result.from_cache
    assert server.requests[0]["data"] == [overpass_query(BOX, 5.0)]
    assert result.cache_file == tmp_path / cache_name(server.url, result.query)
    assert result.cache_file.read_bytes() == ANSWER
    # The second call is answered from the cache: the server sees nothing.
    again = fetch_overpass(BOX, options=fast(server.url), cache_dir=tmp_path)
    assert again.from_cache
    assert again.data == ANSWER
    assert len(server.requests) == 1
    fresh = fetch_overpass(BOX, options=fast(server.url, refresh=True), cache_dir=tmp_path)
    assert not fresh.from_cache
    assert len(server.requests) == 2


def test_busy_server_is_retried(fake_overpass) -> None:
    server = fake_overpass([(429, b"busy"), (504, b"gateway"), (200, ANSWER)])
    result = fetch_overpass(BOX, options=fast(server.url, retries=2))
    assert result.data == ANSWER
    assert len(server.requests) == 3


def test_runtime_error_remark_counts_as_a_failure(fake_overpass) -> None:
    remark = b"<osm><remark> runtime error: Query timed out </remark></osm>"
    server = fake_overpass([(200, remark)])
    with pytest.raises(StageError, match="runtime error"):
        fetch_overpass(BOX, options=fast(server.url, retries=1))
    assert len(server.requests) == 2


def test_rejected_query_is_not_retried(fake_overpass) -> None:
    server = fake_overpass([(400, b"parse error: line 1")])
    with pytest.raises(StageError, match=r"rejected the query: HTTP 400 \(parse error"):
        fetch_overpass(BOX, options=fast(server.url, retries=3))
    assert len(server.requests) == 1


def test_unreachable_server_says_to_pass_osm() -> None:
    url = closed_port_url()
    with pytest.raises(StageError, match=r"after 2 attempts .*pass --osm FILE") as info:
        fetch_overpass(BOX, options=fast(url, retries=1))
    assert urllib.parse.urlsplit(url).netloc in str(info.value)


def test_a_name_that_does_not_resolve_is_not_retried(monkeypatch: pytest.MonkeyPatch) -> None:
    """Offline, DNS fails at once; four attempts would only add the backoff's waits."""
    import socket
    import urllib.error

    from cam2sim.map import overpass

    calls: list[str] = []

    def no_dns(url: str, query: str, timeout_s: float) -> bytes:
        calls.append(url)
        raise urllib.error.URLError(socket.gaierror(-2, "Name or service not known"))

    monkeypatch.setattr(overpass, "_request", no_dns)
    with pytest.raises(StageError, match=r"after 1 attempt \(.*no name resolution.*--osm FILE"):
        fetch_overpass(BOX, options=fast("https://overpass.invalid/api/interpreter", retries=3))
    assert len(calls) == 1


def test_options_are_validated() -> None:
    with pytest.raises(ConfigError, match="not http"):
        OverpassOptions(url="ftp://example.invalid/api")
    with pytest.raises(ConfigError, match="positive timeout"):
        OverpassOptions(timeout_s=0.0)
