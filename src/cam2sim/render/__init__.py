"""Camera renderers that need no training: the simulator-style ``raster`` backend."""
