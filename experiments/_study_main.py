"""The one study main (:func:`study_main`): the body of every Hydra door's task, any registered study
(:data:`icgo.studies.registry.STUDIES`) from a composed config: its typed config -> load -> run -> write, with
Hydra's record of the job (:mod:`experiments._run_study`). The ICGO-RELM study's door (``run``) writes a
run directory with a run record (``run.json``) and the hash of the config that made it, so a sweep re-run into its
directory resumes (:func:`resume`: a finished job of the same configuration kept, one of another refused and left
as it was); its typed config is :class:`icgo.studies.icgo_relm.run_config.RunConfig`
(:mod:`icgo.studies.icgo_relm.job`: load, run, write). Nothing here imports JAX at module import.
"""

from __future__ import annotations

import logging
import sys
import time
from pathlib import Path

from omegaconf import DictConfig, OmegaConf

from experiments._door import hydra_files, hydra_keep
from experiments._preflight import EXIT_CONFIG
from experiments._run_study import run_composed, study_config
from hydra_plugins.icgo_launcher.jobs import (FAILED, FAILURE_FILES, cfg_hash, config_difference, format_traceback,
                                             previous_run, stored_config, stored_hash, write_failure)
from icgo.core.settings import error_status, first_line

log = logging.getLogger(__name__)


#: Doors that read a user's recording: study (or door) name -> its function in :mod:`experiments._data_doors`,
#: ``(cfg, run_dir) -> exit status``.
DATA_DOORS = {"apply": "apply_main", "calibration": "calibrate_main", "discrepancy": "discrepancy_main"}


def study_main(name: str, cfg: DictConfig, entry_keys=("out_dir",)):
    """The body of every Hydra door's task, for ``STUDIES[name]`` (or the ``apply`` door): the typed config first (a
    bad setting: one line, exit 2), then the study, its outputs and Hydra's record written, into the run directory
    (``hydra.run.dir``) or the shared results folder (``out_dir``) with the models into the run directory's
    ``models/`` (:func:`experiments._run_study.run_composed`). ``icgo_relm``: one job of a run or a sweep
    (:func:`run_job`); a door that reads a user's recording: :data:`DATA_DOORS`. Exits with the door's status."""
    from hydra.core.hydra_config import HydraConfig
    from hydra.types import RunMode

    hc = HydraConfig.get()
    run_dir = Path(hc.runtime.output_dir)
    if name == "icgo_relm":  # its objective for a sweeper that minimises one (hydra/sweeper=optuna)
        from icgo.studies.common.tracking_tables import objective

        record = run_job(cfg, run_dir, multirun=hc.mode == RunMode.MULTIRUN)
        return None if record is None else objective(run_dir)
    if name in DATA_DOORS:
        from experiments import _data_doors
        from experiments._tracking import track_job

        rc = getattr(_data_doors, DATA_DOORS[name])(cfg, run_dir)
        out = Path(str(cfg.out)).expanduser() if name == "apply" and cfg.get("out") else run_dir
        if rc not in (1, EXIT_CONFIG):  # a refusal (bad data or setting: one line, nothing written) is not a run
            track_job(OmegaConf.to_container(cfg, resolve=True), out, door=name)  # MLflow, where installed, not off
        if rc:
            raise SystemExit(rc)
        return None
    try:
        config = study_config(name, cfg, entry_keys)
    except ValueError as e:
        print(f"error: {first_line(e)}", file=sys.stderr)
        raise SystemExit(EXIT_CONFIG) from None
    logging.getLogger("icgo").setLevel(logging.INFO)
    from icgo.studies.registry import get_study

    result = run_composed(name, cfg, run_dir / "models", config, entry_keys)
    measure = get_study(name).objective  # what a sweeper minimises (hydra/sweeper=optuna), where the study has one
    return None if measure is None else measure(result)


def resume(cfg: DictConfig, outdir: Path, multirun: bool) -> tuple[bool, dict | None]:
    """(done, the job's run record) for a run directory that already holds a finished run, unless
    ``overwrite=true``: in a sweep a finished job is kept (done, its record) only when it ran this job's
    configuration (:func:`hydra_plugins.icgo_launcher.jobs.cfg_hash`), one of another configuration is refused and
    left as it was (done, None); outside a sweep a complete run is refused (one line, exit 2). Else (False, None)."""
    previous = previous_run(outdir)
    if previous is None or cfg.get("overwrite") is True:
        return False, None
    if not multirun:
        print(f"error: {outdir} already holds a complete run; choose another hydra.run.dir or pass overwrite=true "
              f"(the old run is then replaced whole)", file=sys.stderr)
        raise SystemExit(EXIT_CONFIG)
    there = stored_hash(outdir, previous)
    if there is not None and there == cfg_hash(cfg):
        log.info("kept the finished job in %s (overwrite=true reruns it)", outdir)
        (outdir / FAILED).unlink(missing_ok=True)
        return True, previous
    old = stored_config(outdir)
    diff = config_difference(old, OmegaConf.to_container(cfg, resolve=True)) if old else \
        "it records no readable config"
    log.error("refused: %s holds a finished run of another configuration (%s); it is left as it was "
              "(overwrite=true redoes the job, or choose another hydra.sweep.dir)", outdir, diff)
    return True, None


def run_job(cfg: DictConfig, outdir: Path, multirun: bool = False) -> dict | None:
    """One ICGO-RELM job of a run or a sweep into ``outdir``: :func:`resume`, the typed config and the run directory
    checked, the study computed (every process of a multi-process job), the run directory written (the first
    process only; :mod:`icgo.studies.icgo_relm.job`) and the summary printed. Returns the run record, or None for a
    failed or refused sweep job (or a secondary process).

    Outside a sweep a user's error (ValueError) is one line and exit status 2 or 1; in a sweep it leaves
    :data:`FAILED` (and the traceback of an error met while computing, any exception there) and the job returns
    None, so the other jobs go on.
    """
    from icgo.studies.icgo_relm import job
    from icgo.studies.icgo_relm.run_config import RunConfig

    t0 = time.perf_counter()
    done, kept = resume(cfg, outdir, multirun)
    if done:
        return kept
    try:
        run = RunConfig.from_mapping(OmegaConf.to_container(cfg, resolve=True))
        job.run_output(outdir, run.overwrite, hydra_keep(), FAILURE_FILES)
    except ValueError as e:
        return _failed(e, outdir, multirun)
    try:
        computed, info = job.start_and_compute(run, t0)
    except ValueError as e:  # SettingError, DataError (icgo.core.errors), study/optimizer checks: one line each
        return _failed(e, outdir, multirun, format_traceback(e))
    except Exception as e:
        if not multirun:
            raise
        write_failure(outdir, f"{type(e).__name__}: {first_line(e)}", format_traceback(e))
        log.error("job failed: %s: %s", type(e).__name__, first_line(e))
        return None
    from icgo.core.devices import is_secondary_process

    if is_secondary_process():  # a multi-process job: the first process writes the run directory
        return None
    try:
        record = job.write_run(outdir, run, computed, info, config_yaml=OmegaConf.to_yaml(cfg, resolve=True),
                               config_sha256=cfg_hash(cfg), keep=hydra_keep(), ignore=FAILURE_FILES,
                               records={f".hydra/{k}": v for k, v in hydra_files(cfg).items()})
    except ValueError as e:  # OutputError (a full disk, a read-only directory): the previous run is intact
        return _failed(e, outdir, multirun)
    job.print_run(run, computed, record, outdir, t0)
    from experiments._tracking import track_job

    track_job(OmegaConf.to_container(cfg, resolve=True), outdir)  # MLflow, where installed and not turned off
    return record


def _failed(e: ValueError, outdir: Path, multirun: bool, tb: str | None = None) -> None:
    """A job's user error: in a sweep the FAILED marker (+ ``tb``) and None; else its one line and the exit."""
    if not multirun:
        raise SystemExit(error_status(e) or EXIT_CONFIG)
    write_failure(outdir, first_line(e), tb)
    log.error("job failed: %s", first_line(e))
    return None
