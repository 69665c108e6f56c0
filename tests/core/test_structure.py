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
