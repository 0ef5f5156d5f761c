"""The discrepancy workflow: ``icgo discrepancy data=FILE.csv`` (= ``python -m experiments.discrepancy ...``).

``data=`` a contract CSV, a circuitpython-mag-cal JSON, ``lab_casing``, ``sim:EFFECT+EFFECT``, ``mag_cal:DEVICE``;
``study=hidden|devices|lab_casing`` writes ``results/discrepancy_<study>.md``. Through the one study main
(:mod:`experiments._data_doors`) to :mod:`icgo.studies.discrepancy`: prints the search and the verdict, writes
report.md, discrepancy.json, the figures and the fitted physics model into the run directory
(``outputs/discrepancy/<date>/<time>``). A bad setting: one line per problem, exit 2; bad input data: one line,
exit 1. ``--help`` lists the settings.
"""

from __future__ import annotations

import hydra
from omegaconf import DictConfig

from experiments._door import CONF_DIR, door, one_line_errors
from experiments._schema import register
from experiments._study_main import study_main
from icgo.core.devices import CacheSetting
from icgo.discrepancy.config import WorkflowConfig
from icgo.studies.discrepancy.job import ENTRY_KEYS

# conf/discrepancy.yaml's schema
register("discrepancy", WorkflowConfig, tuple(k for k in ENTRY_KEYS if k != "hydra"), CacheSetting)


@hydra.main(version_base="1.3", config_path=str(CONF_DIR), config_name="discrepancy")
@one_line_errors
def main(cfg: DictConfig) -> None:
    """Hydra task: one data set (or one study=)."""
    study_main("discrepancy", cfg)


if __name__ == "__main__":
    door("discrepancy", main)
