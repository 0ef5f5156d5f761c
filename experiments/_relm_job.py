"""The ICGO-RELM job behind ``python -m experiments.run``: the composed config checked and mapped onto
:class:`icgo.studies.icgo_relm_config.StudyConfig`, the data loaded, the progress bar, and the run directory written.

Like :mod:`experiments._entry`, nothing here imports JAX at module import; functions that need the
library import it inside.
"""

from __future__ import annotations

import json
import sys
import time
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
    from experiments._entry import bool_setting

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


class Progress:
    """A tqdm bar over the search's iterations, fed by ``run_study(progress=...)`` between chunks of iterations.

    The study runs its search in a few jitted chunks and calls this on the host after each
    (:func:`icgo.optim.sharded.run_members`); nothing enters the compiled programs, so the compilation
    cache keeps them. The bar starts after the first chunk, i.e. after
    compiling (or loading) the program, so its rate and ETA measure the search alone.
    """

    def __init__(self, desc: str):
        self.desc, self.bar = desc, None
        print(f"{desc}: compiling or loading the search program, then the bar starts", file=sys.stderr)

    def __call__(self, done: int, total: int) -> None:
        if self.bar is None:
            from tqdm.auto import tqdm

            self.bar = tqdm(total=total, initial=done, desc=self.desc, unit="it", mininterval=0.2,
                            dynamic_ncols=True, file=sys.stderr)
            return
        self.bar.update(done - self.bar.n)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()


def progress_enabled(setting, accelerator: bool = False) -> bool:
    """``progress`` option: ``auto`` (a bar when stderr is a terminal and the search runs on a CPU: on an
    accelerator the bar's host callback would be a round trip inside the iteration loop), true or false."""
    if isinstance(setting, bool):
        return setting
    if setting in (None, "auto"):
        return sys.stderr.isatty() and not accelerator
    raise SettingError(f"progress must be auto, true or false, got {setting!r}")


def run_with_progress(frame, scfg, meta, progress, desc: str, target=None, timings: dict | None = None):
    """``icgo.studies.icgo_relm.run_study`` with a progress bar over the optimizer's iterations (:class:`Progress`).

    The bar follows the search's iterations on the host (``run_study(progress=...)``); without an optimizer (plain
    RELM), or on an accelerator under
    ``progress=auto``, there is no bar. ``progress``: the ``progress`` setting (:func:`progress_enabled`).
    ``timings``: see ``run_study``. Prints the execution plan (``search: ...``).
    """
    from icgo.core.execution import is_accelerator
    from icgo.studies import icgo_relm as study

    plan = scfg.execution()
    enable = progress_enabled(progress, is_accelerator(plan.backend))
    print(f"search: {plan.why}")  # information, on stdout: stderr is for the one error or interruption line
    if not enable or scfg.optimizer is None:
        return study.run_study(frame, scfg, meta, target=target, timings=timings)
    bar = Progress(desc)
    try:
        return study.run_study(frame, scfg, meta, target=target, timings=timings, progress=bar)
    finally:
        bar.close()


def method_label(method: str) -> str:
    """The method's name in every output (:func:`icgo.reporting.names.method_name`)."""
    from icgo.reporting.names import method_name

    return method_name(method)


def summary_table(result, split: str = "test"):
    """Printed/Markdown summary: per method MAE, RMSE, R^2 (mean +/- std over repeats) and evaluations."""
    import numpy as np
    import pandas as pd

    from icgo.reporting.records import SUMMARY_COLUMNS

    s = result.summary.xs(split, level="split")
    evals = dict(zip(result.config.method_names(), np.asarray(result.n_evals).mean(axis=1)))
    rows = []
    for m in s.index:
        rows.append({"method": m, "label": method_label(m), "n": int(s.loc[m, "n"]),
                     "MAE (deg)": s.loc[m, "mae"], "RMSE (deg)": s.loc[m, "rmse"], "R^2": s.loc[m, "r2"],
                     "R^2 of error": s.loc[m, "r2_error"],
                     "evaluations": int(evals[m]) if m in evals else 0})
    return pd.DataFrame(rows, columns=list(SUMMARY_COLUMNS))


def excluded_line(result) -> str | None:
    """The sentence naming the repeats a study left out (:func:`icgo.studies.icgo_relm_prepare.excluded_sentence`), or
    None."""
    from icgo.studies.icgo_relm_prepare import excluded_sentence

    return excluded_sentence(result.excluded, len(result.config.ids()) + len(result.excluded))


def run_output(outdir: Path, overwrite: bool):
    """The run directory as an :class:`icgo.io.files.Output`, checked (a used directory refused unless
    ``overwrite``; a failed attempt's marker does not count); Hydra's job log left alone."""
    from hydra.core.hydra_config import HydraConfig

    from icgo.io.files import Output

    keep = (f"{HydraConfig.get().job.name}.log",) if HydraConfig.initialized() else ()
    return Output(outdir, setting="the run directory", overwrite=overwrite, keep=keep, ignore=FAILURE_FILES,
                  writer="experiments.run").check()


def write_outputs(outdir: Path, cfg: DictConfig, result, info: dict, frame=None, meta=None, plot=None) -> dict:
    """Write the run directory all at once: config, tables, summary, fitted models, figure, then run.json.

    Everything is written into a staging directory inside ``outdir`` first; only when every file is complete
    is the previous content moved aside, the new files moved in (``os.replace``), ``run.json`` last, and the
    old content deleted (:class:`icgo.io.files.Output`). An interruption or a full disk before that leaves
    the previous run as it was (and no staging directory). Hydra's record of the job (``.hydra/``) is staged
    with the rest. File and column names come from :mod:`icgo.reporting.records`; the fitted models are saved
    with :meth:`icgo.models.format.FittedModel.save`.

    Args:
        frame, meta: the study's data and metadata; with a reference field in
            ``meta``, the survey-QC counts before and after MSA (:func:`icgo.survey.apply.study_qc`)
            go into the summary and the run record.
        plot: optional ``path -> None`` writing the study figure (``study.png``).
    Returns:
        The run.json dictionary.
    """
    from experiments._entry import write_hydra_record
    from icgo.reporting import records as run_records

    with run_output(outdir, overwrite=True).staged(last=(run_records.RUN_FILE,)) as stage:
        write_hydra_record(stage, cfg)
        run = _write_run_files(stage, cfg, result, info, frame, meta, plot, run_dir=outdir)
    return run


def _write_run_files(outdir: Path, cfg: DictConfig, result, info: dict, frame, meta, plot, run_dir=None) -> dict:
    """Every file of a run into ``outdir`` (the staging directory), run.json last; ``run_dir``: where they go."""
    import numpy as np

    from icgo.physics.qc import qc_sentence
    from icgo.reporting import records as run_records
    from icgo.studies.splits import describe as describe_split
    from icgo.survey.apply import study_qc
    from icgo.survey.verdict import study_verdict

    t0 = time.perf_counter()
    qc = None if frame is None else study_qc(frame[result.kept].reset_index(drop=True), meta, result.msa_model)

    outdir.mkdir(parents=True, exist_ok=True)
    (outdir / run_records.CONFIG_FILE).write_text(OmegaConf.to_yaml(cfg, resolve=True))
    tags = {"label": info["label"], "dataset": info["dataset"], "condition": info["condition"],
            "seed": result.config.seed}
    for name, df in result.records.items():
        checked = run_records.check_table(name, run_records.tag_table(df, tags), name)
        checked.to_csv(outdir / f"{name}.csv", index=False, float_format="%.10g")
    table = summary_table(result)
    table.to_csv(outdir / "summary.csv", index=False)
    excluded = excluded_line(result)
    md = [f"# ICGO-RELM study: {info['dataset']}", "",
          f"{describe_split(result.config.protocol, result.config.train_fraction).capitalize()}; "
          f"{len(result.config.ids())} repeats, mean +/- std (sample std). "
          f"Optimizer {cfg.optimizer.name or 'none (plain RELM)'}, strategies {list(cfg.strategy.names)}, "
          f"population {cfg.budget.pop_size}, iterations {cfg.budget.iterations}, "
          f"max_evals {cfg.budget.max_evals}.", "",
          table.drop(columns=["method"]).to_markdown(index=False), "",
          *([f"**{excluded}**", ""] if excluded else []),
          f"Wall time of the study: {result.wall_time_s:.1f} s (compile included); "
          f"whole job {info['total_time_s']:.1f} s.", "",
          f"Fitted models: `{result.model.KIND}` (method used by default: {result.model.selected}) and "
          f"`{result.msa_model.KIND}`."]
    if qc:
        md += ["", qc_sentence(qc)]
    verdict = study_verdict(result.metrics, result.coverage, selected=result.model.selected,
                            n_repeats=result.config.n_repeats, protocol=result.config.protocol, qc=qc,
                            trained=result.model.domain, run_dir=str(run_dir or outdir))
    md += ["", *verdict.markdown()]
    (outdir / "summary.md").write_text("\n".join(md) + "\n")
    if plot is not None:
        plot(outdir / "study.png")
    models = [result.model.save(outdir / result.model.KIND).name, result.msa_model.save(outdir / result.msa_model.KIND).name]
    methods = result.config.method_names()
    if "timings" in info:  # everything above, the run record's own few bytes aside
        info = {**info, "timings": {**info["timings"], "write_s": time.perf_counter() - t0}}
    run = {**info, "records_version": run_records.RECORDS_VERSION, "status": "ok", "seed": result.config.seed,
           "wall_time_s": result.wall_time_s, "methods": methods,
           "n_evals": {m: int(v) for m, v in zip(methods, np.asarray(result.n_evals)[:, 0])},
           "n_rows": int(result.kept.sum()), "n_repeats": result.config.n_repeats,
           "repeat_ids": list(result.config.ids()), "models": models, "qc": qc, "config_sha256": cfg_hash(cfg),
           "excluded_repeats": [{"repeat": int(r), "reason": why} for r, why in result.excluded]}
    if result.tuning is not None:
        run["tuning"] = result.tuning
    run["verdict"] = verdict.as_dict()
    missing = [k for k in run_records.RUN_KEYS if k not in run]
    assert not missing, f"run record lacks {missing}"  # a writer bug, not a user error
    (outdir / run_records.RUN_FILE).write_text(json.dumps(run, indent=2, default=str) + "\n")
    return run


def run_help() -> str:
    """``python -m experiments.run --help``: usage, the config groups with their options and defaults, the main
    keys, and where to read more (read from ``conf/``, so it never lists an option that does not exist)."""
    import yaml

    from experiments._entry import CONF_DIR, STUDY_GROUPS, group_options

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

