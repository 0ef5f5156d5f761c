"""Fitted 12-parameter sensor calibrations as :class:`icgo.artifacts.format.FittedModel` artifacts.

One kind, :class:`MagCalibration` (``KIND = "mag_calibration"``), holds what any calibration method of the
calibrate and MISMA studies fits (MISMA paper eqs. 2-4, :mod:`icgo.models.calibration`) as a
:class:`icgo.models.calibration_params.CalibrationParams` pytree and applies it through that family's one
forward pass, :func:`icgo.models.calibration_params.predict`, the one its study scores with:

* the magnetometer parameters ``x_mag = [R^-1 (row-major, 9), b (3, nT)]``,
  corrected field ``B_c = R^-1 (B_meas - b)`` (eq. 4);
* optionally the accelerometer parameters ``x_accel = [S (9), c (3, g)]``,
  ``G_c = S (G_meas - c)`` (the real-device pipelines calibrate both sensors);
* optionally one rotation ``Q`` (3, 3) common to both sensors (axis alignment,
  :func:`icgo.models.cal_pointing.align_to_axis`), applied as ``v @ Q.T``;
* optionally the field's non-linear residual (:mod:`icgo.models.mag_relm`), applied last.

Meta: ``field_scale_nT``: nT per unit of the fitted field. A fit to ``|M_omega|`` in
nT (the simulated studies) has 1.0; a fit to the unit sphere (the real devices) is scaled to the site's field
where one is known (:func:`in_earth_units`: the mean corrected ``|B|`` of its training shots is the site's ``|B|``,
and ``field_reference`` records that site), so ``apply`` reports the field in earth units and its QC compares it
with the reference; where no site is known it carries the median raw ``|B|`` of its training shots and
``field_reference`` is null: a **relative** calibration (the field's direction is calibrated, its level is the
sensor's own scale). ``accuracy``: the expected accuracy the calibrate door stated for this model
(:func:`with_accuracy`), the one every later door prints for it (null: none stated).
``method`` names the method that produced the numbers (:data:`METHODS`:
``ellipsoid``, ``twelve`` (12-parameter least squares), ``misma``, ``sma``,
``joint``, ``modulus`` (MISMA's centre U), ``twelve_relm``); ``axis_aligned`` says whether ``Q`` is
present and ``nl_activation`` names the residual's activation (both also in the params: the header says
which parts a model has, with ``null`` for each part it lacks).
:meth:`MagCalibration.corrected` gives the corrected vectors in fit units (what the studies score);
:meth:`MagCalibration.apply` the data-contract table.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pandas as pd

from icgo.core.errors import ModelError
from icgo.core.settings import need
from icgo.models import calibration as cal
from icgo.models import calibration_params as cal_params
from icgo.models import mag_relm
from icgo.artifacts.format import CORRECTED_B, FittedModel, data_hash, frame_values, sensor_domain
from icgo.physics.frames import azimuth_from_gv, inclination_from_g, toolface_from_g

#: Methods a :class:`MagCalibration` may come from.
METHODS = ("ellipsoid", "twelve", "misma", "sma", "joint", "modulus", "twelve_relm")

_G_COLS = ("gx", "gy", "gz")
_B_COLS = ("bx", "by", "bz")


def _check_params(name, x):
    x = np.asarray(x)
    if x.shape != (cal.N_PARAMS,) or not np.all(np.isfinite(x)):
        raise ModelError(f"mag_calibration: {name} must be {cal.N_PARAMS} finite numbers, got shape {x.shape}")


@dataclasses.dataclass(frozen=True, eq=False)
class MagCalibration(FittedModel):
    """A 12-parameter magnetometer calibration (optionally with accelerometer, axis alignment and residual).

    Attributes:
        method: one of :data:`METHODS`.
        axis_aligned: whether the params hold an alignment.
        field_scale_nT: nT per unit of the corrected field (1.0 for fits in nT).
        params: :class:`icgo.models.calibration_params.CalibrationParams`: ``x_mag`` (12,) ``[R^-1 row-major,
            b]``, ``b`` in raw nT (it is subtracted from the raw reading); ``x_accel`` (12,) ``[S, c (g)]`` or
            None (accelerometer used as read); ``alignment`` (3, 3) rotation Q or None; ``nl_hidden`` (4, L),
            ``nl_out`` (L, 3), the non-linear residual after the alignment, or None (a linear calibration).
        nl_activation: the residual's hidden activation (:data:`icgo.models.mag_relm.ACTIVATIONS`), given exactly
            with a residual; the params' static setting.
        field_reference: the site the field was scaled to, ``{"total_field_nT", "dip_deg", "origin"}``, or None:
            a relative calibration where the fit was to the unit sphere (:attr:`relative`; :func:`in_earth_units`;
            older files have none and load as relative).
        accuracy: the expected accuracy stated when it was fitted (:data:`ACCURACY_KEYS`), or None.
    """

    KIND = "mag_calibration"
    CORRECTS_FIELD = True
    #: A calibration makes the field one earth field: its corrected |B| and dip are checked for spread over a
    #: survey's stations (icgo.survey.apply.one_field_doubt).
    ONE_FIELD = True
    UNITS = {"x_mag": "R^-1 (1), b (nT)", "x_accel": "S (1), c (g)", "alignment": "1",
             "bx,by,bz": "nT", "gx,gy,gz": "g", "angles": "deg", "b_total_nT": "nT"}
    PARAMS = cal_params.CalibrationParams
    PREDICT = cal_params.predict
    INPUTS = _G_COLS + _B_COLS
    OPTIONAL_LEAVES = cal_params.OPTIONAL_LEAVES
    LATER_FIELDS = ("field_reference", "accuracy")

    method: str
    axis_aligned: bool
    field_scale_nT: float
    params: cal_params.CalibrationParams
    nl_activation: str | None = None
    field_reference: dict | None = None
    accuracy: dict | None = None

    def __post_init__(self):
        if self.method not in METHODS:
            raise ModelError(f"mag_calibration: method {self.method!r} is not one of {METHODS}")
        p = self.params
        if not isinstance(p, cal_params.CalibrationParams):
            raise ModelError(f"mag_calibration: params must be a CalibrationParams, got {type(p).__name__}")
        if bool(self.axis_aligned) != (p.alignment is not None):
            raise ModelError("mag_calibration: axis_aligned must be true exactly when an alignment is given")
        if p.alignment is not None and np.shape(p.alignment) != (3, 3):
            raise ModelError(f"mag_calibration: alignment must be (3, 3), got {np.shape(p.alignment)}")
        if not (np.isfinite(self.field_scale_nT) and self.field_scale_nT > 0):
            raise ModelError(f"mag_calibration: field_scale_nT must be > 0, got {self.field_scale_nT}")
        _check_params("x_mag", p.x_mag)
        if p.x_accel is not None:
            _check_params("x_accel", p.x_accel)
        if (p.nl_hidden is None) != (p.nl_out is None):
            raise ModelError("mag_calibration: nl_hidden and nl_out come together")
        if p.nl_hidden is not None:
            h, o = np.asarray(p.nl_hidden), np.asarray(p.nl_out)
            if h.ndim != 2 or h.shape[0] != 4 or o.shape != (h.shape[1], 3) or not (np.all(np.isfinite(h))
                                                                                  and np.all(np.isfinite(o))):
                raise ModelError(f"mag_calibration: nl_hidden (4, L) and nl_out (L, 3) must be finite, got "
                                 f"{h.shape} and {o.shape}")
        act = self.nl_activation
        if p.nl_hidden is not None and act is None:
            raise ModelError("mag_calibration: a non-linear correction without nl_activation (model schema 1 as an "
                             "older icgo build wrote it); refit the model")
        if act is not None and (p.nl_hidden is None or act not in mag_relm.ACTIVATIONS):
            raise ModelError(f"mag_calibration: nl_activation must be one of {mag_relm.ACTIVATIONS} and comes with "
                             f"nl_hidden, got {act!r}")
        if p.nl_activation != act:
            raise ModelError(f"mag_calibration: nl_activation {act!r} is not the params' {p.nl_activation!r}")
        ref = self.field_reference
        if ref is not None:
            ok = (isinstance(ref, dict) and set(ref) == {"total_field_nT", "dip_deg", "origin"}
                  and isinstance(ref["origin"], str) and all(
                      isinstance(ref[k], (int, float)) and not isinstance(ref[k], bool) and np.isfinite(ref[k])
                      for k in ("total_field_nT", "dip_deg"))
                  and ref["total_field_nT"] > 0 and -90.0 <= ref["dip_deg"] <= 90.0)
            if not ok:
                raise ModelError(f"mag_calibration: field_reference must be {{total_field_nT > 0, dip_deg in [-90, 90], "
                                 f"origin}}, got {str(ref)[:80]}")
        acc = self.accuracy
        if acc is not None and not (isinstance(acc, dict) and set(ACCURACY_KEYS) <= set(acc)
                                    and isinstance(acc["deg"], (int, float)) and np.isfinite(acc["deg"])
                                    and isinstance(acc["what"], str)):
            raise ModelError(f"mag_calibration: accuracy must hold {list(ACCURACY_KEYS)} (deg a finite number), got "
                             f"{str(acc)[:80]}")

    @property
    def relative(self) -> bool:
        """Whether the corrected field is in the sensor's own scale, not the site's: a unit-sphere fit (its
        ``field_scale_nT`` not 1) that records no ``field_reference``. A fit in nT (``field_scale_nT`` 1: MISMA's
        simulated studies, fitted to the reference ``|M_omega|``) is in earth units as fitted."""
        return self.field_reference is None and self.field_scale_nT != 1.0

    @classmethod
    def params_like(cls, fields: dict) -> cal_params.CalibrationParams:
        """Placeholders for ``x_mag`` and each optional part the header does not mark ``null``, with the
        meta's ``nl_activation``."""
        parts = {n: None if fields.get(n, 0) is None else 0 for n in cls.OPTIONAL_LEAVES}
        return cal_params.CalibrationParams(x_mag=0, **parts, nl_activation=fields.get("nl_activation"))

    #: Largest condition number of a loaded calibration's matrices (R^-1, S): beyond it a matrix is singular
    #: in float64 and the corrected field meaningless.
    MAX_CONDITION = 1e8

    def validate(self) -> None:
        """The matrices R^-1 (and S) invertible, the alignment a rotation."""
        for name, x in (("x_mag", self.params.x_mag), ("x_accel", self.params.x_accel)):
            if x is not None:
                M = np.asarray(x, np.float64)[:9].reshape(3, 3)
                need(bool(np.linalg.cond(M) < self.MAX_CONDITION), f"{name}: its matrix is singular (condition "
                                                                     f"{np.linalg.cond(M):.3g})", error=ModelError)
        if self.params.alignment is not None:
            Q = np.asarray(self.params.alignment, np.float64)
            need(bool(np.allclose(Q @ Q.T, np.eye(3), atol=1e-6) and np.linalg.det(Q) > 0),
                 "alignment must be a rotation matrix (orthonormal, determinant +1)", error=ModelError)

    def corrected(self, G, B) -> tuple[np.ndarray | None, np.ndarray]:
        """Calibrated, rotated and residual-corrected ``(G_c (N, 3) g, B_c (N, 3) fit units)`` on the host
        (:func:`icgo.models.calibration_params.predict`); ``G`` may be None (then ``G_c`` is None)."""
        B = np.asarray(B, np.float64)
        G_in = np.zeros_like(B) if G is None else np.asarray(G, np.float64)
        out = self.predict(np.concatenate([G_in, B], axis=1))
        return (None if G is None else np.ascontiguousarray(out[:, :3])), np.ascontiguousarray(out[:, 3:])

    def apply(self, frame: pd.DataFrame) -> pd.DataFrame:
        """Corrected sensor values per row; attitude, dip and |B| when the frame has gravity.

        Returns:
            DataFrame with ``station`` (if given), ``bx_corrected, by_corrected,
            bz_corrected`` and ``b_total_nT`` (nT); with ``gx, gy, gz`` also
            ``gx_corrected, gy_corrected, gz_corrected`` (g), ``inclination_compensated``,
            ``toolface_compensated``, ``azimuth_compensated`` (magnetic, from the corrected
            vectors) and ``dip_compensated_deg``.
        """
        B = frame_values(frame, _B_COLS, "mag_calibration model")
        has_g = all(c in frame.columns for c in _G_COLS)
        G = frame_values(frame, _G_COLS, "mag_calibration model") if has_g else None
        Gc, Bc = self.corrected(G, B)
        B_nT = Bc * self.field_scale_nT
        bn = np.linalg.norm(B_nT, axis=1)
        out = {"station": frame["station"].to_numpy()} if "station" in frame.columns else {}
        out.update({**dict(zip(CORRECTED_B, B_nT.T)), "b_total_nT": bn})
        if has_g:
            gn = np.linalg.norm(Gc, axis=1)
            sin_dip = np.clip(np.sum(Gc * B_nT, axis=1) / (gn * bn), -1.0, 1.0)
            out.update({"gx_corrected": Gc[:, 0], "gy_corrected": Gc[:, 1], "gz_corrected": Gc[:, 2],
                        "inclination_compensated": np.asarray(inclination_from_g(Gc)),
                        "toolface_compensated": np.asarray(toolface_from_g(Gc)),
                        "azimuth_compensated": np.asarray(azimuth_from_gv(Gc, B_nT)),
                        "dip_compensated_deg": np.degrees(np.arcsin(sin_dip))})
        return pd.DataFrame(out)


#: The keys every ``accuracy`` of a model holds: ``deg`` (the expected score, the peer's pointing-spread metric),
#: ``what`` (what it is, in words); optionally ``spread_deg`` (its standard error), ``nested_deg`` /
#: ``nested_spread_deg`` / ``nested_what`` (the recommendation rule's nested score, named as such).
ACCURACY_KEYS = ("deg", "what")


def in_earth_units(model: MagCalibration, G, B, site) -> MagCalibration:
    """``model`` with its field scaled to the site's: ``field_scale_nT`` such that the mean corrected ``|B|`` over the
    shots (G, B) (its training shots) is the site's ``|B|``, and the site recorded in ``field_reference``.

    Args:
        G, B: (N, 3) the training shots (g, nT raw). site: :class:`icgo.io.site.Site` (dip deg, |B| nT, origin)
            or None (the model returned as it is: relative).
    """
    if site is None:
        return model
    _, Bc = model.corrected(G, B)
    mean = float(np.mean(np.linalg.norm(Bc, axis=1)))
    return dataclasses.replace(model, field_scale_nT=float(site.field_nT) / mean, field_reference={
        "total_field_nT": float(site.field_nT), "dip_deg": float(site.dip_deg), "origin": str(site.origin)})


def with_accuracy(model: MagCalibration, accuracy: dict | None) -> MagCalibration:
    """``model`` carrying the expected accuracy stated for it (:data:`ACCURACY_KEYS`; None: none)."""
    return dataclasses.replace(model, accuracy=None if accuracy is None else dict(accuracy))


def mag_calibration(method: str, x_mag, G, B, config: dict, *, x_accel=None, alignment=None,
                    field_scale_nT: float = 1.0) -> MagCalibration:
    """Build a linear :class:`MagCalibration` with the header of its training data.

    Args:
        method: one of :data:`METHODS`.
        x_mag: (12,) magnetometer parameters. G, B: (N, 3) training shots (g, nT raw).
        config: the settings of the fit (JSON-able).
        x_accel: (12,) accelerometer parameters or None. alignment: (3, 3) or None.
        field_scale_nT: nT per fit unit.
    """
    arr = lambda a: None if a is None else np.array(a, np.float64)
    params = cal_params.CalibrationParams(x_mag=arr(x_mag), x_accel=arr(x_accel), alignment=arr(alignment))
    return MagCalibration(config=dict(config), data_hash=data_hash(G, B), domain=sensor_domain(G, B),
                          method=method, axis_aligned=alignment is not None, field_scale_nT=float(field_scale_nT),
                          params=params)


def with_residual(model: MagCalibration, nl: mag_relm.MagRELM, config: dict) -> MagCalibration:
    """A linear calibration with the non-linear residual ``nl`` fitted after it (method ``twelve_relm``).

    Args:
        model: the linear calibration the residual was fitted on (its data hash and domain are kept).
        nl: the fitted residual (:func:`icgo.models.mag_relm.fit`). config: the settings of the whole fit.
    """
    params = dataclasses.replace(model.params, nl_hidden=np.array(nl.hidden, np.float64),
                                 nl_out=np.array(nl.out, np.float64), nl_activation=nl.activation)
    return dataclasses.replace(model, method="twelve_relm", params=params, nl_activation=nl.activation,
                               config=dict(config))
