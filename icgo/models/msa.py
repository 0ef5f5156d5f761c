"""Brooks multi-station analysis (ICGO paper section 1.2, eqs. 2-7).

Constant magnetometer errors are solved from many survey stations at once by
asking that the corrected field have the same horizontal and vertical
components at every station:

    B_corr = (B_meas - eps) / (1 + s)                                   eq. (2)
    Bv_i = B_corr,i . G_i / |G_i|                                       eq. (5)
    Bh_i = sqrt(|B_corr,i|^2 - Bv_i^2)                                  eq. (6)
    V = sum_i w_i [(Bh_i - Bh_ref)^2 + (Bv_i - Bv_ref)^2] / (sum w - 1)  eq. (7)

with ``Bh_ref, Bv_ref`` either the (weighted) station means, eqs. (3)-(4) (the
paper), or a known reference field (in-field referencing). ``s`` (scale
factors) is only solved by the ``biases_scales`` model; the paper solves the
three biases. Row weights ``w`` (0/1 masks) select the training stations of a
repeat, so shapes stay fixed and :func:`msa_solve` vmaps over repeats.

The minimisation is :func:`icgo.maths.lsq.least_squares`, the converging entry point
of :mod:`icgo.maths.lsq` (Levenberg-Marquardt, exact forward-mode Jacobian of the
residual vector, Marquardt damping; it stops when the Gauss-Newton step is below
the float64 resolution of V, typically after 2-5 steps here, or after
``max_steps`` steps). No MSA model is linear in its parameters (Bh is a square
root of a quadratic in the biases), so there is no exact linear solve. Biases
are solved in units of the mean measured field magnitude so that the variables
are of order one (the solver's absolute step tolerance is in those units).
:func:`msa_failures` gives each member of a batched solution its verdict.

Observability is checked on the host (:func:`check_observability`): a
parameter the stations cannot determine (e.g. the axial bias when every station
has the same tool-axis direction and no reference field is given) raises
``ValueError``. The check reads the Jacobian *at the solution*: at zero
correction the uncorrected cross-axial biases make an unobservable axial bias
look determined (a spurious, second-order dependence), while at the solution
its column is only noise. Two tests, both scale free: the condition number of
the Jacobian in solver units (noise-free data: an exactly dependent column),
and the linearised standard error of each parameter from the fit's own
residual scatter (noisy data: an undetermined bias has a standard error of the
order of the field magnitude divided by sqrt(N), a determined one of the order
of noise / sqrt(N)).
"""

from __future__ import annotations

from functools import partial
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from icgo.maths.lsq import least_squares
from icgo.physics.frames import azimuth_from_gv

#: Parameter names of each model, in the order of the flat parameter vector.
MODELS: dict[str, tuple[str, ...]] = {
    "axial": ("eps_z",),
    "biases": ("eps_x", "eps_y", "eps_z"),
    "biases_scales": ("eps_x", "eps_y", "eps_z", "s_x", "s_y", "s_z"),
}

#: Default largest acceptable condition number of the Jacobian in solver units.
MAX_CONDITION = 1e8
#: Default largest acceptable standard error of a parameter, relative to |B| for
#: biases and absolute for scale factors (1 % of the field: ~500 nT).
MAX_REL_STD = 0.01


class MSAResult(NamedTuple):
    """Result of a multi-station analysis (leading batch axes if vmapped).

    Attributes:
        bias: (3,) magnetometer biases eps (nT), zeros for unsolved axes.
        scale: (3,) scale-factor errors s (dimensionless), zeros unless solved.
        params: (P,) the solved parameters in the order of ``MODELS[model]``
            (biases in nT).
        cost: () V of eq. (7) at the solution (nT^2).
        n_steps: () int, Levenberg-Marquardt steps taken (accepted and rejected).
        converged: () bool, the solver met its tolerance within ``max_steps``
            (:class:`icgo.maths.lsq.LSQResult` ``ok``).
        condition: () condition number of the residual Jacobian at the
            solution in solver units (biases divided by the mean |B|); small is
            well determined, ~1e8 or more means a dependent parameter.
        singular_values: (P,) singular values of that Jacobian.
        std_error: (P,) linearised standard errors of ``params`` (nT for
            biases) from the residual scatter at the solution.
        reference: (2,) (Bh_ref, Bv_ref) at the solution (nT).
    """

    bias: jnp.ndarray
    scale: jnp.ndarray
    params: jnp.ndarray
    cost: jnp.ndarray
    n_steps: jnp.ndarray
    converged: jnp.ndarray
    condition: jnp.ndarray
    singular_values: jnp.ndarray
    std_error: jnp.ndarray
    reference: jnp.ndarray


def _check_model(model: str) -> tuple[str, ...]:
    if model not in MODELS:
        raise ValueError(f"msa model {model!r}: expected one of {list(MODELS)}")
    return MODELS[model]


def bias_scale(params, model: str):
    """Split a flat parameter vector into (bias (3,) nT, scale (3,)) for ``model``."""
    p = jnp.asarray(params)
    z = jnp.zeros(p.shape[:-1] + (3,), p.dtype)
    if model == "axial":
        return z.at[..., 2].set(p[..., 0]), z
    if model == "biases":
        return p[..., :3], z
    if model == "biases_scales":
        return p[..., :3], p[..., 3:6]
    raise ValueError(f"msa model {model!r}: expected one of {list(MODELS)}")


def correct_field(B, bias, scale=None):
    """Eq. (2) (with optional scale factors): ``(B - eps) / (1 + s)``.

    Args:
        B: (..., 3) measured field, nT.
        bias: (3,) or (..., 3) biases eps, nT.
        scale: (3,) scale-factor errors s (dimensionless) or None.
    Returns:
        (..., 3) corrected field, nT.
    """
    out = jnp.asarray(B) - jnp.asarray(bias)
    if scale is not None:
        out = out / (1.0 + jnp.asarray(scale))
    return out


class MSAParams(NamedTuple):
    """A fitted MSA correction (a leading member axis on both arrays when batched).

    Attributes:
        bias: (3,) magnetometer biases eps, nT. scale: (3,) scale-factor errors s (zeros for the
            bias-only models).
    """

    bias: jnp.ndarray
    scale: jnp.ndarray


def predict(params: MSAParams, x):
    """The MSA-corrected field of eq. (2), ``(B - eps) / (1 + s)`` (:func:`correct_field`).

    Args:
        params: one correction (:class:`MSAParams`, no member axis).
        x: (N, 6) sensor values Gx, Gy, Gz (g), Bx, By, Bz (nT); only the field is corrected.
    Returns:
        (N, 3) corrected field, nT.
    """
    return correct_field(x[:, 3:], params.bias, params.scale)


#: :func:`predict` of M corrections (a leading member axis on the params) on the same rows: (M, N, 3) nT.
predict_members = jax.jit(jax.vmap(predict, in_axes=(0, None)))


def horizontal_vertical(G, B):
    """Eqs. (5)-(6): horizontal and vertical field components (nT) at each station.

    Args:
        G: (..., 3) gravity in the tool frame (any scale).
        B: (..., 3) magnetic field in the tool frame, nT.
    Returns:
        (Bh, Bv), each (...), nT. Bv is positive along gravity (down).
    """
    G = jnp.asarray(G)
    B = jnp.asarray(B)
    bv = jnp.sum(B * G, -1) / jnp.linalg.norm(G, axis=-1)
    bh2 = jnp.sum(B * B, -1) - bv * bv
    # Clamp before sqrt so that the derivative stays finite at a vertical field.
    bh = jnp.sqrt(jnp.maximum(bh2, 1e-12))
    return bh, bv


def _residuals(x, G, B, w, reference, model, unit):
    """Scaled residual vector r (2N,), with sum(r^2) = V of eq. (7)."""
    n_bias = 1 if model == "axial" else 3
    p = x.at[:n_bias].multiply(unit)
    bias, scale = bias_scale(p, model)
    bh, bv = horizontal_vertical(G, correct_field(B, bias, scale))
    wsum = jnp.sum(w)
    if reference is None:  # eqs. (3)-(4): weighted station means
        bh_ref = jnp.sum(w * bh) / wsum
        bv_ref = jnp.sum(w * bv) / wsum
    else:
        bh_ref, bv_ref = reference[0], reference[1]
    sw = jnp.sqrt(w / jnp.maximum(wsum - 1.0, 1.0))
    return jnp.concatenate([sw * (bh - bh_ref), sw * (bv - bv_ref)])


def _reference(x, G, B, w, reference, model, unit):
    n_bias = 1 if model == "axial" else 3
    bias, scale = bias_scale(x.at[:n_bias].multiply(unit), model)
    bh, bv = horizontal_vertical(G, correct_field(B, bias, scale))
    if reference is None:
        return jnp.stack([jnp.sum(w * bh), jnp.sum(w * bv)]) / jnp.sum(w)
    return jnp.asarray(reference, bh.dtype)


def _field_unit(B, w):
    """Mean measured field magnitude over the weighted stations (nT): the bias unit."""
    return jnp.sum(w * jnp.linalg.norm(B, axis=-1)) / jnp.sum(w)


def _unit_svd(J):
    """Singular values, condition number and sum_j V_kj^2 / s_j^2 of J (solver units)."""
    _, sv, vt = jnp.linalg.svd(J, full_matrices=False)
    cond = jnp.where(sv[-1] > 0, sv[0] / sv[-1], jnp.inf)
    inv_diag = jnp.sum((vt / sv[:, None]) ** 2, axis=0)  # diag((J^T J)^-1), inf if singular
    return sv, cond, inv_diag


def _solver_residuals(x, data, model):
    """:func:`_residuals` in the ``(x, args)`` form of :func:`icgo.maths.lsq.least_squares`.

    ``data = (G, B, w, reference, unit)``; returns (2N,) nT.
    """
    G, B, w, reference, unit = data
    return _residuals(x, G, B, w, reference, model, unit)


@partial(jax.jit, static_argnames=("model", "max_steps"))
def msa_solve(G, B, weights, reference=None, model: str = "biases", max_steps: int = 100) -> MSAResult:
    """Levenberg-Marquardt solution of eq. (7) by :func:`icgo.maths.lsq.least_squares`; pure, jittable, vmappable.

    No input checks here (use :func:`multi_station_analysis` for a checked call).

    Args:
        G: (N, 3) gravity, g. B: (N, 3) measured field, nT.
        weights: (N,) non-negative row weights (a 0/1 training mask).
        reference: None for the station means of eqs. (3)-(4), or (2,) known
            (Bh_ref, Bv_ref) in nT.
        model: ``"biases"`` (paper), ``"axial"`` or ``"biases_scales"``.
        max_steps: largest number of solver steps; the problem is nearly
            linear and converges (to 1e-10 relative) in a handful.
    Returns:
        MSAResult.
    """
    G = jnp.asarray(G)
    B = jnp.asarray(B)
    w = jnp.asarray(weights, B.dtype)
    unit = _field_unit(B, w)
    args = (G, B, w, reference, model, unit)
    x0 = jnp.zeros(len(MODELS[model]), B.dtype)
    fit = least_squares(partial(_solver_residuals, model=model), x0, (G, B, w, reference, unit),
                        max_steps=max_steps)
    x, cost = fit.x, fit.cost
    jac = jax.jacfwd(lambda x: _residuals(x, *args))
    J = jac(x)
    sv, cond, inv_diag = _unit_svd(J)
    n_bias = 1 if model == "axial" else 3
    p = x.at[:n_bias].multiply(unit)
    # Cov(x) = s^2 (J_raw^T J_raw)^-1 with s^2 = sum r_raw^2 / (2 N - P); in the
    # scaled residuals of eq. (7) this is V / (2 N - P) (J^T J)^-1.
    dof = jnp.maximum(2.0 * jnp.sum(w > 0) - x.shape[0], 1.0)
    cov_diag = inv_diag * cost / dof
    std = jnp.sqrt(jnp.maximum(cov_diag, 0.0)).at[:n_bias].multiply(unit)
    bias, scale = bias_scale(p, model)
    ref = _reference(x, *args)
    return MSAResult(bias, scale, p, cost, fit.n_steps, fit.ok, cond, sv, std, ref)


def msa_failures(result: MSAResult, model: str = "biases", reference=None,
                 max_condition: float = MAX_CONDITION, max_rel_std: float = MAX_REL_STD) -> list:
    """Host-side verdict on each member of a (batched) solution: None where it is usable, else why not.

    A member fails when the stations could not determine a parameter (the
    condition number exceeds ``max_condition`` or a standard error exceeds
    ``max_rel_std``, times the field magnitude for biases), when its solution is
    not finite, or when the solver did not meet its stopping rule within its
    step budget.

    Args:
        result: an MSAResult, unbatched or with one leading member axis.
        model: the MSA model it was solved with.
        reference: the reference it was solved with (only used in the message).
        max_condition: largest acceptable condition number (solver units).
        max_rel_std: largest acceptable relative standard error.
    Returns:
        One entry per member (one for an unbatched result): None, or a one-line reason
        (e.g. ``"Levenberg-Marquardt did not converge in 100 steps; ..."``).
    """
    names = _check_model(model)
    cond = np.atleast_1d(np.asarray(result.condition, dtype=float))
    R = cond.shape[0]
    std = np.asarray(result.std_error, dtype=float).reshape(R, len(names))
    ref = np.asarray(result.reference, dtype=float).reshape(R, 2)
    cost = np.asarray(result.cost, dtype=float).reshape(R)
    params = np.asarray(result.params, dtype=float).reshape(R, len(names))
    converged = np.asarray(result.converged, dtype=bool).reshape(R)
    n_steps = np.asarray(result.n_steps).reshape(R)
    n_bias = 1 if model == "axial" else 3
    hint = "" if reference is not None else "; a known reference field (reference=...) may fix it"
    out = []
    for k in range(R):
        if not (np.isfinite(cost[k]) and np.isfinite(params[k]).all()):
            out.append("the solution is not finite (NaN or inf in the biases or V)")
            continue
        field = float(np.hypot(*ref[k]))
        limit = np.array([max_rel_std * field] * n_bias + [max_rel_std] * (len(names) - n_bias))
        weak = [n for n, s, lim in zip(names, std[k], limit) if not np.isfinite(s) or s > lim]
        if weak or not np.isfinite(cond[k]) or cond[k] > max_condition:
            if not weak:
                weak = [n for n, s, lim in sorted(zip(names, std[k], limit), key=lambda t: -t[1] / t[2])][:1]
            detail = ", ".join(f"{n} +/- {s:.3g}" for n, s in zip(names, std[k]))
            out.append(f"the stations cannot determine {weak} (condition number {cond[k]:.3g}; standard errors "
                       f"{detail}); add stations with other tool-axis directions{hint}")
        elif not converged[k]:
            out.append(f"Levenberg-Marquardt did not converge in {int(n_steps[k])} steps; raise max_steps "
                       "(msa.iterations)")
        else:
            out.append(None)
    return out


def check_observability(result: MSAResult, model: str = "biases", reference=None,
                        max_condition: float = MAX_CONDITION,
                        max_rel_std: float = MAX_REL_STD) -> np.ndarray:
    """Host-side check that every member of a solution is usable (:func:`msa_failures`), else ValueError.

    Raises ValueError naming the first failing member (``repeat k`` for a batched
    result) and why: undetermined parameters, a non-finite solution, or no
    convergence within the step budget.

    Args:
        result: an MSAResult, unbatched or with one leading repeat axis.
        model, reference, max_condition, max_rel_std: as :func:`msa_failures`.
    Returns:
        the condition number(s), () or (R,) numpy.
    """
    single = np.ndim(result.condition) == 0
    for k, why in enumerate(msa_failures(result, model, reference, max_condition, max_rel_std)):
        if why is not None:
            raise ValueError(f"multi-station analysis{'' if single else f' (repeat {k})'}: {why}")
    cond = np.atleast_1d(np.asarray(result.condition, dtype=float))
    return cond[0] if single else cond


def _validate(G, B, weights, reference, model):
    _check_model(model)
    G = np.asarray(G, dtype=float)
    B = np.asarray(B, dtype=float)
    if G.ndim != 2 or G.shape[1] != 3 or B.shape != G.shape:
        raise ValueError(f"msa: G and B must both be (N, 3); got {G.shape} and {B.shape}")
    if not (np.isfinite(G).all() and np.isfinite(B).all()):
        raise ValueError("msa: G or B contains NaN or inf")
    if np.any(np.linalg.norm(G, axis=1) == 0):
        raise ValueError("msa: a station has G = 0 (no gravity reading)")
    w = np.ones(G.shape[0]) if weights is None else np.asarray(weights, dtype=float)
    if w.shape != (G.shape[0],):
        raise ValueError(f"msa: weights must be ({G.shape[0]},); got {w.shape}")
    if not np.isfinite(w).all() or np.any(w < 0):
        raise ValueError("msa: weights must be finite and non-negative")
    n_eff = int(np.count_nonzero(w))
    if n_eff < len(MODELS[model]) + 1:
        raise ValueError(f"msa: {n_eff} weighted stations cannot determine {len(MODELS[model])} parameters")
    if model == "biases_scales" and reference is None:
        raise ValueError("msa model 'biases_scales' needs a known reference field (reference=...): "
                         "with station means a common scale factor shrinks V without bound")
    if reference is not None:
        reference = np.asarray(reference, dtype=float)
        if reference.shape != (2,) or not np.isfinite(reference).all():
            raise ValueError(f"msa: reference must be finite (Bh_ref, Bv_ref) in nT; got {reference!r}")
    return G, B, w, reference


def reference_from_field(total_field_nT: float, dip_deg: float) -> np.ndarray:
    """(Bh_ref, Bv_ref) in nT from a total field and dip (for in-field referencing)."""
    d = np.deg2rad(dip_deg)
    return np.array([total_field_nT * np.cos(d), total_field_nT * np.sin(d)])


def multi_station_analysis(G, B, weights=None, reference=None, model: str = "biases",
                           max_steps: int = 100, max_condition: float = MAX_CONDITION,
                           max_rel_std: float = MAX_REL_STD) -> MSAResult:
    """Checked multi-station analysis: validate, check observability, then :func:`msa_solve`.

    Args:
        G: (N, 3) gravity, g. B: (N, 3) measured field, nT.
        weights: (N,) row weights or None for all rows.
        reference: None (station means, paper eqs. 3-4) or (Bh_ref, Bv_ref) nT
            (see :func:`reference_from_field`).
        model: ``"biases"`` (paper), ``"axial"``, ``"biases_scales"``.
        max_steps: largest number of Levenberg-Marquardt steps.
        max_condition, max_rel_std: observability thresholds
            (:func:`check_observability`).
    Returns:
        MSAResult.
    Raises:
        ValueError: bad shapes, NaN, too few stations, or a parameter the
            stations cannot determine.
    """
    G, B, w, reference = _validate(G, B, weights, reference, model)
    ref = None if reference is None else jnp.asarray(reference)
    result = msa_solve(jnp.asarray(G), jnp.asarray(B), jnp.asarray(w), ref, model=model, max_steps=max_steps)
    check_observability(result, model, reference, max_condition, max_rel_std)
    return result


def corrected_azimuth(G, B, result_or_bias, scale=None):
    """Azimuth (deg, [0, 360)) from G and the MSA-corrected field.

    Args:
        G: (..., 3). B: (..., 3) measured field, nT.
        result_or_bias: an MSAResult, or a (3,) bias in nT.
        scale: (3,) scale errors when a bare bias is given.
    """
    if isinstance(result_or_bias, MSAResult):
        bias, scale = result_or_bias.bias, result_or_bias.scale
    else:
        bias = result_or_bias
    return azimuth_from_gv(G, correct_field(B, bias, scale))
