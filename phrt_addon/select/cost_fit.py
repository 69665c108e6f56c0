"""An effect's trace cost against its rays, fitted on a window of traced frames: the curve
``item_costs.ItemCosts`` prices items with (see its module's docstring).  Plain numpy, no bpy."""
from __future__ import annotations

from functools import lru_cache

import numpy as np

from .frame_time import median

SPREAD = 1.5  # max/min ray count of the window before the line is fitted
# Per-ray ms over Embree's per-ray ms, before a spread of ray counts lets the slope be fitted:
# atrium path1 (a training path), every caster's shadows, 36,000 rays: 0.56 us a ray against 0.19
# inside Embree (a ratio, machine-independent to first order).
EMBREE_FACTOR = 3.0
MIN_PAIRS = 3  # pairs of frames SPREAD apart in rays before the power law is fitted
# An item's ms grow as its rays to this power at least (1: linear).  Measured, atrium path1 at
# 320x240, shadows beyond the lights' setup, one caster alone: 180 rays 1.0 ms, 840 rays 2.5 ms,
# 22,000 rays 18 ms (the oracle's timing): about rays ** 0.6 (numpy's and Embree's per-call work
# weighs on a small item, not on a large one).
MIN_EXPONENT = 0.6
# Embree's ms a ray is taken from a window's largest batch only when it holds this many rays at
# least (or from the slope between batches SPREAD apart): on fewer its per-call work weighs on each
# ray (atrium path1: 160 rays of one small caster 0.8 us a ray inside Embree, 1,000 rays 0.4, a
# 36,000-ray batch 0.19).  From a smaller batch it is an upper bound: the effect's last trusted
# figure caps it, and without one the line it gives is not extrapolated beyond the largest item
# measured (grows as rays ** MIN_EXPONENT there).  Before: after a stale revision cleared atrium
# path2's shadow window, one 4-ray frame priced the 30,000-ray young tree at 78-412 ms (the oracle
# measured 17-19), which was then never traced again for 90 frames.
TRUSTED_RAYS = 1000


def item_ms(fit, rays: np.ndarray) -> np.ndarray:
    """ms of items of ``rays`` each (a 1-d array, finite, >= 0) under ``fit``, fixed part excluded.
    Beyond the largest item measured, the slowest growth measured (MIN_EXPONENT): an optimistic
    price, so an item larger than any traced yet is tried and measured once (its first traced frame
    corrects the fit) instead of being priced out for good."""
    _, scale, exponent, embree, largest = fit
    within = np.minimum(rays, largest)
    beyond = np.divide(rays, within, out=np.ones_like(within), where=within > 0)
    return np.maximum(scale * within ** exponent * beyond ** MIN_EXPONENT, embree * rays)


def item_ms_one(fit, rays: float) -> float:
    """:func:`item_ms` of one item (finite rays >= 0), in plain Python: the items' own costs price a
    few entries a frame, where numpy's per-call work would cost more than the arithmetic."""
    _, scale, exponent, embree, largest = fit
    within = min(rays, largest)
    beyond = rays / within if within > 0 else 1.0
    return max(scale * within ** exponent * beyond ** MIN_EXPONENT, embree * rays)


@lru_cache(maxsize=8)
def pairs(n: int) -> tuple[np.ndarray, np.ndarray]:
    """The (i, j) index pairs i < j of a window of n samples (read-only, kept per n)."""
    i, j = np.triu_indices(n, 1)
    i.flags.writeable = j.flags.writeable = False
    return i, j


def embree_ms_a_ray(rays, inside) -> tuple[float, bool]:
    """(Embree's own ms a ray, whether it is trusted) from a window's batches (``rays``, ``inside``
    their ms inside Embree): the slope of its time against the rays over pairs of batches SPREAD
    apart (its per-call overhead is no ray's), else its largest batch's ms a ray, trusted from
    TRUSTED_RAYS rays."""
    i, j = pairs(len(rays))
    apart = np.maximum(rays[i], rays[j]) >= SPREAD * np.minimum(rays[i], rays[j])
    largest = int(np.argmax(rays))
    embree = float(inside[largest] / rays[largest])
    trusted = bool(rays[largest] >= TRUSTED_RAYS)
    if np.any(apart):
        first, second = i[apart], j[apart]
        slope = median((inside[second] - inside[first]) / (rays[second] - rays[first]))
        if slope > 0:
            embree, trusted = min(slope, embree), True
    return embree, trusted


def spread(samples, timed_setup: bool):
    """(per-item rays, per-item ms beyond the timed setup, usable, apart: the pairs of frames
    ``pairs`` SPREAD apart in rays an item) of a window of samples (see :func:`fit_window`)."""
    data = np.asarray(samples, np.float64)
    rays, ms, setup, _, items = data.T
    rest = np.maximum(ms - (setup if timed_setup else 0.0), 0.0)
    items = np.maximum(items, 1.0)
    i, j = pairs(len(data))
    x, y = rays / items, rest / items
    usable = (x > 0) & (y > 0)
    apart = (np.maximum(x[i], x[j]) >= SPREAD * np.minimum(x[i], x[j])) & usable[i] & usable[j]
    return x, y, usable, apart


def fit_window(samples, timed_setup: bool, embree=None) -> tuple[float, float, float, float, float]:
    """:func:`fit_shape`'s fit alone."""
    return fit_shape(samples, timed_setup, embree)[0]


def fit_shape(samples, timed_setup: bool, embree=None) -> tuple[tuple[float, float, float, float, float], bool]:
    """((fixed ms, scale, exponent, Embree's ms a ray, the largest item's rays) from a window of
    (rays, ms, setup ms, Embree ms, items): an item of r rays costs max(scale x r ** exponent,
    Embree's ms a ray x r), growing as r ** MIN_EXPONENT beyond the largest item measured.  The
    timed setup (shadows) is taken out first and is the fixed part (so a setup that grows with the
    casters is not counted twice).  ``embree``: (Embree's ms a ray, whether it is trusted), as
    ``ItemCosts`` settles it (an untrusted figure capped by the effect's last trusted one,
    ``TRUSTED_RAYS``); None: :func:`embree_ms_a_ray` of the window), and whether the power law
    was fitted (MIN_PAIRS pairs SPREAD apart; else the line)."""
    data = np.asarray(samples, np.float64)
    rays, ms, setup, inside, _ = data.T
    setup = setup if timed_setup else np.zeros_like(setup)
    rest = np.maximum(ms - setup, 0.0)
    i, j = pairs(len(data))
    embree, trusted = embree_ms_a_ray(rays, inside) if embree is None else embree
    # An item's time against its rays, per item of each frame (a frame of two casters is two
    # items of half its rays each): a power law through the pairs of frames SPREAD apart.
    x, y, usable, apart = spread(data, timed_setup)
    if np.count_nonzero(apart) >= MIN_PAIRS:
        first, second = i[apart], j[apart]
        exponent = min(max(median(np.log(y[second] / y[first]) / np.log(x[second] / x[first])), MIN_EXPONENT), 1.0)
        scale = median(y[usable] / x[usable] ** exponent)
        return (median(setup), scale, exponent, embree, float(np.max(x[usable]))), True
    # Before a spread: linear, EMBREE_FACTOR x Embree's ms a ray, the rest of the frame's time a
    # fixed part paid once (its intercept); from an untrusted Embree figure, not beyond the largest
    # item measured.
    per_ray = EMBREE_FACTOR * embree
    intercept = float(np.clip(median(rest - per_ray * rays), 0.0, float(rest.min())))
    if per_ray == 0.0:  # nothing measured inside Embree (a test double): every ms left per ray
        per_ray = median(np.maximum(rest - intercept, 0.0) / rays)
    if trusted or not np.any(usable):
        return (median(setup) + intercept, per_ray, 1.0, embree, np.inf), False
    return (median(setup) + intercept, per_ray, 1.0, 0.0, float(np.max(x[usable]))), False  # no floor from it
