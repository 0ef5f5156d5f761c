"""The typed config of one run of the ICGO-RELM study's front door (``python -m experiments.run``): frozen
dataclasses mirroring ``conf/config.yaml`` node by node, built from the composed mapping by
:func:`icgo.core.settings.config_from_mapping` (an unknown key is refused in one line naming its dotted path),
each node checking what it owns at construction, with the YAML key in its one-line errors (``split.target``).

:class:`RunConfig` is the whole run: the data set (:data:`DATASET_NODES`: the node of each ``dataset`` option), the
study's nodes (``split``, ``msa``, ``model``, ``fitness``, ``budget``), the search (``optimizer``, ``strategy``,
``schedule``) and the top-level keys. :meth:`RunConfig.study_config` is the one explicit constructor of
:class:`icgo.studies.icgo_relm.config.StudyConfig` (the library's flat settings, which validate the study's values
themselves); every StudyConfig field is named there once, with the YAML key its errors are reported under.

Nothing here imports JAX at module import (the door builds this config before JAX's devices are set up);
:meth:`RunConfig.study_config` imports the study.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

from icgo.core.errors import SettingError
from icgo.core.settings import config_from_mapping, is_int, need
from icgo.core.targets import load_target, target_callable


def _file(path, key: str) -> Path:
    """``path`` expanded, refused in one line unless it is an existing regular file."""
    p = Path(str(path)).expanduser()
    need(p.exists(), f"{key} {str(p)!r}: file not found")
    need(p.is_file(), f"{key} {str(p)!r}: not a regular file (a directory, pipe or device); give a CSV file")
    return p


@dataclasses.dataclass(frozen=True)
class SimulatedData:
    """``dataset=lab_casing``: a simulated data set of :data:`icgo.datasets.registry.DATASETS` (the one registry
    of data sets), or a researcher's own (``_target_``, docs/extending.md).

    Attributes:
        name: its registry name. seed: noise seed (0 <= seed < 2**32; the systematic errors are fixed).
        kwargs: extra keyword arguments of the simulator.
        _target_: ``module.function`` of a user's simulator ``fn(seed, **kwargs) -> Dataset``, registered under
            ``name`` (None: a built-in).
    """

    name: str
    seed: int
    kwargs: dict
    _target_: str | None = None

    def __post_init__(self):
        need(is_int(self.seed) and 0 <= self.seed < 2**32, "dataset.seed",
             f"must be an integer 0 <= seed < 2**32, got {self.seed!r}")
        need(isinstance(self.kwargs, dict), "dataset.kwargs",
             f"must be a mapping of the simulator's keyword arguments, got {self.kwargs!r}")
        from icgo.datasets import registry

        if self._target_ is not None:
            fn = load_target(self._target_, "dataset._target_")
            try:
                registry.register(self.name, fn)
            except ValueError as e:
                raise SettingError("dataset.name", str(e)) from None
        need(self.name in registry.DATASETS, "dataset.name",
             f"{self.name!r} is no data set of icgo.datasets.registry.DATASETS ({', '.join(registry.DATASETS)}) "
             f"nor csv; a simulator of your own is named by dataset._target_ (docs/extending.md)")

    @property
    def condition(self) -> int | None:
        """No condition column to select (only ``well_conditions`` has one)."""
        return None


@dataclasses.dataclass(frozen=True)
class WellConditionsData(SimulatedData):
    """``dataset=well_conditions``: the simulated Table 4 data set; ``condition`` selects one row's stations
    (0-5), null keeps all."""

    condition: int | None = None

    def __post_init__(self):
        super().__post_init__()
        c = self.condition
        need(c is None or (is_int(c) and 0 <= c <= 5), "dataset.condition",
             f"must be null or an integer 0-5 (Table 4 row), got {c!r}")


@dataclasses.dataclass(frozen=True)
class CsvData:
    """``dataset=csv``: a recording of the data contract (docs/data.md).

    Attributes:
        name: ``csv``. path: the CSV (its ``.meta.json`` beside it). require_meta: refuse a CSV without
        its metadata. columns: contract column -> the file's column (None: the contract's name).
        columns_file: a JSON or YAML file of the same map (``columns`` entries win over it).
    """

    name: str
    path: str | None
    require_meta: bool
    columns: dict | None = None
    columns_file: str | None = None

    def __post_init__(self):
        need(self.path not in (None, "???"), "dataset.path is required with dataset=csv "
                                             "(dataset.path=/path/to/file.csv)")
        _file(self.path, "dataset.path")

    condition = None
    kwargs = None


#: ``dataset.name`` -> its node where it takes other keys than :class:`SimulatedData` (a config group whose options
#: take different keys); every other name is a :class:`SimulatedData` of :data:`icgo.datasets.registry.DATASETS`.
DATASET_NODES = {"well_conditions": WellConditionsData, "csv": CsvData}


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
            _file(self.path, "split.target.path")

    def draw(self) -> dict:
        """The :class:`icgo.studies.common.splits.TransferDraw` arguments that are set."""
        return {f.name: getattr(self, f.name) for f in dataclasses.fields(self)
                if f.name != "path" and getattr(self, f.name) is not None}


@dataclasses.dataclass(frozen=True)
class SplitSettings:
    """``split``: the protocol and its repeats (checked by StudyConfig), and the transfer ``target``.

    ``train_fraction`` is absent from the fold protocols' options (their folds set the training rows): None
    there, i.e. the study's default.

    Attributes:
        protocol: ``random`` (paper: rows split 7:3), ``leave_azimuth_out``, ``leave_condition_out`` or ``transfer``.
        n_repeats: repeats (splits); the paper's Table 3 uses 10. seed: repeat k uses key fold_in(PRNGKey(seed), k).
        sigma_filter: n-sigma outlier rule applied once before splitting (paper: 3); null disables.
        train_fraction: training share of each split (paper 7:3: 0.7). target: the second instrument (transfer).
    """

    protocol: str
    n_repeats: int
    seed: int
    sigma_filter: float | None
    train_fraction: float | None = None
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

    model: str
    reference: str
    iterations: int


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

    hidden: int
    lam: float
    theta_bounds: list
    features: str
    tune: bool

    def __post_init__(self):
        if self.tune:
            from icgo.studies.icgo_relm.config import StudyConfig

            for k in ("hidden", "lam"):
                default, v = StudyConfig.__dataclass_fields__[k].default, getattr(self, k)
                need(v == default, f"model.{k}={v} has no effect with model.tune=true (the tuning grid chooses it); "
                                   f"leave it at {default}")


@dataclasses.dataclass(frozen=True)
class FitnessSettings:
    """``fitness``: what the search minimises (values checked by StudyConfig).

    Attributes:
        mode: ``train`` (paper: the RELM's RMSE on the training rows), ``validation`` or ``kfold``.
        val_fraction: validation share of the training rows (mode validation). k_folds: folds (mode kfold).
    """

    mode: str
    val_fraction: float
    k_folds: int


@dataclasses.dataclass(frozen=True)
class BudgetSettings:
    """``budget``: population and iterations or evaluations (values checked by StudyConfig).

    Attributes:
        pop_size: population size (paper: 30). iterations: optimizer iterations (paper: 100); null with max_evals.
        max_evals: a fitness-evaluation budget instead of iterations (CGO spends 4 per seed per iteration).
    """

    pop_size: int
    iterations: int | None
    max_evals: int | None


@dataclasses.dataclass(frozen=True)
class OptimizerSettings:
    """``optimizer``: a registry name of :mod:`icgo.optim` (null: plain RELM) and its config's arguments.

    Attributes:
        name: the optimizer (``cgo``, ``pso``, ``ga``, ``sma``; null: plain RELM, one random hidden layer per repeat),
            or a researcher's own registered under this name.
        params: keyword arguments of its config (e.g. cgo's variant).
        _target_: ``module.NAME`` of a researcher's own :class:`icgo.optim.Algorithm` (docs/extending.md),
            registered in :data:`icgo.optim.OPTIMIZERS` under ``name`` (which must be the algorithm's own name).
    """

    name: str | None
    params: dict | None = None
    _target_: str | None = None

    def __post_init__(self):
        if self._target_ is None:
            return
        from icgo.optim import registry

        alg = load_target(self._target_, "optimizer._target_")
        need(getattr(alg, "name", None) == self.name, "optimizer.name",
             f"{self.name!r} must be the name of the algorithm optimizer._target_ names "
             f"({getattr(alg, 'name', None)!r})")
        try:
            registry.register(alg)
        except ValueError as e:
            raise SettingError("optimizer._target_", str(e)) from None


@dataclasses.dataclass(frozen=True)
class StrategySettings:
    """``strategy``: the CGO 4th-seed strategies run side by side, by their names in the registry
    (:data:`icgo.optim.mutation.MUTATIONS`).

    Attributes:
        names: the strategies (one vmapped program; ignored by optimizers other than cgo).
        define: a researcher's own strategies (docs/extending.md), name -> ``{_target_: module.function, label:
            its name in tables, **keyword arguments of the function}``, registered (after the built-ins) before
            the study is built.
    """

    names: list
    define: dict | None = None

    def __post_init__(self):
        if not self.define:
            return
        need(isinstance(self.define, dict), "strategy.define",
             f"must map a strategy name to {{_target_: module.function, label: ...}}, got {self.define!r}")
        from icgo.optim import mutation

        for name, spec in self.define.items():
            fn, rest = target_callable(spec, f"strategy.define.{name}", reserved=("label",))
            try:
                mutation.register(name, fn, rest.get("label"))
            except ValueError as e:
                raise SettingError(f"strategy.define.{name}", str(e)) from None


#: ``schedule.clock`` values: the wavelet's dilation on the whole run's t/T, or on its stage's own clock.
CLOCKS = ("global", "stage")


@dataclasses.dataclass(frozen=True)
class ScheduleSettings:
    """``schedule``: three_stage's stage boundaries (fractions of the run), stage order and the wavelet's clock.

    Attributes:
        bounds: [b1, b2], the fractions of the run where stages 2 and 3 start, 0 < b1 < b2 < 1.
        order: the three mutations in stage order. clock: ``global`` (the wavelet's dilation on the whole run's
            t/T) or ``stage`` (on its stage's own clock).
    """

    bounds: list
    order: list
    clock: str = "global"

    def __post_init__(self):
        b = list(self.bounds) if isinstance(self.bounds, (list, tuple)) else [self.bounds]
        need(len(b) == 2 and all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in b)
             and 0.0 < b[0] < b[1] < 1.0, f"schedule.bounds must be two fractions 0 < b1 < b2 < 1, got {b}")
        need(self.clock in CLOCKS, "schedule.clock", f"must be global or stage, got {self.clock!r}")


@dataclasses.dataclass(frozen=True)
class RunConfig:
    """One run of ``python -m experiments.run`` (``conf/config.yaml`` with its groups; docs/experiments.md).

    Attributes:
        dataset: the data set's node (:data:`DATASET_NODES`, else :class:`SimulatedData`). split, msa, model, fitness, budget: the study's nodes. optimizer,
            strategy, schedule: the search. precision: the search fitness's precision
            (:data:`icgo.studies.icgo_relm.config.PRECISIONS`). worlds: N independent simulated worlds, or None.
        devices: the most devices the search is sharded over (None: every one). progress: ``auto``, true, false or seconds between
            progress lines (:func:`icgo.studies.icgo_relm.progress.progress_mode`).
        figures: write study.png. overwrite: replace a complete run. label: the experiment's name or None.
        jax_cache_dir: JAX's persistent compilation cache (None: off). tracking: MLflow tracking
            (:func:`icgo.studies.common.tracking.tracking_uri`: auto, true, false or a URI).
    """

    dataset: SimulatedData | WellConditionsData | CsvData = dataclasses.field(
        metadata={"variants": DATASET_NODES, "tag": "name", "default": SimulatedData})
    split: SplitSettings
    msa: MsaSettings
    model: ModelSettings
    fitness: FitnessSettings
    budget: BudgetSettings
    optimizer: OptimizerSettings
    strategy: StrategySettings
    schedule: ScheduleSettings
    precision: str
    worlds: int | None
    devices: int | None
    progress: bool | str | float
    figures: bool
    overwrite: bool
    label: str | None
    jax_cache_dir: str | None
    tracking: bool | str | None = "auto"

    def __post_init__(self):
        from icgo.studies.icgo_relm.progress import progress_enabled

        progress_enabled(self.progress)  # its one check: auto, true, false or seconds
        from icgo.studies.common.tracking import tracking_uri

        tracking_uri(self.tracking)  # auto, true (MLflow installed), false or a URI: one line naming tracking
        need(self.label is None or isinstance(self.label, str), "label",
             f"must be a name (a string) or null, got {self.label!r}")
        n = self.worlds
        if n is None:
            return
        need(is_int(n) and n >= 1, "worlds", f"must be null (one data set) or an integer >= 1 (that many independent "
                                             f"simulated worlds), got {n!r}")
        need(self.dataset.name != "csv", "worlds=N draws N simulated data sets (data seeds dataset.seed .. "
                                         "dataset.seed + N - 1); dataset=csv is one recording: leave worlds=null")
        need(self.split.protocol != "transfer", "worlds=N with split=transfer is not supported (a second instrument "
                                                "per world); run one world at a time")

    @classmethod
    def from_mapping(cls, values: dict) -> "RunConfig":
        """The run's config from the composed (resolved, plain) mapping, ``hydra`` node excluded."""
        return config_from_mapping(cls, values, "conf/config.yaml")

    def study_config(self):
        """The :class:`icgo.studies.icgo_relm.config.StudyConfig` of this run: each field from its YAML key.

        Raises:
            SettingError: one line naming the YAML key (``split.n_repeats``), not the field.
        """
        from icgo.studies.icgo_relm.config import StudyConfig

        sp, m, ms, f, b = self.split, self.model, self.msa, self.fitness, self.budget
        fields = {  # StudyConfig field: (YAML key, value)
            "n_repeats": ("split.n_repeats", sp.n_repeats), "seed": ("split.seed", sp.seed),
            "protocol": ("split.protocol", sp.protocol), "sigma_filter": ("split.sigma_filter", sp.sigma_filter),
            "msa_model": ("msa.model", ms.model), "msa_reference": ("msa.reference", ms.reference),
            "msa_iterations": ("msa.iterations", ms.iterations), "features": ("model.features", m.features),
            "hidden": ("model.hidden", m.hidden), "lam": ("model.lam", m.lam),
            "theta_bounds": ("model.theta_bounds", m.theta_bounds), "tune": ("model.tune", m.tune),
            "fitness": ("fitness.mode", f.mode), "val_fraction": ("fitness.val_fraction", f.val_fraction),
            "k_folds": ("fitness.k_folds", f.k_folds), "optimizer": ("optimizer.name", self.optimizer.name),
            "strategies": ("strategy.names", self.strategy.names), "pop_size": ("budget.pop_size", b.pop_size),
            "iterations": ("budget.iterations", b.iterations), "max_evals": ("budget.max_evals", b.max_evals),
            "precision": ("precision", self.precision), "devices": ("devices", self.devices)}
        if sp.train_fraction is not None:
            fields["train_fraction"] = ("split.train_fraction", sp.train_fraction)
        try:
            return StudyConfig(**{k: v for k, (_, v) in fields.items()}, optimizer_config=self.optimizer_config())
        except SettingError as e:
            if e.field is None:
                raise
            raise SettingError(fields.get(e.field, (e.field,))[0], e.problem) from None

    def optimizer_config(self):
        """The optimizer's config object from ``optimizer.params`` (+ the schedule where the config has one), or
        None for plain RELM."""
        name = self.optimizer.name
        if name is None:
            return None
        from icgo.optim import get

        alg = get(name)
        params = dict(self.optimizer.params or {})
        fields = {f.name for f in dataclasses.fields(alg.config_cls)}
        if {"stage_bounds", "stage_order"} <= fields:
            params.setdefault("stage_bounds", tuple(float(x) for x in self.schedule.bounds))
            params.setdefault("stage_order", tuple(self.schedule.order))
            params.setdefault("wavelet_stage_clock", self.schedule.clock == "stage")
        try:
            return alg.make_config(**params)
        except (TypeError, ValueError) as e:
            raise SettingError(f"optimizer.params for {name}: {str(e).splitlines()[0]}") from None

    def search_sentence(self) -> str:
        """The summary's sentence on the search settings (optimizer, strategies, population, iterations,
        max_evals)."""
        b = self.budget
        return (f"Optimizer {self.optimizer.name or 'none (plain RELM)'}, strategies {list(self.strategy.names)}, "
                f"population {b.pop_size}, iterations {b.iterations}, max_evals {b.max_evals}.")
