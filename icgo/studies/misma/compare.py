"""MISMA vs SMA, one contribution at a time: the rows, their runs, paired tests and convergence.

MISMA differs from the standard SMA in four things at once: its box (around
U instead of a prior box around ``R^-1 = I, b = 0``), its coordinates
(box-normalised), its update operators (eqs. 12-19) and, in the paper's
reading, its objective (the gyro term J_gyro). Each row below changes one of
them; every row runs the same ``repeats`` keys (common random numbers), so
rows are compared repeat by repeat with the paired Wilcoxon test
(:func:`icgo.maths.stats.wilcoxon_paired`, Holm-adjusted within a variant).
The headline test (MISMA against the standard SMA, :func:`headline_tests`) and the
gyro-grade sweep (:func:`sweep_family`) are each one family over every variant.

Boxes (all (12,) in parameter units: ``R^-1`` dimensionless, ``b`` in nT):
``prior`` (SMA's prior knowledge), ``U`` (MISMA's box around the modulus fit),
``U_omega`` (around the gyro-reference fit), ``paper`` (128 / -68 uT:
:func:`icgo.optim.misma.paper_bounds`).
"""

from __future__ import annotations

import time
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import pandas as pd

from icgo.maths import stats
from icgo.optim import base
from icgo.optim.registry import get
from icgo.optim.sma import SMAConfig
from icgo.reporting.families import effect_word

OBJECTIVES = {"mag": "magnetometer + accelerometer (eqs. 5-8)", "mag+gyro": "eqs. 5-8 + J_gyro (M_omega)"}


class Row(NamedTuple):
    """One search: algorithm (``MISMA``/``SMA``), box name, coordinates (``raw``/``unit``), objective key."""

    algorithm: str
    box: str
    coords: str
    objective: str

    @property
    def label(self) -> str:
        return f"{self.algorithm}, box {self.box}, {self.coords}, {self.objective}"


#: The standard SMA (Li et al. 2020) as the paper compares against it.
STANDARD_SMA = Row("SMA", "prior", "raw", "mag")
#: SMA in MISMA's box (around the modulus fit U) but its own raw coordinates: only the box differs from STANDARD_SMA.
SMA_U_RAW = Row("SMA", "U", "raw", "mag")
#: SMA in MISMA's box (around the modulus fit U) and coordinates: only the operators differ from MISMA_U.
SMA_U = Row("SMA", "U", "unit", "mag")
#: MISMA without the gyro term (the magnetometer-only reading).
MISMA_U = Row("MISMA", "U", "unit", "mag")
#: SMA with MISMA's objective (J_gyro) and box (around the gyro-reference fit U_omega).
SMA_U_OMEGA = Row("SMA", "U_omega", "unit", "mag+gyro")
#: MISMA as the paper describes it (J_gyro, box around U_omega).
MISMA_U_OMEGA = Row("MISMA", "U_omega", "unit", "mag+gyro")


def rows(gyro_on: bool) -> list[Row]:
    """The rows of the comparison, each differing from a neighbour in one thing."""
    out = [STANDARD_SMA, SMA_U_RAW, SMA_U, MISMA_U] + ([SMA_U_OMEGA, MISMA_U_OMEGA] if gyro_on else [])
    return out + [paper_row(gyro_on)]


def paper_row(gyro_on: bool) -> Row:
    """MISMA in the paper's 128 / -68 uT box, with the study's objective."""
    return Row("MISMA", "paper", "unit", "mag+gyro" if gyro_on else "mag")


def headline_misma(gyro_on: bool, bounds: str) -> Row:
    """The row the study reports as "MISMA": the configured objective and box."""
    if bounds == "paper":
        return paper_row(gyro_on)
    return MISMA_U_OMEGA if gyro_on else MISMA_U


def contrasts(gyro_on: bool) -> list[tuple[str, Row, Row]]:
    """(name, row a, row b): what each pair of rows isolates."""
    out = [("box (SMA, raw coordinates)", STANDARD_SMA, SMA_U_RAW), ("box coordinates (SMA, box U)", SMA_U_RAW, SMA_U),
           ("update operators, magnetometer objective", SMA_U, MISMA_U)]
    if gyro_on:
        return out + [("gyro term + U_omega box (SMA)", SMA_U, SMA_U_OMEGA),
                      ("update operators, with the gyro term", SMA_U_OMEGA, MISMA_U_OMEGA),
                      ("gyro term + U_omega box (MISMA)", MISMA_U, MISMA_U_OMEGA),
                      ("paper box vs U_omega box (MISMA)", MISMA_U_OMEGA, paper_row(True))]
    return out + [("paper box vs U box (MISMA)", MISMA_U, paper_row(False))]


class UnitBoxFitness:
    """A fitness seen in box-normalised coordinates ``u = (x - lb) / (ub - lb)`` in [0, 1]^12.

    Lets SMA search MISMA's coordinates, so that only the update operators differ.
    Hashed by identity (one compiled program per instance), like the objectives.
    """

    def __init__(self, fitness, lb, ub):
        self.fitness, self.lb, self.span = fitness, jnp.asarray(lb), jnp.asarray(ub) - jnp.asarray(lb)

    def to_x(self, u):
        return self.lb + jnp.asarray(u) * self.span

    def __call__(self, pop, aux=None):
        return self.fitness(self.to_x(pop), aux)


class RowRun(NamedTuple):
    """A row's repeats: best_x (R, 12) in parameter units, best_f (R,), curve (R, T), seconds (wall)."""

    best_x: np.ndarray
    best_f: np.ndarray
    curve: np.ndarray
    seconds: float


def run_row(row: Row, objective, box, keys, pop_size: int, n_iter: int, misma_cfg, sma_z: float) -> RowRun:
    """Run one row's repeats in one vmapped call (``keys``: (R, 2), shared by every row)."""
    lb, ub = (np.asarray(v, np.float64) for v in box)
    fit, bounds = objective, (lb, ub)
    if row.coords == "unit" and row.algorithm == "SMA":  # MISMA normalises internally (icgo.optim.misma)
        fit, bounds = UnitBoxFitness(objective, lb, ub), (np.zeros(12), np.ones(12))
    name, cfg = ("misma", misma_cfg) if row.algorithm == "MISMA" else ("sma", SMAConfig(z=sma_z))
    t0 = time.time()
    r = base.run_batch(get(name), fit, bounds, keys, pop_size, n_iter, config=cfg)
    jax.block_until_ready(r.best_f)
    bx = np.asarray(fit.to_x(r.best_x)) if isinstance(fit, UnitBoxFitness) else np.asarray(r.best_x)
    return RowRun(bx, np.asarray(r.best_f), np.asarray(r.curve), time.time() - t0)


def iters_to(curve, threshold):
    """First iteration (1-based) with best fitness <= threshold, NaN if never; curve (R, T) -> (R,)."""
    hit = np.asarray(curve) <= threshold
    return np.where(hit.any(1), hit.argmax(1) + 1.0, np.nan)


def convergence(fast: RowRun, slow: RowRun) -> dict:
    """The paper's "converges X % faster", defined so that it can be computed.

    Level = the worse (larger) of the two rows' median final best fitness: a
    fitness each reaches in at least half of its repeats. Iterations to reach
    it per repeat; ``faster_pct = 100 (1 - median_fast / median_slow)``. Both
    rows must minimise the same objective.
    """
    level = float(max(np.median(fast.best_f), np.median(slow.best_f)))
    it_f, it_s = iters_to(fast.curve, level), iters_to(slow.curve, level)
    mf, ms = float(np.nanmedian(it_f)), float(np.nanmedian(it_s))
    return {"level": level, "median_iters_a": mf, "median_iters_b": ms,
            "reached_a": int(np.isfinite(it_f).sum()), "reached_b": int(np.isfinite(it_s).sum()),
            "faster_pct": 100.0 * (1.0 - mf / ms)}


def fair_table(runs: dict, scores: dict, boxes_used: dict) -> pd.DataFrame:
    """One row per search: its settings, static-point |azimuth error| (deg) over repeats, parameters recovered,
    and the physics its median repeat must respect at the stops (dip spread, |B| spread, cond(R^-1),
    ``degenerate`` by :data:`icgo.models.cal_sanity.LIMITS`): an error that looks small on a degenerate fit is no win.

    (Wall times are in the study summary's ``runtime_s``, not here: records are deterministic.)

    Args:
        runs: Row -> RowRun. scores: Row -> :class:`icgo.studies.misma.simulated.Scores`.
        boxes_used: box name -> a short description with units.
    """
    out = []
    for row, rr in runs.items():
        sc = scores[row]
        e = sc.err
        out.append({"row": row.label, "algorithm": row.algorithm, "box": boxes_used[row.box],
                    "coordinates": row.coords,
                    "objective": OBJECTIVES[row.objective], "az_err_mean_deg": float(e.mean()),
                    "az_err_std_deg": float(e.std(ddof=1)) if len(e) > 1 else 0.0, "az_err_max_deg": float(e.max()),
                    "params_within_median": float(np.median(sc.within)),
                    "repeats_all_12_within": int((sc.within == 12).sum()),
                    "best_f_median": float(np.median(rr.best_f)), **sc.physics})
    return pd.DataFrame(out)


def paired_tests(pairs: list, errors: dict) -> pd.DataFrame:
    """Paired Wilcoxon (two-sided) on per-repeat errors for each contrast a -> b, Holm-adjusted together; ``b_vs_a``:
    the change's effect on the error (:func:`icgo.reporting.families.effect_word` of the median of b - a)."""
    recs = []
    for name, a, b in pairs:
        if a in errors and b in errors:
            t = stats.wilcoxon_paired(errors[a], errors[b])
            recs.append({"contrast": name, "a": a.label, "b": b.label, "mean_a_deg": float(errors[a].mean()),
                         "mean_b_deg": float(errors[b].mean()),
                         "median_b_minus_a_deg": float(np.median(errors[b] - errors[a])), "p": t.p_value})
    df = pd.DataFrame(recs)
    if len(df):
        df["p_holm"] = stats.holm(df["p"].to_numpy())
        df["b_vs_a"] = [effect_word(d, p) for d, p in zip(df["median_b_minus_a_deg"], df["p_holm"])]
    return df


def headline_tests(summaries: list[dict], errors: list[dict]) -> None:
    """MISMA against the standard SMA on each variant: paired Wilcoxon on the per-repeat mean |azimuth error| at the
    stops, Holm over the variants (one family: the headline table's). Adds ``p_MISMA_vs_SMA``,
    ``p_MISMA_vs_SMA_holm`` and ``MISMA_vs_SMA`` ("lower", "higher" or "no significant difference", MISMA's error
    against SMA's) to each variant's summary, in place.

    Args:
        summaries: the variants' summaries (dicts), in order.
        errors: per variant ``{"MISMA": (R,), "SMA": (R,)}`` errors (deg), paired by repeat.
    """
    p = [stats.wilcoxon_paired(e["MISMA"], e["SMA"]).p_value for e in errors]
    for s, e, pv, ph in zip(summaries, errors, p, stats.holm(np.asarray(p)) if p else []):
        s.update({"p_MISMA_vs_SMA": float(pv), "p_MISMA_vs_SMA_holm": float(ph),
                  "MISMA_vs_SMA": effect_word(float(np.median(e["MISMA"] - e["SMA"])), float(ph))})


def sweep_family(df: pd.DataFrame) -> pd.DataFrame:
    """The gyro-grade sweep's cells (every variant x grade) as one Holm family: ``p_holm`` over all of them and
    ``J_gyro`` ("lower", "higher" or "no significant difference": MISMA's error with the gyro term against without)."""
    if not len(df):
        return df
    df = df.copy()
    df["p_holm"] = stats.holm(df["p"].to_numpy())
    df["J_gyro"] = [effect_word(float(d), float(ph)) for d, ph in
                    zip(df["MISMA_gyro_az_err_median_diff_deg"], df["p_holm"])]
    return df
