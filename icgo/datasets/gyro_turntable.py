"""Patent CN1888384's experiment: a 2-axis gyro + 2-accelerometer inclinometer on a 3-axis turntable.

:func:`turntable` simulates the patent's turntable plan, :func:`turntable_random` a dense random test set and
:func:`turntable_between` a set half-way between the grid points. Each takes a seed (noise only; the
instrument's repeatable errors are arguments with documented defaults) and returns a
:class:`icgo.datasets.dataset.Dataset`. Magnitudes: docs/datasets.md.
"""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp
import numpy as np

from icgo.datasets import instruments as ins
from icgo.datasets.dataset import Dataset, as_float64, contract_frame, jsonable, spawn_rngs
from icgo.physics import frames as F

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
    r_w, r_g = spawn_rngs(seed, 2)
    W_m = as_float64(W_m) + gyro_noise_deg_h * r_w.standard_normal(W_m.shape)
    G_m = as_float64(G_m) + accel_noise_g * r_g.standard_normal(G_m.shape)
    wx, wy, gx, gy = W_m[:, 0], W_m[:, 1], G_m[:, 0], G_m[:, 1]
    a_raw, i_raw, t_raw = ins.patent_attitude_in_our_frame(wx, wy, gx, gy, latitude_deg, gravity_g)
    # Two accelerometers: gz is what eq. (6)'s |g| assumption implies; no z gyro: wz is the ideal earth rate.
    gz = jnp.sqrt(jnp.clip(gravity_g**2 - gx**2 - gy**2, 0.0, None))
    G_out = jnp.stack([gx, gy, gz], -1)
    n = A.shape[0]
    frame = contract_frame(
        np.arange(n), G_out, s.B, A, I, F.wrap360(T),
        {"wx": as_float64(wx), "wy": as_float64(wy), "wz": as_float64(s.W[:, 2]),
         "azimuth_raw_deg": as_float64(a_raw), "inclination_raw_deg": as_float64(i_raw), "toolface_raw_deg": as_float64(t_raw)},
    )
    meta = {
        "name": name, "seed": int(seed), "total_field_nT": float(total_field_nT), "dip_deg": float(dip_deg),
        "declination_deg": float(declination_deg), "gravity_g": float(gravity_g), "latitude": float(latitude_deg),
        "azimuth_reference": "true (gyro compass)",
        "description": "2-axis gyro + 2 accelerometers (patent CN1888384); bx..bz are the ideal field "
                       "(no magnetometer), wz is the ideal earth rate (no z gyro), gz is implied by |g|",
    }
    truth = {
        "gyro": jsonable(gyro), "accel": jsonable(accel), "mount_misalignment_deg": list(mount_misalignment_deg),
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
    inc = as_float64(inclinations_deg).ravel()
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
    r_att, r_noise = spawn_rngs(seed, 2)
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
    inc = np.sort(as_float64(inclinations_deg).ravel())
    if inc.size < 2:
        raise ValueError("turntable_between: need at least 2 inclinations")
    mid = 0.5 * (inc[1:] + inc[:-1])
    ds = turntable(seed, inclinations_deg=mid, azimuth_step_deg=azimuth_step_deg, toolface_step_deg=toolface_step_deg,
                   azimuth_offset_deg=azimuth_step_deg / 2, toolface_offset_deg=toolface_step_deg / 2, **instrument)
    ds.meta["name"] = "turntable_between"
    return ds
