"""MLflow tracking: a run directory's metrics, a run logged and read back through MLflow's own client, a sweep as a
parent run, and (slow) the MLflow UI in headless Chromium showing a run's metric."""

from __future__ import annotations

import json
import os
import shutil
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from icgo.studies.common import tracking
from icgo.studies.common.tracking_tables import directory_metrics, name

ROOT = Path(__file__).resolve().parents[1]
needs_mlflow = pytest.mark.skipif(not tracking.installed(), reason="MLflow is not installed (pip install "
                                                                      "'icgo[tracking]')")


def _run_dir(tmp_path: Path, worlds: bool = False) -> Path:
    """A run directory with the ICGO-RELM tables: 2 methods x 3 repeats (x 2 worlds), 4 iterations."""
    d = tmp_path / "run"
    d.mkdir()
    rng = np.random.default_rng(0)
    rows, curves = [], []
    for w in ((100, 101) if worlds else (None,)):
        for m in ("msa", "cgo-chaos"):
            for r in range(3):
                row = {"method": m, "repeat": r, "split": "test", "mae": rng.uniform(0.1, 1), "rmse": 1.0,
                       "r2": 0.9, "r2_error": 0.5}
                rows.append(row if w is None else {"world": w, **row})
                if m != "msa":
                    curves += [{"method": m, "repeat": r, "iteration": i, "best_fitness": 1.0 / (i + r + 1)}
                               for i in range(1, 5)]
    pd.DataFrame(rows).to_csv(d / "metrics.csv", index=False)
    pd.DataFrame(curves).to_csv(d / "convergence.csv", index=False)
    if worlds:
        m = pd.DataFrame(rows)
        m.groupby(["world", "method"])[["mae", "rmse", "r2_error"]].mean().reset_index().to_csv(d / "worlds.csv",
                                                                                             index=False)
    (d / "run.json").write_text(json.dumps({"wall_time_s": 3.5, "timings": {"search_s": 1.25}, "pid": 7}))
    (d / "summary.md").write_text("# a run\n")
    return d


def test_a_run_directorys_metrics(tmp_path):
    d = _run_dir(tmp_path)
    got = {(k, s): v for k, v, s in directory_metrics(d)}
    m = pd.read_csv(d / "metrics.csv")
    chaos = m[m.method == "cgo-chaos"].sort_values("repeat")
    for r in range(3):  # per repeat, step = repeat
        assert got[("test/cgo-chaos/mae", r)] == pytest.approx(chaos.mae.iloc[r])
    assert got[("test/cgo-chaos/mae_mean", 0)] == pytest.approx(chaos.mae.mean())
    for i in range(1, 5):  # the curve: mean over repeats of 1 / (i + r + 1)
        assert got[("curve/cgo-chaos/best_fitness", i)] == pytest.approx(np.mean([1 / (i + r + 1) for r in range(3)]))
    assert got[("time/search_s", 0)] == 1.25 and got[("run/wall_time_s", 0)] == 3.5
    assert not any(k == "run/pid" for k, _ in got)


def test_a_worlds_runs_metrics_per_world_and_pooled(tmp_path):
    d = _run_dir(tmp_path, worlds=True)
    got = {(k, s): v for k, v, s in directory_metrics(d)}
    w = pd.read_csv(d / "worlds.csv")
    for seed in (100, 101):
        assert got[("world/cgo-chaos/mae", seed)] == pytest.approx(
            w[(w.world == seed) & (w.method == "cgo-chaos")].mae.item())
    assert got[("pooled/cgo-chaos/mae", 0)] == pytest.approx(w[w.method == "cgo-chaos"].mae.mean())
    assert ("test/cgo-chaos/mae", 101 * 1000 + 2) in got  # a repeat of a world: world x 1000 + repeat


def test_metric_names_keep_only_what_mlflow_accepts():
    assert name("test", "cgo-three_stage", "mae") == "test/cgo-three_stage/mae"
    assert name("x", "a(b)", "c") == "x/a_b_/c"


def test_the_tracking_setting(monkeypatch, tmp_path):
    monkeypatch.delenv(tracking.ENV, raising=False)
    for off in (False, "false", "off", "null"):
        assert tracking.tracking_uri(off) is None
    assert tracking.tracking_uri("auto", tmp_path) == (
        f"sqlite:///{tmp_path.resolve() / 'mlruns' / 'mlflow.db'}" if tracking.installed() else None)
    monkeypatch.setenv(tracking.ENV, "false")
    assert tracking.tracking_uri(None) is None and tracking.tracking_uri("auto") is None
    monkeypatch.setenv(tracking.ENV, "sqlite:///e.db")
    if tracking.installed():
        assert tracking.tracking_uri("auto") == "sqlite:///e.db"
    else:
        with pytest.raises(ValueError, match="needs MLflow"):
            tracking.tracking_uri("auto")
    with pytest.raises(ValueError, match="tracking must be auto, true, false or a tracking URI"):
        tracking.tracking_uri("somewhere")
    if tracking.installed():
        assert tracking.tracking_uri("sqlite:///x.db") == "sqlite:///x.db"


@needs_mlflow
def test_a_run_and_a_sweep_logged_and_read_back(tmp_path):
    """log_run_dir under a parent run, read back with MLflow's client: params, per-repeat and curve steps,
    artifacts, the parent's id, and the parent closed with the best objective."""
    from mlflow.tracking import MlflowClient

    uri = tracking.default_uri(tmp_path)
    sweep = tmp_path / "sweep"
    parent = tracking.start_parent(uri, sweep, experiment="icgo-test", params={"overrides": "a=1,2"})
    assert parent and tracking.parent_of(sweep) == parent
    d = _run_dir(tmp_path)
    rid = tracking.log_run_dir(uri, d, experiment="icgo-test", params={"model": {"hidden": 30}, "label": None},
                               run_name="job 0", parent_run_id=parent, extra_metrics={"objective": 0.25})
    tracking.end_parent(uri, sweep, 0.25)
    c = MlflowClient(uri)
    run = c.get_run(rid)
    assert run.data.params["model.hidden"] == "30" and run.data.params["label"] == "None"
    assert run.data.tags["mlflow.parentRunId"] == parent and run.info.status == "FINISHED"
    assert run.data.metrics["objective"] == 0.25
    hist = c.get_metric_history(rid, "test/cgo-chaos/mae")
    m = pd.read_csv(d / "metrics.csv")
    got = sorted((h.step, h.value) for h in hist)
    want = sorted(zip(m[m.method == "cgo-chaos"].repeat, m[m.method == "cgo-chaos"].mae))
    assert [s for s, _ in got] == [s for s, _ in want]
    assert [v for _, v in got] == pytest.approx([v for _, v in want])
    assert [h.step for h in sorted(c.get_metric_history(rid, "curve/cgo-chaos/best_fitness"),
                                   key=lambda h: h.step)] == [1, 2, 3, 4]
    assert {a.path for a in c.list_artifacts(rid)} >= {"metrics.csv", "summary.md", "run.json"}
    p = c.get_run(parent)
    assert p.info.status == "FINISHED" and p.data.metrics["best_objective"] == 0.25


def test_tracking_never_fails_a_run(tmp_path, caplog):
    """An unusable store is a warning, not an error (the run directory is the record)."""
    if not tracking.installed():
        pytest.skip("MLflow is not installed")
    blocker = tmp_path / "file"
    blocker.write_text("")
    assert tracking.log_run_dir(f"sqlite:///{blocker}/sub/mlflow.db", _run_dir(tmp_path), experiment="x",
                                params={}) is None
    assert "was not logged" in caplog.text


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


CHROMIUM, DRIVER = shutil.which("chromium") or "/usr/bin/chromium", shutil.which("chromedriver") or \
    "/usr/bin/chromedriver"


@pytest.mark.slow
def test_the_mlflow_ui_shows_a_runs_metric_in_a_real_browser(tmp_path):
    """A run logged by icgo, `mlflow server` on 127.0.0.1 at a free port over the same store, headless Chromium
    (Debian's chromium + chromium-driver, driven by selenium) opens the experiment's runs page, follows the run's
    link and finds the metric's value on the run page. Needs MLflow, selenium, chromium and chromium-driver
    (.ci/run installs them)."""
    missing = [what for what, ok in (("mlflow", tracking.installed()),
                                     ("selenium", __import__("importlib").util.find_spec("selenium") is not None),
                                     ("chromium", Path(CHROMIUM).is_file()), ("chromium-driver", Path(DRIVER).is_file()))
               if not ok]
    if missing:
        pytest.skip(f"needs {', '.join(missing)} (pip install 'icgo[tracking]' selenium; apt-get install chromium "
                    f"chromium-driver)")
    from mlflow.tracking import MlflowClient
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service
    from selenium.webdriver.common.by import By
    from selenium.webdriver.support.ui import WebDriverWait

    uri = tracking.default_uri(tmp_path)
    value = 0.4142135  # a value no page shows by chance
    rid = tracking.log_run_dir(uri, _run_dir(tmp_path), experiment="icgo-ui-test", params={"model": {"hidden": 30}},
                               run_name="browser-run", extra_metrics={"objective": value})
    assert rid is not None
    eid = MlflowClient(uri).get_experiment_by_name("icgo-ui-test").experiment_id
    port = _free_port()
    log = (tmp_path / "server.log").open("w")
    server = subprocess.Popen([sys.executable, "-m", "mlflow", "server", "--backend-store-uri", uri, "--host",
                               "127.0.0.1", "--port", str(port), "--workers", "1"], stdout=log,
                              stderr=subprocess.STDOUT, cwd=tmp_path)
    try:
        import urllib.request

        deadline = time.monotonic() + 240
        while True:
            try:
                urllib.request.urlopen(f"http://127.0.0.1:{port}/health", timeout=2)
                break
            except OSError:
                assert server.poll() is None, (tmp_path / "server.log").read_text()[-2000:]
                assert time.monotonic() < deadline, "mlflow server did not answer in 240 s"
                time.sleep(0.5)
        options = webdriver.ChromeOptions()
        options.binary_location = CHROMIUM
        for flag in ("--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
                     "--disable-component-update", "--disable-sync", "--no-first-run",
                     f"--user-data-dir={tmp_path / 'chromium-profile'}", "--window-size=1600,1200"):
            options.add_argument(flag)
        driver = webdriver.Chrome(service=Service(DRIVER), options=options)
        try:
            def body(d):
                return d.find_element(By.TAG_NAME, "body").text

            driver.get(f"http://127.0.0.1:{port}/#/experiments/{eid}/runs")
            WebDriverWait(driver, 180).until(lambda d: "browser-run" in body(d))  # the run is listed
            driver.find_element(By.LINK_TEXT, "browser-run").click()
            WebDriverWait(driver, 180).until(lambda d: "objective" in body(d) and f"{value}" in body(d))
            page = body(driver)
            assert "test/cgo-chaos/mae" in page  # a per-repeat metric of the run directory, by name
        finally:
            driver.quit()
    finally:
        server.terminate()
        try:
            server.wait(30)
        except subprocess.TimeoutExpired:
            server.kill()
            server.wait()
        log.close()


@needs_mlflow
def test_a_doors_job_is_tracked_with_its_config_its_files_and_its_objective(tmp_path, monkeypatch):
    """track_job (what run_guarded and the study main call): the setting from the config, the experiment of the door,
    only the files it names, the objective of its convergence table; tracking=false logs nothing."""
    from mlflow.tracking import MlflowClient

    from experiments._tracking import track_job
    from icgo.studies.common.tracking_tables import objective

    d = _run_dir(tmp_path)
    uri = tracking.default_uri(tmp_path)
    assert track_job({"tracking": False, "label": "x"}, d, door="misma") is None
    rid = track_job({"tracking": uri, "label": "x", "model": {"hidden": 8}}, d, files=["summary.md"], door="misma")
    c = MlflowClient(uri)
    run = c.get_run(rid)
    assert c.get_experiment(run.info.experiment_id).name == "icgo-misma"
    assert run.data.params["model.hidden"] == "8" and run.data.params["tracking"] == uri
    assert [a.path for a in c.list_artifacts(rid)] == ["summary.md"]
    assert run.data.metrics["objective"] == pytest.approx(objective(d))


@needs_mlflow
def test_a_refused_run_of_a_data_door_is_not_tracked(tmp_path):
    """A refusal (one line, exit 2: nothing written but Hydra's log) is no run: MLflow gets nothing, while the same
    door's finished run is logged (test_a_doors_job_is_tracked_with_its_config_its_files_and_its_objective)."""
    db = tmp_path / "mlflow.db"
    env = {**os.environ, "ICGO_TRACKING": f"sqlite:///{db}"}
    proc = subprocess.run([sys.executable, "-m", "experiments.discrepancy", "data=sim:hard_iron", "overwrite=maybe",
                           f"hydra.run.dir={tmp_path / 'run'}"], cwd=ROOT, env=env, capture_output=True, text=True,
                          timeout=300)
    assert proc.returncode == 2 and proc.stderr.strip().splitlines() == ["error: overwrite='maybe': must be true or "
                                                                          "false"], proc.stderr
    assert "tracking: logged" not in proc.stdout + proc.stderr and not db.exists()


@pytest.mark.slow
@needs_mlflow
def test_a_sweep_is_a_parent_run_of_its_jobs(tmp_path):
    """A 2-job sweep of the run door with tracking on: one parent run (the sweep), two job runs nested under it, each
    with its objective and the run directory's metrics; the parent closed with the smallest objective."""
    from mlflow.tracking import MlflowClient

    uri = tracking.default_uri(tmp_path)
    sweep = tmp_path / "sweep"
    cmd = [sys.executable, "-m", "experiments.run", "-m", "debug=smoke", "split.seed=1,2", f"tracking={uri}",
           f"hydra.sweep.dir={sweep}", f"jax_cache_dir={ROOT / '.jax_cache' / 'xdg' / 'icgo' / 'jax'}"]
    proc = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=900)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert "SweepTracking" not in proc.stderr, proc.stderr[-3000:]
    c = MlflowClient(uri)
    exp = c.get_experiment_by_name("icgo-run")
    runs = c.search_runs([exp.experiment_id])
    parents = [r for r in runs if tracking.TAG_SWEEP_DIR in r.data.tags]
    assert len(parents) == 1 and parents[0].data.tags[tracking.TAG_SWEEP_DIR] == str(sweep.resolve())
    parent = parents[0]
    jobs = [r for r in runs if r.data.tags.get("mlflow.parentRunId") == parent.info.run_id]
    assert sorted(Path(r.data.tags[tracking.TAG_RUN_DIR]).name for r in jobs) == ["0", "1"]
    for r in jobs:
        assert r.data.params["split.seed"] in ("1", "2") and "test/cgo-three_stage/mae_mean" in r.data.metrics
    assert parent.info.status == "FINISHED"
    assert parent.data.metrics["best_objective"] == pytest.approx(min(r.data.metrics["objective"] for r in jobs))


def test_a_corrected_surveys_scores(tmp_path):
    meta = {"rows": 584, "metrics": {"compensated": {"mae": 0.0633, "rmse": 0.0811}, "raw": {"mae": 2.419}}}
    (tmp_path / "s_corrected.meta.json").write_text(json.dumps(meta))
    got = {k: v for k, v, _ in directory_metrics(tmp_path)}
    assert got == {"survey/s_corrected/compensated/mae": 0.0633, "survey/s_corrected/compensated/rmse": 0.0811,
                   "survey/s_corrected/raw/mae": 2.419}
