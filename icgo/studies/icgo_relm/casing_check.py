"""Cross-check of the casing model against an established magnetics library (the casing sweeps,
``experiment=sweep_casing*``): :func:`compare`, its report :func:`markdown` and :func:`write_results`
(``results/casing_model_check.{md,csv}``, written by ``python -m experiments.casing_check``).

icgo models the lab casing (ICGO 3.1: a 3 m steel tube, 150 mm outer diameter,
axially magnetised, 1 m from the instrument) as a pair of magnetic poles at its
ends (:func:`icgo.datasets.instruments.casing_field_ned`, ``model="pole_pair"``) or as a
line of point dipoles (``"dipole_line"``). magpylib computes the field of the
tube itself in closed form (``magpylib.magnet.CylinderSegment`` over 360 deg,
uniform axial polarisation J = mu0 M). For a uniformly magnetised tube the
exterior field is exactly that of the two end annuli's surface charges, so the
pole pair differs from the tube only by the annuli's size (relative difference of
order (radius / distance)^2) and the comparison says how far that matters at the
lab's geometry: at every station of ``lab_casing`` (its sensor positions) with
the casing moved to 0.5, 0.75, 1, 1.5 and 2 m from the turntable axis (the
distances of the noise-and-interference sweep).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

#: Casing distances from the turntable axis (m): the sweep's values; the paper's lab is 1 m.
DISTANCES_M = (0.5, 0.75, 1.0, 1.5, 2.0)
MU0 = 4e-7 * np.pi  # T m / A


def magpylib_tube_field(points_ned, casing) -> np.ndarray:
    """Field of the casing as a magnetised tube by magpylib, NED (nT).

    Args:
        points_ned: (N, 3) positions (m). casing: :class:`icgo.datasets.instruments.Casing`.
    Returns:
        (N, 3) field (nT). magpylib works in any right-handed Cartesian frame, so NED in, NED out.
    """
    import magpylib as magpy
    from scipy.spatial.transform import Rotation

    ax = np.asarray(casing.axis_ned, float)
    ax = ax / np.linalg.norm(ax)
    centre = np.asarray(casing.end_ned, float) + 0.5 * casing.length_m * ax
    r_out = 0.5 * casing.diameter_m
    tube = magpy.magnet.CylinderSegment(dimension=(r_out - casing.wall_m, r_out, casing.length_m, 0.0, 360.0),
                                        polarization=(0.0, 0.0, MU0 * casing.magnetization_A_m), position=centre,
                                        orientation=Rotation.align_vectors([ax], [[0.0, 0.0, 1.0]])[0])
    points = np.asarray(points_ned, float).reshape(-1, 3)
    return np.asarray(tube.getB(points)).reshape(points.shape) * 1e9  # getB squeezes a single point


def compare(seed: int = 0, distances=DISTANCES_M) -> pd.DataFrame:
    """Pole pair and dipole line against magpylib's tube at every lab_casing station, per casing distance.

    Returns:
        One row per (distance, model): the largest and median relative difference of
        the field vector, the largest difference (nT) and the casing field's median size (nT).
    """
    from icgo.datasets import casing_stations
    from icgo.datasets import instruments as ins

    ds = casing_stations.lab_casing(seed)
    t, f = ds.truth, ds.frame
    pos = np.asarray(ins.sensor_positions_ned(np.asarray(t["pivot_ned_m"]), np.asarray(t["sensor_lever_tool_m"]),
                                              f["azimuth_deg"].to_numpy(), f["inclination_deg"].to_numpy(),
                                              f["toolface_deg"].to_numpy()))
    base = casing_stations.LAB_CASING
    rows = []
    for d in distances:
        casing = ins.casing_at_distance(base, float(d))
        ref = magpylib_tube_field(pos, casing)
        size = np.linalg.norm(ref, axis=1)
        for model in ("pole_pair", "dipole_line"):
            got = np.asarray(ins.casing_field_ned(pos, casing._replace(model=model)))
            diff = np.linalg.norm(got - ref, axis=1)
            rows.append({"distance_m": d, "model": model, "max_rel_diff": float((diff / size).max()),
                         "median_rel_diff": float(np.median(diff / size)), "max_diff_nT": float(diff.max()),
                         "median_field_nT": float(np.median(size)), "n_stations": len(pos)})
    return pd.DataFrame(rows)


def markdown(df: pd.DataFrame, seed: int = 0) -> list[str]:
    """The lines of casing_model_check.md for the :func:`compare` table ``df`` (lab_casing drawn with ``seed``)."""
    import magpylib

    from icgo.datasets import casing_stations
    from icgo.reporting.protocol import protocol_line, settings_line

    noise = float(casing_stations.lab_casing(seed).truth["mag_noise_nT"])
    at_lab = df[(df.distance_m == 1.0) & (df.model == "pole_pair")].iloc[0]
    return ["# Casing model cross-check: icgo's pole pair vs magpylib's magnetised tube", "",
            protocol_line("`python -m experiments.casing_check`", "1 (deterministic fields, no noise)",
                          "none: the two models' fields at the same sensor positions",
                          "the station positions of lab_casing(seed 0)", "none: a deterministic comparison"), "",
            settings_line("no search or fit (closed-form fields)", "one evaluation per position", "float64",
                          "No published protocol: the paper gives the casing's size and distance, not its field."), "",
            "`python -m experiments.casing_check` (magpylib "
            f"{magpylib.__version__}). Field of the lab casing (3 m x 150 mm tube, wall 9 mm, "
            f"M = {casing_stations.LAB_CASING.magnetization_A_m:g} A/m axial) at every lab_casing station "
            f"({int(at_lab.n_stations)} sensor positions), the casing moved to each distance from the turntable axis.",
            "", df.to_markdown(index=False, floatfmt=".4g"), "",
            f"At the paper's 1 m the pole pair differs from the tube by at most {at_lab.max_rel_diff:.2%} of the "
            f"casing field ({at_lab.max_diff_nT:.1f} nT, against a per-sample magnetometer noise of {noise:g} nT), "
            "because a uniformly magnetised tube's exterior field is that of its two end annuli and the annuli are "
            "small beside the distance. The pole pair stays the default (`icgo.datasets.instruments.Casing.model`); "
            "the difference grows as the casing comes closer (see the 0.5 m rows)."]


def write_results(df: pd.DataFrame, lines: list[str], stage: Path) -> None:
    """casing_model_check.csv (the :func:`compare` table) and casing_model_check.md (``lines``) into ``stage``."""
    df.to_csv(stage / "casing_model_check.csv", index=False)
    (stage / "casing_model_check.md").write_text("\n".join(lines) + "\n")
