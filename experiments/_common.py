"""Shared helpers of the Hydra entry points (config checks, data loading, outputs, progress).

Nothing here imports JAX or :mod:`icgo` at module import: the launchers may
start worker processes after this module is imported (loky spawns, submitit
pickles), and JAX must be initialised inside the job, never forked. Every
function that needs the library imports it inside.

Errors the user can fix (a bad override, a missing data file) are raised as
:class:`ConfigError` (or :class:`icgo.io.DataError`), both one line; the entry
point prints ``error: <line>`` and exits with status 2, before any computation.
"""

from __future__ import annotations

import contextlib
import json
import os
import sys
import time
import traceback
from pathlib import Path
from typing import Any

from hydra.experimental.callback import Callback
from omegaconf import DictConfig, OmegaConf

#: Hydra config directory (absolute, so runs work from any working directory).
CONF_DIR = Path(__file__).resolve().parent.parent / "conf"

#: Config groups of the study app whose options are checked before Hydra composes.
STUDY_GROUPS = ("dataset", "model", "optimizer", "strategy", "schedule", "budget", "split", "fitness",
                "experiment")

#: Marker a failed multirun job leaves in its directory (one line: the error).
FAILED = "FAILED"  # == icgo.records.FAILED_FILE (tests/test_experiments_run.py; no icgo import at module import)

EXIT_CONFIG = 2


class ConfigError(ValueError):
    """A bad setting: the message is one line naming the setting and what is allowed."""


# ---------------------------------------------------------------- overrides
def group_options(group: str, conf_dir: Path = CONF_DIR) -> list[str]:
    """Names of the options of a config group (its ``*.yaml`` files)."""
    return sorted(p.stem for p in (conf_dir / group).glob("*.yaml"))


def check_overrides(args: list[str], groups=STUDY_GROUPS, conf_dir: Path = CONF_DIR) -> str | None:
    """One-line error for an override that names an unknown group option, else None.

    Handles ``group=a``, ``+group=a``, ``~group`` (ignored) and sweeps
    ``group=a,b,c``; anything else is left to Hydra.

    Args:
        args: command-line arguments (without the program name).
        groups: config groups to check.
        conf_dir: the config directory.
    Returns:
        The error line, or None when every group override names an existing option.
    """
    for arg in args:
        if arg.startswith("-") or "=" not in arg:
            continue
        key, value = arg.split("=", 1)
        key = key.lstrip("+")
        if key not in groups:
            continue
        options = group_options(key, conf_dir)
        for v in value.split(","):
            v = v.strip()
            if v in ("null", "") and key == "experiment":
                continue
            if v not in options:
                return f"unknown {key} {v!r} in override {arg!r}; choose one of: {', '.join(options)}"
    return None


#: Hydra's run-mode flags that take no value (moved in front of the overrides by :func:`preflight`).
MULTIRUN_FLAGS = ("-m", "--multirun")
#: Overrides naming a directory Hydra creates before the task function runs.
HYDRA_DIR_KEYS = ("hydra.run.dir", "hydra.sweep.dir")


def check_hydra_dirs(args: list[str]) -> str | None:
    """One-line error for a ``hydra.run.dir`` / ``hydra.sweep.dir`` that cannot be a directory, else None.

    Hydra creates these before any entry-point code runs, and a failure there is
    a traceback; so the directory is created here first (a value with an
    interpolation, e.g. ``${now:...}``, is left to Hydra).
    """
    for arg in args:
        key, sep, value = arg.lstrip("+").partition("=")
        if not sep or key not in HYDRA_DIR_KEYS or "${" in value:
            continue
        p = Path(value).expanduser()
        if p.exists() and not p.is_dir():
            return f"{key} {value!r} is a file, not a directory; give a directory"
        try:
            p.mkdir(parents=True, exist_ok=True)
        except OSError as e:
            return f"{key} {value!r}: cannot create the directory ({e.strerror or type(e).__name__})"
    return None


def check_plain_overrides(args: list[str], config_name: str, conf_dir: Path = CONF_DIR) -> str | None:
    """One-line error for an override ``key=value`` (no ``+``) whose key is not in the composed config.

    Hydra refuses such an override itself, but with a six-line block and exit
    status 1; this composes the config the way the entry point will (with the
    command line's group choices, a sweep's first value) and names the key.
    """
    from hydra import compose, initialize_config_dir
    from hydra.core.global_hydra import GlobalHydra
    from hydra.core.override_parser.overrides_parser import OverridesParser
    from hydra.core.override_parser.types import OverrideType

    try:
        overrides = OverridesParser.create().parse_overrides([a for a in args if not a.startswith("-")])
    except Exception:  # Hydra's grammar: let Hydra print its own message for a malformed override
        return None
    groups, plain = [], []
    for ov in overrides:
        key = ov.key_or_group
        if key.startswith("hydra") or (ov.type != OverrideType.CHANGE and not (conf_dir / key).is_dir()):
            continue  # Hydra's own settings; an added or deleted key (the entry points refuse unknown ones)
        if (conf_dir / key).is_dir():
            value = next(iter(ov.sweep_string_iterator())) if ov.is_sweep_override() else ov.get_value_element_as_str()
            prefix = {OverrideType.ADD: "+", OverrideType.FORCE_ADD: "++"}.get(ov.type, "")
            groups.append(f"{prefix}{key}={value}")
        else:
            plain.append(ov)
    if not plain:
        return None
    GlobalHydra.instance().clear()
    try:
        with initialize_config_dir(config_dir=str(conf_dir), version_base="1.3"):
            cfg = compose(config_name=config_name, overrides=groups)
    except Exception:  # a bad group choice: the entry point's own checks name it
        return None
    finally:
        GlobalHydra.instance().clear()
    for ov in plain:
        if not _has_key(cfg, ov.key_or_group):
            where = (conf_dir / f"{config_name}.yaml").relative_to(CONF_DIR.parent)
            return (f"unknown setting {ov.key_or_group!r} in override {ov.input_line!r}: {where} (with the chosen "
                    f"groups) has no such key")
    return None


def _has_key(cfg, dotted: str) -> bool:
    """Whether the composed config has the key ``a.b.c`` (a mandatory ``???`` value counts as present)."""
    from omegaconf import ListConfig

    node = cfg
    for part in dotted.split("."):
        if isinstance(node, DictConfig) and part in node.keys():
            node = node._get_node(part)
        elif isinstance(node, ListConfig) and part.isdigit() and int(part) < len(node):
            node = node._get_node(int(part))
        else:
            return False
    return True


def preflight(config_name: str, args: list[str] | None = None, conf_dir: Path = CONF_DIR) -> None:
    """Checks of a Hydra entry point's command line before Hydra starts; one line and exit 2 on a bad one.

    Moves ``-m``/``--multirun`` in front of the overrides (Hydra's parser refuses
    them after one), then :func:`check_hydra_dirs` and :func:`check_plain_overrides`.
    Rewrites ``sys.argv`` when ``args`` is None.
    """
    argv = sys.argv[1:] if args is None else args
    flags = [a for a in argv if a in MULTIRUN_FLAGS]
    rest = [a for a in argv if a not in MULTIRUN_FLAGS]
    if args is None:
        sys.argv[1:] = flags + rest
    err = check_hydra_dirs(rest) or check_plain_overrides(rest, config_name, conf_dir)
    if err:
        print(f"error: {err}", file=sys.stderr)
        raise SystemExit(EXIT_CONFIG)


# ------------------------------------------------------------------ checks
def _need(cond: bool, msg: str) -> None:
    if not cond:
        raise ConfigError(msg)


def _need_file(p: Path, key: str) -> None:
    _need(p.exists(), f"{key} {str(p)!r}: file not found")
    _need(p.is_file(), f"{key} {str(p)!r}: not a regular file (a directory, pipe or device); give a CSV file")


def _is_int(x) -> bool:
    return isinstance(x, int) and not isinstance(x, bool)


#: Config nodes whose keys are :class:`icgo.studies.icgo_relm.StudyConfig` fields: key ``k`` of node ``g`` is the
#: field ``g_k`` if there is one (``msa.iterations`` -> ``msa_iterations``), else ``k``; except the aliases below.
STUDY_NODES = ("split", "msa", "model", "fitness", "budget")
#: The keys whose field name follows neither rule.
STUDY_ALIASES = {"fitness.mode": "fitness", "optimizer.name": "optimizer", "strategy.names": "strategies",
                 "dtype": "dtype", "workers": "workers"}
#: Keys read by the entry point itself (not StudyConfig fields), per node; "" = top level.
ENTRY_KEYS = {"": ("dataset", "optimizer", "strategy", "schedule", "progress", "figures", "label", "jax_cache_dir",
                   "overwrite", *STUDY_NODES, "dtype", "workers"),
              "optimizer": ("name", "params"), "strategy": ("names",), "schedule": ("bounds", "order", "clock")}
#: Keys of the study nodes that the entry point reads itself (not StudyConfig fields): the transfer target.
STUDY_NODE_ENTRY_KEYS = ("split.target",)
#: Keys of ``split.target`` (:class:`icgo.splits.TransferDraw` fields, plus a recording's path).
TARGET_KEYS = ("seed", "casing_distance_scale", "casing_strength_scale", "misalignment_deg", "path")
#: Keys of each data set option (``dataset.name``).
DATASET_KEYS = {"lab_casing": ("name", "seed", "kwargs"), "well_conditions": ("name", "seed", "condition", "kwargs"),
                "csv": ("name", "path", "require_meta")}


def _unknown(keys, allowed, where: str) -> None:
    bad = sorted(set(keys) - set(allowed))
    _need(not bad, f"unknown setting(s) {[f'{where}{k}' for k in bad]}; {where or 'the config'} "
                   f"takes {sorted(allowed)}")


def check_config(cfg: DictConfig) -> None:
    """Entry-point checks: no unknown key anywhere, and the data set settings.

    The study's own settings are validated by :class:`icgo.studies.icgo_relm.StudyConfig`
    (one place); this checks what only the entry point reads.

    Raises:
        ConfigError: one line naming the setting, its value and what is allowed.
    """
    _unknown(cfg.keys(), ENTRY_KEYS[""], "")
    for node in ("optimizer", "strategy", "schedule"):
        _unknown(cfg[node].keys(), ENTRY_KEYS[node], f"{node}.")
    ds = cfg.dataset
    _need(ds.get("name") in DATASET_KEYS,
          f"dataset.name must be one of {sorted(DATASET_KEYS)}, got {ds.get('name')!r}")
    _unknown(ds.keys(), DATASET_KEYS[ds.name], "dataset.")
    if ds.name == "csv":
        _need(OmegaConf.select(ds, "path", throw_on_missing=False) not in (None, "???"),
              "dataset.path is required with dataset=csv (dataset.path=/path/to/file.csv)")
        _need_file(Path(str(ds.path)).expanduser(), "dataset.path")
    elif ds.name == "well_conditions":
        c = ds.condition
        _need(c is None or (_is_int(c) and 0 <= c <= 5),
              f"dataset.condition must be null or an integer 0-5 (Table 4 row), got {c!r}")
    target = OmegaConf.select(cfg, "split.target")
    protocol = OmegaConf.select(cfg, "split.protocol")
    if target is not None:
        _need(protocol == "transfer", f"split.target is read only by split.protocol=transfer (split=transfer); "
                                      f"here split.protocol={protocol!r}, so it would do nothing")
        _unknown(target.keys(), TARGET_KEYS, "split.target.")
        if target.get("path") is not None:
            _need_file(Path(str(target.path)).expanduser(), "split.target.path")
    elif protocol == "transfer":
        _need(False, "split.protocol=transfer needs split.target (use split=transfer, which defines it)")
    b = list(cfg.schedule.bounds)
    _need(len(b) == 2 and all(isinstance(x, (int, float)) for x in b) and 0.0 < b[0] < b[1] < 1.0,
          f"schedule.bounds must be two fractions 0 < b1 < b2 < 1, got {b}")
    _need(cfg.schedule.get("clock", "global") in ("global", "stage"),
          f"schedule.clock must be global or stage, got {cfg.schedule.get('clock')!r}")
    if OmegaConf.select(cfg, "model.tune") is True:
        from icgo.studies.icgo_relm import StudyConfig

        for k in ("hidden", "lam"):
            default = StudyConfig.__dataclass_fields__[k].default
            _need(cfg.model[k] == default, f"model.{k}={cfg.model[k]} has no effect with model.tune=true (the tuning "
                                           f"grid chooses it); leave it at {default}")


def study_settings(cfg: DictConfig) -> tuple[dict, dict]:
    """(StudyConfig field -> value, field -> config key) from a composed config; unknown keys refused.

    Every key of the study nodes maps to a field by the rule of :data:`STUDY_NODES`
    (no hand-written field list): a new StudyConfig field is a new key in its
    node's yaml, nothing else.
    """
    import dataclasses

    from icgo.studies.icgo_relm import StudyConfig

    fields = {f.name for f in dataclasses.fields(StudyConfig)}
    values, where = {}, {}
    for node in STUDY_NODES:
        for k, v in OmegaConf.to_container(cfg[node], resolve=True).items():
            key = f"{node}.{k}"
            if key in STUDY_NODE_ENTRY_KEYS:
                continue
            field = STUDY_ALIASES.get(key) or (f"{node}_{k}" if f"{node}_{k}" in fields else k)
            _need(field not in where, f"settings {where.get(field)!r} and {key!r} both map to the study field "
                                      f"{field!r}")
            _need(field in fields, f"unknown setting {key!r}: not a setting of the study "
                                   f"(icgo.studies.icgo_relm.StudyConfig has {sorted(fields)})")
            values[field], where[field] = v, key
    for key, field in STUDY_ALIASES.items():
        if key not in where.values():
            v = OmegaConf.select(cfg, key)
            values[field] = OmegaConf.to_container(v, resolve=True) if OmegaConf.is_config(v) else v
            where[field] = key
    return values, where


def study_config(cfg: DictConfig):
    """:class:`icgo.studies.icgo_relm.StudyConfig` from a composed config (entry-point checks first).

    Raises:
        ConfigError: one line naming the config key (``split.n_repeats``), not the field.
    """
    from icgo.studies.icgo_relm import StudyConfig
    from icgo.studies import SettingError

    check_config(cfg)
    values, where = study_settings(cfg)
    try:
        return StudyConfig(**values, optimizer_config=optimizer_config(cfg))
    except SettingError as e:
        raise ConfigError(f"{where.get(e.field, e.field)} {e.problem}") from None


def optimizer_config(cfg: DictConfig):
    """The optimizer's config object from ``optimizer.params`` (+ the schedule where the config has one), or None."""
    name = cfg.optimizer.name
    if name is None:
        return None
    import dataclasses

    from icgo.optim import get

    alg = get(name)
    params = dict(OmegaConf.to_container(cfg.optimizer.params, resolve=True) or {})
    fields = {f.name for f in dataclasses.fields(alg.config_cls)}
    if {"stage_bounds", "stage_order"} <= fields:
        params.setdefault("stage_bounds", tuple(float(x) for x in cfg.schedule.bounds))
        params.setdefault("stage_order", tuple(cfg.schedule.order))
        params.setdefault("wavelet_stage_clock", cfg.schedule.get("clock", "global") == "stage")
    try:
        return alg.make_config(**params)
    except (TypeError, ValueError) as e:
        raise ConfigError(f"optimizer.params for {name}: {str(e).splitlines()[0]}") from None


# -------------------------------------------------------------------- data
def load_data(cfg: DictConfig):
    """(frame, metadata, description) of the configured data set.

    Raises:
        ConfigError / icgo.io.DataError: one line (missing file, bad CSV, unknown data set).
    """
    ds = cfg.dataset
    if ds.name == "csv":
        from icgo.io import read_recording

        rec = read_recording(Path(str(ds.path)).expanduser(), require_meta=bool(ds.require_meta))
        for line in rec.notices:  # what the reader noticed but accepted (icgo.io check prints the same)
            print(f"notice: {line}", file=sys.stderr)
        return rec.frame, dict(rec.meta), f"csv:{ds.path}"
    from icgo import datasets

    fn = getattr(datasets, ds.name, None)
    if fn is None:
        raise ConfigError(f"dataset {ds.name!r}: icgo.datasets has no such protocol")
    kwargs = dict(OmegaConf.to_container(ds.kwargs, resolve=True) or {})
    try:
        data = fn(int(ds.seed), **kwargs)
    except TypeError as e:
        raise ConfigError(f"dataset.kwargs for {ds.name}: {str(e).splitlines()[0]}") from None
    frame, meta = data.frame, dict(data.meta)
    desc = ds.name
    cond = OmegaConf.select(ds, "condition")
    if cond is not None:
        frame, desc = select_condition(frame, int(cond)), f"{ds.name}[{cond}]"
    return frame, meta, desc


def load_target(cfg: DictConfig):
    """The second instrument's survey of ``split=transfer`` (a DataFrame), or None for other protocols.

    ``split.target.path`` reads a recording; otherwise the data set's simulator draws
    the target with the changes of ``split.target`` (:func:`icgo.splits.transfer_survey`).

    Raises:
        ConfigError / icgo.io.DataError: one line.
    """
    if OmegaConf.select(cfg, "split.protocol") != "transfer":
        return None
    t = OmegaConf.to_container(cfg.split.target, resolve=True)
    path = t.pop("path", None)
    if path is not None:
        from icgo.io import read_recording

        return read_recording(Path(str(path)).expanduser(), require_meta=False).frame
    from icgo.splits import TransferDraw, transfer_survey
    from icgo.studies import SettingError

    ds = cfg.dataset
    if ds.name == "csv":
        raise ConfigError("split=transfer on dataset=csv needs split.target.path (a recording of the second "
                          "instrument); only the simulated data sets can draw one")
    try:
        draw = TransferDraw(**t)
        return transfer_survey(ds.name, int(ds.seed), dict(OmegaConf.to_container(ds.kwargs, resolve=True) or {}),
                               draw).frame
    except SettingError as e:
        raise ConfigError(f"split.target.{e.field} {e.problem}") from None


def select_condition(frame, condition: int):
    """Rows of one Table 4 condition of a well_conditions frame (column ``condition``)."""
    if "condition" not in frame.columns:
        raise ConfigError("dataset.condition is set but the data set has no 'condition' column")
    sub = frame[frame["condition"] == condition].reset_index(drop=True)
    if len(sub) == 0:
        raise ConfigError(f"dataset.condition {condition}: no rows with that condition")
    return sub


# ------------------------------------------------------------- JAX set-up
def enable_jax_cache(path: str | None) -> None:
    """Turn on JAX's persistent compilation cache in ``path`` (None: leave it off).

    Programs with host callbacks (the progress bar) are never cached by JAX;
    multirun jobs run without a bar, so their compiled study is reused.
    """
    if not path:
        return
    import jax

    p = Path(path).expanduser()
    try:
        p.mkdir(parents=True, exist_ok=True)
    except OSError as e:  # a read-only file system, a file in the way
        raise ConfigError(f"jax_cache_dir {str(p)!r}: cannot create the cache directory ({e.strerror}); "
                          f"set jax_cache_dir=null to run without the cache") from None
    jax.config.update("jax_compilation_cache_dir", str(Path(path).expanduser()))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)


# ----------------------------------------------------------------- progress
class Progress:
    """A tqdm bar over optimizer iterations, advanced by a host callback from inside the scan.

    :meth:`wrap` returns a fitness that calls ``jax.debug.callback(self.tick)``
    with no operands: under the runner's vmap over repeats and strategies the
    callback is not batched, so it fires once per fitness call of the whole
    batch, i.e. once per iteration (plus once for the initial population).
    tqdm redraws at most every 0.2 s.
    """

    def __init__(self, total: int, desc: str, enable: bool):
        self.total, self.count, self.bar, self.t0 = total, 0, None, time.perf_counter()
        if enable:
            from tqdm.auto import tqdm

            self.bar = tqdm(total=total, desc=desc, unit="it", mininterval=0.2, dynamic_ncols=True,
                            file=sys.stderr)

    def tick(self) -> None:
        """Host side: one more iteration done."""
        if self.count < self.total:
            self.count += 1
            if self.bar is not None:
                self.bar.update(1)

    def wrap(self, fitness):
        """A fitness that reports each call to :meth:`tick`."""
        import jax

        def f(pop, aux):
            jax.debug.callback(self.tick)
            return fitness(pop, aux)

        return f

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()


def progress_enabled(setting) -> bool:
    """``progress`` option: ``auto`` (a bar when stderr is a terminal), true or false."""
    if isinstance(setting, bool):
        return setting
    if setting in (None, "auto"):
        return sys.stderr.isatty()
    raise ConfigError(f"progress must be auto, true or false, got {setting!r}")


def run_with_progress(frame, scfg, meta, enable: bool, desc: str, target=None):
    """``icgo.studies.icgo_relm.run_study`` with a progress bar over the optimizer's iterations.

    The bar wraps the search's fitness (``run_study(wrap_fitness=...)``), so it
    advances from inside the scan; without an optimizer (plain RELM) there is no
    scan and no bar.
    """
    from icgo.studies import icgo_relm as study

    n_workers = scfg.search_workers(len(frame))
    if n_workers > 1:
        print(f"search: {n_workers} worker processes, one per core (workers={scfg.workers}); "
              f"{'no progress bar (workers=1 for one)' if enable else 'progress off'}", file=sys.stderr)
    if not enable or scfg.optimizer is None or n_workers > 1:
        return study.run_study(frame, scfg, meta, target=target)
    from icgo.optim import iterations_for_budget

    n_iter = scfg.iterations if scfg.max_evals is None else iterations_for_budget(
        scfg.optimizer, scfg.pop_size, scfg.max_evals, scfg.optimizer_config)
    bar = Progress(int(n_iter) + 1, desc, True)
    try:
        return study.run_study(frame, scfg, meta, wrap_fitness=bar.wrap, target=target)
    finally:
        bar.close()


# ------------------------------------------------------------------ outputs
#: The paper's names for method labels (everything else is named by the rule in :func:`method_label`).
PAPER_NAMES = {"raw": "raw (eq. 1)", "msa": "MSA only", "relm": "RELM", "cgo-original": "CGO-RELM",
               "cgo-three_stage": "ICGO-RELM (three-stage)"}


def method_label(method: str) -> str:
    """Paper-style label: the paper's name if it has one, else ``<alg>-<value>`` -> ``ALG-RELM (value)``."""
    if method in PAPER_NAMES:
        return PAPER_NAMES[method]
    name, _, value = method.partition("-")
    return f"{name.upper()}-RELM" + (f" ({value})" if value else "")


def summary_table(result, split: str = "test"):
    """Printed/Markdown summary: per method MAE, RMSE, R^2 (mean +/- std over repeats) and evaluations."""
    import numpy as np
    import pandas as pd

    from icgo.records import SUMMARY_COLUMNS

    s = result.summary.xs(split, level="split")
    evals = dict(zip(result.config.method_names(), np.asarray(result.n_evals).mean(axis=1)))
    rows = []
    for m in s.index:
        rows.append({"method": m, "label": method_label(m), "n": int(s.loc[m, "n"]),
                     "MAE (deg)": s.loc[m, "mae"], "RMSE (deg)": s.loc[m, "rmse"], "R^2": s.loc[m, "r2"],
                     "R^2 of error": s.loc[m, "r2_error"],
                     "evaluations": int(evals[m]) if m in evals else 0})
    return pd.DataFrame(rows, columns=list(SUMMARY_COLUMNS))


#: Files of a run directory that a new run replaces or removes (besides the tables and models it writes).
RUN_EXTRAS = ("study.png", "error.txt", FAILED)


def write_outputs(outdir: Path, cfg: DictConfig, result, info: dict, frame=None, meta=None, plot=None) -> dict:
    """Write the run directory atomically: config, tables, summary, fitted models, figure, then run.json.

    Everything is written into a staging directory first (``outdir/.staging``);
    only when every file is complete is the previous run record removed, the
    files moved into place (``os.replace``) and the new ``run.json`` moved last.
    An interruption or a full disk before that leaves the previous run as it was
    (and no staging directory); during the moves it leaves no ``run.json``, so no
    reader takes the directory for a complete run. File and column names come
    from :mod:`icgo.records`; the fitted models are saved with
    :meth:`icgo.models.FittedModel.save`.

    Args:
        frame, meta: the study's data and metadata; with a reference field in
            ``meta``, the survey-QC counts before and after MSA (:func:`icgo.survey.study_qc`)
            go into the summary and the run record.
        plot: optional ``path -> None`` writing the study figure (``study.png``).
    Returns:
        The run.json dictionary.
    """
    import shutil

    stage = outdir / ".staging"
    shutil.rmtree(stage, ignore_errors=True)
    stage.mkdir(parents=True)
    try:
        run = _write_run_files(stage, cfg, result, info, frame, meta, plot)
        _commit_run(stage, outdir)
    finally:
        shutil.rmtree(stage, ignore_errors=True)
    return run


@contextlib.contextmanager
def staged_results(out: Path, last: str | None = None):
    """Write a study's files into a shared results folder all at once, or not at all.

    Yields a fresh staging directory inside ``out`` (same file system). When the
    block ends normally every staged file is moved into ``out`` with
    ``os.replace`` (``last``, the study's summary record, moved last); when it
    raises (Ctrl-C, a full disk, a bug) the staging directory is removed and
    ``out`` holds exactly what it held before, and a line says so on stderr.
    Sub-directories are not supported (the studies write flat files).
    """
    import shutil
    import tempfile

    out.mkdir(parents=True, exist_ok=True)
    stage = Path(tempfile.mkdtemp(prefix=".staging-", dir=out))
    try:
        try:
            yield stage
        except BaseException:
            print(f"[results] stopped before the files were complete: nothing in {out} was changed", file=sys.stderr)
            raise
        for f in sorted(stage.iterdir(), key=lambda f: f.name == last):
            os.replace(f, out / f.name)
    finally:
        shutil.rmtree(stage, ignore_errors=True)


def _commit_run(stage: Path, outdir: Path) -> None:
    """Move a complete staged run into ``outdir``: old record out, files in, new run.json last."""
    from icgo import records as R

    (outdir / R.RUN_FILE).unlink(missing_ok=True)
    for name in RUN_EXTRAS:
        if not (stage / name).exists():
            (outdir / name).unlink(missing_ok=True)
    for f in sorted(stage.iterdir()):
        if f.name != R.RUN_FILE:
            os.replace(f, outdir / f.name)
    os.replace(stage / R.RUN_FILE, outdir / R.RUN_FILE)


def _write_run_files(outdir: Path, cfg: DictConfig, result, info: dict, frame, meta, plot) -> dict:
    """Every file of a run into ``outdir`` (the staging directory), run.json last."""
    import numpy as np

    from icgo import records as R
    from icgo.qc import qc_sentence
    from icgo.survey import study_qc

    qc = None if frame is None else study_qc(frame[result.kept].reset_index(drop=True), meta, result.msa_model)

    outdir.mkdir(parents=True, exist_ok=True)
    (outdir / R.CONFIG_FILE).write_text(OmegaConf.to_yaml(cfg, resolve=True))
    tags = {"label": info["label"], "dataset": info["dataset"], "condition": info["condition"],
            "seed": result.config.seed}
    for name, df in result.records.items():
        R.check_table(name, R.tag_table(df, tags), name).to_csv(outdir / f"{name}.csv", index=False,
                                                                 float_format="%.10g")
    table = summary_table(result)
    table.to_csv(outdir / "summary.csv", index=False)
    md = [f"# ICGO-RELM study: {info['dataset']}", "",
          f"Test split (30 %), {result.config.n_repeats} repeats, mean +/- std (sample std). "
          f"Optimizer {cfg.optimizer.name or 'none (plain RELM)'}, strategies {list(cfg.strategy.names)}, "
          f"population {cfg.budget.pop_size}, iterations {cfg.budget.iterations}, "
          f"max_evals {cfg.budget.max_evals}.", "",
          table.drop(columns=["method"]).to_markdown(index=False), "",
          f"Wall time of the study: {result.wall_time_s:.1f} s (compile included); "
          f"whole job {info['total_time_s']:.1f} s.", "",
          f"Fitted models: `{result.model.KIND}` (method used by default: {result.model.selected}) and "
          f"`{result.msa_model.KIND}`; apply them to a new survey with `icgo.models.load_model`."]
    if qc:
        md += ["", qc_sentence(qc)]
    (outdir / "summary.md").write_text("\n".join(md) + "\n")
    if plot is not None:
        plot(outdir / "study.png")
    models = [result.model.save(outdir / result.model.KIND).name, result.msa_model.save(outdir / result.msa_model.KIND).name]
    methods = result.config.method_names()
    run = {**info, "records_version": R.RECORDS_VERSION, "status": "ok", "seed": result.config.seed,
           "wall_time_s": result.wall_time_s, "methods": methods,
           "n_evals": {m: int(v) for m, v in zip(methods, np.asarray(result.n_evals)[:, 0])},
           "n_rows": int(result.kept.sum()), "n_repeats": result.config.n_repeats,
           "repeat_ids": list(result.config.ids()), "models": models, "qc": qc}
    if result.tuning is not None:
        run["tuning"] = result.tuning
    missing = [k for k in R.RUN_KEYS if k not in run]
    assert not missing, f"run record lacks {missing}"  # a writer bug, not a user error
    (outdir / R.RUN_FILE).write_text(json.dumps(run, indent=2, default=str) + "\n")
    return run


def study_main(cfg: DictConfig, build_config, run) -> None:
    """Body of a study entry point's Hydra main: settings checked first (one line, exit 2), then ``run``.

    Args:
        cfg: the composed config. build_config: ``cfg -> the study's config dataclass``
            (raises ValueError on a bad setting). run: ``(cfg, models_dir, config) -> None``.
    """
    import logging

    from hydra.core.hydra_config import HydraConfig

    try:
        config = build_config(cfg)
    except ValueError as e:
        print(f"error: {one_line(e)}", file=sys.stderr)
        raise SystemExit(EXIT_CONFIG) from None
    logging.getLogger("icgo").setLevel(logging.INFO)
    run(cfg, Path(HydraConfig.get().runtime.output_dir) / "models", config)


def previous_run(outdir: Path) -> dict | None:
    """The run record of a complete previous run in ``outdir``, or None (no run, or an unreadable record)."""
    from icgo import records as R

    if not (outdir / R.RUN_FILE).is_file():
        return None
    try:
        return R.read_run(outdir)
    except R.RecordError:
        return None


def write_failure(outdir: Path, message: str, tb: str | None = None) -> None:
    """Leave the FAILED marker (one line) and, for unexpected errors, the traceback."""
    outdir.mkdir(parents=True, exist_ok=True)
    (outdir / FAILED).write_text(message.strip().splitlines()[0] + "\n")
    if tb:
        (outdir / "error.txt").write_text(tb)


class FailureReport(Callback):
    """Hydra callback: after a multirun, report every job's status (:mod:`experiments._sweep`);
    exit with status 1 unless every job is ok."""

    def on_multirun_end(self, config: DictConfig, **kwargs: Any) -> None:
        from experiments import _sweep

        jobs = _sweep.report(config)
        bad = [j for j in jobs if j["status"] != "ok"]
        if bad:
            print(f"{len(bad)} of {len(jobs)} job(s) did not finish; the others' results are in "
                  f"{config.hydra.sweep.dir} (re-running the sweep into it resumes it)", file=sys.stderr)
            raise SystemExit(1)


def one_line(e: BaseException) -> str:
    """First line of an exception message."""
    text = str(e).strip()
    return text.splitlines()[0] if text else type(e).__name__


def format_traceback(e: BaseException) -> str:
    return "".join(traceback.format_exception(type(e), e, e.__traceback__))


def env_info() -> dict:
    """Host facts recorded in run.json."""
    return {"pid": os.getpid(), "cpu_count": os.cpu_count()}
