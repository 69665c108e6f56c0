"""Traced effects at full, half or quarter rate, reconstructed edge-aware (issue 23).

An effect traced at a rate below 1 casts rays only at the pixels of ``traced_pixel_mask``
(a pattern that rotates with the frame number, so consecutive frames cover every pixel);
``reconstruct`` fills the other pixels that wanted a value from the traced ones around them
with a joint bilateral filter guided by the G-buffer (``Guide``: depth, normal, element id).

- full (1.0): every pixel;
- half (0.5): a checkerboard whose parity flips every frame (2 frames cover the image);
- quarter (0.25): one pixel of each 2x2 block, at (0,0), (1,1), (0,1), (1,0) of the block in
  turn (4 frames cover the image; two consecutive frames form a checkerboard).

Reconstruction of a missing pixel p from the traced pixels q of its 3x3 neighbourhood
(5x5 at quarter rate) weights each q by
  - a spatial Gaussian,
  - depth: the relative distance of q's depth from p's local depth plane (p's depth plus the
    one-sided depth slopes at p that change least, so a plane seen at a grazing angle keeps
    its neighbours while a depth edge gets ~0),
  - normals: max(n_p . n_q, 0) ** NORMAL_POWER,
  - zero where q's element id differs from p's (never across elements).
A pixel whose weights all vanish takes the nearest traced pixel of the same element in its
neighbourhood that is not beyond a depth edge (``FALLBACK_DEPTH``); else it is reported
unfilled and the caller keeps the raster value there.  Plain numpy on whole images: the
Python loops run over the (at most 25) neighbourhood offsets, never over pixels.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

RATES = (0.25, 0.5, 1.0)
# Positions (row, col) of the traced pixel inside each 2x2 block at quarter rate, frame by frame.
QUARTER_ORDER = ((0, 0), (1, 1), (0, 1), (1, 0))
# Relative depth residual (against p's local plane) at which the depth weight is exp(-1).
DEPTH_SIGMA = 0.01
# Exponent of the normal weight max(n_p . n_q, 0) ** NORMAL_POWER.
NORMAL_POWER = 8.0
# Spatial Gaussian sigma (pixels) for the 3x3 (half) and 5x5 (quarter) neighbourhoods.
SPATIAL_SIGMA = {1: 1.0, 2: 1.5}
# Weights below this count as no neighbour (the fallback takes over).
MIN_WEIGHT = 1e-6
# The fallback's nearest neighbour must lie within this relative depth residual.
FALLBACK_DEPTH = 0.05


def check_rate(rate) -> float:
    """``rate`` as one of ``RATES``; anything else is an error (no silent snapping)."""
    value = float(rate)
    for known in RATES:
        if abs(value - known) < 1e-9:
            return known
    raise ValueError(f"unsupported trace rate {rate!r}: use one of {RATES}")


def traced_pixel_mask(rows: int, cols: int, rate, frame: int) -> np.ndarray:
    """(rows, cols) bool: the pixels that get rays at ``rate`` on ``frame`` (see module doc)."""
    rate = check_rate(rate)
    if rate == 1.0:
        return np.ones((rows, cols), bool)
    r = np.arange(rows)[:, None]
    c = np.arange(cols)[None, :]
    if rate == 0.5:
        return (r + c + int(frame)) % 2 == 0
    pr, pc = QUARTER_ORDER[int(frame) % 4]
    return (r % 2 == pr) & (c % 2 == pc)


def rate_radius(rate) -> np.ndarray:
    """Neighbourhood radius per rate: 1 (3x3) at half or full rate, 2 (5x5) at quarter."""
    return np.where(np.asarray(rate, np.float64) < 0.5 - 1e-9, 2, 1)


@dataclass
class Guide:
    """Per-pixel guide of one image, flat (h * w) arrays: ``depth`` (inf where nothing),
    ``normal`` (h * w, 3), ``element`` (int id: pixels of different ids never mix)."""

    depth: np.ndarray
    normal: np.ndarray
    element: np.ndarray

    @classmethod
    def of(cls, depth, normal, element) -> "Guide":
        depth = np.asarray(depth, np.float64).ravel()
        normal = np.asarray(normal, np.float64).reshape(-1, 3)
        length = np.linalg.norm(normal, axis=1, keepdims=True)
        normal = np.divide(normal, length, out=np.zeros_like(normal), where=length > 1e-12)
        return cls(depth=np.where(np.isfinite(depth), depth, np.inf), normal=normal,
                   element=np.asarray(element).ravel().astype(np.int64))


def layer_guide(layer) -> Guide:
    """The guide of a G-buffer layer (``raster.gbuffer.GBufferLayer``): camera distance of its
    positions, its shading normals, and an id that is the element index where there is one and
    ``-2 - material`` elsewhere (surfaces of no element are told apart by material)."""
    position = np.asarray(layer.position, np.float64).reshape(-1, 3)
    covered = np.asarray(layer.covered, bool).ravel()
    depth = np.where(covered, np.sqrt(np.sum(position * position, axis=1)), np.inf)
    element = np.asarray(layer.element).ravel().astype(np.int64)
    material = np.asarray(layer.material).ravel().astype(np.int64)
    ids = np.where(element >= 0, element, -2 - np.maximum(material, -1))
    return Guide.of(depth, layer.normal, np.where(covered, ids, np.iinfo(np.int64).min))


def _depth_slopes(depth: np.ndarray, height: int, width: int):
    """Per pixel (flat), the depth change per pixel along rows and columns: of the two one-sided
    differences the smaller in magnitude (the side on the same surface at a depth edge)."""
    image = depth.reshape(height, width)
    slopes = []
    for axis in (0, 1):
        forward = np.full_like(image, np.inf)
        backward = np.full_like(image, np.inf)
        with np.errstate(invalid="ignore"):
            diff = np.diff(image, axis=axis)
        diff = np.where(np.isfinite(diff), diff, np.inf)
        if axis == 0:
            forward[:-1], backward[1:] = diff, diff
        else:
            forward[:, :-1], backward[:, 1:] = diff, diff
        slope = np.where(np.abs(forward) <= np.abs(backward), forward, backward)
        slopes.append(np.where(np.isfinite(slope), slope, 0.0).ravel())
    return slopes


@dataclass
class Reconstruction:
    """``flat``: the wanted pixels that have a value (traced or filled), ``values`` theirs;
    ``unfilled``: the wanted pixels left without one (the caller keeps the raster value)."""

    flat: np.ndarray
    values: np.ndarray
    unfilled: np.ndarray


def reconstruct(flat_wanted, flat_traced, values, guide: Guide, width: int, rate=0.5) -> Reconstruction:
    """Values at every pixel of ``flat_wanted`` from those of ``flat_traced`` (a subset, with
    ``values`` (m,) or (m, 3)), by the guided joint bilateral filter of the module doc.

    ``rate``: the rate the pixels were traced at, a number or one per wanted pixel (quarter
    rate looks 2 pixels away, others 1).  Non-finite traced values are not used."""
    flat_wanted = np.asarray(flat_wanted, np.int64).ravel()
    flat_traced = np.asarray(flat_traced, np.int64).ravel()
    values = np.asarray(values, np.float64)
    scalar = values.ndim == 1
    values2 = values[:, None] if scalar else values.reshape(len(values), -1 if len(values) else values.shape[-1])
    if len(values2) != len(flat_traced):
        raise ValueError(f"{len(flat_traced)} traced pixels but {len(values2)} values")
    channels = values2.shape[1]
    size = len(guide.depth)
    height = size // int(width)
    empty_values = np.zeros((0,) if scalar else (0, channels))

    def result(flat, vals, unfilled):
        vals = vals.reshape(-1) if scalar else vals.reshape(-1, channels)
        assert np.isfinite(vals).all(), "reconstruction produced a non-finite value"
        return Reconstruction(flat=flat, values=vals, unfilled=unfilled)

    if len(flat_wanted) == 0:
        return result(flat_wanted, empty_values, flat_wanted)
    usable = np.isfinite(values2).all(axis=1) if len(flat_traced) else np.zeros(0, bool)
    have = np.zeros(size, bool)
    have[flat_traced[usable]] = True
    field = np.zeros((size, channels))
    field[flat_traced[usable]] = values2[usable]

    missing = flat_wanted[~have[flat_wanted]]
    radius = np.broadcast_to(rate_radius(rate), flat_wanted.shape)[~have[flat_wanted]]
    n = len(missing)
    total = np.zeros((n, channels))
    weight = np.zeros(n)
    best_distance = np.full(n, np.inf)
    best_value = np.zeros((n, channels))
    if n:
        rows, cols = np.divmod(missing, int(width))
        depth_p = guide.depth[missing]
        normal_p = guide.normal[missing]
        element_p = guide.element[missing]
        slope_r, slope_c = (s[missing] for s in _depth_slopes(guide.depth, height, int(width)))
        scale = np.where(np.isfinite(depth_p) & (depth_p > 0), depth_p, np.inf)
        offsets = sorted(((dr, dc) for dr in range(-2, 3) for dc in range(-2, 3) if (dr, dc) != (0, 0)),
                         key=lambda o: o[0] ** 2 + o[1] ** 2)
        for dr, dc in offsets:
            reach = max(abs(dr), abs(dc))
            r, c = rows + dr, cols + dc
            ok = (radius >= reach) & (r >= 0) & (r < height) & (c >= 0) & (c < width) & np.isfinite(scale)
            q = np.where(ok, r * int(width) + c, 0)
            ok &= have[q] & (guide.element[q] == element_p)
            if not np.any(ok):
                continue
            depth_q = guide.depth[q]
            with np.errstate(invalid="ignore", over="ignore"):
                residual = np.abs(depth_q - (depth_p + slope_r * dr + slope_c * dc)) / scale
            residual = np.where(ok & np.isfinite(residual), residual, np.inf)
            cosine = np.clip(np.sum(normal_p * guide.normal[q], axis=1), 0.0, 1.0)
            spatial = np.exp(-(dr * dr + dc * dc) / (2.0 * np.where(radius == 2, SPATIAL_SIGMA[2],
                                                                     SPATIAL_SIGMA[1]) ** 2))
            w = spatial * np.exp(-np.minimum(residual / DEPTH_SIGMA, 30.0) ** 2) * cosine ** NORMAL_POWER
            w = np.where(ok & np.isfinite(residual), w, 0.0)
            total += w[:, None] * field[q]
            weight += w
            # Offsets come nearest first: the first same-element pixel within the fallback depth wins.
            near = ok & (residual <= FALLBACK_DEPTH) & ~np.isfinite(best_distance)
            best_distance[near] = dr * dr + dc * dc
            best_value[near] = field[q[near]]
    filled = weight > MIN_WEIGHT
    out = np.zeros((n, channels))
    out[filled] = total[filled] / weight[filled, None]
    fallback = ~filled & np.isfinite(best_distance)
    out[fallback] = best_value[fallback]
    got = filled | fallback
    traced_wanted = flat_wanted[have[flat_wanted]]
    flat = np.concatenate([traced_wanted, missing[got]])
    vals = np.concatenate([field[traced_wanted], out[got]])
    order = np.argsort(flat, kind="stable")
    return result(flat[order], vals[order], missing[~got])


def element_rates(rates, effect: str, n_elements: int) -> np.ndarray:
    """(n_elements + 1,) the rate of each element's ``effect`` from ``rates`` (effect name ->
    per-element rates, or None; 1.0 where not given), checked against ``RATES``; the last entry
    (pixels of no element, index -1) is 1.0."""
    result = np.ones(n_elements + 1)
    given = None if rates is None else rates.get(effect)
    if given is not None:
        given = np.broadcast_to(np.asarray(given, np.float64), (n_elements,))
        result[:n_elements] = [check_rate(value) for value in given]
    return result


def traced_subset(flat, pixel_rate, height: int, width: int, frame: int) -> np.ndarray:
    """Bool per pixel of ``flat`` (flat indices of an (height, width) image): whether it gets rays
    on ``frame`` at its rate ``pixel_rate`` (a number or one per pixel)."""
    flat = np.asarray(flat, np.int64)
    pixel_rate = np.broadcast_to(np.asarray(pixel_rate, np.float64), flat.shape)
    cast = np.zeros(flat.shape, bool)
    for rate in np.unique(pixel_rate):
        chosen = pixel_rate == rate
        cast[chosen] = traced_pixel_mask(height, width, rate, frame).ravel()[flat[chosen]]
    return cast
