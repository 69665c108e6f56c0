"""What an (element, effect) item costs to trace: the BENEFIT selection's cost model.

The paper's cost model (``cost_model.py``) predicts an element's ms as its rays times one cost per
ray per effect.  Measured on the sample scenes, an effect's time is mostly a fixed part (atrium,
320x240: shadows of one small caster, 1,000 rays, 4.5 ms; of every caster, 36,000 rays, 28 ms:
about 3.8 ms of building each light's shadow regions over the frame's pixels, then 0.7 us a
ray), so one cost per ray learned on a small item over-predicts a large one by 3-10x, and an
item predicted too dear is never traced, so never measured again.  Here, per effect:

* an item's ms against its rays: a power law, scale x rays ** exponent (``MIN_EXPONENT``..1),
  through the last ``WINDOW`` traced frames and, for the octaves of rays per item none of them
  falls in, the latest frame of each (``ANCHOR_BASE``: a large item measured once keeps its own
  price after the window has moved on), each frame's rays and ms divided among its items,
  over the pairs of frames whose rays an item are ``SPREAD`` apart (``MIN_PAIRS`` of them at
  least); never below Embree's own ms a ray (the slope of its timer, ``TraceCounters.*_embree_ms``,
  against the rays; ``TRUSTED_RAYS``); beyond the largest item of the window, growing as
  rays ** ``MIN_EXPONENT`` (an optimistic price: a fit on small items extrapolated at its own
  exponent priced atrium's oak, never traced, at 40 ms against the oracle's 22-32, so it was
  never tried).  Before such a
  spread: linear, ``EMBREE_FACTOR`` times Embree's ms a ray
  (the numpy work around a ray costs about twice Embree's own), the rest of the time an
  intercept paid once; the cost model's prior times ``UNMEASURED_MARGIN`` before the effect's
  first traced frame;
* ``fixed`` ms, charged once a frame when any item of the effect is traced: the trace stage's own
  timer of the lights' region building for shadows (``TraceCounters.shadow_setup_ms``, the median
  of the window), plus the linear fit's intercept before the power law is fitted;
* each item's rays: its expected rays (``area_px`` x the rays one of its pixels costs, from the
  shadow footprint for shadows) times a ratio learned from the rays the trace stage attributed to
  it (``TraceResult.item_rays``, an EMA); an item never traced takes the median ratio of the
  effect's measured items (1 before any), so one caster's measurement corrects all of them.

At a reduced rate (quality tiers) an item casts that share of its rays and its other pixels are
reconstructed: its cost is the per-ray part times the rate plus the reconstruction's learned ms
per pixel (``TraceCounters.reconstruct_ms`` / ``reconstructed_px``, the median of the window)
times the pixels not cast; before the first reconstruction is measured, the full cost times the
prior share ``TIER_COST``.  The fixed part is the same at every rate.

Q (``rt_cost``) scales an item's cost; it never adds a hidden margin.  Plain numpy, no bpy.
"""
from __future__ import annotations

import math
from collections import deque
from functools import lru_cache

import numpy as np

from ..finite import finite
from ..schema import EFFECTS
from .benefit_selection import TIER_COST, TIER_RATES
from .frame_time import median
from .cost_model import MS_PER_RAY_PRIOR, STALE_DISCOUNT, STALE_FRAMES, STALE_MAX_FRAMES, UNMEASURED_MARGIN

WINDOW = 32
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
# An effect with items that has not been traced for its stale period revises what it learned
# (``cost_model.STALE_FRAMES``): a fixed or per-ray part learned too high (the showcase's first
# traced frames took 2-3x the steady ms a ray) would otherwise price it out for the rest of the
# replay.  Its window is cleared and its costs are divided by STALE_DISCOUNT; each revision doubles
# the effect's idle frames before the next.  Its items' rays ratios are kept (counted rays, not timed).
# Besides the last WINDOW traced frames, each effect keeps its latest frame in every octave of
# rays per item (an anchor), so a large item measured once still prices its own range after the
# window has moved on: atrium path1, the oak's shadows (35,000 rays, about 26 ms traced) were
# priced from the small casters' frames alone once its frame left the window: 50 ms.
ANCHOR_BASE = 2.0
# An effect's costs are fitted again on every FIT_EVERY-th traced frame, and at once when a frame's
# ms are more than SURPRISE (relative) from what the fit predicted for its rays: a frame that
# agrees adds little to a median over WINDOW frames, and the fit cost 0.07-0.1 ms for each
# effect of each traced frame (0.4 ms a frame on atrium).  The first FIT_EVERY samples are each fitted.
FIT_EVERY = 4
SURPRISE = 0.25
# Embree's ms a ray is taken from a window's largest batch only when it holds this many rays at
# least (or from the slope between batches SPREAD apart): on fewer its per-call work weighs on each
# ray (atrium path1: 160 rays of one small caster 0.8 us a ray inside Embree, 1,000 rays 0.4, a
# 36,000-ray batch 0.19).  From a smaller batch it is an upper bound: the effect's last trusted
# figure caps it, and without one the line it gives is not extrapolated beyond the largest item
# measured (grows as rays ** MIN_EXPONENT there).  Before: after a stale revision cleared atrium
# path2's shadow window, one 4-ray frame priced the 30,000-ray young tree at 78-412 ms (the oracle
# measured 17-19), which was then never traced again for 90 frames.
TRUSTED_RAYS = 1000
RATIO_SMOOTHING = 0.3
RATIO_RANGE = (1e-3, 1e3)
MAX_MS = 1e12


class ItemCosts:
    """Learned per replay (keys are element names, so the order of elements may change)."""

    def __init__(self):
        self.samples = {effect: deque(maxlen=WINDOW) for effect in EFFECTS}  # (rays, ms, setup ms, Embree ms)
        self.anchors = {effect: {} for effect in EFFECTS}  # octave of rays per item -> its latest sample
        self.idle = np.zeros(len(EFFECTS), np.int64)  # frames each effect had items and was not traced
        self.stale_after = np.full(len(EFFECTS), STALE_FRAMES, np.int64)  # idle frames before a revision
        self.learned: set[str] = set()  # the effects measured at least once in this replay
        self.ratio: dict[tuple[str, str], float] = {}
        self._fit = {effect: _prior(effect) for effect in EFFECTS}
        self.embree_known = np.full(len(EFFECTS), np.nan)  # each effect's last trusted Embree ms a ray
        self._since_fit = {effect: 0 for effect in EFFECTS}  # samples added since the last fit
        self._pooled = np.ones(len(EFFECTS))
        self.reconstruction = {effect: deque(maxlen=WINDOW) for effect in EFFECTS}  # ms per pixel

    # -- predictions -------------------------------------------------------------------------
    def fixed_ms(self) -> np.ndarray:
        """(3,) ms charged once a frame per effect traced at all (EFFECTS order)."""
        return np.array([self._fit[effect][0] for effect in EFFECTS])

    def per_ray_ms(self) -> np.ndarray:
        """(3,) ms a ray of the linear part (the power law's scale where it is fitted)."""
        return np.array([self._fit[effect][1] for effect in EFFECTS])

    def rays_ms(self, rays) -> np.ndarray:
        """(n, 3) ms of items casting ``rays`` (n, 3), their effects' fixed parts not included."""
        rays = np.maximum(finite(rays, nan=0.0, posinf=MAX_MS), 0.0)
        out = np.empty_like(rays)
        for j, effect in enumerate(EFFECTS):
            out[:, j] = _item_ms(self._fit[effect], rays[:, j])
        return out

    def sample_ms(self, effect, rays: float, items: float) -> float:
        """What the current fit predicts for a traced frame of ``effect``: its fixed part and
        ``items`` items sharing ``rays`` (priced as :meth:`rays_ms` prices them)."""
        items = max(float(items), 1.0)
        return self._fit[effect][0] + items * float(_item_ms(self._fit[effect], np.array([float(rays) / items]))[0])

    def tick(self, wanted, traced) -> None:
        """After a frame: ``wanted`` / ``traced`` (3,) bool, the effects that had eligible items /
        that were traced.  An effect idle for its stale period revises its costs (STALE_*)."""
        wanted, traced = np.asarray(wanted, bool), np.asarray(traced, bool)
        self.idle = np.where(traced, 0, self.idle + (wanted & ~traced))
        for j in np.flatnonzero(self.idle >= self.stale_after):
            effect = EFFECTS[j]
            if effect in self.learned:  # measured once: its costs divided (never: the prior stays)
                fixed, scale, exponent, embree, largest = self._fit[effect]
                self._fit[effect] = (fixed / STALE_DISCOUNT, scale / STALE_DISCOUNT, exponent,
                                     embree / STALE_DISCOUNT, largest)
                self.embree_known[j] /= STALE_DISCOUNT
                self.samples[effect].clear()
                self.anchors[effect].clear()
            self.stale_after[j] = min(2 * self.stale_after[j], STALE_MAX_FRAMES)
            self.idle[j] = 0

    def unmeasured(self) -> np.ndarray:
        """(3,) bool: the effects not measured in this replay, or since their costs were last revised
        (STALE_*): their next item traced is a probe."""
        return np.array([not self.samples[effect] for effect in EFFECTS])

    def measured(self, chosen) -> bool:
        """Whether every effect with a chosen item (``chosen`` (n, 3)) has been measured."""
        return all(self.samples[effect] for j, effect in enumerate(EFFECTS) if np.any(np.asarray(chosen)[:, j]))

    def ratios(self, names) -> np.ndarray:
        """(n, 3) learned rays ratio of each item (the effect's pooled median where unmeasured)."""
        out = np.tile(self._pooled, (len(names), 1))
        if self.ratio:
            for i, name in enumerate(names):
                for j, effect in enumerate(EFFECTS):
                    value = self.ratio.get((name, effect))
                    if value is not None:
                        out[i, j] = value
        return out

    def predict(self, names, expected_rays, rt_cost) -> np.ndarray:
        """(n, 3) ms of each item at full rate, its effect's fixed part not included."""
        rays = np.asarray(expected_rays, np.float64) * self.ratios(names)
        ms = self.rays_ms(rays) * np.asarray(rt_cost, np.float64).reshape(-1, 1)
        return np.clip(finite(ms, nan=MAX_MS, posinf=MAX_MS, neginf=0.0), 0.0, MAX_MS)

    def tier_costs(self, names, expected_rays, pixels, rt_cost) -> np.ndarray:
        """(n, 3, len(TIER_RATES)) ms of each item at each rate of ``TIER_RATES``."""
        full = self.predict(names, expected_rays, rt_cost)
        out = np.empty(full.shape + (len(TIER_RATES),))
        pixels = finite(pixels, nan=0.0, posinf=0.0)
        q = np.asarray(rt_cost, np.float64).reshape(-1, 1)
        rays = np.asarray(expected_rays, np.float64) * self.ratios(names)
        for j, effect in enumerate(EFFECTS):
            per_pixel = float(np.median(self.reconstruction[effect])) if self.reconstruction[effect] else None
            for option, rate in enumerate(TIER_RATES):
                if per_pixel is None or rate >= 1.0:
                    out[:, j, option] = full[:, j] * TIER_COST[rate]
                else:
                    out[:, j, option] = (self.rays_ms(rays * rate)[:, j] + per_pixel * pixels[:, j] * (1.0 - rate)) \
                        * q[:, 0]
        return np.clip(finite(out, nan=MAX_MS, posinf=MAX_MS), 0.0, MAX_MS)

    # -- learning ------------------------------------------------------------------------------
    def observe(self, names, expected_rays, item_rays, chosen, rates, effect_ms, effect_rays,
                shadow_setup_ms=0.0, embree_ms=(0.0, 0.0, 0.0), reconstruct_ms=None, reconstructed_px=None) -> None:
        """A traced frame: ``expected_rays``/``item_rays``/``chosen``/``rates`` (n, 3);
        ``effect_ms``/``effect_rays``/``embree_ms`` (3,) the trace stage's counters per effect."""
        expected = np.asarray(expected_rays, np.float64) * np.where(np.asarray(rates) > 0, rates, 1.0)
        item_rays = finite(item_rays, nan=0.0, posinf=0.0, neginf=0.0)
        chosen = np.asarray(chosen, bool)
        low, high = RATIO_RANGE
        found = np.nonzero(chosen & (expected > 0) & (item_rays > 0))
        for i, j, ratio in zip(*(index.tolist() for index in found), (item_rays[found] / expected[found]).tolist()):
            key = (names[i], EFFECTS[j])
            value = min(max(ratio, low), high)
            old = self.ratio.get(key)
            self.ratio[key] = value if old is None else old + RATIO_SMOOTHING * (value - old)
        for j, effect in enumerate(EFFECTS):
            ms, rays = float(effect_ms[j]), float(effect_rays[j])
            spent = float((reconstruct_ms or {}).get(effect, 0.0))
            filled_px = float((reconstructed_px or {}).get(effect, 0))
            if filled_px > 0 and np.isfinite(spent) and 0 <= spent <= ms:
                self.reconstruction[effect].append(spent / filled_px)
                ms -= spent  # what is left is rays and the fixed part
            if not (chosen[:, j].any() and np.isfinite(ms) and ms > 0 and rays > 0):
                continue
            setup = float(shadow_setup_ms) if effect == "shadows" and np.isfinite(shadow_setup_ms) else 0.0
            inside = float(embree_ms[j]) if np.isfinite(embree_ms[j]) else 0.0
            sample = (rays, ms, min(max(setup, 0.0), ms), min(max(inside, 0.0), ms),
                      float(np.count_nonzero(chosen[:, j])))
            predicted = self.sample_ms(effect, rays, sample[4])
            octave = _octave(rays / sample[4])
            # A new range of rays per item (beyond the largest measured, or an octave not anchored
            # yet) is fitted at once too: it moves the fit's reach, not only its medians.
            new_range = octave not in self.anchors[effect] or rays / sample[4] > self._fit[effect][4]
            self.samples[effect].append(sample)
            self.anchors[effect][octave] = sample
            self._since_fit[effect] += 1
            if len(self.samples[effect]) <= FIT_EVERY or self._since_fit[effect] >= FIT_EVERY or new_range or \
                    not abs(ms - predicted) <= SURPRISE * predicted:
                window = np.asarray(self._window(effect), np.float64)
                embree, trusted = _embree_ms_a_ray(window[:, 0], window[:, 3])
                if trusted and embree > 0:  # 0: no Embree timer (a test double)
                    self.embree_known[j] = embree
                elif not trusted and not np.isnan(self.embree_known[j]):  # capped by the last trusted one
                    embree, trusted = min(embree, float(self.embree_known[j])), True
                self._fit[effect] = _fit(window, effect == "shadows", (embree, trusted))
                self._since_fit[effect] = 0
            self.learned.add(effect)
            measured = [v for (name, e), v in self.ratio.items() if e == effect]
            if measured:
                self._pooled[j] = median(measured)

    def _window(self, effect) -> list:
        """The samples an effect's costs are fitted on: its last WINDOW traced frames and the
        anchors (octaves of rays per item) none of them falls in."""
        recent = list(self.samples[effect])
        covered = {_octave(sample[0] / max(sample[4], 1.0)) for sample in recent}
        return recent + [sample for octave, sample in self.anchors[effect].items() if octave not in covered]


def _item_ms(fit, rays: np.ndarray) -> np.ndarray:
    """ms of items of ``rays`` each (a 1-d array, finite, >= 0) under ``fit``, fixed part excluded.
    Beyond the largest item measured, the slowest growth measured (MIN_EXPONENT): an optimistic
    price, so an item larger than any traced yet is tried and measured once (its first traced frame
    corrects the fit) instead of being priced out for good."""
    _, scale, exponent, embree, largest = fit
    within = np.minimum(rays, largest)
    beyond = np.divide(rays, within, out=np.ones_like(within), where=within > 0)
    return np.maximum(scale * within ** exponent * beyond ** MIN_EXPONENT, embree * rays)


def _octave(rays_per_item: float) -> int:
    return math.floor(math.log2(max(rays_per_item, 1.0)) / math.log2(ANCHOR_BASE))  # exact at powers of 2


@lru_cache(maxsize=8)
def _pairs(n: int) -> tuple[np.ndarray, np.ndarray]:
    """The (i, j) index pairs i < j of a window of n samples (read-only, kept per n)."""
    i, j = np.triu_indices(n, 1)
    i.flags.writeable = j.flags.writeable = False
    return i, j


def _embree_ms_a_ray(rays, inside) -> tuple[float, bool]:
    """(Embree's own ms a ray, whether it is trusted) from a window's batches (``rays``, ``inside``
    their ms inside Embree): the slope of its time against the rays over pairs of batches SPREAD
    apart (its per-call overhead is no ray's), else its largest batch's ms a ray, trusted from
    TRUSTED_RAYS rays."""
    i, j = _pairs(len(rays))
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


def _fit(samples, timed_setup: bool, embree=None) -> tuple[float, float, float, float, float]:
    """(fixed ms, scale, exponent, Embree's ms a ray, the largest item's rays) from a window of
    (rays, ms, setup ms, Embree ms, items): an item of r rays costs max(scale x r ** exponent,
    Embree's ms a ray x r), growing as r ** MIN_EXPONENT beyond the largest item measured.  The
    timed setup (shadows) is taken out first and is the fixed part (so a setup that grows with the
    casters is not counted twice).  ``embree``: (Embree's ms a ray, whether it is trusted), as
    ``ItemCosts`` settles it (an untrusted figure capped by the effect's last trusted one,
    ``TRUSTED_RAYS``); None: :func:`_embree_ms_a_ray` of the window."""
    data = np.asarray(samples, np.float64)
    rays, ms, setup, inside, items = data.T
    setup = setup if timed_setup else np.zeros_like(setup)
    rest = np.maximum(ms - setup, 0.0)
    items = np.maximum(items, 1.0)
    i, j = _pairs(len(data))
    embree, trusted = _embree_ms_a_ray(rays, inside) if embree is None else embree
    # An item's time against its rays, per item of each frame (a frame of two casters is two
    # items of half its rays each): a power law through the pairs of frames SPREAD apart.
    x, y = rays / items, rest / items
    usable = (x > 0) & (y > 0)
    apart = (np.maximum(x[i], x[j]) >= SPREAD * np.minimum(x[i], x[j])) & usable[i] & usable[j]
    if np.count_nonzero(apart) >= MIN_PAIRS:
        first, second = i[apart], j[apart]
        exponent = min(max(median(np.log(y[second] / y[first]) / np.log(x[second] / x[first])), MIN_EXPONENT), 1.0)
        scale = median(y[usable] / x[usable] ** exponent)
        return median(setup), scale, exponent, embree, float(np.max(x[usable]))
    # Before a spread: linear, EMBREE_FACTOR x Embree's ms a ray, the rest of the frame's time a
    # fixed part paid once (its intercept); from an untrusted Embree figure, not beyond the largest
    # item measured.
    per_ray = EMBREE_FACTOR * embree
    intercept = float(np.clip(median(rest - per_ray * rays), 0.0, float(rest.min())))
    if per_ray == 0.0:  # nothing measured inside Embree (a test double): every ms left per ray
        per_ray = median(np.maximum(rest - intercept, 0.0) / rays)
    if trusted or not np.any(usable):
        return median(setup) + intercept, per_ray, 1.0, embree, np.inf
    return median(setup) + intercept, per_ray, 1.0, 0.0, float(np.max(x[usable]))  # no floor from it


def _prior(effect) -> tuple[float, float, float, float, float]:
    """Before an effect's first traced frame: the cost model's prior ms a ray, margined."""
    return 0.0, MS_PER_RAY_PRIOR[effect] * UNMEASURED_MARGIN, 1.0, 0.0, np.inf
