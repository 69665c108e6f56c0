"""One home for each physical rule that the raster and the ray traced paths must answer alike.

An element changes from raster to ray traced when the heuristic selects it; if the
two paths answered a physical question differently, its look would change with it
(the popping the paper wants to avoid).  So each question has one answer, here, and
both paths ask it:

What is transparent (``is_transparent``)
    A surface that lets light through: transmission (of its non-metallic part) above
    ``TRANSPARENT_EPSILON``, or alpha below ``1 - TRANSPARENT_EPSILON``.  Raster draws it
    in the transparent G-buffer layer and blends it; the tracer refracts through its
    transmissive part and passes straight through its ``1 - alpha`` part.

What casts a shadow (``shadow_transmittance``, ``casts_shadow``)
    The fraction of light a surface lets through is
    ``(1 - alpha) + alpha * transmission * (1 - metallic)``.  Shadows are hard in both
    paths (a depth shadow map holds no fractions), so a surface casts a full shadow when
    it lets through less than ``SHADOW_TRANSMITTANCE_LIMIT`` (half) of the light, and none
    otherwise: a 30%-transmissive curtain casts a shadow, a clear window (or an alpha-0.2
    card) does not - in the shadow maps and for shadow rays alike.

Index of refraction (``clamp_ior``)
    PHRT's transparent objects are closed solids in air, so an IOR below 1 (a solid
    optically thinner than air) is read as 1: the surface neither bends nor reflects
    light, and the object vanishes.  Above ``MAX_IOR`` (4, beyond any transparent solid
    at visible wavelengths: diamond 2.42, rutile 2.9) it is clamped to ``MAX_IOR``.
    A NaN IOR is ``DEFAULT_IOR``.

How a texture is sampled (``prepare_texture``, ``texture_coordinates``, ``sample_texture``)
    The image is prepared once: non-finite texels become 0 (1 for +inf) and an image
    larger than ``MAX_TEXTURE_SIZE`` on a side is shrunk by the smallest integer factor
    that fits, averaging each factor x factor block (wrapping at the edges).  The GPU
    gets exactly this image (no mipmaps).  Texture coordinates: a mesh without a UV map
    reads (0, 0) at every corner, as Blender reads a missing attribute, and a non-finite
    coordinate reads 0.  Sampling is bilinear between texel centres with wrap-around
    (repeat) on both axes, in float32: ``sample_texture`` in numpy for the tracer and its GLSL
    twin ``phrt_sample_texture`` (``engine/gpu/gbuffer.py``) on the GPU for the raster pass.

Plain numpy, no ``bpy``.
"""
from __future__ import annotations

import math

import numpy as np

TRANSPARENT_EPSILON = 1e-3
SHADOW_TRANSMITTANCE_LIMIT = 0.5
MIN_IOR = 1.0
MAX_IOR = 4.0
DEFAULT_IOR = 1.5
MAX_TEXTURE_SIZE = 2048


# -- materials -------------------------------------------------------------------------------------

def unit_interval(values, nan=0.0):
    """``values`` as float64 in [0, 1]; NaN reads ``nan``, +inf 1, -inf 0."""
    array = np.nan_to_num(np.asarray(values, dtype=np.float64), nan=nan, posinf=1.0, neginf=0.0)
    return np.clip(array, 0.0, 1.0)


def clamp_ior(ior):
    """The IOR rule of the module docstring: NaN -> DEFAULT_IOR, then clamped to [MIN_IOR, MAX_IOR]."""
    array = np.nan_to_num(np.asarray(ior, dtype=np.float64), nan=DEFAULT_IOR, posinf=MAX_IOR, neginf=MIN_IOR)
    return np.clip(array, MIN_IOR, MAX_IOR)


def transmissive(transmission, metallic):
    """The part of a surface that refracts (metals do not transmit)."""
    return unit_interval(transmission) * (1.0 - unit_interval(metallic))


def shadow_transmittance(transmission, metallic, alpha):
    """Fraction of the light a surface lets through: what alpha leaves out plus what refracts."""
    alpha = unit_interval(alpha, nan=1.0)
    return (1.0 - alpha) + alpha * transmissive(transmission, metallic)


def casts_shadow_values(transmission, metallic, alpha):
    return shadow_transmittance(transmission, metallic, alpha) < SHADOW_TRANSMITTANCE_LIMIT


def is_transparent_values(transmission, metallic, alpha):
    alpha = unit_interval(alpha, nan=1.0)
    return (transmissive(transmission, metallic) > TRANSPARENT_EPSILON) | (alpha < 1.0 - TRANSPARENT_EPSILON)


def _material_values(material):
    return material.transmission, material.metallic, material.alpha


def is_transparent(material) -> bool:
    """Drawn in the transparent layer (blended in raster, refracted or passed through when traced)."""
    return bool(is_transparent_values(*_material_values(material)))


def casts_shadow(material) -> bool:
    """Occludes light in the shadow maps and for shadow rays (see the module docstring)."""
    return bool(casts_shadow_values(*_material_values(material)))


def is_candidate(element) -> bool:
    """Tagged for ray tracing with a priority K > 0 (K = 0 is the designer's "never worth
    tracing": neither selected nor marked in the PHRT Candidate pass)."""
    priority = float(element.priority)
    return bool(element.candidate) and math.isfinite(priority) and priority > 0.0


# -- textures ----------------------------------------------------------------------------------------

def _is_prepared(image) -> bool:
    return (isinstance(image, np.ndarray) and image.dtype == np.float32 and image.ndim == 3
            and image.shape[2] == 4 and max(image.shape[:2]) <= MAX_TEXTURE_SIZE
            and image.flags.c_contiguous and min(image.shape[:2]) >= 1)


def prepare_texture(pixels, max_size: int = MAX_TEXTURE_SIZE) -> np.ndarray:
    """The image both paths sample: (h, w, 4) float32, finite, at most ``max_size`` per side
    (block average by the smallest integer factor that fits; rows from the bottom, as given)."""
    image = np.asarray(pixels)
    if max_size == MAX_TEXTURE_SIZE and _is_prepared(image) and np.isfinite(image).all():
        return image
    image = np.asarray(image, dtype=np.float32)
    if image.ndim == 2:
        image = image[..., None]
    if image.ndim != 3 or image.shape[0] == 0 or image.shape[1] == 0:
        raise ValueError(f"a texture must be an (h, w, channels) image, not shape {image.shape}")
    channels = image.shape[2]
    if channels < 4:  # grey, grey+alpha or RGB: expand to RGBA
        rgb = image[..., :1].repeat(3, axis=2) if channels < 3 else image[..., :3]
        alpha = image[..., 1:2] if channels == 2 else np.ones(image.shape[:2] + (1,), np.float32)
        image = np.concatenate([rgb, alpha], axis=2)
    image = np.nan_to_num(image[..., :4], nan=0.0, posinf=1.0, neginf=0.0)
    height, width = image.shape[:2]
    factor = max(1, math.ceil(max(height, width) / max_size))
    if factor > 1:
        rows, cols = -(-height // factor), -(-width // factor)
        # Pad by wrapping (the sampler wraps too) to whole blocks, then average each block.
        ys = np.arange(rows * factor) % height
        xs = np.arange(cols * factor) % width
        padded = image[ys][:, xs].astype(np.float64)
        image = padded.reshape(rows, factor, cols, factor, 4).mean(axis=(1, 3))
    return np.ascontiguousarray(image, dtype=np.float32)


def texture_coordinates(corner_uvs, n_corners: int) -> np.ndarray:
    """(n_corners, 2) float32 finite texture coordinates: zeros without a UV map, 0 for a
    non-finite coordinate."""
    if corner_uvs is None:
        return np.zeros((n_corners, 2), np.float32)
    uvs = np.asarray(corner_uvs, dtype=np.float32).reshape(-1, 2)
    if len(uvs) != n_corners:
        raise ValueError(f"{len(uvs)} texture coordinates for {n_corners} triangle corners")
    if not np.isfinite(uvs).all():
        uvs = np.nan_to_num(uvs, nan=0.0, posinf=0.0, neginf=0.0)
    return np.ascontiguousarray(uvs)


def sample_texture(texture: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Bilinear, wrapping lookup of a prepared texture at (N, 2) coordinates: (N, 4) float32.
    Texel (i, j) has its centre at ((i + 0.5) / w, (j + 0.5) / h); row 0 is v = 0.
    The same arithmetic as the GLSL twin, in float32.

    GLSL twin: engine/gpu/gbuffer.py phrt_sample_texture"""
    height, width = texture.shape[:2]
    uv = np.nan_to_num(np.asarray(uv, dtype=np.float32).reshape(-1, 2), nan=0.0, posinf=0.0, neginf=0.0)
    wrapped = uv - np.floor(uv)
    position = wrapped * np.array([width, height], np.float32) - np.float32(0.5)
    cell = np.floor(position)
    fraction = (position - cell).astype(np.float32)
    x0 = np.mod(cell[:, 0].astype(np.int64), width)
    y0 = np.mod(cell[:, 1].astype(np.int64), height)
    x1 = (x0 + 1) % width
    y1 = (y0 + 1) % height
    fx, fy = fraction[:, 0:1], fraction[:, 1:2]
    bottom = texture[y0, x0] * (1 - fx) + texture[y0, x1] * fx
    top = texture[y1, x0] * (1 - fx) + texture[y1, x1] * fx
    return (bottom * (1 - fy) + top * fy).astype(np.float32)

