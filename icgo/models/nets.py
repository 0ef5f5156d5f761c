"""The patent's BP network (CN1888384): a trained network is a :class:`NetParams` pytree and :func:`predict`.

Network (patent eqs. 8-12): inputs (inclination I, toolface T, computed
azimuth A_raw), two sigmoid hidden layers of ``m1`` and ``m2`` units (patent:
4-8 each, 8 and 8 in its embodiment), one linear output neuron whose threshold
is zero (eq. 12: ``y = sum_i v_i O2_i``, no output bias)::

    O1 = f(W1 x + b1)        eqs. (8)-(9)
    O2 = f(W2 O1 + b2)       eqs. (10)-(11)   (eq. 10 prints x_j; the text says
                                               "the previous layer's output")
    y  = v . O2              eq. (12)

with ``f`` the logistic sigmoid. It is trained by back-propagation on the
per-pattern error ``e_p = 1/2 (t_p - y_p)^2`` (patent step 4), with optax
(plain gradient descent ``dW = -eta de_p/dW`` as in the patent, or Adam), over
mini-batches (``batch_size=1`` is the patent's pattern-by-pattern update),
with early stopping on a validation part of the training points. Training is a
``lax.scan`` over epochs inside ``jit(vmap(...))`` over seeds, so ten networks
train in one call that compiles once per configuration.

Targets:

* ``target="azimuth"`` (patent-faithful): the network outputs the true azimuth
  itself (scaled by 1/360). The true azimuth jumps 360 -> 0 at north, so a
  smooth network cannot follow it there: the error concentrates near north.
* ``target="error"``: the network outputs the wrapped azimuth error
  ``wrap180(A_true - A_raw)`` (scaled by its training standard deviation) and
  the compensated azimuth is ``wrap360(A_raw + y)``; no seam.

Input encodings (degrees in, dimensionless out):

* ``"scaled"`` (patent-faithful, default): the raw angles, affinely mapped to
  about [-1, 1]: ``(I/45 - 1, T/180 - 1, A/180 - 1)``. An affine map of the
  inputs is absorbed exactly by W1 and b1, so this is the patent's network on
  raw angles; the scaling only keeps the sigmoids out of saturation for
  gradient descent. Toolface and azimuth keep their 0/360 discontinuity.
* ``"sincos"``: ``(I/45 - 1, sin T, cos T, sin A, cos A)`` (5 inputs),
  continuous across 0/360.

The lookup table the network replaced is :mod:`icgo.models.lookup_table`.

All angles are in degrees at every public function.
"""

from __future__ import annotations

import dataclasses
from functools import partial
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import optax

from icgo.physics.frames import angle_diff, wrap360

TARGETS = ("azimuth", "error")
ENCODINGS = ("scaled", "sincos")
OPTIMIZERS = ("sgd", "adam")


# ------------------------------------------------------------------ config
class NetConfig(NamedTuple):
    """Static configuration of the network and its training (hashable).

    Attributes:
        hidden: units of hidden layers 1 and 2 (patent: 4-8 each, default 8, 8).
        encoding: input encoding, ``"scaled"`` (patent) or ``"sincos"``.
        target: ``"azimuth"`` (patent) or ``"error"``.
        optimizer: ``"sgd"`` (plain gradient descent, patent) or ``"adam"``.
        learning_rate: step size eta.
        epochs: maximum number of passes over the training part.
        batch_size: patterns per update; 1 is the patent's per-pattern BP.
        val_fraction: fraction of the training points held out for early stopping.
        patience: stop when the validation loss has not improved for this many epochs.
        init_scale: weights drawn N(0, init_scale^2 / fan_in) (LeCun-style).
    """

    hidden: tuple = (8, 8)
    encoding: str = "scaled"
    target: str = "error"
    optimizer: str = "adam"
    learning_rate: float = 0.01
    epochs: int = 2000
    batch_size: int = 32
    val_fraction: float = 0.2
    patience: int = 300
    init_scale: float = 1.0


def check_config(cfg: NetConfig) -> NetConfig:
    if not isinstance(cfg, NetConfig):
        raise ValueError(f"nets: config must be a NetConfig, got {type(cfg).__name__}")
    hidden = tuple(int(h) for h in cfg.hidden)
    if len(hidden) != 2 or min(hidden) < 1:
        raise ValueError(f"nets: hidden must be two positive layer sizes, got {cfg.hidden!r}")
    if cfg.encoding not in ENCODINGS:
        raise ValueError(f"nets: encoding must be one of {ENCODINGS}, got {cfg.encoding!r}")
    if cfg.target not in TARGETS:
        raise ValueError(f"nets: target must be one of {TARGETS}, got {cfg.target!r}")
    if cfg.optimizer not in OPTIMIZERS:
        raise ValueError(f"nets: optimizer must be one of {OPTIMIZERS}, got {cfg.optimizer!r}")
    if not cfg.learning_rate > 0:
        raise ValueError(f"nets: learning_rate must be > 0, got {cfg.learning_rate}")
    if int(cfg.epochs) < 1 or int(cfg.batch_size) < 1 or int(cfg.patience) < 1:
        raise ValueError("nets: epochs, batch_size and patience must be >= 1, got "
                         f"{cfg.epochs}, {cfg.batch_size}, {cfg.patience}")
    if not 0.0 < cfg.val_fraction < 1.0:
        raise ValueError(f"nets: val_fraction must be in (0, 1), got {cfg.val_fraction}")
    return cfg._replace(hidden=hidden, epochs=int(cfg.epochs), batch_size=int(cfg.batch_size),
                        patience=int(cfg.patience), learning_rate=float(cfg.learning_rate),
                        val_fraction=float(cfg.val_fraction), init_scale=float(cfg.init_scale))


# ------------------------------------------------------------------ network
class MLPParams(NamedTuple):
    """Weights of the 4-layer network (patent eqs. 8-12); a leading seed axis when batched.

    Attributes:
        w1: (m1, n) input -> hidden 1 weights ``w1_{i,j}``.
        b1: (m1,) hidden 1 thresholds ``theta1``.
        w2: (m2, m1) hidden 1 -> hidden 2 weights.
        b2: (m2,) hidden 2 thresholds ``theta2``.
        v: (m2,) hidden 2 -> output weights; the output threshold is zero (eq. 12).
    """

    w1: jnp.ndarray
    b1: jnp.ndarray
    w2: jnp.ndarray
    b2: jnp.ndarray
    v: jnp.ndarray


@partial(jax.tree_util.register_dataclass, data_fields=("w1", "b1", "w2", "b2", "v", "y_scale"),
         meta_fields=("encoding", "target"))
@dataclasses.dataclass(frozen=True)
class NetParams:
    """A trained network as :func:`predict` takes it: its weights, output scale and the two settings of its
    input and output (a pytree; a leading seed axis S on every array when batched).

    Attributes:
        w1, b1, w2, b2, v: the weights of :class:`MLPParams` (patent eqs. 8-12).
        y_scale: () degrees per output unit (360 for ``target="azimuth"``; the training std of the error
            for ``target="error"``).
        encoding: input encoding (:func:`encode_inputs`), static.
        target: ``"azimuth"`` or ``"error"`` (:func:`output_to_azimuth`), static.
    """

    w1: jnp.ndarray
    b1: jnp.ndarray
    w2: jnp.ndarray
    b2: jnp.ndarray
    v: jnp.ndarray
    y_scale: jnp.ndarray
    encoding: str = "scaled"
    target: str = "error"


def n_inputs(encoding: str) -> int:
    """Number of network inputs for an encoding (3 for ``scaled``, 5 for ``sincos``)."""
    if encoding not in ENCODINGS:
        raise ValueError(f"nets: encoding must be one of {ENCODINGS}, got {encoding!r}")
    return 3 if encoding == "scaled" else 5


def init_params(key, n_in: int, hidden=(8, 8), init_scale: float = 1.0, dtype=jnp.float64):
    """Random weights: N(0, init_scale^2/fan_in), thresholds zero.

    Args:
        key: PRNG key.
        n_in: number of inputs.
        hidden: (m1, m2).
        init_scale: weight scale.
    Returns:
        MLPParams.
    """
    m1, m2 = hidden
    k1, k2, k3 = jax.random.split(key, 3)
    return MLPParams(
        w1=init_scale * jax.random.normal(k1, (m1, n_in), dtype) / np.sqrt(n_in),
        b1=jnp.zeros((m1,), dtype),
        w2=init_scale * jax.random.normal(k2, (m2, m1), dtype) / np.sqrt(m1),
        b2=jnp.zeros((m2,), dtype),
        v=init_scale * jax.random.normal(k3, (m2,), dtype) / np.sqrt(m2),
    )


def forward(params: MLPParams, x):
    """Network output (patent eqs. 8-12).

    Args:
        params: MLPParams (unbatched).
        x: (..., n) encoded inputs.
    Returns:
        (...) output y (scaled target units).
    """
    o1 = jax.nn.sigmoid(x @ params.w1.T + params.b1)  # eqs. (8)-(9)
    o2 = jax.nn.sigmoid(o1 @ params.w2.T + params.b2)  # eqs. (10)-(11)
    return o2 @ params.v  # eq. (12): linear output, zero threshold


def pattern_loss(params: MLPParams, x, t):
    """Mean over patterns of the patent's ``e_p = 1/2 (t_p - y_p)^2``.

    Args:
        params: MLPParams.
        x: (P, n) encoded inputs.
        t: (P,) scaled targets.
    Returns:
        () loss.
    """
    r = t - forward(params, x)
    return 0.5 * jnp.mean(r * r)


# ------------------------------------------------------- encoding / targets
def encode_inputs(inclination_deg, toolface_deg, azimuth_deg, encoding: str = "scaled"):
    """Encode (I, T, A_raw) in degrees as network inputs.

    Args:
        inclination_deg, toolface_deg, azimuth_deg: (...) measured angles, deg.
        encoding: ``"scaled"`` -> (I/45-1, T/180-1, A/180-1) with T, A taken in
            [0, 360); ``"sincos"`` -> (I/45-1, sin T, cos T, sin A, cos A).
    Returns:
        (..., 3) or (..., 5) array.
    """
    i = jnp.asarray(inclination_deg)
    t = wrap360(jnp.asarray(toolface_deg, i.dtype))
    a = wrap360(jnp.asarray(azimuth_deg, i.dtype))
    i, t, a = jnp.broadcast_arrays(i, t, a)
    if encoding == "scaled":
        cols = [i / 45.0 - 1.0, t / 180.0 - 1.0, a / 180.0 - 1.0]
    elif encoding == "sincos":
        tr, ar = jnp.deg2rad(t), jnp.deg2rad(a)
        cols = [i / 45.0 - 1.0, jnp.sin(tr), jnp.cos(tr), jnp.sin(ar), jnp.cos(ar)]
    else:
        raise ValueError(f"nets: encoding must be one of {ENCODINGS}, got {encoding!r}")
    return jnp.stack(cols, -1)


def target_deg(azimuth_raw_deg, azimuth_true_deg, target: str):
    """Training target in degrees: the true azimuth in [0, 360), or the wrapped error.

    Args:
        azimuth_raw_deg: (...) computed azimuth, deg.
        azimuth_true_deg: (...) reference (turntable) azimuth, deg.
        target: ``"azimuth"`` or ``"error"``.
    Returns:
        (...) deg.
    """
    if target == "azimuth":
        return wrap360(jnp.asarray(azimuth_true_deg))
    if target == "error":
        return angle_diff(azimuth_true_deg, azimuth_raw_deg)
    raise ValueError(f"nets: target must be one of {TARGETS}, got {target!r}")


def output_to_azimuth(y_deg, azimuth_raw_deg, target: str):
    """Compensated azimuth (deg, [0, 360)) from the network output in degrees."""
    if target == "azimuth":
        return wrap360(y_deg)
    if target == "error":
        return wrap360(jnp.asarray(azimuth_raw_deg) + y_deg)
    raise ValueError(f"nets: target must be one of {TARGETS}, got {target!r}")


# ------------------------------------------------------------------ training
class TrainResult(NamedTuple):
    """Result of training (leading seed axis S when from :func:`fit`).

    Attributes:
        params: :class:`NetParams` at the epoch of best validation loss (what :func:`predict` takes).
        best_epoch: () int, epoch (0-based) of the best validation loss.
        best_val_loss: () best validation loss (scaled units).
        train_loss: (epochs,) training loss per epoch (mean over the epoch's batches).
        val_loss: (epochs,) validation loss per epoch (frozen after the stop).
        stopped_epoch: () int, epoch at which patience ran out (``epochs`` if never).
    """

    params: NetParams
    best_epoch: jnp.ndarray
    best_val_loss: jnp.ndarray
    train_loss: jnp.ndarray
    val_loss: jnp.ndarray
    stopped_epoch: jnp.ndarray


def _make_optimizer(cfg: NetConfig):
    if cfg.optimizer == "sgd":
        return optax.sgd(cfg.learning_rate)
    return optax.adam(cfg.learning_rate)


def split_sizes(n: int, cfg: NetConfig):
    """(n_val, n_train, n_batches) used by :func:`train_one` for ``n`` points."""
    n_val = max(1, int(round(cfg.val_fraction * n)))
    n_train = n - n_val
    n_batches = n_train // cfg.batch_size
    return n_val, n_train, n_batches


def train_one(key, x, t, cfg: NetConfig):
    """Train one network on encoded inputs and scaled targets (pure, jittable).

    The key is split into (init, split, shuffle) keys: the validation part is a
    random ``val_fraction`` of the points, the rest is reshuffled every epoch
    into ``n_train // batch_size`` mini-batches (the remainder sits out that
    epoch). Each batch takes one optimizer step on the mean of ``e_p``. After
    each epoch the validation loss is computed; the best parameters are kept,
    and once ``patience`` epochs pass without improvement the parameters freeze
    (the scan keeps its fixed length, so it stays vmappable).

    Args:
        key: PRNG key.
        x: (N, n) encoded inputs.
        t: (N,) scaled targets.
        cfg: NetConfig (static).
    Returns:
        TrainResult whose params have ``y_scale`` = 1 (callers rescale).
    """
    n = x.shape[0]
    n_val, n_train, n_batches = split_sizes(n, cfg)
    k_init, k_split, k_shuf = jax.random.split(key, 3)
    perm = jax.random.permutation(k_split, n)
    xv, tv = x[perm[:n_val]], t[perm[:n_val]]
    xt, tt = x[perm[n_val:]], t[perm[n_val:]]
    opt = _make_optimizer(cfg)
    params = init_params(k_init, x.shape[1], cfg.hidden, cfg.init_scale, x.dtype)
    grad_fn = jax.value_and_grad(pattern_loss)

    def batch_step(carry, idx):
        p, s = carry
        loss, g = grad_fn(p, xt[idx], tt[idx])
        upd, s = opt.update(g, s, p)
        return (optax.apply_updates(p, upd), s), loss

    def epoch(carry, inp):
        p, s, best_p, best_v, best_e, stopped = carry
        ep, k = inp
        order = jax.random.permutation(k, n_train)[: n_batches * cfg.batch_size]
        (p_new, s_new), losses = jax.lax.scan(
            batch_step, (p, s), order.reshape(n_batches, cfg.batch_size))
        # Frozen after the stop: keep the old parameters (select, vmap-safe).
        p_new = jax.tree.map(lambda a, b: jnp.where(stopped, a, b), p, p_new)
        s_new = jax.tree.map(lambda a, b: jnp.where(stopped, a, b), s, s_new)
        v = pattern_loss(p_new, xv, tv)
        better = (v < best_v) & ~stopped
        best_p = jax.tree.map(lambda a, b: jnp.where(better, a, b), p_new, best_p)
        best_v = jnp.where(better, v, best_v)
        best_e = jnp.where(better, ep, best_e)
        stopped = stopped | (ep - best_e >= cfg.patience)
        return (p_new, s_new, best_p, best_v, best_e, stopped), (jnp.mean(losses), v, stopped)

    v0 = pattern_loss(params, xv, tv)
    carry0 = (params, opt.init(params), params, v0, jnp.asarray(-1), jnp.asarray(False))
    keys = jax.random.split(k_shuf, cfg.epochs)
    (_, _, best_p, best_v, best_e, _), (tl, vl, st) = jax.lax.scan(
        epoch, carry0, (jnp.arange(cfg.epochs), keys))
    stopped_epoch = jnp.where(st.any(), jnp.argmax(st), cfg.epochs)
    params = NetParams(*best_p, y_scale=jnp.asarray(1.0, x.dtype), encoding=cfg.encoding, target=cfg.target)
    return TrainResult(params, best_e, best_v, tl, vl, stopped_epoch)


@partial(jax.jit, static_argnames=("cfg",))
def _train_batch(keys, x, t, cfg):
    return jax.vmap(train_one, in_axes=(0, None, None, None))(keys, x, t, cfg)


def check_angles(name, arrays, n=None, who: str = "nets"):
    """Each array of ``arrays`` as a 1-D float64 array of finite values, all of one length (``n`` if given);
    ValueError ``"<who>: <name> ..."`` naming the first that is not."""
    out = []
    for label, a in zip(name, arrays):
        a = np.asarray(a, dtype=np.float64)
        if a.ndim != 1:
            raise ValueError(f"{who}: {label} must be 1-D, got shape {a.shape}")
        if n is not None and a.shape[0] != n:
            raise ValueError(f"{who}: {label} has {a.shape[0]} rows, expected {n}")
        if not np.all(np.isfinite(a)):
            raise ValueError(f"{who}: {label} contains NaN or inf")
        n = a.shape[0]
        out.append(a)
    return out


def prepare(inclination_deg, toolface_deg, azimuth_raw_deg, azimuth_true_deg, cfg: NetConfig):
    """Validate the training points and return (x (N, n), target in degrees (N,)).

    Raises:
        ValueError: on NaN, mismatched lengths, inclination outside [0, 180],
            or too few points for the validation split and one batch.
    """
    cfg = check_config(cfg)
    i, tf, ar, at = check_angles(
        ("inclination_deg", "toolface_deg", "azimuth_raw_deg", "azimuth_true_deg"),
        (inclination_deg, toolface_deg, azimuth_raw_deg, azimuth_true_deg))
    if np.any((i < 0) | (i > 180)):
        raise ValueError("nets: inclination_deg must lie in [0, 180]")
    n_val, n_train, n_batches = split_sizes(i.shape[0], cfg)
    if n_batches < 1:
        raise ValueError(f"nets: {i.shape[0]} points leave {n_train} for training after the "
                         f"validation split, fewer than batch_size={cfg.batch_size}")
    x = encode_inputs(i, tf, ar, cfg.encoding)
    return x, target_deg(ar, at, cfg.target)


def fit(keys, inclination_deg, toolface_deg, azimuth_raw_deg, azimuth_true_deg,
        cfg: NetConfig = NetConfig()):
    """Train one network per key, all in one jitted, vmapped call.

    Args:
        keys: (S, 2) PRNG keys (e.g. ``jax.random.split(key, 10)``), or one key.
        inclination_deg, toolface_deg, azimuth_raw_deg: (N,) measured angles, deg.
        azimuth_true_deg: (N,) reference azimuth, deg.
        cfg: NetConfig.
    Returns:
        TrainResult with a leading seed axis S (none if one key was given).
    """
    cfg = check_config(cfg)
    x, tdeg = prepare(inclination_deg, toolface_deg, azimuth_raw_deg, azimuth_true_deg, cfg)
    if cfg.target == "azimuth":
        y_scale = 360.0
    else:
        y_scale = float(np.std(np.asarray(tdeg)))
        y_scale = y_scale if y_scale > 0 else 1.0
    keys = jnp.asarray(keys)
    single = keys.ndim == 1
    res = _train_batch(keys[None] if single else keys, x, tdeg / y_scale, cfg)
    res = res._replace(params=dataclasses.replace(res.params, y_scale=jnp.full(res.best_epoch.shape, y_scale)))
    if single:
        res = jax.tree.map(lambda a: a[0], res)
    return res


def predict(params: NetParams, angles):
    """Compensated azimuth (deg, [0, 360)) of one trained network: the whole forward pass, pure.

    Jit- and vmap-able; the study and the saved model call it as it is (:func:`predict_seeds`): the inputs
    are encoded op by op and the network runs as one compiled program (:func:`_network_output`), which
    fixes the rounding of every prediction (a jit around the whole may fuse the encoding and differ in the
    last bits).

    Args:
        params: :class:`NetParams` of one network (no seed axis).
        angles: (N, 3) measured inclination I, toolface T and computed azimuth A_raw, deg.
    Returns:
        (N,) compensated azimuth, deg.
    """
    x = encode_inputs(angles[:, 0], angles[:, 1], angles[:, 2], params.encoding)
    return _network_output(params, x, angles[:, 2])


@jax.jit
def _network_output(params: NetParams, x, azimuth_raw_deg):
    """Compensated azimuth from encoded inputs ``x`` (N, n): eqs. 8-12, scaled to deg, then the target's map."""
    return output_to_azimuth(forward(params, x) * params.y_scale, azimuth_raw_deg, params.target)


#: :func:`predict` of S networks (params with a leading seed axis) on the same points: (S, N) deg.
predict_seeds = jax.vmap(predict, in_axes=(0, None))
