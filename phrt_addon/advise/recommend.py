"""One recommendation per item, with its reason in words naming the measured numbers.

For a tagged item:

- ``untag`` (or ``drop_effect`` when another effect of the same element is worth it): never worth
  its cost at any budget asked: not visible on any judged frame, its mean error drop is below the
  noise floor ``NOISE_FLIP`` (a matte surface's traced reflection, a shadow over nothing), or the
  oracle never chose it at any budget asked;
- ``raise_priority`` / ``lower_priority``: the selection (the scene's: ``PAPER`` or ``BENEFIT``)
  traces it on ``PRIORITY_GAP`` fewer / more of its frames than the oracle does (mean over the
  budgets asked): it under- / over-buys it;
- ``keep`` otherwise.

For an untagged item (a prospect): ``tag`` when its mean drop is above the noise floor and the
oracle, free to choose it, would trace it on at least ``TAG_SHARE`` of its frames at some budget
asked; else ``keep`` (leave it untagged).

:func:`changes` turns a recommendation into the property changes it makes on the element's owner
(an object or a material): what the Advisor's Apply button does.  Plain Python.
"""
from __future__ import annotations

from dataclasses import dataclass

RECOMMENDATIONS = ("keep", "untag", "drop_effect", "raise_priority", "lower_priority", "tag")
# A mean LDR-FLIP drop per frame below this is no change (FLIP noise, a few pixels of a frame).
NOISE_FLIP = 1e-4
# The selection's and the oracle's shares differ by this much before a priority change is advised.
PRIORITY_GAP = 0.25
# An untagged item the oracle would trace on this share of its frames (at some budget) is worth tagging.
TAG_SHARE = 0.25
# What raise_priority / lower_priority do to K.
PRIORITY_FACTOR = 2.0


@dataclass
class Advice:
    recommendation: str
    reason: str


def _budgets(book) -> str:
    return "/".join(f"{fraction:g}" for fraction in sorted(book.oracle_share))


def _measured(book) -> str:
    return (f"traced alone it removes {book.mean_benefit:.5f} LDR-FLIP per frame for {book.mean_cost_ms:.2f} ms "
            f"({book.benefit_per_ms:.5f} per ms) on {len(book.frames)} of {book.judged_frames} judged frames")


def _worthless(book) -> str | None:
    """Why a tagged item is never worth it, or None."""
    if not book.frames:
        return f"not visible on any of the {book.judged_frames} judged frames"
    if book.mean_benefit < NOISE_FLIP:
        return f"{_measured(book)}: below the noise floor of {NOISE_FLIP:g}"
    if book.max_oracle_share <= 0.0:
        return (f"{_measured(book)}, but the oracle chose it on none of its frames at budgets {_budgets(book)}")
    return None


def recommend(books: dict, selection: str = "PAPER") -> dict:
    """{item key: Advice} for the books of :func:`items.books`; ``selection`` is the scene's."""
    worthless = {key: _worthless(book) for key, book in books.items() if book.tagged}
    advice = {}
    for key, book in books.items():
        if not book.tagged:
            advice[key] = _untagged(book)
            continue
        why = worthless[key]
        if why is not None:
            siblings = [other for other, reason in worthless.items()
                        if reason is None and other != key and books[other].element == book.element]
            if siblings:
                best = max(siblings, key=lambda other: books[other].benefit_per_ms)
                kept = books[best]
                advice[key] = Advice("drop_effect", (
                    f"turn off {book.effect}: {why}; its {kept.effect} are worth keeping "
                    f"({kept.mean_benefit:.5f} LDR-FLIP per frame for {kept.mean_cost_ms:.2f} ms)"))
            else:
                advice[key] = Advice("untag", f"never worth its cost: {why}")
            continue
        chosen = book.share(selection)
        oracle = book.mean_oracle_share
        said = (f"{_measured(book)}; {selection} traced it on {0.0 if chosen is None else chosen:.0%} of its frames, "
                f"the oracle on {oracle:.0%} (budgets {_budgets(book)})")
        if chosen is not None and oracle - chosen >= PRIORITY_GAP:
            advice[key] = Advice("raise_priority", f"under-bought: {said}: raise K")
        elif chosen is not None and chosen - oracle >= PRIORITY_GAP:
            advice[key] = Advice("lower_priority", f"over-bought: {said}: lower K")
        else:
            advice[key] = Advice("keep", f"worth its cost: {said}")
    return advice


def _untagged(book) -> Advice:
    if not book.frames:
        return Advice("keep", f"leave untagged: not visible on any of the {book.judged_frames} judged frames")
    best_fraction = max(sorted(book.oracle_share), key=lambda fraction: book.oracle_share[fraction])
    share = book.oracle_share[best_fraction]
    said = f"{_measured(book)}; the oracle would trace it on {share:.0%} of its frames at budget {best_fraction:g}"
    if book.mean_benefit >= NOISE_FLIP and share >= TAG_SHARE:
        return Advice("tag", f"worth tagging for {book.effect}: {said}")
    if book.mean_benefit < NOISE_FLIP:
        return Advice("keep", f"leave untagged: {said}; below the noise floor of {NOISE_FLIP:g}")
    return Advice("keep", f"leave untagged: {said} (under {TAG_SHARE:.0%})")


def changes(element: str, effect: str, recommendation: str, settings: dict, tag_effects=()) -> dict:
    """{property: new value} of the element's owner (``settings``: its current ``candidate``,
    ``priority``, ``shadows``, ``reflections``, ``refractions``) that ``recommendation`` for the item
    (element, effect) makes.  ``tag`` tags the element for ``tag_effects`` (the effects of it
    advised ``tag``; at least ``effect``) and turns its other effects off.  ``keep`` changes nothing."""
    if recommendation not in RECOMMENDATIONS:
        raise ValueError(f"unknown recommendation '{recommendation}'")
    wanted = {}
    if recommendation == "untag":
        wanted = {"candidate": False}
    elif recommendation == "drop_effect":
        wanted = {effect: False}
    elif recommendation == "raise_priority":
        wanted = {"priority": float(settings["priority"]) * PRIORITY_FACTOR}
    elif recommendation == "lower_priority":
        wanted = {"priority": float(settings["priority"]) / PRIORITY_FACTOR}
    elif recommendation == "tag":
        effects = set(tag_effects) | {effect}
        wanted = {"candidate": True, **{name: name in effects for name in ("shadows", "reflections", "refractions")}}
    return {name: value for name, value in wanted.items() if settings.get(name) != value}
