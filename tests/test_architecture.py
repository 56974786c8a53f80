"""Dependencies point one way: factr2_teleop -> policies -> calibration -> hardware (docs/architecture.md),
and inside hardware/ its subpackages and modules import each other without a cycle."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
LAYERS = ["hardware", "calibration", "policies", "factr2_teleop"]  # lower layers first


def _imports(path: Path) -> set[str]:
    tree = ast.parse(path.read_text(), filename=str(path))
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

    visit(ast.parse(path.read_text(), filename=str(path)))
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
