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
PENDING = {
    "calibrate.md": "its numbers belong to the calibrate front door's own rework; it is rendered like every doc and "
                    "joins the untraced-number check once its values are marked",
}


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
        lines += [f"{_name(doc)}:{line}: cites {c}, which does not exist" for line, c in missing_citations(text, results)]
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
    a = ap.parse_args(argv)
    results = Path(a.results)
    if not results.is_dir():
        raise SettingError(f"--results {a.results!r}: not a directory")
    docs = [Path(d) for d in a.docs] or documents()
    for d in docs:
        if not d.is_file() or d.suffix != ".md":
            raise SettingError(f"{str(d)!r}: not a Markdown file")
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
