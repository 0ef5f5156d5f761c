"""Every study by name: one literal mapping (no registration at import)."""

from __future__ import annotations

from icgo.core.errors import SettingError
from icgo.studies import calibration, discrepancy, generalisation, gyro, icgo_relm, misma, optimizers
from icgo.studies.common.study import Study

STUDIES: dict[str, Study] = {
    "icgo_relm": icgo_relm.STUDY,
    "misma": misma.STUDY,
    "gyro": gyro.STUDY,
    "optimizers": optimizers.STUDY,
    "discrepancy": discrepancy.STUDY,
    "generalisation": generalisation.STUDY,
    "calibration": calibration.STUDY,
}


def get_study(name: str) -> Study:
    """Look up a study by name; a one-line :class:`~icgo.core.errors.SettingError` naming the choices if unknown."""
    if name not in STUDIES:
        raise SettingError(f"unknown study {name!r}; choose one of {sorted(STUDIES)}")
    return STUDIES[name]


def all_studies() -> dict[str, Study]:
    """Every study, name -> :class:`~icgo.studies.common.study.Study`."""
    return dict(STUDIES)
