"""ICGO-RELM study core: bookkeeping, batched == alone (bitwise), honesty, bad inputs, lab_casing numbers."""

import dataclasses
import re

import numpy as np
import pandas as pd
import pytest

import icgo  # noqa: F401
from icgo.core.errors import SettingError
from icgo.physics import metrics
from icgo.physics import effects, frames
from icgo.studies.icgo_relm import study
from icgo.studies.icgo_relm.config import RENAMED_PRECISIONS, StudyConfig
from icgo.studies.icgo_relm.prepare import frame_arrays, prepare, sigma_filter
from icgo.studies.icgo_relm.search import check_search, search, search_kernel, train_rows


def sim_frame(seed=0, tf_step=10.0):
    A, T = np.meshgrid([30.0, 120.0, 210.0, 300.0], np.arange(0, 360, tf_step), indexing="ij")
    A, T = A.ravel(), T.ravel()
    I = np.full_like(A, 90.0)
    s = frames.sensors_from_attitude(A, I, T, 50_000.0, 60.0)
    G, B = effects.apply_effects({"hard_iron": np.array([300.0, -200.0, 500.0]),
                                  "mag_cross_coupling": np.array([0.01, -0.006, 0.004]),
                                  "mag_misalignment": np.array([0.3, -0.2, 0.4])},
                                 s.G, s.B, frames.tool_to_earth(A, I, T))
    rng = np.random.default_rng(seed)
    G = np.asarray(G) + rng.normal(0, 3e-4, (A.size, 3))
    B = np.asarray(B) + rng.normal(0, 15.0, (A.size, 3))
    return pd.DataFrame({"station": np.arange(A.size), "gx": G[:, 0], "gy": G[:, 1], "gz": G[:, 2],
                         "bx": B[:, 0], "by": B[:, 1], "bz": B[:, 2], "azimuth_deg": A,
                         "inclination_deg": I, "toolface_deg": T})


PLAIN = StudyConfig(split=dict(n_repeats=3, seed=7), model=dict(hidden=10), optimizer=None)


@pytest.fixture(scope="module")
def frame():
    return sim_frame()


@pytest.fixture(scope="module")
def plain(frame):
    return study.run_study(frame, PLAIN)


def test_bookkeeping_and_metrics_recomputed_from_predictions(plain, frame):
    n = int(plain.kept.sum())
    assert len(frame) - 3 <= n <= len(frame)
    p = plain.predictions
    assert len(p) == 3 * n and set(p.method) == {"relm"}
    n_train = round(0.7 * n)
    assert (p[p.repeat == 0].split == "train").sum() == n_train
    # Different repeats have different splits.
    assert not np.array_equal(p[p.repeat == 0].split.to_numpy(), p[p.repeat == 1].split.to_numpy())
    for r in range(3):
        t = p[(p.repeat == r) & (p.split == "test")]
        m = plain.metrics.query("method == 'relm' and split == 'test' and repeat == @r").iloc[0]
        e = np.asarray(frames.angle_diff(t.azimuth_compensated, t.azimuth_true))
        assert m.mae == pytest.approx(np.mean(np.abs(e)), rel=1e-10)
        assert m.rmse == pytest.approx(np.sqrt(np.mean(e**2)), rel=1e-10)
        assert m.r2_error == pytest.approx(float(metrics.r2_error(t.error_msa, e)), rel=1e-10)
        np.testing.assert_allclose(e, np.asarray(frames.angle_diff(t.error_msa - t.predicted_error, 0.0)),
                                   atol=1e-9)
    # MSA removes most of the raw error, the model most of what is left.
    s = plain.summary
    assert s.loc[("msa", "test"), "mae_mean"] < 0.8 * s.loc[("raw", "test"), "mae_mean"]
    assert s.loc[("relm", "test"), "mae_mean"] < 0.8 * s.loc[("msa", "test"), "mae_mean"]
    assert plain.curves["best_fitness"].shape == (1, 3, 1)
    assert list(plain.msa.repeat) == [0, 1, 2] and np.all(plain.msa.condition < 10)


def test_repeat_alone_equals_batched_bitwise(plain, frame):
    alone = study.run_study(frame, dataclasses.replace(PLAIN, repeat_ids=(2,)))
    a = alone.predictions.drop(columns="repeat").reset_index(drop=True)
    b = plain.predictions[plain.predictions.repeat == 2].drop(columns="repeat").reset_index(drop=True)
    pd.testing.assert_frame_equal(a, b, check_exact=True)
    np.testing.assert_array_equal(alone.curves["best_fitness"][0, 0], plain.curves["best_fitness"][0, 2])


def test_test_rows_never_steer_the_fit(plain, frame):
    # Corrupt the reference azimuth of repeat 0's test rows: training side unchanged.
    # (The sigma filter runs once before splitting, as in the paper, so it is off here.)
    cfg = PLAIN.replace(split={"sigma_filter": None}, repeat_ids=(0,))
    base = study.run_study(frame, cfg)
    test_rows = base.predictions.row[base.predictions.split == "test"].to_numpy()
    bad = frame.copy()
    bad.loc[test_rows, "azimuth_deg"] = np.mod(bad.loc[test_rows, "azimuth_deg"] + 7.0, 360.0)
    other = study.run_study(bad, cfg)
    np.testing.assert_array_equal(other.curves["best_fitness"], base.curves["best_fitness"])
    tr = lambda r: r.predictions[r.predictions.split == "train"].predicted_error.to_numpy()  # noqa: E731
    np.testing.assert_array_equal(tr(other), tr(base))


def test_sigma_filter_drops_a_spike(frame):
    bad = frame.copy()
    bad.loc[5, "bx"] += 3000.0
    keep = sigma_filter(*frame_arrays(bad))
    assert not keep[5] and keep.sum() >= len(bad) - 3


@pytest.mark.parametrize("change, match", [
    ({"model": {"lam": 0.0}}, "model.lam .* lambda"),
    ({"model": {"hidden": 200}}, "hidden"),
    ({"fitness": {"mode": "loo"}}, "fitness.mode"),
    ({"split": {"train_fraction": 1.0}}, "split.train_fraction"),
    ({"optimizer": "nope"}, "unknown optimizer"),
    ({"msa": {"reference": "known"}}, "metadata"),
    ({"split": {"n_repeats": 0}}, "split.n_repeats .*repeats"),
])
def test_bad_config(frame, change, match):
    with pytest.raises(ValueError, match=match):
        study.run_study(frame, PLAIN.replace(**change))


def test_bad_frames(frame):
    with pytest.raises(ValueError, match="column"):
        study.run_study(frame.drop(columns="bz"), PLAIN)
    nan = frame.copy()
    nan.loc[3, "gy"] = np.nan
    with pytest.raises(ValueError, match="row 3, column 'gy'"):
        study.run_study(nan, PLAIN)
    one = frame[frame.azimuth_deg == 30.0]
    with pytest.raises(ValueError, match="eps_z"):
        study.run_study(one, PLAIN.replace(model={"hidden": 5}))


@pytest.mark.slow
def test_cgo_strategies_batched_equals_alone_and_beats_plain(frame):
    cfg = StudyConfig(split=dict(n_repeats=2, seed=3), model=dict(hidden=10), budget=dict(pop_size=8, iterations=6),
                      optimizer="cgo", strategies=("original", "three_stage"))
    res = study.run_study(frame, cfg)
    assert res.curves["best_fitness"].shape == (2, 2, 6)
    assert np.all(np.diff(res.curves["best_fitness"], axis=-1) <= 0)  # best-so-far
    alone = study.run_study(frame, dataclasses.replace(cfg, repeat_ids=(1,)))
    np.testing.assert_array_equal(alone.curves["best_fitness"][:, 0], res.curves["best_fitness"][:, 1])
    a = alone.predictions.drop(columns="repeat").reset_index(drop=True)
    b = res.predictions[res.predictions.repeat == 1].drop(columns="repeat").reset_index(drop=True)
    pd.testing.assert_frame_equal(a, b, check_exact=True)


@pytest.mark.slow
def test_lab_casing_msa_and_plain_relm():
    from icgo.datasets import casing_stations
    from icgo.models import msa

    clean = casing_stations.lab_casing(0, casing=None, effects={"hard_iron": [900.0, -700.0, 1500.0]})
    G, B, A = frame_arrays(clean.frame)
    r = msa.multi_station_analysis(G, B)
    assert np.all(np.abs(np.asarray(r.bias) - [900.0, -700.0, 1500.0]) < 3 * np.asarray(r.std_error))
    ds = casing_stations.lab_casing(0)
    res = study.run_study(ds.frame, StudyConfig(split=dict(n_repeats=3), optimizer=None))
    p = res.predictions[res.predictions.repeat == 0]
    # With the casing, MSA leaves a residual structured in toolface: per azimuth, two
    # toolface harmonics explain most of it.
    explained = []
    for az, g in p.groupby("azimuth_true"):
        t = np.radians(g.toolface_deg.to_numpy())
        X = np.column_stack([np.ones_like(t), np.cos(t), np.sin(t), np.cos(2 * t), np.sin(2 * t)])
        y = g.error_msa.to_numpy()
        fit = X @ np.linalg.lstsq(X, y, rcond=None)[0]
        explained.append(1 - np.sum((y - fit) ** 2) / np.sum((y - y.mean()) ** 2))
    assert np.median(explained) > 0.8 and np.sqrt(np.mean(p.error_msa**2)) > 0.3
    s = res.summary
    assert s.loc[("relm", "test"), "mae_mean"] < s.loc[("msa", "test"), "mae_mean"]


@pytest.mark.parametrize("precision, rtol", [("float32_features", 5e-6), ("float64", 1e-9)])
def test_tiny_cgo_study_train_kernel_batched_equals_alone(frame, precision, rtol):
    """The train-mode searches (float32_features = default, float64): repeat k batched == alone, and the
    fitness they search with, on either kernel, is the row-weighted float64 one to the precision's tolerance."""
    import jax
    import jax.numpy as jnp

    from icgo.core.execution import ACCELERATOR_KERNEL, CPU_KERNEL
    from icgo.models import relm, search_fitness

    cfg = StudyConfig(split=dict(n_repeats=2, seed=5), model=dict(hidden=10), budget=dict(pop_size=6, iterations=3),
                      optimizer="cgo", strategies=("original", "three_stage"), precision=precision)
    assert StudyConfig().precision == "float32_features"
    res = study.run_study(frame, cfg)
    alone = study.run_study(frame, dataclasses.replace(cfg, repeat_ids=(1,)))
    np.testing.assert_array_equal(alone.curves["best_fitness"][:, 0], res.curves["best_fitness"][:, 1])
    G, B, a = frame_arrays(frame)
    prep, _ = prepare(None, G, B, a, cfg.replace(split={"n_repeats": 1}), jax.random.PRNGKey(0))
    data = jax.tree_util.tree_map(lambda x: x[0], prep.data)
    rows = jax.tree_util.tree_map(lambda x: x[0], train_rows(prep))
    pop = relm.random_theta(jax.random.PRNGKey(1), 10, (12,))
    ref = np.asarray(relm.fitness(pop, data, 1e-3, 10))
    for kernel in (CPU_KERNEL, ACCELERATOR_KERNEL):
        sk = search_kernel(precision, "train", kernel)
        assert sk.train_rows
        f = search_fitness.search_fitness(pop, sk.aux(rows, jnp.asarray(1e-3), 10))
        np.testing.assert_allclose(np.asarray(f), ref, rtol=rtol)


def test_a_lambda_sweep_compiles_the_search_once(frame):
    """lam travels as data (:class:`icgo.models.search_fitness.SearchData`): a search at another ridge lambda reuses
    the compiled search and minimises the float64 fitness at that lambda."""
    import jax

    from icgo.models import relm
    from icgo.optim.sharded import compiled_programs

    cfg = StudyConfig(split=dict(n_repeats=2, seed=4), model=dict(hidden=5), budget=dict(pop_size=5, iterations=2),
                      optimizer="pso", precision="float64")
    G, B, a = frame_arrays(frame)
    prep, _ = prepare(None, G, B, a, cfg, jax.random.PRNGKey(cfg.split.seed))
    search(cfg, prep)
    n = compiled_programs()
    thetas, curve, _ = search(cfg.replace(model={"lam": 0.5}), prep)
    assert n >= 1 and compiled_programs() == n
    for r in range(2):
        data = jax.tree_util.tree_map(lambda x, r=r: x[r], prep.data)
        ref = [float(relm.fitness(thetas[0, r][None], data, lam, 5)[0]) for lam in (0.5, 1e-3)]
        assert float(curve[0, r, -1]) == pytest.approx(ref[0], rel=1e-9) and abs(ref[1] / ref[0] - 1) > 1e-6


@pytest.mark.parametrize("old, new", list(RENAMED_PRECISIONS.items()))
def test_old_precision_names_are_refused_naming_the_new_ones(old, new):
    line = f"precision '{old}' was renamed: use float32_features (was fast) or float64 (was mixed)"
    with pytest.raises(SettingError, match=re.escape(line)):
        StudyConfig(precision=old)
    assert StudyConfig(precision=new).precision == new


def test_wrap_fitness_sees_every_search_call(frame):
    """run_study(wrap_fitness=...) wraps the search's fitness (the progress bar's hook)."""
    import jax

    calls = []

    def wrap(f):
        def g(pop, aux):
            jax.debug.callback(lambda: calls.append(1))
            return f(pop, aux)
        return g

    cfg = StudyConfig(split=dict(n_repeats=2, seed=2), model=dict(hidden=10), budget=dict(pop_size=6, iterations=4),
                      optimizer="pso")
    study.run_study(frame, cfg, wrap_fitness=wrap)
    jax.effects_barrier()
    shards = cfg.execution().devices  # each device's block of members calls the fitness on its own
    assert len(calls) == (4 + 1) * shards  # initial population + one call per iteration, per block


def test_a_search_that_never_found_a_finite_fitness_is_a_failed_run():
    curve = np.ones((2, 3, 4))
    check_search(curve, ["a", "b"], (0, 1, 2))
    curve[1, 2, :] = np.inf
    with pytest.raises(ValueError, match=r"search of b \(repeat 2\) never found a finite fitness \(1 of 6"):
        check_search(curve, ["a", "b"], (0, 1, 2))


def test_tuned_relm_picks_the_best_mean_validation_cell_from_training_rows_only(frame):
    """Issue 18's honest baseline: (L, lambda) chosen on the grid by validation on the training rows."""
    from icgo.models import relm

    cfg = PLAIN.replace(split={"sigma_filter": None}, model={"hidden": 30, "tune": True},
                        fitness={"mode": "validation"})
    res = study.run_study(frame, cfg)
    grid = pd.DataFrame(res.tuning["grid"])
    best = grid.loc[grid.val_mean.idxmin()]
    assert ((res.config.model.hidden, res.config.model.lam) == (best.hidden, best.lam)
            == (res.tuning["hidden"], res.tuning["lam"]))
    assert set(grid.lam) == set(relm.TUNE_LAMBDA) and set(grid.hidden) <= set(relm.TUNE_HIDDEN)
    assert res.config.method_names() == ["relm-tuned"] and set(res.metrics.method) >= {"relm-tuned"}
    # the chosen cell's run is plain RELM at that cell: its fitness is the grid's value
    np.testing.assert_allclose(res.curves["best_fitness"][0, :, -1].mean(), best.val_mean, rtol=1e-12)
    # the test rows never steer the choice
    test_rows = res.predictions.row[(res.predictions.split == "test") & (res.predictions.repeat == 0)].to_numpy()
    bad = frame.copy()
    bad.loc[test_rows, "azimuth_deg"] = np.mod(bad.loc[test_rows, "azimuth_deg"] + 7.0, 360.0)
    other = study.run_study(bad, dataclasses.replace(cfg, repeat_ids=(0,)))
    alone = study.run_study(frame, dataclasses.replace(cfg, repeat_ids=(0,)))
    assert other.tuning == alone.tuning


@pytest.mark.parametrize("change, match", [
    ({"optimizer": "cgo"}, "tune tunes plain RELM only"),
    ({"fitness": {"mode": "train"}}, "tune chooses hidden and lam by validation"),
])
def test_tune_needs_plain_relm_and_a_validation_fitness(change, match):
    with pytest.raises(ValueError, match=match):
        StudyConfig(**{"optimizer": None, "model": {"tune": True}, "fitness": {"mode": "validation"}, **change})


def _sigma_filter_by_masks(G, B, a, n_sigma=3.0):
    """The 3-sigma rule with one boolean mask per azimuth group (the former O(N x groups) loop)."""
    from icgo.physics.qc import measured_dip_deg

    keep = np.ones(len(a), bool)
    for q in (np.linalg.norm(G, axis=1), np.linalg.norm(B, axis=1), measured_dip_deg(G, B)):
        if q.std() > 0:
            keep &= np.abs(q - q.mean()) <= n_sigma * q.std()
    err = np.asarray(frames.angle_diff(np.asarray(frames.azimuth_from_gv(G, B)), a))
    for az in np.unique(np.round(a, 6)):
        g = np.round(a, 6) == az
        s = err[g].std()
        if g.sum() > 2 and s > 0:
            keep[g] &= np.abs(err[g] - err[g].mean()) <= n_sigma * s
    return keep


def test_sigma_filter_groups_by_sorting_exactly_as_by_masks(frame):
    G, B, a = frame_arrays(frame)
    rng = np.random.default_rng(5)
    B = B + np.where(rng.random((len(a), 1)) < 0.02, 3000.0, 0.0)  # some outliers to drop
    for az in (a, np.where(rng.random(len(a)) < 0.5, a, rng.uniform(0, 360, len(a))), np.r_[-0.0, a[1:] * 0.0]):
        np.testing.assert_array_equal(sigma_filter(G, B, az), _sigma_filter_by_masks(G, B, az))


@pytest.mark.parametrize("lam", [5e3, 1e300, 0.0, -1.0])
def test_a_lambda_outside_what_a_model_may_carry_is_refused_at_construction(lam):
    """The bound a saved model is read with (icgo.models.relm.MAX_LAM) is the study config's own: a library
    StudyConfig never runs a study whose model load_model would refuse."""
    from icgo.models import relm

    with pytest.raises(SettingError, match=r"lam must be a number > 0 and at most 1000"):
        StudyConfig(model=dict(lam=lam))
    assert StudyConfig(model=dict(lam=relm.MAX_LAM)).model.lam == relm.MAX_LAM
