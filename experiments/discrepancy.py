"""Hydra entry of the discrepancy workflow: read the data, fit, write (:mod:`icgo.studies.discrepancy`).

    python -m experiments.discrepancy data=path/to/file.csv     # .meta.json next to it
    python -m experiments.discrepancy data=device.json [mag_axes=.. grav_axes=..] [groups=..]   # circuitpython-mag-cal
    python -m experiments.discrepancy data=lab_casing
    python -m experiments.discrepancy data=sim:hard_iron+accel_bias design=single_inclination
    python -m experiments.discrepancy data=mag_cal:ab
    python -m experiments.discrepancy study=hidden|devices|lab_casing   # results/discrepancy_<study>.md

Prints the search and the verdict; writes report.md, discrepancy.json, the figures and the fitted physics model
(``discrepancy_model.json`` + ``.npz``) into the run directory. A bad setting (a workflow option of
:class:`icgo.discrepancy.WorkflowConfig`, an unknown key, ``study=`` or ``design=``): one line per problem on stderr
(``error: ...``), exit status 2; bad input data (a bad file, an unknown effect in ``data=sim:...``): one line, exit 1.
"""

from __future__ import annotations

import sys
from pathlib import Path

import hydra
from omegaconf import DictConfig, OmegaConf

from hydra_plugins.icgo_launcher.door import EXIT_CONFIG, hydra_cli, hydra_keep, one_line_errors, run_study
from icgo.core.settings import error_status
from icgo.studies import discrepancy_job as job


def main_body(cfg: DictConfig, out_dir: Path, keep=()) -> int:
    """Run one composed config; 0, :data:`EXIT_CONFIG` (2) for a bad setting, 1 for bad input data. ``out_dir`` is
    written all at once (:class:`icgo.io.files.Output`), refused when it holds files unless ``overwrite=true``."""
    from icgo.io.files import Output
    from icgo.io.recording import column_map

    try:
        config = job.workflow_config(OmegaConf.to_container(cfg, resolve=True))
        columns = column_map(OmegaConf.to_container(cfg.columns) if cfg.get("columns") else None,
                             cfg.get("columns_file"))
        output = None if cfg.study != "none" else Output(out_dir, setting="hydra.run.dir", overwrite=cfg.overwrite,
                                                         keep=keep, writer="experiments.discrepancy").check()
    except ValueError as err:  # one line per problem (a SettingsError has several); each exits 2 here
        error_status(err)
        return EXIT_CONFIG
    if cfg.study != "none":
        print("wrote", job.write_study(str(cfg.study), config, int(cfg.seed), int(cfg.n_stations),
                                       Path(cfg.results_dir)))
        return 0
    shots = {k: (OmegaConf.to_container(cfg[k]) if OmegaConf.is_list(cfg[k]) else cfg[k])
             for k in ("mag_axes", "grav_axes", "groups")}
    inputs = dict(data=str(cfg.data), seed=int(cfg.seed), n_stations=int(cfg.n_stations), design=str(cfg.design),
                  columns=columns, shots=shots)
    try:
        run_study("discrepancy", config, output, inputs=inputs, cfg=cfg)
    except ValueError as err:  # bad data (exit 1) or a bad reading setting (exit 2), one line
        return error_status(err)
    return 0


@hydra.main(version_base="1.3", config_path="../conf", config_name="discrepancy")
@one_line_errors
def main(cfg: DictConfig) -> None:
    from hydra.core.hydra_config import HydraConfig

    rc = main_body(cfg, Path(HydraConfig.get().runtime.output_dir), keep=hydra_keep())
    if rc:
        sys.exit(rc)


if __name__ == "__main__":
    hydra_cli("discrepancy", main)
