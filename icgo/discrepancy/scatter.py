"""The sensors' scatter estimated from the shots themselves (group mode), beside the assumed noise.

The workflow weighs residuals by a noise model and judged "the rest is noise" against it. The default
(:data:`icgo.discrepancy.noise.NOISE`, 15 nT and 0.3 mg per axis) is an industrial grade; consumer sensors
scatter tens to hundreds of times more, and against that assumption every real recording ended
"unexplained". Without a reference attitude (group mode) the shots carry their own scale: shots of one
group share one direction, and every model the search evaluates is scored on held-out shots. The
estimate is the **best held-out prediction of any model the search evaluated** (every candidate at every
step, converged; and the whole vocabulary at once, :data:`VOCABULARY`, evaluated in the first step):

* ``heldout``: that model's held-out chi2 per residual (in units of the assumed noise). The verdict's
  "structure remains" compares the final model's held-out chi2 with ``noise_tolerance`` x
  ``max(noise floor, heldout)``: the final model is "explained" when no model of the vocabulary predicts
  the held-out shots markedly better.
* per sensor, ``sigma = assumed x sqrt(mean held-out chi2 of that sensor's components / noise floor)``:
  the scatter per axis that would give that held-out residual if it were noise (the toolface error the
  accelerometer's scatter makes in the field's cross-axial components counts with the field, as in
  :func:`icgo.discrepancy.noise.effective_sigma`).

So the estimate is what no model of the vocabulary predicts on shots it did not see: sensor noise plus any
structure outside the vocabulary (an accelerometer cross-axis error, a non-linearity, a position-dependent
field), or inside it but beyond what 24 shots can pin down. The report puts it beside the assumption, so
that a scatter far above a sensor's datasheet noise is seen and read as such. The fits keep the assumed
noise as their weights: the ratio of the two sensors' weights is the one the effects' typical magnitudes
were written for, and the search's decisions (relative improvement, paired z) do not depend on a common
scale.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from icgo.discrepancy.noise import Noise

#: Name of the whole-vocabulary model in the search's evaluations.
VOCABULARY = "*vocabulary*"


class NoiseEstimate(NamedTuple):
    """The scatter of the held-out shots about the best model the search evaluated.

    Attributes:
        noise: the estimate (``sigma_b_nT`` nT, ``sigma_g`` g per axis). assumed: the noise the fits weigh with.
        heldout: that model's held-out chi2 per residual (assumed-noise units). model: its effects.
    """

    noise: Noise
    assumed: Noise
    heldout: float
    model: str

    @property
    def ratios(self) -> tuple[float, float]:
        """(magnetometer, accelerometer) estimate / assumption."""
        return self.noise.sigma_b_nT / self.assumed.sigma_b_nT, self.noise.sigma_g / self.assumed.sigma_g

    def sentence(self) -> str:
        """The report's line: assumed and estimated side by side."""
        rb, rg = self.ratios
        return (f"noise assumed {self.assumed.sigma_b_nT:g} nT and {self.assumed.sigma_g * 1e3:g} mg per axis; "
                f"estimated from the shots {self.noise.sigma_b_nT:.4g} nT and {self.noise.sigma_g * 1e3:.3g} mg "
                f"({rb:.0f}x and {rg:.0f}x; the best held-out prediction of any model evaluated, {self.model}, "
                f"chi2/residual {self.heldout:.4g})")


def estimate(chi2_components, valid, floor: float, assumed: Noise, heldout: float, model: str) -> NoiseEstimate:
    """The estimate from the best model's held-out residuals.

    Args:
        chi2_components: (n, 6) its held-out residuals squared in noise units (gx, gy, gz, bx, by, bz).
        valid: (n,) bool, the stations used. floor: the noise-only chi2 per residual.
        assumed: the noise of those units. heldout: its held-out chi2 per residual. model: its effects.
    """
    c = np.asarray(chi2_components, np.float64)[np.asarray(valid, bool)]
    rg = float(np.sqrt(np.mean(c[:, :3]) / floor))
    rb = float(np.sqrt(np.mean(c[:, 3:]) / floor))
    return NoiseEstimate(Noise(assumed.sigma_b_nT * rb, assumed.sigma_g * rg), assumed, float(heldout), str(model))
