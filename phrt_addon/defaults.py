"""Default values shared by the Blender properties, the command line and the core.

One place for each number a user may change (the properties expose them) so the
engine, the CLI and the tests agree.
"""

# Frame time target (ms). The paper's hybrid frames average ~100-200 ms at 640x480.
BUDGET_MS = 150.0
# Budget given as a fraction of the way from raster to ray traced frame time (0..1):
# the sample scenes use it, so a budget means the same on any machine.
BUDGET_AT = 0.4
# The paper's I: relevance bonus of last frame's selection (hysteresis).
SELECTION_WEIGHT = 0.5
# The paper's 40% rule: elements covering more of the frame are not ray traced.
MAX_AREA_FRACTION = 0.40
MAX_BOUNCES = 4
SHADOW_MAP_SIZE = 2048
RESOLUTION = (640, 480)
