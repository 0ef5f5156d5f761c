"""The discrepancy workflow's fitted physics model as an artifact (:class:`PhysicsModel`).

The final model of :func:`icgo.discrepancy.run_workflow` (the named effects with
their fitted parameters, the fitted reference field, the noise weights) saved
with :mod:`icgo.models`. ``apply`` inverts it per station: the attitude that
best explains each measured (G, B) (:func:`icgo.discrepancy.fit.correct_with`).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pandas as pd

from icgo.discrepancy.fit import correct_with, model_params
from icgo.discrepancy.noise import Noise
from icgo.frames import azimuth_from_gv, inclination_from_g, toolface_from_g
from icgo.models import FittedModel, frame_values, register_model, sensor_domain
from icgo.studies import config_to_mapping

SENSORS = ("gx", "gy", "gz", "bx", "by", "bz")


@register_model
@dataclasses.dataclass(frozen=True, eq=False)
class PhysicsModel(FittedModel):
    """Named effects + earth field fitted by the discrepancy workflow.

    Attributes:
        effects: the effect names of the final model, in order (``icgo.effects`` vocabulary).
        sizes: number of parameters of each effect.
        params: (sum(sizes),) their physical parameters, concatenated (units per effect:
            ``icgo.effects``; nT, g, dimensionless, deg).
        field: (3,) total field nT, dip deg, declination deg.
        sigma_b_nT, sigma_g: the residual weights (sensor noise, 1 sigma per axis).
        n_iter: LM steps of the per-station inversion.
    """

    KIND = "discrepancy_model"
    UNITS = {"field": "nT, deg, deg", "sigma_b_nT": "nT", "sigma_g": "g", "angles": "deg"}

    effects: list
    sizes: list
    params: np.ndarray
    field: np.ndarray
    sigma_b_nT: float
    sigma_g: float
    n_iter: int = 10

    @classmethod
    def from_result(cls, res, G, B) -> "PhysicsModel":
        """The model of a workflow result, with the training stations' hash and domain."""
        from icgo.models import data_hash

        p = model_params(res)
        names = list(res.model)
        flat = np.concatenate([np.asarray(p[n], float) for n in names]) if names else np.zeros(0)
        return cls(config=config_to_mapping(res.config), data_hash=data_hash(G, B), domain=sensor_domain(G, B), effects=names,
                   sizes=[int(np.size(p[n])) for n in names], params=flat,
                   field=np.asarray(res.field, float), sigma_b_nT=float(res.config.sigma_b_nT),
                   sigma_g=float(res.config.sigma_g))

    def effect_params(self) -> dict:
        """effect name -> (n_params,) physical parameters."""
        out, i = {}, 0
        for n, k in zip(self.effects, self.sizes):
            out[n] = self.params[i:i + k]
            i += k
        return out

    def apply(self, frame: pd.DataFrame) -> pd.DataFrame:
        """Per row: raw attitude and the attitude the fitted physics model explains best (deg).

        ``azimuth_compensated`` is in the frame of the fitted declination (true
        north when the field was given with its declination), as is
        ``azimuth_raw`` (the standard formula on the raw sensors, + declination).
        """
        v = frame_values(frame, SENSORS, f"{self.KIND} model")
        G, B = v[:, :3], v[:, 3:]
        a, inc = correct_with(self.effect_params(), tuple(float(x) for x in self.field), G, B,
                              Noise(self.sigma_b_nT, self.sigma_g), int(self.n_iter))
        out = {}
        if "station" in frame.columns:
            out["station"] = frame["station"].to_numpy()
        out.update({"inclination_raw": np.asarray(inclination_from_g(G)), "toolface_raw": np.asarray(toolface_from_g(G)),
                    "azimuth_raw": np.mod(np.asarray(azimuth_from_gv(G, B)) + float(self.field[2]), 360.0),
                    "inclination_compensated": np.asarray(inc), "azimuth_compensated": np.asarray(a)})
        return pd.DataFrame(out)
