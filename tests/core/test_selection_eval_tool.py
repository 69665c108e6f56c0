"""``tools/selection_eval.py``: a sweep stopped by a signal stops the evaluation with the sweep's
exit status (no later path is swept, no table written over the last one)."""
import sys
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
