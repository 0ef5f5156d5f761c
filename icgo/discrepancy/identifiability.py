"""Which effects a set of stations can tell apart, as data.

From the noise-weighted Jacobian of the residuals, the canonical correlations
between an effect's columns and those of a context (the rest of the model and
the nuisances, or one other effect): a canonical correlation of ~1 is a
parameter direction that the attitudes cannot tell apart from the context.
Results are :class:`Degeneracy` records (which effect, which parameters of it,
which context parameters mimic them, the canonical correlation); the sentences
are written by :mod:`icgo.discrepancy.report` only.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from icgo.discrepancy.model import Layout, prepare, residuals
from icgo.discrepancy.noise import NOISE, Noise
from icgo.discrepancy.stations import Stations

#: A direction's parameters (or mimicking context parameters) whose weight is
#: below this fraction of the largest are not listed; at most 3 are listed.
_LIST_FRACTION = 0.3
_LIST_MAX = 3


class Degeneracy(NamedTuple):
    """A direction of one effect's parameters that the stations cannot resolve.

    Attributes:
        effect: the effect examined.
        direction: labels of the effect's parameters that make up the direction
            (largest first, up to 3), e.g. ``("accel_bias[z]",)``.
        mimics: labels of the context parameters that reproduce its residual
            signature (largest first, up to 3); empty when the direction leaves
            no trace in the residual at all.
        sources: the effect (or ``field`` / ``group<g>``) each of ``mimics`` belongs to.
        s: sqrt(1 - rho^2) for the canonical correlation rho (0 = indistinguishable).
        chi2_typical: for a single parameter below the noise: the chi2 change that
            its typical magnitude causes (< 1); None otherwise.
    """

    effect: str
    direction: tuple
    mimics: tuple
    sources: tuple
    s: float
    chi2_typical: float | None = None

    @property
    def canonical_correlation(self) -> float:
        return math.sqrt(max(1.0 - self.s**2, 0.0))

    @property
    def unobservable(self) -> bool:
        """True when nothing mimics the direction: it has no (or a sub-noise) residual signature."""
        return not self.mimics


class Pair(NamedTuple):
    """Two effects with a shared direction (``degeneracy.effect == a``; ``b`` among its sources)."""

    a: str
    b: str
    degeneracy: Degeneracy


class Separability(NamedTuple):
    """What a station design cannot separate (:func:`separability`).

    Attributes:
        pairs: effect pairs with a shared direction.
        unobservable: directions (or single parameters) with no residual signature above the noise.
    """

    pairs: tuple
    unobservable: tuple


def _orth(J, tol=1e-10):
    """Orthonormal basis of the column space of J (rows x cols), dropping null directions."""
    if J.shape[1] == 0:
        return np.zeros((J.shape[0], 0))
    u, s, _ = np.linalg.svd(J, full_matrices=False)
    return u[:, s > tol * max(s.max(initial=0.0), 1e-300)]


def canonical_independence(J_e, J_ctx):
    """How much of an effect's columns survive projection off a context.

    Args:
        J_e: (R, p) Jacobian columns of the effect. J_ctx: (R, q) columns of the
            model + nuisances it must be told apart from.
    Returns:
        (s, V, coef): s (p,) ascending in [0, 1] — for each direction V[:, i] of
        the effect's (column-normalized) parameters, the fraction of its residual
        signature that the context cannot mimic (s = sqrt(1 - canonical corr^2));
        coef (q, p): the context combination that best mimics each direction.
    """
    norms = np.linalg.norm(J_e, axis=0)
    live = norms > 1e-12 * max(norms.max(initial=0.0), 1e-300)
    Jn = np.where(live, J_e / np.where(live, norms, 1.0), 0.0)
    Q = _orth(J_ctx)
    P = Jn - Q @ (Q.T @ Jn)
    # generalized: minimize |P v| / |Jn v| over v
    Qe, Re = np.linalg.qr(Jn)
    keep = np.abs(np.diag(Re)) > 1e-9
    s_all = np.zeros(J_e.shape[1])
    V = np.eye(J_e.shape[1])
    if keep.any():
        Rinv = np.linalg.pinv(Re)
        M = P @ Rinv
        _, s, vt = np.linalg.svd(M, full_matrices=False)
        order = np.argsort(s)
        s = np.clip(s[order], 0, 1)
        V = Rinv @ vt[order].T
        V = V / np.maximum(np.linalg.norm(V, axis=0), 1e-300)
        s_all = s
    # columns with zero signature are unobservable (s = 0) even without context
    coef = np.linalg.lstsq(J_ctx, (Jn - P) @ V, rcond=None)[0] if J_ctx.shape[1] else np.zeros((0, V.shape[1]))
    return s_all, V, coef


def _largest(weights, labels) -> tuple:
    """Labels of the largest |weights| (>= 30 % of the largest, up to 3), largest first."""
    w = np.abs(weights)
    return tuple([labels[j] for j in np.argsort(-w) if w[j] > _LIST_FRACTION * w.max()][:_LIST_MAX])


def identifiability(J, layout: Layout, effect: str, context_free, threshold=0.02) -> tuple:
    """Directions of ``effect`` that the context (model + nuisances) can mimic or that leave no trace.

    Args:
        J: (R, P) noise-weighted Jacobian (all stations), or its (P, P) triangular factor
            (:func:`icgo.discrepancy.fit.jacobian_r`; only the column geometry is used, which R keeps).
        effect: the candidate effect name.
        context_free: (P,) bool, the context's free parameters (the effect's own excluded).
        threshold: s below this counts as not separable (canonical correlation
            above sqrt(1 - threshold^2), 0.9998 for 0.02).
    Returns:
        tuple of :class:`Degeneracy`: the non-separable directions (ascending s),
        then each single parameter whose typical magnitude moves chi2 by < 1
        (``chi2_typical`` set). Empty when the effect is separable.
    """
    sl = layout.slice(effect)
    idx_ctx = np.flatnonzero(context_free)
    idx_ctx = idx_ctx[(idx_ctx < sl.start) | (idx_ctx >= sl.stop)]
    J = np.asarray(J)
    s, V, coef = canonical_independence(J[:, sl], J[:, idx_ctx])
    labels, sources = layout.labels(), layout.sources()
    le = labels[sl]
    lc = [labels[i] for i in idx_ctx]
    sc = [sources[i] for i in idx_ctx]
    cn = np.linalg.norm(J[:, idx_ctx], axis=0) if len(idx_ctx) else np.zeros(0)
    out = []
    for i in np.flatnonzero(s < threshold):
        c = coef[:, i] if coef.size else coef
        mimics = ()
        if c.size and np.abs(c).max() >= 1e-6:
            mimics = _largest(np.abs(c) * cn, lc)
        out.append(Degeneracy(effect, _largest(V[:, i], le), mimics, tuple(sc[lc.index(m)] for m in mimics),
                              float(s[i])))
    # absolute observability: theta = 1 is the effect's typical magnitude, so a column
    # norm below 1 means that magnitude moves the chi2 by less than 1 (below the noise)
    norms = np.linalg.norm(J[:, sl], axis=0)
    for j in np.flatnonzero(norms < 1.0):
        out.append(Degeneracy(effect, (le[j],), (), (), 0.0, float(norms[j] ** 2)))
    return tuple(out)


def design_jacobian(st: Stations, noise: Noise = NOISE):
    """Noise-weighted Jacobian of the residuals at the ideal model (no effects).

    Returns:
        (J (6n, P), :class:`~icgo.discrepancy.model.Prepared`) with invalid stations' rows zeroed.
    """
    prep = prepare(st, noise)
    layout, data, valid = prep.layout, prep.data, prep.valid
    theta = jnp.asarray(prep.theta0)
    J = jax.jacfwd(lambda t: (residuals(t, data, layout) * jnp.asarray(valid, float)[:, None]).ravel())(theta)
    return np.asarray(J), prep


def separability(st: Stations, effects=None, config=None) -> Separability:
    """Which effects (or parameter directions) a station design cannot tell apart.

    Evaluated at the ideal model (no effects) from the attitudes and field in
    ``st``: for every pair of effects, the canonical correlations between their
    Jacobian columns after projecting out the nuisances; for every effect, the
    directions unobservable on their own.

    Args:
        st: stations (their attitudes and field matter, not their measurements'
            effects). effects: names to examine (default all).
        config: a :class:`~icgo.discrepancy.config.WorkflowConfig` (its noise and
            ``separability_threshold``); default ``WorkflowConfig()``.
    Returns:
        :class:`Separability`.
    """
    from icgo.discrepancy.config import WorkflowConfig

    config = WorkflowConfig() if config is None else config
    J, prep = design_jacobian(st, config.noise)
    layout, free_nuis = prep.layout, prep.free_nuisance
    names = list(effects or layout.names)
    thr = config.separability_threshold
    unobservable = [d for a in names for d in identifiability(J, layout, a, free_nuis, thr) if d.unobservable]
    pairs = []
    for i, a in enumerate(names):
        for b in names[i + 1:]:
            ctx = free_nuis.copy()
            ctx[layout.slice(b)] = True
            pairs += [Pair(a, b, d) for d in identifiability(J, layout, a, ctx, thr)
                      if not d.unobservable and b in d.sources]
    return Separability(tuple(pairs), tuple(unobservable))
