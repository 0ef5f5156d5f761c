"""The ICGO-RELM job behind ``python -m experiments.run``: the composed config checked and mapped onto
:class:`icgo.studies.icgo_relm_config.StudyConfig`, the data loaded, and the run directory written
(:mod:`icgo.studies.icgo_relm_outputs`).

Like :mod:`hydra_plugins.icgo_launcher.door`, nothing here imports JAX at module import; functions that need the
library import it inside.
"""

from __future__ import annotations

import sys
from pathlib import Path

from omegaconf import DictConfig, ListConfig, OmegaConf

from hydra_plugins.icgo_launcher.jobs import (  # noqa: F401
    FAILURE_FILES, cfg_hash, config_difference, config_hash, stored_config, stored_hash)
from icgo.core.errors import SettingError
from icgo.core.settings import is_int, need


def _check_file(p: Path, key: str) -> None:
    need(p.exists(), f"{key} {str(p)!r}: file not found")
    need(p.is_file(), f"{key} {str(p)!r}: not a regular file (a directory, pipe or device); give a CSV file")


#: Config nodes whose keys are :class:`icgo.studies.icgo_relm_config.StudyConfig` fields: key ``k`` of node ``g`` is the
#: field ``g_k`` if there is one (``msa.iterations`` -> ``msa_iterations``), else ``k``; except the aliases below.
STUDY_NODES = ("split", "msa", "model", "fitness", "budget")
#: The keys whose field name follows neither rule.
STUDY_ALIASES = {"fitness.mode": "fitness", "optimizer.name": "optimizer", "strategy.names": "strategies",
                 "dtype": "dtype", "devices": "devices"}
#: Keys read by the entry point itself (not StudyConfig fields), per node; "" = top level.
ENTRY_KEYS = {"": ("dataset", "optimizer", "strategy", "schedule", "progress", "figures", "label", "jax_cache_dir",
                   "overwrite", *STUDY_NODES, "dtype", "devices", "worlds"),
              "optimizer": ("name", "params"), "strategy": ("names",), "schedule": ("bounds", "order", "clock")}
#: Keys of the study nodes that the entry point reads itself (not StudyConfig fields): the transfer target.
STUDY_NODE_ENTRY_KEYS = ("split.target",)
#: Keys of ``split.target`` (:class:`icgo.studies.splits.TransferDraw` fields, plus a recording's path).
TARGET_KEYS = ("seed", "casing_distance_scale", "casing_strength_scale", "misalignment_deg", "path")
#: Keys of each data set option (``dataset.name``).
DATASET_KEYS = {"lab_casing": ("name", "seed", "kwargs"), "well_conditions": ("name", "seed", "condition", "kwargs"),
                "csv": ("name", "path", "require_meta", "columns", "columns_file")}


def _unknown(keys, allowed, where: str) -> None:
    bad = sorted(set(keys) - set(allowed))
    need(not bad, f"unknown setting(s) {[f'{where}{k}' for k in bad]}; {where or 'the config'} "
                  f"takes {sorted(allowed)}")


def check_config(cfg: DictConfig) -> None:
    """Entry-point checks: no unknown key anywhere, and the data set settings.

    The study's own settings are validated by :class:`icgo.studies.icgo_relm_config.StudyConfig`
    (one place); this checks what only the entry point reads.

    Raises:
        SettingError: one line naming the setting, its value and what is allowed.
    """
    from hydra_plugins.icgo_launcher.door import bool_setting

    _unknown(cfg.keys(), ENTRY_KEYS[""], "")
    for node in ("optimizer", "strategy", "schedule", "dataset", *STUDY_NODES):
        need(isinstance(cfg.get(node), DictConfig), f"{node} must be a group of settings (e.g. {node}.key=value), "
                                                    f"got {cfg.get(node)!r}")
    for node in ("optimizer", "strategy", "schedule"):
        _unknown(cfg[node].keys(), ENTRY_KEYS[node], f"{node}.")
    for key in ("figures", "overwrite"):
        bool_setting(cfg, key)
    need(cfg.get("label") is None or isinstance(cfg.get("label"), str),
         f"label must be a name (a string) or null, got {cfg.get('label')!r}")
    ds = cfg.dataset
    need(ds.get("name") in DATASET_KEYS,
         f"dataset.name must be one of {sorted(DATASET_KEYS)}, got {ds.get('name')!r}")
    _unknown(ds.keys(), DATASET_KEYS[ds.name], "dataset.")
    if "seed" in DATASET_KEYS[ds.name]:
        need(is_int(ds.get("seed")) and 0 <= ds.seed < 2**32, f"dataset.seed must be an integer 0 <= seed < 2**32, "
                                                              f"got {ds.get('seed')!r}")
    if ds.name == "csv":
        need(OmegaConf.select(ds, "path", throw_on_missing=False) not in (None, "???"),
             "dataset.path is required with dataset=csv (dataset.path=/path/to/file.csv)")
        _check_file(Path(str(ds.path)).expanduser(), "dataset.path")
        bool_setting(cfg, "dataset.require_meta")
    elif ds.name == "well_conditions":
        c = ds.condition
        need(c is None or (is_int(c) and 0 <= c <= 5),
             f"dataset.condition must be null or an integer 0-5 (Table 4 row), got {c!r}")
    target = OmegaConf.select(cfg, "split.target")
    protocol = OmegaConf.select(cfg, "split.protocol")
    if target is not None:
        need(isinstance(target, DictConfig), f"split.target must be a group of settings ({', '.join(TARGET_KEYS)}), "
                                             f"got {target!r}")
        need(protocol == "transfer", f"split.target is read only by split.protocol=transfer (split=transfer); "
                                     f"here split.protocol={protocol!r}, so it would do nothing")
        _unknown(target.keys(), TARGET_KEYS, "split.target.")
        if target.get("path") is not None:
            _check_file(Path(str(target.path)).expanduser(), "split.target.path")
    elif protocol == "transfer":
        need(False, "split.protocol=transfer needs split.target (use split=transfer, which defines it)")
    b = cfg.schedule.get("bounds")
    b = list(b) if isinstance(b, ListConfig) else [b]
    need(len(b) == 2 and all(isinstance(x, (int, float)) for x in b) and 0.0 < b[0] < b[1] < 1.0,
         f"schedule.bounds must be two fractions 0 < b1 < b2 < 1, got {b}")
    need(cfg.schedule.get("clock", "global") in ("global", "stage"),
         f"schedule.clock must be global or stage, got {cfg.schedule.get('clock')!r}")
    if OmegaConf.select(cfg, "model.tune") is True:
        from icgo.studies.icgo_relm_config import StudyConfig

        for k in ("hidden", "lam"):
            default = StudyConfig.__dataclass_fields__[k].default
            need(cfg.model[k] == default, f"model.{k}={cfg.model[k]} has no effect with model.tune=true (the tuning "
                                          f"grid chooses it); leave it at {default}")


def study_settings(cfg: DictConfig) -> tuple[dict, dict]:
    """(StudyConfig field -> value, field -> config key) from a composed config; unknown keys refused.

    Every key of the study nodes maps to a field by the rule of :data:`STUDY_NODES`
    (no hand-written field list): a new StudyConfig field is a new key in its
    node's yaml, nothing else.
    """
    import dataclasses

    from icgo.studies.icgo_relm_config import StudyConfig

    fields = {f.name for f in dataclasses.fields(StudyConfig)}
    values, where = {}, {}
    for node in STUDY_NODES:
        for k, v in OmegaConf.to_container(cfg[node], resolve=True).items():
            key = f"{node}.{k}"
            if key in STUDY_NODE_ENTRY_KEYS:
                continue
            field = STUDY_ALIASES.get(key) or (f"{node}_{k}" if f"{node}_{k}" in fields else k)
            need(field not in where, f"settings {where.get(field)!r} and {key!r} both map to the study field "
                                     f"{field!r}")
            need(field in fields, f"unknown setting {key!r}: not a setting of the study "
                                  f"(icgo.studies.icgo_relm_config.StudyConfig has {sorted(fields)})")
            values[field], where[field] = v, key
    for key, field in STUDY_ALIASES.items():
        if key not in where.values():
            v = OmegaConf.select(cfg, key)
            values[field] = OmegaConf.to_container(v, resolve=True) if OmegaConf.is_config(v) else v
            where[field] = key
    return values, where


def study_config(cfg: DictConfig):
    """:class:`icgo.studies.icgo_relm_config.StudyConfig` from a composed config (entry-point checks first).

    Raises:
        SettingError: one line naming the config key (``split.n_repeats``), not the field.
    """
    from icgo.studies.icgo_relm_config import StudyConfig

    check_config(cfg)
    values, where = study_settings(cfg)
    try:
        return StudyConfig(**values, optimizer_config=optimizer_config(cfg))
    except SettingError as e:
        if e.field is None:
            raise
        raise SettingError(where.get(e.field, e.field), e.problem) from None


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
        raise SettingError(f"optimizer.params for {name}: {str(e).splitlines()[0]}") from None


def load_data(cfg: DictConfig):
    """(frame, metadata, description) of the configured data set.

    Raises:
        SettingError / icgo.core.errors.DataError: one line (missing file, bad CSV, unknown data set).
    """
    ds = cfg.dataset
    if ds.name == "csv":
        from icgo.io.recording import column_map, read_recording

        cmap = column_map(OmegaConf.to_container(ds.columns) if ds.get("columns") else None, ds.get("columns_file"),
                          "dataset.columns")
        rec = read_recording(Path(str(ds.path)).expanduser(), require_meta=bool(ds.require_meta), columns=cmap,
                             column_setting="dataset.columns")
        for line in rec.notices:  # what the reader noticed but accepted (icgo.io.recording check prints the same)
            print(f"notice: {line}", file=sys.stderr)
        return rec.frame, dict(rec.meta), f"csv:{ds.path}"
    from icgo.datasets.registry import DATASETS

    fn = DATASETS.get(ds.name)
    if fn is None:
        raise SettingError(f"dataset {ds.name!r}: icgo.datasets.registry.DATASETS has no such data set")
    kwargs = dict(OmegaConf.to_container(ds.kwargs, resolve=True) or {})
    try:
        data = fn(int(ds.seed), **kwargs)
    except TypeError as e:
        raise SettingError(f"dataset.kwargs for {ds.name}: {str(e).splitlines()[0]}") from None
    frame, meta = data.frame, dict(data.meta)
    desc = ds.name
    cond = OmegaConf.select(ds, "condition")
    if cond is not None:
        frame, desc = select_condition(frame, int(cond)), f"{ds.name}[{cond}]"
    return frame, meta, desc


def load_target(cfg: DictConfig):
    """The second instrument's survey of ``split=transfer`` (a DataFrame), or None for other protocols.

    ``split.target.path`` reads a recording; otherwise the data set's simulator draws
    the target with the changes of ``split.target`` (:func:`icgo.studies.splits.transfer_survey`).

    Raises:
        SettingError / icgo.core.errors.DataError: one line.
    """
    if OmegaConf.select(cfg, "split.protocol") != "transfer":
        return None
    t = OmegaConf.to_container(cfg.split.target, resolve=True)
    path = t.pop("path", None)
    if path is not None:
        from icgo.io.recording import read_recording

        return read_recording(Path(str(path)).expanduser(), require_meta=False).frame
    from icgo.core.errors import SettingError
    from icgo.studies.splits import TransferDraw, transfer_survey

    ds = cfg.dataset
    if ds.name == "csv":
        raise SettingError("split=transfer on dataset=csv needs split.target.path (a recording of the second "
                          "instrument); only the simulated data sets can draw one")
    try:
        draw = TransferDraw(**t)
        return transfer_survey(ds.name, int(ds.seed), dict(OmegaConf.to_container(ds.kwargs, resolve=True) or {}),
                               draw).frame
    except SettingError as e:
        raise (SettingError(f"split.target.{e.field}", e.problem) if e.field else e) from None


def select_condition(frame, condition: int):
    """Rows of one Table 4 condition of a well_conditions frame (column ``condition``)."""
    if "condition" not in frame.columns:
        raise SettingError("dataset.condition is set but the data set has no 'condition' column")
    sub = frame[frame["condition"] == condition].reset_index(drop=True)
    if len(sub) == 0:
        raise SettingError(f"dataset.condition {condition}: no rows with that condition")
    return sub


def run_output(outdir: Path, overwrite: bool):
    """The run directory as an :class:`icgo.io.files.Output`, checked (a used directory refused unless
    ``overwrite``; a failed attempt's marker does not count); Hydra's job log left alone."""
    from hydra.core.hydra_config import HydraConfig

    from icgo.io.files import Output

    keep = (f"{HydraConfig.get().job.name}.log",) if HydraConfig.initialized() else ()
    return Output(outdir, setting="the run directory", overwrite=overwrite, keep=keep, ignore=FAILURE_FILES,
                  writer="experiments.run").check()


def search_sentence(cfg: DictConfig) -> str:
    """The summary's sentence on the search settings (optimizer, strategies, population, iterations, max_evals)."""
    return (f"Optimizer {cfg.optimizer.name or 'none (plain RELM)'}, strategies {list(cfg.strategy.names)}, "
            f"population {cfg.budget.pop_size}, iterations {cfg.budget.iterations}, max_evals {cfg.budget.max_evals}.")


def write_outputs(outdir: Path, cfg: DictConfig, result, info: dict, frame=None, meta=None, plot=None) -> dict:
    """Write the run directory all at once (:func:`icgo.studies.icgo_relm_outputs.write_run_files`), Hydra's record
    of the job (``.hydra/``) staged with the rest: an interruption or a full disk before the move leaves the previous
    run as it was (:class:`icgo.io.files.Output`). Returns the run.json dictionary."""
    from hydra_plugins.icgo_launcher.door import write_hydra_record
    from icgo.reporting import records as run_records
    from icgo.studies.icgo_relm_outputs import write_run_files

    with run_output(outdir, overwrite=True).staged(last=(run_records.RUN_FILE,)) as stage:
        write_hydra_record(stage, cfg)
        return write_run_files(stage, result, info, frame, meta, plot, config_yaml=OmegaConf.to_yaml(cfg, resolve=True),
                               search=search_sentence(cfg), config_sha256=cfg_hash(cfg), run_dir=outdir)


def run_help() -> str:
    """``python -m experiments.run --help``: usage, the config groups with their options and defaults, the main
    keys, and where to read more (read from ``conf/``, so it never lists an option that does not exist)."""
    import yaml

    from hydra_plugins.icgo_launcher.door import CONF_DIR, STUDY_GROUPS, group_options

    cfg = yaml.safe_load((CONF_DIR / "config.yaml").read_text())
    defaults = {k: v for d in cfg.get("defaults", []) if isinstance(d, dict) for k, v in d.items()}
    lines = ["ICGO-RELM study: MSA, then a RELM whose hidden layer an optimizer searches; writes a run directory",
             "(metrics, models, figures, summary.md with the verdict) and prints the summary and the verdict.", "",
             "usage: python -m experiments.run [-m] [GROUP=OPTION ...] [KEY=VALUE ...]", "",
             "config groups (GROUP=OPTION; default in brackets):"]
    for g in STUDY_GROUPS:
        lines.append(f"  {g:<11} {', '.join(group_options(g))}  [{defaults.get(g) or 'none'}]")
    lines += ["", "other settings (KEY=VALUE): " + ", ".join(k for k in cfg if k not in ("defaults", "hydra")),
              "  e.g. split.n_repeats=3 budget.iterations=50 dtype=... devices=2 progress=false overwrite=true",
              "  your own recording: dataset=csv dataset.path=FILE.csv [dataset.columns.gx=Gx ...] (docs/data.md)", "",
              "examples:",
              "  python -m experiments.run strategy=three_stage           # make run",
              "  python -m experiments.run experiment=table3              # a paper preset",
              "  python -m experiments.run -m strategy=chaos,wavelet      # a sweep (one process per job)",
              "  python -m experiments.apply model=outputs/<date>/<time> data=survey.csv   # then apply the model", "",
              "docs: docs/experiments.md (groups, presets, launchers), README.md; Hydra's own flags: --hydra-help"]
    return "\n".join(lines)

