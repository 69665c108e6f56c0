"""The GPU frame, one module per pass: ``frame.py`` (``GPUFrame``, the core's ``RasterFrame``,
runs the passes in order), ``gbuffer.py`` (the two layers with chunk culling, and the resolve),
``shadow_maps.py``, ``lighting.py`` (its lights packed by ``light_struct.py``), ``composite.py``,
``traced_textures.py`` (the tracer's results uploaded) and ``readback.py``; ``resources.py``
owns what outlives a frame, ``uniforms.py`` and ``fullscreen.py`` are what the passes share.
The GLSL sits beside its builder (in the pass's module, or its ``*_glsl.py``), each function
headed by the numpy twin in ``phrt_addon/`` it mirrors, the reference the parity tests hold it to
(``// numpy twin: <file> <name>``), whose docstring names it back (``GLSL twin: engine/gpu/<file>
<function>``; both directions checked by ``tests/core/test_glsl_twins.py``).
"""
