"""Choices the reported tables depend on, with the data each was made on, for the writers that must say so.

docs/reporting.md lists every choice; the ones a table's protocol line states in words are here, so the words
follow the facts (the transfer target of the generalisation table, for instance, is the noise draw the RELM's
lambda was chosen on, and its seeds line says so).
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class DataChoice:
    """A setting chosen on data: which setting, on which data set and noise seed, which rows, where it is written."""

    setting: str
    dataset: str
    seed: int
    rows: str
    where: str

    def sentence(self) -> str:
        return f"{self.setting} was chosen on {self.rows} of {self.dataset} noise seed {self.seed} ({self.where})"


#: The RELM ridge parameter of every ICGO-RELM study (``StudyConfig.lam``).
LAMBDA = DataChoice("lambda = 1e-3", "lab_casing", 1, "the validation rows inside the training rows (study seed 100)",
                    "docs/relm_study.md")
