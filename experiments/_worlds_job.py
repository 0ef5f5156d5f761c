"""The ``worlds=N`` job of ``python -m experiments.run``: the study on N independent simulated worlds.

World i is the configured simulated data set at data seed ``dataset.seed + i`` (its own noise draw, filter, MSA,
splits and keys: :mod:`icgo.studies.worlds`); every world's searches run as one sharded program. The run
directory holds the study's tables with a ``world`` column (``metrics``, ``convergence``, ``msa``, ``coverage``;
not the per-row predictions: a model to apply comes from a one-world run), ``worlds.csv`` (each world's mean
over its repeats per method), ``worlds_pooled.csv`` (per method: mean +/- std over worlds, first in k of N
worlds), ``summary.md`` (both, the ranking, the test over worlds with Holm, the development seeds) and
``run.json``.

Like :mod:`experiments._relm_job`, nothing here imports JAX at module import.
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

from omegaconf import DictConfig, OmegaConf

from icgo.core.errors import SettingError

#: Tables of a worlds run directory (the one-world study's, less the per-row predictions).
TABLES = ("metrics", "convergence", "msa", "coverage")
WORLDS_FILE, POOLED_FILE = "worlds.csv", "worlds_pooled.csv"


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
    from experiments import _relm_job as relm_job
    from icgo.core.execution import is_accelerator
    from icgo.studies.worlds import run_worlds

    t1 = time.perf_counter()
    worlds, desc = load_worlds(cfg)
    timings["load_data_s"] = time.perf_counter() - t1
    plan = scfg.execution(cells=len(worlds) * len(scfg.ids()))
    print(f"search: {plan.why}")
    bar = None
    if relm_job.progress_enabled(cfg.progress, is_accelerator(plan.backend)) and scfg.optimizer is not None:
        bar = relm_job.Progress(f"{desc} {'/'.join(scfg.method_names())}")
    try:
        return run_worlds(worlds, scfg, timings=timings, progress=bar), desc
    finally:
        if bar is not None:
            bar.close()


def methods_compared(result) -> list[str]:
    """The fitted methods of the run (its searched or plain RELMs), the baselines raw and MSA left out."""
    return list(result.config.method_names())


def summary(result, cfg: DictConfig, info: dict):
    """(per-world table, pooled table, Markdown lines) of a worlds run."""
    from icgo.reporting import worlds as world_tables
    from icgo.studies.splits import describe as describe_split
    from icgo.studies.worlds import DEVELOPMENT_SEEDS

    per = world_tables.per_world(result.table("metrics"))
    methods = methods_compared(result)
    pooled = world_tables.pooled(per, methods)
    seeds = world_tables.seeds_text(result.seeds)
    dev = result.development
    md = [f"# ICGO-RELM study over {len(result.seeds)} worlds: {info['description']}", "",
          f"{describe_split(result.config.protocol, result.config.train_fraction).capitalize()}; "
          f"{len(result.config.ids())} repeats per world; each world is one independent simulated data set (data "
          f"seeds {seeds}: its own noise draw, filter, MSA, splits and search keys). A world's value is the mean over "
          f"its repeats; the numbers below are mean +/- sample std over worlds. Optimizer "
          f"{cfg.optimizer.name or 'none (plain RELM)'}, strategies {list(cfg.strategy.names)}, population "
          f"{cfg.budget.pop_size}, iterations {cfg.budget.iterations}, max_evals {cfg.budget.max_evals}.", "",
          (f"**Development seeds among these worlds: {world_tables.seeds_text(dev)}** (choices were made on them; "
           "icgo.studies.worlds.DEVELOPMENT_SEEDS): do not report this run." if dev else
           "No world is a development seed (choices were made on data seeds "
           f"{world_tables.seeds_text(DEVELOPMENT_SEEDS)}; icgo.studies.worlds.DEVELOPMENT_SEEDS)."), "",
          "## Pooled over worlds", "", pooled.to_markdown(index=False), ""]
    if len(methods) >= 2 and len(result.seeds) >= 2:
        tests = world_tables.first_against_rest(per, methods)
        md += [world_tables.rank_sentence(per, methods), "",
               f"Wilcoxon signed-rank over worlds (paired by world, per-world mean test MAE), the first by pooled "
               f"mean against each other method, Holm over the {len(tests)} tests:", "",
               *world_tables.markdown_tests(tests), ""]
    elif len(methods) >= 2:
        md += [world_tables.rank_sentence(per, methods), "", "No test over worlds: one world.", ""]
    excluded = result.excluded
    if excluded:
        md += [f"**{len(excluded)} repeat(s) excluded (their MSA failed): "
               + "; ".join(f"world {w} repeat {r}: {why}" for w, r, why in excluded[:10]) + "**", ""]
    md += ["## Each world (mean over its repeats, test split)", "",
           per.astype({"world": str}).to_markdown(index=False, floatfmt=".4f"), "",
           f"Wall time of the study: {result.wall_time_s:.1f} s (compile included); whole job "
           f"{info['total_time_s']:.1f} s."]
    return per, pooled, md


def write_outputs(outdir: Path, cfg: DictConfig, result, info: dict) -> dict:
    """The run directory all at once (staged, run.json last: :func:`experiments._relm_job.write_outputs`' rule)."""
    from experiments import _relm_job as relm_job
    from experiments._entry import write_hydra_record
    from icgo.reporting import records as run_records

    t0 = time.perf_counter()
    with relm_job.run_output(outdir, overwrite=True).staged(last=(run_records.RUN_FILE,)) as stage:
        write_hydra_record(stage, cfg)
        (stage / run_records.CONFIG_FILE).write_text(OmegaConf.to_yaml(cfg, resolve=True))
        tags = {"label": info["label"], "dataset": info["dataset"], "condition": info["condition"],
                "seed": result.config.seed}
        for name in TABLES:
            df = result.table(name)
            checked = run_records.check_table(name, run_records.tag_table(df, tags), name)
            checked.to_csv(stage / f"{name}.csv", index=False, float_format="%.10g")
        per, pooled, md = summary(result, cfg, info)
        per.to_csv(stage / WORLDS_FILE, index=False, float_format="%.10g")
        pooled.to_csv(stage / POOLED_FILE, index=False)
        (stage / "summary.md").write_text("\n".join(md) + "\n")
        methods = result.config.method_names()
        first = result.results[0]
        timings = {**info["timings"], "write_s": time.perf_counter() - t0}
        run = {**info, "timings": timings, "records_version": run_records.RECORDS_VERSION, "status": "ok",
               "seed": result.config.seed, "wall_time_s": result.wall_time_s, "methods": methods,
               "n_evals": {m: int(v) for m, v in zip(methods, first.n_evals[:, 0])},
               "n_rows": [int(r.kept.sum()) for r in result.results], "n_repeats": result.config.n_repeats,
               "repeat_ids": list(result.config.ids()), "models": [], "qc": None,
               "config_sha256": relm_job.cfg_hash(cfg),
               "worlds": {"seeds": list(result.seeds), "development_seeds": result.development},
               "excluded_repeats": [{"world": w, "repeat": r, "reason": why} for w, r, why in result.excluded]}
        missing = [k for k in run_records.RUN_KEYS if k not in run]
        assert not missing, f"run record lacks {missing}"  # a writer bug, not a user error
        (stage / run_records.RUN_FILE).write_text(json.dumps(run, indent=2, default=str) + "\n")
    return run


def print_summary(result, outdir: Path, t0: float) -> None:
    """The pooled table, the ranking and where the files are, on stdout."""
    from icgo.reporting import worlds as world_tables

    per = world_tables.per_world(result.table("metrics"))
    methods = methods_compared(result)
    print(f"\nICGO-RELM study over {len(result.seeds)} worlds (data seeds {world_tables.seeds_text(result.seeds)}), "
          "test split, "
          f"mean +/- std over worlds of each world's mean over {len(result.config.ids())} repeats")
    print(world_tables.pooled(per, methods).drop(columns=["method"]).to_markdown(index=False))
    if len(methods) >= 2:
        print(world_tables.rank_sentence(per, methods))
    if result.development:
        print(f"note: development seed(s) {world_tables.seeds_text(result.development)} among the worlds "
              "(not for reporting)", file=sys.stderr)
    print(f"outputs: {outdir}")
    print(f"wall time: {time.perf_counter() - t0:.1f} s (study {result.wall_time_s:.1f} s incl. compile)")
