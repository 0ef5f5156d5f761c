"""MLflow tracking of the Hydra doors (:mod:`icgo.studies.common.tracking`): a job's run directory logged once it is
written (:func:`track_job`, called by the one study main, :mod:`experiments._study_main`, and by
:func:`experiments._run_study.run_study`),
and a sweep as a parent run (:class:`SweepTracking`, a Hydra callback: any launcher, any sweeper, Optuna's too).

The setting is the composed config's ``tracking`` key where the door has one (``experiments.run``), else the
environment's ``ICGO_TRACKING``, else ``auto``. Nothing here imports MLflow or JAX at module import.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

from hydra.experimental.callback import Callback
from omegaconf import DictConfig, OmegaConf

log = logging.getLogger(__name__)


def _setting(cfg) -> Any:
    """The ``tracking`` setting of a composed config or its plain mapping (None: the environment's, else auto)."""
    if isinstance(cfg, dict):
        return cfg.get("tracking")
    try:
        return OmegaConf.select(cfg, "tracking", default=None) if cfg is not None else None
    except Exception:  # noqa: BLE001  (a config without the key)
        return None


def experiment_name(job_name: str | None) -> str:
    """The MLflow experiment of a door: ``icgo-<door>`` (``icgo-run``, ``icgo-misma``, ...)."""
    return f"icgo-{job_name or 'run'}"


def _hydra():
    """(job name, multirun?, sweep dir, job number, overrides) of the Hydra job in this process, or Nones."""
    from hydra.core.hydra_config import HydraConfig
    from hydra.types import RunMode

    if not HydraConfig.initialized():
        return None, False, None, None, []
    hc = HydraConfig.get()
    multirun = hc.mode == RunMode.MULTIRUN
    return (hc.job.name, multirun, Path(str(hc.sweep.dir)) if multirun else None,
            hc.job.get("num") if multirun else None, list(hc.overrides.task))


def track_job(settings: dict, outdir: Path, files=None, door: str | None = None) -> str | None:
    """Log a written run directory to MLflow (nothing when tracking is off or MLflow absent); a sweep's job under
    its sweep's parent run; with its objective (:func:`icgo.studies.common.tracking_tables.objective`) where it has one.

    Args:
        settings: the composed config as a plain mapping (its ``tracking`` key, else ``ICGO_TRACKING``).
        outdir: the run directory. files: the files to log as artifacts, relative to ``outdir`` (None: every file
            of it; a door writing into a shared results folder names its own). door: the MLflow experiment's
            door (default: the Hydra job's name).
    Returns:
        The MLflow run id, or None.
    """
    from icgo.studies.common import tracking
    from icgo.studies.common.tracking_tables import objective

    try:
        uri = tracking.tracking_uri(_setting(settings))
    except ValueError as e:  # checked with the config before the run; here only a warning
        log.warning("tracking: %s", e)
        return None
    if uri is None:
        return None
    job, multirun, sweep_dir, num, overrides = _hydra()
    params = {k: v for k, v in settings.items() if k != "hydra"}
    name = f"job {num}: {' '.join(overrides)}" if multirun else (params.get("label") or Path(outdir).name)
    return tracking.log_run_dir(uri, Path(outdir), experiment=experiment_name(door or job), params=params,
                                run_name=str(name), tags={"icgo.overrides": " ".join(overrides)},
                                parent_run_id=tracking.parent_of(sweep_dir) if sweep_dir else None,
                                extra_metrics={"objective": objective(Path(outdir))}, files=files)


class SweepTracking(Callback):
    """A sweep as an MLflow parent run: opened before the first job (its id left in the sweep directory for the jobs
    of any launcher), closed after the last with the sweep's report files and the best objective of the jobs'
    directories (the jobs may have run in other processes or on other nodes)."""

    def __init__(self) -> None:
        self.uri: str | None = None

    def on_multirun_start(self, config: DictConfig, **kwargs: Any) -> None:
        from icgo.studies.common import tracking

        try:
            self.uri = tracking.tracking_uri(_setting(config))
        except ValueError:
            self.uri = None  # the job's check says it in one line
        if self.uri is None:
            return
        sweep_dir = Path(str(config.hydra.sweep.dir))
        params = {"overrides": " ".join(config.hydra.overrides.task),
                  "sweeper": OmegaConf.select(config, "hydra.sweeper._target_", default="")}
        sweep = OmegaConf.select(config, "hydra.sweeper.params", default=None)
        sweep = OmegaConf.to_container(sweep, resolve=False) if OmegaConf.is_config(sweep) else {}
        params.update({f"sweep.{k}": v for k, v in (sweep or {}).items()})
        tracking.start_parent(self.uri, sweep_dir, experiment=experiment_name(config.hydra.job.name),
                              params=params, run_name=f"sweep {sweep_dir}")

    def on_multirun_end(self, config: DictConfig, **kwargs: Any) -> None:
        if self.uri is None:
            return
        from icgo.studies.common import tracking
        from icgo.studies.common.tracking_tables import objective

        sweep_dir = Path(str(config.hydra.sweep.dir))  # the jobs ran in other processes: read their directories
        values = [v for d in sorted(sweep_dir.iterdir()) if d.is_dir() and (d / "run.json").is_file()
                  for v in [objective(d)] if v is not None]
        tracking.end_parent(self.uri, sweep_dir, min(values) if values else None)
