"""Frame conventions, attitude <-> sensor vectors, and angle helpers.

Conventions (DESIGN.md, binding for every module and data file):

* Earth frame NED (x north, y east, z down). Tool frame right-handed, z along
  the tool axis pointing downhole, x and y cross-axial.
* Tool-to-earth rotation ``C = Rz(A) @ Ry(I) @ Rz(T)`` (A azimuth, I
  inclination, T toolface). A vector ``v_ned`` reads ``C.T @ v_ned`` in the tool.
* ``G`` is the gravity vector in the tool frame (a vertical tool reads
  ``gz = +1 g``), not specific force. ``B`` in nT. Angles in degrees at every
  public function; radians only inside.
* ``I = atan2(sqrt(Gx^2+Gy^2), Gz)``, ``T = atan2(Gy, -Gx)``,
  ``A = atan2((Gx By - Gy Bx)|G|, Bz (Gx^2+Gy^2) - Gz (Gx Bx + Gy By))``.
  The azimuth is measured from the horizontal projection of the field vector
  that is passed in: magnetic azimuth for B, true azimuth for the earth rate.

Every function here is pure, jittable and vmappable, and works in float32 and
float64 (the dtype of the inputs is kept).
"""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp

#: Earth rotation rate, deg/h (sidereal day; WGS-84 7.2921150e-5 rad/s).
EARTH_RATE_DEG_H = 7.2921150e-5 * 180.0 / jnp.pi * 3600.0

#: Inclination (deg) within which of vertical the azimuth is undefined and flagged.
NEAR_VERTICAL_DEG = 0.5


# --------------------------------------------------------------------------- angles
def wrap180(angle_deg):
    """Wrap angles (deg) to the half-open interval (-180, 180]."""
    a = jnp.asarray(angle_deg)
    w = jnp.remainder(a + 180.0, 360.0) - 180.0  # in [-180, 180)
    return jnp.where(w == -180.0, jnp.asarray(180.0, w.dtype), w)


def wrap360(angle_deg):
    """Wrap angles (deg) to [0, 360)."""
    a = jnp.asarray(angle_deg)
    w = jnp.remainder(a, 360.0)
    return jnp.where(w >= 360.0, jnp.asarray(0.0, w.dtype), w)


def angle_diff(a_deg, b_deg):
    """``a - b`` (deg) wrapped to (-180, 180]."""
    return wrap180(jnp.asarray(a_deg) - jnp.asarray(b_deg))


# ------------------------------------------------------------------ rotations
def rot_z(angle_deg):
    """Rotation matrix about z by ``angle_deg`` (deg), shape (..., 3, 3)."""
    t = jnp.deg2rad(jnp.asarray(angle_deg))
    c, s = jnp.cos(t), jnp.sin(t)
    z, o = jnp.zeros_like(t), jnp.ones_like(t)
    return jnp.stack(
        [jnp.stack([c, -s, z], -1), jnp.stack([s, c, z], -1), jnp.stack([z, z, o], -1)], -2
    )


def rot_y(angle_deg):
    """Rotation matrix about y by ``angle_deg`` (deg), shape (..., 3, 3)."""
    t = jnp.deg2rad(jnp.asarray(angle_deg))
    c, s = jnp.cos(t), jnp.sin(t)
    z, o = jnp.zeros_like(t), jnp.ones_like(t)
    return jnp.stack(
        [jnp.stack([c, z, s], -1), jnp.stack([z, o, z], -1), jnp.stack([-s, z, c], -1)], -2
    )


def tool_to_earth(azimuth_deg, inclination_deg, toolface_deg):
    """Tool-to-earth rotation ``C = Rz(A) Ry(I) Rz(T)``, shape (..., 3, 3)."""
    return rot_z(azimuth_deg) @ rot_y(inclination_deg) @ rot_z(toolface_deg)


def earth_to_tool_vector(v_ned, azimuth_deg, inclination_deg, toolface_deg):
    """Express an earth-frame (NED) vector in the tool frame: ``C^T v``.

    Args:
        v_ned: (..., 3) vector in NED (any unit).
        azimuth_deg, inclination_deg, toolface_deg: (...) attitude, deg.
    Returns:
        (..., 3) the same vector in tool coordinates.
    """
    c = tool_to_earth(azimuth_deg, inclination_deg, toolface_deg)
    return jnp.einsum("...ji,...j->...i", c, jnp.asarray(v_ned))


def tool_to_earth_vector(v_tool, azimuth_deg, inclination_deg, toolface_deg):
    """Express a tool-frame vector in NED: ``C v``. Shapes as above."""
    c = tool_to_earth(azimuth_deg, inclination_deg, toolface_deg)
    return jnp.einsum("...ij,...j->...i", c, jnp.asarray(v_tool))


# ------------------------------------------------------------ field vectors
def field_vector_ned(total_field_nT, dip_deg, declination_deg=0.0):
    """Geomagnetic field vector in NED (nT), shape (..., 3).

    ``declination_deg`` = 0 gives the field in a magnetic-north frame, so that
    azimuths computed from B are magnetic azimuths.
    """
    f = jnp.asarray(total_field_nT)
    d = jnp.deg2rad(jnp.asarray(dip_deg))
    dec = jnp.deg2rad(jnp.asarray(declination_deg))
    h = f * jnp.cos(d)
    return jnp.stack(jnp.broadcast_arrays(h * jnp.cos(dec), h * jnp.sin(dec), f * jnp.sin(d)), -1)


def gravity_vector_ned(gravity_g=1.0):
    """Gravity in NED, (3,), in g (points down)."""
    g = jnp.asarray(gravity_g)
    return jnp.stack([jnp.zeros_like(g), jnp.zeros_like(g), g], -1)


def earth_rate_ned(latitude_deg, rate_deg_h=EARTH_RATE_DEG_H):
    """Earth rotation vector in NED (deg/h): ``Omega (cos phi, 0, -sin phi)``."""
    p = jnp.deg2rad(jnp.asarray(latitude_deg))
    r = jnp.asarray(rate_deg_h, dtype=p.dtype)
    return jnp.stack([r * jnp.cos(p), jnp.zeros_like(p), -r * jnp.sin(p)], -1)


class Sensors(NamedTuple):
    """Ideal tool-frame sensor vectors: G (g), B (nT), W gyro rate (deg/h); each (..., 3)."""

    G: jnp.ndarray
    B: jnp.ndarray
    W: jnp.ndarray


def sensors_from_attitude(
    azimuth_deg,
    inclination_deg,
    toolface_deg,
    total_field_nT=50_000.0,
    dip_deg=60.0,
    declination_deg=0.0,
    latitude_deg=30.0,
    gravity_g=1.0,
):
    """Ideal G, B and earth-rate readings for a tool at the given attitude.

    ``azimuth_deg`` is measured from the x axis of the NED frame the field is
    given in (true north when ``declination_deg`` is the real declination).
    """
    a = jnp.asarray(azimuth_deg)
    i = jnp.asarray(inclination_deg)
    t = jnp.asarray(toolface_deg)
    g = earth_to_tool_vector(gravity_vector_ned(jnp.asarray(gravity_g, a.dtype)), a, i, t)
    b = earth_to_tool_vector(
        field_vector_ned(jnp.asarray(total_field_nT, a.dtype), dip_deg, declination_deg), a, i, t
    )
    w = earth_to_tool_vector(earth_rate_ned(jnp.asarray(latitude_deg, a.dtype)), a, i, t)
    return Sensors(g, b, w)


# ---------------------------------------------------------- attitude solution
class Attitude(NamedTuple):
    """Attitude (deg) solved from sensors, each (...).

    ``near_vertical`` flags inclinations within ``NEAR_VERTICAL_DEG`` of 0 or
    180 deg, where azimuth (and toolface) are undefined: their values are then
    finite but meaningless.
    """

    azimuth: jnp.ndarray
    inclination: jnp.ndarray
    toolface: jnp.ndarray
    near_vertical: jnp.ndarray


def inclination_from_g(G):
    """Inclination (deg) from tool-frame gravity, ``atan2(sqrt(Gx^2+Gy^2), Gz)``."""
    G = jnp.asarray(G)
    return jnp.rad2deg(jnp.arctan2(jnp.hypot(G[..., 0], G[..., 1]), G[..., 2]))


def toolface_from_g(G):
    """Gravity toolface (deg, [0, 360)), ``atan2(Gy, -Gx)``."""
    G = jnp.asarray(G)
    return wrap360(jnp.rad2deg(jnp.arctan2(G[..., 1], -G[..., 0])))


def azimuth_from_gv(G, V):
    """Azimuth (deg, [0, 360)) of the tool axis from gravity G and a reference vector V.

    V is B (magnetic azimuth) or the earth rate (true azimuth: the 3-axis
    gyro-compass). ``A = atan2((Gx Vy - Gy Vx)|G|, Vz (Gx^2+Gy^2) - Gz (Gx Vx + Gy Vy))``.
    """
    G = jnp.asarray(G)
    V = jnp.asarray(V)
    gx, gy, gz = G[..., 0], G[..., 1], G[..., 2]
    vx, vy, vz = V[..., 0], V[..., 1], V[..., 2]
    gnorm = jnp.sqrt(gx * gx + gy * gy + gz * gz)
    num = (gx * vy - gy * vx) * gnorm
    den = vz * (gx * gx + gy * gy) - gz * (gx * vx + gy * vy)
    return wrap360(jnp.rad2deg(jnp.arctan2(num, den)))


def attitude_from_sensors(G, B):
    """Azimuth (magnetic), inclination and toolface (deg) from G and B, with a vertical flag.

    Args:
        G: (..., 3) gravity in the tool frame (any scale).
        B: (..., 3) magnetic field in the tool frame (any scale).
    Returns:
        Attitude; never NaN for finite, non-zero G.
    """
    inc = inclination_from_g(G)
    near = (inc < NEAR_VERTICAL_DEG) | (inc > 180.0 - NEAR_VERTICAL_DEG)
    return Attitude(azimuth_from_gv(G, B), inc, toolface_from_g(G), near)


def gyro_compass_azimuth(G, W):
    """True azimuth (deg) from gravity and a 3-axis gyro's earth-rate reading (same formula as B)."""
    return azimuth_from_gv(G, W)


# ----------------------------------------------------- the papers' own forms
def attitude_icgo_eq1(G, B):
    """The ICGO paper's eq. (1), literally, in its own (north-west-up) sensor frame.

    I = arccos(Gz/|G|); T = -arctan(Gy/Gx) (taken with atan2 to get the quadrant);
    A = arctan[(-Bx sinT + By cosT) / (cosI (Bx cosT + By sinT) - Bz sinI)].

    The paper's frame differs from ours: it agrees with :func:`attitude_from_sensors`
    when fed ``paper_frame_from_tool(G, B)`` (see that function, tested in
    ``tests/test_frames.py``). Returns (azimuth, inclination, toolface) in deg.
    """
    G = jnp.asarray(G)
    B = jnp.asarray(B)
    gx, gy, gz = G[..., 0], G[..., 1], G[..., 2]
    bx, by, bz = B[..., 0], B[..., 1], B[..., 2]
    gnorm = jnp.sqrt(gx * gx + gy * gy + gz * gz)
    inc = jnp.arccos(jnp.clip(gz / gnorm, -1.0, 1.0))
    t = -jnp.arctan2(gy, gx)
    num = -bx * jnp.sin(t) + by * jnp.cos(t)
    den = jnp.cos(inc) * (bx * jnp.cos(t) + by * jnp.sin(t)) - bz * jnp.sin(inc)
    a = jnp.arctan2(num, den)
    return wrap360(jnp.rad2deg(a)), jnp.rad2deg(inc), wrap360(jnp.rad2deg(t))


def paper_frame_from_tool(G, B):
    """Map our tool-frame (G, B) to the sensor frame in which ICGO eq. (1) holds.

    Found by an exhaustive search over the 48 axis permutations and signs of G
    and of B: eq. (1) as printed reproduces our azimuth, inclination and toolface
    (no toolface offset) for ``G' = (-Gx, -Gy, Gz)`` and ``B' = (Bx, -By, -Bz)``.
    No single proper change of sensor frame maps both vectors (G and B need
    different sign patterns), so eq. (1) most likely carries a sign misprint
    (the paper uses a north-west-up frame); we use it only as a cross-check,
    never in the pipeline. Tested in ``tests/test_frames.py``.
    """
    G = jnp.asarray(G)
    B = jnp.asarray(B)
    return G * jnp.asarray(_ICGO_G_SIGNS, G.dtype), B * jnp.asarray(_ICGO_B_SIGNS, B.dtype)


_ICGO_G_SIGNS = (-1.0, -1.0, 1.0)
_ICGO_B_SIGNS = (1.0, -1.0, -1.0)


# Patent CN1888384: 2-axis gyro + 2 accelerometers, ENU frame, eqs. (3)-(7).
def patent_sensors(azimuth_deg, inclination_deg, toolface_deg, latitude_deg,
                   rate_deg_h=EARTH_RATE_DEG_H, gravity_g=1.0):
    """Patent eqs. (3)-(4): gyro (wx, wy, wz) in deg/h and accelerometer (ax, ay, az) in g.

    Written in the patent's own frame (ENU geographic, its rotation order and
    toolface sign). Returns (w, a), each (..., 3).
    """
    A = jnp.deg2rad(jnp.asarray(azimuth_deg))
    I = jnp.deg2rad(jnp.asarray(inclination_deg))
    T = jnp.deg2rad(jnp.asarray(toolface_deg))
    phi = jnp.deg2rad(jnp.asarray(latitude_deg))
    om = jnp.asarray(rate_deg_h, A.dtype)
    g = jnp.asarray(gravity_g, A.dtype)
    sA, cA, sI, cI, sT, cT = jnp.sin(A), jnp.cos(A), jnp.sin(I), jnp.cos(I), jnp.sin(T), jnp.cos(T)
    cp, sp = jnp.cos(phi), jnp.sin(phi)
    wx = om * cp * (sA * cI * cT + cA * sT) - om * sp * sI * cT
    wy = om * cp * (-sA * cI * sT + cA * cT) + om * sp * sI * sT
    wz = om * cp * sA * sI + om * sp * cI
    ax = g * sI * cT
    ay = -g * sI * sT
    az = g * cI
    w = jnp.stack(jnp.broadcast_arrays(wx, wy, wz), -1)
    a = jnp.stack(jnp.broadcast_arrays(ax, ay, az), -1)
    return w, a


def patent_attitude(wx, wy, ax, ay, latitude_deg, rate_deg_h=EARTH_RATE_DEG_H, gravity_g=1.0):
    """Patent eqs. (5)-(7): toolface, inclination, azimuth (deg) from 2-axis gyro and accelerometers.

    T = -arctan(ay/ax); I = arcsin(sqrt(ax^2+ay^2)/g);
    A = arctan[(wx cosT - wy sinT + Omega sin(phi) sinI) / ((wx sinT + wy cosT) cosI)].
    Valid for I < 90 deg (the patent limits I < 75 deg). Returns (A, I, T) in deg.
    """
    ax = jnp.asarray(ax)
    ay = jnp.asarray(ay)
    t = jnp.arctan2(-ay, ax)
    s = jnp.clip(jnp.hypot(ax, ay) / gravity_g, 0.0, 1.0)
    inc = jnp.arcsin(s)
    phi = jnp.deg2rad(jnp.asarray(latitude_deg))
    num = wx * jnp.cos(t) - wy * jnp.sin(t) + rate_deg_h * jnp.sin(phi) * jnp.sin(inc)
    den = (wx * jnp.sin(t) + wy * jnp.cos(t)) * jnp.cos(inc)
    a = jnp.arctan2(num, den)
    return wrap360(jnp.rad2deg(a)), jnp.rad2deg(inc), wrap360(jnp.rad2deg(t))
