"""The oracle and the error-aware relevance on real renders (bpy, Embree, EXR).

A hand-built scene: a mirror cube facing a bright red wall behind the camera (raster shows
the dark environment in it: a large error) and, at the same size and distance on the other
side of the view, a matte cube (tracing changes nothing) - or a second mirror facing only the
dark environment, whose material prior equals the first mirror's.  The budget is given as a
fraction (Budget At 0.75 of tracing both), so exactly one of the two fits whatever the
machine's speed.  Then a replayed camera path: the oracle is never worse than the heuristic,
and has nothing to regret when the budget covers every candidate."""
import os
import tempfile

os.environ.setdefault("BLENDER_USER_RESOURCES", tempfile.mkdtemp(prefix="phrt-test-user-"))

import numpy as np  # noqa: E402
import pytest  # noqa: E402

bpy = pytest.importorskip("bpy")

from phrt.engine import final, session  # noqa: E402
from phrt.engine.runs import replay  # noqa: E402
from phrt.engine.runs import oracle as oracle_engine  # noqa: E402
from phrt.phrt_addon.report import metrics, oracle  # noqa: E402
from phrt.phrt_addon.runs import run_files
from phrt.sample_scenes import showcase as build  # noqa: E402

# A regret below 0 beyond this is the oracle doing worse than the heuristic (benefits of
# several elements only roughly add up, and LDR-FLIP has noise of this order).
REGRET_TOLERANCE = 0.002


# Registered once (conftest's ``blender``); every test starts with nothing cached.
pytestmark = pytest.mark.usefixtures("fresh_caches")


def mirror_scene(second="matte", relevance="PAPER"):
    scene = build.empty_scene(160, 120)
    build.mesh_object("Floor", build.plane(40.0), build.principled("Floor", color=(0.5, 0.5, 0.5), roughness=0.9))
    # The red wall stands behind the camera, on the left half only: the left cube's reflection sees it.
    build.mesh_object("RedWall", build.plane(8.0), build.principled("Red", color=(1, 0, 0), roughness=0.9,
                                                                    emission=((1.0, 0.0, 0.0), 3.0)),
                      location=(-4.0, -3.0, 4.0), rotation=(np.radians(90), 0, 0))
    mirror_material = build.principled("MirrorMat", color=(0.9, 0.9, 0.9), metallic=1.0, roughness=0.0)
    mirror = build.mesh_object("Mirror", build.cube(1.0), mirror_material, location=(-1.2, 5.0, 1.0))
    if second == "matte":
        other = build.mesh_object("Matte", build.cube(1.0), build.principled("MatteMat", color=(0.9, 0.9, 0.9),
                                                                            roughness=0.9), location=(1.2, 5.0, 1.0))
    else:
        other = build.mesh_object("DarkMirror", build.cube(1.0), mirror_material, location=(1.2, 5.0, 1.0))
    for obj in (mirror, other):
        build.tag(obj, shadows=False, reflections=True, refractions=False)
    build.add_camera((0.0, 0.0, 1.0), (0.0, 5.0, 1.0), lens=35.0)
    scene.phrt.mode = "HYBRID"
    scene.phrt.use_budget_at = True
    scene.phrt.budget_at = 0.75
    scene.phrt.relevance = relevance
    return scene, other.name


def render_frames(count):
    """Render the scene ``count`` times (one standalone FrameRenderer carries S and the estimates)."""
    frames = []
    for _ in range(count):
        bpy.ops.render.render()
        frames.append({row["element"]: row for row in session.last_frame().rows})
    return frames


def test_the_papers_relevance_is_indifferent_between_mirror_and_matte():
    _, other = mirror_scene("matte", "PAPER")
    first = render_frames(1)[0]
    mirror, matte = first["Mirror"], first[other]
    assert mirror["visible"] and matte["visible"]
    assert mirror["V"] == pytest.approx(matte["V"], rel=0.02)  # same size, distance and centre offset
    assert mirror["R"] == pytest.approx(matte["R"], rel=0.02)
    assert mirror["selected"] + matte["selected"] == 1  # one of two fits: which is a tie-break
    assert "benefit" not in mirror


@pytest.mark.parametrize("second", ["matte", "dark mirror"])
def test_error_relevance_traces_the_mirror_after_its_first_traced_frames(second):
    _, other = mirror_scene(second, "ERROR")
    frames = render_frames(6)
    chosen = [("Mirror" if f["Mirror"]["selected"] else other if f[other]["selected"] else None) for f in frames]
    # The budget fits one of the two.  On a loaded machine a frame's measured raster time can leave
    # time for neither (a timing event, not a choice): such frames are left out of the verdict.
    assert all(f["Mirror"]["selected"] + f[other]["selected"] <= 1 for f in frames), chosen
    judged = [f for f, name in zip(frames[2:], chosen[2:]) if name is not None]
    assert len(judged) >= 2, chosen
    for frame in judged:
        assert frame["Mirror"]["selected"], chosen
        assert frame["Mirror"]["benefit"] == pytest.approx(1.0) and frame[other]["benefit"] < 0.2
    estimates = session.current().renderers.get(bpy.context.scene.name).benefit_model.estimates
    assert estimates["Mirror"] > 0.2  # measured: the red wall in the mirror, per pixel
    if second == "dark mirror":
        # The dark mirror must have been traced (a tie at equal priors gives it a frame) and seen to
        # change little; never traced, the test fails instead of skipping the check.
        assert other in estimates, f"the dark mirror was never traced: {[f[other]['selected'] for f in frames]}"
        assert estimates[other] < 0.05


def test_oracle_traces_the_mirror_when_only_one_fits():
    scene, other = mirror_scene("matte")
    reference, costs, flips = None, {}, {}
    with oracle_engine.ForcedRenderer(scene, scene.camera) as renderer:
        renderer.render(1, ("Mirror", other))  # warm-up: shaders, Embree
        reference, _, _ = renderer.render(1, ("Mirror", other))
        raster, _, _ = renderer.render(1, ())
        for name in ("Mirror", other):
            image, stats, _ = renderer.render(1, (name,))
            costs[name] = stats["trace_ms"] - stats["upload_ms"]
            flips[name] = metrics.flip(reference, image)
    flip_raster = metrics.flip(reference, raster)
    assert flip_raster > 0.01 and flips[other] == pytest.approx(flip_raster, abs=1e-4)
    names = ["Mirror", other]
    candidates = oracle.FrameCandidates(frame=1, names=names, cost_ms=np.array([costs[n] for n in names]),
                                        benefit=flip_raster - np.array([flips[n] for n in names]),
                                        flip_raster=flip_raster)
    assert all(cost > 0 for cost in costs.values())
    assert candidates.choose(max(costs.values())) == {"Mirror"}
    assert candidates.choose(sum(costs.values())) == {"Mirror", other}


# -- the oracle against a replayed path ------------------------------------------------------------

@pytest.fixture(scope="module")
def replayed(tmp_path_factory):
    """Showcase path (4 frames, 96x72): raytrace, hybrid at 0.3 of the way, hybrid with all the time."""
    final.release_caches()
    scene = build.build_showcase(96, 72)
    camera = scene.camera
    camera.keyframe_insert("location", frame=1)
    camera.location.x -= 1.0
    camera.keyframe_insert("location", frame=4)
    root = tmp_path_factory.mktemp("oracle")
    runs = {}
    for mode, name, extra in (("RASTER", "raster", {}), ("RAYTRACE", "raytrace", {}),
                              ("HYBRID", "tight", {"budget_at": 0.3}),
                              ("HYBRID", "ample", {"budget_ms": 1e6})):
        result = replay.replay(scene, camera, (1, 4), mode, root / name, images="exr", scene_label="showcase",
                               **extra)
        runs[name] = result.run_dir
    info = oracle_engine.run_oracle(scene, camera, runs["raytrace"], {"tight": runs["tight"], "ample": runs["ample"]},
                                    root / "oracle", raster_dir=runs["raster"], every=2)
    return scene, camera, runs, info, oracle.read_results(root / "oracle")


def test_a_budget_at_resolves_from_the_runs_beside_it(replayed):
    _, _, runs, _, _ = replayed
    summary = run_files.read_summary(runs["tight"])
    source = summary["budget_source"]
    assert source["method"] == "runs" and summary["budget_at"] == 0.3
    assert summary["budget_ms"] == pytest.approx(source["raster_ms"] + 0.3 * (source["raytrace_ms"] - source["raster_ms"]),
                                                 rel=1e-4)
    for row in run_files.read_frames(runs["tight"]):
        assert row["budget_ms"] == pytest.approx(summary["budget_ms"], rel=1e-4)


def test_one_oracle_per_budget_fills_the_budgets_nominal_time_for_tracing(replayed):
    _, _, runs, info, results = replayed
    assert info["frames"] == [2, 4]
    rows = results.regret_rows
    assert {row["run"] for row in rows} == {"tight", "ample"} and len(rows) == 4
    shared = {row["frame"]: row["raster_ms"] + row["select_ms"] + row["composite_ms"]
              for row in run_files.read_frames(runs["raster"])}
    for row in rows:
        budget = run_files.read_summary(runs[row["run"]])["budget_ms"]
        assert row["shared_ms"] == pytest.approx(shared[row["frame"]], rel=1e-5)
        assert row["capacity_ms"] == pytest.approx(max(budget - shared[row["frame"]], 0.0), rel=1e-5)
        assert row["oracle_cost_ms"] <= row["capacity_ms"] + 1e-6
        assert row["raster_flip"] > row["oracle_flip"] - REGRET_TOLERANCE
    assert len(results.candidate_rows) > 0
    assert all(float(row["cost_ms"]) >= 0 for row in results.candidate_rows)


def test_the_ample_budgets_regret_is_measured_from_both_images(replayed):
    _, _, runs, _, results = replayed
    reference = runs["raytrace"]
    for row in results.rows_of("ample"):
        assert set(row["oracle"]) == set(row["heuristic"]), row
        run_flip = metrics.flip(metrics.read_image(run_files.frame_image_path(reference, row["frame"])),
                                metrics.read_image(run_files.frame_image_path(runs["ample"], row["frame"])))
        assert row["heuristic_flip"] == pytest.approx(run_flip, rel=1e-4)
        # the oracle's own render of the same subset: traced (its trace time measured), its error measured
        assert row["oracle_trace_ms"] > 0
        assert row["regret"] == pytest.approx(row["heuristic_flip"] - row["oracle_flip"], abs=1e-9)
        assert abs(row["regret"]) <= REGRET_TOLERANCE


def test_forcing_the_heuristics_own_choice_renders_its_image_exactly(replayed):
    scene, camera, runs, _, _ = replayed
    chosen = {row["element"] for row in run_files.read_selection(runs["tight"]) if row["frame"] == 3 and row["selected"]}
    with oracle_engine.ForcedRenderer(scene, camera, (96, 72)) as renderer:
        image, _, _ = renderer.render(3, chosen)
    run_image = metrics.read_image(run_files.frame_image_path(runs["tight"], 3))
    np.testing.assert_array_equal(image, run_image)
