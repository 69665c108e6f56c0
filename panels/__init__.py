"""PHRT's user interface in the 3D view sidebar (N panel, tab ``PHRT``).

``candidates.py``: the candidate list (UIList, its collection and refreshing);
``view3d.py``: the panels, the Replay panel's settings and the overlay toggle.
"""
from . import candidates, view3d

_MODULES = (candidates, view3d)


def register():
    for module in _MODULES:
        module.register()


def unregister():
    for module in reversed(_MODULES):
        module.unregister()
