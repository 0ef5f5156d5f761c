"""The ICGO-RELM study's settings: :class:`StudyConfig`, checked at construction, and the search precisions.

What a study computes (the split, MSA, features, RELM, the search and its precision) and the plan its search runs
on (:meth:`StudyConfig.execution`); the study itself is :mod:`icgo.studies.icgo_relm`.
"""

from __future__ import annotations

import dataclasses
from typing import Any

from icgo.core.execution import ExecutionPlan
from icgo.models import msa as _msa
from icgo.models import relm as _relm
from icgo.optim.base import MIN_POP_SIZE
from icgo.optim.cgo import CGO
from icgo.studies.common import sharding
from icgo.studies.common import splits as _splits
from icgo.studies.icgo_relm import settings as _nodes

#: Search-fitness precisions (``StudyConfig.precision``) -> (dtype of the hidden layer, eq. 8; dtype of the
#: ridge solve and the RMSE, eq. 9). Which kernel computes them follows the backend
#: (:func:`icgo.core.execution.execution_plan`), not this setting.
PRECISIONS = {"float32_features": ("float32", "float64"), "float64": ("float64", "float64"),
              "float32": ("float32", "float32")}
#: ``precision`` names that are refused, each with the name to use instead (a one-line error).
RENAMED_PRECISIONS = {"fast": "float32_features", "mixed": "float64"}


@dataclasses.dataclass(frozen=True)
class StudyConfig:
    """Settings of an ICGO-RELM study (defaults: the paper's protocol where it gives one, written once, in the
    study's settings nodes, :mod:`icgo.studies.icgo_relm.settings`, which ``conf/`` composes from).

    Attributes:
        n_repeats: repeats (random splits); the paper's Table 3 uses 10.
        seed: base seed; repeat k uses key ``fold_in(PRNGKey(seed), k)``.
        repeat_ids: run only these repeat ids (e.g. ``(3,)`` to rerun repeat 3
            alone); None = ``range(n_repeats)``.
        devices: the most devices the search's strategies x repeats members are sharded over (one program,
            :mod:`icgo.studies.common.sharding`); None (default) = every device of the backend (a CPU's host devices,
            one per core of the job: :func:`icgo.core.devices.use_host_devices`). Bitwise the one-device result
            on a CPU (:meth:`execution`).
        protocol: the split (:data:`icgo.studies.common.splits.PROTOCOLS`): ``random`` (paper),
            ``leave_azimuth_out``, ``leave_condition_out`` or ``transfer`` (needs
            ``SurveyData.target``, the second instrument's survey).
        train_fraction: training share of each split (paper 7:3 -> 0.7; random
            and transfer protocols).
        sigma_filter: n-sigma outlier rule applied once before splitting
            (paper: 3); None disables.
        msa_model: ``"biases"`` (paper), ``"axial"`` or ``"biases_scales"``.
        msa_reference: ``"station_mean"`` (paper eqs. 3-4) or ``"known"``
            (reference field from the metadata's total_field_nT and dip_deg).
        msa_iterations: largest number of Levenberg-Marquardt steps of the MSA
            solve (:func:`icgo.maths.lsq.least_squares` ``max_steps``; it stops earlier
            once converged, typically after 2-5 steps on lab_casing).
        features: ``"raw"`` (paper: the six raw sensor values) or ``"msa"``
            (G and the MSA-corrected B).
        hidden: RELM hidden units L (paper: not stated; 30 as in the reference
            scale runs, see docs/relm_study.md).
        lam: ridge lambda (paper: not stated; see docs/relm_study.md).
        fitness: ``"train"`` (paper: training RMSE), ``"validation"`` or ``"kfold"``.
        val_fraction: validation share of the training rows (fitness="validation").
        k_folds: folds (fitness="kfold").
        theta_bounds: (low, high) of every hidden weight and bias: the
            optimizer's search box and plain RELM's uniform draw.
        optimizer: registry name in :mod:`icgo.optim` (``cgo``, ``pso``, ``ga``,
            ``sma``) or None for plain RELM (one random theta per repeat).
        tune: plain RELM only (``optimizer=None``): choose ``hidden`` and ``lam`` on the grid
            :data:`icgo.models.relm.TUNE_HIDDEN` x :data:`icgo.models.relm.TUNE_LAMBDA` by the mean over repeats of
            the validation fitness on the training rows (``fitness`` ``validation`` or ``kfold``;
            the test rows are never seen), then fit at the chosen cell (method ``relm-tuned``).
        strategies: CGO 4th-seed strategies run side by side (vmapped); ignored
            for other optimizers.
        pop_size: population size (paper: 30).
        iterations: optimizer iterations (paper: 100); exclusive with max_evals.
        max_evals: fitness-evaluation budget instead of iterations.
        optimizer_config: the optimizer's config object (None = its defaults).
        precision: the search fitness's precision (:data:`PRECISIONS`), whatever the backend.
            ``"float32_features"`` (default): the hidden layer (eq. 8) in float32, the ridge solve
            and the RMSE in float64: within 5e-6 relative of the float64 fitness (tested), which
            is all a search needs to rank candidates. ``"float64"``: everything in float64 (the
            float64 fitness to 1e-9 relative). ``"float32"``: everything in float32 (1e-3).
            The kernel that computes it follows the backend (:meth:`execution`): on a CPU the
            cache-chunked :func:`icgo.models.relm.train_fitness` for ``fitness="train"`` (float32
            Gram of centred features, float64 Cholesky and iterative refinement), the row-weighted
            :func:`icgo.models.relm.fitness` otherwise (float64, or float32 for ``"float32"``);
            on an accelerator :func:`icgo.models.relm_gram.gram_fitness`. The final refit and every
            reported number are float64 always. ``fast`` and ``mixed`` are refused (:data:`RENAMED_PRECISIONS`).
    """

    n_repeats: int = _nodes.SplitSettings.n_repeats
    seed: int = _nodes.SplitSettings.seed
    devices: int | None = None
    repeat_ids: tuple | None = None
    protocol: str = _nodes.SplitSettings.protocol
    train_fraction: float = _nodes.SplitSettings.train_fraction
    sigma_filter: float | None = _nodes.SplitSettings.sigma_filter
    msa_model: str = _nodes.MsaSettings.model
    msa_reference: str = _nodes.MsaSettings.reference
    msa_iterations: int = _nodes.MsaSettings.iterations
    features: str = _nodes.ModelSettings.features
    hidden: int = _nodes.ModelSettings.hidden
    lam: float = _nodes.ModelSettings.lam
    fitness: str = _nodes.FitnessSettings.mode
    val_fraction: float = _nodes.FitnessSettings.val_fraction
    k_folds: int = _nodes.FitnessSettings.k_folds
    theta_bounds: tuple = _nodes.ModelSettings.theta_bounds
    optimizer: str | None = CGO.name
    tune: bool = _nodes.ModelSettings.tune
    strategies: tuple = ("three_stage",)
    pop_size: int = _nodes.BudgetSettings.pop_size
    iterations: int | None = _nodes.BudgetSettings.iterations
    max_evals: int | None = _nodes.BudgetSettings.max_evals
    optimizer_config: Any = None
    precision: str = _nodes.PRECISION

    def __post_init__(self):
        """Validate every setting that does not depend on the data (one-line SettingError naming the field)."""
        from icgo.core.errors import SettingError
        from icgo.core.settings import is_int, is_real, need
        from icgo.optim import OPTIMIZERS  # importing the package registers every optimizer

        for name in ("strategies", "theta_bounds", "repeat_ids"):  # Hydra/JSON give lists
            v = getattr(self, name)
            if isinstance(v, list):
                object.__setattr__(self, name, tuple(v))
        need(is_int(self.n_repeats) and self.n_repeats >= 1, "n_repeats",
             f"must be an integer >= 1, got {self.n_repeats!r} (repeats)")
        need(is_int(self.seed) and self.seed >= 0, "seed", f"must be an integer >= 0, got {self.seed!r}")
        need(self.devices is None or (is_int(self.devices) and self.devices >= 1), "devices",
             f"must be None (every device) or an integer >= 1, got {self.devices!r}")
        need(self.repeat_ids is None or (len(self.repeat_ids) >= 1 and all(is_int(i) and i >= 0 for i in self.repeat_ids)),
             "repeat_ids", f"must be None or a non-empty tuple of integers >= 0, got {self.repeat_ids!r}")
        need(self.protocol in _splits.PROTOCOLS, "protocol",
             f"must be one of {list(_splits.PROTOCOLS)}, got {self.protocol!r}")
        need(is_real(self.train_fraction) and 0.0 < self.train_fraction < 1.0, "train_fraction",
             f"must be in (0, 1), got {self.train_fraction!r}")
        default_fraction = StudyConfig.__dataclass_fields__["train_fraction"].default
        need(self.protocol not in _splits.FOLD_PROTOCOLS or self.train_fraction == default_fraction, "train_fraction",
             f"has no effect under protocol {self.protocol!r} (its folds set the training rows); leave it at "
             f"{default_fraction}, got {self.train_fraction!r}")
        need(self.sigma_filter is None or (is_real(self.sigma_filter) and self.sigma_filter > 0), "sigma_filter",
             f"must be > 0 or null, got {self.sigma_filter!r}")
        need(isinstance(self.msa_model, str) and self.msa_model in _msa.MODELS, "msa_model",
             f"must be one of {list(_msa.MODELS)}, got {self.msa_model!r}")
        need(self.msa_reference in ("station_mean", "known"), "msa_reference",
             f"must be station_mean or known, got {self.msa_reference!r}")
        need(is_int(self.msa_iterations) and self.msa_iterations >= 1, "msa_iterations",
             f"must be an integer >= 1, got {self.msa_iterations!r}")
        need(self.features in ("raw", "msa"), "features", f"must be 'raw' or 'msa', got {self.features!r}")
        need(is_int(self.hidden) and self.hidden >= 1, "hidden", f"must be an integer >= 1, got {self.hidden!r}")
        need(is_real(self.lam) and 0 < self.lam <= _relm.MAX_LAM, "lam",
             f"must be a number > 0 and at most {_relm.MAX_LAM:g}, got {self.lam!r} (the ridge lambda is absolute: far "
             f"above that the RELM's output weights vanish and it returns MSA's azimuth unchanged, "
             f"docs/reliability.md)")
        need(self.fitness in _relm.FITNESS_MODES, "fitness",
             f"must be one of {list(_relm.FITNESS_MODES)}, got {self.fitness!r}")
        need(is_real(self.val_fraction) and 0.0 < self.val_fraction < 1.0, "val_fraction",
             f"must be in (0, 1), got {self.val_fraction!r}")
        need(is_int(self.k_folds) and self.k_folds >= 2, "k_folds", f"must be an integer >= 2, got {self.k_folds!r}")
        tb = self.theta_bounds
        need(isinstance(tb, tuple) and len(tb) == 2 and all(is_real(x) for x in tb) and tb[0] < tb[1],
             "theta_bounds", f"must be [low, high] with low < high, got {tb!r}")
        need(not (isinstance(self.precision, str) and self.precision in RENAMED_PRECISIONS), "precision",
             f"{self.precision!r} was renamed: use "
             f"{' or '.join(f'{v} (was {k})' for k, v in RENAMED_PRECISIONS.items())}; the kernel follows the backend")
        need(isinstance(self.precision, str) and self.precision in PRECISIONS, "precision",
             f"must be one of {list(PRECISIONS)}, got {self.precision!r}")
        need(isinstance(self.tune, bool), "tune", f"must be true or false, got {self.tune!r}")
        if self.tune:
            need(self.optimizer is None, "tune", f"tunes plain RELM only: set optimizer none (got {self.optimizer!r})")
            need(self.fitness in ("validation", "kfold"), "tune",
                 f"chooses hidden and lam by validation on the training rows: set fitness validation or kfold "
                 f"(got {self.fitness!r})")
        if self.optimizer is None:
            return
        need(isinstance(self.optimizer, str) and self.optimizer in OPTIMIZERS, "optimizer",
             f"must name a registered optimizer (unknown optimizer {self.optimizer!r}); "
             f"choose one of {sorted(OPTIMIZERS)} or None")
        need(isinstance(self.strategies, tuple) and len(self.strategies) >= 1
             and len(set(self.strategies)) == len(self.strategies), "strategies",
             f"must be a non-empty tuple of distinct names, got {self.strategies!r}")
        alg = OPTIMIZERS[self.optimizer]
        if alg.axis:  # the side-by-side values (CGO strategies) are checked by the optimizer itself
            try:
                alg.axis_configs(self.optimizer_config, self.strategies)
            except (TypeError, ValueError) as e:
                raise SettingError("strategies", f"must name {alg.name} {alg.axis} values: "
                                                 f"{str(e).splitlines()[0]}") from None
        need(is_int(self.pop_size) and self.pop_size >= MIN_POP_SIZE, "pop_size",
             f"must be an integer >= {MIN_POP_SIZE}, got {self.pop_size!r}")
        need((self.iterations is None) != (self.max_evals is None), "iterations",
             "and max_evals: give exactly one (the other null)")
        if self.iterations is not None:
            need(is_int(self.iterations) and self.iterations >= 1, "iterations",
                 f"must be an integer >= 1, got {self.iterations!r}")
        else:
            need(is_int(self.max_evals) and self.max_evals >= 1, "max_evals",
                 f"must be an integer >= 1, got {self.max_evals!r}")

    def execution(self, backend: str | None = None, cores: int | None = None,
                  cells: int | None = None) -> ExecutionPlan:
        """How the search runs (:func:`icgo.core.execution.execution_plan`): its members (methods x ``cells``,
        default the repeats) sharded over the backend's devices (``devices``); no search (plain RELM): one device.

        Args:
            backend: the JAX backend (default ``jax.default_backend()``). cores: CPU cores the job may use
                (default: its affinity mask). cells: (world, repeat) cells (default: the repeats).
        """
        members = 0
        if self.optimizer is not None:
            members = len(self.method_names()) * (len(self.ids()) if cells is None else int(cells))
        return sharding.plan(backend, members, None if self.devices is None else int(self.devices), cores)

    def ids(self) -> tuple:
        """The repeat ids this config runs."""
        return tuple(range(self.n_repeats)) if self.repeat_ids is None else tuple(int(i) for i in self.repeat_ids)

    def method_names(self) -> list[str]:
        """One label per model the study fits, e.g. ``["cgo-original"]`` or ``["relm"]``."""
        if self.optimizer is None:
            return ["relm-tuned" if self.tune else "relm"]
        from icgo.optim import get

        return get(self.optimizer).labels(self.strategies)
