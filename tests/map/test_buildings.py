"""Building footprints from OSM: closed building ways, heights from tags, world coordinates."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import pytest
import shapely

from cam2sim.core.frames import WorldFrame
from cam2sim.map.buildings import building_footprints
from cam2sim.map.osm import parse_osm_xml, read_osm

if TYPE_CHECKING:
    from pathlib import Path

_XML = b"""<?xml version="1.0"?>
<osm version="0.6">
  <node id="1" lat="48.0000" lon="11.0000"/>
  <node id="2" lat="48.0000" lon="11.0002"/>
  <node id="3" lat="48.0001" lon="11.0002"/>
  <node id="4" lat="48.0001" lon="11.0000"/>
  <way id="10"><nd ref="1"/><nd ref="2"/><nd ref="3"/><nd ref="4"/><nd ref="1"/>
    <tag k="building" v="yes"/><tag k="height" v="12.5 m"/></way>
  <way id="11"><nd ref="1"/><nd ref="2"/><nd ref="3"/><nd ref="1"/>
    <tag k="building" v="house"/><tag k="building:levels" v="3"/></way>
  <way id="12"><nd ref="1"/><nd ref="2"/><nd ref="3"/><nd ref="4"/><nd ref="1"/>
    <tag k="building" v="no"/></way>
  <way id="13"><nd ref="1"/><nd ref="2"/><nd ref="3"/>
    <tag k="building" v="yes"/></way>
  <way id="14"><nd ref="1"/><nd ref="2"/><nd ref="3"/><nd ref="1"/><tag k="building" v="yes"/></way>
</osm>
"""


def test_buildings_from_tags() -> None:
    osm = parse_osm_xml(_XML, source="test")
    world = WorldFrame(48.0, 11.0)
    out = building_footprints(osm, world, default_height_m=9.0)
    assert [b.osm_id for b in out] == [10, 11, 14]  # building=no and the open way are skipped
    assert [b.height_m for b in out] == [12.5, 10.0, 9.0]
    ring = out[0].xy
    assert ring.shape == (5, 2)
    np.testing.assert_allclose(ring[0], [0.0, 0.0], atol=1e-6)
    # 0.0002 deg of longitude at 48 deg N is about 14.9 m; 0.0001 deg of latitude about 11.1 m.
    assert shapely.Polygon(ring).area == pytest.approx(14.9 * 11.1, rel=0.01)


def test_real_munich_extract_has_its_buildings(shared_data: Path) -> None:
    path = shared_data / "osm" / "munich.osm"
    if not path.is_file():
        pytest.skip(f"{path} is absent")
    osm = read_osm(path)
    world = WorldFrame(float(osm.lat_deg.mean()), float(osm.lon_deg.mean()))
    out = building_footprints(osm, world)
    assert len(out) > 300
    areas = np.array([shapely.Polygon(b.xy).area for b in out])
    assert np.median(areas) > 20.0
    assert all(b.height_m > 0 for b in out)
    # Within the extract's ~1 km around its centre.
    assert np.abs(np.concatenate([b.xy for b in out])).max() < 2000.0
