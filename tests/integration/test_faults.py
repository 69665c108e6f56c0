"""The short version of ``make faults`` (tools/faults.py): four replays SIGKILLed while an image, a
CSV row and summary.json are being written and at a random moment (that one reusing the folder
with --overwrite, over a dead writer's lock): every folder reads back consistently and the report
takes each as partial.  The long version kills 20 times."""
import importlib.util
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
spec = importlib.util.spec_from_file_location("faults", ROOT / "tools" / "faults.py")
faults = importlib.util.module_from_spec(spec)
sys.modules["faults"] = faults  # dataclasses look their module up there
spec.loader.exec_module(faults)

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="the harness uses inotify")


def test_replays_killed_at_every_kind_of_moment_leave_consistent_folders(tmp_path):
    # The first or second event of each kind, a random moment within the first second: each kill
    # lands while the replay runs, however fast the machine is.
    results = faults.run(4, tmp_path / "faults", seed=7, frame_count=24, log=lambda line: None, max_skip=2,
                         max_delay_s=1.0)
    assert [kill.moment for kill in results] == list(faults.MOMENTS)
    assert results[3].overwrite and results[3].run_dir == results[2].run_dir
    assert all(kill.killed for kill in results), [(kill.moment, kill.killed) for kill in results]
    assert [kill.problems for kill in results] == [[]] * 4
