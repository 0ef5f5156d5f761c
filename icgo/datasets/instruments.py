"""Sensor models: accelerometer, magnetometer and gyro; casing and drill-string interference; noise.

Everything here is a pure function over arrays (``jax.numpy``), vectorised over
stations: no Python loop runs per row. Units: positions in m, fields in nT,
gravity in g, rates in deg/h, angles in deg at every public function.

Frames follow DESIGN.md: earth frame NED, tool frame z along the tool axis
(downhole), tool-to-earth rotation ``C = Rz(A) Ry(I) Rz(T)`` from
:func:`icgo.physics.frames.tool_to_earth`.

Interference sources
--------------------
* :class:`Casing`: a magnetized steel tube fixed in the lab (or buried below
  the rig), modelled by two magnetic monopoles at its ends (``"pole_pair"``,
  the usual casing model) or by a line of point dipoles along its axis
  (``"dipole_line"``, which allows a non-uniform magnetization profile; with a
  uniform profile it converges to the pole pair). Its field depends on where
  the sensor is (:func:`casing_field_ned`), so a sensor that sits off the
  tool's roll axis sees a field that changes as the tool is turned: the casing
  is *not* a constant tool-frame bias.
* :func:`drill_string_field_tool`: axial magnetization of the steel above
  (and below) a non-magnetic collar, a pole on the tool axis: a tool-fixed
  axial field.
* :class:`GyroErrors` / :func:`gyro_measure`: gyro bias, g-sensitive drift,
  scale factor and installation misalignment.

Noise: :func:`averaged_samples` draws ``n`` raw samples per station with white
noise plus rare spikes (a digitiser / EMI glitch), and returns their mean, as an
instrument that averages repeated readings does.
"""

from __future__ import annotations

from typing import Mapping, NamedTuple

import jax.numpy as jnp
import numpy as np

from icgo.physics import effects as _effects
from icgo.physics import frames as _frames

#: mu0 / (4 pi) in T m / A.
MU0_OVER_4PI = 1e-7
#: Tesla to nanotesla.
T_TO_NT = 1e9


# ----------------------------------------------------------------- casing
class Casing(NamedTuple):
    """A magnetized casing joint, fixed in the earth (lab) frame.

    Attributes:
        end_ned: (3,) position of the casing's first end (m, NED, lab origin).
        axis_ned: (3,) direction from the first end to the second (normalised
            internally).
        length_m: casing length (m). The ICGO paper: 3 m.
        diameter_m: outer diameter (m). The ICGO paper: 150 mm.
        wall_m: wall thickness (m); with the diameter it sets the steel
            cross-section that carries the magnetization.
        magnetization_A_m: axial magnetization of the steel (A/m); positive
            means the north pole is at the second end.
        model: ``"pole_pair"`` (monopoles +q at the second end, -q at the first)
            or ``"dipole_line"`` (point dipoles along the axis).
        n_segments: dipoles used by ``"dipole_line"``.
        profile: optional (n_segments,) relative magnetization of each segment
            for ``"dipole_line"`` (1 = uniform); ``None`` means uniform.
    """

    end_ned: tuple = (0.0, 1.0, 0.0)
    axis_ned: tuple = (0.0, 1.0, 0.0)
    length_m: float = 3.0
    diameter_m: float = 0.150
    wall_m: float = 0.009
    magnetization_A_m: float = 6000.0
    model: str = "pole_pair"
    n_segments: int = 60
    profile: tuple | None = None


def casing_at_distance(casing: Casing, distance_m: float) -> Casing:
    """``casing`` moved sideways so that its axis line passes ``distance_m`` (m) from the lab's vertical axis.

    The distance is the shortest one between the casing's axis line and the vertical line
    through the origin (the turntable's axis). The casing moves along their common
    perpendicular, a horizontal direction, so its axis direction, its height and its position
    along its own axis are kept (the lab casing, lying north-south 1 m east of the turntable,
    moves east or west). A vertical casing moves straight away from the origin.

    Raises:
        ValueError: a distance that is not positive, or a casing whose axis line meets the
            vertical axis (no sideways direction to move it along).
    """
    if not distance_m > 0.0:
        raise ValueError(f"casing distance {distance_m} m: must be > 0")
    a = np.asarray(casing.axis_ned, float)
    end = np.asarray(casing.end_ned, float)
    u = np.array([-a[1], a[0], 0.0])                    # a x down: horizontal, normal to both lines
    if np.linalg.norm(u) < 1e-12 * np.linalg.norm(a):  # a vertical casing: away from the origin
        u = end * np.array([1.0, 1.0, 0.0])
    now = float(end @ u) / max(float(np.linalg.norm(u)), 1e-300)
    if abs(now) < 1e-12:
        raise ValueError("casing_at_distance: the casing's axis meets the vertical axis; move it by end_ned instead")
    u = u / np.linalg.norm(u)
    return casing._replace(end_ned=tuple(float(x) for x in end + (np.sign(now) * distance_m - now) * u))


def casing_cross_section_m2(diameter_m, wall_m):
    """Steel cross-section of a tube (m^2): ``pi/4 (D^2 - (D - 2 w)^2)``."""
    if not 0.0 < 2.0 * wall_m <= diameter_m:
        raise ValueError(f"casing: wall {wall_m} m must be > 0 and at most half the diameter {diameter_m} m")
    inner = diameter_m - 2.0 * wall_m
    return jnp.pi / 4.0 * (diameter_m**2 - inner**2)


def casing_pole_strength(casing: Casing):
    """Pole strength ``q = M * A_steel`` (A m) of a uniformly magnetized casing."""
    return casing.magnetization_A_m * casing_cross_section_m2(casing.diameter_m, casing.wall_m)


def monopole_field(points, pole_ned, q):
    """Field of a magnetic monopole (nT): ``mu0/(4 pi) q r / |r|^3``, r from pole to point.

    Args:
        points: (..., 3) field points (m). pole_ned: (3,) pole position (m).
        q: pole strength (A m).
    Returns:
        (..., 3) field in the same frame as the positions (nT).
    """
    r = jnp.asarray(points) - jnp.asarray(pole_ned)
    d = jnp.linalg.norm(r, axis=-1, keepdims=True)
    return MU0_OVER_4PI * T_TO_NT * q * r / d**3


def dipole_field(points, pos_ned, moment):
    """Field of point dipoles (nT): ``mu0/(4 pi) (3 (m.r) r / r^5 - m / r^3)``.

    Args:
        points: (P, 3) field points (m). pos_ned: (K, 3) dipole positions (m).
        moment: (K, 3) dipole moments (A m^2).
    Returns:
        (P, 3) summed field (nT).
    """
    r = jnp.asarray(points)[:, None, :] - jnp.asarray(pos_ned)[None, :, :]
    d = jnp.linalg.norm(r, axis=-1, keepdims=True)
    mdotr = jnp.sum(moment[None] * r, -1, keepdims=True)
    b = 3.0 * mdotr * r / d**5 - moment[None] / d**3
    return MU0_OVER_4PI * T_TO_NT * jnp.sum(b, axis=1)


def _check_casing(casing: Casing):
    if casing.model not in ("pole_pair", "dipole_line"):
        raise ValueError(f"casing.model {casing.model!r}: choose 'pole_pair' or 'dipole_line'")
    if casing.length_m <= 0:
        raise ValueError(f"casing.length_m {casing.length_m}: must be > 0")
    ax = np.asarray(casing.axis_ned, dtype=np.float64)  # numpy: the casing is a constant, also under jit
    n = np.linalg.norm(ax)
    if not n > 0:
        raise ValueError("casing.axis_ned: must be a non-zero vector")
    return jnp.asarray(ax / n)


def casing_field_ned(points_ned, casing: Casing):
    """Casing field at the given lab positions, NED (nT).

    Args:
        points_ned: (..., 3) sensor positions (m, NED).
        casing: the :class:`Casing`.
    Returns:
        (..., 3) field in NED (nT). Positions closer to the casing axis than its
        radius are not checked (the sensor is always outside the steel here).
    """
    ax = _check_casing(casing)
    p = jnp.asarray(points_ned, dtype=jnp.float64)
    e1 = jnp.asarray(casing.end_ned, dtype=jnp.float64)
    e2 = e1 + casing.length_m * ax
    if casing.model == "pole_pair":
        q = casing_pole_strength(casing)
        return monopole_field(p, e2, q) + monopole_field(p, e1, -q)
    n = int(casing.n_segments)
    prof = jnp.ones(n) if casing.profile is None else jnp.asarray(casing.profile, dtype=jnp.float64)
    if prof.shape != (n,):
        raise ValueError(f"casing.profile: expected {n} values (n_segments), got shape {prof.shape}")
    dl = casing.length_m / n
    centres = e1 + (jnp.arange(n) + 0.5)[:, None] * dl * ax
    area = casing_cross_section_m2(casing.diameter_m, casing.wall_m)
    moments = (casing.magnetization_A_m * area * dl) * prof[:, None] * ax[None, :]
    flat = p.reshape(-1, 3)
    return dipole_field(flat, centres, moments).reshape(p.shape)


def sensor_positions_ned(pivot_ned, lever_tool, azimuth_deg, inclination_deg, toolface_deg):
    """Lab position of a sensor carried by a tool that turns about a fixed pivot (m, NED).

    ``position = pivot + C(A, I, T) @ lever``: ``lever_tool`` is the sensor's
    position relative to the pivot in tool coordinates, e.g. ``(r, 0, L)`` for
    a sensor ``L`` m down the tool axis from the pivot and ``r`` m off the roll
    axis (the roll axis is the tool z axis through the pivot).

    Args:
        pivot_ned: (3,) pivot position (m). lever_tool: (3,) lever arm (m, tool frame).
        azimuth_deg, inclination_deg, toolface_deg: (N,) attitudes (deg).
    Returns:
        (N, 3) positions (m, NED).
    """
    lever = jnp.asarray(lever_tool, dtype=jnp.float64)
    return jnp.asarray(pivot_ned, dtype=jnp.float64) + _frames.tool_to_earth_vector(
        lever, azimuth_deg, inclination_deg, toolface_deg
    )


# ---------------------------------------------------------- drill string
def drill_string_field_tool(pole_above_A_m=0.0, distance_above_m=1.0, pole_below_A_m=0.0, distance_below_m=1.0):
    """Tool-frame field (nT) of drill-string magnetization: poles on the tool axis.

    The steel above the non-magnetic collar ends ``distance_above_m`` up the
    hole (at ``z = -d``) and carries an effective pole ``pole_above_A_m``; the
    steel below (motor, bit) ends ``distance_below_m`` down the hole. Both
    fields lie along the tool axis and turn with the tool: a ``hard_iron``
    z-component. Returns (3,).
    """
    if distance_above_m <= 0 or distance_below_m <= 0:
        raise ValueError("drill string: pole distances must be > 0 m")
    k = MU0_OVER_4PI * T_TO_NT
    # Pole at z=-d above: r = +d z_hat, field +q/d^2 along +z; pole below at z=+d: field -q/d^2.
    bz = k * pole_above_A_m / distance_above_m**2 - k * pole_below_A_m / distance_below_m**2
    return jnp.array([0.0, 0.0, bz])


# ------------------------------------------------------------ mag / accel
def measure_g_b(G, B, C, effects: Mapping[str, jnp.ndarray] | None = None):
    """Apply vocabulary effects to ideal tool-frame G (g) and B (nT); see :func:`icgo.physics.effects.apply_effects`.

    Args:
        G, B: (N, 3) ideal gravity (g) and total field at the sensor (nT), tool frame.
        C: (N, 3, 3) tool-to-earth rotation of each station.
        effects: mapping effect name -> parameters; ``None`` or empty = ideal sensors.
    Returns:
        (G_meas, B_meas), each (N, 3).
    """
    if not effects:
        return jnp.asarray(G), jnp.asarray(B)
    return _effects.apply_effects(dict(effects), jnp.asarray(G), jnp.asarray(B), C)


def averaged_samples(rng, clean, sigma, n_samples=8, spike_prob=0.0, spike_scale=0.0):
    """Mean of ``n_samples`` noisy raw samples of each station, and the spike mask.

    Each raw sample is ``clean + N(0, sigma^2)``; with probability
    ``spike_prob`` per sample and axis a spike ``+-U(0.5, 1) * spike_scale`` is
    added (an EMI burst or digitiser glitch). The instrument reports the mean.
    Host-side numpy: data sets are generated once, and on a loaded CPU JAX's
    per-shape PRNG compilation cost seconds per call where numpy costs
    milliseconds.

    Args:
        rng: ``numpy.random.Generator`` (one stream per sensor; see
            ``numpy.random.SeedSequence.spawn``).
        clean: (N, 3) noise-free readings.
        sigma: white-noise standard deviation per raw sample (same unit).
        n_samples: samples averaged per station.
        spike_prob, spike_scale: spike rate per sample-axis and spike size.
    Returns:
        (mean (N, 3) float64, spiked (N,) bool: True where any raw sample had a spike).
    """
    if n_samples < 1:
        raise ValueError(f"n_samples {n_samples}: must be >= 1")
    if not 0.0 <= spike_prob <= 1.0:
        raise ValueError(f"spike_prob {spike_prob}: must be in [0, 1]")
    if sigma < 0 or spike_scale < 0:
        raise ValueError(f"sigma {sigma} and spike_scale {spike_scale} must be >= 0")
    clean = np.asarray(clean, dtype=np.float64)
    shape = (int(n_samples),) + clean.shape
    raw = clean[None] + sigma * rng.standard_normal(shape)
    hit = rng.random(shape) < spike_prob
    size = spike_scale * rng.uniform(0.5, 1.0, shape)
    sign = np.where(rng.random(shape) < 0.5, 1.0, -1.0)
    raw = raw + np.where(hit, sign * size, 0.0)
    return raw.mean(0), hit.any(axis=(0, 2))


# -------------------------------------------------------------------- gyro
class GyroErrors(NamedTuple):
    """Repeatable gyro errors (tool frame).

    ``W_meas = (I + diag(scale)) R(misalignment) W + bias + K @ G``

    Attributes:
        bias_deg_h: (3,) constant drift (deg/h).
        g_sensitivity_deg_h_g: (3, 3) g-sensitive drift matrix K (deg/h per g),
            mass unbalance of a dynamically tuned gyro: rows are gyro axes,
            columns the gravity components in the tool frame.
        scale: (3,) scale-factor errors (1).
        misalignment_deg: (3,) small rotation of the gyro axes relative to the
            accelerometer axes (installation error), rotation vector (deg).
    """

    bias_deg_h: tuple = (0.0, 0.0, 0.0)
    g_sensitivity_deg_h_g: tuple = ((0.0, 0.0, 0.0), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0))
    scale: tuple = (0.0, 0.0, 0.0)
    misalignment_deg: tuple = (0.0, 0.0, 0.0)

    def scaled(self, factor: float) -> "GyroErrors":
        """Every error times ``factor`` (a gyro grade relative to this one: 0 = perfect)."""
        f = float(factor)
        return GyroErrors(tuple(f * float(v) for v in self.bias_deg_h),
                          tuple(tuple(f * float(v) for v in row) for row in self.g_sensitivity_deg_h_g),
                          tuple(f * float(v) for v in self.scale), tuple(f * float(v) for v in self.misalignment_deg))


def gyro_measure(W, G, errors: GyroErrors = GyroErrors()):
    """Gyro reading (deg/h) of a true tool-frame rate W (deg/h) under gravity G (g).

    Args:
        W: (N, 3) true angular rate in the tool frame (deg/h), earth rate plus
            any tool rotation. G: (N, 3) gravity in the tool frame (g).
        errors: :class:`GyroErrors`.
    Returns:
        (N, 3) measured rates (deg/h), noise-free.
    """
    W = jnp.asarray(W)
    G = jnp.asarray(G)
    k = jnp.asarray(errors.g_sensitivity_deg_h_g, W.dtype)
    if k.shape != (3, 3):
        raise ValueError(f"GyroErrors.g_sensitivity_deg_h_g: expected a 3x3 matrix, got shape {k.shape}")
    r = _effects.rotation_from_vector(jnp.asarray(errors.misalignment_deg, W.dtype))
    m = jnp.diag(1.0 + jnp.asarray(errors.scale, W.dtype)) @ r
    return W @ m.T + jnp.asarray(errors.bias_deg_h, W.dtype) + G @ k.T


# ------------------------------------------------- patent frame conversion
def patent_attitude_in_our_frame(wx, wy, gx, gy, latitude_deg, gravity_g=1.0, rate_deg_h=_frames.EARTH_RATE_DEG_H):
    """The patent's eqs. (5)-(7) applied to our-frame x/y gyro (deg/h) and accelerometer (g) readings.

    The patent's x, y sensing axes are our tool x, y (its z points up the hole);
    feeding our (wx, wy, gx, gy) into :func:`icgo.physics.frames.patent_attitude` returns
    its azimuth ``A_p = A - 90`` and toolface ``T_p = T + 180`` (exhaustive check
    over axis permutations, tested in ``tests/test_instruments.py``), so we add
    those offsets back. Returns (azimuth, inclination, toolface) in deg, our convention.
    """
    a_p, inc, t_p = _frames.patent_attitude(wx, wy, gx, gy, latitude_deg, rate_deg_h, gravity_g)
    return _frames.wrap360(a_p + 90.0), inc, _frames.wrap360(t_p - 180.0)
