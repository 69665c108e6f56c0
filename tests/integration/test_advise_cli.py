"""``phrt advise`` as users run it (subprocesses): a short advice of the hand-built scene's path,
and bad input exiting 2 with one line, as ``phrt render`` does."""
import csv
import os
import subprocess
import sys
import tempfile
from collections import Counter
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

os.environ.setdefault("BLENDER_USER_RESOURCES", tempfile.mkdtemp(prefix="phrt-test-user-"))

import pytest  # noqa: E402

bpy = pytest.importorskip("bpy")

from advice_scene import advice_scene  # noqa: E402
from phrt.phrt_addon.advise import recommend  # noqa: E402

PHRT = Path(sys.executable).with_name("phrt")


def run(args, cwd):
    process = subprocess.run([str(PHRT), *args], cwd=cwd, capture_output=True, text=True, timeout=600)
    lines = [line for line in process.stderr.splitlines() if line.strip() and "EGL" not in line]
    return process.returncode, process.stdout, lines


@pytest.fixture(scope="module")
def results(blender, tmp_path_factory):
    folder = tmp_path_factory.mktemp("advise-cli")
    advice_scene()
    bpy.ops.wm.save_as_mainfile(filepath=str(folder / "hand.blend"))
    bpy.ops.wm.read_homefile(use_empty=True)
    blend = str(folder / "hand.blend")
    commands = {
        "ok": ["advise", blend, "--frames", "1-4", "--every", "2", "--budget-at", "0.5,1", "--untagged", "1"],
        "missing": ["advise", str(folder / "nothere.blend")],
        "frames": ["advise", blend, "--frames", "4-x"],
        "budget": ["advise", blend, "--budget-at", "0.5,1.5"],
        "path": ["advise", blend, "--path", "NoSuchCamera"],
        "every": ["advise", blend, "--every", "0"],
        "resolution": ["advise", blend, "--resolution", "640by480"],
    }
    with ThreadPoolExecutor(3) as pool:
        futures = {name: pool.submit(run, argv, folder) for name, argv in commands.items()}
        return folder, {name: future.result() for name, future in futures.items()}


def test_advise_writes_the_advice_files_into_the_default_folder(results):
    folder, outcomes = results
    code, stdout, stderr = outcomes["ok"]
    assert code == 0, stderr
    out = folder / "out" / "hand-Camera-advice"
    for name in ("advice.csv", "advice.json", "advice.md", "advice.html", "benefit_per_ms.png", "mattered.png",
                 "tags.json"):
        assert (out / name).is_file(), name
    header = (out / "advice.csv").read_text().splitlines()[0]
    assert header.startswith("element,effect,tagged,visible_share,mean_pixels,benefit,cost_ms,benefit_per_ms,"
                             "paper_share,benefit_share,oracle_share,recommendation,reason")
    assert "per judged frame" in stdout
    with open(out / "advice.csv", newline="") as handle:
        rows = list(csv.DictReader(handle))
    # The summary line counts the file's recommendations.
    counts = Counter(row["recommendation"] for row in rows)
    said = stdout.split("judged frame): ", 1)[1].split(" -> ", 1)[0]  # "keep 3, tag 1, untag 3"
    assert {word: int(count) for word, count in (part.rsplit(" ", 1) for part in said.split(", "))} == counts, stdout
    # The untagged chrome sphere's reflection removes error (measured on images: no timing in it) and
    # is told to be tagged exactly when the oracle bought it often enough at some budget.  Whether it
    # did is a matter of measured milliseconds: on a machine that slows down between the runs that
    # set the budgets and the oracle's timings it may not (seen once in CI on Blender 5.2).
    chrome = next(row for row in rows if row["element"] == "ChromeSphere" and row["effect"] == "reflections")
    assert chrome["tagged"] == "0" and float(chrome["benefit"]) >= recommend.NOISE_FLIP
    best_share = max(float(chrome[f"oracle_share_{fraction}"]) for fraction in ("0.5", "1"))
    assert chrome["recommendation"] == ("tag" if best_share >= recommend.TAG_SHARE else "keep"), chrome


@pytest.mark.parametrize("name,words", [("missing", "no such file"), ("frames", "malformed frame range"),
                                        ("budget", "outside 0..1"), ("path", "NoSuchCamera"),
                                        ("every", "--every 0"), ("resolution", "malformed resolution")])
def test_bad_input_exits_2_with_one_line(results, name, words):
    _, outcomes = results
    code, _, stderr = outcomes[name]
    assert code == 2 and len(stderr) == 1, stderr
    assert stderr[0].startswith("phrt: error: ") and words in stderr[0], stderr
