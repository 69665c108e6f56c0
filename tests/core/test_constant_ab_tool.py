"""``tools/constant_ab.py``: its arguments (bad ones exit 2 with one line) and its paired verdict
(relative LDR-FLIP difference to the baseline's run, an interval that must leave out 0)."""
import sys
from pathlib import Path

import numpy as np
import pytest

TOOLS = Path(__file__).resolve().parents[2] / "tools"


@pytest.fixture
def tool(monkeypatch):
    monkeypatch.syspath_prepend(str(TOOLS))
    import constant_ab
    yield constant_ab
    sys.modules.pop("constant_ab", None)


def test_the_constant_is_a_number_of_a_selection_module(tool):
    from phrt.phrt_addon.select import benefit_selection
    module, name = tool.parse_constant("benefit_selection.ADD_SLACK")
    assert module is benefit_selection and name == "ADD_SLACK"
    for bad in ("ADD_SLACK", "no_such_module.X", "benefit_selection.NO_SUCH", "benefit_selection.BenefitSelector",
                "benefit_selection.STEADY_FRAMES"):  # the last imported from frame_time: set there, it changes nothing
        with pytest.raises(tool.UsageError):
            tool.parse_constant(bad)
    module, name = tool.parse_constant("frame_time.STEADY_FRAMES")
    assert tool.as_values(module, name, [8.0, 12.0]) == [8, 12]  # an integer constant stays one
    with pytest.raises(tool.UsageError):
        tool.as_values(module, name, [8.0, 8.5])


def test_only_a_complete_reference_run_of_the_same_path_frames_and_machine_is_reused(tool, tmp_path):
    import json
    from phrt.phrt_addon.runs import summary as run_summary
    summary = {"mode": "RASTER", "scene": "arcade", "path": "path1", "frame_range": [1, 24],
               "resolution": [320, 240], "images": "exr", "machine": run_summary.machine_info()}
    (tmp_path / "summary.json").write_text(json.dumps(summary))
    assert tool.reusable(tmp_path, "RASTER", "arcade", "path1", (1, 24), (320, 240))
    same = ("RASTER", "arcade", "path1", (1, 24), (320, 240))
    for position, other in ((0, "RAYTRACE"), (1, "atrium"), (2, "path2"), (3, (1, 48)), (4, (640, 480))):
        changed = same[:position] + (other,) + same[position + 1:]
        assert not tool.reusable(tmp_path, *changed)
    (tmp_path / "summary.json").write_text(json.dumps(dict(summary, partial=True)))
    assert not tool.reusable(tmp_path, "RASTER", "arcade", "path1", (1, 24), (320, 240))
    assert not tool.reusable(tmp_path / "nothing", "RASTER", "arcade", "path1", (1, 24), (320, 240))


@pytest.mark.parametrize("argv", [
    ["arcade", "--path", "path1", "--constant", "benefit_selection.ADD_SLACK", "--values", "0.25"],
    ["arcade", "--path", "path1", "--constant", "benefit_selection.ADD_SLACK", "--values", "0.25,x"],
    ["arcade", "--path", "path1", "--constant", "nowhere.X", "--values", "0.25,0"],
    ["arcade", "--path", "path1", "--constant", "benefit_selection.ADD_SLACK", "--values", "0.25,0",
     "--budget-at", "1.5"],
    ["arcade", "--path", "path1", "--constant", "benefit_selection.ADD_SLACK", "--values", "0.25,0",
     "--resolution", "320by240"],
    ["arcade", "--path", "path1", "--constant", "benefit_selection.ADD_SLACK", "--values", "0.25,0,0"],
    ["arcade", "--constant", "benefit_selection.ADD_SLACK", "--values", "0.25,0"],  # no --path
    ["arcade", "--path", "path1", "--constant", "benefit_selection.ADD_SLACK", "--values", "0.25,0", "--block", "0"],
])
def test_bad_arguments_exit_2_with_one_line_and_render_nothing(tool, argv, capsys, monkeypatch):
    monkeypatch.setattr(tool, "run_path", lambda *a, **k: pytest.fail("rendered despite bad arguments"))
    assert tool.main(argv) == 2
    error = capsys.readouterr().err.strip()
    assert error.startswith("constant-ab: ") and len(error.splitlines()) == 1


def test_the_verdict_names_a_difference_only_where_its_interval_leaves_out_0(tool):
    rng = np.random.default_rng(3)
    frames = range(2, 122)
    base = {frame: 0.02 + 0.005 * np.sin(frame / 7.0) + 0.001 * rng.random() for frame in frames}
    runs = {
        "base": base,
        "lower": {frame: value * (0.9 + 0.01 * rng.standard_normal()) for frame, value in base.items()},
        "higher": {frame: value * 1.1 for frame, value in base.items()},
        "same": {frame: value * (1.0 + 0.02 * rng.standard_normal()) for frame, value in base.items()},
    }
    runs["lower"].pop(50)  # a frame a run lacks: compared on the frames all have
    result = tool.compare(runs, "base")
    count, mean, difference, low, high, verdict = result["lower"]
    assert count == len(frames) - 1 and verdict == "lower"
    assert difference == pytest.approx(-0.1, abs=0.005) and low < difference < high < 0.0
    assert result["higher"][5] == "higher" and result["higher"][2] == pytest.approx(0.1)
    assert result["same"][5] == "no difference" and result["same"][3] <= 0.0 <= result["same"][4]
    assert result["base"][2] == 0.0 and result["base"][5] == "no difference"
