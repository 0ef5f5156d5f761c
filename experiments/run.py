"""ICGO-RELM study, the Hydra front door: ``icgo run strategy=three_stage`` (= ``python -m experiments.run ...``).

Composes ``conf/config.yaml`` (groups: dataset, model, optimizer, strategy, schedule, budget, split, fitness,
experiment) and runs it through the one study main (:func:`experiments._study_main.study_main`): the typed
:class:`icgo.studies.icgo_relm.run_config.RunConfig`, the study, the run directory
(``outputs/run/<date>/<time>``; a sweep re-run into its directory resumes), the summary and the verdict.
``--help`` lists the groups and settings; ``--cfg job`` prints the composed config. See docs/experiments.md.
"""

from __future__ import annotations

import hydra
from omegaconf import DictConfig

from experiments._door import CONF_DIR, door, one_line_errors
from experiments._study_main import study_main


@hydra.main(version_base="1.3", config_path=str(CONF_DIR), config_name="config")
@one_line_errors
def main(cfg: DictConfig) -> float | None:
    """Hydra task: one job of a run or a sweep; returns its objective for a sweeper that minimises one
    (``hydra/sweeper=optuna``: :func:`icgo.studies.common.tracking_tables.objective`), None for a failed job."""
    return study_main("icgo_relm", cfg)


if __name__ == "__main__":
    door("run", main)
