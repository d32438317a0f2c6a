"""The road map of a workspace: OSM input, OpenDRIVE conversion, queries and the map report.

Modules (import them directly; this package imports nothing heavy):

- :mod:`cam2sim.map.osm`: read ``.osm``/``.osm.bz2``/``.osm.pbf``/Overpass JSON, crop, write XML;
- :mod:`cam2sim.map.overpass`: fetch a box from the Overpass API (retries, disk cache);
- :mod:`cam2sim.map.convert`: OSM to OpenDRIVE with ``carla.Osm2Odr`` in the world projection;
- :mod:`cam2sim.map.opendrive`: parse OpenDRIVE, evaluate reference lines and lane borders;
- :mod:`cam2sim.map.query`: :class:`~cam2sim.map.query.RoadMap`, lane polygons, drivable area,
  nearest lane and heading for point batches, road edges;
- :mod:`cam2sim.map.check`: OSM nodes against the converted roads (geo-referencing proof);
- :mod:`cam2sim.map.report`: route fit, ``map_report.json`` model, ``map.png``.

The stage that ties them together is :mod:`cam2sim.stages.map`.
"""
