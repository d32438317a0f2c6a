"""``cam2sim demo``: a small synthetic recording, built on the spot, through the whole pipeline.

:mod:`cam2sim.demo.world` defines an L-shaped residential street near Munich (UTM 32N), writes
it as an OSM file, renders a drive along it with a photographic look and writes the drive as a
ROS2 MCAP bag with the config the pipeline needs. Needs no GPU, no CARLA server, no network.
"""
