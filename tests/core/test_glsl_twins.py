"""GLSL and numpy twins name each other.  Every GLSL function of engine/gpu/ is headed by the
numpy function it mirrors (``// numpy twin: <file> <name>``, or ``// numpy twin: none (why)``), and
that function exists; and that numpy function's docstring names the GLSL function back
(``GLSL twin: engine/gpu/<file> <function>``, the function qualified by its shader's constant,
``RESOLVE_FRAG.main``, where the name alone is not unique in the file), every such line naming a
GLSL function that names it.  A reader goes from a shader to its reference and back, and a twin
that is renamed or moved breaks here.  Plain ``ast`` and text: nothing of the engine is imported."""
import ast
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
GPU = ROOT / "engine" / "gpu"
FUNCTION = re.compile(r"^(?:void|float|int|uint|bool|vec[234]|ivec[234]|mat[34]|Surface)\s+(\w+)\s*\(")
TWIN = re.compile(r"^//\s*numpy twin:\s*(.*)$")
BACK = re.compile(r"^GLSL twin:\s*(\S+)\s+(\S+)")


def glsl_sources(path: Path) -> list:
    """The string constants of a module's top-level assignments (GLSL and docstrings alike)."""
    tree = ast.parse(path.read_text())
    sources = []
    for node in tree.body:
        if isinstance(node, ast.Assign):
            sources += [n.value for n in ast.walk(node.value) if isinstance(n, ast.Constant) and isinstance(n.value, str)]
    return sources


def definition(path: Path, name: str):
    """The ``ast`` node of ``name`` (a function or class, or Class.method) in the module at ``path``,
    or None."""
    body, node = ast.parse(path.read_text()).body, None
    for part in name.split("."):
        found = [node for node in body if isinstance(node, (ast.FunctionDef, ast.ClassDef)) and node.name == part]
        if not found:
            return None
        node = found[0]
        body = node.body
    return node


def defines(path: Path, name: str) -> bool:
    """Whether the module at ``path`` defines ``name`` (a function or class, or Class.method)."""
    return definition(path, name) is not None


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


# -- the numpy side names its GLSL twins back ---------------------------------------------------------

def glsl_functions(root: Path = ROOT) -> list:
    """(file, shader constant, function, numpy twin named in its header or None) of every GLSL
    function of ``root``/engine/gpu/."""
    found = []
    for path in sorted((root / "engine" / "gpu").glob("*.py")):
        for node in ast.parse(path.read_text()).body:
            if not isinstance(node, ast.Assign):
                continue
            constant = next((t.id for t in node.targets if isinstance(t, ast.Name)), "")
            for part in ast.walk(node.value):
                if not (isinstance(part, ast.Constant) and isinstance(part.value, str)):
                    continue
                twin = None
                for line in part.value.splitlines():
                    header = TWIN.match(line.strip())
                    if header:
                        twin = header.group(1).strip()
                        continue
                    function = FUNCTION.match(line.strip())
                    if function:
                        found.append((str(path.relative_to(root)), constant, function.group(1), twin))
                        twin = None
    return found


def named_twin(header):
    """(numpy file, name) a ``// numpy twin:`` header names, or None ('none (why)')."""
    if header is None or header.startswith("none"):
        return None
    path, _, rest = header.partition(" ")
    return path, rest.split(" ")[0]


def resolve(functions, gpu_file: str, reference: str) -> list:
    """The GLSL functions of ``gpu_file`` a ``GLSL twin:`` reference (``name`` or ``CONSTANT.name``) means."""
    constant, _, name = reference.rpartition(".")
    return [f for f in functions if f[0] == gpu_file and f[2] == name and (not constant or f[1] == constant)]


def numpy_back_references(root: Path = ROOT) -> list:
    """(numpy file, dotted name, GLSL file, reference) of every ``GLSL twin:`` line in a docstring
    of a function, class or method of ``root``/phrt_addon/."""
    found = []

    def visit(body, prefix, relative):
        for node in body:
            if isinstance(node, (ast.FunctionDef, ast.ClassDef)):
                name = prefix + node.name
                for line in (ast.get_docstring(node) or "").splitlines():
                    back = BACK.match(line.strip())
                    if back:
                        found.append((relative, name, back.group(1), back.group(2)))
                visit(node.body, name + ".", relative)

    for path in sorted((root / "phrt_addon").rglob("*.py")):
        visit(ast.parse(path.read_text()).body, "", str(path.relative_to(root)))
    return found


def back_reference_problems(root: Path = ROOT) -> list:
    """What breaks the pairing: a numpy twin whose docstring does not name the GLSL function that
    names it, and a ``GLSL twin:`` line that names no GLSL function, one ambiguously, or one whose
    header names another numpy function."""
    functions = glsl_functions(root)
    backs = numpy_back_references(root)
    problems = []
    for gpu_file, constant, name, header in functions:
        twin = named_twin(header)
        if twin is None or not (root / twin[0]).is_file() or definition(root / twin[0], twin[1]) is None:
            continue  # no twin, or a missing one (test above)
        if not any(back[:2] == twin and resolve(functions, back[2], back[3]) == [(gpu_file, constant, name, header)]
                   for back in backs):
            problems.append(f"{twin[0]} {twin[1]} does not name its GLSL twin back: "
                            f"'GLSL twin: {gpu_file} {name}' (or {constant}.{name})")
    for numpy_file, numpy_name, gpu_file, reference in backs:
        meant = resolve(functions, gpu_file, reference)
        if len(meant) != 1:
            problems.append(f"{numpy_file} {numpy_name}: 'GLSL twin: {gpu_file} {reference}' names "
                            f"{len(meant)} GLSL functions, not one")
        elif named_twin(meant[0][3]) != (numpy_file, numpy_name):
            problems.append(f"{numpy_file} {numpy_name}: {gpu_file} {reference} names another numpy twin "
                            f"({meant[0][3]})")
    return problems


def test_every_numpy_twin_names_its_glsl_twins_back():
    assert len(numpy_back_references()) >= 20  # the docstrings really were read
    assert back_reference_problems() == []


def test_a_numpy_twin_that_does_not_name_its_glsl_twin_back_is_found(tmp_path):
    (tmp_path / "engine" / "gpu").mkdir(parents=True)
    (tmp_path / "phrt_addon").mkdir()
    (tmp_path / "engine" / "gpu" / "pass.py").write_text(
        'VERT = """\n// numpy twin: phrt_addon/twin.py project\nvoid main() {\n}\n"""\n'
        'FRAG = """\n// numpy twin: phrt_addon/twin.py shade\nvec3 light(int i) { return vec3(0.0); }\n'
        '// numpy twin: phrt_addon/twin.py Table.row\nvoid main() {\n}\n"""\n')
    (tmp_path / "phrt_addon" / "twin.py").write_text(
        'def project():\n    """Named back, qualified.\n\n    GLSL twin: engine/gpu/pass.py VERT.main"""\n\n\n'
        'def shade():\n    """Not named back."""\n\n\n'
        'class Table:\n    def row(self):\n        """Ambiguous, and a stale name.\n\n'
        '        GLSL twin: engine/gpu/pass.py main\n        GLSL twin: engine/gpu/pass.py gone"""\n\n\n'
        'def other():\n    """GLSL twin: engine/gpu/pass.py light"""\n')
    problems = back_reference_problems(tmp_path)
    assert [problem.split(":")[0] for problem in problems] == [
        "phrt_addon/twin.py shade does not name its GLSL twin back",
        "phrt_addon/twin.py Table.row does not name its GLSL twin back",
        "phrt_addon/twin.py Table.row", "phrt_addon/twin.py Table.row", "phrt_addon/twin.py other"], problems
    assert "names 2 GLSL functions" in problems[2] and "names 0 GLSL functions" in problems[3]
    assert "names another numpy twin" in problems[4]
