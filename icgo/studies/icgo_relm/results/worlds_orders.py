"""Which orders between the worlds tables' methods a test carries: ``results/worlds_orders.{md,csv}``.

The worlds tables (:mod:`icgo.studies.icgo_relm.results.worlds_tables`) test the pairs their builders name (Table 3:
three-stage against each single strategy; Table 1 and Fig. 9: CGO-RELM against the others). A sentence that states
any other order (Table 3's third place, Fig. 9's PSO < GA, the tuned RELM against three-stage) needs a test of its
own. :func:`build` tests, from the committed per-world rows alone (``results/<stem>_per_world.csv``, no run
needed), every pair of each table's methods, and the cross-table pairs of :data:`CROSS`:

* each family (:data:`FAMILIES`) is fixed in advance: every pair of a table's methods (not the pairs the data put
  next to each other), so no pair is chosen on the rows it is tested on;
* Wilcoxon signed-rank, two-sided, over worlds (paired by world: the same data seed, splits and keys) of the
  per-world mean test MAE, exact for <= 50 worlds; Holm over the family;
* each row's ``order carried``: ``A < B`` when Holm p < 0.05 (A the lower by the median paired difference), else
  ``untested`` (no significant difference: not an order, and not equivalence; no equivalence test is run).

A stated order is carried only by a row of this file (or of its table's own family) whose ``order carried`` says it;
README.md and docs/ check that with claim markers.
"""

from __future__ import annotations

from itertools import combinations
from pathlib import Path

import pandas as pd

#: Family name -> (the per-world files whose rows it pairs, its methods, or None for every pair of them / the pairs).
_T1, _T3 = ("relm", "relm-tuned", "cgo-original"), ("cgo-original", "cgo-chaos", "cgo-gaussian", "cgo-wavelet",
                                                     "cgo-three_stage")
#: (the per-world files' stems: ``results/<stem>_per_world.csv``). The instrument families are tested apart from
#: the noise-only worlds (their own Holm families).
FAMILIES = {
    "table1": (("table1_worlds",), _T1, None),
    "table3": (("table3_worlds",), _T3, None),
    "fig9": (("fig9_worlds",), ("pso", "ga", "cgo-original"), None),
    "table1 (instruments)": (("table1_instruments",), _T1, None),
    "table3 (instruments)": (("table3_instruments",), _T3, None),
}
#: Every per-world file the families read.
STEMS = ("table1_worlds", "table3_worlds", "fig9_worlds", "table1_instruments", "table3_instruments")
#: The cross-table family: the tuned RELM of Table 1 against the two ICGO-RELM variants the docs compare it with.
CROSS = ("table1 x table3", ("table1_worlds", "table3_worlds"),
         (("relm-tuned", "cgo-three_stage"), ("relm-tuned", "cgo-wavelet")))
#: Where the tests are written (beside the worlds tables).
NAME = "worlds_orders"
#: The test's value: per-world mean test MAE.
VALUE = "mae"


def family_pairs(methods, pairs=None) -> list[tuple[str, str]]:
    """The pairs of a family: ``pairs`` when given, else every pair of ``methods`` in their listed order."""
    return list(pairs) if pairs is not None else list(combinations(methods, 2))


def _rows(results: Path, tables) -> pd.DataFrame | None:
    """The per-world rows of ``tables`` (one file each), or None when one is missing. A method in two files (CGO-RELM
    is run by Table 1's and Table 3's presets alike) keeps each file's rows under its own table."""
    parts = []
    for t in tables:
        path = Path(results) / f"{t}_per_world.csv"
        if not path.is_file():
            return None
        parts.append(pd.read_csv(path).assign(table=t))
    return pd.concat(parts, ignore_index=True)


def _one_table(per: pd.DataFrame, method: str, tables) -> pd.DataFrame:
    """The rows of ``method`` from the first of ``tables`` that holds it."""
    for t in tables:
        rows = per[(per["method"] == method) & (per["table"] == t)]
        if len(rows):
            return rows
    return per.iloc[0:0]


def tests(results: Path) -> pd.DataFrame:
    """Every family's tests (columns: family, comparison, a, b, worlds, a lower in, b lower in (worlds), the median and mean of the
    per-world differences a - b in deg, p, p (Holm), family size, order carried). A family whose per-world file is
    missing is left out."""
    from icgo.studies.icgo_relm.worlds import stats as W
    from icgo.studies.icgo_relm.names import method_name
    from icgo.reporting.protocol import ALPHA
    from icgo.maths.stats import holm

    out = []
    families = [(name, tables, family_pairs(methods, pairs)) for name, (tables, methods, pairs) in FAMILIES.items()]
    families.append((CROSS[0], CROSS[1], list(CROSS[2])))
    for name, tables, pairs in families:
        per = _rows(results, tables)
        if per is None:
            continue
        one = pd.concat([_one_table(per, m, tables) for m in dict.fromkeys(x for p in pairs for x in p)])
        fam = W.paired_tests(one, pairs, VALUE)
        if fam.empty:
            continue
        lower = {"a": [], "b": []}
        for _, r in fam.iterrows():
            w = W.wide(one, [r.a, r.b], VALUE)
            lower["a"].append(f"{int((w[r.a] < w[r.b]).sum())} of {len(w)}")
            lower["b"].append(f"{int((w[r.b] < w[r.a]).sum())} of {len(w)}")
        fam["a lower in"], fam["b lower in"] = lower["a"], lower["b"]
        fam["p (Holm)"] = holm(fam["p"].to_numpy())
        fam["family size"] = len(fam)
        fam["order carried"] = [
            (f"{method_name(r.a)} < {method_name(r.b)}" if r["median difference a - b"] < 0 else
             f"{method_name(r.b)} < {method_name(r.a)}") if r["p (Holm)"] < ALPHA else "untested"
            for _, r in fam.iterrows()]
        out.append(fam.drop(columns=["verdict"]).assign(family=name))
    if not out:
        return pd.DataFrame()
    df = pd.concat(out, ignore_index=True)
    cols = ["family", "comparison", "a", "b", "worlds", "a lower in", "b lower in", "median difference a - b",
            "mean difference a - b", "p", "p (Holm)", "family size", "order carried"]
    return df[cols]


def stamp_line(results: Path) -> str:
    """The stamp of the tests: the worlds tables' own (``Run settings: ...`` of ``results/<table>_worlds.md``), said
    once when they agree, else each with its table's name."""
    from icgo.reporting.protocol import SETTINGS_PREFIX

    found = {}
    for t in STEMS:
        path = Path(results) / f"{t}.md"
        if path.is_file():
            line = next((x for x in path.read_text().splitlines() if x.startswith(SETTINGS_PREFIX)), None)
            if line:
                found[t] = line[len(SETTINGS_PREFIX):]
    if not found:
        return f"{SETTINGS_PREFIX}not recorded (no worlds table beside the per-world rows)."
    if len(set(found.values())) == 1:
        return f"{SETTINGS_PREFIX}{next(iter(found.values()))} (Every worlds table's: these tests read their rows.)"
    return SETTINGS_PREFIX + " ".join(f"{t}: {v}" for t, v in found.items())


def build(results: Path, out: Path | None = None) -> bool:
    """``<out>/worlds_orders.{csv,md}`` from the per-world rows in ``results`` (``out`` defaults to ``results``);
    False (nothing written) when no per-world file is there."""
    from icgo.reporting.protocol import protocol_line
    from icgo.studies.icgo_relm.worlds.stats import seeds_text

    out = Path(out or results)
    df = tests(results)
    if df.empty:
        return False
    present = [t for t in STEMS if (Path(results) / f"{t}_per_world.csv").is_file()]
    seeds = sorted({int(s) for t in present for s in pd.read_csv(Path(results) / f"{t}_per_world.csv")["world"]})
    fams = list(dict.fromkeys(df["family"]))
    protocol = protocol_line(
        "`python -m experiments.worlds_tables --orders` (from the committed per-world rows "
        + ", ".join(f"`results/{t}_per_world.csv`" for t in present) + "; "
        "`python -m experiments.worlds_tables` writes it with the worlds tables)",
        "each world's mean over its repeats (the worlds tables' rows; the same worlds, splits and keys for every "
        "method, so every pair is paired by world)",
        "each worlds table's: random 7:3 of each world's rows, scored on the test rows",
        f"data: lab_casing data seeds {seeds_text(seeds)} (one world each; development seeds are none of them); the "
        "families marked (instruments) read the worlds of an instrument family (instrument=family: each seed also "
        "draws its instrument), the others the noise-only worlds of one instrument",
        "Wilcoxon signed-rank, two-sided, over worlds of the per-world mean test MAE, every pair of each table's "
        "methods fixed in advance; Holm within each family (" + ", ".join(
            f"{f}: {int(df[df.family == f]['family size'].iloc[0])} tests" for f in fams) + ")")
    stamp_note = stamp_line(results)
    lines = ["# Which orders over worlds a test carries: every pair of each worlds table's methods", "",
             stamp_note, "", protocol, "",
             "`order carried`: the lower of a pair where Holm p < 0.05 within its family, else `untested` (no "
             "significant difference: neither an order nor an equivalence, which no test here claims).", ""]
    for f in fams:
        part = df[df.family == f].drop(columns=["family", "a", "b"])
        lines += [f"## {f}", "", part.to_markdown(index=False, floatfmt=".4g"), ""]
    df.to_csv(out / f"{NAME}.csv", index=False, float_format="%.6g")
    (out / f"{NAME}.md").write_text("\n".join(lines).rstrip() + "\n")
    return True
