"""name + add: the greedy forward search over the effect vocabulary.

Shaped like the optimizers of :mod:`icgo.optim` (a pair of pure functions over
a NamedTuple state that carries its own context)::

    state = init(stations, config, key)   # evaluates the reference model + every candidate
    while not state.done:
        state = step(state)               # adds the best candidate, evaluates again
    result = finish(state, seconds)

or simply ``run_workflow(stations, config)``. The loop is host-side Python: the
evaluation is one jitted call per step (:func:`~icgo.discrepancy.fit.evaluate_models`)
and the step's decisions are made on its numbers. Nothing here reads or writes
English text; :mod:`icgo.discrepancy.report` renders the result.

Decision rules (``WorkflowConfig``): a candidate qualifies when it lowers the
held-out chi2 by at least ``min_rel_improvement`` AND its paired per-station
improvement has z >= ``min_z`` AND it raises neither the held-out field residual
(RMS nT) nor the held-out azimuth residual by more than :data:`GAP_TOLERANCE`; the qualifying candidate
with the lowest held-out chi2 is added (all qualifying candidates are considered,
not only the overall lowest); another qualifying
candidate within paired z < ``ambiguity_z`` of it makes the step not separable
(both are reported; the best is kept so that the search can go on). The search
stops when the best does not qualify or ``max_effects`` (when set) are in the model.
Every evaluation goes on from its last fits until every model's fits have converged
(:data:`CONVERGED_GAP`, :data:`CONVERGED_FALL`, at most :data:`MAX_ROUNDS` evaluations); a candidate
whose fits have not converged never qualifies.
Result kinds (:data:`KINDS`): ``not_separable`` when a step was ambiguous,
else ``unexplained`` when the final held-out chi2 per residual exceeds
``noise_tolerance`` x the noise floor (in group mode with ``noise_from_data``: x the larger of the noise
floor and the best held-out chi2 of any converged model evaluated, :mod:`icgo.discrepancy.scatter`), else
``no_missing_effect`` (nothing added) or ``explained``.
"""

from __future__ import annotations

import time
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from icgo.discrepancy.compare import Comparison, Gap, Pattern, azimuth_scored, compare, find_pattern, gap
from icgo.discrepancy.config import WorkflowConfig
from icgo.discrepancy.fit import Evaluation, evaluate_models, folds, standard_errors
from icgo.discrepancy.identifiability import identifiability
from icgo.discrepancy.model import Data, Layout, Prepared, fitted_field, predict, prepare
from icgo.discrepancy.noise import noise_floor
from icgo.discrepancy.outliers import screen
from icgo.discrepancy.scatter import VOCABULARY, NoiseEstimate, estimate
from icgo.discrepancy.stations import Stations, check_stations, pad_stations
from icgo.maths.stats import paired_z
from icgo.physics import effects as _fx
from icgo.physics.frames import angle_diff, azimuth_from_gv, tool_to_earth

#: The result kinds, in the order they are decided.
KINDS = ("not_separable", "unexplained", "no_missing_effect", "explained")

#: Seed of the fold permutation when no key is given (:func:`init`, :func:`run_workflow`).
FOLD_SEED = 0


#: A model's fits have converged when one more Gauss-Newton step would remove at most this fraction of
#: each one's cost (:func:`icgo.maths.lsq.gauss_newton_gap`), or when another ``n_iter`` LM steps lowered
#: their summed cost by at most :data:`CONVERGED_FALL` of it (near a minimum of a badly fitting model the
#: linearised step promises more than any step delivers). The decisions compare scores at 10 % steps.
CONVERGED_GAP = 1e-3
CONVERGED_FALL = 1e-3
#: ... or, for a model with an effect of data-driven start (``magnetic_body``), when another ``n_iter`` LM steps
#: lowered their summed cost by at most this much per residual component fitted (the k folds and the full fit:
#: k x the residual components used): a fit crawling along a
#: valley it cannot resolve (a far ``magnetic_body``, whose distance and moment trade against each other) then
#: counts as converged once its progress is a hundredth of the noise per residual, far below the 10 % steps
#: the decisions compare.
CONVERGED_FALL_PER_RESIDUAL = 1e-2
#: Most evaluations of one step: each goes on from the last for ``n_iter`` more LM steps while a fit has
#: not converged (5 x the default 12 steps = 60).
MAX_ROUNDS = 5

#: Relative rise of the held-out field or azimuth residual that still lets an effect qualify: refitting
#: a model that adds an accelerometer effect moves the magnetometer residual by a fraction of a
#: percent; the bad additions on real devices raised it by 30-100 %.
GAP_TOLERANCE = 0.01


class Candidate(NamedTuple):
    """One model evaluated at a step: the current model + one effect.

    Attributes:
        index: its row in the step's :class:`~icgo.discrepancy.fit.Evaluation`.
        name: the added effect.
        heldout: held-out chi2 per residual component.
        bic: chi2 + (free parameters) ln(residual components), on all stations.
        z: paired z of its per-station held-out improvement over the current model.
        qualifies: passes ``min_rel_improvement`` and ``min_z`` and raises neither the held-out
            field nor the azimuth residual (beyond :data:`GAP_TOLERANCE`; see :func:`_evaluated`).
        params: (n_params,) the effect's fitted physical parameters (all stations).
        gap: its held-out :class:`~icgo.discrepancy.compare.Gap`.
        converged: every fit of the model converged (:data:`CONVERGED_GAP`, within :data:`MAX_ROUNDS`
            evaluations); an unconverged candidate never qualifies.
    """

    index: int
    name: str
    heldout: float
    bic: float
    z: float
    qualifies: bool
    params: np.ndarray
    gap: Gap | None = None
    converged: bool = True


class Step(NamedTuple):
    """One add step.

    Attributes:
        name: the effect added. params, stderr: its physical parameters and their
            standard errors (Gauss-Newton covariance). units: their unit.
        gap_before, gap_after: held-out :class:`~icgo.discrepancy.compare.Gap` without / with it.
        heldout_before, heldout_after: held-out chi2 per residual without / with it.
        z_improvement: paired z of the improvement.
        runner_up: the second-best candidate (None if there was none).
        margin_z, delta_bic: evidence margin over the runner-up (paired z of the
            runner-up's held-out chi2 minus the best's; BIC difference).
        equivalent: other qualifying candidates within ``ambiguity_z`` (not separable).
        degeneracies: directions of the effect the model + nuisances can mimic
            (s < ``separability_threshold``), or that leave no trace.
        equivalences: for each equivalent candidate, the directions it mimics
            (s < ``equivalence_threshold``).
        candidates: every candidate of the step, best first.
        aliases: components of the effect that a component of a vocabulary effect the search
            did not name can mimic with these attitudes (:func:`component_aliases`): the effect
            may win as a whole while those components stay ambiguous.
    """

    name: str
    params: tuple
    stderr: tuple
    units: str
    gap_before: Gap
    gap_after: Gap
    heldout_before: float
    heldout_after: float
    z_improvement: float
    runner_up: str | None
    margin_z: float
    delta_bic: float
    equivalent: tuple
    degeneracies: tuple
    equivalences: tuple
    candidates: tuple
    aliases: tuple = ()

    @property
    def separable(self) -> bool:
        return not self.equivalent


class SearchContext(NamedTuple):
    """Constant data of one search (carried in the state, like ``icgo.optim``'s Context).

    Attributes:
        stations: the (padded) stations. layout, data: see :func:`~icgo.discrepancy.model.prepare`.
        valid: (n,) stations used (real, not near vertical). az_ok: (n,) azimuth scored.
        free_nuisance: (P,) bool. group_free: (P,) 0/1 group-direction nuisances.
        train, test: (K, n) fold weights. valid_w: (n,) 0/1.
        az_meas: (n,) measured azimuth, deg. floor: noise-only chi2 per residual.
        n_res: residual components used. names: candidate effect names. config: the options.
        scatter_from_data: judge the rest against the best held-out prediction of any evaluated model and
            also evaluate every candidate effect together (group mode with ``noise_from_data``;
            :mod:`icgo.discrepancy.scatter`).
        prepared: the :class:`~icgo.discrepancy.model.Prepared` stations (its start ``theta0`` and the
            parameters the data give, never fitted).
        outliers: the robust outliers (:mod:`icgo.discrepancy.outliers`), not in ``valid``.
    """

    stations: Stations
    layout: Layout
    data: Data
    valid: np.ndarray
    az_ok: np.ndarray
    free_nuisance: np.ndarray
    group_free: np.ndarray
    train: np.ndarray
    test: np.ndarray
    valid_w: np.ndarray
    az_meas: np.ndarray
    floor: float
    n_res: int
    names: tuple
    config: WorkflowConfig
    scatter_from_data: bool = False
    prepared: Prepared | None = None
    outliers: tuple = ()


class SearchState(NamedTuple):
    """State of the greedy search after an evaluation.

    Attributes:
        model: effect names added so far.
        theta: (P,) the start of ``evaluation`` (the last added model's full fit).
        evaluation: the current model (row 0) and every candidate, fitted (numpy arrays).
        masks: (M, P) free parameters of each evaluated model.
        heldout: (M,) held-out chi2 per residual of each evaluated model.
        candidates: the candidates (excluding effects already in the model), best first.
        steps: the add steps so far. gaps: held-out gap per model (0 = reference).
        before: comparison of the reference model's full fit with the measurements.
        done: True when the search stops here (best does not qualify, or ``max_effects``).
        ctx: :class:`SearchContext`.
        converged: (M,) whether each evaluated model's fits converged (:data:`CONVERGED_GAP`, :data:`CONVERGED_FALL`).
        best: (held-out chi2 per residual, (n, 6) its held-out chi2 per component, model name) of the best
            converged model evaluated so far (``scatter_from_data``), or None.
    """

    model: tuple
    theta: np.ndarray
    evaluation: Evaluation
    masks: np.ndarray
    heldout: np.ndarray
    candidates: tuple
    steps: tuple
    gaps: tuple
    before: Comparison
    done: bool
    ctx: SearchContext
    converged: np.ndarray | None = None
    best: tuple | None = None


class Result(NamedTuple):
    """Outcome of :func:`run_workflow`.

    Attributes:
        steps: the add steps. kind: one of :data:`KINDS`. model: effect names of the final model.
        theta: (P,) final model's full fit (scaled). layout: the parameter layout.
        gaps: held-out gap per model (step 0 = reference model).
        compare_before, compare_after: reference / final model vs measurements
            (per-station arrays have the padded length; ``valid`` False on pads).
        pattern_before, pattern: their findings.
        field: fitted (total nT, dip deg, declination deg).
        heldout: final held-out chi2 per residual. noise_floor: its noise-only value.
        structure_remains: ``heldout > noise_tolerance * noise_floor``.
        final_candidates: the candidates of the last evaluation (where the search stopped).
        config: the options used. seconds: wall time, s (including compilation).
        noise_estimate: the sensors' scatter estimated from the shots (group mode with ``noise_from_data``;
            :mod:`icgo.discrepancy.scatter`), on which ``structure_remains`` is then based; or None.
        outliers: the robust outliers (:class:`~icgo.discrepancy.outliers.Outlier`), kept out of every fit
            and headline number.
    """

    steps: tuple
    kind: str
    model: tuple
    theta: np.ndarray
    layout: Layout
    gaps: tuple
    compare_before: Comparison
    compare_after: Comparison
    pattern_before: Pattern
    pattern: Pattern
    field: tuple
    heldout: float
    noise_floor: float
    structure_remains: bool
    final_candidates: tuple
    config: WorkflowConfig
    seconds: float
    noise_estimate: NoiseEstimate | None = None
    outliers: tuple = ()

    @property
    def named(self) -> list:
        """Effects named unambiguously (separable steps)."""
        return [s.name for s in self.steps if s.separable]


def _mask(ctx: SearchContext, effects) -> np.ndarray:
    """(P,) 0/1 free parameters of the model ``effects`` (+ the free nuisances); :data:`VOCABULARY`: every
    candidate effect."""
    m = ctx.free_nuisance.astype(float).copy()
    for e in (ctx.names if VOCABULARY in effects else effects):
        m[ctx.layout.slice(e)] = 1.0
    return np.where(ctx.prepared.given, 0.0, m)


def _starts(ctx: SearchContext, trial: list, theta) -> tuple:
    """(M, K, P), (M, P) starts of the evaluation: ``theta`` for every model, but for a candidate effect with a
    data-driven start (:attr:`icgo.physics.effects.Effect.start`, a nonlinear effect such as ``magnetic_body``)
    its parameters start where they best explain the field the current model leaves, found on each fold's
    training stations (and on all stations for the full fit) only."""
    M, K, P = len(trial), len(ctx.train), len(theta)
    s_fold = np.array(np.broadcast_to(np.asarray(theta), (M, K, P)))
    s_full = np.array(np.broadcast_to(np.asarray(theta), (M, P)))
    rows = [(m, c) for m, c in enumerate(trial) if c and c != VOCABULARY and _fx.EFFECTS[c].start is not None]
    if not rows:
        return s_fold, s_full
    pred = predict(jnp.asarray(theta), ctx.data, ctx.layout)
    resid = np.asarray(ctx.data.B - pred.B)
    C = np.asarray(tool_to_earth(pred.azimuth, pred.inclination, pred.toolface))
    scales = ctx.layout.scales()
    for m, c in rows:
        sl = ctx.layout.slice(c)
        fixed = ctx.prepared.fixed_params(c)
        start = _fx.EFFECTS[c].start
        for k in range(K):
            s_fold[m, k, sl] = start(resid, C, ctx.train[k], fixed) / scales[sl]
        s_full[m, sl] = start(resid, C, ctx.valid_w, fixed) / scales[sl]
    return s_fold, s_full


def _gap_of(ctx: SearchContext, ev: Evaluation, m: int) -> Gap:
    az_err = np.asarray(angle_diff(ctx.az_meas, ev.az_held[m]))
    return gap(ev.r_held[m], az_err, ctx.valid, ctx.az_ok, np.asarray(ctx.data.sig), ctx.floor)


def _evaluated(ctx: SearchContext, model: tuple, theta, steps: tuple, gaps: tuple, before,
               own: Evaluation | None = None, best: tuple | None = None) -> SearchState:
    """Evaluate the current model and every candidate from ``theta``; score and rank the candidates.

    ``own``: the current model's evaluation when it was a candidate of the step before (one row of
    each field, the model axis dropped). It replaces the model's refit here, so that one model has one
    score: the fixed-budget fold fits, started from another point, need not land on the same minimum
    (on a real device the same model scored 8528 as a candidate and 2134 refitted).
    """
    cfg, layout, valid = ctx.config, ctx.layout, ctx.valid
    # a fixed number of models (current + every candidate) so that shapes, hence the
    # compiled function, stay the same across steps; effects already in the model are
    # evaluated as duplicates of the current model and ignored.
    trial = [None] + [c if c not in model else "" for c in ctx.names] + (
        [VOCABULARY] if ctx.scatter_from_data else [])
    masks = np.stack([_mask(ctx, model + ((c,) if c else ())) for c in trial])
    starts = _starts(ctx, trial, theta)
    # models that fit an effect with a data-driven start (a nonlinear one, magnetic_body) may crawl along a valley
    started = np.array([any(_fx.EFFECTS[e].start is not None for e in model + ((c,) if c and c != VOCABULARY else ()))
                        for c in trial])
    previous = None
    for _ in range(MAX_ROUNDS):  # go on from the last fits until every fit has converged (a fixed budget)
        ev = evaluate_models(jnp.asarray(theta), jnp.asarray(masks), jnp.asarray(ctx.train), jnp.asarray(ctx.test),
                             jnp.asarray(ctx.valid_w), jnp.asarray(ctx.group_free), ctx.data, layout, cfg.n_iter,
                             starts=(jnp.asarray(starts[0]), jnp.asarray(starts[1])))
        ev = Evaluation(*(np.asarray(x) for x in ev))
        converged = ev.gap <= CONVERGED_GAP
        if previous is not None:
            converged |= (previous - ev.cost_total) <= np.where(
                started, np.maximum(CONVERGED_FALL * previous, CONVERGED_FALL_PER_RESIDUAL * len(ctx.train) * ctx.n_res),
                CONVERGED_FALL * previous)
        # row 0, the current model, is replaced by its own evaluation below; the whole vocabulary is used
        # only from the first evaluation
        pending = ~converged
        pending[0] &= own is None
        pending[-1] &= not (ctx.scatter_from_data and before is not None)
        if not pending.any():
            break
        starts, previous = (ev.theta_fold, ev.theta_full), ev.cost_total
    if own is not None:  # a winner of the step before, whose fits converged
        ev = Evaluation(*(np.concatenate([np.asarray(o)[None], x[1:]]) for o, x in zip(own, ev)))
        converged[0] = True
    g0 = _gap_of(ctx, ev, 0)
    if before is None:
        before = compare(ctx.stations, predict(jnp.asarray(ev.theta_full[0]), ctx.data, layout), valid)
        gaps = (g0,)
    chi2 = ev.chi2_held
    S = chi2[:, valid].mean(1) / 6.0
    bic = ev.cost_full + masks.sum(1) * np.log(max(ctx.n_res, 2))
    scales = layout.scales()
    cands = []
    for m, c in enumerate(trial):
        if not c or c == VOCABULARY:
            continue
        z = paired_z(chi2[0, valid], chi2[m, valid])
        g = _gap_of(ctx, ev, m)
        # an effect must also not raise the held-out field or azimuth residual: on real devices a chi2
        # win came with a worse field (676 -> 898 nT) and azimuth (1.48 -> 3.01 deg)
        az_ok = not (np.isfinite(g.azimuth_rms_deg) and np.isfinite(g0.azimuth_rms_deg)) or \
            g.azimuth_rms_deg <= (1.0 + GAP_TOLERANCE) * g0.azimuth_rms_deg
        mag_ok = g.mag_rms_nT <= (1.0 + GAP_TOLERANCE) * g0.mag_rms_nT
        ok = S[m] < (1.0 - cfg.min_rel_improvement) * S[0] and z >= cfg.min_z and mag_ok and az_ok and converged[m]
        sl = layout.slice(c)
        cands.append(Candidate(m, c, float(S[m]), float(bic[m]), z, bool(ok), ev.theta_full[m][sl] * scales[sl], g,
                               bool(converged[m])))
    cands.sort(key=lambda t: (not t.qualifies, t.heldout))  # every qualifying candidate before any other
    done = not cands or not cands[0].qualifies or (cfg.max_effects is not None and len(model) >= cfg.max_effects)
    if ctx.scatter_from_data:
        rows = [m for m in range(len(trial)) if converged[m] and (m > 0 or own is None)]
        m = min(rows, key=lambda k: S[k]) if rows else None
        if m is not None and (best is None or S[m] < best[0]):
            name = ("every candidate effect together" if trial[m] == VOCABULARY
                    else "+".join(model + ((trial[m],) if trial[m] else ())) or "reference")
            best = (float(S[m]), (ev.r_held[m] / np.asarray(ctx.data.sig)) ** 2, name)
    return SearchState(model, np.asarray(theta), ev, masks, S, tuple(cands), steps, gaps, before, bool(done), ctx,
                       converged, best)


def init(st: Stations, config: WorkflowConfig = WorkflowConfig(), key=None) -> SearchState:
    """Prepare the stations and evaluate the reference model and every candidate.

    Args:
        st: the measured stations. config: the options.
        key: PRNG key of the fold permutation (default ``PRNGKey(FOLD_SEED)``).
    Returns:
        The first :class:`SearchState` (no effect added yet).
    """
    key = jax.random.PRNGKey(FOLD_SEED) if key is None else key
    check_stations(st)
    names = _fx.names_for_rig(st.rig, config.candidates or _fx.ORDER)
    off = [n for n in (config.candidates or ()) if n not in names]
    if off:
        raise ValueError(f"candidates: {off} need data recorded on a rig ({', '.join(sorted({str(_fx.EFFECTS[n].rig) for n in off}))}: "
                         f"meta \"rig\"), and these stations declare {st.rig or 'none'}")
    st, real = pad_stations(st, config.bucket)
    prep = prepare(st, config.noise)
    layout = prep.layout
    # the screen needs a reference attitude: in group mode the scatter is estimated from the shots (scatter.py),
    # and a median absolute deviation over a device's 24 shots is too uncertain to call one of them an outlier
    out_mask, outliers = screen(prep, prep.valid & real, names, config.outlier_z if st.has_reference else np.inf)
    valid = prep.valid & real & ~out_mask
    train, test = folds(valid, config.k_folds, key, group=None if st.has_reference else st.group)
    group_free = np.zeros(layout.n_params)
    group_free[layout.n_effect + 3:] = 1.0
    ctx = SearchContext(
        stations=st, layout=layout, data=prep.data, valid=valid, az_ok=azimuth_scored(st.G, valid),
        free_nuisance=prep.free_nuisance, group_free=group_free, train=train, test=test,
        valid_w=valid.astype(float), az_meas=np.asarray(azimuth_from_gv(st.G, st.B)),
        floor=noise_floor(int(valid.sum()), layout.n_groups), n_res=6 * int(valid.sum()), names=names,
        config=config, scatter_from_data=bool(config.noise_from_data and not st.has_reference), prepared=prep,
        outliers=outliers)
    return _evaluated(ctx, (), prep.theta0, (), (), None)


def step(state: SearchState) -> SearchState:
    """Add the best candidate (with its evidence) and evaluate the next candidates.

    Returns ``state`` unchanged when ``state.done``.
    """
    if state.done:
        return state
    ctx, ev = state.ctx, state.evaluation
    cfg, layout, valid = ctx.config, ctx.layout, ctx.valid
    chi2 = ev.chi2_held
    best = state.candidates[0]
    runner = state.candidates[1] if len(state.candidates) > 1 else None
    if runner is not None:
        margin_z = paired_z(chi2[runner.index, valid], chi2[best.index, valid])
        dbic = float(runner.bic - best.bic)
    else:
        margin_z, dbic = float("inf"), float("inf")
    equivalent = tuple(r.name for r in state.candidates[1:]
                       if r.qualifies and paired_z(chi2[r.index, valid], chi2[best.index, valid]) < cfg.ambiguity_z)
    J = ev.J_full[best.index]  # all P columns (the Jacobian ignores the mask)
    context = _mask(ctx, state.model).astype(bool)
    degeneracies = identifiability(J, layout, best.name, context, cfg.separability_threshold)
    equivalences = []
    for e in equivalent:
        ctx2 = context.copy()
        ctx2[layout.slice(e)] = True
        equivalences += [d for d in identifiability(J, layout, best.name, ctx2, cfg.equivalence_threshold)
                         if e in d.sources]
    aliases = component_aliases(J, layout, best.name, context, state.model + equivalent, ctx.names,
                                cfg.separability_threshold, degeneracies)
    sl = layout.slice(best.name)
    se = standard_errors(J, state.masks[best.index], ev.cost_full[best.index], ctx.n_res)[sl] * layout.scales()[sl]
    gap_after = best.gap
    new = Step(
        name=best.name, params=tuple(float(x) for x in best.params), stderr=tuple(float(x) for x in se),
        units=_fx.EFFECTS[best.name].units, gap_before=state.gaps[-1], gap_after=gap_after,
        heldout_before=float(state.heldout[0]), heldout_after=best.heldout, z_improvement=best.z,
        runner_up=runner.name if runner else None, margin_z=margin_z, delta_bic=dbic,
        equivalent=equivalent, degeneracies=degeneracies, equivalences=tuple(equivalences),
        candidates=state.candidates, aliases=aliases)
    own = Evaluation(*(np.asarray(x)[best.index] for x in ev))
    return _evaluated(ctx, state.model + (best.name,), ev.theta_full[best.index], state.steps + (new,),
                      state.gaps + (gap_after,), state.before, own, state.best)


def component_aliases(J, layout, effect: str, context, exclude, names, threshold, known=()) -> tuple:
    """Components of ``effect`` that a component of an effect *not* named can mimic, for this station design.

    The effect as a whole may win clearly while one of its components (e.g. ``hard_iron[z]`` when the
    tool only rotates in place) is indistinguishable from a component of another vocabulary effect
    that the search did not name (``mag_scale[z]``): the named value then holds that other component
    too. For each vocabulary effect outside the model (and not ``exclude``d: the model and the
    candidates already reported as equivalent), the effect's directions that the context plus that
    effect can mimic (s < ``threshold``) and the context alone cannot (not in ``known``).

    Args:
        J: the noise-weighted Jacobian (all columns) or its triangular factor. layout: the model layout.
        effect: the named effect. context: (P,) bool free parameters of the model and nuisances.
        exclude: effect names not to test. names: the vocabulary searched. threshold: s limit.
        known: the effect's degeneracies against the context alone (:func:`identifiability`).
    Returns:
        tuple of :class:`~icgo.discrepancy.identifiability.Degeneracy` whose ``sources`` name the unnamed effect.
    """
    seen = {d.direction for d in known}
    out = []
    for e in names:
        if e == effect or e in exclude:
            continue
        ctx2 = np.asarray(context, bool).copy()
        ctx2[layout.slice(e)] = True
        out += [d for d in identifiability(J, layout, effect, ctx2, threshold)
                if e in d.sources and d.chi2_typical is None and d.direction not in seen]
    return tuple(out)


def finish(state: SearchState, seconds: float = float("nan")) -> Result:
    """The :class:`Result` of a finished search: the final model's own fit, comparison and kind."""
    ctx = state.ctx
    cfg, layout, valid = ctx.config, ctx.layout, ctx.valid
    theta = state.evaluation.theta_full[0]
    heldout = float(state.evaluation.chi2_held[0, valid].mean() / 6.0)
    after = compare(ctx.stations, predict(jnp.asarray(theta), ctx.data, layout), valid)
    est = None if state.best is None else estimate(state.best[1], valid, ctx.floor, cfg.noise, state.best[0],
                                                    state.best[2])
    scale = ctx.floor if est is None else max(ctx.floor, est.heldout)
    structure_remains = bool(heldout > cfg.noise_tolerance * scale)
    if any(not s.separable for s in state.steps):
        kind = "not_separable"
    elif structure_remains:
        kind = "unexplained"
    elif not state.model:
        kind = "no_missing_effect"
    else:
        kind = "explained"
    return Result(steps=state.steps, kind=kind, model=state.model, theta=theta, layout=layout, gaps=state.gaps,
                  compare_before=state.before, compare_after=after,
                  pattern_before=find_pattern(state.before, cfg.noise), pattern=find_pattern(after, cfg.noise),
                  field=fitted_field(theta, layout, ctx.data), heldout=heldout, noise_floor=ctx.floor,
                  structure_remains=structure_remains,
                  final_candidates=state.candidates, config=cfg, seconds=seconds, noise_estimate=est,
                  outliers=ctx.outliers)


def run_workflow(st: Stations, config: WorkflowConfig = WorkflowConfig(), key=None) -> Result:
    """name + add + show: the greedy forward search, from the reference model to the result.

    Args:
        st: the measured stations. config: the options (:class:`WorkflowConfig`).
        key: PRNG key of the fold permutation (default ``PRNGKey(FOLD_SEED)``).
    Returns:
        :class:`Result`; :func:`icgo.discrepancy.report.verdict` words it.
    """
    t0 = time.perf_counter()
    state = init(st, config, key)
    while not state.done:
        state = step(state)
    return finish(state, time.perf_counter() - t0)


def gap_table(res: Result):
    """The gap after each step as a pandas DataFrame (held-out stations)."""
    import pandas as pd

    rows = [dict(step=0, model="reference", **res.gaps[0]._asdict())]
    for i, s in enumerate(res.steps):
        rows.append(dict(step=i + 1, model="+ " + s.name + ("" if s.separable else f" (or {', '.join(s.equivalent)})"),
                         **s.gap_after._asdict()))
    return pd.DataFrame(rows)
