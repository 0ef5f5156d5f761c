"""Table 1, Table 3 and Fig. 9 over independent simulated worlds: ``results/{table1,table3,fig9}_worlds.{md,csv}``.

:func:`build` (``python -m experiments.worlds_tables``) reads the worlds runs (``worlds=N``; the presets
``experiment={table1,table3,fig9}_worlds``) under the given directories (default: :data:`PLAN`'s) and writes, per
table: the pooled result (mean +/- std over worlds of each world's mean over its repeats, and in how
many worlds each method is first), the paper's value beside ours, the tests over worlds (Wilcoxon signed-rank
paired by world, Friedman; Holm per family), the ranking, the per-world table (``<name>_per_world.csv``) and what
changed against the one-draw result of ``results/<name>.csv`` (data seed 0). :func:`plan_command` gives the command
that makes each entry of :data:`PLAN`.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pandas as pd

from icgo.io.files import RESULTS_DIR
from icgo.reporting import stamp

#: (name, preset, extra overrides, whether the preset is a multirun): the runs each table is made from, into
#: ``multirun/worlds/<name>``.
_TUNED = ["optimizer=none", "model.tune=true", "fitness=validation"]
PLAN = (("table3", "table3_worlds", [], False), ("table1", "table1_worlds", [], True),
        ("table1_tuned", "table1_worlds", _TUNED, True), ("fig9", "fig9_worlds", [], True))
#: The same for the worlds over a family of instruments (``--plan instruments``): ``results/*_instruments.*``.
INSTRUMENT_PLAN = (("table3_instruments", "table3_instruments", [], False),
                   ("table1_instruments", "table1_instruments", [], True),
                   ("table1_instruments_tuned", "table1_instruments", _TUNED, True))
#: What the spread beside the paper's Table 3 value is (its std over repeats of one data set, not over worlds).
TABLE3_PAPER_SPREAD = "(std over its 10 repeats of one data set)"
#: The legend under each pooled table: what the spreads beside ours and beside the paper's are.
COLUMNS_NOTE = ("Columns: `MAE (deg)` and the other metrics are the mean +/- sample std over the worlds of each world's "
                "mean over its repeats (a spread over data sets); `MAE (deg) paper` is the paper's value as it prints "
                "it: Table 3's mean +/- std over its 10 repeats of one data set (a spread over splits and search keys, "
                "not over worlds), Table 1's and Fig. 9's one split.")
#: The output each preset label feeds: its file stem (``results/<stem>.{md,csv}``, ``<stem>_per_world.csv``); the
#: table it restates is the stem's first part.
LABELS = {"table3_worlds": "table3_worlds", "table1_worlds": "table1_worlds", "fig9_worlds": "fig9_worlds",
          "table3_instruments": "table3_instruments", "table1_instruments": "table1_instruments"}


def plan_command(name: str, base: Path = Path("multirun/worlds")) -> list[str]:
    """The command that makes the runs of plan entry ``name``."""
    _, preset, extra, multi = next(p for p in PLAN + INSTRUMENT_PLAN if p[0] == name)
    where = f"hydra.sweep.dir={base / name}" if multi else f"hydra.run.dir={base / name}"
    return [sys.executable, "-m", "experiments.run", *(["-m"] if multi else []), f"experiment={preset}", *extra, where]


def read_runs(dirs) -> dict[str, list[tuple[Path, dict]]]:
    """Every finished worlds run (a run.json with ``worlds``) under ``dirs``, grouped by the table it feeds."""
    out: dict[str, list] = {}
    for d in dirs:
        for rec in sorted(Path(d).rglob("run.json")):
            try:
                run = json.loads(rec.read_text())
            except (OSError, ValueError):
                continue
            if run.get("status") == "ok" and run.get("worlds") and run.get("label") in LABELS:
                out.setdefault(LABELS[run["label"]], []).append((rec.parent, run))
    return out


def per_world(runs) -> tuple[pd.DataFrame, list[dict], list[int]]:
    """(per-world table of every run's methods, the runs' settings, the worlds' seeds)."""
    from icgo.studies.icgo_relm.worlds import stats as world_tables

    parts, seeds = [], set()
    for d, run in runs:
        parts.append(world_tables.per_world(pd.read_csv(d / "metrics.csv")))
        seeds |= set(run["worlds"]["seeds"])
    per = pd.concat(parts, ignore_index=True).drop_duplicates(["world", "method"], keep="last")
    return per, [stamp.run_settings(d) for d, _ in runs], sorted(seeds)


def _one_draw(name: str, results: Path) -> dict[str, float] | None:
    """The one-draw mean MAE (data seed 0) of each method of ``results/<name>.csv``, or None when absent."""
    from icgo.studies.icgo_relm.names import STRATEGY_NAMES, method_name

    path = results / f"{name}.csv"
    if not path.is_file():
        return None
    df = pd.read_csv(path)
    mean = (lambda v: float(str(v).split("+/-")[0]))
    if name == "table3":
        back = {n: f"cgo-{s}" for s, n in STRATEGY_NAMES.items()}
        return {back[r.strategy]: mean(r["MAE (deg) ours"]) for _, r in df.iterrows() if r.strategy in back}
    if name == "fig9":
        back = {method_name(m): m for m in ("pso", "ga", "cgo-original")}
        return {back[r.method]: float(r.mae_mean) for _, r in df.iterrows() if r.method in back}
    row = df[df.metric == "MAE (deg)"].iloc[0]
    cols = {"relm": "RELM (ours)", "relm-tuned": "tuned RELM (ours)", "cgo-original": "CGO-RELM (ours)"}
    return {m: mean(row[c]) for m, c in cols.items() if c in df.columns}


def changed_note(name: str, per: pd.DataFrame, methods, results: Path) -> str:
    """What the worlds say against the one-draw table: its order, and in how many worlds its first is first."""
    from icgo.studies.icgo_relm.worlds import stats as world_tables
    from icgo.studies.icgo_relm.names import method_name

    one = _one_draw(name, results)
    if not one or not all(m in one for m in methods):
        return f"No one-draw `results/{name}.csv` with these methods to compare with."
    one_order = sorted(methods, key=lambda m: one[m])
    order = world_tables.order(per, methods)
    firsts = world_tables.first_counts(per, methods)
    n = len(world_tables.wide(per, methods))
    same = one_order == order
    return (f"Against the one-draw result (`results/{name}.md`, data seed 0, a development seed): its order by mean "
            f"MAE was {' < '.join(method_name(m) for m in one_order)}; over {n} worlds the pooled order is "
            f"{' < '.join(method_name(m) for m in order)} ({'the same order' if same else 'a different order'}). The "
            f"one-draw first, {method_name(one_order[0])}, is first in {int(firsts[one_order[0]])} of {n} worlds.")


def _protocol(stem: str, seeds, settings, test: str) -> str:
    from icgo.studies.icgo_relm.worlds import stats as world_tables
    from icgo.reporting.protocol import protocol_line
    from icgo.studies.icgo_relm.worlds.study import DEVELOPMENT_SEEDS

    family = stem.endswith("_instruments")
    plan, name = (INSTRUMENT_PLAN, stem) if family else (PLAN, stem.removesuffix("_worlds"))
    cmd = f"`python -m experiments.worlds_tables --run{' --plan instruments' if family else ''}` (the runs " + ", ".join(
        f"`python {' '.join(plan_command(p[0])[1:])}`" for p in plan if p[0].startswith(name)) + ")"
    data = (f"lab_casing with instrument=family, data seeds {world_tables.seeds_text(seeds)} (one world each: its "
            "instrument drawn once from icgo.datasets.instrument_family.LAB_RANGES, its noise drawn as in every world)"
            if family else f"lab_casing noise seeds {world_tables.seeds_text(seeds)} (one world each, one instrument)")
    n_rep = sorted({s.get("n_repeats") for s in settings if s.get("n_repeats")})
    return protocol_line(
        cmd, f"{len(seeds)} worlds, each the mean over its {', '.join(map(str, n_rep)) or '?'} repeats (paired: the "
             "same worlds, splits and keys for every method)",
        "random 7:3 of each world's 3-sigma-filtered rows, a new permutation per repeat; fitted (search fitness, "
        "MSA, ridge) on the training rows only, scored on the test rows",
        f"data: {data}; world s, repeat k: split "
        f"and search key fold_in(fold_in(PRNGKey(0), s), k). No world is a seed any choice was made on (development "
        f"seeds {world_tables.seeds_text(DEVELOPMENT_SEEDS)}: icgo.studies.icgo_relm.worlds.study.DEVELOPMENT_SEEDS)", test)


def _write(out: Path, stem: str, title: str, pooled: pd.DataFrame, per: pd.DataFrame, methods, notes, protocol,
           settings) -> None:
    from icgo.studies.icgo_relm.worlds.stats import wide

    pooled.to_csv(out / f"{stem}.csv", index=False)
    per.to_csv(out / f"{stem}_per_world.csv", index=False, float_format="%.10g")
    stamp_line = stamp.describe(settings)["text"]
    each = wide(per, methods).reset_index()
    each["world"] = each["world"].astype(int).astype(str)
    text = [f"# {title}", "", *([stamp_line, ""] if stamp_line else []), protocol, "",
            pooled.to_markdown(index=False), "", COLUMNS_NOTE, "", *notes, "",
            "## Each world: mean test MAE (deg) over its repeats", "",
            each.to_markdown(index=False, floatfmt=".4f"), ""]
    (out / f"{stem}.md").write_text("\n".join(text).rstrip() + "\n")


def _with_paper(pooled: pd.DataFrame, paper: dict) -> pd.DataFrame:
    """The paper's MAE beside ours (its value, or a dash where it gives none)."""
    pooled = pooled.copy()
    pooled.insert(pooled.columns.get_loc("MAE (deg)") + 1, "MAE (deg) paper",
                  [paper.get(m, "(not in the paper)") for m in pooled["method"]])
    return pooled


def _title(stem: str, table: str, n: int) -> str:
    """"Table 3 over 30 worlds" or, for a family of instruments, "Table 3 over 10 instruments"."""
    return f"{table} over {n} " + ("instruments (worlds of an instrument family)" if stem.endswith("_instruments")
                                   else "worlds")


def table3(per, seeds, settings, out: Path, results: Path, stem: str = "table3_worlds") -> None:
    from icgo.maths.stats import holm
    from icgo.studies.icgo_relm.worlds import stats as world_tables
    from icgo.studies.icgo_relm.names import method_name
    from icgo.reporting.published import ICGO
    from icgo.studies.icgo_relm.results.notes import STRATEGIES4

    four = [f"cgo-{s}" for s in STRATEGIES4 if f"cgo-{s}" in set(per.method)]  # the registry's mutated ones run
    singles = [m for m in four if m != "cgo-three_stage"]
    methods = ["cgo-original", *four]
    paper = {f"cgo-{s}": f"{v[0][0]:.4f} +/- {v[0][1]:.4f} {TABLE3_PAPER_SPREAD}" for s, v in ICGO["table3"].items()}
    pooled = _with_paper(world_tables.pooled(per, methods), paper)
    fr = [(k, world_tables.friedman_over_worlds(per, four, k)) for k in ("mae", "rmse")]
    fr_holm = holm([t.p_value for _, t in fr])
    wil = pd.concat([world_tables.paired_tests(per, [("cgo-three_stage", m) for m in singles], k).assign(metric=k)
                     for k in ("mae", "rmse")], ignore_index=True)
    wil["p (Holm)"] = holm(wil["p"].to_numpy())  # one family: both metrics, as the one-draw Table 3
    from icgo.reporting.protocol import comparison

    wil["verdict"] = [comparison(method_name(r.a), method_name(r.b), r["p (Holm)"], r["median difference a - b"],
                                 family=len(wil)) + f" [{r.metric.upper()}]" for _, r in wil.iterrows()]
    notes = [changed_note("table3", per, methods, results), "", world_tables.rank_sentence(per, methods), "",
             *(f"- Friedman over worlds of the {len(four)} mutated strategies ({k.upper()}): chi2 = {t.statistic:.2f}, p = "
               f"{p:.3g} (Holm over the 2 Friedman tests); mean ranks: "
               + ", ".join(f"{method_name(m)} {t.mean_ranks[m]:.2f}" for m in four) + "."
               for (k, t), p in zip(fr, fr_holm)), "",
             f"Wilcoxon signed-rank over worlds (paired by world), three-stage against each single strategy, MAE and "
             f"RMSE, Holm over the {len(wil)} tests:", "", *world_tables.markdown_tests(wil)]
    test = (f"Friedman over worlds of the {len(four)} mutated strategies (MAE, RMSE: Holm over these 2) and Wilcoxon "
            f"signed-rank over worlds of three-stage against each single strategy (MAE, RMSE: Holm over these {len(wil)})")
    _write(out, stem, f"{_title(stem, 'Table 3', len(seeds))}: mean +/- std over worlds (test split)", pooled, per,
           methods, notes, _protocol(stem, seeds, settings, test), settings)


def _pairs_table(stem, title, methods, pairs, paper, per, seeds, settings, out, results) -> None:
    from icgo.studies.icgo_relm.worlds import stats as world_tables

    methods = [m for m in methods if m in set(per["method"])]
    pairs = [(a, b) for a, b in pairs if a in methods and b in methods]
    pooled = _with_paper(world_tables.pooled(per, methods), paper)
    tests = world_tables.paired_tests(per, pairs)
    notes = [changed_note(stem.split("_")[0], per, methods, results), "", world_tables.rank_sentence(per, methods), "",
             f"Wilcoxon signed-rank over worlds (paired by world, per-world mean test MAE), Holm over the {len(tests)} "
             "tests:", "", *world_tables.markdown_tests(tests)]
    test = f"Wilcoxon signed-rank over worlds on test MAE, Holm over the {len(tests)} tests below"
    _write(out, stem, title, pooled, per, methods, notes, _protocol(stem, seeds, settings, test), settings)


def table1(per, seeds, settings, out: Path, results: Path, stem: str = "table1_worlds") -> None:
    from icgo.reporting.published import ICGO

    paper = {m: f"{v[0]:.4f} (one split)" for m, v in ICGO["table1"].items()}
    _pairs_table(stem, f"{_title(stem, 'Table 1', len(seeds))}: RELM vs CGO-RELM (test split)",
                 ["relm", "relm-tuned", "cgo-original"], [("cgo-original", "relm"), ("cgo-original", "relm-tuned")],
                 paper, per, seeds, settings, out, results)


def fig9(per, seeds, settings, out: Path, results: Path, stem: str = "fig9_worlds") -> None:
    from icgo.reporting.published import ICGO

    paper = {m: f"{v[0]:.3f} (one split)" for m, v in ICGO["fig9"].items()}
    _pairs_table(stem, f"{_title(stem, 'Fig. 9', len(seeds))}: RELM tuned by PSO, GA and CGO (test split)",
                 ["pso", "ga", "cgo-original"], [("cgo-original", "pso"), ("cgo-original", "ga")], paper, per, seeds,
                 settings, out, results)


BUILDERS = {"table3": table3, "table1": table1, "fig9": fig9}


def build(dirs, out: Path, results: Path = RESULTS_DIR) -> list[str]:
    """Every table whose runs are under ``dirs`` into ``out`` (the one-draw tables compared with are read from
    ``results``); returns the names written."""
    out.mkdir(parents=True, exist_ok=True)
    done = []
    for stem, runs in read_runs(dirs).items():
        per, settings, seeds = per_world(runs)
        BUILDERS[stem.split("_")[0]](per, seeds, settings, out, results, stem=stem)
        done.append(stem)
    if done:
        from icgo.studies.icgo_relm.results import worlds_orders

        worlds_orders.build(out)  # the pairs of every table whose per-world rows are in out (this build's or before)
    return sorted(done)
