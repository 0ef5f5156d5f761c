"""The discrepancy workflow's fitted physics model as an artifact (:class:`PhysicsModel`).

The final model of :func:`icgo.discrepancy.run_workflow` (the named effects with
their fitted parameters, the fitted reference field, the noise weights) saved
with :mod:`icgo.models.format`. ``apply`` inverts it per station: the attitude that
best explains each measured (G, B) (:func:`icgo.discrepancy.fit.correct_with`).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pandas as pd

from icgo.core.settings import config_to_mapping
from icgo.discrepancy.fit import correct_with, model_params
from icgo.discrepancy.noise import Noise
from icgo.models.format import CORRECTED_B, FittedModel, frame_values, need, need_shape, sensor_domain
from icgo.physics.frames import azimuth_from_gv, inclination_from_g, toolface_from_g
from icgo.physics.qc import QCBands, survey_qc

SENSORS = ("gx", "gy", "gz", "bx", "by", "bz")


@dataclasses.dataclass(frozen=True, eq=False)
class PhysicsModel(FittedModel):
    """Named effects + earth field fitted by the discrepancy workflow.

    Attributes:
        effects: the effect names of the final model, in order (``icgo.physics.effects`` vocabulary).
        sizes: number of parameters of each effect.
        params: (sum(sizes),) their physical parameters, concatenated (units per effect:
            ``icgo.physics.effects``; nT, g, dimensionless, deg).
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

    MAY_BE_EMPTY = ("params",)  # a workflow that found no effect

    #: Largest number of LM steps of the per-station inversion a loaded model may ask for.
    MAX_ITER = 1000

    def validate(self) -> None:
        """Known effects with their parameter counts, field (3,) with |F| > 0, noise > 0, a bounded n_iter."""
        from icgo.physics import effects as E

        need(all(isinstance(n, str) and n in E.EFFECTS for n in self.effects),
             f"effects must be names of icgo.physics.effects ({', '.join(E.EFFECTS)}), got {str(self.effects)[:80]}")
        need(len(set(self.effects)) == len(self.effects), "effects must not repeat")
        need(self.sizes == [E.EFFECTS[n].n_params for n in self.effects],
             f"sizes {str(self.sizes)[:60]} do not match the effects' parameter counts")
        need_shape(self.params, (sum(self.sizes),), "params")
        need_shape(self.field, (3,), "field")
        need(self.field[0] > 0 and abs(self.field[1]) <= 90, "field must be (total nT > 0, dip deg in [-90, 90], "
                                                               "declination deg)")
        need(self.sigma_b_nT > 0 and self.sigma_g > 0, "sigma_b_nT and sigma_g must be > 0")
        need(1 <= self.n_iter <= self.MAX_ITER, f"n_iter must be 1 to {self.MAX_ITER}, got {self.n_iter}")

    @classmethod
    def from_result(cls, res, G, B) -> "PhysicsModel":
        """The model of a workflow result, with the training stations' hash and domain."""
        from icgo.models.format import data_hash

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
        ``bx_corrected .. bz_corrected`` (nT): the measured field with the fitted disturbance
        removed (:class:`icgo.discrepancy.fit.Inversion`), what survey QC checks after the model.
        """
        v = frame_values(frame, SENSORS, f"{self.KIND} model")
        G, B = v[:, :3], v[:, 3:]
        inv = correct_with(self.effect_params(), tuple(float(x) for x in self.field), G, B,
                           Noise(self.sigma_b_nT, self.sigma_g), int(self.n_iter))
        out = {}
        if "station" in frame.columns:
            out["station"] = frame["station"].to_numpy()
        out.update({"inclination_raw": np.asarray(inclination_from_g(G)), "toolface_raw": np.asarray(toolface_from_g(G)),
                    "azimuth_raw": np.mod(np.asarray(azimuth_from_gv(G, B)) + float(self.field[2]), 360.0),
                    "inclination_compensated": inv.inclination, "azimuth_compensated": inv.azimuth})
        out.update(dict(zip(CORRECTED_B, inv.b_corrected.T)))
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
    frame = pd.DataFrame(np.hstack([st.G, st.B]), columns=list(SENSORS))
    after = model.apply(frame)[list(CORRECTED_B)].to_numpy(float)
    return {"raw": survey_qc(st.G, st.B, F, dip, st.gravity_g, bands).counts,
            "physics": survey_qc(st.G, after, F, dip, st.gravity_g, bands).counts}


#: The physics baseline of the generalisation protocols: the 12-parameter magnetometer
#: model (bias, scale, cross-coupling, misalignment) with an earth-fixed external field.
TWELVE_PLUS_FIELD = ("hard_iron", "mag_scale", "mag_cross_coupling", "mag_misalignment", "external_field")


def fit_members(st, weights, effects=TWELVE_PLUS_FIELD, noise=None, n_iter: int = 30) -> list:
    """Fit one fixed physics model per row-weight vector (no search): the discrepancy
    engine's Levenberg-Marquardt (:func:`icgo.discrepancy.fit.lm_fit`) over ``effects``,
    vmapped over the members (one compile for every member).

    Args:
        st: :class:`icgo.discrepancy.stations.Stations` with a reference attitude.
        weights: (M, n) 0/1 station weights, one row per member (its training rows).
        effects: effect names (``icgo.physics.effects`` vocabulary) that are fitted.
        noise: residual weights (:class:`icgo.discrepancy.noise.Noise`); default the
            workflow's noise constants.
        n_iter: LM steps (fixed; 30 reach the converged cost on the bundled data to 1e-9 relative).
    Returns:
        M :class:`PhysicsModel`, each with the effects' parameters and the field (the
        metadata's field when the stations carry one, else the fitted one).
    """
    import jax
    import jax.numpy as jnp

    from icgo.discrepancy.config import WorkflowConfig
    from icgo.discrepancy.fit import lm_fit
    from icgo.discrepancy.model import fitted_field, prepare
    from icgo.models.format import data_hash

    if not st.has_reference:
        raise ValueError("physics baseline: the stations need a reference attitude (azimuth_deg, inclination_deg)")
    cfg = WorkflowConfig()
    noise = cfg.noise if noise is None else noise
    prep = prepare(st, noise)
    layout = prep.layout
    free = prep.free_nuisance.astype(float)
    for e in effects:
        free[layout.slice(e)] = 1.0
    w = np.asarray(weights, float) * prep.valid[None]
    fit = jax.jit(jax.vmap(lambda wm: lm_fit(jnp.zeros(layout.n_params), jnp.asarray(free), wm, prep.data, layout,
                                             n_iter)[0]))
    thetas = np.asarray(fit(jnp.asarray(w)))
    scales = layout.scales()
    out = []
    for th, wm in zip(thetas, w):
        rows = wm > 0
        phys = th * scales
        out.append(PhysicsModel(
            config={"effects": list(effects), "n_iter": int(n_iter), "baseline": "twelve_plus_field"},
            data_hash=data_hash(st.G[rows], st.B[rows]), domain=sensor_domain(st.G[rows], st.B[rows]),
            effects=list(effects), sizes=[int(layout.sizes[layout.names.index(e)]) for e in effects],
            params=np.concatenate([phys[layout.slice(e)] for e in effects]),
            field=np.asarray(fitted_field(th, layout, prep.data), float),
            sigma_b_nT=float(noise.sigma_b_nT), sigma_g=float(noise.sigma_g)))
    return out
