"""Dependencies point one way: factr2_teleop -> policies -> calibration -> hardware (docs/architecture.md),
and inside hardware/ its subpackages and modules import each other without a cycle."""

from __future__ import annotations

import ast
import functools
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
LAYERS = ["hardware", "calibration", "policies", "factr2_teleop"]  # lower layers first


@functools.cache
def _tree(path: Path) -> ast.Module:
    """A file's syntax tree, parsed once per test session: every check below only reads it (parsing the
    whole tree once per check was most of this file's time)."""
    return ast.parse(path.read_text(), filename=str(path))


def _imports(path: Path) -> set[str]:
    tree = _tree(path)
    found = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found |= {a.name.split(".")[0] for a in node.names}
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            found.add(node.module.split(".")[0])
    return found


@pytest.mark.parametrize("layer", LAYERS)
def test_no_upward_imports(layer):
    above = set(LAYERS[LAYERS.index(layer) + 1:])
    bad = []
    for f in sorted((REPO / layer).rglob("*.py")):
        up = _imports(f) & above
        if up:
            bad.append(f"{f.relative_to(REPO)} imports {sorted(up)}")
    assert not bad, "upward imports:\n" + "\n".join(bad)


# Imports inside hardware/ that may point back up for now: (file, the hardware part it imports).
HARDWARE_CYCLE_ALLOWED: set[tuple[str, str]] = set()  # (file, part) imports exempt from the cycle check: none


def _is_type_checking(node: ast.AST) -> bool:
    t = node.test if isinstance(node, ast.If) else None
    return (isinstance(t, ast.Name) and t.id == "TYPE_CHECKING") or (
        isinstance(t, ast.Attribute) and t.attr == "TYPE_CHECKING")


def _hardware_imports(path: Path) -> set[str]:
    """The hardware parts (subpackage or top-level module: hardware.X) a file imports anywhere in it,
    function bodies included, `if TYPE_CHECKING:` blocks excluded (annotations only, never run)."""
    found: set[str] = set()

    def visit(node: ast.AST) -> None:
        if _is_type_checking(node):
            return
        names = []
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names = [node.module] + ([f"{node.module}.{a.name}" for a in node.names]
                                     if node.module == "hardware" else [])
        for n in names:
            parts = n.split(".")
            if parts[0] == "hardware" and len(parts) > 1:
                found.add(parts[1])
        for child in ast.iter_child_nodes(node):
            visit(child)

    visit(_tree(path))
    return found


def hardware_import_graph() -> dict[str, set[str]]:
    """hardware part -> the other hardware parts it imports."""
    root = REPO / "hardware"
    graph: dict[str, set[str]] = {}
    for f in sorted(root.rglob("*.py")):
        rel = f.relative_to(root)
        part = rel.parts[0].removesuffix(".py") if len(rel.parts) == 1 else rel.parts[0]
        if part == "__init__":
            continue
        deps = {d for d in _hardware_imports(f)
                if d != part and (str(f.relative_to(REPO)), d) not in HARDWARE_CYCLE_ALLOWED}
        graph.setdefault(part, set()).update(deps)
    return graph


def find_cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """One cycle through each strongly connected group of more than one node (Tarjan)."""
    index, low, stack, on, groups, counter = {}, {}, [], set(), [], [0]

    def strong(v: str) -> None:
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in sorted(graph.get(v, ())):
            if w not in index:
                strong(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            group = []
            while True:
                w = stack.pop()
                on.discard(w)
                group.append(w)
                if w == v:
                    break
            if len(group) > 1:
                groups.append(sorted(group))

    for v in sorted(graph):
        if v not in index:
            strong(v)
    return groups


def test_find_cycles_finds_one():
    assert find_cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert find_cycles({"a": {"b"}, "b": set()}) == []


def test_hardware_has_no_import_cycle():
    graph = hardware_import_graph()
    assert {"rigs", "sim", "registry", "connect"} <= set(graph)
    cycles = find_cycles(graph)
    detail = [" <-> ".join(c) + ": " + "; ".join(f"{a} imports {sorted(graph[a] & set(c))}" for a in c)
              for c in cycles]
    assert not cycles, "import cycles inside hardware/:\n" + "\n".join(detail)


# -- inside the application: session / tasks / teleop / demo / tui / commands ----------------------------
# Lowest first; a part imports only parts on a lower level (parts on one level do not import each other).
# The package root (__init__.py: the version) is below everything; cli.py is the top (docs/architecture.md).
APP_LEVELS: list[tuple[str, ...]] = [("__init__",), ("teleop",), ("session",), ("tasks", "demo"), ("tui",),
                                     ("commands",), ("cli",)]


def _app_part(module: str) -> str:
    """factr2_teleop.X.Y -> X; factr2_teleop.cli -> cli; factr2_teleop -> __init__."""
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else "__init__"


def app_import_edges() -> dict[tuple[str, str], list[str]]:
    """(part, part it imports) -> the module imports behind it, inside factr2_teleop/ (function bodies
    included, `if TYPE_CHECKING:` excluded)."""
    edges: dict[tuple[str, str], list[str]] = {}
    for mod, deps in module_import_graph().items():
        if mod.split(".")[0] != "factr2_teleop":
            continue
        for dep in deps:
            if dep.split(".")[0] == "factr2_teleop" and _app_part(dep) != _app_part(mod):
                edges.setdefault((_app_part(mod), _app_part(dep)), []).append(f"{mod} imports {dep}")
    return edges


def test_app_parts_import_downwards_only():
    level = {p: i for i, ps in enumerate(APP_LEVELS) for p in ps}
    found = {_app_part(m) for m in module_import_graph() if m.split(".")[0] == "factr2_teleop"}
    assert found == set(level), f"parts of factr2_teleop/ without a level in APP_LEVELS: {found ^ set(level)}"
    bad = [f"{a} -> {b}: " + "; ".join(why) for (a, b), why in sorted(app_import_edges().items())
           if level[b] >= level[a]]
    assert not bad, "imports that do not point down the app's levels (APP_LEVELS):\n" + "\n".join(bad)


# -- the whole tree's module graph: no circles --------------------------------------------------------------
def _module_name(path: Path) -> str:
    rel = path.relative_to(REPO).with_suffix("")
    return ".".join(rel.parts[:-1] if rel.name == "__init__" else rel.parts)


def _resolve(name: str, modules: set[str]) -> str | None:
    """The module a dotted import name runs: itself, else its closest parent that is a module here."""
    while name and name not in modules:
        name = name.rpartition(".")[0]
    return name or None


def _module_imports(path: Path, modules: set[str]) -> set[str]:
    """The tree's modules a file imports anywhere in it (function bodies included, `if TYPE_CHECKING:`
    excluded). `from a.b import c` is an import of a.b.c when that is a module, else of a.b."""
    me = _module_name(path)
    package = me if path.name == "__init__.py" else me.rpartition(".")[0]
    found: set[str] = set()

    def visit(node: ast.AST) -> None:
        if _is_type_checking(node):
            return
        if isinstance(node, ast.Import):
            found.update(m for m in (_resolve(a.name, modules) for a in node.names) if m)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")[: len(package.split(".")) - node.level + 1]
                src = ".".join(base + ([node.module] if node.module else []))
            else:
                src = node.module or ""
            for a in node.names:
                m = f"{src}.{a.name}" if f"{src}.{a.name}" in modules else _resolve(src, modules)
                if m:
                    found.add(m)
        for child in ast.iter_child_nodes(node):
            visit(child)

    visit(_tree(path))
    found.discard(me)
    return found


@functools.cache
def module_import_graph() -> dict[str, set[str]]:
    """Every module of hardware/, calibration/, policies/ and factr2_teleop/ -> the tree's modules it imports.
    Importing a.b.c also runs a/__init__.py; that implicit edge is not counted (a package's __init__ that
    re-exports its modules would otherwise close a circle with each of them), an explicit `from a import x`
    of a name defined in a/__init__.py is. Built once per test session; the tests only read it."""
    files = [f for layer in LAYERS for f in sorted((REPO / layer).rglob("*.py"))]
    modules = {_module_name(f) for f in files}
    return {_module_name(f): _module_imports(f, modules) for f in files}


def cycle_through(graph: dict[str, set[str]], group: list[str]) -> list[str]:
    """One circle inside a strongly connected group, as a path that starts and ends at group[0]."""
    start, inside = group[0], set(group)
    came_from: dict[str, str] = {}
    frontier = [start]
    while frontier:  # breadth first: the shortest circle back to start
        nxt = []
        for v in frontier:
            for w in sorted(graph[v] & inside):
                if w == start:
                    path = [v]
                    while path[-1] != start:
                        path.append(came_from[path[-1]])
                    return [start] + path[::-1][1:] + [start] if v != start else [start, start]
                if w not in came_from:
                    came_from[w] = v
                    nxt.append(w)
        frontier = nxt
    raise ValueError(f"{group} is not strongly connected")


def test_cycle_through_prints_the_circle():
    g = {"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}
    assert cycle_through(g, find_cycles(g)[0]) == ["a", "b", "c", "a"]
    two = {"x": {"y"}, "y": {"x"}}
    assert find_cycles(two) == [["x", "y"]] and cycle_through(two, ["x", "y"]) == ["x", "y", "x"]


def test_module_graph_resolves_imports():
    graph = module_import_graph()
    assert len(graph) > 200
    # an import inside a function counts, and `from package import module` is an import of the module
    assert "calibration.leader_gravity" in graph["factr2_teleop.teleop.leader_law"]
    assert "hardware.sim.actuators" in graph["hardware.sim.world"]
    # `if TYPE_CHECKING:` imports (annotations only) do not
    assert "hardware.sim.motors" not in graph["hardware.dynamixel.emulator"]


def test_whole_tree_has_no_import_circle():
    graph = module_import_graph()
    circles = [" -> ".join(cycle_through(graph, g)) for g in find_cycles(graph)]
    assert not circles, ("import circles (strongly connected modules, one circle shown for each):\n"
                         + "\n".join(circles))


# -- process-wide switches: FACTR2_* environment variables are read in one place ---------------------------
SWITCHES_FILE = "hardware/switches.py"
ENV_HANDSHAKES = {"hardware/cameras/render_process.py"}  # the render process's address, parent to child


def _environ_reads(path: Path) -> list[str]:
    """The FACTR2_* names a file reads from the environment: os.environ.get / os.environ[...] / os.getenv."""
    def is_environ(n: ast.AST) -> bool:
        return isinstance(n, ast.Attribute) and n.attr == "environ"

    out = []
    for node in ast.walk(_tree(path)):
        key = None
        if isinstance(node, ast.Call) and node.args and isinstance(node.func, ast.Attribute) and (
                (node.func.attr == "get" and is_environ(node.func.value)) or node.func.attr == "getenv"):
            key = node.args[0]
        elif isinstance(node, ast.Subscript) and is_environ(node.value):
            key = node.slice
        if isinstance(key, ast.Constant) and isinstance(key.value, str) and key.value.startswith("FACTR2_"):
            out.append(key.value)
    return out


def test_factr2_switches_are_read_in_one_place():
    reads = {str(f.relative_to(REPO)): _environ_reads(f)
             for layer in LAYERS for f in (REPO / layer).rglob("*.py")}
    assert set(reads[SWITCHES_FILE]) >= {"FACTR2_NO_RT", "FACTR2_NO_PIN", "FACTR2_CACHE"}
    bad = [f"{f} reads {names}" for f, names in sorted(reads.items())
           if names and f != SWITCHES_FILE and f not in ENV_HANDSHAKES]
    assert not bad, f"FACTR2_* switches read outside {SWITCHES_FILE}:\n" + "\n".join(bad)


# -- thread limits: one function (hardware/threads.py) ------------------------------------------------------
THREADS_FILE = "hardware/threads.py"
# the trainers choose their own thread counts (pick_threads, ThreadProbe per batch): a choice, not a limit
THREAD_CHOOSERS = {"calibration/next/train.py", "calibration/next/threads.py",
                   "policies/training/train_threads.py"}


def test_threads_are_limited_through_one_function():
    bad = []
    for layer in LAYERS:
        for f in sorted((REPO / layer).rglob("*.py")):
            rel = str(f.relative_to(REPO))
            if rel in THREAD_CHOOSERS | {THREADS_FILE}:
                continue
            for node in ast.walk(_tree(f)):
                name = getattr(node, "attr", None) or getattr(node, "id", None)
                if name in ("set_num_threads", "threadpool_limits"):
                    bad.append(f"{rel}:{node.lineno} uses {name}")
    assert not bad, f"threads limited outside {THREADS_FILE} (use limit_threads):\n" + "\n".join(bad)
