"""The patent's BP network (CN1888384) and the lookup-table baseline it replaced.

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

Lookup table (the prior art of the patent's background section): the azimuth
error tabulated over (inclination, azimuth) at the turntable points, toolface
ignored (its values averaged over the toolface positions at each node, or taken
at one fixed toolface), compensated by bilinear interpolation, periodic in
azimuth and clamped in inclination.

All angles are in degrees at every public function.
"""

from __future__ import annotations

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
        params: MLPParams at the epoch of best validation loss.
        y_scale: () degrees per output unit (360 for target=azimuth; the training
            std of the error for target=error).
        best_epoch: () int, epoch (0-based) of the best validation loss.
        best_val_loss: () best validation loss (scaled units).
        train_loss: (epochs,) training loss per epoch (mean over the epoch's batches).
        val_loss: (epochs,) validation loss per epoch (frozen after the stop).
        stopped_epoch: () int, epoch at which patience ran out (``epochs`` if never).
    """

    params: MLPParams
    y_scale: jnp.ndarray
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
        TrainResult with ``y_scale`` = 1 (callers rescale).
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
    return TrainResult(best_p, jnp.asarray(1.0, x.dtype), best_e, best_v, tl, vl, stopped_epoch)


@partial(jax.jit, static_argnames=("cfg",))
def _train_batch(keys, x, t, cfg):
    return jax.vmap(train_one, in_axes=(0, None, None, None))(keys, x, t, cfg)


def _check_angles(name, arrays, n=None):
    out = []
    for label, a in zip(name, arrays):
        a = np.asarray(a, dtype=np.float64)
        if a.ndim != 1:
            raise ValueError(f"nets: {label} must be 1-D, got shape {a.shape}")
        if n is not None and a.shape[0] != n:
            raise ValueError(f"nets: {label} has {a.shape[0]} rows, expected {n}")
        if not np.all(np.isfinite(a)):
            raise ValueError(f"nets: {label} contains NaN or inf")
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
    i, tf, ar, at = _check_angles(
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
    res = res._replace(y_scale=jnp.full(res.best_epoch.shape, y_scale))
    if single:
        res = jax.tree.map(lambda a: a[0], res)
    return res


@partial(jax.jit, static_argnames=("cfg",))
def _predict(params, y_scale, x, azimuth_raw_deg, cfg):
    def one(p, s):
        return output_to_azimuth(forward(p, x) * s, azimuth_raw_deg, cfg.target)
    if params.v.ndim == 1:
        return one(params, y_scale)
    return jax.vmap(one)(params, y_scale)


def predict(result: TrainResult, inclination_deg, toolface_deg, azimuth_raw_deg,
            cfg: NetConfig = NetConfig()):
    """Compensated azimuth (deg, [0, 360)) from trained network(s).

    Args:
        result: TrainResult from :func:`fit` (batched over seeds or not).
        inclination_deg, toolface_deg, azimuth_raw_deg: (N,) measured angles, deg.
        cfg: the NetConfig used for training.
    Returns:
        (S, N) or (N,) compensated azimuth.
    """
    cfg = check_config(cfg)
    i, tf, ar = _check_angles(("inclination_deg", "toolface_deg", "azimuth_raw_deg"),
                              (inclination_deg, toolface_deg, azimuth_raw_deg))
    x = encode_inputs(i, tf, ar, cfg.encoding)
    return _predict(result.params, result.y_scale, x, jnp.asarray(ar), cfg)


# ------------------------------------------------------------- lookup table
class LookupTable(NamedTuple):
    """Azimuth error tabulated over (inclination, azimuth) nodes.

    Attributes:
        inc_nodes: (Ni,) ascending inclinations, deg.
        az_nodes: (Na,) ascending azimuths in [0, 360), deg.
        error: (Ni, Na) azimuth error ``wrap180(A_true - A_raw)`` at the nodes, deg.
    """

    inc_nodes: jnp.ndarray
    az_nodes: jnp.ndarray
    error: jnp.ndarray


def _node_index(values, nodes, tol, label, periodic=False):
    d = values[:, None] - nodes[None, :]
    if periodic:
        d = (d + 180.0) % 360.0 - 180.0
    j = np.argmin(np.abs(d), axis=1)
    if np.any(np.abs(d[np.arange(len(values)), j]) > tol):
        k = int(np.argmax(np.abs(d[np.arange(len(values)), j]) > tol))
        raise ValueError(f"nets: {label} {values[k]:.6g} deg is not on a table node "
                         f"(tolerance {tol} deg)")
    return j


def lookup_table_fit(inclination_deg, azimuth_deg, error_deg, toolface_deg=None,
                     at_toolface_deg=None, inc_nodes=None, az_nodes=None, tol=1e-6):
    """Build the prior-art error table from turntable points (toolface ignored).

    Each table node is the mean of the wrapped errors of the points at that
    (inclination, azimuth), i.e. averaged over the toolface positions, or, when
    ``at_toolface_deg`` is given, the error of the points at that one toolface
    (the patent background's table built with the toolface held fixed).

    Args:
        inclination_deg, azimuth_deg: (N,) nominal (turntable) angles, deg; they
            must sit on the nodes.
        error_deg: (N,) azimuth error ``wrap180(A_true - A_raw)``, deg.
        toolface_deg: (N,) nominal toolface, needed with ``at_toolface_deg``.
        at_toolface_deg: None (average over toolface) or one toolface, deg.
        inc_nodes, az_nodes: node angles; default the distinct input values.
        tol: how far (deg) a point may sit from its node.
    Returns:
        LookupTable.
    Raises:
        ValueError: a node without points, a point off the nodes, NaN input.
    """
    i, a, e = _check_angles(("inclination_deg", "azimuth_deg", "error_deg"),
                            (inclination_deg, azimuth_deg, error_deg))
    a = np.mod(a, 360.0)
    e = (e + 180.0) % 360.0 - 180.0
    if at_toolface_deg is not None:
        if toolface_deg is None:
            raise ValueError("nets: at_toolface_deg needs toolface_deg")
        (tf,) = _check_angles(("toolface_deg",), (toolface_deg,), n=i.shape[0])
        keep = np.abs((tf - at_toolface_deg + 180.0) % 360.0 - 180.0) <= tol
        if not keep.any():
            raise ValueError(f"nets: no point at toolface {at_toolface_deg} deg")
        i, a, e = i[keep], a[keep], e[keep]
    inc_nodes = np.unique(np.round(i, 9)) if inc_nodes is None else np.sort(np.asarray(
        inc_nodes, np.float64))
    az_nodes = np.unique(np.round(a, 9) % 360.0) if az_nodes is None else np.sort(np.mod(
        np.asarray(az_nodes, np.float64), 360.0))
    if len(inc_nodes) < 1 or len(az_nodes) < 2:
        raise ValueError("nets: the table needs at least 1 inclination and 2 azimuth nodes")
    ji = _node_index(i, inc_nodes, tol, "inclination")
    ja = _node_index(a, az_nodes, tol, "azimuth", periodic=True)
    flat = ji * len(az_nodes) + ja
    size = len(inc_nodes) * len(az_nodes)
    count = np.bincount(flat, minlength=size)
    if np.any(count == 0):
        k = int(np.argmax(count == 0))
        raise ValueError(f"nets: table node (I={inc_nodes[k // len(az_nodes)]:g}, "
                         f"A={az_nodes[k % len(az_nodes)]:g}) has no turntable point")
    err = (np.bincount(flat, weights=e, minlength=size) / count).reshape(
        len(inc_nodes), len(az_nodes))
    return LookupTable(jnp.asarray(inc_nodes), jnp.asarray(az_nodes), jnp.asarray(err))


@jax.jit
def lookup_table_error(table: LookupTable, inclination_deg, azimuth_deg):
    """Bilinear interpolation of the table's error (deg) at (I, A_raw).

    Periodic in azimuth (the last node interpolates towards the first + 360);
    inclinations outside the nodes take the edge value (no extrapolation).

    Args:
        table: LookupTable.
        inclination_deg, azimuth_deg: (...) measured angles, deg.
    Returns:
        (...) interpolated azimuth error, deg.
    """
    inc = jnp.asarray(inclination_deg)
    az = wrap360(jnp.asarray(azimuth_deg))
    ni = table.inc_nodes
    na = table.az_nodes
    # inclination: clamp, then linear between bracketing nodes
    ic = jnp.clip(inc, ni[0], ni[-1])
    k = jnp.clip(jnp.searchsorted(ni, ic, side="right") - 1, 0, max(ni.shape[0] - 2, 0))
    k1 = jnp.minimum(k + 1, ni.shape[0] - 1)
    span = ni[k1] - ni[k]
    wi = jnp.where(span > 0, (ic - ni[k]) / jnp.where(span > 0, span, 1.0), 0.0)
    # azimuth: periodic, nodes extended by the first node + 360
    ext = jnp.concatenate([na, na[:1] + 360.0])
    azs = jnp.where(az < na[0], az + 360.0, az)
    m = jnp.clip(jnp.searchsorted(ext, azs, side="right") - 1, 0, na.shape[0] - 1)
    wa = (azs - ext[m]) / (ext[m + 1] - ext[m])
    m1 = (m + 1) % na.shape[0]
    e = table.error
    lo = (1 - wa) * e[k, m] + wa * e[k, m1]
    hi = (1 - wa) * e[k1, m] + wa * e[k1, m1]
    return (1 - wi) * lo + wi * hi


def lookup_table_predict(table: LookupTable, inclination_deg, azimuth_raw_deg):
    """Compensated azimuth (deg, [0, 360)): ``A_raw + table error at (I, A_raw)``."""
    (i, a) = _check_angles(("inclination_deg", "azimuth_raw_deg"),
                           (inclination_deg, azimuth_raw_deg))
    return wrap360(jnp.asarray(a) + lookup_table_error(table, jnp.asarray(i), jnp.asarray(a)))
