"""Every order the README and docs state over worlds is carried by a test (results/worlds_orders.{csv,md},
icgo.studies.icgo_relm.results.worlds_orders), and the claim markers fail when a stated order flips: a copy of
results/ is perturbed so that an order the prose states no longer holds (or an order it calls untested becomes
significant), and the render of the real README.md and docs/ reports the sentence."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from icgo.reporting import documents as D
from icgo.reporting.render import RenderError, carried, pair, untested
from icgo.studies.icgo_relm.results import worlds_orders as O

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "results"


def test_the_committed_order_tests_recompute_from_the_per_world_rows():
    """results/worlds_orders.csv is what the per-world rows give (no hand edit), and one pair checked against
    scipy's exact Wilcoxon and Holm by hand."""
    from scipy import stats

    got = O.tests(RESULTS)
    committed = pd.read_csv(RESULTS / "worlds_orders.csv")
    assert list(got["comparison"]) == list(committed["comparison"])
    assert list(got["order carried"]) == list(committed["order carried"])
    np.testing.assert_allclose(got["p (Holm)"], committed["p (Holm)"], rtol=1e-5)
    per = pd.read_csv(RESULTS / "fig9_worlds_per_world.csv").pivot_table(index="world", columns="method", values="mae")
    raw = {(a, b): stats.wilcoxon(per[a], per[b]).pvalue for a, b in (("pso", "ga"), ("pso", "cgo-original"),
                                                                       ("ga", "cgo-original"))}
    ps = sorted(raw.values())
    holm = {k: min(1.0, max((3 - i) * ps[i] for i in range(sorted(raw.values()).index(v) + 1)))
            for k, v in raw.items()}
    fig9 = got[got.family == "fig9"].set_index(["a", "b"])
    for k, p in holm.items():
        assert fig9.loc[k, "p (Holm)"] == pytest.approx(p, rel=1e-9)
    assert fig9.loc[("pso", "ga"), "a lower in"] == f"{int((per['pso'] < per['ga']).sum())} of {len(per)}"


def test_every_family_is_every_pair_of_its_table_fixed_in_advance():
    for name, (_, methods, pairs) in O.FAMILIES.items():
        n = len(methods)
        assert pairs is None and len(O.family_pairs(methods)) == n * (n - 1) // 2, name
    got = O.tests(RESULTS)
    assert dict(got.groupby("family")["family size"].first()) == {
        "table1": 3, "table3": 10, "fig9": 3, "table1 x table3": 2, "table1 (instruments)": 3,
        "table3 (instruments)": 10}


def test_carried_untested_and_pair_read_the_order_either_way_round():
    rows = [{"a": "x", "b": "y", "median difference a - b": -0.002, "p (Holm)": 0.01},
            {"a": "y", "b": "z", "median difference a - b": 0.001, "p (Holm)": 0.2}]
    assert carried(rows, "x", "y") and not carried(rows, "y", "x")
    assert not carried(rows, "z", "y") and untested(rows, "y", "z") and untested(rows, "z", "y")
    assert not untested(rows, "x", "y") and pair(rows, "z", "y") is rows[1]
    with pytest.raises(RenderError, match="0 rows compare them"):
        pair(rows, "x", "z")
    with pytest.raises(RenderError, match="2 rows compare them"):
        pair(rows + rows[:1], "y", "x")


@pytest.fixture
def copy(tmp_path):
    out = tmp_path / "results"
    shutil.copytree(RESULTS, out)
    assert D.check(D.documents(), out) == []  # the copy renders clean before it is perturbed
    return out


def _swap(path: Path, m1: str, m2: str, value: str | None = None) -> None:
    """Swap two methods' per-world rows (all metrics, or one)."""
    df = pd.read_csv(path)
    a, b = df["method"] == m1, df["method"] == m2
    cols = [value] if value else ["mae", "rmse", "r2_error"]
    for c in cols:
        va, vb = df.loc[a, c].to_numpy().copy(), df.loc[b, c].to_numpy().copy()
        df.loc[a, c], df.loc[b, c] = vb, va
    df.to_csv(path, index=False, float_format="%.10g")


def _problems(results: Path, needle: str) -> list[str]:
    return [p for p in D.check(D.documents(), results) if needle in p]


def test_fig9_pso_below_ga_flipped_in_the_per_world_rows_fails_the_render(copy):
    _swap(copy / "fig9_worlds_per_world.csv", "pso", "ga")
    assert O.build(copy)
    assert pair(pd.read_csv(copy / "worlds_orders.csv").query("family == 'fig9'").to_dict("records"), "pso",
                "ga")["order carried"] == "GA-RELM < PSO-RELM"
    hits = _problems(copy, 'carried(p9, "pso", "ga")')
    assert {h.split(":")[0] for h in hits} >= {"README.md", "docs/optimizers.md", "docs/relm_study.md"}, hits


def test_table3_third_place_made_significant_fails_the_untested_sentence(copy):
    """The prose calls chaotic vs Gaussian untested; rows where chaotic is lower in every world make it a carried
    order, and the sentences that call it untested fail."""
    path = copy / "table3_worlds_per_world.csv"
    df = pd.read_csv(path)
    chaos, gauss = df["method"] == "cgo-chaos", df["method"] == "cgo-gaussian"
    df.loc[chaos, "mae"] = df.loc[gauss, "mae"].to_numpy() - 0.001
    df.to_csv(path, index=False, float_format="%.10g")
    assert O.build(copy)
    hits = _problems(copy, 'untested(p3, x, y)')
    assert {h.split(":")[0] for h in hits} >= {"README.md", "docs/relm_study.md"}, hits


def test_table3_pooled_order_flipped_fails_the_render(copy):
    """Three-stage's pooled MAE set above the chaotic's (the issue's perturbation, on the order the README states)."""
    path = copy / "table3_worlds.csv"
    df = pd.read_csv(path)
    df.loc[df["method"] == "cgo-three_stage", "MAE (deg)"] = "0.0406 +/- 0.0015"
    df.to_csv(path, index=False)
    hits = _problems(copy, 'num(w3["cgo-wavelet"]["MAE (deg)"]) < num(w3["cgo-three_stage"]["MAE (deg)"])')
    assert [h.split(":")[0] for h in hits] == ["README.md"], hits


def test_tuned_relm_against_three_stage_flipped_fails_the_render(copy):
    _swap(copy / "table1_worlds_per_world.csv", "relm-tuned", "relm")  # the tuned RELM now far above three-stage
    path = copy / "table3_worlds_per_world.csv"
    df = pd.read_csv(path)
    df.loc[df["method"] == "cgo-three_stage", "mae"] = 1.0  # and three-stage above it in every world
    df.to_csv(path, index=False, float_format="%.10g")
    assert O.build(copy)
    hits = _problems(copy, 'carried([tx], "cgo-three_stage", "relm-tuned")')
    assert [h.split(":")[0] for h in hits] == ["README.md"], hits


def test_the_instrument_family_order_flipped_fails_the_render(copy):
    """Wavelet and three-stage swapped in the instrument family's rows: the README's and docs/relm_study.md's
    sentences that the wavelet is first over the family fail."""
    _swap(copy / "table3_instruments_per_world.csv", "cgo-wavelet", "cgo-three_stage")
    assert O.build(copy)
    hits = [p for p in D.check(D.documents(), copy) if 'family="table3 (instruments)"' in p or "carried(q3" in p]
    assert {h.split(":")[0] for h in hits} == {"README.md", "docs/relm_study.md"}, hits
