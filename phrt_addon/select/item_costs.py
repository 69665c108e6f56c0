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

* each item's own correction: the effect's fit prices items by their rays, but items of equal rays
  differ (a tree's shadow rays cross its leaves' many triangles, a statue's a few), and a median
  over ``WINDOW`` frames follows a new item only once it holds half the window (atrium path2's
  young tree, traced alone for 30 frames: 5-7 ms a frame over its price).  Once the power law is
  fitted, a traced frame's ms of an effect beyond its timed setup is shared among its chosen
  items as their current prices of their measured rays (the fit's times each one's correction, so
  items traced together keep what each learned alone), and each keeps an EMA (``COST_SMOOTHING``)
  of the log of its share and of its rays.  Its correction is that share over what the current
  fit prices those rays at (so a refit that learns the same thing does not count it twice),
  within ``COST_RATIO_RANGE``, fading towards 1 by half every ``COST_HALF_LIFE`` frames it is
  not traced (an item priced high is tried again).  What the chosen set costs is what is learned.

At a reduced rate (quality tiers) an item casts that share of its rays and its other pixels are
reconstructed: its cost is the per-ray part times the rate plus the reconstruction's learned ms
per pixel (``TraceCounters.reconstruct_ms`` / ``reconstructed_px``, the median of the window)
times the pixels not cast; before the first reconstruction is measured, the full cost times the
prior share ``TIER_COST``.  The fixed part is the same at every rate.

These are the ms an item takes: the designer's Q (``rt_cost``) weighs it in the choice (its value
per ms is divided by Q, ``FrameRenderer._choose_items``), never the time the frame is planned with.
Plain numpy, no bpy.
"""
from __future__ import annotations

import math
from collections import deque

import numpy as np

from ..finite import finite
from ..schema import EFFECTS
from .benefit_selection import TIER_COST, TIER_RATES
from .cost_fit import embree_ms_a_ray, fit_shape, item_ms, item_ms_one
from .frame_time import median
from .cost_model import MS_PER_RAY_PRIOR, STALE_DISCOUNT, STALE_FRAMES, STALE_MAX_FRAMES, UNMEASURED_MARGIN

WINDOW = 32
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
RATIO_SMOOTHING = 0.3
RATIO_RANGE = (1e-3, 1e3)
# An item's own cost correction (see the module's docstring): smoothed as the rays ratios are,
# bounded so one stalled frame cannot price an item out, and fading over the fit's own window.
COST_SMOOTHING = RATIO_SMOOTHING
COST_RATIO_RANGE = (0.5, 2.0)
COST_HALF_LIFE = WINDOW
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
        # (name, effect) -> (EMA of log rays, EMA of log ms, frame learned): the items' own costs.
        self.own: dict[tuple[str, str], tuple[float, float, int]] = {}
        self.power = {effect: False for effect in EFFECTS}  # whether the effect's power law is fitted
        self.frames = 0  # frames ticked (the corrections' age)
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
            out[:, j] = item_ms(self._fit[effect], rays[:, j])
        return out

    def sample_ms(self, effect, rays: float, items: float) -> float:
        """What the current fit predicts for a traced frame of ``effect``: its fixed part and
        ``items`` items sharing ``rays`` (priced as :meth:`rays_ms` prices them)."""
        items = max(float(items), 1.0)
        return self._fit[effect][0] + items * float(item_ms(self._fit[effect], np.array([float(rays) / items]))[0])

    def tick(self, wanted, traced) -> None:
        """After a frame: ``wanted`` / ``traced`` (3,) bool, the effects that had eligible items /
        that were traced.  An effect idle for its stale period revises its costs (STALE_*)."""
        wanted, traced = np.asarray(wanted, bool), np.asarray(traced, bool)
        self.frames += 1
        self.idle = np.where(traced, 0, self.idle + (wanted & ~traced))
        for j in np.flatnonzero(self.idle >= self.stale_after):
            effect = EFFECTS[j]
            if effect in self.learned:  # measured once: its costs divided (never: the prior stays)
                self.own = {key: value for key, value in self.own.items() if key[1] != effect}
                self.power[effect] = False  # until a refit of new samples
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

    def cost_ratios(self, names) -> np.ndarray:
        """(n, 3) each item's own cost correction (1 where none was learned), faded by its age."""
        out = np.ones((len(names), len(EFFECTS)))
        if self.own:
            row = {name: i for i, name in enumerate(names)}
            for (name, effect), learned in self.own.items():
                i = row.get(name)
                if i is not None and self.power[effect]:
                    out[i, EFFECTS.index(effect)] = self._correction(effect, *learned)
        return out

    def _correction(self, effect, log_rays, log_ms, frame) -> float:
        """A learned share (EMAs of log rays and log ms, the frame learned) over the current fit's
        price of its rays, within COST_RATIO_RANGE, faded by its age."""
        priced = item_ms_one(self._fit[effect], math.exp(log_rays))
        low, high = COST_RATIO_RANGE
        ratio = min(max(math.exp(log_ms) / priced, low), high) if priced > 0 else 1.0
        return ratio ** (0.5 ** ((self.frames - frame) / COST_HALF_LIFE))

    def predict(self, names, expected_rays, own=None) -> np.ndarray:
        """(n, 3) ms of each item at full rate, its effect's fixed part not included (``own``: its
        :meth:`cost_ratios`, if already computed this frame)."""
        rays = np.asarray(expected_rays, np.float64) * self.ratios(names)
        ms = self.rays_ms(rays) * (self.cost_ratios(names) if own is None else own)
        return np.clip(finite(ms, nan=MAX_MS, posinf=MAX_MS, neginf=0.0), 0.0, MAX_MS)

    def tier_costs(self, names, expected_rays, pixels, own=None) -> np.ndarray:
        """(n, 3, len(TIER_RATES)) ms of each item at each rate of ``TIER_RATES`` (``own`` as for
        :meth:`predict`)."""
        own = self.cost_ratios(names) if own is None else own
        full = self.predict(names, expected_rays, own)
        out = np.empty(full.shape + (len(TIER_RATES),))
        pixels = finite(pixels, nan=0.0, posinf=0.0)
        rays = np.asarray(expected_rays, np.float64) * self.ratios(names)
        for j, effect in enumerate(EFFECTS):
            per_pixel = float(np.median(self.reconstruction[effect])) if self.reconstruction[effect] else None
            for option, rate in enumerate(TIER_RATES):
                if per_pixel is None or rate >= 1.0:
                    out[:, j, option] = full[:, j] * TIER_COST[rate]
                else:
                    out[:, j, option] = (self.rays_ms(rays * rate)[:, j] * own[:, j]
                                         + per_pixel * pixels[:, j] * (1.0 - rate))
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
            if self.power[effect]:  # the fit prices items by their rays: the chosen ones learn their own
                self._learn_own(names, np.flatnonzero(chosen[:, j]), effect, ms - min(max(setup, 0.0), ms),
                                item_rays[:, j])
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
                embree, trusted = embree_ms_a_ray(window[:, 0], window[:, 3])
                if trusted and embree > 0:  # 0: no Embree timer (a test double)
                    self.embree_known[j] = embree
                elif not trusted and not np.isnan(self.embree_known[j]):  # capped by the last trusted one
                    embree, trusted = min(embree, float(self.embree_known[j])), True
                self._fit[effect], self.power[effect] = fit_shape(window, effect == "shadows", (embree, trusted))
                self._since_fit[effect] = 0
            self.learned.add(effect)
            measured = [v for (name, e), v in self.ratio.items() if e == effect]
            if measured:
                self._pooled[j] = median(measured)

    def _learn_own(self, names, items, effect, rest_ms, item_rays) -> None:
        """The chosen ``items`` of ``effect`` share ``rest_ms`` (its ms beyond the timed setup) as
        their current prices of their measured ``item_rays`` (the fit's, times each one's own
        correction: two items traced together keep what each learned alone); each learns its
        share and its rays."""
        fit, keys = self._fit[effect], [(names[i], effect) for i in items.tolist()]
        rays = [max(float(value), 0.0) for value in item_rays[items].tolist()]
        priced = [item_ms_one(fit, r) * (self._correction(effect, *self.own[key]) if key in self.own else 1.0)
                  for key, r in zip(keys, rays)]
        total = sum(priced)
        if not (total > 0 and math.isfinite(total) and rest_ms > 0):
            return
        for key, item_rays_now, price in zip(keys, rays, priced):
            share = price * rest_ms / total
            if item_rays_now <= 0 or share <= 0:
                continue
            now = (math.log(item_rays_now), math.log(share))
            old = self.own.get(key)
            if old is not None:
                now = tuple(before + COST_SMOOTHING * (value - before) for before, value in zip(old[:2], now))
            self.own[key] = (now[0], now[1], self.frames)

    def _window(self, effect) -> list:
        """The samples an effect's costs are fitted on: its last WINDOW traced frames and the
        anchors (octaves of rays per item) none of them falls in."""
        recent = list(self.samples[effect])
        covered = {_octave(sample[0] / max(sample[4], 1.0)) for sample in recent}
        return recent + [sample for octave, sample in self.anchors[effect].items() if octave not in covered]


def _octave(rays_per_item: float) -> int:
    return math.floor(math.log2(max(rays_per_item, 1.0)) / math.log2(ANCHOR_BASE))  # exact at powers of 2


def _prior(effect) -> tuple[float, float, float, float, float]:
    """Before an effect's first traced frame: the cost model's prior ms a ray, margined."""
    return 0.0, MS_PER_RAY_PRIOR[effect] * UNMEASURED_MARGIN, 1.0, 0.0, np.inf
