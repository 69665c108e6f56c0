"""Read-back: frame targets into numpy (docs/platform-notes.md: a flat ``gpu.types.Buffer``
passed to ``read_color`` and a reshape; ``np.asarray`` on a multi-dimensional buffer scrambles
the pixels), and the G-buffer layers decoded as the core's ``GBufferLayer``."""
from __future__ import annotations

import numpy as np

from ...phrt_addon.raster.gbuffer import GBuffer, GBufferLayer


def read(gpu, framebuffer, slot, kind, channels, width, height, rect=None) -> np.ndarray:
    """Colour attachment ``slot`` as (h, w, channels) float32 (``kind`` "FLOAT"), uint32 ("UINT")
    or uint8 ("UBYTE", an 8-bit target as stored); (h, w) for one channel.  ``rect`` (x, y, w, h; row 0 at the bottom): only those
    pixels, as an array of the rectangle's size."""
    x, y, w, h = (0, 0, width, height) if rect is None else rect
    buffer = gpu.types.Buffer(kind, w * h * channels)
    with framebuffer.bind():
        framebuffer.read_color(x, y, w, h, channels, slot, kind, data=buffer)
    dtype = {"FLOAT": np.float32, "UINT": np.uint32, "UBYTE": np.uint8}[kind]
    # The array keeps the buffer it views alive: no copy.
    return np.asarray(buffer, dtype=dtype).reshape((h, w, channels) if channels > 1 else (h, w))


def read_target(gpu, frame, name, kind="FLOAT", channels=4, rect=None) -> np.ndarray:
    """One of ``frame.targets`` read back whole, or only the rectangle ``rect`` (x, y, w, h; row 0
    at the bottom) placed among zeros."""
    framebuffer = gpu.types.GPUFrameBuffer(color_slots=(frame.targets[name],))
    part = read(gpu, framebuffer, 0, kind, channels, frame.width, frame.height, rect)
    if rect is None:
        return part
    x, y, w, h = rect
    whole = np.zeros((frame.height, frame.width) + part.shape[2:], part.dtype)
    whole[y:y + h, x:x + w] = part
    return whole


def read_gbuffer(gpu, frame, transparent_drawn: bool, rect=None, faces: bool = False) -> GBuffer:
    """Both layers of ``frame`` (float32 positions relative to the camera); the transparent one
    empty when nothing transparent was drawn; with ``rect`` (x, y, w, h) only those pixels, the
    others as cleared ones; ``faces``: the pass wrote the face normals (read as the layers'
    ``geometric_normal``; without, the trace stage reconstructs them from the positions)."""
    targets, width, height = frame.targets, frame.width, frame.height

    def layer(name):
        # One frame buffer a layer: the Python API binds at most 6 colour attachments.
        framebuffer = gpu.types.GPUFrameBuffer(color_slots=tuple(
            targets[f"{name}_{target}"] for target in ("position", "normal", "element", "geometric")[:4 if faces else 3]))
        position = read(gpu, framebuffer, 0, "FLOAT", 4, width, height, rect)
        normal = read(gpu, framebuffer, 1, "FLOAT", 4, width, height, rect)
        element = read(gpu, framebuffer, 2, "UINT", 1, width, height, rect)
        geometric = read(gpu, framebuffer, 3, "UBYTE", 4, width, height, rect) if faces else None
        decoded = decode_layer(position, normal, element, geometric)
        if rect is None:
            return decoded
        # Decoded inside the rectangle only, then placed among cleared pixels (at 640x480 decoding
        # whole layers of zeros cost more than reading the rectangle).
        x, y, w, h = rect

        def placed(array, cleared):
            whole = np.full((height, width) + array.shape[2:], cleared, array.dtype)
            whole[y:y + h, x:x + w] = array
            return whole

        normal = placed(normal, 0.0)
        return GBufferLayer(covered=placed(decoded.covered, False), position=placed(position, 0.0)[..., :3],
                            normal=normal[..., :3], roughness=normal[..., 3], albedo=None, metallic=None,
                            material=placed(decoded.material, -1), element=placed(decoded.element, -1),
                            geometric_normal=None if geometric is None else placed(geometric, 0))

    opaque = layer("opaque")
    transparent = layer("transparent") if transparent_drawn else GBufferLayer.empty(width, height)
    return GBuffer(opaque=opaque, transparent=transparent, origin=frame.snapshot.camera.position,
                   view_depth=frame.view_depth)


def read_albedo(gpu, frame) -> tuple:
    """(opaque, transparent) albedo + metallic, (h, w, 4) (stored as sqrt: squared here)."""
    framebuffer = gpu.types.GPUFrameBuffer(color_slots=(frame.targets["opaque_albedo"],
                                                        frame.targets["transparent_albedo"]))
    result = []
    for slot in (0, 1):
        stored = read(gpu, framebuffer, slot, "FLOAT", 4, frame.width, frame.height)
        stored[..., :3] *= stored[..., :3]  # stored as sqrt
        result.append(stored)
    return tuple(result)


def decode_layer(position: np.ndarray, normal: np.ndarray, element: np.ndarray,
                 geometric: np.ndarray | None = None) -> GBufferLayer:
    """The raw read-back targets as a ``GBufferLayer`` (whole-array numpy; no albedo: only the
    reference lighting reads it, ``read_albedo``).  Cleared pixels read as zeros in every target.
    Position, normal and roughness are views of the read-back (h, w, 4) arrays, not copies: a
    pixel's row stays 16 bytes apart, so ``reshape(-1, 3)`` and the gathers of the pixels that get
    rays need no copy of the whole layer (three full copies were 0.8 ms a layer at 320x240).
    ``geometric``: the face normals the G-buffer pass wrote, encoded (``encode_face_normals``)."""
    material = np.rint(position[..., 3]).astype(np.int64) - 1
    covered = material >= 0
    return GBufferLayer(
        covered=covered,
        position=position[..., :3],
        normal=normal[..., :3],
        roughness=normal[..., 3],
        albedo=None,
        metallic=None,
        material=material.astype(np.int32),
        element=element.astype(np.int64) - 1,
        geometric_normal=geometric,
    )
