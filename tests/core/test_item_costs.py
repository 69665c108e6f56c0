"""The BENEFIT selection's item costs: a fixed part per effect and a per-ray part, learned apart;
each item's rays ratio, an unmeasured item taking its effect's median."""
import numpy as np
import pytest

from phrt_addon.select import cost_fit, item_costs
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
    assert per_ray == pytest.approx(cost_fit.EMBREE_FACTOR * 2e-4)
    assert 3.2 <= fixed <= 4.6
    # The large caster, never traced, takes the small one's rays ratio (0.5).
    large = costs.predict(NAMES, expected)[1, 0]
    assert large == pytest.approx(36000 * per_ray, rel=1e-6)
    assert large < 0.2 * 36 * 4.6


def power_frame(costs, casters, scale=0.05, exponent=0.6, setup=3.0, embree=2e-4):
    """One traced frame of shadow items, each ``scale x rays ** exponent`` ms beyond the setup."""
    names = [f"C{i}" for i in range(len(casters))]
    rays = np.array(casters, float)
    expected = np.zeros((len(rays), 3))
    expected[:, 0] = rays
    chosen = np.zeros((len(rays), 3), bool)
    chosen[:, 0] = True
    ms = setup + float(np.sum(scale * rays ** exponent))
    costs.observe(names, expected, expected, chosen, chosen.astype(float), [ms, 0, 0], [rays.sum(), 0, 0],
                  shadow_setup_ms=setup, embree_ms=[embree * rays.sum(), 0, 0])
    return names, expected


def test_a_spread_of_ray_counts_fits_the_power_law():
    """One caster alone at 180 and 840 rays, two at 500 each: an item's ms are fitted as a power of
    its rays (the measured shape: a large caster costs far less a ray than a small one), so a
    22,000-ray caster is priced near the truth rather than by the small ones' ms a ray."""
    costs = ItemCosts()
    for casters in ([180], [840], [500, 500], [180], [840], [2000]):
        power_frame(costs, casters)
    fixed, scale, exponent, _, _ = costs._fit["shadows"]
    assert exponent == pytest.approx(0.6, rel=1e-6) and scale == pytest.approx(0.05, rel=1e-6)
    assert fixed == pytest.approx(3.0)
    names, expected = ["Oak"], np.array([[22000.0, 0, 0]])
    assert costs.predict(names, expected)[0, 0] == pytest.approx(0.05 * 22000 ** 0.6, rel=1e-6)
    # The small casters' ms a ray (0.05 x 180 ** -0.4 = 6.3 us) would have said 140 ms.
    assert costs.predict(names, expected)[0, 0] < 0.25 * 22000 * 0.05 * 180 ** -0.4


def test_an_item_never_costs_less_than_its_rays_inside_embree():
    costs = ItemCosts()
    for casters in ([180], [840], [180], [840]):
        power_frame(costs, casters, exponent=0.3, embree=1e-3)
    _, _, exponent, embree, _ = costs._fit["shadows"]
    assert exponent == pytest.approx(cost_fit.MIN_EXPONENT) and embree == pytest.approx(1e-3)
    assert costs.predict(["Oak"], np.array([[1e6, 0, 0]]))[0, 0] == pytest.approx(1e6 * 1e-3)


def test_rays_ratio_is_learned_per_item():
    costs = ItemCosts()
    expected = shadows_frame(costs, 1000, 36000, chosen_large=True)
    assert costs.ratios(NAMES)[:, 0] == pytest.approx([0.5, 0.5, 0.5])
    ms = costs.predict(NAMES, expected)
    assert ms[1, 0] == pytest.approx(36000 * costs.per_ray_ms()[0])
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
    ms = costs.predict(["A"], np.array([[np.inf, np.nan, 1.0]]))
    assert np.all(np.isfinite(ms)) and np.all(ms >= 0)


def test_a_reduced_rate_costs_its_share_of_the_rays_plus_its_reconstruction():
    """Issue 23: the learned quarter-rate cost is the per-ray part at a quarter of the rays plus the
    reconstruction of the other three quarters; an effect's fixed part is the same at every rate."""
    costs = ItemCosts()
    names = ["Mirror"]
    expected = np.array([[0.0, 4000.0, 0.0]])
    pixels = np.array([[0.0, 2000.0, 0.0]])
    # Before any reconstruction is measured: the priors' shares of the full cost.
    prior = costs.tier_costs(names, expected, pixels)
    full = costs.predict(names, expected)[0, 1]
    assert prior[0, 1].tolist() == pytest.approx([full * item_costs.TIER_COST[r] for r in item_costs.TIER_RATES])
    ray_ms = (lambda rays: 0.02 * rays ** 0.8)
    for rate, recon in ((1.0, 0.0), (0.25, 1.5), (1.0, 0.0), (0.5, 1.0), (0.25, 1.5)):
        rays = 4000 * rate
        filled = int(2000 * (1 - rate))
        costs.observe(names, expected, np.array([[0, rays, 0]], float), np.array([[False, True, False]]),
                      np.array([[0, rate, 0]]), [0, ray_ms(rays) + recon, 0], [0, rays, 0],
                      embree_ms=[0, rays * 1e-4, 0],
                      reconstruct_ms={"reflections": recon} if recon else {},
                      reconstructed_px={"reflections": filled} if recon else {})
    assert costs._fit["reflections"][2] == pytest.approx(0.8, rel=1e-6)
    assert costs.fixed_ms()[1] == pytest.approx(0.0, abs=1e-9)
    tiers = costs.tier_costs(names, expected, pixels)[0, 1]
    per_pixel = 1.5 / 1500  # the reconstruction's ms per pixel filled
    by_rate = dict(zip(item_costs.TIER_RATES, tiers))
    assert by_rate[1.0] == pytest.approx(ray_ms(4000))
    assert by_rate[0.25] == pytest.approx(ray_ms(1000) + per_pixel * 1500)
    assert by_rate[0.5] == pytest.approx(ray_ms(2000) + per_pixel * 1000)


def test_an_item_beyond_the_largest_measured_grows_at_the_slowest_exponent():
    """Small casters measured growing linearly (180 to 2,000 rays an item): a 22,000-ray caster never
    traced is priced as the largest measured item grown as rays ** MIN_EXPONENT (optimistic, so it is
    tried once), not the small ones' line extrapolated 11x; within the measured range, the fit."""
    costs = ItemCosts()
    for casters in ([180], [840], [500, 500], [180], [840], [2000]):
        power_frame(costs, casters, exponent=1.0, scale=1e-3, embree=1e-5)
    _, scale, exponent, _, largest = costs._fit["shadows"]
    assert exponent == pytest.approx(1.0) and largest == pytest.approx(2000)
    within = costs.predict(["C"], np.array([[1000.0, 0, 0]]))[0, 0]
    assert within == pytest.approx(1e-3 * 1000, rel=1e-6)
    oak = costs.predict(["Oak"], np.array([[22000.0, 0, 0]]))[0, 0]
    assert oak == pytest.approx(1e-3 * 2000 * 11 ** cost_fit.MIN_EXPONENT, rel=1e-6)
    assert oak < 22000 * 1e-3
    # Once a large caster is measured, its own ms stand (the window's fit reaches it).
    power_frame(costs, [22000], exponent=1.0, scale=1e-3, embree=1e-5)
    assert costs.predict(["Oak"], np.array([[22000.0, 0, 0]]))[0, 0] == pytest.approx(22.0, rel=1e-6)


def test_an_idle_effect_revises_its_costs_by_halves_ever_more_rarely():
    """An effect with items, not traced for STALE_FRAMES frames: its learned costs are divided by
    STALE_DISCOUNT (not reset to the cheap prior: a cost measured right, too dear for the time
    left, must not be traced at once at a guessed price), its next item is a probe, and the next
    revision waits twice as long.  Its items' rays ratios are kept; a never-measured effect keeps
    its prior."""
    costs = ItemCosts()
    expected = shadows_frame(costs, 1000, 36000, chosen_large=True)
    before = costs.predict(NAMES, expected)
    ratios = costs.ratios(NAMES).copy()
    prior = costs.per_ray_ms()[1]
    wanted, idle = np.array([True, True, False]), np.zeros(3, bool)
    for _ in range(item_costs.STALE_FRAMES - 1):
        costs.tick(wanted, idle)
    assert costs.predict(NAMES, expected)[:, 0] == pytest.approx(before[:, 0])
    assert not costs.unmeasured()[0]
    costs.tick(wanted, idle)  # the STALE_FRAMES-th idle frame
    after = costs.predict(NAMES, expected)
    assert after[:, 0] == pytest.approx(before[:, 0] / item_costs.STALE_DISCOUNT)
    assert costs.fixed_ms()[0] > 0 and costs.unmeasured()[0]
    assert costs.ratios(NAMES) == pytest.approx(ratios)
    assert costs.per_ray_ms()[1] == pytest.approx(prior)  # reflections, never measured: the prior
    # The next revision comes after twice the idle frames.
    for _ in range(2 * item_costs.STALE_FRAMES - 1):
        costs.tick(wanted, idle)
    assert costs.predict(NAMES, expected)[:, 0] == pytest.approx(after[:, 0])
    costs.tick(wanted, idle)
    assert costs.predict(NAMES, expected)[:, 0] == pytest.approx(after[:, 0] / item_costs.STALE_DISCOUNT)
    # A frame that traces the effect resets its idle count: no revision while it is traced.
    for _ in range(10 * item_costs.STALE_MAX_FRAMES):
        costs.tick(wanted, np.array([True, False, False]))
    assert costs.idle[0] == 0 and costs.stale_after[0] <= item_costs.STALE_MAX_FRAMES


def test_a_large_item_measured_once_keeps_its_price_after_the_window_moves_on():
    """A 22,000-ray caster traced once among frames of small casters (all at 1e-3 ms a ray): after
    WINDOW more frames of small casters only, its frame is out of the window but still anchors
    its octave of rays, so the caster is priced at its measured 22 ms, not the small ones'
    extrapolation (2,000 rays grown as rays ** MIN_EXPONENT: 8.4 ms).  A newer frame of the same
    octave replaces the anchor; a revision of the effect's costs clears the anchors too."""
    costs = ItemCosts()
    small = ([180], [840], [500, 500], [2000])
    for casters in small:
        power_frame(costs, casters, exponent=1.0, scale=1e-3, embree=1e-5)
    power_frame(costs, [22000], exponent=1.0, scale=1e-3, embree=1e-5)
    for frame in range(item_costs.WINDOW):
        power_frame(costs, small[frame % len(small)], exponent=1.0, scale=1e-3, embree=1e-5)
    assert all(sample[0] <= 2000 for sample in costs.samples["shadows"])  # the large frame left the window
    oak = costs.predict(["Oak"], np.array([[22000.0, 0, 0]]))[0, 0]
    assert oak == pytest.approx(22.0, rel=1e-6)
    # A newer frame in the same octave (20,000 rays) is the anchor now, the older one is gone.
    power_frame(costs, [20000], exponent=1.0, scale=1e-3, embree=1e-5)
    large = [sample for sample in costs.anchors["shadows"].values() if sample[0] > 2000]
    assert [sample[0] for sample in large] == [20000.0]
    # An idle effect's revision forgets its anchors with its window.
    for _ in range(item_costs.STALE_FRAMES):
        costs.tick(np.array([True, False, False]), np.zeros(3, bool))
    assert not costs.anchors["shadows"] and not costs.samples["shadows"]


def test_the_fit_waits_for_a_few_frames_unless_one_surprises_it():
    """A traced frame whose ms agree with the fit (within SURPRISE) is fitted with the next ones,
    every FIT_EVERY-th frame; a 10x spike (a cost that rose), or a larger item than any measured,
    is fitted at once."""
    costs = ItemCosts()
    for casters in ([180], [840], [500, 500], [180], [840], [500, 500], [180], [840]):
        power_frame(costs, casters)
    probe = np.array([[600.0, 0, 0]])
    settled = costs.predict(["C"], probe)[0, 0]
    power_frame(costs, [600], scale=0.05 * 1.1)  # 10% dearer: within SURPRISE of the fit
    assert costs.predict(["C"], probe)[0, 0] == settled  # not fitted yet
    for _ in range(item_costs.FIT_EVERY - 1):
        power_frame(costs, [600], scale=0.05 * 1.1)
    # the FIT_EVERY-th frame fitted them: the fit of the window as it is now
    assert costs._fit["shadows"] == cost_fit.fit_window(costs._window("shadows"), True)
    power_frame(costs, [600], scale=0.05 * 1.1)  # agrees: waits
    assert costs._fit["shadows"] != cost_fit.fit_window(costs._window("shadows"), True)
    power_frame(costs, [600], scale=0.5, setup=30.0)  # a 10x spike: fitted at once
    assert costs._fit["shadows"] == cost_fit.fit_window(costs._window("shadows"), True)
    reach = costs.predict(["Oak"], np.array([[22000.0, 0, 0]]))[0, 0]
    power_frame(costs, [22000])  # beyond the largest item measured
    assert costs.predict(["Oak"], np.array([[22000.0, 0, 0]]))[0, 0] != reach


def test_a_fit_that_waits_is_the_fit_of_every_frame_on_its_turn():
    """Skipping the fit on frames that agree changes nothing once the FIT_EVERY-th frame comes:
    the same window, the same fit; in between the two differ (the costs drift, each frame within
    SURPRISE of the fit)."""
    every, waiting = ItemCosts(), ItemCosts()
    frames = [[180], [840], [500, 500], [300], [700], [600], [250], [800], [400], [650], [350], [800]]
    differed = 0
    for number, casters in enumerate(frames):
        drift = 1.0 + 0.04 * number  # up 4% a frame
        power_frame(waiting, casters, scale=0.05 * drift)
        power_frame(every, casters, scale=0.05 * drift)
        every._fit["shadows"] = cost_fit.fit_window(every._window("shadows"), True)
        if waiting._since_fit["shadows"] == 0:
            assert waiting._fit["shadows"] == every._fit["shadows"]
        else:
            differed += waiting._fit["shadows"] != every._fit["shadows"]
    assert differed > 0


def test_an_item_beyond_the_largest_measured_is_fitted_at_once():
    """A frame that agrees with the fit but whose item has more rays than any measured (in an
    octave already anchored) moves the fit's reach at once."""
    costs = ItemCosts()
    for casters in ([180], [840], [500, 500], [180], [840], [500, 500], [180], [840]):
        power_frame(costs, casters)
    assert costs._fit["shadows"][4] == pytest.approx(840)
    power_frame(costs, [1000])  # log2 1000 and 840: both octave 9; the same law
    assert costs._fit["shadows"][4] == pytest.approx(1000)


def _tiny_frame(costs, rays, ms=3.5, setup=2.5, embree_ms=0.05):
    """A traced frame of one small caster: ``rays`` rays, Embree's time mostly its per-call work."""
    names = ["Small", "Tree"]
    expected = np.array([[rays, 0, 0], [30000, 0, 0]], float)
    chosen = np.array([[True, False, False], [False, False, False]])
    costs.observe(names, expected, expected * chosen, chosen, chosen.astype(float), [ms, 0, 0], [rays, 0, 0],
                  shadow_setup_ms=setup, embree_ms=[embree_ms, 0, 0])


def test_a_tiny_batch_after_a_revision_does_not_price_a_large_caster_by_embrees_per_call_time():
    """Shadows learned on 5,000-ray frames (0.2 us a ray inside Embree), then idle until the stale
    revision cleared the window; the next frame traces a 4-ray caster whose Embree call took 0.05
    ms (12.5 us a ray: per-call work).  The 30,000-ray tree is priced with the last trusted Embree
    figure (halved by the revision), not 60x dearer (atrium path2: 78-412 ms against the oracle's
    17-19, never traced again for 90 frames)."""
    costs = ItemCosts()
    for _ in range(6):
        shadows_frame(costs, 5000, 0, chosen_large=False, ms_per_ray=6e-4, fixed=5.0, embree=2e-4)
    assert costs.embree_known[0] == pytest.approx(2e-4)
    for _ in range(item_costs.STALE_FRAMES):
        costs.tick([True, False, False], [False, False, False])
    assert costs.embree_known[0] == pytest.approx(2e-4 / item_costs.STALE_DISCOUNT)
    _tiny_frame(costs, 4)
    tree = costs.predict(["Small", "Tree"], np.array([[4, 0, 0], [30000, 0, 0]], float))[1, 0]
    rays = 30000 * costs.ratios(["Tree"])[0, 0]  # the effect's median rays ratio
    assert tree == pytest.approx(rays * cost_fit.EMBREE_FACTOR * 1e-4, rel=1e-6)
    # The slope between two batches SPREAD apart is trusted again, per-call work out.
    _tiny_frame(costs, 143, embree_ms=0.05 + 139 * 2e-4)
    assert costs._fit["shadows"][3] == pytest.approx(2e-4, rel=1e-6)


def test_a_line_from_tiny_batches_alone_is_not_extrapolated_beyond_them():
    """The replay's first shadow frames trace 4- and 5-ray casters only (Embree's time all per-call
    work, nothing trusted yet): beyond the largest item measured the line grows as rays **
    MIN_EXPONENT, with no Embree floor from those figures, so a 30,000-ray caster is tried (its
    first frame corrects the fit) instead of being priced at seconds."""
    costs = ItemCosts()
    _tiny_frame(costs, 4)
    _tiny_frame(costs, 5)
    fixed, per_ray, exponent, embree, largest = costs._fit["shadows"]
    assert exponent == 1.0 and embree == 0.0 and largest == pytest.approx(5.0)
    assert np.isnan(costs.embree_known[0])
    rays = 30000 * costs.ratios(["Tree"])[0, 0]
    tree = costs.predict(["Tree"], np.array([[30000.0, 0, 0]]))[0, 0]
    assert tree == pytest.approx(per_ray * 5 * (rays / 5) ** cost_fit.MIN_EXPONENT, rel=1e-6)
    assert tree < 0.05 * per_ray * rays
    # Within what was measured, the line.
    assert costs.predict(["Small"], np.array([[4.0, 0, 0]]))[0, 0] == pytest.approx(4 * per_ray)



def law(rays, scale=0.05, exponent=0.6):
    return scale * np.asarray(rays, float) ** exponent


def item_frame(costs, name, rays, factor=1.0, setup=3.0):
    """``name`` traced alone (shadows), ``factor`` x the power law's ms beyond the setup."""
    expected = np.array([[float(rays), 0, 0]])
    chosen = np.array([[True, False, False]])
    costs.tick([True, False, False], [True, False, False])
    costs.observe([name], expected, expected, chosen, chosen.astype(float), [setup + factor * law(rays), 0, 0],
                  [float(rays), 0, 0], shadow_setup_ms=setup, embree_ms=[2e-4 * rays, 0, 0])


def test_an_item_dearer_than_its_rays_learns_its_own_cost():
    """Statues and a wall follow the power law; a tree's 20,000 rays cost 1.5x what the law prices
    (its leaves' triangles).  Alternating with the wall, the tree learns its own price within a few
    of its frames (the window's median would follow only once it held half the window), and the
    others keep theirs."""
    costs = ItemCosts()
    for rays in (180, 840, 400, 1600, 250, 1200, 15000, 25000, 18000, 22000):
        item_frame(costs, "Statue" if rays < 10000 else "Wall", rays)
    assert costs.power["shadows"]
    tree = np.array([[20000.0, 0, 0]])
    fit_alone = float(costs.rays_ms(tree)[0, 0])
    for rays in (20000, 300, 19000, 21000, 900, 20000, 21000, 500, 20000, 19000):
        name = "Statue" if rays < 1000 else ("Tree" if rays == 20000 else "Wall")
        item_frame(costs, name, rays, factor=1.5 if name == "Tree" else 1.0)
    measured = 1.5 * law(20000)
    assert costs.predict(["Tree"], tree)[0, 0] == pytest.approx(measured, rel=0.12)
    assert abs(float(costs.rays_ms(tree)[0, 0]) - measured) > 0.2 * measured  # the fit alone misses it
    assert fit_alone == pytest.approx(law(20000), rel=0.02)
    assert costs.predict(["Statue"], np.array([[800.0, 0, 0]]))[0, 0] == pytest.approx(law(800), rel=0.1)
    assert costs.predict(["Wall"], tree)[0, 0] == pytest.approx(law(20000), rel=0.1)
    # Not traced for COST_HALF_LIFE frames, its correction fades to its square root (tried again).
    before = costs.predict(["Tree"], tree)[0, 0] / costs.rays_ms(tree)[0, 0]
    for _ in range(item_costs.COST_HALF_LIFE):
        costs.tick([True, False, False], [True, False, False])
    after = costs.predict(["Tree"], tree)[0, 0] / costs.rays_ms(tree)[0, 0]
    assert after == pytest.approx(before ** 0.5, rel=1e-6)


def test_an_items_own_cost_is_against_the_current_fit_not_counted_twice():
    """A statue's own cost is learned (the law); then 33 frames of a wall at 1.5x the law move the
    fit to 1.5x.  The statue's price follows what it measured, faded towards the new fit by its
    age, not the new fit times a ratio frozen when it was learned (which would say 1.5x)."""
    costs = ItemCosts()
    for rays in (180, 840, 400, 1600, 250, 1200, 3000, 600, 2000, 350):
        item_frame(costs, "Statue", rays)
    assert costs.cost_ratios(["Statue"])[0, 0] == pytest.approx(1.0, rel=1e-6)  # the fit is the law
    for rays in (180, 840, 400, 1600, 250, 1200, 3000, 600, 2000, 350) * 3 + (800, 900, 1000):
        item_frame(costs, "Wall", rays, factor=1.5)
    probe = np.array([[1000.0, 0, 0]])
    assert costs.rays_ms(probe)[0, 0] == pytest.approx(1.5 * law(1000), rel=1e-6)
    fade = 0.5 ** (33 / item_costs.COST_HALF_LIFE)
    assert costs.predict(["Statue"], probe)[0, 0] == pytest.approx(1.5 * law(1000) * (1 / 1.5) ** fade, rel=0.02)
    assert costs.predict(["Wall"], probe)[0, 0] == pytest.approx(1.5 * law(1000), rel=0.02)


def test_an_items_own_cost_is_bounded_and_cleared_by_a_stale_revision():
    costs = ItemCosts()
    for rays in (180, 840, 400, 1600, 250, 1200):
        item_frame(costs, "Statue", rays)
    item_frame(costs, "Stalled", 5000, factor=50.0)  # one stalled frame: 50x the law
    assert costs.cost_ratios(["Stalled"])[0, 0] == pytest.approx(item_costs.COST_RATIO_RANGE[1])
    for _ in range(int(costs.stale_after[0])):  # wanted, never traced: the effect's costs are revised
        costs.tick([True, False, False], [False, False, False])
    assert costs.cost_ratios(["Stalled"])[0, 0] == 1.0


def test_items_traced_together_keep_what_each_learned_alone():
    """A tree learned 1.5x the law alone, a wall 1x; traced together at their true costs, the frame's
    ms are shared as their corrected prices: each keeps its own (split by the fit alone, both
    would drift to the average)."""
    costs = ItemCosts()
    for rays in (180, 840, 400, 1600, 250, 1200, 15000, 25000, 18000, 22000):
        item_frame(costs, "Statue" if rays < 10000 else "Wall", rays)
    for _ in range(8):
        item_frame(costs, "Tree", 20000, factor=1.5)
        item_frame(costs, "Wall", 20000)
    tree = costs.cost_ratios(["Tree"])[0, 0] * costs.rays_ms(np.array([[20000.0, 0, 0]]))[0, 0]
    for _ in range(10):
        expected = np.array([[20000.0, 0, 0], [20000.0, 0, 0]])
        chosen = np.array([[True, False, False], [True, False, False]])
        costs.tick([True, False, False], [True, False, False])
        costs.observe(["Tree", "Wall"], expected, expected, chosen, chosen.astype(float),
                      [3.0 + 2.5 * law(20000), 0, 0], [40000.0, 0, 0], shadow_setup_ms=3.0,
                      embree_ms=[2e-4 * 40000, 0, 0])
    own = costs.cost_ratios(["Tree", "Wall"])[:, 0] * costs.rays_ms(np.array([[20000.0, 0, 0]]))[0, 0]
    assert own[0] == pytest.approx(1.5 * law(20000), rel=0.1) and own[1] == pytest.approx(law(20000), rel=0.1)
    assert tree == pytest.approx(1.5 * law(20000), rel=0.12)


def test_one_items_price_in_plain_python_is_the_arrays_price():
    rng = np.random.default_rng(3)
    fits = [(1.0, 0.05, 0.6, 2e-4, 5000.0), (0.0, 3e-4, 1.0, 1e-4, np.inf), (2.0, 0.01, 0.8, 0.0, 800.0)]
    rays = np.r_[0.0, 1.0, rng.uniform(0, 40000, 50)]
    for fit in fits:
        assert [cost_fit.item_ms_one(fit, r) for r in rays.tolist()] == pytest.approx(
            cost_fit.item_ms(fit, rays).tolist(), rel=1e-12)
