"""The library's one nonlinear least-squares solver: optimistix Levenberg-Marquardt.

Every nonlinear least-squares fit in icgo (multi-station analysis, the
magnetometer calibrations, the discrepancy fits) calls :func:`least_squares`
instead of carrying its own damping rule. It wraps
``optimistix.LevenbergMarquardt`` (Equinox family, maintained, differentiable,
jit/vmap-safe) rather than a hand-written loop so that there is one tested
implementation of the damping and termination logic.

Method (optimistix 0.1): minimise ``sum_i r_i(x)^2`` with the exact Jacobian
``J = d r / d x`` (forward mode). Each step solves the damped Gauss-Newton
system

    (J^T J + lambda I) delta = -J^T r

(as the augmented least-squares problem by QR), with ``lambda = 1 / Delta``
and ``Delta`` a classical trust-region radius that starts at 1: a step is
accepted when the actual reduction of ``0.5 sum r^2`` is at least 0.01 of the
Gauss-Newton-predicted reduction; ``Delta`` is multiplied by 3.5 when that
ratio exceeds 0.99, kept otherwise, and multiplied by 0.25 when the step is
rejected. The damping is the identity (Levenberg), not ``diag(J^T J)``
(Marquardt), so callers should pass well-scaled variables (each of order 1).
The solve stops after an accepted step with both ``max|dx| < atol + rtol |x|``
and ``max|dr| < atol + rtol |r|`` element-wise (Cauchy termination, in the
units of ``x`` and of the residuals), or after ``max_steps`` steps (then
``ok`` is False).
"""

from __future__ import annotations

from typing import Any, Callable, NamedTuple

import jax
import jax.numpy as jnp
import optimistix as optx


class LSQResult(NamedTuple):
    """Result of :func:`least_squares` (leading batch axes if vmapped).

    Attributes:
        x: (P,) solution, in the units of ``x0``.
        cost: () sum of squared residuals at ``x`` (residual units squared).
        n_steps: () int, solver steps taken (accepted and rejected).
        ok: () bool, the solver reported success (optimistix
            ``RESULTS.successful``) and ``x`` and ``cost`` are finite.
    """

    x: jax.Array
    cost: jax.Array
    n_steps: jax.Array
    ok: jax.Array


def least_squares(residual_fn: Callable[[jax.Array, Any], jax.Array], x0, args=None, *,
                  max_steps: int = 100, rtol: float = 1e-10, atol: float = 1e-10) -> LSQResult:
    """Minimise ``sum(residual_fn(x, args)**2)`` by Levenberg-Marquardt (optimistix).

    Pure, jittable and vmappable (never raises on failure: ``throw=False``;
    check ``ok``). Runs in float64 when x64 is enabled (``import icgo``).

    Args:
        residual_fn: ``(x (P,), args) -> (M,)`` residual vector; pure and
            differentiable in ``x``. Any units; ``cost`` is in their square.
        x0: (P,) starting point; should be scaled so that each component is of
            order 1 (the damping is the identity, see the module docstring).
        args: pytree of data passed unchanged to ``residual_fn`` (vmap over it
            to batch problems).
        max_steps: largest number of solver steps (accepted + rejected).
        rtol, atol: Cauchy termination tolerances on the step in ``x`` and on
            the change of the residual vector (element-wise, max norm).
    Returns:
        LSQResult (x (P,), cost (), n_steps (), ok ()).
    """
    x0 = jnp.asarray(x0, dtype=jnp.result_type(float))
    solver = optx.LevenbergMarquardt(rtol=rtol, atol=atol)
    sol = optx.least_squares(residual_fn, solver, x0, args=args, max_steps=max_steps, throw=False)
    x = sol.value
    cost = jnp.sum(jnp.asarray(residual_fn(x, args)) ** 2)
    ok = (sol.result == optx.RESULTS.successful) & jnp.isfinite(cost) & jnp.all(jnp.isfinite(x))
    return LSQResult(x, cost, jnp.asarray(sol.stats["num_steps"]), ok)
