"""One run of the ICGO-RELM study's front door from its typed config
(:class:`icgo.studies.icgo_relm.run_config.RunConfig`):

- the data loaded: :func:`load_data` (the configured data set, a simulation of :data:`icgo.datasets.registry.DATASETS`
  or a recording), :func:`load_target` (the second instrument's survey of ``split=transfer``), :func:`load_worlds`
  (the worlds of ``worlds=N``, :mod:`icgo.studies.icgo_relm.worlds.study`); every failure one line
  (:class:`icgo.core.errors.SettingError` naming the YAML key, or :class:`icgo.core.errors.DataError`);
- the study run with its progress bar (:func:`compute`), its run record's fields (:func:`run_info`);
- the run directory written all at once (:func:`write_run`: :class:`icgo.io.files.Output`, staged, ``run.json`` last;
  what it holds: :mod:`icgo.studies.icgo_relm.outputs`, :mod:`icgo.studies.icgo_relm.worlds.outputs`).

Nothing here imports JAX at module import; the functions import the study.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path
from typing import NamedTuple

from icgo.core.errors import SettingError


class Computed(NamedTuple):
    """What a run computed: the study's result (a StudyResult, or a WorldsResult for ``worlds=N``), the data's
    description, and the single data set's frame and metadata (None for worlds)."""

    result: object
    desc: str
    frame: object = None
    meta: dict | None = None


def run_output(outdir: Path, overwrite: bool, keep=(), ignore=()):
    """The run directory as an :class:`icgo.io.files.Output`, checked: a used directory is refused unless
    ``overwrite``; ``keep``: names left alone (Hydra's job log); ``ignore``: a failed attempt's files."""
    from icgo.io.files import Output

    return Output(outdir, setting="the run directory", overwrite=overwrite, keep=keep, ignore=ignore,
                  writer="experiments.run").check()


def start_and_compute(run, t0: float) -> tuple[Computed, dict]:
    """The devices started (before JAX's backend: ``jax.distributed``, the CPU's host devices), every setting
    checked (:meth:`RunConfig.study_config`), the compilation cache on, then :func:`compute`; returns what it
    computed and :func:`run_info`. ``t0``: ``time.perf_counter()`` at the job's start."""
    from icgo.core.devices import enable_jax_cache, start_devices

    devices = start_devices()
    scfg = run.study_config()  # every check before any computation (imports the study, JAX with it)
    timings = {"import_s": time.perf_counter() - t0}
    enable_jax_cache(run.jax_cache_dir)
    computed = compute(run, scfg, timings)
    return computed, run_info(run, computed.desc, timings, devices, t0)


def compute(run, scfg, timings: dict) -> Computed:
    """Load the data and run the study (``scfg``: ``run.study_config()``) with the plan line, the search's estimated
    time and its progress (:mod:`icgo.studies.icgo_relm.progress`); ``timings`` gets ``load_data_s`` and the
    study's stages. A worlds run also says when it has too few worlds for its test to reach p < 0.05."""
    t1 = time.perf_counter()
    if run.worlds is None:
        from icgo.studies.icgo_relm.progress import run_with_progress

        frame, meta, desc = load_data(run)
        target = load_target(run)
        timings["load_data_s"] = time.perf_counter() - t1
        result = run_with_progress(frame, scfg, meta, run.progress, desc=f"{desc} {'/'.join(scfg.method_names())}",
                                   target=target, timings=timings, jax_cache_dir=run.jax_cache_dir)
        return Computed(result, desc, frame, meta)
    from icgo.core.execution import is_accelerator
    from icgo.studies.common.run_log import to_log_files
    from icgo.studies.icgo_relm.progress import announce, make_progress
    from icgo.studies.icgo_relm.worlds.stats import power_note
    from icgo.studies.icgo_relm.worlds.study import run_worlds

    worlds, desc = load_worlds(run)
    timings["load_data_s"] = time.perf_counter() - t1
    note = power_note(len(worlds), len(scfg.method_names()))
    if note:
        print(f"note: {note}", file=sys.stderr)
        to_log_files(f"note: {note}")
    plan = scfg.execution(cells=len(worlds) * len(scfg.ids()))
    print(f"search: {plan.why}")
    bar = None
    if scfg.optimizer is not None:
        est = announce(scfg, plan, len(worlds) * len(scfg.ids()), len(worlds[0].frame), run.jax_cache_dir)
        bar = make_progress(run.progress, f"{desc} {'/'.join(scfg.method_names())}", is_accelerator(plan.backend),
                            est.evals_per_iteration, est.record)
    try:
        return Computed(run_worlds(worlds, scfg, timings=timings, progress=bar), desc)
    finally:
        if bar is not None:
            bar.close()


def run_info(run, desc: str, timings: dict, devices: dict, t0: float) -> dict:
    """The run record's fields known before the study's files are written (label, data set, search settings,
    execution plan, timings, devices, environment); ``t0``: ``time.perf_counter()`` at the job's start."""
    from icgo.core.devices import env_info

    ds, opt = run.dataset, run.optimizer
    return {"label": run.label, "dataset": ds.name, "condition": ds.condition, "description": desc,
            "dataset_kwargs": ds.kwargs, "optimizer": opt.name, "strategies": list(run.strategy.names),
            "schedule": run.schedule_record(), "optimizer_params": opt.params if opt.name else None,
            "execution": timings.pop("execution"), "timings": timings, "devices": devices,
            "total_time_s": time.perf_counter() - t0, **env_info()}


def write_run(outdir: Path, run, computed: Computed, info: dict, *, config_yaml: str, config_sha256: str,
              records: dict | None = None, keep=(), ignore=()) -> dict:
    """Write the run directory all at once; ``records``: further files (relative path -> text, e.g. Hydra's
    ``.hydra/`` record of the job) staged with the rest. An interruption or a full disk before the move leaves
    the previous run as it was. Returns the run.json dictionary."""
    from icgo.reporting import records as run_records

    with run_output(outdir, True, keep, ignore).staged(last=(run_records.RUN_FILE,)) as stage:
        for name, text in (records or {}).items():
            (stage / name).parent.mkdir(parents=True, exist_ok=True)
            (stage / name).write_text(text)
        common = {"config_yaml": config_yaml, "search": run.search_sentence(), "config_sha256": config_sha256}
        if run.worlds is not None:
            from icgo.studies.icgo_relm.worlds.outputs import write_run_files as write_worlds

            return write_worlds(stage, computed.result, info, **common, figures=run.figures)
        from icgo.studies.icgo_relm.outputs import write_run_files

        plot = None
        if run.figures:
            from icgo.studies.icgo_relm.figure import plot_study

            def plot(path):
                plot_study(computed.result, path, title=computed.desc)

        return write_run_files(stage, computed.result, info, computed.frame, computed.meta, plot, **common,
                               run_dir=outdir)


def print_run(run, computed: Computed, record: dict, outdir: Path, t0: float) -> None:
    """The summary on stdout (:func:`icgo.studies.icgo_relm.outputs.print_summary`, or the worlds' one)."""
    if run.worlds is not None:
        from icgo.studies.icgo_relm.worlds.outputs import print_summary as print_worlds

        print_worlds(computed.result, outdir, t0)
        return
    from icgo.studies.icgo_relm.outputs import print_summary

    print_summary(computed.result, computed.desc, record, outdir, t0)

def load_data(run):
    """(frame, metadata, description) of ``run.dataset``.

    Raises:
        SettingError / icgo.core.errors.DataError: one line (missing file, bad CSV, unknown data set).
    """
    ds = run.dataset
    if ds.name == "csv":
        from icgo.io.recording import column_map, read_recording

        cmap = column_map(ds.columns or None, ds.columns_file, "dataset.columns")
        rec = read_recording(Path(str(ds.path)).expanduser(), require_meta=ds.require_meta, columns=cmap,
                             column_setting="dataset.columns")
        for line in rec.notices:  # what the reader noticed but accepted (icgo.io.recording check prints the same)
            print(f"notice: {line}", file=sys.stderr)
        return rec.frame, dict(rec.meta), f"csv:{ds.path}"
    from icgo.datasets.registry import DATASETS

    fn = DATASETS.get(ds.name)
    if fn is None:
        raise SettingError(f"dataset {ds.name!r}: icgo.datasets.registry.DATASETS has no such data set")
    try:
        data = fn(int(ds.seed), **ds.kwargs)
    except TypeError as e:
        raise SettingError(f"dataset.kwargs for {ds.name}: {str(e).splitlines()[0]}") from None
    frame, meta, desc = data.frame, dict(data.meta), ds.name
    if ds.condition is not None:
        frame, desc = select_condition(frame, int(ds.condition)), f"{ds.name}[{ds.condition}]"
    return frame, meta, desc


def load_target(run):
    """The second instrument's survey of ``split=transfer`` (a DataFrame), or None for other protocols.

    ``split.target.path`` reads a recording; otherwise the data set's simulator draws the target with the changes
    of ``split.target`` (:func:`icgo.studies.common.splits.transfer_survey`).

    Raises:
        SettingError / icgo.core.errors.DataError: one line.
    """
    target = run.split.target
    if run.split.protocol != "transfer" or target is None:
        return None
    if target.path is not None:
        from icgo.io.recording import read_recording

        return read_recording(Path(str(target.path)).expanduser(), require_meta=False).frame
    from icgo.studies.common.splits import TransferDraw, transfer_survey

    ds = run.dataset
    if ds.name == "csv":
        raise SettingError("split=transfer on dataset=csv needs split.target.path (a recording of the second "
                           "instrument); only the simulated data sets can draw one")
    try:
        return transfer_survey(ds.name, int(ds.seed), dict(ds.kwargs), TransferDraw(**target.draw())).frame
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


def load_worlds(run):
    """(the :class:`icgo.studies.icgo_relm.worlds.study.World` s, description) of ``run.worlds`` data seeds from
    ``dataset.seed``."""
    from icgo.studies.icgo_relm.worlds.study import World, simulate, world_seeds

    ds = run.dataset
    try:
        worlds = simulate(ds.name, world_seeds(int(ds.seed), int(run.worlds)), **ds.kwargs)
    except TypeError as e:
        raise SettingError(f"dataset.kwargs for {ds.name}: {str(e).splitlines()[0]}") from None
    cond = ds.condition
    if cond is not None:
        worlds = [World(w.seed, select_condition(w.frame, int(cond)), w.meta) for w in worlds]
    first, last = worlds[0].seed, worlds[-1].seed
    return worlds, f"{ds.name}{f'[{cond}]' if cond is not None else ''} worlds {first}-{last}"
