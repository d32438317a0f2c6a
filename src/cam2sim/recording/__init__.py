"""cam2sim.recording."""
