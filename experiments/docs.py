"""Render the result values of README.md and docs/ from results/ (``make docs``), or check them (``--check``).

``python -m experiments.docs [DOC ...] [--results DIR] [--check]``

Every value marker (:mod:`icgo.reporting.render`) is re-read from its results file. Without ``--check`` the documents
whose values changed are rewritten (all of them or none: a marker that fails, or a claim that no longer holds, stops
the command before anything is written, with one line per problem). With ``--check`` nothing is written; the exit
status is 1 when a value is stale, a marker fails, a claim is false, or a result number stands in the prose without
a marker (:mod:`icgo.reporting.prose`), each listed on its own line. After a regeneration of ``results/``,
``make docs`` is the one step that brings the documents up to date. The checks are :mod:`icgo.reporting.documents`.
"""

from __future__ import annotations

import sys
from pathlib import Path


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


def main(argv=None) -> int:
    from icgo.core.errors import SettingError
    from icgo.core.settings import ArgumentParser
    from icgo.io.files import RESULTS_DIR
    from icgo.reporting import documents as D

    ap = ArgumentParser(prog="python -m experiments.docs", description=__doc__.split("\n\n")[0])
    ap.add_argument("docs", nargs="*", help="Markdown documents (default: README.md and docs/*.md)")
    ap.add_argument("--results", default=str(RESULTS_DIR), help="the results directory the markers read (default "
                                                                 "results/)")
    ap.add_argument("--check", action="store_true", help="write nothing; exit 1 on any stale value, failing marker, "
                                                         "false claim or untraced result number")
    ap.add_argument("--suggest", action="store_true", help="write nothing; for each untraced number, the results "
                                                           "cells that hold it (to write its marker)")
    a = ap.parse_args(argv)
    results = Path(a.results)
    if not results.is_dir():
        raise SettingError(f"--results {a.results!r}: not a directory")
    docs = [Path(d) for d in a.docs] or D.documents()
    for d in docs:
        if not d.is_file() or d.suffix != ".md":
            raise SettingError(f"{str(d)!r}: not a Markdown file")
    if a.suggest:
        for d in docs:
            print("\n".join(D.suggest(d, results)))
        return 0
    if a.check:
        problems = D.check(docs, results)
        print("\n".join([*problems, f"docs: {len(docs)} document(s) checked, {len(problems)} problem(s)"]))
        return 1 if problems else 0
    changed, problems = D.render(docs, results)
    if problems:
        print("\n".join([*problems, f"error: {len(problems)} marker(s) could not be rendered; no document was "
                                    "written"]), file=sys.stderr)
        return 1
    write(changed)
    print("\n".join([*(f"rendered {D.name(doc)}" for doc in changed), f"docs: {len(docs)} document(s), "
                                                                      f"{len(changed)} changed"]))
    return 0


if __name__ == "__main__":
    from icgo.core.settings import run_cli

    raise SystemExit(run_cli(main))
