"""Every GLSL function of engine/gpu/ is headed by the numpy function it mirrors
(``// numpy twin: <file> <name>``, or ``// numpy twin: none (why)``), and that function exists:
a reader goes from a shader to its reference, and a twin that is renamed or moved breaks here.
Plain ``ast`` and text: nothing of the engine is imported."""
import ast
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
GPU = ROOT / "engine" / "gpu"
FUNCTION = re.compile(r"^(?:void|float|int|uint|bool|vec[234]|ivec[234]|mat[34]|Surface)\s+(\w+)\s*\(")
TWIN = re.compile(r"^//\s*numpy twin:\s*(.*)$")


def glsl_sources(path: Path) -> list:
    """The string constants of a module's top-level assignments (GLSL and docstrings alike)."""
    tree = ast.parse(path.read_text())
    sources = []
    for node in tree.body:
        if isinstance(node, ast.Assign):
            sources += [n.value for n in ast.walk(node.value) if isinstance(n, ast.Constant) and isinstance(n.value, str)]
    return sources


def defines(path: Path, name: str) -> bool:
    """Whether the module at ``path`` defines ``name`` (a function or class, or Class.method)."""
    body = ast.parse(path.read_text()).body
    for part in name.split("."):
        found = [node for node in body if isinstance(node, (ast.FunctionDef, ast.ClassDef)) and node.name == part]
        if not found:
            return False
        body = found[0].body
    return True


def twin_problems(source: str, root: Path = ROOT) -> list:
    """(function, problem) of each GLSL function in ``source`` whose header names no twin, or a
    twin that does not exist."""
    problems = []
    twin = None
    for line in source.splitlines():
        stripped = line.strip()
        header = TWIN.match(stripped)
        if header:
            twin = header.group(1).strip()
            continue
        function = FUNCTION.match(stripped)
        if function is None:
            continue
        name, named, twin = function.group(1), twin, None
        if named is None:
            problems.append((name, "no '// numpy twin:' line above it"))
        elif named.startswith("none"):
            if not re.fullmatch(r"none \(.+\)", named):
                problems.append((name, "a function without a twin says why: 'none (...)'"))
        else:
            path, _, rest = named.partition(" ")
            twin_name = rest.split(" ")[0] if rest else ""
            if not (root / path).is_file():
                problems.append((name, f"{path} does not exist"))
            elif not twin_name or not defines(root / path, twin_name):
                problems.append((name, f"{path} defines no {twin_name or '(name missing)'}"))
    return problems


def test_every_glsl_function_of_the_gpu_frame_names_a_numpy_twin_that_exists():
    problems, functions = [], 0
    for path in sorted(GPU.glob("*.py")):
        for source in glsl_sources(path):
            functions += sum(1 for line in source.splitlines() if FUNCTION.match(line.strip()))
            problems += [(path.name, *problem) for problem in twin_problems(source)]
    assert functions >= 15  # the shaders' main()s and the shared library really were read
    assert problems == []


def test_a_function_without_a_twin_or_with_a_missing_one_is_found():
    source = """
// numpy twin: phrt_addon/scene/shading.py fresnel_schlick
vec3 fresnel(vec3 f0, float c) { return f0; }
float bare(float x) { return x; }
// numpy twin: phrt_addon/scene/shading.py no_such_function
float gone(float x) { return x; }
// numpy twin: phrt_addon/nowhere.py anything
void main() {
// numpy twin: none
float unexplained() { return 0.0; }
// numpy twin: phrt_addon/raster/reference_raster.py ReferenceRaster.shade (the sum)
vec3 method(int i) { return vec3(0.0); }
"""
    assert [name for name, _ in twin_problems(source)] == ["bare", "gone", "main", "unexplained"]
