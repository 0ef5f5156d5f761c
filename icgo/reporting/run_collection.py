"""The runs a ``results/`` build collects: every ``run.json`` below the given directories, pooled (newest wins on
duplicates), read through :mod:`icgo.reporting.records` (schema checked); the repeats the runs left out
(:func:`write_excluded`) and the jobs that left no result (:func:`missing_jobs`).
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pandas as pd

from icgo.reporting import records as R
from icgo.reporting import stamp


def check_repeats(df: pd.DataFrame, run: dict, name: str) -> None:
    """RecordError unless every method of a run's table has exactly the repeats its run record names."""
    expected = set(run.get("repeat_ids") or range(int(run["n_repeats"])))
    for method, g in df.groupby("method"):
        got = set(pd.to_numeric(g["repeat"], errors="coerce").dropna().astype(int))
        if got != expected:
            raise R.RecordError(f"{Path(run['dir']) / (name + '.csv')}: method {method!r} has {len(got)} of the "
                                f"{len(expected)} repeats the run record names (a truncated or edited file?)")


class Runs:
    """Pooled outputs of many run directories (newest wins on duplicates).

    Every run record and table is read through :mod:`icgo.reporting.records` (schema
    checked); a directory that fails the check is skipped with one line on
    stderr naming it and why.
    """
    KEY = ["dataset", "condition", "seed", "method", "repeat"]

    def __init__(self, dirs, runs=None):
        self._cache: dict = {}
        self.failed = []  # (directory, why) of every job found that left no result
        if runs is not None:  # a subset of another collection (see split_label)
            self.runs = runs
            return
        self.runs = []
        for d in dirs:
            d = Path(d)
            if not d.exists():
                raise SystemExit(f"error: {d}: no such directory")
            for rj in sorted(d.rglob(R.RUN_FILE)):
                if (rj.parent / R.FAILED_FILE).exists():
                    print(f"skipped {rj.parent}: the job failed ({R.FAILED_FILE} marker)", file=sys.stderr)
                    self.failed.append((rj.parent, "FAILED marker"))
                    continue
                try:
                    info = R.read_run(rj.parent)
                except R.RecordError as e:
                    print(f"skipped {rj.parent}: {e}", file=sys.stderr)
                    continue
                if info.get("status") != "ok":
                    print(f"skipped {rj.parent}: status {info.get('status')!r}", file=sys.stderr)
                    continue
                info["dir"] = rj.parent
                info["mtime"] = rj.stat().st_mtime
                self.runs.append(info)
        self.runs.sort(key=lambda r: r["mtime"])

    def settings(self) -> list[dict]:
        """Budget, repeats and dtype of every run (:func:`icgo.reporting.stamp.run_settings`)."""
        return [stamp.run_settings(r["dir"]) for r in self.runs]

    def split_label(self, *labels: str) -> tuple["Runs", "Runs"]:
        """(the runs with one of these run labels, the others): runs that must not replace the pooled ones."""
        return (Runs(None, [r for r in self.runs if r.get("label") in labels]),
                Runs(None, [r for r in self.runs if r.get("label") not in labels]))

    def _table(self, name: str) -> pd.DataFrame:
        if name not in self._cache:
            frames = []
            for order, r in enumerate(self.runs):
                try:
                    df = R.read_table(r["dir"], name)
                    check_repeats(df, r, name)
                except R.RecordError as e:
                    print(f"skipped {r['dir']} for {name}: {e}", file=sys.stderr)
                    continue
                df["run_order"] = order
                df["condition"] = df["condition"].astype("float").fillna(-1).astype(int)
                frames.append(df)
            if not frames:  # the schema's columns, so that a builder's column tests see "no runs", not an error
                self._cache[name] = pd.DataFrame(columns=list(R.TAG_COLUMNS) + list(R.TABLES[name]))
            else:
                df = pd.concat(frames, ignore_index=True)
                newest = df.groupby(self.KEY)["run_order"].transform("max")
                self._cache[name] = df[df["run_order"] == newest]
        return self._cache[name]

    def _rows(self, df: pd.DataFrame) -> pd.DataFrame:
        """The rows a builder reads, their runs added to the output's stamp (:func:`icgo.reporting.stamp.use`)."""
        if "run_order" not in df:
            return df
        stamp.use([stamp.run_settings(self.runs[int(i)]["dir"]) for i in sorted(df["run_order"].unique())])
        return df.drop(columns="run_order")

    def metrics(self, dataset="lab_casing", split="test", seed=0) -> pd.DataFrame:
        df = self._table("metrics")
        if df.empty:
            return self._rows(df)
        return self._rows(df[(df.dataset == dataset) & (df.split == split) & (df.seed == seed)])

    def convergence(self, dataset="lab_casing", seed=0) -> pd.DataFrame:
        df = self._table("convergence")
        return self._rows(df if df.empty else df[(df.dataset == dataset) & (df.seed == seed)])

    def predictions(self, dataset="lab_casing", seed=0) -> pd.DataFrame:
        df = self._table("predictions")
        return self._rows(df if df.empty else df[(df.dataset == dataset) & (df.seed == seed)])


#: Lists the repeats that runs left out (their MSA failed): the tables hold only the others.
EXCLUDED_FILE = "excluded_repeats.txt"


def write_excluded(runs: Runs, path: Path) -> None:
    """One line per repeat a collected run left out (run.json ``excluded_repeats``); no file when none did."""
    lines = [f"{r['dir']} ({r.get('label')}): repeat {e['repeat']}: {e['reason']}\n"
             for r in runs.runs for e in r.get("excluded_repeats") or ()]
    if lines:
        path.write_text("".join(lines))
    elif path.exists():
        path.unlink()


def missing_jobs(dirs, failed, report_file: str | None) -> list[str]:
    """Every job below ``dirs`` that left no result: a sweep report's failed, killed or not-run jobs (with their
    overrides) and any other directory with a ``FAILED`` marker.

    Args:
        dirs: the directories collected. failed: :attr:`Runs.failed` of their collection.
        report_file: the name of a sweep launcher's report (``hydra_plugins.icgo_launcher.report.REPORT_FILE``); None:
            no sweep report is read.
    """
    lines, named = [], set()
    for d in dirs if report_file else ():
        for rep in sorted(Path(d).rglob(report_file)):
            try:
                jobs = json.loads(rep.read_text()).get("jobs", [])
            except (OSError, ValueError):
                continue
            for j in jobs:
                if j.get("status") != "ok":
                    where = rep.parent / str(j.get("dir", j.get("num")))
                    named.add(str(where))
                    lines.append(f"{where} ({' '.join(j.get('overrides', [])) or 'no overrides'}): {j.get('status')}"
                                 + (f", {j['reason']}" if j.get("reason") else ""))
    for where, why in failed:
        if str(where) not in named:
            lines.append(f"{where}: failed ({why})")
    return lines
