"""ICGO-RELM study, the Hydra front door: ``python -m experiments.run strategy=three_stage``.

Composes ``conf/config.yaml`` (groups: dataset, model, optimizer, strategy,
schedule, budget, split, fitness, experiment), runs :func:`icgo.studies.icgo_relm.run_study`
and writes into the run directory (``HydraConfig.get().runtime.output_dir``):
``config.yaml`` (resolved), ``metrics.csv`` (per method, repeat, split),
``convergence.csv``, ``predictions.csv``, ``msa.csv``, ``summary.csv``,
``summary.md``, the fitted models ``relm_compensation.json/.npz`` and
``msa.json/.npz`` (:mod:`icgo.artifacts.format`), ``study.png`` and, last, ``run.json``
(file and column names: :mod:`icgo.reporting.records`); prints the summary table and a
final line with the wall time.

Examples::

    python -m experiments.run strategy=three_stage            # make run
    python -m experiments.run strategy=all                    # five strategies, one vmapped call
    python -m experiments.run -m strategy=chaos,gaussian,wavelet,three_stage hydra/launcher=joblib
    python -m experiments.run experiment=table3               # a paper preset (see conf/experiment)

JAX is imported inside the job (never at module import), so launchers that
start worker processes never fork an initialised XLA runtime. See
docs/experiments.md.
"""

from __future__ import annotations

import logging
import sys
import time
from pathlib import Path

import hydra
from omegaconf import DictConfig, OmegaConf

from hydra_plugins.icgo_launcher.door import CONF_DIR, EXIT_CONFIG, check_overrides, one_line_errors, preflight

log = logging.getLogger(__name__)


def run_job(cfg: DictConfig, outdir: Path, multirun: bool = False) -> dict | None:
    """Run one configured study and write its run directory.

    Args:
        cfg: composed config (without the ``hydra`` node).
        outdir: the run directory.
        multirun: True inside a sweep: a failure is recorded in ``outdir/FAILED``
            and the job returns None, so the other jobs go on.
    Returns:
        The run.json dictionary, or None for a failed multirun job.
    Raises:
        SystemExit(2): a bad setting or data file outside a sweep (one line on stderr).
    """
    from hydra_plugins.icgo_launcher import door, jobs
    from icgo.core import devices as runtime
    from experiments import _relm_job as relm_job

    t0 = time.perf_counter()
    previous = jobs.previous_run(outdir)
    if previous is not None and multirun and cfg.overwrite is not True:
        # Re-running a sweep into its directory resumes it: a finished job is kept only when it ran this
        # job's configuration (its hash); one of another configuration is refused, never taken for this job.
        there = relm_job.stored_hash(outdir, previous)
        if there is not None and there == relm_job.cfg_hash(cfg):
            log.info("kept the finished job in %s (overwrite=true reruns it)", outdir)
            (outdir / jobs.FAILED).unlink(missing_ok=True)
            return previous
        old = relm_job.stored_config(outdir)
        diff = relm_job.config_difference(old, OmegaConf.to_container(cfg, resolve=True)) if old else \
            "it records no readable config"
        log.error("refused: %s holds a finished run of another configuration (%s); it is left as it was "
                  "(overwrite=true redoes the job, or choose another hydra.sweep.dir)", outdir, diff)
        return None
    if previous is not None and not multirun and cfg.overwrite is not True:
        print(f"error: {outdir} already holds a complete run; choose another hydra.run.dir or pass overwrite=true "
              f"(the old run is then replaced whole)", file=sys.stderr)
        raise SystemExit(EXIT_CONFIG)
    from experiments import _worlds_job as worlds_job
    from icgo.studies.icgo_relm_progress import progress_enabled, run_with_progress

    timings = {}
    worlds = cfg.get("worlds") is not None
    try:
        relm_job.check_config(cfg)
        worlds_job.check(cfg)
        relm_job.run_output(outdir, overwrite=door.bool_setting(cfg, "overwrite"))
    except ValueError as e:
        if multirun:
            jobs.write_failure(outdir, jobs.one_line(e))
            log.error("job failed: %s", jobs.one_line(e))
            return None
        door.fail_line(e)
    try:
        devices = runtime.start_devices()  # before JAX's backend starts: jax.distributed, the CPU's host devices
        scfg = relm_job.study_config(cfg)  # every check before any computation (imports the study, JAX with it)
        progress_enabled(cfg.progress)
        timings["import_s"] = time.perf_counter() - t0
        runtime.enable_jax_cache(cfg.jax_cache_dir)
        if worlds:
            result, desc = worlds_job.run_study(cfg, scfg, timings)
        else:
            t1 = time.perf_counter()
            frame, meta, desc = relm_job.load_data(cfg)
            target = relm_job.load_target(cfg)
            timings["load_data_s"] = time.perf_counter() - t1
            result = run_with_progress(frame, scfg, meta, cfg.progress, desc=f"{desc} {'/'.join(scfg.method_names())}",
                                       target=target, timings=timings)
    except ValueError as e:  # SettingError, DataError (icgo.core.errors), study/optimizer checks: one line each
        if multirun:
            jobs.write_failure(outdir, jobs.one_line(e), jobs.format_traceback(e))
            log.error("job failed: %s", jobs.one_line(e))
            return None
        door.fail_line(e)
    except Exception as e:
        if not multirun:
            raise
        jobs.write_failure(outdir, f"{type(e).__name__}: {jobs.one_line(e)}", jobs.format_traceback(e))
        log.error("job failed: %s: %s", type(e).__name__, jobs.one_line(e))
        return None

    info = {"label": cfg.label, "dataset": cfg.dataset.name,
            "condition": cfg.dataset.get("condition", None), "description": desc,
            "dataset_kwargs": OmegaConf.to_container(cfg.dataset.kwargs, resolve=True) if "kwargs" in cfg.dataset
            else None,
            "optimizer": cfg.optimizer.name, "strategies": list(cfg.strategy.names),
            "schedule": OmegaConf.to_container(cfg.schedule, resolve=True),
            "optimizer_params": OmegaConf.to_container(cfg.optimizer.params, resolve=True) if cfg.optimizer.name
            else None,
            "execution": timings.pop("execution"), "timings": timings, "devices": devices,
            "total_time_s": time.perf_counter() - t0, **runtime.env_info()}
    if runtime.is_secondary_process():  # a multi-process job: the first process writes the run directory
        return None
    if worlds:
        try:
            run = worlds_job.write_outputs(outdir, cfg, result, info)
        except ValueError as e:  # OutputError: the previous run is intact
            if multirun:
                jobs.write_failure(outdir, jobs.one_line(e))
                log.error("job failed: %s", jobs.one_line(e))
                return None
            door.fail_line(e)
        from icgo.studies.worlds_outputs import print_summary as print_worlds

        print_worlds(result, outdir, t0)
        return run
    plot = None
    if cfg.figures:
        from icgo.reporting.run_figure import plot_study

        def _plot(path):
            plot_study(result, path, title=desc)

        plot = _plot
    try:
        run = relm_job.write_outputs(outdir, cfg, result, info, frame, meta, plot)
    except ValueError as e:  # OutputError (a full disk, a read-only directory): the previous run is intact
        if multirun:
            jobs.write_failure(outdir, jobs.one_line(e))
            log.error("job failed: %s", jobs.one_line(e))
            return None
        door.fail_line(e)
    from icgo.studies.icgo_relm_outputs import print_summary

    print_summary(result, desc, run, outdir, t0)
    return run


@hydra.main(version_base="1.3", config_path=str(CONF_DIR), config_name="config")
@one_line_errors
def app(cfg: DictConfig) -> None:
    """Hydra task function: one job of a run or a sweep."""
    from hydra.core.hydra_config import HydraConfig
    from hydra.types import RunMode

    hc = HydraConfig.get()
    run_job(cfg, Path(hc.runtime.output_dir), multirun=hc.mode == RunMode.MULTIRUN)


def main() -> None:
    """Entry point: ``--help``, then reject unknown group options in one line, then hand over to Hydra."""
    if any(a in ("--help", "-h") for a in sys.argv[1:]):
        from experiments._relm_job import run_help

        print(run_help())
        return
    preflight("config")
    err = check_overrides(sys.argv[1:])
    if err:
        print(f"error: {err}", file=sys.stderr)
        raise SystemExit(EXIT_CONFIG)
    app()


if __name__ == "__main__":
    from hydra_plugins.icgo_launcher.door import guarded

    guarded(main)
