"""Split protocols (icgo.studies.common.splits), the padded fast fitness, split-conformal coverage (icgo.maths.conformal),
the protocols through the ICGO-RELM study and the physics baseline of the generalisation table."""

from __future__ import annotations

import dataclasses

import jax
import numpy as np
import pandas as pd
import pytest

from icgo.core.errors import SettingError
from icgo.datasets import casing_stations
from icgo.maths.conformal import conformal_quantile, member_coverage
from icgo.models import relm
from icgo.studies.common import splits
from icgo.studies.icgo_relm.study import run_study
from icgo.studies.icgo_relm.config import StudyConfig


@pytest.fixture(scope="module")
def lab():
    return casing_stations.lab_casing(0, toolface_step_deg=45.0)


def test_random_members_are_the_papers_permutation_split(lab):
    key = jax.random.PRNGKey(4)
    mem = splits.members("random", lab.frame, key, [0, 3], 0.7)
    n = len(lab.frame)
    for i, r in enumerate((0, 3)):
        perm = np.asarray(jax.random.permutation(jax.random.split(jax.random.fold_in(key, r), 3)[0], n))
        expect = np.zeros(n)
        expect[perm[:round(0.7 * n)]] = 1
        np.testing.assert_array_equal(mem.train[i], expect)
        np.testing.assert_array_equal(mem.test[i], 1 - expect)
        np.testing.assert_array_equal(mem.heldout[i], mem.test[i])


def test_leave_azimuth_out_holds_out_each_station_once_per_repeat(lab):
    mem = splits.members("leave_azimuth_out", lab.frame, jax.random.PRNGKey(0), [0, 1], 0.7)
    az = lab.frame["azimuth_deg"].to_numpy()
    assert len(mem.fold_label) == len(np.unique(az)) == 8 and mem.train.shape[0] == 16
    for r in (0, 1):
        sel = mem.repeat == r
        np.testing.assert_array_equal(mem.test[sel].sum(axis=0), np.ones(len(az)))  # every row tested exactly once
        for t, tr in zip(mem.test[sel], mem.train[sel]):
            assert len(np.unique(az[t > 0])) == 1                                    # one whole azimuth
            assert not np.isin(az[tr > 0], az[t > 0]).any()                          # never seen in training
    assert len({tuple(k) for k in mem.keys.tolist()}) == 16                            # one key per member


def test_transfer_trains_on_the_random_splits_rows_and_tests_only_the_target(lab):
    key = jax.random.PRNGKey(2)
    n = len(lab.frame)
    both = pd.concat([lab.frame, lab.frame.iloc[:10]])
    tr = splits.members("transfer", both, key, [0, 1], 0.7, n_source=n)
    rnd = splits.members("random", lab.frame, key, [0, 1], 0.7)
    np.testing.assert_array_equal(tr.train[:, :n], rnd.train)
    assert (tr.train[:, n:] == 0).all() and (tr.test[:, :n] == 0).all() and (tr.test[:, n:] == 1).all()
    assert (tr.heldout[:, n:] == 0).all()                          # the target never calibrates an interval
    np.testing.assert_array_equal(tr.heldout[:, :n], rnd.test)


def test_fold_protocols_name_a_missing_column_or_a_single_group(lab):
    with pytest.raises(ValueError, match="needs a 'condition' column"):
        splits.members("leave_condition_out", lab.frame, jax.random.PRNGKey(0), [0], 0.7)
    one = lab.frame[lab.frame["azimuth_deg"] == 30.0]
    with pytest.raises(ValueError, match="need at least 2"):
        splits.members("leave_azimuth_out", one, jax.random.PRNGKey(0), [0], 0.7)


def test_transfer_draw_changes_only_what_it_says():
    d = splits.TransferDraw(seed=3, casing_distance_scale=1.2, casing_strength_scale=0.5, misalignment_deg=(0.1, 0, 0))
    t = splits.transfer_survey("lab_casing", 0, {"toolface_step_deg": 90.0}, d)
    c = casing_stations.LAB_CASING
    truth = t.truth
    assert t.meta["seed"] == 3
    np.testing.assert_allclose(truth["effects"]["mag_misalignment"],
                               np.asarray(casing_stations.LAB_EFFECTS["mag_misalignment"]) + [0.1, 0, 0])
    cas = truth["casing"]
    np.testing.assert_allclose(cas["end_ned"], 1.2 * np.asarray(c.end_ned))
    assert cas["magnetization_A_m"] == pytest.approx(0.5 * c.magnetization_A_m)
    with pytest.raises(ValueError, match="another noise draw"):
        splits.transfer_survey("lab_casing", 3, {}, d)
    with pytest.raises(SettingError, match="misalignment_deg"):
        splits.TransferDraw(misalignment_deg=(0.1, 0.2))


@pytest.mark.parametrize("n_train", [37, 52])
def test_padded_fast_fitness_equals_the_float64_row_weighted_fitness(n_train):
    N, L = 80, 9
    X = jax.random.normal(jax.random.PRNGKey(0), (N, 6))
    T = jax.random.normal(jax.random.PRNGKey(1), (N,))
    m = np.zeros(N)
    m[np.random.default_rng(n_train).permutation(N)[:n_train]] = 1
    data = relm.FitData(X, T, m[None], m[None])
    pop = relm.random_theta(jax.random.PRNGKey(3), L, (13,))
    ref = np.asarray(relm.fitness(pop, data, 1e-3, L))
    padded = relm.train_rows(data, 60, padded=True)          # 60 >= n_train rows, the rest weight 0
    assert float(padded.w.sum()) == n_train
    np.testing.assert_allclose(np.asarray(relm.train_fitness(pop, padded, 1e-3, L)), ref, rtol=1e-10)


def test_conformal_quantile_is_the_ceil_rank_order_statistic():
    x = np.arange(1.0, 20.0)                                  # n = 19: ceil(20 * 0.9) = 18th smallest
    assert conformal_quantile(np.random.default_rng(0).permutation(x), 0.9) == 18.0
    assert conformal_quantile(x[:5], 0.9) == 5.0              # ceil(6 * 0.9) = 6 > n: the largest
    assert np.isnan(conformal_quantile([], 0.9))


def test_member_coverage_never_calibrates_on_the_members_own_test_rows():
    # two members: each tests half of the rows and trains on the other half. Member 0's test rows carry
    # large errors; its interval comes from member 1's held-out rows (small errors), so it covers nothing.
    N = 20
    a_true = np.zeros(N)
    first = (np.arange(N) < 10).astype(float)
    test = np.stack([first, 1 - first])
    a_comp = np.stack([np.where(first > 0, 5.0, 0.0), np.where(first > 0, 0.0, 0.1)])[None]
    q, cov, n_cal = member_coverage(a_comp, a_true, 1 - test, test, test, np.zeros(2, int), 0.9)
    assert q[0, 0] == pytest.approx(0.1) and cov[0, 0] == 0.0
    assert q[0, 1] == pytest.approx(5.0) and cov[0, 1] == 1.0
    np.testing.assert_array_equal(n_cal, [10, 10])


def _coverage_by_gathering(a_comp, a_true, train, heldout, test, pool, level):
    """member_coverage's definition, one member at a time: gather its calibration values, take their quantile."""
    from icgo.physics.frames import angle_diff

    err = np.abs(np.asarray(angle_diff(a_comp, a_true[None, None])))
    train, heldout, test = (np.asarray(x) > 0 for x in (train, heldout, test))
    S, M, _ = err.shape
    q, cov, n_cal = np.full((S, M), np.nan), np.full((S, M), np.nan), np.zeros(M, int)
    for m in range(M):
        others = (pool == pool[m]) & (np.arange(M) != m)
        cal = heldout[others] & train[m][None]
        n_cal[m] = cal.sum()
        for s in range(S):
            q[s, m] = conformal_quantile(err[s][others][cal], level)
            if test[m].any():
                cov[s, m] = np.mean(err[s, m, test[m]] <= q[s, m])
    return q, cov, n_cal


@pytest.mark.parametrize("pooled", [False, True])
def test_member_coverage_equals_gathering_each_members_calibration_values(pooled):
    """The sorted-once computation equals the per-member gather of the definition exactly: random splits of one pool
    (more members than a chunk, ties in the errors) and fold-like groups; a member without calibration rows is NaN."""
    from icgo.maths import conformal

    rng = np.random.default_rng(4)
    M, N, S = conformal.COVERAGE_CHUNK + 9, 40, 2
    test = rng.random((M, N)) < 0.3
    train = ~test
    a_comp = np.round(rng.normal(0, 0.05, (S, M, N)), 3)                        # rounded: tied errors
    pool = np.repeat(np.arange(M // 3 + 1), 3)[:M] if pooled else np.zeros(M, int)
    if pooled:
        pool[-1] = 10_000                                                        # alone in its group: no calibration
    got = member_coverage(a_comp, np.zeros(N), train, test, test, pool, 0.9)
    want = _coverage_by_gathering(a_comp, np.zeros(N), train, test, test, pool, 0.9)
    for g, w in zip(got, want):
        np.testing.assert_array_equal(g, w)
    assert np.isnan(got[0][:, -1]).all() == pooled


def test_leave_azimuth_out_study_pools_each_rows_held_out_prediction(lab):
    cfg = StudyConfig(split=dict(protocol="leave_azimuth_out", n_repeats=2), model=dict(hidden=8),
                      budget=dict(pop_size=6, iterations=3), optimizer="pso")
    res = run_study(lab.frame, cfg)
    p = res.predictions
    test = p[(p["split"] == "test") & (p["method"] == "pso")]
    assert sorted(test.groupby("repeat")["row"].nunique()) == [len(res.kept.nonzero()[0])] * 2
    for r, g in test.groupby("repeat"):
        mae = float(np.abs(g["error_compensated"]).mean())
        m = res.metrics[(res.metrics["method"] == "pso") & (res.metrics["repeat"] == r) & (res.metrics["split"] == "test")]
        assert float(m["mae"].iloc[0]) == pytest.approx(mae, rel=1e-12)
    assert set(res.coverage["fold"]) == set(range(8)) and res.coverage["coverage"].between(0, 1).all()
    # the folds' searches batch together: fold 3 of repeat 1 equals that member run alone
    alone = run_study(lab.frame, dataclasses.replace(cfg, repeat_ids=(1,)))
    h, ha = res.histories, alone.histories
    np.testing.assert_array_equal(h[(h["repeat"] == 1) & (h["fold"] == 3)]["best_fitness"].to_numpy(),
                                  ha[ha["fold"] == 3]["best_fitness"].to_numpy())


def test_transfer_study_refuses_a_missing_target_and_fold_protocols_refuse_train_fraction(lab):
    with pytest.raises(ValueError, match="needs the second instrument"):
        run_study(lab.frame, StudyConfig(split=dict(protocol="transfer", n_repeats=2), model=dict(hidden=8),
                                         optimizer=None))
    with pytest.raises(SettingError, match="train_fraction has no effect"):
        StudyConfig(split=dict(protocol="leave_azimuth_out", train_fraction=0.5))
    with pytest.raises(SettingError, match="protocol must be one of"):
        StudyConfig(split=dict(protocol="leave_one_out"))


def test_physics_baseline_recovers_the_twelve_parameters_and_an_earth_fixed_field():
    """Independent reference: data simulated with exactly the baseline's effects and no casing; the fit must
    recover them and leave an azimuth error at the noise level."""
    from icgo.discrepancy.fit import TWELVE_PLUS_FIELD, fit_members
    from icgo.discrepancy.inversion import predict
    from icgo.discrepancy.stations import stations_from_recording
    from icgo.io import recording as icgo_io
    from icgo.physics.frames import angle_diff

    truth = {"hard_iron": (400.0, -300.0, 250.0), "mag_scale": (0.004, -0.003, 0.002),
             "mag_cross_coupling": (0.003, -0.002, 0.001), "mag_misalignment": (0.2, -0.1, 0.15),
             "external_field": (300.0, -200.0, 100.0)}
    ds = casing_stations.lab_casing(1, toolface_step_deg=30.0, casing=None, effects=truth, spike_prob=0.0,
                             inclination_deg=60.0)
    st = stations_from_recording(icgo_io.validate(ds.frame, ds.meta, source="sim"))
    (params,) = fit_members(st, np.ones((1, st.n)), TWELVE_PLUS_FIELD)
    got = params.effects
    np.testing.assert_allclose(got["hard_iron"], truth["hard_iron"], atol=15.0)          # nT
    np.testing.assert_allclose(got["mag_misalignment"], truth["mag_misalignment"], atol=0.02)  # deg
    a = predict(params, ds.frame[["gx", "gy", "gz", "bx", "by", "bz"]].to_numpy(float)).azimuth
    err = np.asarray(angle_diff(np.asarray(a), ds.frame["azimuth_deg"]))
    floor = casing_stations.noise_floor("lab_casing", 1, toolface_step_deg=30.0, inclination_deg=60.0)
    assert np.abs(err).mean() < 2 * float(floor["mae"].iloc[0])


def test_generalisation_defaults_are_the_relm_studys():
    from icgo.studies.generalisation.study import GeneralisationConfig

    g, r = GeneralisationConfig(), StudyConfig()
    assert (g.pop_size, g.iterations, g.hidden) == (r.budget.pop_size, r.budget.iterations, r.model.hidden)
    assert g.transfer == splits.TransferDraw()


def test_every_protocol_is_described_with_its_own_fraction():
    """A run's caption names its split (not a fixed 30 %)."""
    assert splits.describe("random", 0.8) == "test rows: a random 20 % of the rows per repeat"
    assert "70 % of the first instrument" in splits.describe("transfer", 0.7)
    for protocol in splits.PROTOCOLS:
        assert splits.describe(protocol, 0.7).startswith("test rows: ")
    with pytest.raises(ValueError, match="bogus"):
        splits.describe("bogus", 0.7)


def test_generalisation_table_bolds_only_a_separable_first_and_says_what_lambda_was_chosen_on():
    """The table rebuilt from the committed records: a column's first by mean is bold only when every other method
    differs from it at Holm p < 0.05 (the transfer column's is not); the seeds line says the transfer target is the
    noise draw lambda was chosen on; the stamp line is there."""
    from pathlib import Path

    import pandas as pd

    from icgo.studies.generalisation.report import markdown
    from icgo.reporting.choices import LAMBDA
    from icgo.reporting.protocol import parse_protocols
    from icgo.studies.generalisation.study import GeneralisationConfig

    res = Path(__file__).resolve().parents[1] / "results"
    rec = {"metrics": pd.read_csv(res / "generalisation.csv"),
           "coverage": pd.read_csv(res / "generalisation_coverage.csv"),
           "tests": pd.read_csv(res / "generalisation_tests.csv"), "qc": pd.read_csv(res / "generalisation_qc.csv"),
           "noise_floor": pd.DataFrame({"dataset": ["lab_casing"] * 3 + ["well_conditions"] * 2,
                                        "protocol": ["random", "leave_azimuth_out", "transfer", "random",
                                                     "leave_condition_out"], "mae": [0.0237] * 3 + [0.184] * 2})}
    config = GeneralisationConfig()
    md = markdown(rec, config, {"lab_casing/random": 1.0})
    table = md.split("| method |")[1].split("\n\n")[0]
    wavelet = next(line for line in table.splitlines() if line.startswith("| ICGO-RELM (wavelet) |"))
    cells = [c.strip() for c in wavelet.split("|")[2:-1]]
    t = rec["tests"]
    for cell, (d, p) in zip(cells, [("lab_casing", "random"), ("lab_casing", "leave_azimuth_out"),
                                    ("lab_casing", "transfer")]):
        separable = (t[(t.dataset == d) & (t.protocol == p)]["p_holm"] < 0.05).all()
        assert cell.startswith("**") == bool(separable) and cell.endswith("(first by mean)") != bool(separable), cell
    assert not (t[(t.dataset == "lab_casing") & (t.protocol == "transfer")]["p_holm"] < 0.05).all()
    seeds = parse_protocols(md)[0]["seeds"]
    assert config.transfer.seed == LAMBDA.seed and "the transfer column is scored on the draw lambda was chosen on" \
        in seeds and "Nothing here was chosen" not in md
    assert "Run settings: population 30 x 100 iterations, L = 30 hidden units, 10 repeats per cell" in md
