"""What several ICGO-RELM tables say beside their numbers: the strategies they compare, the noise floor of the data
set, the reduction against plain RELM and the tuned RELM's chosen cell.
"""

from __future__ import annotations

import pandas as pd

from icgo.datasets.casing_stations import noise_floor
from icgo.models.relm import TUNE_HIDDEN, TUNE_LAMBDA
from icgo.optim import STRATEGIES
from icgo.studies.icgo_relm.results.outputs import PAPER
from icgo.studies.icgo_relm.names import method_name
from icgo.reporting.run_collection import Runs
from icgo.reporting.table_writer import one_draw
from icgo.studies.icgo_relm.config import StudyConfig

#: The registry's built-in CGO 4th-seed strategies (:data:`icgo.optim.STRATEGIES`) that the paper reports (its
#: Table 2: the five the paper's tables compare, in index order) and the mutated ones (all but ``original``). A
#: built-in added later is in every study that names it, not in the paper's tables.
STRATEGIES5 = tuple(s for s in STRATEGIES if s in PAPER["table2"])
STRATEGIES4 = tuple(s for s in STRATEGIES5 if s != "original")


def tuned_note(runs: Runs, m: pd.DataFrame, others) -> str:
    """The tuned plain-RELM baseline: its chosen cell (on validation rows inside the training rows) and the CGO rows'
    mean MAE against it (the paired tests are the table's)."""
    info = [r for r in runs.runs if "relm-tuned" in r.get("methods", []) and r.get("tuning")]
    cell = info[-1]["tuning"] if info else {}
    t = m[m.method == "relm-tuned"]["mae"].mean()
    parts = [f"{method_name(o)}: mean MAE {100 * (m[m.method == o]['mae'].mean() / t - 1):+.1f} %" for o in others]

    d = StudyConfig()
    return (f"Tuned RELM (`model.tune=true fitness=validation optimizer=none`): hidden L and lambda chosen on "
            f"L in {{{', '.join(map(str, TUNE_HIDDEN))}}} x lambda in {TUNE_LAMBDA[0]:g} .. {TUNE_LAMBDA[-1]:g} by the "
            f"mean validation RMSE over repeats on the training rows only ({100 * d.fitness.val_fraction:.0f} % of them held "
            f"out), chosen L = {cell.get('hidden')}, lambda = {cell.get('lam')}. Against it: "
            f"{'; '.join(parts) or 'no CGO runs'} (tests below). The CGO rows use L = {d.model.hidden}.")


def floor_note(dataset: str = "lab_casing") -> str:
    """The noise floor of the data set beside every table (:func:`icgo.datasets.casing_stations.noise_floor`, data
    seed 0)."""
    f = noise_floor(dataset, 0).iloc[0]
    return (f"Noise floor: the same `{dataset}` draw (seed 0, as the presets) with the casing, every systematic "
            f"sensor effect and the spikes removed gives an azimuth error of MAE {f.mae:.4f} deg, RMSE "
            f"{f.rmse:.4f} deg (all {int(f.n)} rows): the simulated sensor noise alone, the best any "
            "compensation can do on average.")


def reduction_note(m: pd.DataFrame, base: str, others) -> str:
    parts = []
    b_mae, b_rmse = m[m.method == base]["mae"].mean(), m[m.method == base]["rmse"].mean()
    for o in others:
        mae, rmse = m[m.method == o]["mae"].mean(), m[m.method == o]["rmse"].mean()
        parts.append(f"{method_name(o)}: MAE -{100 * (1 - mae / b_mae):.1f} %, RMSE -{100 * (1 - rmse / b_rmse):.1f} %")
    return (f"Reduction vs plain RELM (means over repeats): {'; '.join(parts)}; it rests on {one_draw(m)}. Paper: "
            f"three-stage ICGO-RELM vs RELM, MAE -{PAPER['reduction_pct']['mae']} %, RMSE "
            f"-{PAPER['reduction_pct']['rmse']} % (abstract, section 3.3).")
