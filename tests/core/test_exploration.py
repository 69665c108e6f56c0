"""The exploration bonus (select/exploration.py) and its bound on work: at most
``benefit_selection.EXPLORE_MAX`` never-measured items compete in one frame, the longest waiting
first, and none is starved."""
import numpy as np

from phrt.phrt_addon.select import benefit_selection
from phrt.phrt_addon.select.benefit_selection import BenefitSelector
from phrt.phrt_addon.select.exploration import exploration


def _instance(rng, n=40):
    explore = rng.random((n, 3)) < 0.5
    value = rng.random((n, 3)) * 10
    cost = rng.random((n, 3)) * 5 + 0.1
    waited = rng.integers(0, 12, int(explore.sum())).astype(float)
    return explore, waited, value, cost


def test_within_the_bound_every_fitting_item_gets_its_bonus():
    rng = np.random.default_rng(0)
    explore, waited, value, cost = _instance(rng)
    allowed = explore | (rng.random(explore.shape) < 0.2)
    added = allowed & ~explore & (rng.random(explore.shape) < 0.5)
    got, bonus = exploration(explore, allowed, added, waited, value, cost, 100.0, 8, int(allowed.sum()))
    np.testing.assert_array_equal(got, allowed)  # as many items as the bound: all of them
    np.testing.assert_allclose(bonus[explore], 100.0 * np.minimum((waited + 1) / 8, 1.0))
    assert not bonus[~explore].any()


def test_beyond_the_bound_the_longest_waiting_then_the_most_valuable_per_ms_compete():
    rng = np.random.default_rng(1)
    for _ in range(20):
        explore, waited, value, cost = _instance(rng)
        most = int(rng.integers(1, explore.sum()))
        allowed = explore | (rng.random(explore.shape) < 0.2)
        added = allowed & ~explore & (rng.random(explore.shape) < 0.5)
        got, bonus = exploration(explore, allowed, added, waited, value, cost, 100.0, 8, most)
        chosen = bonus > 0
        assert chosen.sum() == most and not (chosen & ~explore).any()
        # More items than the bound: the knapsack holds the bonus items and the first one's adds.
        np.testing.assert_array_equal(got, allowed & (chosen | added))
        flat = np.flatnonzero(explore.ravel())
        picked = chosen.ravel()[flat]
        ratio = value.ravel()[flat] / cost.ravel()[flat]
        # Nothing left out waited longer, or as long and is worth more per ms.
        for w, r in zip(waited[~picked], ratio[~picked]):
            assert np.all((waited[picked] > w) | ((waited[picked] == w) & (ratio[picked] >= r)))
        np.testing.assert_allclose(bonus.ravel()[flat[picked]], 100.0 * np.minimum((waited[picked] + 1) / 8, 1.0))


def test_a_bound_below_the_never_measured_items_starves_none(monkeypatch):
    """Seven never-measured items whose priors say worthless (only the bonus adds them), room for
    all, at most two with the bonus a frame: each frame adds two of those that waited longest and
    every item is traced within four frames (a measured item leaves the exploration)."""
    monkeypatch.setattr(benefit_selection, "EXPLORE_MAX", 2)
    selector = BenefitSelector()
    names = [f"Item{i}" for i in range(7)]
    pixels = np.zeros((7, 3))
    pixels[:, 1] = 100.0
    eligible = pixels > 0
    priors = np.zeros((7, 3))
    cost = np.where(eligible, 1.0, 0.0)
    first_traced = {}
    for frame in range(6):
        selector.observe_time(1.0, 1.0)
        choice = selector.choose(names, eligible, pixels, priors, np.ones(7), cost, 100.0, 0.0)
        new = [name for name, chosen in zip(names, choice.chosen[:, 1]) if chosen and name not in first_traced]
        assert len(new) <= 2, (frame, new)
        first_traced.update((name, frame) for name in new)
        measured = np.where(choice.chosen, pixels * 0.01, 0.0)
        selector.observe(names, choice, priors, measured, pixels)
    assert sorted(first_traced) == names and max(first_traced.values()) <= 3, first_traced


def test_items_whose_effects_fixed_part_does_not_fit_do_not_hold_the_bonus_places(monkeypatch):
    """Two never-measured shadow items of 3 ms whose effect's fixed part (4 ms) no kept item pays
    cannot fit the 5 ms left; with room for only two bonus places they must not hold them (they
    would, waiting ever longer, for good): the two 1 ms reflections are traced."""
    monkeypatch.setattr(benefit_selection, "EXPLORE_MAX", 2)
    selector = BenefitSelector()
    names = [f"I{i}" for i in range(4)]
    pixels = np.zeros((4, 3))
    pixels[:2, 0] = pixels[2:, 1] = 100.0
    eligible = pixels > 0
    priors = np.zeros((4, 3))
    cost = np.zeros((4, 3))
    cost[:2, 0], cost[2:, 1] = 3.0, 1.0
    traced = set()
    for _ in range(12):
        selector.observe_time(5.0, 5.0)
        choice = selector.choose(names, eligible, pixels, priors, np.ones(4), cost, 5.0, 0.0,
                                 fixed_ms=np.array([4.0, 0.0, 0.0]))
        traced |= {(int(i), int(j)) for i, j in zip(*np.nonzero(choice.chosen))}
        selector.observe(names, choice, priors, np.where(choice.chosen, pixels * 0.01, 0.0), pixels)
    assert traced == {(2, 1), (3, 1)}
