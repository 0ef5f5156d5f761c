"""Worlds over a family of instruments (icgo.datasets.instrument_family; lab_casing(instrument="family")): a world's
instrument is a function of its seed alone, drawn within the stated ranges, and the data set it gives is the one the
same instrument set by hand gives."""

from __future__ import annotations

import numpy as np
import pytest

from icgo.datasets import instrument_family as F
from icgo.datasets.casing_stations import LAB_EFFECTS, lab_casing


def test_the_instrument_is_a_function_of_the_seed_alone():
    a, b, c = F.draw(100, LAB_EFFECTS), F.draw(100, LAB_EFFECTS), F.draw(101, LAB_EFFECTS)
    assert a == b and a != c
    # its own stream: the noise streams of the seed (SeedSequence(seed).spawn(2)) are not it
    noise = [np.random.default_rng(s).uniform() for s in np.random.SeedSequence(100).spawn(2)]
    assert F.instrument_rng(100).uniform() not in noise
    with pytest.raises(ValueError, match="seed -1"):
        F.draw(-1, LAB_EFFECTS)


def test_every_draw_is_within_the_stated_ranges_and_spans_them():
    r = F.LAB_RANGES
    draws = [F.draw(s, LAB_EFFECTS) for s in range(400)]
    dist = np.array([d.casing_distance_m for d in draws])
    mag = np.array([d.casing_magnetization_A_m for d in draws])
    noise = np.array([d.noise_factor for d in draws])
    fac = np.concatenate([np.ravel(v) for d in draws for v in d.effects_factors.values()])
    for x, (lo, hi) in ((dist, r.casing_distance_m), (mag, r.casing_magnetization_A_m), (noise, r.noise_factor),
                        (fac, r.effects_factor)):
        assert lo <= x.min() and x.max() <= hi
        assert x.min() < lo + 0.05 * (hi - lo) and x.max() > hi - 0.05 * (hi - lo)  # spans the range
    # log-uniform: half the draws below the geometric midpoint (binomial 400, 1/2: 5 sigma = 50)
    assert abs(int((mag < np.sqrt(np.prod(r.casing_magnetization_A_m))).sum()) - 200) < 50
    for d in draws[:5]:  # each error parameter is the lab's times its factor, its sign kept
        for k, p in LAB_EFFECTS.items():
            np.testing.assert_allclose(d.effects[k], np.asarray(p) * np.asarray(d.effects_factors[k]), rtol=0)
    with pytest.raises(ValueError, match="noise_factor"):
        F.draw(0, LAB_EFFECTS, ranges=F.InstrumentRanges(noise_factor=(2.0, 1.0)))


def test_a_family_world_is_the_drawn_instrument_set_by_hand():
    d = F.draw(7, LAB_EFFECTS)
    fam = lab_casing(7, instrument="family")
    hand = lab_casing(7, casing_distance_m=d.casing_distance_m, casing_magnetization_A_m=d.casing_magnetization_A_m,
                      effects=d.effects, noise_scale=d.noise_factor)
    np.testing.assert_array_equal(fam.frame.to_numpy(), hand.frame.to_numpy())
    assert fam.meta["instrument"] == d.as_dict() == fam.truth["instrument"]
    assert fam.truth["casing"]["magnetization_A_m"] == pytest.approx(d.casing_magnetization_A_m, rel=0)
    assert fam.truth["mag_noise_nT"] == pytest.approx(30.0 * d.noise_factor, rel=1e-15)
    fixed = lab_casing(7)
    assert "instrument" not in fixed.meta and not np.array_equal(fixed.frame.to_numpy(), fam.frame.to_numpy())


def test_family_settings_that_contradict_it_are_one_line():
    with pytest.raises(ValueError, match="instrument must be 'fixed' or 'family'"):
        lab_casing(0, instrument="famly")
    with pytest.raises(ValueError, match="leave casing_distance_m"):
        lab_casing(0, instrument="family", casing_distance_m=1.0)


def test_worlds_of_a_family_each_draw_their_own_instrument():
    from icgo.studies.icgo_relm.worlds.study import simulate

    two = simulate("lab_casing", [100, 101], instrument="family")
    one = simulate("lab_casing", [101], instrument="family")
    assert two[0].meta["instrument"] != two[1].meta["instrument"]
    assert two[1].meta["instrument"] == one[0].meta["instrument"]
    np.testing.assert_array_equal(two[1].frame.to_numpy(), one[0].frame.to_numpy())


def test_the_worlds_builder_writes_an_instrument_family_table_beside_the_worlds(tmp_path):
    """A (synthetic) worlds run labelled table1_instruments gives results/table1_instruments.{md,csv} and its own
    Holm family in worlds_orders, stamped with the run's environment and protocol."""
    import json

    import pandas as pd

    from icgo.studies.icgo_relm.results import worlds_tables as T

    rng = np.random.default_rng(0)
    env = {"python": "3.12.1", "jax": "0.12.1", "jaxlib": "0.12.1", "numpy": "2", "scipy": "1", "cpu": "X",
           "backend": "cpu", "device": "cpu", "device_count": 2}
    for job, methods in (("a", ("relm", "cgo-original")), ("b", ("relm-tuned",))):
        d = tmp_path / "runs" / job
        d.mkdir(parents=True)
        rows = [{"world": w, "method": m, "repeat": k, "split": "test", "mae": 0.04 + 0.01 * (m == "relm")
                 + rng.normal(0, 1e-3), "rmse": 0.05, "r2_error": 0.99}
                for w in range(100, 108) for m in methods for k in range(3)]
        pd.DataFrame(rows).to_csv(d / "metrics.csv", index=False)
        (d / "config.yaml").write_text("budget: {pop_size: 30, iterations: 100}\nsplit: {n_repeats: 3}\n"
                                       "precision: float32_features\n")
        (d / "run.json").write_text(json.dumps({"status": "ok", "label": "table1_instruments", "environment": env,
                                                "worlds": {"seeds": list(range(100, 108))}}))
    out = tmp_path / "results"
    assert T.build([tmp_path / "runs"], out) == ["table1_instruments"]
    md = (out / "table1_instruments.md").read_text()
    assert md.startswith("# Table 1 over 8 instruments (worlds of an instrument family)")
    assert "Environment: Python 3.12.1, jax 0.12.1" in md and "instrument=family" in md
    assert "--run --plan instruments" in md and len(pd.read_csv(out / "table1_instruments_per_world.csv")) == 24
    orders = pd.read_csv(out / "worlds_orders.csv")
    assert set(orders.family) == {"table1 (instruments)"} and (orders["family size"] == 3).all()
