"""Gyro inclinometer study entry point: ``conf/gyro.yaml`` -> :mod:`icgo.studies.gyro` -> ``results/gyro_*``.

Tables and figures go to ``results/gyro_*`` (:mod:`icgo.studies.gyro_report`) with ``gyro_run.json``, the fitted
models (lookup table, networks, RELMs) into the Hydra run directory (``outputs/gyro/<time>/models/``)::

    .venv/bin/python -m experiments.gyro                       # full study
    .venv/bin/python -m experiments.gyro n_seeds=3 net.epochs=300 sweep.enabled=false relm.enabled=false

The one study main (:func:`hydra_plugins.icgo_launcher.door.study_main`) composes the config, loads, runs and writes.
"""

from __future__ import annotations

import hydra
from omegaconf import DictConfig

from hydra_plugins.icgo_launcher.door import hydra_cli, one_line_errors, study_main

#: Settings of the entry point, not of the study (excluded from the study's config dataclass).
ENTRY_KEYS = ("out_dir", "jax_cache")


@hydra.main(config_path="../conf", config_name="gyro", version_base="1.3")
@one_line_errors
def main(cfg: DictConfig) -> None:
    """Hydra entry point: ``python -m experiments.gyro [overrides]``; a bad setting exits 2 with one line."""
    study_main("gyro", cfg, ENTRY_KEYS)


if __name__ == "__main__":
    hydra_cli("gyro", main)
