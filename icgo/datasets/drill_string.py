"""The MISMA paper's experiment: a rotating drill string, stopped for a static survey every 300 s.

:func:`rotating_drill` takes a seed (noise and stick-slip only; the 12-parameter magnetometer error and the
gyro's errors are arguments with documented defaults) and returns a :class:`icgo.datasets.dataset.Dataset`.
Magnitudes: docs/datasets.md.
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from icgo.datasets import instruments as ins
from icgo.datasets.dataset import Dataset, as_float64, contract_frame, jsonable, spawn_rngs
from icgo.physics import frames as F
from icgo.physics import strapdown

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
    Rm = as_float64(R)
    bv = as_float64(b_nT)
    if Rm.shape != (3, 3) or bv.shape != (3,):
        raise ValueError(f"rotating_drill: R must be 3x3 and b_nT length 3, got {Rm.shape} and {bv.shape}")
    dt = 1.0 / sample_rate_hz
    t = np.arange(n) * dt
    phase = np.mod(t, stop_every_s)
    static = phase >= stop_every_s - stop_duration_s
    survey = np.where(static, (t // stop_every_s).astype(np.int64), -1)
    r_ou, r_t0, r_b, r_g, r_vib, r_w = spawn_rngs(seed, 6)
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
    B = as_float64(s.B) @ Rm.T + bv + mag_noise_nT * r_b.standard_normal((n, 3))
    omega = np.deg2rad(rate_deg_s)
    rot = (~static)[:, None]
    vib = r_vib.standard_normal((n, 3)) * np.array([vibration_g, vibration_g, axial_vibration_g])
    centripetal = np.stack([omega**2 * accel_radius_m / 9.80665, 0 * omega, 0 * omega], -1)
    G = as_float64(s.G) + rot * (vib + centripetal) + accel_noise_g * r_g.standard_normal((n, 3))
    # the gyro's true sample = the constant body rate (earth rate included) that turns attitude k-1 into k
    W_true = strapdown.gyro_rates_from_attitude(A, I, T, dt, latitude_deg, rate_deg_s)
    W = as_float64(ins.gyro_measure(W_true, as_float64(s.G), gyro)) + gyro_noise_deg_h * r_w.standard_normal((n, 3))
    frame = contract_frame(
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
        "R": Rm.tolist(), "b_nT": bv.tolist(), "gyro": jsonable(gyro), "rotation_rpm": rotation_rpm,
        "rpm_variation": rpm_variation, "mag_noise_nT": mag_noise_nT, "accel_noise_g": accel_noise_g,
        "vibration_g": vibration_g, "axial_vibration_g": axial_vibration_g, "accel_radius_m": accel_radius_m,
        "gyro_noise_deg_h": gyro_noise_deg_h, "stop_every_s": stop_every_s, "stop_duration_s": stop_duration_s,
        "rate_deg_s": rate_deg_s,
    }
    return Dataset(frame, meta, truth)
