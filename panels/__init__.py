"""PHRT's user interface: Properties > Render and the 3D view sidebar (N panel, tab ``PHRT``).

``render.py``: the scene's renderer settings (Properties > Render);
``candidates.py``: the N panel's candidate list (UIList and its refresh handlers);
``view3d.py``: the N panels (element tags, candidates, replay, last render) and the overlay.
Panels import only downward (properties, operators' names, engine, core).
"""
from . import candidates, render, view3d

_MODULES = (render, candidates, view3d)


def register():
    for module in _MODULES:
        module.register()


def unregister():
    for module in reversed(_MODULES):
        module.unregister()
