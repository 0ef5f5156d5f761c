"""A non-linear magnetometer correction: a RELM on the residual of a linear calibration.

After a linear calibration (12-parameter least squares + axis alignment) the
field ``b`` (unit sphere, tool frame) keeps a small non-linear error, mostly the
non-linear response of each sensor axis (Underwood 2021, the model behind the
peer's ``fit_non_linear``). We model it as

    b' = b + phi([u, 1] A) W,        u = b / |b|,

a regularized extreme learning machine: ``L`` hidden units with a fixed hidden
layer ``A`` ((4, L), last row the bias) and output weights ``W`` ((L, 3)). The
hidden layer is the per-axis Gaussian basis of Underwood's correction (three
units per tool axis, centres -1, 0, 1 of that axis' unit component, width 0.5:
:func:`axis_rbf_hidden`, ``phi(z) = exp(-z^2)``), with outputs on all three axes, so
a non-linearity of one axis may move the others after the linear matrix mixed them.

**Trained by group consistency and one field** (no reference attitude). ``W``
minimises, over the training shots (:func:`residuals`, all in deg),

* each rolled shot's pointing direction (:func:`icgo.models.cal_pointing.pointing_directions`)
  minus its group's mean direction (3 components, rad -> deg): the peer's metric;
* each shot's dip minus the mean dip of the training shots (one field);
* each shot's ``|b'| / mean|b'| - 1`` (rad -> deg; one field strength);
* plus ``lambda |W|^2`` (``lambda`` in deg^2 per unit weight^2),

a non-linear least-squares problem (the direction and dip are non-linear in
``W``), solved by :func:`icgo.maths.lsq.least_squares_fixed` from ``W = 0``.

**The ridge is chosen by leave-one-group-out on the training shots only**: each
group (every single shot, every roll) is left out in turn, ``W`` fitted on the
rest, and the same residuals evaluated on the left-out shots (the roll's spread
about its own mean; a shot's dip and modulus against the fitting shots' field).
The chosen ``lambda`` minimises their mean square over :data:`LAMBDAS`; all
``len(LAMBDAS) x (groups + 1)`` fits run as vmapped batches, one call per ridge (an interrupt is answered between them).

Why not a closed-form fit: ``W`` fitted to fixed targets (the field at the group's
mean azimuth and the median dip) with 12 random tanh units reaches 0.428 deg
in-sample on the bundled devices. Fixed targets cannot follow the direction the
correction moves, and that model cannot reach the peer's in-sample spread even
unregularized (0.30 deg); ``docs/calibrate.md`` has the measurements.
"""

from __future__ import annotations

from functools import partial
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from icgo.maths.lsq import least_squares_fixed
from icgo.models.cal_pointing import pointing_jnp
from icgo.models.calibration import normalized_dot
from icgo.physics.rolls import MIN_ROLLED_SHOTS

#: Candidate ridge parameters, deg^2 per unit weight^2 (leave-one-group-out picks one). The largest leaves
#: the linear calibration nearly unchanged (its correction is below 0.01 deg on the bundled devices).
LAMBDAS = tuple(float(v) for v in 10.0 ** np.arange(0.0, 7.01, 0.5))
#: Basis centres on each axis' unit component and their width (Underwood's 3-parameter basis, mag_cal ``RBF``).
CENTRES = (-1.0, 0.0, 1.0)
WIDTH = 0.5
#: Levenberg-Marquardt steps per fit. On the 9 bundled devices x 3 splits, 20, 40 and 80
#: steps choose the same ridges and give the same scores to 1e-15 deg (10 steps: 3e-9 deg); each step
#: costs the batch of 15 ridges x (groups + 1) fits, the largest part of a calibration's time.
N_STEPS = 20
#: Hidden activations, by the name saved in a model file: the Gaussian basis ``exp(-z^2)``.
_ACTIVATIONS = {"gauss": lambda z, xp: xp.exp(-z * z)}
ACTIVATIONS = tuple(_ACTIVATIONS)


class MagRELM(NamedTuple):
    """A fitted residual RELM.

    Attributes:
        hidden: (4, L) hidden layer (last row: bias). out: (L, 3) output weights (unit-sphere field).
        activation: one of :data:`ACTIVATIONS`. lam: the chosen ridge (deg^2).
        cv: (len(LAMBDAS),) leave-one-group-out mean square residual per ridge (deg^2).
    """

    hidden: np.ndarray
    out: np.ndarray
    activation: str
    lam: float
    cv: np.ndarray


def axis_rbf_hidden(centres=CENTRES, width: float = WIDTH) -> np.ndarray:
    """Hidden layer (4, 3 x len(centres)) of the per-axis Gaussian basis: unit j on axis a has
    ``z_j = (u_a - c_j) / width``."""
    cols = []
    for a in range(3):
        for c in centres:
            w = np.zeros(4)
            w[a], w[3] = 1.0 / width, -c / width
            cols.append(w)
    return np.stack(cols, 1)


def _act(z, activation: str, xp):
    return _ACTIVATIONS[activation](z, xp)


def features(b, hidden, activation: str = "gauss", xp=np):
    """Hidden layer ``phi([u, 1] A)`` of unit field directions ``u = b / |b|``, (N, L)."""
    u = b / xp.linalg.norm(b, axis=1, keepdims=True)
    return _act(xp.concatenate([u, xp.ones((u.shape[0], 1), u.dtype)], axis=1) @ hidden, activation, xp)


def apply(hidden, out, b, activation: str = "gauss") -> np.ndarray:
    """The corrected field ``b + phi([u, 1] A) W``, (N, 3), same units as ``b`` (unit sphere)."""
    if activation not in ACTIVATIONS:
        raise ValueError(f"mag_relm: activation must be one of {ACTIVATIONS}, got {activation!r}")
    b = np.asarray(b, np.float64)
    return b + features(b, np.asarray(hidden, np.float64), activation) @ np.asarray(out, np.float64)


def residuals(W, H, G, b, member, fit_w):
    """Per-shot residuals (N, 5), deg, of the corrected field ``b + H W`` (see the module doc).

    Args:
        W: (L, 3). H: (N, L) hidden layer of ``b``. G: (N, 3) calibrated gravity. b: (N, 3) unit-sphere field.
        member: (K, N) 0/1, shot n in rolled group k (each group mean is over all its shots).
        fit_w: (N,) 0/1, the shots whose field (mean dip, mean |b'|) is the reference.
    Returns:
        columns 0-2 pointing deviation from the group mean (0 for single shots), 3 dip deviation,
        4 relative modulus deviation, all deg.
    """
    bn = b + H @ W
    d = pointing_jnp(G, bn)
    count = member.sum(1, keepdims=True)
    mean = (member @ d) / jnp.maximum(count, 1.0)
    dev = (d - member.T @ mean) * member.sum(0)[:, None]  # 0 for single shots (in no rolled group)
    dip = jnp.arcsin(jnp.clip(normalized_dot(G, bn), -1.0, 1.0))
    mod = jnp.linalg.norm(bn, axis=1)
    nw = jnp.sum(fit_w)
    dip_dev = dip - jnp.sum(fit_w * dip) / nw
    mod_dev = mod / (jnp.sum(fit_w * mod) / nw) - 1.0
    return jnp.degrees(jnp.concatenate([dev, dip_dev[:, None], mod_dev[:, None]], 1))


def _fit_one(lam, fit_w, held_w, H, G, b, member, n_steps):
    """W (L, 3) minimising the fit shots' squared residuals + lam |W|^2, and the held shots' sum of squares."""
    L = H.shape[1]

    def res(x, _):
        r = residuals(x.reshape(L, 3), H, G, b, member, fit_w) * fit_w[:, None]
        return jnp.concatenate([r.ravel(), jnp.sqrt(lam) * x])

    x = least_squares_fixed(res, jnp.zeros(3 * L, b.dtype), n_steps=n_steps).x
    held = residuals(x.reshape(L, 3), H, G, b, member, fit_w) * held_w[:, None]
    return x.reshape(L, 3), jnp.sum(held ** 2)


@partial(jax.jit, static_argnames="n_steps")
def _fit_batch(lambdas, fit_w, held_w, H, G, b, member, n_steps):
    """:func:`_fit_one` for every ridge (lambdas (R,)) x fold (fit_w, held_w (F, N)): W (R, F, L, 3), held (R, F)."""
    one = partial(_fit_one, n_steps=n_steps)
    over_folds = jax.vmap(one, in_axes=(None, 0, 0, None, None, None, None))
    return jax.vmap(over_folds, in_axes=(0, None, None, None, None, None, None))(lambdas, fit_w, held_w, H, G, b,
                                                                                member)


def fit(G, b, groups, hidden=None, lambdas=LAMBDAS, train=None) -> MagRELM:
    """Fit the residual RELM on linearly calibrated shots; ``lambda`` by leave-one-group-out.

    Args:
        G: (N, 3) calibrated gravity (tool frame, any scale). b: (N, 3) linearly calibrated field (unit sphere).
        groups: (N,) group ids; groups of at least :data:`icgo.physics.rolls.MIN_ROLLED_SHOTS` shots are rolls.
        hidden: (4, L) hidden layer (default :func:`axis_rbf_hidden`). lambdas: candidate ridges (deg^2).
        train: (N,) bool, the shots to fit on (default all); the others get zero weight, so that every
            split of one recording has the same shapes (one compilation).
    Returns:
        :class:`MagRELM`.
    Raises:
        ValueError: fewer than two training groups (nothing to leave out).
    """
    G = jnp.asarray(G, jnp.float64)
    b = jnp.asarray(b, jnp.float64)
    groups = np.asarray(groups)
    train = np.ones(len(groups), bool) if train is None else np.asarray(train, bool)
    ids = np.unique(groups)
    if len(np.unique(groups[train])) < 2:
        raise ValueError(f"mag_relm.fit: leave-one-group-out needs at least 2 groups, got "
                         f"{len(np.unique(groups[train]))}")
    hidden = axis_rbf_hidden() if hidden is None else np.asarray(hidden, np.float64)
    H = features(b, jnp.asarray(hidden), "gauss", jnp)
    rolled = [g for g in ids if (groups == g).sum() >= MIN_ROLLED_SHOTS]
    member = jnp.asarray(np.array([train & (groups == g) for g in rolled], np.float64).reshape(len(rolled),
                                                                                              len(groups)))
    # fold 0 fits every training shot (the final model); fold k >= 1 leaves group ids[k-1] out and scores it
    fit_w = np.array([train] + [train & (groups != g) for g in ids], np.float64)
    held_w = np.array([np.zeros(len(groups))] + [train & (groups == g) for g in ids], np.float64)
    # one call per ridge (all folds vmapped): each returns within a bounded time, so Ctrl-C / SIGTERM are
    # answered between them, and a recording compiles once (the shape does not depend on the ridge)
    parts = [_fit_batch(jnp.asarray([lam], jnp.float64), jnp.asarray(fit_w), jnp.asarray(held_w), H, G, b, member,
                        n_steps=N_STEPS) for lam in lambdas]
    W, held = (jnp.concatenate([p[i] for p in parts]) for i in (0, 1))
    cv = np.asarray(held[:, 1:].sum(1)) / int(train.sum())
    if not np.all(np.isfinite(cv)):
        raise ValueError("mag_relm.fit: a leave-one-group-out fit is not finite (shots with gravity along the field?)")
    k = int(np.argmin(cv))
    return MagRELM(hidden, np.asarray(W[k, 0]), "gauss", float(lambdas[k]), cv)
