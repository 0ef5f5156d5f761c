"""Experiment protocols that simulate the papers' measurements.

Each function takes a seed (noise only: the systematic errors are arguments
with documented defaults, so they repeat between runs as a real instrument's
do) and returns a :class:`Dataset`: a DataFrame in the data contract
(DESIGN.md), its metadata and the ground truth that was injected.

* :func:`lab_casing`: ICGO paper, section 3.1 (magnetized casing 1 m from a
  horizontal inclinometer, 8 azimuths x a full toolface turn, 8-sample means,
  3-sigma filter).
* :func:`well_conditions`: ICGO paper, section 4 / Table 4 (six inclination /
  azimuth pairs, casing buried below the sensor).
* :func:`turntable`, :func:`turntable_random`, :func:`turntable_between`:
  patent CN1888384's 3-axis turntable plan for a 2-axis gyro + 2-accelerometer
  inclinometer, a dense random test set and a set between the grid points.
* :func:`rotating_drill`: MISMA paper's field run (1 Hz, 4200 s, rotating
  string with a stop every 300 s, 12-parameter magnetometer error, gyro).

Command line: ``python -m icgo.datasets NAME --out DIR [--seed S]`` writes
``DIR/NAME.csv`` and ``DIR/NAME.meta.json`` through :mod:`icgo.io.recording`.

Magnitudes and their physical justification: docs/datasets.md.
"""

from __future__ import annotations

from functools import partial
from typing import Any, Mapping, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import pandas as pd

from icgo.datasets import instruments as ins
from icgo.physics import frames as F
from icgo.physics import strapdown


class Dataset(NamedTuple):
    """A simulated recording.

    Attributes:
        frame: DataFrame with the data-contract columns (station, gx, gy, gz,
            bx, by, bz, azimuth_deg, inclination_deg, toolface_deg, ...).
        meta: data-contract metadata (total_field_nT, dip_deg,
            declination_deg, gravity_g, ...) plus ``name`` and ``seed``.
        truth: every injected parameter (effects, geometry, noise, dropped rows).
    """

    frame: pd.DataFrame
    meta: dict
    truth: dict


def _np(x) -> np.ndarray:
    return np.asarray(x, dtype=np.float64)


def _jsonable(x: Any):
    """Convert arrays / tuples / NamedTuples in a truth dict to plain JSON types."""
    if isinstance(x, Mapping):
        return {str(k): _jsonable(v) for k, v in x.items()}
    if hasattr(x, "_asdict"):
        return {k: _jsonable(v) for k, v in x._asdict().items()}
    if isinstance(x, (list, tuple)):
        return [_jsonable(v) for v in x]
    if isinstance(x, (np.ndarray, jnp.ndarray)):
        return _jsonable(np.asarray(x).tolist())
    if isinstance(x, (np.floating, np.integer, np.bool_)):
        return x.item()
    return x


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


def _contract_frame(station, G, B, A, I, T, extra: Mapping[str, Any] | None = None) -> pd.DataFrame:
    G, B = _np(G), _np(B)
    cols = {
        "station": np.asarray(station, dtype=np.int64),
        "gx": G[:, 0], "gy": G[:, 1], "gz": G[:, 2],
        "bx": B[:, 0], "by": B[:, 1], "bz": B[:, 2],
        "azimuth_deg": _np(A), "inclination_deg": _np(I), "toolface_deg": _np(T),
    }
    for k, v in (extra or {}).items():
        cols[k] = np.asarray(v)
    return pd.DataFrame(cols)


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


def _rngs(seed, n):
    """``n`` independent numpy generators from one seed (SeedSequence.spawn: streams never overlap)."""
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"seed {seed!r}: must be a non-negative integer")
    return [np.random.default_rng(s) for s in np.random.SeedSequence(int(seed)).spawn(n)]


def _sample_sensors(seed, G, B, n_samples, accel_noise_g, mag_noise_nT, spike_prob, spike_nT):
    r_g, r_b = _rngs(seed, 2)
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
    Returns:
        Dataset; ``truth`` has the effects, casing, geometry, noise, the rows
        that had spikes and the rows the filter dropped, and the casing field
        at each kept row (NED, nT).
    """
    az = _np(azimuths_deg).ravel()
    if az.size == 0:
        raise ValueError("lab_casing: azimuths_deg is empty")
    if not 0.0 < toolface_step_deg <= 360.0:
        raise ValueError(f"lab_casing: toolface_step_deg {toolface_step_deg} must be in (0, 360]")
    if not 0.0 <= inclination_deg <= 180.0:
        raise ValueError(f"lab_casing: inclination_deg {inclination_deg} must be in [0, 180]")
    if not noise_scale >= 0.0:
        raise ValueError(f"lab_casing: noise_scale {noise_scale} must be >= 0")
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
        extra_truth={"toolface_end_inclusive": toolface_end_inclusive},
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
                    extra_truth=None, extra_cols=None) -> Dataset:
    """Static stations near a casing: ideal sensors + casing + effects + averaged noise + 3-sigma filter."""
    Gm, Bm, b_cas = _station_fields(np.asarray(A, float), np.asarray(I, float), np.asarray(T, float),
                                    float(total_field_nT), float(dip_deg), float(gravity_g), _hashable(casing),
                                    np.asarray(pivot_ned, float), np.asarray(lever_tool, float),
                                    {k: np.asarray(v, float) for k, v in effects.items()})
    g_mean, b_mean, spiked = _sample_sensors(seed, Gm, Bm, n_samples, accel_noise_g, mag_noise_nT, spike_prob, spike_nT)
    g_mean, b_mean, spiked = _np(g_mean), _np(b_mean), np.asarray(spiked)
    n = g_mean.shape[0]
    if outlier_sigma is None:
        keep = np.ones(n, bool)
    else:
        keep = three_sigma_keep(
            np.stack([np.linalg.norm(b_mean, axis=1), np.linalg.norm(g_mean, axis=1)], 1), outlier_sigma
        )
    station = np.arange(n)
    extra = {k: np.asarray(v)[keep] for k, v in (extra_cols or {}).items()}
    frame = _contract_frame(station[keep], g_mean[keep], b_mean[keep], _np(A)[keep], _np(I)[keep],
                            _wrap360(T)[keep], extra)
    meta = {
        "name": name, "seed": int(seed), "total_field_nT": float(total_field_nT), "dip_deg": float(dip_deg),
        "declination_deg": 0.0, "gravity_g": float(gravity_g), "azimuth_reference": "magnetic",
        "n_raw_rows": int(n), "n_rows": int(keep.sum()), "samples_per_row": int(n_samples),
    }
    truth = {
        "effects": {k: v.tolist() for k, v in effects.items()},
        "casing": None if casing is None else _jsonable(casing._asdict()),
        "casing_pole_strength_A_m": None if casing is None else float(ins.casing_pole_strength(casing)),
        "pivot_ned_m": list(pivot_ned), "sensor_lever_tool_m": list(lever_tool),
        "accel_noise_g": accel_noise_g, "mag_noise_nT": mag_noise_nT, "n_samples": n_samples,
        "spike_prob": spike_prob, "spike_nT": spike_nT, "outlier_sigma": outlier_sigma,
        "spiked_stations": station[spiked].tolist(), "dropped_stations": station[~keep].tolist(),
        "casing_field_ned_nT": _np(b_cas)[keep],
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
    cond = _np(conditions).reshape(-1, 2)
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


# ================================================== turntable (patent CN1888384)
#: The patent's inclination test points (deg), "dense near zero, 10 deg apart above 10".
PATENT_INCLINATIONS = (3.0, 5.0, 10.0, 15.0, 25.0, 35.0, 45.0, 55.0, 65.0, 75.0)

#: Repeatable errors of a dynamically tuned 2-axis gyro (deg/h scale, typical of
#: gyro-compass inclinometers); the z row is unused (no z gyro).
PATENT_GYRO = ins.GyroErrors(
    bias_deg_h=(0.25, -0.18, 0.0),
    g_sensitivity_deg_h_g=((0.12, 0.05, 0.20), (-0.04, 0.10, -0.15), (0.0, 0.0, 0.0)),
    scale=(8e-4, -5e-4, 0.0),
    misalignment_deg=(0.10, -0.08, 0.15),
)


class AccelErrors(NamedTuple):
    """Accelerometer bias (g) and scale-factor error (1), per tool axis (z unused by a 2-accelerometer tool)."""

    bias_g: tuple = (5e-5, -4e-5, 0.0)
    scale: tuple = (3e-4, -2e-4, 0.0)


def _turntable_survey(name, seed, A, I, T, *, latitude_deg, gravity_g, gyro, accel, mount_misalignment_deg,
                      gyro_noise_deg_h, accel_noise_g, total_field_nT, dip_deg, declination_deg, extra_truth=None):
    A, I, T = jnp.asarray(A, jnp.float64), jnp.asarray(I, jnp.float64), jnp.asarray(T, jnp.float64)
    s = F.sensors_from_attitude(A, I, T, total_field_nT, dip_deg, declination_deg, latitude_deg, gravity_g)
    # Installation misalignment of the sensor block relative to the turntable's tool frame.
    from icgo.physics.effects import rotation_from_vector

    rm = rotation_from_vector(jnp.asarray(mount_misalignment_deg, jnp.float64))
    G_s = s.G @ rm.T
    W_s = s.W @ rm.T
    W_m = ins.gyro_measure(W_s, G_s, gyro)
    G_m = G_s * (1.0 + jnp.asarray(accel.scale)) + jnp.asarray(accel.bias_g)
    r_w, r_g = _rngs(seed, 2)
    W_m = _np(W_m) + gyro_noise_deg_h * r_w.standard_normal(W_m.shape)
    G_m = _np(G_m) + accel_noise_g * r_g.standard_normal(G_m.shape)
    wx, wy, gx, gy = W_m[:, 0], W_m[:, 1], G_m[:, 0], G_m[:, 1]
    a_raw, i_raw, t_raw = ins.patent_attitude_in_our_frame(wx, wy, gx, gy, latitude_deg, gravity_g)
    # Two accelerometers: gz is what eq. (6)'s |g| assumption implies; no z gyro: wz is the ideal earth rate.
    gz = jnp.sqrt(jnp.clip(gravity_g**2 - gx**2 - gy**2, 0.0, None))
    G_out = jnp.stack([gx, gy, gz], -1)
    n = A.shape[0]
    frame = _contract_frame(
        np.arange(n), G_out, s.B, A, I, F.wrap360(T),
        {"wx": _np(wx), "wy": _np(wy), "wz": _np(s.W[:, 2]),
         "azimuth_raw_deg": _np(a_raw), "inclination_raw_deg": _np(i_raw), "toolface_raw_deg": _np(t_raw)},
    )
    meta = {
        "name": name, "seed": int(seed), "total_field_nT": float(total_field_nT), "dip_deg": float(dip_deg),
        "declination_deg": float(declination_deg), "gravity_g": float(gravity_g), "latitude": float(latitude_deg),
        "azimuth_reference": "true (gyro compass)",
        "description": "2-axis gyro + 2 accelerometers (patent CN1888384); bx..bz are the ideal field "
                       "(no magnetometer), wz is the ideal earth rate (no z gyro), gz is implied by |g|",
    }
    truth = {
        "gyro": _jsonable(gyro), "accel": _jsonable(accel), "mount_misalignment_deg": list(mount_misalignment_deg),
        "gyro_noise_deg_h": gyro_noise_deg_h, "accel_noise_g": accel_noise_g, **(extra_truth or {}),
    }
    return Dataset(frame, meta, truth)


_TT_DEFAULTS = dict(
    latitude_deg=39.98, gravity_g=1.0, gyro=PATENT_GYRO, accel=AccelErrors(), mount_misalignment_deg=(0.05, -0.04, 0.0),
    gyro_noise_deg_h=0.02, accel_noise_g=1e-5, total_field_nT=54_940.0, dip_deg=59.40, declination_deg=-7.49,
)


def turntable(seed: int = 0, *, inclinations_deg=PATENT_INCLINATIONS, azimuth_step_deg: float = 30.0,
              toolface_step_deg: float = 30.0, azimuth_offset_deg: float = 0.0, toolface_offset_deg: float = 0.0,
              **instrument) -> Dataset:
    """Patent CN1888384's 3-axis turntable plan for a 2-axis gyro + 2-accelerometer inclinometer.

    Inclination x azimuth x toolface grid (patent: I in :data:`PATENT_INCLINATIONS`,
    A and T every 30 deg: 10 x 12 x 12 = 1440 points). The instrument solves
    A, I, T with the patent's eqs. (5)-(7) from gyro and accelerometer readings
    carrying repeatable errors (:data:`PATENT_GYRO`, :class:`AccelErrors`, an
    installation misalignment of the sensor block), so the raw azimuth error
    depends on I, A and T and repeats between runs (the seed only draws the
    small noise).

    Args:
        seed: PRNG seed (noise only).
        inclinations_deg: inclination test points (deg), each in (0, 90).
        azimuth_step_deg, toolface_step_deg: grid steps (deg) over [0, 360).
        azimuth_offset_deg, toolface_offset_deg: shift of the grid (deg).
        **instrument: overrides of latitude_deg (39.98, Beijing), gravity_g,
            gyro (GyroErrors), accel (AccelErrors), mount_misalignment_deg,
            gyro_noise_deg_h, accel_noise_g, total_field_nT, dip_deg, declination_deg.
    Returns:
        Dataset; extra columns wx, wy, wz (deg/h), azimuth_raw_deg,
        inclination_raw_deg, toolface_raw_deg (the instrument's own solution).
    """
    inc = _np(inclinations_deg).ravel()
    if inc.size == 0 or np.any((inc <= 0) | (inc >= 90)):
        raise ValueError(f"turntable: inclinations {inc.tolist()} must be non-empty and in (0, 90) deg (patent eqs. 5-7)")
    for nm, st in (("azimuth_step_deg", azimuth_step_deg), ("toolface_step_deg", toolface_step_deg)):
        if not 0.0 < st <= 360.0:
            raise ValueError(f"turntable: {nm} {st} must be in (0, 360]")
    az = np.arange(0.0, 360.0 - 1e-9, azimuth_step_deg) + azimuth_offset_deg
    tf = np.arange(0.0, 360.0 - 1e-9, toolface_step_deg) + toolface_offset_deg
    I, A, T = (x.ravel() for x in np.meshgrid(inc, az, tf, indexing="ij"))
    kw = _turntable_kwargs(instrument)
    return _turntable_survey("turntable", seed, A, I, T, **kw, extra_truth={
        "inclinations_deg": inc.tolist(), "azimuth_step_deg": azimuth_step_deg, "toolface_step_deg": toolface_step_deg})


def _turntable_kwargs(instrument):
    unknown = set(instrument) - set(_TT_DEFAULTS)
    if unknown:
        raise ValueError(f"turntable: unknown argument(s) {sorted(unknown)}; known: {sorted(_TT_DEFAULTS)}")
    return {**_TT_DEFAULTS, **instrument}


def turntable_random(seed: int = 0, *, n: int = 2000, inclination_range_deg=(3.0, 75.0), **instrument) -> Dataset:
    """Dense random test set: ``n`` attitudes uniform in I over the range and in A, T over [0, 360).

    The attitudes and the noise both come from ``seed``; the instrument's
    systematic errors are the same as :func:`turntable`'s (same overrides).
    """
    lo, hi = (float(v) for v in inclination_range_deg)
    if not 0.0 < lo < hi < 90.0:
        raise ValueError(f"turntable_random: inclination_range_deg {inclination_range_deg} must satisfy 0 < lo < hi < 90")
    if n < 1:
        raise ValueError(f"turntable_random: n {n} must be >= 1")
    r_att, r_noise = _rngs(seed, 2)
    u = r_att.random((n, 3))
    I, A, T = lo + (hi - lo) * u[:, 0], 360.0 * u[:, 1], 360.0 * u[:, 2]
    noise_seed = int(r_noise.integers(0, 2**31 - 1))
    return _turntable_survey("turntable_random", noise_seed, A, I, T, **_turntable_kwargs(instrument),
                             extra_truth={"inclination_range_deg": [lo, hi], "seed": int(seed)})


def turntable_between(seed: int = 0, *, inclinations_deg=PATENT_INCLINATIONS, azimuth_step_deg: float = 30.0,
                      toolface_step_deg: float = 30.0, **instrument) -> Dataset:
    """Test points half-way between the grid points of :func:`turntable` in I, A and T.

    Inclinations are the midpoints of consecutive test points (4, 7.5, 12.5,
    20, ..., 70 deg); azimuth and toolface are shifted by half a step.
    """
    inc = np.sort(_np(inclinations_deg).ravel())
    if inc.size < 2:
        raise ValueError("turntable_between: need at least 2 inclinations")
    mid = 0.5 * (inc[1:] + inc[:-1])
    ds = turntable(seed, inclinations_deg=mid, azimuth_step_deg=azimuth_step_deg, toolface_step_deg=toolface_step_deg,
                   azimuth_offset_deg=azimuth_step_deg / 2, toolface_offset_deg=toolface_step_deg / 2, **instrument)
    ds.meta["name"] = "turntable_between"
    return ds


# ====================================================== rotating_drill (MISMA)
#: 12-parameter magnetometer error of a MEMS (AMR) magnetometer strapped to a
#: steel drill rod: B_meas = R B_true + b. Sensitivity errors dominate the
#: off-diagonal ones (MISMA's Tables 2 and 4); b is large in the field.
MISMA_R = ((1.045, 0.018, -0.012), (-0.010, 0.965, 0.022), (0.015, -0.020, 1.030))
MISMA_B_NT = (3500.0, -2200.0, 4800.0)

#: MEMS gyro (CRG20-02 class): bias ~0.05 deg/s, scale 0.5 %, g-sensitivity ~0.01 deg/s/g.
MISMA_GYRO = ins.GyroErrors(
    bias_deg_h=(180.0, -144.0, 216.0),
    g_sensitivity_deg_h_g=((36.0, 0.0, 0.0), (0.0, -30.0, 0.0), (0.0, 0.0, 20.0)),
    scale=(5e-3, -4e-3, 3e-3),
    misalignment_deg=(0.2, -0.3, 0.1),
)


def rotating_drill(
    seed: int = 0,
    *,
    duration_s: float = 4200.0,
    sample_rate_hz: float = 1.0,
    stop_every_s: float = 300.0,
    stop_duration_s: float = 30.0,
    rotation_rpm: float = 30.0,
    rpm_variation: float = 0.15,
    inclination_start_deg: float = 10.0,
    inclination_end_deg: float = 85.0,
    azimuth_start_deg: float = 60.0,
    azimuth_end_deg: float = 135.0,
    total_field_nT: float = 52_650.0,
    dip_deg: float = 53.8,
    latitude_deg: float = 35.2,
    gravity_g: float = 9.7966 / 9.80665,
    R=MISMA_R,
    b_nT=MISMA_B_NT,
    mag_noise_nT: float = 50.0,
    accel_noise_g: float = 2e-3,
    vibration_g: float = 0.05,
    axial_vibration_g: float = 0.02,
    accel_radius_m: float = 0.02,
    gyro: ins.GyroErrors = MISMA_GYRO,
    gyro_noise_deg_h: float = 72.0,
) -> Dataset:
    """MISMA paper's field run: 1 Hz for 4200 s while drilling, the string stopped every 300 s.

    Each 300 s segment rotates for ``stop_every_s - stop_duration_s`` s and
    ends with a ``stop_duration_s`` static survey (``static == 1``, ``survey``
    its index; the reference azimuth at a stop is the true azimuth). The rate
    is ``rotation_rpm`` with a slow random stick-slip variation (relative
    ``rpm_variation``, an Ornstein-Uhlenbeck process with a 20 s time
    constant), so the 1 Hz samples land at scattered toolfaces. The borehole
    direction changes linearly with drilled time from the start to the end
    values. Default: a build-and-turn section (inclination 10 -> 85 deg,
    magnetic azimuth 60 -> 135 deg, landing near horizontal), along which the
    tool-axis field component changes sign and the tool axis' east component
    varies, so all 12 magnetometer parameters are identifiable from the run
    (docs/datasets.md). The near-straight hole (88 -> 86.5, 120 -> 124) is the
    non-identifiable contrast: pass those four angles.

    Sensors: magnetometer ``B_meas = R B_true + b`` + white noise; accelerometer
    gravity + white noise + lateral/axial vibration while rotating + the
    centripetal term ``omega^2 r`` on x for an accelerometer ``r`` off axis
    (G is gravity minus the tool's acceleration in our sign convention, so the
    centripetal acceleration toward the axis reads as ``+omega^2 r`` on x);
    gyro ``W`` (deg/h) = the body's mean rate over each sample interval relative to
    inertial space (string rotation, build and turn, earth rate; exact increments:
    :func:`icgo.physics.strapdown.gyro_rates_from_attitude`), with :class:`GyroErrors`
    and white noise. Site: MISMA's (dip 53.8 deg, 52.65 uT,
    g = 9.7966 m/s^2, Jiaozuo ~35.2 N).

    Returns:
        Dataset with ``time_s``, ``wx, wy, wz``, ``static``, ``survey``
        columns; ``truth['R']``, ``truth['b_nT']`` the 12 parameters.
    """
    n = int(round(duration_s * sample_rate_hz))
    if n < 2:
        raise ValueError(f"rotating_drill: duration_s * sample_rate_hz = {n} samples; need >= 2")
    if not 0.0 <= stop_duration_s < stop_every_s:
        raise ValueError(f"rotating_drill: stop_duration_s {stop_duration_s} must be in [0, stop_every_s)")
    Rm = _np(R)
    bv = _np(b_nT)
    if Rm.shape != (3, 3) or bv.shape != (3,):
        raise ValueError(f"rotating_drill: R must be 3x3 and b_nT length 3, got {Rm.shape} and {bv.shape}")
    dt = 1.0 / sample_rate_hz
    t = np.arange(n) * dt
    phase = np.mod(t, stop_every_s)
    static = phase >= stop_every_s - stop_duration_s
    survey = np.where(static, (t // stop_every_s).astype(np.int64), -1)
    r_ou, r_t0, r_b, r_g, r_vib, r_w = _rngs(seed, 6)
    # Stick-slip: OU process on the relative rate, 20 s time constant, unit variance.
    a = np.exp(-dt / 20.0)
    eps = r_ou.standard_normal(n)
    from scipy.signal import lfilter  # here, not at import: scipy.signal costs 1.4 s, and only this drift needs it

    ou = lfilter([np.sqrt(1.0 - a * a)], [1.0, -a], eps)  # x_k = a x_{k-1} + sqrt(1-a^2) e_k
    rate_deg_s = np.where(static, 0.0, rotation_rpm * 6.0 * (1.0 + rpm_variation * ou))
    T = np.mod(r_t0.uniform(0.0, 360.0) + np.cumsum(rate_deg_s) * dt, 360.0)
    drilled = np.cumsum(~static) * dt / max(np.sum(~static) * dt, 1e-12)
    I = inclination_start_deg + (inclination_end_deg - inclination_start_deg) * drilled
    A = azimuth_start_deg + (azimuth_end_deg - azimuth_start_deg) * drilled
    s = F.sensors_from_attitude(jnp.asarray(A), jnp.asarray(I), jnp.asarray(T), total_field_nT, dip_deg, 0.0,
                                latitude_deg, gravity_g)
    B = _np(s.B) @ Rm.T + bv + mag_noise_nT * r_b.standard_normal((n, 3))
    omega = np.deg2rad(rate_deg_s)
    rot = (~static)[:, None]
    vib = r_vib.standard_normal((n, 3)) * np.array([vibration_g, vibration_g, axial_vibration_g])
    centripetal = np.stack([omega**2 * accel_radius_m / 9.80665, 0 * omega, 0 * omega], -1)
    G = _np(s.G) + rot * (vib + centripetal) + accel_noise_g * r_g.standard_normal((n, 3))
    # the gyro's true sample = the constant body rate (earth rate included) that turns attitude k-1 into k
    W_true = strapdown.gyro_rates_from_attitude(A, I, T, dt, latitude_deg, rate_deg_s)
    W = _np(ins.gyro_measure(W_true, _np(s.G), gyro)) + gyro_noise_deg_h * r_w.standard_normal((n, 3))
    frame = _contract_frame(
        np.arange(n), G, B, A, I, T,
        {"time_s": t, "wx": W[:, 0], "wy": W[:, 1], "wz": W[:, 2], "static": static.astype(np.int64), "survey": survey},
    )
    meta = {
        "name": "rotating_drill", "seed": int(seed), "total_field_nT": float(total_field_nT), "dip_deg": float(dip_deg),
        "declination_deg": 0.0, "gravity_g": float(gravity_g), "latitude": float(latitude_deg),
        "azimuth_reference": "magnetic", "sample_rate_hz": float(sample_rate_hz),
        "description": "MISMA field run: rotating string, static survey every 300 s (static=1, survey id); "
                       "reference attitude known at every sample (simulation), used at the stops",
    }
    truth = {
        "R": Rm.tolist(), "b_nT": bv.tolist(), "gyro": _jsonable(gyro), "rotation_rpm": rotation_rpm,
        "rpm_variation": rpm_variation, "mag_noise_nT": mag_noise_nT, "accel_noise_g": accel_noise_g,
        "vibration_g": vibration_g, "axial_vibration_g": axial_vibration_g, "accel_radius_m": accel_radius_m,
        "gyro_noise_deg_h": gyro_noise_deg_h, "stop_every_s": stop_every_s, "stop_duration_s": stop_duration_s,
        "rate_deg_s": rate_deg_s,
    }
    return Dataset(frame, meta, truth)


# ====================================================================== CLI
#: Data sets the command line can write.
DATASETS = {
    "lab_casing": lab_casing,
    "well_conditions": well_conditions,
    "turntable": turntable,
    "turntable_random": turntable_random,
    "turntable_between": turntable_between,
    "rotating_drill": rotating_drill,
}


def write_dataset(ds: Dataset, out_dir, name: str | None = None):
    """Write ``DIR/NAME.csv`` + ``DIR/NAME.meta.json`` (via :func:`icgo.io.recording.write_recording`) and ``DIR/NAME.truth.json``.

    Returns the path of the CSV.
    """
    import json
    from pathlib import Path

    from icgo.io import recording as io

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    name = name or ds.meta["name"]
    path = out / f"{name}.csv"
    io.write_recording(path, ds.frame, ds.meta)
    (out / f"{name}.truth.json").write_text(json.dumps(_jsonable(ds.truth), indent=1) + "\n")
    return path


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
