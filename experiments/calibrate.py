"""Calibration of a user's recording: ``icgo calibrate data=shots.csv`` (= ``python -m experiments.calibrate ...``).

``conf/calibrate.yaml`` (its schema made from :class:`icgo.studies.calibration.study.CalibrationConfig`) -> the one study
main -> :mod:`icgo.studies.calibration.job`: the shots read, every method fitted and scored, one recommended, the run
directory written (``outputs/calibrate/<date>/<time>``). ``data=bundled``: the 9 bundled devices -> results/. A bad
setting: one line, exit 2; bad data: one line, exit 1, nothing written; nothing to recommend: every file written,
one line, exit 4. ``--help`` lists the settings.
"""

from __future__ import annotations

import hydra
from omegaconf import DictConfig

from experiments._data_doors import CALIBRATE_KEYS
from experiments._door import CONF_DIR, door, one_line_errors
from experiments._schema import register
from experiments._study_main import study_main
from icgo.core.devices import CacheSetting
from icgo.studies.calibration.study import CalibrationConfig

register("calibrate", CalibrationConfig, CALIBRATE_KEYS, CacheSetting)  # conf/calibrate.yaml's schema


@hydra.main(version_base="1.3", config_path=str(CONF_DIR), config_name="calibrate")
@one_line_errors
def main(cfg: DictConfig) -> None:
    """Hydra task: one recording (or data=bundled)."""
    study_main("calibration", cfg)


if __name__ == "__main__":
    door("calibrate", main)
