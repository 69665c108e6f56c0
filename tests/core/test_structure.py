"""The structure rules of docs/DESIGN.md, checked by tools/check_structure.py (plain ``ast``)."""
import importlib.util
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
spec = importlib.util.spec_from_file_location("check_structure", ROOT / "tools" / "check_structure.py")
check = importlib.util.module_from_spec(spec)
spec.loader.exec_module(check)

def test_the_import_graph_has_no_cycle():
    assert check.cycles(check.import_graph()) == []


def test_the_cycle_finder_finds_a_cycle():
    assert check.cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]


def test_the_core_never_imports_blender():
    assert check.blender_imports_in_core() == []


def test_no_module_level_state_outside_the_engine_session():
    assert check.module_state() == []


def test_the_state_finder_finds_caches_and_globals(tmp_path):
    (tmp_path / "engine").mkdir()
    (tmp_path / "engine" / "cache.py").write_text(
        "CACHE = {}\nHANDLE = None\nLIMITS = {'a': 1}\nOWNER = Owner()\n\n"
        "def put(k, v):\n    CACHE[k] = v\n\ndef set_handle(h):\n    global HANDLE\n    HANDLE = h\n")
    assert [name for _, name, _ in check.module_state(tmp_path)] == ["CACHE", "HANDLE", "OWNER"]


def test_the_whole_project_is_checked_and_has_no_problems():
    # every package of the project is in the graph: core, engine, operators, panels, cli, scenes
    tops = {check.top_level(name) for name in check.import_graph()}
    assert {"phrt.phrt_addon", "phrt.engine", "phrt.operators", "phrt.panels", "phrt.cli",
            "phrt.sample_scenes"} <= tops
    assert check.oversized() == []
    assert check.package_cycles(check.import_graph()) == []
    assert check.private_names() == []


def test_the_private_name_rule_finds_another_modules_underscore_names_in_tests_and_tools_too(tmp_path):
    for folder in ("engine", "tools"):
        (tmp_path / folder).mkdir()
    (tmp_path / "engine" / "own.py").write_text(
        "import numpy as np\n\nclass Thing:\n    def go(self):\n        return self._state, np._NoValue\n")
    (tmp_path / "engine" / "user.py").write_text(
        "from . import own\nfrom .own import _helper\n\ndef run():\n    return own._helper(), own.Thing().go()\n")
    (tmp_path / "tools" / "script.py").write_text(
        "import phrt.engine.own\nfrom phrt.engine import own as o\n\n"
        "phrt.engine.own._cache, o._cache, o.__name__\n")
    assert check.private_names(tmp_path) == [
        ("engine/user.py", 2, "from .own import _helper"), ("engine/user.py", 5, "own._helper"),
        ("tools/script.py", 4, "o._cache"), ("tools/script.py", 4, "phrt.engine.own._cache")]


def test_the_size_rule_finds_a_long_module_in_any_package(tmp_path):
    (tmp_path / "cli").mkdir()
    (tmp_path / "cli" / "long.py").write_text("x = 1\n" * 401)
    (tmp_path / "panels").mkdir()
    (tmp_path / "panels" / "short.py").write_text("x = 1\n" * 400)
    assert check.oversized(tmp_path, allowed={}) == [("cli/long.py", 401)]


def test_the_package_rule_finds_a_cycle_through_a_function_level_import(tmp_path):
    for package in ("engine", "cli"):
        (tmp_path / package).mkdir()
        (tmp_path / package / "__init__.py").write_text("")
    (tmp_path / "engine" / "sweep.py").write_text("def run():\n    from ..cli import blender\n")
    (tmp_path / "cli" / "blender.py").write_text("from ..engine import sweep\n")
    graph = check.import_graph(tmp_path)
    assert check.package_cycles(graph) == [["phrt.cli", "phrt.engine"]]
    # the modules themselves form a cycle too
    assert check.cycles(graph) == [["phrt.cli.blender", "phrt.engine.sweep"]]


def test_the_core_rule_finds_bpy_imported_through_importlib(tmp_path):
    (tmp_path / "phrt_addon").mkdir()
    (tmp_path / "phrt_addon" / "sneaky.py").write_text(
        "import importlib\n\ndef blender():\n    return importlib.import_module('bpy')\n")
    (tmp_path / "phrt_addon" / "plain.py").write_text("import gpu\n")
    assert sorted(check.blender_imports_in_core(tmp_path)) == [("phrt_addon/plain.py", "gpu"),
                                                             ("phrt_addon/sneaky.py", "bpy")]


def test_every_file_docs_design_names_exists():
    assert check.missing_design_paths() == []


def test_the_design_path_rule_finds_a_file_that_is_gone(tmp_path):
    for folder in ("engine/gpu", "docs"):
        (tmp_path / folder).mkdir(parents=True)
    for name in ("engine/gpu/frame.py", "engine/extract.py", "props.py"):
        (tmp_path / name).write_text("")
    design = tmp_path / "docs" / "DESIGN.md"
    design.write_text(
        "| folder | what |\n|---|---|\n"
        "| `engine/gpu/` | the frame (`frame.py`), the lighting (`lighting.py`) |\n"
        "| `props.py`, `engine/` | properties (`props.py`), extraction (`extract.py`), gone (`gone.py`) |\n"
        "\n    depsgraph --engine/extract.py--> snapshot (engine/snapshot.py), docs/formats.md\n"
        "A bare name in prose (`frame.py`) exists somewhere, this one (`nowhere.py`) nowhere;\n"
        "URL-like words are no paths: https://example.org/a.html, engine/gpu/frame.pyc.\n")
    assert check.missing_design_paths(tmp_path, design) == [
        (3, "lighting.py"), (4, "gone.py"), (6, "engine/snapshot.py"), (6, "docs/formats.md"), (7, "nowhere.py")]
