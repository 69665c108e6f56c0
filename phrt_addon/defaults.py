"""Default values shared by the Blender properties, the command line and the core.

One place for each number a user may change (the properties expose them) so the
engine, the CLI and the tests agree.
"""

# Frame time target (ms). The paper's hybrid frames average ~100-200 ms at 640x480.
BUDGET_MS = 150.0
# The paper's I: relevance bonus of last frame's selection (hysteresis).
SELECTION_WEIGHT = 0.5
# The paper's 40% rule: elements covering more of the frame are not ray traced.
MAX_AREA_FRACTION = 0.40
MAX_BOUNCES = 4
SHADOW_MAP_SIZE = 2048
RESOLUTION = (640, 480)
