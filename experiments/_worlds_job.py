"""The ``worlds=N`` job of ``python -m experiments.run``: the study on N independent simulated worlds.

World i is the configured simulated data set at data seed ``dataset.seed + i`` (its own noise draw, filter, MSA,
splits and keys: :mod:`icgo.studies.worlds`); every world's searches run as one sharded program. What the run
directory holds: :mod:`icgo.studies.worlds_outputs`.

Like :mod:`experiments._relm_job`, nothing here imports JAX at module import.
"""

from __future__ import annotations

import time
from pathlib import Path

from omegaconf import DictConfig, OmegaConf

from icgo.core.errors import SettingError


def check(cfg: DictConfig) -> None:
    """The ``worlds`` setting: null, or an integer >= 1 on a simulated data set and a protocol without a target."""
    n = cfg.get("worlds")
    if n is None:
        return
    if isinstance(n, bool) or not isinstance(n, int) or n < 1:
        raise SettingError(f"worlds must be null (one data set) or an integer >= 1 (that many independent simulated "
                           f"worlds), got {n!r}")
    if cfg.dataset.name == "csv":
        raise SettingError("worlds=N draws N simulated data sets (data seeds dataset.seed .. dataset.seed + N - 1); "
                           "dataset=csv is one recording: leave worlds=null")
    if OmegaConf.select(cfg, "split.protocol") == "transfer":
        raise SettingError("worlds=N with split=transfer is not supported (a second instrument per world); run one "
                           "world at a time")


def load_worlds(cfg: DictConfig):
    """(the :class:`icgo.studies.worlds.World` s, description) of ``worlds`` data seeds from ``dataset.seed``."""
    from experiments._relm_job import select_condition
    from icgo.studies.worlds import World, simulate, world_seeds

    ds = cfg.dataset
    kwargs = dict(OmegaConf.to_container(ds.kwargs, resolve=True) or {})
    try:
        worlds = simulate(ds.name, world_seeds(int(ds.seed), int(cfg.worlds)), **kwargs)
    except TypeError as e:
        raise SettingError(f"dataset.kwargs for {ds.name}: {str(e).splitlines()[0]}") from None
    cond = OmegaConf.select(ds, "condition")
    if cond is not None:
        worlds = [World(w.seed, select_condition(w.frame, int(cond)), w.meta) for w in worlds]
    first, last = worlds[0].seed, worlds[-1].seed
    return worlds, f"{ds.name}{f'[{cond}]' if cond is not None else ''} worlds {first}-{last}"


def run_study(cfg: DictConfig, scfg, timings: dict):
    """Load the worlds and run them (:func:`icgo.studies.worlds.run_worlds`), with the plan line and a bar."""
    from icgo.core.execution import is_accelerator
    from icgo.studies.icgo_relm_progress import Progress, progress_enabled
    from icgo.studies.worlds import run_worlds

    t1 = time.perf_counter()
    worlds, desc = load_worlds(cfg)
    timings["load_data_s"] = time.perf_counter() - t1
    plan = scfg.execution(cells=len(worlds) * len(scfg.ids()))
    print(f"search: {plan.why}")
    bar = None
    if progress_enabled(cfg.progress, is_accelerator(plan.backend)) and scfg.optimizer is not None:
        bar = Progress(f"{desc} {'/'.join(scfg.method_names())}")
    try:
        return run_worlds(worlds, scfg, timings=timings, progress=bar), desc
    finally:
        if bar is not None:
            bar.close()


def write_outputs(outdir: Path, cfg: DictConfig, result, info: dict) -> dict:
    """The run directory all at once (:func:`icgo.studies.worlds_outputs.write_run_files`; staged, run.json last:
    :func:`experiments._relm_job.write_outputs`' rule). Returns the run.json dictionary."""
    from experiments import _relm_job as relm_job
    from hydra_plugins.icgo_launcher.door import write_hydra_record
    from icgo.reporting import records as run_records
    from icgo.studies.worlds_outputs import write_run_files

    with relm_job.run_output(outdir, overwrite=True).staged(last=(run_records.RUN_FILE,)) as stage:
        write_hydra_record(stage, cfg)
        return write_run_files(stage, result, info, config_yaml=OmegaConf.to_yaml(cfg, resolve=True),
                               search=relm_job.search_sentence(cfg), config_sha256=relm_job.cfg_hash(cfg))
