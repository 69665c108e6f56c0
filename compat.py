"""What differs between the Blender versions PHRT supports, in one place.

The supported versions are the ones ``make test-compat`` runs the whole suite
on: 4.5 LTS (Python 3.11, numpy 1), 5.0 (Python 3.11, numpy 1) and 5.2 LTS
(Python 3.13, numpy 2).  Everything else in the add-on, the command line, the
sample scenes and the tests calls these functions instead of testing versions
itself.  A difference is detected by the feature where Blender offers one to test
(``hasattr``), else by the version number; each function says which versions do what.
"""
import gzip
import re

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


def node_tree_of(datablock):
    """The node tree Blender renders a material or world with, or None.  From 5.0 a
    material or world always uses its node tree (``use_nodes`` is deprecated and warns);
    on 4.5 only when ``use_nodes`` is on."""
    if bpy.app.version >= (5, 0, 0):
        return datablock.node_tree
    return datablock.node_tree if datablock.use_nodes else None


def ensure_node_tree(datablock):
    """The node tree of a new material or world, made on 4.5 (which creates both without
    one; ``use_nodes = True`` adds the Principled BSDF or Background node) and already
    there on 5.0+."""
    if node_tree_of(datablock) is None:
        datablock.use_nodes = True
    return datablock.node_tree


def ensure_channelbag(action, slot):
    """The F-curve container of ``slot`` in ``action`` (a layered action, Blender 4.4+),
    made if missing.  5.0 added ``bpy_extras.anim_utils.action_ensure_channelbag_for_slot``
    for this; 4.5 lacks it, so this takes the path that function takes, on every version:
    the first layer, its first keyframe strip, the strip's channelbag for the slot."""
    layer = action.layers[0] if len(action.layers) else action.layers.new("Layer")
    strip = layer.strips[0] if len(layer.strips) else layer.strips.new(type="KEYFRAME")
    return strip.channelbag(slot, ensure=True)


def new_fcurve(channelbag, data_path, index, group_name):
    """A new F-curve of ``channelbag`` in the channel group ``group_name`` (made if missing).
    5.0 added a ``group_name`` argument to ``ActionChannelbagFCurves.new``; 4.5 lacks it, so
    the group is assigned after, which both versions accept."""
    group = channelbag.groups.get(group_name) or channelbag.groups.new(group_name)
    curve = channelbag.fcurves.new(data_path, index=index)
    curve.group = group
    return curve


# "BLENDER-v405" (4.x: pointer size, endianness, version 405 = 4.5) or
# "BLENDER17-01v0502" (5.0+: header size, format 01, version 0502 = 5.2).
_BLEND_HEADER = re.compile(rb"BLENDER(?:[-_][vV](\d{3})|\d\d-\d\d[vV](\d{4}))")


def new_grease_pencil(name):
    """A new grease pencil datablock an object can use: Blender 4.5 keeps the legacy one in
    ``bpy.data.grease_pencils`` (not valid for new objects) and the new one in
    ``grease_pencils_v3``; from 5.0 ``grease_pencils`` is the new one."""
    import bpy
    return getattr(bpy.data, "grease_pencils_v3", bpy.data.grease_pencils).new(name)


def blend_file_version(path):
    """(major, minor) of the Blender that saved the .blend file ``path``, read from its
    header (plain, gzip or zstd compressed), or None when the header is not a .blend's.

    A file saved by a newer Blender opens in 4.5 and 5.0 only "with loss of data" (they
    warn so, and report leaked memory at exit), so the command line rebuilds a sample
    scene saved by another version instead of opening it."""
    import zstandard  # a dependency of the bpy module, bundled with Blender

    with open(path, "rb") as handle:
        head = handle.read(32)
        try:
            if head.startswith(b"\x28\xb5\x2f\xfd"):  # zstd: Blender 3.0+ compression
                handle.seek(0)
                head = zstandard.ZstdDecompressor().stream_reader(handle).read(32)
            elif head.startswith(b"\x1f\x8b"):  # gzip: before 3.0
                handle.seek(0)
                head = gzip.GzipFile(fileobj=handle).read(32)
        except (zstandard.ZstdError, OSError, EOFError):  # a damaged file: not a .blend header
            return None
    match = _BLEND_HEADER.match(head)
    if match is None:
        return None
    number = int(match.group(1) or match.group(2))
    return divmod(number, 100)
