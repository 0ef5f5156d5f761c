"""The ICGO-RELM study's settings nodes, each with its defaults (the one place they are written: the paper's
protocol where it gives one): ``split``, ``msa``, ``model``, ``fitness``, ``budget`` of ``conf/config.yaml``, and
the search precision's default.

:class:`icgo.studies.icgo_relm.run_config.RunConfig` (the run door's typed config) holds them as nodes, Hydra
composes their defaults first (``config_defaults``), and :class:`icgo.studies.icgo_relm.config.StudyConfig` (the
library's flat config) takes its defaults from them. Nothing here imports JAX or the rest of the study.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

from icgo.core.settings import need

#: The search fitness's precision by default (:data:`icgo.studies.icgo_relm.config.PRECISIONS`).
PRECISION = "float32_features"


def existing_file(path, key: str) -> Path:
    """``path`` expanded, refused in one line unless it is an existing regular file."""
    p = Path(str(path)).expanduser()
    need(p.exists(), f"{key} {str(p)!r}: file not found")
    need(p.is_file(), f"{key} {str(p)!r}: not a regular file (a directory, pipe or device); give a CSV file")
    return p


@dataclasses.dataclass(frozen=True)
class TransferTarget:
    """``split.target`` of ``split=transfer``: how the second instrument differs
    (:class:`icgo.studies.common.splits.TransferDraw`, which checks the values; a null field keeps its default), or
    ``path``: a recording of the second instrument instead."""

    seed: int | None = None
    casing_distance_scale: float | None = None
    casing_strength_scale: float | None = None
    misalignment_deg: list | None = None
    path: str | None = None

    def __post_init__(self):
        if self.path is not None:
            existing_file(self.path, "split.target.path")

    def draw(self) -> dict:
        """The :class:`icgo.studies.common.splits.TransferDraw` arguments that are set."""
        return {f.name: getattr(self, f.name) for f in dataclasses.fields(self)
                if f.name != "path" and getattr(self, f.name) is not None}


@dataclasses.dataclass(frozen=True)
class SplitSettings:
    """``split``: the protocol and its repeats (checked by StudyConfig), and the transfer ``target``.

    The fold protocols' folds set the training rows: their ``train_fraction`` stays at this default.

    Attributes:
        protocol: ``random`` (paper: rows split 7:3), ``leave_azimuth_out``, ``leave_condition_out`` or ``transfer``.
        n_repeats: repeats (splits); the paper's Table 3 uses 10. seed: repeat k uses key fold_in(PRNGKey(seed), k).
        sigma_filter: n-sigma outlier rule applied once before splitting (paper: 3); null disables.
        train_fraction: training share of each split (paper 7:3: 0.7). target: the second instrument (transfer).
    """

    protocol: str = "random"
    n_repeats: int = 10
    seed: int = 0
    sigma_filter: float | None = 3.0
    train_fraction: float = 0.7
    target: TransferTarget | None = None

    def __post_init__(self):
        if self.target is not None:
            need(self.protocol == "transfer", f"split.target is read only by split.protocol=transfer (split=transfer); "
                                              f"here split.protocol={self.protocol!r}, so it would do nothing")
        else:
            need(self.protocol != "transfer",
                 "split.protocol=transfer needs split.target (use split=transfer, which defines it)")


@dataclasses.dataclass(frozen=True)
class MsaSettings:
    """``msa``: MSA (ICGO section 1.2, eqs. 2-7) before the RELM (values checked by StudyConfig).

    Attributes:
        model: ``biases`` (paper: three constant magnetometer biases), ``axial`` or ``biases_scales``.
        reference: ``station_mean`` (paper eqs. 3-4) or ``known`` (the metadata's total_field_nT and dip_deg).
        iterations: largest number of Levenberg-Marquardt steps (it stops once converged).
    """

    model: str = "biases"
    reference: str = "station_mean"
    iterations: int = 100


@dataclasses.dataclass(frozen=True)
class ModelSettings:
    """``model``: the RELM (values checked by StudyConfig); ``tune=true`` chooses ``hidden`` and ``lam`` itself,
    so they must stay at the study's defaults.

    Attributes:
        hidden: hidden units L (paper: not stated). lam: ridge lambda (paper: not stated).
        theta_bounds: [low, high] of every hidden weight and bias: the search box and plain RELM's uniform draw.
        features: ``raw`` (paper: the six raw sensor values) or ``msa`` (G and the MSA-corrected B).
        tune: plain RELM only (optimizer=none, fitness=validation or kfold): hidden and lam chosen on a grid by
            validation on the training rows (method relm-tuned).
    """

    hidden: int = 30
    lam: float = 1e-3
    theta_bounds: tuple = (-1.0, 1.0)
    features: str = "raw"
    tune: bool = False

    def __post_init__(self):
        if self.tune:
            for k in ("hidden", "lam"):
                default, v = getattr(ModelSettings, k), getattr(self, k)
                need(v == default, f"model.{k}={v} has no effect with model.tune=true (the tuning grid chooses it); "
                                   f"leave it at {default}")


@dataclasses.dataclass(frozen=True)
class FitnessSettings:
    """``fitness``: what the search minimises (values checked by StudyConfig).

    Attributes:
        mode: ``train`` (paper: the RELM's RMSE on the training rows), ``validation`` or ``kfold``.
        val_fraction: validation share of the training rows (mode validation). k_folds: folds (mode kfold).
    """

    mode: str = "train"
    val_fraction: float = 0.3
    k_folds: int = 5


@dataclasses.dataclass(frozen=True)
class BudgetSettings:
    """``budget``: population and iterations or evaluations (values checked by StudyConfig).

    Attributes:
        pop_size: population size (paper: 30). iterations: optimizer iterations (paper: 100); null with max_evals.
        max_evals: a fitness-evaluation budget instead of iterations (CGO spends 4 per seed per iteration).
    """

    pop_size: int = 30
    iterations: int | None = 100
    max_evals: int | None = None
