"""The ICGO-RELM results/ builders (icgo.studies.icgo_relm.results): collection of run directories and the paper tables, on synthetic run outputs.

The runs are written by hand with known numbers, so each table is checked
against a direct computation (numpy mean/std, scipy's Wilcoxon and Friedman).
"""

from __future__ import annotations

import json
import os
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from scipy import stats as st

from icgo.studies.icgo_relm.results import outputs as O
from icgo.reporting import records as REC
from icgo.reporting.run_collection import Runs
from icgo.studies.icgo_relm.results import notes as N
from icgo.studies.icgo_relm.results.build import BUILDERS, build

S5 = N.STRATEGIES5
R = 10


def _run_dir(path: Path, metrics: pd.DataFrame, *, dataset="lab_casing", seed=0, conv=None, pred=None,
             failed=False, label="t", extra=None):
    """A run directory in the icgo.reporting.records schema, written by hand with known numbers."""
    path.mkdir(parents=True)
    tag = {"label": label, "dataset": dataset, "condition": None, "seed": seed}
    for name, df in (("metrics", metrics), ("convergence", conv), ("predictions", pred)):
        df = pd.DataFrame(columns=list(REC.TABLES[name])) if df is None else df.copy()
        for c in REC.TABLES[name]:
            if c not in df.columns:
                df[c] = np.nan
        REC.tag_table(df, tag).to_csv(path / f"{name}.csv", index=False)
    run = {k: None for k in REC.RUN_KEYS} | {"status": "ok", "dataset": dataset, "seed": seed, "label": label,
                                               "n_repeats": R, **(extra or {})}
    (path / "run.json").write_text(json.dumps(run))
    if failed:
        (path / "FAILED").write_text("boom\n")


def _metrics(methods, rng, scale=None, split="test"):
    rows = []
    for i, m in enumerate(methods):
        for r in range(R):
            base = (scale or {}).get(m, 0.05 + 0.01 * i)
            mae = base * (1 + 0.2 * rng.standard_normal())
            rows.append({"method": m, "repeat": r, "split": split, "mae": mae, "rmse": 1.3 * mae,
                         "r2": 1 - mae / 50, "r2_error": 1 - mae})
    return pd.DataFrame(rows)


def _conv(methods, T=5):
    rows = [{"method": m, "repeat": r, "iteration": t, "evals": 8 + 32 * t, "best_fitness": 1.0 / (t + i + r + 1)}
            for i, m in enumerate(methods) for r in range(R) for t in range(1, T + 1)]
    return pd.DataFrame(rows)


def _pred(methods, rng, azimuths=(30.0, 60.0), n=6):
    rows = []
    for m in methods:
        for r in range(R):
            for j in range(n * len(azimuths)):
                a = azimuths[j % len(azimuths)]
                e = 1 + 0.1 * rng.standard_normal()
                p = e + 0.05 * rng.standard_normal()
                rows.append({"method": m, "repeat": r, "row": j, "station": j, "split": "test" if (j // len(azimuths)) % 2 == 0 else "train",
                             "azimuth_true": a, "azimuth_raw": a + 5 + rng.standard_normal(),
                             "azimuth_msa": a + e, "error_msa": e, "predicted_error": p,
                             "azimuth_compensated": a + e - p, "error_compensated": e - p})
    return pd.DataFrame(rows)


def _holm_by_hand(p):
    """Holm's step-down adjustment written out: the i-th smallest p times (m - i), running maximum, capped at 1."""
    order = sorted(range(len(p)), key=lambda i: p[i])
    out, running = [0.0] * len(p), 0.0
    for rank, i in enumerate(order):
        running = max(running, min(1.0, (len(p) - rank) * p[i]))
        out[i] = running
    return out


@pytest.fixture()
def runs_dir(tmp_path):
    rng = np.random.default_rng(1)
    cgo = [f"cgo-{s}" for s in S5]
    _run_dir(tmp_path / "m" / "table3", _metrics(cgo, rng), conv=_conv(cgo), pred=_pred(cgo, rng))
    _run_dir(tmp_path / "m" / "relm", _metrics(["relm"], rng, {"relm": 0.5}))
    _run_dir(tmp_path / "m" / "fig9", _metrics(["pso", "ga"], rng, {"pso": 0.08, "ga": 0.09}))
    return tmp_path


def test_tables_match_direct_computation(runs_dir, tmp_path):
    out = tmp_path / "results"
    done = build([runs_dir / "m"], out)
    assert {k for k, v in done.items() if v is True} == set(BUILDERS) - {"table4"}
    assert done["table4"] == ("no runs of cgo-three_stage; made by "
                              "`python -m experiments.run -m experiment=table4`")
    assert done["fig9_budgets"].startswith("no runs of pso, ga, cgo-original; made by "
                                           "`python -m experiments.run -m experiment=fig9 budget=evaluations")
    missing = (out / "tables_missing.txt").read_text().splitlines()
    assert [ln.split(":")[0] for ln in missing] == ["table4", "sweep_noise", "sweep_casing", "sweep_mutations",
                                                    "fig9_budgets", "sweep_schedules", "fig9_ablation"]
    assert missing[0] == f"table4: {done['table4']}"
    m = pd.concat([pd.read_csv(p) for p in sorted((runs_dir / "m").rglob("metrics.csv"))])
    m = m[m.split == "test"]

    t1 = pd.read_csv(out / "table1.csv").set_index("metric")
    relm = m[m.method == "relm"].mae
    assert t1.loc["MAE (deg)", "RELM (ours)"] == f"{relm.mean():.4f} +/- {relm.std(ddof=1):.4f}"
    assert t1.loc["MAE (deg)", "RELM (paper)"] == 0.5111 and t1.loc["R^2", "CGO-RELM (paper)"] == 0.998

    t2 = pd.read_csv(out / "table2.csv").set_index("strategy")
    r0 = m[(m.method == "cgo-wavelet") & (m.repeat == 0)].mae.iloc[0]
    assert t2.loc["wavelet", "MAE (deg) ours"] == pytest.approx(round(r0, 4))
    assert t2.loc["three-stage", "MAE (deg) paper"] == 0.0300

    t3 = pd.read_csv(out / "table3.csv").set_index("strategy")
    g = m[m.method == "cgo-gaussian"].rmse
    assert t3.loc["Gaussian", "RMSE (deg) ours"] == f"{g.mean():.4f} +/- {g.std(ddof=1):.4f}"
    assert t3.loc["three-stage", "MAE (deg) paper"] == "0.0391 +/- 0.0100"
    assert t3.loc["original", "MAE (deg) paper"] == "(not in Table 3)"

    s = pd.read_csv(out / "table3_stats.csv")
    wide = m.pivot_table(index="repeat", columns="method", values="mae")
    fr = st.friedmanchisquare(*[wide[f"cgo-{x}"] for x in N.STRATEGIES4])
    row = s[(s.metric == "MAE (deg)") & s.test.str.startswith("Friedman")].iloc[0]
    assert row.statistic == pytest.approx(round(fr.statistic, 4)) and row.p == pytest.approx(fr.pvalue)
    ranks = np.apply_along_axis(st.rankdata, 1, wide[[f"cgo-{x}" for x in N.STRATEGIES4]].to_numpy()).mean(0)
    assert f"three-stage {ranks[3]:.2f}" in row["effect"]
    w = st.wilcoxon(wide["cgo-three_stage"], wide["cgo-chaos"])
    row = s[(s.metric == "MAE (deg)") & (s.comparison == "three-stage vs chaotic")].iloc[0]
    assert row.p == pytest.approx(w.pvalue)
    assert float(row.effect) == pytest.approx(round(np.median(wide["cgo-three_stage"] - wide["cgo-chaos"]), 4))
    for family, n in (("Friedman", 2), ("Wilcoxon", 6)):  # Holm within each family, by hand
        g = s[s.family == family]
        assert len(g) == n
        np.testing.assert_allclose(g["p (Holm)"], _holm_by_hand(g["p"].to_numpy()))
    md = (out / "table3.md").read_text()
    assert "Order by mean MAE, ours:" in md and "Friedman test on MAE" in md and "paper:" in md
    assert "Protocol: command: `make figures`" in md and "Holm over these 6" in md

    f10 = pd.read_csv(out / "fig10.csv").set_index("strategy")
    assert f10.loc["chaos", "mae_mean"] == pytest.approx(m[m.method == "cgo-chaos"].mae.mean())
    for f in ("fig9", "fig10", "fig11", "fig12", "fig13"):
        assert (out / f"{f}.png").stat().st_size > 10_000


def test_failed_runs_are_skipped_and_newest_duplicate_wins(runs_dir, tmp_path):
    rng = np.random.default_rng(2)
    bad = _metrics(["relm"], rng, {"relm": 99.0})
    _run_dir(tmp_path / "m" / "failed", bad, failed=True)
    newer = _metrics(["relm"], rng, {"relm": 0.25})
    _run_dir(tmp_path / "m" / "zz_newer", newer)
    future = time.time() + 100
    os.utime(tmp_path / "m" / "zz_newer" / "run.json", (future, future))
    out = tmp_path / "res"
    build([tmp_path / "m"], out)
    t1 = pd.read_csv(out / "table1.csv").set_index("metric")
    mae = newer.mae
    assert t1.loc["MAE (deg)", "RELM (ours)"] == f"{mae.mean():.4f} +/- {mae.std(ddof=1):.4f}"


def test_other_split_seeds_are_kept_apart(tmp_path):
    rng = np.random.default_rng(3)
    _run_dir(tmp_path / "a", _metrics(["relm", "cgo-original"], rng), seed=0)
    _run_dir(tmp_path / "b", _metrics(["relm", "cgo-original"], rng, {"relm": 7.0}), seed=1)
    runs = Runs([tmp_path])
    a, b = runs.metrics(seed=0), runs.metrics(seed=1)
    assert a[a.method == "relm"].mae.max() < 1 and b[b.method == "relm"].mae.min() > 1


def test_table4_per_condition_from_azimuth(tmp_path):
    rng = np.random.default_rng(4)
    cgo = [f"cgo-{s}" for s in S5]
    az = tuple(r[1] for r in O.PAPER["table4"])
    pred = _pred(cgo, rng, azimuths=az, n=4)
    _run_dir(tmp_path / "w", _metrics(cgo, rng), dataset="well_conditions", pred=pred)
    out = tmp_path / "res"
    assert build([tmp_path / "w"], out)["table4"]
    t4 = pd.read_csv(out / "table4.csv")
    assert list(t4["azimuth (deg)"]) == list(az)
    d = pred[(pred.method == "cgo-three_stage") & (pred.repeat == 0) & (pred.split == "test")
             & (pred.azimuth_true == 60.0)]
    row = t4[t4["azimuth (deg)"] == 60.0].iloc[0]
    assert row["compensated mean ours"] == pytest.approx(round(np.abs(d.error_compensated).mean(), 4))
    assert row["raw mean paper"] == 29.6639
    assert (out / "fig15.png").exists()


def test_missing_directory_is_one_line(tmp_path):
    with pytest.raises(SystemExit) as e:
        Runs([tmp_path / "nope"])
    assert "no such directory" in str(e.value)


def test_a_table_missing_repeats_or_cut_short_is_skipped_and_named(tmp_path, capsys):
    rng = np.random.default_rng(0)
    _run_dir(tmp_path / "m" / "good", _metrics(["relm", "cgo-original"], rng))
    m = _metrics(["relm", "cgo-original"], rng)
    _run_dir(tmp_path / "m" / "rows_lost", m[m.repeat < 5])             # whole rows cut: 5 of 10 repeats
    _run_dir(tmp_path / "m" / "cut", m)
    cut = tmp_path / "m" / "cut" / "metrics.csv"
    cut.write_bytes(cut.read_bytes()[:-7])                               # cut inside the last line
    runs = Runs([tmp_path / "m"])
    got = runs.metrics()
    assert len(got) == 2 * R                                             # only the good run
    err = capsys.readouterr().err
    assert "rows_lost/metrics.csv: method 'cgo-original' has 5 of the 10 repeats the run record names" in err
    assert "cut/metrics.csv: does not end with a newline (a truncated file?)" in err


def test_no_runs_at_all_is_missing_runs_not_a_traceback(tmp_path):
    (tmp_path / "empty").mkdir()
    done = build([tmp_path / "empty"], tmp_path / "out")
    assert not any(v is True for v in done.values())
    assert all(v.startswith("no runs") for v in done.values())


def test_a_truncated_table_is_skipped_and_named(tmp_path, capsys):
    rng = np.random.default_rng(0)
    _run_dir(tmp_path / "m" / "good", _metrics(["relm", "cgo-original"], rng))
    _run_dir(tmp_path / "m" / "bad", _metrics(["relm", "cgo-original"], rng))
    (tmp_path / "m" / "bad" / "metrics.csv").write_text("label,dataset,condition,seed,method,rep")
    runs = Runs([tmp_path / "m"])
    m = runs.metrics()
    err = capsys.readouterr().err
    assert "skipped" in err and str(tmp_path / "m" / "bad") in err and "metrics" in err
    assert len(m) == 2 * R


def test_paper_consistency_note_flags_the_three_stage_row():
    from icgo.studies.icgo_relm.results.outputs import PAPER, paper_consistency_note, paper_variances

    var = paper_variances()
    mae, rmse, r2 = (x[0] for x in PAPER["table3"]["three_stage"])
    assert var["Table 3 three_stage"] == pytest.approx(rmse ** 2 / (1 - r2))
    assert var["Table 1 relm"] == pytest.approx(0.6035 ** 2 / (1 - 0.866))
    others = [v for k, v in var.items() if k != "Table 3 three_stage"]
    assert var["Table 3 three_stage"] < 0.65 * min(others)
    assert "1.58 deg^2" in paper_consistency_note() and "2.67-3.05" in paper_consistency_note()


def test_equal_evaluation_runs_sit_beside_not_over_the_equal_iteration_ones(runs_dir, tmp_path):
    """Issue 18 item 3: Fig. 9 at equal iterations and at equal evaluations, side by side."""
    import time

    rng = np.random.default_rng(3)
    fig9 = ["pso", "ga", "cgo-original"]
    time.sleep(0.01)  # newer than the equal-iteration runs: it must still not replace them
    _run_dir(runs_dir / "m" / "fig9_evals", _metrics(fig9, rng, {"pso": 0.03, "ga": 0.04, "cgo-original": 0.06}),
             conv=_conv(fig9), label=O.EQUAL_EVALS_LABEL)
    out = tmp_path / "results"
    done = build([runs_dir / "m"], out)
    assert done["fig9_budgets"] and done["fig9"]
    m = pd.concat([pd.read_csv(p) for p in sorted((runs_dir / "m").rglob("metrics.csv"))])
    m = m[m.split == "test"]
    f9 = pd.read_csv(out / "fig9.csv").set_index("method")
    pso_iter = m[(m.method == "pso") & (m.label == "t")].mae
    assert f9.loc["PSO-RELM", "mae_mean"] == pytest.approx(pso_iter.mean())  # not the equal-evaluation run's
    b = pd.read_csv(out / "fig9_budgets.csv")
    pso_ev = m[(m.method == "pso") & (m.label == O.EQUAL_EVALS_LABEL)].mae
    row = b[(b.method == "PSO-RELM") & b.budget.str.startswith("equal evaluations")].iloc[0]
    assert row["MAE (deg)"] == f"{pso_ev.mean():.4f} +/- {pso_ev.std(ddof=1):.4f}"
    assert "Holm" in (out / "fig9_budgets.md").read_text()


def test_schedules_sweep_pairs_each_schedule_with_the_single_strategies(runs_dir, tmp_path):
    """Issue 18 sweep 1: one column per schedule run, kept apart from Table 3's three-stage."""
    rng = np.random.default_rng(4)
    for i, (bounds, clock) in enumerate((([0.2, 0.7], "global"), ([1 / 3, 2 / 3], "stage"))):
        _run_dir(runs_dir / "m" / f"sched{i}", _metrics(["cgo-three_stage"], rng, {"cgo-three_stage": 0.01 + 0.1 * i}),
                 label=O.SCHEDULES_LABEL,
                 extra={"schedule": {"bounds": bounds, "order": ["chaos", "gaussian", "wavelet"], "clock": clock}})
    out = tmp_path / "results"
    done = build([runs_dir / "m"], out)
    assert done["sweep_schedules"] and done["table3"]
    t = pd.read_csv(out / "sweep_schedules.csv").set_index("column")
    fast = t.loc["three-stage chaos>gaussian>wavelet at 20/70 %"]
    assert t.index[0] == "three-stage chaos>gaussian>wavelet at 20/70 %" and fast["repeats best"] == 10
    assert "three-stage chaos>gaussian>wavelet at 33/67 % (wavelet on its stage clock)" in t.index
    assert {"chaotic", "Gaussian", "wavelet"} <= set(t.index)
    # Table 3 still reads its own three-stage runs, not the sweep's
    m = pd.concat([pd.read_csv(p) for p in sorted((runs_dir / "m" / "table3").rglob("metrics.csv"))])
    t3 = pd.read_csv(out / "table3.csv").set_index("strategy")
    ts = m[(m.split == "test") & (m.method == "cgo-three_stage")].mae
    assert t3.loc["three-stage", "MAE (deg) ours"] == f"{ts.mean():.4f} +/- {ts.std(ddof=1):.4f}"


def test_mutation_readings_sweep_names_each_reading_and_checks_the_paper_order(runs_dir, tmp_path):
    rng = np.random.default_rng(5)
    # a reading under which three-stage is best and wavelet second: the paper's order if Gaussian < chaos
    _run_dir(runs_dir / "m" / "wav", _metrics(["cgo-wavelet", "cgo-three_stage"], rng,
                                              {"cgo-wavelet": 0.02, "cgo-three_stage": 0.001}),
             label="sweep_wavelet", extra={"strategies": ["wavelet", "three_stage"],
                                             "optimizer_params": {"variant": "paper", "wavelet_zeta": 1.0,
                                                                  "wavelet_amplitude": "none"}})
    _run_dir(runs_dir / "m" / "sig", _metrics(["cgo-gaussian", "cgo-three_stage"], rng,
                                              {"cgo-gaussian": 0.5, "cgo-three_stage": 0.6}),
             label="sweep_sigma", extra={"strategies": ["gaussian", "three_stage"],
                                             "optimizer_params": {"variant": "paper", "sigma": 0.2}})
    out = tmp_path / "results"
    assert build([runs_dir / "m"], out)["sweep_mutations"]
    t = pd.read_csv(out / "sweep_mutations.csv").set_index("reading")
    assert set(t.index) == {"wavelet zeta 1, amplitude none", "Gaussian sigma 0.2 (0.1 of the box width)"}
    wav = t.loc["wavelet zeta 1, amplitude none"]
    assert wav["order by mean MAE (untested)"].startswith("three-stage < wavelet")
    assert not t.loc["Gaussian sigma 0.2 (0.1 of the box width)", "paper's order by mean"]
    assert 0 <= wav["p Holm"] <= 1


def test_readings_with_identical_columns_are_one_holm_test(runs_dir, tmp_path):
    """Two readings that give the same numbers (wavelet without the amplitude at two zetas) are one test: Holm over
    the distinct tests, the shared p adjusted once."""
    rng = np.random.default_rng(9)
    same = _metrics(["cgo-wavelet", "cgo-three_stage"], rng, {"cgo-wavelet": 0.04, "cgo-three_stage": 0.05})
    for zeta in (1.0, 2.0):
        _run_dir(runs_dir / "m" / f"wav{zeta}", same, label="sweep_wavelet",
                 extra={"strategies": ["wavelet", "three_stage"],
                        "optimizer_params": {"variant": "paper", "wavelet_zeta": zeta, "wavelet_amplitude": "none"}})
    _run_dir(runs_dir / "m" / "sig", _metrics(["cgo-gaussian", "cgo-three_stage"], rng,
                                              {"cgo-gaussian": 0.05, "cgo-three_stage": 0.03}),
             label="sweep_sigma", extra={"strategies": ["gaussian", "three_stage"],
                                         "optimizer_params": {"variant": "paper", "sigma": 0.2}})
    out = tmp_path / "results"
    assert build([runs_dir / "m"], out)["sweep_mutations"]
    t = pd.read_csv(out / "sweep_mutations.csv").set_index("reading")
    raw = t["p three-stage vs single"]
    w1, w2, g = (t.index.get_loc(r) for r in ("wavelet zeta 1, amplitude none", "wavelet zeta 2, amplitude none",
                                               "Gaussian sigma 0.2 (0.1 of the box width)"))
    assert raw.iloc[w1] == raw.iloc[w2]
    want = _holm_by_hand([raw.iloc[w1], raw.iloc[g]])
    np.testing.assert_allclose(t["p Holm"].iloc[[w1, w2, g]], [want[0], want[0], want[1]], rtol=1e-12)
    md = (out / "sweep_mutations.md").read_text()
    assert "Holm over the 2 distinct tests" in md
    assert "wavelet zeta 1, amplitude none, wavelet zeta 2, amplitude none" in md


def test_an_unknown_sweep_never_replaces_the_paper_runs(runs_dir, tmp_path):
    import time

    rng = np.random.default_rng(6)
    out0 = tmp_path / "before"
    build([runs_dir / "m"], out0)
    time.sleep(0.01)
    _run_dir(runs_dir / "m" / "other", _metrics(["cgo-three_stage", "relm"], rng, {"cgo-three_stage": 9.0, "relm": 9.0}),
             label="sweep_something_new")
    out1 = tmp_path / "after"
    build([runs_dir / "m"], out1)
    for name in ("table1.csv", "table3.csv", "table3_stats.csv"):
        assert (out1 / name).read_text() == (out0 / name).read_text(), name


def test_paper_literal_run_is_one_reading_with_every_strategy_from_it(runs_dir, tmp_path):
    """Issue 18 sweep 2: the sweep_paper_literal preset's row takes all four strategies from its own run."""
    rng = np.random.default_rng(7)
    scale = {"cgo-chaos": 0.001, "cgo-gaussian": 0.002, "cgo-wavelet": 0.003, "cgo-three_stage": 0.004,
             "cgo-original": 0.005}
    _run_dir(runs_dir / "m" / "lit", _metrics([f"cgo-{s}" for s in S5], rng, scale), label="sweep_paper_literal",
             extra={"strategies": list(S5), "optimizer_params": {"variant": "paper", "wavelet_amplitude": "none",
                                                                   "sigma": 1.0}})
    out = tmp_path / "results"
    assert build([runs_dir / "m"], out)["sweep_mutations"]
    t = pd.read_csv(out / "sweep_mutations.csv")
    row = t[t.reading.str.startswith("the paper's literal readings")].iloc[0]
    assert "amplitude none" in row["reading"]
    assert row["order by mean MAE (untested)"] == "chaotic < Gaussian < wavelet < three-stage"  # this run's
    assert not row["paper's order by mean"]


def _condition_runs(root: Path, label: str, key: str, levels, rng, best_at):
    """Runs of a noise/casing sweep: 4 jobs per level (CGO's five strategies, RELM, PSO, GA) with known MAEs."""
    cgo = [f"cgo-{s}" for s in S5]
    for lv in levels:
        for job, methods in (("cgo", cgo), ("none", ["relm"]), ("pso", ["pso"]), ("ga", ["ga"])):
            scale = {m: 0.05 + 0.01 * i for i, m in enumerate(["relm", "pso", "ga", *cgo])}
            scale[best_at(lv)] = 0.001
            m = _metrics([*methods, "raw", "msa"], rng, {**scale, "raw": 2.0, "msa": 0.8})
            _run_dir(root / f"{label}-{lv}-{job}", m, label=label,
                     extra={"strategies": list(S5), "dataset_kwargs": {key: lv}})


def test_noise_and_casing_sweeps_report_every_method_against_the_floor(runs_dir, tmp_path):
    """Issue 18 sweep 5: one row per level, every method, the level's noise floor, ranking statistics."""
    from icgo.datasets.casing_stations import noise_floor
    from icgo.studies.icgo_relm.results import condition_sweeps as SC

    rng = np.random.default_rng(8)
    _condition_runs(runs_dir / "m", "sweep_noise", "noise_scale", (0.5, 1.0, 2.0), rng,
                    lambda lv: "pso" if lv < 2 else "cgo-wavelet")
    _condition_runs(runs_dir / "m", "sweep_casing", "casing_distance_m", (0.5, 1.0), rng, lambda lv: "ga")
    out = tmp_path / "results"
    done = build([runs_dir / "m"], out)
    assert done["sweep_noise"] is True and done["sweep_casing"] is True
    t = pd.read_csv(out / "sweep_noise.csv")
    assert list(t["noise x"]) == [0.5, 1.0, 2.0]
    assert set(SC.METHODS.values()) <= set(t.columns)
    for _, row in t.iterrows():  # the floor is the level's own noise-only draw
        assert row["floor MAE (deg)"] == pytest.approx(noise_floor("lab_casing", 0, noise_scale=row["noise x"]).mae[0])
    assert t["floor MAE (deg)"].is_monotonic_increasing
    # the physics of each level's raw readings, recomputed from the draw: |G| against gravity, in mg
    from icgo.datasets.casing_stations import lab_casing

    f = lab_casing(0, noise_scale=2.0).frame
    g = np.linalg.norm(f[["gx", "gy", "gz"]].to_numpy(), axis=1)
    assert t.iloc[2]["raw |G| dev RMS (mg)"] == pytest.approx(1e3 * np.sqrt(np.mean((g - 1.0) ** 2)), abs=1e-3)
    assert t["raw |G| dev RMS (mg)"].is_monotonic_increasing
    assert [o.split(" < ")[0] for o in t["order by MAE"]] == ["PSO-RELM", "PSO-RELM", "ICGO-RELM (wavelet)"]
    tau = t.set_index("noise x")["Kendall tau vs default order"]
    assert tau[1.0] == 1.0 and tau[2.0] < 1.0
    # Friedman over the 8 methods, recomputed from the runs of level 2
    wide = pd.concat([pd.read_csv(p) for p in (runs_dir / "m").glob("sweep_noise-2.0-*/metrics.csv")])
    wide = wide[wide.split == "test"].pivot_table(index="repeat", columns="method", values="mae")[list(SC.METHODS)]
    p_fr = [st.friedmanchisquare(*w.to_numpy().T).pvalue for w in (
        pd.concat([pd.read_csv(p) for p in (runs_dir / "m").glob(f"sweep_noise-{lv}-*/metrics.csv")]).query(
            "split == 'test'").pivot_table(index="repeat", columns="method", values="mae")[list(SC.METHODS)]
        for lv in ("0.5", "1.0", "2.0"))]
    assert p_fr[2] == pytest.approx(st.friedmanchisquare(*wide.to_numpy().T).pvalue)
    np.testing.assert_allclose(t["Friedman p (Holm)"], _holm_by_hand(p_fr))  # one family over the levels
    c = pd.read_csv(out / "sweep_casing.csv")
    assert set(c["sweep"]) == {"sweep_casing"} and list(c["casing distance (m)"]) == [0.5, 1.0]
    near, far = (float(x.split()[0]) for x in c["casing field at sensor (nT)"])
    assert c["raw |B| dev RMS (nT)"].iloc[0] != c["raw |B| dev RMS (nT)"].iloc[1]
    assert near > 1.2 * far  # poles 1.5 m along the casing: 1.58 m away at 0.5 m against 1.80 m at 1 m
    assert (out / "sweep_noise.png").stat().st_size > 0 and "Noise floor" in (out / "sweep_noise.md").read_text()


def test_conditions_builders_say_which_runs_are_missing(runs_dir, tmp_path):
    out = tmp_path / "results"
    done = build([runs_dir / "m"], out)
    assert "experiment=sweep_noise" in done["sweep_noise"]
    assert "experiment=sweep_casing_strength" in done["sweep_casing"]


def test_fig9_ablation_rows_against_the_default_cgo(tmp_path):
    """The CGO ablation behind Fig. 9: each run's final training RMSE and test MAE against the default CGO-RELM,
    paired Wilcoxon, Holm over the ablation rows (one family per metric), recomputed here with scipy."""
    rng = np.random.default_rng(11)
    methods = ["pso", "ga", "cgo-original"]
    conv = _conv(methods)
    _run_dir(tmp_path / "m" / "fig9", _metrics(methods, rng), conv=conv, label="fig9")
    runs = {}
    for k, dims in enumerate(("one", "all")):
        c = _conv(["cgo-original"]).assign(best_fitness=lambda d, k=k: d.best_fitness * (0.5 + k) + 1e-3 * d.repeat)
        runs[dims] = c
        _run_dir(tmp_path / "m" / f"abl-{dims}", _metrics(["cgo-original"], rng), conv=c, label=O.ABLATION_LABEL,
                 extra={"optimizer_params": {"variant": "paper", "dims": dims}})
    out = tmp_path / "r"
    assert build([tmp_path / "m"], out)["fig9_ablation"] is True
    t = pd.read_csv(out / "fig9_ablation.csv").set_index("configuration")
    assert list(t.index[:3]) == ["PSO-RELM", "GA-RELM",
                                 "CGO-RELM (default: variant paper, dims subset, bound_mode clip)"]
    last = lambda c: c.sort_values("iteration").groupby("repeat").best_fitness.last()  # noqa: E731
    base = last(conv[conv.method == "cgo-original"])
    p = [st.wilcoxon(last(runs[d]), base).pvalue for d in ("one", "all")]
    rows = ["CGO-RELM, dims one", "CGO-RELM, dims all"]
    np.testing.assert_allclose(t.loc[rows, "p training RMSE (Holm)"], _holm_by_hand(p))
    assert t.loc[rows[0], "training RMSE - default, median (deg)"] == pytest.approx(
        round(float((last(runs["one"]) - base).median()), 4))
    assert "Protocol: command: `make figures`" in (out / "fig9_ablation.md").read_text()


def test_fig9_ablation_tests_the_default_against_pso_and_ga_and_names_the_controls(tmp_path):
    """The third family: the default CGO-RELM's final training RMSE against PSO-RELM's and GA-RELM's (Holm over
    the 2, scipy recomputed); a control run with another population is labelled by it, every row says the
    evaluations its runs spent, and the rows below both peers by mean are named as untested."""
    import yaml

    rng = np.random.default_rng(12)
    methods = ["pso", "ga", "cgo-original"]
    conv = _conv(methods)
    _run_dir(tmp_path / "m" / "fig9", _metrics(methods, rng), conv=conv, label="fig9")
    (tmp_path / "m" / "fig9" / "config.yaml").write_text(yaml.safe_dump({"budget": {"pop_size": 30}}))
    ctrl = _conv(["cgo-original"]).assign(best_fitness=lambda d: d.best_fitness * 0.3 + 1e-3 * d.repeat,
                                          evals=lambda d: 40 + 120 * d.iteration)
    d = tmp_path / "m" / "ctrl"
    _run_dir(d, _metrics(["cgo-original"], rng), conv=ctrl, label=O.ABLATION_LABEL,
             extra={"optimizer_params": {"variant": "paper", "fourth_seed": False}})
    (d / "config.yaml").write_text(yaml.safe_dump({"budget": {"pop_size": 40}}))
    out = tmp_path / "r"
    assert build([tmp_path / "m"], out)["fig9_ablation"] is True
    t = pd.read_csv(out / "fig9_ablation.csv").set_index("configuration")
    row = "CGO-RELM, fourth_seed False, population 40"
    assert t.loc[row, "evaluations per run"] == 40 + 120 * 5 and t.loc["PSO-RELM", "evaluations per run"] == 8 + 32 * 5
    last = lambda c: c.sort_values("iteration").groupby("repeat").best_fitness.last()  # noqa: E731
    fit = {m: last(conv[conv.method == m]) for m in methods}
    holm = _holm_by_hand([st.wilcoxon(fit["cgo-original"], fit[peer]).pvalue for peer in ("pso", "ga")])
    md = (out / "fig9_ablation.md").read_text()
    peer_rows = [ln for ln in md.splitlines() if ln.startswith(("| PSO-RELM ", "| GA-RELM "))][-2:]
    got = [float(ln.split("|")[5]) for ln in peer_rows]
    np.testing.assert_allclose(got, holm, rtol=1e-3)
    below = last(ctrl).mean() < min(fit["pso"].mean(), fit["ga"].mean())
    assert ("(not tested against PSO/GA): `fourth_seed False, population 40`." in md) == below


def test_table4_note_gives_the_ratio_of_the_near_vertical_errors_from_the_table():
    t = pd.DataFrame({"inclination (deg)": [0.594, 1.8, 60.0, 90.0, 135.0, 150.0],
                      "compensated mean ours": [0.7805, 0.4536, 0.0836, 0.1001, 0.0773, 0.0915],
                      "noise floor MAE": [0.7812, 0.2337, 0.0252, 0.0198, 0.0197, 0.0259]})
    from icgo.studies.icgo_relm.results.table4 import _table4_high_inclination

    note = _table4_high_inclination(t)
    assert "stays 3.3-5.1 times its noise floor" in note
    assert f"means are {0.4536 / 0.1001:.1f}-{0.7805 / 0.0773:.1f} times those at I >= 60 deg" in note  # 4.5-10.1
    assert "ten times" not in note and "cause" not in note
