"""Tests of cam2sim.map and the map stage."""
