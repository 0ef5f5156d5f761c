"""icgo.studies.misma (MISMA vs SMA on rotating_drill and the real devices) and its entry point experiments.misma."""

from __future__ import annotations

import jax
import numpy as np
import pandas as pd
import pytest
from hydra import compose, initialize_config_dir
from hydra.errors import ConfigCompositionException
from omegaconf import OmegaConf

import icgo  # noqa: F401
from experiments import misma as entry
from experiments import _run_study as door
from experiments._preflight import CONF_DIR
from icgo.core.errors import SettingError
from icgo.core.settings import config_from_mapping, config_to_mapping
from icgo.datasets.drill_string import rotating_drill
from icgo.io.mag_cal_bundled import load_mag_cal_device
from icgo.models import calibration as cal
from icgo.artifacts.calibration import MagCalibration
from icgo.artifacts.registry import load_model
from icgo.studies.calibration import study as calibration
from icgo.studies.misma import study as misma, compare as misma_compare
from icgo.studies.misma.config import MismaConfig
from icgo.studies.misma.simulated import prior_box
from icgo.studies.registry import STUDIES

#: A short drilling run (600 s: two stops), 2 repeats of 5 iterations, one real device, no peer package.
TINY = {"simulated": {"variants": {"short": {"duration_s": 600.0}}, "repeats": 2, "n_iter": 5, "pop_size": 6},
        "real": {"peer": False, "misma_iter": 3, "misma_repeats": 2}}


def _compose(*overrides):
    with initialize_config_dir(config_dir=str(CONF_DIR), version_base="1.3"):
        return compose("misma", list(overrides))


def test_registered():
    s = STUDIES["misma"]
    assert s is misma.STUDY and s.config_cls is MismaConfig and s.run is misma.run


def test_the_study_defaults_come_from_the_dataclass_once():
    """conf/misma.yaml writes none of MismaConfig's fields: the node it names first (made from the dataclass,
    experiments/_schema.py) gives them, so the composed settings are the dataclass's defaults and build it."""
    import dataclasses

    own = OmegaConf.load(CONF_DIR / "misma.yaml")
    assert not {f.name for f in dataclasses.fields(MismaConfig)} & set(own.keys())
    composed = {k: v for k, v in OmegaConf.to_container(_compose(), resolve=True).items() if k not in entry.ENTRY_KEYS}
    assert composed == config_to_mapping(MismaConfig())
    assert door.study_config("misma", _compose(), entry.ENTRY_KEYS) == MismaConfig()


def test_unknown_settings_are_refused():
    with pytest.raises(ConfigCompositionException):
        _compose("simulated.repeat=3")  # struct mode: no such key
    for ov, msg in [("+repeats=3", "unknown setting"),
                    ("+simulated.misma.zmax=1", r"simulated.misma: unknown setting")]:
        with pytest.raises(ValueError, match=msg):
            door.study_config("misma", _compose(ov), entry.ENTRY_KEYS)


def test_config_errors_are_one_line_and_name_the_field():
    for ov, msg in [(["simulated.pop_size=2"], "simulated.pop_size"), (["simulated.repeats=0"], "simulated.repeats"),
                    (["simulated.n_iter=0"], "simulated.n_iter"),
                    (["simulated.dot_samples=some"], "simulated.dot_samples"),
                    (["simulated.subsample=0"], "simulated.subsample"),
                    (["simulated.objective.pearson_mode=x"], "simulated.objective.pearson_mode"),
                    (["simulated.misma.d=1.5"], "simulated.misma.d"), (["simulated.sma.z=-1"], "simulated.sma.z"),
                    (["+simulated.variants.bad={depth: 1}"], "simulated.variants.bad unknown rotating_drill"),
                    (["real.misma_iter=0"], "real.misma_iter"), (["seed=-1"], "seed"), (["real.peer=2"], "real.peer"),
                    (["simulated.enabled=false", "real.enabled=false"], "nothing to run")]:
        with pytest.raises(ValueError, match=msg) as e:
            door.study_config("misma", _compose(*ov), entry.ENTRY_KEYS)
        assert "\n" not in str(e.value), ov
        assert isinstance(e.value, SettingError), ov  # "<dotted key> <problem>"


def test_offset_key_is_the_seed_stream():
    np.testing.assert_array_equal(misma.offset_key(jax.random.PRNGKey(5), 7), jax.random.PRNGKey(12))
    typed = misma.offset_key(jax.random.key(5), 1)
    np.testing.assert_array_equal(jax.random.key_data(typed), jax.random.key_data(jax.random.key(6)))


def test_prior_box_and_iters_to():
    lb, ub = prior_box(50_000.0, 0.5, 0.2)
    np.testing.assert_allclose(0.5 * (lb + ub), np.r_[np.eye(3).ravel(), np.zeros(3)])
    np.testing.assert_allclose((ub - lb)[9:], 2 * 0.2 * 50_000.0)
    curve = np.array([[5.0, 3.0, 1.0, 1.0], [5.0, 4.0, 4.0, 4.0]])
    np.testing.assert_array_equal(misma_compare.iters_to(curve, 2.0), [3.0, np.nan])


@pytest.fixture(scope="module")
def tiny():
    cfg = config_from_mapping(MismaConfig, TINY)
    data = misma.MismaData({"short": rotating_drill(0, duration_s=600.0)}, {"ab": load_mag_cal_device("ab")})
    return cfg, data, misma.run(data, cfg, jax.random.PRNGKey(0))


@pytest.mark.slow
def test_tiny_run_records_and_models(tiny):
    cfg, data, res = tiny
    assert set(res.records) == {"params_short", "modulus_short", "fair_short", "tests_short", "gyro_sweep",
                                "simulated", "real_devices", "real_summary"}
    p = res.records["params_short"]
    truth = data.simulated["short"].truth
    np.testing.assert_allclose(p["true"], np.asarray(cal.params_from_error_model(np.asarray(truth["R"]),
                                                                                  np.asarray(truth["b_nT"]))))
    s = res.summary["simulated"][0]
    assert s["variant"] == "short" and s["overrides"] == {"duration_s": 600.0}
    # the true parameters cut the raw static-point azimuth error (noise floor below the raw error)
    assert s["baselines_az_err_deg"]["true parameters"] < s["az_err_raw_deg"]
    # survey QC at the static points: raw and after every fit, against the run's reference field
    n_static = int(data.simulated["short"].frame["static"].sum())
    assert list(s["qc_static"]) == ["raw", "U", "twelve", "SMA", "MISMA"]
    assert all(c["n"] == n_static for c in s["qc_static"].values())
    real = res.records["real_devices"]
    # the calibration study's splits (in-sample, each group held out), then the inner splits of each held-out one
    labels = list(dict.fromkeys(real.split))
    outer = [s[0] for s in calibration.splits(data.devices["ab"].frame["group"].to_numpy())]
    assert outer == ["in-sample", "held-out group 8", "held-out group 9"] and labels[:3] == outer
    assert len(labels) > 3 and all(label.split(" / ")[0] in outer[1:] for label in labels[3:])
    assert {"ab_ellipsoid", "ab_twelve_axis", "ab_misma_axis", "ab_joint", "short_misma", "short_sma",
            "short_modulus"} <= set(res.models)
    assert all(isinstance(m, MagCalibration) for m in res.models.values())
    # the in-sample score is what the returned model gives
    rec = data.devices["ab"]
    groups = rec.frame["group"].to_numpy()
    ins = real[real.split == "in-sample"].set_index("method")
    for col, name in (("twelve+axis", "ab_twelve_axis"), ("joint", "ab_joint")):
        got = calibration.group_score(res.models[name], rec.G, rec.B, groups, np.ones(len(groups), bool))
        assert not ins.loc[col, "degenerate"] and got == ins.loc[col, "score_deg"]
    # the unaligned ellipsoid fit sees a different dip in every shot: it fails the sanity check and has no score
    assert ins.loc["ellipsoid", "degenerate"] and np.isnan(ins.loc["ellipsoid", "score_deg"])


@pytest.mark.slow
def test_same_key_same_records(tiny):
    cfg, data, res = tiny
    again = misma.run(data, cfg, jax.random.PRNGKey(0))
    for k in res.records:
        pd.testing.assert_frame_equal(again.records[k], res.records[k], check_exact=True)
    for k in res.models:
        np.testing.assert_array_equal(again.models[k].params.x_mag, res.models[k].params.x_mag)


@pytest.mark.slow  # ~15 s of compilation in a fresh process; tests/test_studies.py runs the example in the fast suite
def test_smoke_simulated_only_is_deterministic_by_key():
    cfg = config_from_mapping(MismaConfig, {**TINY, "real": {"enabled": False}})
    data = misma.MismaData({"short": rotating_drill(0, duration_s=600.0)}, {})
    a, b = (misma.run(data, cfg, jax.random.PRNGKey(2)) for _ in range(2))
    for k in a.records:
        pd.testing.assert_frame_equal(a.records[k], b.records[k], check_exact=True)
    c = misma.run(data, cfg, jax.random.PRNGKey(3))
    assert not a.records["params_short"]["MISMA"].equals(c.records["params_short"]["MISMA"])


@pytest.mark.slow
def test_entry_point_writes_tables_figures_and_models(tmp_path):
    cfg = _compose(f"out_dir={tmp_path}", "simulated.repeats=2", "simulated.n_iter=5", "simulated.pop_size=6",
                   "~simulated.variants", "+simulated.variants={short: {duration_s: 600.0}}", "real.enabled=false")
    res = door.run_composed("misma", cfg, tmp_path / "models", entry_keys=entry.ENTRY_KEYS)
    for name in ("misma_params_short.csv", "misma_params_short.md", "misma_modulus_short.csv", "misma_short.png",
                 "misma_summary.md", "misma_summary.json"):
        assert (tmp_path / name).is_file(), name
    back = load_model(tmp_path / "models" / "short_misma.json")
    frame = rotating_drill(0, duration_s=600.0).frame
    pd.testing.assert_frame_equal(back.apply(frame), res.models["short_misma"].apply(frame), check_exact=True)


def _holm_by_hand(p):
    order, out, running = np.argsort(p), np.empty(len(p)), 0.0
    for rank, i in enumerate(order):
        running = max(running, min(1.0, (len(p) - rank) * p[i]))
        out[i] = running
    return out


def test_the_headline_test_and_the_gyro_sweep_are_one_holm_family_each():
    """MISMA vs SMA over the variants, and every (variant, grade) cell of the gyro sweep, each Holm-adjusted as one
    family (scipy's paired Wilcoxon, Holm written out); the verdict words follow the adjusted p and the sign."""
    from scipy.stats import wilcoxon

    rng = np.random.default_rng(0)
    errors = [{"MISMA": rng.normal(0.3, 0.05, 10), "SMA": rng.normal(4.0, 0.5, 10)},
              {"MISMA": rng.normal(6.0, 1.0, 10), "SMA": rng.normal(6.1, 1.0, 10)}]
    sums = [{"variant": "a"}, {"variant": "b"}]
    misma_compare.headline_tests(sums, errors)
    p = np.array([wilcoxon(e["MISMA"], e["SMA"]).pvalue for e in errors])
    np.testing.assert_allclose([s["p_MISMA_vs_SMA"] for s in sums], p, rtol=1e-12)
    np.testing.assert_allclose([s["p_MISMA_vs_SMA_holm"] for s in sums], _holm_by_hand(p), rtol=1e-12)
    assert [s["MISMA_vs_SMA"] for s in sums] == ["lower", "no significant difference"]
    cells = pd.DataFrame({"variant": ["a"] * 5 + ["b"] * 5, "p": [0.5, 0.4, 0.3, 0.2, 0.1, 1.0, 0.9, 0.8, 0.6, 0.0039],
                          "MISMA_gyro_az_err_median_diff_deg": [-0.1] * 9 + [3.5]})
    out = misma_compare.sweep_family(cells)
    np.testing.assert_allclose(out["p_holm"], _holm_by_hand(cells["p"].to_numpy()))
    assert out["p_holm"].iloc[-1] == pytest.approx(0.039) and out["J_gyro"].iloc[-1] == "higher"
    assert set(out["J_gyro"].iloc[:-1]) == {"no significant difference"}


def test_contrast_tests_say_which_way_each_change_moves_the_error():
    from scipy.stats import wilcoxon

    rng = np.random.default_rng(1)
    a, b, c = misma_compare.SMA_U, misma_compare.MISMA_U, misma_compare.MISMA_U_OMEGA
    errors = {a: rng.normal(1.7, 0.1, 10), b: rng.normal(0.5, 0.05, 10)}
    errors[c] = errors[b] + rng.normal(0.0, 0.01, 10)
    df = misma_compare.paired_tests([("ops", a, b), ("gyro", b, c)], errors)
    p = [wilcoxon(errors[a], errors[b]).pvalue, wilcoxon(errors[b], errors[c]).pvalue]
    np.testing.assert_allclose(df["p_holm"], _holm_by_hand(np.array(p)), rtol=1e-12)
    assert df["median_b_minus_a_deg"].iloc[0] == pytest.approx(float(np.median(errors[b] - errors[a])))
    assert df["b_vs_a"].tolist() == ["lower", "no significant difference"]
