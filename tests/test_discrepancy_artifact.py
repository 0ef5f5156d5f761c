"""The discrepancy workflow's physics model as an artifact: fit, apply to the stations, save/load bitwise."""

from __future__ import annotations

import jax
import numpy as np
import pandas as pd
import pytest

from icgo.artifacts.registry import load_model
from icgo.studies.registry import get_study

HARD_IRON = np.array([300.0, -200.0, 150.0])  # nT, what icgo.studies.discrepancy.study.example hides


@pytest.fixture(scope="module")
def fitted():
    study = get_study("discrepancy")
    data, cfg = study.example()
    return data.stations, study.run(data, cfg, jax.random.PRNGKey(0))


def test_the_physics_model_recovers_the_hidden_effect_and_corrects_azimuth(fitted):
    st, out = fitted
    m = out.models["discrepancy_model"]
    assert m.effects == ["hard_iron"]
    np.testing.assert_allclose(m.params.effects["hard_iron"], HARD_IRON, atol=15.0)  # noise 15 nT over 60 stations
    frame = pd.DataFrame(np.column_stack([st.G, st.B]), columns=["gx", "gy", "gz", "bx", "by", "bz"])
    got = m.apply(frame)

    def rms(a):
        return float(np.sqrt(np.mean(((a - st.azimuth + 180.0) % 360.0 - 180.0) ** 2)))

    assert rms(got.azimuth_compensated) < 0.2 * rms(got.azimuth_raw)
    np.testing.assert_allclose(got.inclination_compensated, st.inclination, atol=0.2)


def test_predict_is_pure_jit_able(fitted):
    """The family's predict jits whole (the same function up to XLA's fusion) and the model applies it as it is."""
    from icgo.discrepancy import inversion

    st, out = fitted
    m = out.models["discrepancy_model"]
    x = np.column_stack([st.G, st.B])
    eager, jitted = inversion.predict(m.params, x), jax.jit(inversion.predict)(m.params, x)
    frame = pd.DataFrame(x, columns=["gx", "gy", "gz", "bx", "by", "bz"])
    np.testing.assert_array_equal(m.apply(frame)["azimuth_compensated"], np.asarray(eager.azimuth))
    np.testing.assert_allclose(np.asarray(jitted.azimuth), np.asarray(eager.azimuth), rtol=0, atol=1e-9)
    np.testing.assert_allclose(np.asarray(jitted.b_corrected), np.asarray(eager.b_corrected), rtol=0, atol=1e-6)


def test_save_load_apply_is_bitwise(fitted, tmp_path):
    st, out = fitted
    m = out.models["discrepancy_model"]
    frame = pd.DataFrame(np.column_stack([st.G, st.B]), columns=["gx", "gy", "gz", "bx", "by", "bz"])
    pd.testing.assert_frame_equal(m.apply(frame), load_model(m.save(tmp_path / "phys")).apply(frame),
                                  check_exact=True)
    steps = out.records["steps"]
    assert list(steps.effect) == ["hard_iron"] and bool(steps.separable.iloc[0])
    assert steps.heldout_after.iloc[0] < steps.heldout_before.iloc[0]


def test_corrected_field_and_station_qc(fitted):
    # a hard-iron-only model's disturbance is the constant bias: the corrected field is B - bias exactly
    from icgo.artifacts.discrepancy import station_qc
    from icgo.physics.qc import survey_qc

    st, out = fitted
    m = out.models["discrepancy_model"]
    frame = pd.DataFrame(np.column_stack([st.G, st.B]), columns=["gx", "gy", "gz", "bx", "by", "bz"])
    b_after = m.apply(frame)[["bx_corrected", "by_corrected", "bz_corrected"]].to_numpy()
    np.testing.assert_allclose(b_after, st.B - m.params.effects["hard_iron"], rtol=0, atol=1e-6)
    qc = station_qc(m, st)
    F, dip = st.field[0], st.field[1]
    assert qc == {"raw": survey_qc(st.G, st.B, F, dip, st.gravity_g).counts,
                  "physics": survey_qc(st.G, b_after, F, dip, st.gravity_g).counts}
    assert qc["physics"]["b"] < qc["raw"]["b"]
    assert station_qc(m, st._replace(field=None)) is None


def test_a_schema_1_model_is_refused_with_what_to_do(fitted, tmp_path):
    """Schema 1 stored the effects as one flat array: such a file is refused in one line naming it and the refit."""
    import json

    from icgo.core.errors import ModelError

    _, out = fitted
    path = out.models["discrepancy_model"].save(tmp_path / "phys")
    head = json.loads(path.read_text())
    head["schema_version"] = 1
    path.write_text(json.dumps(head))
    says = r"phys\.json: a discrepancy_model file of model schema 1.*experiments\.discrepancy"
    with pytest.raises(ModelError, match=says) as e:
        load_model(path)
    assert "\n" not in str(e.value)
