"""Calibration of grouped shots (icgo.studies.calibration, icgo.cal_sanity) and its front door experiments.calibrate."""

from __future__ import annotations

import json
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
from experiments._common import CONF_DIR
from icgo import calibration as cal
from icgo import io
from icgo.cal_sanity import LIMITS, sanity
from icgo.frames import sensors_from_attitude
from icgo.models import load_model
from icgo.studies import SettingError, config_to_mapping
from icgo.studies import calibration as C

ROOT = CONF_DIR.parent
FAST = ["peer=false", "misma_iter=3", "misma_repeats=2", "misma_pop=6"]


def _compose(*overrides):
    with initialize_config_dir(config_dir=str(CONF_DIR), version_base="1.3"):
        return compose("calibrate", list(overrides))


def test_conf_yaml_equals_the_dataclass_defaults():
    composed = {k: v for k, v in OmegaConf.to_container(_compose(), resolve=True).items() if k not in entry.ENTRY_KEYS}
    assert composed == config_to_mapping(C.CalibrationConfig())


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
    rec = io.load_mag_cal_device("fb")
    G, B = rec.G, rec.B
    xg = cal.ellipsoid_fit_accel(G)
    xm = cal.ellipsoid_fit(B, 1.0, G)
    Gc = np.asarray(cal.correct(xg, G))
    x12 = cal.fit_twelve(Gc, B, 1.0, x0=xm)
    lb, ub = C.misma_box(xm, x12, float(np.median(np.linalg.norm(B, axis=1))))
    assert np.all((lb < x12) & (x12 < ub))
    # the bias half-width is 2 % of the field in nT (hundreds of nT), not 2 % of 1.0
    assert np.all(ub[9:] - xm[9:] >= 0.02 * np.median(np.linalg.norm(B, axis=1)) - 1e-9)
    assert np.all(ub[9:] - xm[9:] > 100.0)


def test_splits_hold_out_each_rolled_group():
    groups = io.load_mag_cal_device("ab").frame.group.to_numpy()
    labels = [s[0] for s in C.splits(groups)]
    assert labels == ["in-sample", "held-out group 8", "held-out group 9"]
    with pytest.raises(ValueError, match="no rolled group"):
        C.splits(np.arange(10))


def _run_entry(tmp_path, *args):
    cmd = [sys.executable, "-m", "experiments.calibrate", f"hydra.run.dir={tmp_path / 'run'}", *args]
    return subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=600)


@pytest.mark.slow
def test_front_door_on_an_exported_device_and_apply_on_another(tmp_path):
    rec = io.load_mag_cal_device("bh")
    csv = tmp_path / "bh.csv"
    io.write_recording(csv, rec.frame, rec.meta)
    out = _run_entry(tmp_path, f"data={csv}", *FAST)
    assert out.returncode == 0, out.stderr
    run = tmp_path / "run"
    for name in ("report.md", "calibration.csv", "bh.png", "models/bh_twelve_axis.json", "models/bh_joint.json"):
        assert (run / name).is_file(), name
    fits = pd.read_csv(run / "calibration.csv")
    assert set(fits.method) == set(C.METHODS) and set(fits.split) == {"in-sample", "held-out group 8",
                                                                      "held-out group 9"}
    assert fits.loc[fits.degenerate, "score_deg"].isna().all()
    # the saved calibration applies to a second recording of the same family
    model = load_model(run / "models" / "bh_twelve_axis.json")
    other = io.load_mag_cal_device("jd").frame
    applied = model.apply(other)
    assert np.isfinite(applied[["bx_corrected", "by_corrected", "bz_corrected"]].to_numpy()).all()


@pytest.mark.slow
def test_front_door_on_a_raw_layout_json(tmp_path):
    rec = io.load_mag_cal_device("ee")
    inv = np.argsort(io.MAG_CAL_DEVICE_TO_TOOL)
    doc = {"mag": (rec.B[:, inv] / 1000.0).tolist(), "grav": (rec.G[:, inv] * io.STANDARD_GRAVITY).tolist()}
    path = tmp_path / "ee_raw.json"
    path.write_text(json.dumps(doc))
    out = _run_entry(tmp_path, f"data={path}", "mag_axes=+x+y+z", *FAST)
    assert out.returncode == 0, out.stderr
    assert "m/s^2 / 9.80665 -> g" in (tmp_path / "run" / "report.md").read_text()


@pytest.mark.parametrize("args,code,match", [
    ([], 2, "data= is required"),
    (["data=bundled", "mag_axes=+x+y+z"], 2, "mag_axes / grav_axes apply"),
    ([f"data={io._mag_cal_dir().joinpath('ab.json')}", "mag_axes=+x+y+z"], 2, "device frame already"),
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


def test_rolls_alone_are_refused_with_a_hint(tmp_path):
    rec = io.load_mag_cal_device("ee")
    csv = tmp_path / "rolls.csv"
    io.write_recording(csv, rec.frame.iloc[8:].reset_index(drop=True), {})
    out = _run_entry(tmp_path, f"data={csv}", *FAST)
    err = out.stderr.strip()
    assert out.returncode == 1 and len(err.splitlines()) == 1, err
    assert "rolls, in-sample: ellipsoid fit" in err and "many orientations" in err


def test_csv_without_groups_is_one_line(tmp_path):
    rec = io.load_mag_cal_device("ab")
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


def test_relm_targets_are_the_field_itself_for_exact_shots():
    from icgo import mag_relm

    G, B, groups = _rolled_recording()
    np.testing.assert_allclose(mag_relm.targets(G, B, groups), B, atol=1e-9)


def test_relm_learns_a_smooth_distortion_and_chooses_its_ridge_by_groups():
    # what group consistency and one field can see of a smooth distortion: the dip, |B| and the rolls' spread
    from icgo import mag_relm
    from icgo.qc import measured_dip_deg

    G, B, groups = _rolled_recording(n_single=40)
    distorted = B + 0.02 * np.sin(3.0 * B[:, [1, 2, 0]])  # a smooth non-linear error, ~1 deg
    model = mag_relm.fit(G, distorted, groups)
    assert model.lam in mag_relm.LAMBDAS
    fixed = mag_relm.apply(model.hidden, model.out, distorted)
    # measured: dip std 0.676 -> 0.592 deg, rolls' spread 1.475 -> 1.290 deg (leave-one-group-out picks a strong
    # ridge: most of this distortion is invisible to one-field and group consistency on single shots)
    assert np.std(measured_dip_deg(G, fixed)) < 0.9 * np.std(measured_dip_deg(G, distorted))
    assert cal.group_spread_deg(G, fixed, groups)[0] < 0.9 * cal.group_spread_deg(G, distorted, groups)[0]
    assert np.std(np.linalg.norm(fixed, axis=1)) <= np.std(np.linalg.norm(distorted, axis=1))


def test_a_relm_calibration_saves_and_applies_bitwise(tmp_path):
    rec = io.load_mag_cal_device("ai")
    fitted = C.fit_recording(rec.G, rec.B, rec.frame.group.to_numpy(), C.CalibrationConfig(peer=False, misma_iter=2,
                             misma_repeats=1, misma_pop=6), jax.random.PRNGKey(0), {})
    model = fitted["twelve+axis+relm"]
    assert model.method == "twelve_relm" and model.nl_out.shape == (model.nl_hidden.shape[1], 3)
    back = load_model(model.save(tmp_path / "ai_relm"))
    pd.testing.assert_frame_equal(back.apply(rec.frame), model.apply(rec.frame), check_exact=True)
    # without the residual part it is the linear calibration
    lin = fitted["twelve+axis"]
    assert isinstance(lin, type(model)) and lin.nl_hidden is None
    assert not np.allclose(model.apply(rec.frame).bx_corrected, lin.apply(rec.frame).bx_corrected)


def test_misma_bounds_option_reaches_the_search_and_is_recorded():
    rec = io.load_mag_cal_device("ai")
    cfg = C.CalibrationConfig(peer=False, misma_iter=2, misma_repeats=1, misma_pop=6, misma_bounds="paper")
    fitted = C.fit_recording(rec.G, rec.B, rec.frame.group.to_numpy(), cfg, jax.random.PRNGKey(0), {})
    header = fitted["misma+axis"].config
    assert header["misma_box"].startswith("icgo.optim.misma.paper_bounds")
    assert header["misma_box_lb"][9:] == [-68_000.0] * 3 and header["misma_box_ub"][:9] == [128.0] * 9
    with pytest.raises(SettingError, match="misma_bounds must be one of around_lsq, paper"):
        C.CalibrationConfig(misma_bounds="wide")
