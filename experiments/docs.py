"""Render the result values of README.md and docs/ from results/ (``make docs``), or check them (``--check``).

``python -m experiments.docs [DOC ...] [--results DIR] [--check]``

Every value marker (:mod:`icgo.reporting.render`) is re-read from its results file. Without ``--check`` the documents
whose values changed are rewritten (all of them or none: a marker that fails, or a claim that no longer holds, stops
the command before anything is written, with one line per problem). With ``--check`` nothing is written; the exit
status is 1 when a value is stale, a marker fails, a claim is false, or a result number stands in the prose without
a marker (:mod:`icgo.reporting.prose`), each listed on its own line. After a regeneration of ``results/``,
``make docs`` is the one step that brings the documents up to date.
"""

from __future__ import annotations

import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "results"
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


def check(docs, results: Path) -> list[str]:
    """Every problem of ``docs`` against ``results``: stale or failing markers, false claims, untraced numbers."""
    from icgo.reporting.prose import missing_citations, result_values, untraced
    from icgo.reporting.render import stale

    values = result_values(results)
    lines = []
    for doc in docs:
        text = Path(doc).read_text()
        lines += [str(p) for p in stale(text, results, _name(doc))]
        lines += [f"{_name(doc)}:{line}: cites {c}, which does not exist"
                  for line, c in missing_citations(text, results)]
        if Path(doc).name not in PENDING:
            lines += [f"{_name(doc)}:{u.line}: {u.number!r} {u.why}" for u in untraced(text, results, values)]
    return lines


def render(docs, results: Path) -> tuple[dict[Path, str], list[str]]:
    """{document: its new text} for the documents whose values changed, and the problems (none written)."""
    from icgo.reporting.render import render_text

    changed, problems = {}, []
    for doc in docs:
        old = Path(doc).read_text()
        new, probs = render_text(old, results, _name(doc))
        problems += [str(p) for p in probs]
        if new != old:
            changed[Path(doc)] = new
    return changed, problems


def write(changed: dict[Path, str]) -> None:
    """The changed documents, each directory's all at once (:class:`icgo.io.files.Output`, shared)."""
    from icgo.io.files import Output

    by_dir: dict[Path, list[Path]] = {}
    for doc in changed:
        by_dir.setdefault(doc.parent, []).append(doc)
    for folder, docs in by_dir.items():
        with Output(folder, setting="docs", shared=True).staged() as stage:
            for doc in docs:
                (stage / doc.name).write_text(changed[doc])


def suggest(doc: Path, results: Path, limit: int = 3) -> list[str]:
    """For each untraced number of ``doc``, up to ``limit`` cells of the results files it cites (or of any results
    CSV when it cites none) that hold it at its written precision, as ready marker expressions."""
    import re

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
            out.append(f"{_name(doc)}:{u.line}: {u.number!r}: no suggestion")
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
        out.append(f"{_name(doc)}:{u.line}: {u.number!r}: " + ("; ".join(hits[:limit]) or "no cell holds it")
                   + (f" (+{len(hits) - limit} more)" if len(hits) > limit else ""))
    return out


def _name(doc) -> str:
    try:
        return str(Path(doc).resolve().relative_to(ROOT))
    except ValueError:
        return str(doc)


def main(argv=None) -> int:
    from icgo.core.errors import SettingError
    from icgo.core.settings import ArgumentParser

    ap = ArgumentParser(prog="python -m experiments.docs", description=__doc__.split("\n\n")[0])
    ap.add_argument("docs", nargs="*", help="Markdown documents (default: README.md and docs/*.md)")
    ap.add_argument("--results", default=str(RESULTS), help="the results directory the markers read (default "
                                                             "results/)")
    ap.add_argument("--check", action="store_true", help="write nothing; exit 1 on any stale value, failing marker, "
                                                         "false claim or untraced result number")
    ap.add_argument("--suggest", action="store_true", help="write nothing; for each untraced number, the results "
                                                           "cells that hold it (to write its marker)")
    a = ap.parse_args(argv)
    results = Path(a.results)
    if not results.is_dir():
        raise SettingError(f"--results {a.results!r}: not a directory")
    docs = [Path(d) for d in a.docs] or documents()
    for d in docs:
        if not d.is_file() or d.suffix != ".md":
            raise SettingError(f"{str(d)!r}: not a Markdown file")
    if a.suggest:
        for d in docs:
            print("\n".join(suggest(d, results)))
        return 0
    if a.check:
        problems = check(docs, results)
        for p in problems:
            print(p)
        print(f"docs: {len(docs)} document(s) checked, {len(problems)} problem(s)")
        return 1 if problems else 0
    changed, problems = render(docs, results)
    if problems:
        for p in problems:
            print(p, file=sys.stderr)
        print(f"error: {len(problems)} marker(s) could not be rendered; no document was written", file=sys.stderr)
        return 1
    write(changed)
    for doc in changed:
        print(f"rendered {_name(doc)}")
    print(f"docs: {len(docs)} document(s), {len(changed)} changed")
    return 0


if __name__ == "__main__":
    from icgo.core.settings import run_cli

    raise SystemExit(run_cli(main))
