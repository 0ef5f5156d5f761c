"""The report answers first (missing effect, gap before -> after in %, the truth beside it) and names the robust
outliers it keeps out of the fits (a 7,000 nT spike on one axis, as lab_casing's filter lets through)."""

import jax
import numpy as np

from icgo import discrepancy as D
from icgo.discrepancy.report import answer, truth_effects

jax.config.update("jax_enable_x64", True)

HIDDEN = {"hard_iron": np.array([300.0, -200.0, 150.0])}


def test_answer_first_with_truth_and_outlier():
    st = D.simulate(jax.random.PRNGKey(3), 60, HIDDEN)
    B = st.B.copy()
    B[7, 0] += 7000.0  # a spike the fits must not see
    st = st._replace(B=B)
    res = D.run_workflow(st, D.WorkflowConfig(max_effects=2, k_folds=3))
    assert [o.station for o in res.outliers] == [7] and res.outliers[0].component == "bx"
    assert 5000.0 < res.outliers[0].residual < 7100.0  # the screening fit (least squares) leans a little towards it
    assert res.named == ["hard_iron"] and res.kind == "explained", D.verdict(res)
    # a data set's truth record (nested, as NAME.truth.json) and a plain one read the same
    nested = {"effects": {k: v.tolist() for k, v in HIDDEN.items()}, "casing": None, "mag_noise_nT": 15.0}
    assert truth_effects(nested) == truth_effects(HIDDEN) == {"hard_iron": [300.0, -200.0, 150.0]}
    head = answer(res, nested)
    g0, g1 = res.gaps[0].mag_rms_nT, res.gaps[-1].mag_rms_nT
    assert head[0].startswith("**Answer:** missing: **hard_iron**")
    assert f"{g0:.1f} -> {g1:.1f} nT per axis ({100 * (g1 - g0) / g0:+.0f} %)" in head[0]
    assert "injected (truth): hard_iron: found hard_iron" in head[0]
    assert head[1].startswith("**Then:**") and "station 7 (bx +" in head[1] and "what remains is noise" in head[1]
    md = D.report_markdown(res, "x", nested)
    assert md.splitlines()[2] == head[0]  # the answer right under the title
    assert "Injected (truth): hard_iron = [300.0, -200.0, 150.0]" in md
    # the casing of a data set's truth is what magnetic_body models
    assert "magnetic_body" in truth_effects({"effects": {}, "casing": {"model": "pole_pair", "length_m": 3.0}})
