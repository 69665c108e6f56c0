"""``tools/selection_eval.py``: a sweep stopped by a signal stops the evaluation with the sweep's
exit status (no later path is swept, no table written over the last one)."""
import sys

import pytest
from pathlib import Path

TOOLS = Path(__file__).resolve().parents[2] / "tools"


def test_a_signal_stopping_a_sweep_stops_the_evaluation(monkeypatch, tmp_path, capsys):
    monkeypatch.syspath_prepend(str(TOOLS))
    import selection_eval
    from phrt import cli
    calls = []
    monkeypatch.setattr(cli, "main", lambda argv: calls.append(argv) or 143)  # SIGTERM during the first
    status = selection_eval.main(["--out", str(tmp_path / "eval"), "--paths", "arcade/path3,atrium/path2",
                                  "--variants", "measured"])
    assert status == 143
    assert len(calls) == 1  # the second path was not swept
    assert calls[0][:2] == ["sweep", "arcade"] and "--lockstep" in calls[0]  # the hybrid runs in lockstep
    assert not (tmp_path / "eval" / "selection_eval.csv").exists()
    assert "resume" in capsys.readouterr().err
    sys.modules.pop("selection_eval", None)


def test_one_after_another_runs_the_plain_sweep(monkeypatch, tmp_path):
    monkeypatch.syspath_prepend(str(TOOLS))
    import selection_eval
    from phrt import cli
    calls = []
    monkeypatch.setattr(cli, "main", lambda argv: calls.append(argv) or 130)
    selection_eval.main(["--out", str(tmp_path / "eval"), "--paths", "atrium/path2", "--variants", "measured",
                         "--one-after-another"])
    assert calls and "--lockstep" not in calls[0]
    sys.modules.pop("selection_eval", None)


def test_the_paired_table_compares_variants_on_the_same_judged_frames(monkeypatch, tmp_path):
    monkeypatch.syspath_prepend(str(TOOLS))
    import numpy as np
    import selection_eval
    from phrt.phrt_addon.report import oracle
    frames = list(range(4, 84, 4))
    generator = np.random.default_rng(1)
    gain = generator.gamma(0.8, 0.004, len(frames))
    runs = {"benefit": "p-hybrid-at0.50-benefit", "measured": "p-hybrid-at0.50-measured"}
    shares = {"benefit": 0.7, "measured": 0.4}
    rows, candidates = [], []
    for frame, possible in zip(frames, gain):
        item = oracle.FrameCandidates(frame=frame, names=["Mirror"], cost_ms=np.array([3.0]),
                                      benefit=np.array([possible]), flip_raster=0.02 + possible)
        candidates.append(item)
        for variant, run in runs.items():
            run_flip = 0.02 + possible * (1 - shares[variant] + generator.normal(0, 0.02))
            rows.append(oracle.regret_row(run, frame, 40.0, 30.0, 8.0, set(), run_flip, {"Mirror"}, 0.02, item))
    oracle.write_results(tmp_path / "atrium-path2" / "oracle", 4, frames, candidates, rows, {})
    table = [{"path": "atrium/path2", "variant": variant, "budget_at": "0.5", "run": run} for variant, run in runs.items()]
    (pair,) = selection_eval.paired(table, tmp_path)
    assert (pair["first"], pair["second"], pair["judged_frames"]) == ("benefit", "measured", len(frames))
    assert pair["difference"] > 0 and pair["difference_lo"] > 0 and pair["verdict"] == "benefit captures more"
    assert "| atrium/path2 | 0.50 | benefit - measured | +0.3" in selection_eval.paired_markdown([pair])
    sys.modules.pop("selection_eval", None)


def test_the_raster_floor_comes_from_the_raster_run_the_oracle_took_its_shared_time_from(monkeypatch, tmp_path):
    """The p95 floor of the table: the steady p95 (first frame left out) of the raster run named in
    oracle.json's shared_from (lockstep: the group raster run), and only while it is that run."""
    monkeypatch.syspath_prepend(str(TOOLS))
    import numpy as np
    import selection_eval
    from phrt.phrt_addon.report import oracle
    from phrt.phrt_addon.runs.run_log import RunLog
    sweep = tmp_path / "atrium-path2"
    group = sweep / "atrium-path2-raster-group"
    log = RunLog(group)
    for frame in range(1, 22):
        log.add_frame({"frame": frame, "mode": "RASTER", "total_ms": 900.0 if frame == 1 else 30.0 + frame,
                       "raster_ms": 20.0, "select_ms": 1.0, "trace_ms": 0.0, "composite_ms": 9.0, "budget_ms": 0.0,
                       "predicted_trace_ms": 0.0, "n_candidates": 0, "n_visible": 0, "n_selected": 0, "rays": 0})
    log.close({"scene": "atrium", "path": "path2", "resolution": [8, 8], "blender_version": "5.0.1",
               "embreex_version": "4.4.0.post1"})
    assert selection_eval._shared_raster_p95(sweep) is None  # no oracle yet: the caller takes the first raster run's
    oracle.write_results(sweep / oracle.ORACLE_DIR, 4, [], [], [], {}, shared_dir=group)
    # Frames 2-21: 32..51 ms, p95 50.05; the first frame's 900 ms (one-time work) would make it 51.0.
    assert selection_eval._shared_raster_p95(sweep) == pytest.approx(float(np.percentile(np.arange(32.0, 52.0), 95)))
    assert selection_eval._shared_raster_p95(sweep) == pytest.approx(50.05)
    (group / "summary.json").write_text((group / "summary.json").read_text().replace("atrium", "arcade"))
    assert selection_eval._shared_raster_p95(sweep) is None  # the run was redone since the oracle: not its floor
    sys.modules.pop("selection_eval", None)
