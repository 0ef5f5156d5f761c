"""Generalisation study: every method under every protocol of :mod:`icgo.studies.common.splits`.

A *cell* is a (data set, protocol) pair. In each cell every method is fitted on
the same members (the split depends only on the key, the repeat and the fold, so
the methods are paired repeat by repeat) and scored on the members' test rows:

* ``raw`` (eq. 1 on the raw sensors) and ``msa`` (MSA only);
* ``relm`` (random hidden weights), ``pso`` and ``ga`` (PSO-/GA-RELM) and the five
  CGO 4th-seed strategies (``cgo-original`` = CGO-RELM, then chaos, Gaussian,
  wavelet and the three-stage ICGO), all through :mod:`icgo.studies.icgo_relm`;
* ``physics``: the 12-parameter magnetometer model with an earth-fixed external
  field, fitted by the discrepancy engine on the member's training rows
  (:func:`icgo.discrepancy.fit.fit_members`) and inverted per station on its test rows
  (:func:`icgo.discrepancy.inversion.predict`).

Per (cell, method, repeat): MAE / RMSE / R^2 over the repeat's test rows (fold
protocols pool the folds: every row is predicted by the fold that held it out)
and the coverage of the member's 90 % conformal interval (:mod:`icgo.maths.conformal`;
not for raw, msa and physics, which carry no interval). Per cell: a two-sided
Wilcoxon signed-rank test of every method against the best (lowest mean MAE) on
the paired repeats, Holm-adjusted over the cell's comparisons. Per cell, survey-QC
counts (:mod:`icgo.physics.qc`): raw and after MSA (the first method's MSA ensemble) on all
the cell's stations (the target instrument's under transfer); after the physics
baseline (the field with its fitted disturbance removed) on the stations repeat 0
tests, each corrected by the member that tested it (all of them for fold protocols
and transfer; repeat 0's 30 % under the random split).
"""

from __future__ import annotations

import dataclasses
import logging
from typing import NamedTuple

import numpy as np
import pandas as pd

from icgo.maths.stats import holm, wilcoxon_paired
from icgo.optim import STRATEGIES
from icgo.optim.base import MIN_POP_SIZE
from icgo.artifacts.format import CORRECTED_B
from icgo.physics.frames import angle_diff
from icgo.studies.generalisation import report as generalisation_report
from icgo.studies.common import splits as _splits
from icgo.studies.icgo_relm import StudyConfig
from icgo.studies.common.study import Study

log = logging.getLogger(__name__)

_RELM = StudyConfig()  # the budget and model size default to the ICGO-RELM study's own (one source)

#: The data sets of :data:`icgo.datasets.registry.DATASETS` a cell can use (the ICGO paper's two, simulated;
#: ``SurveyData`` built by :func:`build_data`).
CELL_DATASETS = ("lab_casing", "well_conditions")
#: The default cells: every protocol on the data set it is meant for, and the random split on both.
CELLS = (("lab_casing", "random"), ("lab_casing", "leave_azimuth_out"), ("lab_casing", "transfer"),
         ("well_conditions", "random"), ("well_conditions", "leave_condition_out"))
#: Learned methods compared: plain RELM and the optimizers that search its hidden weights.
METHODS = ("relm", "pso", "ga", "cgo")
PHYSICS = "physics"


@dataclasses.dataclass(frozen=True)
class GeneralisationConfig:
    """Settings of the generalisation study.

    Attributes:
        cells: (data set, protocol) pairs (:data:`CELL_DATASETS` x :data:`icgo.studies.common.splits.PROTOCOLS`).
        n_repeats: repeats per cell (each a full pass over the folds for fold protocols).
        seed: the study key's seed (every method of a cell shares it: paired repeats).
        data_seed: noise seed of the simulated data sets (the transfer target's is ``transfer.seed``).
        methods: learned methods (:data:`METHODS`; ``relm`` = random hidden weights).
        strategies: the CGO strategies run side by side (default: every built-in one of the registry).
        pop_size, iterations: every optimizer's budget (default: the ICGO-RELM study's, the paper's 30, 100).
        hidden: RELM hidden units (default: the ICGO-RELM study's). physics: include the physics baseline.
        transfer: how the transfer target differs (:class:`icgo.studies.common.splits.TransferDraw`).
    """

    cells: tuple = CELLS
    n_repeats: int = 10
    seed: int = 0
    data_seed: int = 0
    methods: tuple = METHODS
    strategies: tuple = STRATEGIES
    pop_size: int = _RELM.budget.pop_size
    iterations: int = _RELM.budget.iterations
    hidden: int = _RELM.model.hidden
    physics: bool = True
    transfer: _splits.TransferDraw = _splits.TransferDraw()

    def __post_init__(self):
        from icgo.core.settings import is_int, need

        cells = tuple(tuple(c) for c in self.cells)
        object.__setattr__(self, "cells", cells)
        object.__setattr__(self, "strategies", tuple(self.strategies))
        object.__setattr__(self, "methods", tuple(self.methods))
        if isinstance(self.transfer, dict):
            object.__setattr__(self, "transfer", _splits.TransferDraw(**self.transfer))
        need(len(cells) >= 1
             and all(len(c) == 2 and c[0] in CELL_DATASETS and c[1] in _splits.PROTOCOLS for c in cells), "cells",
             f"must be [data set, protocol] pairs with a data set in {list(CELL_DATASETS)} and a protocol in "
             f"{list(_splits.PROTOCOLS)}, got {list(cells)}")
        need(len(set(cells)) == len(cells), "cells", f"must be distinct, got {list(cells)}")
        need(len(self.methods) >= 1 and set(self.methods) <= set(METHODS) and len(set(self.methods)) == len(self.methods),
             "methods", f"must be distinct names from {list(METHODS)}, got {list(self.methods)}")
        for name, lo in (("n_repeats", 2), ("seed", 0), ("data_seed", 0), ("pop_size", MIN_POP_SIZE), ("iterations", 1),
                         ("hidden", 1)):
            v = getattr(self, name)
            need(is_int(v) and v >= lo, name, f"must be an integer >= {lo}, got {v!r}")
        need(isinstance(self.physics, bool), "physics", f"must be true or false, got {self.physics!r}")

    def study_config(self, protocol: str, optimizer):
        """The ICGO-RELM study config of one method in a cell of ``protocol``."""
        return StudyConfig(split=dict(protocol=protocol, n_repeats=self.n_repeats, seed=self.seed),
                           model=dict(hidden=self.hidden), budget=dict(pop_size=self.pop_size,
                                      iterations=self.iterations),
                           optimizer=optimizer, strategies=self.strategies if optimizer == "cgo" else ("three_stage",))


def build_data(config: GeneralisationConfig) -> dict:
    """(data set, protocol) -> :class:`icgo.studies.icgo_relm.study.SurveyData` for every cell, simulated."""
    from icgo.datasets.registry import DATASETS
    from icgo.studies.icgo_relm import SurveyData

    out = {}
    for name, protocol in config.cells:
        ds = DATASETS[name](config.data_seed)
        target = None
        if protocol == "transfer":
            target = _splits.transfer_survey(name, config.data_seed, {}, config.transfer).frame
        out[(name, protocol)] = SurveyData(ds.frame, ds.meta, target)
    return out


def noise_floors(config: GeneralisationConfig) -> pd.DataFrame:
    """Per cell: the azimuth error the simulator's noise alone implies on the rows the cell tests (deg)."""
    from icgo.datasets.casing_stations import noise_floor

    rows = []
    for name, protocol in config.cells:
        seed = config.transfer.seed if protocol == "transfer" else config.data_seed
        f = noise_floor(name, seed)
        n = f["n"].to_numpy(float)
        rows.append({"dataset": name, "protocol": protocol, "mae": float(np.sum(f["mae"] * n) / n.sum()),
                     "rmse": float(np.sqrt(np.sum(f["rmse"] ** 2 * n) / n.sum()))})
    return pd.DataFrame(rows)


class GeneralisationResult(NamedTuple):
    """Attributes: records (``metrics``, ``coverage``, ``tests``, ``noise_floor``, ``qc``: survey-QC counts
    per cell and stage raw / msa / physics, see :func:`run`), models (none: an
    evaluation; ``experiments.run split=<protocol>`` saves the models of one method), seconds per cell."""

    records: dict
    models: dict
    seconds: dict


def _qc_stations(data, cfg) -> pd.DataFrame:
    """The stations a cell's QC counts: the target instrument's under transfer, else the source's (filtered)."""
    from icgo.studies.icgo_relm import filtered

    return filtered(data.target if data.target is not None else data.frame, cfg)[0].reset_index(drop=True)


def _qc_row(stage: str, frame: pd.DataFrame, B_after, meta: dict) -> dict:
    """One QC record: counts of :func:`icgo.physics.qc.survey_qc` of ``frame``'s G with ``B_after`` (nT)."""
    from icgo.physics.qc import survey_qc

    ref = (float(meta["total_field_nT"]), float(meta["dip_deg"]), float(meta.get("gravity_g", 1.0)))
    return {"stage": stage, **survey_qc(frame[["gx", "gy", "gz"]].to_numpy(float), B_after, *ref).counts}


def _physics(data, config: GeneralisationConfig, protocol: str, key) -> tuple[list[dict], dict]:
    """Metric rows of the physics baseline in one cell (members as the ICGO-RELM study builds them), and its
    QC record on the cell's QC stations (:func:`_qc_stations`) that repeat 0 tests, corrected by the member
    that tested each."""
    from icgo.discrepancy.fit import fit_members
    from icgo.discrepancy.inversion import predict
    from icgo.discrepancy.stations import stations_from_recording
    from icgo.io import recording as icgo_io
    from icgo.physics.metrics import azimuth_metrics
    from icgo.physics.frames import azimuth_from_gv
    from icgo.studies.icgo_relm import filtered

    cfg = config.study_config(protocol, None)
    rows = filtered(data.frame, cfg)[0]
    n_source = len(rows)
    if data.target is not None:
        rows = pd.concat([rows, filtered(data.target, cfg)[0]])
    mem = _splits.members(protocol, rows, key, cfg.ids(), cfg.split.train_fraction, n_source)
    source = icgo_io.validate(rows.iloc[:n_source].reset_index(drop=True), data.meta, source="physics baseline")
    members = fit_members(stations_from_recording(source), mem.train[:, :n_source])
    a_true = rows["azimuth_deg"].to_numpy(float)
    sensors = rows[["gx", "gy", "gz", "bx", "by", "bz"]].to_numpy(float)
    est = np.tile(a_true, (len(members), 1))  # rows a member does not test keep weight 0
    b_after = np.full((len(rows), 3), np.nan)
    for m, params in enumerate(members):
        sel = mem.test[m] > 0
        inv = predict(params, sensors[sel])
        est[m, sel] = np.asarray(inv.azimuth)
        if mem.repeat[m] == cfg.ids()[0]:
            b_after[sel] = np.asarray(inv.b_corrected)
    G, B = sensors[:, :3], sensors[:, 3:]
    err_raw = np.asarray(angle_diff(np.asarray(azimuth_from_gv(G, B)), a_true))
    out = []
    for r in cfg.ids():
        sel = mem.repeat == r
        F = int(sel.sum())
        m = azimuth_metrics(np.tile(a_true, F), est[sel].ravel(), np.tile(err_raw, F), mem.test[sel].ravel())
        out.append({"method": PHYSICS, "repeat": r, **{k: float(v) for k, v in m._asdict().items()}})
    qc_rows = np.arange(len(rows)) >= (n_source if data.target is not None else 0)
    qc_rows &= np.isfinite(b_after[:, 0])
    return out, _qc_row(PHYSICS, rows[qc_rows], b_after[qc_rows], data.meta)


def paired_tests(metrics: pd.DataFrame, value: str = "mae") -> pd.DataFrame:
    """Per cell: every method against the cell's best (lowest mean ``value``), Wilcoxon signed-rank on the
    paired repeats, Holm-adjusted over the cell's comparisons."""
    out = []
    for (name, protocol), g in metrics.groupby(["dataset", "protocol"], sort=False):
        wide = g.pivot_table(index="repeat", columns="method", values=value)
        best = wide.mean().idxmin()
        others = [m for m in wide.columns if m != best]
        p = [wilcoxon_paired(wide[m], wide[best]).p_value for m in others]
        for m, pv, pa in zip(others, p, holm(p) if p else []):
            out.append({"dataset": name, "protocol": protocol, "method": m, "best": best,
                        "mean_diff": float((wide[m] - wide[best]).mean()), "p_value": pv, "p_holm": float(pa)})
    return pd.DataFrame(out, columns=["dataset", "protocol", "method", "best", "mean_diff", "p_value", "p_holm"])


def run(data: dict, config: GeneralisationConfig, key) -> GeneralisationResult:
    """Every method in every cell; which cell / method starts is logged (INFO).

    Args:
        data: (data set, protocol) -> SurveyData (:func:`build_data`).
        config: :class:`GeneralisationConfig`. key: PRNG key shared by the methods of a cell.
    """
    import time

    from icgo.studies.icgo_relm import run as run_relm

    metrics, coverage, qc, seconds = [], [], [], {}
    for cell in config.cells:
        name, protocol = cell
        if cell not in data:
            raise ValueError(f"generalisation: no data for cell {cell}; build it with build_data(config)")
        t0 = time.perf_counter()
        for i, meth in enumerate(config.methods):
            log.info("%s / %s: %s", name, protocol, meth)
            res = run_relm(data[cell], config.study_config(protocol, None if meth == "relm" else meth), key)
            test = res.metrics[res.metrics["split"] == "test"]
            if i > 0:  # raw and msa once per cell
                test = test[~test["method"].isin(["raw", "msa"])]
            else:
                st = _qc_stations(data[cell], res.config)
                after = res.msa_model.apply(st)[list(CORRECTED_B)].to_numpy(float)
                qc += [{"dataset": name, "protocol": protocol, **row} for row in
                       (_qc_row("raw", st, st[["bx", "by", "bz"]].to_numpy(float), data[cell].meta),
                        _qc_row("msa", st, after, data[cell].meta))]
            metrics.append(test.drop(columns="split").assign(dataset=name, protocol=protocol))
            c = res.coverage
            pooled = (c.assign(hit=c["coverage"] * c["n_test"]).groupby(["method", "repeat"], sort=False)
                      .agg(hit=("hit", "sum"), n_test=("n_test", "sum"), halfwidth_deg=("halfwidth_deg", "mean"))
                      .reset_index())
            pooled["coverage"] = pooled.pop("hit") / pooled["n_test"]
            coverage.append(pooled.assign(dataset=name, protocol=protocol))
        if config.physics:
            log.info("%s / %s: physics", name, protocol)
            rows, qc_phys = _physics(data[cell], config, protocol, key)
            metrics.append(pd.DataFrame(rows).assign(dataset=name, protocol=protocol))
            qc.append({"dataset": name, "protocol": protocol, **qc_phys})
        seconds[f"{name}/{protocol}"] = time.perf_counter() - t0
    front = ["dataset", "protocol", "method", "repeat"]
    metrics = pd.concat(metrics, ignore_index=True)
    metrics = metrics[front + [c for c in metrics.columns if c not in front]]
    coverage = pd.concat(coverage, ignore_index=True)
    coverage = coverage[front + [c for c in coverage.columns if c not in front]]
    return GeneralisationResult({"metrics": metrics, "coverage": coverage, "tests": paired_tests(metrics),
                                 "noise_floor": noise_floors(config), "qc": pd.DataFrame(qc)}, {}, seconds)


def example() -> tuple:
    """A tiny instance: leave-azimuth-out and transfer on lab_casing at a 45 deg toolface step, RELM and CGO."""
    from icgo.datasets.casing_stations import lab_casing
    from icgo.studies.icgo_relm import SurveyData

    cfg = GeneralisationConfig(cells=(("lab_casing", "leave_azimuth_out"), ("lab_casing", "transfer")), n_repeats=2,
                               methods=("relm", "cgo"), strategies=("original", "three_stage"), pop_size=6,
                               iterations=3, hidden=8)
    ds = lab_casing(0, toolface_step_deg=45.0)
    target = _splits.transfer_survey("lab_casing", 0, {"toolface_step_deg": 45.0}, cfg.transfer).frame
    data = {("lab_casing", "leave_azimuth_out"): SurveyData(ds.frame, ds.meta),
            ("lab_casing", "transfer"): SurveyData(ds.frame, ds.meta, target)}
    return data, cfg


STUDY = Study("generalisation", GeneralisationConfig, run, "every method under the random, "
              "leave-azimuth-out, leave-condition-out and transfer protocols (paired repeats, Holm-adjusted "
              "tests, conformal coverage)", example, fits_models=False, load=build_data,
              write=generalisation_report.write, last=("generalisation.md",))
