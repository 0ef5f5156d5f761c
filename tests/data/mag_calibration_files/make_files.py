"""Write the saved mag_calibration files that tests/test_calibration_files.py loads.

The files are the ones users hold: written by icgo at commit 5e92a81 (``git worktree add <dir> 5e92a81``, then
``<dir>/.venv/bin/python tests/data/mag_calibration_files/make_files.py`` from that worktree). Each model is one
combination of the optional parts (accelerometer fit, axis alignment, non-linear residual), plus one fitted on
the bundled device ``ai`` by the calibrate study; ``expected.npz`` holds the survey they are applied to and what
that build's ``apply`` and ``corrected`` gave, to the bit
(``corrected``: ``[G_c | B_c | B_c without G]``, (N, 9)).
"""

from __future__ import annotations

import dataclasses
import itertools
from pathlib import Path

import jax
import numpy as np

import icgo  # noqa: F401  (float64)
from icgo.artifacts.calibration import mag_calibration
from icgo.io.mag_cal_bundled import load_mag_cal_device
from icgo.models import calibration as cal
from icgo.models import mag_relm
from icgo.physics.frames import sensors_from_attitude
from icgo.studies.calibration import study as cal_study

HERE = Path(__file__).parent
SCALE = 48_000.0  # nT per unit of the fitted (unit-sphere) field


def survey(n=12, seed=3):
    rng = np.random.default_rng(seed)
    A, I, T = rng.uniform(0, 360, n), rng.uniform(5, 175, n), rng.uniform(0, 360, n)
    s = sensors_from_attitude(A, I, T, SCALE, 62.0)
    r = np.eye(3) + rng.normal(0, 0.03, (3, 3))
    G = np.asarray(s.G) * 1.01 + rng.normal(0, 0.002, (n, 3))
    B = np.asarray(cal.distort(r, rng.normal(0, 800, 3), s.B))
    return G, B


def models(G, B):
    rng = np.random.default_rng(7)
    x_mag = np.r_[(np.eye(3) + rng.normal(0, 0.03, (3, 3))).ravel() / SCALE, rng.normal(0, 500, 3)]
    x_accel = np.r_[(np.eye(3) + rng.normal(0, 0.01, (3, 3))).ravel(), rng.normal(0, 0.01, 3)]
    Q = np.linalg.qr(rng.normal(size=(3, 3)))[0]
    Q = Q if np.linalg.det(Q) > 0 else -Q
    hidden = mag_relm.axis_rbf_hidden()
    out = rng.normal(0, 0.01, (hidden.shape[1], 3))
    made = {}
    for accel, aligned, nl in itertools.product((False, True), repeat=3):
        m = mag_calibration("twelve_relm" if nl else "twelve", x_mag, G, B, {"made_by": "make_files.py"},
                            x_accel=x_accel if accel else None, alignment=Q if aligned else None,
                            field_scale_nT=SCALE)
        if nl:
            m = dataclasses.replace(m, nl_hidden=hidden, nl_out=out, nl_activation="gauss")
        made[f"accel{int(accel)}_aligned{int(aligned)}_nl{int(nl)}"] = m
    rec = load_mag_cal_device("ai")
    cfg = cal_study.CalibrationConfig(peer=False, misma_iter=2, misma_repeats=1, misma_pop=6)
    fitted = cal_study.fit_recording(rec.G, rec.B, rec.frame.group.to_numpy(), cfg, jax.random.PRNGKey(0), {})
    made["device_ai_twelve_axis_relm"] = fitted["twelve+axis+relm"]
    made["device_ai_joint"] = fitted["joint"]
    made["device_ai_ellipsoid"] = fitted["ellipsoid"]
    return made


def main():
    import pandas as pd

    G, B = survey()
    frame = pd.DataFrame({"station": np.arange(len(G)), "gx": G[:, 0], "gy": G[:, 1], "gz": G[:, 2],
                          "bx": B[:, 0], "by": B[:, 1], "bz": B[:, 2]})
    expected = {"G": G, "B": B}
    for name, m in models(G, B).items():
        m.save(HERE / name)
        out, field_only = m.apply(frame), m.apply(frame[["bx", "by", "bz"]])
        expected[f"{name}.apply"] = out.to_numpy(np.float64)
        expected[f"{name}.apply_columns"] = np.array(out.columns, dtype=str)
        expected[f"{name}.apply_field_only"] = field_only.to_numpy(np.float64)
        expected[f"{name}.apply_field_only_columns"] = np.array(field_only.columns, dtype=str)
        expected[f"{name}.corrected"] = np.hstack([*m.corrected(G, B), m.corrected(None, B)[1]])
    np.savez_compressed(HERE / "expected.npz", **expected)


if __name__ == "__main__":
    main()
