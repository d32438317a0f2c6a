"""Fixtures of the map tests (helpers live in map_helpers.py)."""

from __future__ import annotations

from typing import TYPE_CHECKING

import pytest

from cam2sim.map.osm import OsmData, read_osm

from .map_helpers import ROUTE_WAY, FakeOverpass, Route, make_workspace, osm_file, route_along_way

if TYPE_CHECKING:
    from collections.abc import Callable, Iterator
    from pathlib import Path

    from cam2sim.core.workspace import Workspace


@pytest.fixture(scope="session")
def munich() -> OsmData:
    return read_osm(osm_file("munich.osm"))


@pytest.fixture(scope="session")
def street_route(munich: OsmData) -> Route:
    return route_along_way(munich, ROUTE_WAY)


@pytest.fixture
def street_ws(tmp_path: Path, street_route: Route) -> Workspace:
    return make_workspace(tmp_path / "ws", street_route)


@pytest.fixture
def fake_overpass() -> Iterator[Callable[[list[tuple[int, bytes]]], FakeOverpass]]:
    servers: list[FakeOverpass] = []

    def start(answers: list[tuple[int, bytes]]) -> FakeOverpass:
        server = FakeOverpass(answers)
        servers.append(server)
        return server

    yield start
    for server in servers:
        server.close()
