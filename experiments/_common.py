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

import json
import math
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
FAILED = "FAILED"  # == icgo.records.FAILED_FILE (checked by tests; this module must not import icgo at import)

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


# ------------------------------------------------------------------ checks
def _need(cond: bool, msg: str) -> None:
    if not cond:
        raise ConfigError(msg)


def _is_int(x) -> bool:
    return isinstance(x, int) and not isinstance(x, bool)


def check_config(cfg: DictConfig) -> None:
    """Validate the settings a study needs, cheaply and before any computation.

    Raises:
        ConfigError: one line naming the setting, its value and what is allowed.
    """
    from icgo.optim import OPTIMIZERS, STRATEGIES

    sp, bd, md, ft = cfg.split, cfg.budget, cfg.model, cfg.fitness
    _need(_is_int(sp.n_repeats) and sp.n_repeats >= 1,
          f"split.n_repeats must be an integer >= 1, got {sp.n_repeats!r}")
    _need(_is_int(sp.seed) and sp.seed >= 0, f"split.seed must be an integer >= 0, got {sp.seed!r}")
    _need(isinstance(sp.train_fraction, (int, float)) and 0.0 < sp.train_fraction < 1.0,
          f"split.train_fraction must be in (0, 1), got {sp.train_fraction!r}")
    _need(sp.sigma_filter is None or (isinstance(sp.sigma_filter, (int, float)) and sp.sigma_filter > 0),
          f"split.sigma_filter must be > 0 or null, got {sp.sigma_filter!r}")
    _need(_is_int(md.hidden) and md.hidden >= 1, f"model.hidden must be an integer >= 1, got {md.hidden!r}")
    _need(isinstance(md.lam, (int, float)) and math.isfinite(md.lam) and md.lam > 0,
          f"model.lam must be a number > 0, got {md.lam!r}")
    lo_hi = list(md.theta_bounds)
    _need(len(lo_hi) == 2 and lo_hi[0] < lo_hi[1], f"model.theta_bounds must be [low, high] with low < high, "
                                                   f"got {lo_hi}")
    _need(md.features in ("raw", "msa"), f"model.features must be 'raw' or 'msa', got {md.features!r}")
    _need(ft.mode in ("train", "validation", "kfold"),
          f"fitness.mode must be train, validation or kfold, got {ft.mode!r}")
    _need(0.0 < ft.val_fraction < 1.0, f"fitness.val_fraction must be in (0, 1), got {ft.val_fraction!r}")
    _need(_is_int(ft.k_folds) and ft.k_folds >= 2, f"fitness.k_folds must be an integer >= 2, got {ft.k_folds!r}")
    _need(cfg.msa.model in ("biases", "axial", "biases_scales"),
          f"msa.model must be biases, axial or biases_scales, got {cfg.msa.model!r}")
    _need(cfg.msa.reference in ("station_mean", "known"),
          f"msa.reference must be station_mean or known, got {cfg.msa.reference!r}")
    _need(cfg.dtype in ("float64", "float32"), f"dtype must be float64 or float32, got {cfg.dtype!r}")
    name = cfg.optimizer.name
    _need(name is None or name in OPTIMIZERS,
          f"optimizer.name {name!r} is not a registered optimizer; choose one of {sorted(OPTIMIZERS)} or none")
    strategies = list(cfg.strategy.names)
    bad = [s for s in strategies if s not in STRATEGIES]
    _need(len(strategies) >= 1 and not bad,
          f"strategy.names has unknown strategies {bad}; choose from {list(STRATEGIES)}")
    _need(len(set(strategies)) == len(strategies), f"strategy.names repeats a strategy: {strategies}")
    b = list(cfg.schedule.bounds)
    _need(len(b) == 2 and 0.0 < b[0] < b[1] < 1.0,
          f"schedule.bounds must be two fractions 0 < b1 < b2 < 1, got {b}")
    order = list(cfg.schedule.order)
    _need(len(order) == 3 and all(o in STRATEGIES[:4] for o in order),
          f"schedule.order must name 3 of {list(STRATEGIES[:4])}, got {order}")
    if name is not None:
        _need(_is_int(bd.pop_size) and bd.pop_size >= 4,
              f"budget.pop_size must be an integer >= 4, got {bd.pop_size!r}")
        _need((bd.iterations is None) != (bd.max_evals is None),
              "budget: give exactly one of budget.iterations and budget.max_evals (the other null)")
        if bd.iterations is not None:
            _need(_is_int(bd.iterations) and bd.iterations >= 1,
                  f"budget.iterations must be an integer >= 1, got {bd.iterations!r}")
        else:
            _need(_is_int(bd.max_evals) and bd.max_evals >= 1,
                  f"budget.max_evals must be an integer >= 1, got {bd.max_evals!r}")
    ds = cfg.dataset
    if ds.name == "csv":
        _need(OmegaConf.select(ds, "path", throw_on_missing=False) not in (None, "???"),
              "dataset.path is required with dataset=csv (dataset.path=/path/to/file.csv)")
        p = Path(str(ds.path)).expanduser()
        _need(p.is_file(), f"dataset.path {str(p)!r}: file not found")
    elif ds.name == "well_conditions":
        c = ds.condition
        _need(c is None or (_is_int(c) and 0 <= c <= 5),
              f"dataset.condition must be null or an integer 0-5 (Table 4 row), got {c!r}")
    else:
        _need(ds.name == "lab_casing", f"dataset.name must be lab_casing, well_conditions or csv, got {ds.name!r}")


def optimizer_config(cfg: DictConfig):
    """The optimizer's config object from ``optimizer.params`` (+ the schedule for CGO), or None."""
    name = cfg.optimizer.name
    if name is None:
        return None
    from icgo.optim import get

    params = dict(OmegaConf.to_container(cfg.optimizer.params, resolve=True) or {})
    if name == "cgo":
        params.setdefault("stage_bounds", tuple(float(x) for x in cfg.schedule.bounds))
        params.setdefault("stage_order", tuple(cfg.schedule.order))
    try:
        return get(name).config_cls(**params)
    except (TypeError, ValueError) as e:
        raise ConfigError(f"optimizer.params for {name}: {str(e).splitlines()[0]}") from None


def study_config(cfg: DictConfig):
    """:class:`icgo.study.StudyConfig` from a composed config (checked first)."""
    from icgo.study import StudyConfig

    check_config(cfg)
    opt = cfg.optimizer.name
    return StudyConfig(
        n_repeats=int(cfg.split.n_repeats), seed=int(cfg.split.seed), train_fraction=float(cfg.split.train_fraction),
        sigma_filter=None if cfg.split.sigma_filter is None else float(cfg.split.sigma_filter),
        msa_model=cfg.msa.model, msa_reference=cfg.msa.reference, msa_iterations=int(cfg.msa.iterations),
        features=cfg.model.features, hidden=int(cfg.model.hidden), lam=float(cfg.model.lam),
        fitness=cfg.fitness.mode, val_fraction=float(cfg.fitness.val_fraction), k_folds=int(cfg.fitness.k_folds),
        theta_bounds=tuple(float(x) for x in cfg.model.theta_bounds), optimizer=opt,
        strategies=tuple(cfg.strategy.names), pop_size=int(cfg.budget.pop_size),
        iterations=None if cfg.budget.iterations is None else int(cfg.budget.iterations),
        max_evals=None if cfg.budget.max_evals is None else int(cfg.budget.max_evals),
        optimizer_config=optimizer_config(cfg), dtype=cfg.dtype)


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

    Path(path).expanduser().mkdir(parents=True, exist_ok=True)
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


def run_with_progress(frame, scfg, meta, enable: bool, desc: str):
    """``icgo.study.run_study`` with a progress bar over the optimizer's iterations.

    The bar wraps the search's fitness (``run_study(wrap_fitness=...)``), so it
    advances from inside the scan; without an optimizer (plain RELM) there is no
    scan and no bar.
    """
    from icgo import study

    if not enable or scfg.optimizer is None:
        return study.run_study(frame, scfg, meta)
    from icgo.optim import iterations_for_budget

    n_iter = scfg.iterations if scfg.max_evals is None else iterations_for_budget(
        scfg.optimizer, scfg.pop_size, scfg.max_evals, scfg.optimizer_config)
    bar = Progress(int(n_iter) + 1, desc, True)
    try:
        return study.run_study(frame, scfg, meta, wrap_fitness=bar.wrap)
    finally:
        bar.close()


# ------------------------------------------------------------------ outputs
def method_label(method: str) -> str:
    """Paper-style label: ``cgo-three_stage`` -> ``ICGO-RELM (three_stage)``."""
    if method in ("raw", "msa"):
        return {"raw": "raw (eq. 1)", "msa": "MSA only"}[method]
    if method == "relm":
        return "RELM"
    if method.startswith("cgo-"):
        s = method[4:]
        return {"original": "CGO-RELM", "three_stage": "ICGO-RELM (three-stage)"}.get(s, f"CGO-RELM ({s})")
    return f"{method.upper()}-RELM"


def summary_table(result, split: str = "test"):
    """Printed/Markdown summary: per method MAE, RMSE, R^2 (mean +/- std over repeats) and evaluations."""
    import numpy as np
    import pandas as pd

    s = result.summary.xs(split, level="split")
    evals = dict(zip(result.config.method_names(), np.asarray(result.n_evals).mean(axis=1)))
    rows = []
    for m in s.index:
        rows.append({"method": m, "label": method_label(m), "n": int(s.loc[m, "n"]),
                     "MAE (deg)": s.loc[m, "mae"], "RMSE (deg)": s.loc[m, "rmse"], "R^2": s.loc[m, "r2"],
                     "R^2 of error": s.loc[m, "r2_error"],
                     "evaluations": int(evals[m]) if m in evals else 0})
    return pd.DataFrame(rows)


def write_outputs(outdir: Path, cfg: DictConfig, result, info: dict) -> dict:
    """Write the run directory: config, tables, summary, fitted models, then run.json.

    File and column names come from :mod:`icgo.records`; the fitted models
    (:class:`icgo.compensation.RELMCompensation` and the MSA-only model) are
    saved with :meth:`icgo.models.FittedModel.save`. ``run.json`` is written
    last, so a run record always describes complete files.

    Returns:
        The run.json dictionary.
    """
    import numpy as np

    from icgo import records as R

    outdir.mkdir(parents=True, exist_ok=True)
    (outdir / R.CONFIG_FILE).write_text(OmegaConf.to_yaml(cfg, resolve=True))
    tags = {"label": info["label"], "dataset": info["dataset"], "condition": info["condition"],
            "seed": result.config.seed}
    for name, df in (("metrics", result.metrics), ("convergence", result.histories),
                     ("predictions", result.predictions), ("msa", result.msa)):
        df = df.rename(columns={"condition": "condition_number"}) if name == "msa" else df
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
    (outdir / "summary.md").write_text("\n".join(md) + "\n")
    models = [result.model.save(outdir / result.model.KIND).name, result.msa_model.save(outdir / result.msa_model.KIND).name]
    methods = result.config.method_names()
    run = {**info, "records_version": R.RECORDS_VERSION, "status": "ok", "seed": result.config.seed,
           "wall_time_s": result.wall_time_s, "methods": methods,
           "n_evals": {m: int(v) for m, v in zip(methods, np.asarray(result.n_evals)[:, 0])},
           "n_rows": int(result.kept.sum()), "n_repeats": result.config.n_repeats, "models": models}
    missing = [k for k in R.RUN_KEYS if k not in run]
    assert not missing, f"run record lacks {missing}"  # a writer bug, not a user error
    (outdir / R.RUN_FILE).write_text(json.dumps(run, indent=2, default=str) + "\n")
    return run


def write_failure(outdir: Path, message: str, tb: str | None = None) -> None:
    """Leave the FAILED marker (one line) and, for unexpected errors, the traceback."""
    outdir.mkdir(parents=True, exist_ok=True)
    (outdir / FAILED).write_text(message.strip().splitlines()[0] + "\n")
    if tb:
        (outdir / "error.txt").write_text(tb)


class FailureReport(Callback):
    """Hydra callback: after a multirun, list failed jobs and exit with status 1 if any failed."""

    def on_multirun_end(self, config: DictConfig, **kwargs: Any) -> None:
        sweep = Path(str(config.hydra.sweep.dir))
        failed = sorted(sweep.glob(f"*/{FAILED}")) if sweep.is_dir() else []
        for f in failed:
            print(f"job {f.parent.name} failed: {f.read_text().strip()}", file=sys.stderr)
        if failed:
            print(f"{len(failed)} job(s) failed; the other jobs' results are in {sweep}", file=sys.stderr)
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
