"""Fitted azimuth compensations of the gyro inclinometer study as :class:`icgo.models.format.FittedModel` artifacts.

Three kinds, each mapping the instrument's own solution (measured inclination
``I``, toolface ``T`` and computed azimuth ``A_raw``, deg; frame columns
``inclination_raw_deg, toolface_raw_deg, azimuth_raw_deg``) to a compensated
azimuth (deg, [0, 360)):

* :class:`GyroNetwork` (``"gyro_network"``): the patent's 3-8-8-1 BP network
  (CN1888384 eqs. 8-12, :mod:`icgo.methods.nets`), one trained network per seed;
* :class:`GyroRELM` (``"gyro_relm"``): a RELM on the encoded (I, T, A_raw)
  (ICGO paper eqs. 8-9, :mod:`icgo.methods.relm`), one per seed, hidden weights random
  (``relm``) or searched (``icgo_relm``);
* :class:`LookupTableModel` (``"gyro_lookup_table"``): the prior-art error
  table over (I, A) with bilinear interpolation (toolface ignored).

``members(frame)`` returns every seed's compensated azimuth, (S, N), computed
exactly as the study scores it; ``apply(frame)`` the ensemble: circular mean
over seeds and the spread (sample std, deg).
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pandas as pd

from icgo.core.errors import ModelError
from icgo.methods import nets, relm
from icgo.models.format import FittedModel, data_hash, frame_values, need, need_shape
from icgo.models.relm import circular_mean_spread
from icgo.physics.frames import wrap360

#: Frame columns every gyro model reads (deg): the instrument's own attitude solution.
ANGLE_COLUMNS = ("inclination_raw_deg", "toolface_raw_deg", "azimuth_raw_deg")


def turntable_hash(frame: pd.DataFrame) -> str:
    """:func:`icgo.models.format.data_hash` of a turntable frame's measured angles and reference azimuth."""
    return data_hash(frame[list(ANGLE_COLUMNS) + ["azimuth_deg"]].to_numpy(float))


def turntable_domain(frame: pd.DataFrame) -> dict:
    """Training-domain ranges (deg) of the measured inclination and the number of points."""
    i = frame["inclination_raw_deg"].to_numpy(float)
    return {"inclination_raw_deg": [float(i.min()), float(i.max())], "n_points": int(len(frame))}


def _angles(frame: pd.DataFrame, what: str):
    v = frame_values(frame, ANGLE_COLUMNS, what)
    return v[:, 0], v[:, 1], v[:, 2]


def _ensemble(model, frame: pd.DataFrame) -> pd.DataFrame:
    """``station`` (if given), ``azimuth_raw_deg`` and the circular mean / spread (deg) of ``model.members``."""
    i, t, a_raw = _angles(frame, f"{model.KIND} model")
    mean, spread = circular_mean_spread(np.atleast_2d(model._members(i, t, a_raw)))
    out = {"station": frame["station"].to_numpy()} if "station" in frame.columns else {}
    out.update({"azimuth_raw_deg": a_raw, "azimuth_compensated": mean, "azimuth_spread_deg": spread})
    return pd.DataFrame(out)


@dataclasses.dataclass(frozen=True, eq=False)
class GyroNetwork(FittedModel):
    """The patent's network, one per seed (leading axis S on every array).

    Attributes:
        variant: the study's variant name (e.g. ``net_error``).
        net_config: :class:`icgo.methods.nets.NetConfig` fields (``hidden`` as a list).
        w1 (S, m1, n), b1 (S, m1), w2 (S, m2, m1), b2 (S, m2), v (S, m2): weights (eqs. 8-12).
        y_scale: (S,) deg per output unit. best_epoch, stopped_epoch: (S,) ints.
        best_val_loss: (S,). train_loss, val_loss: (S, epochs) training record.
    """

    KIND = "gyro_network"
    UNITS = {"y_scale": "deg", "angles": "deg"}

    variant: str
    net_config: dict
    w1: np.ndarray
    b1: np.ndarray
    w2: np.ndarray
    b2: np.ndarray
    v: np.ndarray
    y_scale: np.ndarray
    best_epoch: np.ndarray
    best_val_loss: np.ndarray
    train_loss: np.ndarray
    val_loss: np.ndarray
    stopped_epoch: np.ndarray

    @classmethod
    def from_fit(cls, variant: str, cfg: nets.NetConfig, res: nets.TrainResult, train: pd.DataFrame,
                 config: dict) -> "GyroNetwork":
        """Wrap a batched :func:`icgo.methods.nets.fit` result (seed axis first)."""
        arr = {k: np.asarray(v) for k, v in res.params._asdict().items()}
        net_cfg = {**cfg._asdict(), "hidden": list(cfg.hidden)}
        return cls(config=dict(config), data_hash=turntable_hash(train), domain=turntable_domain(train),
                   variant=variant, net_config=net_cfg, **arr, y_scale=np.asarray(res.y_scale),
                   best_epoch=np.asarray(res.best_epoch), best_val_loss=np.asarray(res.best_val_loss),
                   train_loss=np.asarray(res.train_loss), val_loss=np.asarray(res.val_loss),
                   stopped_epoch=np.asarray(res.stopped_epoch))

    def validate(self) -> None:
        """S seeds: the weights' shapes follow ``net_config`` (hidden sizes, encoding), ``y_scale`` > 0."""
        try:
            cfg = nets.check_config(self.netconfig())
            n = nets.n_inputs(cfg.encoding)
        except (TypeError, ValueError, KeyError) as e:
            raise ModelError(f"net_config is not a network configuration ({type(e).__name__}: "
                             f"{str(e).splitlines()[0][:100] if str(e) else ''})") from None
        need(isinstance(self.variant, str), "variant must be a name")
        m1, m2 = cfg.hidden
        S = np.shape(self.v)[0] if np.ndim(self.v) == 2 else -1
        need(S >= 1, f"array 'v' has shape {np.shape(self.v)}, expected (S, {m2})")
        E = np.shape(self.train_loss)[-1] if np.ndim(self.train_loss) == 2 else None
        for name, shape in (("w1", (S, m1, n)), ("b1", (S, m1)), ("w2", (S, m2, m1)), ("b2", (S, m2)), ("v", (S, m2)),
                            ("y_scale", (S,)), ("best_epoch", (S,)), ("best_val_loss", (S,)),
                            ("train_loss", (S, E)), ("val_loss", (S, E)), ("stopped_epoch", (S,))):
            need_shape(getattr(self, name), shape, name)
        need(bool(np.all(self.y_scale > 0)), "y_scale must be > 0 (deg per output unit)")

    def netconfig(self) -> nets.NetConfig:
        """The :class:`icgo.methods.nets.NetConfig` the networks were trained with."""
        return nets.NetConfig(**{**self.net_config, "hidden": tuple(self.net_config["hidden"])})

    def train_result(self) -> nets.TrainResult:
        """The :class:`icgo.methods.nets.TrainResult` (seed axis first) these arrays came from."""
        params = nets.MLPParams(*(jnp.asarray(getattr(self, k)) for k in nets.MLPParams._fields))
        return nets.TrainResult(params, jnp.asarray(self.y_scale), jnp.asarray(self.best_epoch),
                                jnp.asarray(self.best_val_loss), jnp.asarray(self.train_loss),
                                jnp.asarray(self.val_loss), jnp.asarray(self.stopped_epoch))

    def members(self, frame: pd.DataFrame) -> np.ndarray:
        """Compensated azimuth of every seed, (S, N) deg (:func:`icgo.methods.nets.predict`)."""
        return self._members(*_angles(frame, f"{self.KIND} model"))

    def _members(self, i, t, a):
        return np.asarray(nets.predict(self.train_result(), i, t, a, self.netconfig()))

    def apply(self, frame: pd.DataFrame) -> pd.DataFrame:
        """``azimuth_raw_deg``, ``azimuth_compensated`` (circular mean over seeds), ``azimuth_spread_deg``."""
        return _ensemble(self, frame)


@dataclasses.dataclass(frozen=True, eq=False)
class GyroRELM(FittedModel):
    """RELM azimuth-error compensation on (I, T, A_raw), one per seed.

    Attributes:
        method: ``relm`` (random hidden weights) or ``icgo_relm`` (searched).
        encoding: input encoding (:func:`icgo.methods.nets.encode_inputs`). hidden: L. lam: ridge lambda.
        theta: (S, (n_in + 1) L) hidden weights and biases. beta: (S, L) output weights (deg).
        mean, std: (S, n_in) input standardisation (encoded units).
        train_fitness: (S,) training fitness (RMSE, deg) of the hidden weights.
    """

    KIND = "gyro_relm"
    UNITS = {"beta": "deg", "train_fitness": "deg", "angles": "deg"}

    method: str
    encoding: str
    hidden: int
    lam: float
    theta: np.ndarray
    beta: np.ndarray
    mean: np.ndarray
    std: np.ndarray
    train_fitness: np.ndarray

    def validate(self) -> None:
        """S seeds: theta (S, (n_in + 1) L), beta (S, L), mean and std (S, n_in) with std > 0."""
        need(self.method in ("relm", "icgo_relm"), f"method must be relm or icgo_relm, got {self.method!r}")
        need(self.encoding in nets.ENCODINGS, f"encoding must be one of {nets.ENCODINGS}, got {self.encoding!r}")
        need(self.hidden >= 1, f"hidden must be >= 1, got {self.hidden}")
        need(self.lam > 0, f"lam must be > 0, got {self.lam}")
        n, L = nets.n_inputs(self.encoding), self.hidden
        S = np.shape(self.beta)[0] if np.ndim(self.beta) == 2 else -1
        need(S >= 1, f"array 'beta' has shape {np.shape(self.beta)}, expected (S, {L})")
        for name, shape in (("theta", (S, (n + 1) * L)), ("beta", (S, L)), ("mean", (S, n)), ("std", (S, n)),
                            ("train_fitness", (S,))):
            need_shape(getattr(self, name), shape, name)
        need(bool(np.all(self.std > 0)), "std must be > 0 (the inputs are divided by it)")

    def relms(self) -> relm.RELM:
        """The batched :class:`icgo.methods.relm.RELM` (seed axis first)."""
        return relm.RELM(jnp.asarray(self.theta), jnp.asarray(self.beta), jnp.asarray(self.mean),
                         jnp.asarray(self.std))

    def members(self, frame: pd.DataFrame) -> np.ndarray:
        """Compensated azimuth ``wrap360(A_raw + predicted error)`` of every seed, (S, N) deg."""
        return self._members(*_angles(frame, f"{self.KIND} model"))

    def _members(self, i, t, a):
        Xt = jnp.asarray(nets.encode_inputs(i, t, a, self.encoding))
        e = jax.vmap(lambda m: relm.predict(m, Xt))(self.relms())
        return np.asarray(wrap360(jnp.asarray(a)[None] + e))

    def apply(self, frame: pd.DataFrame) -> pd.DataFrame:
        """``azimuth_raw_deg``, ``azimuth_compensated`` (circular mean over seeds), ``azimuth_spread_deg``."""
        return _ensemble(self, frame)


@dataclasses.dataclass(frozen=True, eq=False)
class LookupTableModel(FittedModel):
    """The prior-art azimuth-error table over (inclination, azimuth) nodes.

    Attributes:
        toolface: ``"mean"`` (node = error averaged over toolface) or the one toolface used, deg.
        inc_nodes: (Ni,) deg. az_nodes: (Na,) deg in [0, 360). error: (Ni, Na) ``wrap180(A_true - A_raw)``, deg.
    """

    KIND = "gyro_lookup_table"
    UNITS = {"inc_nodes": "deg", "az_nodes": "deg", "error": "deg", "angles": "deg"}

    toolface: str | float
    inc_nodes: np.ndarray
    az_nodes: np.ndarray
    error: np.ndarray

    def __post_init__(self):
        if np.shape(self.error) != (np.size(self.inc_nodes), np.size(self.az_nodes)):
            raise ModelError(f"gyro_lookup_table: error must be ({np.size(self.inc_nodes)}, {np.size(self.az_nodes)}), "
                             f"got {np.shape(self.error)}")

    def validate(self) -> None:
        """Ascending nodes (inclination in [0, 180], azimuth in [0, 360)), the error table on them."""
        for name, hi in (("inc_nodes", 180.0), ("az_nodes", 360.0)):
            a = getattr(self, name)
            need(np.ndim(a) == 1 and bool(np.all(np.diff(a) > 0)), f"{name} must be a 1-d ascending array")
            need(bool(np.all((a >= 0) & (a <= hi))), f"{name} must lie in [0, {hi:g}] deg")
        need(isinstance(self.toolface, str) and self.toolface == "mean" or not isinstance(self.toolface, str),
             f"toolface must be 'mean' or a number (deg), got {self.toolface!r}")

    def table(self) -> nets.LookupTable:
        """The :class:`icgo.methods.nets.LookupTable`."""
        return nets.LookupTable(jnp.asarray(self.inc_nodes), jnp.asarray(self.az_nodes), jnp.asarray(self.error))

    def members(self, frame: pd.DataFrame) -> np.ndarray:
        """Compensated azimuth ``A_raw + table error at (I, A_raw)``, (1, N) deg."""
        return self._members(*_angles(frame, f"{self.KIND} model"))

    def _members(self, i, t, a):
        return np.asarray(nets.lookup_table_predict(self.table(), i, a))[None]

    def apply(self, frame: pd.DataFrame) -> pd.DataFrame:
        """``azimuth_raw_deg``, ``azimuth_compensated`` and ``azimuth_spread_deg`` (0: one table)."""
        return _ensemble(self, frame)
