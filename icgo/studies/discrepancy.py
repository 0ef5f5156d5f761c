"""The discrepancy workflow as a registered study (:mod:`icgo.discrepancy`).

``run(stations, WorkflowConfig, key)``: the greedy search of
:func:`icgo.discrepancy.run_workflow` (fold assignment from ``key``); records:
the gap after each step and one row per step; model: the final physics model
(:class:`icgo.artifacts.discrepancy.PhysicsModel`), which ``apply`` inverts on
new surveys.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import jax
import numpy as np
import pandas as pd

from icgo import discrepancy as D
from icgo.artifacts.discrepancy import PhysicsModel
from icgo.studies.study import Study


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


def run(data: D.Stations, config: D.WorkflowConfig, key) -> DiscrepancyResult:
    """Run the workflow on stations; the key sets the held-out folds."""
    res = D.run_workflow(data, config, key)
    gaps = D.gap_table(res)
    summary = pd.DataFrame([{"kind": res.kind, "model": ",".join(res.model), "heldout": res.heldout,
                             "noise_floor": res.noise_floor, "structure_remains": bool(res.structure_remains)}])
    return DiscrepancyResult(res, {"gaps": gaps, "steps": step_table(res), "summary": summary},
                             {PhysicsModel.KIND: PhysicsModel.from_result(res, data.G, data.B)})


def example() -> tuple:
    """A tiny case (seconds): 60 random-attitude stations with a hard-iron bias hidden."""
    st = D.simulate(jax.random.PRNGKey(3), 60, {"hard_iron": np.array([300.0, -200.0, 150.0])})
    return st, D.WorkflowConfig(max_effects=2, k_folds=3)


STUDY = Study("discrepancy", D.WorkflowConfig, run, "find, name and add the missing physical effect "
              "(greedy held-out search over the effect vocabulary)", example)
