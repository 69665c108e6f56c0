"""Steady frame times (phrt_addon/runs/steady.py): the first frame is out, its cost reported alone."""
import pytest

from phrt.phrt_addon.runs import steady


def rows(totals, setups=None):
    setups = setups or [0.0] * len(totals)
    return [{"frame": index + 1, "total_ms": total, "setup_ms": setup}
            for index, (total, setup) in enumerate(zip(totals, setups))]


def test_steady_means_exclude_the_first_frame():
    frames = rows([1000.0, 50.0, 60.0, 70.0], [900.0, 0.0, 0.0, 0.0])
    assert steady.steady_stats(frames)["mean"] == pytest.approx(60.0)
    assert steady.steady_stats(frames)["max"] == pytest.approx(70.0)
    assert steady.first_frame_ms(frames) == pytest.approx(1000.0)
    # out of order in the file: the first frame is the lowest frame number
    assert steady.steady_stats(list(reversed(frames)))["mean"] == pytest.approx(60.0)


def test_later_one_time_work_is_taken_out_and_a_single_frame_is_its_own_steady_frame():
    assert steady.steady_stats(rows([900.0, 150.0, 60.0], [0.0, 100.0, 0.0]))["mean"] == pytest.approx(55.0)
    assert steady.steady_stats(rows([300.0], [200.0]))["mean"] == pytest.approx(100.0)
    assert steady.steady_stats([])["mean"] is None and steady.first_frame_ms([]) is None


def test_p95_over_budget():
    assert steady.over_budget(110.0, 100.0) == pytest.approx(1.1)
    assert steady.over_budget(110.0, None) is None and steady.over_budget(None, 100.0) is None


def test_speed_against_the_raster_run_is_the_median_ratio_over_common_steady_frames():
    reference = [{"frame": frame, "gbuffer_ms": ms} for frame, ms in ((1, 500.0), (2, 20.0), (3, 20.0), (4, 40.0))]
    # frame 1 holds one-time work (left out); frame 5 has no reference; a missing or 0 value is skipped
    run = [{"frame": 1, "gbuffer_ms": 5.0}, {"frame": 2, "gbuffer_ms": 30.0}, {"frame": 3, "gbuffer_ms": 24.0},
           {"frame": 4, "gbuffer_ms": 48.0}, {"frame": 5, "gbuffer_ms": 90.0}, {"frame": 6, "gbuffer_ms": None}]
    assert steady.speed_against(run, reference) == pytest.approx(1.2)  # median of 1.5, 1.2, 1.2
    assert steady.speed_against(run, [{"frame": 9, "gbuffer_ms": 10.0}]) is None
    assert steady.speed_against([{"frame": 2, "gbuffer_ms": float("nan")}, {"frame": 3, "gbuffer_ms": 0.0}],
                                reference) is None
