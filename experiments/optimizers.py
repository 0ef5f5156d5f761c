"""Optimizer study: our JAX optimizers vs mealpy 3.x side by side, equal evaluation budget.

    .venv/bin/python -m experiments.optimizers            # writes results/optimizers.md + CSV
    .venv/bin/python -m experiments.optimizers --runs 5 --dims 10 --out /tmp/x   # quick look
    .venv/bin/python -m experiments.optimizers --functions sphere --dims 10 --runs 120 --out DIR  # one cell, more runs

8 shifted/rotated CEC 2017 functions (icgo.optim.benchmarks.STUDY) x dims x runs. Every
run of every algorithm gets the same number of fitness evaluations (measured with
a call counter on the mealpy side, ``n_evals`` on ours). Pairs compared with the
Wilcoxon rank-sum test (two-sided, alpha 0.05): ``+`` ours significantly lower
(better), ``-`` significantly higher, ``=`` no significant difference.

The study is ``icgo.studies.optimizers``; the options become its ``OptimizerStudyConfig``, run by the one study
main (``PRNGKey(seed)``): optimizers.md, optimizers_table.csv (cells) and optimizers_runs.csv (runs).
"""

from __future__ import annotations

import argparse
import sys

#: Config fields set from the command line (option --pop-size -> field pop_size).
FIELDS = ("functions", "dims", "runs", "pop_size", "budget", "jobs", "seed", "alpha", "peer", "methods")


def parser() -> argparse.ArgumentParser:
    """The command line (defaults: :class:`icgo.studies.optimizers.study.OptimizerStudyConfig`)."""
    from icgo.core.settings import ArgumentParser
    from icgo.io.files import RESULTS_DIR
    from icgo.studies.optimizers.study import OptimizerStudyConfig

    d = OptimizerStudyConfig()
    ap = ArgumentParser(prog="python -m experiments.optimizers", description=__doc__,
                        formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--dims", type=int, nargs="+", default=list(d.dims))
    ap.add_argument("--runs", type=int, default=d.runs)
    ap.add_argument("--pop-size", type=int, default=d.pop_size)
    ap.add_argument("--budget", type=int, default=d.budget,
                    help="fitness evaluations per run (default 3220 = 20 + 40 x 80: 40 CGO / 160 PSO-GA-SMA iterations)")
    ap.add_argument("--jobs", type=int, default=d.jobs, help="processes for the mealpy runs (joblib)")
    ap.add_argument("--seed", type=int, default=d.seed, help="our runs use the key PRNGKey(seed)")
    ap.add_argument("--alpha", type=float, default=d.alpha, help="significance level (rank-sum and Holm)")
    ap.add_argument("--no-peer", dest="peer", action="store_false", default=d.peer,
                    help="skip the mealpy runs (our runs only, no comparison)")
    ap.add_argument("--functions", nargs="+", default=d.functions, metavar="NAME",
                    help="a subset of the study functions (a follow-up of single cells with more runs)")
    ap.add_argument("--methods", nargs="+", default=d.methods, metavar="LABEL",
                    help="a subset of our methods by label, e.g. 'icgo (paper, three_stage)' pso")
    ap.add_argument("--out", default=str(RESULTS_DIR),
                    help="results/ (default: its optimizers files are replaced) or a directory of its own")
    ap.add_argument("--overwrite", action="store_true", help="replace a used --out directory (not results/) whole")
    return ap


def main(argv=None):
    """The command: options -> the study's config (a bad one: one line, exit 2) -> the one study main."""
    ap, argv = parser(), sys.argv[1:] if argv is None else argv
    args = ap.parse_args(argv)
    from experiments._run_study import progress_to_stdout, run_study
    from icgo.core.errors import SettingError
    from icgo.core.settings import config_from_mapping
    from icgo.io.files import results_output
    from icgo.studies.optimizers import study

    try:
        cfg = config_from_mapping(study.OptimizerStudyConfig, {k: getattr(args, k) for k in FIELDS},
                                  "experiments.optimizers")
        study.study_functions(None, cfg)
    except SettingError as e:
        ap.error(f"--{e.field.replace('_', '-')}: {e.problem}" if e.field else str(e))
    output = results_output(args.out, overwrite=args.overwrite, writer="experiments.optimizers")
    progress_to_stdout("optimizers")
    run_study("optimizers", cfg, output, argv=argv)


if __name__ == "__main__":
    from icgo.core.settings import run_cli

    sys.exit(run_cli(main))
