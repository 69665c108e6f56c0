"""The scene as the core sees it: the snapshot, the physical rules raster and tracer answer alike, the BRDF."""
