"""The optimizer benchmark: our JAX optimizers vs mealpy 3.x side by side at an equal evaluation budget.

Shifted and rotated CEC 2017 functions (:mod:`icgo.optim.benchmarks`; the suite is
``data``, default :data:`icgo.optim.benchmarks.STUDY`) x dimensions x runs. Every run
of every algorithm gets the same number of fitness evaluations (``n_evals`` on
our side, a call counter on mealpy's). Each of our methods is compared with its
mealpy peer cell by cell (one function, one dimension) with the Wilcoxon
rank-sum test (two-sided, ``alpha``): ``+`` ours significantly lower error
(better), ``-`` significantly higher, ``=`` no significant difference; the same
decision after Holm's adjustment over each method's family (all its cells).

Our side (:data:`METHODS`, built from the optimizer registry): CGO in the
``paper`` and ``mealpy`` variants with the 4th-seed strategies ``original`` and
``three_stage`` side by side (``alg.axis_configs``), CGO ``matlab``, PSO, GA,
SMA. Each (job, dimension) is ONE jitted :func:`icgo.optim.run_batch` call that
vmaps over all functions x runs (the function is per-repeat ``aux`` data) and,
for CGO, over the strategies.

Randomness: job ``j`` (position in :func:`jobs`) at dimension ``D`` uses the
keys ``split(fold_in(key, 1000 D + j), F runs)``, function ``i`` run ``r`` taking
key ``i runs + r`` (so a subset of functions draws other keys). A raw
``PRNGKey(seed)`` is wrapped into a typed key first, so ``PRNGKey(seed)`` and
``jax.random.key(seed)`` give bit for bit the same numbers. The mealpy peer is seeded by its own rule:
run ``r`` uses ``seed=r`` (``key`` does not reach it).

The mealpy peer (numpy, host-side; ``jobs`` > 1 runs it in joblib processes)
needs ``mealpy`` and ``opfunu``, imported lazily; without them ``peer=True``
raises a one-line error. Its fitness is opfunu's numpy operator on the same
shift/rotation data (an independent implementation of each function).

A benchmark fits no model: ``result.models`` is ``{}``. Records:

* ``runs``: one row per (dim, algorithm, function, run): final ``error``
  (f(x) - f* of the best point) and ``evals``; our methods by label, the peer
  as ``mealpy <registry name>``;
* ``cells``: one row per (dim, function, our method): median and IQR of both
  sides, maximum evaluations, rank-sum ``p_value`` and ``result`` (+/=/-),
  ``p_holm`` and ``result_holm``;
* ``summary``: +/=/- counts per (dim, method), raw and after Holm.
"""

from __future__ import annotations

import dataclasses
import logging
import time
from typing import NamedTuple

import numpy as np
import pandas as pd

from icgo.core.settings import is_int, is_real, need
from icgo.optim import benchmarks as bm
from icgo.optim import iterations_for_budget
from icgo.optim.base import MIN_POP_SIZE
from icgo.optim.cgo import CGO, CGOConfig
from icgo.optim.ga import GA
from icgo.optim.mutation import STRATEGIES
from icgo.optim.pso import PSO
from icgo.optim.registry import get
from icgo.optim.sma import SMA
from icgo.studies.optimizers import report as optimizers_report
from icgo.studies.common.study import Study

log = logging.getLogger(__name__)

#: Dimensions for which CEC 2017 ships shift/rotation data for every slot the study uses.
CEC2017_DIMS = (2, 10, 20, 30, 50, 100)

#: Our registry name -> (mealpy module, mealpy class) of the peer it is compared with.
PEERS = {CGO.name: ("CGO", "OriginalCGO"), PSO.name: ("PSO", "OriginalPSO"), GA.name: ("GA", "BaseGA"),
         SMA.name: ("SMA", "OriginalSMA")}

#: CGO 4th-seed strategies run side by side: the unmutated CGO and the ICGO three-stage mutation.
CGO_STRATEGIES = (STRATEGIES[0], "three_stage")


# ===================================================================== config
@dataclasses.dataclass(frozen=True)
class OptimizerStudyConfig:
    """Settings of the optimizer benchmark (defaults: ``make optimizers`` apart from ``jobs``).

    Attributes:
        functions: the functions to run, a subset of the suite (``data``); None = all of it.
        dims: dimensions D, each one CEC 2017 ships data for (:data:`CEC2017_DIMS`).
        runs: runs per (function, dimension, algorithm).
        pop_size: population size of every algorithm (ours and mealpy's).
        budget: fitness evaluations per run for every algorithm (3220 = 20 + 40 x 80:
            40 CGO / 160 PSO-GA-SMA iterations at population 20); each algorithm runs
            ``(budget - pop_size) // per_iteration`` iterations.
        seed: base seed: the entry point's key is ``PRNGKey(seed)`` (recorded here;
            ``run`` draws from its ``key``).
        jobs: processes for the mealpy runs (joblib); 1 runs them in this process.
        alpha: significance level of the rank-sum decisions and of Holm's adjustment.
        peer: run the mealpy peer; False gives our runs only (peer columns NaN, no decisions).
        methods: labels of our methods to report (:func:`methods`), None = all. A job runs whole
            when any of its labels is chosen and keeps its key, so a subset reproduces the full
            study's numbers for those methods; the peer runs only the algorithms chosen.
    """

    functions: tuple | None = None
    dims: tuple = (10, 30)
    runs: int = 30
    pop_size: int = 20
    budget: int = 3220
    seed: int = 0
    jobs: int = 1
    alpha: float = 0.05
    peer: bool = True
    methods: tuple | None = None

    def __post_init__(self):
        """Validate every setting (one-line :class:`icgo.core.errors.SettingError` naming the field)."""
        for name in ("functions", "dims", "methods"):  # Hydra/JSON/argparse give lists
            v = getattr(self, name)
            if isinstance(v, list):
                object.__setattr__(self, name, tuple(v))
        f = self.functions
        need(f is None or (isinstance(f, tuple) and len(f) >= 1 and all(isinstance(n, str) for n in f)),
             "functions", f"must be None or a non-empty list of function names, got {f!r}")
        if f is not None:
            unknown = [n for n in f if n not in bm.SPECS]
            need(not unknown, "functions", f"unknown {unknown}; choose from {list(bm.SPECS)}")
            need(len(set(f)) == len(f), "functions", f"must not repeat a name, got {list(f)}")
        d = self.dims
        need(isinstance(d, tuple) and len(d) >= 1 and all(is_int(x) for x in d) and len(set(d)) == len(d),
             "dims", f"must be a non-empty list of distinct integers, got {d!r}")
        bad = [x for x in d if x not in CEC2017_DIMS]
        need(not bad, "dims", f"{bad} have no CEC 2017 data; choose from {list(CEC2017_DIMS)}")
        need(is_int(self.runs) and self.runs >= 1, "runs", f"must be an integer >= 1, got {self.runs!r}")
        need(is_int(self.pop_size) and self.pop_size >= MIN_POP_SIZE, "pop_size",
             f"must be an integer >= {MIN_POP_SIZE}, got {self.pop_size!r}")
        need(is_int(self.budget) and self.budget >= 1, "budget", f"must be an integer >= 1, got {self.budget!r}")
        least = self.pop_size + max(_per_iteration(a, self.pop_size) for a in PEERS)
        need(self.budget >= least, "budget",
             f"must allow one iteration of every algorithm (>= {least} at pop_size {self.pop_size}), "
             f"got {self.budget}")
        need(is_int(self.seed) and self.seed >= 0, "seed", f"must be an integer >= 0, got {self.seed!r}")
        need(is_int(self.jobs) and self.jobs >= 1, "jobs", f"must be an integer >= 1, got {self.jobs!r}")
        need(is_real(self.alpha) and 0.0 < self.alpha < 1.0, "alpha", f"must be in (0, 1), got {self.alpha!r}")
        need(isinstance(self.peer, (bool, np.bool_)), "peer", f"must be true or false, got {self.peer!r}")
        m = self.methods
        need(m is None or (isinstance(m, tuple) and len(m) >= 1 and all(isinstance(x, str) for x in m)),
             "methods", f"must be None or a non-empty list of method labels, got {m!r}")
        if m is not None:
            known = [x.label for x in methods()]
            unknown = [x for x in m if x not in known]
            need(not unknown, "methods", f"unknown {unknown}; choose from {known}")
            need(len(set(m)) == len(m), "methods", f"must not repeat a label, got {list(m)}")


def _per_iteration(name: str, pop_size: int) -> int:
    """Fitness evaluations per iteration of a registered optimizer at its default config."""
    from icgo.optim import get

    alg = get(name)
    return int(alg.evals(pop_size, alg.config_cls())[1])


def study_functions(data, config: OptimizerStudyConfig) -> tuple:
    """The functions a run covers: ``config.functions`` (or all) of the suite ``data`` (None = ``STUDY``).

    Raises:
        SettingError: ``functions`` names a function outside the suite, or the suite is bad.
    """
    suite = bm.STUDY if data is None else data
    if isinstance(suite, str) or not all(isinstance(n, str) and n in bm.SPECS for n in suite) or not len(suite):
        raise ValueError(f"optimizer study data must be a non-empty tuple of names from {list(bm.SPECS)} "
                         f"or None, got {data!r}")
    chosen = tuple(config.functions or suite)
    unknown = [n for n in chosen if n not in suite]
    need(not unknown, "functions", f"unknown {unknown}; choose from {list(suite)}")
    return chosen


# ===================================================================== lineup
class Job(NamedTuple):
    """One compiled call per dimension: an algorithm with one config or several side by side.

    Attributes:
        name: job name (the compilation report's key).
        algorithm: registry name in :mod:`icgo.optim` (also the mealpy peer's key in :data:`PEERS`).
        config: the config (``configs`` None), or None with ``configs``.
        configs: configs run side by side along the algorithm's axis, or None.
        labels: one method label per config.
    """

    name: str
    algorithm: str
    config: object
    configs: tuple | None
    labels: tuple


def _cgo_label(variant: str, strategy: str | None = None) -> str:
    """``cgo (matlab)``, ``cgo (paper, original)``, ``icgo (paper, three_stage)`` (ICGO: CGO + a 4th-seed mutation)."""
    if strategy is None:
        return f"{CGO.name} ({variant})"
    return f"{'' if strategy == STRATEGIES[0] else 'i'}{CGO.name} ({variant}, {strategy})"


def jobs() -> tuple[Job, ...]:
    """The study's jobs in run order (job ``j`` draws from ``fold_in(key, 1000 D + j)``)."""
    out = []
    for factory in (CGOConfig.paper, CGOConfig.mealpy):
        base = factory()
        name = CGO.name if base.variant == CGOConfig().variant else f"{CGO.name}_{base.variant}"
        out.append(Job(name, CGO.name, None, tuple(CGO.axis_configs(base, CGO_STRATEGIES)),
                       tuple(_cgo_label(base.variant, s) for s in CGO_STRATEGIES)))
    matlab = CGOConfig.matlab()
    out.append(Job(f"{CGO.name}_{matlab.variant}", CGO.name, matlab, None, (_cgo_label(matlab.variant),)))
    for alg in (PSO, GA, SMA):
        out.append(Job(alg.name, alg.name, None, None, tuple(alg.labels())))
    return tuple(out)


class Method(NamedTuple):
    """One of our methods (a row family of the cell table) and its peer."""

    label: str
    job: str
    algorithm: str

    @property
    def peer_label(self) -> str:
        """The peer's name in the cell table, e.g. ``mealpy OriginalCGO``."""
        return f"mealpy {PEERS[self.algorithm][1]}"

    @property
    def peer_runs_label(self) -> str:
        """The peer's name in the run table, e.g. ``mealpy cgo``."""
        return f"mealpy {self.algorithm}"


def methods(config: OptimizerStudyConfig | None = None) -> tuple[Method, ...]:
    """Our methods in table order (those ``config.methods`` chooses; all without a config)."""
    chosen = None if config is None else config.methods
    return tuple(Method(label, j.name, j.algorithm) for j in jobs() for label in j.labels
                 if chosen is None or label in chosen)


# ===================================================================== our side
def ours(dim: int, runs: int, pop_size: int, budget: int, key, functions_: tuple, labels=None):
    """Our optimizers at one dimension.

    Args:
        dim: dimension D.
        runs: runs per function.
        pop_size, budget: population and evaluation budget per run.
        key: typed JAX PRNG key (see the module docstring for the per-job keys).
        functions_: function names (F of them).
        labels: the methods to return (None = all); jobs with none of them are skipped.
    Returns:
        ``({label: (errors (F, runs), evals (F, runs))}, [(job, new compiled programs, seconds)])``.
    """
    import jax

    from icgo.optim import base, run_batch

    F = len(functions_)
    s = bm.suite(functions_, dim)
    aux = jax.tree_util.tree_map(lambda a: np.repeat(np.asarray(a), runs, axis=0), s)  # (F*runs, ...)
    bounds = (-bm.BOX * np.ones(dim), bm.BOX * np.ones(dim))
    res, info = {}, []
    for j, job in enumerate(jobs()):
        if labels is not None and not set(job.labels) & set(labels):
            continue
        keys = jax.random.split(jax.random.fold_in(key, 1000 * dim + j), F * runs)
        before = base.compiled_runners()
        t0 = time.time()
        configs = None if job.configs is None else list(job.configs)
        r = run_batch(get(job.algorithm), bm.suite_fitness, bounds, keys, pop_size, max_evals=budget, config=job.config,
                      configs=configs, aux=aux)
        jax.block_until_ready(r.best_f)
        if configs is None:
            r = jax.tree_util.tree_map(lambda x: x[None], r)
        for i, label in enumerate(job.labels):
            if labels is not None and label not in labels:
                continue
            res[label] = (np.asarray(r.best_f[i]).reshape(F, runs), np.asarray(r.n_evals[i]).reshape(F, runs))
        info.append((job.name, base.compiled_runners() - before, time.time() - t0))
    return res, info


# ===================================================================== the peer
def _need_peer():
    try:
        import mealpy  # noqa: F401
        import opfunu  # noqa: F401
    except ImportError as e:  # opfunu 1.0.1 imports pkg_resources (pyproject.toml's extras)
        raise ValueError(f"peer=True needs mealpy and opfunu, which does not import here ({e}: "
                         "pip install mealpy opfunu 'setuptools<81'), or run with peer=False") from None


def cec2017_schwefel(z) -> float:
    """CEC 2017's modified Schwefel function (Awad et al. 2016, F10's base) of a rotated, scaled point ``z`` (D,).

    Written from the report's definition, for the peer where opfunu is older than 1.0.4: opfunu 1.0.1's
    ``modified_schwefel_func`` adds ``mod(z, 500)`` to 500 in the ``z > 500`` branch where the definition subtracts it.
    """
    z = np.asarray(z, float).ravel() + 420.9687462275036
    d = z.size
    inside = z * np.sin(np.sqrt(np.abs(z)))
    m_hi = 500.0 - np.fmod(z, 500.0)
    above = m_hi * np.sin(np.sqrt(np.abs(m_hi))) - (z - 500.0) ** 2 / (10000.0 * d)
    m_lo = np.fmod(np.abs(z), 500.0) - 500.0
    below = m_lo * np.sin(np.sqrt(np.abs(m_lo))) - (z + 500.0) ** 2 / (10000.0 * d)
    g = np.where(z > 500.0, above, np.where(z < -500.0, below, inside))
    return float(418.9828872724338 * d - g.sum())


def _opfunu_fixed_schwefel() -> bool:
    """Whether the installed opfunu's modified Schwefel follows the CEC 2017 definition (1.0.4 and later)."""
    import opfunu

    return tuple(int(p) for p in opfunu.__version__.split(".")[:3]) >= (1, 0, 4)


def numpy_fn(name: str, dim: int):
    """Independent numpy fitness for mealpy: opfunu's operator on the same shift/rotation data.

    Schwefel is :func:`cec2017_schwefel` where opfunu is older than 1.0.4 (the only opfunu Python 3.12 installs).
    """
    _need_peer()
    from opfunu.utils import operator as op

    b = bm.make(name, dim)
    base = {"sphere": op.sphere_func, "ellipsoid": op.elliptic_func, "rastrigin": op.rastrigin_func,
            "ackley": op.ackley_func, "griewank": op.griewank_func,
            "rosenbrock": lambda z: op.rosenbrock_func(z, shift=1.0), "levy": lambda z: op.levy_func(z, shift=1.0),
            "schwefel": op.modified_schwefel_func if _opfunu_fixed_schwefel() else cec2017_schwefel,
            "bent_cigar": op.bent_cigar_func,
            "zakharov": op.zakharov_func}[name]
    M, o, s = b.rotation, b.shift, b.scale
    return lambda x: float(base(M @ (s * (np.asarray(x) - o))))


def mealpy_runs(name: str, dim: int, algo: str, runs: int, pop_size: int, budget: int):
    """Final errors and evaluation counts of ``runs`` mealpy runs (seeds 0..runs-1).

    Args:
        name: benchmark function; dim: D.
        algo: our registry name of the algorithm (a key of :data:`PEERS`).
        runs, pop_size, budget: as in :class:`OptimizerStudyConfig`.
    Returns:
        ``(name, dim, algo, errors (runs,), evals (runs,))``.
    """
    _need_peer()
    import mealpy

    f = numpy_fn(name, dim)
    count = [0]

    def obj(x):
        count[0] += 1
        return f(x)

    # same name in both registries; mealpy's initial population also costs pop_size evaluations
    epochs = iterations_for_budget(get(algo), pop_size, budget)
    module, cls = PEERS[algo]
    make = getattr(getattr(mealpy, module), cls)
    problem = {"obj_func": obj, "bounds": mealpy.FloatVar(lb=(-bm.BOX,) * dim, ub=(bm.BOX,) * dim),
               "minmax": "min", "log_to": None}
    out, evals = [], []
    for r in range(runs):
        count[0] = 0
        g = make(epoch=epochs, pop_size=pop_size).solve(problem, seed=r)
        out.append(f(g.solution))
        evals.append(count[0])
    return name, dim, algo, np.array(out), np.array(evals)


# ===================================================================== decisions
def decide(a, b, alpha: float = 0.05) -> tuple[str, float]:
    """Rank-sum decision for one cell: (``+`` a lower, ``-`` a higher, ``=`` no significant difference, p).

    Identical samples (``np.allclose``) are ``=`` with p = 1 without a test.
    """
    from scipy.stats import ranksums

    if np.allclose(a, b):
        return "=", 1.0
    p = float(ranksums(a, b).pvalue)
    if p >= alpha:
        return "=", p
    return ("+" if np.median(a) < np.median(b) else "-"), p


def cell_table(runs: pd.DataFrame, dims, functions_, alpha: float = 0.05, methods_=None) -> pd.DataFrame:
    """The per-cell comparison computed from the run table (one row per dim x method x function).

    ``methods_``: the :class:`Method` rows (default: all of :func:`methods`).

    A method whose peer has no runs in ``runs`` gets NaN peer columns, NaN p-values and empty decisions.
    """
    from icgo.maths.stats import holm

    groups = {k: g for k, g in runs.groupby(["dim", "algorithm", "function"], sort=False)}
    q = lambda v: np.percentile(v, [25, 50, 75])  # noqa: E731
    rows = []
    for dim in dims:
        for m in methods_ or methods():
            for name in functions_:
                a = groups[(dim, m.label, name)].sort_values("run", kind="stable")
                qa = q(a.error.to_numpy())
                row = dict(dim=dim, function=name, ours=m.label, ours_median=qa[1], ours_iqr=qa[2] - qa[0],
                           ours_evals=int(a.evals.max()), mealpy=m.peer_label)
                b = groups.get((dim, m.peer_runs_label, name))
                if b is None:
                    row.update(mealpy_median=np.nan, mealpy_iqr=np.nan, mealpy_evals=np.nan, p_value=np.nan,
                               result="")
                else:
                    b = b.sort_values("run", kind="stable")
                    qb = q(b.error.to_numpy())
                    sign, p = decide(a.error.to_numpy(), b.error.to_numpy(), alpha)
                    row.update(mealpy_median=qb[1], mealpy_iqr=qb[2] - qb[0], mealpy_evals=int(b.evals.max()),
                               p_value=p, result=sign)
                rows.append(row)
    df = pd.DataFrame(rows)
    # Holm over each method's family (functions x dims): an identical algorithm gets a raw `-` in one of 16
    # cells by chance about 1 time in 3 (1 - 0.975^16 = 0.33); the adjusted decision bounds that at alpha.
    tested = df.p_value.notna()
    df["p_holm"] = np.nan
    if tested.any():
        df.loc[tested, "p_holm"] = df[tested].groupby("ours").p_value.transform(holm)
    df["result_holm"] = np.where(df.p_holm < alpha, df.result, np.where(tested, "=", ""))
    return df


def summary_table(cells: pd.DataFrame, dims, methods_=None) -> pd.DataFrame:
    """+/=/- counts per (dim, method) over the functions: after Holm (the decision) and uncorrected (for reference)."""
    out = []
    for dim in dims:
        for m in methods_ or methods():
            d = cells[(cells.ours == m.label) & (cells.dim == dim)]
            n = {c: int((d.result == c).sum()) for c in "+=-"}
            out.append({"dim": dim, "ours": m.label, "vs": m.peer_label, "+ uncorrected": n["+"],
                        "= uncorrected": n["="], "- uncorrected": n["-"],
                        "+ / = / - (Holm: the decision)":
                            "/".join(str(int((d.result_holm == c).sum())) for c in "+=-")})
    return pd.DataFrame(out)


# ===================================================================== run
class OptimizerStudyResult(NamedTuple):
    """What :func:`run` returns.

    Attributes:
        records: ``{"runs", "cells", "summary"}`` DataFrames (module docstring).
        models: ``{}``: a benchmark fits no model.
        compilation: per (dim, job): new compiled programs and seconds (machine- and cache-dependent,
            so not a record).
        wall_s: ``{"ours", "peer", "total"}`` seconds.
        functions: the functions run.
        config: the :class:`OptimizerStudyConfig`.
        methods: our methods run (:func:`methods`), in table order.
    """

    records: dict
    models: dict
    compilation: pd.DataFrame
    wall_s: dict
    functions: tuple
    config: OptimizerStudyConfig
    methods: tuple


def _typed(key):
    """A typed PRNG key (``jax.random.key`` style) from a typed or raw (``PRNGKey``) key, same bits."""
    import jax

    if jax.dtypes.issubdtype(key.dtype, jax.dtypes.prng_key):
        return key
    return jax.random.wrap_key_data(key)


def run(data, config: OptimizerStudyConfig, key) -> OptimizerStudyResult:
    """Run the benchmark.

    Args:
        data: the suite, a tuple of names from :data:`icgo.optim.benchmarks.SPECS`, or None for
            :data:`icgo.optim.benchmarks.STUDY`; ``config.functions`` picks a subset.
        config: :class:`OptimizerStudyConfig`.
        key: JAX PRNG key (typed or raw); ``PRNGKey(config.seed)`` and ``jax.random.key(config.seed)`` draw the same numbers.
    Returns:
        :class:`OptimizerStudyResult`.
    Raises:
        ValueError: a function outside the suite, or ``peer=True`` without mealpy/opfunu.
    """
    names = study_functions(data, config)
    if config.peer:
        _need_peer()
    key = _typed(key)
    chosen = methods(config)
    labels = None if config.methods is None else [m.label for m in chosen]
    t_start = time.time()
    rows, comp, t_ours = [], [], 0.0
    for dim in config.dims:
        t0 = time.time()
        res, info = ours(dim, config.runs, config.pop_size, config.budget, key, names, labels)
        t_ours += time.time() - t0
        log.info("ours D=%d: %.1f s  %s", dim, time.time() - t0, {j: (n, t) for j, n, t in info})
        comp += [dict(dim=dim, job=j, compiles=n, seconds=t) for j, n, t in info]
        for label, (vals, evals) in res.items():
            for i, name in enumerate(names):
                rows += [dict(dim=dim, algorithm=label, function=name, run=r, error=v, evals=int(e))
                         for r, (v, e) in enumerate(zip(vals[i], evals[i]))]
    t_peer = 0.0
    if config.peer:
        tasks = [(n, d, a) for d in config.dims for n in names for a in PEERS
                 if any(m.algorithm == a for m in chosen)]
        t0 = time.time()
        args = (config.runs, config.pop_size, config.budget)
        if config.jobs > 1:
            from joblib import Parallel, delayed

            mp = Parallel(n_jobs=config.jobs)(delayed(mealpy_runs)(n, d, a, *args) for n, d, a in tasks)
        else:
            mp = [mealpy_runs(n, d, a, *args) for n, d, a in tasks]
        t_peer = time.time() - t0
        log.info("mealpy: %.1f s", t_peer)
        peer_rows = []
        for n, d, a, vals, evals in mp:
            peer_rows += [dict(dim=d, algorithm=f"mealpy {a}", function=n, run=r, error=v, evals=int(e))
                          for r, (v, e) in enumerate(zip(vals, evals))]
        # our rows of dimension D, then the peer's rows of D (the row order of results/optimizers_runs.csv)
        rows = [r for dim in config.dims for part in (rows, peer_rows) for r in part if r["dim"] == dim]
    runs = pd.DataFrame(rows, columns=["dim", "algorithm", "function", "run", "error", "evals"])
    cells = cell_table(runs, config.dims, names, config.alpha, chosen)
    summary = summary_table(cells, config.dims, chosen)
    return OptimizerStudyResult({"runs": runs, "cells": cells, "summary": summary}, {},
                                pd.DataFrame(comp, columns=["dim", "job", "compiles", "seconds"]),
                                {"ours": t_ours, "peer": t_peer, "total": time.time() - t_start}, names, config, chosen)


def example() -> tuple:
    """A tiny benchmark (seconds, no mealpy): sphere and Rastrigin, D = 2, 3 runs, 60 evaluations, PSO and the
    paper CGO (original and three_stage, one compiled call), no peer."""
    labels = tuple(m.label for m in methods() if m.job in (CGO.name, PSO.name))
    return ("sphere", "rastrigin"), OptimizerStudyConfig(dims=(2,), runs=3, pop_size=4, budget=60, peer=False,
                                                         methods=labels)


STUDY = Study("optimizers", OptimizerStudyConfig, run,
              "our optimizers vs mealpy 3.x on shifted/rotated CEC 2017 functions at an equal "
              "evaluation budget (rank-sum +/=/-, Holm)", example, fits_models=False,
              write=optimizers_report.write, last=("optimizers.md",))
