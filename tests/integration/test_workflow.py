"""The designer's workflow inside Blender (issue 5), with real bpy, the real engine and
real files: tagging, the candidate list and panels, replaying a camera path (blocking
and step by step, cancelled), exporting the selection log, the viewport path and the
decision overlay.  Renders are 160x120 (~0.1 s a frame)."""
from __future__ import annotations

import csv
import json
import os
import tempfile
import types
from pathlib import Path

os.environ.setdefault("BLENDER_USER_RESOURCES", tempfile.mkdtemp(prefix="phrt-user-"))

import bpy  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402

import phrt  # noqa: E402
from phrt import compat  # noqa: E402
from phrt.engine import final, session, viewport  # noqa: E402
from phrt.engine.runs import camera_path, replay  # noqa: E402
from phrt.phrt_addon import schema
from phrt.phrt_addon.runs import run_files
from phrt.sample_scenes.showcase import build_showcase  # noqa: E402
from gpu_probe import run_on_gpu  # noqa: E402

WIDTH, HEIGHT = 160, 120
PATH_FRAMES = 30


@pytest.fixture(scope="module", autouse=True)
def addon():
    if not hasattr(bpy.types.Scene, "phrt"):
        phrt.register()
    yield


@pytest.fixture
def scene():
    """The showcase at 160x120 with its camera keyframed over frames 1-30."""
    scene = build_showcase(WIDTH, HEIGHT)
    animate_camera(scene.camera, PATH_FRAMES)
    session.last_frame().clear()
    return scene


def animate_camera(camera, frames):
    """Keyframe a short dolly: frame 1 where build_showcase put it, ``frames`` 1.5 m to the side."""
    start = camera.location.copy()
    camera.keyframe_insert("location", frame=1)
    camera.location = (start.x - 1.5, start.y - 0.5, start.z)
    camera.keyframe_insert("location", frame=frames)
    camera.location = start


def read_passes(path) -> dict:
    """{pass.channel: (h, w) array, top row first} of a multilayer EXR written by Blender."""
    import OpenEXR
    channels = {}
    with OpenEXR.File(str(path), separate_channels=True) as exr:
        for part in exr.parts:
            for name, channel in part.channels.items():
                channels[name.split(".", 1)[-1]] = np.asarray(channel.pixels)
    return channels


def render_passes(scene, path) -> dict:
    settings = scene.render.image_settings
    compat.set_image_format(settings, compat.MULTILAYER_EXR)
    settings.color_depth = "32"
    scene.render.filepath = str(path)
    bpy.ops.render.render(write_still=True)
    return read_passes(f"{path}.exr")


def rgb(channels):
    return np.stack([channels[f"Combined.{c}"] for c in "RGB"], axis=-1)


def row_of(element, rows=None):
    rows = session.last_frame().rows if rows is None else rows
    return next(row for row in rows if row["element"] == element)


# -- tagging ---------------------------------------------------------------------

def test_untagged_mirror_gets_no_ray_traced_reflection(scene, tmp_path):
    for name in ("GlassSlab", "Fence"):  # the mirror is the only candidate
        bpy.data.objects[name].phrt.candidate = False
    mirror = bpy.data.objects["MirrorSphere"]
    scene.phrt.mode = "RAYTRACE"

    tagged = render_passes(scene, tmp_path / "tagged")
    assert row_of("MirrorSphere")["selected"] and row_of("MirrorSphere")["reason"] == ""
    sphere = tagged["PHRT Candidate.X"] > 0.5
    assert sphere.sum() > 300  # the sphere covers ~3% of the frame
    assert np.array_equal(sphere, tagged["PHRT Selected.X"] > 0.5)

    mirror.phrt.candidate = False
    untagged = render_passes(scene, tmp_path / "untagged")
    assert not row_of("MirrorSphere")["selected"]
    assert row_of("MirrorSphere")["reason"] == "not_candidate"
    assert untagged["PHRT Candidate.X"].max() == 0.0
    assert np.abs(rgb(tagged) - rgb(untagged))[sphere].mean() > 0.05  # the traced reflection is gone

    # An untagged mirror in RAYTRACE looks exactly like the raster frame.
    mirror.phrt.candidate = True
    scene.phrt.mode = "RASTER"
    raster = render_passes(scene, tmp_path / "raster")
    assert np.abs(rgb(untagged) - rgb(raster)).max() < 1e-6


def test_copy_settings_to_selected_tags_several_objects(scene):
    active, cube, floor = (bpy.data.objects[name] for name in ("MirrorSphere", "RedCube", "Floor"))
    active.phrt.priority, active.phrt.rt_cost, active.phrt.shadows = 3.5, 2.0, False
    for obj in scene.objects:
        obj.select_set(obj in (active, cube, floor))
    bpy.context.view_layer.objects.active = active
    assert bpy.ops.phrt.copy_settings_to_selected() == {"FINISHED"}
    for obj in (cube, floor):
        assert obj.phrt.candidate and obj.phrt.priority == pytest.approx(3.5)
        assert obj.phrt.rt_cost == pytest.approx(2.0) and not obj.phrt.shadows and not obj.phrt.refractions
    assert not bpy.data.objects["GlassSlab"].phrt.priority == pytest.approx(3.5)  # not selected

    glass = bpy.data.materials["Glass"]
    glass.phrt.candidate, glass.phrt.priority = True, 4.0
    active.active_material = glass
    assert bpy.ops.phrt.copy_settings_to_selected(source="MATERIAL") == {"FINISHED"}
    assert bpy.data.materials["Red"].phrt.candidate and bpy.data.materials["Floor"].phrt.priority == 4.0
    assert not bpy.data.materials["Wood"].phrt.candidate  # the fence is not selected


def test_material_tag_makes_its_own_element_in_the_list(scene):
    bpy.data.materials["Red"].phrt.candidate = True
    bpy.ops.render.render()
    names = [item.name for item in bpy.context.window_manager.phrt_candidates]
    assert "RedCube/Red" in names and "RedCube" not in names  # all its faces are the material element
    assert row_of("RedCube/Red")["reason"] != "not_candidate"


# -- the candidate list and the panels ---------------------------------------------

def test_candidate_list_is_refreshed_after_a_render_and_selects_on_click(scene):
    window_manager = bpy.context.window_manager
    window_manager.phrt_candidates.clear()
    bpy.ops.render.render()  # render_post refreshes the list
    items = {item.name: item for item in window_manager.phrt_candidates}
    assert set(items) == {"Floor", "RedCube", "MirrorSphere", "GlassSlab", "Fence"}
    mirror = items["MirrorSphere"]
    row = row_of("MirrorSphere")
    assert mirror.candidate and mirror.rendered and mirror.selected
    assert mirror.relevance == pytest.approx(row["R"], rel=1e-5)
    assert mirror.visibility == pytest.approx(row["V"], rel=1e-5)
    assert mirror.priority == pytest.approx(2.0) and mirror.effects == "Shd Rfl"
    assert not items["Floor"].candidate and items["Floor"].reason == "not_candidate"

    window_manager.phrt_candidate_index = list(items).index("GlassSlab")
    assert bpy.context.view_layer.objects.active.name == "GlassSlab"
    assert [obj.name for obj in bpy.context.selected_objects] == ["GlassSlab"]

    bpy.data.objects["Fence"].phrt.priority = 7.0
    assert bpy.ops.phrt.refresh_candidates() == {"FINISHED"}
    assert window_manager.phrt_candidates["Fence"].priority == pytest.approx(7.0)
    assert window_manager.phrt_candidates[window_manager.phrt_candidate_index].name == "GlassSlab"


def test_tagging_an_object_updates_the_candidate_list_without_a_render(scene):
    window_manager = bpy.context.window_manager
    bpy.ops.phrt.refresh_candidates()
    assert not window_manager.phrt_candidates["RedCube"].candidate
    bpy.data.objects["RedCube"].phrt.candidate = True
    assert window_manager.phrt_candidates["RedCube"].candidate
    bpy.data.objects["RedCube"].phrt.candidate = False
    assert not window_manager.phrt_candidates["RedCube"].candidate


def test_candidate_list_sorts_by_relevance_and_hides_non_candidates(scene):
    from phrt.panels import candidates
    from phrt.engine import candidate_list
    bpy.ops.render.render()
    window_manager = bpy.context.window_manager
    items = window_manager.phrt_candidates
    ui_list = types.SimpleNamespace(filter_name="", bitflag_filter_item=1 << 30, sort_by_relevance=True,
                                    show_non_candidates=False)
    flags, order = candidates.PHRT_UL_candidates.filter_items(ui_list, bpy.context, window_manager, "phrt_candidates")
    shown = sorted((order[i], items[i].name) for i in range(len(items)) if flags[i])
    assert [name for _, name in shown] == ["MirrorSphere", "Fence", "GlassSlab"]  # R 2.0, 0.48, 0.47
    ui_list.show_non_candidates = True
    flags, order = candidates.PHRT_UL_candidates.filter_items(ui_list, bpy.context, window_manager, "phrt_candidates")
    assert all(flags) and sorted(order) == list(range(len(items)))
    assert items[order.index(0)].name == "Floor"  # R 12.9: big but not a candidate

    assert candidates.relevance_order([0.5, None, 2.0, 0.5]) == [1, 3, 0, 2]


ICONS = set(bpy.types.UILayout.bl_rna.functions["prop"].parameters["icon"].enum_items.keys())


def check_call(function, kwargs):
    """The keyword arguments a panel passes to a UILayout function exist, and so do its icons."""
    parameters = bpy.types.UILayout.bl_rna.functions[function].parameters
    unknown = [key for key in kwargs if key not in parameters]
    assert not unknown, f"UILayout.{function}() has no {unknown}"
    assert kwargs.get("icon", "NONE") in ICONS, f"no icon {kwargs['icon']!r}"


class FakeLayout:
    """Records what a panel draws and checks every property, operator, icon and argument it names."""

    def __init__(self, log):
        object.__setattr__(self, "log", log)

    def __setattr__(self, name, value):
        assert name in bpy.types.UILayout.bl_rna.properties, f"UILayout has no attribute {name!r}"
        object.__setattr__(self, name, value)

    def _child(function):
        def child(self, **kwargs):
            check_call(function, kwargs)
            return FakeLayout(self.log)
        return child

    row, column, box, grid_flow = _child("row"), _child("column"), _child("box"), _child("grid_flow")

    def label(self, **kwargs):
        check_call("label", kwargs)
        self.log.append(("label", kwargs.get("text", "")))

    def prop(self, data, name, **kwargs):
        check_call("prop", kwargs)
        assert name in data.bl_rna.properties, f"{type(data).__name__} has no property {name!r}"
        self.log.append(("prop", name))

    def operator(self, idname, **kwargs):
        check_call("operator", kwargs)
        module, name = idname.split(".")
        rna = getattr(getattr(bpy.ops, module), name).get_rna_type()
        self.log.append(("operator", idname))
        properties = FakeOperatorProperties(rna)
        self.log.append(("operator properties", idname, properties.values))
        return properties

    def template_list(self, list_type, list_id, data, propname, active_data, active_propname, **kwargs):
        check_call("template_list", kwargs)
        assert hasattr(bpy.types, list_type), list_type
        assert propname in data.bl_rna.properties and active_propname in active_data.bl_rna.properties
        self.log.append(("list", list_type))


class FakeOperatorProperties:
    """What ``layout.operator()`` returns: records the properties a panel sets, which must exist."""

    def __init__(self, rna):
        object.__setattr__(self, "rna", rna)
        object.__setattr__(self, "values", {})

    def __setattr__(self, name, value):
        assert name in self.rna.properties, f"{self.rna.identifier} has no property {name!r}"
        self.values[name] = value


def panel_context(scene, engine="PHRT"):
    return types.SimpleNamespace(
        engine=engine, scene=scene, object=bpy.context.view_layer.objects.active,
        selected_objects=bpy.context.selected_objects, window_manager=bpy.context.window_manager)


def draw_panel(panel, context):
    log = []
    fake = types.SimpleNamespace(layout=FakeLayout(log))
    if hasattr(panel, "draw_header"):
        panel.draw_header(fake, context)
    panel.draw(fake, context)
    return log


def test_panels_register_poll_on_the_engine_and_draw(scene):
    from phrt.panels import view3d
    mirror = bpy.data.objects["MirrorSphere"]
    bpy.context.view_layer.objects.active = mirror
    mirror.select_set(True)
    session.last_frame().problems = ["Object 'Broken' skipped: no geometry"]
    for panel in view3d.PANELS:
        assert hasattr(bpy.types, panel.__name__), f"{panel.__name__} is not registered"
        assert panel.bl_category == "PHRT" and panel.bl_space_type == "VIEW_3D" and panel.bl_region_type == "UI"
        assert panel.poll(panel_context(scene, "PHRT"))
        assert not panel.poll(panel_context(scene, "CYCLES"))
        assert not panel.poll(panel_context(scene, "BLENDER_EEVEE"))

    bpy.ops.render.render()
    bpy.context.window_manager.phrt_candidate_index = 0
    bpy.context.window_manager.phrt_overlay = True
    context = panel_context(scene)
    logs = {panel.__name__: draw_panel(panel, context) for panel in view3d.PANELS}
    props = lambda name: [item[1] for item in logs[name] if item[0] == "prop"]  # noqa: E731
    assert {"candidate", "priority", "rt_cost", "shadows", "reflections",
            "refractions"} <= set(props("PHRT_PT_element"))
    assert ("operator", "phrt.copy_settings_to_selected") in logs["PHRT_PT_element"]
    from phrt.panels import render
    assert render.PHRT_PT_render.bl_context == "render" and hasattr(bpy.types, "PHRT_PT_render")
    assert render.PHRT_PT_render.poll(panel_context(scene, "PHRT"))
    assert not render.PHRT_PT_render.poll(panel_context(scene, "CYCLES"))
    render_log = draw_panel(render.PHRT_PT_render, context)
    assert {"mode", "budget_ms", "selection_weight", "max_area_fraction", "max_bounces",
            "cost_mode"} <= {item[1] for item in render_log if item[0] == "prop"}
    assert ("label", render.frame_rate_text(scene.phrt.budget_ms)) in render_log
    assert ("list", "PHRT_UL_candidates") in logs["PHRT_PT_candidates"]
    assert ("operator", "phrt.replay_path") in logs["PHRT_PT_replay"]
    assert ("operator", "phrt.export_selection_log") in logs["PHRT_PT_replay"]
    assert ("label", "Frames 1-30") in logs["PHRT_PT_replay"]
    assert ("label", "Object 'Broken' skipped: no geometry") not in logs["PHRT_PT_last_render"]  # a new frame
    assert ("label", "No problems") in logs["PHRT_PT_last_render"]

    session.last_frame().problems = ["Object 'Broken' skipped: no geometry"]
    assert ("label", "Object 'Broken' skipped: no geometry") in draw_panel(view3d.PHRT_PT_last_render, context)

    from phrt.panels import candidates
    from phrt.engine import candidate_list
    log = []
    item = bpy.context.window_manager.phrt_candidates["MirrorSphere"]
    candidates.PHRT_UL_candidates.draw_item(None, context, FakeLayout(log), None, item, 0, None, "", 0)
    assert ("label", "MirrorSphere") in log and ("label", "K 2") in log
    mirror.phrt.priority = 5.0  # the list shows the settings as they are now
    candidates.PHRT_UL_candidates.draw_item(None, context, FakeLayout(log), None, item, 0, None, "", 0)
    assert ("label", "K 5") in log


def test_replay_panel_button_runs_the_replay_it_shows(scene, tmp_path):
    from phrt.panels import view3d
    settings = scene.phrt_replay
    settings.camera = bpy.data.objects["Camera"]
    settings.use_path_range = False
    settings.frame_start, settings.frame_end = 2, 3
    settings.modes = {"RASTER", "HYBRID"}
    settings.images = "NONE"
    settings.output_dir = str(tmp_path)
    log = draw_panel(view3d.PHRT_PT_replay, panel_context(scene))
    arguments = next(entry[2] for entry in log if entry[:2] == ("operator properties", "phrt.replay_path"))
    assert bpy.ops.phrt.replay_path(**arguments) == {"FINISHED"}
    for mode in ("RASTER", "HYBRID"):
        check_run(replay.default_run_dir(tmp_path, scene.name, "Camera", mode), [2, 3], mode, images="none")


def test_renders_finished_on_another_thread_refresh_the_list_on_the_main_thread(scene):
    import threading
    from phrt.panels import candidates
    from phrt.engine import candidate_list
    bpy.ops.render.render()
    window_manager = bpy.context.window_manager
    window_manager.phrt_candidates.clear()
    thread = threading.Thread(target=candidate_list.refresh_after_render, args=(scene,))
    thread.start()
    thread.join()
    assert len(window_manager.phrt_candidates) == 0  # nothing touched off the main thread
    assert candidate_list.drain_pending() > 0  # the timer keeps running
    assert len(window_manager.phrt_candidates) == 5


def test_frame_rate_beside_the_budget():
    from phrt.panels import render
    assert render.frame_rate_text(16.6667) == "60 fps"
    assert render.frame_rate_text(150.0) == "6.67 fps"
    assert render.frame_rate_text(0.0) == "no budget"


def test_operators_and_panels_unregister_cleanly(scene):
    from phrt import operators, panels
    from phrt.engine import candidate_list
    assert candidate_list.refresh_after_render in bpy.app.handlers.render_post
    panels.unregister()
    operators.unregister()
    try:
        assert candidate_list.refresh_after_render not in bpy.app.handlers.render_post
        assert hasattr(bpy.types.WindowManager, "phrt_candidates")  # a property: properties.py owns it
        assert not hasattr(bpy.types, "PHRT_PT_element")
        assert not hasattr(bpy.types, "PHRT_OT_replay_path")
        bpy.ops.render.render()  # the engine still renders without its UI
    finally:
        operators.register()
        panels.register()
    assert candidate_list.refresh_after_render in bpy.app.handlers.render_post
    assert bpy.app.handlers.render_post.count(candidate_list.refresh_after_render) == 1


# -- replaying a camera path -------------------------------------------------------

def check_run(run_dir, frames, mode, images="exr"):
    """The files of a finished run agree with each other and with CONTRACT section 4."""
    run_dir = Path(run_dir)
    with open(run_dir / schema.FRAMES_CSV, newline="") as handle:
        header = next(csv.reader(handle))
    assert set(schema.FRAME_COLUMNS) <= set(header)
    assert header[:len(schema.FRAME_COLUMNS)] == list(schema.FRAME_COLUMNS)
    with open(run_dir / schema.SELECTION_CSV, newline="") as handle:
        assert next(csv.reader(handle))[:len(schema.SELECTION_COLUMNS)] == list(schema.SELECTION_COLUMNS)
    frame_rows = run_files.read_frames(run_dir)
    selection = run_files.read_selection(run_dir)
    assert [row["frame"] for row in frame_rows] == list(frames)
    assert {row["mode"] for row in frame_rows} == {mode}
    for row in frame_rows:
        rows = [s for s in selection if s["frame"] == row["frame"]]
        assert len({s["element"] for s in rows}) == len(rows) == 5
        assert row["n_selected"] == sum(bool(s["selected"]) for s in rows)
        assert row["n_candidates"] == sum(s["reason"] != "not_candidate" for s in rows)
        assert row["n_visible"] == sum(bool(s["visible"]) for s in rows)
        assert row["lighting_ms"] == row["composite_ms"]  # docs/formats.md: the column's first name
        for s in rows:
            assert (s["reason"] == "") == bool(s["selected"])
            assert s["reason"] in ("",) + schema.REASONS
    summary = run_files.read_summary(run_dir)
    assert summary["frame_count"] == len(frames) and summary["mode"] == mode
    assert summary["resolution"] == [WIDTH, HEIGHT]
    suffix = {"exr": ".exr", "png": ".png", "none": None}[images]
    written = sorted((run_dir / schema.FRAMES_DIR).iterdir())
    if suffix is None:
        assert written == []
    else:
        assert [path.name for path in written] == [f"{frame:04d}{suffix}" for frame in frames]
    return frame_rows, selection, summary


def test_replay_of_thirty_frames_from_a_saved_blend(scene, tmp_path):
    """What ``blender -b scene.blend --python-expr "...replay_path(...)"`` does (docs/batch.md)."""
    blend = tmp_path / "showcase.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(blend))
    bpy.ops.wm.open_mainfile(filepath=str(blend))
    filepath = bpy.context.scene.render.filepath
    assert bpy.ops.phrt.replay_path(modes={"HYBRID"}, output_dir="//runs") == {"FINISHED"}
    run_dir = replay.default_run_dir(tmp_path / "runs", "showcase", "Camera", "HYBRID")
    frame_rows, selection, summary = check_run(run_dir, range(1, PATH_FRAMES + 1), "HYBRID")
    assert summary["scene"] == "showcase" and summary["path"] == "Camera" and not summary["cancelled"]
    assert summary["partial"] is False and summary["frames_planned"] == PATH_FRAMES
    assert summary["frame_range"] == [1, PATH_FRAMES]
    channels = read_passes(run_dir / "frames" / "0030.exr")
    assert {"Combined.R", "Depth.Z", "Normal.X", "PHRT Selected.X", "PHRT Candidate.X"} <= set(channels)
    # The frame rendered and the one logged agree: selected pixels only where elements were selected.
    assert (channels["PHRT Selected.X"] > 0.5).any() == (frame_rows[-1]["n_selected"] > 0)
    scene = bpy.context.scene
    assert scene.frame_current == 1 and scene.render.filepath == filepath  # the scene is restored
    assert bpy.context.window_manager.phrt_candidates  # refreshed after the replay


def test_replay_in_several_modes_writes_one_run_per_mode(scene, tmp_path):
    result = bpy.ops.phrt.replay_path(frame_start=3, frame_end=4, modes={"RASTER", "RAYTRACE"},
                                      output_dir=str(tmp_path), images="NONE")
    assert result == {"FINISHED"}
    assert sorted(path.name for path in tmp_path.iterdir()) == [f"{scene.name}-Camera-raster",
                                                                 f"{scene.name}-Camera-raytrace"]
    _, raster_rows, _ = check_run(tmp_path / f"{scene.name}-Camera-raster", [3, 4], "RASTER", images="none")
    _, traced_rows, _ = check_run(tmp_path / f"{scene.name}-Camera-raytrace", [3, 4], "RAYTRACE", images="none")
    assert not any(row["selected"] for row in raster_rows)
    assert {row["element"] for row in traced_rows if row["selected"]} == {"MirrorSphere", "GlassSlab", "Fence"}


@pytest.mark.parametrize("arguments, message", [
    ({"path": "NoSuchCamera"}, "no camera path 'NoSuchCamera'"),
    ({"frame_start": 9, "frame_end": 3}, "ends before it starts"),
    ({"modes": set()}, "no mode chosen"),
])
def test_replay_operator_rejects_bad_input_and_writes_nothing(scene, tmp_path, arguments, message):
    with pytest.raises(RuntimeError, match=message):
        bpy.ops.phrt.replay_path(output_dir=str(tmp_path / "out"), **arguments)
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("arguments, message", [
    ({"mode": "pathtrace"}, "unknown mode 'pathtrace'"),
    ({"images": "tiff"}, "unknown image format 'tiff'"),
    ({"budget_ms": -1.0}, "budget -1 ms is not >= 0"),
    ({"budget_ms": float("nan")}, "budget nan ms is not >= 0"),
    ({"budget_at": 1.5}, "--budget-at 1.5 is outside 0..1"),
    ({"frame_range": (9, 3)}, "frame range 9-3 ends before it starts"),
])
def test_a_replay_refuses_bad_arguments_as_the_command_does_and_writes_nothing(scene, tmp_path, arguments, message):
    """replay.check_input is the one check of a replay's arguments: the Python entry point refuses
    them with the messages ``phrt render`` prints."""
    given = {"mode": "RASTER", "frame_range": (1, 2), **arguments}
    with pytest.raises(camera_path.ReplayError, match=message):
        replay.replay(scene, scene.camera, given.pop("frame_range"), given.pop("mode"), tmp_path / "out", **given)
    assert not (tmp_path / "out").exists()


def test_replay_operator_rejects_an_output_folder_under_a_file(scene, tmp_path):
    blocker = tmp_path / "somefile"
    blocker.write_text("")
    with pytest.raises(RuntimeError, match="is a file, not a folder"):
        bpy.ops.phrt.replay_path(output_dir=str(blocker / "x"))


def test_replay_operator_on_a_scene_without_camera(tmp_path):
    build_showcase(WIDTH, HEIGHT)
    bpy.data.objects.remove(bpy.data.objects["Camera"])
    with pytest.raises(RuntimeError, match="has no camera"):
        bpy.ops.phrt.replay_path(output_dir=str(tmp_path / "out"))
    assert not (tmp_path / "out").exists()


def test_cancelled_replay_keeps_complete_frames_and_logs(scene, tmp_path):
    done = []
    result = replay.replay(scene, scene.camera, (1, PATH_FRAMES), "HYBRID", tmp_path / "run",
                           on_progress=lambda count, total, ms: done.append(count),
                           should_stop=lambda: len(done) >= 4)
    assert result.cancelled and result.frames_done == 4
    check_run(tmp_path / "run", [1, 2, 3, 4], "HYBRID")
    assert run_files.read_summary(tmp_path / "run")["cancelled"] is True
    assert run_files.read_summary(tmp_path / "run")["partial"] is True
    assert len(run_files.read_selection(tmp_path / "run")) == 4 * 5


def test_stepped_replay_cancelled_by_esc_keeps_what_was_rendered(scene, tmp_path):
    """The modal operator's path: one frame per timer tick, Esc -> finish(cancelled=True)."""
    filepath = scene.render.filepath
    run = replay.ReplayRun(scene, scene.camera, (1, PATH_FRAMES), "HYBRID", tmp_path / "run", scene_label="showcase")
    for _ in range(3):
        run.step()
    assert run.remaining == PATH_FRAMES - 3
    assert final.active_replay() is run.state  # between ticks the replay's state stays active
    result = run.finish(cancelled=True)
    assert result.cancelled and result.frames_done == 3 and final.active_replay() is None
    _, _, summary = check_run(tmp_path / "run", [1, 2, 3], "HYBRID")
    assert summary["cancelled"] is True and summary["partial"] is True and summary["scene"] == "showcase"
    assert scene.frame_current == 1 and scene.render.filepath == filepath


def test_stepped_replay_stopped_during_a_render_drops_that_frame(scene, tmp_path, monkeypatch):
    """Esc while a frame renders: the engine returns without a result (test_break); the
    frame's rows are dropped, the frames before it stay complete.  (Without images: an
    engine that writes no result and write_still=True crashes Blender 5.0.1 in background.)"""
    run = replay.ReplayRun(scene, scene.camera, (1, PATH_FRAMES), "RASTER", tmp_path / "run", images="none")
    run.step()
    run.step()
    monkeypatch.setattr(final.FinalRender, "render", lambda self, depsgraph: None)
    with pytest.raises(replay.ReplayInterrupted):
        run.step()
    assert run.done == 2
    run.finish(cancelled=True)
    _, _, summary = check_run(tmp_path / "run", [1, 2], "RASTER", images="none")
    assert summary["cancelled"] is True


def test_stepped_replay_closed_by_blender_leaves_the_scene_alone(scene, tmp_path):
    run = replay.ReplayRun(scene, scene.camera, (1, PATH_FRAMES), "RASTER", tmp_path / "run", images="none")
    run.step()
    run.finish(cancelled=True, restore_scene=False)
    assert scene.render.engine == "PHRT" and scene.frame_current == 1  # as the replay left it
    assert run_files.read_summary(tmp_path / "run")["frame_count"] == 1


def test_stepped_replay_writes_what_replay_writes(scene, tmp_path):
    replay.replay(scene, scene.camera, (5, 7), "RAYTRACE", tmp_path / "blocking", images="none")
    run = replay.ReplayRun(scene, scene.camera, (5, 7), "RAYTRACE", tmp_path / "stepped", images="none")
    while run.remaining:
        run.step()
    run.finish()
    for name in (schema.FRAMES_CSV, schema.SELECTION_CSV):
        with open(tmp_path / "blocking" / name) as a, open(tmp_path / "stepped" / name) as b:
            assert a.readline() == b.readline()  # same columns
    decisions = lambda run_dir: [(r["frame"], r["element"], r["visible"], r["selected"], r["reason"])  # noqa: E731
                                 for r in run_files.read_selection(run_dir)]
    assert decisions(tmp_path / "blocking") == decisions(tmp_path / "stepped")
    blocking, stepped = (run_files.read_summary(tmp_path / d) for d in ("blocking", "stepped"))
    timing_free = {"total_ms", "all_frames_total_ms", "first_frame_ms", "p95_over_budget", "stage_mean_ms",
                   "predicted_trace_mean_ms", "machine", "mean_rays"}
    assert {k: v for k, v in blocking.items() if k not in timing_free} == \
           {k: v for k, v in stepped.items() if k not in timing_free}


# -- the selection log ---------------------------------------------------------------

def test_export_selection_log_round_trips_csv_and_json(scene, tmp_path):
    with pytest.raises(RuntimeError, match="render a frame with PHRT first"):
        bpy.ops.phrt.export_selection_log(filepath=str(tmp_path / "empty.csv"))
    bpy.ops.render.render()
    rows = session.last_frame().rows
    assert bpy.ops.phrt.export_selection_log(filepath=str(tmp_path / "log.csv")) == {"FINISHED"}
    assert bpy.ops.phrt.export_selection_log(filepath=str(tmp_path / "log.JSON")) == {"FINISHED"}

    with open(tmp_path / "log.csv", newline="") as handle:
        reader = csv.DictReader(handle)
        assert reader.fieldnames[:len(schema.SELECTION_COLUMNS)] == list(schema.SELECTION_COLUMNS)
        from_csv = list(reader)
    from_json = json.loads((tmp_path / "log.JSON").read_text())
    assert len(from_csv) == len(from_json) == len(rows) == 5
    for row, csv_row, json_row in zip(rows, from_csv, from_json):
        assert csv_row["element"] == json_row["element"] == row["element"]
        assert csv_row["reason"] == json_row["reason"] == row["reason"]
        assert json_row["selected"] is bool(row["selected"]) and csv_row["selected"] == str(int(row["selected"]))
        for column in ("A", "P", "D", "V", "Q", "C", "K", "S", "R"):
            assert float(csv_row[column]) == pytest.approx(row[column], rel=1e-5)
            assert json_row[column] == pytest.approx(row[column], rel=1e-12)


def test_export_selection_log_of_a_run_folder(scene, tmp_path):
    replay.replay(scene, scene.camera, (1, 3), "RAYTRACE", tmp_path / "run", images="none")
    bpy.ops.phrt.export_selection_log(filepath=str(tmp_path / "run.json"), run_dir=str(tmp_path / "run"))
    exported = json.loads((tmp_path / "run.json").read_text())
    assert [(r["frame"], r["element"]) for r in exported] == \
           [(r["frame"], r["element"]) for r in run_files.read_selection(tmp_path / "run")]
    with pytest.raises(RuntimeError, match="is not a run folder"):
        bpy.ops.phrt.export_selection_log(filepath=str(tmp_path / "x.csv"), run_dir=str(tmp_path))


@pytest.mark.parametrize("name", ["log.txt", "log", "log.csv.gz"])
def test_export_selection_log_rejects_other_extensions(scene, tmp_path, name):
    bpy.ops.render.render()
    with pytest.raises(RuntimeError, match=r"must end in \.csv or \.json"):
        bpy.ops.phrt.export_selection_log(filepath=str(tmp_path / name))
    assert list(tmp_path.iterdir()) == []


# -- the viewport ---------------------------------------------------------------------

def test_overlay_colors_follow_the_last_decisions():
    rows = [
        {"element": "Mirror", "selected": 1, "reason": ""},
        {"element": "Glass/Glass", "selected": 0, "reason": "over_budget"},
        {"element": "Wall", "selected": 0, "reason": "over_area"},
        {"element": "Lamp@Set:3", "selected": 0, "reason": "not_visible"},
        {"element": "Floor", "selected": 0, "reason": "not_candidate"},
        {"element": "Puddle", "selected": 1, "reason": "", "rate": 0.25},  # quality tiers: a quarter
        {"element": "Chrome", "selected": 1, "reason": "", "rate": 1.0},
    ]
    colors = viewport.overlay_colors(rows)
    assert colors == {"Mirror": viewport.OVERLAY_PALETTE["selected"],
                      "Puddle": viewport.OVERLAY_PALETTE["reduced_rate"],
                      "Chrome": viewport.OVERLAY_PALETTE["selected"],
                      "Glass/Glass": viewport.OVERLAY_PALETTE["over_budget"],
                      "Wall": viewport.OVERLAY_PALETTE["over_area"],
                      "Lamp@Set:3": viewport.OVERLAY_PALETTE["not_visible"]}
    assert len(set(viewport.OVERLAY_PALETTE.values())) == len(viewport.OVERLAY_PALETTE)
    assert {key for key, _, _ in viewport.OVERLAY_LEGEND} == set(viewport.OVERLAY_PALETTE)
    assert viewport.overlay_colors([]) == {}


def test_overlay_boxes_surround_the_candidates_of_the_last_frame(scene):
    bpy.data.materials["Red"].phrt.candidate = True
    bpy.ops.render.render()
    colors = viewport.overlay_colors(session.last_frame().rows)
    assert set(colors) == {"MirrorSphere", "GlassSlab", "Fence", "RedCube/Red"}
    boxes = viewport.overlay_boxes(bpy.context.evaluated_depsgraph_get(), colors)
    assert len(boxes) == 4
    mirror = next(corners for color, corners in boxes
                  if color == colors["MirrorSphere"] and np.allclose(corners.mean(axis=0), (0.2, 0.4, 0.7)))
    assert np.allclose(mirror.min(axis=0), (0.2 - 0.7, 0.4 - 0.7, 0.0), atol=1e-3)
    cube = [corners for color, corners in boxes if np.allclose(corners.mean(axis=0), (-1.6, 1.2, 0.5))]
    assert len(cube) == 1 and np.allclose(cube[0].max(axis=0) - cube[0].min(axis=0), 1.04, atol=1e-4)


def test_viewport_size_keeps_the_region_aspect_within_the_pixel_cap():
    assert viewport.preview_size(320, 240) == (320, 240)
    width, height = viewport.preview_size(1920, 1080)
    assert width * height <= viewport.VIEWPORT_MAX_PIXELS and abs(width / height - 16 / 9) < 0.01
    assert viewport.preview_size(0, 0) == (1, 1)


def scene_camera_view(depsgraph, width, height):
    """The scene camera's view and projection matrices, as a RegionView3D would give them."""
    camera = depsgraph.scene_eval.camera.evaluated_get(depsgraph)
    projection = camera.calc_matrix_camera(depsgraph, x=width, y=height)
    return camera.matrix_world.inverted(), projection


def test_viewport_path_renders_what_the_final_render_renders(scene, tmp_path):
    from phrt.phrt_addon.frame import FrameRenderer
    scene.phrt.mode = "RAYTRACE"
    final_render = render_passes(scene, tmp_path / "final")

    def job(engine, depsgraph):
        view, projection = scene_camera_view(depsgraph, WIDTH, HEIGHT)
        camera = viewport.view_camera(np.array(view), np.array(projection), WIDTH, HEIGHT)
        renderer = FrameRenderer()
        try:
            return viewport.render_view(depsgraph, camera, renderer)
        finally:
            renderer.close()

    result = run_on_gpu(scene, job)
    assert result.stats["n_selected"] == 3
    combined = result.passes.combined[::-1, :, :3]  # bottom row first -> top row first
    assert combined.shape == (HEIGHT, WIDTH, 3)
    assert np.abs(combined - rgb(final_render)).mean() < 1e-3
    assert np.abs(rgb(final_render)).mean() > 0.1  # not two black images


def test_view_draw_draws_the_frame_over_the_region_and_renders_again_only_on_change(scene, tmp_path):
    """ViewportRender.draw() as view_draw calls it, with a fake region drawing into an offscreen."""
    import gpu
    from mathutils import Matrix
    final_render = render_passes(scene, tmp_path / "final")

    def job(engine, depsgraph):
        view, projection = scene_camera_view(depsgraph, WIDTH, HEIGHT)
        context = types.SimpleNamespace(
            region=types.SimpleNamespace(width=WIDTH, height=HEIGHT),
            region_data=types.SimpleNamespace(view_matrix=view, window_matrix=projection, is_perspective=True),
            space_data=types.SimpleNamespace(clip_start=0.05, clip_end=100.0))
        view_render = viewport.ViewportRender()
        offscreen = gpu.types.GPUOffScreen(WIDTH, HEIGHT, format="RGBA16F")
        textures = []
        try:
            with offscreen.bind():
                framebuffer = gpu.state.active_framebuffer_get()
                framebuffer.clear(color=(0.0, 0.0, 0.0, 0.0))
                with gpu.matrix.push_pop(), gpu.matrix.push_pop_projection():
                    gpu.matrix.load_matrix(Matrix.Identity(4))
                    gpu.matrix.load_projection_matrix(Matrix.Identity(4))
                    gpu.matrix.translate((-1.0, -1.0))
                    gpu.matrix.scale((2.0 / WIDTH, 2.0 / HEIGHT))  # region pixels, as in view_draw
                    for update in (False, False, True):
                        if update:
                            view_render.update(depsgraph)
                        view_render.draw(engine, context, depsgraph)
                        textures.append((view_render.image_frame, session.current().resources.frames_drawn))
                buffer = gpu.types.Buffer("FLOAT", WIDTH * HEIGHT * 4)
                framebuffer.read_color(0, 0, WIDTH, HEIGHT, 4, 0, "FLOAT", data=buffer)
                drawn = np.asarray(buffer).reshape(HEIGHT, WIDTH, 4).copy()
        finally:
            offscreen.free()
        return drawn, textures

    drawn, textures = run_on_gpu(scene, job)
    assert textures[0][0] is not None
    assert textures[0] == textures[1]  # nothing changed: the same GPU image is drawn again, no render
    assert textures[2][1] == textures[1][1] + 1  # view_update: rendered again
    image = drawn[::-1, :, :3]
    assert np.abs(image - rgb(final_render)).mean() < 0.01  # half-float target of the same frame


def test_a_budget_given_as_an_override_holds_for_the_whole_replay(scene, tmp_path):
    """overrides={'budget_ms': ...} is a fixed budget like budget_ms=..., not replaced by the
    scene's (possibly animated) budget read at every frame."""
    scene.phrt.budget_ms = 5000.0
    camera = scene.camera
    result = replay.replay(scene, camera, (1, 3), "HYBRID", tmp_path / "run", images="none",
                           overrides={"budget_ms": 7.0})
    budgets = {row["budget_ms"] for row in run_files.read_frames(result.run_dir)}
    assert budgets == {7.0}
