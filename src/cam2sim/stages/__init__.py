"""cam2sim.stages."""
