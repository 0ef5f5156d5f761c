"""Worlds: a study over independent simulated data sets in one sharded search; per-world and pooled reports.

One tiny worlds study through the front door (2 worlds x 2 strategies x 2 repeats, the smoke budget, a 104-row
lab_casing) is shared by the tests of its run directory; the library tests reuse its shapes.
"""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest
from scipy import stats as sps

import icgo  # noqa: F401  (float64)
from icgo.core.errors import SettingError
from icgo.studies.icgo_relm.worlds import stats as R
from icgo.studies.icgo_relm import study as S
from icgo.studies.icgo_relm.worlds import study as W
from icgo.studies.icgo_relm.config import StudyConfig
from tests.test_experiments_run import _compose, _job_cfg

KWARGS = {"toolface_step_deg": 30.0}
CFG = StudyConfig(split=dict(n_repeats=2), model=dict(hidden=8), budget=dict(pop_size=8, iterations=3),
                  optimizer="cgo", strategies=("original", "wavelet"))
FRONT = ["budget=smoke", "progress=false", "figures=false", "jax_cache_dir=null", "worlds=2", "dataset.seed=100",
         "+dataset.kwargs.toolface_step_deg=30.0", "strategy.names=[original,wavelet]", "split.n_repeats=2",
         "model.hidden=8"]


@pytest.fixture(scope="module")
def worlds_run(tmp_path_factory):
    from experiments._study_main import run_job

    out = tmp_path_factory.mktemp("worlds") / "run"
    run = run_job(_job_cfg(FRONT), out)
    return out, run


def test_the_front_door_writes_each_world_and_the_pooled_result(worlds_run):
    out, run = worlds_run
    for f in ("metrics.csv", "convergence.csv", "msa.csv", "coverage.csv", "worlds.csv", "worlds_pooled.csv",
              "summary.md", "run.json", "config.yaml"):
        assert (out / f).is_file(), f
    assert not (out / "predictions.csv").exists()
    rec = json.loads((out / "run.json").read_text())
    assert rec["worlds"] == {"seeds": [100, 101], "development_seeds": []} and rec["models"] == []
    assert rec["execution"]["members"] == 2 * 2 * 2 and rec["timings"]["capacity"] == [128, 80]
    m = pd.read_csv(out / "metrics.csv")
    assert set(m.world) == {100, 101} and set(m.repeat) == {0, 1}
    # worlds.csv is each world's mean over its repeats, recomputed here from the metrics
    per = pd.read_csv(out / "worlds.csv")
    test = m[m.split == "test"].groupby(["world", "method"]).mae.mean()
    for _, r in per.iterrows():
        assert r.mae == pytest.approx(test[(r.world, r.method)], rel=1e-9)
    pooled = pd.read_csv(out / "worlds_pooled.csv").set_index("method")
    w = per[per.method == "cgo-wavelet"].mae
    assert pooled.loc["cgo-wavelet", "MAE (deg)"] == f"{w.mean():.4f} +/- {w.std(ddof=1):.4f}"
    md = (out / "summary.md").read_text()
    assert "No world is a development seed" in md and "first (worlds)" in md and "Holm over the 1 tests" in md
    assert "## Each world" in md


def test_a_world_of_a_worlds_run_is_that_world_alone(worlds_run):
    """Bitwise the same world run alone through run_worlds (same padded shapes, same key); against the unpadded
    one-data-set study of the same seed and key the fitness agrees to 1e-6 relative."""
    worlds = W.simulate("lab_casing", [100, 101], **KWARGS)
    both = W.run_worlds(worlds, CFG)
    for w, res in zip(worlds, both.results):
        alone = W.run_worlds([w], CFG).results[0]
        np.testing.assert_array_equal(alone.model.params.theta, res.model.params.theta)
        np.testing.assert_array_equal(alone.curves["best_fitness"], res.curves["best_fitness"])
        pd.testing.assert_frame_equal(alone.metrics, res.metrics)
        one = S.run(S.SurveyData(w.frame, w.meta), CFG, W.world_key(CFG.split.seed, w.seed))
        np.testing.assert_allclose(one.curves["best_fitness"][..., 0], res.curves["best_fitness"][..., 0], rtol=1e-6)
        pd.testing.assert_frame_equal(one.msa, res.msa, rtol=1e-9)
    assert both.table("metrics").world.tolist()[0] == 100 and both.development == []


def test_the_worlds_tables_and_tests_against_independent_computations():
    rng = np.random.default_rng(3)
    rows = []
    for world in range(12):
        base = rng.normal(0.04, 0.004)
        for method, shift in (("a", 0.0), ("b", 0.003), ("c", 0.001)):
            for repeat in range(3):
                rows.append({"world": world, "method": method, "repeat": repeat, "split": "test",
                             "mae": base + shift + rng.normal(0, 0.002), "rmse": 1.3 * base, "r2_error": 0.99})
    m = pd.DataFrame(rows)
    per = R.per_world(m)
    assert len(per) == 36 and set(per.n) == {3}
    a = m[m.method == "a"].groupby("world").mae.mean().to_numpy()
    b = m[m.method == "b"].groupby("world").mae.mean().to_numpy()
    c = m[m.method == "c"].groupby("world").mae.mean().to_numpy()
    np.testing.assert_allclose(per[per.method == "a"].mae, a)
    # first in k of N: the lowest of the three per world
    firsts = R.first_counts(per, ["a", "b", "c"])
    lowest = np.argmin(np.column_stack([a, b, c]), axis=1)
    assert firsts.tolist() == [int((lowest == i).sum()) for i in range(3)]
    pooled = R.pooled(per, ["a", "b", "c"]).set_index("method")
    assert pooled.loc["a", "MAE (deg)"] == f"{a.mean():.4f} +/- {a.std(ddof=1):.4f}"
    assert pooled.loc["b", "first (worlds)"] == f"{firsts['b']} of 12"
    # Wilcoxon over worlds, Holm over the family: scipy's p-values, adjusted by hand
    tests = R.paired_tests(per, [("a", "b"), ("a", "c")])
    p = np.array([sps.wilcoxon(a, b).pvalue, sps.wilcoxon(a, c).pvalue])
    np.testing.assert_allclose(tests["p"], p)
    order = np.argsort(p)
    holm = np.empty(2)
    holm[order] = np.minimum(np.maximum.accumulate(np.array([2, 1]) * p[order]), 1.0)
    np.testing.assert_allclose(tests["p (Holm)"], holm)
    assert tests["median difference a - b"].iloc[0] == pytest.approx(np.median(a - b))
    assert ("significantly better" in tests["verdict"].iloc[0]) == (holm[0] < 0.05)
    fr = R.friedman_over_worlds(per, ["a", "b", "c"])
    assert fr.p_value == pytest.approx(sps.friedmanchisquare(a, b, c).pvalue)
    assert R.order(per, ["a", "b", "c"]) == [x for _, x in sorted(zip([a.mean(), b.mean(), c.mean()], "abc"))]
    assert R.seeds_text([100, 101, 102, 110]) == "100-102, 110"


def test_the_reported_worlds_exclude_every_development_seed():
    assert W.FIRST_REPORTED_SEED not in W.DEVELOPMENT_SEEDS
    for preset in ("table1_worlds", "table3_worlds", "fig9_worlds"):
        cfg = _compose([f"experiment={preset}"])
        seeds = W.world_seeds(cfg.dataset.seed, cfg.worlds)
        assert cfg.worlds >= 30 and not set(seeds) & set(W.DEVELOPMENT_SEEDS), preset
        assert cfg.dataset.name == "lab_casing" and cfg.label == preset


@pytest.mark.parametrize("overrides, message", [
    (["worlds=0"], "worlds must be null"),
    (["worlds=2", "dataset=csv", "dataset.path=/etc/hostname"], "dataset=csv is one recording"),
    (["worlds=2", "split=transfer"], "split=transfer is not supported"),
])
def test_bad_worlds_settings_are_one_line(overrides, message):
    from omegaconf import OmegaConf

    from icgo.studies.icgo_relm.run_config import RunConfig

    with pytest.raises(SettingError, match=message):
        RunConfig.from_mapping(OmegaConf.to_container(_compose(overrides), resolve=True))


def test_worlds_need_distinct_seeds_and_no_transfer():
    worlds = W.simulate("lab_casing", [100], **KWARGS)
    with pytest.raises(ValueError, match="distinct"):
        W.run_worlds(worlds + worlds, CFG)
    with pytest.raises(ValueError, match="no data set"):
        W.simulate("bogus", [1])
    with pytest.raises(ValueError, match=">= 1"):
        W.world_seeds(100, 0)


@pytest.mark.parametrize("name,pairs", [
    ("table3", [("cgo-three_stage", "cgo-wavelet"), ("cgo-three_stage", "cgo-chaos")]),
    ("table1", [("cgo-original", "relm"), ("cgo-original", "relm-tuned")]),
    ("fig9", [("cgo-original", "pso"), ("cgo-original", "ga")])])
def test_the_committed_worlds_tables_from_their_per_world_rows(name, pairs):
    """results/<name>_worlds.{csv,md} recomputed from its per-world rows: pooled mean +/- sample std, first in k of N
    worlds, and the Wilcoxon signed-rank p of each pair (scipy, exact for 30 worlds without ties)."""
    from pathlib import Path

    res = Path(__file__).resolve().parents[1] / "results"
    per = pd.read_csv(res / f"{name}_worlds_per_world.csv")
    pooled = pd.read_csv(res / f"{name}_worlds.csv").set_index("method")
    wide = per.pivot(index="world", columns="method", values="mae")[list(pooled.index)]
    assert sorted(wide.index) == list(range(100, 130))
    first = wide.idxmin(axis=1).value_counts()
    for m, row in pooled.iterrows():
        assert row["MAE (deg)"] == f"{wide[m].mean():.4f} +/- {wide[m].std(ddof=1):.4f}"
        assert row["first (worlds)"] == f"{int(first.get(m, 0))} of 30"
    md = (res / f"{name}_worlds.md").read_text()
    names = dict(zip(pooled.index, pooled["name"]))
    for a, b in pairs:
        p = sps.wilcoxon(wide[a], wide[b]).pvalue
        line = next(ln for ln in md.splitlines() if ln.startswith(f"| {names[a]} vs {names[b]} "))
        cells = [c.strip() for c in line.strip("|").split("|")]
        assert float(cells[4]) == pytest.approx(p, rel=1e-3)
