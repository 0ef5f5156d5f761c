"""icgo.models.calibration_params: the calibration's params pytree and its one predict.

The saved files under tests/data/mag_calibration_files were written by icgo before the params pytree
(make_files.py there says how); ``expected.npz`` holds what that build's ``apply`` and ``corrected`` gave on
one survey, on the machine that wrote them. They must load and save back to the same header and arrays (bitwise:
no arithmetic), and apply to within :data:`FIXTURE_ULPS` units in the last place of each column's magnitude: the
same arithmetic on another CPU takes other BLAS kernels and differs by a few ulps (seen: up to 9 ulps of an element,
4e-16 relative, on an AVX-512 Xeon and an AMD EPYC against the writer). Bitwise equality of apply is tested within one
process (``test_save_load_apply_is_bitwise``: the loaded model against the one saved). Every
combination of the optional parts is also checked against the arithmetic written out in float64 numpy
(:func:`_reference`), and jit / vmap / float32 against the eager result.
"""

from __future__ import annotations

import dataclasses
import itertools
import json
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pandas as pd
import pytest

import icgo  # noqa: F401  (float64)
from icgo.artifacts.calibration import MagCalibration, mag_calibration, with_residual
from icgo.artifacts.format import param_arrays
from icgo.artifacts.registry import load_model
from icgo.core.errors import ModelError
from icgo.models import calibration as cal
from icgo.models import mag_relm
from icgo.models.calibration_params import LEAVES, CalibrationParams, predict

FILES = Path(__file__).parent / "data" / "mag_calibration_files"
NAMES = sorted(p.stem for p in FILES.glob("*.json"))
COMBOS = list(itertools.product((False, True), repeat=3))  # (accelerometer, alignment, residual)
#: Units in the last place, of the largest magnitude in each column, that a fixture computed on another CPU may differ
#: by. Seen: at most 9 ulps of an element, i.e. at most 9 of the column's; 64 leaves room and is still ~1e-14 relative.
FIXTURE_ULPS = 64


def assert_close_in_ulps(actual, expected, ulps=FIXTURE_ULPS):
    """``actual`` equals ``expected`` (both (n, k)) within ``ulps`` units in the last place of each column's largest
    magnitude; NaN only where ``expected`` has NaN."""
    actual, expected = np.atleast_2d(np.asarray(actual, np.float64)), np.atleast_2d(np.asarray(expected, np.float64))
    assert actual.shape == expected.shape
    np.testing.assert_array_equal(np.isnan(actual), np.isnan(expected))
    scale = np.spacing(np.nanmax(np.abs(expected), axis=0, initial=0.0))
    off = np.nan_to_num(np.abs(actual - expected)) / scale
    assert off.max() <= ulps, f"differs by {off.max():.0f} ulps of its column (column {int(off.max(0).argmax())})"


@pytest.fixture(scope="module")
def expected():
    return dict(np.load(FILES / "expected.npz"))


def _frame(G, B):
    return pd.DataFrame({"station": np.arange(len(G)), "gx": G[:, 0], "gy": G[:, 1], "gz": G[:, 2],
                         "bx": B[:, 0], "by": B[:, 1], "bz": B[:, 2]})


def _params(accel: bool, aligned: bool, nl: bool, seed: int = 0) -> CalibrationParams:
    rng = np.random.default_rng(seed)
    Q = np.linalg.qr(rng.normal(size=(3, 3)))[0]
    hidden = mag_relm.axis_rbf_hidden()
    return CalibrationParams(
        x_mag=np.r_[(np.eye(3) + rng.normal(0, 0.03, (3, 3))).ravel() / 5e4, rng.normal(0, 500, 3)],
        x_accel=np.r_[(np.eye(3) + rng.normal(0, 0.01, (3, 3))).ravel(), rng.normal(0, 0.01, 3)] if accel else None,
        alignment=Q * np.sign(np.linalg.det(Q)) if aligned else None,
        nl_hidden=hidden if nl else None, nl_out=rng.normal(0, 0.01, (hidden.shape[1], 3)) if nl else None,
        nl_activation="gauss" if nl else None)


def _shots(n=30, seed=1):
    rng = np.random.default_rng(seed)
    G = rng.normal(0, 1, (n, 3))
    G /= np.linalg.norm(G, axis=1, keepdims=True)
    B = rng.normal(0, 1, (n, 3)) * 4.5e4 + rng.normal(0, 500, 3)
    return G, B


def _reference(p: CalibrationParams, G, B):
    """The calibration's arithmetic step by step, float64: eq. (4) (jax, as icgo has always evaluated it),
    then the rotation and the residual in numpy."""
    Bc = np.asarray(cal.correct(jnp.asarray(p.x_mag), B))
    Gc = G if p.x_accel is None else np.asarray(cal.correct(jnp.asarray(p.x_accel), G))
    if p.alignment is not None:
        Bc, Gc = Bc @ p.alignment.T, Gc @ p.alignment.T
    if p.nl_hidden is not None:
        Bc = mag_relm.apply(p.nl_hidden, p.nl_out, Bc, p.nl_activation)
    return Gc, Bc


@pytest.mark.parametrize("accel,aligned,nl", COMBOS)
def test_predict_is_the_calibration_arithmetic_bitwise(accel, aligned, nl):
    p = _params(accel, aligned, nl)
    G, B = _shots()
    out = predict(p, np.hstack([G, B]))
    Gc, Bc = _reference(p, G, B)
    assert isinstance(out, np.ndarray) and out.shape == (len(G), 6)
    np.testing.assert_array_equal(out[:, :3], Gc)
    np.testing.assert_array_equal(out[:, 3:], Bc)
    # each part changes the result (the structure decides which steps run)
    linear = predict(CalibrationParams(p.x_mag), np.hstack([G, B]))
    assert np.array_equal(out, linear) == (not any((accel, aligned, nl)))


@pytest.mark.parametrize("accel,aligned,nl", COMBOS)
def test_jit_and_vmap_agree_with_the_eager_predict(accel, aligned, nl):
    p = _params(accel, aligned, nl)
    G, B = _shots()
    x = np.hstack([G, B])
    eager = np.asarray(predict(jax.tree_util.tree_map(jnp.asarray, p), jnp.asarray(x)))
    jitted = np.asarray(jax.jit(predict)(p, x))
    if nl:  # XLA fuses the residual's exp and sums differently under jit: the last bit of a few values
        np.testing.assert_allclose(jitted, eager, rtol=0, atol=4 * np.finfo(float).eps * np.abs(eager).max())
    else:
        np.testing.assert_array_equal(jitted, eager)
    rows = lambda r: predict(p, r[None])[0]  # one shot at a time
    np.testing.assert_array_equal(np.asarray(jax.vmap(rows)(jnp.asarray(x))), eager)
    np.testing.assert_array_equal(np.asarray(jax.jit(jax.vmap(rows))(jnp.asarray(x))), jitted)
    # the host evaluation is the same function to a few ulps (numpy's and XLA's exp and norm differ)
    np.testing.assert_allclose(predict(p, x), eager, rtol=1e-14, atol=1e-14 * np.abs(eager).max())
    # vmap over calibrations: a stack of three, each as predicted alone
    ps = [_params(accel, aligned, nl, seed=s) for s in range(3)]
    stacked = jax.tree_util.tree_map(lambda *a: np.stack(a), *ps)
    batched = np.asarray(jax.jit(jax.vmap(predict, in_axes=(0, None)))(stacked, x))
    for k, pk in enumerate(ps):
        np.testing.assert_array_equal(batched[k], np.asarray(jax.jit(predict)(pk, x)))


def test_one_compilation_per_structure():
    G, B = _shots()
    x = jnp.asarray(np.hstack([G, B]))
    traces = []
    f = jax.jit(lambda p, x: (traces.append(p.parts()), predict(p, x))[1])
    for seed in range(3):
        f(_params(True, True, True, seed), x)
    assert len(traces) == 1
    f(_params(True, False, True), x)
    assert len(traces) == 2 and traces[1]["alignment"] is False


@pytest.mark.parametrize("accel,aligned,nl", COMBOS)
def test_float32_is_close_to_float64(accel, aligned, nl):
    p = _params(accel, aligned, nl)
    G, B = _shots()
    x = np.hstack([G, B])
    ref = predict(p, x)
    p32 = jax.tree_util.tree_map(lambda a: jnp.asarray(a, jnp.float32), p)
    out = jax.jit(predict)(p32, jnp.asarray(x, jnp.float32))
    assert out.dtype == jnp.float32
    np.testing.assert_allclose(np.asarray(out[:, :3]), ref[:, :3], atol=1e-6)  # g
    np.testing.assert_allclose(np.asarray(out[:, 3:]), ref[:, 3:], atol=3e-6)  # unit sphere (|B_c| ~ 1)


def test_leaves_are_the_saved_array_names():
    p = _params(True, True, True)
    assert list(param_arrays(p)) == list(LEAVES)
    assert list(param_arrays(_params(False, False, False))) == ["x_mag"]
    assert p.parts() == {"x_accel": True, "alignment": True, "nl_hidden": True, "nl_out": True}


@pytest.mark.parametrize("accel,aligned,nl", COMBOS)
def test_save_load_apply_is_bitwise(tmp_path, accel, aligned, nl):
    p = _params(accel, aligned, nl)
    G, B = _shots()
    model = mag_calibration("twelve", p.x_mag, G, B, {"seed": 0}, x_accel=p.x_accel, alignment=p.alignment,
                            field_scale_nT=5e4)
    if nl:
        model = with_residual(model, mag_relm.MagRELM(p.nl_hidden, p.nl_out, "gauss", 1.0, np.zeros(1)), {"seed": 0})
    back = load_model(model.save(tmp_path / "m"))
    frame = _frame(*_shots(seed=4))
    pd.testing.assert_frame_equal(back.apply(frame), model.apply(frame), check_exact=True)
    assert jax.tree_util.tree_structure(back.params) == jax.tree_util.tree_structure(model.params)
    head = json.loads((tmp_path / "m.json").read_text())
    absent = [n for n, has in p.parts().items() if not has]
    assert [n for n, v in head["fields"].items() if v is None and n != "nl_activation"] == absent
    assert not {"field_reference", "accuracy"} & set(head["fields"])  # LATER_FIELDS: left out while None
    assert sorted(head["array_names"]) == sorted(set(LEAVES) - set(absent))


def test_ulp_check_takes_what_another_cpu_gives_and_refuses_more():
    x = np.array([[1.0, -3e4, 0.0], [0.5, 2e4, 1e-3]])
    assert_close_in_ulps(x + 9 * np.spacing(np.abs(x).max(0)), x)
    with pytest.raises(AssertionError, match="ulps of its column"):
        assert_close_in_ulps(x + [[0.0, 65 * np.spacing(3e4), 0.0], [0.0, 0.0, 0.0]], x)
    with pytest.raises(AssertionError):
        assert_close_in_ulps(np.where(x == 0.0, np.nan, x), x)


@pytest.mark.parametrize("name", NAMES)
def test_files_written_before_load_and_apply(tmp_path, expected, name):
    G, B = expected["G"], expected["B"]
    with jax.default_device(jax.devices("cpu")[0]):  # the device the expected values were computed on
        model = load_model(FILES / f"{name}.json")
        out = model.apply(_frame(G, B))
        field_only = model.apply(_frame(G, B)[["bx", "by", "bz"]])
        corrected = np.hstack([*model.corrected(G, B), model.corrected(None, B)[1]])
    assert isinstance(model, MagCalibration)
    assert list(out.columns) == list(expected[f"{name}.apply_columns"])
    assert_close_in_ulps(out.to_numpy(np.float64), expected[f"{name}.apply"])
    assert list(field_only.columns) == list(expected[f"{name}.apply_field_only_columns"])
    assert_close_in_ulps(field_only.to_numpy(np.float64), expected[f"{name}.apply_field_only"])
    assert_close_in_ulps(corrected, expected[f"{name}.corrected"])
    # saved again, the header and the arrays are the ones the file holds: an older icgo reads it as well
    path = model.save(tmp_path / name)
    old, new = json.loads((FILES / f"{name}.json").read_text()), json.loads(path.read_text())
    assert {**new, "arrays": ""} == {**old, "arrays": ""} and list(new["fields"]) == list(old["fields"])
    a_old, a_new = np.load(FILES / f"{name}.npz"), np.load(path.with_suffix(".npz"))
    assert sorted(a_new.files) == sorted(a_old.files)
    for k in a_old.files:
        np.testing.assert_array_equal(a_new[k], a_old[k])
        assert a_new[k].dtype == a_old[k].dtype


def test_a_part_the_header_marks_present_must_be_in_the_arrays(tmp_path):
    """A header whose null for a part was removed asks for that array; a part given as a non-null header
    value is refused; each in one line."""
    src = json.loads((FILES / "accel0_aligned0_nl0.json").read_text())
    (tmp_path / "m.npz").write_bytes((FILES / "accel0_aligned0_nl0.npz").read_bytes())
    for edit, msg in [(lambda f: f.pop("x_accel"), "lacks array 'x_accel'"),
                      (lambda f: f.__setitem__("x_accel", [1, 2]), "'x_accel' must be an array in m.npz or null"),
                      (lambda f: f.pop("nl_out"), "lacks array 'nl_out'")]:
        head = json.loads(json.dumps(src))
        edit(head["fields"])
        head["arrays"] = "m.npz"
        (tmp_path / "m.json").write_text(json.dumps(head))
        with pytest.raises(ModelError, match=msg) as e:
            load_model(tmp_path / "m.json")
        assert "\n" not in str(e.value)


def test_with_residual_keeps_the_linear_calibration():
    p = _params(True, True, True)
    G, B = _shots()
    lin = mag_calibration("twelve", p.x_mag, G, B, {"a": 1}, x_accel=p.x_accel, alignment=p.alignment)
    nl = with_residual(lin, mag_relm.MagRELM(p.nl_hidden, p.nl_out, "gauss", 1.0, np.zeros(1)), {"a": 2})
    assert nl.method == "twelve_relm" and nl.nl_activation == "gauss" and nl.config == {"a": 2}
    assert nl.data_hash == lin.data_hash and nl.domain == lin.domain
    stripped = dataclasses.replace(nl.params, nl_hidden=None, nl_out=None, nl_activation=None)
    assert jax.tree_util.tree_structure(stripped) == jax.tree_util.tree_structure(lin.params)
    assert all(a is b for a, b in zip(jax.tree_util.tree_leaves(stripped), jax.tree_util.tree_leaves(lin.params)))
    np.testing.assert_array_equal(nl.corrected(G, B)[0], lin.corrected(G, B)[0])
