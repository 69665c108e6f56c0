"""Pay only for what a scene uses: raster never touches Embree, no candidates means no
tracing, no lights means no shadow work."""
import subprocess
import sys
import textwrap

RASTER_SCRIPT = textwrap.dedent("""
    import sys
    import bpy
    import phrt
    phrt.register()
    from phrt.sample_scenes import showcase
    scene = showcase.build_showcase(96, 72)
    scene.phrt.mode = "RASTER"
    bpy.ops.render.render()
    bpy.ops.render.render()
    from phrt.engine import session
    stats = session.last_frame().stats
    assert stats["n_selected"] == 0 and stats["rays"] == 0, stats
    print("EMBREEX-IMPORTED" if "embreex" in sys.modules else "EMBREEX-NOT-IMPORTED")
""")


def test_raster_mode_never_imports_embree(tmp_path):
    script = tmp_path / "raster.py"
    script.write_text(RASTER_SCRIPT)
    run = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr[-2000:]
    assert "EMBREEX-NOT-IMPORTED" in run.stdout


def test_no_candidates_means_no_trace_work(blender):
    from phrt.engine import session
    from phrt.sample_scenes import showcase
    scene = showcase.build_showcase(96, 72)
    for obj in scene.objects:
        if hasattr(obj, "phrt"):
            obj.phrt.candidate = False
    scene.phrt.mode = "RAYTRACE"
    blender.ops.render.render()
    stats = session.last_frame().stats
    assert stats["n_candidates"] == 0
    assert stats["rays"] == 0 and stats["upload_ms"] == 0.0
    # Counted, not timed: no ray, no upload, and no Embree scene was ever built for this scene.
    from phrt.engine import session
    assert session.current().renderers.get(scene.name).trace_stage.trace_scene is None
    assert all(row["reason"] == "not_candidate" for row in session.last_frame().rows)


def test_no_lights_means_no_shadow_work(blender):
    from phrt.engine import session
    from phrt.sample_scenes import showcase
    scene = showcase.build_showcase(96, 72)
    for obj in [o for o in scene.objects if o.type == "LIGHT"]:
        blender.data.objects.remove(obj)
    scene.phrt.mode = "RAYTRACE"
    blender.ops.render.render()
    stats = session.last_frame().stats
    assert stats["n_selected"] > 0, "candidates are still traced (reflections, refractions)"
    assert stats["shadow_rays"] == 0
    assert stats["reflection_rays"] > 0
