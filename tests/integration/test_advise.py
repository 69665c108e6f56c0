"""The tagging advisor on real renders (bpy, Embree, EXR, LDR-FLIP): the hand-built scene of
``advice_scene.py`` advised over frames 1-4 (frames 2 and 4 judged), at a budget that covers
everything (1e6 ms), so each item's advice depends only on what tracing it changes, not on the
machine's timings."""
import csv
import json
import os
import re
import tempfile

os.environ.setdefault("BLENDER_USER_RESOURCES", tempfile.mkdtemp(prefix="phrt-test-user-"))

import numpy as np  # noqa: E402
import pytest  # noqa: E402

bpy = pytest.importorskip("bpy")

from advice_scene import advice_scene  # noqa: E402
from phrt.engine import final  # noqa: E402
from phrt.engine.runs import advise, item_measure  # noqa: E402
from phrt.engine.runs import oracle as oracle_engine  # noqa: E402
from phrt.phrt_addon.report import metrics, oracle  # noqa: E402
from phrt.phrt_addon.runs import run_files  # noqa: E402


@pytest.fixture(scope="module")
def advised(blender, tmp_path_factory):
    final.release_caches()
    scene, camera = advice_scene()
    out = tmp_path_factory.mktemp("advice")
    written = advise.run_advice(scene, camera, (1, 4), out, budget_at=(), budget_ms=(1e6,), every=2, scene_label="hand")
    with open(written["csv"], newline="") as handle:
        rows = {(row["element"], row["effect"]): row for row in csv.DictReader(handle)}
    yield scene, camera, out, written, rows
    final.release_caches()


def test_the_advice_keeps_the_mirror_untags_the_matte_tags_the_chrome_and_drops_the_glass_shadow(advised):
    _, _, _, _, rows = advised
    advice = {item: row["recommendation"] for item, row in rows.items()}
    assert advice[("Mirror", "reflections")] == "keep", rows[("Mirror", "reflections")]["reason"]
    assert advice[("MatteCube", "reflections")] in ("untag", "drop_effect")
    assert advice[("ChromeSphere", "reflections")] == "tag", rows[("ChromeSphere", "reflections")]["reason"]
    assert advice[("GlassBall", "shadows")] == "drop_effect", rows[("GlassBall", "shadows")]["reason"]
    assert advice[("GlassBall", "refractions")] == "keep"
    assert rows[("ChromeSphere", "reflections")]["tagged"] == "0" and rows[("Mirror", "reflections")]["tagged"] == "1"


def test_each_reason_names_its_measured_numbers(advised):
    _, _, _, _, rows = advised
    for row in rows.values():  # the CSV keeps 6 significant digits, the words 5 decimals / 2 for ms
        said = re.search(r"removes (-?[0-9.]+) LDR-FLIP per frame for ([0-9.]+) ms", row["reason"])
        assert said is not None, row["reason"]
        assert float(said.group(1)) == pytest.approx(float(row["benefit"]), abs=1e-5)
        assert float(said.group(2)) == pytest.approx(float(row["cost_ms"]), abs=0.01)


def test_the_files_and_the_per_pixel_maps_are_written(advised):
    _, _, out, written, rows = advised
    for name in ("csv", "json", "md", "html", "chart", "strips", "tags"):
        assert written[name].is_file() and written[name].stat().st_size > 100, name
    document = json.loads(written["json"].read_text())
    assert document["prospects"]["judged"] == ["ChromeSphere"] and document["judged_frames"] == 2
    mirror = next(item for item in document["items"] if item["item"] == "Mirror/reflections")
    assert (out / "maps" / mirror["map"]).is_file()
    tags = {entry["element"]: entry for entry in json.loads(written["tags"].read_text())["elements"]}
    assert tags["MatteCube"]["visible_in_ray_tracing"] is False and tags["MatteCube"]["culling_priority"] == 8
    assert tags["Mirror"]["visible_in_ray_tracing"] is True and tags["Mirror"]["culling_priority"] == 0


def test_the_scene_is_left_as_it_was(advised):
    scene, _, _, _, _ = advised
    chrome = bpy.data.objects["ChromeSphere"].phrt
    assert not chrome.candidate and chrome.shadows and chrome.reflections and chrome.refractions
    glass = bpy.data.objects["GlassBall"].phrt
    assert glass.candidate and glass.shadows and glass.refractions and not glass.reflections


def test_benefit_per_ms_is_the_oracles_own_measurement_on_the_same_frames(advised):
    """The oracle measures the Mirror element (tagged for reflections only: the item
    Mirror/reflections) on the same judged frames against the same reference: the same error drop,
    and the advice's benefit per ms is the ratio of the summed drops to the summed costs it logged."""
    scene, camera, out, written, rows = advised
    document = json.loads(written["json"].read_text())
    mirror = next(item for item in document["items"] if item["item"] == "Mirror/reflections")
    reference_dir = out / advise.RUNS_DIR / "reference"
    hybrid = next((out / advise.RUNS_DIR).glob("hybrid-paper-*"))
    info = oracle_engine.run_oracle(scene, camera, reference_dir, {"paper": hybrid}, out / "oracle", every=1,
                                    raster_dir=out / advise.RUNS_DIR / "raster")
    oracle_rows = [row for row in oracle.read_csv(out / "oracle" / oracle.CANDIDATES_CSV)
                   if row["element"] == "Mirror"]
    by_frame = {int(row["frame"]): float(row["benefit"]) for row in oracle_rows}
    assert info["frames"] == [2, 4]
    for frame, benefit in zip(mirror["frames"], mirror["benefit_by_frame"]):
        assert benefit == pytest.approx(by_frame[frame], abs=1e-5)
    with oracle_engine.ForcedRenderer(scene, camera) as renderer:
        reference = metrics.read_image(run_files.frame_image_path(reference_dir, 2))
        renderer.render(2, ("Mirror",))
        raster = item_measure.measure_subset(renderer, 2, (), reference, timings=1)
        alone = item_measure.measure_subset(renderer, 2, ("Mirror",), reference)
    assert raster.flip - alone.flip == pytest.approx(mirror["benefit_by_frame"][0], abs=1e-5)
    assert alone.trace_ms > 0
    ratio = sum(max(b, 0.0) for b in mirror["benefit_by_frame"]) / sum(mirror["cost_ms_by_frame"])
    assert float(rows[("Mirror", "reflections")]["benefit_per_ms"]) == pytest.approx(ratio, rel=1e-4)
    assert np.isfinite(ratio) and ratio > 0


def test_the_benefit_selections_shares_are_its_items(advised):
    """The BENEFIT selection's choices fill benefit_share per item: with all the time there is, it
    traces the mirror's reflection and the glass ball's refraction every visible frame, and never
    the glass ball's shadow over nothing, which the paper's selection buys with the ball."""
    _, _, _, written, rows = advised
    assert "BENEFIT" in json.loads(open(written["json"], encoding="utf-8").read())["selections"]
    share = {item: row["benefit_share"] for item, row in rows.items() if row["tagged"] == "1"}
    assert all(value != "" for value in share.values()), share
    assert float(share[("Mirror", "reflections")]) == 1.0
    assert float(share[("GlassBall", "refractions")]) == 1.0
    assert float(share[("GlassBall", "shadows")]) < float(rows[("GlassBall", "shadows")]["paper_share"]), rows[
        ("GlassBall", "shadows")]


def test_applying_recommendations_changes_exactly_their_properties_in_one_undoable_step(advised):
    """Last in this module: it changes the scene.  ``bpy.ops.ed.undo`` needs a window, which Blender
    as a module in background mode has none of (its poll fails: checked on bpy 5.0.1), so where it
    cannot run the test checks what makes the change one undo step: a single operator call
    registered with the UNDO option."""
    from phrt.operators import advisor
    _, _, _, written, _ = advised
    window_manager = bpy.context.window_manager
    advisor.fill_list(window_manager, written["csv"])
    index = {(item.element, item.effect): position for position, item in enumerate(window_manager.phrt_advice)}
    names = [obj.name for obj in bpy.data.objects if obj.type == "MESH"]
    before = {name: item_measure.read_settings(bpy.data.objects[name]) for name in names}
    expected = {name: dict(settings) for name, settings in before.items()}
    expected["GlassBall"]["shadows"] = False
    expected["MatteCube"]["candidate"] = False
    expected["ChromeSphere"].update(candidate=True, shadows=False, refractions=False, reflections=True)
    assert "UNDO" in advisor.PHRT_OT_apply_advice.bl_options
    for item in (("GlassBall", "shadows"), ("MatteCube", "reflections"), ("ChromeSphere", "reflections")):
        assert bpy.ops.phrt.apply_advice(index=index[item]) == {"FINISHED"}
    after = {name: item_measure.read_settings(bpy.data.objects[name]) for name in names}
    assert after == expected
    assert window_manager.phrt_advice[index[("GlassBall", "shadows")]].applied
    assert bpy.ops.phrt.apply_advice(index=index[("Mirror", "reflections")]) == {"FINISHED"}  # keep: no change
    assert item_measure.read_settings(bpy.data.objects["Mirror"]) == before["Mirror"]
    if bpy.ops.ed.undo.poll():
        for _ in range(4):
            bpy.ops.ed.undo()
        assert {name: item_measure.read_settings(bpy.data.objects[name]) for name in names} == before
