"""The chain a field engineer runs (issue 48): a bundled device exported as a field-style CSV, calibrated by
``experiments.calibrate`` with a column map and the site, the recommended calibration applied by
``experiments.apply`` to the device's own shots: QC in earth units against the site, one accuracy carried by the
model from calibrate to apply."""

from __future__ import annotations

import dataclasses
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from icgo.artifacts.registry import load_model
from icgo.io import mag_cal_bundled
from icgo.physics.qc import QCBands, measured_dip_deg

ROOT = Path(__file__).resolve().parent.parent
FAST = ["peer=false", "misma_iter=3", "misma_repeats=2", "misma_pop=6"]
#: The export's names of the contract columns (a field export's header, with units and a roll number).
EXPORT = {"station": "Shot", "gx": "Gx (g)", "gy": "Gy (g)", "gz": "Gz (g)", "bx": "Bx (nT)", "by": "By (nT)",
          "bz": "Bz (nT)", "group": "Roll #"}
COLUMNS = [f"columns.{k}='{v}'" for k, v in EXPORT.items()]
#: The site of the test: the dip every sound fit of the bundled devices sees (66.5-66.7 deg; docs/calibrate.md, "The
#: site": results/calibration_devices.csv, column dip_deg) and a mid-latitude |B| (the devices' own is unknown: their
#: sensors' gains differ, so any |B| in the earth's range is as right as another; the calibration is scaled to it).
SITE = ["site.dip=66.7", "site.field=49330"]


def _door(*args, cwd=ROOT):
    return subprocess.run([sys.executable, "-m", *args], cwd=cwd, capture_output=True, text=True, timeout=600)


def run_chain(tmp: Path, device: str):
    """A bundled device exported as a field CSV, calibrated with the column map and :data:`SITE`, the recommended
    calibration applied to the same shots: (tmp, recording, export, calibrate's and apply's processes, the
    calibration record, the model, apply's corrected table and its metadata)."""
    rec = mag_cal_bundled.load_mag_cal_device(device)
    export = tmp / f"{device}_export.csv"
    rec.frame.rename(columns=EXPORT).to_csv(export, index=False)  # no .meta.json: a field export
    cal = _door("experiments.calibrate", f"data={export}", *COLUMNS, *SITE, *FAST, f"hydra.run.dir={tmp / 'cal'}")
    assert cal.returncode == 0, cal.stderr
    app = _door("experiments.apply", f"model={tmp / 'cal'}", f"data={export}", *COLUMNS, *SITE, f"out={tmp / 'app'}")
    assert app.returncode == 0, app.stderr
    record = json.loads((tmp / "cal" / "calibration.json").read_text())
    model = load_model(tmp / "cal" / record["recommendation"]["model"])
    table = pd.read_csv(tmp / "app" / f"{device}_export_corrected.csv")
    meta = json.loads((tmp / "app" / f"{device}_export_corrected.meta.json").read_text())
    return tmp, rec, export, cal, app, record, model, table, meta


@pytest.fixture(scope="module")
def chain(tmp_path_factory):
    return run_chain(tmp_path_factory.mktemp("field"), "ab")


def sound_shots(model, G, B, bands=QCBands()) -> np.ndarray:
    """The shots the in-sample fit explains: its corrected |G| within the |G| band of 1 g, its corrected dip and |B|
    within the bands of their own means over the shots (the fit's consistency, the site left out)."""
    Gc, Bc = model.corrected(G, B)
    bn, dip = np.linalg.norm(Bc, axis=1), measured_dip_deg(Gc, Bc)
    return ((np.abs(np.linalg.norm(Gc, axis=1) - 1.0) <= bands.g_tol_g)
            & (np.abs(bn / bn.mean() - 1.0) <= bands.b_tol_nT / 49330.0)
            & (np.abs(dip - dip.mean()) <= bands.dip_tol_deg))


def test_a_calibration_applied_to_its_own_shots_passes_qc_in_earth_units(chain):
    tmp, rec, _, _, app, record, model, table, meta = chain
    # the model is in earth units: scaled to the site given to calibrate, which it records
    assert model.field_reference == {"total_field_nT": 49330.0, "dip_deg": 66.7,
                                     "origin": "given (site.dip, site.field)"}
    assert table["b_total_nT"].mean() == pytest.approx(49330.0, rel=1e-9)  # in-sample: the mean is the site's
    # QC judges the corrected |G|, |B| and dip (the bug: corrected |G| was the raw |G|, the dip from raw G)
    Gc = table[["gx_corrected", "gy_corrected", "gz_corrected"]].to_numpy(float)
    Bc = table[["bx_corrected", "by_corrected", "bz_corrected"]].to_numpy(float)
    np.testing.assert_allclose(table["corrected_g_total_g"], np.linalg.norm(Gc, axis=1), rtol=1e-12)
    np.testing.assert_allclose(table["corrected_dip_deg"], table["dip_compensated_deg"], atol=1e-9)
    np.testing.assert_allclose(table["corrected_dip_deg"], measured_dip_deg(Gc, Bc), atol=1e-9)
    assert not np.allclose(table["corrected_g_total_g"], table["raw_g_total_g"])
    # the reference used is named: the site given to apply
    assert meta["reference"]["origin"].startswith("the site given to apply")
    assert "QC reference: |B| 49330 nT, dip 66.70 deg" in app.stdout
    assert "from the site given to apply" in meta["verdict"]["qc"]
    # the goal: QC passes on >= 90 % of the shots the in-sample fit scores as sound
    sound = sound_shots(model, rec.G, rec.B)
    passed = table["corrected_qc_pass"].to_numpy(bool)
    assert sound.sum() >= 12 and passed[sound].mean() >= 0.9, (sound.sum(), passed[sound].mean())
    assert meta["qc"]["raw"]["any"] == len(table)  # raw: the sensor's scale and hard iron fail every shot


#: The other bundled devices on which the goal holds with the test's one shared site, measured 2026-12-07 (a
#: regression check, not a claim over devices): on bi, fb, hj and jd QC passes 86-89 % of the sound shots, on bh 33 %
#: (its calibrated mean dip is 66.38 deg, 0.32 from the shared site). The bundle records no site; the table and the
#: command: docs/calibrate.md, "Calibrate -> apply on every bundled device".
HOLDS = ("ai", "ee", "hj2")


@pytest.mark.slow
@pytest.mark.parametrize("device", HOLDS)
def test_the_goal_holds_on_the_devices_it_held_on(device, tmp_path):
    _, rec, _, _, _, _, model, table, _ = run_chain(tmp_path, device)
    sound = sound_shots(model, rec.G, rec.B)
    passed = table["corrected_qc_pass"].to_numpy(bool)
    assert sound.sum() >= 12 and passed[sound].mean() >= 0.9, (device, int(sound.sum()), passed[sound].mean())


@pytest.mark.slow
def test_a_wrong_site_fails_qc_and_the_model_site_serves_without_one(chain, tmp_path):
    """Controls: a site 2 deg off in dip fails the dip band on every shot; without site.* and without metadata
    the site the calibration was fitted at is the reference, and apply says so."""
    tmp, _, export, *_ = chain
    wrong = _door("experiments.apply", f"model={tmp / 'cal'}", f"data={export}", *COLUMNS, "site.dip=64.7",
                  "site.field=49330", f"out={tmp_path / 'wrong'}")
    assert wrong.returncode == 0, wrong.stderr
    m = json.loads((tmp_path / "wrong" / "ab_export_corrected.meta.json").read_text())
    assert m["qc"]["corrected"]["dip"] == m["qc"]["corrected"]["n"]
    own = _door("experiments.apply", f"model={tmp / 'cal'}", f"data={export}", *COLUMNS, f"out={tmp_path / 'own'}")
    assert own.returncode == 0, own.stderr
    m = json.loads((tmp_path / "own" / "ab_export_corrected.meta.json").read_text())
    assert m["reference"]["origin"].startswith("the site the calibration was fitted at")
    assert m["reference"]["total_field_nT"] == 49330.0 and m["qc"]["corrected"]["b"] == 0


def test_a_relative_calibration_is_named_and_scaled_to_the_reference(chain, tmp_path):
    """A calibration fitted without a site (an older file, or no site.*): relative; apply scales its field to the
    reference over the survey and says that the level is then not checked."""
    from icgo.io.recording import write_recording
    from icgo.survey.apply_settings import run_apply

    tmp, rec, *_, model, _, _ = chain
    relative = dataclasses.replace(model, field_reference=None,
                                   field_scale_nT=float(np.median(np.linalg.norm(rec.B, axis=1))))
    assert relative.relative and not model.relative
    assert not dataclasses.replace(relative, field_scale_nT=1.0).relative  # a fit in nT (MISMA's): earth units
    path = relative.save(tmp_path / "relative")
    survey = tmp_path / "ab.csv"
    write_recording(survey, rec.frame, {"total_field_nT": 49330.0, "dip_deg": 66.7, "declination_deg": 0.0},
                    require_reference=False)
    settings = {"model": str(path), "data": str(survey), "method": None, "require_meta": False, "out": None,
                "qc": {"g_tol_g": 0.0025, "b_tol_nT": 300.0, "dip_tol_deg": 0.25}, "columns": None,
                "columns_file": None, "overwrite": False, "max_mb": 64, "stream_mb": 64, "chunk_rows": 1000,
                "site": None}
    meta = run_apply(settings, tmp_path / "out")
    assert any("the calibration is relative" in n for n in meta["notices"])
    assert meta["reference"]["origin"].startswith("the survey's metadata")
    t = pd.read_csv(tmp_path / "out" / "ab_corrected.csv")
    assert t["b_total_nT"].median() == pytest.approx(49330.0, rel=1e-9)
    assert meta["qc"]["corrected"]["b"] <= 2


def test_one_accuracy_from_calibrate_to_apply(chain):
    """The accuracy calibrate states for the recommended calibration is the one its model carries and apply prints:
    the applied method's held-out score, the rule's nested score beside it and named as such."""
    _, _, _, cal, app, record, model, _, meta = chain
    r = record["recommendation"]
    acc = model.accuracy
    assert acc["deg"] == pytest.approx(r["held_out_deg"], rel=1e-12)
    assert acc["nested_deg"] == pytest.approx(r["accuracy_deg"], rel=1e-12)
    assert "nested score" in acc["nested_what"] and r["method"] in acc["what"]
    cal_line = next(line for line in cal.stdout.splitlines() if line.startswith("  expected accuracy:"))
    app_line = meta["verdict"]["accuracy"]
    from icgo.survey.verdict import accuracy_line

    assert accuracy_line(acc) in cal_line and app_line.startswith(accuracy_line(acc))
    assert f"pointing spread {acc['deg']:.3f}" in app.stdout and "no interval" not in app.stdout


def test_the_rule_declares_no_winner_on_a_zero_margin_or_one_split():
    """A RELM the regularisation shrinks to nothing scores within 1e-6 deg of the baseline, with a smaller standard
    error still (the 24-shot case of issue 48): no win, no clear winner. One held-out split: no standard error, no
    win either; the model carries the method's own score."""
    from icgo.studies.calibration.select import MIN_MARGIN_DEG, beats, model_accuracy, recommend

    def table(rows):
        return pd.DataFrame([{"recording": "r", "split": sp, "outer": "", "method": m, "score_deg": sc,
                              "degenerate": False, "site_flag": False, "site_reason": ""} for sp, m, sc in rows])

    tiny = [("in-sample", "twelve+axis", 0.5), ("in-sample", "twelve+axis+relm", 0.5 - 1e-6),
            ("held-out group 8", "twelve+axis", 0.6), ("held-out group 8", "twelve+axis+relm", 0.6 - 1.0e-6),
            ("held-out group 9", "twelve+axis", 0.7), ("held-out group 9", "twelve+axis+relm", 0.7 - 1.1e-6)]
    r = recommend(table(tiny), "r")
    assert r["method"] == "twelve+axis" and not r["clear_winner"] and "beats twelve+axis by 0.000" not in r["criterion"]
    assert beats(np.array([1.0e-6, 1.1e-6])) is None and beats(np.array([0.2, 0.18])) is not None
    assert beats(np.array([MIN_MARGIN_DEG / 2] * 3)) is None and beats(np.array([0.3])) is None
    one = [x for x in tiny if x[0] != "held-out group 9"]
    one = [(sp, m, sc - (0.2 if m == "twelve+axis+relm" else 0.0)) for sp, m, sc in one]
    r = recommend(table(one), "r")
    assert r["method"] == "twelve+axis" and not r["clear_winner"]
    acc = model_accuracy(table(one), "r", "twelve+axis")
    assert acc["deg"] == pytest.approx(0.6) and acc["spread_deg"] is None and "1 held-out split" in acc["what"]
    acc = model_accuracy(table([x for x in tiny if x[0] == "in-sample"]), "r", "twelve+axis")
    assert acc["deg"] == pytest.approx(0.5) and "no held-out split" in acc["what"] and "optimistic" in acc["what"]


def test_an_icgo_relm_model_states_one_interval_in_run_and_apply(tmp_path):
    """The interval run's verdict states is the one the saved model carries and apply prints; the repeats' own
    mean half-width (another quantity) is named beside it, never in its place."""
    from icgo.datasets import casing_stations
    from icgo.studies.icgo_relm import study as icgo_relm
    from icgo.studies.icgo_relm.config import StudyConfig
    from icgo.studies.icgo_relm.outputs import model_interval
    from icgo.survey.apply import correct_survey
    from icgo.survey.verdict import study_verdict, survey_verdict

    res = icgo_relm.run_study(casing_stations.lab_casing(0, toolface_step_deg=30.0).frame,
                              StudyConfig(split=dict(n_repeats=3), model=dict(hidden=8), budget=dict(pop_size=6,
                                          iterations=3), optimizer="pso"))
    hw = model_interval(res.model)
    run = study_verdict(res.metrics, res.coverage, selected=res.model.selected, n_repeats=3, protocol="random",
                        qc=None, trained=res.model.domain, run_dir="R", model_interval_deg=hw)
    new = casing_stations.lab_casing(5, toolface_step_deg=30.0).frame
    app = survey_verdict(correct_survey(res.model, new), res.model, QCBands(), out_csv="o", model_path="m",
                         survey_path="s")
    assert app.numbers["interval_deg"] == hw and run.numbers["model_interval_deg"] == hw
    stated = f"+/- {hw:.3f} deg at 90 %"
    assert stated in run.accuracy and stated in app.accuracy
    assert run.accuracy.index(stated) < run.accuracy.index("one repeat's own interval")
