"""What differs between the Blender versions PHRT supports, in one place.

The supported versions are the ones ``make test-compat`` runs the whole suite
on: 4.5 LTS (Python 3.11, numpy 1), 5.0 (Python 3.11, numpy 1) and 5.2 LTS
(Python 3.13, numpy 2).  Everything else in the add-on, the command line, the
sample scenes and the tests calls these functions instead of testing versions
itself.  Each difference is detected by the feature, not the version number, and
each function says which versions do what.
"""
import bpy

# Blender's own format ids are not the same on every version: these are ours.
MULTILAYER_EXR = "MULTILAYER_EXR"
PNG = "PNG"


def set_image_format(image_settings, image_format):
    """Make ``image_settings`` (an ``ImageFormatSettings``) write ``image_format``:
    ``MULTILAYER_EXR`` (every render pass in one file) or ``PNG``.

    Blender 5.0 split the file type in two: ``media_type`` ('IMAGE',
    'MULTI_LAYER_IMAGE', 'VIDEO') and, for images, ``file_format``;
    'OPEN_EXR_MULTILAYER' is no longer a ``file_format``.  4.5 has no
    ``media_type`` and selects multilayer EXR with ``file_format`` alone.
    """
    has_media_type = hasattr(image_settings, "media_type")  # Blender 5.0+
    if image_format == MULTILAYER_EXR:
        if has_media_type:
            image_settings.media_type = "MULTI_LAYER_IMAGE"  # its one file format is OpenEXR
        else:
            image_settings.file_format = "OPEN_EXR_MULTILAYER"
    elif image_format == PNG:
        if has_media_type:
            image_settings.media_type = "IMAGE"
        image_settings.file_format = "PNG"
    else:
        raise ValueError(f"unknown image format '{image_format}': use {MULTILAYER_EXR} or {PNG}")


def image_format_state(image_settings):
    """The file type settings of ``image_settings``, in the order that restores them
    (``media_type`` first where it exists: setting it resets ``file_format``)."""
    keys = ("media_type", "file_format", "color_depth", "color_mode", "exr_codec")
    return {key: getattr(image_settings, key) for key in keys if hasattr(image_settings, key)}


def restore_image_format(image_settings, state):
    """Put back what ``image_format_state`` read (values the current format rejects are skipped)."""
    for key, value in state.items():
        try:
            setattr(image_settings, key, value)
        except (TypeError, ValueError):
            pass


def ensure_channelbag(action, slot):
    """The F-curve container of ``slot`` in ``action`` (a layered action, Blender 4.4+),
    made if missing.  5.0 added ``bpy_extras.anim_utils.action_ensure_channelbag_for_slot``
    for this; 4.5 lacks it, so this takes the path that function takes, on every version:
    the first layer, its first keyframe strip, the strip's channelbag for the slot."""
    layer = action.layers[0] if len(action.layers) else action.layers.new("Layer")
    strip = layer.strips[0] if len(layer.strips) else layer.strips.new(type="KEYFRAME")
    return strip.channelbag(slot, ensure=True)
