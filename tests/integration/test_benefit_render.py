"""The BENEFIT selection on real renders (bpy, the GPU frame, Embree): the mirror facing the red
wall against a matte cube of the same size (test_relevance_oracle's scene), the budget a
fraction that fits one of the two.  BENEFIT picks the mirror from the first frame (its
material prior) and keeps it; the rows carry each element's predicted ms, its benefit and the
effects traced; a glass ball's refraction is bought without its shadow."""
import os
import tempfile

os.environ.setdefault("BLENDER_USER_RESOURCES", tempfile.mkdtemp(prefix="phrt-test-user-"))

import pytest  # noqa: E402

bpy = pytest.importorskip("bpy")

from phrt.engine import session  # noqa: E402
from phrt.sample_scenes import showcase as build  # noqa: E402

from test_relevance_oracle import mirror_scene, render_frames  # noqa: E402

pytestmark = pytest.mark.usefixtures("fresh_caches")


def test_benefit_traces_the_mirror_from_the_first_frame_and_keeps_it():
    scene, other = mirror_scene("matte")
    scene.phrt.selection = "BENEFIT"
    # An ample budget: what is bought is then a matter of value alone (a budget that fits one of
    # the two is in the core tests: here the trace stage's fixed parts, about ten times one
    # mirror's per-ray cost, leave a window narrower than a loaded machine's noise).
    scene.phrt.use_budget_at = False
    scene.phrt.budget_ms = 1e6
    frames = render_frames(6)
    chosen = [("Mirror" if f["Mirror"]["selected"] else "") + (other if f[other]["selected"] else "") for f in frames]
    assert all(f["Mirror"]["selected"] for f in frames), chosen
    for f in frames:
        assert f["Mirror"]["benefit"] > 5 * f[other]["benefit"], (f["Mirror"]["benefit"], f[other]["benefit"])
        assert f["Mirror"]["predicted_ms"] > 0
        assert f["Mirror"]["effects"] == ("reflections" if f["Mirror"]["selected"] else "")
    renderer = session.current().renderers.get(bpy.context.scene.name)
    assert renderer.benefit_selector.estimates[("Mirror", "reflections")] > 0.1  # measured: the red wall


def test_a_glass_balls_refraction_is_bought_without_its_shadow_over_nothing():
    """A glass ball tagged for refraction and shadows, in front of a bright backdrop, the sun
    straight down onto nothing: its refraction is traced, its shadow (no receiver) is not."""
    scene = build.empty_scene(128, 96)
    build.mesh_object("Backdrop", build.plane(12.0), build.principled("Back", color=(0.1, 0.8, 0.1), roughness=0.9,
                                                                       emission=((0.1, 1.0, 0.1), 2.0)),
                      location=(0.0, 8.0, 1.2), rotation=(1.5708, 0, 0))
    glass = build.mesh_object("Glass", build.sphere(1.0), build.principled("GlassMat", color=(1, 1, 1), roughness=0.0,
                                                                          transmission=1.0, ior=1.5),
                              location=(0.0, 4.0, 1.2))
    build.tag(glass, shadows=True, reflections=False, refractions=True)
    build.add_light("SUN", (0.0, 4.0, 10.0), 3.0)
    build.add_camera((0.0, -1.0, 1.2), (0.0, 4.0, 1.2), lens=35.0)
    scene.phrt.mode = "HYBRID"
    scene.phrt.selection = "BENEFIT"
    scene.phrt.budget_ms = 1e6
    frames = render_frames(2)
    row = frames[-1]["Glass"]
    assert row["selected"] and row["effects"] == "refractions", row
    stats = session.last_frame().stats
    assert stats["refraction_rays"] > 0 and stats["shadow_rays"] == 0, stats
    # The paper's selection buys the element whole: its shadow region is traced too (and is empty).
    scene.phrt.selection = "PAPER"
    paper = render_frames(1)[0]["Glass"]
    assert paper["selected"] and "effects" not in paper
