"""The documents whose result values are rendered from results/ (README.md and docs/), checked and rendered.

:func:`check` lists every problem of a set of documents against a results directory (a stale or failing value
marker of :mod:`icgo.reporting.render`, a false claim, a citation of a missing results file, a result number in
the prose without a marker: :mod:`icgo.reporting.prose`); :func:`render` gives the new text of each document whose
values changed (the command ``python -m experiments.docs`` writes them); :func:`suggest` proposes a marker for
each untraced number.
"""

from __future__ import annotations

import re
from pathlib import Path

#: The repository (README.md and docs/ beside icgo/).
ROOT = Path(__file__).resolve().parents[2]
#: Documents whose numbers are not checked against results/, and why.
NOT_CHECKED = {
    "design.md": "a copy of the project's design document",
    "engineering-notes.md": "a copy of the project's engineering notes",
}
#: Documents whose result numbers are not yet all marked (rendered, but the untraced-number check skips them).
PENDING: dict[str, str] = {}


def documents(root: Path = ROOT) -> list[Path]:
    """README.md and every note of docs/ (the copies in :data:`NOT_CHECKED` left out)."""
    return [root / "README.md"] + sorted(p for p in (root / "docs").glob("*.md") if p.name not in NOT_CHECKED)


def name(doc) -> str:
    """A document's path as problems name it: relative to the repository when inside it."""
    try:
        return str(Path(doc).resolve().relative_to(ROOT))
    except ValueError:
        return str(doc)


def check(docs, results: Path) -> list[str]:
    """Every problem of ``docs`` against ``results``: stale or failing markers, false claims, untraced numbers."""
    from icgo.reporting.prose import missing_citations, result_values, untraced
    from icgo.reporting.render import stale

    values = result_values(results)
    lines = []
    for doc in docs:
        text = Path(doc).read_text()
        lines += [str(p) for p in stale(text, results, name(doc))]
        lines += [f"{name(doc)}:{line}: cites {c}, which does not exist"
                  for line, c in missing_citations(text, results)]
        if Path(doc).name not in PENDING:
            lines += [f"{name(doc)}:{u.line}: {u.number!r} {u.why}" for u in untraced(text, results, values)]
    return lines


def render(docs, results: Path) -> tuple[dict[Path, str], list[str]]:
    """{document: its new text} for the documents whose values changed, and the problems (none written)."""
    from icgo.reporting.render import render_text

    changed, problems = {}, []
    for doc in docs:
        old = Path(doc).read_text()
        new, probs = render_text(old, results, name(doc))
        problems += [str(p) for p in probs]
        if new != old:
            changed[Path(doc)] = new
    return changed, problems


def suggest(doc: Path, results: Path, limit: int = 3) -> list[str]:
    """For each untraced number of ``doc``, up to ``limit`` cells of the results files it cites (or of any results
    CSV when it cites none) that hold it at its written precision, as ready marker expressions."""
    from icgo.reporting.prose import untraced
    from icgo.reporting.render import Sources

    text = Path(doc).read_text()
    src = Sources(results)
    tables = {}
    for f in sorted(results.rglob("*.csv")):
        rel = str(f.relative_to(results))
        try:
            rows = src.csv(rel)
        except Exception:  # noqa: BLE001  (an unreadable file suggests nothing)
            continue
        tables[rel] = rows
    lines = text.splitlines()
    out = []
    for u in untraced(text, results):
        if not u.number or not re.fullmatch(r"[-+]?\d+(\.\d+)?(e[-+]?\d+)?", u.number, re.I):
            out.append(f"{name(doc)}:{u.line}: {u.number!r}: no suggestion")
            continue
        cited = set(re.findall(r"results/([\w./-]+\.csv)", lines[u.line - 1])) if u.line <= len(lines) else set()
        q, digits = float(u.number), len(u.number.split(".")[1]) if "." in u.number else 0
        hits = []
        for rel, rows in tables.items():
            if cited and rel not in cited:
                continue
            for i, r in enumerate(rows):
                for c, v in r.items():
                    for scale, fmt in ((1, f".{digits}f"), (100, f".{digits}f")):
                        if isinstance(v, (int, float)) and abs(scale * v - q) <= 0.5 * 10 ** -digits * (1 + 1e-9):
                            key = next(iter(r))
                            hits.append(f'{{{"100 * " if scale == 100 else ""}csv("{rel}")[{i}]["{c}"]:{fmt}}}'
                                        f"  ({key} = {r[key]!r})")
        out.append(f"{name(doc)}:{u.line}: {u.number!r}: " + ("; ".join(hits[:limit]) or "no cell holds it")
                   + (f" (+{len(hits) - limit} more)" if len(hits) > limit else ""))
    return out
