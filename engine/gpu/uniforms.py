"""Uniform blocks: one table per GLSL struct drives both its source text (``glsl``) and its
packing (``Packed``), so no offset is ever written by hand.

A table is a tuple of ``Field``s, each a vec4 or a mat4 (or an array of them) whose floats are
named ``parts``.  Under std140 such members sit at the running sum of their sizes and an array
of structs packs as their concatenation; ``tests/integration/test_light_struct.py`` reads every
member back through a shader to check it.  ``CAMERA`` and ``FRAME`` are the blocks the passes
bind (``CameraData``, ``FrameData``); ``light_struct.LIGHT`` is the lights'.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

FLOATS = {"vec4": 4, "mat4": 16}


@dataclass(frozen=True)
class Field:
    """One member.  ``parts``: (name, floats) in order, filling the type ("" pads); a part's
    name is what the packing writes (``Packed.set``), the member's what the GLSL reads."""

    name: str
    glsl_type: str
    parts: tuple
    count: int = 1  # an array of this many
    comment: str = ""


def layout(fields) -> tuple:
    """({part: (first float, floats, array length, array stride)}, floats of the struct)."""
    parts = {}
    offset = 0
    for field in fields:
        width = FLOATS[field.glsl_type]
        if sum(floats for _, floats in field.parts) != width:
            raise ValueError(f"{field.name}: its parts do not fill a {field.glsl_type}")
        inner = 0
        for part, floats in field.parts:
            if part:
                if part in parts:
                    raise ValueError(f"two parts named {part}")
                parts[part] = (offset + inner, floats, field.count, width)
            inner += floats
        offset += width * field.count
    return parts, offset


def floats(fields) -> int:
    """The floats of a struct with ``fields`` (std140, as packed)."""
    return layout(fields)[1]


def glsl(name: str, fields) -> str:
    """The GLSL source of struct ``name`` with ``fields``."""
    lines = [f"struct {name} {{"]
    for field in fields:
        member = f"{field.glsl_type} {field.name}{f'[{field.count}]' if field.count > 1 else ''};"
        lines.append(f"  {member:<26}/* {field.comment} */" if field.comment else f"  {member}")
    return "\n".join(lines) + "\n};\n"


class Packed:
    """One struct's floats (float32), written and read part by part; ``values``: an existing
    packing to read (else zeros)."""

    def __init__(self, fields, values=None):
        self.parts, self.floats = layout(fields)
        self.values = np.zeros(self.floats, np.float32) if values is None else values

    def where(self, part: str, index: int = 0) -> slice:
        """The floats of ``part`` (of array element ``index``)."""
        first, floats, count, stride = self.parts[part]
        if not 0 <= index < count:
            raise IndexError(f"{part}[{index}] of {count}")
        start = first + index * stride
        return slice(start, start + floats)

    def set(self, part: str, value, index: int = 0):
        self.values[self.where(part, index)] = value

    def get(self, part: str, index: int = 0) -> np.ndarray:
        return self.values[self.where(part, index)]


CAMERA = (
    Field("forward_ortho", "vec4", (("forward", 3), ("ortho", 1)), comment="camera axis, w = 1 for orthographic"),
    Field("world", "vec4", (("world", 3), ("", 1)), comment="uniform environment colour"),
    Field("traced", "vec4", (("traced", 3), ("", 1)),
          comment="x: opaque reflections, y: transparent reflections, z: refractions uploaded"),
)

# What a geometry pass draws with: the view-projection, and the view's axis (shadow maps only).
FRAME = (
    Field("view_proj", "mat4", (("view_proj", 16),)),
    Field("axis", "vec4", (("axis", 3), ("", 1))),
)


def column_major(matrix) -> list:
    """Row-major 4x4 -> the column-major flat list GLSL expects."""
    return np.asarray(matrix, dtype=np.float32).T.ravel().tolist()


def model_relative(matrix_world, origin) -> np.ndarray:
    """A model matrix that places the mesh relative to ``origin`` (the camera or a shadow view's
    origin): float32 positions keep their precision at any world coordinate."""
    model = np.array(matrix_world, dtype=np.float64)
    model[:3, 3] -= origin
    return model


def upload(gpu, values):
    """A uniform buffer of ``values`` (float32).  Keep it referenced until drawn: a dropped
    buffer reads as zeros."""
    values = np.ascontiguousarray(values, dtype=np.float32).ravel()
    return gpu.types.GPUUniformBuf(gpu.types.Buffer("FLOAT", values.size, values))


def camera_block(gpu, snapshot, traced_flags=(0.0, 0.0, 0.0)):
    """``CameraData`` of this frame; ``traced_flags``: which traced textures were uploaded."""
    camera = snapshot.camera
    packed = Packed(CAMERA)
    packed.set("forward", camera.forward)
    packed.set("ortho", 1.0 if camera.ortho else 0.0)
    packed.set("world", np.asarray(snapshot.world_color, np.float64)[:3])
    packed.set("traced", traced_flags)
    return upload(gpu, packed.values)


def frame_block(gpu, view_proj, axis=(0.0, 0.0, 0.0)):
    """``FrameData`` for a view-projection (row-major) and a view axis."""
    packed = Packed(FRAME)
    packed.set("view_proj", column_major(view_proj))
    packed.set("axis", axis)
    return upload(gpu, packed.values)
