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
``DIR/NAME.csv`` and ``DIR/NAME.meta.json`` through :mod:`icgo.io`.

Magnitudes and their physical justification: docs/datasets.md.
"""

from __future__ import annotations

from typing import Any, Mapping, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import pandas as pd

from icgo import frames as F
from icgo import instruments as ins


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
    from icgo.effects import EFFECTS, check_names

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


def _sample_sensors(key, G, B, n_samples, accel_noise_g, mag_noise_nT, spike_prob, spike_nT):
    k_g, k_b = jax.random.split(key)
    g_mean, _ = ins.averaged_samples(k_g, G, accel_noise_g, n_samples)
    b_mean, spiked = ins.averaged_samples(k_b, B, mag_noise_nT, n_samples, spike_prob, spike_nT)
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
    eff = _effects_dict(effects)
    tf = _toolfaces(toolface_step_deg, toolface_end_inclusive)
    A = np.repeat(az, tf.size)
    T = np.tile(tf, az.size)
    I = np.full(A.shape, float(inclination_deg))
    return _station_survey(
        "lab_casing", seed, A, I, T, total_field_nT, dip_deg, gravity_g, casing,
        pivot_ned=(0.0, 0.0, 0.0), lever_tool=(sensor_offset_m, 0.0, sensor_lever_m),
        effects=eff, n_samples=n_samples, accel_noise_g=accel_noise_g, mag_noise_nT=mag_noise_nT,
        spike_prob=spike_prob, spike_nT=spike_nT, outlier_sigma=outlier_sigma,
        extra_truth={"toolface_end_inclusive": toolface_end_inclusive},
    )


def _station_survey(name, seed, A, I, T, total_field_nT, dip_deg, gravity_g, casing, pivot_ned, lever_tool,
                    effects, n_samples, accel_noise_g, mag_noise_nT, spike_prob, spike_nT, outlier_sigma,
                    extra_truth=None, extra_cols=None) -> Dataset:
    """Static stations near a casing: ideal sensors + casing + effects + averaged noise + 3-sigma filter."""
    A, I, T = jnp.asarray(A), jnp.asarray(I), jnp.asarray(T)
    C = F.tool_to_earth(A, I, T)
    earth = F.field_vector_ned(total_field_nT, dip_deg, 0.0)
    pos = ins.sensor_positions_ned(pivot_ned, lever_tool, A, I, T)
    b_cas = ins.casing_field_ned(pos, casing) if casing is not None else jnp.zeros_like(pos)
    B_ned = earth + b_cas
    B = jnp.einsum("nji,nj->ni", C, B_ned)
    G = jnp.einsum("nji,j->ni", C, F.gravity_vector_ned(float(gravity_g)))
    Gm, Bm = ins.measure_g_b(G, B, C, effects)
    key = jax.random.PRNGKey(int(seed))
    g_mean, b_mean, spiked = _sample_sensors(key, Gm, Bm, n_samples, accel_noise_g, mag_noise_nT, spike_prob, spike_nT)
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
                            _np(F.wrap360(T))[keep], extra)
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
