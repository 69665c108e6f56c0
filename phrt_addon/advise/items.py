"""The advisor's items and their books: (element, effect) pairs measured on judged frames.

An item is named ``"<element>/<effect>"`` (the benefit selection's item keys, ``select/items.py``);
``effect`` is one of ``schema.EFFECTS``.  Tagged items are the tagged effects of candidate
elements; untagged ones are *prospects*: objects nobody tagged whose material could change when
traced (:func:`prospect_effects`), the most promising ``cap`` of them (:func:`choose_prospects`),
made temporary candidates for the measurement only.

One judged frame's measurements are an ``oracle.FrameCandidates`` whose names are item keys
(the oracle's own type: benefit = LDR-FLIP of the raster frame minus that of the frame with the
item traced alone, cost = the median trace ms less the trace stage's fixed part).
:func:`books` sums them over the path into one :class:`ItemBook` per item, with how often each
selection and the oracle (one per budget: the exact knapsack within the budget's time left)
chose it.  Plain Python + numpy.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..report import oracle
from ..schema import EFFECTS

SEPARATOR = "/"
# A material this glossy or metallic shows its surroundings when its reflections are traced.
GLOSSY_ROUGHNESS = 0.3
METALLIC = 0.5
# This transmissive (or this transparent) refracts what is behind it.
TRANSMISSIVE = 0.5
TRANSPARENT_ALPHA = 0.95
# A shadow caster covering at most this share of the frame on average (a prop, not a wall or a
# floor, which receive more than they cast).
CASTER_SHARE = 0.05
# How much an effect promises per pixel of a prospect, for ranking prospects before measuring.
PROMISE = {"reflections": 1.0, "refractions": 1.0, "shadows": 0.3}
# Untagged objects judged at most (the most promising), unless the caller says otherwise.
DEFAULT_PROSPECTS = 8
# Costs at or below this many ms count as this (a benefit per ms stays finite).
MIN_COST_MS = 1e-3


def item_key(element: str, effect: str) -> str:
    if effect not in EFFECTS:
        raise ValueError(f"unknown effect '{effect}': one of {', '.join(EFFECTS)}")
    return f"{element}{SEPARATOR}{effect}"


def split_key(key: str) -> tuple[str, str]:
    element, _, effect = str(key).rpartition(SEPARATOR)
    if not element or effect not in EFFECTS:
        raise ValueError(f"'{key}' is not an item key '<element>/<effect>'")
    return element, effect


def tagged_keys(element: str, shadows: bool, reflections: bool, refractions: bool) -> list[str]:
    """The items of a tagged element: one per effect it is tagged for."""
    flags = {"shadows": shadows, "reflections": reflections, "refractions": refractions}
    return [item_key(element, effect) for effect in EFFECTS if flags[effect]]


def prospect_effects(metallic: float, roughness: float, transmission: float, alpha: float,
                     casts_shadow: bool, area_share: float) -> tuple[str, ...]:
    """The effects tracing could change on an untagged object with this material: reflections if it
    is metallic or glossy, refractions if it is transmissive or transparent, shadows if it is a
    shadow caster small enough to be a prop (``CASTER_SHARE`` of the frame)."""
    effects = []
    if casts_shadow and 0.0 < area_share <= CASTER_SHARE:
        effects.append("shadows")
    if metallic >= METALLIC or roughness <= GLOSSY_ROUGHNESS:
        effects.append("reflections")
    if transmission >= TRANSMISSIVE or alpha < TRANSPARENT_ALPHA:
        effects.append("refractions")
    return tuple(effects)


@dataclass
class Prospect:
    """An untagged object judged as "would it be worth tagging"."""

    element: str
    effects: tuple
    mean_pixels: float  # over the frames it is visible on
    visible_share: float

    @property
    def promise(self) -> float:
        """Pixels x visibility x what its effects promise per pixel: the order prospects are judged in."""
        return self.mean_pixels * self.visible_share * sum(PROMISE[effect] for effect in self.effects)

    @property
    def keys(self) -> list[str]:
        return [item_key(self.element, effect) for effect in self.effects]


def choose_prospects(prospects, cap: int = DEFAULT_PROSPECTS) -> tuple[list, int]:
    """The ``cap`` most promising prospects with an effect to judge, and how many were left out."""
    usable = [prospect for prospect in prospects if prospect.effects and prospect.visible_share > 0]
    usable.sort(key=lambda prospect: (-prospect.promise, prospect.element))
    cap = max(int(cap), 0)
    return usable[:cap], max(len(usable) - cap, 0)


@dataclass
class ItemBook:
    """One item's measurements over the judged frames and the choices made for it."""

    key: str
    tagged: bool
    frames: list = field(default_factory=list)  # judged frames it was visible on (measured)
    pixels: list = field(default_factory=list)
    benefit: list = field(default_factory=list)  # LDR-FLIP drop per measured frame
    cost_ms: list = field(default_factory=list)
    judged_frames: int = 0
    # {selection name: {budget fraction: share of its visible frames the selection chose it}}
    selection_share: dict = field(default_factory=dict)
    oracle_share: dict = field(default_factory=dict)  # {budget fraction: share of its measured frames}

    @property
    def element(self) -> str:
        return split_key(self.key)[0]

    @property
    def effect(self) -> str:
        return split_key(self.key)[1]

    @property
    def visible_share(self) -> float:
        return len(self.frames) / self.judged_frames if self.judged_frames else 0.0

    @property
    def mean_pixels(self) -> float:
        return float(np.mean(self.pixels)) if self.pixels else 0.0

    @property
    def mean_benefit(self) -> float:
        return float(np.mean(self.benefit)) if self.benefit else 0.0

    @property
    def mean_cost_ms(self) -> float:
        return float(np.mean(self.cost_ms)) if self.cost_ms else 0.0

    @property
    def benefit_per_ms(self) -> float:
        """Summed benefit over summed cost (a ratio of sums over its measured frames); negative
        drops (FLIP noise) count as none."""
        if not self.benefit:
            return 0.0
        return float(np.sum(np.maximum(self.benefit, 0.0)) / max(float(np.sum(self.cost_ms)), MIN_COST_MS))

    def share(self, selection: str) -> float | None:
        """Mean over the budgets asked of how often ``selection`` chose it (None: not replayed)."""
        shares = self.selection_share.get(selection)
        return float(np.mean(list(shares.values()))) if shares else None

    @property
    def mean_oracle_share(self) -> float:
        return float(np.mean(list(self.oracle_share.values()))) if self.oracle_share else 0.0

    @property
    def max_oracle_share(self) -> float:
        return float(max(self.oracle_share.values())) if self.oracle_share else 0.0


def books(measured, tagged, budgets_ms, shared_ms, selections=None, judged_frames=None) -> dict:
    """{item key: ItemBook} from the judged frames' ``FrameCandidates`` (names = item keys).

    ``tagged`` {key: bool} lists every item judged; ``budgets_ms`` {fraction: budget ms};
    ``shared_ms`` {frame: the raster + select + composite ms every selection pays on that frame}: the oracle
    at a budget fills ``oracle.nominal_time_left(budget, shared)``, as the sweep's oracle does; ``selections`` {name: {fraction: {key: share}}} from the
    replays (:func:`selection_shares`)."""
    measured = list(measured)
    count = len(measured) if judged_frames is None else int(judged_frames)
    result = {key: ItemBook(key=key, tagged=bool(flag), judged_frames=count) for key, flag in tagged.items()}
    chosen_counts = {key: {fraction: 0 for fraction in budgets_ms} for key in result}
    for candidates in measured:
        shared = shared_ms.get(candidates.frame, 0.0)
        choices = {fraction: candidates.choose(oracle.nominal_time_left(budget, shared))
                   for fraction, budget in budgets_ms.items()}
        for index, key in enumerate(candidates.names):
            book = result.get(key)
            if book is None:
                continue
            book.frames.append(candidates.frame)
            book.pixels.append(float(candidates.area_px[index]) if len(candidates.area_px) else 0.0)
            book.benefit.append(float(candidates.benefit[index]))
            book.cost_ms.append(float(candidates.cost_ms[index]))
            for fraction, chosen in choices.items():
                chosen_counts[key][fraction] += int(key in chosen)
    for key, book in result.items():
        if book.frames:
            book.oracle_share = {fraction: chosen_counts[key][fraction] / len(book.frames) for fraction in budgets_ms}
        else:
            book.oracle_share = {fraction: 0.0 for fraction in budgets_ms}
        for name, by_budget in (selections or {}).items() if book.tagged else ():  # untagged: no selection sees it
            book.selection_share[name] = {fraction: float(shares.get(key, 0.0))
                                          for fraction, shares in by_budget.items()}
    return result


def selection_shares(rows, keys_of_element) -> dict:
    """{item key: share of the frames its element was visible on that the selection traced it} from
    a run's ``selection.csv`` rows (``frame, element, visible, selected`` and, where the selection
    buys effects one by one, ``effects``: the ``;``-joined effects it traced).  A selection that
    buys whole elements (the paper's) traces every tagged effect of a selected element."""
    visible, chosen = {}, {}
    for row in rows:
        element = str(row["element"])
        keys = keys_of_element.get(element)
        if not keys or not row.get("visible"):
            continue
        traced_effects = row.get("effects")
        for key in keys:
            visible[key] = visible.get(key, 0) + 1
            if row.get("selected"):
                if traced_effects is None or split_key(key)[1] in str(traced_effects).split(";"):
                    chosen[key] = chosen.get(key, 0) + 1
    return {key: chosen.get(key, 0) / count for key, count in visible.items()}
