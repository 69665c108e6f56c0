"""PHRT's sample scenes, built in code: ``arcade`` (indoor courtyard, after
the paper's sponza) and ``atrium`` (outdoor garden), each with tagged ray
tracing candidates and three first-person camera paths.

The entry points live in ``generate`` (``SCENES``, ``build_scene``,
``write_scene``, ``path_names``); importing this package does not import bpy.
"""
