"""The ``BENEFIT`` selection: (element, effect) items bought for the most error per millisecond.

Beside the paper's heuristic (``heuristic.py``, the ``PAPER`` selection, unchanged), one
frame at a time, plain numpy:

Items
    Every tagged effect of a visible candidate within the area limit is one item: a glass
    ball can buy its refraction without its shadow.
Value
    Expected reduction of error: the pixels the effect changes (own pixels for reflections and
    refractions, the shadow footprint on receivers for shadows) x a per-pixel difference between
    the traced and the raster image x K / Q (the designer's weights) x the effect's LDR-FLIP per unit
    of change (``prior_scale.EFFECT_WEIGHT``).  The difference is learned on frames where the item
    was traced (the GPU measures it beside the image, ``item_benefit.measure``), pulled back to its
    prior by ``DECAY`` on each frame it is visible but not traced (the view changed), and before
    its first measurement is a prior from the materials under its pixels (``item_benefit.priors``)
    scaled per effect to what the scene's traced items measure (``prior_scale.PriorScale``).
Exploration
    An item never measured gains a bonus that grows with the frames it waited, visible:
    after ``EXPLORE_FRAMES`` such frames it is worth more than every other item together, so
    it is traced as soon as it fits the time the items kept from last frame leave.  The bonus
    competes with this frame's adds only: a guess never evicts a traced item (a pop each).  At
    most ``EXPLORE_MAX`` such items compete in one frame (the longest waiting).
Switching cost
    Changing an item's state pops its pixels by about its own value (what tracing changes
    there), so dropping a selected item costs ``SWITCH`` times its value and adding one costs
    the same: a rival must be worth (1 + SWITCH) / (1 - SWITCH) times more to displace it;
    a clearly better item wins at once.
A band in time
    The time left moves from frame to frame with the raster half's own noise (atrium path1 at
    0.75 of the way, a 63 ms budget: between 2 and 26 ms within 20 frames, often halving or
    doubling from one frame to the next); without a band every move forces a drop or allows an
    add.  An item not traced last frame must fit (``ADD_SLACK`` to spare: 0 since 6 Dec 2026) in
    the time left the recent frames could count on (the ``STEADY_QUANTILE``-th percentile of the
    last ``STEADY_FRAMES``, this one's included), not in this frame's peak.  An item traced last
    frame, and an effect whose fixed part was paid last frame, are charged ``HOLD`` less than
    predicted (the overrun this allows is at most HOLD / (1 - HOLD) of the time left).  An item
    dropped while it could still compete waits ``REST`` frames before it is added again; an item
    that left the view does not wait when it returns.
A guard on flips
    The pop is the element's, whichever of its effects comes back.  An element none of whose
    items is traced is taken again only ``FLIP_GAP`` frames after its last flip (a change of its
    traced state between two frames in view), whatever the time left does: no element flips more
    than twice within FLIP_GAP + 1 frames (issue 20: twice in 10), even when the budget forces
    drops (``flip_guard``).  The guard holds adds only; a drop the time left forces is never
    delayed (the budget comes first).
Cost
    Per item from ``item_costs`` (its expected rays times its learned rays ratio times the
    effect's learned ms; a designer's Q divides the item's value instead, never its ms), plus per
    effect a fixed part paid once if any of its items is traced (``knapsack.solve_grouped``);
    the trace stage's fixed overhead is charged once; the time left is reduced by the margin
    and planned to the aim of ``frame_time.FrameTime`` (the predictions' recent errors, the
    share of frames over budget).
Choice: ``knapsack.solve_grouped`` within the time left (``solve_choices`` with tiers).

The constants were set on the training paths (arcade path1-2, atrium path1) only; the
judged paths are arcade path3, atrium path2-3 and the showcase (docs/DESIGN.md).
"""
from __future__ import annotations

from itertools import compress, repeat

import numpy as np

from . import knapsack
from .flip_guard import FLIP_GAP, FlipGuard  # noqa: F401
from .frame_time import (AIM_OVER, AIM_RANGE, AIM_SHARE, AIM_STEP, MARGIN_FRAMES, STEADY_FRAMES,  # noqa: F401
                         STEADY_QUANTILE, FrameTime, MeasureCost)
from .exploration import exploration
from .item_choice import ItemChoice
from .prior_scale import PriorScale
from ..finite import finite
from ..schema import EFFECTS

SWITCH = 0.25
# An item not traced last frame is charged this share more than predicted, besides fitting the steady
# time left (0.25 until 6 Dec 2026; docs/selection.md, "Adds without slack").
ADD_SLACK = 0.0
# An item traced last frame is charged this share less (it keeps its place through the time
# left's noise); an item dropped while it competed waits REST frames before it is added again.
HOLD = 0.1
REST = 4
DECAY = 0.05
SMOOTHING = 0.3
EXPLORE_FRAMES = 8
# At most this many never-measured items get the bonus in one frame, and beyond this many items the
# exploration's knapsack holds only those and the first one's adds (exploration.py): a bound on its
# work (sample scenes have at most 48 items; at 1,000 candidates it took 9.5-11 ms a frame).
EXPLORE_MAX = 64
# Quality tiers (issue 23): the rates an item may be traced at, the share of its full-rate benefit
# each keeps and of its cost each takes: priors (tests/core/test_trace_rates.py), replaced per
# effect and rate by what is measured (BenefitSelector.keep; item_costs.ItemCosts.tier_costs).
TIER_RATES = (1.0, 0.5, 0.25)
TIER_KEEP = {1.0: 1.0, 0.5: 0.85, 0.25: 0.65}
TIER_COST = {1.0: 1.0, 0.5: 0.9, 0.25: 0.7}
KEEP_SMOOTHING = 0.1
KEEP_RANGE = (0.25, 1.0)  # a share learned near 0 would never be tried again
# A traced frame measures what its items changed (the GPU's change read back costs ms): when it
# traces an item never measured or at another rate than at its last measurement; MEASURE_EVERY
# frames after the last measurement when the time its items leave pays the measurement's learned
# cost (frame_time.MeasureCost); MEASURE_STALE frames after it in any case.
MEASURE_EVERY = 2
MEASURE_STALE = 8
# The material priors are recomputed every PRIOR_EVERY frames, and when a visible candidate has none.
PRIOR_EVERY = 8
MAX_VALUE, NO_ROOM = 1e15, 1e12  # NO_ROOM: the add factor when the recent frames left no time at all


def _item_keys(names) -> list:
    """The (name, effect) keys of the (n, 3) item arrays, row by row."""
    return [(name, effect) for name in names for effect in EFFECTS]


class BenefitSelector:
    """What the BENEFIT selection keeps from frame to frame of a replay (by element name)."""

    def __init__(self):
        self.estimates: dict[tuple[str, str], float] = {}
        self.observations: dict[tuple[str, str], int] = {}
        self.waited: dict[tuple[str, str], int] = {}
        self.previous: set[tuple[str, str]] = set()
        self.dropped_at: dict[tuple[str, str], int] = {}  # item -> self.frames when it was last dropped
        self.guard = FlipGuard()  # the elements' flips
        self.previous_rate: dict[tuple[str, str], float] = {}
        self.prior_cache: dict[str, np.ndarray] = {}  # element name -> (3,) its last computed priors
        self.priors_at = None  # self.frames when the priors were last computed
        self.kept: dict[tuple[str, float], float] = {}  # (effect, rate) -> learned share of the benefit
        self.measured_at: dict[tuple[str, str], float] = {}  # item -> the rate of its last measurement
        self.frames = 0
        self._names_keys = None  # (the last frame's names, their item keys, {item key: flat index} when asked)
        self.time = FrameTime()  # the margin, the steady time left, the aim
        self.measure_cost = MeasureCost()
        self.measured_frame = -MEASURE_STALE  # the frame index of the last measurement
        self.prior_scale = PriorScale()  # the priors' scale, each effect's weight (fitted, learned)

    def _keys(self, names) -> list:
        """:func:`_item_keys`, kept while the element names stay those of the last frame."""
        cached = self._names_keys
        if cached is None or cached[0] != list(names):
            cached = (list(names), _item_keys(names), {})
            self._names_keys = cached
        return cached[1]

    def _mask(self, names, members) -> np.ndarray:
        """(n, 3) bool: the items of ``names`` among ``members`` (item keys), by a lookup of each
        member (the members are few beside the items: the traced, the recently dropped)."""
        keys = self._keys(names)
        positions = self._names_keys[2]
        if not positions:
            positions.update(zip(keys, range(len(keys))))
        flat = np.zeros(len(keys), bool)
        found = [index for index in map(positions.get, members) if index is not None]
        flat[found] = True
        return flat.reshape(len(names), len(EFFECTS))

    # -- the decision ------------------------------------------------------------
    def margin_ms(self, available_ms: float) -> float:
        return self.time.margin_ms(available_ms, self.frames)

    def per_pixel(self, names, priors: np.ndarray, eligible: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(n, 3) learned estimates (prior where never measured) and (n, 3) never-measured flags."""
        shape = np.shape(eligible)
        learned = np.fromiter(map(self.estimates.get, self._keys(names), repeat(np.nan)), np.float64,
                              count=shape[0] * len(EFFECTS)).reshape(shape)
        fresh = np.isnan(learned)
        estimate = np.where(fresh, np.asarray(priors, np.float64).reshape(shape), learned)
        return np.clip(finite(estimate, nan=0.0, posinf=0.0), 0.0, MAX_VALUE), fresh

    def choose(self, names, eligible, pixels, priors, priority, cost_ms, time_left_ms, overhead_ms,
               tiers: bool = False, fixed_ms=None, unmeasured=None, tier_costs=None, visible=None) -> ItemChoice:
        """This frame's items.  Arrays (n, 3) in ``EFFECTS`` order except ``priority`` (n,): K / Q;
        ``cost_ms`` each item's predicted ms at full rate (``item_costs``: the ms it takes);
        ``fixed_ms`` (3,) per effect the ms paid once if any of its items is traced;
        ``unmeasured`` (3,) bool, effects whose cost was never measured: one item of each (the
        most valuable per predicted ms) is the probe, the others wait for its measurement.
        ``tiers``: each item may be bought at full, half or quarter rate (``TIER_RATES``), at
        ``tier_costs`` (n, 3, len(TIER_RATES)) ms (``item_costs.tier_costs``; None: the full cost
        x ``TIER_COST``).  ``visible`` (n,) the elements in view (None: those with an eligible
        item), for the guard on flips."""
        eligible = np.asarray(eligible, bool)
        visible = eligible.any(axis=1) if visible is None else np.asarray(visible, bool).reshape(len(names))
        per_pixel, fresh = self.per_pixel(names, priors, eligible)
        value = np.asarray(pixels, np.float64) * per_pixel * np.outer(priority, self.prior_scale.weight)
        value = np.where(eligible, np.clip(finite(value, nan=0.0, posinf=MAX_VALUE), 0.0, MAX_VALUE), 0.0)
        cost = np.clip(finite(cost_ms, nan=np.inf, posinf=np.inf), 0.0, np.inf)
        self.frames += 1
        available = max(float(time_left_ms) - float(overhead_ms), 0.0)
        margin = self.margin_ms(available)
        capacity = max(available - margin, 0.0)
        # Adds are sized for the time left the recent frames could be counted on (STEADY_QUANTILE
        # of the last STEADY_FRAMES), not for this frame's peak: an item added on a frame of
        # uncommon room would be dropped again on the next ordinary one.
        steady = self.time.steady_ms(available)
        # How much this frame's time exceeds the steady one; no steady time at all: nothing new is
        # added (a finite factor, so a 0 ms cost stays a number).
        peak = available / steady if 0.0 < steady < available else (1.0 if steady > 0.0 else NO_ROOM)
        add_factor = (1.0 + ADD_SLACK) * peak
        fixed = np.zeros(len(EFFECTS)) if fixed_ms is None else np.clip(finite(fixed_ms, nan=np.inf), 0.0, np.inf)
        if unmeasured is not None:  # an effect's first frame traces one probe item (its cost is a guess)
            for j in np.flatnonzero(np.asarray(unmeasured, bool) & eligible.any(axis=0)):
                fits = eligible[:, j] & (cost[:, j] + fixed[j] <= capacity)
                ratio = np.where(fits, value[:, j] / np.maximum(cost[:, j], 1e-12), -1.0)
                probe = np.zeros(len(eligible), bool)
                if fits.any():
                    probe[int(np.argmax(ratio))] = True
                eligible = eligible.copy()
                eligible[:, j] &= probe

        keys = self._keys(names)
        was = self._mask(names, self.previous)
        resting = self._mask(names, [key for key, at in self.dropped_at.items() if self.frames - at < REST])
        traced_before = was.any(axis=1)
        guarded = self.guard.blocked(names, self.frames) & ~traced_before
        may_add = eligible & ~(~was & resting) & ~guarded[:, None]
        held = was.any(axis=0)  # the effects whose fixed part was paid last frame
        charged_fixed = np.where(held, fixed * (1.0 - HOLD), fixed * peak)
        switched = np.where(was, value * (1.0 + SWITCH), value * (1.0 - SWITCH))
        if tier_costs is None:
            tier_costs = cost[:, :, None] * np.array([TIER_COST[tier] for tier in TIER_RATES])[None, None, :]
        tier_costs = np.clip(finite(tier_costs, nan=np.inf), 0.0, np.inf)
        charged = np.where(was, cost * (1.0 - HOLD), cost * add_factor)

        def fill(allowed, bonus, room, fixed_due):
            """(n, 3) rates of the best items among ``allowed`` within ``room``."""
            if tiers:
                return self._choose_rates(names, allowed, value, bonus, was, tier_costs, room, fixed_due,
                                          add_factor)
            items = np.flatnonzero(allowed.ravel())  # only those allowed: no infinite cost to clean
            flat = np.zeros(allowed.size)
            flat[items[knapsack.solve_grouped((switched + bonus).ravel()[items], charged.ravel()[items],
                                              items % len(EFFECTS), fixed_due, room)]] = 1.0
            return flat.reshape(allowed.shape)

        rate = fill(may_add, np.zeros(eligible.shape), capacity, charged_fixed)
        # Exploration competes only for the time the items kept from last frame leave: a guess may
        # displace this frame's adds, never a traced item (arcade path1 at 0.75: seven pops at once).
        kept = (rate > 0) & was
        option = np.searchsorted(-np.asarray(TIER_RATES), -rate)  # each kept item's tier (full: 0)
        kept_cost = np.take_along_axis(tier_costs, np.minimum(option, len(TIER_RATES) - 1)[:, :, None],
                                       axis=2)[:, :, 0] if tiers else charged  # tiers: at most their cost
        paid = kept.any(axis=0)
        room = capacity - float(np.sum(kept_cost[kept])) - float(np.sum(charged_fixed[paid]))
        explore = may_add & ~kept & fresh & (cost * add_factor <= room)
        if np.any(explore):
            waited = np.fromiter(map(self.waited.get, compress(keys, explore.ravel().tolist()), repeat(0)), np.float64)
            allowed, bonus = exploration(explore, may_add & ~kept, None if tiers else rate > 0, waited, switched, cost,
                                         float(switched[eligible].sum()) + 1e-12, EXPLORE_FRAMES, EXPLORE_MAX,
                                         cost * add_factor + np.where(paid, 0.0, charged_fixed) <= room)
            added = fill(allowed, bonus, room, np.where(paid, 0.0, charged_fixed))
            rate = np.where(kept, rate, added)
        chosen = rate > 0
        spent = np.zeros(eligible.shape)
        for option, tier in enumerate(TIER_RATES):
            spent = np.where(chosen & (rate == tier), tier_costs[:, :, option], spent)
        return ItemChoice(chosen=chosen, eligible=eligible, value=value, cost_ms=np.where(eligible, cost, 0.0),
                          per_pixel=per_pixel, capacity_ms=capacity, margin_ms=margin, rate=rate,
                          chosen_cost_ms=spent, fixed_ms=float(fixed[chosen.any(axis=0)].sum()), visible=visible)

    def keep(self, effect: str, tier: float) -> float:
        """The share of an item's full-rate benefit a rate keeps: learned per effect and rate from
        items measured at that rate right after a full-rate measurement, ``TIER_KEEP`` before."""
        return self.kept.get((effect, tier), TIER_KEEP[tier])

    def _choose_rates(self, names, eligible, value, bonus, was, tier_costs, capacity, fixed,
                      add_factor=1.0 + ADD_SLACK) -> np.ndarray:
        """(n, 3) rate per item (0: not traced) by the multiple-choice knapsack over TIER_RATES:
        an option's value is the item's value x its kept share, its cost ``tier_costs``, each
        effect's ``fixed`` part paid once if any of its items is traced; the switching cost counts
        a change of rate like a change of state; shadows only at full rate."""
        items = np.argwhere(eligible)
        rows, effects = items[:, 0], items[:, 1]
        tiers = np.asarray(TIER_RATES, np.float64)
        before = np.fromiter(map(self.previous_rate.get, [(names[i], EFFECTS[j]) for i, j in items.tolist()],
                                 repeat(0.0)), np.float64, count=len(items))
        kept = was[rows, effects][:, None]
        same = kept & (before[:, None] == tiers[None, :])
        factor = np.where(same, 1.0 + SWITCH, np.where(kept, 1.0, 1.0 - SWITCH))
        shares = np.array([[self.keep(effect, tier) for tier in TIER_RATES] for effect in EFFECTS])
        values = value[rows, effects][:, None] * shares[effects] * factor + bonus[rows, effects][:, None]
        costs = tier_costs[rows, effects, :] * np.where(same, 1.0 - HOLD, np.where(kept, 1.0, add_factor))
        reduced_shadow = (effects == EFFECTS.index("shadows"))[:, None] & (tiers < 1.0)[None, :]  # full rate only
        values[reduced_shadow], costs[reduced_shadow] = 0.0, np.inf
        picked = knapsack.solve_choices(values, costs, capacity, groups=effects, group_costs=fixed)
        rate = np.zeros(eligible.shape)
        traced = picked >= 0
        rate[rows[traced], effects[traced]] = tiers[picked[traced]]
        return rate

    # -- learning ------------------------------------------------------------------
    def observe(self, names, choice: ItemChoice, priors, measured=None, pixels=None) -> None:
        """After the frame: ``measured`` (n, 3) summed differences per item where traced (None:
        not measured), ``pixels`` (n, 3) the pixels each item covers (its divisor)."""
        chosen = np.asarray(choice.chosen, bool)
        eligible = np.asarray(choice.eligible, bool)
        keys = self._keys(names)
        was = self._mask(names, self.previous)
        # Dropped while it competed (not for leaving the view): it rests (REST); older drops are
        # forgotten (they hold nothing back any more).
        self.dropped_at = {key: at for key, at in self.dropped_at.items() if self.frames - at < REST}
        self.dropped_at.update((keys[k], self.frames) for k in np.flatnonzero((eligible & ~chosen & was).ravel()))
        visible = eligible.any(axis=1) if choice.visible is None else np.asarray(choice.visible, bool)
        self.guard.observe(names, visible, chosen.any(axis=1), {name for name, _ in self.previous}, self.frames)
        traced = np.flatnonzero(chosen.ravel())
        self.previous = {keys[k] for k in traced}
        rates = np.ones(len(keys)) if choice.rate is None else np.asarray(choice.rate, np.float64).ravel()
        self.previous_rate = {keys[k]: float(rates[k]) for k in traced}
        # Per eligible item: measured (traced, with a measurement); traced without one: kept as
        # it is (a traced frame measures at most every MEASURE_STALE frames, and a traced item's
        # estimate pulled towards its prior meanwhile drifted 30-40% of the way there); not traced:
        # decayed towards its prior (it has an estimate: the view moved on since), else one more
        # frame waited.
        if measured is not None and pixels is not None:
            pixels = np.asarray(pixels, np.float64)
            with np.errstate(divide="ignore", invalid="ignore"):
                seen_all = np.clip(finite(np.asarray(measured, np.float64) / pixels), 0.0, MAX_VALUE)
            measuring = eligible & chosen & (pixels > 0)
        else:
            seen_all, measuring = None, np.zeros(eligible.shape, bool)
        if seen_all is not None:  # the priors' scale learns from the full-rate measurements
            self.prior_scale.observe(seen_all, measuring, priors, rates.reshape(eligible.shape) == 1.0)
        rest = np.flatnonzero((eligible & ~chosen).ravel())
        rest_keys = [keys[k] for k in rest]
        known = np.fromiter(map(self.estimates.__contains__, rest_keys), bool, count=len(rest_keys))
        decaying = [key for key, flag in zip(rest_keys, known.tolist()) if flag]
        if decaying:
            estimate = np.fromiter(map(self.estimates.__getitem__, decaying), np.float64, count=len(decaying))
            prior = finite(np.asarray(priors, np.float64).ravel()[rest[known]])
            self.estimates.update(zip(decaying, (estimate + DECAY * (prior - estimate)).tolist()))
        for key in (key for key, flag in zip(rest_keys, known.tolist()) if not flag):
            self.waited[key] = self.waited.get(key, 0) + 1
        for k in np.flatnonzero(measuring.ravel()).tolist():
            key = keys[k]
            effect = key[1]
            tier = float(rates[k])
            seen = float(seen_all.ravel()[k])
            old = self.estimates.get(key)
            if tier < 1.0 and old is not None and old > 0 and self.measured_at.get(key) == 1.0:
                # Measured at a reduced rate right after a full-rate measurement: the share kept.
                share = min(max(seen / old, KEEP_RANGE[0]), KEEP_RANGE[1])
                before = self.keep(effect, tier)
                self.kept[(effect, tier)] = before + KEEP_SMOOTHING * (share - before)
            self.measured_at[key] = tier
            # What a reduced rate changed, as the full rate's estimate (over its kept share).
            value = min(max(seen / (self.keep(effect, tier) if tier < 1.0 else 1.0), 0.0), MAX_VALUE)
            self.estimates[key] = value if old is None else old + SMOOTHING * (value - old)
            self.observations[key] = self.observations.get(key, 0) + 1
            self.waited.pop(key, None)

    def needs_priors(self, names, visible_candidates) -> bool:
        """Whether this frame must compute the material priors (read the layers before the
        selection): a visible candidate has none cached, or they are PRIOR_EVERY frames old."""
        if self.priors_at is None or self.frames - self.priors_at >= PRIOR_EVERY:
            return bool(np.any(visible_candidates))
        return any(names[i] not in self.prior_cache for i in np.flatnonzero(visible_candidates))

    def priors(self, names, computed=None) -> np.ndarray:
        """(n, 3) priors: ``computed`` this frame (and cached), else the cached ones (0 where none),
        times the scale per effect (``prior_scale``: fitted on the training paths, learned in the
        replay)."""
        if computed is not None:
            computed = np.asarray(computed, np.float64)
            self.prior_cache.update({name: computed[i].copy() for i, name in enumerate(names)})
            self.priors_at = self.frames
            return self.prior_scale.apply(computed)
        zero = np.zeros(len(EFFECTS))
        cached = np.array([self.prior_cache.get(name, zero) for name in names], np.float64).reshape(len(names), 3)
        return self.prior_scale.apply(cached)

    def wants_measurement(self, names, choice: ItemChoice, frame_index: int) -> bool:
        """Whether this traced frame measures what its items changed (see MEASURE_EVERY); a yes
        is recorded as a measurement at ``frame_index``."""
        since = frame_index - self.measured_frame
        cost = self.measure_cost.cost_ms()
        spare = float(choice.capacity_ms) - float(np.sum(choice.chosen_cost_ms)) - float(choice.fixed_ms)
        rate = np.ones(np.shape(choice.chosen)) if choice.rate is None else choice.rate
        # An item never measured, or traced at another rate than at its last measurement (quality
        # tiers learn the share a rate keeps from such pairs), is measured at once.
        wanted = since >= MEASURE_STALE or (since >= MEASURE_EVERY and (cost is None or spare >= cost)) or any(
            (names[i], EFFECTS[j]) not in self.estimates or self.measured_at.get((names[i], EFFECTS[j])) != rate[i, j]
            for i, j in zip(*np.nonzero(choice.chosen)))
        if wanted:
            self.measured_frame = frame_index
        return wanted

    def observe_measure_cost(self, measured: bool, ms: float) -> None:
        """A steady traced frame's composite ms, with the measurement's own ms when it measured."""
        self.measure_cost.observe(measured, ms)

    @property
    def aim(self) -> float:
        return self.time.aim

    def aimed_time_left(self, time_left_ms: float, budget_ms: float) -> float:
        return self.time.aimed_time_left(time_left_ms, budget_ms)

    def observe_frame(self, total_ms: float, budget_ms: float, traced: bool = True) -> None:
        self.time.observe_frame(total_ms, budget_ms, traced)

    def observe_time(self, predicted_ms: float, measured_ms: float) -> None:
        self.time.observe_time(predicted_ms, measured_ms, self.frames)
