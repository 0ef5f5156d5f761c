"""icgo.studies.gyro (the gyro inclinometer study) and its entry point experiments.gyro."""

from __future__ import annotations

import json

import jax
import numpy as np
import pandas as pd
import pytest
from hydra import compose, initialize_config_dir
from hydra.errors import ConfigCompositionException
from omegaconf import OmegaConf

import icgo  # noqa: F401
from experiments import gyro as entry
from experiments import _run_study as door
from experiments._preflight import CONF_DIR
from icgo.core.errors import SettingError
from icgo.core.settings import config_from_mapping, config_to_mapping
from icgo.artifacts.registry import load_model
from icgo.studies.gyro import study as gyro
from icgo.studies.registry import STUDIES

#: A study small enough for a test: 32 turntable points, 2 seeds, 2 variants, tiny RELM search and sweep.
TINY = {"n_seeds": 2,
        "data": {"inclinations_deg": [10, 40], "azimuth_step_deg": 90, "toolface_step_deg": 90, "n_random": 50},
        "net": {"epochs": 10, "patience": 10, "batch_size": 8},
        "variants": {"net_error": {}, "net_azimuth": {"target": "azimuth"}},
        "relm": {"hidden": 5, "pop_size": 6, "iterations": 3},
        "sweep": {"azimuth_steps": [90], "toolface_steps": [90, 180], "table_only_azimuth_steps": [45]}}


def _compose(*overrides):
    with initialize_config_dir(config_dir=str(CONF_DIR), version_base="1.3"):
        return compose("gyro", list(overrides))


def test_registered():
    s = STUDIES["gyro"]
    assert s is gyro.STUDY and s.config_cls is gyro.GyroConfig and s.run is gyro.run


def test_the_study_defaults_come_from_the_dataclass_once():
    """conf/gyro.yaml writes none of GyroConfig's fields: the node it names first (made from the dataclass,
    experiments/_schema.py) gives them, so the composed settings are the dataclass's defaults and build it."""
    import dataclasses

    own = OmegaConf.load(CONF_DIR / "gyro.yaml")
    assert not {f.name for f in dataclasses.fields(gyro.GyroConfig)} & set(own.keys())
    composed = {k: v for k, v in OmegaConf.to_container(_compose(), resolve=True).items() if k not in entry.ENTRY_KEYS}
    assert composed == config_to_mapping(gyro.GyroConfig())
    assert door.study_config("gyro", _compose(), entry.ENTRY_KEYS) == gyro.GyroConfig()


def test_unknown_settings_are_refused():
    with pytest.raises(ConfigCompositionException):
        _compose("net.optimiser=sgd")  # struct mode: no such key
    for ov, msg in [("+epochs=3", "unknown setting"), ("+relm.foo=1", r"relm: unknown setting.*foo")]:
        with pytest.raises(ValueError, match=msg):
            door.study_config("gyro", _compose(ov), entry.ENTRY_KEYS)


def test_config_errors_are_one_line_and_name_the_field():
    for ov, msg in [("n_seeds=0", "n_seeds"), ("data.azimuth_step_deg=0", "data.azimuth_step_deg"),
                    ("data.inclinations_deg=[10,95]", "data.inclinations_deg"),
                    ("net.target=true_azimuth", "net nets: target"),
                    ("+variants.bad={optimiser: sgd}", r"variants.bad unknown key"),
                    ("sweep.variant=nope", "sweep.variant"), ("table.toolface=median", "table.toolface"),
                    ("relm.fitness=test", "relm.fitness"), ("relm.optimizer=adam", "relm.optimizer"),
                    ("relm.strategy=nope", "relm.strategy"), ("relm.theta_bounds=[1,-1]", "relm.theta_bounds"),
                    ("seam.band_deg=0", "seam.band_deg")]:
        with pytest.raises(ValueError, match=msg) as e:
            door.study_config("gyro", _compose(ov), entry.ENTRY_KEYS)
        assert "\n" not in str(e.value), ov
        assert isinstance(e.value, SettingError), ov  # "<dotted key> <problem>"


def _frame(I, A, T, rng):
    """A turntable-like frame: raw attitude = nominal + a smooth systematic error (deg) + noise."""
    a_raw = A + 1.5 * np.sin(np.radians(T + A)) + 0.5 * np.cos(np.radians(2 * A)) + 0.01 * rng.standard_normal(A.shape)
    return pd.DataFrame({"station": np.arange(len(A)), "inclination_deg": I, "azimuth_deg": A, "toolface_deg": T,
                         "inclination_raw_deg": I + 0.01 * rng.standard_normal(A.shape),
                         "toolface_raw_deg": np.mod(T + 0.2, 360.0), "azimuth_raw_deg": np.mod(a_raw, 360.0)})


def synthetic(seed=0) -> gyro.GyroData:
    """Fast stand-in for load_data (no instrument simulation): a 2 x 4 x 4 grid and 50 random attitudes."""
    rng = np.random.default_rng(seed)
    I, A, T = (x.ravel() for x in np.meshgrid([10.0, 40.0], np.arange(0, 360, 90.0), np.arange(0, 360, 90.0),
                                              indexing="ij"))
    u = rng.random((3, 50))
    rand = _frame(10 + 30 * u[0], 360 * u[1], 360 * u[2], rng)
    return gyro.GyroData(_frame(I, A, T, rng), {"random": rand, "between": _frame(I + 15, A + 45, T + 45, rng)})


def test_table_is_exact_at_the_nodes():
    # Same turntable points as train and test: the table reproduces the toolface-mean error of each node
    train = synthetic().train
    err = gyro.azimuth_errors(train["azimuth_raw_deg"], train["azimuth_deg"])
    f = train.assign(inclination_raw_deg=train["inclination_deg"], azimuth_raw_deg=train["azimuth_deg"])
    pred = gyro.fit_table(gyro.TableConfig(), train, {}).members(f)[0]
    node_mean = pd.Series(err).groupby([train["inclination_deg"], train["azimuth_deg"]]).transform("mean")
    np.testing.assert_allclose(gyro.azimuth_errors(train["azimuth_deg"], pred), node_mean, atol=1e-9)


#: Smaller still: one variant, no RELM, no sweep (the fast smoke run).
SMOKE = {**TINY, "variants": {"net_error": {}}, "relm": {"enabled": False}, "sweep": {"enabled": False}}


def test_smoke_run_is_deterministic_by_key(tmp_path):
    cfg = config_from_mapping(gyro.GyroConfig, SMOKE)
    data = synthetic()
    a, b = (gyro.run(data, cfg, jax.random.PRNGKey(1)) for _ in range(2))
    assert set(a.records) == {"methods", "seam"} and set(a.models) == {"table", "net_error"}
    for k in a.records:
        pd.testing.assert_frame_equal(a.records[k], b.records[k], check_exact=True)
    np.testing.assert_array_equal(a.models["net_error"].params.w1, b.models["net_error"].params.w1)
    # the study scored every method through the predict its saved model applies: save -> load -> members bitwise
    for name, model in a.models.items():
        back = load_model(model.save(tmp_path / name))
        for k, f in data.tests.items():
            np.testing.assert_array_equal(back.members(f), a.predictions[name][k])


@pytest.fixture(scope="module")
def tiny():
    cfg = config_from_mapping(gyro.GyroConfig, TINY)
    data = gyro.load_data(cfg)
    return cfg, data, gyro.run(data, cfg, jax.random.PRNGKey(3))


@pytest.mark.slow
def test_tiny_run_records_models_and_raw_scores(tiny):
    cfg, data, res = tiny
    m = res.records["methods"]
    assert list(dict.fromkeys(m.method)) == ["raw", "table", "net_error", "net_azimuth", "relm", "icgo_relm"]
    assert set(res.models) == {"table", "net_error", "net_azimuth", "relm", "icgo_relm"}
    assert {k: c["n"] for k, c in res.summary["qc"].items()} == {"train": len(data.train),
                                                                  **{k: len(f) for k, f in data.tests.items()}}
    assert (m.loc[m.method == "net_error", "n_seeds"] == 2).all()
    # raw RMSE recomputed independently from the data (numpy, no icgo angle helpers)
    for k, f in data.tests.items():
        d = np.mod(f["azimuth_raw_deg"] - f["azimuth_deg"] + 180.0, 360.0) - 180.0
        got = m.loc[(m.method == "raw") & (m.test == k), "rmse_mean"].item()
        np.testing.assert_allclose(got, np.sqrt(np.mean(d ** 2)), rtol=1e-12)
    # every scored prediction is what the returned model applies
    for name, model in res.models.items():
        for k, f in data.tests.items():
            np.testing.assert_array_equal(model.members(f), np.atleast_2d(res.predictions[name][k]))
    # the search starts from random hidden weights and keeps the best: its training fitness beats plain RELM's
    assert np.all(res.models["icgo_relm"].train_fitness < res.models["relm"].train_fitness)
    pts = res.records["points"]
    assert set(pts.n_points.dropna()) == {32.0, 16.0, 64.0}
    assert set(pts.loc[pts.n_points == 64, "method"]) == {"table"}  # table-only step


@pytest.mark.slow
def test_same_key_same_records(tiny):
    cfg, data, res = tiny
    again = gyro.run(data, cfg, jax.random.PRNGKey(3))
    assert set(again.records) == set(res.records)
    for k in res.records:
        pd.testing.assert_frame_equal(again.records[k], res.records[k], check_exact=True)
    other = gyro.run(data, cfg, jax.random.PRNGKey(4))
    a, b = other.records["methods"], res.records["methods"]
    assert not np.array_equal(a.loc[a.method == "net_error", "rmse_mean"], b.loc[b.method == "net_error", "rmse_mean"])


@pytest.mark.slow
def test_entry_point_writes_tables_figures_and_models(tmp_path):
    overrides = [f"out_dir={tmp_path}", "jax_cache_dir=null", "n_seeds=2", "data.inclinations_deg=[10,40]",
                 "data.azimuth_step_deg=90", "data.toolface_step_deg=90", "data.n_random=50", "net.epochs=10",
                 "net.patience=10", "net.batch_size=8", "~variants", "+variants={net_error: {}}",
                 "relm.enabled=false", "sweep.azimuth_steps=[90]", "sweep.toolface_steps=[90]",
                 "sweep.table_only_azimuth_steps=[45]"]
    summary = door.run_composed("gyro", _compose(*overrides), tmp_path / "models", entry_keys=entry.ENTRY_KEYS).summary
    for name in ("gyro_methods.csv", "gyro_methods.md", "gyro_seam.csv", "gyro_seam.png", "gyro_points.csv",
                 "gyro_points.png", "gyro_toolface.png", "gyro_run.json"):
        assert (tmp_path / name).is_file(), name
    m = pd.read_csv(tmp_path / "gyro_methods.csv")
    assert m.columns[-1] == "train_s" and m.loc[m.method == "raw", "train_s"].isna().all()
    assert json.loads((tmp_path / "gyro_run.json").read_text())["n_train"] == summary["n_train"] == 32
    net = load_model(tmp_path / "models" / "gyro_net_error.json")
    f = gyro.load_data(door.study_config("gyro", _compose(*overrides), entry.ENTRY_KEYS)).tests["random"]
    e = gyro.azimuth_errors(f["azimuth_deg"].to_numpy(), net.members(f))
    np.testing.assert_allclose(np.sqrt(np.mean(e ** 2, axis=1)).mean(),
                               m.loc[(m.method == "net_error") & (m.test == "random"), "rmse_mean"].item(), rtol=1e-12)
