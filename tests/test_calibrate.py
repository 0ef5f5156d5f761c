"""Calibration of grouped shots (icgo.studies.calibration, icgo.models.cal_sanity) and its front door experiments.calibrate."""

from __future__ import annotations

import dataclasses
import json
import re
import subprocess
import sys

import jax
import numpy as np
import pandas as pd
import pytest
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf

import icgo  # noqa: F401
from experiments import calibrate as entry
from experiments._preflight import CONF_DIR
from icgo.core.errors import SettingError
from icgo.core.settings import config_to_mapping
from icgo.io import mag_cal_bundled, schema
from icgo.io import recording as io
from icgo.models import cal_pointing
from icgo.models import calibration as cal
from icgo.models.cal_sanity import LIMITS, sanity
from icgo.artifacts.registry import load_model
from icgo.physics.frames import sensors_from_attitude
from icgo.physics.rolls import MIN_ROLLED_SHOTS
from icgo.studies.calibration import study as cal_study

ROOT = CONF_DIR.parent
FAST = ["peer=false", "misma_iter=3", "misma_repeats=2", "misma_pop=6"]


def _compose(*overrides):
    with initialize_config_dir(config_dir=str(CONF_DIR), version_base="1.3"):
        return compose("calibrate", list(overrides))


def test_the_study_defaults_come_from_the_dataclass_once():
    """conf/calibrate.yaml writes none of CalibrationConfig's fields: its schema gives them, so the composed study
    settings are the dataclass's defaults."""
    own = OmegaConf.load(CONF_DIR / "calibrate.yaml")
    assert not {f.name for f in dataclasses.fields(cal_study.CalibrationConfig)} & set(own.keys())
    composed = {k: v for k, v in OmegaConf.to_container(_compose(), resolve=True).items() if k not in entry.CALIBRATE_KEYS}
    assert composed == config_to_mapping(cal_study.CalibrationConfig())
    # the compilation cache's default is written once (icgo.core.devices.JAX_CACHE_DEFAULT): no YAML restates it;
    # the study doors compose it from CacheSetting, the run door from RunConfig
    from icgo.core.devices import JAX_CACHE_DEFAULT

    import experiments._groups  # noqa: F401  (they store the doors' ConfigStore nodes)
    import experiments.discrepancy  # noqa: F401
    import experiments.gyro  # noqa: F401
    import experiments.misma  # noqa: F401

    assert not [p for p in CONF_DIR.rglob("*.yaml") if "icgo/jax" in p.read_text()]
    for name in ("calibrate", "discrepancy", "misma", "gyro", "config"):
        with initialize_config_dir(config_dir=str(CONF_DIR), version_base="1.3"):
            assert OmegaConf.to_container(compose(name))["jax_cache_dir"] == JAX_CACHE_DEFAULT, name


def test_conf_yaml_is_checked_against_the_schema_of_the_dataclass(tmp_path):
    """conf/calibrate.yaml names the schema made from CalibrationConfig: an int or str study field of the wrong type
    is refused when Hydra composes (the door prints Hydra's error as one line, exit 2, and composes a sweep's later
    values before its first job); a bool and the entry point's own settings are the library's and the door's checks."""
    from hydra.errors import ConfigCompositionException

    from experiments._hydra_errors import check_sweep_values, composition_error

    for ov in ("misma_iter=abc", "misma_pop=1e9", "misma_bounds=[1]"):
        with pytest.raises(ConfigCompositionException) as e:
            _compose(ov)
        assert composition_error(e.value, "calibrate", [ov]).startswith(f"setting {ov.split('=')[0]!r}: ")
    assert check_sweep_values(["misma_iter=1,abc"], "calibrate").startswith("setting 'misma_iter': ")
    assert _compose("peer=maybe").peer == "maybe"
    assert check_sweep_values(["peer=true,maybe", "max_shots=1,abc"], "calibrate") is None
    out = _run_entry(tmp_path, "data=x.json", "misma_iter=1,abc")
    lines = out.stderr.strip().splitlines()
    assert out.returncode == 2 and len(lines) == 1, out.stderr
    assert lines[0].startswith("error: setting 'misma_iter': ") and "schema" in lines[0], lines[0]


def _one_field(n=40, seed=0, F=50_000.0, dip=60.0):
    """Shots of one field at random attitudes (tool frame), exact: the closed-form sanity reference."""
    r = np.random.default_rng(seed)
    A, I, T = r.uniform(0, 360, n), r.uniform(5, 175, n), r.uniform(0, 360, n)
    G, B = (np.asarray(x) for x in sensors_from_attitude(A, I, T, F, dip)[:2])
    return G, B


def test_sanity_passes_one_field_and_flags_a_collapsed_matrix():
    G, B = _one_field()
    ok = sanity(G, B, np.eye(3))
    assert not ok.degenerate and ok.dip_spread_deg < 1e-9 and ok.b_spread_pct < 1e-9 and ok.cond == pytest.approx(1.0)
    # a rank-1 matrix maps every shot onto one line: the score can be 0 while the field is gone
    u = np.array([1.0, 0.2, -0.1])
    collapsed = B @ np.outer(u, u).T
    bad = sanity(G, collapsed + 1e-9, np.outer(u, u))
    assert bad.degenerate and any(r.startswith("cond") for r in bad.reasons)
    assert any(r.startswith("dip_spread_deg") for r in bad.reasons)
    # a 1 % gain error on one axis bends |B| and the dip within the limits; a 5 % one moves the dip too far
    s = sanity(G, B * np.array([1.01, 1.0, 1.0]), np.diag([1.01, 1.0, 1.0]))
    assert 0 < s.b_spread_pct < LIMITS["b_spread_pct"] and s.cond == pytest.approx(1.01) and not s.degenerate
    s = sanity(G, B * np.array([1.05, 1.0, 1.0]), np.diag([1.05, 1.0, 1.0]))
    assert s.degenerate and s.reasons == (f"dip_spread_deg {s.dip_spread_deg:.3g} > 2",)


def test_misma_box_is_in_data_units_and_contains_the_least_squares():
    rec = mag_cal_bundled.load_mag_cal_device("fb")
    G, B = rec.G, rec.B
    xg = cal.ellipsoid_fit_accel(G)
    xm = cal.ellipsoid_fit(B, 1.0, G)
    Gc = np.asarray(cal.correct(xg, G))
    x12 = cal.fit_twelve(Gc, B, 1.0, x0=xm)
    lb, ub = cal_study.misma_box(xm, x12, float(np.median(np.linalg.norm(B, axis=1))))
    assert np.all((lb < x12) & (x12 < ub))
    # the bias half-width is 2 % of the field in nT (hundreds of nT), not 2 % of 1.0
    assert np.all(ub[9:] - xm[9:] >= 0.02 * np.median(np.linalg.norm(B, axis=1)) - 1e-9)
    assert np.all(ub[9:] - xm[9:] > 100.0)


def test_splits_hold_out_each_rolled_group():
    groups = mag_cal_bundled.load_mag_cal_device("ab").frame.group.to_numpy()
    labels = [s[0] for s in cal_study.splits(groups)]
    assert labels == ["in-sample", "held-out group 8", "held-out group 9"]
    with pytest.raises(ValueError, match="no rolled group"):
        cal_study.splits(np.arange(10))


def _run_entry(tmp_path, *args):
    cmd = [sys.executable, "-m", "experiments.calibrate", f"hydra.run.dir={tmp_path / 'run'}", *args]
    return subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=600)


@pytest.mark.slow
def test_front_door_on_an_exported_device_and_apply_on_another(tmp_path):
    rec = mag_cal_bundled.load_mag_cal_device("bh")
    csv = tmp_path / "bh.csv"
    io.write_recording(csv, rec.frame, rec.meta)
    out = _run_entry(tmp_path, f"data={csv}", *FAST)
    assert out.returncode == 0, out.stderr
    run = tmp_path / "run"
    for name in ("report.md", "calibration.csv", "bh.png", "models/bh_twelve_axis.json", "models/bh_joint.json"):
        assert (run / name).is_file(), name
    fits = pd.read_csv(run / "calibration.csv")
    outer = fits[fits.outer.isna()]
    assert set(fits.method) == set(cal_study.METHODS) and set(outer.split) == {"in-sample", "held-out group 8",
                                                                       "held-out group 9"}
    # inside each held-out split, its training shots split again (the nested choice): the other roll's halves
    assert set(fits.loc[fits.outer == "held-out group 8", "split"]) == {
        "held-out group 8 / held-out half of group 9 (odd shots)", "held-out group 8 / held-out half of group 9 (even shots)"}
    assert fits.loc[fits.degenerate, "score_deg"].isna().all()
    # the saved calibration applies to a second recording of the same family
    model = load_model(run / "models" / "bh_twelve_axis.json")
    other = mag_cal_bundled.load_mag_cal_device("jd").frame
    applied = model.apply(other)
    assert np.isfinite(applied[["bx_corrected", "by_corrected", "bz_corrected"]].to_numpy()).all()


@pytest.mark.slow
def test_front_door_on_a_raw_layout_json(tmp_path):
    rec = mag_cal_bundled.load_mag_cal_device("ee")
    inv = np.argsort(mag_cal_bundled.MAG_CAL_DEVICE_TO_TOOL)
    doc = {"mag": (rec.B[:, inv] / 1000.0).tolist(), "grav": (rec.G[:, inv] * schema.STANDARD_GRAVITY).tolist()}
    path = tmp_path / "ee_raw.json"
    path.write_text(json.dumps(doc))
    out = _run_entry(tmp_path, f"data={path}", "mag_axes=+x+y+z", *FAST)
    assert out.returncode == 0, out.stderr
    assert "m/s^2 / 9.80665 -> g" in (tmp_path / "run" / "report.md").read_text()


#: The bundled device ab as circuitpython-mag-cal JSON.
AB_JSON = mag_cal_bundled._mag_cal_dir().joinpath("ab.json")


@pytest.mark.parametrize("args,code,match", [
    ([], 2, "data= is required"),
    (["data=bundled", "mag_axes=+x+y+z"], 2, "mag_axes / grav_axes / groups / columns apply to a file"),
    ([f"data={AB_JSON}", "groups=[8-15,12-20]"], 2, "groups ranges 8-15 and 12-20 overlap"),
    ([f"data={AB_JSON}", "groups=[8-10]"], 2, "range 8-10 holds 3 shot(s)"),
    ([f"data={AB_JSON}", "groups=[8-23]"], 1, "group 8 (shots 8-23) is not a plausible roll"),
    ([f"data={AB_JSON}", "mag_axes=+x+y+z"], 2, "device frame already"),
    (["data=x.json", "misma_iter=0"], 2, "misma_iter must be an integer >= 1"),
    (["data=x.csv", "+no_such=1"], 2, "unknown setting"),
    (["data=/nonexistent/shots.csv"], 1, "/nonexistent/shots.csv"),
])
def test_bad_settings_and_data_are_one_line(tmp_path, args, code, match):
    out = _run_entry(tmp_path, *args)
    assert out.returncode == code, out.stderr
    err = out.stderr.strip()
    assert match in err and len(err.splitlines()) == 1, err
    assert not (tmp_path / "run" / "report.md").exists()


def test_rolls_alone_leave_a_report_with_the_reason_and_exit_4(tmp_path):
    rec = mag_cal_bundled.load_mag_cal_device("ee")
    csv = tmp_path / "rolls.csv"
    io.write_recording(csv, rec.frame.iloc[8:].reset_index(drop=True), {})
    out = _run_entry(tmp_path, f"data={csv}", *FAST)
    err = out.stderr.strip()
    assert out.returncode == 4 and len(err.splitlines()) == 1, err
    assert "no calibration recommended for rolls: in-sample: ellipsoid fit" in err and "many orientations" in err
    run = tmp_path / "run"
    report = (run / "report.md").read_text()
    assert "No calibration recommended: the fits refuse the shots" in report and "Rolls of `rolls`" in report
    record = json.loads((run / "calibration.json").read_text())
    assert record["recommendation"] is None and "many orientations" in record["refused"]
    assert (run / "rolls.png").is_file() and (run / "calibration.csv").is_file()
    assert not any(w in err + report for w in ("inf", "nan", "NaN"))


def test_csv_without_groups_is_one_line(tmp_path):
    rec = mag_cal_bundled.load_mag_cal_device("ab")
    csv = tmp_path / "nogroup.csv"
    io.write_recording(csv, rec.frame.drop(columns="group").assign(azimuth_deg=0.0, inclination_deg=0.0), {})
    out = _run_entry(tmp_path, f"data={csv}")
    assert out.returncode == 1 and "no 'group' column" in out.stderr and len(out.stderr.strip().splitlines()) == 1


def _rolled_recording(seed=1, n_single=10, n_roll=8, rolls=((40.0, 100.0), (-20.0, 230.0))):
    """Exact one-field shots: singles at random attitudes, then rolls (fixed A, I; toolface turning)."""
    r = np.random.default_rng(seed)
    A = list(r.uniform(0, 360, n_single))
    I = list(r.uniform(20, 160, n_single))
    T = list(r.uniform(0, 360, n_single))
    groups = list(range(n_single))
    for k, (inc, az) in enumerate(rolls):
        A += [az] * n_roll
        I += [90.0 + inc] * n_roll
        T += list(np.linspace(0, 315, n_roll))
        groups += [n_single + k] * n_roll
    G, B = (np.asarray(x) for x in sensors_from_attitude(np.array(A), np.array(I), np.array(T), 1.0, 60.0)[:2])
    return G, B, np.array(groups)


def _relm_residuals_numpy(W, G, b, groups, fit_rows):
    """The residuals of icgo.models.mag_relm written again from their definitions (numpy, deg), for the fitting shots."""
    from icgo.models import mag_relm
    from icgo.physics.qc import measured_dip_deg

    bn = b + mag_relm.features(b, mag_relm.axis_rbf_hidden()) @ W
    d = cal_pointing.pointing_directions(G, bn)
    dev = np.zeros_like(d)
    for g in np.unique(groups):
        m = groups == g
        if m.sum() >= MIN_ROLLED_SHOTS:
            dev[m] = d[m] - d[m].mean(0)
    dip, mod = measured_dip_deg(G, bn), np.linalg.norm(bn, axis=1)
    return np.hstack([np.degrees(dev), (dip - dip[fit_rows].mean())[:, None],
                      np.degrees(mod / mod[fit_rows].mean() - 1.0)[:, None]])


def test_relm_residuals_vanish_for_exact_shots():
    from icgo.models import mag_relm

    G, B, groups = _rolled_recording()
    b = B  # unit sphere already
    member = np.array([groups == g for g in np.unique(groups) if (groups == g).sum() >= MIN_ROLLED_SHOTS], float)
    H = mag_relm.features(b, mag_relm.axis_rbf_hidden())
    r = mag_relm.residuals(np.zeros((H.shape[1], 3)), H, G, b, member, np.ones(len(b)))
    np.testing.assert_allclose(np.asarray(r), 0.0, atol=1e-9)
    # at a non-zero W, against the residuals written again in numpy (fit on the first 20 shots only)
    W = 0.01 * np.random.default_rng(3).normal(size=(H.shape[1], 3))
    fit_w = (np.arange(len(b)) < 20).astype(float)
    np.testing.assert_allclose(np.asarray(mag_relm.residuals(W, H, G, b, member, fit_w)),
                               _relm_residuals_numpy(W, G, b, groups, fit_w > 0), atol=1e-10)


def _axis_distorted(seed=1):
    """Exact shots with a per-axis non-linear response (Underwood's model), ~0.5 deg, unit-sphere field."""
    G, B, groups = _rolled_recording(seed=seed, n_single=16)
    b = B  # unit sphere already
    return G, b + 0.01 * np.sin(4.0 * b), groups


def test_relm_fit_matches_scipy_and_leave_one_group_out_equals_refitting_without_the_group():
    # the vmapped fixed-step LM against scipy's least_squares on residuals written again in numpy; each fold's
    # masked fit against a fit on the shots with that group removed
    from scipy.optimize import least_squares

    from icgo.models import mag_relm

    G, b, groups = _axis_distorted()
    lam = 100.0
    model = mag_relm.fit(G, b, groups, lambdas=(lam,))
    L = model.hidden.shape[1]

    def res(x):
        return np.concatenate([_relm_residuals_numpy(x.reshape(L, 3), G, b, groups, slice(None)).ravel(),
                               np.sqrt(lam) * x])

    ref = least_squares(res, np.zeros(3 * L), method="lm", xtol=1e-14, ftol=1e-14).x.reshape(L, 3)
    np.testing.assert_allclose(model.out, ref, atol=1e-7)
    held = 0.0
    for g in np.unique(groups):
        keep = groups != g
        W = mag_relm.fit(G[keep], b[keep], groups[keep], lambdas=(lam,)).out
        held += np.sum(_relm_residuals_numpy(W, G, b, groups, keep)[~keep] ** 2)
    np.testing.assert_allclose(model.cv[0], held / len(b), rtol=1e-6)


def test_relm_learns_a_per_axis_non_linearity_and_chooses_its_ridge_by_groups():
    from icgo.models import mag_relm
    from icgo.physics.qc import measured_dip_deg

    G, b, groups = _axis_distorted()
    model = mag_relm.fit(G, b, groups)
    assert model.lam in mag_relm.LAMBDAS and model.lam == mag_relm.LAMBDAS[int(np.argmin(model.cv))]
    fixed = mag_relm.apply(model.hidden, model.out, b)
    before, after = cal_pointing.group_spread_deg(G, b, groups)[0], cal_pointing.group_spread_deg(G, fixed, groups)[0]
    assert after < 0.5 * before
    assert np.ptp(measured_dip_deg(G, fixed)) < 0.5 * np.ptp(measured_dip_deg(G, b))
    # held out: a roll it never saw, and fresh singles
    G2, b2, g2 = _axis_distorted(seed=7)
    fixed2 = mag_relm.apply(model.hidden, model.out, b2)
    assert cal_pointing.group_spread_deg(G2, fixed2, g2)[0] < 0.7 * cal_pointing.group_spread_deg(G2, b2, g2)[0]


def test_relm_on_exact_shots_stays_the_identity():
    from icgo.models import mag_relm

    G, B, groups = _rolled_recording()
    b = B  # unit sphere already
    model = mag_relm.fit(G, b, groups)
    np.testing.assert_allclose(mag_relm.apply(model.hidden, model.out, b), b, atol=1e-9)


def test_an_older_builds_relm_file_and_a_bad_activation_are_refused(tmp_path):
    """A correction without nl_activation (model schema 1 as an older build wrote it, tanh units) is refused in
    one line, from the constructor and from a file; so are an unknown activation and one without a correction."""
    from icgo.core.errors import ModelError
    from icgo.models import mag_relm
    from icgo.artifacts.calibration import MagCalibration
    from icgo.models.calibration_params import CalibrationParams

    h, o = np.random.default_rng(0).normal(size=(4, 5)), np.zeros((5, 3))
    kw = dict(config={}, data_hash="-", domain={}, method="twelve_relm", axis_aligned=False, field_scale_nT=1.0)
    x = np.r_[np.eye(3).ravel(), 0, 0, 0]
    nl = lambda act: CalibrationParams(x, nl_hidden=h, nl_out=o, nl_activation=act)
    line = ("a non-linear correction without nl_activation (model schema 1 as an older icgo build wrote it); "
            "refit the model")
    with pytest.raises(ModelError, match=re.escape(line)):
        MagCalibration(**kw, params=nl(None))
    path = MagCalibration(**kw, params=nl("gauss"), nl_activation="gauss").save(tmp_path / "m")
    head = json.loads(path.read_text())
    del head["fields"]["nl_activation"]
    path.write_text(json.dumps(head))
    with pytest.raises(ModelError, match=re.escape(line)) as e:
        load_model(path)
    assert "\n" not in str(e.value)
    with pytest.raises(ModelError, match="nl_activation"):
        MagCalibration(**kw, params=nl("relu"), nl_activation="relu")
    with pytest.raises(ModelError, match="nl_activation"):
        MagCalibration(**kw, params=CalibrationParams(x), nl_activation="gauss")
    with pytest.raises(ModelError, match="nl_activation"):  # the meta and the params' static setting disagree
        MagCalibration(**kw, params=nl(None), nl_activation="gauss")
    assert mag_relm.ACTIVATIONS == ("gauss",)


def test_a_relm_calibration_saves_and_applies_bitwise(tmp_path):
    rec = mag_cal_bundled.load_mag_cal_device("ai")
    cfg = cal_study.CalibrationConfig(peer=False, misma_iter=2, misma_repeats=1, misma_pop=6)
    fitted = cal_study.fit_recording(rec.G, rec.B, rec.frame.group.to_numpy(), cfg, jax.random.PRNGKey(0), {})
    model = fitted["twelve+axis+relm"]
    assert model.method == "twelve_relm" and model.params.nl_out.shape == (model.params.nl_hidden.shape[1], 3)
    assert model.nl_activation == "gauss" and model.config["relm_lambda_deg2"] in cal_study.mag_relm.LAMBDAS
    back = load_model(model.save(tmp_path / "ai_relm"))
    pd.testing.assert_frame_equal(back.apply(rec.frame), model.apply(rec.frame), check_exact=True)
    # without the residual part it is the linear calibration
    lin = fitted["twelve+axis"]
    assert isinstance(lin, type(model)) and lin.params.nl_hidden is None
    assert not np.allclose(model.apply(rec.frame).bx_corrected, lin.apply(rec.frame).bx_corrected)


def test_misma_bounds_option_reaches_the_search_and_is_recorded():
    rec = mag_cal_bundled.load_mag_cal_device("ai")
    cfg = cal_study.CalibrationConfig(peer=False, misma_iter=2, misma_repeats=1, misma_pop=6, misma_bounds="paper")
    fitted = cal_study.fit_recording(rec.G, rec.B, rec.frame.group.to_numpy(), cfg, jax.random.PRNGKey(0), {})
    header = fitted["misma+axis"].config
    assert header["misma_box"].startswith("icgo.optim.misma.paper_bounds")
    assert header["misma_box_lb"][9:] == [-68_000.0] * 3 and header["misma_box_ub"][:9] == [128.0] * 9
    with pytest.raises(SettingError, match="misma_bounds must be one of around_lsq, paper"):
        cal_study.CalibrationConfig(misma_bounds="wide")


def _fits_table(rows):
    """A calibration table (the columns evaluate writes) from (split, method, score, degenerate[, outer, site flag])
    rows."""
    out = []
    for r in rows:
        sp, m, sc, d = r[:4]
        outer = r[4] if len(r) > 4 else ""
        flag = r[5] if len(r) > 5 else False
        out.append({"recording": "r", "split": sp, "outer": outer, "method": m, "score_deg": np.nan if d else sc,
                    "degenerate": d, "site_flag": flag, "site_reason": "mean dip off" if flag else ""})
    return pd.DataFrame(out)


def test_the_rule_keeps_twelve_axis_unless_a_sound_method_beats_it_by_more_than_the_standard_error():
    from icgo.studies.calibration.select import recommend

    rows = [("in-sample", "twelve+axis", 0.5, False), ("held-out group 8", "twelve+axis", 0.50, False),
            ("held-out group 9", "twelve+axis", 0.70, False),
            ("in-sample", "twelve+axis+relm", 0.2, False), ("held-out group 8", "twelve+axis+relm", 0.30, False),
            ("held-out group 9", "twelve+axis+relm", 0.52, False),
            ("in-sample", "joint", 0.1, False), ("held-out group 8", "joint", 0.1, True),
            ("held-out group 9", "joint", 0.1, False)]
    r = recommend(_fits_table(rows), "r")
    # paired differences twelve+axis - relm: 0.20, 0.18 -> mean 0.19 > its standard error 0.01; joint (lowest where
    # it is sound) has a degenerate fit: never recommended
    assert r["method"] == "twelve+axis+relm" and r["model"] == "models/r_twelve_axis_relm.json"
    assert r["held_out_deg"] == pytest.approx(0.41) and r["runner_up"] == "twelve+axis"
    assert r["spread_deg"] == pytest.approx(np.std([0.3, 0.52], ddof=1) / np.sqrt(2))
    assert r["clear_winner"] and "beats twelve+axis by 0.190 deg" in r["criterion"]
    # a lower mean that varies more than it gains (differences 0.30, -0.10: mean 0.10 < standard error 0.20)
    noisy = [(sp, m, {"held-out group 8": 0.20, "held-out group 9": 0.80}.get(sp, sc) if m == "twelve+axis+relm"
              else sc, d) for sp, m, sc, d in rows]
    r = recommend(_fits_table(noisy), "r")
    assert r["method"] == "twelve+axis" and "no other sound method beats it" in r["criterion"]
    # no held-out split: the baseline, whatever the in-sample scores say; no accuracy estimate
    r = recommend(_fits_table([x for x in rows if x[0] == "in-sample"]), "r")
    assert r["method"] == "twelve+axis" and r["spread_deg"] is None and r["accuracy_deg"] is None
    assert "no held-out split" in r["criterion"] and "accuracy not estimated" in r["sentence"]
    # a fit inconsistent with the site is never recommended; with none sound, nothing is, and the reason says why
    r = recommend(_fits_table([x + ("", x[1] == "twelve+axis+relm") for x in rows]), "r")
    assert r["method"] == "twelve+axis"
    r = recommend(_fits_table([("in-sample", "joint", 0.1, True), ("in-sample", "twelve+axis", 0.4, False, "", True)]),
                  "r")
    assert r["model"] is None and r["method"] is None and r["sentence"].startswith("No calibration recommended")
    assert "twelve+axis: inconsistent with the site" in r["refused"] and "joint: a degenerate fit" in r["refused"]


def test_the_accuracy_printed_is_nested_the_choice_made_inside_each_held_out_split():
    from icgo.studies.calibration.select import recommend

    outer = [("in-sample", "twelve+axis", 0.5, False), ("in-sample", "twelve+axis+relm", 0.2, False),
             ("held-out group 8", "twelve+axis", 0.50, False), ("held-out group 8", "twelve+axis+relm", 0.30, False),
             ("held-out group 9", "twelve+axis", 0.70, False), ("held-out group 9", "twelve+axis+relm", 0.52, False)]
    # inside group 8's split the RELM wins clearly; inside group 9's it does not: the baseline is chosen there
    inner = [("g8 / a", "twelve+axis", 0.6, False, "held-out group 8"), ("g8 / a", "twelve+axis+relm", 0.3, False,
                                                                           "held-out group 8"),
             ("g8 / b", "twelve+axis", 0.7, False, "held-out group 8"), ("g8 / b", "twelve+axis+relm", 0.41, False,
                                                                           "held-out group 8"),
             ("g9 / a", "twelve+axis", 0.6, False, "held-out group 9"), ("g9 / a", "twelve+axis+relm", 0.3, False,
                                                                           "held-out group 9"),
             ("g9 / b", "twelve+axis", 0.7, False, "held-out group 9"), ("g9 / b", "twelve+axis+relm", 0.9, False,
                                                                           "held-out group 9")]
    r = recommend(_fits_table(outer + inner), "r")
    assert r["method"] == "twelve+axis+relm" and r["held_out_deg"] == pytest.approx(0.41)
    assert [x["chosen"] for x in r["accuracy_splits"]] == ["twelve+axis+relm", "twelve+axis"]
    # the nested estimate scores each split's own choice on that split: (0.30 + 0.70) / 2, not the chosen 0.41
    assert r["accuracy_deg"] == pytest.approx(0.5) and r["accuracy_spread_deg"] == pytest.approx(0.2)
    # the sentence: the applied method's own held-out score first (what its model carries), the rule's beside it
    assert "expected accuracy 0.410 +/- 0.110 deg (its held-out score" in r["sentence"]
    assert "the rule's nested score 0.500 +/- 0.200 deg (nested" in r["sentence"]


def test_the_bundled_table_states_its_protocol():
    """results/calibration_devices.md's protocol line, from a small fits table (no fit run): the counts come from
    the table, the command from the config (its non-default settings spelled out)."""
    from icgo.studies.calibration.report import protocol, report, settings
    from icgo.studies.calibration.job import SEED
    from icgo.core.settings import config_overrides
    from icgo.reporting.protocol import PROTOCOL_FIELDS, parse_protocols

    splits = {"a": ["in-sample", "held-out group 8", "held-out group 9"],
              "b": ["in-sample", "held-out group 8", "held-out group 9", "held-out group 10"]}
    df = pd.DataFrame([{"recording": r, "split": sp, "method": m, "score_deg": 0.1 * (i + 1), "degenerate": False,
                        "dip_spread_deg": 0.5, "b_spread_pct": 0.1, "cond": 1.01, "reasons": ""}
                       for r, sps in splits.items() for sp in sps for i, m in enumerate(cal_study.METHODS)])
    md = report(df, cal_study.summary(df), {}, "two recordings", {}, {}, {},
                protocol(df, cal_study.CalibrationConfig(), SEED),
                settings(cal_study.CalibrationConfig(misma_pop=12)))
    (line,) = parse_protocols(md)
    assert md.splitlines()[2].startswith("Protocol: ") and set(line) == set(PROTOCOL_FIELDS)
    assert md.splitlines()[3].startswith("Run settings: ") and "misma+axis: population 12 x 300 iterations" in md
    assert line["command"] == "`make calibration` (`python -m experiments.calibrate data=bundled`)"
    assert "4 MISMA runs (population 30, 300 iterations)" in line["repeats"]
    assert "its recording's 2-3 held-out split(s)" in line["repeats"]
    assert "all 2 recordings (2 in-sample and 5 held-out fits per method)" in line["repeats"]
    assert "each rolled group left out of the fit in turn" in line["split"]
    assert f"PRNGKey({SEED})" in line["seeds"] and "the 2 bundled recordings" in line["seeds"]
    assert line["test"].startswith("none: no p-value here")
    # a run with other settings names them, so the line's command regenerates its table
    fast = cal_study.CalibrationConfig(peer=False, misma_iter=3, misma_repeats=2)
    assert config_overrides(fast) == ["peer=false", "misma_iter=3", "misma_repeats=2"]
    assert config_overrides(cal_study.CalibrationConfig()) == []
    (line,) = parse_protocols(protocol(df[df.recording == "a"], fast, SEED))
    assert line["command"] == "`python -m experiments.calibrate data=bundled peer=false misma_iter=3 misma_repeats=2`"
    assert "2 MISMA runs (population 30, 3 iterations)" in line["repeats"] and "2 held-out split(s)" in line["repeats"]
    # a run on a user's file has no protocol line (its command is not known here)
    assert not parse_protocols(report(df, cal_study.summary(df), {}, "x.csv", {}, {}, {}))


def test_splits_of_one_roll_hold_out_its_interleaved_halves():
    groups = np.r_[np.arange(8), [8] * 8]
    labels = [s[0] for s in cal_study.splits(groups)]
    assert labels == ["in-sample", "held-out half of group 8 (odd shots)", "held-out half of group 8 (even shots)"]
    _, train, score = cal_study.splits(groups)[1]
    assert score.tolist() == [False] * 8 + [False, True] * 4 and (train == ~score).all()
    assert [s[0] for s in cal_study.splits(np.r_[np.arange(8), [8] * 6])] == ["in-sample"]


def test_apply_takes_the_model_a_calibrate_run_recommends(tmp_path):
    from icgo.survey.apply_run import model_path
    from icgo.core.errors import RecordError

    run = tmp_path / "run"
    (run / "models").mkdir(parents=True)
    rec = {"model": "models/x_joint.json", "method": "joint", "criterion": "c", "held_out_deg": 0.4,
           "spread_deg": 0.1, "clear_winner": True, "runner_up": "twelve+axis"}
    (run / "calibration.json").write_text(json.dumps({"recommendation": rec, "recommendations": {"x": rec}}))
    assert model_path(run) == run / "models" / "x_joint.json"
    (run / "calibration.json").write_text(json.dumps({"recommendations": {"a": {"model": "models/a.json"},
                                                                          "b": {"model": "models/b.json"}}}))
    with pytest.raises(RecordError, match="one per recording: models/a.json, models/b.json"):
        model_path(run)
    (run / "calibration.json").write_text(json.dumps({"recommendation": {**rec, "model": "../../etc/x.json"}}))
    with pytest.raises(RecordError, match="inside the run directory"):
        model_path(run)


@pytest.mark.slow
def test_front_door_on_a_16_shot_json_recommends_and_apply_uses_it(tmp_path):
    from mag_cal_files import device_attitudes, synth, write_fixture

    A, I, T = device_attitudes("hj2")
    G, B = synth("hj2", A[:16], I[:16], T[:16], noise_g=3e-4 * 3, noise_b_nT=15 * 10, seed=4)
    path = tmp_path / "hj2_16.json"
    write_fixture(path, G, B)
    out = _run_entry(tmp_path, f"data={path}", *FAST)
    assert out.returncode == 0, out.stderr
    run = tmp_path / "run"
    record = json.loads((run / "calibration.json").read_text())
    r = record["recommendation"]
    assert set(r) >= {"model", "method", "criterion", "held_out_deg", "spread_deg", "clear_winner", "runner_up",
                      "accuracy_deg", "accuracy_spread_deg", "accuracy_splits", "refused"}
    assert (run / r["model"]).is_file() and r["method"] in cal_study.METHODS and isinstance(r["clear_winner"], bool)
    assert [x["shots"] for x in record["recordings"]["hj2_16"]["rolls"]] == ["8-15"]
    text = (run / "report.md").read_text()
    assert "## Recommendation" in text and f"Apply `{r['method']}`" in text and "held-out half of group 8" in text
    fits = pd.read_csv(run / "calibration.csv")
    assert set(fits[fits.outer.isna()].split) == {"in-sample", "held-out half of group 8 (odd shots)",
                                                  "held-out half of group 8 (even shots)"}
    survey = tmp_path / "survey.csv"
    hj2 = mag_cal_bundled.load_mag_cal_device("hj2")
    io.write_recording(survey, hj2.frame.drop(columns="group"), {}, require_reference=False)
    applied = subprocess.run([sys.executable, "-m", "experiments.apply", f"model={run}", f"data={survey}",
                              f"out={tmp_path / 'applied'}"], cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert applied.returncode == 0, applied.stderr
    meta = json.loads((tmp_path / "applied" / "survey_corrected.meta.json").read_text())
    assert meta["model"] == str(run / r["model"])


@pytest.mark.slow
def test_front_door_names_a_missing_mounting(tmp_path):
    from mag_cal_files import device_attitudes, synth, write_raw

    G, B = synth("ai", *device_attitudes("ai"))
    path = tmp_path / "raw.json"
    write_raw(path, G, B, "-y+x+z", "+z-x-y", keys=False)
    out = _run_entry(tmp_path, f"data={path}", *FAST)
    err = out.stderr.strip()
    assert out.returncode == 4 and len(err.splitlines()) == 1 and "probable cause: the mounting is not given" in err
    # the shots were read: the run directory says why nothing is recommended
    assert "probable cause: the mounting is not given" in (tmp_path / "run" / "report.md").read_text()
    assert json.loads((tmp_path / "run" / "calibration.json").read_text())["recommendation"] is None
    import shutil

    shutil.rmtree(tmp_path / "run")
    out = _run_entry(tmp_path, f"data={path}", "mag_axes=-y+x+z", "grav_axes=+z-x-y", *FAST)
    assert out.returncode == 0, out.stderr
