"""The library's nonlinear least-squares solvers, all in this one module.

Every nonlinear least-squares fit in icgo calls one of two entry points here
instead of carrying its own damping rule:

* :func:`least_squares` -- optimistix Levenberg-Marquardt with a convergence
  test (multi-station analysis :mod:`icgo.methods.msa`, the magnetometer calibrations
  :mod:`icgo.methods.calibration`). A maintained, tested JAX library (Equinox family,
  differentiable, jit/vmap-safe) rather than a hand-written loop.
* :func:`least_squares_fixed` -- an in-house Levenberg-Marquardt with a fixed
  number of steps in ``lax.scan`` and Marquardt scaling, for large vmapped
  batches of fits (the discrepancy package: every candidate model x k folds in
  :func:`icgo.discrepancy.fit.evaluate_models`, and the per-station attitude
  inversion :func:`icgo.discrepancy.fit.correct`).

Why two. A solver with a convergence test runs a ``while_loop``; under
``vmap`` that loop runs until the slowest member of the batch stops, so every
fit pays for the worst one. Measured on the discrepancy workflow with
:func:`least_squares` in place of the fixed-step solver (``docs/discrepancy.md``):
parameters agreed (<= 3e-9 standard errors) but a 120-station workflow went
from 1.1 s to 43 s and a real 24-shot device from 13 s to 648 s, because 5 of
7 candidate fits (wrong models, nearly flat directions) never met the Cauchy
test and ran to 100 steps; the per-station inversion was 15x slower. A fixed
budget costs ``n_steps`` per member whatever the others do, and Marquardt's
``diag(JᵀJ)`` scaling copes with the badly scaled candidate models. Where a
single fit (or a small batch of similar ones) needs a convergence guarantee,
use :func:`least_squares`; where many fits are batched and a fixed budget has
been shown to suffice, use :func:`least_squares_fixed`.

:func:`least_squares` method (optimistix 0.1): minimise ``sum_i r_i(x)^2`` with
the exact Jacobian ``J = d r / d x`` (forward mode). Each step solves the
damped Gauss-Newton system

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

:func:`least_squares_fixed` method: see its docstring (Marquardt damping
``lam diag(JᵀJ)``, lam from ``lam0`` = 1e-3, x0.3 after an accepted step, x10
after a rejected one, exactly ``n_steps`` steps).
"""

from __future__ import annotations

from typing import Any, Callable, NamedTuple

import jax
import jax.numpy as jnp
import optimistix as optx


class LSQResult(NamedTuple):
    """Result of :func:`least_squares` and :func:`least_squares_fixed` (leading batch axes if vmapped).

    Attributes:
        x: (P,) solution, in the units of ``x0``.
        cost: () sum of squared residuals at ``x`` (residual units squared).
        n_steps: () int, solver steps taken (accepted and rejected); always
            ``n_steps`` for :func:`least_squares_fixed`.
        ok: () bool. :func:`least_squares`: the solver reported success
            (optimistix ``RESULTS.successful``) and ``x`` and ``cost`` are
            finite. :func:`least_squares_fixed`: ``x`` and ``cost`` are finite
            (a fixed budget has no convergence test).
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


def _normal_equations(residual_fn, args, f, blocks, P: int, dtype):
    """``(cost(x), normal(x) -> (JᵀJ, Jᵀr))`` of ``residual_fn`` (fixed columns, ``f == 0``, zeroed), summed over
    ``blocks`` when given (see :func:`least_squares_fixed`)."""
    if blocks is None:
        def res(x):
            return jnp.ravel(residual_fn(x, args))

        def cost(x):
            return jnp.sum(res(x) ** 2)

        def normal(x):
            r = res(x)
            J = jax.jacfwd(res)(x) * f
            return J.T @ J, J.T @ r
        return cost, normal

    def res_b(x, blk):
        return jnp.ravel(residual_fn(x, (args, blk)))

    def over_blocks(fn, init):  # sum of fn(block) over the leading block axis
        def body(acc, blk):
            return jax.tree_util.tree_map(jnp.add, acc, fn(blk)), None
        return jax.lax.scan(body, init, blocks)[0]

    def cost_b(x):
        return over_blocks(lambda blk: jnp.sum(res_b(x, blk) ** 2), jnp.zeros((), dtype))

    def normal_b(x):
        def one(blk):
            r = res_b(x, blk)
            J = jax.jacfwd(res_b)(x, blk) * f
            return J.T @ J, J.T @ r
        return over_blocks(one, (jnp.zeros((P, P), dtype), jnp.zeros((P,), dtype)))
    return cost_b, normal_b


def least_squares_fixed(residual_fn: Callable[[jax.Array, Any], jax.Array], x0, args=None, *, n_steps: int,
                        free=None, lam0: float = 1e-3, blocks=None) -> LSQResult:
    """Minimise ``sum(residual_fn(x, args)**2)`` by Levenberg-Marquardt with exactly ``n_steps`` steps.

    For large vmapped batches of fits: the steps run in ``lax.scan``, so a
    batch of any size costs ``n_steps`` steps per member, with no member
    waiting for the slowest one (see the module docstring for the measured
    cost of a while-loop solver under ``vmap``). There is no convergence test:
    choose ``n_steps`` by checking that more steps do not change the result
    your caller uses. Pure, jittable and vmappable (also over ``free`` and
    ``lam0``); never raises. Runs in float64 when x64 is enabled.

    Damping rule (Marquardt). With ``r = r(x)``, the exact forward-mode
    Jacobian ``J`` (fixed columns zeroed), ``H = JᵀJ`` and ``g = Jᵀr``, each
    step solves

        (H + lam diag(diag(H) + 1e-9) + F + 1e-10 I) delta = -g,

    where ``F`` is 1 on the diagonal of fixed parameters (0 elsewhere), and
    zeroes ``delta`` on fixed parameters. The trial ``x + delta`` is accepted
    when its cost is finite and strictly lower than the current cost; then
    ``lam *= 0.3``, else ``lam *= 10`` and ``x`` stays. ``lam`` starts at
    ``lam0``. ``lam0 = 0`` gives Gauss-Newton steps with a cost-decrease
    safeguard (``lam`` then stays 0, so after a rejected step the iterate stays
    where it is). Because ``diag(H)`` scales the damping, parameters need not
    be of order 1, but an all-zero Jacobian column gets only the 1e-10 ridge.
    Non-finite residuals at a trial point reject it; non-finite residuals at
    ``x0`` leave ``x = x0`` and ``ok = False``.

    Args:
        residual_fn: ``(x (P,), args) -> residuals`` (any shape, raveled to
            (M,)); pure and differentiable in ``x``. Any units; ``cost`` is in
            their square.
        x0: (P,) start, in the units ``residual_fn`` expects.
        args: pytree of data passed unchanged to ``residual_fn`` (vmap over it
            to batch problems).
        n_steps: number of LM steps, accepted and rejected (static, >= 0).
        free: (P,) bool mask of parameters that move, or None (all). Fixed
            parameters keep their ``x0`` value exactly. 0/1 floats are read as
            bool (nonzero = free).
        lam0: initial damping ``lam`` (dimensionless, >= 0).
        blocks: None, or a pytree of arrays with a leading block axis (nb, ...) for a residual
            vector too long to hold its Jacobian: the residuals are then the concatenation over
            blocks b of ``residual_fn(x, (args, blocks[b]))``, and ``JᵀJ``, ``Jᵀr`` and the cost
            are accumulated over the blocks (``lax.scan``), so memory is that of one block's
            Jacobian (M_b x P) whatever the number of blocks. Same steps as unblocked, up to
            floating-point rounding of the sums.
    Returns:
        LSQResult (x (P,), cost (), n_steps () = ``n_steps``, ok ()).
    """
    x0 = jnp.asarray(x0, dtype=jnp.result_type(float))
    dtype = x0.dtype
    P = x0.shape[0]
    f = jnp.ones((P,), dtype) if free is None else (jnp.asarray(free) != 0).astype(dtype)
    cost, normal = _normal_equations(residual_fn, args, f, blocks, P, dtype)

    eye = jnp.eye(P, dtype=dtype)

    def step(carry, _):
        x, lam, c = carry
        H, g = normal(x)
        Hd = H + lam * jnp.diag(jnp.diag(H) + 1e-9) + (1.0 - f)[:, None] * eye + 1e-10 * eye
        delta = -jnp.linalg.solve(Hd, g) * f
        x_new = x + delta
        c_new = cost(x_new)
        accept = jnp.isfinite(c_new) & (c_new < c)
        return (jnp.where(accept, x_new, x), jnp.where(accept, lam * 0.3, lam * 10.0),
                jnp.where(accept, c_new, c)), None

    init = (x0, jnp.asarray(lam0, dtype), cost(x0))
    (x, _, c), _ = jax.lax.scan(step, init, None, length=n_steps)
    ok = jnp.isfinite(c) & jnp.all(jnp.isfinite(x))
    return LSQResult(x, c, jnp.asarray(n_steps), ok)


def gauss_newton_gap(residual_fn: Callable[[jax.Array, Any], jax.Array], x, args=None, free=None,
                     blocks=None) -> jax.Array:
    """Fraction of the cost at ``x`` that one full Gauss-Newton step would still remove: a convergence measure.

    With ``r = r(x)`` and ``J`` its Jacobian (fixed columns dropped through ``free``), the linearised
    problem's best step removes ``|P_J r|^2 = gᵀ (JᵀJ)⁺ g`` (``g = Jᵀr``, ``P_J`` the projection onto
    ``J``'s columns) of the cost ``|r|^2``, so ``gap`` is in [0, 1]: 0 at a stationary point (``g = 0``),
    near 1 far from one. A fixed-budget fit (:func:`least_squares_fixed`) that ended with a gap above
    1e-3 had not converged. The pseudo-inverse drops directions with eigenvalues below 1e-12 of the
    largest (parameters the residuals do not see). Pure, jittable, vmappable.

    Args:
        residual_fn, x, args, blocks: as :func:`least_squares_fixed`. free: (P,) mask or None (all).
    Returns:
        () gap; 0 when the cost is 0, 1 when it is not finite.
    """
    x = jnp.asarray(x, dtype=jnp.result_type(float))
    P = x.shape[0]
    f = jnp.ones((P,), x.dtype) if free is None else (jnp.asarray(free) != 0).astype(x.dtype)
    cost_fn, normal = _normal_equations(residual_fn, args, f, blocks, P, x.dtype)
    H, g = normal(x)
    w, V = jnp.linalg.eigh(H)
    keep = w > 1e-12 * jnp.max(w)
    proj = V.T @ g
    removed = jnp.sum(jnp.where(keep, proj ** 2 / jnp.where(keep, w, 1.0), 0.0))
    cost = cost_fn(x)
    gap = jnp.where(cost > 0, removed / jnp.where(cost > 0, cost, 1.0), 0.0)
    return jnp.where(jnp.isfinite(cost) & jnp.isfinite(gap), jnp.clip(gap, 0.0, 1.0), 1.0)
