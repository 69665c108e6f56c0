"""PHRT for Blender: the extension's entry point.

It only registers and unregisters, walking one ordered tuple of sub-modules and
its reverse.  The sub-modules are imported here, inside ``register()``, so that
importing the package (as ``phrt`` from the checkout, or as
``bl_ext.<repo>.phrt`` when Blender installs it) never pulls in ``bpy``: the
plain-Python core in ``phrt_addon`` stays usable and testable without Blender.

``register()`` also arranges for ``unregister()`` to run when the Python
interpreter ends, unless something unregisters first.  With Blender as a Python
module (``import bpy``), a process that ends with Python classes still
registered hangs at exit on Blender 4.5 (README, "Blender versions"), so the
``phrt`` command, the tests and a user's script that registers and simply ends
all exit cleanly.  Blender itself unregisters add-ons before Python ends, which
leaves that hook nothing to do; ``unregister()`` is a no-op when not registered.
"""
import atexit
import importlib

# Order matters: properties before the engine and the UI that use them.
_MODULE_NAMES = ("properties", "engine", "operators", "panels")

_registered = False


def _modules():
    return [importlib.import_module("." + name, __package__) for name in _MODULE_NAMES]


def register():
    global _registered
    done = []
    try:
        for module in _modules():
            module.register()
            done.append(module)
    except BaseException:
        for module in reversed(done):  # a half-registered add-on would hang the exit too
            module.unregister()
        raise
    _registered = True
    atexit.register(unregister)


def unregister():
    global _registered
    atexit.unregister(unregister)
    if not _registered:
        return
    _registered = False
    for module in reversed(_modules()):
        module.unregister()
