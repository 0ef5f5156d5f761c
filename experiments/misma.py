"""MISMA study entry point: ``conf/misma.yaml`` -> :mod:`icgo.studies.misma` -> ``results/misma_*``.

One command writes every table and figure into ``results/misma_*`` and the
fitted calibrations into the Hydra run directory (``outputs/misma/<time>/models/``)::

    .venv/bin/python -m experiments.misma                    # full study
    .venv/bin/python -m experiments.misma simulated.repeats=3 simulated.n_iter=300 real.enabled=false

The science is in :mod:`icgo.studies.misma`, the tables, figures, summary and models in
:mod:`icgo.studies.misma_report`; the one study main (:func:`hydra_plugins.icgo_launcher.door.study_main`)
composes the config, loads, runs and writes.
"""

from __future__ import annotations

import hydra
from omegaconf import DictConfig

from hydra_plugins.icgo_launcher.door import hydra_cli, one_line_errors, study_main

#: Settings of the entry point, not of the study (excluded from the study's config dataclass).
ENTRY_KEYS = ("out_dir",)


@hydra.main(config_path="../conf", config_name="misma", version_base="1.3")
@one_line_errors
def main(cfg: DictConfig) -> None:
    """Hydra entry point: ``python -m experiments.misma [overrides]``; a bad setting exits 2 with one line."""
    study_main("misma", cfg, ENTRY_KEYS)


if __name__ == "__main__":
    hydra_cli("misma", main)
