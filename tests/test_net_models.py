"""icgo.artifacts.network: the gyro network, RELM and lookup-table artifacts (apply, save/load round trip, errors)."""

from __future__ import annotations

import jax
import numpy as np
import pandas as pd
import pytest

import icgo  # noqa: F401
from icgo.core.errors import ModelError
from icgo.models import gyro_relm, nets
from icgo.artifacts.network import GyroNetwork, GyroRELM, LookupTableModel
from icgo.artifacts.registry import load_model
from icgo.studies.gyro import study as gyro


def _frame(I, A, T, rng):
    a_raw = A + 2.0 * np.sin(np.radians(T)) + 0.5 * np.cos(np.radians(A)) + 0.01 * rng.standard_normal(A.shape)
    return pd.DataFrame({"station": np.arange(len(A)), "inclination_deg": I, "azimuth_deg": A, "toolface_deg": T,
                         "inclination_raw_deg": I, "toolface_raw_deg": T, "azimuth_raw_deg": np.mod(a_raw, 360.0)})


@pytest.fixture(scope="module")
def fitted():
    rng = np.random.default_rng(0)
    I, A, T = (x.ravel() for x in np.meshgrid([10.0, 30.0, 50.0], np.arange(0, 360, 60.0), np.arange(0, 360, 60.0),
                                              indexing="ij"))
    train = _frame(I, A, T, rng)
    u = rng.random((3, 40))
    new = _frame(10 + 40 * u[0], 360 * u[1], 360 * u[2], rng)
    keys = jax.random.split(jax.random.PRNGKey(0), 3)
    ncfg = nets.NetConfig(epochs=300, patience=300, batch_size=16)
    rc = gyro.RelmConfig(hidden=20)
    models = {"table": gyro.fit_table(gyro.TableConfig(), train, {"k": 1}),
              "net": gyro.fit_network("net_error", ncfg, keys, train, {"k": 2})[0],
              "relm": gyro.fit_relm(rc, keys, train, False, {"k": 3})[0]}
    return train, new, keys, ncfg, models


def test_members_are_the_library_predictions(fitted):
    train, new, keys, ncfg, models = fitted
    i, t, a = (new[c].to_numpy() for c in ("inclination_raw_deg", "toolface_raw_deg", "azimuth_raw_deg"))
    res = nets.fit(keys, train.inclination_raw_deg, train.toolface_raw_deg, train.azimuth_raw_deg,
                   train.azimuth_deg, ncfg)
    np.testing.assert_array_equal(models["net"].members(new),
                                  np.asarray(nets.predict_seeds(res.params, np.column_stack([i, t, a]))))
    assert models["net"].members(new).shape == (3, 40) and models["relm"].members(new).shape == (3, 40)
    assert models["table"].members(new).shape == (1, 40)
    # every method compensates most of the smooth systematic error it was trained on
    raw = np.abs(gyro.azimuth_errors(new.azimuth_deg, new.azimuth_raw_deg)).mean()
    for name in ("net", "relm"):
        assert np.abs(gyro.azimuth_errors(new.azimuth_deg, models[name].members(new))).mean() < 0.5 * raw, name


def test_apply_is_the_circular_mean_over_seeds(fitted):
    _, new, _, _, models = fitted
    out = models["net"].apply(new)
    assert list(out.columns) == ["station", "azimuth_raw_deg", "azimuth_compensated", "azimuth_spread_deg"]
    m = models["net"].members(new)
    dev = ((m - m[0] + 180.0) % 360.0) - 180.0
    np.testing.assert_allclose(((out.azimuth_compensated - m[0] - dev.mean(0) + 180.0) % 360.0) - 180.0, 0, atol=1e-9)
    np.testing.assert_allclose(out.azimuth_spread_deg, dev.std(0, ddof=1), atol=1e-12)
    assert (models["table"].apply(new).azimuth_spread_deg == 0).all()


@pytest.mark.parametrize("name,cls", [("table", LookupTableModel), ("net", GyroNetwork), ("relm", GyroRELM)])
def test_save_load_apply_is_bitwise(fitted, tmp_path, name, cls):
    _, new, _, _, models = fitted
    m = models[name]
    before = m.apply(new)
    back = load_model(m.save(tmp_path / name))
    assert isinstance(back, cls) and back.config == m.config and back.data_hash == m.data_hash
    pd.testing.assert_frame_equal(back.apply(new), before, check_exact=True)
    np.testing.assert_array_equal(back.members(new), m.members(new))


@pytest.mark.parametrize("name", ["table", "net", "relm"])
def test_predict_is_pure_jit_and_vmap_able(fitted, name):
    """Each family's predict jits whole (the same function up to XLA's fusion: last-bit rounding) and vmaps over
    members; the model applies it as it is."""
    _, new, _, _, models = fitted
    m = models[name]
    x = m.inputs(new)
    np.testing.assert_allclose(np.atleast_2d(np.asarray(jax.jit(type(m).PREDICT)(m.params, x))), m.members(new),
                               rtol=0, atol=1e-9)
    if name != "table":  # one member alone is predict of that member's params
        one = jax.tree.map(lambda a: a[1], m.params)
        single = {"net": nets.predict, "relm": gyro_relm.predict}[name]
        np.testing.assert_allclose(np.asarray(single(one, x)), m.members(new)[1], rtol=0, atol=1e-9)


@pytest.mark.parametrize("name", ["table", "net", "relm"])
def test_a_schema_1_file_loads_as_it_is(fitted, tmp_path, name):
    """The gyro kinds' layout is schema 1's: a file written before schema 2 loads and applies the same."""
    import json

    _, new, _, _, models = fitted
    path = models[name].save(tmp_path / name)
    head = json.loads(path.read_text())
    head["schema_version"] = 1
    path.write_text(json.dumps(head))
    pd.testing.assert_frame_equal(load_model(path).apply(new), models[name].apply(new), check_exact=True)


def test_missing_angle_column_is_one_line(fitted):
    _, new, _, _, models = fitted
    for m in models.values():
        with pytest.raises(ModelError, match="toolface_raw_deg|azimuth_raw_deg") as e:
            m.apply(new.drop(columns=["toolface_raw_deg", "azimuth_raw_deg"]))
        assert "\n" not in str(e.value)
