"""The scene as the core sees it: the snapshot, the physical rules raster and tracer answer alike, the BRDF,
and the lights' kinds with the light maths the GPU packing shares (``lights.py``)."""
