"""``cam2sim map``: the typer command, run through a small app that registers it."""

from __future__ import annotations

import logging
import subprocess
import sys
from collections.abc import Iterator
from typing import TYPE_CHECKING

import pytest
import typer
from typer.testing import CliRunner, Result

from cam2sim.cli.display import StageErrorGroup
from cam2sim.cli.map_cmd import map_

from .map_helpers import MUNICH, closed_port_url, requires_carla

if TYPE_CHECKING:
    from cam2sim.core.workspace import Workspace

# A stage error ends in one line through the command group, as under the cam2sim root.
app = typer.Typer(cls=StageErrorGroup, add_completion=False, pretty_exceptions_enable=False)
app.command("map")(map_)


@app.callback()
def _root() -> None:
    """Test app holding the map command."""


@pytest.fixture(autouse=True)
def _restore_logging() -> Iterator[None]:
    root = logging.getLogger()
    handlers, level = root.handlers[:], root.level
    yield
    root.handlers[:] = handlers
    root.setLevel(level)


def invoke(*args: str) -> Result:
    return CliRunner().invoke(app, ["map", *args], env={"COLUMNS": "200"})


def test_help_lists_the_options() -> None:
    result = invoke("--help")
    assert result.exit_code == 0
    for flag in (
        "--osm",
        "--margin",
        "--road-types",
        "--lane-width",
        "--sidewalks",
        "--traffic-lights",
        "--overpass-url",
        "--refresh-osm",
        "--force",
    ):
        assert flag in result.output
    assert "cam2sim map ws --osm" in result.output


@requires_carla
def test_map_command_builds_the_map(street_ws: Workspace) -> None:
    result = invoke(str(street_ws.root), "--osm", str(MUNICH), "--margin", "80")
    assert result.exit_code == 0, result.output
    assert "map.xodr" in result.output
    assert "100.0% on a driving lane" in result.output
    assert (street_ws.map_dir / "map_report.json").is_file()
    again = invoke(str(street_ws.root), "--osm", str(MUNICH), "--margin", "80")
    assert "up to date" in again.output


def test_errors_are_one_line_and_exit_1(street_ws: Workspace) -> None:
    result = invoke(
        str(street_ws.root),
        "--road",
        "osm",
        "--overpass-url",
        closed_port_url(),
        "--overpass-retries",
        "0",
    )
    assert result.exit_code == 1
    assert "error:" in result.output
    assert "--osm" in result.output


def test_bad_option_values_are_errors(street_ws: Workspace) -> None:
    result = invoke(str(street_ws.root), "--osm", str(MUNICH), "--road-types", "footway")
    assert result.exit_code == 1
    assert "not drivable OSM highway values" in result.output
    result = invoke(str(street_ws.root), "--lane-width", "9")
    assert result.exit_code == 1
    assert "lane width 9.0" in result.output


def test_importing_the_command_loads_no_heavy_module() -> None:
    code = (
        "import sys, cam2sim.cli.map_cmd; "
        "heavy = [m for m in ('carla', 'osmium', 'pyproj', 'shapely', 'matplotlib') "
        "if m in sys.modules]; print(heavy)"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True
    ).stdout
    assert out.strip() == "[]"
