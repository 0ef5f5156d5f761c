"""The library's nonlinear least-squares solvers, all in this one module.

Every nonlinear least-squares fit in icgo calls one of two entry points here
instead of carrying its own damping rule. Both are Levenberg-Marquardt with
Marquardt's scaling and the same damped step (:func:`_damped_step`); they
differ in when they stop:

* :func:`least_squares` -- stops when the Gauss-Newton step from the current
  point is negligible (below), or after ``max_steps`` steps (then ``ok`` is
  False): multi-station analysis :mod:`icgo.models.msa`, the magnetometer
  calibrations :mod:`icgo.models.calibration`.
* :func:`least_squares_fixed` -- exactly ``n_steps`` steps in ``lax.scan``,
  for large vmapped batches of fits (the discrepancy package: every candidate
  model x k folds in :func:`icgo.discrepancy.fit.evaluate_models`, and the
  per-station attitude inversion :func:`icgo.discrepancy.fit.correct`).

Why two. A solver with a convergence test runs a ``while_loop``; under
``vmap`` that loop runs until the slowest member of the batch stops, so every
fit pays for the worst one. Measured on the discrepancy workflow with a
converging solver (then optimistix's LM) in place of the fixed-step one
(``docs/discrepancy.md``): parameters agreed (<= 3e-9 standard errors) but a
120-station workflow went from 1.1 s to 43 s and a real 24-shot device from
13 s to 648 s, because 5 of 7 candidate fits (wrong models, nearly flat
directions) ran to 100 steps; the per-station inversion was 15x slower. A
fixed budget costs ``n_steps`` per member whatever the others do. Where a
single fit (or a small batch of similar ones) needs a convergence guarantee,
use :func:`least_squares`; where many fits are batched and a fixed budget has
been shown to suffice, use :func:`least_squares_fixed`.

The step (both). With ``r = r(x)``, the exact forward-mode Jacobian ``J``,
``H = JᵀJ`` and ``g = Jᵀr``, each step solves

    (H + lam diag(diag(H) + 1e-9) + 1e-10 I) delta = -g

and accepts ``x + delta`` when its cost ``sum r^2`` is finite and strictly
lower; then ``lam *= 0.3``, else ``lam *= 10`` and ``x`` stays (``lam`` starts
at ``lam0`` = 1e-3).

The stopping rule of :func:`least_squares`, and why it is not a cost
comparison. At the current point it computes the Gauss-Newton step
``d = -H⁺ g`` (pseudo-inverse: eigenvalues of ``H`` below ``P eps max`` are
dropped) and its predicted reduction ``|J d|^2 = gᵀ H⁺ g``, both from ``J`` and
``r`` directly, and stops when either is negligible:

* fit: ``|J d|^2 <= ftol * sum r^2``: no step can lower the cost by more than
  ``ftol`` of it. ``ftol`` defaults to ``16 M eps`` (M residuals), the float64
  resolution of a sum of M squares: every step the solver still takes is then
  predicted to lower the cost by more than rounding can hide, so its
  acceptance test is decided by the model, not by the last bits;
* step: ``|d_j| <= atol + rtol |x_j|`` for every j (zero-residual problems,
  whose relative reduction stays of order one to the end).

It then takes ``d`` once more if that does not raise the cost. Why not
optimistix's LM (Cauchy termination on an *accepted* step with the
residual vector changing by < 1e-10 + 1e-10 |r_i| element-wise): it cannot
meet its own tolerance at the float64 minimum of a large-residual problem:
there every Gauss-Newton step changes the cost by about one unit in the last
place, so acceptance is decided by rounding; it stops only after the trust
region has shrunk the step to exactly zero *and* two separately computed
float64 sums of squares (the cost and the model's prediction) agree bitwise.
A different reduction order (a GPU) breaks that tie for some problems, and that
solver then rejects every step to ``max_steps`` (measured: the Table 3 MSA at 100
repeats on an H100, repeat 61, 1,000 steps). ``docs/relm_study.md`` has the
evidence and the CPU reproduction.
"""

from __future__ import annotations

from typing import Any, Callable, NamedTuple

import jax
import jax.numpy as jnp


class LSQResult(NamedTuple):
    """Result of :func:`least_squares` and :func:`least_squares_fixed` (leading batch axes if vmapped).

    Attributes:
        x: (P,) solution, in the units of ``x0``.
        cost: () sum of squared residuals at ``x`` (residual units squared).
        n_steps: () int, solver steps taken (accepted and rejected); always
            ``n_steps`` for :func:`least_squares_fixed`.
        ok: () bool. :func:`least_squares`: the stopping rule was met within
            ``max_steps`` and ``x`` and ``cost`` are finite.
            :func:`least_squares_fixed`: ``x`` and ``cost`` are finite (a fixed
            budget has no convergence test).
    """

    x: jax.Array
    cost: jax.Array
    n_steps: jax.Array
    ok: jax.Array


def _damped_step(H, g, lam, f, eye):
    """The Levenberg-Marquardt step of both solvers (module docstring); ``f`` (P,) 1 = free, 0 = fixed."""
    Hd = H + lam * jnp.diag(jnp.diag(H) + 1e-9) + (1.0 - f)[:, None] * eye + 1e-10 * eye
    return -jnp.linalg.solve(Hd, g) * f


def _gauss_newton(H, g):
    """Pseudo-inverse Gauss-Newton step ``-H⁺ g`` (P,) and its predicted cost reduction ``gᵀ H⁺ g`` ()."""
    mu, V = jnp.linalg.eigh(H)  # ascending
    keep = mu > H.shape[0] * jnp.finfo(H.dtype).eps * mu[-1]
    proj = V.T @ g
    coef = jnp.where(keep, proj / jnp.where(keep, mu, 1.0), 0.0)
    return -V @ coef, jnp.sum(coef * proj)


class _State(NamedTuple):
    x: jax.Array
    r: jax.Array
    J: jax.Array
    cost: jax.Array
    lam: jax.Array
    n: jax.Array
    done: jax.Array
    d: jax.Array  # the Gauss-Newton step at x


def least_squares(residual_fn: Callable[[jax.Array, Any], jax.Array], x0, args=None, *,
                  max_steps: int = 100, rtol: float = 1e-10, atol: float = 1e-10, ftol: float | None = None,
                  lam0: float = 1e-3) -> LSQResult:
    """Minimise ``sum(residual_fn(x, args)**2)`` by Levenberg-Marquardt, stopping when converged.

    Pure, jittable and vmappable (never raises on failure: check ``ok``); runs
    in float64 when x64 is enabled (``import icgo``). The step and the stopping
    rule are in the module docstring: it stops when the Gauss-Newton step from
    the current point would lower the cost by at most ``ftol`` of it, or would
    move every parameter by at most ``atol + rtol |x_j|``.

    Args:
        residual_fn: ``(x (P,), args) -> residuals`` (any shape, raveled to
            (M,)); pure and differentiable in ``x``. Any units; ``cost`` is in
            their square.
        x0: (P,) starting point, preferably scaled so that each component is
            of order 1 (``atol`` is absolute in these units).
        args: pytree of data passed unchanged to ``residual_fn`` (vmap over it
            to batch problems).
        max_steps: largest number of steps (accepted + rejected).
        rtol, atol: the step rule's tolerances on the Gauss-Newton step.
        ftol: the fit rule's tolerance on the relative cost reduction the
            Gauss-Newton step predicts; None = ``16 M eps``, the float64
            resolution of a sum of M squares (smaller values are not resolvable).
        lam0: initial damping.
    Returns:
        LSQResult (x (P,), cost (), n_steps (), ok ()).
    """
    x0 = jnp.asarray(x0, dtype=jnp.result_type(float))
    dtype = x0.dtype
    P = x0.shape[0]
    eye = jnp.eye(P, dtype=dtype)
    free = jnp.ones((P,), dtype)

    def res(x):
        return jnp.ravel(residual_fn(x, args))

    M = jax.eval_shape(res, x0).shape[0]
    f_tol = 16.0 * M * float(jnp.finfo(dtype).eps) if ftol is None else float(ftol)

    def linearise(x):
        r = res(x)
        return r, jax.jacfwd(res)(x), jnp.sum(r * r)

    def verdict(x, r, J, cost):
        d, reduction = _gauss_newton(J.T @ J, J.T @ r)
        small = (reduction <= f_tol * cost) | jnp.all(jnp.abs(d) <= atol + rtol * jnp.abs(x))
        return small & jnp.isfinite(cost), d

    def body(s: _State) -> _State:
        x_new = s.x + _damped_step(s.J.T @ s.J, s.J.T @ s.r, s.lam, free, eye)
        r_new, J_new, c_new = linearise(x_new)
        accept = jnp.isfinite(c_new) & (c_new < s.cost)
        x, r, J, cost = (jnp.where(accept, new, old) for new, old in
                         ((x_new, s.x), (r_new, s.r), (J_new, s.J), (c_new, s.cost)))
        done, d = verdict(x, r, J, cost)
        return _State(x, r, J, cost, jnp.where(accept, s.lam * 0.3, s.lam * 10.0), s.n + 1, done, d)

    r0, J0, c0 = linearise(x0)
    done0, d0 = verdict(x0, r0, J0, c0)
    # a non-finite start cannot be repaired by a step: stop at once (ok False)
    s = _State(x0, r0, J0, c0, jnp.asarray(lam0, dtype), jnp.asarray(0), done0 | ~jnp.isfinite(c0), d0)
    s = jax.lax.while_loop(lambda s: ~s.done & (s.n < max_steps), body, s)
    converged = s.done & jnp.isfinite(s.cost)
    # the last Gauss-Newton step, where it does not raise the cost
    x_last = s.x + s.d
    r_last = res(x_last)
    c_last = jnp.sum(r_last * r_last)
    take = converged & jnp.isfinite(c_last) & (c_last <= s.cost)
    x = jnp.where(take, x_last, s.x)
    cost = jnp.where(take, c_last, s.cost)
    ok = converged & jnp.isfinite(cost) & jnp.all(jnp.isfinite(x))
    return LSQResult(x, cost, s.n, ok)


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
        x_new = x + _damped_step(H, g, lam, f, eye)
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
    1e-3 had not converged. ``gᵀ (JᵀJ)⁺ g`` is computed by :func:`_pinv_quadratic` (no LAPACK call).
    Pure, jittable, vmappable.

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
    removed = _pinv_quadratic(H, g)
    cost = cost_fn(x)
    gap = jnp.where(cost > 0, removed / jnp.where(cost > 0, cost, 1.0), 0.0)
    return jnp.where(jnp.isfinite(cost) & jnp.isfinite(gap), jnp.clip(gap, 0.0, 1.0), 1.0)


#: Ridge added to the unit-diagonal (Jacobi-scaled) normal matrix in :func:`_pinv_quadratic`.
PINV_RIDGE = 1e-11


def _pinv_quadratic(H, g):
    """``gᵀ H⁺ g`` () for a symmetric positive semi-definite ``H`` (P, P) and ``g`` (P,) in its range.

    Jacobi-scaled (unit diagonal; a zero column, a fixed parameter, is left out), a ridge of
    :data:`PINV_RIDGE`, then a Cholesky factor and one forward substitution written in ``jnp`` and
    ``lax.fori_loop``: ``|L⁻¹ g|²``. Directions the residuals do not see (eigenvalues at the ridge) carry
    no part of ``g``, so they add nothing, as the pseudo-inverse drops them (tested against ``eigh``).

    Why not ``jnp.linalg.eigh``: on CPU, jaxlib's batched LAPACK kernels wait for their batch on XLA's
    intra-op thread pool, and two such calls running side by side in one program (the fold fits and the
    all-station fits of :func:`icgo.discrepancy.fit.evaluate_models`) can hold every thread of a 2-core
    pool while waiting for each other: the program never finishes (measured: jaxlib 0.10.2, 2 cores).
    """
    P = H.shape[0]
    d = jnp.diag(H)
    seen = d > 0
    s = jnp.where(seen, 1.0 / jnp.sqrt(jnp.where(seen, d, 1.0)), 0.0)
    idx = jnp.arange(P)
    A = H * s[:, None] * s[None, :] + jnp.diag(jnp.where(seen, PINV_RIDGE, 1.0))
    b = g * s

    def column(j, L):
        v = A[:, j] - L @ L[j, :]
        ljj = jnp.sqrt(jnp.maximum(v[j], PINV_RIDGE))
        return L.at[:, j].set(jnp.where(idx > j, v / ljj, jnp.where(idx == j, ljj, 0.0)))

    L = jax.lax.fori_loop(0, P, column, jnp.zeros_like(A))

    def forward(i, y):
        return y.at[i].set((b[i] - L[i, :] @ y) / L[i, i])

    y = jax.lax.fori_loop(0, P, forward, jnp.zeros_like(b))
    return jnp.sum(y * y)
