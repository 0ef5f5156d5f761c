"""Fitted models as artifacts (icgo.artifacts.format, icgo.artifacts.relm): apply, save/load round trips, errors."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pandas as pd
import pytest

from icgo.core.errors import ModelError
from icgo.datasets import casing_stations
from icgo.artifacts.format import SCHEMA_VERSION
from icgo.artifacts.registry import load_model
from icgo.artifacts.relm import MSAModel, RELMCompensation, circular_mean_spread
from icgo.studies.icgo_relm import study
from icgo.studies.icgo_relm.config import StudyConfig

CFG = dict(split={"n_repeats": 3, "seed": 3}, model={"hidden": 10}, budget={"pop_size": 6, "iterations": 3})


@pytest.fixture(scope="module")
def fitted():
    frame = casing_stations.lab_casing(0).frame
    res = study.run_study(frame, StudyConfig(optimizer="pso", **CFG))
    return frame, res


def test_apply_reproduces_the_study_predictions(fitted):
    """Each member's apply on the training data IS the study's own prediction (bitwise: one forward pass)."""
    frame, res = fitted
    model = res.model
    assert isinstance(model, RELMCompensation) and model.methods == ["pso"] and model.selected == "pso"
    kept = frame.iloc[np.flatnonzero(res.kept)].reset_index(drop=True)
    a_msa, pred = model.members(kept)
    p = res.predictions
    comp = []
    for r, rid in enumerate(model.repeat_ids):
        rows = p[(p.repeat == rid)].sort_values("row")
        np.testing.assert_array_equal(pred[r], rows.predicted_error.to_numpy())
        np.testing.assert_array_equal(a_msa[r], rows.azimuth_msa.to_numpy())
        np.testing.assert_array_equal(np.mod(a_msa[r] - pred[r], 360.0), rows.azimuth_compensated.to_numpy())
        comp.append(rows.azimuth_compensated.to_numpy())
    out = model.apply(kept)
    comp = np.stack(comp)
    dev = (comp - comp[0] + 180.0) % 360.0 - 180.0  # members relative to member 0, no wrap jumps
    np.testing.assert_allclose(((out.azimuth_compensated - comp[0] + 180.0) % 360.0 - 180.0), dev.mean(axis=0),
                               rtol=0, atol=1e-9)
    np.testing.assert_allclose(out.azimuth_spread_deg, dev.std(axis=0, ddof=1), rtol=0, atol=1e-9)
    assert out.azimuth_spread_deg.max() > 0


def test_one_member_predicts_the_same_alone_or_among_others(fitted):
    """A member's prediction does not depend on how many members or rows it is run with (lax.map)."""
    import jax
    import jax.numpy as jnp

    from icgo.models.compensation import members, predict

    frame, res = fitted
    model = res.model
    params = members(model.method_params())
    assert params.hidden == model.hidden and params.raw_features
    v = jnp.asarray(frame[["gx", "gy", "gz", "bx", "by", "bz"]].to_numpy())
    whole = predict(params, v)
    alone = predict(jax.tree_util.tree_map(lambda x: x[1:2], params), v[:700])
    np.testing.assert_array_equal(np.asarray(alone.error), np.asarray(whole.error)[1:2, :700])
    np.testing.assert_array_equal(np.asarray(alone.a_msa), np.asarray(whole.a_msa)[1:2, :700])


def test_msa_model_applies_the_biases(fitted):
    frame, res = fitted
    m = res.msa_model
    assert isinstance(m, MSAModel) and m.params.bias.shape == (3, 3)
    out = m.apply(frame)
    B = frame[["bx", "by", "bz"]].to_numpy()
    np.testing.assert_allclose(out[["bx_corrected", "by_corrected", "bz_corrected"]].to_numpy(),
                               B - m.params.bias.mean(axis=0), rtol=0, atol=1e-9)
    np.testing.assert_array_equal(m.params.bias, res.model.params.msa_bias)  # one MSA, two artifacts


def test_save_load_apply_is_bitwise(fitted, tmp_path):
    _, res = fitted
    new = casing_stations.lab_casing(11).frame
    for model in (res.model, res.msa_model):
        before = model.apply(new)
        path = model.save(tmp_path / model.KIND)
        head = json.loads(path.read_text())
        assert head["schema_version"] == SCHEMA_VERSION and head["kind"] == model.KIND
        assert head["fields"]["data_hash"] == model.data_hash
        after = load_model(path).apply(new)
        pd.testing.assert_frame_equal(before, after, check_exact=True)


def test_fresh_process_reproduces_prediction_bitwise(fitted, tmp_path):
    """A saved model loaded in a fresh Python process gives the same corrected survey, bit for bit."""
    _, res = fitted
    new = casing_stations.lab_casing(12).frame
    new.to_csv(tmp_path / "new.csv", index=False)
    res.model.save(tmp_path / "model")
    here = res.model.apply(new)
    code = ("import pandas as pd, icgo; from icgo.artifacts.registry import load_model; "
            f"m = load_model(r'{tmp_path / 'model.json'}'); "
            f"m.apply(pd.read_csv(r'{tmp_path / 'new.csv'}')).to_csv(r'{tmp_path / 'out.csv'}', index=False, float_format='%.17g')")
    subprocess.run([sys.executable, "-c", code], check=True, timeout=300)
    there = pd.read_csv(tmp_path / "out.csv")
    for c in here.columns:
        np.testing.assert_array_equal(here[c].to_numpy(), there[c].to_numpy(), err_msg=c)


def test_model_errors_are_one_line(fitted, tmp_path):
    _, res = fitted
    (tmp_path / "junk.json").write_text("{not json")
    with pytest.raises(ModelError, match="not a model file"):
        load_model(tmp_path / "junk.json")
    (tmp_path / "plain.json").write_text(json.dumps({"a": 1}))
    with pytest.raises(ModelError, match="not a model file"):
        load_model(tmp_path / "plain.json")
    path = res.model.save(tmp_path / "m")
    head = json.loads(path.read_text())
    head["schema_version"] = SCHEMA_VERSION + 1
    path.write_text(json.dumps(head))
    with pytest.raises(ModelError, match="newer than this icgo"):
        load_model(path)
    with pytest.raises(ModelError, match="model file not found"):
        load_model(tmp_path / "absent.json")
    survey = casing_stations.lab_casing(1).frame.drop(columns=["bz"])
    with pytest.raises(ModelError, match=r"needs column\(s\) \['bz'\]") as e:
        res.model.apply(survey)
    assert "\n" not in str(e.value)


def test_circular_mean_across_north():
    mean, spread = circular_mean_spread(np.array([[359.0, 10.0], [1.0, 12.0]]))
    np.testing.assert_allclose(mean, [0.0, 11.0], atol=1e-12)
    np.testing.assert_allclose(spread, [np.sqrt(2.0), np.sqrt(2.0)], atol=1e-12)


def test_out_of_bag_halfwidth_is_the_conformal_quantile():
    from icgo.artifacts.relm import out_of_bag_halfwidth

    a_true = np.array([10.0, 20.0, 30.0, 359.0, 0.5])
    # member 0 held out rows 0, 1, 3; member 1 held out rows 1, 2, 3; row 4 is never held out
    train = np.array([[0, 0, 1, 0, 1], [1, 0, 0, 0, 1]], bool)
    err = np.array([[0.1, 0.2, 9.0, -0.4, 50.0], [7.0, 0.4, -0.3, -0.2, 50.0]])  # deg, per member
    a_comp = (a_true[None] + err)[None]                                            # (S=1, R=2, N)
    oob = np.array([0.1, 0.3, 0.3, 0.3])  # |mean OOB error| of rows 0-3: 0.1, (0.2+0.4)/2, 0.3, (0.4+0.2)/2
    n = 4
    for level, rank in ((0.5, int(np.ceil(5 * 0.5))), (0.9, n)):
        got = out_of_bag_halfwidth(a_comp, a_true, train, level)
        assert got.shape == (1,) and got[0] == pytest.approx(np.sort(oob)[rank - 1], abs=1e-12)


def test_models_carry_their_interval(fitted):
    frame, res = fitted
    out = res.model.apply(casing_stations.lab_casing(3).frame)
    hw = res.model.interval_halfwidth
    assert hw.shape == (1,) and np.isfinite(hw).all() and hw[0] > 0
    assert (out.azimuth_interval_deg == hw[0]).all() and res.model.interval_level == 0.9


# ---------------------------------------------------------------- hostile model files (docs/reliability.md)
def _copy_model(tmp_path, kind="msa"):
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parent))
    import hostile_models

    return hostile_models.models()[kind].save(tmp_path / "m")


def test_only_the_models_own_arrays_are_read(tmp_path):
    """An extra member is never opened: here one whose data is corrupt (reading it would fail its CRC)."""
    import zipfile

    path = _copy_model(tmp_path)
    with zipfile.ZipFile(tmp_path / "m.npz", "a") as z:
        z.writestr("extra.npy", b"\x93NUMPY" + b"x" * 100)
    data = bytearray((tmp_path / "m.npz").read_bytes())
    i = data.rfind(b"x" * 100)
    data[i:i + 10] = b"y" * 10  # corrupt the extra member only
    (tmp_path / "m.npz").write_bytes(bytes(data))
    assert load_model(path).KIND == "msa"


def test_an_array_header_claiming_a_huge_shape_is_refused_before_reading(tmp_path):
    import zipfile

    path = _copy_model(tmp_path)
    with zipfile.ZipFile(tmp_path / "m.npz") as z:
        members = {i.filename: z.read(i) for i in z.infolist()}
    hdr = "{'descr': '<f8', 'fortran_order': False, 'shape': (1000000, 1000000), }"
    hdr += " " * (118 - len(hdr)) + "\n"
    members["bias.npy"] = b"\x93NUMPY\x01\x00" + len(hdr).to_bytes(2, "little") + hdr.encode()
    with zipfile.ZipFile(tmp_path / "m.npz", "w") as z:
        for k, v in members.items():
            z.writestr(k, v)
    with pytest.raises(ModelError, match=r"'bias' declares shape \(1000000, 1000000\).*over the 64 MiB limit"):
        load_model(path)


@pytest.mark.parametrize("edit, says", [
    (lambda h: h.__setitem__("fields", [1, 2]), "'fields' must be a JSON object"),
    (lambda h: h.__setitem__("kind", ["msa"]), "unknown model kind"),
    (lambda h: h.__setitem__("arrays", "../x.npz"), "'arrays' must be a file name"),
    (lambda h: h["fields"].__setitem__("repeat_ids", None), "field 'repeat_ids' must be list"),
    (lambda h: h["fields"]["domain"].__setitem__("dip_deg", [float("nan"), 1.0]), "NaN in the model header"),
    (lambda h: h["fields"]["domain"].__setitem__("dip_deg", [5.0, 1.0]), "training domain 'dip_deg'"),
    (lambda h: h["fields"]["domain"].__setitem__("dip_deg", "wide"), "training domain 'dip_deg'"),
])
def test_edited_headers_are_one_modelerror_line(tmp_path, edit, says):
    path = _copy_model(tmp_path)
    head = json.loads(path.read_text())
    edit(head)
    path.write_text(json.dumps(head))
    with pytest.raises(ModelError, match=says) as e:
        load_model(path)
    assert "\n" not in str(e.value) and "m.json" in str(e.value)


@pytest.mark.parametrize("array, value, says", [
    ("bias", np.full((2, 3), np.nan), "NaN or inf"), ("bias", np.full((2, 3), 1e300), "beyond"),
    ("bias", np.ones((3, 2)), "shape"), ("bias", np.ones((2, 3)) + 1j, "dtype complex"),
    ("scale", -np.ones((2, 3)), "scale must be > -1"), ("bias", np.zeros((0, 3)), "empty"),
])
def test_edited_arrays_are_one_modelerror_line(tmp_path, array, value, says):
    path = _copy_model(tmp_path)
    with np.load(tmp_path / "m.npz") as z:
        arrays = {k: z[k] for k in z.files}
    arrays[array] = value
    head = json.loads(path.read_text())
    head.pop("array_shapes")  # a file of the first build: the shape is then checked by the kind itself
    path.write_text(json.dumps(head))
    with open(tmp_path / "m.npz", "wb") as fh:
        np.savez(fh, **arrays)
    with pytest.raises(ModelError, match=says):
        load_model(path)


@pytest.mark.parametrize("listed", ["../outside.json", "/etc/passwd", "link.json"])
def test_a_run_directory_may_not_point_out_of_itself(tmp_path, listed):
    run = tmp_path / "run"
    run.mkdir()
    _copy_model(tmp_path)
    (tmp_path / "m.json").rename(tmp_path / "outside.json")
    (run / "link.json").symlink_to(tmp_path / "outside.json")
    (run / "run.json").write_text(json.dumps({"models": [listed]}))
    with pytest.raises(ModelError, match="models"):
        load_model(run)


def test_every_kind_loads_back_checked(tmp_path):
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parent))
    import hostile_models

    survey = hostile_models.survey()
    for kind, model in hostile_models.models().items():
        back = load_model(model.save(tmp_path / kind))
        pd.testing.assert_frame_equal(back.apply(survey), model.apply(survey))


def test_apply_in_row_blocks_is_bitwise_the_whole():
    """RELMCompensation applies a long survey in row blocks (bounded memory); the result does not depend on them."""
    import sys
    from pathlib import Path

    import jax.numpy as jnp

    from icgo.models.compensation import members, predict

    sys.path.insert(0, str(Path(__file__).resolve().parent))
    import hostile_models

    model, survey = hostile_models.models()["relm_compensation"], hostile_models.survey(n=130)
    v = jnp.asarray(survey[["gx", "gy", "gz", "bx", "by", "bz"]].to_numpy())
    whole = predict(members(model.method_params()), v)
    blocks = predict(members(model.method_params()), v, block_rows=50)
    np.testing.assert_array_equal(np.asarray(blocks.error), np.asarray(whole.error))
    np.testing.assert_array_equal(np.asarray(blocks.a_msa), np.asarray(whole.a_msa))
    np.testing.assert_array_equal(model.members(survey)[1], np.asarray(whole.error))


# ---------------------------------------------------------------- the one model pattern (RELM and MSA families)
def test_the_saved_params_predict_what_the_study_scored(fitted):
    """The model's predict (every method) on the study's rows IS the study's prediction table, bitwise; it jits
    whole (up to XLA's fusion) and the MSA family's predict is the field the study's MSA corrected."""
    import jax

    from icgo.models import compensation
    from icgo.models import msa as _msa

    frame, res = fitted
    kept = frame.iloc[np.flatnonzero(res.kept)].reset_index(drop=True)
    x = res.model.inputs(kept)
    out = res.model.predict(x)
    S, R = len(res.model.methods), len(res.model.repeat_ids)
    p = res.predictions
    assert out.error.shape == (S, R, len(kept))
    np.testing.assert_array_equal(np.asarray(out.error).ravel(), p.predicted_error.to_numpy())
    np.testing.assert_array_equal(np.asarray(out.a_msa).ravel(), p.azimuth_msa.to_numpy())
    jitted = jax.jit(compensation.predict_methods)(res.model.params, x)
    np.testing.assert_allclose(np.asarray(jitted.error), np.asarray(out.error), rtol=0, atol=1e-9)
    b_corr = np.asarray(res.msa_model.predict(x))                               # (R, N, 3)
    np.testing.assert_array_equal(b_corr[1], np.asarray(_msa.predict(jax.tree.map(lambda a: a[1],
                                                                                    res.msa_model.params), x)))
    np.testing.assert_allclose(b_corr, x[None, :, 3:] - res.msa_model.params.bias[:, None], rtol=0, atol=1e-9)


def test_fit_reproduces_the_studys_refit(fitted):
    """compensation.fit (checked, one member) on a repeat's training rows, MSA and hidden weights gives the output
    weights and statistics the study refitted for that repeat (the same ridge problem, eq. 9)."""
    from icgo.models import compensation

    frame, res = fitted
    kept = frame.iloc[np.flatnonzero(res.kept)].reset_index(drop=True)
    x = res.model.inputs(kept)
    params, p = res.model.params, res.predictions
    for r, rid in enumerate(res.model.repeat_ids):
        rows = p[p.repeat == rid].sort_values("row")
        train = (rows.split == "train").to_numpy()
        one = compensation.fit(params.theta[0, r], x, rows.error_msa.to_numpy(), res.model.lam, res.model.hidden,
                               weights=train.astype(float), msa_bias=params.msa_bias[r],
                               msa_scale=params.msa_scale[r], raw_features=True)
        np.testing.assert_allclose(np.asarray(one.x_mean), params.x_mean[r], rtol=1e-12)
        np.testing.assert_allclose(np.asarray(one.x_std), params.x_std[r], rtol=1e-12)
        np.testing.assert_allclose(np.asarray(one.beta), params.beta[0, r], rtol=1e-7, atol=1e-9)


LEGACY = __import__("pathlib").Path(__file__).resolve().parent / "data" / "models"


@pytest.mark.parametrize("kind", ["relm_compensation", "msa"])
def test_a_file_of_the_previous_layout_loads_and_applies_as_it_did(kind):
    """Files written by the build before the RELM and MSA families had params pytrees (tests/data/models/README.md)
    load through the generic path and apply as that build did (its outputs stored beside them)."""
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parent))
    import hostile_models

    model = load_model(LEGACY / f"{kind}.json")
    survey = hostile_models.survey(n=40, seed=3)
    with np.load(LEGACY / "expected_apply.npz") as z:
        expected = {k: z[k] for k in z.files if k.startswith(f"{kind}.")}
    methods = model.methods if kind == "relm_compensation" else [None]
    assert len(expected) == len(methods) * len(model.apply(survey).columns)
    for m in methods:
        got = model.apply(survey, method=m) if m else model.apply(survey)
        for c in got.columns:
            np.testing.assert_allclose(got[c].to_numpy(), expected[f"{kind}.{m or ''}.{c}"], rtol=0, atol=1e-9,
                                       err_msg=f"{m} {c}")
