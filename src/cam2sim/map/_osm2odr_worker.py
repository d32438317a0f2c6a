"""Run ``carla.Osm2Odr.convert`` once, in its own process.

CARLA's converter (SUMO netconvert inside libcarla) keeps global option state: after one failed
conversion every later call in the same process fails ("configuration-file is an already used
option name"). It also writes its warnings straight to the C-level stdout/stderr. Running each
conversion in a fresh interpreter isolates both, and a crash of the native code cannot take the
caller down. :mod:`cam2sim.map.convert` starts this file; it is not part of the API.

Usage: ``python _osm2odr_worker.py REQUEST.json``, where the request names the OSM input file,
the OpenDRIVE output file and the settings. Exit code 0 on success; otherwise the last stderr
line is ``osm2odr error: <message>``.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path


def main(request_path: str) -> int:
    """Convert the OSM file named in the request; return the exit code."""
    request = json.loads(Path(request_path).read_text(encoding="utf-8"))
    try:
        import carla  # noqa: PLC0415 - PROJ_LIB must be set (by the parent) before this
    except ImportError as err:
        sys.stderr.write(f"osm2odr error: cannot import carla ({err})\n")
        return 3
    settings = carla.Osm2OdrSettings()
    settings.proj_string = request["proj_string"]
    settings.center_map = False
    settings.use_offsets = False
    settings.offset_x = 0.0
    settings.offset_y = 0.0
    settings.default_lane_width = float(request["lane_width_m"])
    settings.generate_traffic_lights = bool(request["traffic_lights"])
    settings.all_junctions_with_traffic_lights = bool(request["all_junctions_traffic_lights"])
    settings.elevation_layer_height = 0.0
    settings.set_osm_way_types(list(request["road_types"]))
    osm_text = Path(request["osm_path"]).read_text(encoding="utf-8")
    try:
        xodr = carla.Osm2Odr.convert(osm_text, settings)
    except RuntimeError as err:
        sys.stdout.flush()
        sys.stderr.write(f"\nosm2odr error: {err}\n")
        return 2
    Path(request["xodr_path"]).write_text(xodr, encoding="utf-8")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1]))
