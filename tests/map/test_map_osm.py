"""OSM input: every file kind, JOSM deletes, cropping, XML round trip, malformed input."""

from __future__ import annotations

import bz2
import gzip
import json
import re
from pathlib import Path

import numpy as np
import pytest

from cam2sim.core.errors import StageError
from cam2sim.map.osm import BBox, parse_osm_xml, parse_overpass_json, read_osm

from .map_helpers import osm_file

SMALL = b"""<?xml version='1.0' encoding='UTF-8'?>
<osm version='0.6' generator='test'>
  <bounds minlat='48.0' minlon='11.0' maxlat='48.1' maxlon='11.1'/>
  <node id='1' lat='48.01' lon='11.01'/>
  <node id='2' lat='48.02' lon='11.02'><tag k='highway' v='traffic_signals'/></node>
  <node id='3' action='delete' lat='48.03' lon='11.03'/>
  <node id='-4' action='modify' lat='48.09' lon='11.09'/>
  <way id='10'><nd ref='1'/><nd ref='2'/><nd ref='3'/>
    <tag k='highway' v='residential'/><tag k='name' v='A &amp; B'/></way>
  <way id='11' action='delete'><nd ref='1'/><nd ref='2'/><tag k='highway' v='primary'/></way>
  <way id='12'><nd ref='2'/><nd ref='-4'/><tag k='highway' v='footway'/></way>
  <relation id='20'><member type='way' ref='10' role='from'/>
    <member type='way' ref='11' role='to'/><tag k='type' v='restriction'/></relation>
</osm>
"""


def test_parse_drops_josm_deleted_elements_and_their_references() -> None:
    osm = parse_osm_xml(SMALL, source="small.osm")
    assert osm.node_id.tolist() == [1, 2, -4]
    assert [w.id for w in osm.ways] == [10, 12]
    assert osm.ways[0].refs.tolist() == [1, 2]  # the deleted node 3 is gone from the way
    assert osm.ways[0].tags["name"] == "A & B"
    assert osm.node_tags[2] == {"highway": "traffic_signals"}
    assert osm.relations[0].members == (("way", 10, "from"),)
    assert osm.dropped_deleted == 2
    assert osm.bounds == BBox(48.0, 11.0, 48.1, 11.1)


def test_real_josm_file_has_no_deleted_element_left(tmp_path: Path) -> None:
    path = osm_file("tram_crossing.osm")
    text = path.read_text(encoding="utf-8")
    deleted = {
        int(m.group(2))
        for m in re.finditer(r"<(node|way|relation) [^>]*?id='(-?\d+)'[^>]*action='delete'", text)
    }
    deleted |= {
        int(m.group(3))
        for m in re.finditer(r"<(node|way|relation) action='delete'([^>]*?)id='(-?\d+)'", text)
    }
    osm = read_osm(path)
    assert osm.dropped_deleted == 53
    assert deleted, "the fixture should contain deleted elements"
    kept = set(osm.node_id.tolist()) | {w.id for w in osm.ways} | {r.id for r in osm.relations}
    assert not (kept & deleted)
    written = tmp_path / "clean.osm"
    written.write_text(osm.to_xml(), encoding="utf-8")
    assert "action=" not in written.read_text(encoding="utf-8")


@pytest.mark.parametrize(
    ("name", "nodes", "ways"),
    [
        ("munich.osm", 6578, 1202),
        ("moosacher_lerchenauer.osm", 528, 53),
        ("West-Oakland.osm.bz2", 446, 66),
        ("aguascalientes.osm.pbf", 3083, 733),
        ("overpass-response-piedmont.json.gz", 2889, 287),
    ],
)
def test_read_osm_reads_every_file_kind(name: str, nodes: int, ways: int) -> None:
    osm = read_osm(osm_file(name))
    assert (osm.node_id.size, len(osm.ways)) == (nodes, ways)
    assert np.all(osm.extent().contains(osm.lat_deg, osm.lon_deg) | (osm.bounds is not None))


def test_xml_round_trip_keeps_nodes_ways_relations_and_tags() -> None:
    osm = read_osm(osm_file("moosacher_lerchenauer.osm"))
    again = parse_osm_xml(osm.to_xml().encode(), source="again")
    np.testing.assert_array_equal(again.node_id, osm.node_id)
    np.testing.assert_allclose(again.lat_deg, osm.lat_deg, atol=1e-9)
    np.testing.assert_allclose(again.lon_deg, osm.lon_deg, atol=1e-9)
    assert [(w.id, w.refs.tolist(), dict(w.tags)) for w in again.ways] == [
        (w.id, w.refs.tolist(), dict(w.tags)) for w in osm.ways
    ]
    assert [(r.id, r.members) for r in again.relations] == [
        (r.id, r.members) for r in osm.relations
    ]
    assert dict(again.node_tags) == dict(osm.node_tags)
    assert again.bounds == osm.bounds


def test_compressed_and_json_inputs_match_the_plain_ones(tmp_path: Path) -> None:
    plain = osm_file("moosacher_lerchenauer.osm")
    gz = tmp_path / "m.osm.gz"
    gz.write_bytes(gzip.compress(plain.read_bytes()))
    bz = tmp_path / "m.osm.bz2"
    bz.write_bytes(bz2.compress(plain.read_bytes()))
    ref = read_osm(plain)
    for path in (gz, bz):
        osm = read_osm(path)
        np.testing.assert_array_equal(osm.node_id, ref.node_id)
        assert len(osm.ways) == len(ref.ways)
    doc = {
        "elements": [
            {"type": "node", "id": int(i), "lat": float(a), "lon": float(o)}
            for i, a, o in zip(ref.node_id, ref.lat_deg, ref.lon_deg, strict=True)
        ]
        + [
            {"type": "way", "id": w.id, "nodes": w.refs.tolist(), "tags": dict(w.tags)}
            for w in ref.ways
        ]
    }
    js = tmp_path / "answer.txt"  # content decides, not the name
    js.write_text(json.dumps(doc))
    osm = read_osm(js)
    np.testing.assert_array_equal(osm.node_id, ref.node_id)
    assert [w.refs.tolist() for w in osm.ways] == [w.refs.tolist() for w in ref.ways]


def test_crop_keeps_whole_ways_touching_the_box() -> None:
    osm = read_osm(osm_file("munich.osm"))
    box = BBox(48.185, 11.549, 48.187, 11.552)
    cropped = osm.crop(box)
    assert 0 < len(cropped.ways) < len(osm.ways)
    for way in cropped.ways:
        lat, lon = cropped.way_coords(way)
        assert lat.size == way.refs.size  # whole way kept
        assert box.contains(lat, lon).any()
    assert cropped.bounds == box


def test_malformed_xml_names_file_and_line(tmp_path: Path) -> None:
    path = tmp_path / "broken.osm"
    path.write_text(SMALL.decode().replace("<way id='12'>", "<way id='12'"), encoding="utf-8")
    with pytest.raises(StageError, match=r"broken\.osm, line 11, column \d+: malformed XML"):
        read_osm(path)


def test_node_without_coordinates_names_the_element_and_line(tmp_path: Path) -> None:
    path = tmp_path / "nolat.osm"
    path.write_text(SMALL.decode().replace("lat='48.02' ", ""), encoding="utf-8")
    with pytest.raises(StageError, match=r"nolat\.osm, line 5: <node id='2'> has no valid lat="):
        read_osm(path)


def test_wrong_root_element_is_refused() -> None:
    with pytest.raises(StageError, match=r"x\.osm, line 1: the root element is <gpx>"):
        parse_osm_xml(b"<gpx version='1.1'></gpx>", source="x.osm")


def test_bad_overpass_json_names_the_element() -> None:
    with pytest.raises(StageError, match=r"elements\[1\].*malformed"):
        parse_overpass_json(
            b'{"elements": [{"type": "node", "id": 1, "lat": 1, "lon": 2}, {"type": "way"}]}',
            source="a.json",
        )
    with pytest.raises(StageError, match="no 'elements' list"):
        parse_overpass_json(b"[]", source="a.json")


def test_missing_and_corrupt_files_are_clear_errors(tmp_path: Path) -> None:
    with pytest.raises(StageError, match="does not exist"):
        read_osm(tmp_path / "none.osm")
    bad = tmp_path / "x.osm.bz2"
    bad.write_bytes(b"not bz2")
    with pytest.raises(StageError, match="cannot decompress"):
        read_osm(bad)


def test_bbox_validates_and_intersects() -> None:
    with pytest.raises(ValueError, match="south <= north"):
        BBox(2.0, 0.0, 1.0, 1.0)
    a = BBox(0.0, 0.0, 2.0, 2.0)
    assert a.intersection(BBox(1.0, 1.0, 3.0, 3.0)) == BBox(1.0, 1.0, 2.0, 2.0)
    assert a.intersection(BBox(3.0, 3.0, 4.0, 4.0)) is None
    assert a.covers(BBox(0.5, 0.5, 1.0, 1.0))
    assert a.overpass() == "0.0000000,0.0000000,2.0000000,2.0000000"
