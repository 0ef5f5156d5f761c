"""The discrepancy workflow as a registered study (:mod:`icgo.discrepancy`).

``run(DiscrepancyData, WorkflowConfig, key)``: the greedy search of
:func:`icgo.discrepancy.run_workflow` (fold assignment from ``key``; None: the workflow's own); records:
the gap after each step and one row per step; model: the final physics model
(:class:`icgo.artifacts.discrepancy.PhysicsModel`), which ``apply`` inverts on
new surveys. :func:`load` reads or simulates the stations of a ``data=`` value
(:func:`icgo.studies.discrepancy.job.load_stations`), :func:`write` the run directory of one fit.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, NamedTuple

import jax
import numpy as np
import pandas as pd

from icgo import discrepancy as D
from icgo.discrepancy import report
from icgo.artifacts.discrepancy import PhysicsModel, station_qc
from icgo.physics.qc import qc_sentence
from icgo.studies.discrepancy import job
from icgo.studies.common.study import Study


class DiscrepancyData(NamedTuple):
    """What the workflow runs on: the stations, a one-line description of them, the hidden effects when
    simulated (name -> parameters; else None)."""

    stations: D.Stations
    label: str
    truth: dict | None = None


class DiscrepancyResult(NamedTuple):
    """Attributes: result (:class:`icgo.discrepancy.Result`), records, models."""

    result: Any
    records: dict
    models: dict


def step_table(res) -> pd.DataFrame:
    """One row per added effect: name, separability, held-out chi2 before/after, evidence (z, BIC)."""
    rows = [{"step": i + 1, "effect": s.name, "separable": s.separable, "equivalent": ",".join(s.equivalent),
             "heldout_before": s.heldout_before, "heldout_after": s.heldout_after, "z_improvement": s.z_improvement,
             "runner_up": s.runner_up or "", "margin_z": s.margin_z, "delta_bic": s.delta_bic,
             "params": " ".join(f"{p:.6g}" for p in s.params), "stderr": " ".join(f"{p:.3g}" for p in s.stderr),
             "units": s.units} for i, s in enumerate(res.steps)]
    cols = ["step", "effect", "separable", "equivalent", "heldout_before", "heldout_after", "z_improvement",
            "runner_up", "margin_z", "delta_bic", "params", "stderr", "units"]
    return pd.DataFrame(rows, columns=cols)


def load(config: D.WorkflowConfig, *, data: str, seed: int, n_stations: int, design: str, columns: dict | None = None,
         shots: dict | None = None) -> DiscrepancyData:
    """The stations of a ``data=`` value (:func:`icgo.studies.discrepancy.job.load_stations`, simulated with
    ``config.noise``), checked (too few, NaN: one line before the workflow starts); prints what was read. The
    inputs are the front door's settings of the same names (conf/discrepancy.yaml).

    Raises:
        icgo.core.errors.DataError / ValueError: bad data (one line). SettingError: a bad reading setting.
    """
    st, label, truth = job.load_stations(data, seed, n_stations, design, config.noise, columns, shots)
    D.check_stations(st)
    print(f"data: {label} ({st.n} stations, {'reference attitude' if st.has_reference else 'groups, no reference'})")
    return DiscrepancyData(st, label, truth)


def run(data: DiscrepancyData, config: D.WorkflowConfig, key) -> DiscrepancyResult:
    """Run the workflow on the stations; the key sets the held-out folds."""
    st = data.stations
    res = D.run_workflow(st, config, key)
    gaps = D.gap_table(res)
    summary = pd.DataFrame([{"kind": res.kind, "model": ",".join(res.model), "heldout": res.heldout,
                             "noise_floor": res.noise_floor, "structure_remains": bool(res.structure_remains)}])
    return DiscrepancyResult(res, {"gaps": gaps, "steps": step_table(res), "summary": summary},
                             {PhysicsModel.KIND: PhysicsModel.from_result(res, st.G, st.B)})


def write(result: DiscrepancyResult, data: DiscrepancyData, config, stage: Path, invocation) -> str:
    """The run directory of one fit (:func:`icgo.studies.discrepancy.job.write_fit`: report, JSON, figures, the
    physics model); returns the search log, the steps, the survey QC and where the report and model are."""
    res, model = result.result, result.models[PhysicsModel.KIND]
    qc = station_qc(model, data.stations)
    job.write_fit(stage, res, data.label, data.truth, qc, model)
    return "\n".join([*report.search_log(res), *report.step_summary(res),
                      qc_sentence(qc) if qc else "survey QC: no reference field given",
                      f"report: {invocation.out / 'report.md'}", f"model: {invocation.out / 'discrepancy_model.json'}"])


def example() -> tuple:
    """A tiny case (seconds): 60 random-attitude stations with a hard-iron bias hidden."""
    hidden = {"hard_iron": np.array([300.0, -200.0, 150.0])}
    st = D.simulate(jax.random.PRNGKey(3), 60, hidden)
    return DiscrepancyData(st, "60 simulated stations with a hidden hard_iron", hidden), \
        D.WorkflowConfig(max_effects=2, k_folds=3)


STUDY = Study("discrepancy", D.WorkflowConfig, run, "find, name and add the missing physical effect "
              "(greedy held-out search over the effect vocabulary)", example, load=load, write=write,
              last=("report.md",))
