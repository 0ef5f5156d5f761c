"""One run of the ICGO-RELM study's front door from its typed config
(:class:`icgo.studies.icgo_relm.run_config.RunConfig`): the data loaded (:mod:`icgo.studies.icgo_relm.load`), the
study run with its progress bar (one data set, or ``worlds=N``: :mod:`icgo.studies.icgo_relm.worlds.study`), its run record's
fields, and the run directory written all at once (:class:`icgo.io.files.Output`: staged, ``run.json`` last; what
it holds: :mod:`icgo.studies.icgo_relm.outputs`, :mod:`icgo.studies.icgo_relm.worlds.outputs`).

Nothing here imports JAX at module import; the functions import the study.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path
from typing import NamedTuple


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
        from icgo.studies.icgo_relm.load import load_data, load_target
        from icgo.studies.icgo_relm.progress import run_with_progress

        frame, meta, desc = load_data(run)
        target = load_target(run)
        timings["load_data_s"] = time.perf_counter() - t1
        result = run_with_progress(frame, scfg, meta, run.progress, desc=f"{desc} {'/'.join(scfg.method_names())}",
                                   target=target, timings=timings, jax_cache_dir=run.jax_cache_dir)
        return Computed(result, desc, frame, meta)
    from icgo.core.execution import is_accelerator
    from icgo.studies.icgo_relm.load import load_worlds
    from icgo.studies.icgo_relm.progress import make_progress
    from icgo.studies.common.run_log import to_log_files
    from icgo.studies.icgo_relm.progress import announce
    from icgo.studies.icgo_relm.worlds.study import run_worlds
    from icgo.studies.icgo_relm.worlds.stats import power_note

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
