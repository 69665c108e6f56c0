"""The oracle judges at most N candidates per sampled frame (oracle.cap_candidates): the most
valuable by the selection's own estimate, plus a few at random from the rest, the same ones on a
rerun; 10,000 candidates cost N renders, not 10,000."""
import numpy as np
import pytest

from phrt.phrt_addon.report import oracle


def test_ten_thousand_candidates_are_capped_to_the_most_relevant_and_a_few_random():
    names = [f"e{index}" for index in range(10000)]
    relevance = np.random.default_rng(1).random(10000)
    kept, capped = oracle.cap_candidates(names, relevance, cap=48, random_extra=8, seed=5)
    assert capped and len(kept) == 48 == len(set(kept))
    best = {names[index] for index in np.argsort(-relevance)[:40]}
    assert best <= set(kept)
    assert len(set(kept) - best) == 8
    assert kept == [name for name in names if name in set(kept)]  # the frame's own order
    assert oracle.cap_candidates(names, relevance, cap=48, random_extra=8, seed=5)[0] == kept
    assert oracle.cap_candidates(names, relevance, cap=48, random_extra=8, seed=6)[0] != kept


def test_a_frame_within_the_cap_is_judged_whole():
    kept, capped = oracle.cap_candidates(["a", "b"], [0.1, np.nan], cap=2)
    assert kept == ["a", "b"] and not capped
    with pytest.raises(ValueError):
        oracle.cap_candidates(["a"], [1.0], cap=0)
