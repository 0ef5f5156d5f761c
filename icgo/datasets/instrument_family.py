"""A family of simulated instruments: each data seed draws its own instrument of the ``lab_casing`` experiment.

By default every ``lab_casing`` world (:mod:`icgo.studies.icgo_relm.worlds.study`) is a noise draw of *one* instrument: the same
casing, sensor errors and noise level. With ``instrument="family"`` (``dataset.kwargs.instrument=family``;
:func:`icgo.datasets.casing_stations.lab_casing`) a data seed also draws, once, the instrument it measures with,
from the ranges of :data:`LAB_RANGES`, so a claim over worlds is a claim over a family of instruments:

* the casing's distance from the turntable axis (m), uniform in ``casing_distance_m``;
* its axial magnetization (A/m), log-uniform in ``casing_magnetization_A_m``;
* every sensor-error parameter of :data:`icgo.datasets.casing_stations.LAB_EFFECTS` (hard iron, cross coupling,
  scale, misalignment, accelerometer bias and scale) multiplied by its own factor, uniform in ``effects_factor``
  (the sign of each error kept);
* the noise level: both the accelerometer and the magnetometer noise multiplied by one factor, log-uniform in
  ``noise_factor``.

The draw comes from its own stream of the data seed (``SeedSequence(seed, spawn_key=(INSTRUMENT_STREAM,))``), apart
from the two the noise and spikes use (``SeedSequence(seed).spawn(2)``), so a world's instrument is a function of its
seed alone, and the noise of a world is the same stream whether or not its instrument is drawn.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

#: The spawn key of the instrument's stream of a data seed (the noise uses spawn keys 0 and 1).
INSTRUMENT_STREAM = 65_543


class InstrumentRanges(NamedTuple):
    """The ranges a family's instrument is drawn from (each a (low, high) pair).

    Attributes:
        casing_distance_m: the casing axis's distance from the turntable's vertical axis (m), uniform.
        casing_magnetization_A_m: the casing's axial magnetization (A/m), log-uniform.
        effects_factor: the factor on each sensor-error parameter (1), uniform.
        noise_factor: the factor on the accelerometer and magnetometer noise (1), log-uniform.
    """

    casing_distance_m: tuple = (0.75, 1.5)
    casing_magnetization_A_m: tuple = (4_000.0, 16_000.0)
    effects_factor: tuple = (0.5, 1.5)
    noise_factor: tuple = (0.5, 2.0)

    def check(self) -> None:
        """ValueError naming the first range that is not ``0 < low <= high``."""
        for name, (lo, hi) in self._asdict().items():
            if not (np.isfinite(lo) and np.isfinite(hi) and 0.0 < lo <= hi):
                raise ValueError(f"instrument family: {name} = ({lo}, {hi}) must satisfy 0 < low <= high")


#: The lab instrument's family: around the ICGO paper's lab (1 m, 8 kA/m, the tool's factory-calibrated errors and
#: its noise), within the casing sweeps' ranges (`results/sweep_casing.md`, `results/sweep_noise.md`).
LAB_RANGES = InstrumentRanges()


class InstrumentDraw(NamedTuple):
    """One instrument of a family: the keyword arguments of :func:`icgo.datasets.casing_stations.lab_casing` it
    sets, and the factors it was made with.

    Attributes:
        casing_distance_m, casing_magnetization_A_m: the casing (m, A/m).
        effects: name -> parameters, :data:`icgo.datasets.casing_stations.LAB_EFFECTS` times ``effects_factors``.
        effects_factors: name -> the factor on each parameter.
        noise_factor: the factor on both noise levels.
    """

    casing_distance_m: float
    casing_magnetization_A_m: float
    effects: dict
    effects_factors: dict
    noise_factor: float

    def as_dict(self) -> dict:
        """A JSON-able record (meta and truth of the data set)."""
        return {"casing_distance_m": self.casing_distance_m, "casing_magnetization_A_m": self.casing_magnetization_A_m,
                "effects": {k: list(v) for k, v in self.effects.items()},
                "effects_factors": {k: list(v) for k, v in self.effects_factors.items()},
                "noise_factor": self.noise_factor}


def instrument_rng(seed: int) -> np.random.Generator:
    """The instrument's stream of data seed ``seed`` (never one the noise draws from)."""
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"instrument family: seed {seed!r} must be a non-negative integer")
    return np.random.default_rng(np.random.SeedSequence(int(seed), spawn_key=(INSTRUMENT_STREAM,)))


def _log_uniform(rng, lo: float, hi: float) -> float:
    return float(np.exp(rng.uniform(np.log(lo), np.log(hi)))) if hi > lo else float(lo)


def draw(seed: int, base_effects: dict, ranges: InstrumentRanges = LAB_RANGES) -> InstrumentDraw:
    """The instrument of data seed ``seed``: one draw from ``ranges`` (the same for the same seed).

    Args:
        seed: the data seed (a world's).
        base_effects: name -> parameters scaled by the draw (``lab_casing``'s: :data:`icgo.datasets.casing_stations.
            LAB_EFFECTS` by default), in a fixed order (sorted names) so the draw does not depend on a dict's order.
        ranges: :class:`InstrumentRanges`.
    """
    ranges.check()
    rng = instrument_rng(seed)
    dist = float(rng.uniform(*ranges.casing_distance_m))
    mag = _log_uniform(rng, *ranges.casing_magnetization_A_m)
    factors, effects = {}, {}
    for name in sorted(base_effects):
        p = np.asarray(base_effects[name], float).ravel()
        f = rng.uniform(*ranges.effects_factor, size=p.size)
        factors[name] = tuple(float(x) for x in f)
        effects[name] = tuple(float(x) for x in p * f)
    noise = _log_uniform(rng, *ranges.noise_factor)
    return InstrumentDraw(dist, mag, effects, factors, noise)
