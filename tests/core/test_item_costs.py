"""The BENEFIT selection's item costs: a fixed part per effect and a per-ray part, learned apart;
each item's rays ratio, an unmeasured item taking its effect's median."""
import numpy as np
import pytest

from phrt_addon.select import item_costs
from phrt_addon.select.item_costs import ItemCosts

NAMES = ["Small", "Large", "Mirror"]


def shadows_frame(costs, rays_small, rays_large, chosen_large, ms_per_ray=6e-4, fixed=4.0, embree=2e-4):
    """One traced frame of shadow items: the stage's counters as a line fixed + ms_per_ray x rays."""
    expected = np.array([[2 * rays_small, 0, 0], [2 * rays_large, 0, 0], [0, 100, 0]], float)
    chosen = np.array([[True, False, False], [chosen_large, False, False], [False, False, False]])
    item_rays = np.array([[rays_small, 0, 0], [rays_large if chosen_large else 0, 0, 0], [0, 0, 0]], float)
    rays = item_rays[:, 0].sum()
    costs.observe(NAMES, expected, item_rays, chosen, chosen.astype(float), [fixed + ms_per_ray * rays, 0, 0],
                  [rays, 0, 0], shadow_setup_ms=0.8 * fixed, embree_ms=[embree * rays, 0, 0])
    return expected


def test_a_small_casters_frames_do_not_price_a_large_caster_by_their_fixed_part():
    """Only the small caster traced (1,000 rays in 4.6 ms, 4 of them fixed): the large caster's
    36,000 rays cost EMBREE_FACTOR x Embree's per-ray ms plus the fixed part once, not 36x 4.6 ms."""
    costs = ItemCosts()
    for _ in range(3):
        expected = shadows_frame(costs, 1000, 36000, chosen_large=False)
    fixed, per_ray = costs.fixed_ms()[0], costs.per_ray_ms()[0]
    assert per_ray == pytest.approx(item_costs.EMBREE_FACTOR * 2e-4)
    assert 3.2 <= fixed <= 4.6
    # The large caster, never traced, takes the small one's rays ratio (0.5).
    large = costs.predict(NAMES, expected, np.ones(3))[1, 0]
    assert large == pytest.approx(36000 * per_ray, rel=1e-6)
    assert large < 0.2 * 36 * 4.6


def test_a_spread_of_ray_counts_fits_the_line():
    costs = ItemCosts()
    for rays_large in (0, 36000, 0, 36000, 0, 18000):
        shadows_frame(costs, 1000, rays_large, chosen_large=rays_large > 0)
    assert costs.per_ray_ms()[0] == pytest.approx(6e-4, rel=1e-6)  # Theil-Sen through exact points
    assert costs.fixed_ms()[0] == pytest.approx(4.0, rel=1e-6)


def test_rays_ratio_is_learned_per_item_and_q_scales_the_cost():
    costs = ItemCosts()
    expected = shadows_frame(costs, 1000, 36000, chosen_large=True)
    assert costs.ratios(NAMES)[:, 0] == pytest.approx([0.5, 0.5, 0.5])
    ms = costs.predict(NAMES, expected, np.array([1.0, 2.0, 1.0]))
    assert ms[1, 0] == pytest.approx(2 * 36000 * costs.per_ray_ms()[0])
    # The mirror's reflection was never traced: the cost model's prior, margined.
    assert costs.per_ray_ms()[1] == pytest.approx(item_costs.MS_PER_RAY_PRIOR["reflections"]
                                                  * item_costs.UNMEASURED_MARGIN)
    assert costs.measured(np.array([[True, False, False]])) and not costs.measured(np.array([[False, True, False]]))


def test_bad_numbers_are_not_learned():
    costs = ItemCosts()
    expected = np.array([[100.0, 0, 0]])
    costs.observe(["A"], expected, np.array([[np.nan, 0, 0]]), np.array([[True, False, False]]),
                  np.ones((1, 3)), [np.inf, 0, 0], [50, 0, 0], shadow_setup_ms=np.nan, embree_ms=[np.nan, 0, 0])
    assert not costs.samples["shadows"] and not costs.ratio
    ms = costs.predict(["A"], np.array([[np.inf, np.nan, 1.0]]), [1.0])
    assert np.all(np.isfinite(ms)) and np.all(ms >= 0)


def test_a_reduced_rate_costs_its_share_of_the_rays_plus_its_reconstruction():
    """Issue 23: the learned quarter-rate cost is about a quarter of the per-ray part plus the
    reconstruction of the other three quarters; the fixed part is the same at every rate."""
    costs = ItemCosts()
    names = ["Mirror"]
    expected = np.array([[0.0, 4000.0, 0.0]])
    pixels = np.array([[0.0, 2000.0, 0.0]])
    # Before any reconstruction is measured: the priors' shares of the full cost.
    prior = costs.tier_costs(names, expected, pixels, [1.0])
    full = costs.predict(names, expected, [1.0])[0, 1]
    assert prior[0, 1].tolist() == pytest.approx([full * item_costs.TIER_COST[r] for r in item_costs.TIER_RATES])
    for rate, rays, ms, recon in ((1.0, 4000, 2.0 + 4000 * 5e-4, 0.0), (0.25, 1000, 2.0 + 1000 * 5e-4 + 1.5, 1.5),
                                  (1.0, 4000, 2.0 + 4000 * 5e-4, 0.0), (0.5, 2000, 2.0 + 2000 * 5e-4 + 1.0, 1.0),
                                  (0.25, 1000, 2.0 + 1000 * 5e-4 + 1.5, 1.5)):
        filled = int(2000 * (1 - rate))
        costs.observe(names, expected, np.array([[0, rays, 0]], float), np.array([[False, True, False]]),
                      np.array([[0, rate, 0]]), [0, ms, 0], [0, rays, 0], embree_ms=[0, rays * 1e-4, 0],
                      reconstruct_ms={"reflections": recon} if recon else {},
                      reconstructed_px={"reflections": filled} if recon else {})
    assert costs.per_ray_ms()[1] == pytest.approx(5e-4, rel=1e-6)
    assert costs.fixed_ms()[1] == pytest.approx(2.0, rel=1e-6)
    tiers = costs.tier_costs(names, expected, pixels, [1.0])[0, 1]
    per_pixel = 1.5 / 1500  # the reconstruction's ms per pixel filled
    by_rate = dict(zip(item_costs.TIER_RATES, tiers))
    assert by_rate[1.0] == pytest.approx(4000 * 5e-4)
    assert by_rate[0.25] == pytest.approx(0.25 * 4000 * 5e-4 + per_pixel * 1500)
    assert by_rate[0.5] == pytest.approx(0.5 * 4000 * 5e-4 + per_pixel * 1000)
