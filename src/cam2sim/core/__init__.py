"""cam2sim.core."""
