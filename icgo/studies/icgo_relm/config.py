"""The ICGO-RELM study's settings: :class:`StudyConfig`, checked at construction, and the search precisions.

What a study computes (the split, MSA, features, RELM, the search and its precision) and the plan its search runs
on (:meth:`StudyConfig.execution`); the study itself is :mod:`icgo.studies.icgo_relm`.
"""

from __future__ import annotations

import dataclasses
from typing import Any

from icgo.core.execution import ExecutionPlan, runtime_plan
from icgo.optim.cgo import CGO
from icgo.studies.icgo_relm import settings as _nodes

#: Search-fitness precisions (``StudyConfig.precision``) -> (dtype of the hidden layer, eq. 8; dtype of the
#: ridge solve and the RMSE, eq. 9). Which kernel computes them follows the backend
#: (:func:`icgo.core.execution.execution_plan`), not this setting.
PRECISIONS = {"float32_features": ("float32", "float64"), "float64": ("float64", "float64"),
              "float32": ("float32", "float32")}
#: ``precision`` names that are refused, each with the name to use instead (a one-line error).
RENAMED_PRECISIONS = {"fast": "float32_features", "mixed": "float64"}


#: The study's settings nodes by key (``StudyConfig`` and ``RunConfig`` hold them under these names).
NODES = {"split": _nodes.SplitSettings, "msa": _nodes.MsaSettings, "model": _nodes.ModelSettings,
         "fitness": _nodes.FitnessSettings, "budget": _nodes.BudgetSettings}


@dataclasses.dataclass(frozen=True)
class StudyConfig:
    """Settings of an ICGO-RELM study, nested as ``conf/config.yaml`` is: the study's nodes
    (:mod:`icgo.studies.icgo_relm.settings`, where their defaults and checks are written once) and the search.

    A node may be given as a mapping of its keys (``StudyConfig(split={"n_repeats": 2})``): it is built, and checked,
    as its dataclass. Defaults: the paper's protocol where it gives one.

    Attributes:
        split: :class:`~icgo.studies.icgo_relm.settings.SplitSettings`: protocol (``random`` (paper),
            ``leave_azimuth_out``, ``leave_condition_out`` or ``transfer``, which needs ``SurveyData.target``, the
            second instrument's survey), n_repeats, seed (repeat k uses key ``fold_in(PRNGKey(seed), k)``),
            sigma_filter, train_fraction.
        msa: :class:`~icgo.studies.icgo_relm.settings.MsaSettings`: model (``biases``, paper), reference,
            iterations (the largest number of Levenberg-Marquardt steps, :func:`icgo.maths.lsq.least_squares`).
        model: :class:`~icgo.studies.icgo_relm.settings.ModelSettings`: hidden (L; paper: not stated, 30 as in the
            reference scale runs, docs/relm_study.md), lam (ridge lambda), theta_bounds (the search box and plain
            RELM's uniform draw), features (``raw``, paper, or ``msa``), tune (plain RELM only: ``hidden`` and
            ``lam`` chosen on :data:`icgo.models.relm.TUNE_HIDDEN` x :data:`icgo.models.relm.TUNE_LAMBDA` by the
            mean over repeats of the validation fitness on the training rows; method ``relm-tuned``).
        fitness: :class:`~icgo.studies.icgo_relm.settings.FitnessSettings`: mode (``train``, paper: training RMSE;
            ``validation``; ``kfold``), val_fraction, k_folds.
        budget: :class:`~icgo.studies.icgo_relm.settings.BudgetSettings`: pop_size (paper: 30), iterations (paper:
            100) or max_evals.
        optimizer: registry name in :mod:`icgo.optim` (``cgo``, ``pso``, ``ga``, ``sma``) or None for plain RELM
            (one random theta per repeat).
        strategies: CGO 4th-seed strategies run side by side (vmapped); ignored for other optimizers.
        optimizer_config: the optimizer's config object (None = its defaults).
        precision: the search fitness's precision (:data:`PRECISIONS`), whatever the backend.
            ``"float32_features"`` (default): the hidden layer (eq. 8) in float32, the ridge solve
            and the RMSE in float64: within 5e-6 relative of the float64 fitness (tested), which
            is all a search needs to rank candidates. ``"float64"``: everything in float64 (the
            float64 fitness to 1e-9 relative). ``"float32"``: everything in float32 (1e-3).
            The kernel that computes it follows the backend (:meth:`execution`): on a CPU the
            cache-chunked :func:`icgo.models.relm.train_fitness` for ``fitness.mode="train"`` (float32
            Gram of centred features, float64 Cholesky and iterative refinement), the row-weighted
            :func:`icgo.models.relm.fitness` otherwise (float64, or float32 for ``"float32"``);
            on an accelerator :func:`icgo.models.relm_gram.gram_fitness`. The final refit and every
            reported number are float64 always. ``fast`` and ``mixed`` are refused (:data:`RENAMED_PRECISIONS`).
        devices: the most devices the search's strategies x repeats members are sharded over (one program,
            :func:`icgo.optim.sharded.run_grid`); None (default) = every device of the backend (a CPU's host devices,
            one per core of the job: :func:`icgo.core.devices.use_host_devices`). Bitwise the one-device result
            on a CPU (:meth:`execution`).
        repeat_ids: run only these repeat ids (e.g. ``(3,)`` to rerun repeat 3 alone); None = ``range(split.n_repeats)``.
    """

    split: _nodes.SplitSettings = dataclasses.field(default_factory=_nodes.SplitSettings)
    msa: _nodes.MsaSettings = dataclasses.field(default_factory=_nodes.MsaSettings)
    model: _nodes.ModelSettings = dataclasses.field(default_factory=_nodes.ModelSettings)
    fitness: _nodes.FitnessSettings = dataclasses.field(default_factory=_nodes.FitnessSettings)
    budget: _nodes.BudgetSettings = dataclasses.field(default_factory=_nodes.BudgetSettings)
    optimizer: str | None = CGO.name
    strategies: tuple = ("three_stage",)
    optimizer_config: Any = None
    precision: str = _nodes.PRECISION
    devices: int | None = None
    repeat_ids: tuple | None = None

    def __post_init__(self):
        """Build the nodes given as mappings (each checks its own values) and check what spans them (one-line
        SettingError naming the key)."""
        from icgo.core.errors import SettingError
        from icgo.core.settings import config_from_mapping, is_int, need
        from icgo.optim import OPTIMIZERS  # importing the package registers every optimizer

        for name, node in NODES.items():
            v = getattr(self, name)
            if isinstance(v, dict):
                object.__setattr__(self, name, config_from_mapping(node, v, name, f"{name}."))
            else:
                need(isinstance(v, node), name, f"must be a {node.__name__} or a mapping of its keys, got {v!r}")
        for name in ("strategies", "repeat_ids"):  # Hydra/JSON give lists
            v = getattr(self, name)
            if isinstance(v, list):
                object.__setattr__(self, name, tuple(v))
        need(self.devices is None or (is_int(self.devices) and self.devices >= 1), "devices",
             f"must be None (every device) or an integer >= 1, got {self.devices!r}")
        need(self.repeat_ids is None or (len(self.repeat_ids) >= 1 and all(is_int(i) and i >= 0 for i in self.repeat_ids)),
             "repeat_ids", f"must be None or a non-empty tuple of integers >= 0, got {self.repeat_ids!r}")
        need(not (isinstance(self.precision, str) and self.precision in RENAMED_PRECISIONS), "precision",
             f"{self.precision!r} was renamed: use "
             f"{' or '.join(f'{v} (was {k})' for k, v in RENAMED_PRECISIONS.items())}; the kernel follows the backend")
        need(isinstance(self.precision, str) and self.precision in PRECISIONS, "precision",
             f"must be one of {list(PRECISIONS)}, got {self.precision!r}")
        if self.model.tune:
            need(self.optimizer is None, "model.tune",
                 f"tunes plain RELM only: set optimizer none (got {self.optimizer!r})")
            need(self.fitness.mode in ("validation", "kfold"), "model.tune",
                 f"chooses hidden and lam by validation on the training rows: set fitness validation or kfold "
                 f"(got {self.fitness.mode!r})")
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

    def replace(self, **changes) -> "StudyConfig":
        """A copy with ``changes``: a node's given as a mapping changes only those keys of it
        (``cfg.replace(model={"lam": 0.5}, repeat_ids=(0,))``); checked as a new config."""
        for name in NODES.keys() & changes.keys():
            if isinstance(changes[name], dict):
                changes[name] = dataclasses.replace(getattr(self, name), **changes[name])
        return dataclasses.replace(self, **changes)

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
        return runtime_plan(backend, members, None if self.devices is None else int(self.devices), cores)

    def ids(self) -> tuple:
        """The repeat ids this config runs."""
        return tuple(range(self.split.n_repeats)) if self.repeat_ids is None else tuple(int(i) for i in self.repeat_ids)

    def method_names(self) -> list[str]:
        """One label per model the study fits, e.g. ``["cgo-original"]`` or ``["relm"]``."""
        if self.optimizer is None:
            return ["relm-tuned" if self.model.tune else "relm"]
        from icgo.optim import get

        return get(self.optimizer).labels(self.strategies)
