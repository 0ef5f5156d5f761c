"""Fitted azimuth compensations of the gyro inclinometer study as :class:`icgo.artifacts.format.FittedModel` artifacts.

Three kinds, each a params pytree and the pure ``predict`` of its family, mapping the instrument's own
solution (measured inclination ``I``, toolface ``T`` and computed azimuth ``A_raw``, deg; frame columns
``inclination_raw_deg, toolface_raw_deg, azimuth_raw_deg``, the input ``x`` (N, 3)) to a compensated
azimuth (deg, [0, 360)):

* :class:`GyroNetwork` (``"gyro_network"``): the patent's 3-8-8-1 BP network
  (CN1888384 eqs. 8-12), :class:`icgo.models.nets.NetParams` of every seed and
  :func:`icgo.models.nets.predict_seeds`;
* :class:`GyroRELM` (``"gyro_relm"``): a RELM on the encoded (I, T, A_raw)
  (ICGO paper eqs. 8-9), :class:`icgo.models.gyro_relm.GyroRELMParams` of every seed and
  :func:`icgo.models.gyro_relm.predict_seeds`; hidden weights random (``relm``) or searched (``icgo_relm``);
* :class:`LookupTableModel` (``"gyro_lookup_table"``): the prior-art error table over (I, A) with bilinear
  interpolation (toolface ignored), :class:`icgo.models.lookup_table.LookupTable` and
  :func:`icgo.models.lookup_table.predict`.

``members(frame)`` returns every seed's compensated azimuth, (S, N) ((1, N) for the table), by the
same ``predict`` the study scores with; ``apply(frame)`` the ensemble: circular mean over seeds and the
spread (sample std, deg).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pandas as pd

from icgo.core.errors import ModelError
from icgo.core.settings import need
from icgo.models import gyro_relm, lookup_table, nets
from icgo.artifacts.format import FittedModel, data_hash, need_shape
from icgo.artifacts.relm import circular_mean_spread

#: Frame columns every gyro model reads (deg): the instrument's own attitude solution, the input ``x``.
ANGLE_COLUMNS = ("inclination_raw_deg", "toolface_raw_deg", "azimuth_raw_deg")


def turntable_hash(frame: pd.DataFrame) -> str:
    """:func:`icgo.artifacts.format.data_hash` of a turntable frame's measured angles and reference azimuth."""
    return data_hash(frame[list(ANGLE_COLUMNS) + ["azimuth_deg"]].to_numpy(float))


def turntable_domain(frame: pd.DataFrame) -> dict:
    """Training-domain ranges (deg) of the measured inclination and the number of points."""
    i = frame["inclination_raw_deg"].to_numpy(float)
    return {"inclination_raw_deg": [float(i.min()), float(i.max())], "n_points": int(len(frame))}


def _net_config(net_config: dict) -> nets.NetConfig:
    """The checked :class:`icgo.models.nets.NetConfig` of a saved ``net_config`` (ModelError naming it)."""
    try:
        return nets.check_config(nets.NetConfig(**{**net_config, "hidden": tuple(net_config["hidden"])}))
    except (TypeError, ValueError, KeyError) as e:
        raise ModelError(f"net_config is not a network configuration ({type(e).__name__}: "
                         f"{str(e).splitlines()[0][:100] if str(e) else ''})") from None


def _seeds(a, name: str, tail: tuple) -> int:
    """S, the leading axis of ``a`` whose trailing shape must be ``tail`` (ModelError naming ``name``)."""
    S = np.shape(a)[0] if np.ndim(a) == 1 + len(tail) else -1
    need(S >= 1, f"array {name!r} has shape {np.shape(a)}, expected (S, {', '.join(map(str, tail))})", error=ModelError)
    return S


@dataclasses.dataclass(frozen=True, eq=False)
class GyroModel(FittedModel):
    """What the three gyro kinds share: the input ``x`` (:data:`ANGLE_COLUMNS`), members and the ensemble."""

    INPUTS = ANGLE_COLUMNS

    def members(self, frame: pd.DataFrame) -> np.ndarray:
        """Compensated azimuth of every member, (S, N) deg (the study's ``predict``)."""
        return self._members(self.inputs(frame))

    def _members(self, x) -> np.ndarray:
        return np.atleast_2d(np.asarray(self.predict(x)))

    def apply(self, frame: pd.DataFrame) -> pd.DataFrame:
        """``station`` (if given), ``azimuth_raw_deg``, ``azimuth_compensated`` (circular mean over members)
        and ``azimuth_spread_deg`` (sample std over members; 0 for one)."""
        x = self.inputs(frame)
        mean, spread = circular_mean_spread(self._members(x))
        out = {"station": frame["station"].to_numpy()} if "station" in frame.columns else {}
        out.update({"azimuth_raw_deg": x[:, 2], "azimuth_compensated": mean, "azimuth_spread_deg": spread})
        return pd.DataFrame(out)


@dataclasses.dataclass(frozen=True, eq=False)
class GyroNetwork(GyroModel):
    """The patent's network, one per seed (leading axis S on every array).

    Attributes:
        variant: the study's variant name (e.g. ``net_error``).
        net_config: :class:`icgo.models.nets.NetConfig` fields (``hidden`` as a list); its ``encoding`` and
            ``target`` are the params' settings.
        params: :class:`icgo.models.nets.NetParams`: w1 (S, m1, n), b1 (S, m1), w2 (S, m2, m1), b2 (S, m2),
            v (S, m2) weights (eqs. 8-12), y_scale (S,) deg per output unit.
        best_epoch, stopped_epoch: (S,) ints. best_val_loss: (S,). train_loss, val_loss: (S, epochs): the
            training record.
    """

    KIND = "gyro_network"
    UNITS = {"y_scale": "deg", "angles": "deg"}
    PARAMS = nets.NetParams
    PREDICT = nets.predict_seeds

    variant: str
    net_config: dict
    params: nets.NetParams
    best_epoch: np.ndarray
    best_val_loss: np.ndarray
    train_loss: np.ndarray
    val_loss: np.ndarray
    stopped_epoch: np.ndarray

    @classmethod
    def params_like(cls, fields: dict) -> nets.NetParams:
        """Placeholder weights with the ``encoding`` and ``target`` of ``fields["net_config"]``."""
        cfg = _net_config(fields["net_config"])
        return nets.NetParams(*[0] * 6, encoding=cfg.encoding, target=cfg.target)

    @classmethod
    def from_fit(cls, variant: str, cfg: nets.NetConfig, res: nets.TrainResult, train: pd.DataFrame,
                 config: dict) -> "GyroNetwork":
        """Wrap a batched :func:`icgo.models.nets.fit` result (seed axis first)."""
        record = {k: np.asarray(getattr(res, k)) for k in ("best_epoch", "best_val_loss", "train_loss", "val_loss",
                                                           "stopped_epoch")}
        params = nets.NetParams(*(np.asarray(getattr(res.params, k)) for k in ("w1", "b1", "w2", "b2", "v",
                                                                                 "y_scale")),
                                encoding=res.params.encoding, target=res.params.target)
        return cls(config=dict(config), data_hash=turntable_hash(train), domain=turntable_domain(train),
                   variant=variant, net_config={**cfg._asdict(), "hidden": list(cfg.hidden)}, params=params, **record)

    def validate(self) -> None:
        """S seeds: the weights' shapes follow ``net_config`` (hidden sizes, encoding), ``y_scale`` > 0."""
        cfg = self.netconfig()
        n = nets.n_inputs(cfg.encoding)
        need(isinstance(self.variant, str), "variant must be a name", error=ModelError)
        m1, m2 = cfg.hidden
        p = self.params
        S = _seeds(p.v, "v", (m2,))
        E = np.shape(self.train_loss)[-1] if np.ndim(self.train_loss) == 2 else None
        for name, a, shape in (("w1", p.w1, (S, m1, n)), ("b1", p.b1, (S, m1)), ("w2", p.w2, (S, m2, m1)),
                               ("b2", p.b2, (S, m2)), ("v", p.v, (S, m2)), ("y_scale", p.y_scale, (S,)),
                               ("best_epoch", self.best_epoch, (S,)), ("best_val_loss", self.best_val_loss, (S,)),
                               ("train_loss", self.train_loss, (S, E)), ("val_loss", self.val_loss, (S, E)),
                               ("stopped_epoch", self.stopped_epoch, (S,))):
            need_shape(a, shape, name)
        need(bool(np.all(p.y_scale > 0)), "y_scale must be > 0 (deg per output unit)", error=ModelError)

    def netconfig(self) -> nets.NetConfig:
        """The :class:`icgo.models.nets.NetConfig` the networks were trained with."""
        return _net_config(self.net_config)


@dataclasses.dataclass(frozen=True, eq=False)
class GyroRELM(GyroModel):
    """RELM azimuth-error compensation on (I, T, A_raw), one per seed.

    Attributes:
        method: ``relm`` (random hidden weights) or ``icgo_relm`` (searched).
        encoding: input encoding (:func:`icgo.models.nets.encode_inputs`), the params' setting. hidden: L.
            lam: ridge lambda.
        params: :class:`icgo.models.gyro_relm.GyroRELMParams`: theta (S, (n_in + 1) L) hidden weights and
            biases, beta (S, L) output weights (deg), mean and std (S, n_in) input standardisation.
        train_fitness: (S,) training fitness (RMSE, deg) of the hidden weights.
    """

    KIND = "gyro_relm"
    UNITS = {"beta": "deg", "train_fitness": "deg", "angles": "deg"}
    PARAMS = gyro_relm.GyroRELMParams
    PREDICT = gyro_relm.predict_seeds

    method: str
    encoding: str
    hidden: int
    lam: float
    params: gyro_relm.GyroRELMParams
    train_fitness: np.ndarray

    @classmethod
    def params_like(cls, fields: dict) -> gyro_relm.GyroRELMParams:
        """Placeholder arrays with the ``encoding`` of ``fields``."""
        return gyro_relm.GyroRELMParams(*[0] * 4, encoding=fields.get("encoding"))

    def validate(self) -> None:
        """S seeds: theta (S, (n_in + 1) L), beta (S, L), mean and std (S, n_in) with std > 0."""
        need(self.method in ("relm", "icgo_relm"), f"method must be relm or icgo_relm, got {self.method!r}", error=ModelError)
        need(self.encoding in nets.ENCODINGS, f"encoding must be one of {nets.ENCODINGS}, got {self.encoding!r}", error=ModelError)
        need(self.hidden >= 1, f"hidden must be >= 1, got {self.hidden}", error=ModelError)
        need(self.lam > 0, f"lam must be > 0, got {self.lam}", error=ModelError)
        n, L, p = nets.n_inputs(self.encoding), self.hidden, self.params
        S = _seeds(p.beta, "beta", (L,))
        for name, a, shape in (("theta", p.theta, (S, (n + 1) * L)), ("beta", p.beta, (S, L)), ("mean", p.mean, (S, n)),
                               ("std", p.std, (S, n)), ("train_fitness", self.train_fitness, (S,))):
            need_shape(a, shape, name)
        need(bool(np.all(p.std > 0)), "std must be > 0 (the inputs are divided by it)", error=ModelError)


@dataclasses.dataclass(frozen=True, eq=False)
class LookupTableModel(GyroModel):
    """The prior-art azimuth-error table over (inclination, azimuth) nodes.

    Attributes:
        toolface: ``"mean"`` (node = error averaged over toolface) or the one toolface used, deg.
        params: :class:`icgo.models.lookup_table.LookupTable`: inc_nodes (Ni,) deg, az_nodes (Na,) deg in
            [0, 360), error (Ni, Na) ``wrap180(A_true - A_raw)``, deg.
    """

    KIND = "gyro_lookup_table"
    UNITS = {"inc_nodes": "deg", "az_nodes": "deg", "error": "deg", "angles": "deg"}
    PARAMS = lookup_table.LookupTable
    PREDICT = lookup_table.predict

    toolface: str | float
    params: lookup_table.LookupTable

    def __post_init__(self):
        t = self.params
        if np.shape(t.error) != (np.size(t.inc_nodes), np.size(t.az_nodes)):
            raise ModelError(f"gyro_lookup_table: error must be ({np.size(t.inc_nodes)}, {np.size(t.az_nodes)}), "
                             f"got {np.shape(t.error)}")

    def validate(self) -> None:
        """Ascending nodes (inclination in [0, 180], azimuth in [0, 360)), the error table on them."""
        for name, hi in (("inc_nodes", 180.0), ("az_nodes", 360.0)):
            a = getattr(self.params, name)
            need(np.ndim(a) == 1 and bool(np.all(np.diff(a) > 0)), f"{name} must be a 1-d ascending array", error=ModelError)
            need(bool(np.all((a >= 0) & (a <= hi))), f"{name} must lie in [0, {hi:g}] deg", error=ModelError)
        need(isinstance(self.toolface, str) and self.toolface == "mean" or not isinstance(self.toolface, str),
             f"toolface must be 'mean' or a number (deg), got {self.toolface!r}", error=ModelError)
