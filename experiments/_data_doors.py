"""The doors that read a user's recording (``apply``, ``calibrate``, ``discrepancy``), as the one study main runs
them (:func:`experiments._study_main.study_main`): the composed config's settings checked, the recording read,
the outputs written into the run directory all at once (refused when it holds files, unless ``overwrite=true``)
with Hydra's record of the job. A bad setting exits 2, bad data 1, each with one line. Nothing here imports JAX
at module import.
"""

from __future__ import annotations

import time
from pathlib import Path

from omegaconf import DictConfig, OmegaConf

from experiments._door import bool_setting, hydra_keep, repo_path, write_hydra_record
from experiments._preflight import EXIT_CONFIG
from experiments._run_study import run_study, study_config
from icgo.core.errors import SettingError
from icgo.core.settings import error_status, first_line

#: Settings of the calibrate door, not of the study (excluded from CalibrationConfig; its schema's untyped keys).
CALIBRATE_KEYS = ("data", "mag_axes", "grav_axes", "groups", "columns", "columns_file", "site", "max_shots",
                  "max_groups", "results_dir", "jax_cache_dir", "overwrite")


def _shots(cfg: DictConfig) -> dict:
    """How grouped shots are read: ``mag_axes``, ``grav_axes``, ``groups`` (a list as a list)."""
    return {k: (OmegaConf.to_container(cfg[k]) if OmegaConf.is_list(cfg[k]) else cfg[k])
            for k in ("mag_axes", "grav_axes", "groups")}


def _columns(cfg: DictConfig) -> dict:
    """The field export's column map (``columns.*``, ``columns_file``)."""
    from icgo.io.recording import column_map

    return column_map(OmegaConf.to_container(cfg.columns) if cfg.get("columns") else None, cfg.get("columns_file"))


def apply_settings(cfg: DictConfig) -> dict:
    """The apply door's composed config as a plain mapping, a mandatory value not given (``???``) as None."""
    return {k: None if OmegaConf.is_missing(cfg, k) else v
            for k, v in OmegaConf.to_container(cfg, resolve=True, throw_on_missing=False).items()}


def run_apply(cfg: DictConfig, out_dir: Path, keep=()) -> dict:
    """:func:`icgo.survey.apply_settings.run_apply` of a composed config, Hydra's record written with the files."""
    from icgo.survey.apply_settings import run_apply as apply

    return apply(apply_settings(cfg), out_dir, keep, lambda stage: write_hydra_record(stage, cfg))


def apply_main(cfg: DictConfig, run_dir: Path) -> int:
    """One survey, one model: the corrected survey into ``out=`` or ``run_dir``; returns the verdict's exit status
    (:data:`icgo.survey.verdict.EXIT_OUT_OF_DOMAIN` when the result is not to be used as it stands, else 0)."""
    from icgo.survey.apply_run import report
    from icgo.survey.apply_settings import check_settings

    check_settings(apply_settings(cfg))  # out= among them, before it is used
    out = Path(str(cfg.out)).expanduser() if cfg.get("out") else run_dir
    meta = run_apply(cfg, out, keep=hydra_keep())
    report(meta, out, Path(str(cfg.data)).stem)
    return meta["verdict"]["exit_code"]


def calibrate_main(cfg: DictConfig, run_dir: Path) -> int:
    """:func:`icgo.studies.calibration.job.run` of a composed config; returns 0, or
    :data:`icgo.survey.verdict.EXIT_NO_RECOMMENDATION` (4) for a run that recommends no calibration (its report
    written)."""
    from icgo.core.devices import enable_jax_cache
    from icgo.io.files import Output
    from icgo.io.site import site_reference
    from icgo.studies.calibration import job as calibration_run

    try:
        config = study_config("calibration", cfg, CALIBRATE_KEYS, config_name="calibrate")
    except ValueError as e:
        raise SettingError(first_line(e)) from None
    t0 = time.perf_counter()
    enable_jax_cache(cfg.get("jax_cache_dir"))
    site = cfg.get("site")
    if site is not None and not OmegaConf.is_dict(site):
        raise SettingError(f"site={site!r}: give site.lat= site.lon= site.date=, or site.dip= site.field=")
    site = site_reference(None if site is None else OmegaConf.to_container(site, resolve=True))
    output = Output(run_dir, setting="hydra.run.dir", overwrite=bool_setting(cfg, "overwrite"), keep=hydra_keep(),
                    writer="experiments.calibrate")

    def load() -> dict:  # name -> Recording of data= (settings checked, then read)
        calibration_run.check_settings(cfg.data, cfg.get("max_shots"), cfg.get("max_groups"))
        return calibration_run.load_recordings(cfg.data, _shots(cfg), _columns(cfg), int(cfg.max_shots),
                                               int(cfg.max_groups))

    return calibration_run.run(str(cfg.data), config, site, output, load,
                               lambda stage: write_hydra_record(stage, cfg), repo_path(cfg.results_dir), t0)


def discrepancy_main(cfg: DictConfig, run_dir: Path, keep=None) -> int:
    """The discrepancy workflow of one composed config into ``run_dir`` (or ``study=``: its results/ file); 0,
    :data:`EXIT_CONFIG` (2) for a bad setting (one line per problem), 1 for bad input data."""
    from icgo.core.devices import enable_jax_cache
    from icgo.io.files import Output
    from icgo.studies.discrepancy import job

    keep = hydra_keep() if keep is None else keep
    try:
        config = job.workflow_config(OmegaConf.to_container(cfg, resolve=True))
        enable_jax_cache(cfg.get("jax_cache_dir"))
        columns = _columns(cfg)
        output = None if cfg.study != "none" else Output(run_dir, setting="hydra.run.dir", overwrite=cfg.overwrite,
                                                         keep=keep, writer="experiments.discrepancy").check()
    except ValueError as err:  # one line per problem (a SettingsError has several); each exits 2 here
        error_status(err)
        return EXIT_CONFIG
    if cfg.study != "none":
        print("wrote", job.write_study(str(cfg.study), config, int(cfg.seed), int(cfg.n_stations),
                                       Path(cfg.results_dir)))
        return 0
    inputs = dict(data=str(cfg.data), seed=int(cfg.seed), n_stations=int(cfg.n_stations), design=str(cfg.design),
                  columns=columns, shots=_shots(cfg))
    try:
        run_study("discrepancy", config, output, inputs=inputs, cfg=cfg)
    except ValueError as err:  # bad data (exit 1) or a bad reading setting (exit 2), one line
        return error_status(err)
    return 0
