"""Tests for icgo.datasets.instruments: closed-form fields, casing physics, gyro model, noise, patent frame."""

import numpy as np
import pytest

import icgo  # noqa: F401  (float64)
from icgo.datasets import instruments as ins
from icgo.physics import frames as F


def test_monopole_inverse_square_closed_form():
    b = np.asarray(ins.monopole_field(np.array([[0.0, 0.0, 2.0]]), np.zeros(3), 10.0))
    # mu0/(4 pi) q / r^2 = 1e-7 * 10 / 4 T = 250 nT along +z
    np.testing.assert_allclose(b, [[0.0, 0.0, 250.0]], rtol=1e-12)


def test_dipole_line_uniform_converges_to_pole_pair():
    pts = np.array([[0.3, 1.0, 0.2], [2.0, -1.0, 0.5], [-1.0, 0.5, 1.5]])
    c = ins.Casing(end_ned=(-1.5, 0.0, 0.0), axis_ned=(1.0, 0.0, 0.0))
    pp = np.asarray(ins.casing_field_ned(pts, c))
    dl = np.asarray(ins.casing_field_ned(pts, c._replace(model="dipole_line", n_segments=600)))
    np.testing.assert_allclose(dl, pp, rtol=2e-4, atol=1e-3)


def test_casing_pole_strength_closed_form():
    c = ins.Casing(diameter_m=0.15, wall_m=0.009, magnetization_A_m=1000.0)
    area = np.pi / 4 * (0.15**2 - 0.132**2)
    assert float(ins.casing_pole_strength(c)) == pytest.approx(1000.0 * area, rel=1e-12)


def test_casing_field_full_toolface_turn_constant_in_lab_not_in_tool():
    """Sensor on the roll axis: the casing field is fixed in the lab, so it turns in the tool frame."""
    casing = ins.Casing(end_ned=(-1.5, 1.0, 0.0), axis_ned=(1.0, 0.0, 0.0), magnetization_A_m=8000.0)
    T = np.arange(0.0, 360.0, 5.0)
    A, I = np.full_like(T, 60.0), np.full_like(T, 90.0)
    pos = ins.sensor_positions_ned((0, 0, 0), (0.0, 0.0, 0.15), A, I, T)
    b_lab = np.asarray(ins.casing_field_ned(pos, casing))
    b_tool = np.asarray(F.earth_to_tool_vector(b_lab, A, I, T))
    assert np.ptp(b_lab, axis=0).max() < 1e-9 * np.abs(b_lab).max()
    assert np.ptp(b_tool, axis=0).max() > 0.5 * np.linalg.norm(b_lab[0])
    # |B| is the same in both frames
    np.testing.assert_allclose(np.linalg.norm(b_tool, axis=1), np.linalg.norm(b_lab, axis=1), rtol=1e-12)


def test_off_axis_sensor_sees_casing_gradient():
    """Off the roll axis, the lab-frame field varies over a turn by ~ gradient x 2 offset."""
    casing = ins.Casing(end_ned=(-1.5, 1.0, 0.0), axis_ned=(1.0, 0.0, 0.0), magnetization_A_m=8000.0)
    T = np.arange(0.0, 360.0, 5.0)
    A, I = np.full_like(T, 0.0), np.full_like(T, 90.0)
    r = 0.015
    pos = np.asarray(ins.sensor_positions_ned((0, 0, 0), (r, 0.0, 0.0), A, I, T))
    assert np.allclose(np.linalg.norm(pos, axis=1), r)
    b = np.asarray(ins.casing_field_ned(pos, casing))
    # finite-difference gradient at the origin, along the plane the sensor sweeps (y-z for a north-pointing tool)
    h = 1e-4
    grad = [np.asarray(ins.casing_field_ned(np.array([[0, h, 0], [0, 0, h]]) * s, casing)) for s in (1, -1)]
    g = (grad[0] - grad[1]) / (2 * h)  # rows: d/dy, d/dz
    expected = 2 * r * np.sqrt((g**2).sum(0))  # peak-to-peak of a linear field over a circle of radius r
    np.testing.assert_allclose(np.ptp(b, axis=0), expected, rtol=0.05, atol=0.5)
    assert np.ptp(b, axis=0).max() > 10.0  # nT: not negligible


def test_drill_string_pole_axial_closed_form():
    b = np.asarray(ins.drill_string_field_tool(pole_above_A_m=20.0, distance_above_m=2.0))
    np.testing.assert_allclose(b, [0, 0, 1e-7 * 20 / 4 * 1e9], rtol=1e-12)
    with pytest.raises(ValueError, match="distances"):
        ins.drill_string_field_tool(1.0, 0.0)


def test_gyro_measure_errors():
    W = np.array([[10.0, -5.0, 2.0]])
    G = np.array([[0.1, 0.2, 0.97]])
    np.testing.assert_allclose(ins.gyro_measure(W, G), W, atol=1e-12)
    K = ((0.1, 0.0, 0.2), (0.0, 0.3, 0.0), (0.0, 0.0, 0.0))
    e = ins.GyroErrors(bias_deg_h=(1.0, 2.0, 3.0), g_sensitivity_deg_h_g=K, scale=(0.01, 0.0, 0.0))
    exp = W * np.array([1.01, 1, 1]) + np.array([1.0, 2.0, 3.0]) + G @ np.array(K).T
    np.testing.assert_allclose(ins.gyro_measure(W, G, e), exp, rtol=1e-12)
    with pytest.raises(ValueError, match="3x3"):
        ins.gyro_measure(W, G, ins.GyroErrors(g_sensitivity_deg_h_g=(1.0, 2.0)))


def test_averaged_samples_noise_and_spikes():
    rng = np.random.default_rng(0)
    clean = np.zeros((4000, 3))
    m, spiked = ins.averaged_samples(rng, clean, 8.0, n_samples=16)
    assert np.std(m) == pytest.approx(2.0, rel=0.05)  # sigma / sqrt(n)
    assert not spiked.any()
    m, spiked = ins.averaged_samples(rng, clean, 0.0, n_samples=8, spike_prob=0.01, spike_scale=800.0)
    assert 0 < spiked.sum() < 4000
    big = np.abs(m).max(1) >= 800 * 0.5 / 8 - 1e-9
    assert np.all(spiked[big])  # every large mean comes from a spike
    assert big.sum() >= 0.9 * spiked.sum()  # (two opposite spikes on one axis may cancel)
    with pytest.raises(ValueError, match="n_samples"):
        ins.averaged_samples(rng, clean, 1.0, n_samples=0)


def test_patent_attitude_in_our_frame_roundtrip():
    rng = np.random.default_rng(1)
    A, I, T = rng.uniform(0, 360, 200), rng.uniform(1, 80, 200), rng.uniform(0, 360, 200)
    s = F.sensors_from_attitude(A, I, T, latitude_deg=40.0)
    W, G = np.asarray(s.W), np.asarray(s.G)
    a, i, t = ins.patent_attitude_in_our_frame(W[:, 0], W[:, 1], G[:, 0], G[:, 1], 40.0)
    np.testing.assert_allclose(np.asarray(F.angle_diff(a, A)), 0, atol=1e-9)
    np.testing.assert_allclose(i, I, atol=1e-9)
    np.testing.assert_allclose(np.asarray(F.angle_diff(t, T)), 0, atol=1e-9)
    # the same (x, y) readings are the patent's eq. (3)-(4) at A - 90, T + 180
    w_p, a_p = F.patent_sensors(A - 90.0, I, T + 180.0, 40.0)
    np.testing.assert_allclose(np.asarray(w_p)[:, :2], W[:, :2], atol=1e-9)
    np.testing.assert_allclose(np.asarray(a_p)[:, :2], G[:, :2], atol=1e-12)


def test_bad_casing_inputs():
    with pytest.raises(ValueError, match="model"):
        ins.casing_field_ned(np.zeros((1, 3)) + 1, ins.Casing(model="cylinder"))
    with pytest.raises(ValueError, match="wall"):
        ins.casing_pole_strength(ins.Casing(wall_m=0.2))
    with pytest.raises(ValueError, match="profile"):
        ins.casing_field_ned(np.ones((1, 3)), ins.Casing(model="dipole_line", n_segments=4, profile=(1.0, 1.0)))


def test_casing_at_distance_moves_the_axis_line_sideways_only():
    lab = ins.Casing(end_ned=(-1.5, 1.0, 0.0), axis_ned=(1.0, 0.0, 0.0))
    assert ins.casing_at_distance(lab, 1.0).end_ned == pytest.approx(lab.end_ned)
    assert ins.casing_at_distance(lab, 0.5).end_ned == pytest.approx((-1.5, 0.5, 0.0))
    # a tilted, skew casing: the shortest distance between its axis line and the vertical axis becomes 2 m
    # (checked by minimising over both lines' parameters), moving horizontally; everything else is kept
    from scipy.optimize import minimize

    skew = ins.Casing(end_ned=(0.3, -0.8, 0.4), axis_ned=(1.0, 1.0, 0.5), magnetization_A_m=5000.0)
    moved = ins.casing_at_distance(skew, 2.0)

    def gap(c):
        e, a = np.asarray(c.end_ned), np.asarray(c.axis_ned)
        return minimize(lambda st: np.linalg.norm(e + st[0] * a - np.array([0.0, 0.0, st[1]])), [0.0, 0.0],
                        method="Nelder-Mead", options={"xatol": 1e-10, "fatol": 1e-12}).fun

    assert gap(moved) == pytest.approx(2.0, abs=1e-6) and gap(skew) != pytest.approx(2.0, abs=1e-2)
    assert moved.end_ned[2] == skew.end_ned[2]
    assert moved._replace(end_ned=skew.end_ned) == skew
    vertical = ins.Casing(end_ned=(3.0, 4.0, -1.0), axis_ned=(0.0, 0.0, 1.0))
    assert ins.casing_at_distance(vertical, 10.0).end_ned == pytest.approx((6.0, 8.0, -1.0))
    with pytest.raises(ValueError, match="must be > 0"):
        ins.casing_at_distance(lab, 0.0)
    with pytest.raises(ValueError, match="meets the vertical axis"):
        ins.casing_at_distance(ins.Casing(end_ned=(0.0, 0.0, 1.0), axis_ned=(0.0, 0.0, 1.0)), 1.0)
