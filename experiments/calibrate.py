"""Calibration front door for a user's recording: ``conf/calibrate.yaml`` -> :mod:`icgo.studies.calibration`.

    python -m experiments.calibrate data=shots.csv                       # contract CSV with a group column
    python -m experiments.calibrate data=device.json                     # circuitpython-mag-cal: its layout's rolls
    python -m experiments.calibrate data=raw.json mag_axes=+x+y-z grav_axes=-y-x+z   # the raw layout
    python -m experiments.calibrate data=device.json groups=auto         # the rolls found in the data instead
    python -m experiments.calibrate data=device.json site.lat=51.5 site.lon=-0.1 site.date=2024-06-01
    python -m experiments.calibrate data=bundled                         # the 9 bundled devices -> results/

Reads the shots, fits and scores every method, recommends one and writes the run directory
(:mod:`icgo.studies.calibration_run`, which says what each file holds). A bad setting: one line, exit 2; bad data:
one line, exit 1, nothing written; a recording with nothing to recommend: every file written, one line, exit 4.
"""

from __future__ import annotations

import time
from pathlib import Path

import hydra
from omegaconf import DictConfig, OmegaConf

from hydra_plugins.icgo_launcher.door import (bool_setting, hydra_cli, hydra_keep, one_line_errors, repo_path,
                                               study_config, write_hydra_record)
from hydra_plugins.icgo_launcher.schema import register
from icgo.core.devices import enable_jax_cache
from icgo.core.errors import SettingError
from icgo.core.settings import first_line
from icgo.studies.calibration import CalibrationConfig

#: Settings of the entry point, not of the study (excluded from CalibrationConfig).
ENTRY_KEYS = ("data", "mag_axes", "grav_axes", "groups", "columns", "columns_file", "site", "max_shots",
              "max_groups", "results_dir", "jax_cache_dir", "overwrite")
register("calibrate", CalibrationConfig, ENTRY_KEYS)  # conf/calibrate.yaml's schema


def load(cfg: DictConfig) -> dict:
    """name -> Recording of ``data=`` (:mod:`icgo.studies.calibration_run`: settings checked, then read)."""
    from icgo.io.recording import column_map
    from icgo.studies.calibration_run import check_settings, load_recordings

    check_settings(cfg.data, cfg.get("max_shots"), cfg.get("max_groups"))
    settings = {k: (OmegaConf.to_container(cfg[k]) if OmegaConf.is_list(cfg[k]) else cfg[k])
                for k in ("mag_axes", "grav_axes", "groups")}
    columns = column_map(OmegaConf.to_container(cfg.columns) if cfg.get("columns") else None, cfg.get("columns_file"))
    return load_recordings(cfg.data, settings, columns, int(cfg.max_shots), int(cfg.max_groups))


@hydra.main(config_path="../conf", config_name="calibrate", version_base="1.3")
@one_line_errors
def main(cfg: DictConfig) -> None:
    """Hydra entry point: :func:`icgo.studies.calibration_run.run` with the settings of ``cfg``. A bad setting exits
    2, bad data exits 1, each with one line; a run that recommends no calibration writes its report and exits
    :data:`icgo.survey.verdict.EXIT_NO_RECOMMENDATION` (4)."""
    from hydra.core.hydra_config import HydraConfig

    from icgo.io.files import Output
    from icgo.io.site import site_reference
    from icgo.studies import calibration_run

    try:
        config = study_config("calibration", cfg, ENTRY_KEYS, config_name="calibrate")
    except ValueError as e:
        raise SettingError(first_line(e)) from None
    t0 = time.perf_counter()
    enable_jax_cache(cfg.get("jax_cache_dir"))
    site = cfg.get("site")
    if site is not None and not OmegaConf.is_dict(site):
        raise SettingError(f"site={site!r}: give site.lat= site.lon= site.date=, or site.dip= site.field=")
    site = site_reference(None if site is None else OmegaConf.to_container(site, resolve=True))
    output = Output(Path(HydraConfig.get().runtime.output_dir), setting="hydra.run.dir",
                    overwrite=bool_setting(cfg, "overwrite"), keep=hydra_keep(), writer="experiments.calibrate")
    rc = calibration_run.run(str(cfg.data), config, site, output, lambda: load(cfg),
                             lambda stage: write_hydra_record(stage, cfg), repo_path(cfg.results_dir), t0)
    from hydra_plugins.icgo_launcher.tracking_hooks import track_job

    track_job(OmegaConf.to_container(cfg, resolve=True), output.path, door="calibrate")  # MLflow, where installed
    if rc:
        raise SystemExit(rc)


if __name__ == "__main__":
    hydra_cli("calibrate", main)
