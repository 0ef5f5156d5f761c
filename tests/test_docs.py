"""The repository is self-contained: README, docs/ and results/ refer to nothing outside it."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
#: References that only make sense beside the project's original workspace or its issue tracker.
OUTSIDE = re.compile(r"\.\./shared|/work/|(?-i:ENGINEERING-NOTES)|(?<![\w/])(?-i:DESIGN)\.md|\bissues? ?#?\d+|\bissue-\d+",
                     re.IGNORECASE)


def _texts():
    yield ROOT / "README.md"
    yield from sorted((ROOT / "docs").glob("*.md"))
    yield from sorted((ROOT / "results").rglob("*.md"))


def test_readme_docs_and_results_refer_only_to_the_repository():
    bad = [f"{p.relative_to(ROOT)}:{i}: {m.group(0)}" for p in _texts()
           for i, line in enumerate(p.read_text().splitlines(), 1) for m in OUTSIDE.finditer(line)]
    assert bad == []


def test_the_design_document_is_the_shipped_one():
    design = (ROOT / "docs" / "design.md").read_text()
    for heading in ("## Conventions", "## Data contract", "## Effect vocabulary", "## Honesty rules for studies",
                    "## Fitted models", "## Batching"):
        assert heading in design
    notes = (ROOT / "docs" / "engineering-notes.md").read_text()
    assert "Industry survey QC: |Btotal - Bref| <= 300 nT" in notes
    linked = {m for p in _texts() for m in re.findall(r"`(docs/[\w.-]+\.md)`", p.read_text())}
    assert linked and all((ROOT / m).is_file() for m in linked), sorted(m for m in linked if not (ROOT / m).is_file())
