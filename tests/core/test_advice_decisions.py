"""The tagging advisor's decisions on measured numbers (no Blender): item books, recommendations,
the property changes they make, the export's culling priority, and the files."""
import csv
import json

import numpy as np
import pytest

from phrt.phrt_addon.advise import export, files, items, recommend
from phrt.phrt_addon.report.oracle import FrameCandidates

TAGGED = {"Mirror/reflections": True, "Matte/reflections": True, "Glass/refractions": True,
          "Glass/shadows": True, "Chrome/reflections": False}
# (benefit, cost ms) per item on every judged frame: the hand-built scene's shape.
MEASURED = {"Mirror/reflections": (0.02, 2.0), "Matte/reflections": (0.0, 1.5), "Glass/refractions": (0.01, 3.0),
            "Glass/shadows": (0.0, 1.0), "Chrome/reflections": (0.015, 2.0)}


def frames(count=4, measured=MEASURED):
    names = list(measured)
    return [FrameCandidates(frame=frame, names=names, cost_ms=np.array([measured[n][1] for n in names]),
                            benefit=np.array([measured[n][0] for n in names]), flip_raster=0.05,
                            area_px=np.full(len(names), 400.0), overhead_ms=0.5)
            for frame in range(1, count + 1)]


def paper_everything(keys=TAGGED):
    return {"PAPER": {1.0: {key: 1.0 for key, tagged in keys.items() if tagged}}}


def advise(measured=MEASURED, selections=None, budgets=None):
    budgets = budgets or {1.0: 100.0}
    book = items.books(frames(measured=measured), {key: TAGGED.get(key, True) for key in measured}, budgets,
                       {frame: 10.0 for frame in range(1, 5)},
                       selections if selections is not None else paper_everything())
    return book, recommend.recommend(book, "PAPER")


def test_the_hand_built_scenes_advice_keeps_the_mirror_untags_the_matte_tags_the_chrome_drops_the_shadow():
    _, advice = advise()
    assert advice["Mirror/reflections"].recommendation == "keep"
    assert advice["Matte/reflections"].recommendation == "untag"
    assert advice["Chrome/reflections"].recommendation == "tag"
    assert advice["Glass/shadows"].recommendation == "drop_effect"
    assert advice["Glass/refractions"].recommendation == "keep"


def test_each_reason_names_the_measured_numbers():
    book, advice = advise()
    for key, item in advice.items():
        assert f"{book[key].mean_benefit:.5f}" in item.reason, item.reason
        assert f"{book[key].mean_cost_ms:.2f} ms" in item.reason, item.reason
    assert "noise floor" in advice["Matte/reflections"].reason
    assert "refractions are worth keeping" in advice["Glass/shadows"].reason


def test_benefit_per_ms_is_a_ratio_of_sums_and_the_oracle_share_follows_the_budget():
    measured = dict(MEASURED)
    book = items.books(frames(measured=measured), TAGGED, {0.1: 14.0, 1.0: 100.0}, {f: 10.0 for f in range(1, 5)})
    mirror = book["Mirror/reflections"]
    assert mirror.benefit_per_ms == pytest.approx(0.02 / 2.0)
    # 4 ms of tracing: the fixed 0.5 ms, then the best value within 3.5 ms is the mirror alone (2 ms).
    assert mirror.oracle_share == {0.1: 1.0, 1.0: 1.0}
    assert book["Glass/refractions"].oracle_share[0.1] == 0.0
    assert book["Glass/refractions"].oracle_share[1.0] == 1.0


def test_a_selection_that_under_buys_an_item_gets_raise_priority_and_over_buying_lower():
    low = {"PAPER": {1.0: {"Mirror/reflections": 0.2, "Glass/refractions": 1.0}}}
    _, advice = advise(selections=low)
    assert advice["Mirror/reflections"].recommendation == "raise_priority"
    assert "PAPER traced it on 20%" in advice["Mirror/reflections"].reason
    # At the tight budget the oracle leaves the glass (at the ample one it takes it); the paper
    # traces it every frame at both: over-bought.
    every_frame = {"Mirror/reflections": 1.0, "Glass/refractions": 1.0}
    book = items.books(frames(), TAGGED, {0.1: 14.0, 1.0: 100.0}, {f: 10.0 for f in range(1, 5)},
                       {"PAPER": {0.1: every_frame, 1.0: every_frame}})
    assert recommend.recommend(book)["Glass/refractions"].recommendation == "lower_priority"


def test_an_item_never_visible_is_untagged_and_a_weak_untagged_one_stays_untagged():
    measured = dict(MEASURED)
    book = items.books(frames(measured=measured), {**TAGGED, "Hidden/reflections": True}, {1.0: 100.0},
                       {f: 10.0 for f in range(1, 5)})
    advice = recommend.recommend(book)
    assert advice["Hidden/reflections"].recommendation == "untag"
    assert "not visible on any of the 4 judged frames" in advice["Hidden/reflections"].reason
    weak = {**MEASURED, "Chrome/reflections": (0.00005, 2.0)}
    _, advice = advise(measured=weak)
    assert advice["Chrome/reflections"].recommendation == "keep"
    assert advice["Chrome/reflections"].reason.startswith("leave untagged")


def test_changes_touch_exactly_the_properties_of_the_recommendation():
    settings = {"candidate": True, "priority": 1.5, "shadows": True, "reflections": True, "refractions": True}
    assert recommend.changes("Glass", "shadows", "drop_effect", settings) == {"shadows": False}
    assert recommend.changes("Matte", "reflections", "untag", settings) == {"candidate": False}
    assert recommend.changes("Mirror", "reflections", "raise_priority", settings) == {"priority": 3.0}
    assert recommend.changes("Mirror", "reflections", "lower_priority", settings) == {"priority": 0.75}
    assert recommend.changes("Mirror", "reflections", "keep", settings) == {}
    untagged = {**settings, "candidate": False}
    assert recommend.changes("Chrome", "reflections", "tag", untagged) == {
        "candidate": True, "shadows": False, "refractions": False}
    with pytest.raises(ValueError):
        recommend.changes("Chrome", "reflections", "paint_it_red", settings)


def test_prospects_are_the_materials_tracing_can_change_capped_to_the_most_promising():
    assert items.prospect_effects(1.0, 0.1, 0.0, 1.0, True, 0.5) == ("reflections",)
    assert items.prospect_effects(0.0, 0.9, 0.0, 1.0, True, 0.5) == ()  # a matte wall: nothing to gain
    assert items.prospect_effects(0.0, 0.9, 0.0, 1.0, True, 0.01) == ("shadows",)  # a matte prop casts
    assert items.prospect_effects(0.0, 0.05, 1.0, 1.0, False, 0.02) == ("reflections", "refractions")
    prospects = [items.Prospect("Small", ("reflections",), 50.0, 1.0), items.Prospect("Big", ("reflections",), 900, 1.0),
                 items.Prospect("Caster", ("shadows",), 900.0, 1.0), items.Prospect("Matte", (), 5000.0, 1.0)]
    chosen, left_out = items.choose_prospects(prospects, cap=2)
    assert [p.element for p in chosen] == ["Big", "Caster"] and left_out == 1


def test_selection_shares_count_whole_elements_for_the_paper_and_effects_where_logged():
    keys = {"Glass": ["Glass/refractions", "Glass/shadows"]}
    rows = [{"frame": 1, "element": "Glass", "visible": True, "selected": True},
            {"frame": 2, "element": "Glass", "visible": True, "selected": False},
            {"frame": 3, "element": "Glass", "visible": False, "selected": False}]
    assert items.selection_shares(rows, keys) == {"Glass/refractions": 0.5, "Glass/shadows": 0.5}
    rows[0]["effects"] = "refractions"
    assert items.selection_shares(rows, keys) == {"Glass/refractions": 0.5, "Glass/shadows": 0.0}


def test_item_keys_round_trip_material_elements():
    assert items.split_key(items.item_key("Window/Glass", "refractions")) == ("Window/Glass", "refractions")
    with pytest.raises(ValueError):
        items.item_key("Mirror", "glow")


def test_culling_priority_steps_once_per_halving_and_worthless_is_eight():
    assert export.culling_priority(0.01, 0.01, True) == 0
    assert export.culling_priority(0.005, 0.01, True) == 1
    assert export.culling_priority(0.01 / 300, 0.01, True) == 8
    assert export.culling_priority(0.01, 0.01, False) == 8


def test_the_files_have_the_contract_columns_worst_value_tags_first(tmp_path):
    book, advice = advise()
    info = {"scene": "hand", "path": "Camera", "frames": [1, 4], "judged_frames": 4, "every": 1,
            "resolution": [96, 72], "budgets_ms": {1.0: 100.0}, "selections": ["PAPER"], "selection": "PAPER",
            "prospects": {"judged": ["Chrome"], "cap": 8, "left_out": 0}, "seconds": 8.0,
            "seconds_per_judged_frame": 2.0}
    written = files.write_advice(tmp_path, book, advice, info)
    with open(written["csv"], newline="") as handle:
        reader = csv.DictReader(handle)
        rows = list(reader)
    assert tuple(reader.fieldnames[:len(files.COLUMNS)]) == files.COLUMNS
    assert "oracle_share_1" in reader.fieldnames
    tagged = [row for row in rows if row["tagged"] == "1"]
    assert [float(row["benefit_per_ms"]) for row in tagged] == sorted(float(row["benefit_per_ms"]) for row in tagged)
    assert rows[-1]["element"] == "Chrome" and rows[-1]["recommendation"] == "tag"
    document = json.loads(written["json"].read_text())
    assert {item["item"] for item in document["items"]} == set(MEASURED)
    assert "Matte / reflections: untag" in written["md"].read_text()
    assert "<img src='benefit_per_ms.png'" in written["html"].read_text()
    assert written["chart"].stat().st_size > 1000 and written["strips"].stat().st_size > 1000
    tags = export.export_tags(files.advice_rows(book, advice, [1.0]), {
        "Mirror": {"candidate": True, "priority": 1.0, "reflections": True},
        "Matte": {"candidate": True, "priority": 1.0, "reflections": True}}, "hand", "Camera")
    by_name = {entry["element"]: entry for entry in tags["elements"]}
    assert by_name["Mirror"]["culling_priority"] == 0 and by_name["Mirror"]["visible_in_ray_tracing"]
    assert by_name["Matte"]["culling_priority"] == 8 and not by_name["Matte"]["visible_in_ray_tracing"]
    assert by_name["Chrome"]["visible_in_ray_tracing"]  # worth tagging
