"""Many repeats: the MSA stops by its rule at every repeat, a repeat whose MSA fails is left out and named
(never averaged in, never aborting the others), and a 1,000-repeat study completes."""

from __future__ import annotations

import json
import time

import jax
import numpy as np
import pandas as pd
import pytest

import icgo  # noqa: F401  (float64)
from icgo.datasets import casing_stations
from icgo.models import msa
from icgo.studies.icgo_relm import study as S
from icgo.studies.icgo_relm.config import StudyConfig
from icgo.studies.icgo_relm.prepare import filtered, prepare


def _prepared(frame, cfg):
    rows, G, B, a, _ = filtered(frame, cfg)
    return prepare(rows, G, B, a, cfg, jax.random.PRNGKey(cfg.split.seed))


def test_msa_of_a_thousand_table3_repeats_stops_by_its_rule():
    """Every repeat converges in a few steps (the optimistix LM took 6-37 steps here, most of them rejected
    at the float64 floor, and on a GPU some repeats never stopped)."""
    cfg = StudyConfig(split=dict(n_repeats=1000))
    prep, _ = _prepared(casing_stations.lab_casing(0).frame, cfg)
    steps = np.asarray(prep.msa.n_steps)
    assert np.asarray(prep.msa.converged).all()
    assert steps.max() <= 6, np.bincount(steps)
    assert all(why is None for why in msa.msa_failures(prep.msa))


def _two_azimuth_frame():
    """One azimuth turned through 360 deg of toolface plus two stations at another azimuth: a 7:3 split that
    puts both of those in the test rows leaves every training station on one tool axis, so the station-mean
    MSA cannot determine the axial bias eps_z (a real failure, not a mock)."""
    f = casing_stations.lab_casing(0, toolface_step_deg=15.0).frame
    az = sorted(f.azimuth_deg.unique())
    return pd.concat([f[f.azimuth_deg == az[0]], f[f.azimuth_deg == az[3]].iloc[:2]]).reset_index(drop=True)


def _failing_ids(frame, n_repeats):
    cfg = StudyConfig(split=dict(n_repeats=n_repeats), model=dict(hidden=4))
    prep, mem = _prepared(frame, cfg)
    return [int(r) for r, why in zip(mem.repeat, msa.msa_failures(prep.msa)) if why is not None]


def test_a_repeat_whose_msa_fails_is_left_out_and_named(tmp_path, capsys):
    from hydra import compose, initialize_config_dir
    from hydra.core.global_hydra import GlobalHydra
    from hydra.core.hydra_config import HydraConfig
    from omegaconf import open_dict

    from experiments import _preflight as E
    from experiments._study_main import run_job
    from icgo.io.recording import write_recording
    from icgo.reporting.run_collection import EXCLUDED_FILE
    from icgo.studies.icgo_relm.results.build import build

    frame = _two_azimuth_frame()
    n = 12
    bad = _failing_ids(frame, n)
    assert 1 <= len(bad) < n, bad  # the split of some repeats, not all, is unobservable
    path = tmp_path / "two_azimuths.csv"
    write_recording(path, frame, {"total_field_nT": 54940.0, "dip_deg": 59.4, "name": "two_azimuths"})
    GlobalHydra.instance().clear()
    with initialize_config_dir(config_dir=str(E.CONF_DIR), version_base="1.3"):
        cfg = compose(config_name="config", return_hydra_config=True,
                      overrides=["budget=smoke", "progress=false", "figures=false", "jax_cache_dir=null",
                                 "dataset=csv", f"dataset.path={path}", f"split.n_repeats={n}", "model.hidden=4"])
    HydraConfig.instance().set_config(cfg)
    with open_dict(cfg):
        del cfg["hydra"]
    run_dir = tmp_path / "run"
    run = run_job(cfg, run_dir)

    good = sorted(set(range(n)) - set(bad))
    assert [e["repeat"] for e in run["excluded_repeats"]] == bad
    assert all("cannot determine ['eps_z']" in e["reason"] for e in run["excluded_repeats"])
    assert run["repeat_ids"] == good and run["n_repeats"] == n
    # no table holds an excluded repeat; the summary's n is the kept repeats
    for name in ("metrics", "convergence", "predictions", "msa", "coverage"):
        assert sorted(pd.read_csv(run_dir / f"{name}.csv").repeat.unique()) == good, name
    summary = pd.read_csv(run_dir / "summary.csv")
    assert set(summary.n) == {len(good)}
    m = pd.read_csv(run_dir / "metrics.csv").query("method == 'cgo-three_stage' and split == 'test'")
    assert summary.set_index("method").loc["cgo-three_stage", "MAE (deg)"].startswith(f"{m.mae.mean():.4f}")
    sentence = f"{len(bad)} of {n} repeats excluded"
    md = (run_dir / "summary.md").read_text()
    assert sentence in md and f"repeat {bad[0]}: MSA: the stations cannot determine" in md
    assert f"{len(good)} repeats" in md
    assert sentence in capsys.readouterr().out
    # the tables builder reads the run and lists what it left out
    build([run_dir], tmp_path / "fig")
    listed = (tmp_path / "fig" / EXCLUDED_FILE).read_text().splitlines()
    assert [int(line.split("repeat ")[1].split(":")[0]) for line in listed] == bad


def test_every_repeat_failing_stops_the_study_in_one_line():
    frame = casing_stations.lab_casing(0, toolface_step_deg=45.0).frame
    with pytest.raises(ValueError, match=r"^multi-station analysis \(repeat 0\): Levenberg-Marquardt did not "
                                         r"converge in 1 steps"):
        S.run_study(frame, StudyConfig(split=dict(n_repeats=3), msa=dict(iterations=1), model=dict(hidden=4),
                                       budget=dict(pop_size=4, iterations=1)))


def test_a_thousand_repeat_smoke_study_completes():
    """1,000 repeats x 1 strategy at the smoke budget (population 8, 3 iterations) on a 104-row survey."""
    frame = casing_stations.lab_casing(0, toolface_step_deg=30.0).frame
    cfg = StudyConfig(split=dict(n_repeats=1000), model=dict(hidden=8), budget=dict(pop_size=8, iterations=3))
    t0 = time.perf_counter()
    res = S.run_study(frame, cfg)
    wall = time.perf_counter() - t0
    assert res.excluded == () and len(res.config.ids()) == 1000
    test = res.metrics.query("split == 'test'")
    assert test.groupby("method").repeat.nunique().to_dict() == {"cgo-three_stage": 1000, "msa": 1000, "raw": 1000}
    assert np.isfinite(test.mae).all()
    assert res.predictions.shape[0] == 1000 * int(res.kept.sum())
    print(f"1,000-repeat smoke study: {wall:.1f} s")
    json.dumps(res.tuning)  # no tuning record; the result is complete
