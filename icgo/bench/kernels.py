"""What the benchmarks measure with: the study's data and fitness settings, a numpy reference fitness, timing
helpers, the flop count of one evaluation and mealpy's CGO on the same data.

Shared by :mod:`icgo.bench.cpu` (the CPU benchmark) and :mod:`icgo.bench.backend` (the per-backend
check), so that neither imports the other.
"""

from __future__ import annotations

import time
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

import icgo  # noqa: F401  (enables float64)
from icgo.datasets import casing_stations as datasets
from icgo.models import relm
from icgo.studies.icgo_relm.config import PRECISIONS, StudyConfig
from icgo.studies.icgo_relm.prepare import frame_arrays, prepare, sigma_filter
from icgo.studies.icgo_relm.search import train_rows

HIDDEN = 30
LAM = 1e-3
N_INPUTS = relm.N_INPUTS
#: Feature dtype of the study's default search kernel (``StudyConfig.precision``): what the benchmark's study path runs.
FEATURES = PRECISIONS[StudyConfig().precision][0]


# --------------------------------------------------------------------------- flops
def flops_per_eval(n: int, hidden: int = HIDDEN, d: int = N_INPUTS) -> int:
    """Floating-point operations of one float64 RELM fitness evaluation (train mode).

    Counted as a dense-algebra textbook does (one exp = 1 flop, fused
    multiply-add = 2): pre-activation ``X W + b`` 2ndL + nL, sigmoid 3nL
    (negate, exp, add, divide counted as 3), Gram ``H^T H`` 2nL^2 (as a
    general product computes it), ``H^T T`` 2nL, Cholesky L^3/3, two triangular
    solves 2L^2, prediction ``H beta`` 2nL, residual, square and sum 3n, plus
    ``L`` for the ridge term. Iterative-refinement work of the fast kernel is
    *not* counted: it is overhead, not work the fitness needs.

    Args:
        n: training rows. hidden: L. d: inputs.
    Returns:
        flops per evaluation (int).
    """
    L = hidden
    return int(2 * n * d * L + n * L + 3 * n * L + 2 * n * L * L + 2 * n * L + L**3 // 3 + 2 * L * L
               + 2 * n * L + 3 * n + L)


# ------------------------------------------------------------------ numpy reference
def numpy_fitness(theta: np.ndarray, X: np.ndarray, T: np.ndarray, lam: float = LAM, hidden: int = HIDDEN) -> float:
    """RELM training RMSE of one theta in plain numpy float64 (the mealpy objective).

    Args:
        theta: (7 L,) hidden weights then biases. X: (n, 6) standardised training
            inputs. T: (n,) targets (deg). lam: ridge lambda. hidden: L.
    Returns:
        RMSE (deg); +inf if not finite.
    """
    W = theta[: N_INPUTS * hidden].reshape(N_INPUTS, hidden)
    H = 1.0 / (1.0 + np.exp(-(X @ W + theta[N_INPUTS * hidden:])))
    A = H.T @ H + lam * np.eye(hidden)
    c = np.linalg.cholesky(A)
    y = np.linalg.solve(c, H.T @ T)  # forward solve (general solve on a triangular matrix)
    beta = np.linalg.solve(c.T, y)
    r = H @ beta - T
    f = float(np.sqrt(np.mean(r * r)))
    return f if np.isfinite(f) else float("inf")


# ---------------------------------------------------------------------------- data
class StudyData(NamedTuple):
    """The study's data for R repeats (leading axis R)."""

    fit: relm.FitData       # all rows, masks (library fitness)
    compact: relm.TrainRows  # training rows only (fast kernel)
    n_train: int
    n_rows: int
    prep: object            # icgo_relm_prepare.Prepared, for scoring
    a_true: np.ndarray
    G: np.ndarray           # (N, 3) g
    B: np.ndarray           # (N, 3) nT


def study_data(n_repeats: int, seed: int = 0, dataset_seed: int = 0, tile: int = 1) -> StudyData:
    """Simulated lab-casing data (ICGO 3.1) prepared exactly as ``run_study`` does.

    Args:
        n_repeats: repeats (splits). seed: study seed. dataset_seed: simulator seed.
        tile: repeat the data set ``tile`` times (data-size scaling rows).
    """
    cfg = StudyConfig(split=dict(n_repeats=n_repeats, seed=seed))
    G, B, a = frame_arrays(datasets.lab_casing(dataset_seed).frame)
    kept = sigma_filter(G, B, a, cfg.split.sigma_filter)
    G, B, a = (np.tile(x[kept], (tile, 1)) if x.ndim == 2 else np.tile(x[kept], tile) for x in (G, B, a))
    prep, _ = prepare(None, G, B, a, cfg, jax.random.PRNGKey(seed))
    rows = train_rows(prep)
    return StudyData(prep.data, rows, int(rows.T.shape[1]), len(a), prep, a, G, B)


def slice_tree(tree, i):
    return jax.tree_util.tree_map(lambda x: x[i], tree)


# ------------------------------------------------------------------------- timing
def best_time(f, *args, reps: int = 5) -> float:
    jax.block_until_ready(f(*args))
    best = float("inf")
    for _ in range(reps):
        t = time.perf_counter()
        jax.block_until_ready(f(*args))
        best = min(best, time.perf_counter() - t)
    return best


def matmul_gflops(dtype, n: int = 2048, reps: int = 5) -> float:
    """Rate of a large dense n x n matrix product in ``dtype`` (GFLOP/s, best of reps)."""
    a = jax.random.uniform(jax.random.PRNGKey(0), (n, n), jnp.dtype(dtype))
    f = jax.jit(lambda x: x @ x)
    return 2 * n**3 / best_time(f, a, reps=reps) / 1e9


def population(key, P: int, hidden: int = HIDDEN):
    return jax.random.uniform(key, (P, relm.n_params(hidden)), jnp.float64, -1.0, 1.0)


class _NumpyObjective:
    """:func:`numpy_fitness` on one repeat's rows, picklable (mealpy's ``mode="process"`` sends it to workers)."""

    def __init__(self, X: np.ndarray, T: np.ndarray):
        self.X, self.T = X, T

    def __call__(self, theta) -> float:
        return numpy_fitness(np.asarray(theta), self.X, self.T)


def run_mealpy(sd: StudyData, n_runs: int, pop_size=30, iterations=100, mode: str = "single",
               n_workers: int | None = None, first: int = 0):
    """mealpy 3.x OriginalCGO on :func:`numpy_fitness`, one run per (strategy, repeat) slot.

    Run j (``first`` <= j < ``first + n_runs``) uses repeat ``j % R`` of the study's data and seed j.
    ``mode``/``n_workers``: mealpy's own parallel modes (``"process"``: each population's fitness on
    ``n_workers`` processes).

    Returns:
        dict: total_s, per_run_s, evals_per_run (mealpy's counter), best_f (n_runs,).
    """
    from mealpy import CGO, FloatVar

    R = sd.compact.T.shape[0]
    D = relm.n_params(HIDDEN)
    best, evals = [], []
    t0 = time.perf_counter()
    for j in range(first, first + n_runs):
        obj = _NumpyObjective(np.asarray(sd.compact.Xa[j % R])[:, :N_INPUTS], np.asarray(sd.compact.T[j % R]))
        problem = {"obj_func": obj, "bounds": FloatVar(lb=[-1.0] * D, ub=[1.0] * D), "minmax": "min",
                   "log_to": None}
        model = CGO.OriginalCGO(epoch=iterations, pop_size=pop_size)
        g = model.solve(problem, mode=mode, n_workers=n_workers, seed=j)
        best.append(float(g.target.fitness))
        evals.append(model.nfe_counter)
    total = time.perf_counter() - t0
    return {"total_s": total, "per_run_s": total / n_runs, "evals_per_run": int(np.median(evals)),
            "best_f": np.asarray(best)}
