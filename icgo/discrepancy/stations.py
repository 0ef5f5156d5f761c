"""Measured stations: the workflow's input, its checks, and simulated stations.

:class:`Stations` holds host-side numpy arrays. They come from a data-contract
recording (:func:`stations_from_recording`) or from the simulator
(:func:`simulate`, :func:`hidden_stations`) on a physical test design
(:func:`design_attitudes`). Units: G in g, B in nT, angles in degrees.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from icgo.core.errors import DataError
from icgo.discrepancy.noise import NOISE, Noise
from icgo.physics import effects as _fx
from icgo.physics.frames import sensors_from_attitude, tool_to_earth


class Stations(NamedTuple):
    """Measured stations, host-side numpy (the workflow's input).

    Attributes:
        G: (n, 3) measured gravity, g. B: (n, 3) measured field, nT.
        azimuth: (n,) reference azimuth (deg, true north), or None.
        inclination: (n,) reference inclination (deg), or None.
        group: (n,) int group id (same true direction), or None.
        field: (total_field_nT, dip_deg, declination_deg) or None (unknown: nuisances).
        gravity_g: magnitude of gravity, g.
        extras: name -> (n,) float extra columns (temperature_c, time_s, ...), used
            only to describe unexplained structure.
        rig: the rig the data were recorded on (meta ``"rig"``): ``"turntable"`` when every station was
            turned about one fixed pivot (then position-dependent effects, ``magnetic_body``, are candidates),
            or None.
        lever_m: (3,) the sensor's lever arm from the pivot (m, tool frame; meta ``"sensor_lever_m"``) when
            given, else None (a turntable's lever arm is then fitted).
    """

    G: np.ndarray
    B: np.ndarray
    azimuth: np.ndarray | None = None
    inclination: np.ndarray | None = None
    group: np.ndarray | None = None
    field: tuple | None = None
    gravity_g: float = 1.0
    extras: dict | None = None
    rig: str | None = None
    lever_m: tuple | None = None

    @property
    def n(self) -> int:
        return int(self.G.shape[0])

    @property
    def has_reference(self) -> bool:
        return self.azimuth is not None and self.inclination is not None


#: Fewest stations the workflow accepts.
MIN_STATIONS = 6


def check_stations(st: Stations) -> None:
    """Raise ValueError (one line) for inputs the workflow cannot use."""
    G, B = np.asarray(st.G), np.asarray(st.B)
    if G.ndim != 2 or G.shape[1] != 3 or B.shape != G.shape:
        raise ValueError(f"stations: G and B must both be (n, 3), got {G.shape} and {B.shape}")
    if G.shape[0] < MIN_STATIONS:
        raise ValueError(f"stations: need at least {MIN_STATIONS} stations, got {G.shape[0]}")
    if not (np.all(np.isfinite(G)) and np.all(np.isfinite(B))):
        raise ValueError("stations: G or B contains NaN/inf")
    distinct = len(np.unique(np.hstack([G, B]), axis=0))
    if distinct < MIN_STATIONS:  # copies of one reading identify nothing (z-scores of 1e8 on a zero residual)
        raise ValueError(f"stations: {G.shape[0]} stations but only {distinct} distinct (G, B) reading(s); need at "
                         f"least {MIN_STATIONS} different readings (are the rows copies of one station?)")
    if not st.has_reference:
        if st.group is None:
            raise ValueError("stations: need a reference attitude (azimuth, inclination) or a group column")
        if st.azimuth is not None or st.inclination is not None:
            raise ValueError("stations: give both azimuth and inclination, or neither")
    else:
        for name, v in (("azimuth", st.azimuth), ("inclination", st.inclination)):
            v = np.asarray(v)
            if v.shape != (G.shape[0],) or not np.all(np.isfinite(v)):
                raise ValueError(f"stations: {name} must be (n,) finite, got shape {v.shape}")
    if st.group is not None and np.asarray(st.group).shape != (G.shape[0],):
        raise ValueError(f"stations: group must be (n,), got {np.asarray(st.group).shape}")
    if st.rig not in RIGS:
        raise ValueError(f"stations: rig {st.rig!r} is not known; choose one of {[r for r in RIGS if r]} or none")
    if st.lever_m is not None:
        lv = np.asarray(st.lever_m, float)
        if lv.shape != (3,) or not np.all(np.isfinite(lv)) or st.rig is None:
            raise ValueError(f"stations: sensor_lever_m {st.lever_m!r} must be 3 finite numbers (m, tool frame) "
                             "on a declared rig (rig: turntable)")


#: Rigs a recording may declare (meta ``"rig"``); None: none declared.
RIGS = (None, "turntable")


def rig_from_meta(meta, source: str = "meta") -> tuple:
    """(rig, lever_m) from a recording's metadata: ``"rig"`` and ``"sensor_lever_m"`` (m, tool frame).

    Raises:
        icgo.core.errors.DataError: one line naming the key when the rig is not known or the lever arm is not
        3 numbers.
    """
    rig = meta.get("rig")
    if rig not in RIGS:
        raise DataError(f"{source}: \"rig\": {rig!r} is not known; choose {[r for r in RIGS if r]} (every station "
                         "turned about one fixed pivot) or leave it out")
    lever = meta.get("sensor_lever_m")
    if lever is None:
        return rig, None
    try:
        lv = tuple(float(x) for x in lever)
    except (TypeError, ValueError):
        lv = ()
    if len(lv) != 3 or not np.all(np.isfinite(lv)) or rig is None:
        raise DataError(f"{source}: \"sensor_lever_m\": {lever!r} must be 3 finite numbers (m, tool frame, from the "
                         "pivot) with \"rig\": \"turntable\"")
    return rig, lv


def stations_from_recording(rec) -> Stations:
    """Convert an ``icgo.io.recording.Recording`` (data contract) into :class:`Stations`.

    Uses the reference attitude when present, else the ``group`` column; the
    field from the metadata (or the field model) when present, else None.
    """
    fr = rec.frame
    has_ref = all(c in fr.columns for c in ("azimuth_deg", "inclination_deg"))
    field = None
    if rec.field is not None:
        field = (float(rec.field.total_field_nT), float(rec.field.dip_deg), float(rec.field.declination_deg))
    extras = {}
    for c in ("temperature_c", "time_s"):
        if c in fr.columns:
            extras[c] = fr[c].to_numpy(np.float64)
    grav = float(rec.field.gravity_g) if rec.field is not None else float(rec.meta.get("gravity_g", 1.0))
    rig, lever = rig_from_meta(rec.meta, getattr(rec, "source", None) or "meta")
    return Stations(
        G=rec.G,
        B=rec.B,
        azimuth=fr["azimuth_deg"].to_numpy(np.float64) if has_ref else None,
        inclination=fr["inclination_deg"].to_numpy(np.float64) if has_ref else None,
        group=fr["group"].to_numpy(np.int64) if ("group" in fr.columns and not has_ref) else None,
        field=field,
        gravity_g=grav,
        extras=extras or None,
        rig=rig,
        lever_m=lever,
    )


def select_stations(st: Stations, idx) -> Stations:
    """The stations at integer indices ``idx`` (extra columns dropped)."""
    take = lambda a: None if a is None else np.asarray(a)[idx]
    return st._replace(G=st.G[idx], B=st.B[idx], azimuth=take(st.azimuth), inclination=take(st.inclination),
                       group=take(st.group), extras=None)


def pad_stations(st: Stations, bucket: int):
    """Pad to a multiple of ``bucket`` stations by repeating the last one.

    Returns (padded Stations, real mask (n_pad,)). The padded stations are marked
    invalid (weight 0) so they change nothing, but every data set of up to
    ``bucket`` stations reuses one compiled fit (no recompilation per size).
    ``bucket = 0`` pads nothing.
    """
    n = st.n
    n_pad = max(bucket, int(math.ceil(n / bucket)) * bucket) if bucket else n
    real = np.arange(n_pad) < n
    if n_pad == n:
        return st, real
    rep = lambda a: None if a is None else np.concatenate([np.asarray(a), np.repeat(np.asarray(a)[-1:], n_pad - n, 0)])
    extras = None if st.extras is None else {k: rep(v) for k, v in st.extras.items()}
    return st._replace(G=rep(st.G), B=rep(st.B), azimuth=rep(st.azimuth), inclination=rep(st.inclination),
                       group=rep(st.group), extras=extras), real


# ============================================================ simulation
DESIGNS = ("random", "single_inclination", "rotation", "turntable", "turntable_fixed_toolface")


def design_attitudes(key, n, design="random", inclination_deg=45.0, azimuth_deg=30.0):
    """Station attitudes (A, I, T) in deg, each (n,), for a physical test design.

    Designs:
        ``random``: A, T uniform in [0, 360), I uniform in [5, 175].
        ``single_inclination``: I fixed at ``inclination_deg``, A, T random.
        ``rotation``: A and I fixed, only T varies (a tool rolled in place).
        ``turntable``: the patent's 3-axis plan (CN1888384 step 2): I in
            {3,5,10,15,25,35,45,55,65,75}, A and T every 30 deg (1440 points);
            ``n`` of them drawn without replacement (all when n >= 1440).
        ``turntable_fixed_toolface``: the lookup-table plan the patent replaced:
            toolface fixed at 0, I on the same grid, A every 30 deg (120 points).
    """
    ka, ki, kt = jax.random.split(key, 3)
    u = lambda k, lo, hi: np.asarray(jax.random.uniform(k, (n,), minval=lo, maxval=hi))
    if design == "random":
        return u(ka, 0.0, 360.0), u(ki, 5.0, 175.0), u(kt, 0.0, 360.0)
    if design == "single_inclination":
        return u(ka, 0.0, 360.0), np.full(n, float(inclination_deg)), u(kt, 0.0, 360.0)
    if design == "rotation":
        return np.full(n, float(azimuth_deg)), np.full(n, float(inclination_deg)), u(kt, 0.0, 360.0)
    incs = np.array([3, 5, 10, 15, 25, 35, 45, 55, 65, 75], float)
    grid30 = np.arange(0.0, 360.0, 30.0)
    if design == "turntable":
        I, A, T = (g.ravel() for g in np.meshgrid(incs, grid30, grid30, indexing="ij"))
    elif design == "turntable_fixed_toolface":
        I, A = (g.ravel() for g in np.meshgrid(incs, grid30, indexing="ij"))
        T = np.zeros_like(I)
    else:
        raise ValueError(f"design {design!r}: choose one of {DESIGNS}")
    if n < I.size:
        idx = np.sort(np.asarray(jax.random.choice(ka, I.size, (n,), replace=False)))
        A, I, T = A[idx], I[idx], T[idx]
    return A, I, T


def random_effect_params(key, name, lo=0.5, hi=1.5) -> np.ndarray:
    """Random realistic parameters of one effect: each component ``typical * U(lo, hi) * (+-1)``.

    Returns:
        (n_params,) physical parameters in the effect's units.
    """
    e = _fx.EFFECTS[name]
    k1, k2 = jax.random.split(key)
    mag = jax.random.uniform(k1, (e.n_params,), minval=lo, maxval=hi)
    sign = jnp.where(jax.random.bernoulli(k2, 0.5, (e.n_params,)), 1.0, -1.0)
    return np.asarray(e.typical_each() * mag * sign)


def simulate(key, n=240, effect_params=None, design="random", field=(50_000.0, 60.0, 0.0),
             noise: Noise = NOISE, gravity_g=1.0, **design_kw) -> Stations:
    """Simulate measured stations with hidden effects and white noise.

    Args:
        key: PRNG key. n: number of stations.
        effect_params: name -> (n_params,) physical parameters of the injected effects.
        design: see :func:`design_attitudes` (``design_kw`` go there).
        field: (total nT, dip deg, declination deg) of the site.
        noise: white noise added to G (g) and B (nT), 1 sigma per axis.
        gravity_g: magnitude of gravity, g.
    Returns:
        Stations with the reference attitude (the truth) and the field.
    """
    kd, kg, kb = jax.random.split(key, 3)
    A, I, T = design_attitudes(kd, n, design, **design_kw)
    n = A.shape[0]
    s = sensors_from_attitude(A, I, T, field[0], field[1], field[2], gravity_g=gravity_g)
    C = tool_to_earth(A, I, T)
    G, B = _fx.apply_effects(dict(effect_params or {}), s.G, s.B, C)
    G = np.asarray(G) + noise.sigma_g * np.asarray(jax.random.normal(kg, (n, 3)))
    B = np.asarray(B) + noise.sigma_b_nT * np.asarray(jax.random.normal(kb, (n, 3)))
    return Stations(G=G, B=B, azimuth=np.asarray(A), inclination=np.asarray(I),
                    field=tuple(float(f) for f in field), gravity_g=float(gravity_g))


def hidden_stations(seed: int, names, n=240, design="random", noise: Noise = NOISE):
    """Stations with the named effects hidden at random realistic magnitudes.

    Effect ``i`` draws its parameters with key ``fold_in(PRNGKey(seed), 100 + i)``
    (:func:`random_effect_params`); the stations use ``fold_in(PRNGKey(seed), 1)``.

    Returns:
        (Stations, truth: name -> (n_params,) physical parameters).
    """
    _fx.check_names(list(names))
    key = jax.random.PRNGKey(seed)
    truth = {nm: random_effect_params(jax.random.fold_in(key, 100 + i), nm) for i, nm in enumerate(names)}
    return simulate(jax.random.fold_in(key, 1), n, truth, design=design, noise=noise), truth
