"""The typed config of one run of the ICGO-RELM study's front door (``python -m experiments.run``): frozen
dataclasses mirroring ``conf/config.yaml`` node by node, built from the composed mapping by
:func:`icgo.core.settings.config_from_mapping` (an unknown key is refused in one line naming its dotted path),
each node checking what it owns at construction, with the YAML key in its one-line errors (``split.target``).

:class:`RunConfig` is the whole run: the data set (:data:`DATASET_NODES`: the node of each ``dataset`` option), the
study's nodes (``split``, ``msa``, ``model``, ``fitness``, ``budget``: :mod:`icgo.studies.icgo_relm.settings`, where
their defaults and checks are written), the search (``optimizer``, ``strategy``, ``schedule``) and the top-level keys.
:meth:`RunConfig.study_config` hands the same study nodes to :class:`icgo.studies.icgo_relm.config.StudyConfig` (the
library's config, nested the same way), with the search's optimizer and strategies.

Nothing here imports JAX at module import (the door builds this config before JAX's devices are set up; a node's
check imports the module that lists its values, which sets up no device); :meth:`RunConfig.study_config` imports the
study.
"""

from __future__ import annotations

import dataclasses

from icgo.core.devices import JAX_CACHE_DEFAULT
from icgo.core.errors import SettingError
from icgo.core.settings import config_from_mapping, is_int, need
from icgo.core.targets import load_target, target_callable
from icgo.studies.icgo_relm.settings import (PRECISION, BudgetSettings, FitnessSettings, ModelSettings, MsaSettings,
                                             SplitSettings, existing_file)


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
        existing_file(self.path, "dataset.path")

    condition = None
    kwargs = None


#: ``dataset.name`` -> its node where it takes other keys than :class:`SimulatedData` (a config group whose options
#: take different keys); every other name is a :class:`SimulatedData` of :data:`icgo.datasets.registry.DATASETS`.
DATASET_NODES = {"well_conditions": WellConditionsData, "csv": CsvData}


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

    A null keeps the optimizer config's own default (:class:`icgo.optim.cgo.CGOConfig`: equal thirds, chaos then
    gaussian then wavelet, the wavelet on the whole run's clock; ``schedule=thirds``), where it is written once.

    Attributes:
        bounds: [b1, b2], the fractions of the run where stages 2 and 3 start, 0 < b1 < b2 < 1 (null: thirds).
        order: the three mutations in stage order (null: chaos, gaussian, wavelet).
        clock: ``global`` (the wavelet's dilation on the whole run's t/T) or ``stage`` (on its stage's own clock)
            (null: global).
    """

    bounds: list | None = None
    order: list | None = None
    clock: str | None = None

    def __post_init__(self):
        if self.bounds is not None:
            b = list(self.bounds) if isinstance(self.bounds, (list, tuple)) else [self.bounds]
            need(len(b) == 2 and all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in b)
                 and 0.0 < b[0] < b[1] < 1.0, f"schedule.bounds must be two fractions 0 < b1 < b2 < 1, got {b}")
        need(self.clock is None or self.clock in CLOCKS, "schedule.clock",
             f"must be global or stage, got {self.clock!r}")

    def optimizer_params(self) -> dict:
        """The CGO config arguments this schedule sets (those it leaves null keep the config's defaults)."""
        return {k: v for k, v in (("stage_bounds", None if self.bounds is None else tuple(float(x) for x in self.bounds)),
                                  ("stage_order", None if self.order is None else tuple(self.order)),
                                  ("wavelet_stage_clock", None if self.clock is None else self.clock == "stage"))
                if v is not None}


@dataclasses.dataclass(frozen=True)
class RunConfig:
    """One run of ``python -m experiments.run`` (``conf/config.yaml`` with its groups; docs/experiments.md).

    The one source of the door's defaults: each node's dataclass (:mod:`icgo.studies.icgo_relm.settings`) and the
    top-level fields below; Hydra composes them first (``config_defaults`` in ConfigStore,
    registered by ``experiments/_groups.py`` from :func:`icgo.core.settings.defaults_of`), then the group options
    (``conf/<group>/<option>.yaml``, which write only what they change), then ``conf/config.yaml`` and a preset.
    ``dataset``, ``optimizer`` and ``strategy`` have no default here: their group options are them; ``schedule``'s
    nulls keep the optimizer config's own stage defaults.

    Attributes:
        dataset: the data set's node (:data:`DATASET_NODES`, else :class:`SimulatedData`).
        optimizer, strategy, schedule: the search.
        split, msa, model, fitness, budget: the study's nodes.
        precision: the search fitness's precision (:data:`icgo.studies.icgo_relm.config.PRECISIONS`):
            float32_features = the hidden layer (eq. 8) in float32, the ridge solve and RMSE in float64 (the float64
            fitness to 5e-6 relative); float64; float32. The kernel follows the backend (cache-chunked on a CPU,
            batched on an accelerator), recorded in run.json.
        worlds: N: the study on N independent simulated worlds, data seeds dataset.seed .. dataset.seed + N - 1
            (each its own noise draw, MSA, splits and keys), every world's search in one sharded program; reports
            per world and pooled over worlds (docs/relm_study.md, "Worlds"). None: one data set.
        devices: the search's members (strategies x repeats x worlds) sharded over the devices of one program:
            None = every device (a CPU's cores as host devices, every GPU, every node's); an integer caps it.
        progress: auto = a tqdm bar on a terminal (CPU), else a line every 30 s (done/total, rate, ETA) on stderr
            and in the run's log; true / false force it; a number: a line every that many seconds
            (:func:`icgo.studies.icgo_relm.progress.progress_mode`).
        figures: write study.png into the run directory.
        overwrite: a run directory that holds a complete run is refused (true: replace it whole); in a sweep, a
            finished job is kept (re-running a sweep resumes it).
        label: the experiment's name written to run.json (set by the presets in conf/experiment), or None.
        jax_cache_dir: JAX's persistent compilation cache (repeated runs and sweep jobs reuse compiled programs);
            None: off. Default: under the user's cache directory (XDG_CACHE_HOME or ~/.cache).
        tracking: MLflow (pip install 'icgo[tracking]', :func:`icgo.studies.common.tracking.tracking_uri`): auto =
            log every run and sweep job to mlruns/mlflow.db under the working directory where MLflow is installed;
            false = off; a URI (sqlite:///x.db, http://host:5000).
    """

    dataset: SimulatedData | WellConditionsData | CsvData = dataclasses.field(
        metadata={"variants": DATASET_NODES, "tag": "name", "default": SimulatedData})
    optimizer: OptimizerSettings
    strategy: StrategySettings
    schedule: ScheduleSettings = dataclasses.field(default_factory=ScheduleSettings)
    split: SplitSettings = dataclasses.field(default_factory=SplitSettings)
    msa: MsaSettings = dataclasses.field(default_factory=MsaSettings)
    model: ModelSettings = dataclasses.field(default_factory=ModelSettings)
    fitness: FitnessSettings = dataclasses.field(default_factory=FitnessSettings)
    budget: BudgetSettings = dataclasses.field(default_factory=BudgetSettings)
    precision: str = PRECISION
    worlds: int | None = None
    devices: int | None = None
    progress: bool | str | float = "auto"
    figures: bool = True
    overwrite: bool = False
    label: str | None = None
    jax_cache_dir: str | None = JAX_CACHE_DEFAULT
    tracking: bool | str | None = "auto"

    def __post_init__(self):
        from icgo.studies.icgo_relm.progress import progress_enabled

        progress_enabled(self.progress)  # its one check: auto, true, false or seconds
        from icgo.studies.common.tracking import tracking_uri

        tracking_uri(self.tracking)  # auto, true (MLflow installed), false or a URI: one line naming tracking
        if self.split.target is not None:
            need(self.split.protocol == "transfer", f"split.target is read only by split.protocol=transfer "
                                                    f"(split=transfer); here split.protocol={self.split.protocol!r}, "
                                                    f"so it would do nothing")
        else:
            need(self.split.protocol != "transfer",
                 "split.protocol=transfer needs split.target (use split=transfer, which defines it)")
        if self.model.tune:  # the tuning grid chooses them: a typed value would do nothing
            for k in ("hidden", "lam"):
                default, v = getattr(ModelSettings, k), getattr(self.model, k)
                need(v == default, f"model.{k}={v} has no effect with model.tune=true (the tuning grid chooses it); "
                                   f"leave it at {default}")
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
        """The :class:`icgo.studies.icgo_relm.config.StudyConfig` of this run: the same study nodes, the search.

        Raises:
            SettingError: one line naming the YAML key (``strategy.names``).
        """
        from icgo.studies.icgo_relm.config import StudyConfig

        search_keys = {"optimizer": "optimizer.name", "strategies": "strategy.names"}  # their YAML keys
        try:
            return StudyConfig(split=self.split, msa=self.msa, model=self.model, fitness=self.fitness,
                               budget=self.budget, optimizer=self.optimizer.name, strategies=self.strategy.names,
                               optimizer_config=self.optimizer_config(), precision=self.precision,
                               devices=self.devices)
        except SettingError as e:
            if e.field not in search_keys:
                raise
            raise SettingError(search_keys[e.field], e.problem) from None

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
            params = {**self.schedule.optimizer_params(), **params}
        try:
            return alg.make_config(**params)
        except (TypeError, ValueError) as e:
            raise SettingError(f"optimizer.params for {name}: {str(e).splitlines()[0]}") from None

    def schedule_record(self) -> dict:
        """run.json's ``schedule``: the three-stage schedule the search's config holds (the node's nulls resolved to
        the config's defaults), or the node as given for an optimizer without stages."""
        config = self.optimizer_config()
        if not hasattr(config, "stage_order"):
            return dataclasses.asdict(self.schedule)
        from icgo.optim import mutation

        names = tuple(mutation.MUTATIONS)
        return {"bounds": [float(x) for x in config.stage_bounds], "order": [names[i] for i in config.stage_order],
                "clock": "stage" if config.wavelet_stage_clock else "global"}

    def search_sentence(self) -> str:
        """The summary's sentence on the search settings (optimizer, strategies, population, iterations,
        max_evals)."""
        b = self.budget
        return (f"Optimizer {self.optimizer.name or 'none (plain RELM)'}, strategies {list(self.strategy.names)}, "
                f"population {b.pop_size}, iterations {b.iterations}, max_evals {b.max_evals}.")
