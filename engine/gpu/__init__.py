"""The GPU frame: ``frame.py`` (``GPUFrame``), its GLSL (``lighting_glsl.py``) and the resources kept across frames (``resources.py``)."""
