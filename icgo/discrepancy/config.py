"""Every option of the discrepancy workflow, with its one default.

``conf/discrepancy.yaml`` repeats these defaults for the command line;
``tests/test_discrepancy.py`` checks that the composed Hydra config equals
``WorkflowConfig()`` field by field, so the two cannot drift apart. Like every
study config, it is built from a plain mapping by
:func:`icgo.core.settings.config_from_mapping` (unknown keys refused) and written back
by :func:`icgo.core.settings.config_to_mapping` (tuples as lists).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence

from icgo.core.errors import SettingsError
from icgo.discrepancy.noise import NOISE, Noise
from icgo.physics import effects as _fx


@dataclasses.dataclass(frozen=True)
class WorkflowConfig:
    """Options of :func:`~icgo.discrepancy.search.run_workflow` (validated on construction:
    :class:`~icgo.core.errors.SettingsError`, one line per bad value).

    Attributes:
        k_folds: folds of the held-out score (each station held out once).
        max_effects: most effects the greedy search adds, or None (the default): no cap, the search
            stops by its held-out rule alone (each candidate is added at most once). A cap is a user's
            budget, not part of the rule: the default was 6 ("lab_casing names 6"), a number read off the
            data set it then reported; ``make discrepancy`` passes 4 for the 24-shot devices.
        min_rel_improvement: the best candidate must lower the held-out chi2 by
            at least this fraction (ENGINEERING-NOTES: 10 %) ...
        min_z: ... and its paired per-station improvement must have z >= this.
        ambiguity_z: another qualifying candidate within this paired z of the
            best makes the step "not separable".
        noise_tolerance: the final held-out chi2 per residual within this
            multiple of the noise floor counts as "the rest is noise".
        separability_threshold: s = sqrt(1 - rho^2) below this is a
            non-separable direction given the model (rho: canonical correlation).
        equivalence_threshold: s below this is reported as the direction that
            makes two equivalent candidates equivalent.
        n_iter: Levenberg-Marquardt iterations per fit.
        sigma_b_nT: magnetometer noise, nT (1 sigma per axis).
        sigma_g: accelerometer noise, g (1 sigma per axis).
        candidates: effect names the search considers; None = the whole vocabulary.
        bucket: stations are padded to a multiple of this so data sets of up to
            ``bucket`` stations share one compiled fit (0 = no padding).
        noise_from_data: in group mode (no reference attitude), estimate the sensors' scatter from the
            shots (:func:`icgo.discrepancy.scatter.estimate_noise`) and use it in place of ``sigma_b_nT`` /
            ``sigma_g`` (each kept as a floor) for the fits and the verdict; both are reported. No effect with
            a reference attitude.
        outlier_z: a station whose residual (after one fit with every linear-start candidate free) lies more
            than this many robust standard deviations (1.4826 x MAD) from its component's median is an
            outlier: named in the result, weight 0 in every fit and headline number
            (:mod:`icgo.discrepancy.outliers`); ``.inf``: no screen. Only with a reference attitude: in group
            mode the scatter is estimated from the shots, and a MAD over a device's 24 shots is too uncertain.
    """

    k_folds: int = 5
    max_effects: int | None = None
    min_rel_improvement: float = 0.10
    min_z: float = 3.0
    ambiguity_z: float = 2.0
    noise_tolerance: float = 1.5
    separability_threshold: float = 0.02
    equivalence_threshold: float = 0.2
    n_iter: int = 12
    sigma_b_nT: float = NOISE.sigma_b_nT
    sigma_g: float = NOISE.sigma_g
    candidates: tuple | None = None
    bucket: int = 120
    noise_from_data: bool = True
    outlier_z: float = 10.0

    def __post_init__(self):
        bad = []

        def integer(name, lo):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or v < lo:
                bad.append(f"{name}={v!r}: must be an integer >= {lo}")

        def real(name, lo, hi, lo_open=False, hi_open=False):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                bad.append(f"{name}={v!r}: must be a finite number")
                return
            if (v <= lo if lo_open else v < lo) or (v >= hi if hi_open else v > hi):
                rng = f"{'(' if lo_open else '['}{lo}, {hi}{')' if hi_open else ']'}"
                bad.append(f"{name}={v!r}: must lie in {rng}")
                return
            object.__setattr__(self, name, float(v))

        integer("k_folds", 2)
        if self.max_effects is not None:
            integer("max_effects", 0)
        real("min_rel_improvement", 0.0, 1.0, hi_open=True)
        real("min_z", 0.0, math.inf, hi_open=True)
        real("ambiguity_z", 0.0, math.inf, hi_open=True)
        real("noise_tolerance", 0.0, math.inf, lo_open=True, hi_open=True)
        real("separability_threshold", 0.0, 1.0, lo_open=True)
        real("equivalence_threshold", 0.0, 1.0, lo_open=True)
        integer("n_iter", 1)
        real("sigma_b_nT", 0.0, math.inf, lo_open=True, hi_open=True)
        real("sigma_g", 0.0, math.inf, lo_open=True, hi_open=True)
        integer("bucket", 0)
        v = self.outlier_z
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not v > 3.0:
            bad.append(f"outlier_z={v!r}: must be a number > 3 (.inf: no screen)")
        else:
            object.__setattr__(self, "outlier_z", float(v))
        if not isinstance(self.noise_from_data, bool):
            bad.append(f"noise_from_data={self.noise_from_data!r}: must be true or false")
        c = self.candidates
        if c is not None:
            if isinstance(c, str) or not isinstance(c, Sequence) or not all(isinstance(x, str) for x in c):
                bad.append(f"candidates={c!r}: must be None or a list of effect names")
            else:
                unknown = [x for x in c if x not in _fx.EFFECTS]
                if unknown or not c:
                    bad.append(f"candidates={list(c)!r}: unknown effect(s) {unknown}; choose from {list(_fx.ORDER)}"
                               if unknown else "candidates=[]: give at least one effect name, or None for all")
                else:
                    object.__setattr__(self, "candidates", tuple(c))
        if bad:
            raise SettingsError(f"WorkflowConfig: {b}" for b in bad)

    @property
    def noise(self) -> Noise:
        """The sensor noise (``sigma_b_nT``, ``sigma_g``)."""
        return Noise(self.sigma_b_nT, self.sigma_g)
