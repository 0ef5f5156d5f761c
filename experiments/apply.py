"""Apply a fitted model to a new survey: ``icgo apply model=<run dir or model> data=<survey.csv>``
(= ``python -m experiments.apply ...``).

Any saved model (:func:`icgo.artifacts.registry.load_model`; a run directory of ``run`` gives its main model, one of
``calibrate`` the calibration its record recommends) corrects the survey: ``<survey>_corrected.csv`` and ``.meta.json``
into the run directory (``outputs/apply/<date>/<time>/`` or ``out=``), both or neither; the MAE (or "QC only"), the
QC counts and the verdict printed (:mod:`experiments._data_doors`). A bad setting: one line, exit 2; a bad model,
survey or output place: exit 1, nothing written; a result not to be used as it stands: exit 3, files written.
"""

from __future__ import annotations

import hydra
from omegaconf import DictConfig

from experiments._door import CONF_DIR, door, one_line_errors
from experiments._study_main import study_main


@hydra.main(version_base="1.3", config_path=str(CONF_DIR / "apply"), config_name="apply")
@one_line_errors
def main(cfg: DictConfig) -> None:
    """Hydra task: one survey, one model."""
    study_main("apply", cfg)


if __name__ == "__main__":
    door("apply", main)
