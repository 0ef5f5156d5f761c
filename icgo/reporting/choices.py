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


#: The RELM ridge parameter of every ICGO-RELM study (``StudyConfig.model.lam``).
LAMBDA = DataChoice("lambda = 1e-3", "lab_casing", 1, "the validation rows inside the training rows (study seed 100)",
                    "docs/relm_study.md")

#: ``lab_casing`` data seeds that choices were made on (what was read on each: ``icgo.studies.icgo_relm.worlds.study``, which
#: reports worlds only of other seeds); a one-draw table on one of them says so in its protocol line.
LAB_CASING_DEVELOPMENT_SEEDS = tuple(range(12))


def development_note(dataset: str, seed) -> str:
    """The protocol line's words for a one-draw table on a development seed ('' for any other data seed)."""
    if dataset != "lab_casing" or seed not in LAB_CASING_DEVELOPMENT_SEEDS:
        return ""
    return (f"lab_casing noise seed {seed} is a development seed (icgo.studies.icgo_relm.worlds.study.DEVELOPMENT_SEEDS: "
            + ("the sweeps and the Fig. 9 ablation were run and read on its test rows before the defaults were kept, "
               "and the defaults stayed the published readings" if seed == 0 else "choices were made on it")
            + "), so this table is one draw, not a claim; the claims are over worlds of other seeds "
              "(docs/relm_study.md, \"Worlds\")")
