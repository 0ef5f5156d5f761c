"""MISMA study, the Hydra front door: ``icgo misma [KEY=VALUE ...]`` (= ``python -m experiments.misma ...``).

``conf/misma.yaml`` -> the one study main (:func:`experiments._study_main.study_main`) -> :mod:`icgo.studies.misma`:
every table and figure into ``results/misma_*``, the fitted calibrations into the run directory
(``outputs/misma/<date>/<time>/models/``). ``--help`` lists the settings.
"""

from __future__ import annotations

import hydra
from omegaconf import DictConfig

from experiments._door import CONF_DIR, door, one_line_errors
from experiments._schema import register_defaults
from experiments._study_main import study_main
from icgo.core.devices import CacheSetting
from icgo.studies.misma.config import MismaConfig

#: Settings of the door, not of the study (excluded from the study's config dataclass).
ENTRY_KEYS = ("out_dir", "jax_cache_dir")

register_defaults("misma", MismaConfig, CacheSetting)  # the study's defaults, named first by conf/misma.yaml


@hydra.main(version_base="1.3", config_path=str(CONF_DIR), config_name="misma")
@one_line_errors
def main(cfg: DictConfig) -> float | None:
    """Hydra task: the study; returns its objective for a sweeper (``hydra/sweeper=optuna``); a bad setting exits 2
    with one line."""
    return study_main("misma", cfg, ENTRY_KEYS)


if __name__ == "__main__":
    door("misma", main)
