"""Generalisation table: every method under every split protocol.

    .venv/bin/python -m experiments.generalisation       # results/generalisation.md + CSVs + figure (make generalisation)
    .venv/bin/python -m experiments.generalisation --n-repeats 2 --iterations 5 --out /tmp/g   # quick look

The study is ``icgo.studies.generalisation`` (registered as ``generalisation``):
raw, MSA only, RELM, PSO-RELM, GA-RELM, CGO-RELM, the four ICGO strategies and the
physics baseline, under the random 7:3 split, leave-azimuth-out and transfer on
lab_casing and the random split and leave-condition-out on the six well
conditions; paired repeats, Wilcoxon against the best with Holm adjustment, the
coverage of the 90 % conformal interval and the noise floor of every cell.
Writes generalisation.md, generalisation.csv (per cell, method and repeat),
generalisation_coverage.csv, generalisation_tests.csv and generalisation.png.
"""

from __future__ import annotations

import argparse
import sys


def parser() -> argparse.ArgumentParser:
    """The command line (defaults: :class:`icgo.studies.generalisation.study.GeneralisationConfig`)."""
    from icgo.core.settings import ArgumentParser
    from icgo.io.files import RESULTS_DIR
    from icgo.studies.generalisation.study import GeneralisationConfig

    d = GeneralisationConfig()
    ap = ArgumentParser(prog="python -m experiments.generalisation", description=__doc__,
                        formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--n-repeats", type=int, default=d.n_repeats)
    ap.add_argument("--iterations", type=int, default=d.iterations)
    ap.add_argument("--pop-size", type=int, default=d.pop_size)
    ap.add_argument("--seed", type=int, default=d.seed)
    ap.add_argument("--out", default=str(RESULTS_DIR),
                    help="results/ (default: its generalisation files are replaced) or a directory of its own")
    ap.add_argument("--overwrite", action="store_true", help="replace a used --out directory (not results/) whole")
    return ap


def main(argv=None) -> int:
    """The command: options -> the study's config (a bad one: one line, exit 2) -> the one study main."""
    import dataclasses

    from experiments._run_study import progress_to_stdout, run_study
    from icgo.core.errors import SettingError
    from icgo.io.files import results_output
    from icgo.studies.generalisation.study import GeneralisationConfig

    args = parser().parse_args(sys.argv[1:] if argv is None else argv)
    try:
        config = dataclasses.replace(GeneralisationConfig(), n_repeats=args.n_repeats, iterations=args.iterations,
                                     pop_size=args.pop_size, seed=args.seed)
    except SettingError as e:
        print(f"error: --{e.field.replace('_', '-')} {e.problem}" if e.field else f"error: {e}", file=sys.stderr)
        return 2
    output = results_output(args.out, overwrite=args.overwrite, writer="experiments.generalisation")
    progress_to_stdout("generalisation")
    run_study("generalisation", config, output)
    return 0


if __name__ == "__main__":
    from icgo.core.settings import run_cli

    sys.exit(run_cli(main))
