"""What the tracer computed (``frame.TracedTerms``), uploaded as the textures the lighting and
composite passes sample: per light and layer a visibility image (-1 where the shadow map
stays), the reflection and refraction radiance (alpha 1 where traced).  They live for one
frame; where nothing was traced the passes bind the frame's stand-ins ("no_visibility",
"no_radiance"), of the same size and format."""
from __future__ import annotations

import numpy as np


def texture(gpu, resources, image):
    """A one-frame texture of ``image`` ((h, w) R32F or (h, w, 4) RGBA32F)."""
    image = np.ascontiguousarray(image, dtype=np.float32)
    height, width = image.shape[:2]
    buffer = gpu.types.Buffer("FLOAT", image.size, image.ravel())
    resources.created["traced"] += 1
    resources.freed["traced"] += 1  # dropped with this frame
    return gpu.types.GPUTexture((width, height), format="RGBA32F" if image.ndim == 3 else "R32F", data=buffer)


def upload(gpu, resources, traced, width, height) -> dict:
    """{"visibility": {(layer, light index): texture}, "reflection": {layer: texture},
    "refraction": texture or None} of ``traced`` (None: nothing traced)."""
    n = width * height
    uploads = {"visibility": {}, "reflection": {}, "refraction": None}
    if traced is None:
        return uploads
    for (layer, light_index), (pixels, visibility) in traced.shadow_visibility.items():
        image = np.full(n, -1.0, np.float32)
        image[pixels] = visibility
        uploads["visibility"][(layer, light_index)] = texture(gpu, resources, image.reshape(height, width))
    for layer, (pixels, radiance) in traced.reflection.items():
        image = np.zeros((n, 4), np.float32)
        image[pixels, :3] = radiance
        image[pixels, 3] = 1.0
        uploads["reflection"][layer] = texture(gpu, resources, image.reshape(height, width, 4))
    if traced.refraction is not None:
        pixels, radiance = traced.refraction
        image = np.zeros((n, 4), np.float32)
        image[pixels, :3] = radiance
        image[pixels, 3] = 1.0
        uploads["refraction"] = texture(gpu, resources, image.reshape(height, width, 4))
    return uploads


def flags(uploads) -> tuple:
    """CameraData.traced: (opaque reflections, transparent reflections, refractions) uploaded."""
    return (float("opaque" in uploads["reflection"]), float("transparent" in uploads["reflection"]),
            float(uploads["refraction"] is not None))
