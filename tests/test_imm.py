"""IMM filter (tracking/imm.py) against independent computations.

* a hand computation of the IMM cycle (Blom & Bar-Shalom 1988) for one track, written
  with per-model loops, np.linalg.inv and Φ, Q from Van Loan's method (scipy expm of the
  continuous Singer and coordinated-turn models), not from singer_filter.py or
  coordinated_turn.py;
* filterpy's IMMEstimator with filterpy KalmanFilter objects carrying the same F, Q, H, R
  (skipped when filterpy is not installed);
* Monte Carlo consistency (NEES) on straight flight, a rate-one turn against the
  single-model Singer filter, and batch-versus-one-track equality.
"""

from __future__ import annotations

import math
import time

import numpy as np
import pytest
from pydantic import ValidationError
from scipy.linalg import expm
from scipy.stats import chi2, multivariate_normal

from radar_fusion.tracking.imm import MANOEUVRE, QUIET, Evidence, IMMFilter, IMMParams, IMMState
from radar_fusion.tracking.singer_filter import SingerFilter

H = np.zeros((2, 6))
H[0, 0] = H[1, 3] = 1.0


def van_loan(dt_s: float, alpha_per_s: float, sigma_m_mps2: float) -> tuple[np.ndarray, np.ndarray]:
    """Φ and Q (6×6) of the continuous Singer model by Van Loan's method (1978):
    expm([[−A, G q_c Gᵀ], [0, Aᵀ]]·T) = [[·, Φ⁻¹Q], [0, Φᵀ]], q_c = 2 α σ_m²."""
    a = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [0.0, 0.0, -alpha_per_s]])
    gqg = np.zeros((3, 3))
    gqg[2, 2] = 2.0 * alpha_per_s * sigma_m_mps2**2
    big = np.zeros((6, 6))
    big[:3, :3] = -a
    big[:3, 3:] = gqg
    big[3:, 3:] = a.T
    e = expm(big * dt_s)
    phi3 = e[3:, 3:].T
    q3 = phi3 @ e[:3, 3:]
    phi, q = np.zeros((6, 6)), np.zeros((6, 6))
    for s in (slice(0, 3), slice(3, 6)):
        phi[s, s], q[s, s] = phi3, q3
    return phi, 0.5 * (q + q.T)


def van_loan_turn(dt_s: float, rate_deg_s: float, q_m2_s3: float) -> tuple[np.ndarray, np.ndarray]:
    """Φ and Q (6×6) of a coordinated turn at rate_deg_s (right positive: clockwise in
    (east, north)) by Van Loan's method on [x, vx, y, vy], lifted to the Singer state with
    the turn's centripetal acceleration ax = −ω vy, ay = ω vx."""
    w = -math.radians(rate_deg_s)
    a = np.zeros((4, 4))
    a[0, 1] = a[2, 3] = 1.0
    a[1, 3], a[3, 1] = -w, w
    big = np.zeros((8, 8))
    big[:4, :4], big[:4, 4:], big[4:, 4:] = -a, np.diag([0.0, q_m2_s3, 0.0, q_m2_s3]), a.T
    e = expm(big * dt_s)
    f4 = e[4:, 4:].T
    q4 = f4 @ e[:4, 4:]
    lift = np.zeros((6, 4))  # rows x, vx, ax, y, vy, ay from [x, vx, y, vy]
    lift[0, 0] = lift[1, 1] = lift[3, 2] = lift[4, 3] = 1.0
    lift[2, 3], lift[5, 1] = -w, w
    pick = np.zeros((4, 6))
    pick[0, 0] = pick[1, 1] = pick[2, 3] = pick[3, 4] = 1.0
    return lift @ f4 @ pick, lift @ (0.5 * (q4 + q4.T)) @ lift.T


G_MPS2 = 9.80665  # standard gravity


def turn_rates_deg_s(params: IMMParams, x0: np.ndarray | None) -> list[float]:
    """The turn models' rates in mode order after the two Singer models: a right and a left
    one per fixed rate, then per bank angle φ the rate of a level coordinated turn at φ,
    g tan φ / v, at the speed v of the state the model predicts from (x0[j]), 50 m/s at
    least."""
    out: list[float] = []
    for rate in params.turn_rates_deg_s:
        out += [rate, -rate]
    j = 2 + len(out)
    for bank in params.turn_banks_deg:
        for b in (bank, -bank):
            speed = max(math.hypot(x0[j][1], x0[j][4]), 50.0) if x0 is not None else math.nan
            out.append(math.degrees(G_MPS2 * math.tan(math.radians(b)) / speed))
            j += 1
    return out


def model_fq(params: IMMParams, dt_s: float, x0: np.ndarray | None = None) -> list[tuple[np.ndarray, np.ndarray]]:
    """Φ, Q of every model in mode order: quiet, manoeuvre, then a right and a left turn per
    rate and per bank angle (a banked turn's rate from its own mixed state x0[j])."""
    out = [
        van_loan(dt_s, params.quiet_alpha_per_s, params.quiet_sigma_m_mps2),
        van_loan(dt_s, params.manoeuvre_alpha_per_s, params.manoeuvre_sigma_m_mps2),
    ]
    for rate in turn_rates_deg_s(params, x0):
        out.append(van_loan_turn(dt_s, rate, params.turn_q_m2_s3))
    return out


def hand_markov(params: IMMParams, dt_s: float) -> np.ndarray:
    """p_ij (eq. 0): stay exp(−dt/τ_i); leave the quiet mode (0) for the manoeuvre model (1)
    by the share quiet_exit_manoeuvre_share and for each of the n turn models by the rest
    over n; leave any other mode to each other mode equally."""
    n_turns = 2 * (len(params.turn_rates_deg_s) + len(params.turn_banks_deg))
    tau = [params.quiet_dwell_s, params.manoeuvre_dwell_s] + [params.turn_dwell_s] * n_turns
    m = len(tau)
    p = np.empty((m, m))
    for i in range(m):
        for j in range(m):
            stay = math.exp(-dt_s / tau[i])
            if i == j:
                p[i, j] = stay
            elif i == 0 and n_turns:
                share = params.quiet_exit_manoeuvre_share
                p[i, j] = (1.0 - stay) * (share if j == 1 else (1.0 - share) / n_turns)
            else:
                p[i, j] = (1.0 - stay) / (m - 1)
    return p


def hand_cycle(
    params: IMMParams,
    xs: list[np.ndarray],
    Ps: list[np.ndarray],
    mu: np.ndarray,
    dt_s: float,
    z: np.ndarray,
    R: np.ndarray,
) -> tuple[list[np.ndarray], list[np.ndarray], np.ndarray]:
    """One IMM cycle for one track, every model, written out term by term: the interaction
    and the models' predictions ``params.switch_substeps`` times over an equal share of dt_s
    (each share's mixing from the share before's predictions and c̄), then the update."""
    k = params.switch_substeps
    p = hand_markov(params, dt_s / k)
    m = p.shape[0]
    preds = list(zip(xs, Ps))
    c_bar = list(mu)
    for _ in range(k):
        prior = c_bar
        c_bar = [sum(p[i, j] * prior[i] for i in range(m)) for j in range(m)]
        mixed = []
        for j in range(m):
            w = [p[i, j] * prior[i] / c_bar[j] for i in range(m)]
            x0 = sum(w[i] * preds[i][0] for i in range(m))
            P0 = sum(w[i] * (preds[i][1] + np.outer(preds[i][0] - x0, preds[i][0] - x0)) for i in range(m))
            mixed.append((x0, P0))
        fq = model_fq(params, dt_s / k, np.array([x0 for x0, _ in mixed]))
        preds = [(fq[j][0] @ mixed[j][0], fq[j][0] @ mixed[j][1] @ fq[j][0].T + fq[j][1]) for j in range(m)]
    new_x, new_P, lik = [], [], []
    for j in range(m):
        xp, Pp = preds[j]
        S = H @ Pp @ H.T + R
        K = Pp @ H.T @ np.linalg.inv(S)
        nu = z - H @ xp
        new_x.append(xp + K @ nu)
        I_KH = np.eye(6) - K @ H
        new_P.append(I_KH @ Pp @ I_KH.T + K @ R @ K.T)
        lik.append(math.exp(-0.5 * nu @ np.linalg.inv(S) @ nu) / (2.0 * math.pi * math.sqrt(np.linalg.det(S))))
    mu_new = np.array([lik[j] * c_bar[j] for j in range(m)])
    return new_x, new_P, mu_new / mu_new.sum()


def hand_combine(xs: list[np.ndarray], Ps: list[np.ndarray], mu: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    x = sum(m * xi for m, xi in zip(mu, xs))
    P = sum(m * (Pi + np.outer(xi - x, xi - x)) for m, xi, Pi in zip(mu, xs, Ps))
    return np.asarray(x), np.asarray(P)


def turning_measurements(n: int, dt_s: np.ndarray, seed: int) -> np.ndarray:
    """Noisy positions of a 200 m/s aircraft turning at 3°/s after 20 s."""
    rng = np.random.default_rng(seed)
    t = np.cumsum(dt_s)
    w = math.radians(3.0)
    th = w * np.clip(t - 20.0, 0.0, None)
    x = np.where(t < 20.0, 200.0 * t, 4000.0 + 200.0 / w * np.sin(th))
    y = np.where(t < 20.0, 0.0, 200.0 / w * (1.0 - np.cos(th)))
    return np.stack([x, y], axis=1) + 50.0 * rng.standard_normal((t.size, 2))


X0 = np.array([0.0, 200.0, 0.0, 0.0, 0.0, 0.0])
P0 = np.diag([50.0**2, 30.0**2, 3.0**2, 50.0**2, 30.0**2, 3.0**2])
R50 = 50.0**2 * np.eye(2)


# ------------------------------------------------------------------ hand computation


@pytest.mark.parametrize("substeps", [1, 3])
def test_cycle_matches_hand_computation_with_varying_dt(substeps: int) -> None:
    """1: the textbook IMM, mixing once per interval; 3 (the default): three mixings and
    predictions over thirds of each interval."""
    params = IMMParams(switch_substeps=substeps)
    imm = IMMFilter(params)
    dts = np.array([4.0, 2.5, 6.0, 4.0, 0.5, 8.0, 4.0, 4.0, 3.0, 4.0])
    zs = turning_measurements(dts.size, dts, seed=3)
    st = imm.initiate(X0[None], P0[None])
    m = imm.n_models
    assert m == 6  # quiet, manoeuvre, right and left turns at banks of 15° and 25°
    xs, Ps, mu = [X0.copy()] * m, [P0.copy()] * m, params.prior_mu()
    mu_max = 0.0
    for dt, z in zip(dts, zs):
        st = imm.update(imm.predict(st, dt), z[None], R50[None])
        xs, Ps, mu = hand_cycle(params, xs, Ps, mu, float(dt), z, R50)
        np.testing.assert_allclose(st.mu[0], mu, rtol=1e-9, atol=1e-12)
        for j in range(m):
            np.testing.assert_allclose(st.x_models[0, j], xs[j], rtol=1e-9, atol=1e-7)
            np.testing.assert_allclose(st.P_models[0, j], Ps[j], rtol=1e-8, atol=1e-7)
        x, P = imm.combine(st)
        xh, Ph = hand_combine(xs, Ps, mu)
        np.testing.assert_allclose(x[0], xh, rtol=1e-9, atol=1e-7)
        np.testing.assert_allclose(P[0], Ph, rtol=1e-8, atol=1e-7)
        mu_max = max(mu_max, 1.0 - float(mu[QUIET]))
    assert mu_max > 0.5  # the turn was seen: the other models mattered


@pytest.mark.parametrize("substeps", [1, 3])
def test_matches_filterpy_imm_estimator(substeps: int) -> None:
    """With switch_substeps K, the engine's cycle over 4 s against filterpy's predict() K
    times over 4/K s (its filters' F and Q and its Markov matrix those of 4/K s), then
    update()."""
    fp_kalman = pytest.importorskip("filterpy.kalman")
    params = IMMParams(switch_substeps=substeps)
    imm = IMMFilter(params)
    dt = 4.0 / substeps  # filterpy's step
    filters = []

    class BankedTurnKF(fp_kalman.KalmanFilter):  # type: ignore[misc,name-defined]
        """A banked turn (model j): F and Q from the state IMMEstimator mixed into it, at
        the rate of a coordinated turn at its bank and the state's speed."""

        def __init__(self, j: int) -> None:
            super().__init__(dim_x=6, dim_z=2)
            self.j = j

        def predict(self, *args: object, **kwargs: object) -> None:
            x0 = np.zeros((imm.n_models, 6))
            x0[self.j] = self.x[:, 0]
            self.F, self.Q = model_fq(params, dt, x0)[self.j]
            super().predict(*args, **kwargs)

    n_fixed = 2 + 2 * len(params.turn_rates_deg_s)
    for j in range(imm.n_models):
        kf = BankedTurnKF(j) if j >= n_fixed else fp_kalman.KalmanFilter(dim_x=6, dim_z=2)
        kf.x = X0.reshape(6, 1).copy()
        kf.P = P0.copy()
        if j < n_fixed:
            kf.F, kf.Q = model_fq(params, dt)[j]
        kf.H, kf.R = H.copy(), R50.copy()
        filters.append(kf)
    assert n_fixed < imm.n_models  # the banked turns are in the comparison
    # filterpy's code forms c̄ = μ·M, i.e. M[i, j] is the probability from mode i to mode j
    # (its docstring says the transpose); p_ij = exp(−dt/τ_i) on the diagonal, eq. 0
    est = fp_kalman.IMMEstimator(filters, params.prior_mu(), hand_markov(params, dt))
    st = imm.initiate(X0[None], P0[None])
    zs = turning_measurements(15, np.full(15, 4.0), seed=11)
    mu_max = 0.0
    for z in zs:
        for step in range(substeps):
            if step:  # filterpy's mixing weights and c̄ come from μ, which only its update() sets:
                est.mu = est.cbar.copy()  # the prior of this share is the last share's c̄
                est._compute_mixing_probabilities()
            est.predict()
        est.update(z.reshape(2, 1))
        st = imm.update(imm.predict(st, 4.0), z[None], R50[None])
        np.testing.assert_allclose(st.mu[0], est.mu, rtol=1e-9, atol=1e-12)
        for j, kf in enumerate(est.filters):
            np.testing.assert_allclose(st.x_models[0, j], kf.x[:, 0], rtol=1e-9, atol=1e-7)
            np.testing.assert_allclose(st.P_models[0, j], kf.P, rtol=1e-8, atol=1e-7)
        x, P = imm.combine(st)
        np.testing.assert_allclose(x[0], est.x[:, 0], rtol=1e-9, atol=1e-7)
        np.testing.assert_allclose(P[0], est.P, rtol=1e-8, atol=1e-7)
        mu_max = max(mu_max, 1.0 - float(est.mu[QUIET]))
    assert mu_max > 0.5  # the turn was seen: the other models mattered


def test_quiet_exits_go_mostly_to_the_turn_models() -> None:
    """Eq. 0's exit shares: each row of Π sums to 1 at any dt; the quiet mode leaves for
    the manoeuvre model by quiet_exit_manoeuvre_share (the mixing kernels read the same
    shares: a quiet track's c̄ after one step is μ_q p_q· by hand); with the share at
    1/(M − 1) it is the textbook uniform rule; without turn models all of it goes to the
    manoeuvre model."""
    params = IMMParams()
    imm = IMMFilter(params)
    m = imm.n_models
    pi = imm.transition_matrix(np.array([4.0, 60.0]))
    np.testing.assert_allclose(pi.sum(axis=2), 1.0, rtol=1e-14)
    leave = 1.0 - math.exp(-4.0 / params.quiet_dwell_s)
    assert pi[0, 0, 1] == pytest.approx(leave * params.quiet_exit_manoeuvre_share, rel=1e-12)
    np.testing.assert_allclose(pi[0, 0, 2:], leave * (1 - params.quiet_exit_manoeuvre_share) / (m - 2), rtol=1e-12)
    mu = np.zeros((1, m))
    mu[0, 0] = 1.0
    st = IMMState(np.repeat(X0[None, None], m, axis=1), np.repeat(P0[None, None], m, axis=1), mu)
    # over switch_substeps K equal shares of the 4 s, c̄ is μ Π(4/K)^K
    k = params.switch_substeps
    by_hand = np.linalg.matrix_power(hand_markov(params, 4.0 / k), k)[0]
    np.testing.assert_allclose(imm.predict(st, 4.0).mu[0], by_hand, rtol=1e-12, atol=1e-300)
    uniform = IMMFilter(IMMParams(quiet_exit_manoeuvre_share=1.0 / (m - 1))).transition_matrix(np.array([4.0]))[0]
    off = ~np.eye(m, dtype=bool)
    stay = np.exp(-4.0 / params.dwell_s())
    np.testing.assert_allclose(uniform[off], np.repeat((1.0 - stay) / (m - 1), m - 1), rtol=1e-12)
    singer_only = IMMFilter(IMMParams(turn_banks_deg=())).transition_matrix(np.array([4.0]))[0]
    assert singer_only.shape == (2, 2) and singer_only[0, 1] == pytest.approx(leave, rel=1e-12)


def test_transition_matrix_and_likelihood() -> None:
    imm = IMMFilter()
    dt = np.array([0.0, 4.0, 30.0])
    pi = imm.transition_matrix(dt)
    for n, d in enumerate(dt):
        np.testing.assert_allclose(pi[n], hand_markov(IMMParams(), float(d)), rtol=1e-13, atol=1e-300)
    # log Λ_j (eq. 5) against scipy's Gaussian
    rng = np.random.default_rng(5)
    st = imm.predict(imm.initiate(X0[None], P0[None]), 4.0)
    z = rng.normal(800.0, 100.0, size=(1, 2))
    ll = imm.log_likelihoods(st, z, R50[None])
    for j in range(imm.n_models):
        S = H @ st.P_models[0, j] @ H.T + R50
        ref = multivariate_normal(mean=H @ st.x_models[0, j], cov=S).logpdf(z[0])
        assert ll[0, j] == pytest.approx(ref, rel=1e-12)


def test_predict_over_zero_dt_changes_nothing() -> None:
    """Π(0) = I: no mixing, no motion, no process noise; even a mode of probability 0
    (c̄_j = 0) keeps its state instead of dividing by zero.  A turn model's acceleration
    is the turn's own (ω·[−vy, vx], coordinated_turn.py eq. 4) at any dt, 0 included:
    there only position and velocity stay as they were."""
    imm = IMMFilter()
    rng = np.random.default_rng(2)
    mu = np.zeros((2, imm.n_models))
    mu[0, QUIET], mu[1, QUIET], mu[1, MANOEUVRE] = 1.0, 0.3, 0.7
    st = imm.initiate(X0[None].repeat(2, 0), P0[None].repeat(2, 0), mu=mu)
    st.x_models += rng.normal(0.0, 10.0, st.x_models.shape)
    out = imm.predict(st, 0.0)
    np.testing.assert_array_equal(out.mu, st.mu)
    singer, pv = [QUIET, MANOEUVRE], [0, 1, 3, 4]
    np.testing.assert_allclose(out.x_models[:, singer], st.x_models[:, singer], rtol=1e-15, atol=1e-12)
    np.testing.assert_allclose(out.P_models[:, singer], st.P_models[:, singer], rtol=1e-15, atol=1e-9)
    np.testing.assert_allclose(out.x_models[..., pv], st.x_models[..., pv], rtol=1e-15, atol=1e-12)
    np.testing.assert_allclose(out.P_models[:, :, pv][..., pv], st.P_models[:, :, pv][..., pv], rtol=1e-15, atol=1e-9)
    for n in range(2):  # no mixing over dt = 0: each model at its own state (a banked turn at its speed)
        for j, rate in enumerate(turn_rates_deg_s(imm.params, st.x_models[n]), start=2):
            w = -math.radians(rate)
            np.testing.assert_allclose(out.x_models[n, j, 2], -w * st.x_models[n, j, 4], atol=1e-12)
            np.testing.assert_allclose(out.x_models[n, j, 5], w * st.x_models[n, j, 1], atol=1e-12)


def test_params_are_a_strict_frozen_config_section() -> None:
    p = IMMParams()
    with pytest.raises(ValidationError):
        IMMParams(quiet_sigma_m_mps2=0.5, no_such_field=1.0)  # type: ignore[call-arg]
    with pytest.raises(ValidationError):
        p.quiet_dwell_s = 10.0  # type: ignore[misc]
    with pytest.raises(ValidationError):
        IMMParams(prior_manoeuvre_prob=1.5)
    for name, field in IMMParams.model_fields.items():
        assert field.description and len(field.description) > 40, name
    assert p.prior_mu().sum() == pytest.approx(1.0)


# ------------------------------------------------------------------ Monte Carlo


def test_straight_flight_quiet_model_wins_and_nees_is_consistent() -> None:
    """Truth drawn from the quiet model itself (Φ, Q by Van Loan), 1,000 runs at once.

    The position NEES averaged over the runs at one time is χ²(2·1000)/1000 for a
    consistent filter: 99 % band [1.84, 2.17], which rejects a covariance off by 20 %
    either way (asserted, so the band cannot pass by accident).  The Kalman filter of the
    quiet model alone (matched to the truth) must fall in it, which proves the truth and
    the band.  The IMM mixes a little of the manoeuvre model into every cycle, so its
    covariance is a little larger than the matched filter's: on the same errors its NEES
    must be 0.85-1.0 times the matched filter's (never overconfident, at most 15 %
    conservative), at five times 12 scans apart.
    """
    params = IMMParams()
    imm = IMMFilter(params)
    quiet = SingerFilter(alpha_per_s=params.quiet_alpha_per_s, sigma_m_mps2=params.quiet_sigma_m_mps2)
    n_runs, n_steps, dt = 1000, 60, 4.0
    rng = np.random.default_rng(20)
    F, Q = van_loan(dt, params.quiet_alpha_per_s, params.quiet_sigma_m_mps2)
    lq = np.linalg.cholesky(Q)
    truth = np.zeros((n_runs, 6))
    truth[:, 1] = 200.0
    truth[:, [2, 5]] = params.quiet_sigma_m_mps2 * rng.standard_normal((n_runs, 2))  # stationary acceleration
    P_init = np.diag([50.0**2, 20.0**2, 1.0**2, 50.0**2, 20.0**2, 1.0**2])
    x_init = truth + rng.standard_normal((n_runs, 6)) @ np.linalg.cholesky(P_init).T
    st = imm.initiate(x_init, np.broadcast_to(P_init, (n_runs, 6, 6)))
    sq = (x_init, np.broadcast_to(P_init, (n_runs, 6, 6)))
    R = np.broadcast_to(R50, (n_runs, 2, 2))
    lo, hi = chi2.ppf(0.005, 2 * n_runs) / n_runs, chi2.ppf(0.995, 2 * n_runs) / n_runs

    def avg_nees(x: np.ndarray, P: np.ndarray, scale: float = 1.0) -> float:
        e = x[:, [0, 3]] - truth[:, [0, 3]]
        Pp = scale * P[:, [0, 3]][:, :, [0, 3]]
        return float(np.mean(np.einsum("ni,nij,nj->n", e, np.linalg.inv(Pp), e)))

    checked = 0
    for k in range(1, n_steps + 1):
        truth = truth @ F.T + rng.standard_normal((n_runs, 6)) @ lq.T
        z = truth[:, [0, 3]] + 50.0 * rng.standard_normal((n_runs, 2))
        st = imm.update(imm.predict(st, dt), z, R)
        xq, Pq, _, _ = quiet.update(*quiet.predict(*sq, dt), z, R)
        sq = (xq, Pq)
        if k % 12 == 0:
            x, P = imm.combine(st)
            matched, ours = avg_nees(xq, Pq), avg_nees(x, P)
            print(f"\nscan {k}: NEES matched KF {matched:.3f}, IMM {ours:.3f} (band {lo:.2f}-{hi:.2f})", end="")
            assert lo < matched < hi
            assert not lo < avg_nees(xq, Pq, 1.2) < hi and not lo < avg_nees(xq, Pq, 1 / 1.2) < hi
            assert 0.85 * matched < ours < matched
            checked += 1
    assert checked == 5
    assert st.mu[:, QUIET].mean() > 0.95


def test_exactly_straight_track_quiet_model_probability_high() -> None:
    imm = IMMFilter()
    n_runs, dt = 200, 4.0
    rng = np.random.default_rng(8)
    st = imm.initiate(np.broadcast_to(X0, (n_runs, 6)), np.broadcast_to(P0, (n_runs, 6, 6)))
    for k in range(1, 41):
        z = np.array([200.0 * dt * k, 0.0]) + 50.0 * rng.standard_normal((n_runs, 2))
        st = imm.update(imm.predict(st, dt), z, np.broadcast_to(R50, (n_runs, 2, 2)))
    assert st.mu[:, QUIET].mean() > 0.95
    assert np.median(st.mu[:, QUIET]) > 0.97


def _turn_truth(t_s: np.ndarray, t_turn_s: float, turn_s: float, v_mps: float, w_rps: float) -> np.ndarray:
    """Straight east, a left turn at ω from t_turn_s for turn_s, then straight again."""
    r = v_mps / w_rps
    tt = np.clip(t_s - t_turn_s, 0.0, turn_s)
    th = w_rps * tt
    after = np.clip(t_s - t_turn_s - turn_s, 0.0, None)
    x = v_mps * np.minimum(t_s, t_turn_s) + r * np.sin(th) + v_mps * after * math.cos(w_rps * turn_s)
    y = r * (1.0 - np.cos(th)) + v_mps * after * math.sin(w_rps * turn_s)
    return np.stack([x, y], axis=1)


def test_rate_one_turn_imm_beats_quiet_singer_and_detects_the_manoeuvre() -> None:
    """200 m/s, 3°/s for 60 s (180°), plots every 4 s with σ = 50 m, 200 runs."""
    params = IMMParams()
    imm = IMMFilter(params)
    quiet = SingerFilter(alpha_per_s=params.quiet_alpha_per_s, sigma_m_mps2=params.quiet_sigma_m_mps2)
    baseline = SingerFilter()
    n_runs, dt, t_turn, turn_s = 200, 4.0, 160.0, 60.0
    t = np.arange(dt, 360.0 + dt / 2, dt)
    truth = _turn_truth(t, t_turn, turn_s, 200.0, math.radians(3.0))
    rng = np.random.default_rng(4)
    z_all = truth[None] + 50.0 * rng.standard_normal((n_runs, t.size, 2))
    R = np.broadcast_to(R50, (n_runs, 2, 2))
    x0 = np.broadcast_to(X0, (n_runs, 6)).copy()
    x0[:, [0, 3]] = 50.0 * rng.standard_normal((n_runs, 2))
    p_init = np.broadcast_to(P0, (n_runs, 6, 6))
    st = imm.initiate(x0, p_init)
    sq = (x0, p_init)
    sb = (x0, p_init)
    err = {"imm": [], "quiet": [], "baseline": []}
    mu_m = []
    for k in range(t.size):
        st = imm.update(imm.predict(st, dt), z_all[:, k], R)
        x, _ = imm.combine(st)
        xq, Pq, _, _ = quiet.update(*quiet.predict(*sq, dt), z_all[:, k], R)
        xb, Pb, _, _ = baseline.update(*baseline.predict(*sb, dt), z_all[:, k], R)
        sq, sb = (xq, Pq), (xb, Pb)
        for key, xx in (("imm", x), ("quiet", xq), ("baseline", xb)):
            err[key].append(np.sum((xx[:, [0, 3]] - truth[k]) ** 2, axis=1))
        mu_m.append(1.0 - st.mu[:, QUIET].mean())  # every model but the quiet one
    mu = np.array(mu_m)
    in_turn = (t > t_turn) & (t <= t_turn + turn_s)
    straight = (t > 60.0) & (t <= t_turn)
    rms = {
        key: {w: math.sqrt(np.mean(np.array(e)[m])) for w, m in (("turn", in_turn), ("straight", straight))}
        for key, e in err.items()
    }
    print(
        "\nrate-one turn, position RMS m (straight / turn): "
        + ", ".join(f"{k} {v['straight']:.1f} / {v['turn']:.1f}" for k, v in rms.items())
        + f"; IMM turn/straight {rms['imm']['turn'] / rms['imm']['straight']:.2f}"
    )
    print("mean 1 - mu_quiet from 8 s before the turn: " + " ".join(f"{m:.2f}" for m in mu[(t >= 152) & (t <= 300)]))
    assert rms["imm"]["turn"] < 0.35 * rms["quiet"]["turn"]
    assert rms["imm"]["turn"] < rms["baseline"]["turn"]
    # the straight flight is not paid for: IMM within 15 % of the quiet filter alone
    assert rms["imm"]["straight"] < 1.15 * rms["quiet"]["straight"]
    first = int(np.flatnonzero(t > t_turn)[0])  # the first update inside the turn
    assert mu[first - 10 : first].max() < 0.1  # quiet before the turn
    assert mu[first + 2] > 0.5  # by the third update of the turn
    end = int(np.flatnonzero(t > t_turn + turn_s)[0])
    assert mu[end + 8] < 0.2 * mu[first:end].max()  # falls within 8 updates after the turn


# ------------------------------------------------------------------ Mode S roll angle


def hand_roll_likelihood(params: IMMParams, roll_deg: float) -> np.ndarray:
    """p(roll | model) written out with scipy's normal density, model by model: quiet
    N(0, 2.5°), manoeuvre N(0, 20°), then the banked turns, right and left, N(±bank, 5°),
    each mixed with the uniform share over ±90°."""
    from scipy.stats import norm

    means = [0.0, 0.0] + [b * s for b in params.turn_banks_deg for s in (1.0, -1.0)]
    sigmas = [params.roll_quiet_sigma_deg, params.roll_manoeuvre_sigma_deg]
    sigmas += [params.roll_turn_sigma_deg] * (2 * len(params.turn_banks_deg))
    eps = params.roll_outlier_share
    return np.array([(1 - eps) * norm.pdf(roll_deg, mu, sd) + eps / 180.0 for mu, sd in zip(means, sigmas)])


def test_roll_evidence_matches_hand_computation() -> None:
    """A Mode S roll angle multiplies each model's likelihood Λ_j (eq. 5) by p(roll | j):
    μ_j ∝ Λ_j c̄_j p(roll | j). The kernels' cycle against hand_cycle's μ times that
    product, carried on to the next cycles' mixing; without a report, nothing changes."""
    params = IMMParams()
    imm = IMMFilter(params)
    dts = np.array([4.0, 4.0, 4.0, 5.0, 4.0, 4.0, 3.0, 4.0])
    zs = turning_measurements(dts.size, dts, seed=5)
    rolls = [math.nan, 1.2, math.nan, math.nan, 24.0, math.nan, -3.0, 17.5]
    st = plain = imm.initiate(X0[None], P0[None])
    m = imm.n_models
    xs, Ps, mu = [X0.copy()] * m, [P0.copy()] * m, params.prior_mu()
    for dt, z, roll in zip(dts, zs, rolls):
        plain = imm.update(imm.predict(plain, dt), z[None], R50[None])
        lf = imm.roll_log_likelihoods(np.array([roll]), np.array([200.0]), np.array([0.0]))
        both, _, _ = imm.predict_update(st, np.array([dt]), z[None], R50[None], lf)
        st = imm.update(imm.predict(st, dt), z[None], R50[None], lf)
        xs, Ps, mu = hand_cycle(params, xs, Ps, mu, float(dt), z, R50)
        if math.isnan(roll):
            assert np.all(lf == 0.0)
        else:
            mu = mu * hand_roll_likelihood(params, roll)
            mu = mu / mu.sum()
        np.testing.assert_allclose(st.mu[0], mu, rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(both.mu[0], mu, rtol=1e-9, atol=1e-12)
        for j in range(m):
            np.testing.assert_allclose(st.x_models[0, j], xs[j], rtol=1e-9, atol=1e-7)
    # the last report, 17.5° right, against positions turning left: it still moves μ
    right = [2, 4]
    assert st.mu[0, right].sum() > 5 * plain.mu[0, right].sum()


def test_roll_evidence_bayes_factor_and_weight() -> None:
    """imm.Evidence: the kernels' log Bayes factor of the roll against the position equals
    log Σ c̄ f Λ − log Σ c̄ f − log Σ c̄ Λ from the predicted state's own per-model
    likelihoods (log_likelihoods, scipy's logsumexp); weight 0 leaves μ as without any roll
    but still measures the factor; a roll the positions bear out scores above one that
    contradicts them."""
    from scipy.special import logsumexp

    imm = IMMFilter(IMMParams())
    rng = np.random.default_rng(11)
    st = _random_state(imm, 40, rng)
    dt = rng.uniform(2.0, 8.0, 40)
    z = st.x_models[:, 0][:, [0, 3]] + rng.normal(0.0, 60.0, (40, 2))
    R = np.broadcast_to(60.0**2 * np.eye(2), (40, 2, 2))
    roll = np.where(rng.random(40) < 0.8, rng.uniform(-30.0, 30.0, 40), np.nan)
    lf = imm.roll_log_likelihoods(roll, st.x_models[:, 0, 1], st.x_models[:, 0, 4])
    pred = imm.predict(st, dt)
    lp = imm.log_likelihoods(pred, z, R) + np.log(pred.mu)
    want = logsumexp(lp + lf, axis=1) - logsumexp(lf + np.log(pred.mu), axis=1) - logsumexp(lp, axis=1)
    for weight in (None, np.zeros(40)):
        ev = Evidence(np.empty(40), weight)
        upd, _, _ = imm.predict_update(st, dt, z, R, lf, ev)
        np.testing.assert_allclose(ev.log_bayes_factor, want, rtol=1e-9, atol=1e-9)
        ev2 = Evidence(np.empty(40), weight)
        imm.update(pred, z, R, lf, ev2)
        np.testing.assert_allclose(ev2.log_bayes_factor, want, rtol=1e-9, atol=1e-9)
        plain, _, _ = imm.predict_update(st, dt, z, R)
        if weight is None:
            assert np.abs(upd.mu - plain.mu).max() > 0.1
        else:  # weight 0: as if no roll were given
            np.testing.assert_allclose(upd.mu, plain.mu, rtol=1e-12, atol=1e-15)
    assert np.all(want[np.isnan(roll)] == 0.0)


def _velocity_case(imm: IMMFilter, n: int, seed: int):
    """A random updated state and velocity reports near each track's velocity, some far off."""
    rng = np.random.default_rng(seed)
    st = _random_state(imm, n, rng)
    v = st.x_models[:, 0][:, [1, 4]] + rng.normal(0.0, 8.0, (n, 2))
    v[: max(n // 8, 1)] += 400.0  # far beyond every model: refused
    a = rng.normal(size=(n, 2, 2)) * 1.5
    R = a @ np.swapaxes(a, 1, 2) + 0.5 * np.eye(2)
    age = rng.uniform(0.0, 2.5, n)
    return st, v, R, age


def test_velocity_update_matches_hand_computation() -> None:
    """IMMFilter.velocity_update_rows against one Kalman update per track and model written
    out with an explicit H (v(t − a) = v − a·acc), the Joseph form and scipy's normal
    density for eq. 5-6, σ_a² acc accᵀ added to R; a report beyond the χ² gate under every
    model leaves the track as it was; rows not named are not touched."""
    params = IMMParams(velocity_age_sigma_s=0.4)
    imm = IMMFilter(params)
    n = 24
    st, v, R, age = _velocity_case(imm, n, 3)
    before = st.select(slice(None))
    rows = np.arange(0, n, 2)  # every other track
    x, P, used = imm.velocity_update_rows(st, rows, v[rows], R[rows], age[rows])
    assert 0 < used.sum() < rows.size and not used[0]
    np.testing.assert_array_equal(st.x_models[1::2], before.x_models[1::2])
    for i, r in enumerate(rows):
        if not used[i]:
            np.testing.assert_array_equal(st.x_models[r], before.x_models[r])
            np.testing.assert_array_equal(st.mu[r], before.mu[r])
            continue
        H = np.zeros((2, 6))
        H[0, 1] = H[1, 4] = 1.0
        H[0, 2] = H[1, 5] = -age[r]
        post = np.empty(imm.n_models)
        for j in range(imm.n_models):
            xj, Pj = before.x_models[r, j], before.P_models[r, j]
            acc = xj[[2, 5]]
            Rt = R[r] + 0.4**2 * np.outer(acc, acc)
            S = H @ Pj @ H.T + Rt
            K = Pj @ H.T @ np.linalg.inv(S)
            ImKH = np.eye(6) - K @ H
            np.testing.assert_allclose(st.x_models[r, j], xj + K @ (v[r] - H @ xj), rtol=1e-9, atol=1e-8)
            np.testing.assert_allclose(st.P_models[r, j], ImKH @ Pj @ ImKH.T + K @ Rt @ K.T, rtol=1e-7, atol=1e-8)
            post[j] = before.mu[r, j] * multivariate_normal.pdf(v[r], H @ xj, S)
        np.testing.assert_allclose(st.mu[r], post / post.sum(), rtol=1e-9, atol=1e-12)
        xc = st.mu[r] @ st.x_models[r]  # eq. 7-8
        e = st.x_models[r] - xc
        Pc = np.einsum("j,jkl->kl", st.mu[r], st.P_models[r] + e[:, :, None] * e[:, None, :])
        np.testing.assert_allclose(x[i], xc, rtol=1e-9, atol=1e-8)
        np.testing.assert_allclose(P[i], Pc, rtol=1e-9, atol=1e-8)


def test_velocity_update_leaves_a_track_with_a_nan_model_as_it_was() -> None:
    """A track one of whose models holds NaN (degenerate input upstream) is not updated by a
    velocity report (its rows unchanged, ``used`` False); the other tracks are."""
    imm = IMMFilter()
    st, v, R, age = _velocity_case(imm, 6, 5)
    v[:] = st.x_models[:, 0][:, [1, 4]]  # every report near the track's velocity
    st.x_models[2, 1, 4] = np.nan
    before = st.select(slice(None))
    _, _, used = imm.velocity_update_rows(st, np.arange(6), v, R, age)
    assert not used[2] and used[[0, 1, 3, 4, 5]].all()
    np.testing.assert_array_equal(st.mu[2], before.mu[2])
    np.testing.assert_array_equal(st.P_models[2], before.P_models[2])


def test_position_then_velocity_equals_one_joint_update() -> None:
    """The velocity after the position is sequential updating: with a report of age 0 (and
    no age term) it equals one update of each model with the 4-D measurement [position,
    velocity] of block-diagonal covariance, states and mode probabilities alike (eq. 5-6,
    scipy's density of the joint innovation)."""
    params = IMMParams(velocity_age_sigma_s=0.0)
    imm = IMMFilter(params)
    rng = np.random.default_rng(8)
    n = 10
    st = _random_state(imm, n, rng)
    dt = rng.uniform(2.0, 6.0, n)
    z = st.x_models[:, 0][:, [0, 3]] + rng.normal(0.0, 60.0, (n, 2))
    Rz = np.broadcast_to(60.0**2 * np.eye(2), (n, 2, 2))
    v = st.x_models[:, 0][:, [1, 4]] + rng.normal(0.0, 5.0, (n, 2))
    Rv = np.broadcast_to(np.diag([1.0, 4.0]), (n, 2, 2))
    pred = imm.predict(st, dt)
    seq = imm.update(pred, z, Rz)
    _, _, used = imm.velocity_update_rows(seq, np.arange(n), v, Rv, np.zeros(n))
    assert used.all()
    H = np.zeros((4, 6))
    H[0, 0] = H[1, 3] = H[2, 1] = H[3, 4] = 1.0
    Rj = np.zeros((4, 4))
    Rj[:2, :2], Rj[2:, 2:] = Rz[0], Rv[0]
    for r in range(n):
        post = np.empty(imm.n_models)
        for j in range(imm.n_models):
            xj, Pj = pred.x_models[r, j], pred.P_models[r, j]
            zj = np.concatenate([z[r], v[r]])
            S = H @ Pj @ H.T + Rj
            K = Pj @ H.T @ np.linalg.inv(S)
            np.testing.assert_allclose(seq.x_models[r, j], xj + K @ (zj - H @ xj), rtol=1e-8, atol=1e-6)
            np.testing.assert_allclose(seq.P_models[r, j], Pj - K @ S @ K.T, rtol=1e-6, atol=1e-6)
            post[j] = pred.mu[r, j] * multivariate_normal.pdf(zj, H @ xj, S)
        np.testing.assert_allclose(seq.mu[r], post / post.sum(), rtol=1e-7, atol=1e-12)


def test_roll_of_a_fixed_rate_turn_is_its_bank_at_the_tracks_speed() -> None:
    """A fixed-rate model's roll is that of a coordinated turn at the track's speed:
    tan φ = v ω / g (3°/s at 150 m/s: 38.7°), so a report of that roll favours it."""
    params = IMMParams(turn_rates_deg_s=(3.0,), turn_banks_deg=())
    imm = IMMFilter(params)
    bank_deg = math.degrees(math.atan(150.0 * math.radians(3.0) / 9.80665))
    lf = imm.roll_log_likelihoods(np.array([bank_deg, -bank_deg]), np.array([150.0, 0.0]), np.array([0.0, -150.0]))
    sd, eps = params.roll_turn_sigma_deg, params.roll_outlier_share
    peak = math.log((1 - eps) / (sd * math.sqrt(2 * math.pi)) + eps / 180.0)
    np.testing.assert_allclose([lf[0, 2], lf[1, 3]], [peak, peak], rtol=1e-12)
    assert lf[0, 2] > lf[0, 3] + 5 and lf[1, 3] > lf[1, 2] + 5  # the uniform share caps it at log(180 / (ε σ √2π))
    assert IMMFilter(IMMParams(roll_dap=False)).roll_log_likelihoods(np.array([25.0]), [200.0], [0.0]).max() == 0.0


def test_roll_reports_bring_the_turn_model_in_from_the_first_report() -> None:
    """200 m/s, a left turn of 1.5°/s (a 28° bank) for 60 s, plots every 4 s with σ = 80 m
    (a fused plot far out), a roll report on every third plot (σ 1°), 200 runs: the turn's
    position error falls and the turn models take over at the first report in the turn,
    where positions alone need several scans; straight flight is not paid for."""
    imm = IMMFilter(IMMParams())
    n_runs, dt, t_turn, turn_s = 200, 4.0, 160.0, 60.0
    w = math.radians(1.5)
    bank_deg = math.degrees(math.atan(200.0 * w / 9.80665))
    t = np.arange(dt, 320.0 + dt / 2, dt)
    truth = _turn_truth(t, t_turn, turn_s, 200.0, w)
    rng = np.random.default_rng(8)
    z_all = truth[None] + 80.0 * rng.standard_normal((n_runs, t.size, 2))
    in_turn_at = (t > t_turn) & (t <= t_turn + turn_s)
    true_roll = np.where(in_turn_at, -bank_deg, 0.0)  # a left turn: left wing down, negative
    report = (np.arange(t.size) % 3 == 0)[None] & np.ones((n_runs, 1), bool)
    rolls = np.where(report, true_roll[None] + rng.standard_normal((n_runs, t.size)), np.nan)
    R = np.broadcast_to(80.0**2 * np.eye(2), (n_runs, 2, 2))
    x0 = np.broadcast_to(X0, (n_runs, 6)).copy()
    err: dict[str, list[np.ndarray]] = {"roll": [], "positions": []}
    turn_mu: dict[str, list[float]] = {"roll": [], "positions": []}
    for key in err:
        st = imm.initiate(x0, np.broadcast_to(P0, (n_runs, 6, 6)))
        for k in range(t.size):
            lf = (
                imm.roll_log_likelihoods(rolls[:, k], np.full(n_runs, 200.0), np.zeros(n_runs))
                if key == "roll"
                else None
            )
            st, x, _ = imm.predict_update(st, np.full(n_runs, dt), z_all[:, k], R, lf)
            err[key].append(np.sum((x[:, [0, 3]] - truth[k]) ** 2, axis=1))
            turn_mu[key].append(float(st.mu[:, [3, 5]].sum(axis=1).mean()))  # the left turns
    straight = (t > 60.0) & (t <= t_turn)
    turn_and_after = (t > t_turn) & (t <= t_turn + turn_s + 24.0)  # the roll-out's scans too
    rms = {k: {w_: math.sqrt(np.mean(np.array(e)[m])) for w_, m in (("turn", turn_and_after), ("straight", straight))}
           for k, e in err.items()}  # fmt: skip
    print(f"\nturn / straight RMS m: with roll {rms['roll']['turn']:.1f} / {rms['roll']['straight']:.1f}, "
          f"positions alone {rms['positions']['turn']:.1f} / {rms['positions']['straight']:.1f}")  # fmt: skip
    assert rms["roll"]["turn"] < 0.97 * rms["positions"]["turn"]
    assert rms["roll"]["straight"] < 1.02 * rms["positions"]["straight"]
    first = int(np.flatnonzero(in_turn_at & report[0])[0])  # the first report inside the turn
    assert turn_mu["roll"][first] > 0.9
    assert turn_mu["positions"][first] < 0.7
    out = int(np.flatnonzero((t > t_turn + turn_s) & report[0])[0])  # the first report after it
    assert turn_mu["roll"][out] < 0.1
    assert turn_mu["positions"][out] > 0.3


# ------------------------------------------------------------------ vectorisation


def _random_state(imm: IMMFilter, n: int, rng: np.random.Generator) -> IMMState:
    """Positive definite covariances D A Aᵀ D + diag, distinct per track and model."""
    d = np.array([30.0, 10.0, 1.0, 30.0, 10.0, 1.0])
    a = rng.normal(size=(n, imm.n_models, 6, 6)) * d[:, None]
    P = a @ np.swapaxes(a, 2, 3) + np.diag([2500.0, 400.0, 4.0, 2500.0, 400.0, 4.0])
    x = rng.normal(size=(n, imm.n_models, 6)) * np.array([5000.0, 150.0, 3.0, 5000.0, 150.0, 3.0])
    mu = rng.dirichlet(np.ones(imm.n_models), size=n)
    return IMMState(x, 0.5 * (P + np.swapaxes(P, 2, 3)), mu)


def test_batch_equals_one_track_runs() -> None:
    imm = IMMFilter()
    rng = np.random.default_rng(9)
    n = 7
    st = _random_state(imm, n, rng)
    dt1 = np.array([0.0, 0.5, 2.0, 4.0, 4.7, 8.0, 12.0])
    dt2 = rng.permutation(dt1) + 1.0
    z1 = st.x_models[:, 0, [0, 3]] + rng.normal(0.0, 80.0, (n, 2))
    z2 = z1 + rng.normal(0.0, 500.0, (n, 2))
    b = rng.normal(size=(n, 2, 2))
    R = b @ np.swapaxes(b, 1, 2) * 900.0 + 100.0 * np.eye(2)

    def cycle(s: IMMState, rows: slice) -> tuple[IMMState, np.ndarray, np.ndarray]:
        s = imm.update(imm.predict(s, dt1[rows]), z1[rows], R[rows])
        s = imm.update(imm.predict(s, dt2[rows]), z2[rows], R[rows])
        s = imm.predict(s, dt1[rows])  # and a coasting prediction
        x, P = imm.combine(s)
        return s, x, P

    batch, xb, Pb = cycle(st, slice(None))
    for i in range(n):
        one, x1, P1 = cycle(st.select(slice(i, i + 1)), slice(i, i + 1))
        np.testing.assert_allclose(batch.mu[i], one.mu[0], rtol=1e-12, atol=1e-15)
        np.testing.assert_allclose(batch.x_models[i], one.x_models[0], rtol=1e-12, atol=1e-9)
        np.testing.assert_allclose(batch.P_models[i], one.P_models[0], rtol=1e-12, atol=1e-9)
        np.testing.assert_allclose(xb[i], x1[0], rtol=1e-12, atol=1e-9)
        np.testing.assert_allclose(Pb[i], P1[0], rtol=1e-12, atol=1e-9)
    # the tracks really differ (different dt and μ): equality above is not trivial
    assert np.ptp(batch.mu[:, MANOEUVRE]) > 0.1


def test_batched_prediction_equals_each_models_own_predict() -> None:
    """predict() runs every model in one compiled pass per track (imm_kernels.py, Φ and Q
    laid out from model_terms); each model's own predict() (SingerFilter: Shu eq. 8, 11
    written out per block; CoordinatedTurnModel: on its 4-D sub-state, then lifted) on the
    mixed states of mix() (numpy, eq. 1-4 as batched products) gives the same, for dt = 0,
    small dt (the turn noise's series) and long ones. The kernel mixes with its own order
    of additions, and eq. 4 subtracts spreads of the model states (5 km apart here, so
    (x_i − x⁰)² ~ 10⁷ m² against P ~ 10⁴ m²): the two agree to ~1e-12 of P's scale,
    which is 1e-16 of the spread terms, not to the bit. One mixing over dt, as mix() does
    (switch_substeps 1; the sub-steps are the hand computation's, above)."""
    imm = IMMFilter(IMMParams(switch_substeps=1))
    rng = np.random.default_rng(21)
    n = 9
    st = _random_state(imm, n, rng)
    dt = np.array([0.0, 1e-3, 0.2, 0.5, 2.0, 4.0, 4.7, 12.0, 60.0])
    out = imm.predict(st, dt)
    c_bar, x0, P0 = imm.mix(st, dt)
    np.testing.assert_allclose(out.mu, c_bar, rtol=1e-14, atol=0)  # eq. 1: sums of six products, to round-off
    for j, model in enumerate(imm.models):
        x, P = model.predict(x0[:, j], P0[:, j], dt)
        scale = np.sqrt(np.diagonal(P, axis1=1, axis2=2))
        np.testing.assert_allclose(out.x_models[:, j], x, rtol=1e-13, atol=1e-9)
        np.testing.assert_allclose((out.P_models[:, j] - P) / (scale[:, :, None] * scale[:, None, :]), 0.0, atol=1e-11)
    # exactly symmetric (the kernel forms one triangle and mirrors it)
    np.testing.assert_array_equal(out.P_models, np.swapaxes(out.P_models, 2, 3))


def test_predict_position_equals_the_combined_prediction() -> None:
    """predict_position() (the engine's output: x and the x-y covariance) equals the
    combination (eq. 7-8) of the full prediction, restricted to x and y. It mixes once over
    dt whatever switch_substeps (a view for output, imm.py "Switching inside the
    interval"): the full prediction with one sub-step."""
    imm = IMMFilter(IMMParams(switch_substeps=1))
    rng = np.random.default_rng(23)
    st = _random_state(imm, 9, rng)
    dt = np.array([0.0, 1e-3, 0.2, 0.5, 2.0, 4.0, 4.7, 12.0, 60.0])
    x, P_xy = imm.predict_position(st, dt)
    xc, Pc = imm.combine(imm.predict(st, dt))
    np.testing.assert_allclose(x, xc, rtol=1e-13, atol=1e-9)
    np.testing.assert_allclose(P_xy, Pc[:, [0, 3]][:, :, [0, 3]], rtol=1e-12, atol=1e-9)
    np.testing.assert_array_equal(P_xy, np.swapaxes(P_xy, 1, 2))


def test_predict_gate_equals_the_full_prediction_on_what_association_reads() -> None:
    """predict_gate() (association's prediction) gives each model's predicted position and
    its covariance, and the combination's position and velocity block, as the full
    prediction does (predict(), checked against the hand computation above), and NaN in
    the entries it does not form. One mixing over dt, as predict_position."""
    imm = IMMFilter(IMMParams(switch_substeps=1))
    rng = np.random.default_rng(29)
    st = _random_state(imm, 9, rng)
    dt = np.array([0.0, 1e-3, 0.2, 0.5, 2.0, 4.0, 4.7, 12.0, 60.0])
    x, P, xy, cov = imm.predict_gate(st, dt)
    full = imm.predict(st, dt)
    xc, Pc = imm.combine(full)
    np.testing.assert_allclose(xy, full.x_models[:, :, [0, 3]], rtol=1e-13, atol=1e-9)
    np.testing.assert_allclose(cov, full.P_models[:, :, [0, 3]][:, :, :, [0, 3]], rtol=1e-12, atol=1e-9)
    np.testing.assert_allclose(x, xc, rtol=1e-13, atol=1e-9)
    block = np.array([0, 1, 3, 4])
    np.testing.assert_allclose(P[:, block][:, :, block], Pc[:, block][:, :, block], rtol=1e-12, atol=1e-9)
    other = np.array([2, 5])
    assert np.isnan(P[:, other]).all() and np.isnan(P[:, :, other]).all()


def test_gate_and_output_views_mix_once_whatever_the_substeps() -> None:
    """predict_gate() and predict_position() mix once over their span (imm.py, "Switching
    inside the interval"): with the default three sub-steps they give what the filter with
    one gives, while the cycle's own prediction (predict()) differs from that one."""
    three, one = IMMFilter(), IMMFilter(IMMParams(switch_substeps=1))
    assert three.params.switch_substeps == 3
    rng = np.random.default_rng(37)
    st = _random_state(three, 9, rng)
    dt = np.array([0.0, 1e-3, 0.2, 0.5, 2.0, 4.0, 4.7, 12.0, 60.0])
    for a, b in zip(three.predict_gate(st, dt), one.predict_gate(st, dt)):
        np.testing.assert_array_equal(a, b)
    x3, P3 = three.predict_position(st, dt)
    xc, Pc = one.combine(one.predict(st, dt))
    np.testing.assert_allclose(x3, xc, rtol=1e-13, atol=1e-9)
    np.testing.assert_allclose(P3, Pc[:, [0, 3]][:, :, [0, 3]], rtol=1e-12, atol=1e-9)
    cycle = three.predict(st, dt)
    assert np.abs(cycle.mu[5:] - one.predict(st, dt).mu[5:]).max() > 1e-4  # the sub-steps do differ


def test_predict_update_equals_update_of_predict() -> None:
    """predict_update() (the engine's cycle for a track with a plot) is combine(update(
    predict(...))) in one pass."""
    imm = IMMFilter()
    rng = np.random.default_rng(31)
    st = _random_state(imm, 9, rng)
    dt = np.array([0.0, 1e-3, 0.2, 0.5, 2.0, 4.0, 4.7, 12.0, 60.0])
    z = st.x_models[:, 0, [0, 3]] + rng.normal(0.0, 300.0, (9, 2))
    b = rng.normal(size=(9, 2, 2))
    R = b @ np.swapaxes(b, 1, 2) * 900.0 + 100.0 * np.eye(2)
    one, x1, P1 = imm.predict_update(st, dt, z, R)
    two = imm.update(imm.predict(st, dt), z, R)
    x2, P2 = imm.combine(two)
    np.testing.assert_allclose(one.mu, two.mu, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(one.x_models, two.x_models, rtol=1e-13, atol=1e-9)
    np.testing.assert_allclose(one.P_models, two.P_models, rtol=1e-12, atol=1e-9)
    np.testing.assert_allclose(x1, x2, rtol=1e-13, atol=1e-9)
    np.testing.assert_allclose(P1, P2, rtol=1e-12, atol=1e-9)


def test_row_variants_work_in_place_on_the_chosen_rows_only() -> None:
    """predict_update_rows() updates the chosen rows of a track table's columns in place,
    as predict_update() of those rows would, and leaves the other rows as they were;
    predict_position_rows() is predict_position() of the chosen rows."""
    imm = IMMFilter()
    rng = np.random.default_rng(37)
    st = _random_state(imm, 12, rng)
    rows = np.array([7, 2, 10, 3])
    dt = rng.uniform(0.5, 8.0, rows.size)
    z = st.x_models[rows, 0][:, [0, 3]] + rng.normal(0.0, 200.0, (rows.size, 2))
    R = np.broadcast_to(R50, (rows.size, 2, 2)).copy()
    x_p, P_p = imm.predict_position_rows(st, rows, dt)
    x_sel, P_sel = imm.predict_position(st.select(rows), dt)
    np.testing.assert_array_equal(x_p, x_sel)
    np.testing.assert_array_equal(P_p[:, [0, 3]][:, :, [0, 3]], P_sel)
    assert np.isnan(P_p[:, [1, 2, 4, 5]]).all()  # the rest of P is not formed
    want, x_w, P_w = imm.predict_update(st.select(rows), dt, z, R)
    before = st.select(slice(None))
    x_u, P_u = imm.predict_update_rows(st, rows, dt, z, R)
    np.testing.assert_array_equal(x_u, x_w)
    np.testing.assert_array_equal(P_u, P_w)
    np.testing.assert_array_equal(st.x_models[rows], want.x_models)
    np.testing.assert_array_equal(st.P_models[rows], want.P_models)
    np.testing.assert_array_equal(st.mu[rows], want.mu)
    others = np.setdiff1d(np.arange(12), rows)
    np.testing.assert_array_equal(st.P_models[others], before.P_models[others])
    np.testing.assert_array_equal(st.mu[others], before.mu[others])
    with pytest.raises(ValueError, match="in place"):
        imm.predict_update_rows(IMMState(st.x_models[:, :, ::-1], st.P_models, st.mu), rows, dt, z, R)


def test_degenerate_inputs_give_nan_not_an_exception() -> None:
    """A singular innovation covariance (zero P and R) divides by zero: the compiled loops
    give NaN as numpy would (compiled.py, error_model), and raise nothing that would stop
    the daemon's processing thread; healthy tracks in the same batch are unaffected."""
    imm = IMMFilter()
    st = imm.initiate(np.zeros((2, 6)), np.stack([np.zeros((6, 6)), P0]))
    R = np.stack([np.zeros((2, 2)), R50])
    out, x, P = imm.predict_update(st, np.array([0.0, 4.0]), np.zeros((2, 2)), R)
    assert np.isnan(x[0]).all() and np.isnan(out.mu[0]).all()
    assert np.isfinite(x[1]).all() and np.isfinite(P[1]).all()
    np.testing.assert_allclose(out.mu[1].sum(), 1.0)


# ------------------------------------------------------------------ cost (printed, not asserted)


def test_print_cost_at_4000_tracks() -> None:
    n = 4000
    rng = np.random.default_rng(0)
    imm = IMMFilter()
    singer = SingerFilter()
    st = _random_state(imm, n, rng)
    x, P = imm.combine(st)
    dt = rng.uniform(3.5, 4.5, n)
    z = x[:, [0, 3]] + rng.normal(0.0, 50.0, (n, 2))
    R = np.broadcast_to(R50, (n, 2, 2)).copy()
    t_imm, t_singer = [], []
    for _ in range(15):  # interleaved, best of 15: the machine is shared
        t0 = time.perf_counter()
        out = imm.update(imm.predict(st, dt), z, R)
        t1 = time.perf_counter()
        singer.update(*singer.predict(x, P, dt), z, R)
        t2 = time.perf_counter()
        t_imm.append(t1 - t0)
        t_singer.append(t2 - t1)
    a, b = min(t_imm), min(t_singer)
    print(f"\nN={n}: IMM predict+update {a * 1e3:.1f} ms, Singer {b * 1e3:.1f} ms, ratio {a / b:.1f}")
    # what was timed is a valid result (not asserted on time)
    assert np.isfinite(out.P_models).all()
    np.testing.assert_allclose(out.mu.sum(axis=1), 1.0, rtol=1e-12)


def test_mixed_covariances_are_exactly_symmetric() -> None:
    """mix() leaves out a symmetrisation: eq. 4 as formed there is symmetric to the bit when
    the model covariances are (every (k, l) and (l, k) term is computed the same way)."""
    imm = IMMFilter()
    st = _random_state(imm, 300, np.random.default_rng(12))
    st.x_models *= 30.0  # model states far apart, positions of 10⁵ m
    _, _, P0 = imm.mix(st, np.random.default_rng(1).uniform(0.0, 12.0, 300))
    np.testing.assert_array_equal(P0, np.swapaxes(P0, 2, 3))
    assert (np.linalg.eigvalsh(P0) > 0).all()


@pytest.mark.slow  # a child interpreter compiles every kernel afresh: ~20 s, a sixth of the fast tier
def test_kernels_run_uncached_where_no_cache_directory_is_writable() -> None:
    """A read-only install run by a user without a writable cache directory: numba refuses
    cache=True at import ("no locator available"; forced here by allowing only its zip
    locator), and the kernels are compiled in the process instead (compiled.py).
    The results are those of the cached kernels."""
    import json
    import os
    import subprocess
    import sys

    code = (
        "import json, numpy as np\n"
        "from radar_fusion.tracking.imm import IMMFilter\n"
        "from radar_fusion.tracking import imm_kernels\n"
        "f = IMMFilter()\n"
        "assert imm_kernels.predict_kernel._cache.__class__.__name__ == 'NullCache'\n"
        "P = np.diag([2500.0, 400, 4, 2500, 400, 4])[None]\n"
        "st = f.initiate(np.array([[1e4, 200.0, 0.5, -3e4, 10.0, 0.0]]), P)\n"
        "st = f.update(f.predict(st, np.array([4.0])), np.array([[1.08e4, -2.99e4]]), 2500.0 * np.eye(2)[None])\n"
        "print(json.dumps([st.x_models.tolist(), st.mu.tolist()]))\n"
    )
    env = {**os.environ, "NUMBA_CACHE_LOCATOR_CLASSES": "ZipCacheLocator"}
    env.pop("NUMBA_CACHE_DIR", None)
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    x_models, mu = json.loads(out.stdout.strip().splitlines()[-1])
    f = IMMFilter()
    st = f.initiate(np.array([[1e4, 200.0, 0.5, -3e4, 10.0, 0.0]]), np.diag([2500.0, 400, 4, 2500, 400, 4])[None])
    st = f.update(f.predict(st, np.array([4.0])), np.array([[1.08e4, -2.99e4]]), 2500.0 * np.eye(2)[None])
    np.testing.assert_allclose(x_models, st.x_models, rtol=1e-12)
    np.testing.assert_allclose(mu, st.mu, rtol=1e-12)


def test_threads_give_the_same_tracks_to_the_bit() -> None:
    """imm_threads > 1 runs the per-track kernels on shares of the rows at once (the
    engine's association prediction, output prediction and update in place): every result
    equals the one-thread run's exactly, the rows given in any order, and rows the update
    does not list stay untouched. Three threads over 1,000 rows: three shares."""
    one, three = IMMFilter(), IMMFilter(threads=3)
    assert three.threads == 3 and three._pool is not None
    handed: list[int] = []  # the shares handed to the pool's two threads
    submit = three._pool.submit
    three._pool.submit = lambda fn, a, b: (handed.append(b - a), submit(fn, a, b))[1]  # type: ignore[method-assign]
    rng = np.random.default_rng(31)
    n = 1_100
    st = _random_state(one, n, rng)
    dt = rng.uniform(0.0, 12.0, n)
    for a, b in zip(one.predict_gate(st, dt), three.predict_gate(st, dt)):
        np.testing.assert_array_equal(a, b)
    rows = rng.permutation(n)[:1_000]
    for a, b in zip(one.predict_position_rows(st, rows, dt[rows]), three.predict_position_rows(st, rows, dt[rows])):
        np.testing.assert_array_equal(a, b)
    z = st.x_models[rows, 0][:, [0, 3]] + rng.normal(0.0, 80.0, (rows.size, 2))
    R = np.broadcast_to(900.0 * np.eye(2), (rows.size, 2, 2))
    s1, s3 = st.select(slice(None)), st.select(slice(None))
    r1 = one.predict_update_rows(s1, rows, dt[rows], z, R)
    r3 = three.predict_update_rows(s3, rows, dt[rows], z, R)
    for a, b in zip(r1, r3):
        np.testing.assert_array_equal(a, b)
    for a, b in ((s1.x_models, s3.x_models), (s1.P_models, s3.P_models), (s1.mu, s3.mu)):
        np.testing.assert_array_equal(a, b)
    untouched = np.setdiff1d(np.arange(n), rows)
    np.testing.assert_array_equal(s3.x_models[untouched], st.x_models[untouched])
    assert not np.array_equal(s3.x_models[rows], st.x_models[rows])  # the update did happen
    assert handed == [367, 367, 333, 334, 333, 334]  # two shares of three per call, three calls
