"""The captured share (phrt_addon/report/captured.py): a ratio of sums over judged frames, its 90%
block-bootstrap interval covers the truth on a synthetic camera path, verdicts only without overlap."""
import numpy as np
import pytest

from phrt.phrt_addon.report import captured


def test_captured_is_a_ratio_of_sums_not_a_mean_of_ratios():
    raster = np.array([0.20, 0.100001])
    oracle = np.array([0.10, 0.100000])  # frame 2: the oracle gains 1e-6
    run = np.array([0.15, 0.099000])  # frame 2's per-frame ratio would be 1001
    share = captured.captured_share(raster, run, oracle)
    assert share == pytest.approx((0.05 + 0.001001) / (0.10 + 1e-6))
    assert share < 1.0
    assert captured.captured_share([0.1, 0.1], [0.1, 0.1], [0.1, 0.1]) is None  # the oracle gains nothing


def test_a_run_as_good_as_the_oracle_captures_one_and_raster_captures_zero():
    raster, oracle = np.full(12, 0.2), np.linspace(0.05, 0.15, 12)
    assert captured.captured_share(raster, oracle, oracle) == pytest.approx(1.0)
    assert captured.captured_share(raster, raster, oracle) == pytest.approx(0.0)
    result = captured.measure(raster, oracle - 0.001 * (np.arange(12) == 3), oracle)
    assert result.beat_oracle == 1 and result.min_regret == pytest.approx(-0.001) and result.judged_frames == 12


def synthetic_path(generator, frames, truth):
    """Per-frame errors of a camera path: the oracle's gain drifts with the view (AR(1)), the run gets
    ``truth`` of it in expectation, with correlated frame-to-frame noise of mean 0."""
    drift = np.empty(frames)
    drift[0] = generator.normal()
    for index in range(1, frames):
        drift[index] = 0.5 * drift[index - 1] + generator.normal() * np.sqrt(1 - 0.25)
    gain = 0.05 * np.exp(0.4 * drift)
    noise = 0.01 * generator.normal(size=frames)
    raster = 0.2 + 0.02 * generator.normal(size=frames)
    oracle = raster - gain
    run = raster - truth * gain - noise * gain / gain.mean()
    return raster, run, oracle


def test_the_90_percent_interval_covers_the_truth_about_90_percent_of_the_time():
    truth, frames, seeds = 0.6, 48, 300
    covered = []
    for seed in range(seeds):
        raster, run, oracle = synthetic_path(np.random.default_rng(seed), frames, truth)
        low, high = captured.block_bootstrap(raster, run, oracle, resamples=800, seed=seed)
        covered.append(low <= truth <= high)
    coverage = float(np.mean(covered))
    assert 0.82 <= coverage <= 0.97, coverage


def test_the_interval_narrows_with_more_judged_frames_and_holds_the_share():
    generator = np.random.default_rng(7)
    widths = []
    for frames in (12, 200):
        raster, run, oracle = synthetic_path(generator, frames, 0.6)
        low, high = captured.block_bootstrap(raster, run, oracle)
        assert low <= captured.captured_share(raster, run, oracle) <= high
        widths.append(high - low)
    assert widths[1] < widths[0] / 2
    assert captured.block_bootstrap([0.2], [0.1], [0.05]) == (None, None)


def test_verdict_says_no_difference_when_intervals_overlap():
    a = captured.Captured(share=0.62, low=0.50, high=0.71, judged_frames=12)
    b = captured.Captured(share=0.55, low=0.42, high=0.66, judged_frames=12)
    assert captured.verdict("measured", a, "error", b) == captured.NO_DIFFERENCE
    c = captured.Captured(share=0.90, low=0.82, high=0.97, judged_frames=12)
    assert captured.verdict("measured", a, "benefit", c) == "benefit captures more"
    assert captured.verdict("measured", a, "none", captured.Captured()) == captured.NO_DIFFERENCE


def test_the_paired_difference_tells_apart_what_two_overlapping_intervals_cannot():
    generator = np.random.default_rng(3)
    frames = 48
    # Frames differ a lot in what the oracle can gain (a mirror in view or not) and in what any
    # selection gets of it (both runs miss the same hard frames); run a gets 15% more than run b,
    # each with a little noise of its own.
    possible = generator.gamma(0.6, 0.004, frames)
    raster = 0.02 + possible
    oracle = raster - possible
    shared = generator.normal(0, 0.4, frames)
    run_a = raster - possible * (0.60 + shared + generator.normal(0, 0.05, frames))
    run_b = raster - possible * (0.45 + shared + generator.normal(0, 0.05, frames))
    a, b = captured.measure(raster, run_a, oracle), captured.measure(raster, run_b, oracle)
    difference, low, high = captured.paired_difference(raster, run_a, run_b, oracle)
    assert difference == pytest.approx(a.share - b.share)
    assert captured.overlap(a.interval, b.interval)  # one run's interval each: "no difference"
    assert 0.0 < low < difference < high and high - low < min(a.high - a.low, b.high - b.low)
    assert captured.paired_verdict("a", "b", difference, low, high) == "a captures more"
    assert captured.paired_verdict("a", "b", 0.1, -0.05, 0.2) == captured.NO_DIFFERENCE


def test_a_run_paired_with_itself_differs_by_nothing_and_no_gain_gives_none():
    raster, oracle = np.full(10, 0.03), np.full(10, 0.02)
    run = np.linspace(0.021, 0.029, 10)
    assert captured.paired_difference(raster, run, run, oracle) == (0.0, 0.0, 0.0)
    assert captured.paired_difference(raster, run, run, raster) == (None, None, None)
