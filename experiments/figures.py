"""Regenerate results/ for the ICGO paper: Tables 1-4 and Figs. 9-13, 15 from study runs.

``python -m experiments.figures [DIR ...] [--out results] [--jobs N]``

* With directories: every ``run.json`` below them (run or multirun directories of ``experiments.run``; jobs that
  left a ``FAILED`` marker are skipped) is collected; of two runs holding the same (data set, condition, split
  seed, method, repeat) the newer wins (:class:`icgo.reporting.run_collection.Runs`).
* Without: a fresh run of the preset plan (:data:`icgo.studies.icgo_relm.results.outputs.PLAN`, :mod:`experiments.figures_plan`)
  first, into ``multirun/figures-<time>/``.

Outputs (``--out``, default ``results/``; :func:`icgo.studies.icgo_relm.results.build.build`): ``tableN.csv`` +
``tableN.md`` with the paper's published numbers in adjacent columns, ``table3_stats.*`` (Wilcoxon signed-rank and
Friedman with mean ranks), ``figN.png`` and ``figN.csv`` (the plotted numbers), the sweeps. A table whose runs are
missing is listed in ``results/tables_missing.txt`` instead of being written.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path


def main(argv=None) -> int:
    from icgo.core.settings import ArgumentParser

    ap = ArgumentParser(prog="python -m experiments.figures", description=__doc__.split("\n\n")[0])
    ap.add_argument("dirs", nargs="*", help="run/multirun directories to collect (default: run the presets)")
    ap.add_argument("--out", default=str(Path(__file__).resolve().parent.parent / "results"),
                    help="results/ (default: its tables and figures are replaced) or a directory of its own")
    ap.add_argument("--overwrite", action="store_true", help="replace a used --out directory (not results/) whole")
    ap.add_argument("--jobs", type=int, default=None,
                    help="jobs at once for the preset plan (icgo_local launcher; default one per core)")
    ap.add_argument("--override", action="append", default=[], help="extra Hydra override for the preset plan")
    a = ap.parse_args(argv)
    from icgo.io.files import results_output
    from experiments.figures_plan import check_plan_overrides, run_plan
    from hydra_plugins.icgo_launcher.report import REPORT_FILE
    from icgo.core.errors import SettingError
    from icgo.studies.icgo_relm.results.outputs import PLAN
    from icgo.studies.icgo_relm.results.build import build

    if a.jobs is not None and a.jobs < 1:
        raise SettingError(f"--jobs {a.jobs}: must be >= 1")
    if a.override and a.dirs:
        raise SettingError("--override applies to the preset plan; it has no effect when run directories are given")
    check_plan_overrides(a.override)
    for d in a.dirs:
        if not Path(d).is_dir():
            raise SettingError(f"{d!r}: not a directory (give run or multirun directories to collect)")
    output = results_output(a.out, overwrite=a.overwrite, writer="experiments.figures")
    t0 = time.perf_counter()
    dirs, failed = a.dirs, []
    if not dirs:
        dirs, failed = run_plan(Path("multirun") / f"figures-{time.strftime('%Y-%m-%d_%H-%M-%S')}", a.jobs, a.override)
    with output.staged() as stage:  # all tables and figures move in together, or none (Ctrl-C, full disk)
        done = build(dirs, stage, REPORT_FILE)
        complete = not (stage / "tables_missing.txt").exists()
    if complete:  # nothing missing now: an old list must not stay beside the new results
        (output.path / "tables_missing.txt").unlink(missing_ok=True)
    for name, ok in done.items():
        print(f"{name}: {'written' if ok is True else ok}")
    print(f"figures: {time.perf_counter() - t0:.0f} s, output in {a.out}")
    if failed:
        print(f"error: {len(failed)} of {len(PLAN)} preset sweep(s) did not finish ({', '.join(failed)}); their "
              f"tables are missing or incomplete", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    from icgo.core.settings import run_cli

    raise SystemExit(run_cli(main))
