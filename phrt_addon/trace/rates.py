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
unfilled and the caller keeps the raster value there.  A binary field (shadow visibility) takes
the value its same-element traced neighbours all agree on without weighing them (``_filter``).
Plain numpy over the missing pixels (``_filter``): the Python loops run over the 4 parity classes
and the offsets that reach traced pixels, never over pixels.  Cost here (atrium's oak shadows at
320x240, 27k of 35k pixels reconstructed, in one process against the windowed filter before):
quarter rate 33-43 -> 13-16 ms, half 22-33 -> 11-14 ms.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .reconstruction_guide import NO_ID, PAD, Guide

RATES = (0.25, 0.5, 1.0)
# Positions (row, col) of the traced pixel inside each 2x2 block at quarter rate, frame by frame.
QUARTER_ORDER = ((0, 0), (1, 1), (0, 1), (1, 0))
# Relative depth residual (against p's local plane) at which the depth weight is exp(-1).
DEPTH_SIGMA = 0.01
# Exponent of the normal weight max(n_p . n_q, 0) ** NORMAL_POWER (applied by three squarings).
NORMAL_POWER = 8
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


def _smaller_step(depth, here, pixel, step):
    """Per pixel (indices ``pixel`` of a flat padded depth image, ``here`` its depth), the depth
    change per pixel along ``step``: of the two one-sided differences the smaller in magnitude
    (the side on the same surface at a depth edge); 0 where neither side has a depth."""
    with np.errstate(invalid="ignore"):
        forward, backward = np.take(depth, pixel + step) - here, here - np.take(depth, pixel - step)
        # No depth on a side (inf or NaN) counts as an infinite difference: fmin drops NaN.
        slope = np.where(np.fmin(np.abs(forward), np.inf) <= np.fmin(np.abs(backward), np.inf), forward, backward)
    return np.where(np.isfinite(slope), slope, np.float32(0.0))


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
    size = guide.size
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
    # Channel-first (C, size): 1-D gathers and scatters per channel are much faster than of rows.
    field = np.zeros((channels, size))
    for channel in range(channels):
        field[channel][flat_traced[usable]] = values2[usable, channel]

    missing = flat_wanted[~have[flat_wanted]]
    radius = np.broadcast_to(rate_radius(rate), flat_wanted.shape)[~have[flat_wanted]]
    n = len(missing)
    traced_wanted = flat_wanted[have[flat_wanted]]
    out = np.zeros((channels, n))
    got = np.zeros(n, bool)
    if n:
        out, got = _filter(missing, radius, field, flat_traced[usable], guide, height, int(width))
    flat = np.concatenate([traced_wanted, missing[got]])
    order = np.argsort(flat, kind="stable")
    vals = np.stack([np.concatenate([field[channel][traced_wanted], out[channel][got]])[order]
                     for channel in range(channels)], axis=1)
    return result(flat[order], vals, missing[~got])


def _offsets_for(klass: int, traced_class: np.ndarray, far_wanted: bool) -> list:
    """The neighbourhood offsets (nearest first) from a pixel of parity ``klass`` that land on a
    parity class with traced pixels; those 2 away only if ``far_wanted``."""
    offsets = sorted(((dr, dc) for dr in range(-2, 3) for dc in range(-2, 3) if (dr, dc) != (0, 0)),
                     key=lambda o: o[0] ** 2 + o[1] ** 2)
    return [(dr, dc) for dr, dc in offsets
            if traced_class[(klass // 2 + dr) % 2 * 2 + (klass % 2 + dc) % 2] and
            (far_wanted or max(abs(dr), abs(dc)) < 2)]


def _agreeing(pos, e_p, reach, offsets, wide, traced_id, values):
    """For a binary field (0 or 1): per pixel, (the value its traced neighbours of the same id
    within its reach all have, or NaN where they disagree or there are none)."""
    count, total = np.zeros(len(pos)), np.zeros(len(pos))
    far_only = bool(np.any(reach != 2))
    for dr, dc in offsets:
        q = pos + (dr * wide + dc)
        ok = np.take(traced_id, q) == e_p
        if far_only and max(abs(dr), abs(dc)) == 2:
            ok &= reach == 2
        count += ok
        total += ok * np.take(values, q)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where((count > 0) & ((total == 0) | (total == count)), total / count, np.nan)


def _weighted(pos, e_p, reach, offsets, guide_images, wide, traced_id, values):
    """The joint bilateral weights of the module doc at the pixels ``pos`` (padded indices) over
    ``offsets``: (values (C, n), filled (n,))."""
    depth, normal = guide_images
    channels = len(values)
    d_p = np.take(depth, pos)
    n_p = [np.take(component, pos) for component in normal]
    s_r, s_c = _smaller_step(depth, d_p, pos, wide), _smaller_step(depth, d_p, pos, 1)
    scale = np.where(np.isfinite(d_p) & (d_p > 0), d_p, np.float32(np.inf))
    far_ok = reach == 2
    any_far, all_far = bool(far_ok.any()), bool(far_ok.all())  # of these pixels, not the class's
    spatial = (-0.5 / np.where(far_ok, SPATIAL_SIGMA[2], SPATIAL_SIGMA[1]) ** 2).astype(np.float32)
    inverse_sigma = np.float32(1.0 / DEPTH_SIGMA)
    weight, found = np.zeros(len(pos)), np.zeros(len(pos), bool)
    total = [np.zeros(len(pos)) for _ in range(channels)]
    best = [np.zeros(len(pos)) for _ in range(channels)]
    for dr, dc in offsets:
        far = max(abs(dr), abs(dc)) == 2
        if far and not any_far:
            continue
        q = pos + (dr * wide + dc)
        ok = np.take(traced_id, q) == e_p
        if far and not all_far:
            ok &= far_ok
        if not ok.any():
            continue
        residual = np.abs(np.take(depth, q) - (d_p + s_r * np.float32(dr) + s_c * np.float32(dc))) / scale
        # NaN (no depth at q or at p) counts as infinitely far: fmin drops it for 30.
        spread = np.fmin(residual * inverse_sigma, np.float32(30.0))
        cosine = n_p[0] * np.take(normal[0], q) + n_p[1] * np.take(normal[1], q) + n_p[2] * np.take(normal[2], q)
        np.clip(cosine, 0.0, 1.0, out=cosine)
        cosine *= cosine
        cosine *= cosine
        cosine *= cosine  # ** NORMAL_POWER (8) by squaring
        spread *= spread
        wq = np.exp(spatial * np.float32(dr * dr + dc * dc) - spread) * cosine * ok
        weight += wq
        # Offsets come nearest first: the first same-element pixel within the fallback depth wins.
        near = ok & (residual <= FALLBACK_DEPTH) & ~found
        found |= near
        for channel in range(channels):
            value_q = np.take(values[channel], q)
            total[channel] += wq * value_q
            np.copyto(best[channel], value_q, where=near)
    use = weight > MIN_WEIGHT
    safe = np.where(use, weight, 1.0)
    return np.array([np.where(use, total[channel] / safe, best[channel]) for channel in range(channels)]), \
        use | found


def _filter(missing, radius, field, traced, guide: Guide, height: int, width: int):
    """The joint bilateral filter (module doc) at the ``missing`` pixels: (values (C, n), filled);
    ``field``: (C, h * w) the traced values.

    On the guide's padded window (``Guide.padded``: every offset of a pixel is an index, no
    bounds tests), the traced pixels' ids and values scattered in; then per (row, col) parity
    class of the missing pixels, the offsets that land on a class with traced pixels (4 at half
    rate, 4 or 6 at quarter), each a few float32 operations over the class's missing pixels:
    the cost follows the missing pixels, not their rectangle.  Values and sums in float64.
    A binary field (every traced value 0 or 1: shadow visibility) first gives each pixel whose
    traced neighbours of its own id all agree that value (the weighted mean of equal values,
    whatever the weights; where they all vanish the weighted filter leaves the pixel to the
    raster term, this keeps its own element's agreed value); only the rest are weighted."""
    channels = field.shape[0]
    n = len(missing)
    rows, cols = np.divmod(missing, width)
    # The window: the whole image when the missing pixels spread over much of it (one window for
    # all of a layer's lights, computed once), else their rectangle and its 2-pixel reach.
    r0, r1 = max(int(rows.min()) - 2, 0), min(int(rows.max()) + 3, height)
    c0, c1 = max(int(cols.min()) - 2, 0), min(int(cols.max()) + 3, width)
    if 4 * (r1 - r0) * (c1 - c0) > height * width:
        r0, r1, c0, c1 = 0, height, 0, width
    depth, normal, ids = guide.padded(width, slice(r0, r1), slice(c0, c1))
    wide = c1 - c0 + 2 * PAD

    def padded_index(flat):
        rows, cols = np.divmod(flat, width)
        return (rows - r0 + PAD) * wide + (cols - c0 + PAD), rows, cols

    t_rows, t_cols = np.divmod(traced, width)
    traced = traced[(t_rows >= r0) & (t_rows < r1) & (t_cols >= c0) & (t_cols < c1)]
    at, t_rows, t_cols = padded_index(traced)
    traced_id = np.full(len(ids), NO_ID + 1, np.int64)  # untraced pixels: an id no pixel has
    traced_id[at] = np.take(ids, at)
    values = [np.zeros(len(ids)) for _ in range(channels)]
    for channel in range(channels):
        values[channel][at] = np.take(field[channel], traced)
    traced_values = field[:, traced]
    binary = channels == 1 and bool(np.all((traced_values == 0.0) | (traced_values == 1.0)))
    position, _, _ = padded_index(missing)
    klass_of = rows % 2 * 2 + cols % 2
    traced_class = np.bincount(t_rows % 2 * 2 + t_cols % 2, minlength=4)
    out = np.zeros((channels, n))
    filled = np.zeros(n, bool)
    for klass in range(4):
        members = np.flatnonzero(klass_of == klass)
        if len(members) == 0:
            continue
        reach = radius[members]
        offsets = _offsets_for(klass, traced_class, bool(np.any(reach == 2)))
        pos, e_p = position[members], np.take(ids, position[members])
        if binary:
            agreed = _agreeing(pos, e_p, reach, offsets, wide, traced_id, values[0])
            settled = np.isfinite(agreed)
            out[0][members[settled]] = agreed[settled]
            filled[members[settled]] = True
            members, pos, e_p, reach = members[~settled], pos[~settled], e_p[~settled], reach[~settled]
            if len(members) == 0:
                continue
        with np.errstate(invalid="ignore", over="ignore"):  # once: per offset it cost 10 us a call
            got, ok = _weighted(pos, e_p, reach, offsets, (depth, normal), wide, traced_id, values)
        out[:, members] = got
        filled[members] = ok
    return out, filled


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


def forced_rates(forced, names):
    """The oracle's rates (``FrameRenderer.forced_rates``) as the trace stage takes them: per effect
    name a rate for every element (a float) or per element name (a dict; 1.0 for those not named),
    as per-element arrays over ``names``; None when nothing is forced."""
    if not forced:
        return None
    arrays = {}
    for effect, rate in forced.items():
        if isinstance(rate, dict):
            unknown = sorted(set(rate) - set(names))
            if unknown:  # a misspelt name would quietly trace at full rate
                raise ValueError(f"forced {effect} rate for elements not in the frame: {', '.join(map(str, unknown))}")
            arrays[effect] = np.array([check_rate(rate.get(name, 1.0)) for name in names], np.float64)
        else:
            arrays[effect] = np.full(len(names), check_rate(rate))
    return arrays


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
