"""The built-in demo streets: the paper's street and the choice of street."""

from __future__ import annotations

import json
import math
from typing import TYPE_CHECKING

import numpy as np
import pytest

from cam2sim.core.errors import ConfigError
from cam2sim.demo.recording import recorded_street
from cam2sim.demo.world import (
    L_STREET,
    PAPER_STREET,
    STREETS,
    demo_street,
    demo_world,
)

if TYPE_CHECKING:
    from pathlib import Path

EGO_HALF_WIDTH = 1.08  # the scenario's vehicle, mirrors included


def test_the_paper_street_is_the_papers() -> None:
    street = PAPER_STREET
    assert 440.0 < street.length_m < 460.0
    assert len(street.route.bends()) == 3
    assert street.speed_mps == pytest.approx(20 / 3.6)
    assert not street.lane_markings
    world = demo_world(0, street)
    assert world.truth_world().lane_markings is False
    assert L_STREET.lane_markings
    assert demo_world(0).truth_world().lane_markings
    # The truth world says what it is (the report's inputs show it).
    noted = world.truth_world(notes=("built-in",))
    assert (noted.title, noted.notes) == (street.title, ("built-in",))


def test_parked_cars_narrow_the_lane_but_leave_the_recorded_car_room() -> None:
    street = PAPER_STREET
    world = demo_world(0, street)
    s = np.arange(0.0, street.length_m, 0.25)
    xy, heading = street.drive_points(s)
    route_xy, _ = street.route_points(s)
    narrowing, clearance = [], []
    for car in world.cars:
        k = int(np.argmin(np.hypot(*(route_xy - [car.x, car.y]).T)))
        nx, ny = -math.sin(heading[k]), math.cos(heading[k])
        lateral = abs((car.x - route_xy[k, 0]) * nx + (car.y - route_xy[k, 1]) * ny)
        if lateral < street.lane_m + street.parking_m:  # the right side, beside the route
            narrowing.append(street.lane_m / 2 - (lateral - car.width / 2))
            near = np.abs(s - s[k]) < car.length / 2 + 2.0
            d = np.abs((car.x - xy[near, 0]) * nx + (car.y - xy[near, 1]) * ny)
            clearance.append(float(d.min()) - car.width / 2 - EGO_HALF_WIDTH)
    assert len(narrowing) >= 10
    assert np.mean(np.asarray(narrowing) > 0) > 0.9  # they stand into the driving lane
    assert min(clearance) > 0.3  # but the recorded driver passes every one with room


def test_buildings_do_not_overlap_and_leave_the_bends_open() -> None:
    shapely = pytest.importorskip("shapely")
    for street in STREETS.values():
        world = demo_world(0, street)
        polys = [shapely.Polygon(b.xy) for b in world.buildings]
        for i, a in enumerate(polys):
            assert not any(a.intersects(b) for b in polys[i + 1 :]), street.name
        road = shapely.LineString(street.route_points(np.arange(0.0, street.length_m, 1.0))[0])
        assert min(p.distance(road) for p in polys) > street.lane_m / 2 + street.parking_m


def test_a_street_is_chosen_by_name(tmp_path: Path) -> None:
    assert demo_street("paper") is PAPER_STREET
    with pytest.raises(ConfigError, match="l-street, paper"):
        demo_street("oakland")
    assert recorded_street(tmp_path) is None
    (tmp_path / "demo.json").write_text(json.dumps({"version": 3}))
    assert recorded_street(tmp_path) == "l-street"  # recordings from before there was a choice


def test_the_cli_refuses_to_mix_streets_in_one_folder(tmp_path: Path) -> None:
    from typer.testing import CliRunner

    from cam2sim.cli.main import app

    (tmp_path / "demo.json").write_text(json.dumps({"version": 3, "world": "l-street"}))
    result = CliRunner().invoke(app, ["demo", "-o", str(tmp_path), "--world", "paper"])
    assert result.exit_code == 1
    assert "demo of world 'l-street'" in " ".join(result.output.split())
    assert sorted(p.name for p in tmp_path.iterdir()) == ["demo.json"]
