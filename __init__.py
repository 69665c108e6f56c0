"""PHRT for Blender: the extension's entry point.

It only registers and unregisters, walking one ordered tuple of sub-modules and
its reverse.  The sub-modules are imported here, inside ``register()``, so that
importing the package (as ``phrt`` from the checkout, or as
``bl_ext.<repo>.phrt`` when Blender installs it) never pulls in ``bpy``: the
plain-Python core in ``phrt_addon`` stays usable and testable without Blender.
"""
import importlib

# Order matters: properties before the engine and the UI that use them.
_MODULE_NAMES = ("properties", "engine", "operators", "panels")


def _modules():
    return [importlib.import_module("." + name, __package__) for name in _MODULE_NAMES]


def register():
    for module in _modules():
        module.register()


def unregister():
    for module in reversed(_modules()):
        module.unregister()
