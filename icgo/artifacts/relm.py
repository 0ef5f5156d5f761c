"""Fitted azimuth compensations of the ICGO-RELM study: MSA alone and MSA + RELM.

Both are :class:`icgo.artifacts.format.FittedModel` artifacts (saved as ``.npz`` + JSON
header) and hold one member per repeat of the study (each repeat fitted its own
MSA biases, input standardisation and RELM on its own training rows). ``apply``
runs every member on a new survey and returns the ensemble: the circular mean
of the members' compensated azimuths and their spread (sample std, deg), the
per-station uncertainty of the compensation.

Both follow the one model pattern (:mod:`icgo.artifacts.format`): :class:`RELMCompensation` holds an
:class:`icgo.models.compensation.RELMParams` and applies :func:`icgo.models.compensation.predict_methods`,
the forward pass the study scores with (MSA correction, eq. 2; standardised features; RELM, eq. 8;
compensated azimuth ``A_msa - H beta``); :class:`MSAModel` holds an :class:`icgo.models.msa.MSAParams` and
applies :func:`icgo.models.msa.predict_members` (eq. 2).
"""

from __future__ import annotations

import dataclasses

import jax.numpy as jnp
import numpy as np
import pandas as pd

from icgo.core.errors import ModelError
from icgo.core.settings import need
from icgo.maths.conformal import conformal_quantile
from icgo.models import msa as _msa
from icgo.models import relm as _relm
from icgo.models.compensation import RELMParams, predict_methods
from icgo.artifacts.format import CORRECTED_B, FittedModel, need_shape
from icgo.physics.frames import angle_diff, azimuth_from_gv, inclination_from_g, toolface_from_g, wrap360

SENSORS = ("gx", "gy", "gz", "bx", "by", "bz")
#: Input features of the RELM: the six raw sensor values (the paper) or G with the MSA-corrected field.
FEATURES = ("raw", "msa")
#: Largest number of hidden units of a loaded model.
MAX_HIDDEN = 100_000


def circular_mean_spread(a_deg):
    """Circular mean (deg, [0, 360)) and spread (sample std of wrapped deviations, deg) over axis 0.

    Args:
        a_deg: (R, N) azimuths of R members.
    Returns:
        (mean (N,), spread (N,)); spread is 0 for R = 1.
    """
    a = np.asarray(a_deg, float)
    ref = a[0]
    dev = np.asarray(angle_diff(a, ref[None]))
    mean_dev = dev.mean(axis=0)
    spread = dev.std(axis=0, ddof=1) if a.shape[0] > 1 else np.zeros(a.shape[1])
    return np.asarray(wrap360(ref + mean_dev)), spread


#: Nominal coverage of the conformal azimuth interval the models carry.
INTERVAL_LEVEL = 0.9


def out_of_bag_halfwidth(a_comp, a_true, train, level: float = INTERVAL_LEVEL):
    """Split-conformal half-width of the azimuth interval from out-of-bag errors (deg).

    Each repeat of a study is fitted on its own training rows; a row is out of bag
    for the repeats that did not train on it. The out-of-bag error of a row is the
    mean of those repeats' compensated-azimuth errors (wrapped); the half-width is
    the ``ceil((n + 1) level) / n`` empirical quantile of their absolute values over
    the ``n`` rows that are out of bag at least once (the split-conformal rule, with
    every repeat's held-out rows as calibration rows). Rows no repeat held out are
    not used.

    Args:
        a_comp: (S, R, N) compensated azimuths (deg) of S methods and R repeats.
        a_true: (N,) reference azimuth (deg). train: (R, N) bool, training rows of each repeat.
        level: nominal coverage.
    Returns:
        (S,) half-widths (deg); NaN for a method with no out-of-bag row.
    """
    err = np.asarray(angle_diff(np.asarray(a_comp, float), np.asarray(a_true, float)[None, None]))  # (S, R, N)
    oob = ~np.asarray(train, bool)                                                                   # (R, N)
    k = oob.sum(axis=0)
    used = k > 0
    mean_err = np.where(oob[None], err, 0.0).sum(axis=1)[:, used] / k[used]                           # (S, n)
    return np.array([conformal_quantile(np.abs(e), level) for e in mean_err])


def _attitude_columns(frame: pd.DataFrame, G) -> dict:
    out = {}
    if "station" in frame.columns:
        out["station"] = frame["station"].to_numpy()
    out["inclination_compensated"] = np.asarray(inclination_from_g(G))  # G is not corrected by these models
    out["toolface_compensated"] = np.asarray(toolface_from_g(G))
    return out


@dataclasses.dataclass(frozen=True, eq=False)
class MSAModel(FittedModel):
    """Multi-station analysis alone: constant magnetometer biases (and scales) per repeat.

    Attributes:
        params: :class:`icgo.models.msa.MSAParams` of the R members: bias (R, 3) biases eps, nT; scale (R, 3)
            scale errors s.
        repeat_ids: the repeat id of each of the R members (a fold protocol has one member per repeat and fold).
    """

    KIND = "msa"
    CORRECTS_FIELD = True
    UNITS = {"bias": "nT", "scale": "1", "gx,gy,gz": "g", "bx,by,bz": "nT", "angles": "deg"}
    PARAMS = _msa.MSAParams
    PREDICT = _msa.predict_members
    INPUTS = SENSORS

    params: _msa.MSAParams
    repeat_ids: list

    def validate(self) -> None:
        """R members: bias (R, 3), scale (R, 3) with 1 + s > 0, R repeat ids."""
        _check_members(self.params.bias, self.params.scale, self.repeat_ids, "bias", "scale")

    def apply(self, frame: pd.DataFrame) -> pd.DataFrame:
        """Per row: corrected field (ensemble mean, nT), MSA azimuth (ensemble) and its spread (deg)."""
        v = self.inputs(frame)
        G, B = v[:, :3], v[:, 3:]
        B_corr = np.asarray(self.predict(jnp.asarray(v)))
        a = np.asarray(azimuth_from_gv(G[None], B_corr))
        a_mean, spread = circular_mean_spread(a)
        Bm = B_corr.mean(axis=0)
        return pd.DataFrame({**_attitude_columns(frame, G), "azimuth_raw": np.asarray(azimuth_from_gv(G, B)),
                             **dict(zip(CORRECTED_B, Bm.T)), "azimuth_compensated": a_mean,
                             "azimuth_spread_deg": spread})


def _check_members(bias, scale, repeat_ids, bname: str, sname: str) -> int:
    R = len(repeat_ids)
    need(R >= 1, "repeat_ids must list one id per member (at least one)", error=ModelError)
    need_shape(bias, (R, 3), bname)
    need_shape(scale, (R, 3), sname)
    need(bool(np.all(1.0 + np.asarray(scale) > 0)), f"{sname} must be > -1 (the field is divided by 1 + s)", error=ModelError)
    return R


@dataclasses.dataclass(frozen=True, eq=False)
class RELMCompensation(FittedModel):
    """MSA + RELM azimuth compensation (plain RELM or optimizer-searched, one model per method and repeat).

    Attributes:
        methods: the S method labels (e.g. ``["cgo-three_stage"]``, ``["relm"]``).
        selected: the method :meth:`apply` uses by default: the one with the
            lowest mean training RMSE over repeats (training rows only).
        repeat_ids: the repeat id of each of the R members (a fold protocol has one member per repeat and fold).
        hidden: RELM hidden units L. lam: ridge lambda. features: ``raw`` or ``msa``; ``hidden`` and
            ``features`` are the params' static settings.
        params: :class:`icgo.models.compensation.RELMParams` of S methods x R repeats: msa_bias, msa_scale
            (R, 3) MSA biases (nT) and scale errors per repeat; x_mean, x_std (R, 6) input standardisation per
            repeat (g, nT); theta (S, R, 7 L) hidden weights and biases; beta (S, R, L) output weights (deg).
        train_rmse: (S, R) training RMSE of the refit (deg).
        interval_halfwidth: (S,) half-width (deg) of the conformal azimuth interval at
            :attr:`interval_level` (:func:`out_of_bag_halfwidth`).
        interval_level: its nominal coverage.
    """

    KIND = "relm_compensation"
    UNITS = {"msa_bias": "nT", "x_mean": "g,g,g,nT,nT,nT", "x_std": "g,g,g,nT,nT,nT", "beta": "deg",
             "train_rmse": "deg", "angles": "deg"}
    PARAMS = RELMParams
    PREDICT = predict_methods
    INPUTS = SENSORS

    methods: list
    selected: str
    repeat_ids: list
    hidden: int
    lam: float
    features: str
    params: RELMParams
    train_rmse: np.ndarray
    interval_halfwidth: np.ndarray
    interval_level: float = INTERVAL_LEVEL

    NAN_OK = ("interval_halfwidth",)  # NaN: a method no row was out of bag for

    @classmethod
    def params_like(cls, fields: dict) -> RELMParams:
        """Placeholder arrays with the ``hidden`` units and the ``features`` of ``fields``."""
        return RELMParams(*[0] * 6, hidden=fields["hidden"], raw_features=fields["features"] == "raw")

    def validate(self) -> None:
        """S methods x R members: the shapes agree with ``hidden``, ``x_std`` > 0, names and settings known."""
        S = len(self.methods)
        need(S >= 1 and all(isinstance(m, str) for m in self.methods) and len(set(self.methods)) == S,
             f"methods must be a list of distinct names, got {str(self.methods)[:80]}", error=ModelError)
        need(self.selected in self.methods, f"selected {self.selected!r} is not one of the methods {self.methods}", error=ModelError)
        need(self.features in FEATURES, f"features must be one of {FEATURES}, got {self.features!r}", error=ModelError)
        need(1 <= self.hidden <= MAX_HIDDEN, f"hidden must be 1 to {MAX_HIDDEN}, got {self.hidden}", error=ModelError)
        need(0 < self.lam <= _relm.MAX_LAM, f"lam must be > 0 and at most {_relm.MAX_LAM:g}, got {self.lam}", error=ModelError)
        need(0 < self.interval_level < 1, f"interval_level must be in (0, 1), got {self.interval_level}", error=ModelError)
        p = self.params
        R = _check_members(p.msa_bias, p.msa_scale, self.repeat_ids, "msa_bias", "msa_scale")
        L = self.hidden
        for name, a, shape in (("x_mean", p.x_mean, (R, 6)), ("x_std", p.x_std, (R, 6)),
                               ("theta", p.theta, (S, R, _relm.n_params(L))), ("beta", p.beta, (S, R, L)),
                               ("train_rmse", self.train_rmse, (S, R)),
                               ("interval_halfwidth", self.interval_halfwidth, (S,))):
            need_shape(a, shape, name)
        need(bool(np.all(p.x_std > 0)), "x_std must be > 0 (the inputs are divided by it)", error=ModelError)

    def method_params(self, method: str | None = None) -> RELMParams:
        """The params of one method (default :attr:`selected`): theta (1, R, 7 L), beta (1, R, L)."""
        method = self.selected if method is None else method
        if method not in self.methods:
            raise ModelError(f"method {method!r} is not in this model; it holds {self.methods}")
        s = self.methods.index(method)
        return dataclasses.replace(self.params, theta=self.params.theta[s:s + 1], beta=self.params.beta[s:s + 1])

    def members(self, frame: pd.DataFrame, method: str | None = None):
        """Every repeat's (A_msa, predicted error) for one method: two (R, N) arrays, deg
        (:func:`icgo.models.compensation.predict_methods`, the study's own forward pass)."""
        out = predict_methods(self.method_params(method), jnp.asarray(self.inputs(frame)))
        return np.asarray(out.a_msa[0]), np.asarray(out.error[0])

    def apply(self, frame: pd.DataFrame, method: str | None = None) -> pd.DataFrame:
        """Compensated azimuth per row: ensemble over repeats of ``method`` (default :attr:`selected`).

        Returns:
            DataFrame with ``station`` (if given), ``inclination_compensated``,
            ``toolface_compensated`` (from G, which these models do not correct),
            ``azimuth_raw``, ``azimuth_msa``, ``predicted_error``,
            ``azimuth_compensated`` (circular mean over repeats) and
            ``azimuth_spread_deg`` (sample std over repeats), ``azimuth_interval_deg``
            (half-width of the conformal interval at ``interval_level``), all deg; the
            MSA-corrected field ``bx_corrected, by_corrected, bz_corrected`` (ensemble mean, nT).
        """
        a_msa, pred = self.members(frame, method)
        v = self.inputs(frame)
        G, B = v[:, :3], v[:, 3:]
        a_comp, spread = circular_mean_spread(np.asarray(wrap360(a_msa - pred)))
        a_msa_mean, _ = circular_mean_spread(a_msa)
        msa = _msa.MSAParams(jnp.asarray(self.params.msa_bias), jnp.asarray(self.params.msa_scale))
        Bm = np.asarray(_msa.predict_members(msa, jnp.asarray(v))).mean(0)
        return pd.DataFrame({**_attitude_columns(frame, G), "azimuth_raw": np.asarray(azimuth_from_gv(G, B)),
                             "azimuth_msa": a_msa_mean, "predicted_error": pred.mean(axis=0),
                             "azimuth_compensated": a_comp, "azimuth_spread_deg": spread,
                             "azimuth_interval_deg": np.full(len(a_comp), float(
                                 self.interval_halfwidth[self.methods.index(method or self.selected)])),
                             **dict(zip(CORRECTED_B, Bm.T))})
