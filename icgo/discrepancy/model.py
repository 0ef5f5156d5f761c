"""The forward model: parameter layout, device-side data, prediction, residuals.

Sign convention (the whole package): a **residual is measured - predicted**,
in physical units (g, nT, deg) or divided by the noise sigma ("noise units").
:func:`residuals`, the held-out residuals of :mod:`~icgo.discrepancy.fit`, and
:mod:`~icgo.discrepancy.compare` all use it.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from icgo.discrepancy.noise import NOISE, Noise, effective_sigma
from icgo.discrepancy.stations import Stations, check_stations
from icgo.physics import effects as _fx
from icgo.physics.frames import (
    azimuth_from_gv,
    field_vector_ned,
    inclination_from_g,
    tool_to_earth,
    toolface_from_g,
)

#: Scales of the reference-field nuisance parameters (total nT, dip deg, declination deg).
FIELD_SCALES = (300.0, 0.5, 0.5)
#: Scale of the per-group direction nuisances (deg).
GROUP_SCALE_DEG = 1.0
#: Stations whose inclination (from G) is within this of vertical are left out:
#: toolface, hence the predicted cross-axial field, is undefined there.
VERTICAL_EXCLUDE_DEG = 1.0
#: Component names of a 3-parameter effect whose components are not x, y, z.
_COMPONENTS = {"mag_cross_coupling": ("xy", "xz", "yz"), "external_field": ("N", "E", "D")}


class Layout(NamedTuple):
    """Where each parameter lives in the flat vector theta (static, hashable).

    theta = [effects in ORDER | field nuisances (3) | group directions (2 per group)];
    physical value = scale * theta (so theta = 1 is an effect's typical magnitude).
    """

    names: tuple
    starts: tuple
    sizes: tuple
    n_effect: int
    n_groups: int

    @property
    def n_params(self) -> int:
        return self.n_effect + 3 + 2 * self.n_groups

    def slice(self, name) -> slice:
        i = self.names.index(name)
        return slice(self.starts[i], self.starts[i] + self.sizes[i])

    def scales(self) -> np.ndarray:
        """(P,) physical value of theta = 1 for each parameter."""
        s = [_fx.EFFECTS[nm].typical_each() for nm in self.names]
        s.append(np.asarray(FIELD_SCALES, float))
        s.append(np.full(2 * self.n_groups, GROUP_SCALE_DEG))
        return np.concatenate(s)

    def labels(self) -> list[str]:
        """(P,) parameter labels, e.g. ``hard_iron[z]``, ``field[dip]``, ``group3[azimuth]``."""
        out = []
        for nm, k in zip(self.names, self.sizes):
            comp = _fx.EFFECTS[nm].labels or _COMPONENTS.get(nm, ("x", "y", "z") if k == 3 else tuple(range(k)))
            out += [f"{nm}[{comp[j]}]" for j in range(k)]
        out += ["field[total]", "field[dip]", "field[declination]"]
        for g in range(self.n_groups):
            out += [f"group{g}[azimuth]", f"group{g}[inclination]"]
        return out

    def sources(self) -> list[str]:
        """(P,) what each parameter belongs to: an effect name, ``field`` or ``group<g>``."""
        out = [nm for nm, k in zip(self.names, self.sizes) for _ in range(k)] + ["field"] * 3
        return out + [f"group{g}" for g in range(self.n_groups) for _ in range(2)]


def make_layout(n_groups=0, rig: str | None = None) -> Layout:
    """The layout of every registered effect meaningful on data of ``rig`` (in ``effects.ORDER``,
    :func:`icgo.physics.effects.names_for_rig`) plus nuisances."""
    names = _fx.names_for_rig(rig)
    sizes = tuple(_fx.EFFECTS[n].n_params for n in names)
    starts = tuple(int(x) for x in np.cumsum((0,) + sizes)[:-1])
    return Layout(names, starts, sizes, int(sum(sizes)), int(n_groups))


class Data(NamedTuple):
    """Device-side arrays for the fits (a pytree)."""

    G: jnp.ndarray        # (n, 3) g
    B: jnp.ndarray        # (n, 3) nT
    A0: jnp.ndarray       # (n,) reference azimuth, or (n_groups,) initial group azimuth, deg
    I0: jnp.ndarray       # (n,) or (n_groups,) deg
    group: jnp.ndarray    # (n,) int index into A0/I0 (identity in reference mode)
    field0: jnp.ndarray   # (3,) total nT, dip deg, declination deg
    gravity: jnp.ndarray  # () g
    sig: jnp.ndarray      # (n, 6) effective 1-sigma of the residual components (g, nT)
    scales: jnp.ndarray   # (P,)


class Prepared(NamedTuple):
    """What :func:`prepare` builds from Stations.

    Attributes:
        layout: the parameter layout. data: device-side arrays.
        valid: (n,) bool, stations used (not near vertical).
        free_nuisance: (P,) bool, the nuisance parameters that are fitted.
        theta0: (P,) the start: 0, but for the given parameters (a turntable's lever arm).
        given: (P,) bool, parameters given by the data, never fitted (a turntable's lever arm).
    """

    layout: Layout
    data: Data
    valid: np.ndarray
    free_nuisance: np.ndarray
    theta0: np.ndarray | None = None
    given: np.ndarray | None = None

    def fixed_params(self, name: str) -> np.ndarray:
        """(n_params,) the given physical parameters of effect ``name`` (NaN where fitted)."""
        sl = self.layout.slice(name)
        return np.where(self.given[sl], (self.theta0 * self.layout.scales())[sl], np.nan)


def _circmean_deg(a) -> float:
    r = np.deg2rad(a)
    return float(np.rad2deg(np.arctan2(np.mean(np.sin(r)), np.mean(np.cos(r)))))


def prepare(st: Stations, noise: Noise = NOISE) -> Prepared:
    """Build the layout, device data, valid mask and free-nuisance mask from Stations.

    Without a field in ``st`` the field nuisances start from the data (median |B|
    and median G-B angle) and are free; without a reference attitude each group's
    direction starts from the circular mean of the raw attitudes and is free.
    """
    check_stations(st)
    G = np.asarray(st.G, np.float64)
    B = np.asarray(st.B, np.float64)
    n = G.shape[0]
    inc_g = np.asarray(inclination_from_g(G))
    valid = (inc_g > VERTICAL_EXCLUDE_DEG) & (inc_g < 180.0 - VERTICAL_EXCLUDE_DEG)
    if st.field is not None:
        field0 = np.asarray(st.field, np.float64)
    else:
        cosang = np.sum(G * B, 1) / (np.linalg.norm(G, axis=1) * np.linalg.norm(B, axis=1))
        field0 = np.array([np.median(np.linalg.norm(B, axis=1)),
                           np.median(np.rad2deg(np.arcsin(np.clip(cosang, -1, 1)))), 0.0])
    if st.has_reference:
        layout = make_layout(0, st.rig)
        A0 = np.asarray(st.azimuth, np.float64)
        I0 = np.asarray(st.inclination, np.float64)
        gidx = np.arange(n)
    else:
        ug, gidx = np.unique(np.asarray(st.group), return_inverse=True)
        layout = make_layout(len(ug), st.rig)
        # raw magnetic azimuth (declination 0 in group mode: directions are relative)
        a_raw = np.asarray(azimuth_from_gv(G, B))
        A0 = np.array([_circmean_deg(a_raw[gidx == g]) for g in range(len(ug))])
        I0 = np.array([float(np.mean(inc_g[gidx == g])) for g in range(len(ug))])
        field0[2] = 0.0
    free_nuis = np.zeros(layout.n_params, bool)
    ne = layout.n_effect
    if st.field is None:
        free_nuis[ne:ne + 2] = True  # total, dip
        if st.has_reference:
            free_nuis[ne + 2] = True  # declination (true azimuth reference)
    free_nuis[ne + 3:] = True  # group directions
    data = Data(jnp.asarray(G), jnp.asarray(B), jnp.asarray(A0), jnp.asarray(I0), jnp.asarray(gidx),
                jnp.asarray(field0), jnp.asarray(float(st.gravity_g)),
                jnp.asarray(effective_sigma(G, B, noise)), jnp.asarray(layout.scales()))
    theta0, given = np.zeros(layout.n_params), np.zeros(layout.n_params, bool)
    if st.lever_m is not None and "magnetic_body" in layout.names:  # a turntable's given lever arm
        sl = layout.slice("magnetic_body")
        idx = np.arange(sl.start, sl.stop)[6:9]
        theta0[idx] = np.asarray(st.lever_m, float) / layout.scales()[idx]
        given[idx] = True
    return Prepared(layout, data, valid, free_nuis, theta0, given)


def station_fields(layout: Layout) -> tuple:
    """Names of the :class:`Data` fields with one entry per station (A0, I0 too in reference mode)."""
    return ("G", "B", "group", "sig") + (() if layout.n_groups else ("A0", "I0"))


def station_blocks(data: Data, layout: Layout, block: int, *extra):
    """The per-station arrays of ``data`` (and of ``extra``) as row blocks of ``block`` stations.

    The last block is padded by repeating the last station, so a pad's residuals are finite;
    ``real`` marks the stations that are not pads (weight them 0/1).

    Args:
        data: the device data (n stations). layout: its layout. block: stations per block.
        extra: further (n, ...) per-station arrays (e.g. station weights).
    Returns:
        (fields: name -> (nb, block, ...) for :func:`station_fields`, tuple of the extra arrays as
        (nb, block, ...), real (nb, block) 0/1), nb = ceil(n / block). ``data._replace(**fields_b)``
        with one block's fields is that block's Data for :func:`predict` and :func:`residuals`.
    """
    n = data.G.shape[0]
    nb = -(-n // block)
    pad = nb * block - n

    def split(a):
        a = jnp.asarray(a)
        return jnp.pad(a, [(0, pad)] + [(0, 0)] * (a.ndim - 1), mode="edge").reshape((nb, block) + a.shape[1:])

    fields = {k: split(getattr(data, k)) for k in station_fields(layout)}
    real = (jnp.arange(nb * block) < n).reshape(nb, block).astype(data.G.dtype)
    return fields, tuple(split(a) for a in extra), real


def effect_params(theta, layout: Layout, scales) -> dict:
    """name -> physical parameters from the flat scaled vector theta (P,)."""
    phys = theta * scales
    return {nm: phys[layout.slice(nm)] for nm in layout.names}


def fitted_field(theta, layout: Layout, data: Data) -> tuple:
    """(total nT, dip deg, declination deg) of the field for parameters ``theta``."""
    ne = layout.n_effect
    return tuple(float(x) for x in np.asarray(data.field0) + np.asarray(theta)[ne:ne + 3] * np.asarray(FIELD_SCALES))


def _g_effects() -> tuple:
    """Names of the registered effects that change G (probed with their typical magnitude)."""
    G = np.array([[0.3, -0.4, 0.8]])
    out = []
    for nm, e in _fx.EFFECTS.items():
        with jax.ensure_compile_time_eval():
            g, _ = e.apply(jnp.asarray(e.typical_each()), jnp.asarray(G), jnp.zeros((1, 3)), jnp.eye(3)[None])
        if not np.allclose(np.asarray(g), G, rtol=0, atol=0):
            out.append(nm)
    return tuple(out)


def remove_accel_effects(params, G_meas, n_fixed=3):
    """Invert the G part of the effects by fixed-point iteration: G_true with apply(G_true) = G_meas.

    Works for any registered effect that acts on G (contraction by |effect| ~ 1e-3 per pass).

    Args:
        params: name -> physical parameters (effects that do not act on G are ignored).
        G_meas: (..., 3) measured gravity, g.
    Returns:
        (..., 3) gravity with the accelerometer effects removed, g.
    """
    params = {k: v for k, v in params.items() if k in _g_effects()}
    if not params:
        return G_meas
    eye = jnp.broadcast_to(jnp.eye(3, dtype=G_meas.dtype), G_meas.shape[:-1] + (3, 3))
    zeroB = jnp.zeros_like(G_meas)
    g = G_meas
    for _ in range(n_fixed):
        gm, _ = _fx.apply_effects(params, g, zeroB, eye)
        g = g - (gm - G_meas)
    return g


class Prediction(NamedTuple):
    """What the model predicts at each station (a pytree).

    Attributes:
        G: (n, 3) predicted gravity, g. B: (n, 3) predicted field, nT.
        toolface, azimuth, inclination: (n,) the attitude the model assumes, deg.
    """

    G: jnp.ndarray
    B: jnp.ndarray
    toolface: jnp.ndarray
    azimuth: jnp.ndarray
    inclination: jnp.ndarray


def predict(theta, data: Data, layout: Layout) -> Prediction:
    """simulate: predicted (G, B) at each station for parameters ``theta`` (P,).

    Toolface comes from the *measured* G with the model's accelerometer effects
    removed (ENGINEERING-NOTES "Discrepancy fitting"), so it moves with theta.
    """
    params = effect_params(theta, layout, data.scales)
    ne = layout.n_effect
    fs = data.scales[ne:ne + 3]
    F = data.field0[0] + theta[ne] * fs[0]
    dip = data.field0[1] + theta[ne + 1] * fs[1]
    dec = data.field0[2] + theta[ne + 2] * fs[2]
    gdir = theta[ne + 3:].reshape(-1, 2) * GROUP_SCALE_DEG
    if layout.n_groups:
        A = (data.A0 + gdir[:, 0])[data.group]
        I = (data.I0 + gdir[:, 1])[data.group]
    else:
        A, I = data.A0, data.I0
    T = toolface_from_g(remove_accel_effects(params, data.G))
    C = tool_to_earth(A, I, T)
    g_ned = jnp.stack([0.0 * F, 0.0 * F, data.gravity + 0.0 * F])
    G0 = jnp.einsum("nji,j->ni", C, g_ned)
    B0 = jnp.einsum("nji,j->ni", C, field_vector_ned(F, dip, dec))
    Gp, Bp = _fx.apply_effects(params, G0, B0, C)
    return Prediction(Gp, Bp, T, A, I)


def physical_residuals(pred: Prediction, data: Data):
    """Residuals measured - predicted in physical units, (n, 6): gx, gy, gz (g), bx, by, bz (nT)."""
    return jnp.concatenate([data.G - pred.G, data.B - pred.B], 1)


def residuals(theta, data: Data, layout: Layout):
    """Noise-normalized residuals (measured - predicted) / sigma, (n, 6): G then B components."""
    return physical_residuals(predict(theta, data, layout), data) / data.sig
