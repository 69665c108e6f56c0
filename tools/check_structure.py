"""Structure checks of the whole project (issues 12 and 19), run by ``tests/core/test_structure.py``:

    python tools/check_structure.py            # prints the findings, exit 1 if any

- the import graph of the package (every ``import``/``from`` statement, at module level
  or inside functions, relative imports resolved) has no cycle;
- no cycle between the top-level packages either (``phrt_addon``, ``engine``, ``operators``,
  ``panels``, ``cli``, ``sample_scenes``, ``benchmarks`` and the root modules);
- no module of any package is longer than ``MAX_LINES``;
- ``phrt_addon/`` imports no ``bpy`` (nor ``gpu``/``mathutils``), also not through
  ``importlib.import_module("bpy")`` / ``__import__``;
- no module of the add-on assigns a mutable object (dict, list, set, call of a class...)
  to a module-level name outside ``engine/session.py``, except declared constants;
- no file of the project (tests and tools included) uses another module's underscore name:
  ``from .x import _name`` or ``x._name`` where ``x`` is a project module it imported;
- every file ``docs/DESIGN.md`` names exists: each ``path/like.py`` (or ``.md``) from the
  repository's root, each bare ``name.py`` of its map in that row's folder, any other bare
  ``name.py`` somewhere in the project.

Plain ``ast``: nothing is imported or run.
"""
from __future__ import annotations

import ast
import re
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
PACKAGE = "phrt"
SKIP_DIRS = {"tests", "tools", ".venv", "out", "dist", "build", "wheels"}
MAX_LINES = 400
BLENDER_MODULES = {"bpy", "gpu", "mathutils", "gpu_extras", "bmesh"}
# Module-level state the session does not own, on purpose (file: names).
ALLOWED_STATE = {
    "engine/session.py": {"_SESSION"},
    "__init__.py": {"_registered"},  # the add-on's own registration flag (register()/unregister() of Blender)
    "cli/sweep.py": {"_WARM"},  # issue 13's file: processes that rendered their warm-up frame
}


def modules(root: Path = ROOT):
    """{dotted module name: path} of the add-on's Python files."""
    found = {}
    for path in sorted(root.rglob("*.py")):
        relative = path.relative_to(root)
        if relative.parts[0] in SKIP_DIRS or any(part.startswith(".") for part in relative.parts):
            continue
        parts = list(relative.with_suffix("").parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
        found[".".join([PACKAGE] + parts)] = path
    return found


def _is_package(path: Path) -> bool:
    return path.name == "__init__.py"


def imports(name: str, path: Path, known) -> set:
    """The add-on modules ``name`` imports (anywhere in the file)."""
    tree = ast.parse(path.read_text(), str(path))
    package = name if _is_package(path) else name.rsplit(".", 1)[0]
    targets = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            candidates = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")
                base = base[:len(base) - (node.level - 1)]
                stem = ".".join(base + ([node.module] if node.module else []))
            else:
                stem = node.module or ""
            candidates = [f"{stem}.{alias.name}" if f"{stem}.{alias.name}" in known else stem
                          for alias in node.names]
        else:
            continue
        for candidate in candidates:
            # the longest known module the name is or lies in
            parts = candidate.split(".")
            while parts and ".".join(parts) not in known:
                parts.pop()
            target = ".".join(parts)
            # Importing a submodule runs its packages' __init__ first: an edge to one's own package
            # is how Python works, not a cycle of the design.
            if parts and target != name and not name.startswith(target + "."):
                targets.add(target)
    return targets


def cycles(graph) -> list:
    """Strongly connected components of more than one module (Tarjan)."""
    index, low, stack, on_stack, result = {}, {}, [], set(), []
    counter = [0]

    def visit(node):
        index[node] = low[node] = counter[0]
        counter[0] += 1
        stack.append(node)
        on_stack.add(node)
        for target in graph.get(node, ()):
            if target not in index:
                visit(target)
                low[node] = min(low[node], low[target])
            elif target in on_stack:
                low[node] = min(low[node], index[target])
        if low[node] == index[node]:
            component = []
            while True:
                member = stack.pop()
                on_stack.discard(member)
                component.append(member)
                if member == node:
                    break
            if len(component) > 1:
                result.append(sorted(component))

    sys.setrecursionlimit(10000)
    for node in sorted(graph):
        if node not in index:
            visit(node)
    return result


def import_graph(root: Path = ROOT):
    known = modules(root)
    return {name: imports(name, path, known) for name, path in known.items()}


# Modules still over the limit, each with the issue that removes it (empty when none).
OVERSIZED_UNTIL_SPLIT = {}


def oversized(root: Path = ROOT, limit: int = MAX_LINES, allowed=None):
    """(file, lines) of every module of every package of the project over ``limit`` lines."""
    allowed = OVERSIZED_UNTIL_SPLIT if allowed is None else allowed
    return sorted((relative, count) for path in modules(root).values()
                  if (relative := str(path.relative_to(root))) not in allowed
                  and (count := len(path.read_text().splitlines())) > limit)


def top_level(name: str) -> str:
    """The top-level package (or root module) a module belongs to: ``phrt.engine.runs.replay`` ->
    ``phrt.engine``; the extension's own ``__init__`` is ``phrt``."""
    parts = name.split(".")
    return ".".join(parts[:2])


def package_cycles(graph) -> list:
    """Cycles between top-level packages (imports inside functions count too)."""
    packages = {}
    for name, targets in graph.items():
        source = top_level(name)
        packages.setdefault(source, set()).update(
            top_level(t) for t in targets if top_level(t) != source and top_level(t) != "phrt")
    return cycles(packages)


def blender_imports_in_core(root: Path = ROOT):
    found = []
    for path in sorted((root / "phrt_addon").rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            names = [a.name for a in node.names] if isinstance(node, ast.Import) else \
                [node.module or ""] if isinstance(node, ast.ImportFrom) and not node.level else []
            if isinstance(node, ast.Call) and _call_name(node) in ("importlib.import_module", "import_module",
                                                                   "__import__") \
                    and node.args and isinstance(node.args[0], ast.Constant) and isinstance(node.args[0].value, str):
                names = [node.args[0].value]
            found += [(str(path.relative_to(root)), n) for n in names if n.split(".")[0] in BLENDER_MODULES]
    return found


_MUTABLE_CALL_EXCEPTIONS = {"frozenset", "tuple", "re.compile", "Path", "np.array", "np.zeros", "np.finfo",
                            "float", "int", "str", "dict", "logging.getLogger", "TypeVar", "max", "min",
                            "math.radians", "np.radians"}


def _call_name(node) -> str:
    func = node.func
    parts = []
    while isinstance(func, ast.Attribute):
        parts.append(func.attr)
        func = func.value
    if isinstance(func, ast.Name):
        parts.append(func.id)
    return ".".join(reversed(parts))


_MUTATORS = {"append", "add", "update", "clear", "pop", "popitem", "setdefault", "extend", "insert", "remove",
             "discard", "put", "__setitem__"}


def _mutated_names(tree) -> set:
    """Names whose object the module changes in place: ``NAME[k] = v``, ``NAME.append(...)``..."""
    names = set()
    for node in ast.walk(tree):
        if isinstance(node, (ast.Assign, ast.AugAssign)):
            targets = node.targets if isinstance(node, ast.Assign) else [node.target]
            for target in targets:
                if isinstance(target, ast.Subscript) and isinstance(target.value, ast.Name):
                    names.add(target.value.id)
        elif isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute) \
                and isinstance(node.func.value, ast.Name) and node.func.attr in _MUTATORS:
            names.add(node.func.value.id)
    return names


def module_state(root: Path = ROOT):
    """Module-level names bound to mutable objects: (file, name, line).  A name rebound by
    ``global`` or changed in place by its module, any name bound to an object made by a call (a cache, a queue, a resource owner),
    and a lower-case name bound to a container are state; containers spelled in capitals are
    constants (never changed, a convention the review keeps)."""
    found = []
    for name, path in modules(root).items():
        relative = str(path.relative_to(root))
        tree = ast.parse(path.read_text())
        allowed = ALLOWED_STATE.get(relative, set())
        rebound = {n for node in ast.walk(tree) if isinstance(node, ast.Global) for n in node.names}
        rebound |= _mutated_names(tree)
        for node in tree.body:
            targets = node.targets if isinstance(node, ast.Assign) else [node.target] \
                if isinstance(node, ast.AnnAssign) and node.value is not None else []
            value = getattr(node, "value", None)
            for target in targets:
                if not isinstance(target, ast.Name) or target.id in allowed or target.id == "__all__":
                    continue
                constant = target.id.lstrip("_").isupper()
                container = isinstance(value, (ast.List, ast.Set, ast.Dict, ast.ListComp, ast.SetComp,
                                               ast.DictComp))
                obj = isinstance(value, ast.Call) and _call_name(value) not in _MUTABLE_CALL_EXCEPTIONS
                if target.id in rebound or obj or (container and not constant):
                    found.append((relative, target.id, node.lineno))
    return found


def _is_private(name: str) -> bool:
    return name.startswith("_") and not name.startswith("__")


def private_names(root: Path = ROOT):
    """(file, line, what) of every use of another project module's underscore name, in every
    Python file under ``root`` (tests and tools too): ``from .x import _name``, ``x._name`` or
    ``phrt.x._name`` where the module was imported (a class's own ``_attributes`` through an
    instance or ``self`` are not module names and are not looked at)."""
    found = []
    skip = SKIP_DIRS - {"tests", "tools"}
    for path in sorted(root.rglob("*.py")):
        relative = path.relative_to(root)
        if relative.parts[0] in skip or any(part.startswith(".") for part in relative.parts):
            continue
        tree = ast.parse(path.read_text(), str(path))
        bound = set()  # names (and dotted prefixes) bound to project modules or their names
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom) and (node.level or (node.module or "").split(".")[0] == PACKAGE):
                for alias in node.names:
                    if _is_private(alias.name):
                        found.append((str(relative), node.lineno, f"from {'.' * node.level}{node.module or ''} "
                                                                  f"import {alias.name}"))
                    bound.add(alias.asname or alias.name)
            elif isinstance(node, ast.Import):
                for alias in node.names:
                    if alias.name.split(".")[0] == PACKAGE:
                        bound.add(alias.asname or alias.name)
        for node in ast.walk(tree):
            if isinstance(node, ast.Attribute) and _is_private(node.attr):
                owner = _dotted(node.value)
                if owner in bound:
                    found.append((str(relative), node.lineno, f"{owner}.{node.attr}"))
    return sorted(found)


def _dotted(node) -> str | None:
    parts = []
    while isinstance(node, ast.Attribute):
        parts.append(node.attr)
        node = node.value
    return ".".join([node.id] + list(reversed(parts))) if isinstance(node, ast.Name) else None


_PATH = re.compile(r"(?<![\w./])([A-Za-z_][\w.-]*(?:/[\w.-]+)+\.(?:py|md))(?![\w/])")
_BARE = re.compile(r"`([A-Za-z_][\w-]*\.py)`")
_FOLDER = re.compile(r"`([A-Za-z_][\w/-]*/)`")


def missing_design_paths(root: Path = ROOT, design: Path | None = None) -> list:
    """(line, name) of every file ``docs/DESIGN.md`` (or ``design``) names that does not exist."""
    design = root / "docs" / "DESIGN.md" if design is None else design
    everywhere = {path.name for path in root.rglob("*.py") if ".venv" not in path.parts}
    missing = []
    for number, line in enumerate(design.read_text(encoding="utf-8").splitlines(), start=1):
        missing += [(number, path) for path in _PATH.findall(line) if not (root / path).is_file()]
        bare = [name for name in _BARE.findall(line)]
        cells = line.split("|")
        if line.startswith("|") and len(cells) > 2:  # a row of the map: | folders | what lives there |
            folders = [root / folder for folder in _FOLDER.findall(cells[1])]
            if any(name in _BARE.findall(cells[1]) for name in bare):
                folders.append(root)  # a row of root modules (`properties.py`, ...)
            missing += [(number, name) for name in bare
                        if folders and not any((folder / name).is_file() for folder in folders)]
        else:
            missing += [(number, name) for name in bare if name not in everywhere]
    return missing


def main() -> int:
    graph = import_graph()
    problems = 0
    print(f"import graph: {len(graph)} modules, {sum(len(v) for v in graph.values())} edges")
    for component in cycles(graph):
        problems += 1
        print("import cycle:", " <-> ".join(component))
    for component in package_cycles(graph):
        problems += 1
        print("import cycle between packages:", " <-> ".join(component))
    for path, count in oversized():
        problems += 1
        print(f"over {MAX_LINES} lines: {path} ({count})")
    for path, name in blender_imports_in_core():
        problems += 1
        print(f"phrt_addon imports Blender: {path}: {name}")
    for path, name, line in module_state():
        problems += 1
        print(f"module-level state outside the session: {path}:{line} {name}")
    for path, line, what in private_names():
        problems += 1
        print(f"another module's underscore name: {path}:{line} {what}")
    for line, name in missing_design_paths():
        problems += 1
        print(f"docs/DESIGN.md:{line} names a file that does not exist: {name}")
    print("no problems" if not problems else f"{problems} problems")
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())
