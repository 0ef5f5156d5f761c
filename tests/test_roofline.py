"""icgo/bench/roofline.py: the flop and byte counts by hand, and one small run (no timing is tested)."""

import json

import pytest
from conftest import relm_train_data

from icgo.bench import roofline
from icgo.models import relm


def test_stage_counts_match_hand_count():
    # n=10, d1=7, L=2, C=1, refine=1, float64 features (s=8)
    c = roofline.stage_counts(10, 7, 2, 1, 1, 8)
    assert list(c) == list(roofline.STAGES)
    assert c["pre-activation"] == (280, 8 * 7 * 2 + 8 * 10 * 2 + 8 * 10 * 7)   # 2 n d1 L; theta, Z, Xa
    assert c["sigmoid"] == (80, 320)                                            # 4 n L; read Z, write H
    assert c["centring + Gram"] == (80 + 80 + 8, 160 + 80 + 48)                 # 2nL^2 + 4nL + 2L^2
    assert c["Cholesky + solve"] == pytest.approx((8 / 3 + 8 + 2, 96))          # L^3/3 + 2L^2 + L
    assert c["refinement"] == (80 + 10 + 8 + 6, 160 + 80 + 64)                  # 4nL + n + 2L^2 + 3L
    assert c["final RMSE"] == (40 + 30 + 2, 160 + 80 + 16)                     # 2nL + 3n + 2
    # float32 features halve the bytes of H, not the flops
    c32 = roofline.stage_counts(10, 7, 2, 1, 1, 4)
    assert c32["sigmoid"] == (80, 160) and c32["centring + Gram"][0] == c["centring + Gram"][0]


def test_roofline_at_the_study_shape_with_one_chunk_reports_every_stage():
    """About the study's shape (~400 training rows, L = 30, chunks of 10), one chunk per call: every stage, both
    feature dtypes, positive times, sane fractions (at much smaller shapes a call's fixed cost swamps the rates)."""
    _, _, mask, _, fit = relm_train_data(n=580, hidden=30)
    rows = relm.train_rows(fit, int(mask.sum()))
    res = roofline.measure(rows, hidden=30, lam=1e-3, batch=10, chunk=10, refine=2, reps=2)
    res = json.loads(json.dumps(res))  # what the module prints is JSON
    assert set(res["rates"]) == {"gemm_L_float64"} | {f"{k}_{fd}" for k in ("gemm_d1", "gemm_n", "stream", "numpy_copy")
                                                        for fd in roofline.FEATURE_DTYPES}
    assert all(v > 0 for v in res["rates"].values())
    for fd in roofline.FEATURE_DTYPES:
        stages = res[fd]["stages"]
        assert list(stages) == list(roofline.STAGES)
        for v in stages.values():
            assert v["time_us"] > 0 and v["ceiling_us"] > 0 and 0 < v["fraction"] <= 5
            assert v["bound"] in ("compute", "memory")
        assert 0 < res[fd]["kernel_fraction"] <= 5 and res[fd]["kernel_us"] > 0
    assert res["f32_speedup"] > 0
    assert roofline.table(res).count("\n") == 2 + 2 * (len(roofline.STAGES) + 1) - 1


def test_kernel_ab_specs_and_a_small_run():
    """--ab: specs parsed or refused in one line; a variant equal to the first is bitwise it, every variant within
    the search kernel's 5e-6 of the float64 fitness at refine >= 1 (no timing is tested)."""
    from icgo.bench import kernel_ab

    assert kernel_ab.parse_spec("base") == {} and kernel_ab.parse_spec("chunk=5, refine=1") == {"chunk": 5, "refine": 1}
    for bad, what in (("chunks=5", "not name=value"), ("refine=one", "is not a int"), ("chunk", "not name=value")):
        with pytest.raises(ValueError, match=what):
            kernel_ab.parse_spec(bad)
    res = kernel_ab.run(["base", "chunk=10,refine=2", "refine=1"], members=2, batch=20, rounds=1)
    v = {x["spec"]: x for x in res["variants"]}
    assert v["chunk=10,refine=2"]["bitwise"] and v["base"]["ratio"] == 1.0
    assert all(x["max_rel_vs_float64"] < 5e-6 and x["evals_per_cpu_s"] > 0 for x in res["variants"])
    assert "| `refine=1` |" in kernel_ab.table(res)
