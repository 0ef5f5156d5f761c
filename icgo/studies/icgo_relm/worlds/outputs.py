"""What a worlds run (``worlds=N``: the ICGO-RELM study on N independent simulated worlds) writes and prints.

Its run directory holds the study's tables with a ``world`` column (:data:`TABLES`; not the per-row predictions: a
model to apply comes from a one-world run), ``worlds.csv`` (each world's mean over its repeats per method),
``worlds_pooled.csv`` (per method: mean +/- std over worlds, first in k of N worlds), ``summary.md`` (both, the
ranking, the test over worlds with Holm, whether there are enough worlds for it, the development seeds),
``worlds.png`` (``figures=true``: each world's value and the pooled order) and ``run.json``.
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

from icgo.core.environment import environment

#: Tables of a worlds run directory (the one-world study's, less the per-row predictions).
TABLES = ("metrics", "convergence", "msa", "coverage")
WORLDS_FILE, POOLED_FILE, FIGURE_FILE = "worlds.csv", "worlds_pooled.csv", "worlds.png"


def methods_compared(result) -> list[str]:
    """The fitted methods of the run (its searched or plain RELMs), the baselines raw and MSA left out."""
    return list(result.config.method_names())


def summary(result, info: dict, search: str):
    """(per-world table, pooled table, Markdown lines) of a worlds run; ``search``: the sentence on the search
    settings."""
    from icgo.studies.icgo_relm.worlds import stats as world_tables
    from icgo.studies.common.splits import describe as describe_split
    from icgo.studies.icgo_relm.worlds.study import DEVELOPMENT_SEEDS

    per = world_tables.per_world(result.table("metrics"))
    methods = methods_compared(result)
    pooled = world_tables.pooled(per, methods)
    seeds = world_tables.seeds_text(result.seeds)
    dev = result.development
    md = [f"# ICGO-RELM study over {len(result.seeds)} worlds: {info['description']}", "",
          f"{describe_split(result.config.split.protocol, result.config.split.train_fraction).capitalize()}; "
          f"{len(result.config.ids())} repeats per world; each world is one independent simulated data set (data "
          f"seeds {seeds}: its own noise draw, filter, MSA, splits and search keys). A world's value is the mean over "
          f"its repeats; the numbers below are mean +/- sample std over worlds. {search}", "",
          (f"**Development seeds among these worlds: {world_tables.seeds_text(dev)}** (choices were made on them; "
           "icgo.studies.icgo_relm.worlds.study.DEVELOPMENT_SEEDS): do not report this run." if dev else
           "No world is a development seed (choices were made on data seeds "
           f"{world_tables.seeds_text(DEVELOPMENT_SEEDS)}; icgo.studies.icgo_relm.worlds.study.DEVELOPMENT_SEEDS)."), "",
          "## Pooled over worlds", "", pooled.to_markdown(index=False), ""]
    if len(methods) >= 2 and len(result.seeds) >= 2:
        tests = world_tables.first_against_rest(per, methods)
        note = world_tables.power_note(len(result.seeds), len(methods))
        md += [world_tables.rank_sentence(per, methods), "", *([f"**Note: {note}.**", ""] if note else []),
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


def write_run_files(stage: Path, result, info: dict, *, config_yaml: str, search: str, config_sha256: str,
                    figures: bool = False) -> dict:
    """Every file of a worlds run into ``stage`` (the staging directory; the staged write is the caller's), run.json
    last: the resolved config (``config_yaml``), the tables, the per-world and pooled tables, ``summary.md``
    (``search``: its sentence on the search settings), ``worlds.png`` (``figures``) and the run record
    (``config_sha256`` in it)."""
    from icgo.reporting import records as run_records

    t0 = time.perf_counter()
    (stage / run_records.CONFIG_FILE).write_text(config_yaml)
    tags = {"label": info["label"], "dataset": info["dataset"], "condition": info["condition"],
            "seed": result.config.split.seed}
    for name in TABLES:
        df = result.table(name)
        checked = run_records.check_table(name, run_records.tag_table(df, tags), name)
        checked.to_csv(stage / f"{name}.csv", index=False, float_format="%.10g")
    per, pooled, md = summary(result, info, search)
    per.to_csv(stage / WORLDS_FILE, index=False, float_format="%.10g")
    pooled.to_csv(stage / POOLED_FILE, index=False)
    (stage / "summary.md").write_text("\n".join(md) + "\n")
    methods_fitted = methods_compared(result)
    if figures and len(methods_fitted) >= 1:
        from icgo.studies.icgo_relm.worlds.figure import plot_worlds

        plot_worlds(per, methods_fitted, stage / FIGURE_FILE,
                    title=f"{info['description']}: {len(result.seeds)} worlds")
    methods = result.config.method_names()
    first = result.results[0]
    timings = {**info["timings"], "write_s": time.perf_counter() - t0}
    run = {**info, "timings": timings, "records_version": run_records.RECORDS_VERSION, "status": "ok",
           "seed": result.config.split.seed, "wall_time_s": result.wall_time_s, "methods": methods,
           "n_evals": {m: int(v) for m, v in zip(methods, first.n_evals[:, 0])},
           "n_rows": [int(r.kept.sum()) for r in result.results], "n_repeats": result.config.split.n_repeats,
           "repeat_ids": list(result.config.ids()), "models": [], "qc": None, "config_sha256": config_sha256,
           "worlds": {"seeds": list(result.seeds), "development_seeds": result.development},
           "excluded_repeats": [{"world": w, "repeat": r, "reason": why} for w, r, why in result.excluded]}
    run["environment"] = environment()  # what the numbers were made with (a table's stamp names it)
    missing = [k for k in run_records.RUN_KEYS if k not in run]
    assert not missing, f"run record lacks {missing}"  # a writer bug, not a user error
    (stage / run_records.RUN_FILE).write_text(json.dumps(run, indent=2, default=str) + "\n")
    return run


def print_summary(result, outdir: Path, t0: float) -> None:
    """The pooled table, the ranking and where the files are, on stdout."""
    from icgo.studies.icgo_relm.worlds import stats as world_tables

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
