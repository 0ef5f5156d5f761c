"""The end-of-sweep report: every job of a multirun with its status (ok / failed / killed / not run).

The job list is expanded from the sweep's own config (``hydra.sweeper.params``
plus the command line's sweep overrides, the basic sweeper's order), so the
report is the same for every launcher (``icgo_local``, joblib, submitit,
SLURM) and names the jobs that never started. A job's status is read from its
directory:

* ``ok``: a complete run record (``run.json``) of this job's configuration;
* ``refused``: a complete run record of another configuration (the directory
  held it before this sweep; a re-run never takes it for this job, and leaves
  it as it was: ``overwrite=true`` redoes the job). The configuration is
  matched by the hash of the job's resolved config
  (:func:`hydra_plugins.icgo_launcher.jobs.config_hash`), never by the job's number;
* ``killed``: a ``FAILED`` marker saying so, or a directory with neither a
  marker nor a run record (the job started and its process died);
* ``failed``: any other ``FAILED`` marker (its one line is the reason);
* ``not run``: no directory.

The report is printed (stderr) and written to ``sweep_report.json`` in the
sweep directory (atomically), beside the cross-job results table
``sweep_results.csv`` / ``.md``: one row per finished job and method, with the job's
swept overrides and its test MAE / RMSE / R^2 (mean +/- std over repeats, from the
job's ``summary.csv``). Nothing here imports JAX.
"""

from __future__ import annotations

import json
import os
import sys
from pathlib import Path
from typing import Any

from hydra._internal.core_plugins.basic_sweeper import BasicSweeper
from hydra.core.global_hydra import GlobalHydra
from hydra.core.override_parser.overrides_parser import OverridesParser
from hydra.experimental.callback import Callback
from omegaconf import DictConfig, OmegaConf, open_dict

from hydra_plugins.icgo_launcher.jobs import (FAILED, config_difference, config_hash, previous_run, stored_config,
                                             stored_hash)

REPORT_FILE = "sweep_report.json"
#: The cross-job results table (``.csv`` and ``.md``) beside the report.
RESULTS_FILE = "sweep_results"
STATUSES = ("ok", "refused", "failed", "killed", "not run")


def job_overrides(config: DictConfig) -> list[list[str]]:
    """Each job's overrides, in the basic sweeper's order (job number = position)."""
    params = OmegaConf.select(config, "hydra.sweeper.params") or {}
    args = [f"{k}={v}" for k, v in params.items()] + list(config.hydra.overrides.task)
    parsed = OverridesParser.create().parse_overrides(args)
    return [job for batch in BasicSweeper.split_arguments(parsed, None) for job in batch]


def job_config(config: DictConfig, overrides) -> dict | None:
    """The resolved task config (no ``hydra`` node) of one job, composed as the launcher composes it, or None
    outside a running Hydra application (a library call)."""
    gh = GlobalHydra.instance()
    if not gh.is_initialized():
        return None
    job = gh.config_loader().load_sweep_config(config, list(overrides))
    with open_dict(job):
        del job["hydra"]  # as the task function receives it (Hydra's run_job drops it)
    return OmegaConf.to_container(job, resolve=True)


def job_status(job_dir: Path, expected: dict | None = None) -> tuple[str, str]:
    """(status, reason) of one job's directory; see the module docstring.

    Args:
        expected: the job's resolved config; a finished run of another config is ``refused``
            (None: any finished run is ``ok``).
    """
    if not job_dir.is_dir():
        return "not run", ""
    run = previous_run(job_dir)
    if run is not None:
        if expected is None or stored_hash(job_dir, run) == config_hash(expected):
            return "ok", ""
        old = stored_config(job_dir)
        diff = config_difference(old, expected) if old else "it records no readable config"
        return "refused", (f"the directory holds a finished run of another configuration ({diff}); left as it was: "
                           f"overwrite=true redoes the job, or choose another hydra.sweep.dir")
    marker = job_dir / FAILED
    if marker.is_file():
        reason = marker.read_text(errors="replace").strip()
        return ("killed" if reason.startswith("killed") else "failed"), reason
    return "killed", "the job started and ended without a result or a FAILED marker"


def statuses(config: DictConfig) -> list[dict]:
    """One entry per job: num, overrides (the swept ones), dir, status, reason."""
    sweep = Path(str(config.hydra.sweep.dir))
    subdir = OmegaConf.to_container(config.hydra.sweep, resolve=False).get("subdir")
    jobs = []
    for num, overrides in enumerate(job_overrides(config)):
        # The default subdir is the job number; another pattern is resolved per job as Hydra does.
        name = str(num) if subdir == "${hydra.job.num}" else _subdir(config, overrides, num)
        finished = previous_run(sweep / name) is not None  # only then is the job's config needed (composing costs)
        status, reason = job_status(sweep / name, job_config(config, overrides) if finished else None)
        jobs.append({"num": num, "overrides": list(overrides), "dir": name, "status": status, "reason": reason})
    return jobs


def _subdir(config: DictConfig, overrides, num: int) -> str:
    c = OmegaConf.create(OmegaConf.to_container(config, resolve=False))
    OmegaConf.set_struct(c, False)
    c.hydra.job.num = num
    c.hydra.job.override_dirname = ",".join(overrides)
    return str(OmegaConf.select(c, "hydra.sweep.subdir"))


def report(config: DictConfig, file=None) -> list[dict]:
    """Print the report (to ``file``, default the current ``sys.stderr``), write ``sweep_report.json``; return the jobs
    (see :func:`statuses`)."""
    file = sys.stderr if file is None else file
    sweep = Path(str(config.hydra.sweep.dir))
    jobs = statuses(config)
    counts = {s: sum(j["status"] == s for j in jobs) for s in STATUSES}
    print(f"sweep {sweep}: {len(jobs)} job(s): " + ", ".join(f"{n} {s}" for s, n in counts.items() if n), file=file)
    width = max((len(str(j["num"])) for j in jobs), default=1)
    for j in jobs:
        line = f"  job {j['num']:>{width}}  {j['status']:<7}  {' '.join(j['overrides']) or '(no overrides)'}"
        print(line + (f"  -- {j['reason']}" if j["reason"] else ""), file=file)
    if sweep.is_dir():
        tmp = sweep / f".{REPORT_FILE}.{os.getpid()}"
        tmp.write_text(json.dumps({"sweep_dir": str(sweep), "counts": counts, "jobs": jobs}, indent=1) + "\n")
        os.replace(tmp, sweep / REPORT_FILE)
        table = results_table(sweep, jobs)
        if table is not None:
            for ext, text in (("csv", table.to_csv(index=False)), ("md", table.to_markdown(index=False) + "\n")):
                tmp = sweep / f".{RESULTS_FILE}.{ext}.{os.getpid()}"
                tmp.write_text(text)
                os.replace(tmp, sweep / f"{RESULTS_FILE}.{ext}")
            print(f"results of the {sum(j['status'] == 'ok' for j in jobs)} finished job(s) (test split; "
                  f"{sweep / RESULTS_FILE}.csv):", file=file)
            print(table.to_markdown(index=False), file=file)
    return jobs


def results_table(sweep: Path, jobs: list[dict]):
    """One row per finished job and method: the job, its overrides, and its summary (test MAE, RMSE, R^2; a worlds
    job's pooled over worlds, from ``worlds_pooled.csv``); None when no finished job has either file."""
    import pandas as pd  # here, not at the top: Hydra imports this module at every start (its plugin scan)

    rows = []
    for j in jobs:
        one, worlds = sweep / j["dir"] / "summary.csv", sweep / j["dir"] / "worlds_pooled.csv"  # a worlds job: pooled
        f = one if one.is_file() else worlds
        if j["status"] != "ok" or not f.is_file():
            continue
        try:
            s = pd.read_csv(f)
        except (OSError, ValueError):
            continue
        for _, r in s.iterrows():
            n = r.get("n") if f is one else f"{r.get('worlds')} worlds x {r.get('repeats per world')}"
            rows.append({"job": j["num"], "overrides": " ".join(j["overrides"]) or "(none)",
                         "method": r.get("label") if f is one else r.get("name"), "repeats": n,
                         "MAE (deg)": r.get("MAE (deg)"), "RMSE (deg)": r.get("RMSE (deg)"),
                         "R^2": r.get("R^2") if f is one else r.get("R^2 of error")})
    return pd.DataFrame(rows) if rows else None


class FailureReport(Callback):
    """Hydra callback: after a multirun, report every job's status (this module);
    exit with status 1 unless every job is ok."""

    def on_multirun_end(self, config: DictConfig, **kwargs: Any) -> None:
        jobs = report(config)
        bad = [j for j in jobs if j["status"] != "ok"]
        if bad:
            refused = sum(j["status"] == "refused" for j in bad)
            print(f"{len(bad)} of {len(jobs)} job(s) did not finish"
                  + (f" ({refused} refused: their directories hold runs of another configuration)" if refused else "")
                  + f"; the others' results are in {config.hydra.sweep.dir} (re-running the sweep into it resumes "
                    f"it)", file=sys.stderr)
            raise SystemExit(1)
