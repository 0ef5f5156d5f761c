"""Property-based tests (Hypothesis) of the data contract's readers and the study configs (issue 19, item 7).

* Valid recordings, generated, round-trip through ``write_recording`` / ``read_recording`` exactly.
* Malformed CSVs (valid ones with bytes cut, replaced or inserted) and arbitrary JSON metadata end
  in :class:`icgo.core.errors.DataError` with one line, or read; never another exception.
* Arbitrary values for the study settings end in a one-line ``SettingError`` or a valid config.

The fast suite runs a bounded number of examples (``FAST``); ``make test-all`` runs the
``slow`` variants with many more.
"""

from __future__ import annotations

import json
import re
import math

import numpy as np
import pandas as pd
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import icgo  # noqa: F401
from icgo.core.errors import DataError, SettingError
from icgo.io import csv_text
from icgo.io import recording as io
from icgo.studies.icgo_relm.config import StudyConfig

# The fast suite is derandomized (the same examples every run: CI stays deterministic); the long
# runs of make test-all draw new examples each time, to find what the fixed ones miss.
FAST = settings(max_examples=40, deadline=None, derandomize=True,
                suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
LONG = settings(max_examples=1500, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture,
                                                                         HealthCheck.too_slow])


def _unit(v):
    v = np.asarray(v, float)
    return v / np.linalg.norm(v)


@st.composite
def recordings(draw):
    """A valid contract frame: G near 1 g, B near the earth's field in nT, the reference attitude."""
    n = draw(st.integers(1, 12))
    direction = st.tuples(*[st.floats(-1, 1, allow_nan=False)] * 3).filter(lambda v: math.hypot(*v) > 0.1)
    rows = []
    for i in range(n):
        g = _unit(draw(direction)) * draw(st.floats(0.95, 1.05))
        b = _unit(draw(direction)) * draw(st.floats(30_000.0, 65_000.0))
        rows.append({"station": i + draw(st.integers(0, 5)) * 100, "gx": g[0], "gy": g[1], "gz": g[2],
                     "bx": b[0], "by": b[1], "bz": b[2],
                     "azimuth_deg": draw(st.floats(0.0, 359.999, allow_nan=False)),
                     "inclination_deg": draw(st.floats(0.0, 180.0, allow_nan=False))})
    frame = pd.DataFrame(rows).drop_duplicates("station")
    meta = draw(st.one_of(st.just({}), st.fixed_dictionaries({
        "total_field_nT": st.floats(30_000.0, 65_000.0), "dip_deg": st.floats(-89.0, 89.0)})))
    return frame, meta


def _round_trip(tmp_path, frame, meta):
    path = tmp_path / "rec.csv"
    io.write_recording(path, frame, meta)
    back = io.read_recording(path)
    cols = list(frame.columns)
    pd.testing.assert_frame_equal(back.frame[cols].reset_index(drop=True), frame.reset_index(drop=True)[cols],
                                  check_dtype=False, check_exact=True)
    assert back.meta == meta


@FAST
@given(recordings())
def test_valid_recordings_round_trip_exactly(tmp_path_factory, rec):
    _round_trip(tmp_path_factory.mktemp("rt"), *rec)


def _mutated_text(draw, text):
    ops = draw(st.lists(st.tuples(st.sampled_from(["cut", "replace", "insert", "truncate"]),
                                  st.integers(0, max(len(text) - 1, 0)),
                                  st.text(alphabet=st.sampled_from(list(",.-e+\n\r\"x0123456789 naif\x00")),
                                          min_size=1, max_size=6)), min_size=1, max_size=4))
    for op, i, s in ops:
        i = min(i, len(text))
        if op == "cut":
            text = text[:i] + text[i + len(s):]
        elif op == "replace":
            text = text[:i] + s + text[i + len(s):]
        elif op == "insert":
            text = text[:i] + s + text[i:]
        else:
            text = text[:i]
    return text


def _read_or_one_line_error(path):
    try:
        io.read_recording(path, require_meta=False)
    except DataError as e:
        msg = str(e)
        assert msg and "\n" not in msg, msg
        assert path.name in msg or io.meta_path_for(path).name in msg, msg  # names the file at fault


def _check_mutated_csvs(tmp_path_factory, data):
    frame, meta = data.draw(recordings())
    d = tmp_path_factory.mktemp("fz")
    path = d / "rec.csv"
    io.write_recording(path, frame, meta)
    path.write_text(_mutated_text(data.draw, path.read_text()))
    _read_or_one_line_error(path)


@FAST
@given(st.data())
def test_mutated_csvs_read_or_fail_in_one_line(tmp_path_factory, data):
    _check_mutated_csvs(tmp_path_factory, data)


@pytest.mark.slow
@LONG
@given(st.data())
def test_mutated_csvs_read_or_fail_in_one_line_long(tmp_path_factory, data):
    _check_mutated_csvs(tmp_path_factory, data)


def _check_fast_reader_is_exact(data):
    """The pandas fast path of read_recording returns a frame only when the exact (csv module) reader
    returns the same frame and notices; where the exact reader refuses the text, the fast one declines."""
    frame, _ = data.draw(recordings())
    extra = data.draw(st.sampled_from(["none", "number", "text", "mixed"]))
    if extra == "number":
        frame = frame.assign(temperature_x=np.arange(len(frame)) * 0.5)
    elif extra == "text":
        frame = frame.assign(operator="jd")
    elif extra == "mixed":
        frame = frame.assign(operator=[f"{i}.5" if i % 2 else "x" for i in range(len(frame))])
    text = _mutated_text(data.draw, frame.to_csv(index=False, lineterminator="\n"))
    text = text.replace("\r\n", "\n").replace("\r", "\n")  # what read_text's universal newlines leave
    if not text.strip():
        return
    fast_notes, exact_notes = [], []
    fast = csv_text._read_fast(text, "f.csv", fast_notes, True)
    try:
        exact = csv_text._read_exact(text, "f.csv", exact_notes, True)
    except DataError:
        assert fast is None
        return
    if fast is not None:
        pd.testing.assert_frame_equal(fast, exact, check_exact=True)
        assert fast_notes == exact_notes


@FAST
@given(st.data())
def test_fast_reader_equals_the_exact_reader(data):
    _check_fast_reader_is_exact(data)


@pytest.mark.slow
@LONG
@given(st.data())
def test_fast_reader_equals_the_exact_reader_long(data):
    _check_fast_reader_is_exact(data)


JSON = st.recursive(st.none() | st.booleans() | st.integers() | st.floats() | st.text(max_size=8),
                    lambda kids: st.lists(kids, max_size=4) | st.dictionaries(st.text(max_size=8), kids, max_size=4),
                    max_leaves=12)
META_KEYS = st.sampled_from(["total_field_nT", "dip_deg", "declination_deg", "latitude", "gravity_g", "date",
                             "name", "units", "x"])


def _check_metadata(tmp_path_factory, rec, meta):
    frame, _ = rec
    d = tmp_path_factory.mktemp("meta")
    path = d / "rec.csv"
    io.write_recording(path, frame, {})
    (d / "rec.meta.json").write_text(json.dumps(meta, allow_nan=True))
    _read_or_one_line_error(path)


@FAST
@given(recordings(), st.one_of(JSON, st.dictionaries(META_KEYS, JSON, max_size=5)))
def test_arbitrary_metadata_reads_or_fails_in_one_line(tmp_path_factory, rec, meta):
    _check_metadata(tmp_path_factory, rec, meta)


@pytest.mark.slow
@LONG
@given(recordings(), st.one_of(JSON, st.dictionaries(META_KEYS, JSON, max_size=5)))
def test_arbitrary_metadata_reads_or_fails_in_one_line_long(tmp_path_factory, rec, meta):
    _check_metadata(tmp_path_factory, rec, meta)


SETTING_VALUES = st.one_of(st.none(), st.booleans(), st.integers(-10**6, 10**6), st.floats(), st.text(max_size=6),
                           st.lists(st.floats(), max_size=3))
FIELDS = st.sampled_from(["split.n_repeats", "split.seed", "split.train_fraction", "split.sigma_filter",
                          "msa.iterations", "model.hidden", "model.lam", "fitness.mode", "fitness.val_fraction",
                          "fitness.k_folds", "model.theta_bounds", "budget.pop_size", "budget.iterations", "precision",
                          "split.protocol", "model.features", "msa.model", "model.tune", "strategies"])


def _check_settings(values):
    nested: dict = {}
    for key, v in values.items():  # "model.lam" -> {"model": {"lam": v}}
        node, _, name = key.rpartition(".")
        (nested.setdefault(node, {}) if node else nested)[name] = v
    try:
        StudyConfig(**nested)
    except SettingError as e:
        msg = str(e)
        assert "\n" not in msg and e.field in msg, msg


@FAST
@given(st.dictionaries(FIELDS, SETTING_VALUES, min_size=1, max_size=3))
def test_study_settings_are_valid_or_one_line_setting_errors(values):
    _check_settings(values)


def test_a_list_where_a_name_belongs_is_a_setting_error():
    """Found by Hypothesis in a CI run: ``msa.model=[1.0]`` raised TypeError (unhashable) instead of one line."""
    with pytest.raises(SettingError, match="msa.model must be one of"):
        StudyConfig(msa=dict(model=[1.0]))


@pytest.mark.slow
@LONG
@given(st.dictionaries(FIELDS, SETTING_VALUES, min_size=1, max_size=3))
def test_study_settings_are_valid_or_one_line_setting_errors_long(values):
    _check_settings(values)


# ---------------------------------------------------------------- model files and the JSON layouts
# Hostile edits of saved models (every kind, tests/hostile_models.py): a header value replaced by an arbitrary
# JSON value, an array replaced by an arbitrary array (any dtype, shape, NaN/inf/huge). Loading ends in a model
# or one ModelError line naming the file; a model that loads corrects the survey with finite azimuths, or says
# in one IcgoError line why not. Never another exception.
import sys as _sys  # noqa: E402
from pathlib import Path as _Path  # noqa: E402

from hypothesis.extra import numpy as hnp  # noqa: E402

_sys.path.insert(0, str(_Path(__file__).resolve().parent))
import hostile_models  # noqa: E402

from icgo.core.errors import IcgoError, ModelError  # noqa: E402
from icgo.artifacts.registry import load_model  # noqa: E402
from icgo.survey.apply import correct_survey  # noqa: E402

_MODELS = hostile_models.models()
_SURVEY = hostile_models.survey()
HEADER_PATHS = st.one_of(
    st.sampled_from([("kind",), ("schema_version",), ("arrays",), ("fields",), ("array_shapes",), ("units",)]),
    st.sampled_from(sorted(_MODELS)).flatmap(lambda k: st.sampled_from(
        [("fields", f) for f in _MODELS[k].header()["fields"]]
        + [("fields", "domain", d) for d in _MODELS[k].domain] + [("array_shapes", a) for a in
                                                                  _MODELS[k].header()["array_names"]])))
ARRAYS = hnp.arrays(dtype=st.one_of(hnp.floating_dtypes(), hnp.integer_dtypes(), hnp.complex_number_dtypes(),
                                    hnp.boolean_dtypes(), hnp.unicode_string_dtypes(max_len=3)),
                    shape=hnp.array_shapes(min_dims=0, max_dims=3, min_side=0, max_side=5))


def _load_and_apply(path):
    try:
        model = load_model(path)
    except ModelError as e:
        msg = str(e)
        assert msg and "\n" not in msg, msg
        assert _Path(path).stem in msg, msg  # names the file at fault
        return
    try:
        res = correct_survey(model, _SURVEY)
    except IcgoError as e:
        assert "\n" not in str(e), str(e)
        return
    assert np.isfinite(res.table["azimuth_compensated"].to_numpy(float)).all()


def _check_header_edit(tmp_path_factory, kind, path, value):
    d = tmp_path_factory.mktemp("mh")
    p = _MODELS[kind].save(d / "m")
    head = json.loads(p.read_text())
    node = head
    for key in path[:-1]:
        node = node.get(key) if isinstance(node, dict) else None
        if not isinstance(node, dict):
            return
    node[path[-1]] = value
    p.write_text(json.dumps(head, allow_nan=True))
    _load_and_apply(p)


def _check_array_edit(tmp_path_factory, kind, data):
    d = tmp_path_factory.mktemp("ma")
    p = _MODELS[kind].save(d / "m")
    with np.load(d / "m.npz") as z:
        arrays = {k: z[k] for k in z.files}
    name = data.draw(st.sampled_from(sorted(arrays)))
    factor = data.draw(st.sampled_from([np.nan, np.inf, 1e300, -1.0, 0.0, 1.0]))
    with np.errstate(all="ignore"):  # inf * 0 is NaN: wanted
        scaled = arrays[name] * factor
    arrays[name] = data.draw(st.one_of(ARRAYS, st.just(scaled)))
    with open(d / "m.npz", "wb") as fh:
        np.savez(fh, **arrays)
    _load_and_apply(p)


@FAST
@given(st.sampled_from(sorted(_MODELS)), HEADER_PATHS, JSON)
def test_edited_model_headers_load_or_fail_in_one_line(tmp_path_factory, kind, path, value):
    _check_header_edit(tmp_path_factory, kind, path, value)


@FAST
@given(st.sampled_from(sorted(_MODELS)), st.data())
def test_edited_model_arrays_load_or_fail_in_one_line(tmp_path_factory, kind, data):
    _check_array_edit(tmp_path_factory, kind, data)


@pytest.mark.slow
@LONG
@given(st.sampled_from(sorted(_MODELS)), HEADER_PATHS, JSON)
def test_edited_model_headers_load_or_fail_in_one_line_long(tmp_path_factory, kind, path, value):
    _check_header_edit(tmp_path_factory, kind, path, value)


@pytest.mark.slow
@LONG
@given(st.sampled_from(sorted(_MODELS)), st.data())
def test_edited_model_arrays_load_or_fail_in_one_line_long(tmp_path_factory, kind, data):
    _check_array_edit(tmp_path_factory, kind, data)


TRIPLE = st.one_of(st.lists(st.one_of(st.floats(), st.integers(-10**6, 10**6), st.none(), st.text(max_size=2),
                                      st.booleans()), min_size=0, max_size=4),
                   st.tuples(st.floats(-100, 100), st.floats(-100, 100), st.floats(-100, 100)).map(list))
LAYOUTS = st.one_of(
    JSON,
    st.fixed_dictionaries({"mag": st.lists(TRIPLE, max_size=30), "grav": st.lists(TRIPLE, max_size=30)},
                          optional={"mag_axes": JSON | st.sampled_from(["+x+y+z", "-y+x+z", "+X-Z+Y"]),
                                    "grav_axes": JSON | st.sampled_from(["+x+y+z", "+z+z+z"]), "name": JSON}),
    st.fixed_dictionaries({"shots": st.fixed_dictionaries({
        "mag": st.lists(st.one_of(st.floats(), st.none(), st.integers(), st.text(max_size=2)), max_size=80),
        "grav": st.lists(st.one_of(st.floats(), st.none(), st.integers()), max_size=80)})}))


def _check_layout(tmp_path_factory, doc):
    """The whole reading of a shots file (the layout, the groups, the search of the data where no layout is known)."""
    from icgo.studies.common.shots import read_shots

    d = tmp_path_factory.mktemp("js")
    p = d / "dev.json"
    p.write_text(json.dumps(doc, allow_nan=True))
    try:
        rec = read_shots(p)
    except DataError as e:
        assert str(e) and "\n" not in str(e) and "dev.json" in str(e), str(e)
        return
    assert np.isfinite(rec.frame[["gx", "gy", "gz", "bx", "by", "bz"]].to_numpy(float)).all()


def _device_doc():
    from icgo.io.mag_cal_bundled import MAG_CAL_DEVICE_TO_TOOL, load_mag_cal_device

    rec = load_mag_cal_device("ab")
    inv = np.argsort(MAG_CAL_DEVICE_TO_TOOL)
    return {"mag": (rec.B[:, inv] / 1000.0).tolist(), "grav": rec.G[:, inv].tolist()}


_DEVICE = _device_doc()
#: One value of a real 24-shot recording replaced by a hostile but finite number (1e300 hung the roll search).
HOSTILE_VALUE = st.tuples(st.sampled_from(["mag", "grav"]), st.integers(0, 23), st.integers(0, 2),
                          st.one_of(st.floats(allow_nan=False, allow_infinity=False, min_value=1e6),
                                    st.floats(allow_nan=False, allow_infinity=False, max_value=-1e6),
                                    st.floats(min_value=-1e-6, max_value=1e-6), st.just(1e300), st.just(-1e308)))


def _check_hostile_value(tmp_path_factory, edit):
    import time

    from icgo.studies.common.shots import read_shots

    key, shot, axis, value = edit
    doc = json.loads(json.dumps(_DEVICE))
    doc[key][shot][axis] = value
    d = tmp_path_factory.mktemp("hv")
    p = d / "dev.json"
    p.write_text(json.dumps(doc))
    t0 = time.perf_counter()
    try:
        rec = read_shots(p, mag_axes="+x+y+z")
    except DataError as e:
        msg = str(e)
        assert "\n" not in msg and "dev.json" in msg, msg
        assert not re.search(r"\b(inf|nan)\b", msg, re.I), msg  # say what is wrong, not a non-number
        assert time.perf_counter() - t0 < 30.0, "the refusal took too long (a check after a heavy computation?)"
        return
    assert np.isfinite(rec.frame[["gx", "gy", "gz", "bx", "by", "bz"]].to_numpy(float)).all()


@FAST
@given(HOSTILE_VALUE)
def test_a_hostile_value_in_a_real_recording_is_refused_first_and_in_words(tmp_path_factory, edit):
    _check_hostile_value(tmp_path_factory, edit)


@pytest.mark.slow
@LONG
@given(HOSTILE_VALUE)
def test_a_hostile_value_in_a_real_recording_is_refused_first_and_in_words_long(tmp_path_factory, edit):
    _check_hostile_value(tmp_path_factory, edit)


@FAST
@given(LAYOUTS)
def test_mag_cal_json_layouts_read_or_fail_in_one_line(tmp_path_factory, doc):
    _check_layout(tmp_path_factory, doc)


@pytest.mark.slow
@LONG
@given(LAYOUTS)
def test_mag_cal_json_layouts_read_or_fail_in_one_line_long(tmp_path_factory, doc):
    _check_layout(tmp_path_factory, doc)
