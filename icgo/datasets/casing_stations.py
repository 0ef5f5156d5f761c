"""The ICGO paper's experiments: static stations near a magnetized casing.

Each function takes a seed (noise only: the systematic errors are arguments with documented defaults, so they
repeat between runs as a real instrument's do) and returns a :class:`icgo.datasets.dataset.Dataset`.

* :func:`lab_casing`: ICGO paper, section 3.1 (magnetized casing 1 m from a
  horizontal inclinometer, 8 azimuths x a full toolface turn, 8-sample means,
  3-sigma filter, :func:`three_sigma_keep`).
* :func:`well_conditions`: ICGO paper, section 4 / Table 4 (six inclination /
  azimuth pairs, casing buried below the sensor).
* :func:`noise_floor`: the azimuth error the simulated sensor noise alone implies for either.

Magnitudes and their physical justification: docs/datasets.md.
"""

from __future__ import annotations

from functools import partial
from typing import Any, Mapping

import jax
import jax.numpy as jnp
import numpy as np
import pandas as pd

from icgo.datasets import instruments as ins
from icgo.datasets.dataset import Dataset, as_float64, contract_frame, jsonable, spawn_rngs
from icgo.physics import frames as F


def _effects_dict(effects: Mapping[str, Any] | None) -> dict:
    from icgo.physics.effects import EFFECTS, check_names

    effects = {} if effects is None else dict(effects)
    check_names(effects)
    out = {}
    for k, v in effects.items():
        a = np.asarray(v, dtype=np.float64)
        if a.shape != (EFFECTS[k].n_params,):
            raise ValueError(f"effect {k!r}: expected {EFFECTS[k].n_params} parameters, got shape {a.shape}")
        out[k] = a
    return out


def three_sigma_keep(values, n_sigma=3.0) -> np.ndarray:
    """Pauta (3-sigma) criterion: keep rows within ``n_sigma`` standard deviations of the mean.

    Args:
        values: (N,) or (N, K) quantities; a row is dropped if any column is out.
        n_sigma: threshold in standard deviations.
    Returns:
        (N,) bool mask of rows kept (one pass, as the criterion is usually applied).
    """
    v = np.asarray(values, dtype=np.float64)
    v = v[:, None] if v.ndim == 1 else v
    mu, sd = v.mean(0), v.std(0, ddof=1)
    return np.all(np.abs(v - mu) <= n_sigma * np.where(sd > 0, sd, np.inf), axis=1)


# =========================================================== lab_casing (ICGO 3.1)
#: Realistic tool-fixed errors of a fluxgate/quartz inclinometer after factory
#: calibration, in a housing with some residual magnetism (docs/datasets.md).
LAB_EFFECTS = {
    "hard_iron": (900.0, -700.0, 1500.0),         # nT, housing/electronics remanence
    "mag_cross_coupling": (0.006, -0.004, 0.003),  # soft iron + non-orthogonality
    "mag_scale": (0.004, -0.003, 0.002),           # residual scale-factor error
    "mag_misalignment": (0.30, -0.20, 0.25),       # deg, magnetometer vs accelerometer triad
    "accel_bias": (4e-4, -3e-4, 2e-4),             # g
    "accel_scale": (1.5e-3, -1.0e-3, 5e-4),        # 1
}

#: Paper's section 3.1 azimuths (deg).
LAB_AZIMUTHS = (30.0, 60.0, 120.0, 150.0, 210.0, 240.0, 300.0, 330.0)

#: Default lab casing (ICGO section 3.1: 3 m x 150 mm, 1 m from the instrument):
#: lying horizontally along magnetic north, its axis 1 m east of the
#: turntable's vertical axis at sensor height, centred abreast of it.
LAB_CASING = ins.Casing(end_ned=(-1.5, 1.0, 0.0), axis_ned=(1.0, 0.0, 0.0), magnetization_A_m=8000.0)


def _toolfaces(step_deg, end_inclusive):
    """Toolfaces 0, step, ... through one turn (deg); 360 included when ``end_inclusive``."""
    tf = np.arange(0.0, 360.0 + 1e-9, step_deg)
    return tf if end_inclusive else tf[tf < 360.0 - 1e-9]


def _sample_sensors(seed, G, B, n_samples, accel_noise_g, mag_noise_nT, spike_prob, spike_nT):
    r_g, r_b = spawn_rngs(seed, 2)
    g_mean, _ = ins.averaged_samples(r_g, G, accel_noise_g, n_samples)
    b_mean, spiked = ins.averaged_samples(r_b, B, mag_noise_nT, n_samples, spike_prob, spike_nT)
    return g_mean, b_mean, spiked


def lab_casing(
    seed: int = 0,
    *,
    azimuths_deg=LAB_AZIMUTHS,
    inclination_deg: float = 90.0,
    toolface_step_deg: float = 5.0,
    toolface_end_inclusive: bool = True,
    n_samples: int = 8,
    total_field_nT: float = 54_940.0,
    dip_deg: float = 59.40,
    gravity_g: float = 1.0,
    casing: ins.Casing | None = LAB_CASING,
    sensor_offset_m: float = 0.015,
    sensor_lever_m: float = 0.15,
    effects: Mapping[str, Any] | None = LAB_EFFECTS,
    accel_noise_g: float = 5e-4,
    mag_noise_nT: float = 30.0,
    spike_prob: float = 1.5e-4,
    spike_nT: float = 100_000.0,
    outlier_sigma: float | None = 3.0,
    noise_scale: float = 1.0,
    casing_distance_m: float | None = None,
    casing_magnetization_A_m: float | None = None,
    instrument: str = "fixed",
) -> Dataset:
    """ICGO paper section 3.1: horizontal inclinometer turned about its axis near a magnetized casing.

    Plan: inclination 90 deg; 8 azimuths; toolface from 0 deg in 5 deg steps
    through a full turn. The paper reports 584 raw rows = 8 x 73, i.e. the turn
    is recorded at both ends (0 and 360 deg, ``toolface_end_inclusive``);
    ``False`` gives 0..355 (576 rows). Each row is the mean of 8 raw samples;
    rare spikes in the raw magnetometer samples make the outliers that the
    3-sigma rule (on |B| and |G|) removes (the paper kept 582 of 584).

    Geometry (lab NED, origin on the azimuth turntable's vertical axis at sensor
    height): the tool's roll axis passes through the origin; the magnetometer
    sits ``sensor_lever_m`` along the tool axis from the vertical axis and
    ``sensor_offset_m`` off the roll axis (tool x). The casing is fixed in the
    lab, so its field at the sensor changes with azimuth (lever) and with
    toolface (offset, through the casing's gradient).

    Args:
        seed: PRNG seed (noise and spikes only).
        azimuths_deg: magnetic azimuths of the 8 stations (deg).
        inclination_deg: tool inclination (deg); the paper: 90.
        toolface_step_deg: toolface step (deg).
        toolface_end_inclusive: include 360 deg as the last toolface (584 rows).
        n_samples: raw samples averaged per row.
        total_field_nT, dip_deg: the lab's geomagnetic field (default: WMM2025
            at Beijing, 2025.0; the paper does not give its site). Azimuths are
            magnetic (declination 0).
        gravity_g: local gravity (g).
        casing: the lab casing, or ``None`` to remove it.
        sensor_offset_m: magnetometer distance from the roll axis (m).
        sensor_lever_m: magnetometer distance along the tool from the turntable's vertical axis (m).
        effects: vocabulary effects of the instrument (name -> params); ``None`` for ideal sensors.
        accel_noise_g, mag_noise_nT: white noise per raw sample.
        spike_prob, spike_nT: spike rate per raw magnetometer sample-axis and spike size.
        outlier_sigma: 3-sigma threshold; ``None`` keeps all rows (raw data).
        noise_scale: factor on both ``accel_noise_g`` and ``mag_noise_nT`` (the noise sweep, ``experiment=sweep_noise``).
        casing_distance_m: the casing moved sideways so its axis passes this far from the
            turntable's vertical axis (m, :func:`icgo.datasets.instruments.casing_at_distance`); ``None``
            keeps ``casing`` as given (the lab's 1 m).
        casing_magnetization_A_m: the casing's axial magnetization (A/m); ``None`` keeps
            ``casing``'s (8000 A/m by default). Both casing options are ignored without a casing.
        instrument: ``"fixed"`` (the instrument above, whatever the seed) or ``"family"``: the seed also draws the
            instrument (the casing's distance and magnetization, a factor on each of ``effects``' parameters and
            one on the noise) from :data:`icgo.datasets.instrument_family.LAB_RANGES`, from a stream of its own
            (:func:`icgo.datasets.instrument_family.draw`); ``meta["instrument"]`` and ``truth["instrument"]``
            hold the draw. ``casing_distance_m`` and ``casing_magnetization_A_m`` must then be left unset.
    Returns:
        Dataset; its meta declares the rig (``"rig": "turntable"``: every station turned about the
        turntable's pivot) and the sensor's lever arm from the pivot (``"sensor_lever_m"``, m, tool frame);
        ``truth`` has the effects, casing, geometry, noise, the rows
        that had spikes and the rows the filter dropped, and the casing field
        at each kept row (NED, nT).
    """
    az = as_float64(azimuths_deg).ravel()
    if az.size == 0:
        raise ValueError("lab_casing: azimuths_deg is empty")
    if not 0.0 < toolface_step_deg <= 360.0:
        raise ValueError(f"lab_casing: toolface_step_deg {toolface_step_deg} must be in (0, 360]")
    if not 0.0 <= inclination_deg <= 180.0:
        raise ValueError(f"lab_casing: inclination_deg {inclination_deg} must be in [0, 180]")
    if not noise_scale >= 0.0:
        raise ValueError(f"lab_casing: noise_scale {noise_scale} must be >= 0")
    drawn = None
    if instrument == "family":
        from icgo.datasets import instrument_family

        if casing is None or casing_distance_m is not None or casing_magnetization_A_m is not None:
            raise ValueError("lab_casing: instrument='family' draws the casing; leave casing_distance_m and "
                             "casing_magnetization_A_m unset and keep a casing")
        drawn = instrument_family.draw(seed, _effects_dict(effects))
        casing_distance_m, casing_magnetization_A_m = drawn.casing_distance_m, drawn.casing_magnetization_A_m
        effects, noise_scale = drawn.effects, noise_scale * drawn.noise_factor
    elif instrument != "fixed":
        raise ValueError(f"lab_casing: instrument must be 'fixed' or 'family', got {instrument!r}")
    if casing is not None and casing_distance_m is not None:
        casing = ins.casing_at_distance(casing, float(casing_distance_m))
    if casing is not None and casing_magnetization_A_m is not None:
        casing = casing._replace(magnetization_A_m=float(casing_magnetization_A_m))
    eff = _effects_dict(effects)
    tf = _toolfaces(toolface_step_deg, toolface_end_inclusive)
    A = np.repeat(az, tf.size)
    T = np.tile(tf, az.size)
    I = np.full(A.shape, float(inclination_deg))
    return _station_survey(
        "lab_casing", seed, A, I, T, total_field_nT, dip_deg, gravity_g, casing,
        pivot_ned=(0.0, 0.0, 0.0), lever_tool=(sensor_offset_m, 0.0, sensor_lever_m),
        effects=eff, n_samples=n_samples, accel_noise_g=noise_scale * accel_noise_g,
        mag_noise_nT=noise_scale * mag_noise_nT, spike_prob=spike_prob, spike_nT=spike_nT, outlier_sigma=outlier_sigma,
        extra_truth={"toolface_end_inclusive": toolface_end_inclusive,
                     **({"instrument": drawn.as_dict()} if drawn else {})},
        extra_meta={"rig": "turntable", "sensor_lever_m": [float(sensor_offset_m), 0.0, float(sensor_lever_m)],
                    **({"instrument": drawn.as_dict()} if drawn else {})},
    )


def _wrap360(angle_deg) -> np.ndarray:
    """:func:`icgo.physics.frames.wrap360` in numpy (host-side, no compiled program)."""
    w = np.mod(np.asarray(angle_deg, float), 360.0)
    return np.where(w >= 360.0, 0.0, w)


def _hashable(casing):
    """A casing whose array fields are tuples (a static argument of :func:`_station_fields`), or None."""
    if casing is None:
        return None
    return casing._replace(**{k: tuple(np.ravel(v).tolist()) for k, v in casing._asdict().items()
                              if isinstance(v, (np.ndarray, list, tuple))})


@partial(jax.jit, static_argnames=("casing",))
def _station_fields(A, I, T, total_field_nT, dip_deg, gravity_g, casing, pivot_ned, lever_tool, effects):
    """The noise-free measured (G, B) at every station and the casing field (NED, nT): one compiled program
    (the persistent compilation cache then loads it in one read, not one per array operation)."""
    C = F.tool_to_earth(A, I, T)
    pos = ins.sensor_positions_ned(pivot_ned, lever_tool, A, I, T)
    b_cas = ins.casing_field_ned(pos, casing) if casing is not None else jnp.zeros_like(pos)
    B = jnp.einsum("nji,nj->ni", C, F.field_vector_ned(total_field_nT, dip_deg, 0.0) + b_cas)
    G = jnp.einsum("nji,j->ni", C, F.gravity_vector_ned(gravity_g))
    return (*ins.measure_g_b(G, B, C, effects), b_cas)


def _station_survey(name, seed, A, I, T, total_field_nT, dip_deg, gravity_g, casing, pivot_ned, lever_tool,
                    effects, n_samples, accel_noise_g, mag_noise_nT, spike_prob, spike_nT, outlier_sigma,
                    extra_truth=None, extra_cols=None, extra_meta=None) -> Dataset:
    """Static stations near a casing: ideal sensors + casing + effects + averaged noise + 3-sigma filter."""
    Gm, Bm, b_cas = _station_fields(np.asarray(A, float), np.asarray(I, float), np.asarray(T, float),
                                    float(total_field_nT), float(dip_deg), float(gravity_g), _hashable(casing),
                                    np.asarray(pivot_ned, float), np.asarray(lever_tool, float),
                                    {k: np.asarray(v, float) for k, v in effects.items()})
    g_mean, b_mean, spiked = _sample_sensors(seed, Gm, Bm, n_samples, accel_noise_g, mag_noise_nT, spike_prob, spike_nT)
    g_mean, b_mean, spiked = as_float64(g_mean), as_float64(b_mean), np.asarray(spiked)
    n = g_mean.shape[0]
    if outlier_sigma is None:
        keep = np.ones(n, bool)
    else:
        keep = three_sigma_keep(
            np.stack([np.linalg.norm(b_mean, axis=1), np.linalg.norm(g_mean, axis=1)], 1), outlier_sigma
        )
    station = np.arange(n)
    extra = {k: np.asarray(v)[keep] for k, v in (extra_cols or {}).items()}
    frame = contract_frame(station[keep], g_mean[keep], b_mean[keep], as_float64(A)[keep], as_float64(I)[keep],
                            _wrap360(T)[keep], extra)
    meta = {
        "name": name, "seed": int(seed), "total_field_nT": float(total_field_nT), "dip_deg": float(dip_deg),
        "declination_deg": 0.0, "gravity_g": float(gravity_g), "azimuth_reference": "magnetic",
        "n_raw_rows": int(n), "n_rows": int(keep.sum()), "samples_per_row": int(n_samples),
        **(extra_meta or {}),
    }
    truth = {
        "effects": {k: v.tolist() for k, v in effects.items()},
        "casing": None if casing is None else jsonable(casing._asdict()),
        "casing_pole_strength_A_m": None if casing is None else float(ins.casing_pole_strength(casing)),
        "pivot_ned_m": list(pivot_ned), "sensor_lever_tool_m": list(lever_tool),
        "accel_noise_g": accel_noise_g, "mag_noise_nT": mag_noise_nT, "n_samples": n_samples,
        "spike_prob": spike_prob, "spike_nT": spike_nT, "outlier_sigma": outlier_sigma,
        "spiked_stations": station[spiked].tolist(), "dropped_stations": station[~keep].tolist(),
        "casing_field_ned_nT": as_float64(b_cas)[keep],
        **(extra_truth or {}),
    }
    return Dataset(frame, meta, truth)


# ===================================================== well_conditions (ICGO 4)
#: The six (inclination, azimuth) pairs of the ICGO paper's Table 4 (deg).
TABLE4_CONDITIONS = ((0.594, 30.0), (1.8, 60.0), (60.0, 135.0), (90.0, 150.0), (135.0, 210.0), (150.0, 270.0))

#: The paper's Table 4 "original" (raw) azimuth error mean and std per condition (deg).
TABLE4_ORIGINAL = ((31.2905, 0.8895), (29.6639, 0.9838), (6.2256, 0.1378), (5.7334, 0.6672),
                   (9.2645, 0.4551), (7.1916, 0.3263))

#: Tool-fixed errors of the instrument in the section-4 runs: smaller than
#: LAB_EFFECTS so that the toolface spread is of the order of Table 4's std
#: column; a uniform lab field (steel in the building) shifts every azimuth by
#: a few degrees, as Table 4's same-signed 6-9 deg at high inclination suggests.
WELL_EFFECTS = {
    "external_field": (0.0, -2500.0, 0.0),         # nT NED, uniform lab field
    "hard_iron": (300.0, -250.0, 500.0),
    "mag_cross_coupling": (0.004, -0.003, 0.002),
    "mag_scale": (0.003, -0.002, 0.002),
    "mag_misalignment": (0.20, -0.15, 0.20),
    "accel_bias": (6e-5, -5e-5, 5e-5),
    "accel_scale": (1.0e-3, -8e-4, 5e-4),
}

#: Casing buried upright below the tilt fixture: top end 1 m below the pivot and
#: 0.3 m to the west, 3 m x 150 mm, magnetized along its axis.
WELL_CASING = ins.Casing(end_ned=(0.0, -0.3, 1.0), axis_ned=(0.0, 0.0, 1.0), magnetization_A_m=15000.0)


def well_conditions(
    seed: int = 0,
    *,
    conditions=TABLE4_CONDITIONS,
    toolface_step_deg: float = 5.0,
    toolface_end_inclusive: bool = False,
    n_samples: int = 8,
    total_field_nT: float = 54_940.0,
    dip_deg: float = 59.40,
    gravity_g: float = 1.0,
    casing: ins.Casing | None = WELL_CASING,
    sensor_lever_m: float = 0.6,
    sensor_offset_m: float = 0.015,
    effects: Mapping[str, Any] | None = WELL_EFFECTS,
    accel_noise_g: float = 5e-4,
    mag_noise_nT: float = 30.0,
    spike_prob: float = 0.0,
    spike_nT: float = 100_000.0,
    outlier_sigma: float | None = None,
) -> Dataset:
    """ICGO paper section 4 / Table 4: six attitudes, toolface swept, casing buried below the sensor.

    The tool sits on a tilt fixture that turns about a pivot; the magnetometer
    is ``sensor_lever_m`` down the tool axis from the pivot. Near vertical it
    hangs closest to the casing's top pole, which is offset horizontally, so a
    strong horizontal casing field rotates the apparent magnetic north there:
    the raw error is largest at the two near-vertical conditions (as in Table
    4). At high inclinations the sensor swings away from the casing and the
    error falls to the uniform lab field's shift plus the tool's own errors.
    Near vertical, tool-fixed cross-axial errors also weigh more (accelerometer
    bias over ``sin I``), which widens the toolface spread there.

    Args:
        seed: PRNG seed (noise only).
        conditions: (inclination, azimuth) pairs (deg).
        toolface_step_deg, toolface_end_inclusive: toolface sweep (default 0..355 by 5).
        n_samples: raw samples averaged per row.
        total_field_nT, dip_deg, gravity_g: site (default as :func:`lab_casing`).
        casing: buried casing (``None`` removes it).
        sensor_lever_m, sensor_offset_m: sensor position in the tool relative to the pivot.
        effects: instrument effects; see :data:`WELL_EFFECTS`.
        accel_noise_g, mag_noise_nT, spike_prob, spike_nT, outlier_sigma: as :func:`lab_casing`
            (no spikes and no filter by default: the paper does not mention one here).
    Returns:
        Dataset with an extra ``condition`` column (index into ``conditions``).
    """
    cond = as_float64(conditions).reshape(-1, 2)
    if cond.size == 0:
        raise ValueError("well_conditions: conditions is empty")
    if np.any((cond[:, 0] < 0) | (cond[:, 0] > 180)):
        raise ValueError(f"well_conditions: inclinations {cond[:, 0].tolist()} must be in [0, 180]")
    tf = _toolfaces(toolface_step_deg, toolface_end_inclusive)
    I = np.repeat(cond[:, 0], tf.size)
    A = np.repeat(cond[:, 1], tf.size)
    T = np.tile(tf, len(cond))
    k = np.repeat(np.arange(len(cond)), tf.size)
    return _station_survey(
        "well_conditions", seed, A, I, T, total_field_nT, dip_deg, gravity_g, casing,
        pivot_ned=(0.0, 0.0, 0.0), lever_tool=(sensor_offset_m, 0.0, sensor_lever_m),
        effects=_effects_dict(effects), n_samples=n_samples, accel_noise_g=accel_noise_g,
        mag_noise_nT=mag_noise_nT, spike_prob=spike_prob, spike_nT=spike_nT, outlier_sigma=outlier_sigma,
        extra_truth={"conditions": cond.tolist(), "paper_table4_original": [list(r) for r in TABLE4_ORIGINAL]},
        extra_cols={"condition": k},
    )


def noise_floor(name: str, seed: int = 0, **kwargs) -> pd.DataFrame:
    """The azimuth error the simulator's sensor noise alone implies for a data set (deg).

    The same protocol and seed with the casing, every systematic sensor effect and
    the spikes removed, so that only the simulated accelerometer and magnetometer
    noise remains; the standard azimuth formula on those readings against the true
    azimuth is the best any compensation could do on average. Rows of the
    noise-only draw line up with the study's (same plan and noise draws).

    Args:
        name: ``lab_casing`` or ``well_conditions``.
        seed: the data set's seed. kwargs: other arguments of the protocol (not the
            casing/effects/spikes, which are switched off).
    Returns:
        DataFrame with ``condition`` (-1 when the data set has none), ``n``,
        ``mae`` and ``rmse`` of the noise-only azimuth error (deg).
    """
    from icgo.physics.frames import angle_diff, azimuth_from_gv

    if name not in ("lab_casing", "well_conditions"):
        raise ValueError(f"noise_floor: {name!r} has no azimuth compensation study; use lab_casing or well_conditions")
    fn = lab_casing if name == "lab_casing" else well_conditions
    f = fn(seed, **{**kwargs, "casing": None, "effects": None, "spike_prob": 0.0}).frame
    a = np.asarray(azimuth_from_gv(f[["gx", "gy", "gz"]].to_numpy(float), f[["bx", "by", "bz"]].to_numpy(float)))
    err = np.asarray(angle_diff(a, f["azimuth_deg"].to_numpy(float)))
    cond = f["condition"].to_numpy() if "condition" in f.columns else np.full(len(f), -1)
    rows = [{"condition": int(c), "n": int((cond == c).sum()), "mae": float(np.abs(err[cond == c]).mean()),
             "rmse": float(np.sqrt(np.mean(err[cond == c] ** 2)))} for c in np.unique(cond)]
    return pd.DataFrame(rows)
