"""icgo.artifacts.format's generic save/load of (kind, params leaves, meta), on a toy family of the shape the RELM
and calibration families take: nested and dict-valued params, an optional leaf, a static setting, a member axis,
meta JSON values and a record array."""

from __future__ import annotations

import dataclasses
import json
import zipfile
from functools import partial
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import pandas as pd
import pytest

import icgo  # noqa: F401  (float64)
from icgo.core.errors import ModelError
from icgo.core.settings import need
from icgo.artifacts.format import SCHEMA_VERSION, FittedModel, need_shape, param_arrays, read_model


class Scale(NamedTuple):
    gain: jnp.ndarray    # (M, 3)
    offset: jnp.ndarray  # (M, 3)


@partial(jax.tree_util.register_dataclass, data_fields=("scale", "terms", "rotation"), meta_fields=("power",))
@dataclasses.dataclass(frozen=True)
class ToyParams:
    scale: Scale
    terms: dict             # name -> (M, 3)
    rotation: jnp.ndarray | None
    power: int


def toy_predict(params: ToyParams, x):
    """(N, 3) -> (N, 3): ``(gain * x + offset + sum(terms)) ** power``, rotated if a rotation is given."""
    y = params.scale.gain * x + params.scale.offset + sum(params.terms.values())
    y = y ** params.power
    return y if params.rotation is None else y @ params.rotation.T


@dataclasses.dataclass(frozen=True, eq=False)
class ToyModel(FittedModel):
    KIND = "toy"
    PARAMS = ToyParams
    PREDICT = jax.vmap(toy_predict, in_axes=(0, None))
    INPUTS = ("bx", "by", "bz")

    terms: list
    rotated: bool
    power: int
    params: ToyParams
    fit_cost: np.ndarray  # (M,) a record: saved, not used by predict

    @classmethod
    def params_like(cls, fields):
        return ToyParams(Scale(0, 0), {t: 0 for t in fields["terms"]}, 0 if fields["rotated"] else None,
                         fields["power"])

    def validate(self):
        M = np.shape(self.params.scale.gain)[0]
        need(self.power in (1, 2), f"power must be 1 or 2, got {self.power}", error=ModelError)
        for name, a in param_arrays(self.params).items():
            need_shape(a, (M, 3, 3) if name == "rotation" else (M, 3), name)

    def apply(self, frame):
        return pd.DataFrame(np.asarray(self.predict(self.inputs(frame))).mean(0), columns=["x", "y", "z"])


KINDS = {"toy": ToyModel}


def _toy(rotated=True, terms=("drift", "bias")):
    rng = np.random.default_rng(0)
    M = 2
    rot = np.stack([np.eye(3)[[1, 2, 0]]] * M) if rotated else None
    params = ToyParams(Scale(rng.normal(size=(M, 3)), rng.normal(size=(M, 3))),
                       {t: rng.normal(size=(M, 3)) for t in terms}, rot, 2)
    return ToyModel(config={"toy": True}, data_hash="0" * 16, domain={"b_norm_nT": [0.0, 1.0]}, terms=list(terms),
                    rotated=rotated, power=2, params=params, fit_cost=np.array([0.5, 0.25]))


@pytest.mark.parametrize("rotated", [True, False])
def test_save_load_predict_is_bitwise(tmp_path, rotated):
    model = _toy(rotated)
    x = np.random.default_rng(1).normal(size=(7, 3))
    back = read_model(model.save(tmp_path / "toy"), KINDS)
    assert jax.tree_util.tree_structure(back.params) == jax.tree_util.tree_structure(model.params)
    for a, b in zip(jax.tree.leaves(back.params), jax.tree.leaves(model.params)):
        np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(back.predict(x), model.predict(x))
    np.testing.assert_array_equal(back.fit_cost, model.fit_cost)
    assert (back.terms, back.rotated, back.power, back.config) == (model.terms, rotated, 2, model.config)
    # the independent reference: the toy's formula in numpy, member by member
    p = model.params
    want = (p.scale.gain[:, None] * x + p.scale.offset[:, None] + p.terms["drift"][:, None]
            + p.terms["bias"][:, None]) ** 2
    if rotated:
        want = np.einsum("mnj,mij->mni", want, p.rotation)
    np.testing.assert_allclose(np.asarray(back.predict(x)), want, rtol=1e-14)


def test_the_file_holds_the_leaves_by_path_and_the_meta(tmp_path):
    path = _toy().save(tmp_path / "toy")
    head = json.loads(path.read_text())
    assert head["schema_version"] == SCHEMA_VERSION and head["kind"] == "toy"
    assert head["array_names"] == sorted(["scale.gain", "scale.offset", "terms.bias", "terms.drift", "rotation",
                                          "fit_cost"])
    assert set(head["fields"]) == {"config", "data_hash", "domain", "terms", "rotated", "power"}
    with zipfile.ZipFile(tmp_path / "toy.npz") as z:
        assert sorted(z.namelist()) == sorted(f"{n}.npy" for n in head["array_names"])
    assert "rotation" not in json.loads(_toy(rotated=False).save(tmp_path / "plain").read_text())["array_names"]


def test_params_that_their_meta_does_not_describe_are_not_saved(tmp_path):
    m = _toy()
    for wrong in (dataclasses.replace(m, power=1), dataclasses.replace(m, terms=["drift"]),
                  dataclasses.replace(m, rotated=False)):
        with pytest.raises(ValueError, match="would not load as it is"):
            wrong.save(tmp_path / "x")


def _edit(tmp_path, header=None, arrays=None):
    path = _toy().save(tmp_path / "toy")
    if header:
        head = json.loads(path.read_text())
        header(head)
        path.write_text(json.dumps(head))
    if arrays:
        with np.load(tmp_path / "toy.npz") as z:
            a = {k: z[k] for k in z.files}
        arrays(a)
        with open(tmp_path / "toy.npz", "wb") as fh:
            np.savez(fh, **a)
    return path


@pytest.mark.parametrize("header, arrays, says", [
    (None, lambda a: a.pop("terms.drift"), "lacks array 'terms.drift'"),
    (None, lambda a: a.__setitem__("scale.gain", np.full((2, 3), np.nan)), "'scale.gain' holds NaN"),
    (None, lambda a: a.__setitem__("terms.bias", np.ones((2, 3)) + 1j), "'terms.bias' has dtype complex"),
    (lambda h: h.pop("array_shapes"), lambda a: a.__setitem__("rotation", np.ones((2, 3))), "'rotation' has shape"),
    (lambda h: h["fields"].__setitem__("terms", ["drift", "bias", "new"]), None, "lacks array 'terms.new'"),
    (lambda h: h["fields"].__setitem__("terms", ["../x"]), None, "not a plain name"),
    (lambda h: h["fields"].__setitem__("power", 3), None, "power must be 1 or 2"),
    (lambda h: h["fields"].__setitem__("rotated", "yes"), None, "field 'rotated' must be bool"),
    (lambda h: h["fields"].pop("terms"), None, "lacks field 'terms'"),
    # a range given as a number: only n_* entries are counts (apply compares every range with the survey's)
    (lambda h: h["fields"]["domain"].__setitem__("b_norm_nT", 0), None, r"training domain 'b_norm_nT' must be \[low"),
])
def test_edited_files_are_one_modelerror_line(tmp_path, header, arrays, says):
    path = _edit(tmp_path, header, arrays)
    with pytest.raises(ModelError, match=says) as e:
        read_model(path, KINDS)
    assert "\n" not in str(e.value) and ("toy.json" in str(e.value) or "toy.npz" in str(e.value))


def test_a_kind_refuses_files_older_than_its_layout(tmp_path):
    class NewToy(ToyModel):
        OLDEST_SCHEMA = SCHEMA_VERSION
        REFIT = "refit it with the toy command"

    path = _edit(tmp_path, header=lambda h: h.__setitem__("schema_version", SCHEMA_VERSION - 1))
    assert read_model(path, KINDS).KIND == "toy"  # the toy itself reads every schema
    with pytest.raises(ModelError, match=rf"toy\.json: a toy file of model schema {SCHEMA_VERSION - 1}, .*"
                                         r"refit it with the toy command"):
        read_model(path, {"toy": NewToy})


@dataclasses.dataclass(frozen=True, eq=False)
class OptionalToy(ToyModel):
    """The toy whose rotation is an optional leaf: the header says whether it has one (null: it has not)."""

    OPTIONAL_LEAVES = ("rotation",)

    @classmethod
    def params_like(cls, fields):
        return ToyParams(Scale(0, 0), {t: 0 for t in fields["terms"]}, None if fields.get("rotation", 0) is None
                         else 0, fields["power"])


@pytest.mark.parametrize("rotated", [True, False])
def test_an_absent_optional_leaf_is_null_in_the_header(tmp_path, rotated):
    model = OptionalToy(**{f.name: getattr(_toy(rotated), f.name) for f in dataclasses.fields(ToyModel)})
    path = model.save(tmp_path / "toy")
    head = json.loads(path.read_text())
    assert ("rotation" in head["fields"]) == (not rotated) and head["fields"].get("rotation") is None
    assert ("rotation" in head["array_names"]) == rotated
    back = read_model(path, {"toy": OptionalToy})
    assert jax.tree_util.tree_structure(back.params) == jax.tree_util.tree_structure(model.params)
    x = np.random.default_rng(1).normal(size=(7, 3))
    np.testing.assert_array_equal(back.predict(x), model.predict(x))
    if not rotated:  # a part marked present must be an array; a non-null value is refused
        for value, says in [(0, "'rotation' must be an array in toy.npz or null"), (None, None)]:
            head["fields"]["rotation"] = value
            path.write_text(json.dumps(head))
            if says is None:
                assert read_model(path, {"toy": OptionalToy}).params.rotation is None
                continue
            with pytest.raises(ModelError, match=says) as e:
                read_model(path, {"toy": OptionalToy})
            assert "\n" not in str(e.value)
        del head["fields"]["rotation"]
        path.write_text(json.dumps(head))
        with pytest.raises(ModelError, match="lacks array 'rotation' in toy.npz"):
            read_model(path, {"toy": OptionalToy})
    with pytest.raises(ModelError, match="unknown field"):  # a kind without the optional leaf refuses the null
        read_model(OptionalToy(**{f.name: getattr(_toy(False), f.name) for f in dataclasses.fields(ToyModel)}).save(
            tmp_path / "other"), KINDS)
