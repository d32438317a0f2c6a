"""cam2sim.cli."""
