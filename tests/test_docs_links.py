"""Every relative link in the docs (docs/*.md, README.md) points to a file that exists and, with a #fragment,
to a heading of that Markdown file (GitHub's anchor rule); and no page names a development machine's
absolute path."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PAGES = sorted((ROOT / "docs").glob("*.md")) + [ROOT / "README.md"]
LINK = re.compile(r"\[[^\]]*\]\(([^)\s]+)\)")
FENCE = re.compile(r"^(```|~~~).*?^\1", re.S | re.M)


def anchor(heading: str) -> str:
    """GitHub's anchor of a heading: lower case, punctuation dropped except hyphens and underscores
    (`snake_case` keeps its underscore), each space to a hyphen."""
    return re.sub(r"[^\w\- ]", "", heading.strip().lower()).replace(" ", "-")


def test_anchor_rule():
    assert anchor("The `lean` rollout: CPU (s)") == "the-lean-rollout-cpu-s"
    assert anchor("`grab_nm` and `rest_s`") == "grab_nm-and-rest_s"
    assert anchor("A -- B") == "a----b"


def anchors(page: Path) -> set[str]:
    seen: dict[str, int] = {}
    out = set()
    for line in FENCE.sub("", page.read_text()).splitlines():
        if m := re.match(r"#{1,6}\s+(.*)", line):
            a = anchor(m.group(1))
            out.add(a if a not in seen else f"{a}-{seen[a]}")
            seen[a] = seen.get(a, 0) + 1
    return out


def broken_links(page: Path) -> list[str]:
    bad = []
    for target in LINK.findall(FENCE.sub("", page.read_text())):
        if re.match(r"[a-z]+:", target):  # http:, https:, mailto:
            continue
        path, _, frag = target.partition("#")
        dest = (page.parent / path).resolve() if path else page
        if not dest.exists():
            bad.append(f"{page.name}: {target} (no such file)")
        elif frag and dest.suffix == ".md" and frag not in anchors(dest):
            bad.append(f"{page.name}: {target} (no such heading)")
    return bad


def test_relative_links_resolve():
    bad = [b for page in PAGES for b in broken_links(page)]
    assert not bad, "\n".join(bad)


def test_no_machine_paths():
    hits = [f"{p.name}:{i}" for p in PAGES for i, line in enumerate(p.read_text().splitlines(), 1)
            if re.search(r"(?<![\w.])/(work|home|tmp)/", line)]
    assert not hits, f"absolute machine paths in the docs: {hits}"
