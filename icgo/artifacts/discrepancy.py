"""The discrepancy workflow's fitted physics model as an artifact (:class:`PhysicsModel`).

The final model of :func:`icgo.discrepancy.run_workflow` (the named effects with their fitted parameters,
the fitted reference field, the noise weights): a :class:`icgo.discrepancy.inversion.PhysicsParams`
pytree saved with :mod:`icgo.artifacts.format`. ``apply`` inverts it per station through the family's pure
:func:`icgo.discrepancy.inversion.predict`: the attitude that best explains each measured (G, B).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pandas as pd

from icgo.core.errors import ModelError
from icgo.core.settings import config_to_mapping, need
from icgo.discrepancy import inversion
from icgo.artifacts.format import CORRECTED_B, FittedModel, data_hash, need_shape, sensor_domain
from icgo.physics import effects as _fx
from icgo.physics.frames import azimuth_from_gv, inclination_from_g, toolface_from_g
from icgo.physics.qc import QCBands, survey_qc

SENSORS = ("gx", "gy", "gz", "bx", "by", "bz")


@dataclasses.dataclass(frozen=True, eq=False)
class PhysicsModel(FittedModel):
    """Named effects + earth field fitted by the discrepancy workflow.

    Attributes:
        effects: the effect names of the final model, in the order the search added them
            (``icgo.physics.effects`` vocabulary).
        sigma_b_nT, sigma_g: the residual weights (sensor noise, 1 sigma per axis), the params' settings.
        n_iter: LM steps of the per-station inversion, the params' setting.
        params: :class:`icgo.discrepancy.inversion.PhysicsParams`: ``effects.<name>`` (n_params,) physical
            parameters of each effect (units per effect: ``icgo.physics.effects``; nT, g, dimensionless, deg),
            ``field`` (3,) total field nT, dip deg, declination deg.
    """

    KIND = "discrepancy_model"
    CORRECTS_FIELD = True
    UNITS = {"field": "nT, deg, deg", "sigma_b_nT": "nT", "sigma_g": "g", "angles": "deg"}
    PARAMS = inversion.PhysicsParams
    PREDICT = inversion.predict
    INPUTS = SENSORS
    #: Schema 2 stores each effect's parameters as its own array (``effects.<name>``).
    OLDEST_SCHEMA = 2
    REFIT = ("refit it with python -m experiments.discrepancy data=<its data>, which saves discrepancy_model.json "
             "in the run directory")

    effects: list
    sigma_b_nT: float
    sigma_g: float
    params: inversion.PhysicsParams
    n_iter: int = inversion.N_ITER

    #: Largest number of LM steps of the per-station inversion a loaded model may ask for.
    MAX_ITER = 1000

    @classmethod
    def params_like(cls, fields: dict) -> inversion.PhysicsParams:
        """One placeholder array per effect of ``fields["effects"]`` and the field, with the meta's settings."""
        effects = fields["effects"]
        need(all(isinstance(n, str) and n in _fx.EFFECTS for n in effects),
             f"effects must be names of icgo.physics.effects ({', '.join(_fx.EFFECTS)}), got {str(effects)[:80]}", error=ModelError)
        return inversion.PhysicsParams({n: 0 for n in effects}, 0, fields["sigma_b_nT"], fields["sigma_g"],
                                       fields.get("n_iter", inversion.N_ITER))

    def validate(self) -> None:
        """Known effects with their parameter counts, field (3,) with |F| > 0, noise > 0, a bounded n_iter."""
        need(len(set(self.effects)) == len(self.effects), "effects must not repeat", error=ModelError)
        need(set(self.effects) == set(self.params.effects), f"effects {self.effects} are not the params' "
                                                            f"{sorted(self.params.effects)}", error=ModelError)
        for n in self.effects:
            need_shape(self.params.effects[n], (_fx.EFFECTS[n].n_params,), f"effects.{n}")
        f = self.params.field
        need_shape(f, (3,), "field")
        need(f[0] > 0 and abs(f[1]) <= 90, "field must be (total nT > 0, dip deg in [-90, 90], declination deg)", error=ModelError)
        need(self.sigma_b_nT > 0 and self.sigma_g > 0, "sigma_b_nT and sigma_g must be > 0", error=ModelError)
        need(1 <= self.n_iter <= self.MAX_ITER, f"n_iter must be 1 to {self.MAX_ITER}, got {self.n_iter}", error=ModelError)

    @classmethod
    def from_params(cls, params: inversion.PhysicsParams, effects, G, B, config: dict) -> "PhysicsModel":
        """The artifact of fitted params, with the training stations' hash and domain.

        Args:
            params: :class:`icgo.discrepancy.inversion.PhysicsParams`. effects: their names in the model's
                order. G, B: (n, 3) training stations, g and nT. config: the fit's settings (JSON-able).
        """
        params = inversion.PhysicsParams({n: np.asarray(params.effects[n], float) for n in effects},
                                         np.asarray(params.field, float), params.sigma_b_nT, params.sigma_g,
                                         params.n_iter)
        return cls(config=config, data_hash=data_hash(G, B), domain=sensor_domain(G, B), effects=list(effects),
                   sigma_b_nT=params.sigma_b_nT, sigma_g=params.sigma_g, params=params, n_iter=params.n_iter)

    @classmethod
    def from_result(cls, res, G, B) -> "PhysicsModel":
        """The model of a workflow result (:func:`icgo.discrepancy.inversion.physics_params`), with the
        training stations' hash and domain."""
        return cls.from_params(inversion.physics_params(res), res.model, G, B, config_to_mapping(res.config))

    def apply(self, frame: pd.DataFrame) -> pd.DataFrame:
        """Per row: raw attitude and the attitude the fitted physics model explains best (deg).

        ``azimuth_compensated`` is in the frame of the fitted declination (true
        north when the field was given with its declination), as is
        ``azimuth_raw`` (the standard formula on the raw sensors, + declination).
        ``bx_corrected .. bz_corrected`` (nT): the measured field with the fitted disturbance
        removed (:class:`icgo.discrepancy.inversion.Inversion`), what survey QC checks after the model.
        """
        x = self.inputs(frame)
        G, B = x[:, :3], x[:, 3:]
        inv = self.predict(x)
        out = {}
        if "station" in frame.columns:
            out["station"] = frame["station"].to_numpy()
        out.update({"inclination_raw": np.asarray(inclination_from_g(G)), "toolface_raw": np.asarray(toolface_from_g(G)),
                    "azimuth_raw": np.mod(np.asarray(azimuth_from_gv(G, B)) + float(self.params.field[2]), 360.0),
                    "inclination_compensated": np.asarray(inv.inclination),
                    "azimuth_compensated": np.asarray(inv.azimuth)})
        out.update(dict(zip(CORRECTED_B, np.asarray(inv.b_corrected).T)))
        return pd.DataFrame(out)


def station_qc(model: PhysicsModel, st, bands: QCBands = QCBands()) -> dict | None:
    """Survey-QC counts of the stations before and after the model, or None without a reference field.

    Args:
        model: the fitted physics model. st: :class:`icgo.discrepancy.stations.Stations`
            (its ``field`` is the reference: total nT, dip deg, declination deg).
        bands: QC bands.
    Returns:
        ``{"raw": counts, "physics": counts}`` (:class:`icgo.physics.qc.QCResult` counts); "after" checks
        the field with the fitted disturbance removed (``bx_corrected ..``).
    """
    if st.field is None:
        return None
    F, dip = float(st.field[0]), float(st.field[1])
    after = np.asarray(model.predict(np.hstack([st.G, st.B])).b_corrected)
    return {"raw": survey_qc(st.G, st.B, F, dip, st.gravity_g, bands).counts,
            "physics": survey_qc(st.G, after, F, dip, st.gravity_g, bands).counts}
