"""Coordinated-turn model (tracking/coordinated_turn.py) against independent computations:
the exact circular arc of a turning aircraft, and Φ, Q of the continuous model by Van
Loan's method (scipy expm), not the closed forms of the module."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.linalg import expm

from radar_fusion.tracking.coordinated_turn import (
    BankedTurnModel,
    CoordinatedTurnModel,
    ct_matrices_into,
    ct_noise_4d,
    ct_process_noise,
    ct_transition,
    ct_transition_4d,
    lift_cov,
    lift_rows,
)

SUB = [0, 1, 3, 4]  # x, vx, y, vy of the state [x, vx, ax, y, vy, ay]


def van_loan_ct(omega_rad_s: float, q_m2_s3: float, dt_s: float) -> tuple[np.ndarray, np.ndarray]:
    """F, Q (4×4, [x, vx, y, vy]) of d/dt [x, vx, y, vy] = [vx, −ω vy, vy, ω vx] + white
    acceleration q on each axis: expm([[−A, GqGᵀ], [0, Aᵀ]]·T) = [[·, F⁻¹Q], [0, Fᵀ]]."""
    A = np.zeros((4, 4))
    A[0, 1] = A[2, 3] = 1.0
    A[1, 3], A[3, 1] = -omega_rad_s, omega_rad_s
    gqg = np.diag([0.0, q_m2_s3, 0.0, q_m2_s3])
    big = np.zeros((8, 8))
    big[:4, :4], big[:4, 4:], big[4:, 4:] = -A, gqg, A.T
    e = expm(big * dt_s)
    F = e[4:, 4:].T
    return F, F @ e[:4, 4:]


@pytest.mark.parametrize("rate_deg_s", [3.0, -3.0, 1.5, 1e-5])
@pytest.mark.parametrize("dt_s", [4.0, 0.25, 1e-3, 12.0])
def test_transition_and_noise_equal_van_loan(rate_deg_s: float, dt_s: float) -> None:
    m = CoordinatedTurnModel(rate_deg_s, 2.0)
    F, Q = van_loan_ct(m.turn_rate_rad_s, 2.0, dt_s)
    np.testing.assert_allclose(m.transition(dt_s)[0][np.ix_(SUB, SUB)], F, rtol=1e-10, atol=1e-10)
    np.testing.assert_allclose(m.process_noise(dt_s)[0][np.ix_(SUB, SUB)], Q, rtol=1e-9, atol=1e-12 * dt_s**3)
    # the acceleration rows are the turn's centripetal acceleration of the predicted velocity
    phi = m.transition(dt_s)[0]
    w = m.turn_rate_rad_s
    np.testing.assert_allclose(phi[2], -w * phi[4], atol=1e-15)
    np.testing.assert_allclose(phi[5], w * phi[1], atol=1e-15)
    Q6 = m.process_noise(dt_s)[0]
    assert np.all(np.linalg.eigvalsh(Q6) > -1e-9 * np.abs(Q6).max())


def test_prediction_follows_the_exact_arc_of_a_right_turn() -> None:
    """An aircraft heading north at 200 m/s turning right at 3°/s: after T it is on the
    circle of radius v/ω centred east of it, its heading 3·T degrees."""
    v, rate = 200.0, 3.0
    w = math.radians(rate)
    radius = v / w
    m = CoordinatedTurnModel(rate, 0.0)
    x0 = np.array([[0.0, 0.0, 0.0, 0.0, v, 0.0]])
    for T in (1.0, 4.0, 30.0, 60.0):
        x, P = m.predict(x0, np.zeros((1, 6, 6)), T)
        heading = w * T  # clockwise from north
        assert x[0, 0] == pytest.approx(radius * (1.0 - math.cos(heading)), abs=1e-6)
        assert x[0, 3] == pytest.approx(radius * math.sin(heading), abs=1e-6)
        assert x[0, 1] == pytest.approx(v * math.sin(heading), abs=1e-9)
        assert x[0, 4] == pytest.approx(v * math.cos(heading), abs=1e-9)
        # centripetal acceleration v²/r = v·ω, towards the centre
        a = x[0, [2, 5]]
        assert np.hypot(*a) == pytest.approx(v * w, rel=1e-12)
        centre = np.array([radius, 0.0])
        to_centre = centre - x[0, [0, 3]]
        assert float(a @ to_centre) / (np.hypot(*a) * np.hypot(*to_centre)) == pytest.approx(1.0, abs=1e-12)
        np.testing.assert_array_equal(P, np.zeros((1, 6, 6)))


def test_batch_of_tracks_with_their_own_dt() -> None:
    m = CoordinatedTurnModel(-1.5, 1.0)
    rng = np.random.default_rng(4)
    x = rng.normal(0.0, 100.0, (5, 6))
    A = rng.normal(0.0, 10.0, (5, 6, 6))
    P = A @ np.swapaxes(A, 1, 2)
    dt = np.array([0.0, 1.0, 4.0, 5.5, 10.0])
    xb, Pb = m.predict(x, P, dt)
    for n in range(5):
        x1, P1 = m.predict(x[n : n + 1], P[n : n + 1], dt[n])
        np.testing.assert_allclose(xb[n], x1[0], rtol=1e-12, atol=1e-9)
        np.testing.assert_allclose(Pb[n], P1[0], rtol=1e-12, atol=1e-9)
    np.testing.assert_allclose(xb[0][[0, 1, 3, 4]], x[0][[0, 1, 3, 4]], atol=1e-12)


def test_an_axis_of_turn_rates_equals_each_rate_on_its_own() -> None:
    """The IMM predicts its turn models as one array axis (dt (N, 1) against K rates):
    F, Q of eq. (2-3) broadcast over the rates equal each rate's own, ω = 0 and the series
    below |ωT| = 0.01 included; ct_matrices_into's entry-by-entry Φ and Q₆ equal the lifted
    M·F·S and M·Q·Mᵀ of eq. (4) (lift_rows, lift_cov), and Van Loan's at one point."""
    w = np.radians([3.0, -3.0, 1.5, -1.5, 0.0, 1e-4])
    q = np.array([1.0, 1.0, 2.0, 2.0, 0.5, 1.0])
    dt = np.array([0.0, 1e-3, 0.2, 0.5, 4.0, 12.0, 60.0])
    F4 = ct_transition_4d(dt[:, None], w)
    Q4 = ct_noise_4d(dt[:, None], w, q)
    phi = np.zeros((dt.size, w.size, 6, 6))
    Q6 = np.zeros_like(phi)
    ct_matrices_into(phi, Q6, dt[:, None], w, q)
    for k in range(w.size):
        np.testing.assert_array_equal(F4[:, k], ct_transition_4d(dt, w[k]))
        np.testing.assert_allclose(Q4[:, k], ct_noise_4d(dt, w[k], q[k]), rtol=1e-15, atol=0.0)
        lifted = np.zeros((dt.size, 6, 6))
        lifted[:, :, SUB] = lift_rows(F4[:, k], w[k])
        np.testing.assert_allclose(phi[:, k], lifted, rtol=1e-15, atol=1e-18)
        np.testing.assert_allclose(phi[:, k], ct_transition(dt, w[k]), rtol=1e-15, atol=1e-18)
        np.testing.assert_allclose(Q6[:, k], lift_cov(Q4[:, k], w[k]), rtol=1e-14, atol=1e-300)
        np.testing.assert_allclose(Q6[:, k], ct_process_noise(dt, w[k], q[k]), rtol=1e-14, atol=1e-300)
    F, Q = van_loan_ct(w[0], q[0], 4.0)
    np.testing.assert_allclose(phi[4, 0][np.ix_(SUB, SUB)], F, rtol=1e-10, atol=1e-10)
    np.testing.assert_allclose(Q6[4, 0][np.ix_(SUB, SUB)], Q, rtol=1e-9, atol=1e-12)


@pytest.mark.parametrize("speed_mps", [120.0, 240.0])
def test_a_banked_turn_follows_the_circle_of_its_bank_at_any_speed(speed_mps: float) -> None:
    """A level coordinated turn at bank φ has radius v²/(g tan φ) (the lift's horizontal
    part is the centripetal force m v²/r): an aircraft heading north at v banked 25° to
    the right is after T on that circle centred east of it, and one banked left on the
    mirror circle; the same model object fits both speeds."""
    g = 9.80665
    radius = speed_mps**2 / (g * math.tan(math.radians(25.0)))
    for bank, side in ((25.0, 1.0), (-25.0, -1.0)):
        m = BankedTurnModel(bank, 0.0)
        x0 = np.array([[0.0, 0.0, 0.0, 0.0, speed_mps, 0.0]])
        for T in (1.0, 4.0, 30.0):
            x, P = m.predict(x0, np.zeros((1, 6, 6)), T)
            heading = speed_mps * T / radius  # arc length over radius
            assert x[0, 0] == pytest.approx(side * radius * (1.0 - math.cos(heading)), abs=1e-6)
            assert x[0, 3] == pytest.approx(radius * math.sin(heading), abs=1e-6)
            assert np.hypot(x[0, 1], x[0, 4]) == pytest.approx(speed_mps, rel=1e-12)
            assert np.hypot(x[0, 2], x[0, 5]) == pytest.approx(speed_mps**2 / radius, rel=1e-12)
            np.testing.assert_array_equal(P, np.zeros((1, 6, 6)))


def test_a_batch_of_banked_turns_is_each_track_at_its_own_rate() -> None:
    """Tracks of different speeds in one call: each is the fixed-rate model at the rate
    g tan φ / v of its speed (v at least 50 m/s: a slow or not yet moving track turns at
    the rate of a 50 m/s turn), x and P alike."""
    g = 9.80665
    rng = np.random.default_rng(5)
    x = rng.normal(0.0, 100.0, (4, 6))
    x[:, [1, 4]] = [[0.0, 0.0], [20.0, -30.0], [100.0, 50.0], [-180.0, 160.0]]
    A = rng.normal(0.0, 10.0, (4, 6, 6))
    P = A @ np.swapaxes(A, 1, 2)
    dt = np.array([4.0, 2.0, 4.0, 8.0])
    m = BankedTurnModel(-15.0, 1.5)
    xb, Pb = m.predict(x, P, dt)
    for n in range(4):
        speed = max(math.hypot(x[n, 1], x[n, 4]), 50.0)
        rate_deg_s = -math.degrees(g * math.tan(math.radians(15.0)) / speed)  # a left turn
        x1, P1 = CoordinatedTurnModel(rate_deg_s, 1.5).predict(x[n : n + 1], P[n : n + 1], dt[n])
        np.testing.assert_allclose(xb[n], x1[0], rtol=1e-12, atol=1e-9)
        np.testing.assert_allclose(Pb[n], P1[0], rtol=1e-12, atol=1e-9)
    with pytest.raises(ValueError):
        BankedTurnModel(90.0, 1.0)
