"""The results/ builders and experiments.figures' plan on what a run really was: one split, a smoke budget, missing and failed jobs, the plan."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml

from experiments import figures_plan as FP
from hydra_plugins.icgo_launcher import report as sweep_report
from icgo.studies.icgo_relm.results import outputs as O
from icgo.reporting import stamp
from icgo.studies.icgo_relm.names import METHOD_NAMES, STRATEGY_NAMES, method_name
from icgo.studies.icgo_relm.results import condition_sweeps as SC
from icgo.studies.icgo_relm.results import notes as N
from icgo.studies.icgo_relm.results.build import build
from tests.test_figures import _condition_runs, _conv, _metrics, _pred, _run_dir

S5 = N.STRATEGIES5


def _config(path, pop=8, iterations=3, repeats=10, dtype="float32_features"):
    (path / "config.yaml").write_text(yaml.safe_dump({"budget": {"pop_size": pop, "iterations": iterations,
                                                                 "max_evals": None}, "dtype": dtype,
                                                      "split": {"n_repeats": repeats, "protocol": "random"}}))


def test_a_single_split_run_writes_what_it_supports_and_names_what_it_skips(tmp_path):
    rng = np.random.default_rng(3)
    cgo = [f"cgo-{s}" for s in S5]
    m = _metrics(cgo, rng)
    one = tmp_path / "m" / "fig11"
    _run_dir(one, m[m.repeat == 0], conv=(c := _conv(cgo))[c.repeat == 0], pred=(p := _pred(cgo, rng))[p.repeat == 0],
             extra={"n_repeats": 1, "repeat_ids": [0]})
    _config(one, repeats=1)
    out = tmp_path / "results"
    done = build([tmp_path / "m"], out)
    for name in ("table2", "fig10", "fig11", "fig12", "fig13"):
        assert done[name] is True, (name, done[name])
    assert done["table3"].startswith("skipped: 1 repeat: Table 3's mean +/- std and its Friedman and Wilcoxon")
    assert "table3: skipped: 1 repeat" in (out / "tables_missing.txt").read_text()
    t2 = (out / "table2.md").read_text()
    assert ("Run settings: population 8 x 3 iterations, 1 repeat(s) per run, search dtype float32_features. NOT the paper's "
            "protocol") in t2
    f10 = pd.read_csv(out / "fig10.csv")
    assert f10["n_repeats"].tolist() == [1] * 5 and f10["mae_std"].isna().all()
    assert (out / "fig11.png").stat().st_size > 10_000


def test_stamps_say_the_papers_protocol_and_fig9_its_budget(tmp_path):
    rng = np.random.default_rng(4)
    cgo = [f"cgo-{s}" for s in S5]
    for name, methods in (("table3", cgo), ("fig9", ["pso", "ga"])):
        d = tmp_path / "m" / name
        _run_dir(d, _metrics(methods, rng), conv=_conv(methods), pred=_pred(methods, rng) if name == "table3" else None)
        _config(d, pop=30, iterations=100)
    out = tmp_path / "r"
    build([tmp_path / "m"], out)
    t3 = (out / "table3.md").read_text()
    assert "population 30 x 100 iterations, 10 repeat(s) per run, search dtype float32_features. The paper's protocol" in t3
    assert t3.startswith("# Table 3: 10 repeats")
    assert "Equal iterations (population x iterations 30 x 100, the paper's)" in (out / "fig9.md").read_text()
    # a smoke budget is said as such, in fig9 too
    for d in (tmp_path / "m").iterdir():
        _config(d, pop=8, iterations=3)
    build([tmp_path / "m"], out)
    f9 = (out / "fig9.md").read_text()
    assert "Equal iterations (population x iterations 8 x 3)" in f9 and "the paper's 30 x 100" not in f9
    assert "NOT the paper's protocol" in (out / "table3.md").read_text()


def test_run_settings_read_the_precision_of_new_and_older_run_directories(tmp_path):
    """A run's config.yaml names the search's precision ``precision``; one written before the key had that name
    says ``dtype``: both read the same."""
    for key, value in (("precision", "float64"), ("dtype", "float32_features")):
        d = tmp_path / key
        d.mkdir()
        (d / "config.yaml").write_text(yaml.safe_dump({key: value, "budget": {"pop_size": 30}}))
        assert stamp.run_settings(d)["dtype"] == value and stamp.run_settings(d)["pop_size"] == 30


def test_describe_and_title():
    paper = {"pop_size": 30, "iterations": 100, "max_evals": None, "dtype": "float32_features", "n_repeats": 10,
             "protocol": "random"}
    assert stamp.describe([paper])["paper"]
    assert stamp.describe([paper | {"max_evals": 12030}])["paper"]  # the equal-evaluation variant
    smoke = stamp.describe([paper | {"pop_size": 8, "iterations": 3}, paper])
    assert not smoke["paper"] and smoke["short"].endswith("mixed: NOT the paper's protocol")
    with stamp.stamping([paper | {"pop_size": 8, "iterations": 3}]):
        assert stamp.title("Fig. X") == "Fig. X\n[8 x 3, 10 repeat(s): NOT the paper's protocol]"
    assert stamp.title("Fig. X") == "Fig. X" and stamp.note() == ""


def test_a_sweep_level_missing_a_method_keeps_its_column_and_names_the_job(tmp_path):
    rng = np.random.default_rng(8)
    root = tmp_path / "m"
    _condition_runs(root, "sweep_noise", "noise_scale", (0.5, 1.0, 2.0), rng, lambda lv: "pso")
    import shutil

    shutil.rmtree(root / "sweep_noise-2.0-ga")  # GA's job at x2 did not run
    (root / "sweep_report.json").write_text(json.dumps({"jobs": [
        {"num": 11, "overrides": ["+dataset.kwargs.noise_scale=2.0", "optimizer=ga"], "dir": "11",
         "status": "not run", "reason": ""}]}))
    bad = root / "sweep_noise-4.0-cgo"
    _run_dir(bad, _metrics(["cgo-original"], rng), label="sweep_noise", failed=True)
    out = tmp_path / "r"
    done = build([root], out, sweep_report.REPORT_FILE)
    assert done["sweep_noise"] is True
    t = pd.read_csv(out / "sweep_noise.csv").set_index("noise x")
    assert t.loc[2.0, "GA-RELM"] == "missing" and t.loc[1.0, "GA-RELM"] != "missing"
    missing = (out / "tables_missing.txt").read_text()
    assert ("sweep_noise: written without sweep_noise: level noise_scale=2 has no GA-RELM (`python -m experiments.run "
            "experiment=sweep_noise +dataset.kwargs.noise_scale=2 optimizer=ga`)") in missing
    assert f"job {root / '11'} (+dataset.kwargs.noise_scale=2.0 optimizer=ga): not run" in missing
    assert f"job {bad}: failed (FAILED marker)" in missing
    assert set(SC.METHODS.values()) <= set(t.columns)


def test_plan_counts_jobs_and_prints_an_eta(monkeypatch, capsys, tmp_path):
    assert [FP.plan_jobs(p, o) for _, p, o in O.PLAN] == [1, 1, 1, 2, 3, 5, 6, 3, 1, 20, 20, 20, 1, 13]
    clock = iter(range(0, 10_000, 10))
    monkeypatch.setattr(FP.time, "perf_counter", lambda: float(next(clock)))
    monkeypatch.setattr(FP.subprocess, "call", lambda *a, **k: 0)
    FP.run_plan(tmp_path, None)
    lines = [ln for ln in capsys.readouterr().out.splitlines() if ln.startswith("[")]
    assert len(lines) == 14 and lines[0].startswith("[1/14] table3: 1 job(s); elapsed 0:10, ETA after the first")
    # after table3 (1 job; 40 s of the fake clock so far): 96 jobs left at 40 s per job
    assert lines[1] == "[2/14] table1: 1 job(s); elapsed 0:40, ETA 1:04:00"


def test_one_set_of_names():
    assert method_name("relm-tuned") == "RELM (tuned)" and method_name("cgo-chaos") == "ICGO-RELM (chaotic)"
    assert method_name("cgo-original") == "CGO-RELM" and method_name("sma-x") == "SMA-RELM (x)"
    assert O.LABEL is STRATEGY_NAMES and SC.METHODS["cgo-wavelet"] == METHOD_NAMES["cgo-wavelet"]
    from icgo.studies.generalisation import report as G

    assert G.NAMES["cgo-chaos"] == "ICGO-RELM (chaotic)"
    from icgo.maths.stats import format_mean_std

    assert format_mean_std(0.1, float("nan")) == "0.1000" and format_mean_std(0.1, 0.02) == "0.1000 +/- 0.0200"


def test_sweep_results_table_beside_the_report(tmp_path):
    for num, mae in ((0, "0.0400 +/- 0.0010"), (1, "0.0300 +/- 0.0020")):
        d = tmp_path / str(num)
        d.mkdir()
        pd.DataFrame([{"method": "cgo-three_stage", "label": "ICGO-RELM (three-stage)", "n": 10, "MAE (deg)": mae,
                       "RMSE (deg)": "0.05", "R^2": "0.99", "R^2 of error": "0.9", "evaluations": 12030}]
                     ).to_csv(d / "summary.csv", index=False)
    jobs = [{"num": 0, "overrides": ["strategy=chaos"], "dir": "0", "status": "ok", "reason": ""},
            {"num": 1, "overrides": ["strategy=wavelet"], "dir": "1", "status": "ok", "reason": ""},
            {"num": 2, "overrides": ["strategy=gaussian"], "dir": "2", "status": "failed", "reason": "x"}]
    t = sweep_report.results_table(tmp_path, jobs)
    assert t["overrides"].tolist() == ["strategy=chaos", "strategy=wavelet"]
    assert t["MAE (deg)"].tolist() == ["0.0400 +/- 0.0010", "0.0300 +/- 0.0020"]
    assert sweep_report.results_table(tmp_path, jobs[2:]) is None
    # a worlds job's row is its result pooled over worlds (worlds_pooled.csv)
    d = tmp_path / "3"
    d.mkdir()
    pd.DataFrame([{"method": "pso", "name": "PSO-RELM", "worlds": 30, "repeats per world": 10,
                   "MAE (deg)": "0.0370 +/- 0.0025", "RMSE (deg)": "0.05", "R^2 of error": "0.99",
                   "first (worlds)": "12 of 30"}]).to_csv(d / "worlds_pooled.csv", index=False)
    t = sweep_report.results_table(tmp_path, [{"num": 3, "overrides": ["optimizer=pso"], "dir": "3", "status": "ok"}])
    assert t.iloc[0][["method", "repeats", "MAE (deg)", "R^2"]].tolist() == ["PSO-RELM", "30 worlds x 10",
                                                                            "0.0370 +/- 0.0025", 0.99]


@pytest.mark.parametrize("flag", ["--help", "-h"])
def test_run_help_lists_the_groups_not_apply(flag):
    import subprocess
    import sys

    r = subprocess.run([sys.executable, "-m", "experiments.run", flag], capture_output=True, text=True, timeout=120, check=False,
                       cwd=Path(FP.__file__).resolve().parent.parent)
    assert r.returncode == 0 and "config groups" in r.stdout and "strategy    all, chaos" in r.stdout
    assert "apply" not in r.stdout.split("examples:")[0]


def test_each_table_is_stamped_from_its_own_runs(tmp_path):
    """Table 4 (one split of well_conditions) and Table 3 (10 repeats of lab_casing) collected together: each
    stamp and protocol line names only the runs its numbers come from."""
    rng = np.random.default_rng(5)
    cgo = [f"cgo-{s}" for s in S5]
    lab = tmp_path / "m" / "table3"
    _run_dir(lab, _metrics(cgo, rng), conv=_conv(cgo), pred=_pred(cgo, rng))
    _config(lab, pop=30, iterations=100, repeats=10)
    az = tuple(r[1] for r in O.PAPER["table4"])
    well = tmp_path / "m" / "table4"
    m, p = _metrics(cgo, rng), _pred(cgo, rng, azimuths=az, n=4)
    _run_dir(well, m[m.repeat == 0], dataset="well_conditions", pred=p[p.repeat == 0],
             extra={"n_repeats": 1, "repeat_ids": [0]})
    _config(well, pop=30, iterations=100, repeats=1)
    for d, name in ((lab, "lab_casing"), (well, "well_conditions")):
        cfg = yaml.safe_load((d / "config.yaml").read_text())
        (d / "config.yaml").write_text(yaml.safe_dump(cfg | {"dataset": {"name": name, "seed": 0}}))
    out = tmp_path / "r"
    done = build([tmp_path / "m"], out)
    assert done["table3"] is True and done["table4"] is True
    t4, t3 = (out / "table4.md").read_text(), (out / "table3.md").read_text()
    assert "Run settings: population 30 x 100 iterations, 1 repeat(s) per run, search dtype" in t4
    assert "10 repeat(s)" not in t4 and "data: well_conditions with noise seed 0;" in t4
    assert "Run settings: population 30 x 100 iterations, 10 repeat(s) per run, search dtype" in t3
    assert "1 repeat(s)" not in t3 and "data: lab_casing with noise seed 0;" in t3


def test_every_fig9_ablation_option_composes_into_a_valid_cgo_config():
    """Each +cgo_ablation option of the preset composes and builds its CGOConfig; the controls drop the 4th seed, the
    second with 40 members so that it spends the default's 120 evaluations per iteration."""
    from hydra import compose, initialize_config_dir
    from omegaconf import OmegaConf

    from experiments._preflight import CONF_DIR
    from icgo.optim import get

    sweep = yaml.safe_load((CONF_DIR / "experiment" / "fig9_cgo_ablation.yaml").read_text())
    options = sweep["hydra"]["sweeper"]["params"]["+cgo_ablation"].split(",")
    assert sorted(options) == sorted(p.stem for p in (CONF_DIR / "cgo_ablation").glob("*.yaml"))
    cgo = get("cgo")
    with initialize_config_dir(config_dir=str(CONF_DIR), version_base="1.3"):
        for opt in options:
            cfg = compose("config", ["experiment=fig9_cgo_ablation", f"+cgo_ablation={opt}"])
            params = OmegaConf.to_container(cfg.optimizer.params)
            c = cgo.make_config(**params)
            first, per = cgo.evals(cfg.budget.pop_size, c)
            if opt.startswith("no_fourth"):
                assert not c.fourth_seed and per == 3 * cfg.budget.pop_size
            else:
                assert c.fourth_seed and per == 4 * cfg.budget.pop_size == 120
    assert cgo.evals(40, cgo.make_config(fourth_seed=False))[1] == 120
