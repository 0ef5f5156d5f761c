"""The ``icgo`` console script (``[project.scripts]`` in pyproject.toml): every front door of the README as
``icgo <command> [ARGS ...]``, exactly ``python -m <module> [ARGS ...]`` (the module run as ``__main__`` with the
same arguments: the same checks, messages, exit statuses and outputs).

    icgo run strategy=three_stage          # = python -m experiments.run strategy=three_stage
    icgo calibrate data=shots.csv          # = python -m experiments.calibrate data=shots.csv
    icgo bench --quick                     # = python -m experiments.bench --quick
    icgo io check FILE.csv                 # = python -m icgo.io check FILE.csv
    icgo --help                            # the commands; icgo <command> --help: its own help

A door started here names ``icgo <door>`` in the commands it prints to run next (:mod:`icgo.core.commands`).
Nothing here imports JAX.
"""

from __future__ import annotations

import os
import runpy
import sys

#: command -> (module run as ``__main__``, what it does). Hydra doors take ``GROUP=OPTION KEY=VALUE``, the others
#: ``--flags``; ``icgo <command> --help`` says which.
COMMANDS = {
    "run": ("experiments.run", "the ICGO-RELM study, any setting, a paper preset or a sweep (Hydra)"),
    "apply": ("experiments.apply", "apply a fitted model to a new survey (Hydra)"),
    "calibrate": ("experiments.calibrate", "calibrate a magnetometer from grouped shots (Hydra)"),
    "discrepancy": ("experiments.discrepancy", "where simulation and data disagree, and the missing effect (Hydra)"),
    "misma": ("experiments.misma", "the MISMA study against SMA -> results/misma_* (Hydra)"),
    "gyro": ("experiments.gyro", "the gyro network against the lookup table -> results/gyro_* (Hydra)"),
    "figures": ("experiments.figures", "every ICGO table and figure of results/ from run directories"),
    "fig9_seeds": ("experiments.fig9_seeds", "how often each CGO seed is accepted -> results/fig9_seeds.*"),
    "worlds_tables": ("experiments.worlds_tables", "Tables 1, 3 and Fig. 9 over worlds -> results/"),
    "generalisation": ("experiments.generalisation", "every method under every protocol -> results/generalisation.md"),
    "optimizers": ("experiments.optimizers", "the optimizers against mealpy on CEC 2017 -> results/optimizers.md"),
    "calibration_unseen": ("experiments.calibration_unseen", "calibrate on perturbed copies of the bundled devices"),
    "dataset_figures": ("experiments.dataset_figures", "the simulated data sets beside the papers' figures"),
    "casing_check": ("experiments.casing_check", "the casing model against magpylib -> results/casing_model_check.*"),
    "bench": ("experiments.bench", "the benchmark (--quick, --gpu-check, --rows, --calibrate)"),
    "roofline": ("experiments.roofline", "per-stage roofline of the RELM fitness on this CPU"),
    "docs": ("experiments.docs", "render the result numbers of README.md and docs/ from results/ (--check)"),
    "datasets": ("icgo.datasets", "write a simulated data set (NAME --out DIR)"),
    "io": ("icgo.io", "check or convert a recording (check FILE, convert FILE.json --out FILE.csv)"),
}


def usage() -> str:
    """``icgo --help``: the commands, one line each."""
    lines = ["usage: icgo <command> [ARGS ...]   (= python -m <module> [ARGS ...]; icgo <command> --help: its help)",
             "", "commands:"]
    lines += [f"  {name:<19} {what}" for name, (_, what) in COMMANDS.items()]
    lines += ["", "e.g. icgo run strategy=three_stage; icgo apply model=outputs/run/<date>/<time> data=survey.csv",
              "docs: README.md (commands), docs/experiments.md"]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    """Run ``icgo <command> [ARGS ...]``; returns the exit status (the command's own, raised as SystemExit)."""
    argv = sys.argv[1:] if argv is None else list(argv)
    if argv[:1] in (["-h"], ["--help"], ["help"]):
        print(usage())
        return 0
    name = argv[0].replace("-", "_") if argv else ""
    if name not in COMMANDS:
        print(f"error: {'unknown command ' + repr(argv[0]) if argv else 'no command'}; choose one of: "
              f"{', '.join(COMMANDS)} (icgo --help)", file=sys.stderr)
        return 2
    from icgo.core.commands import SCRIPT_ENV
    from icgo.core.settings import startup_interrupts

    startup_interrupts()  # a Ctrl-C while the command's modules load: one line, as with python -m
    os.environ[SCRIPT_ENV] = os.path.abspath(sys.argv[0])
    sys.argv[1:] = argv[1:]
    runpy.run_module(COMMANDS[name][0], run_name="__main__", alter_sys=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
