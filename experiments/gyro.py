"""Gyro inclinometer study, the Hydra front door: ``icgo gyro [KEY=VALUE ...]`` (= ``python -m experiments.gyro``).

``conf/gyro.yaml`` -> the one study main (:func:`experiments._study_main.study_main`) -> :mod:`icgo.studies.gyro`:
tables and figures into ``results/gyro_*`` with ``gyro_run.json``, the fitted models (lookup table, networks, RELMs)
into the run directory (``outputs/gyro/<date>/<time>/models/``). ``--help`` lists the settings.
"""

from __future__ import annotations

import hydra
from omegaconf import DictConfig

from experiments._door import CONF_DIR, door, one_line_errors
from experiments._schema import register_defaults
from experiments._study_main import study_main
from icgo.core.devices import CacheSetting
from icgo.studies.gyro.study import GyroConfig

#: Settings of the door, not of the study (excluded from the study's config dataclass).
ENTRY_KEYS = ("out_dir", "jax_cache_dir")

register_defaults("gyro", GyroConfig, CacheSetting)  # the study's defaults, named first by conf/gyro.yaml


@hydra.main(version_base="1.3", config_path=str(CONF_DIR), config_name="gyro")
@one_line_errors
def main(cfg: DictConfig) -> float | None:
    """Hydra task: the study; returns its objective for a sweeper (``hydra/sweeper=optuna``); a bad setting exits 2
    with one line."""
    return study_main("gyro", cfg, ENTRY_KEYS)


if __name__ == "__main__":
    door("gyro", main)
