"""Dependencies point one way: factr2_teleop -> policies -> calibration -> hardware (docs/architecture.md)."""

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
