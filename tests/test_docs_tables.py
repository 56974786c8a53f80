"""The tables in docs/ agree with their results files (bench/docs_tables.py), and results/README.md lists what
results/ holds (bench/results_index.py): a number changed on one side only fails here."""

from __future__ import annotations

import re

from bench import docs_tables, harness, results_index
from bench.first_report import DOCS_BEGIN


def test_generated_tables_match_their_results():
    for page in sorted({p for p, _ in docs_tables.TABLES}):
        text = (docs_tables.DOCS / page).read_text()
        assert docs_tables.render_page(text, page) == text, (
            f"docs/{page}: a table differs from its results file: run `python -m bench.docs_tables`")


def test_a_hand_edited_number_is_caught():
    text = (docs_tables.DOCS / "faults.md").read_text()
    row = next(line for line in text.splitlines() if line.startswith("| can_busoff |") and "| main |" in line)
    edited = text.replace(row, row.replace("| 60/60 |", "| 59/60 |", 1))
    assert edited != text and docs_tables.render_page(edited, "faults.md") == text


def test_every_generated_table_restores_a_hand_edit():
    """In each generated table, a changed digit of its last row is rewritten from its results file."""
    for (page, name), _ in docs_tables.TABLES.items():
        text = (docs_tables.DOCS / page).read_text()
        block = text.split(f"<!-- table {name}:", 1)[1].split(f"<!-- /table {name} -->", 1)[0]
        row = next(line for line in reversed(block.splitlines()) if re.search(r"\d", line))
        i = re.search(r"\d", row).start()
        edited_row = row[:i] + str((int(row[i]) + 1) % 10) + row[i + 1:]
        edited = text.replace(row, edited_row, 1)
        assert edited != text and docs_tables.render_page(edited, page) == text, f"docs/{page} table {name}"


def test_first_block_matches_first_headline():
    assert docs_tables.first_block_problems() == []


def test_first_block_drift_is_caught():
    page = (docs_tables.DOCS / "first.md").read_text()
    head, block = page.split(DOCS_BEGIN, 1)
    row = next(line for line in block.splitlines() if line.startswith("| first |"))
    edited = head + DOCS_BEGIN + block.replace(row, row.replace("**", "**1", 1), 1)
    assert any("pooled" in p for p in docs_tables.first_block_problems(edited))


def test_results_are_records_and_the_index_is_current():
    for p in sorted(harness.RESULTS.glob("*.json")):
        data = harness.load(p) if not p.stem.startswith("first_cells") else None
        assert data is None or data["experiment"] == p.stem, f"{p.name}: named by its experiment"
    assert results_index.INDEX.read_text() == results_index.render(), (
        "results/README.md is stale: run `python -m bench.results_index`")
