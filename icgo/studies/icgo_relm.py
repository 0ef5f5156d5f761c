"""The ICGO-RELM study core (ICGO paper sections 3.1-3.4), plain Python, no Hydra.

Pipeline, per repeat (one PRNG key each, ``fold_in(PRNGKey(seed), repeat_id)``):

1. 3-sigma filter (host-side, once for the data set; :func:`sigma_filter`);
2. the split (``protocol``, :mod:`icgo.studies.splits`): the paper's random 7:3 split
   (a permutation of the rows, the first ``round(0.7 N)`` are training rows)
   or a generalisation protocol (whole azimuths or well conditions held out,
   or a second instrument build as the test set). Each fitted model is a
   *member* with 0/1 row masks, so shapes stay fixed across members;
3. multi-station analysis on the training rows only (:mod:`icgo.methods.msa`);
4. target = azimuth error left after MSA, ``wrap(A_msa - A_true)`` (deg);
5. model: RELM on the six raw sensor values standardised with training
   statistics; hidden parameters drawn at random (plain RELM) or searched by an
   optimizer of :mod:`icgo.optim` on a training-only fitness (:mod:`icgo.methods.relm`);
6. output weights refit on all training rows; compensated azimuth
   ``A_msa - predicted error`` scored on the test rows (:mod:`icgo.maths.metrics`).

Test rows never steer anything: MSA, standardisation, fitness and output
weights see them only with zero weight. Stages 2-6 run as three jitted calls:
``_prepare`` (mapped over repeats: split, MSA, features), a host-side MSA
observability check, the optimizer's runner (:func:`icgo.studies.sharding.run_grid`,
one program over repeats and CGO strategies, sharded over the devices), then ``score_all`` (refit
vmapped over strategies and mapped over repeats; predictions by
:func:`icgo.methods.compensation.predict_methods`, the forward pass the saved model
applies to the same params; metrics).
Repeat k of a batched run equals the same repeat run alone (``repeat_ids``).

Fold protocols fit one member per (repeat, fold); a repeat's metrics pool its
folds' test rows (each row is held out by exactly one fold), so every protocol
gives one number per method and repeat.

Entry point: :func:`run_study` ``(frame, StudyConfig) -> StudyResult``.
"""

from __future__ import annotations

import dataclasses
import functools
import logging
import time
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import pandas as pd

from icgo.core.execution import ACCELERATOR_KERNEL, CPU_KERNEL, ExecutionPlan
from icgo.maths.metrics import azimuth_metrics
from icgo.maths.stats import mean_std_table
from icgo.methods import msa as _msa
from icgo.methods import relm as _relm
from icgo.methods import relm_fit
from icgo.methods.compensation import RELMParams, predict_methods
from icgo.methods.search_fitness import SearchData, search_fitness
from icgo.optim.cgo import CGO
from icgo.physics.frames import angle_diff, azimuth_from_gv, wrap360
from icgo.physics.qc import measured_dip_deg
from icgo.studies import splits as _splits
from icgo.studies import sharding, timing
from icgo.studies.protocol import Study

REQUIRED_COLUMNS = ("gx", "gy", "gz", "bx", "by", "bz", "azimuth_deg")


log = logging.getLogger(__name__)

#: Search-fitness precisions (``StudyConfig.dtype``) -> (dtype of the hidden layer, eq. 8; dtype of the
#: ridge solve and the RMSE, eq. 9). Which kernel computes them follows the backend
#: (:func:`icgo.core.execution.execution_plan`), not this setting.
PRECISIONS = {"float32_features": ("float32", "float64"), "float64": ("float64", "float64"),
              "float32": ("float32", "float32")}
#: Former ``dtype`` values, refused with their new names.
RENAMED_DTYPES = {"fast": "float32_features", "mixed": "float64"}


@dataclasses.dataclass(frozen=True)
class StudyConfig:
    """Settings of an ICGO-RELM study (defaults: the paper's protocol where it gives one).

    Attributes:
        n_repeats: repeats (random splits); the paper's Table 3 uses 10.
        seed: base seed; repeat k uses key ``fold_in(PRNGKey(seed), k)``.
        repeat_ids: run only these repeat ids (e.g. ``(3,)`` to rerun repeat 3
            alone); None = ``range(n_repeats)``.
        devices: the most devices the search's strategies x repeats members are sharded over (one program,
            :mod:`icgo.studies.sharding`); None (default) = every device of the backend (a CPU's host devices,
            one per core of the job: :func:`icgo.core.devices.use_host_devices`). Bitwise the one-device result
            on a CPU (:meth:`execution`).
        protocol: the split (:data:`icgo.studies.splits.PROTOCOLS`): ``random`` (paper),
            ``leave_azimuth_out``, ``leave_condition_out`` or ``transfer`` (needs
            ``SurveyData.target``, the second instrument's survey).
        train_fraction: training share of each split (paper 7:3 -> 0.7; random
            and transfer protocols).
        sigma_filter: n-sigma outlier rule applied once before splitting
            (paper: 3); None disables.
        msa_model: ``"biases"`` (paper), ``"axial"`` or ``"biases_scales"``.
        msa_reference: ``"station_mean"`` (paper eqs. 3-4) or ``"known"``
            (reference field from the metadata's total_field_nT and dip_deg).
        msa_iterations: largest number of Levenberg-Marquardt steps of the MSA
            solve (:func:`icgo.maths.lsq.least_squares` ``max_steps``; it stops earlier
            once converged, typically after 2-5 steps on lab_casing).
        features: ``"raw"`` (paper: the six raw sensor values) or ``"msa"``
            (G and the MSA-corrected B).
        hidden: RELM hidden units L (paper: not stated; 30 as in the reference
            scale runs, see docs/relm_study.md).
        lam: ridge lambda (paper: not stated; see docs/relm_study.md).
        fitness: ``"train"`` (paper: training RMSE), ``"validation"`` or ``"kfold"``.
        val_fraction: validation share of the training rows (fitness="validation").
        k_folds: folds (fitness="kfold").
        theta_bounds: (low, high) of every hidden weight and bias: the
            optimizer's search box and plain RELM's uniform draw.
        optimizer: registry name in :mod:`icgo.optim` (``cgo``, ``pso``, ``ga``,
            ``sma``) or None for plain RELM (one random theta per repeat).
        tune: plain RELM only (``optimizer=None``): choose ``hidden`` and ``lam`` on the grid
            :data:`icgo.methods.relm.TUNE_HIDDEN` x :data:`icgo.methods.relm.TUNE_LAMBDA` by the mean over repeats of
            the validation fitness on the training rows (``fitness`` ``validation`` or ``kfold``;
            the test rows are never seen), then fit at the chosen cell (method ``relm-tuned``).
        strategies: CGO 4th-seed strategies run side by side (vmapped); ignored
            for other optimizers.
        pop_size: population size (paper: 30).
        iterations: optimizer iterations (paper: 100); exclusive with max_evals.
        max_evals: fitness-evaluation budget instead of iterations.
        optimizer_config: the optimizer's config object (None = its defaults).
        dtype: precision of the search's fitness (:data:`PRECISIONS`), whatever the backend.
            ``"float32_features"`` (default): the hidden layer (eq. 8) in float32, the ridge solve
            and the RMSE in float64: within 5e-6 relative of the float64 fitness (tested), which
            is all a search needs to rank candidates. ``"float64"``: everything in float64 (the
            float64 fitness to 1e-9 relative). ``"float32"``: everything in float32 (1e-3).
            The kernel that computes it follows the backend (:meth:`execution`): on a CPU the
            cache-chunked :func:`icgo.methods.relm.train_fitness` for ``fitness="train"`` (float32
            Gram of centred features, float64 Cholesky and iterative refinement), the row-weighted
            :func:`icgo.methods.relm.fitness` otherwise (float64, or float32 for ``"float32"``);
            on an accelerator :func:`icgo.methods.relm_gram.gram_fitness`. The final refit and every
            reported number are float64 always. (Formerly ``fast`` and ``mixed``: refused with their new names.)
    """

    n_repeats: int = 10
    seed: int = 0
    devices: int | None = None
    repeat_ids: tuple | None = None
    protocol: str = "random"
    train_fraction: float = 0.7
    sigma_filter: float | None = 3.0
    msa_model: str = "biases"
    msa_reference: str = "station_mean"
    msa_iterations: int = 100
    features: str = "raw"
    hidden: int = 30
    lam: float = 1e-3
    fitness: str = "train"
    val_fraction: float = 0.3
    k_folds: int = 5
    theta_bounds: tuple = (-1.0, 1.0)
    optimizer: str | None = CGO.name
    tune: bool = False
    strategies: tuple = ("three_stage",)
    pop_size: int = 30
    iterations: int | None = 100
    max_evals: int | None = None
    optimizer_config: Any = None
    dtype: str = "float32_features"

    def __post_init__(self):
        """Validate every setting that does not depend on the data (one-line SettingError naming the field)."""
        from icgo.core.errors import SettingError
        from icgo.core.settings import is_int, is_real, need
        from icgo.optim import OPTIMIZERS  # importing the package registers every optimizer

        for name in ("strategies", "theta_bounds", "repeat_ids"):  # Hydra/JSON give lists
            v = getattr(self, name)
            if isinstance(v, list):
                object.__setattr__(self, name, tuple(v))
        need(is_int(self.n_repeats) and self.n_repeats >= 1, "n_repeats",
             f"must be an integer >= 1, got {self.n_repeats!r} (repeats)")
        need(is_int(self.seed) and self.seed >= 0, "seed", f"must be an integer >= 0, got {self.seed!r}")
        need(self.devices is None or (is_int(self.devices) and self.devices >= 1), "devices",
             f"must be None (every device) or an integer >= 1, got {self.devices!r}")
        need(self.repeat_ids is None or (len(self.repeat_ids) >= 1 and all(is_int(i) and i >= 0 for i in self.repeat_ids)),
             "repeat_ids", f"must be None or a non-empty tuple of integers >= 0, got {self.repeat_ids!r}")
        need(self.protocol in _splits.PROTOCOLS, "protocol",
             f"must be one of {list(_splits.PROTOCOLS)}, got {self.protocol!r}")
        need(is_real(self.train_fraction) and 0.0 < self.train_fraction < 1.0, "train_fraction",
             f"must be in (0, 1), got {self.train_fraction!r}")
        default_fraction = StudyConfig.__dataclass_fields__["train_fraction"].default
        need(self.protocol not in _splits.FOLD_PROTOCOLS or self.train_fraction == default_fraction, "train_fraction",
             f"has no effect under protocol {self.protocol!r} (its folds set the training rows); leave it at "
             f"{default_fraction}, got {self.train_fraction!r}")
        need(self.sigma_filter is None or (is_real(self.sigma_filter) and self.sigma_filter > 0), "sigma_filter",
             f"must be > 0 or null, got {self.sigma_filter!r}")
        need(isinstance(self.msa_model, str) and self.msa_model in _msa.MODELS, "msa_model",
             f"must be one of {list(_msa.MODELS)}, got {self.msa_model!r}")
        need(self.msa_reference in ("station_mean", "known"), "msa_reference",
             f"must be station_mean or known, got {self.msa_reference!r}")
        need(is_int(self.msa_iterations) and self.msa_iterations >= 1, "msa_iterations",
             f"must be an integer >= 1, got {self.msa_iterations!r}")
        need(self.features in ("raw", "msa"), "features", f"must be 'raw' or 'msa', got {self.features!r}")
        need(is_int(self.hidden) and self.hidden >= 1, "hidden", f"must be an integer >= 1, got {self.hidden!r}")
        need(is_real(self.lam) and 0 < self.lam <= _relm.MAX_LAM, "lam",
             f"must be a number > 0 and at most {_relm.MAX_LAM:g}, got {self.lam!r} (the ridge lambda is absolute: far "
             f"above that the RELM's output weights vanish and it returns MSA's azimuth unchanged, "
             f"docs/reliability.md)")
        need(self.fitness in _relm.FITNESS_MODES, "fitness",
             f"must be one of {list(_relm.FITNESS_MODES)}, got {self.fitness!r}")
        need(is_real(self.val_fraction) and 0.0 < self.val_fraction < 1.0, "val_fraction",
             f"must be in (0, 1), got {self.val_fraction!r}")
        need(is_int(self.k_folds) and self.k_folds >= 2, "k_folds", f"must be an integer >= 2, got {self.k_folds!r}")
        tb = self.theta_bounds
        need(isinstance(tb, tuple) and len(tb) == 2 and all(is_real(x) for x in tb) and tb[0] < tb[1],
             "theta_bounds", f"must be [low, high] with low < high, got {tb!r}")
        need(not (isinstance(self.dtype, str) and self.dtype in RENAMED_DTYPES), "dtype",
             f"{self.dtype!r} was renamed: use {' or '.join(f'{v} (was {k})' for k, v in RENAMED_DTYPES.items())}; "
             f"dtype names the precision only, the kernel follows the backend")
        need(isinstance(self.dtype, str) and self.dtype in PRECISIONS, "dtype",
             f"must be one of {list(PRECISIONS)}, got {self.dtype!r}")
        need(isinstance(self.tune, bool), "tune", f"must be true or false, got {self.tune!r}")
        if self.tune:
            need(self.optimizer is None, "tune", f"tunes plain RELM only: set optimizer none (got {self.optimizer!r})")
            need(self.fitness in ("validation", "kfold"), "tune",
                 f"chooses hidden and lam by validation on the training rows: set fitness validation or kfold "
                 f"(got {self.fitness!r})")
        if self.optimizer is None:
            return
        need(isinstance(self.optimizer, str) and self.optimizer in OPTIMIZERS, "optimizer",
             f"must name a registered optimizer (unknown optimizer {self.optimizer!r}); "
             f"choose one of {sorted(OPTIMIZERS)} or None")
        need(isinstance(self.strategies, tuple) and len(self.strategies) >= 1
             and len(set(self.strategies)) == len(self.strategies), "strategies",
             f"must be a non-empty tuple of distinct names, got {self.strategies!r}")
        alg = OPTIMIZERS[self.optimizer]
        if alg.axis:  # the side-by-side values (CGO strategies) are checked by the optimizer itself
            try:
                alg.axis_configs(self.optimizer_config, self.strategies)
            except (TypeError, ValueError) as e:
                raise SettingError("strategies", f"must name {alg.name} {alg.axis} values: "
                                                 f"{str(e).splitlines()[0]}") from None
        need(is_int(self.pop_size) and self.pop_size >= 4, "pop_size",
             f"must be an integer >= 4, got {self.pop_size!r}")
        need((self.iterations is None) != (self.max_evals is None), "iterations",
             "and max_evals: give exactly one (the other null)")
        if self.iterations is not None:
            need(is_int(self.iterations) and self.iterations >= 1, "iterations",
                 f"must be an integer >= 1, got {self.iterations!r}")
        else:
            need(is_int(self.max_evals) and self.max_evals >= 1, "max_evals",
                 f"must be an integer >= 1, got {self.max_evals!r}")

    def execution(self, backend: str | None = None, cores: int | None = None,
                  cells: int | None = None) -> ExecutionPlan:
        """How the search runs (:func:`icgo.core.execution.execution_plan`): its members (methods x ``cells``,
        default the repeats) sharded over the backend's devices (``devices``); no search (plain RELM): one device.

        Args:
            backend: the JAX backend (default ``jax.default_backend()``). cores: CPU cores the job may use
                (default: its affinity mask). cells: (world, repeat) cells (default: the repeats).
        """
        members = 0
        if self.optimizer is not None:
            members = len(self.method_names()) * (len(self.ids()) if cells is None else int(cells))
        return sharding.plan(backend, members, None if self.devices is None else int(self.devices), cores)

    def ids(self) -> tuple:
        """The repeat ids this config runs."""
        return tuple(range(self.n_repeats)) if self.repeat_ids is None else tuple(int(i) for i in self.repeat_ids)

    def method_names(self) -> list[str]:
        """One label per model the study fits, e.g. ``["cgo-original"]`` or ``["relm"]``."""
        if self.optimizer is None:
            return ["relm-tuned" if self.tune else "relm"]
        from icgo.optim import get

        return get(self.optimizer).labels(self.strategies)


class StudyResult(NamedTuple):
    """Everything a study produces (numpy / pandas, host-side).

    Attributes:
        metrics: one row per (method, repeat, split): mae, rmse, r2 (eq. 21),
            r2_error; methods include ``raw`` (eq. 1 on raw data) and ``msa``
            (after MSA only) as baselines. Fold protocols: over every (fold, row)
            of the split, i.e. the test metrics of each row's held-out fold.
        summary: mean +/- std over repeats per (method, split).
        histories: long table (method, repeat, fold, iteration, evals, best_fitness).
        predictions: per (method, repeat, fold, row) azimuths and errors, with split
            (``train``, ``test``, or ``heldout``: transfer's unused source rows).
        msa: per member (repeat, fold): biases (nT), standard errors, condition number, V.
        coverage: per (method, repeat, fold): the member's conformal half-width
            (deg, :func:`icgo.maths.conformal.member_coverage`), its coverage of the test
            rows at :data:`icgo.models.relm.INTERVAL_LEVEL`, the test and calibration row counts.
        curves: dict of arrays: ``best_fitness`` and ``evals`` (S, M, T) over members.
        kept: (N_in,) bool, rows of the input frame surviving the sigma filter
            (for transfer: of the source; the target's kept rows are the
            predictions' ``survey == "target"`` rows).
        config: the StudyConfig.
        wall_time_s: wall time of the jitted stages (incl. compile), s.
        n_evals: fitness evaluations per method and member (S, M).
        model: the fitted compensation (:class:`icgo.models.relm.RELMCompensation`):
            MSA biases, input statistics, hidden and output weights per method
            and repeat; ``model.apply(frame)`` corrects a new survey.
        msa_model: the MSA-only fit (:class:`icgo.models.relm.MSAModel`).
        tuning: with ``config.tune``: ``{"hidden", "lam", "grid": [{hidden, lam, val_mean, val_std}, ...]}``
            (the chosen cell is ``config.hidden`` / ``config.lam``); else None.
        excluded: ``((repeat id, reason), ...)``: the repeats left out because their MSA failed
            (:func:`exclude_failed_repeats`); every table, the summary and the models hold the others
            only, and ``config.repeat_ids`` names those. Empty when every repeat was usable.
    """

    metrics: pd.DataFrame
    summary: pd.DataFrame
    histories: pd.DataFrame
    predictions: pd.DataFrame
    msa: pd.DataFrame
    coverage: pd.DataFrame
    curves: dict
    kept: np.ndarray
    config: StudyConfig
    wall_time_s: float
    n_evals: np.ndarray
    model: Any
    msa_model: Any
    tuning: Any = None
    excluded: tuple = ()

    @property
    def records(self) -> dict:
        """The tables a run directory holds (names and columns: :mod:`icgo.reporting.records`)."""
        return {"metrics": self.metrics, "convergence": self.histories, "predictions": self.predictions,
                "msa": self.msa.rename(columns={"condition": "condition_number"}), "coverage": self.coverage}

    @property
    def models(self) -> dict:
        """The fitted models by kind."""
        return {self.model.KIND: self.model, self.msa_model.KIND: self.msa_model}


# --------------------------------------------------------------------- filter
def sigma_filter(G, B, azimuth_true, n_sigma: float = 3.0):
    """The 3-sigma rule (paper section 3.1), one pass, host-side.

    A row is dropped when any of these lies more than ``n_sigma`` standard
    deviations from its mean: |G|, |B| and the magnetic dip over the whole
    data set (sensor faults), and the raw azimuth error within its group of
    equal reference azimuth (the error varies by several degrees between
    azimuths, so a global rule on it would test the interference, not outliers).

    Args:
        G: (N, 3) g. B: (N, 3) nT. azimuth_true: (N,) deg.
        n_sigma: the rule's threshold.
    Returns:
        (N,) bool mask of kept rows.
    """
    G = np.asarray(G, float)
    B = np.asarray(B, float)
    a = np.asarray(azimuth_true, float)
    gn = np.linalg.norm(G, axis=1)
    bn = np.linalg.norm(B, axis=1)
    dip = measured_dip_deg(G, B)
    err = np.asarray(_raw_errors(G, B, a)[1])
    keep = np.ones(len(a), bool)
    for q in (gn, bn, dip):
        s = q.std()
        if s > 0:
            keep &= np.abs(q - q.mean()) <= n_sigma * s
    # groups of equal azimuth by one stable sort (O(N log N) for any number of groups); each group's rows
    # keep their order, so its mean and std are those of err[group mask]
    az = np.round(a, 6)
    order = np.argsort(az, kind="stable")
    starts = np.flatnonzero(np.r_[True, az[order][1:] != az[order][:-1]])
    ends = np.r_[starts[1:], len(a)]
    for i0, i1 in zip(starts[ends - starts > 2], ends[ends - starts > 2]):
        g = order[i0:i1]
        e = err[g]
        s = e.std()
        if s > 0:
            keep[g] &= np.abs(e - e.mean()) <= n_sigma * s
    return keep


#: The host-side filter's and tables' raw azimuth errors and metrics, one compiled program each (not one per array
#: operation).
_table_metrics = jax.jit(azimuth_metrics)
_raw_errors = jax.jit(lambda G, B, a: (azimuth_from_gv(G, B), angle_diff(azimuth_from_gv(G, B), a)))
_errors = jax.jit(angle_diff)


# ------------------------------------------------------------------ stages
class Prepared(NamedTuple):
    """Per-repeat arrays (leading axis R when batched)."""

    train: jnp.ndarray      # (N,) 0/1
    test: jnp.ndarray       # (N,) 0/1
    msa: _msa.MSAResult
    target: jnp.ndarray     # (N,) deg
    data: _relm.FitData     # standardised features, target, fold weights
    key: jnp.ndarray        # model key
    x_mean: jnp.ndarray     # (6,) feature mean over the training rows (g, nT)
    x_std: jnp.ndarray      # (6,) feature std over the training rows (g, nT)


@functools.partial(jax.jit, static_argnames=("msa_model", "msa_iter", "features", "mode", "val_fraction",
                                             "k_folds"))
def _prepare(keys, train, test, G, B, a_true, reference, *, msa_model, msa_iter, features, mode,
             val_fraction, k_folds) -> Prepared:
    """Per member (lax.map): MSA on its training rows, targets, standardised features, fold weights.

    keys: (M, 2); train, test: (M, N) 0/1 masks (:func:`icgo.studies.splits.members`).
    """
    def one(args):
        key, train, test = args
        _, k_fold, k_model = jax.random.split(key, 3)  # the first split drew the random protocol's permutation
        m = _msa.msa_solve(G, B, train, reference, model=msa_model, max_steps=msa_iter)
        b_corr = _msa.correct_field(B, m.bias, m.scale)
        target = angle_diff(azimuth_from_gv(G, b_corr), a_true)
        X = jnp.concatenate([G, B if features == "raw" else b_corr], axis=1)
        mean, std = _relm.standardize_stats(X, train)
        Xs = _relm.standardize(X, mean, std)
        fit_w, score_w = _relm.fold_weights(k_fold, train, mode, val_fraction, k_folds)
        return Prepared(train, test, m, target, _relm.FitData(Xs, target, fit_w, score_w), k_model, mean,
                        std)

    # lax.map, not vmap: the per-repeat program is then the same whatever the
    # number of repeats, so repeat k of a batch equals repeat k alone bitwise
    # (a vmapped reduction may be reordered by XLA for another batch size).
    # These stages are cheap; the search (the cost) is vmapped by the runner.
    return jax.lax.map(one, (keys, train.astype(G.dtype), test.astype(G.dtype)))


class SearchKernel(NamedTuple):
    """The search's fitness kernel: its name in :mod:`icgo.methods.relm` (one of
    :data:`icgo.methods.search_fitness.SEARCH_KERNELS`), whether it reads the gathered training rows
    (:func:`train_rows`)
    or the row-weighted FitData, and its precisions (:class:`icgo.methods.search_fitness.SearchData`)."""

    name: str
    train_rows: bool
    feature_dtype: str
    solve_dtype: str

    def aux(self, rows, lam, hidden: int) -> SearchData:
        """The optimizer's ``aux`` for :func:`icgo.methods.search_fitness.search_fitness`: ``rows`` (TrainRows or
        FitData)
        and ``lam`` (an array with the rows' leading axes: (R,) for a search, () for one repeat) as data."""
        return SearchData(rows, lam, int(hidden), self.name, self.feature_dtype, self.solve_dtype)


def search_kernel(dtype: str, fitness: str, kernel: str) -> SearchKernel:
    """The fitness kernel a search runs for a precision (:data:`PRECISIONS`), fitness mode and backend kernel.

    ``kernel`` :data:`icgo.core.execution.ACCELERATOR_KERNEL`: the fused kernel
    :func:`icgo.methods.relm_fused.fused_train_fitness` (train mode with float32 features: the default),
    :func:`icgo.methods.relm_gram.gram_train_fitness` (train mode, other precisions) or
    :func:`icgo.methods.relm_gram.gram_fitness`. CPU: the train-mode kernel
    :func:`icgo.methods.relm.train_fitness` for ``fitness="train"`` with a float64 solve, else the
    row-weighted :func:`icgo.methods.relm.fitness` (float64; float32 for ``dtype="float32"``).
    """
    features, solve = PRECISIONS[dtype]
    train = fitness == "train"
    if kernel == ACCELERATOR_KERNEL:
        if train and (features, solve) == ("float32", "float64"):
            return SearchKernel("fused_train_fitness", True, features, solve)
        return SearchKernel("gram_train_fitness" if train else "gram_fitness", train, features, solve)
    if kernel != CPU_KERNEL:
        raise ValueError(f"study: unknown search kernel {kernel!r}")
    if train and solve == "float64":
        return SearchKernel("train_fitness", True, features, solve)
    return SearchKernel("fitness", False, "float64", solve)


def _plain_dtype(cfg: StudyConfig) -> str | None:
    """Plain RELM's fitness precision: ``float32`` when asked, else None (the float64 library path)."""
    return "float32" if cfg.dtype == "float32" else None


class _Scored(NamedTuple):
    a_msa: jnp.ndarray      # (S, R, N) MSA azimuth, deg
    pred: jnp.ndarray       # (S, R, N) predicted error, deg
    a_comp: jnp.ndarray     # (S, R, N) compensated azimuth, deg
    test: Any               # Metrics (S, R)
    train: Any              # Metrics (S, R)
    params: RELMParams      # the fitted members (S strategies x R repeats) the saved model holds


@functools.partial(jax.jit, static_argnames=("hidden",))
def refit_all(thetas, prep: Prepared, lam, hidden):
    """Output weights beta (S, R, L) refitted on all training rows of each (strategy, repeat) (eq. 9; row blocks
    above :data:`icgo.methods.relm.ROW_BLOCK` rows, so memory does not grow with strategies x rows x hidden)."""
    over_s = jax.vmap(lambda th, p: relm_fit.ridge_beta(th, p.data.X, p.target, lam, hidden, p.train), in_axes=(0, None))
    # lax.map over repeats for bitwise batch-size independence (see _prepare).
    return jnp.swapaxes(jax.lax.map(lambda tp: over_s(*tp), (jnp.swapaxes(thetas, 0, 1), prep)), 0, 1)


@jax.jit
def _metrics(a_comp, prep: Prepared, a_true):
    """Test and training metrics (S, R) of the compensated azimuths a_comp (S, R, N)."""
    def one(ap):
        a, p = ap
        return jax.vmap(lambda x: (azimuth_metrics(a_true, x, p.target, p.test),
                                   azimuth_metrics(a_true, x, p.target, p.train)))(a)

    test, train = jax.lax.map(one, (jnp.swapaxes(a_comp, 0, 1), prep._replace(data=None)))
    return jax.tree_util.tree_map(lambda x: jnp.swapaxes(x, 0, 1), (test, train))


def score_all(thetas, prep: Prepared, G, B, a_true, lam, hidden: int, raw_features: bool) -> _Scored:
    """Refit, predict and score every (strategy, repeat).

    The predictions come from :func:`icgo.methods.compensation.predict_methods` on the params the study saves
    (:attr:`_Scored.params`), the forward pass its artifact applies, so a saved model reproduces them bitwise.

    Args:
        thetas: (S, R, 7 L) searched hidden weights. prep: the R repeats' :class:`Prepared`.
        G, B: (N, 3) the study's rows (g, nT). a_true: (N,) reference azimuth, deg.
        lam: ridge lambda. hidden: L. raw_features: the RELM reads (G, B), else (G, B_corr).
    """
    params = RELMParams(prep.msa.bias, prep.msa.scale, prep.x_mean, prep.x_std, thetas,
                        refit_all(thetas, prep, lam, hidden), int(hidden), bool(raw_features))
    a_msa, pred = predict_methods(params, jnp.concatenate([jnp.asarray(G), jnp.asarray(B)], axis=1))
    a_comp = wrap360(a_msa - pred)
    test, train = _metrics(a_comp, prep, jnp.asarray(a_true))
    return _Scored(a_msa, pred, a_comp, test, train, params)


@functools.partial(jax.jit, static_argnames=("hidden", "low", "high", "dtype"))
def _plain(keys, data, lam, hidden, low, high, dtype):
    """Plain RELM: theta ~ U(low, high) per repeat and its fitness (mapped over repeats)."""
    def one(kd):
        theta = _relm.random_theta(kd[0], hidden, (), low, high)
        return theta, _relm.fitness(theta[None], kd[1], lam, hidden, dtype)[0]

    return jax.lax.map(one, (keys, data))


@functools.partial(jax.jit, static_argnames=("n_train", "padded"))
def _train_rows(data, n_train, padded):
    return jax.vmap(lambda d: _relm.train_rows(d, n_train, padded))(data)


def search(cfg: StudyConfig, prep: Prepared, wrap_fitness=None, kernel: str = CPU_KERNEL, progress=None,
           devices=None):
    """Hidden parameters per (method, repeat): (S, R, D), curves (S, R, T), evals (S, R, T).

    Plain RELM (no optimizer): one random theta per repeat. Else :func:`search_cells` of the members' keys and
    training data (:func:`search_aux`); ``kernel`` (:meth:`StudyConfig.execution`) chooses the fitness kernel
    (:func:`search_kernel`).
    """
    if cfg.optimizer is None:
        low, high = cfg.theta_bounds
        theta, f = _plain(prep.key, prep.data, cfg.lam, cfg.hidden, float(low), float(high), _plain_dtype(cfg))
        return theta[None], f[None, :, None], jnp.ones((1, prep.key.shape[0], 1), jnp.int32)
    return search_cells(cfg, prep.key, search_aux(cfg, prep, kernel), wrap_fitness, progress, devices)


def search_aux(cfg: StudyConfig, prep: Prepared, kernel: str, capacity: int | None = None) -> SearchData:
    """The search's data for each member of ``prep`` (leading axis: its members): the rows the fitness kernel of
    ``kernel`` reads (gathered training rows, ``capacity`` of them when given, or the row-weighted FitData),
    lambda and the precisions."""
    sk = search_kernel(cfg.dtype, cfg.fitness, kernel)
    return sk.aux(train_rows(prep, capacity) if sk.train_rows else prep.data,
                  np.full(prep.key.shape[0], cfg.lam, prep.data.X.dtype), cfg.hidden)


def search_cells(cfg: StudyConfig, keys, aux, wrap_fitness=None, progress=None, devices=None):
    """Every method on every cell (``keys`` (C, 2), ``aux`` leading axis C: :func:`search_aux`), as one program
    (:func:`icgo.studies.sharding.run_grid`: ``lax.scan`` over iterations, the methods x cells members sharded over
    ``devices``, default every device, vmapped on each): (S, C, D) thetas, (S, C, T) curves and evaluations.
    ``progress``: see :func:`icgo.optim.sharded.run_members`."""
    from icgo.optim import get

    low, high = cfg.theta_bounds
    D = _relm.n_params(cfg.hidden)
    alg = get(cfg.optimizer)
    configs = alg.axis_configs(cfg.optimizer_config, cfg.strategies) if alg.axis else None
    fitness = search_fitness if wrap_fitness is None else wrap_fitness(search_fitness)
    res = sharding.run_grid(alg, fitness, (np.full(D, low), np.full(D, high)), keys, cfg.pop_size, cfg.iterations,
                            max_evals=cfg.max_evals, config=None if configs else cfg.optimizer_config,
                            configs=configs, aux=aux, devices=devices, progress=progress)
    return jnp.asarray(res.best_x), jnp.asarray(res.curve), jnp.asarray(res.evals_curve)


# ----------------------------------------------------------------- checking
def _check_config(cfg: StudyConfig, mem: _splits.Members) -> None:
    """The data-dependent checks (the settings validated themselves in ``StudyConfig.__post_init__``)."""
    if not isinstance(cfg, StudyConfig):
        raise ValueError(f"config must be a StudyConfig, got {type(cfg).__name__}")
    n_train = mem.train.sum(axis=1)
    n_test = mem.test.sum(axis=1)
    m = int(np.argmin(n_train))
    n_fit = rows_per_fit(cfg, mem)
    hidden = min(_relm.TUNE_HIDDEN) if cfg.tune else cfg.hidden
    where = "" if cfg.protocol == "random" else f" ({cfg.protocol}, fold {mem.fold_label[mem.fold[m]]!r})"
    if n_fit < hidden or n_test.min() < 1:
        raise ValueError(f"study: a split{where} of {mem.train.shape[1]} rows gives {int(n_train[m])} training rows "
                         f"({n_fit} per fit) and {int(n_test.min())} test rows; need at least hidden = {hidden} "
                         f"rows per fit and one test row")


def rows_per_fit(cfg: StudyConfig, mem: _splits.Members) -> int:
    """Training rows the smallest member fits the output weights on (less the validation share or one fold)."""
    n_fit = int(mem.train.sum(axis=1).min())
    if cfg.fitness == "validation":
        n_fit -= int(round(cfg.val_fraction * n_fit))
    elif cfg.fitness == "kfold":
        n_fit -= int(np.ceil(n_fit / cfg.k_folds))
    return n_fit


def frame_arrays(frame: pd.DataFrame):
    """(G (N, 3) g, B (N, 3) nT, azimuth (N,) deg) from a data-contract frame, checked."""
    if not isinstance(frame, pd.DataFrame):
        raise ValueError(f"study: expected a pandas DataFrame, got {type(frame).__name__}")
    missing = [c for c in REQUIRED_COLUMNS if c not in frame.columns]
    if missing:
        raise ValueError(f"study: data frame lacks required column(s) {missing}")
    if len(frame) == 0:
        raise ValueError("study: data frame is empty")
    vals = frame[list(REQUIRED_COLUMNS)]
    try:
        arr = vals.to_numpy(dtype=float)
    except (TypeError, ValueError):
        raise ValueError("study: non-numeric value in the sensor/azimuth columns") from None
    bad = np.argwhere(~np.isfinite(arr))
    if bad.size:
        r, c = bad[0]
        raise ValueError(f"study: NaN/inf in row {r}, column {REQUIRED_COLUMNS[c]!r}")
    return arr[:, :3], arr[:, 3:6], arr[:, 6]


def _reference(cfg: StudyConfig, metadata):
    if cfg.msa_reference == "station_mean":
        return None
    md = metadata or {}
    if "total_field_nT" not in md or "dip_deg" not in md:
        raise ValueError("study: msa_reference='known' needs metadata with total_field_nT and dip_deg")
    return jnp.asarray(_msa.reference_from_field(float(md["total_field_nT"]), float(md["dip_deg"])))


# --------------------------------------------------------------------- run
class SurveyData(NamedTuple):
    """The ICGO-RELM study's data: a data-contract frame and its metadata.

    Attributes:
        frame: DataFrame with gx, gy, gz (g), bx, by, bz (nT), azimuth_deg (deg);
            ``condition`` for ``protocol="leave_condition_out"``.
        meta: metadata dict (``total_field_nT``, ``dip_deg`` for msa_reference="known") or None.
        target: ``protocol="transfer"`` only: the second instrument's survey (same
            columns; :func:`icgo.studies.splits.transfer_survey` simulates one), every row a test row.
    """

    frame: pd.DataFrame
    meta: dict | None = None
    target: pd.DataFrame | None = None


def run(data: SurveyData, config: StudyConfig, key, *, wrap_fitness=None) -> StudyResult:
    """The registered study's ``run(data, config, key)``: repeat k uses ``fold_in(key, k)``.

    Args:
        data: :class:`SurveyData`.
        config: :class:`StudyConfig` (its ``seed`` is recorded; the randomness comes from ``key``).
        key: JAX PRNG key.
        wrap_fitness: see :func:`run_study`.
    """
    return _run(data.frame, config, data.meta, key, wrap_fitness, data.target)


def run_study(frame: pd.DataFrame, config: StudyConfig | None = None, metadata: dict | None = None, *,
              wrap_fitness=None, target: pd.DataFrame | None = None, timings: dict | None = None,
              progress=None) -> StudyResult:
    """Run an ICGO-RELM study on a data-contract frame with the key ``PRNGKey(config.seed)``.

    Args:
        frame: DataFrame with gx, gy, gz (g), bx, by, bz (nT), azimuth_deg (the
            reference azimuth); optional station, toolface_deg.
        config: StudyConfig (defaults if None).
        metadata: the data set's metadata (needed for msa_reference="known").
        wrap_fitness: optional ``f -> f'`` applied to the search's fitness
            ``f(pop, aux)`` (e.g. to instrument it). A wrapped fitness is a new
            static argument of the runner, so that run compiles afresh; for progress
            use ``progress``, which keeps the compiled programs cacheable.
        target: the second instrument's survey (``protocol="transfer"`` only).
        timings: a dict to fill with where the time went: per stage (``prepare``: split and MSA;
            ``search``; ``score``: refit and metrics; ``tables``) its wall seconds ``<stage>_s`` and the
            part spent compiling or loading programs ``<stage>_compile_s`` (:mod:`icgo.studies.timing`);
            ``execution``: the plan run (:meth:`StudyConfig.execution`, with the fitness function's
            name and the dtype).
        progress: optional ``progress(done, total)`` called on the host as the search's iterations complete
            (:func:`icgo.optim.sharded.run_members`); it never enters the compiled programs, so they stay in
            the compilation cache.
    Returns:
        StudyResult.
    Raises:
        ValueError: bad data (missing columns, NaN), bad config (lambda <= 0,
            fewer training rows than hidden units, unknown names), or stations
            that cannot determine the MSA parameters.
    """
    cfg = StudyConfig() if config is None else config
    return _run(frame, cfg, metadata, jax.random.PRNGKey(cfg.seed), wrap_fitness, target, timings, progress)


def filtered(frame: pd.DataFrame, cfg: StudyConfig):
    """(kept rows of the frame, G, B, azimuth) after the sigma filter."""
    G, B, a = frame_arrays(frame)
    kept = sigma_filter(G, B, a, cfg.sigma_filter) if cfg.sigma_filter else np.ones(len(a), bool)
    return frame[kept], G[kept], B[kept], a[kept], kept


class Staged(NamedTuple):
    """A study up to its search (:func:`stage`): the filtered rows, the checked members and their prepared arrays.

    ``cfg`` holds the repeats kept (``repeat_ids``) and, with ``tune``, the chosen cell; ``n_source``: transfer's
    source rows (the target's follow), else all rows; ``capacity``: None, or the rows G, B, a_true and ``prep`` are
    padded to (:func:`prepare`)."""

    cfg: StudyConfig
    rows: pd.DataFrame
    kept: np.ndarray
    G: np.ndarray
    B: np.ndarray
    a_true: np.ndarray
    n_source: int
    mem: _splits.Members
    prep: Prepared
    excluded: tuple
    tuning: Any
    capacity: int | None = None


def stage(frame, cfg: StudyConfig, metadata, base_key, target=None, stages=None, capacity=None) -> Staged:
    """Filter, split, MSA and features of every member (rows padded to ``capacity``: :func:`prepare`), the failed
    repeats left out, plain RELM tuned."""
    if (cfg.protocol == "transfer") != (target is not None):
        raise ValueError("study: protocol 'transfer' needs the second instrument's survey (target) and no other "
                         f"protocol takes one; got protocol {cfg.protocol!r} with"
                         f"{'out' if target is None else ''} a target")
    rows, G, B, a_true, kept = filtered(frame, cfg)
    n_source = len(a_true)
    if target is not None:  # the sigma filter is applied to each instrument's survey on its own
        t_rows, Gt, Bt, at, _ = filtered(target, cfg)
        rows = pd.concat([rows, t_rows])
        G, B, a_true = np.vstack([G, Gt]), np.vstack([B, Bt]), np.concatenate([a_true, at])
    reference = _reference(cfg, metadata)
    if cfg.msa_model == "biases_scales" and reference is None:
        raise ValueError("study: msa_model='biases_scales' needs msa_reference='known'")
    stages = timing.Stages() if stages is None else stages
    with stages("prepare"):
        prep, mem = prepare(rows, G, B, a_true, cfg, base_key, reference, n_source, capacity)
        prep, mem, cfg, excluded = exclude_failed_repeats(prep, mem, cfg, reference)
        jax.block_until_ready(prep)
    tuning = None
    if cfg.tune:
        cfg, tuning = _tune(cfg, prep, rows_per_fit(cfg, mem))
    if capacity is not None:
        G, B, a_true = pad_rows(capacity, G, B, a_true)
    return Staged(cfg, rows, kept, G, B, a_true, n_source, mem, prep, excluded, tuning, capacity)


def finish(st: Staged, thetas, curve, evals, t0: float, stages) -> StudyResult:
    """The searched members checked, refitted and scored, and the study's tables (``t0``: its start, for the wall
    time; ``stages``: the :class:`icgo.studies.timing.Stages` that time it)."""
    cfg, mem = st.cfg, st.mem
    check_search(np.asarray(curve), cfg.method_names(), [f"{r}" if cfg.protocol not in _splits.FOLD_PROTOCOLS
                                                          else f"{r}, {mem.fold_label[f]}"
                                                          for r, f in zip(mem.repeat, mem.fold)])
    with stages("score"):
        scored = jax.block_until_ready(score_all(thetas, st.prep, st.G, st.B, st.a_true, cfg.lam, cfg.hidden,
                                                 cfg.features == "raw"))
    wall = time.perf_counter() - t0
    prep = st.prep._replace(data=None)  # the features (members x rows x 6) are done with: free them before the tables
    G, B, a_true = st.G, st.B, st.a_true
    if st.capacity is not None:  # the padded rows dropped: every table holds the data set's own rows
        n = len(st.kept.nonzero()[0])
        G, B, a_true = G[:n], B[:n], a_true[:n]
        prep = prep._replace(train=prep.train[:, :n], test=prep.test[:, :n], target=prep.target[:, :n])
        scored = scored._replace(a_msa=scored.a_msa[..., :n], pred=scored.pred[..., :n], a_comp=scored.a_comp[..., :n])
    with stages("tables"):
        res = _collect(cfg, st.rows, st.kept, a_true, G, B, st.n_source, mem, prep, thetas, scored, curve, evals,
                       wall)
    return res._replace(tuning=st.tuning, excluded=st.excluded)


def execution_record(cfg: StudyConfig, plan: ExecutionPlan) -> dict:
    """run.json's ``execution``: the plan, the fitness function that ran and the dtype."""
    if cfg.optimizer is None:
        return {**plan._asdict(), "fitness": "icgo.methods.relm.fitness (plain RELM, no search)", "dtype": cfg.dtype}
    name = search_kernel(cfg.dtype, cfg.fitness, plan.kernel).name
    module = {"fused_train_fitness": "relm_fused", "gram_fitness": "relm_gram", "gram_train_fitness": "relm_gram"}.get(
        name, "relm")
    return {**plan._asdict(), "fitness": f"icgo.methods.{module}.{name}", "dtype": cfg.dtype}


def _run(frame, cfg: StudyConfig, metadata, base_key, wrap_fitness, target=None, timings=None,
         progress=None) -> StudyResult:
    t0 = time.perf_counter()
    stages = timing.Stages()
    st = stage(frame, cfg, metadata, base_key, target, stages)
    plan = st.cfg.execution(cells=len(st.mem.repeat))
    with stages("search"):
        thetas, curve, evals = jax.block_until_ready(search(st.cfg, st.prep, wrap_fitness, plan.kernel, progress,
                                                            sharding.plan_devices(plan)))
    res = finish(st, thetas, curve, evals, t0, stages)
    if timings is not None:
        timings.update(stages.times, execution=execution_record(st.cfg, plan))
    return res


def _tune(cfg: StudyConfig, prep: Prepared, n_fit: int):
    """Plain RELM's (hidden, lam) by the mean validation fitness over repeats on the grid (training rows only).

    Each cell draws theta from the repeat's model key (so the lambdas of one L
    share their theta, and the chosen cell's run reuses it) and scores it with the
    study's fitness mode (``validation``/``kfold``: fitted on part of the training
    rows, scored on the rest). Widths above ``n_fit`` (rows per fit) are left out,
    as the study refuses them. Returns (config at the chosen cell, tuning record).
    """
    low, high = (float(v) for v in cfg.theta_bounds)
    dtype = _plain_dtype(cfg)
    grid = []
    for hidden in (h for h in _relm.TUNE_HIDDEN if h <= n_fit):
        for lam in _relm.TUNE_LAMBDA:
            _, f = _plain(prep.key, prep.data, lam, hidden, low, high, dtype)
            f = np.asarray(f)
            grid.append({"hidden": hidden, "lam": lam, "val_mean": float(f.mean()), "val_std": float(f.std(ddof=1))
                         if f.size > 1 else 0.0})
    best = min(grid, key=lambda g: g["val_mean"])
    log.info("tuned plain RELM: hidden %d, lam %g (mean validation fitness %.4g)", best["hidden"], best["lam"],
             best["val_mean"])
    return (dataclasses.replace(cfg, hidden=best["hidden"], lam=best["lam"]),
            {"hidden": best["hidden"], "lam": best["lam"], "grid": grid})


def prepare(rows: pd.DataFrame, G, B, a_true, cfg: StudyConfig, base_key, reference=None,
            n_source: int | None = None, capacity: int | None = None) -> tuple[Prepared, _splits.Members]:
    """The members of ``cfg.protocol`` and their prepared arrays (split, MSA, features), checked.

    Args:
        rows: the filtered rows (a DataFrame; fold protocols read their groups from it), or None
            (the random protocol on arrays).
        G: (N, 3) g. B: (N, 3) nT. a_true: (N,) deg; the filtered rows' arrays.
        cfg: StudyConfig. base_key: the study's PRNG key.
        reference: (3,) known reference field or None (station mean).
        n_source: transfer only: the source's row count (the target's rows follow).
        capacity: None, or the rows every array is padded to (copies of the last row, weight 0 in every mask), so
            that data sets of other sizes share the programs (:mod:`icgo.studies.worlds`).
    Returns:
        (:class:`Prepared` with a leading member axis, :class:`icgo.studies.splits.Members`).
    """
    if rows is None:  # arrays only: enough for the random protocol
        rows = pd.DataFrame(index=pd.RangeIndex(len(a_true)))
    mem = _splits.members(cfg.protocol, rows, base_key, cfg.ids(), cfg.train_fraction, n_source)
    _check_config(cfg, mem)
    train, test = mem.train, mem.test
    if capacity is not None:
        G, B, a_true = pad_rows(capacity, G, B, a_true)
        train, test = (np.pad(np.asarray(x), ((0, 0), (0, int(capacity) - x.shape[1]))) for x in (train, test))
    prep = _prepare(jnp.asarray(mem.keys), jnp.asarray(train), jnp.asarray(test), jnp.asarray(G),
                    jnp.asarray(B), jnp.asarray(a_true), reference, msa_model=cfg.msa_model,
                    msa_iter=cfg.msa_iterations, features=cfg.features, mode=cfg.fitness,
                    val_fraction=float(cfg.val_fraction), k_folds=int(cfg.k_folds))
    return prep, mem


def pad_rows(capacity: int, *arrays) -> tuple:
    """Each (N, ...) array padded to ``capacity`` rows with copies of its last row (finite; their weights are 0)."""
    return tuple(np.pad(np.asarray(x), [(0, int(capacity) - len(x))] + [(0, 0)] * (np.ndim(x) - 1), mode="edge")
                 for x in arrays)


def train_rows(prep: Prepared, capacity: int | None = None):
    """The fast fitness's data (:class:`icgo.methods.relm.TrainRows`, leading member axis): each member's training
    rows gathered, padded with weight-0 rows where members have different numbers of them (or, with ``capacity``,
    always padded to that many rows)."""
    n_train = np.asarray(prep.train).sum(axis=1).astype(int)
    if capacity is not None:
        return _train_rows(prep.data, int(capacity), True)
    return _train_rows(prep.data, int(n_train.max()), bool(n_train.min() != n_train.max()))


def exclude_failed_repeats(prep: Prepared, mem: _splits.Members, cfg: StudyConfig, reference=None):
    """Leave out the repeats whose multi-station analysis failed, so that the others go on.

    A repeat is left out whole (all its folds) when the MSA of any of its members failed
    (:func:`icgo.methods.msa.msa_failures`: parameters the training stations cannot determine, a
    non-finite solution, or no convergence within ``msa_iterations`` steps). Its numbers would
    rest on an unusable correction, so it is neither searched nor scored nor averaged in; the
    result names it (``StudyResult.excluded``) and so do the printed summary, ``summary.md`` and
    ``run.json``. Only when every repeat failed does the study stop (the same one-line
    ValueError as :func:`icgo.methods.msa.check_observability`, naming the first).

    Args:
        prep, mem: the prepared members and their protocol (:func:`prepare`).
        cfg: the StudyConfig. reference: the MSA reference field or None.
    Returns:
        (prep, mem, cfg, excluded): the kept members; ``cfg`` with ``repeat_ids`` the kept ids
        (unchanged when none failed); ``excluded`` = ``((repeat id, reason), ...)``.
    Raises:
        ValueError: every repeat's MSA failed.
    """
    reasons = _msa.msa_failures(prep.msa, cfg.msa_model, reference)
    failed: dict[int, tuple[str, str]] = {}  # repeat id -> (fold label or "", reason)
    for k, why in enumerate(reasons):
        rid = int(mem.repeat[k])
        if why is not None and rid not in failed:
            failed[rid] = (mem.fold_label[mem.fold[k]] if cfg.protocol in _splits.FOLD_PROTOCOLS else "", why)
    if not failed:
        return prep, mem, cfg, ()
    kept_ids = tuple(r for r in cfg.ids() if r not in failed)
    if not kept_ids:
        rid, (fold, why) = next(iter(failed.items()))
        raise ValueError(f"multi-station analysis (repeat {rid}{', ' + fold if fold else ''}): {why}")
    sel = np.flatnonzero(np.isin(mem.repeat, kept_ids))
    prep = jax.tree_util.tree_map(lambda a: a[sel], prep)
    mem = mem._replace(keys=mem.keys[sel], repeat=mem.repeat[sel], fold=mem.fold[sel], train=mem.train[sel],
                       test=mem.test[sel], heldout=mem.heldout[sel])
    excluded = tuple((rid, f"MSA{f' ({fold})' if fold else ''}: {why}") for rid, (fold, why) in sorted(failed.items()))
    log.warning("%s", excluded_sentence(excluded, len(cfg.ids())))
    return prep, mem, dataclasses.replace(cfg, repeat_ids=kept_ids), excluded


def excluded_sentence(excluded, n_repeats: int, limit: int = 10) -> str | None:
    """One line naming the excluded repeats (the first ``limit``), or None when there are none.

    E.g. ``"1 of 1000 repeats excluded (their MSA failed, so they are in no number): repeat 61: MSA:
    Levenberg-Marquardt did not converge in 100 steps; raise max_steps (msa.iterations)"``.
    """
    if not excluded:
        return None
    named = "; ".join(f"repeat {rid}: {why}" for rid, why in list(excluded)[:limit])
    more = f"; and {len(excluded) - limit} more (run.json)" if len(excluded) > limit else ""
    return (f"{len(excluded)} of {n_repeats} repeats excluded (their MSA failed, so they are in no number): "
            f"{named}{more}")


def check_search(curve, methods, ids) -> None:
    """A search in which no candidate was ever finite is a failed run, not a result.

    Args:
        curve: (S, R, T) best-so-far fitness. methods: the S labels. ids: the R repeat ids.
    Raises:
        ValueError: one line naming the first (method, repeat) whose best fitness is not finite.
    """
    bad = np.argwhere(~np.isfinite(np.asarray(curve)[..., -1]))
    if bad.size:
        s, r = bad[0]
        raise ValueError(f"study: the search of {methods[s]} (repeat {ids[r]}) never found a finite fitness "
                         f"({len(bad)} of {curve.shape[0] * curve.shape[1]} searches): every candidate's ridge "
                         f"solve failed; check the data (constant or non-finite features) and model.lam")


def _collect(cfg, rows, kept, a_true, G, B, n_source, mem: _splits.Members, prep, thetas, scored, curve, evals,
             wall) -> StudyResult:
    from icgo.maths.conformal import member_coverage
    from icgo.models.relm import INTERVAL_LEVEL

    methods = cfg.method_names()
    ids = cfg.ids()
    curve, evals = np.asarray(curve), np.asarray(evals)
    train = np.asarray(prep.train) > 0
    test = np.asarray(prep.test) > 0
    target = np.asarray(prep.target)
    a_msa = np.asarray(scored.a_msa[0])  # every strategy of a repeat shares its MSA
    a_comp = np.asarray(scored.a_comp)
    a_raw, err_raw = (np.asarray(x) for x in _raw_errors(G, B, a_true))
    one_member = len(mem.fold_label) == 1  # random / transfer: the jitted per-member metrics are the repeat's
    # a repeat's members side by side, repeats in ``ids`` order: (..., M, N) -> (..., R, F N), so that every
    # repeat's metrics over its pooled folds come from one batched call (not one call per repeat)
    position = {rid: i for i, rid in enumerate(ids)}
    order = np.argsort([position[int(r)] for r in mem.repeat], kind="stable")
    R, F = len(ids), len(order) // len(ids)

    def pooled(x):
        x = np.asarray(x)[..., order, :]
        return x.reshape(*x.shape[:-2], R, F * x.shape[-1])

    a_true_p, err_raw_p = np.tile(a_true, F), np.tile(err_raw, F)
    per_split = {}
    for split, mask in (("test", test), ("train", train)):
        w = pooled(mask.astype(float))
        per_method = {"raw": _table_metrics(a_true_p, np.broadcast_to(np.tile(a_raw, F), w.shape), err_raw_p, w),
                      "msa": _table_metrics(a_true_p, pooled(a_msa), err_raw_p, w)}
        if one_member:
            m = scored.test if split == "test" else scored.train
            per_method |= {name: type(m)(*(np.asarray(v)[s][order] for v in m)) for s, name in enumerate(methods)}
        else:
            m = _table_metrics(a_true_p, pooled(a_comp), pooled(target), w)
            per_method |= {name: type(m)(*(np.asarray(v)[s] for v in m)) for s, name in enumerate(methods)}
        per_split[split] = {name: {k: np.asarray(v, dtype=float) for k, v in m._asdict().items()}
                            for name, m in per_method.items()}
    out = [{"method": name, "repeat": rid, "split": split, **{k: float(v[i]) for k, v in vals.items()}}
           for i, rid in enumerate(ids) for split, by_method in per_split.items() for name, vals in by_method.items()]
    metrics = pd.DataFrame(out)
    summary = mean_std_table(metrics, ["method", "split"], ["mae", "rmse", "r2", "r2_error"])

    S, M, T = curve.shape
    histories = pd.DataFrame({
        "method": np.repeat(methods, M * T), "repeat": np.tile(np.repeat(mem.repeat, T), S),
        "fold": np.tile(np.repeat(mem.fold, T), S),
        "iteration": np.tile(np.arange(1, T + 1), S * M), "evals": evals.ravel(), "best_fitness": curve.ravel()})

    N = len(a_true)
    station = rows["station"].to_numpy() if "station" in rows.columns else np.arange(N)
    # S x M x N rows: the text columns are categoricals (one byte a row, not one string object a row)
    split = np.where(train, 0, np.where(test, 1, 2)).astype(np.int8)
    predictions = pd.DataFrame({
        "method": _categorical(np.repeat(np.arange(S, dtype=np.int8), M * N), methods),
        "repeat": np.tile(np.repeat(mem.repeat, N), S),
        "fold": np.tile(np.repeat(mem.fold, N), S),
        "row": np.tile(np.asarray(rows.index), S * M), "station": np.tile(station, S * M),
        "split": _categorical(np.tile(split.ravel(), S), ["train", "test", "heldout"]),
        "azimuth_true": np.tile(a_true, S * M), "azimuth_raw": np.tile(a_raw, S * M),
        "azimuth_msa": np.tile(a_msa.ravel(), S), "error_msa": np.tile(target.ravel(), S),
        "predicted_error": np.asarray(scored.pred).ravel(), "azimuth_compensated": a_comp.ravel(),
        "error_compensated": np.asarray(_errors(a_comp, a_true[None, None])).ravel()}, copy=False)
    if "toolface_deg" in rows.columns:
        predictions.insert(6, "toolface_deg", np.tile(rows["toolface_deg"].to_numpy(), S * M))
    if cfg.protocol == "transfer":
        predictions["survey"] = _categorical(np.tile((np.arange(N) >= n_source).astype(np.int8), S * M),
                                             ["source", "target"])

    names = _msa.MODELS[cfg.msa_model]
    m = prep.msa
    msa_df = pd.DataFrame({"repeat": mem.repeat, "fold": mem.fold, "cost_V": np.asarray(m.cost),
                           "condition": np.asarray(m.condition),
                           **{f"bias_{ax}": np.asarray(m.bias)[:, i] for i, ax in enumerate("xyz")},
                           **{f"scale_{ax}": np.asarray(m.scale)[:, i] for i, ax in enumerate("xyz")},
                           **{f"std_{n}": np.asarray(m.std_error)[:, i] for i, n in enumerate(names)}})
    pool = mem.repeat if cfg.protocol in _splits.FOLD_PROTOCOLS else np.zeros(M, int)
    q, cov, n_cal = member_coverage(a_comp, a_true, mem.train, mem.heldout, mem.test, pool, INTERVAL_LEVEL)
    coverage = pd.DataFrame({"method": np.repeat(methods, M), "repeat": np.tile(mem.repeat, S),
                             "fold": np.tile(mem.fold, S), "fold_label": np.tile(np.asarray(mem.fold_label)[mem.fold], S),
                             "level": INTERVAL_LEVEL, "halfwidth_deg": q.ravel(), "coverage": cov.ravel(),
                             "n_test": np.tile(mem.test.sum(axis=1).astype(int), S), "n_calibration": np.tile(n_cal, S)})
    return StudyResult(metrics, summary, histories, predictions, msa_df, coverage,
                       {"best_fitness": curve, "evals": evals}, kept, cfg, wall, evals[..., -1],
                       *_fitted_models(cfg, G[:n_source], B[:n_source], a_true, mem, prep, thetas, scored))


def _categorical(codes, categories) -> pd.Categorical:
    """A text column as a pandas Categorical of ``categories[codes]`` (written to CSV as the text)."""
    return pd.Categorical.from_codes(codes, categories=list(categories))


def _fitted_models(cfg: StudyConfig, G, B, a_true, mem: _splits.Members, prep: Prepared, thetas, scored: _Scored):
    """The study's fitted artifacts: (RELMCompensation, MSAModel), host-side numpy.

    One member per fitted model (repeat, fold); G, B are the training survey's rows
    (for transfer: the source instrument's), which set the data hash and domain; the
    conformal half-width uses the rows each member held out of that survey only.
    """
    from icgo.models.format import data_hash, sensor_domain
    from icgo.models.relm import MSAModel, RELMCompensation, out_of_bag_halfwidth

    methods = cfg.method_names()
    ids = [int(r) for r in mem.repeat]
    train_rmse = np.asarray(scored.train.rmse)
    selected = methods[int(np.argmin(train_rmse.mean(axis=1)))]
    a_src = a_true[:len(G)]
    common = dict(data_hash=data_hash(G, B, a_src),
                  domain={**sensor_domain(G, B), "azimuth_deg": [float(np.min(a_src)), float(np.max(a_src))]})
    params = jax.tree_util.tree_map(np.asarray, scored.params)
    settings = {f.name: getattr(cfg, f.name) for f in dataclasses.fields(cfg) if f.name != "optimizer_config"}
    settings["optimizer_config"] = None if cfg.optimizer_config is None else repr(cfg.optimizer_config)
    relm = RELMCompensation(config=settings, methods=list(methods), selected=selected, repeat_ids=ids,
                            hidden=int(cfg.hidden), lam=float(cfg.lam), features=cfg.features, params=params,
                            train_rmse=train_rmse,
                            interval_halfwidth=out_of_bag_halfwidth(np.asarray(scored.a_comp), a_true,
                                                                    mem.heldout == 0), **common)
    msa = MSAModel(config={"msa_model": cfg.msa_model, "msa_reference": cfg.msa_reference,
                           "train_fraction": cfg.train_fraction, "seed": cfg.seed, "protocol": cfg.protocol},
                   params=_msa.MSAParams(params.msa_bias, params.msa_scale), repeat_ids=ids, **common)
    return relm, msa


def example() -> tuple:
    """A tiny ICGO-RELM study (seconds): lab_casing at a 45 deg toolface step, PSO, 2 repeats."""
    from icgo.datasets import casing_stations as datasets

    frame = datasets.lab_casing(0, toolface_step_deg=45.0).frame
    return SurveyData(frame), StudyConfig(optimizer="pso", n_repeats=2, hidden=8, pop_size=6, iterations=3)


STUDY = Study("icgo_relm", StudyConfig, run, "MSA + RELM whose hidden weights an optimizer searches "
              "(ICGO paper sections 3.1-3.4)", example)
