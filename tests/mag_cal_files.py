"""Real-looking circuitpython-mag-cal recordings made from the 9 bundled devices (test helper, not a test).

A bundled device's own distortions (its accelerometer ellipsoid fit, 12-parameter magnetometer fit and
roll-axis rotation, fitted on all its shots) are inverted to turn chosen attitudes into raw readings, so a
test can move a roll, drop one, add noise or write any layout while the sensors stay those of a real
device. ``device_attitudes(name)`` are the attitudes the device's own shots were taken at (from that fit),
so ``synth(name, *device_attitudes(name))`` is close to the device's recording.
"""

from __future__ import annotations

import json
from functools import lru_cache

import jax.numpy as jnp
import numpy as np

from icgo.io import mag_cal_bundled, schema
from icgo.models import cal_pointing
from icgo.models import calibration as cal
from icgo.physics.frames import sensors_from_attitude
from icgo.physics.qc import measured_dip_deg

INV = np.argsort(mag_cal_bundled.MAG_CAL_DEVICE_TO_TOOL)  # tool -> device columns
#: The industrial noise the discrepancy workflow assumes (icgo.discrepancy.noise.NOISE): g, nT.
INDUSTRIAL = (3e-4, 15.0)


@lru_cache(maxsize=None)
def device_model(name: str):
    """(xg (12,), xm (12,), Q (3, 3), dip deg, |B| scale nT) of a bundled device's twelve+axis fit."""
    rec = mag_cal_bundled.load_mag_cal_device(name)
    G, B, groups = rec.G, rec.B, rec.frame.group.to_numpy()
    xg = cal.ellipsoid_fit_accel(G)
    xm = cal.ellipsoid_fit(B, 1.0, G)
    Gc = np.asarray(cal.correct(jnp.asarray(xg), G))
    x12 = cal.fit_twelve(Gc, B, 1.0, x0=xm)
    Bc = np.asarray(cal.correct(jnp.asarray(x12), B))
    Q = cal_pointing.align_to_axis(Gc, Bc, groups)
    dip = float(np.median(measured_dip_deg(Gc, Bc)))
    return xg, x12, Q, dip, float(np.median(np.linalg.norm(B, axis=1)))


def device_attitudes(name: str):
    """(A, I, T) deg of the device's own 24 shots, from its fit (azimuth magnetic)."""
    from icgo.physics.frames import azimuth_from_gv, inclination_from_g, toolface_from_g

    xg, xm, Q, _, _ = device_model(name)
    rec = mag_cal_bundled.load_mag_cal_device(name)
    Gt = np.asarray(cal.correct(jnp.asarray(xg), rec.G)) @ Q.T
    Bt = np.asarray(cal.correct(jnp.asarray(xm), rec.B)) @ Q.T
    return (np.asarray(azimuth_from_gv(Gt, Bt)), np.asarray(inclination_from_g(Gt)),
            np.asarray(toolface_from_g(Gt)))


def synth(name: str, A, I, T, noise_g: float = 0.0, noise_b_nT: float = 0.0, seed: int = 0):
    """Raw tool-frame readings (G g, B nT) of the device at attitudes (A, I, T) deg, plus white noise."""
    xg, xm, Q, dip, _ = device_model(name)
    Gt, Bt = (np.asarray(v) for v in sensors_from_attitude(np.asarray(A, float), np.asarray(I, float),
                                                             np.asarray(T, float), 1.0, dip)[:2])
    S, c = np.asarray(xg[:9]).reshape(3, 3), np.asarray(xg[9:])
    Rinv, b = np.asarray(xm[:9]).reshape(3, 3), np.asarray(xm[9:])
    G = np.linalg.solve(S, (Gt @ Q).T).T + c
    B = np.linalg.solve(Rinv, (Bt @ Q).T).T + b
    r = np.random.default_rng(seed)
    return G + noise_g * r.standard_normal(G.shape), B + noise_b_nT * r.standard_normal(B.shape)


def roll(az: float, inc: float, n: int = 8, start: float = 10.0):
    """Attitudes of one roll: n shots at (az, inc), toolface turning by 360/n deg."""
    return np.full(n, az), np.full(n, inc), start + np.arange(n) * 360.0 / n


def join(*parts):
    """Concatenate (A, I, T) tuples."""
    return tuple(np.concatenate([p[k] for p in parts]) for k in range(3))


def singles(name: str):
    """The device's own 8 single-shot attitudes."""
    A, I, T = device_attitudes(name)
    return A[:8], I[:8], T[:8]


def write_fixture(path, G, B, name: str = "test device") -> None:
    """The fixture layout: device frame, flat lists, gravity g, field uT, NaN padding like the peer's files."""
    g, m = G[:, INV].ravel().tolist(), (B[:, INV] / 1000.0).ravel().tolist()
    pad = [float("nan")] * 6
    path.write_text(json.dumps({"name": name, "shots": {"mag": m + pad, "grav": g + pad}}))


def to_sensor(v, axes: str):
    """Device-frame (N, 3) -> sensor frame for a mag_cal mounting string (the inverse of Axes.fix_axes)."""
    from icgo.io.mag_cal_json import parse_axes

    idx, sign = parse_axes(axes, "axes")
    out = np.empty_like(v)
    out[:, idx] = v * np.asarray(sign)
    return out


def write_raw(path, G, B, mag_axes: str, grav_axes: str, keys: bool = True, g_unit: str = "m/s^2") -> None:
    """The raw layout: sensor frames, [[x, y, z], ...], gravity m/s^2 (or g), field uT; axes keys optional."""
    g = to_sensor(G[:, INV], grav_axes) * (schema.STANDARD_GRAVITY if g_unit == "m/s^2" else 1.0)
    doc = {"mag": to_sensor(B[:, INV] / 1000.0, mag_axes).tolist(), "grav": g.tolist()}
    if keys:
        doc.update({"mag_axes": mag_axes, "grav_axes": grav_axes})
    path.write_text(json.dumps(doc))
