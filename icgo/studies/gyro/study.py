"""The gyro inclinometer study (patent CN1888384): BP network vs lookup table (+ RELM, ICGO-RELM).

Training data: the patent's turntable plan (:func:`icgo.datasets.gyro_turntable.turntable`:
inclination 3, 5, 10, 15, 25, 35, 45, 55, 65, 75 deg x azimuth and toolface
every 30 deg = 1440 points) from a 2-axis gyro + 2-accelerometer instrument
with repeatable systematic errors. Test data: a dense random set of attitudes
in the same ranges (:func:`icgo.datasets.gyro_turntable.turntable_random`) and a set half-way
between the grid points in I, A and T (:func:`icgo.datasets.gyro_turntable.turntable_between`).

Methods, each scored by the azimuth RMSE (deg) on both test sets, ``n_seeds``
seeds per trained method (mean +/- sample std over seeds, ddof 1):

* ``raw``: the instrument's computed azimuth (patent eq. 7);
* ``table``: the prior-art error table over (I, A), toolface ignored, bilinear
  (:mod:`icgo.models.lookup_table`; :class:`icgo.artifacts.network.LookupTableModel`);
* the network variants of ``variants`` (patent eqs. 8-12, :mod:`icgo.models.nets`; all
  seeds of one variant train in one jitted, vmapped call;
  :class:`icgo.artifacts.network.GyroNetwork`);
* ``relm`` / ``icgo_relm``: RELM (ICGO paper eqs. 8-9, :mod:`icgo.models.gyro_relm`) on the
  encoded (I, T, computed A) with random hidden weights, or with hidden
  weights searched by ``relm.optimizer`` (CGO with the three-stage 4th-seed
  mutation by default) on the training-only RELM fitness
  (:class:`icgo.artifacts.network.GyroRELM`).

Every method is scored through its family's pure ``predict(params, x)`` on the test sets' measured angles
(:func:`predict_all`), the function its saved model applies.

Also: error vs number of turntable points (:func:`points_sweep`) and the
``target=azimuth`` seam at north (:func:`seam_rows`).

Randomness: ``key`` is split into the ``n_seeds`` per-seed keys shared by every
trained method (seed k of every method uses key k); the data sets' noise comes
from ``config.seed`` (train ``seed``, random ``seed + 1``, between ``seed + 2``).
"""

from __future__ import annotations

import dataclasses
import logging
import time
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import pandas as pd

from icgo.core.errors import SettingError
from icgo.core.settings import is_int, is_real, need
from icgo.datasets import gyro_turntable
from icgo.maths import stats
from icgo.physics import metrics
from icgo.models import gyro_relm, lookup_table, nets, relm
from icgo.artifacts.network import ANGLE_COLUMNS, GyroNetwork, GyroRELM, LookupTableModel, turntable_domain, turntable_hash
from icgo.optim.cgo import CGO
from icgo.optim.registry import get
from icgo.physics.frames import angle_diff
from icgo.physics.qc import earth_rate_qc
from icgo.studies.gyro import report as gyro_report
from icgo.studies.common.study import Study

log = logging.getLogger(__name__)


# ===================================================================== config
# Every check raises icgo.core.errors.SettingError(<dotted key>, <problem>): one line, "<key> <problem>".
def _integer(where, v, minimum=1):
    """SettingError unless ``v`` is an integer >= minimum."""
    need(is_int(v) and v >= minimum, where, f"must be an integer >= {minimum}, got {v!r}")


def _in_range(where, v, lo, hi):
    """SettingError unless ``v`` is a finite number with lo < v <= hi."""
    need(is_real(v) and lo < v <= hi, where, f"must be a number in ({lo:g}, {hi:g}], got {v!r}")


def _steps(where, values):
    """Tuple of angle steps, each in (0, 360] deg."""
    need(not isinstance(values, (str, bytes)) and hasattr(values, "__len__"), where,
         f"must be a list of steps in deg, got {values!r}")
    for v in values:
        _in_range(where, v, 0.0, 360.0)
    return tuple(values)


@dataclasses.dataclass(frozen=True)
class DataConfig:
    """The turntable plan (:func:`icgo.datasets.gyro_turntable.turntable`).

    Attributes:
        inclinations_deg: test inclinations, deg, each in (0, 90) (patent's 10 points).
        azimuth_step_deg, toolface_step_deg: grid steps, deg, in (0, 360].
        n_random: size of the dense random test set (I within the plan's range).
        instrument: overrides of the simulated instrument (see ``turntable``'s docstring).
    """

    inclinations_deg: tuple = (3, 5, 10, 15, 25, 35, 45, 55, 65, 75)
    azimuth_step_deg: float = 30
    toolface_step_deg: float = 30
    n_random: int = 2000
    instrument: dict = dataclasses.field(default_factory=dict)

    def __post_init__(self):
        inc = self.inclinations_deg
        need(not isinstance(inc, (str, bytes)) and hasattr(inc, "__len__") and len(inc) >= 2,
             "data.inclinations_deg", f"must list at least 2 inclinations, got {inc!r}")
        for v in inc:
            need(is_real(v) and 0 < v < 90, "data.inclinations_deg", f"each must be in (0, 90) deg, got {v!r}")
        object.__setattr__(self, "inclinations_deg", tuple(inc))
        _in_range("data.azimuth_step_deg", self.azimuth_step_deg, 0.0, 360.0)
        _in_range("data.toolface_step_deg", self.toolface_step_deg, 0.0, 360.0)
        _integer("data.n_random", self.n_random)
        need(isinstance(self.instrument, dict), "data.instrument",
             f"must be a mapping of instrument overrides, got {self.instrument!r}")


_NET = nets.NetConfig()  # the one source of the network defaults


@dataclasses.dataclass(frozen=True)
class NetSection:
    """:class:`icgo.models.nets.NetConfig` defaults of every network variant (same fields, same meaning, same defaults)."""

    hidden: tuple = _NET.hidden
    encoding: str = _NET.encoding
    target: str = _NET.target
    optimizer: str = _NET.optimizer
    learning_rate: float = _NET.learning_rate
    epochs: int = _NET.epochs
    batch_size: int = _NET.batch_size
    val_fraction: float = _NET.val_fraction
    patience: int = _NET.patience
    init_scale: float = _NET.init_scale

    def __post_init__(self):
        if isinstance(self.hidden, (list, tuple)):
            object.__setattr__(self, "hidden", tuple(self.hidden))
        self.netconfig({}, "net")

    def netconfig(self, overrides: dict, where: str) -> nets.NetConfig:
        """The checked :class:`icgo.models.nets.NetConfig` of these defaults updated by ``overrides``.

        Raises:
            SettingError: ``<where> ...`` for an unknown key or a bad value.
        """
        d = {**dataclasses.asdict(self), **dict(overrides or {})}
        unknown = sorted(set(d) - set(nets.NetConfig._fields))
        need(not unknown, where, f"unknown key(s) {unknown}; known: {list(nets.NetConfig._fields)}")
        try:
            d["hidden"] = tuple(int(h) for h in d["hidden"])
            return nets.check_config(nets.NetConfig(**d))  # the one validation of NetConfig
        except (TypeError, ValueError) as e:
            raise SettingError(where, str(e).splitlines()[0]) from None


def _default_variants():
    patent_sgd = {"optimizer": "sgd", "batch_size": 1, "learning_rate": 0.01, "epochs": 1000, "patience": 200}
    return {"net_error": {}, "net_error_sincos": {"encoding": "sincos"}, "net_error_sgd_patent": dict(patent_sgd),
            "net_azimuth": {"target": "azimuth"}, "net_azimuth_sgd_patent": {"target": "azimuth", **patent_sgd}}


@dataclasses.dataclass(frozen=True)
class TableConfig:
    """Lookup table: ``toolface="mean"`` (node = error averaged over toolface) or one toolface (deg).

    Attributes:
        toolface: ``mean`` (each node the error averaged over the toolface positions) or a number: only the
            stations at that toolface, deg.
    """

    toolface: str | float = "mean"

    def __post_init__(self):
        tf = self.toolface
        need(tf == "mean" or is_real(tf), "table.toolface", f"must be 'mean' or a toolface in deg, got {tf!r}")


@dataclasses.dataclass(frozen=True)
class RelmConfig:
    """Plain RELM and ICGO-RELM on (I, T, computed A); target = azimuth error (deg).

    Attributes:
        enabled: run both. encoding: as the network's. hidden: L. lam: ridge lambda.
        theta_bounds: (low, high) of the hidden weights. fitness: train (paper) | validation | kfold.
        optimizer: registered optimizer of the search; strategy: its side-by-side axis value
            (CGO: the 4th-seed mutation; ignored by optimizers without an axis).
        pop_size, iterations: search budget.
    """

    enabled: bool = True
    encoding: str = "scaled"
    hidden: int = 30
    lam: float = 1.0e-3
    theta_bounds: tuple = (-1.0, 1.0)
    fitness: str = "train"
    optimizer: str = CGO.name
    strategy: str = "three_stage"
    pop_size: int = 30
    iterations: int = 100

    def __post_init__(self):
        need(self.encoding in nets.ENCODINGS, "relm.encoding", f"must be one of {nets.ENCODINGS}, got {self.encoding!r}")
        need(self.fitness in relm.FITNESS_MODES, "relm.fitness",
             f"must be one of {relm.FITNESS_MODES}, got {self.fitness!r}")
        _integer("relm.hidden", self.hidden)
        need(is_real(self.lam) and self.lam > 0, "relm.lam", f"must be a number > 0, got {self.lam!r}")
        tb = tuple(self.theta_bounds) if isinstance(self.theta_bounds, (list, tuple)) else ()
        need(len(tb) == 2 and all(is_real(x) for x in tb) and tb[0] < tb[1], "relm.theta_bounds",
             f"must be [low, high] with low < high, got {self.theta_bounds!r}")
        object.__setattr__(self, "theta_bounds", tb)
        _integer("relm.pop_size", self.pop_size, minimum=4)
        _integer("relm.iterations", self.iterations)
        self.search_configs()

    def search_configs(self):
        """``run_batch(configs=...)`` for the search: one config at ``strategy`` on the optimizer's axis, or None."""
        from icgo.optim import get

        try:
            alg = get(self.optimizer)
        except ValueError as e:
            raise SettingError("relm.optimizer", str(e)) from None
        if alg.axis is None:
            return None
        try:
            return alg.axis_configs(None, [self.strategy])
        except (TypeError, ValueError) as e:
            raise SettingError("relm.strategy", str(e).splitlines()[0]) from None


@dataclasses.dataclass(frozen=True)
class SweepConfig:
    """Error vs number of turntable points: the network (``variant``) and the table on each step pair.

    Attributes:
        enabled: run it. variant: the network variant retrained on each plan (a key of ``variants``).
        azimuth_steps, toolface_steps: the plans' grid steps, deg (every pair is one plan).
        table_only_azimuth_steps: denser azimuth steps for the table alone (the network is not retrained), deg.
    """

    enabled: bool = True
    variant: str = "net_error"
    azimuth_steps: tuple = (30, 60)
    toolface_steps: tuple = (30, 45, 60, 90)
    table_only_azimuth_steps: tuple = (10, 15)

    def __post_init__(self):
        for f in ("azimuth_steps", "toolface_steps", "table_only_azimuth_steps"):
            object.__setattr__(self, f, _steps(f"sweep.{f}", getattr(self, f)))


@dataclasses.dataclass(frozen=True)
class SeamConfig:
    """The 0/360 seam: "near north" = |true azimuth| < ``band_deg`` (deg, in (0, 180]).

    Attributes:
        band_deg: half-width of the band around north whose errors are reported apart, deg, in (0, 180].
    """

    band_deg: float = 15

    def __post_init__(self):
        _in_range("seam.band_deg", self.band_deg, 0.0, 180.0)


@dataclasses.dataclass(frozen=True)
class GyroConfig:
    """The whole study (defaults = ``conf/gyro.yaml``; tested field by field).

    Attributes:
        seed: data noise seed (int >= 0). n_seeds: networks / RELMs per method.
        data, net, table, relm, sweep, seam: the sections above.
        variants: name -> overrides of ``net`` (one row of the methods table each).
    """

    seed: int = 0
    n_seeds: int = 10
    data: DataConfig = DataConfig()
    net: NetSection = NetSection()
    variants: dict = dataclasses.field(default_factory=_default_variants)
    table: TableConfig = TableConfig()
    relm: RelmConfig = RelmConfig()
    sweep: SweepConfig = SweepConfig()
    seam: SeamConfig = SeamConfig()

    def __post_init__(self):
        _integer("seed", self.seed, minimum=0)
        _integer("n_seeds", self.n_seeds)
        need(isinstance(self.variants, dict) and bool(self.variants), "variants",
             "at least one network variant is needed")
        object.__setattr__(self, "variants", {str(k): dict(v or {}) for k, v in self.variants.items()})
        for name, ov in self.variants.items():
            self.net.netconfig(ov, f"variants.{name}")
        need(not self.sweep.enabled or self.sweep.variant in self.variants, "sweep.variant",
             f"{self.sweep.variant!r} is not one of variants {list(self.variants)}")

    def netconfig(self, variant: str) -> nets.NetConfig:
        """The :class:`icgo.models.nets.NetConfig` of one variant."""
        return self.net.netconfig(self.variants[variant], f"variants.{variant}")


# ======================================================================= data
class GyroData(NamedTuple):
    """Training turntable frame and the test frames ``{"random": ..., "between": ...}``."""

    train: pd.DataFrame
    tests: dict


def turntable_train(config: GyroConfig, azimuth_step=None, toolface_step=None) -> pd.DataFrame:
    """The training plan (seed ``config.seed``), optionally with other azimuth/toolface steps (deg)."""
    d = config.data
    return gyro_turntable.turntable(config.seed, inclinations_deg=[float(x) for x in d.inclinations_deg],
                              azimuth_step_deg=float(d.azimuth_step_deg if azimuth_step is None else azimuth_step),
                              toolface_step_deg=float(d.toolface_step_deg if toolface_step is None else toolface_step),
                              **d.instrument).frame


def load_data(config: GyroConfig) -> GyroData:
    """Training plan and the two test sets of :class:`GyroConfig` ``.data``."""
    d = config.data
    inc = [float(x) for x in d.inclinations_deg]
    tests = {
        "random": gyro_turntable.turntable_random(config.seed + 1, n=int(d.n_random),
                                            inclination_range_deg=(min(inc), max(inc)), **d.instrument).frame,
        "between": gyro_turntable.turntable_between(config.seed + 2, inclinations_deg=inc,
                                              azimuth_step_deg=float(d.azimuth_step_deg),
                                              toolface_step_deg=float(d.toolface_step_deg), **d.instrument).frame,
    }
    return GyroData(turntable_train(config), tests)


def _cols(f: pd.DataFrame):
    """Measured (I, T, A_raw) and reference A (deg) of a turntable frame, four (N,) arrays."""
    return (f["inclination_raw_deg"].to_numpy(), f["toolface_raw_deg"].to_numpy(),
            f["azimuth_raw_deg"].to_numpy(), f["azimuth_deg"].to_numpy())


# ==================================================================== scoring
def azimuth_errors(a_true, a_pred):
    """Wrapped errors ``A_pred - A_true`` (deg, (-180, 180]), shape of ``a_pred`` ((S, N) or (N,))."""
    return np.asarray(angle_diff(np.asarray(a_pred), np.asarray(a_true)))


def rmse_per_seed(a_true, a_pred) -> np.ndarray:
    """(S,) azimuth RMSE (deg, :func:`icgo.physics.metrics.rmse`, wrapped) per seed; ``a_pred`` (S, N) or (N,)."""
    return np.asarray(metrics.rmse(np.asarray(a_true), np.atleast_2d(np.asarray(a_pred))))


def seed_mean_std(x) -> tuple[float, float]:
    """(mean, sample std) over seeds (:func:`icgo.maths.stats.mean_std`, ddof 1); std 0 for a single value."""
    x = np.atleast_1d(np.asarray(x, float))
    return stats.mean_std(x) if x.size > 1 else (float(x[0]), 0.0)


def pm(x, digits=3) -> str:
    """``"mean +/- std"`` over seeds (sample std, :func:`icgo.maths.stats.format_mean_std`), or the single value."""
    x = np.atleast_1d(np.asarray(x, float))
    return stats.format_mean_std(*seed_mean_std(x), digits=digits) if x.size > 1 else f"{x[0]:.{digits}f}"


def score_rows(method, preds: dict, tests: dict, extra=None) -> list[dict]:
    """One row per test set: RMSE / MAE / max |error| (deg) per seed, summarised over seeds.

    Args:
        preds: test name -> (S, N) or (N,) compensated azimuth, deg.
        tests: test name -> frame with ``azimuth_deg``.
        extra: columns added to every row.
    """
    rows = []
    for k, f in tests.items():
        e = np.atleast_2d(azimuth_errors(f["azimuth_deg"].to_numpy(), preds[k]))
        r = rmse_per_seed(f["azimuth_deg"].to_numpy(), preds[k])
        r_mean, r_std = seed_mean_std(r)
        rows.append({"method": method, "test": k, "n_seeds": e.shape[0],
                     "rmse_mean": r_mean, "rmse_std": r_std,
                     "mae_mean": np.abs(e).mean(1).mean(), "max_abs_mean": np.abs(e).max(1).mean(),
                     "rmse": pm(r), **(extra or {})})
    return rows


def seam_rows(method, preds, f: pd.DataFrame, band) -> dict:
    """RMSE (deg) within ``band`` deg of north vs elsewhere, and their ratio; preds (S, N) or (N,)."""
    a = f["azimuth_deg"].to_numpy()
    north = np.abs(np.asarray(angle_diff(a, 0.0))) < band
    p = np.atleast_2d(np.asarray(preds))
    (rn, rn_std), (rf, rf_std) = (seed_mean_std(rmse_per_seed(a[m], p[:, m])) for m in (north, ~north))
    return {"method": method, "n_north": int(north.sum()), "rmse_north_mean": rn,
            "rmse_north_std": rn_std, "rmse_elsewhere_mean": rf, "rmse_elsewhere_std": rf_std,
            "ratio": rn / rf}


def predict_all(model, tests: dict) -> dict:
    """``{test: (S, N) compensated azimuth, deg}``: the model's ``predict`` (its family's pure forward pass on its
    params, :meth:`icgo.artifacts.format.FittedModel.predict`) on each test set's measured angles ((1, N) for the
    table)."""
    return {k: np.atleast_2d(np.asarray(model.predict(f[list(ANGLE_COLUMNS)].to_numpy(float))))
            for k, f in tests.items()}


# ==================================================================== methods
def fit_table(tcfg: TableConfig, train: pd.DataFrame, config: dict) -> LookupTableModel:
    """The lookup table from the turntable points (nominal I, A; error ``A_true - A_raw``)."""
    err = azimuth_errors(train["azimuth_raw_deg"], train["azimuth_deg"])
    tf = tcfg.toolface
    t = lookup_table.fit(train["inclination_deg"], train["azimuth_deg"], err, toolface_deg=train["toolface_deg"],
                         at_toolface_deg=None if tf == "mean" else float(tf))
    return LookupTableModel(config=dict(config), data_hash=turntable_hash(train), domain=turntable_domain(train),
                            toolface=tf, params=lookup_table.LookupTable(*(np.asarray(a) for a in t)))


def fit_network(variant: str, ncfg: nets.NetConfig, keys, train: pd.DataFrame, config: dict):
    """Train ``len(keys)`` networks in one vmapped call; (GyroNetwork, seconds incl. compilation)."""
    i, t, a, at = _cols(train)
    t0 = time.perf_counter()
    res = nets.fit(keys, i, t, a, at, ncfg)
    jax.block_until_ready(res.params)
    secs = time.perf_counter() - t0
    return GyroNetwork.from_fit(variant, ncfg, res, train, config), secs


def fit_relm(rc: RelmConfig, keys, train: pd.DataFrame, optimized: bool, config: dict):
    """Plain RELM or ICGO-RELM on the encoded (I, T, A_raw); target = wrapped error ``A_true - A_raw``.

    Hidden weights per seed are random (``optimized=False``) or searched by ``rc.optimizer``
    (:func:`icgo.models.gyro_relm.search_theta`); the output weights are the ridge solution (eq. 9) on
    all training points (:func:`icgo.models.gyro_relm.refit`).

    Returns:
        (GyroRELM, seconds incl. compilation).
    """
    L, lam, bounds = int(rc.hidden), float(rc.lam), tuple(float(x) for x in rc.theta_bounds)
    i, t, a, at = _cols(train)
    X = jnp.asarray(nets.encode_inputs(i, t, a, rc.encoding))
    T = jnp.asarray(azimuth_errors(a, at))
    t0 = time.perf_counter()
    data, k_theta = gyro_relm.fit_data(keys, X, T, rc.fitness)
    if optimized:
        theta, best_f = gyro_relm.search_theta(keys, data, L, lam, bounds, get(rc.optimizer), rc.search_configs(),
                                               int(rc.pop_size), int(rc.iterations))
    else:
        theta, best_f = gyro_relm.random_theta(k_theta, data, L, lam, bounds)
    params = gyro_relm.refit(theta, X, T, lam, L, rc.encoding)
    jax.block_until_ready(params.beta)
    secs = time.perf_counter() - t0
    params = jax.tree.map(np.asarray, params)
    model = GyroRELM(config=dict(config), data_hash=turntable_hash(train), domain=turntable_domain(train),
                     method="icgo_relm" if optimized else "relm", encoding=rc.encoding, hidden=L, lam=lam,
                     params=params, train_fitness=np.asarray(best_f))
    return model, secs


# ===================================================================== sweep
def sweep_steps(config: GyroConfig) -> list:
    """(azimuth step, toolface step, with network) of the points sweep, deg."""
    sw = config.sweep
    steps = [(float(a), float(t), True) for a in sw.azimuth_steps for t in sw.toolface_steps]
    return steps + [(float(a), float(t), False) for a in sw.table_only_azimuth_steps for t in sw.toolface_steps]


def points_sweep(config: GyroConfig, keys, tests: dict, default_preds: dict) -> pd.DataFrame:
    """Test RMSE vs number of turntable points: the table on every step pair, the network on the first ones.

    ``default_preds`` are the sweep variant's predictions on the default plan (not retrained).
    """
    rows = [{**r, "azimuth_step_deg": np.nan, "toolface_step_deg": np.nan, "n_points": np.nan}
            for r in score_rows("raw", {k: f["azimuth_raw_deg"].to_numpy() for k, f in tests.items()}, tests)]
    ncfg = config.netconfig(config.sweep.variant)
    default = (float(config.data.azimuth_step_deg), float(config.data.toolface_step_deg))
    for a_step, t_step, with_net in sweep_steps(config):
        tr = turntable_train(config, a_step, t_step)
        meta = {"azimuth_step_deg": a_step, "toolface_step_deg": t_step, "n_points": len(tr)}
        rows += score_rows("table", predict_all(fit_table(config.table, tr, {}), tests), tests, meta)
        if with_net:
            preds = default_preds if (a_step, t_step) == default else \
                predict_all(fit_network(config.sweep.variant, ncfg, keys, tr, {})[0], tests)
            rows += score_rows("network", preds, tests, meta)
        log.info("[gyro] sweep A step %g, T step %g: %d points", a_step, t_step, len(tr))
    return pd.DataFrame(rows)


# ======================================================================= run
class GyroResult(NamedTuple):
    """Result of :func:`run`.

    Attributes:
        records: ``methods`` (one row per method and test set), ``seam`` (random test set),
            ``points`` (if the sweep ran); RMSE etc. in deg.
        models: ``table``, each network variant, ``relm`` and ``icgo_relm`` (if enabled).
        summary: n_train, n_tests, train_seconds (per method, incl. compilation), best_epoch
            (per variant and seed), ``<relm method>_train_fitness`` (deg, per seed).
        predictions: method -> test -> (S, N) compensated azimuth, deg (``raw``: (N,)).
    """

    records: dict
    models: dict
    summary: dict
    predictions: dict


def _model_config(config: GyroConfig, method: str) -> dict:
    return {"study": "gyro", "method": method, "seed": config.seed, "n_seeds": config.n_seeds}


def rate_qc(train: pd.DataFrame, tests: dict) -> dict:
    """Earth-rate QC counts (:func:`icgo.physics.qc.earth_rate_qc`) of the raw gyro, per data set.

    The instrument has no magnetometer and its gz is implied by |g|, so the |G| / |B| / dip
    checks cannot fail here; the total-rate check is the gyro survey's. The methods correct the
    azimuth, not the rates, so there is no "after" count. Data sets without the rate columns
    (``wx, wy, wz``) are left out.
    """
    return {name: earth_rate_qc(f[["wx", "wy", "wz"]].to_numpy(float)).counts
            for name, f in {"train": train, **tests}.items() if {"wx", "wy", "wz"} <= set(f.columns)}


def run(data: GyroData | None, config: GyroConfig, key) -> GyroResult:
    """Run the study (see the module doc).

    Args:
        data: :class:`GyroData`, or None for :func:`load_data` ``(config)``.
        config: :class:`GyroConfig`.
        key: JAX PRNG key, split into the ``n_seeds`` per-seed keys.
    """
    data = load_data(config) if data is None else data
    train, tests = data
    keys = jax.random.split(key, int(config.n_seeds))
    log.info("[gyro] train %d turntable points; tests %s", len(train),
             ", ".join(f"{k} {len(v)}" for k, v in tests.items()))
    summary = {"n_train": len(train), "n_tests": {k: len(v) for k, v in tests.items()},
               "train_seconds": {}, "best_epoch": {}, "qc": rate_qc(train, tests)}
    preds = {"raw": {k: f["azimuth_raw_deg"].to_numpy() for k, f in tests.items()}}
    models = {"table": fit_table(config.table, train, _model_config(config, "table"))}
    preds["table"] = predict_all(models["table"], tests)
    for name in config.variants:
        models[name], summary["train_seconds"][name] = fit_network(name, config.netconfig(name), keys, train,
                                                                  _model_config(config, name))
        preds[name] = predict_all(models[name], tests)
        summary["best_epoch"][name] = np.asarray(models[name].best_epoch).tolist()
        log.info("[gyro] %s: %.1f s for %d networks; random RMSE %s", name, summary["train_seconds"][name],
                 len(keys), pm(rmse_per_seed(tests["random"]["azimuth_deg"].to_numpy(), preds[name]["random"])))
    if config.relm.enabled:
        for name, optimized in (("relm", False), ("icgo_relm", True)):
            models[name], summary["train_seconds"][name] = fit_relm(config.relm, keys, train, optimized,
                                                                    _model_config(config, name))
            preds[name] = predict_all(models[name], tests)
            summary[f"{name}_train_fitness"] = models[name].train_fitness.tolist()
            log.info("[gyro] %s: %.1f s", name, summary["train_seconds"][name])
    records = {"methods": pd.DataFrame([r for m, p in preds.items() for r in score_rows(m, p, tests)])}
    band = float(config.seam.band_deg)
    records["seam"] = pd.DataFrame([seam_rows(m, p["random"], tests["random"], band) for m, p in preds.items()
                                    if m != "table"])
    if config.sweep.enabled:
        records["points"] = points_sweep(config, keys, tests, preds[config.sweep.variant])
    return GyroResult(records, models, summary, preds)


def example() -> tuple[GyroData, GyroConfig]:
    """A tiny real instance (seconds once compiled): a 32-point plan, 2 seeds, one network variant, no RELM/sweep."""
    cfg = GyroConfig(n_seeds=2, data=DataConfig(inclinations_deg=(10, 40), azimuth_step_deg=90, toolface_step_deg=90,
                                                n_random=50),
                     net=NetSection(epochs=10, patience=10, batch_size=8), variants={"net_error": {}},
                     relm=RelmConfig(enabled=False), sweep=SweepConfig(enabled=False))
    return load_data(cfg), cfg


def objective(result: GyroResult) -> float | None:
    """What a hyperparameter search minimises (``hydra/sweeper=optuna`` on the gyro door): the networks' best
    validation loss (the part of the turntable plan each network holds out for early stopping; scaled units),
    averaged over the network variants and seeds; never a test set's error. None without a network variant."""
    losses = [np.asarray(m.best_val_loss, float) for m in result.models.values() if hasattr(m, "best_val_loss")]
    return float(np.mean(np.concatenate([x.ravel() for x in losses]))) if losses else None


STUDY = Study("gyro", GyroConfig, run,
              "gyro inclinometer: the patent's BP network vs its lookup table, plus RELM and ICGO-RELM",
              example, load=load_data, write=gyro_report.write, last=("gyro_run.json",),
              objective=objective)
