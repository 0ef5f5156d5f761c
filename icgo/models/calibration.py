"""12-parameter magnetometer calibration: the model, the data it is fitted on, closed-form and least-squares fits.

The MISMA paper (Yang & Cai, ``seeds/002_438cb34a40e5ab84.txt``) lost its
equations in the text extraction; each formula below is reconstructed from the
paragraph that describes it and carries the paper's equation number. The list
of reconstructions, with the reasons, is in ``docs/misma.md``.

Model (paper eqs. 2-4). The magnetometer reads ``B_meas = R B_true + b``
(R: 3x3 matrix lumping scale factors, non-orthogonality, misalignment and soft
iron; b: hard iron and sensor bias, nT). The paper identifies the 12 numbers
``Mcc = [R^-1 (row-major, 9), b (3)]`` and corrects with
``B_true = R^-1 (B_meas - b)`` (eq. 4). A parameter vector here is that (12,)
array; ``R^-1`` is dimensionless and ``b`` in nT.

The samples a calibration is fitted on: :class:`CalData` (:func:`make_caldata` checks them); the objectives
over them (eqs. 5-8, 15) are in :mod:`icgo.models.cal_objectives`, and
:class:`icgo.models.misma_objective.MismaObjective` combines those into the penalised fitness that MISMA and
SMA minimise.

Closed-form / deterministic baselines (host side, numpy; the nonlinear least
squares by :func:`icgo.maths.lsq.least_squares`, the converging entry point of :mod:`icgo.maths.lsq`):
:func:`ellipsoid_fit` (the classical quadric fit, symmetric ``R^-1``),
:func:`fit_twelve` (all 12 parameters by least squares on the dot-invariance
and magnitude residuals) and :func:`modulus_fit` (MISMA's U), each refusing too few distinct orientations
(:func:`check_orientations`). The pointing direction of rolled groups, the peer package's score and the
common rotation onto the roll axis are in :mod:`icgo.models.cal_pointing`.
"""

from __future__ import annotations

import warnings
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from icgo.maths.lsq import LSQResult, least_squares
from icgo.physics.frames import angle_diff, azimuth_from_gv

N_PARAMS = 12
#: Tool-frame directions closer than this (deg, in G and in B) count as one orientation.
DISTINCT_SEPARATION_DEG = 2.0
#: Distinct orientations a 12-parameter fit needs (see :func:`check_orientations`).
MIN_ORIENTATIONS_12 = 12
#: ... and the 9-coefficient ellipsoid (quadric) fit.
MIN_ORIENTATIONS_ELLIPSOID = 9


# ----------------------------------------------------------------------- model
def pack(r_inv, b):
    """12-vector ``[R^-1 row-major, b]`` from ``R^-1`` (..., 3, 3) and ``b`` (..., 3) nT."""
    r_inv = jnp.asarray(r_inv)
    b = jnp.asarray(b)
    return jnp.concatenate([r_inv.reshape(r_inv.shape[:-2] + (9,)), b], axis=-1)


def unpack(x):
    """Inverse of :func:`pack`: ``(R^-1 (..., 3, 3), b (..., 3))`` from (..., 12)."""
    x = jnp.asarray(x)
    return x[..., :9].reshape(x.shape[:-1] + (3, 3)), x[..., 9:]


def params_from_error_model(r, b):
    """Calibration parameters (12,) for a sensor with ``B_meas = R B_true + b`` (eq. 3)."""
    return pack(jnp.linalg.inv(jnp.asarray(r)), b)


def identity_params(dtype=jnp.float64):
    """Parameters of a perfect magnetometer (R^-1 = I, b = 0), (12,)."""
    return pack(jnp.eye(3, dtype=dtype), jnp.zeros(3, dtype))


def distort(r, b, B_true):
    """Eq. (3): ``B_meas = R B_true + b``; B_true (N, 3) nT -> (N, 3) nT."""
    return jnp.einsum("ij,...j->...i", jnp.asarray(r), jnp.asarray(B_true)) + jnp.asarray(b)


def correct(x, B_meas):
    """Eq. (4): ``B_true = R^-1 (B_meas - b)``.

    Args:
        x: (12,) parameters ``[R^-1, b]``.
        B_meas: (N, 3) raw magnetometer readings, nT.
    Returns:
        (N, 3) corrected field, nT.
    """
    r_inv, b = unpack(x)
    return jnp.einsum("ij,nj->ni", r_inv, jnp.asarray(B_meas) - b)


# ------------------------------------------------------------------ objectives
def normalized_dot(G, B):
    """``G.B / (|G| |B|)`` per sample, (N,). Equals sin(dip) for ideal sensors."""
    G = jnp.asarray(G)
    B = jnp.asarray(B)
    num = jnp.sum(G * B, -1)
    return num / (jnp.linalg.norm(G, axis=-1) * jnp.linalg.norm(B, axis=-1))


# --------------------------------------------------------------- the fitness
class CalData(NamedTuple):
    """Samples a calibration is fitted on.

    Attributes:
        G: (N, 3) gravity, g. B: (N, 3) raw magnetometer, nT.
        segment: (N,) int32 rotating-stretch id (0 .. n_segments-1).
        rotating: (N,) float 1/0, samples taken while the string rotates.
        ref_nT: reference modulus |M_omega| (nT), scalar.
        weights: (N,) sample weights of the magnitude term.
        dot_weights: (N,) sample weights of the dot-invariance term (the
            paper takes gravity at zero-velocity stops: see :func:`make_caldata`).
    """

    G: jnp.ndarray
    B: jnp.ndarray
    segment: jnp.ndarray
    rotating: jnp.ndarray
    ref_nT: jnp.ndarray
    weights: jnp.ndarray
    dot_weights: jnp.ndarray


def make_caldata(G, B, ref_nT, segment=None, rotating=None, weights=None, dot_weights=None) -> CalData:
    """Validate and pack calibration samples.

    Args:
        G: (N, 3) gravity in the tool frame, g. B: (N, 3) raw field, nT.
        ref_nT: reference field modulus |M_omega|, nT (> 0).
        segment: (N,) ints >= 0 or None (one segment).
        rotating: (N,) bools or None (no sample rotating: no Pearson term).
        weights: (N,) non-negative or None (all 1), for the magnitude term.
        dot_weights: (N,) non-negative or None (= weights), for the dot term;
            e.g. 1 at static samples only, where the accelerometer reads
            gravity without vibration and centripetal acceleration.
    Raises:
        ValueError: one line naming the bad argument.
    """
    G = np.asarray(G, np.float64)
    B = np.asarray(B, np.float64)
    if G.ndim != 2 or G.shape[1] != 3 or B.shape != G.shape:
        raise ValueError(f"calibration data: G and B must both be (N, 3), got {G.shape} and {B.shape}")
    n = G.shape[0]
    if n < 2:
        raise ValueError(f"calibration data: need at least 2 samples, got {n}")
    for name, v in (("G", G), ("B", B)):
        bad = np.argwhere(~np.isfinite(v))
        if bad.size:
            raise ValueError(f"calibration data: {name} has a non-finite value at row {bad[0][0]}")
    if np.any(np.linalg.norm(G, axis=1) == 0) or np.any(np.linalg.norm(B, axis=1) == 0):
        raise ValueError("calibration data: a G or B row is the zero vector")
    if not np.isfinite(ref_nT) or ref_nT <= 0:
        raise ValueError(f"calibration data: reference modulus must be > 0, got {ref_nT}")
    seg = np.zeros(n, np.int32) if segment is None else np.asarray(segment)
    if seg.shape != (n,) or np.any(seg < 0):
        raise ValueError(f"calibration data: segment must be (N,) non-negative ints, got shape {seg.shape}")
    rot = np.zeros(n) if rotating is None else np.asarray(rotating, np.float64)
    if rot.shape != (n,):
        raise ValueError(f"calibration data: rotating must be (N,), got shape {rot.shape}")
    w = np.ones(n) if weights is None else np.asarray(weights, np.float64)
    if w.shape != (n,) or np.any(w < 0) or w.sum() <= 0:
        raise ValueError("calibration data: weights must be (N,), non-negative, not all zero")
    dw = w if dot_weights is None else np.asarray(dot_weights, np.float64)
    if dw.shape != (n,) or np.any(dw < 0) or dw.sum() <= 0:
        raise ValueError("calibration data: dot_weights must be (N,), non-negative, not all zero")
    return CalData(jnp.asarray(G), jnp.asarray(B), jnp.asarray(seg.astype(np.int32)),
                   jnp.asarray(rot), jnp.asarray(float(ref_nT)), jnp.asarray(w), jnp.asarray(dw))


# ------------------------------------------------ orientation count (bad input)
def count_distinct_orientations(G, B, min_sep_deg=DISTINCT_SEPARATION_DEG) -> int:
    """Number of distinct tool-frame orientations (greedy clustering of unit G and B).

    Two samples belong to one orientation when both their G directions and
    their raw B directions are within ``min_sep_deg`` of each other.
    """
    G = np.asarray(G, np.float64)
    B = np.asarray(B, np.float64)
    g = G / np.linalg.norm(G, axis=1, keepdims=True)
    b = B / np.linalg.norm(B, axis=1, keepdims=True)
    c = np.cos(np.deg2rad(min_sep_deg))
    reps_g, reps_b = np.zeros((0, 3)), np.zeros((0, 3))
    for gi, bi in zip(g, b):
        if reps_g.shape[0] and np.any((reps_g @ gi >= c) & (reps_b @ bi >= c)):
            continue
        reps_g = np.vstack([reps_g, gi])
        reps_b = np.vstack([reps_b, bi])
    return int(reps_g.shape[0])


def check_orientations(G, B, n_required=MIN_ORIENTATIONS_12, what="the 12-parameter model",
                       min_sep_deg=DISTINCT_SEPARATION_DEG) -> int:
    """Raise ValueError when a recording has too few distinct orientations.

    Each static orientation gives two scalar conditions (field modulus and dip)
    with an unknown heading; we ask for one distinct orientation per parameter
    (12 for the full model, 9 for the ellipsoid's quadric), which leaves the
    least-squares problems over-determined by a factor of ~2. Geometry that is
    rank deficient despite enough orientations (e.g. rotation about one axis
    only) is caught by :func:`ellipsoid_fit`.

    Returns:
        the number of distinct orientations.
    """
    n = count_distinct_orientations(G, B, min_sep_deg)
    if n < n_required:
        raise ValueError(
            f"only {n} distinct orientations (>{min_sep_deg:g} deg apart) in the recording; "
            f"{what} needs at least {n_required}: record {n_required - n} more")
    return n


# --------------------------------------------------------- closed-form fits
def _sqrtm_spd(m):
    w, v = np.linalg.eigh(0.5 * (m + m.T))
    return (v * np.sqrt(w)) @ v.T, w


def ellipsoid_fit(B, ref_nT, G=None, check=True) -> np.ndarray:
    """Classical closed-form ellipsoid fit; symmetric ``R^-1`` and bias b.

    Least squares on the quadric ``x^T A x + 2 v^T x = 1`` (9 coefficients),
    centre ``b = -A^-1 v``, and ``R^-1 = |M_omega| sqrtm(A / (1 + b^T A b))``,
    the symmetric square root (the rotation part of R is invisible to
    magnitudes). Exact on noise-free data when R is symmetric positive definite.

    Args:
        B: (N, 3) raw field, nT. ref_nT: radius to scale to, nT.
        G: optional (N, 3) gravity; with ``check`` the orientation count is checked.
        check: raise on too few orientations / degenerate geometry.
    Returns:
        (12,) numpy parameters.
    Raises:
        ValueError: too few distinct orientations, rank-deficient design or a
            quadric that is not an ellipsoid.
    """
    B = np.asarray(B, np.float64)
    if check:
        check_orientations(G if G is not None else np.ones_like(B), B,
                           MIN_ORIENTATIONS_ELLIPSOID, "the ellipsoid fit")
    with np.errstate(over="ignore", invalid="ignore"):  # an overflow is refused just below
        s = np.median(np.linalg.norm(B, axis=1))
        x, y, z = (B / s).T
        D = np.stack([x * x, y * y, z * z, 2 * x * y, 2 * x * z, 2 * y * z, 2 * x, 2 * y, 2 * z], 1)
    if not np.all(np.isfinite(D)):  # LAPACK on inf hangs or fails: a reading far larger than the others
        raise ValueError("ellipsoid fit: a reading is too large to square (check the units of every shot)")
    sv = np.linalg.svd(D, compute_uv=False)
    if check and sv[-1] < 1e-9 * sv[0]:
        raise ValueError(
            "ellipsoid fit: the orientations do not span the sphere (rank-deficient design, e.g. "
            "rotation about a single axis): record orientations with other inclinations/azimuths")
    a, bq, c, d, e, f, g, h, i = np.linalg.lstsq(D, np.ones(len(B)), rcond=None)[0]
    A = np.array([[a, d, e], [d, bq, f], [e, f, c]])
    v = np.array([g, h, i])
    centre = -np.linalg.solve(A, v)
    k = 1.0 + centre @ A @ centre
    M = A / k
    if np.any(np.linalg.eigvalsh(M) <= 0):
        raise ValueError("ellipsoid fit: the fitted quadric is not an ellipsoid (data too noisy or degenerate)")
    root, _ = _sqrtm_spd(M)
    return np.concatenate([(ref_nT / s * root).ravel(), centre * s])


#: Step budget of the calibration least squares (Levenberg-Marquardt steps).
LSQ_MAX_STEPS = 500


def _twelve_residuals(u, args):
    """Residuals of :func:`fit_twelve`: eq. (5) ``d_k - d_bar`` and ``sqrt(mu) (|B_k| / |M| - 1)``, (2N,)."""
    scale, G, B, sw, ref_nT, mu = args
    Bc = correct(u * scale, B)
    d = normalized_dot(G, Bc)
    r1 = (d - jnp.sum(sw * sw * d) / jnp.sum(sw * sw)) * sw  # the weighted mean: zero-weight shots do not enter
    r2 = jnp.sqrt(mu) * (jnp.linalg.norm(Bc, axis=1) / ref_nT - 1.0) * sw
    return jnp.concatenate([r1, r2])


def _modulus_residuals(u, args):
    """Residuals of :func:`modulus_fit`: ``|R^-1 (B_k - b)| / |M| - 1`` (N,) and ``ridge (u - u0)`` (12,)."""
    scale, B, ref_nT, u0, ridge = args
    m = jnp.linalg.norm(correct(u * scale, B), axis=1) / ref_nT - 1.0
    return jnp.concatenate([m, ridge * (u - u0)])


def _column_scaled(fn):
    """``fn`` in variables ``v = c * u`` (``args = (c, fn_args)``), c: (P,) column scales."""
    return lambda v, args: fn(v / args[0], args[1])


_twelve_scaled_residuals = _column_scaled(_twelve_residuals)


@jax.jit
def _solve_twelve(u0, args) -> LSQResult:
    """:func:`fit_twelve`'s solve, each variable also in units of its Jacobian column norm at the start.

    That is the fixed form of the ``x_scale="jac"`` the scipy version used;
    without it the near-straight ``rotating_drill`` variant (condition ~4e3)
    does not converge in 500 steps. Returns x in the ``u`` variables.
    """
    c = jnp.linalg.norm(jax.jacfwd(_twelve_residuals)(u0, args), axis=0)
    c = jnp.where(c > 0, c, 1.0)
    fit = least_squares(_twelve_scaled_residuals, u0 * c, (c, args), max_steps=LSQ_MAX_STEPS)
    return fit._replace(x=fit.x / c)


@jax.jit
def _solve_modulus(u0, args) -> LSQResult:
    return least_squares(_modulus_residuals, u0, args, max_steps=LSQ_MAX_STEPS)


def _checked(fit: LSQResult, what: str) -> np.ndarray:
    """The solution (numpy) of a calibration least squares.

    Raises ValueError if it is not finite; warns (RuntimeWarning) and returns
    the last iterate when the step budget ran out before convergence.
    """
    x = np.asarray(fit.x)
    if not np.all(np.isfinite(x)) or not np.isfinite(float(fit.cost)):
        raise ValueError(f"{what}: the least squares diverged to a non-finite solution (bad start or data)")
    if not bool(fit.ok):
        warnings.warn(f"{what}: Levenberg-Marquardt did not converge in {int(fit.n_steps)} steps; "
                      "returning the last iterate", RuntimeWarning, stacklevel=3)
    return x


def fit_twelve(G, B, ref_nT, x0=None, mu_magnitude=1.0, weights=None, check=True):
    """All 12 parameters by least squares (the deterministic 12-parameter baseline).

    Residuals: ``d_k - d_bar`` (eq. 5) and ``sqrt(mu_m) (|B_k| / |M_omega| - 1)``,
    solved by :func:`icgo.maths.lsq.least_squares` (Levenberg-Marquardt, exact JAX
    Jacobian) from the ellipsoid fit, in variables scaled so that the matrix
    (by its largest start entry) and the bias (by ``ref_nT``) are of order one
    and then by the Jacobian's column norms at the start.
    Unlike the ellipsoid fit it also finds the rotation of the magnetometer
    relative to the accelerometers.

    Args:
        G: (N, 3) g. B: (N, 3) raw nT. ref_nT: |M_omega|, nT.
        x0: start (12,) or None (ellipsoid fit).
        mu_magnitude: weight of the magnitude residuals.
        weights: (N,) or None.
    Returns:
        (12,) numpy parameters.
    """
    G = np.asarray(G, np.float64)
    B = np.asarray(B, np.float64)
    if check:
        check_orientations(G, B)
    if x0 is None:
        x0 = ellipsoid_fit(B, ref_nT, G, check=check)
    w = np.ones(len(B)) if weights is None else np.asarray(weights, np.float64)
    sw = jnp.asarray(np.sqrt(w / w.mean()))
    # scale the variables so the bias (nT) and the matrix (1) are comparable
    scale = np.concatenate([np.full(9, np.abs(np.asarray(x0[:9])).max()), np.full(3, ref_nT)])
    args = (jnp.asarray(scale), jnp.asarray(G), jnp.asarray(B), sw, jnp.asarray(float(ref_nT)),
            jnp.asarray(float(mu_magnitude)))
    fit = _solve_twelve(jnp.asarray(np.asarray(x0, np.float64) / scale), args)
    return _checked(fit, "fit_twelve") * scale


def modulus_fit(B, ref_nT, x0=None, ridge=0.03):
    """U of MISMA (eqs. 9-10): parameters whose corrected modulus matches ``|M_omega|``.

    Least squares (:func:`icgo.maths.lsq.least_squares`) on
    ``|R^-1 (B_k - b)| / |M_omega| - 1`` with a weak ridge ``ridge * (x - x0)``
    (scaled) towards ``x0`` (default: identity matrix, bias = mean of B), so
    the fit stays defined where the geometry cannot separate all 12
    parameters (e.g. rotation about one axis only, where the ellipsoid fit is
    rank deficient). On well-spread data it agrees with :func:`ellipsoid_fit`
    up to a rotation, which moduli cannot see.

    Returns:
        (12,) numpy parameters.
    """
    B = np.asarray(B, np.float64)
    if x0 is None:  # a roughly calibrated sensor: identity (scaled to the reference), no bias
        s = np.median(np.linalg.norm(B, axis=1))
        x0 = np.concatenate([(np.eye(3) * ref_nT / s).ravel(), np.zeros(3)])
    x0 = np.asarray(x0, np.float64)
    scale = np.concatenate([np.full(9, np.abs(x0[:9]).max()), np.full(3, ref_nT)])
    u0 = jnp.asarray(x0 / scale)
    args = (jnp.asarray(scale), jnp.asarray(B), jnp.asarray(float(ref_nT)), u0, jnp.asarray(float(ridge)))
    return _checked(_solve_modulus(u0, args), "modulus_fit") * scale


# ------------------------------------------------------- accelerometer
def ellipsoid_fit_accel(G, check=True) -> np.ndarray:
    """Ellipsoid fit of the accelerometer: ``G_true = S (G_meas - c)`` on the unit sphere.

    Same closed form as :func:`ellipsoid_fit` with radius 1 g; returns (12,)
    ``[S, c]`` usable with :func:`correct`.
    """
    return ellipsoid_fit(np.asarray(G, np.float64), 1.0, check=False) if not check else \
        ellipsoid_fit(np.asarray(G, np.float64), 1.0, G, check=True)


# ------------------------------------------------------------------- azimuth
def azimuth_error_deg(G, B, reference_azimuth_deg, declination_deg=0.0):
    """Wrapped azimuth error (deg, (-180, 180]) of ``azimuth_from_gv(G, B) + declination`` vs a reference."""
    a = azimuth_from_gv(jnp.asarray(G), jnp.asarray(B)) + declination_deg
    return np.asarray(angle_diff(a, jnp.asarray(reference_azimuth_deg)))
