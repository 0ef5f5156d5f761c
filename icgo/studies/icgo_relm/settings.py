"""The ICGO-RELM study's settings nodes, each with its defaults and its checks (the one place either is written;
the defaults are the paper's protocol where it gives one): ``split``, ``msa``, ``model``, ``fitness``, ``budget`` of
``conf/config.yaml``, and the search precision's default.

:class:`icgo.studies.icgo_relm.config.StudyConfig` (the library's config) and
:class:`icgo.studies.icgo_relm.run_config.RunConfig` (the run door's) hold the same nodes under the same names, so a
value has one key everywhere (``model.lam``) and is checked once, where it enters: at the node's construction, with
that key in the one-line error. Hydra composes their defaults first (``config_defaults``). Nothing here imports JAX
at module import; a node's check imports the module that lists the values it accepts.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

from icgo.core.settings import is_int, is_real, need

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
    """``split``: the protocol and its repeats, and the run door's transfer ``target`` (read when the data are loaded:
    :class:`icgo.studies.icgo_relm.run_config.RunConfig` checks it against the protocol).

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
        from icgo.studies.common.splits import FOLD_PROTOCOLS, PROTOCOLS

        need(self.protocol in PROTOCOLS, "split.protocol", f"must be one of {list(PROTOCOLS)}, got {self.protocol!r}")
        need(is_int(self.n_repeats) and self.n_repeats >= 1, "split.n_repeats",
             f"must be an integer >= 1, got {self.n_repeats!r} (repeats)")
        need(is_int(self.seed) and self.seed >= 0, "split.seed", f"must be an integer >= 0, got {self.seed!r}")
        need(is_real(self.train_fraction) and 0.0 < self.train_fraction < 1.0, "split.train_fraction",
             f"must be in (0, 1), got {self.train_fraction!r}")
        default = SplitSettings.train_fraction
        need(self.protocol not in FOLD_PROTOCOLS or self.train_fraction == default, "split.train_fraction",
             f"has no effect under protocol {self.protocol!r} (its folds set the training rows); leave it at "
             f"{default}, got {self.train_fraction!r}")
        need(self.sigma_filter is None or (is_real(self.sigma_filter) and self.sigma_filter > 0), "split.sigma_filter",
             f"must be > 0 or null, got {self.sigma_filter!r}")


@dataclasses.dataclass(frozen=True)
class MsaSettings:
    """``msa``: MSA (ICGO section 1.2, eqs. 2-7) before the RELM.

    Attributes:
        model: ``biases`` (paper: three constant magnetometer biases), ``axial`` or ``biases_scales``.
        reference: ``station_mean`` (paper eqs. 3-4) or ``known`` (the metadata's total_field_nT and dip_deg).
        iterations: largest number of Levenberg-Marquardt steps (it stops once converged).
    """

    model: str = "biases"
    reference: str = "station_mean"
    iterations: int = 100

    def __post_init__(self):
        from icgo.models.msa import MODELS

        need(isinstance(self.model, str) and self.model in MODELS, "msa.model",
             f"must be one of {list(MODELS)}, got {self.model!r}")
        need(self.reference in ("station_mean", "known"), "msa.reference",
             f"must be station_mean or known, got {self.reference!r}")
        need(is_int(self.iterations) and self.iterations >= 1, "msa.iterations",
             f"must be an integer >= 1, got {self.iterations!r}")


@dataclasses.dataclass(frozen=True)
class ModelSettings:
    """``model``: the RELM; ``tune=true`` chooses ``hidden`` and ``lam`` itself (the study's config then carries the
    chosen cell; the run door refuses them typed beside ``tune=true``).

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
        from icgo.models.relm import MAX_LAM

        if isinstance(self.theta_bounds, list):  # Hydra and JSON give lists
            object.__setattr__(self, "theta_bounds", tuple(self.theta_bounds))
        need(self.features in ("raw", "msa"), "model.features", f"must be 'raw' or 'msa', got {self.features!r}")
        need(is_int(self.hidden) and self.hidden >= 1, "model.hidden",
             f"must be an integer >= 1, got {self.hidden!r}")
        need(is_real(self.lam) and 0 < self.lam <= MAX_LAM, "model.lam",
             f"must be a number > 0 and at most {MAX_LAM:g}, got {self.lam!r} (the ridge lambda is absolute: far "
             f"above that the RELM's output weights vanish and it returns MSA's azimuth unchanged, "
             f"docs/reliability.md)")
        tb = self.theta_bounds
        need(isinstance(tb, tuple) and len(tb) == 2 and all(is_real(x) for x in tb) and tb[0] < tb[1],
             "model.theta_bounds", f"must be [low, high] with low < high, got {tb!r}")
        need(isinstance(self.tune, bool), "model.tune", f"must be true or false, got {self.tune!r}")


@dataclasses.dataclass(frozen=True)
class FitnessSettings:
    """``fitness``: what the search minimises.

    Attributes:
        mode: ``train`` (paper: the RELM's RMSE on the training rows), ``validation`` or ``kfold``.
        val_fraction: validation share of the training rows (mode validation). k_folds: folds (mode kfold).
    """

    mode: str = "train"
    val_fraction: float = 0.3
    k_folds: int = 5

    def __post_init__(self):
        from icgo.models.relm import FITNESS_MODES

        need(self.mode in FITNESS_MODES, "fitness.mode", f"must be one of {list(FITNESS_MODES)}, got {self.mode!r}")
        need(is_real(self.val_fraction) and 0.0 < self.val_fraction < 1.0, "fitness.val_fraction",
             f"must be in (0, 1), got {self.val_fraction!r}")
        need(is_int(self.k_folds) and self.k_folds >= 2, "fitness.k_folds",
             f"must be an integer >= 2, got {self.k_folds!r}")


@dataclasses.dataclass(frozen=True)
class BudgetSettings:
    """``budget``: population and iterations or evaluations of the search (plain RELM has none and reads none).

    Attributes:
        pop_size: population size (paper: 30). iterations: optimizer iterations (paper: 100); null with max_evals.
        max_evals: a fitness-evaluation budget instead of iterations (CGO spends 4 per seed per iteration).
    """

    pop_size: int = 30
    iterations: int | None = 100
    max_evals: int | None = None

    def __post_init__(self):
        from icgo.optim.base import MIN_POP_SIZE

        need(is_int(self.pop_size) and self.pop_size >= MIN_POP_SIZE, "budget.pop_size",
             f"must be an integer >= {MIN_POP_SIZE}, got {self.pop_size!r}")
        need((self.iterations is None) != (self.max_evals is None), "budget.iterations",
             "and budget.max_evals: give exactly one (the other null)")
        if self.iterations is not None:
            need(is_int(self.iterations) and self.iterations >= 1, "budget.iterations",
                 f"must be an integer >= 1, got {self.iterations!r}")
        else:
            need(is_int(self.max_evals) and self.max_evals >= 1, "budget.max_evals",
                 f"must be an integer >= 1, got {self.max_evals!r}")
