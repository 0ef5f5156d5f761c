"""Every ICGO-RELM table and figure of ``results/`` from the runs below some directories: :func:`build`."""

from __future__ import annotations

from pathlib import Path

from icgo.reporting import stamp
from icgo.studies.icgo_relm.results.outputs import (ABLATION_LABEL, EQUAL_EVALS_LABEL, MUTATIONS_LABELS,
                                                    SCHEDULES_LABEL, SOURCES, SWEEP_PREFIX, plan_command)
from icgo.reporting.run_collection import EXCLUDED_FILE, Runs, missing_jobs, write_excluded
from icgo.reporting.table_writer import LACKING
from icgo.studies.icgo_relm.results import condition_sweeps
from icgo.studies.icgo_relm.results.fig9 import fig9, fig9_ablation, fig9_budgets
from icgo.studies.icgo_relm.results.figures import fig10, fig11, fig12, fig13
from icgo.studies.icgo_relm.results.sweeps import sweep_mutations, sweep_schedules
from icgo.studies.icgo_relm.results.table4 import table4
from icgo.studies.icgo_relm.results.tables import table1, table2, table3

BUILDERS = {"table1": table1, "fig9": fig9, "table2": table2, "fig10": fig10, "fig11": fig11, "table3": table3,
            "fig12": fig12, "fig13": fig13, "table4": table4}


def build(dirs, out: Path, report_file: str | None = None) -> dict:
    """Collect runs below ``dirs`` and write every table and figure they support into ``out``.

    Args:
        dirs: run or multirun directories of ``experiments.run``. out: the output folder.
        report_file: the name of a sweep launcher's report (``hydra_plugins.icgo_launcher.report.REPORT_FILE``): its
            jobs that left no result are listed in ``tables_missing.txt`` (None: only the ``FAILED`` markers are).
    Returns:
        {name: True if written, else a line naming the methods whose runs were missing}.
    """
    out.mkdir(parents=True, exist_ok=True)
    found = Runs(dirs)
    evals, runs = found.split_label(EQUAL_EVALS_LABEL)
    # a sweep's runs (label "sweep_...") and the CGO ablation's never replace the paper presets' runs in the
    # pooled tables, whether or not a builder reads them
    sweeps, runs = runs.split_label(ABLATION_LABEL, *{str(r.get("label")) for r in runs.runs
                                                      if str(r.get("label") or "").startswith(SWEEP_PREFIX)})
    sched, mutations = sweeps.split_label(SCHEDULES_LABEL)[0], sweeps.split_label(*MUTATIONS_LABELS)[0]
    ablation = sweeps.split_label(ABLATION_LABEL)[0]
    # each output: its builder and the runs it is made from beyond those whose rows it reads from the pooled runs
    # (Runs hands those to the stamp as it reads them): their budget, repeats and dtype stamp it
    calls = {name: (lambda fn=fn: fn(runs, out), Runs(None, [])) for name, fn in BUILDERS.items()}
    calls |= {name: (lambda name=name: condition_sweeps.build(sweeps, out, name, LACKING.get()),
                     sweeps.split_label(*condition_sweeps.OUTPUTS[name])[0]) for name in condition_sweeps.OUTPUTS}
    calls |= {"sweep_mutations": (lambda: sweep_mutations(runs, mutations, out), mutations),
              "fig9_budgets": (lambda: fig9_budgets(runs, evals, out), evals),
              "sweep_schedules": (lambda: sweep_schedules(runs, sched, out), sched),
              "fig9_ablation": (lambda: fig9_ablation(runs, ablation, out), ablation)}
    done, partial = {}, []
    for name, (call, source) in calls.items():
        lacking = []
        token = LACKING.set(lacking)
        try:
            with stamp.stamping(source.settings()):
                ok = call()
        except (ValueError, KeyError) as e:  # one output that cannot be built never stops the others
            ok, lacking[:] = False, [f"skipped: could not be built from these runs ({type(e).__name__}: "
                                     f"{str(e).splitlines()[0] if str(e) else ''})"]
        finally:
            LACKING.reset(token)
        skipped = [x for x in lacking if x.startswith("skipped: ")]
        partial += [f"{name}: written without {x[len('partial: '):]}" for x in lacking if x.startswith("partial: ")]
        methods = [x for x in lacking if not x.startswith(("skipped: ", "partial: "))]
        done[name] = True if ok else ("; ".join(skipped) if skipped else (
            ("no runs of " + ", ".join(methods) if methods else "no runs") + "; made by "
            + " and ".join(f"`{plan_command(src)}`" for src in SOURCES[name])))
    missing = {n: why for n, why in done.items() if why is not True}
    jobs = missing_jobs(dirs, found.failed, report_file)
    miss = out / "tables_missing.txt"
    if missing or jobs or partial:
        miss.write_text("".join(f"{n}: {why}\n" for n, why in missing.items()) + "".join(f"{p}\n" for p in partial)
                        + "".join(f"job {j}\n" for j in jobs))
    elif miss.exists():
        miss.unlink()
    write_excluded(Runs(None, evals.runs + sweeps.runs + runs.runs), out / EXCLUDED_FILE)
    return done
