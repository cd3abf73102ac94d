"""Tests of radar_fusion.tracking.fusion (Shu eq. 5–6 and the information-form generalisation)."""

import numpy as np
import pytest

from radar_fusion.tracking.fusion import (
    contradicting_pairs,
    fuse_clusters,
    fuse_common_velocity,
    leave_one_out_outliers,
)


def polar_cov(range_m, az_rad, sigma_r_m, sigma_az_rad):
    """Cartesian covariance of a radar plot (azimuth from north, clockwise)."""
    # x = r sin θ, y = r cos θ: Jacobian columns d/dr, d/dθ
    J = np.array([[np.sin(az_rad), range_m * np.cos(az_rad)], [np.cos(az_rad), -range_m * np.sin(az_rad)]])
    return J @ np.diag([sigma_r_m**2, sigma_az_rad**2]) @ J.T


def test_scalar_weights_match_hand_computation_of_eq6():
    # three isotropic plots, σ_w = 50, 100, 200 m
    z = np.array([[1000.0, 2000.0], [1100.0, 1900.0], [700.0, 2300.0]])
    s2 = np.array([50.0, 100.0, 200.0]) ** 2
    R = s2[:, None, None] * np.eye(2)
    zf, Rf, n = fuse_clusters(np.zeros(3, int), z, R, 1, "scalar")
    # eq. 6 by hand: 1/σ² = 1/2500, 1/10000, 1/40000; Σ = (16 + 4 + 1)/40000 = 21/40000
    alpha = np.array([16.0, 4.0, 1.0]) / 21.0
    assert alpha.sum() == pytest.approx(1.0)
    np.testing.assert_allclose(zf[0], alpha @ z, rtol=1e-14)  # eq. 5
    # Σ α_i² σ_i² = 1 / Σ 1/σ_i² = 40000/21
    np.testing.assert_allclose(Rf[0], np.eye(2) * 40000.0 / 21.0, rtol=1e-13)
    assert n[0] == 3


def test_scalar_weights_sum_to_one_and_sigma_w2_is_mean_eigenvalue():
    """Fusing the same point with any R returns that point: the weights sum to 1.

    With anisotropic R_i, σ_w²(i) = trace(R_i)/2 gives the weights; check one by hand."""
    rng = np.random.default_rng(0)
    m = 7
    A = rng.normal(size=(m, 2, 2)) * 80
    R = A @ np.swapaxes(A, 1, 2) + 100 * np.eye(2)
    p = np.array([3.0e4, -1.2e4])
    zf, _, _ = fuse_clusters(np.zeros(m, int), np.tile(p, (m, 1)), R, 1, "scalar")
    np.testing.assert_allclose(zf[0], p, rtol=1e-14)
    # unit-vector trick: weight of plot j is the fused value when only z_j = 1
    s2 = np.array([np.trace(r) / 2 for r in R])
    alpha = (1 / s2) / np.sum(1 / s2)
    for j in range(m):
        z = np.zeros((m, 2))
        z[j] = [1.0, 0.0]
        zf, Rf, _ = fuse_clusters(np.zeros(m, int), z, R, 1, "scalar")
        assert zf[0, 0] == pytest.approx(alpha[j], rel=1e-12)
    np.testing.assert_allclose(Rf[0], np.einsum("i,ijk->jk", alpha**2, R), rtol=1e-12)


def test_scalar_equals_matrix_for_isotropic_covariances():
    rng = np.random.default_rng(1)
    m, k = 40, 9
    labels = rng.integers(0, k, m)
    z = rng.normal(0, 1e4, (m, 2))
    R = rng.uniform(30, 300, m)[:, None, None] ** 2 * np.eye(2)
    zs, Rs, ns = fuse_clusters(labels, z, R, k, "scalar")
    zm, Rm, nm = fuse_clusters(labels, z, R, k, "matrix")
    ok = ns > 0
    np.testing.assert_allclose(zs[ok], zm[ok], rtol=1e-12)
    np.testing.assert_allclose(Rs[ok], Rm[ok], rtol=1e-10, atol=1e-9)
    np.testing.assert_array_equal(ns, nm)


def three_radar_plots():
    """One aircraft seen by three radars from different directions: elongated R_i."""
    Rs = [
        polar_cov(60e3, np.radians(30), 50.0, np.radians(0.08)),
        polar_cov(120e3, np.radians(140), 70.0, np.radians(0.07)),
        polar_cov(40e3, np.radians(260), 40.0, np.radians(0.1)),
    ]
    return np.array(Rs)


@pytest.mark.parametrize("method", ["scalar", "matrix"])
def test_monte_carlo_covariance_matches_r_fused(method):
    """Many draws, each as its own cluster: empirical fused-error covariance ≈ R_fused."""
    rng = np.random.default_rng(2)
    R3 = three_radar_plots()
    n_draws = 20000
    truth = np.array([1.5e4, -2.5e4])
    err = np.stack([rng.multivariate_normal([0, 0], r, n_draws) for r in R3], axis=1)
    z = (truth + err).reshape(-1, 2)  # draw-major: plots of draw d are 3d, 3d+1, 3d+2
    labels = np.repeat(np.arange(n_draws), 3)
    R = np.tile(R3, (n_draws, 1, 1))
    zf, Rf, n = fuse_clusters(labels, z, R, n_draws, method)
    assert np.all(n == 3)
    np.testing.assert_allclose(Rf, np.broadcast_to(Rf[0], Rf.shape), rtol=1e-12)
    e = zf - truth
    C = e.T @ e / n_draws
    Li = np.linalg.inv(np.linalg.cholesky(Rf[0]))
    # whitened empirical covariance ≈ I; sampling error ~ sqrt(2/n) ≈ 0.01
    np.testing.assert_allclose(Li @ C @ Li.T, np.eye(2), atol=0.04)
    np.testing.assert_allclose(e.mean(0) @ Li.T, 0, atol=0.03)


def test_matrix_fused_covariance_never_larger_than_scalar():
    rng = np.random.default_rng(3)
    k = 500
    n_per = rng.integers(1, 6, k)
    labels = np.repeat(np.arange(k), n_per)
    m = labels.size
    ranges = rng.uniform(5e3, 250e3, m)
    az = rng.uniform(0, 2 * np.pi, m)
    R = np.array(
        [polar_cov(r, a, rng.uniform(30, 120), np.radians(rng.uniform(0.05, 0.2))) for r, a in zip(ranges, az)]
    )
    z = rng.normal(0, 1e5, (m, 2))
    _, Rs, _ = fuse_clusters(labels, z, R, k, "scalar")
    _, Rm, _ = fuse_clusters(labels, z, R, k, "matrix")
    d = np.linalg.eigvalsh(Rs - Rm)
    assert np.all(d >= -1e-9 * np.linalg.eigvalsh(Rs).max(axis=1, keepdims=True))
    # strictly better somewhere (elongated, differently oriented R_i)
    assert np.mean(d.max(axis=1) > 1e-3 * np.trace(Rs, axis1=1, axis2=2)) > 0.5

    # and the empirical errors agree: for one 3-radar cluster, Monte Carlo Cov_scalar −
    # Cov_matrix is PSD within sampling error
    R3 = three_radar_plots()
    n_draws = 20000
    err = np.stack([rng.multivariate_normal([0, 0], r, n_draws) for r in R3], axis=1)
    lab = np.repeat(np.arange(n_draws), 3)
    es, _, _ = fuse_clusters(lab, err.reshape(-1, 2), np.tile(R3, (n_draws, 1, 1)), n_draws, "scalar")
    em, _, _ = fuse_clusters(lab, err.reshape(-1, 2), np.tile(R3, (n_draws, 1, 1)), n_draws, "matrix")
    Cs, Cm = es.T @ es / n_draws, em.T @ em / n_draws
    assert np.linalg.eigvalsh(Cs - Cm).min() > -0.05 * np.trace(Cm)


def test_fused_variance_below_best_single_plot():
    R3 = three_radar_plots()
    z = np.zeros((3, 2))
    _, Rs, _ = fuse_clusters(np.zeros(3, int), z, R3, 1, "scalar")
    _, Rm, _ = fuse_clusters(np.zeros(3, int), z, R3, 1, "matrix")
    best_trace = min(np.trace(r) for r in R3)
    assert np.trace(Rs[0]) < best_trace
    # matrix form: R_f ≤ every R_i in the PSD order
    for r in R3:
        assert np.linalg.eigvalsh(r - Rm[0]).min() > 0


def test_vectorised_equals_per_cluster_loop_with_ignored_and_empty_clusters():
    rng = np.random.default_rng(4)
    k, m = 12, 60
    labels = rng.integers(-1, k - 2, m)  # clusters k−2, k−1 stay empty; −1 ignored
    z = rng.normal(0, 5e4, (m, 2))
    R = np.array([polar_cov(rng.uniform(5e3, 2e5), rng.uniform(0, 6.3), 60.0, np.radians(0.1)) for _ in range(m)])
    for method in ("scalar", "matrix"):
        zf, Rf, n = fuse_clusters(labels, z, R, k, method)
        for c in range(k):
            sel = labels == c
            assert n[c] == sel.sum()
            if not sel.any():
                assert np.all(np.isnan(zf[c])) and np.all(np.isnan(Rf[c]))
                continue
            zc, Rc = z[sel], R[sel]
            if method == "scalar":
                inv_s2 = np.array([2.0 / np.trace(r) for r in Rc])
                a = inv_s2 / inv_s2.sum()
                zr = sum(ai * zi for ai, zi in zip(a, zc))
                Rr = sum(ai**2 * ri for ai, ri in zip(a, Rc))
            else:
                info = sum(np.linalg.inv(r) for r in Rc)
                Rr = np.linalg.inv(info)
                zr = Rr @ sum(np.linalg.solve(r, zi) for r, zi in zip(Rc, zc))
            np.testing.assert_allclose(zf[c], zr, rtol=1e-9, atol=1e-6)
            np.testing.assert_allclose(Rf[c], Rr, rtol=1e-9, atol=1e-9 * np.abs(Rr).max())


def test_single_plot_cluster_passes_through_and_bad_input_rejected():
    R = np.array([[[400.0, 30.0], [30.0, 900.0]]])
    for method in ("scalar", "matrix"):
        zf, Rf, n = fuse_clusters([0], [[5.0, 6.0]], R, 1, method)
        np.testing.assert_allclose(zf[0], [5.0, 6.0])
        np.testing.assert_allclose(Rf[0], R[0], rtol=1e-12)
    with pytest.raises(ValueError):
        fuse_clusters([0], [[0.0, 0.0]], R, 1, "mean")
    with pytest.raises(ValueError):
        fuse_clusters([1], [[0.0, 0.0]], R, 1)
    zf, Rf, n = fuse_clusters(np.zeros(0, int), np.zeros((0, 2)), np.zeros((0, 2, 2)), 2)
    assert zf.shape == (2, 2) and np.all(np.isnan(zf)) and np.all(n == 0)


def _loo_reference(z, R, gate):
    """Leave-one-out by hand for one cluster: per plot, the others fused with np.linalg.inv,
    d² against the plot; the largest flagged if above the gate."""
    d2 = []
    for i in range(len(z)):
        others = [j for j in range(len(z)) if j != i]
        info = sum(np.linalg.inv(R[j]) for j in others)
        R_o = np.linalg.inv(info)
        z_o = R_o @ sum(np.linalg.inv(R[j]) @ z[j] for j in others)
        y = z[i] - z_o
        d2.append(float(y @ np.linalg.inv(R[i] + R_o) @ y))
    out = np.zeros(len(z), bool)
    k = int(np.argmax(d2))
    out[k] = d2[k] > gate
    return out, d2


def test_leave_one_out_flags_the_wild_plot_of_a_new_target_as_a_loop_by_hand():
    rng = np.random.default_rng(3)
    gate = 13.8155
    for trial in range(200):
        n = int(rng.integers(3, 6))
        z = rng.normal(0.0, 150.0, (n, 2))
        a = rng.normal(size=(n, 2, 2)) * 120.0
        R = a @ np.swapaxes(a, 1, 2) + 50.0**2 * np.eye(2)
        if trial % 2:
            z[int(rng.integers(n))] += rng.uniform(1_000.0, 3_000.0) * np.array([np.cos(trial), np.sin(trial)])
        got = leave_one_out_outliers(np.zeros(n, np.intp), z, R, np.array([True]), 1, gate)
        want, d2 = _loo_reference(z, R, gate)
        np.testing.assert_array_equal(got, want, err_msg=str(d2))
    # several clusters at once: one of two plots is never judged, unchecked clusters neither
    z = np.array(
        [[0.0, 0.0], [50.0, 0.0], [2_500.0, 0.0], [0.0, 0.0], [3_000.0, 0.0], [0.0, 0.0], [0.0, 10.0], [5e3, 0]]
    )
    R = np.broadcast_to(100.0**2 * np.eye(2), (8, 2, 2)).copy()
    labels = np.array([0, 0, 0, 1, 1, 2, 2, 2])
    got = leave_one_out_outliers(labels, z, R, np.array([True, True, False]), 3, gate)
    assert got.tolist() == [False, False, True, False, False, False, False, False]


def test_contradicting_pairs_against_a_loop_by_hand():
    """Both plots of a checked cluster of exactly two plots of one Mode S address whose
    distance, in the metric of their summed covariance (np.linalg.solve), is beyond the
    gate; clusters of one or three plots, of two addresses or none, and unchecked ones never."""
    rng = np.random.default_rng(5)
    gate = 13.8155
    n_cl = 60
    sizes = rng.integers(1, 4, n_cl)
    labels = np.repeat(np.arange(n_cl), sizes)
    m = labels.size
    z = rng.normal(0.0, 100.0, (m, 2)) + 1e4 * labels[:, None]
    wild = rng.random(m) < 0.3
    z[wild] += rng.uniform(300.0, 3_000.0, (int(wild.sum()), 1)) * np.array([[0.6, 0.8]])
    a = rng.normal(size=(m, 2, 2)) * 80.0
    R = a @ np.swapaxes(a, 1, 2) + 40.0**2 * np.eye(2)
    mode_s = np.where(rng.random(m) < 0.8, 0x3C0000 + labels, -1)
    mode_s[rng.random(m) < 0.1] = 0x400000  # another address
    check = rng.random(n_cl) < 0.8
    got = contradicting_pairs(labels, z, R, mode_s, check, n_cl, gate)
    want = np.zeros(m, bool)
    for c in range(n_cl):
        i = np.flatnonzero(labels == c)
        if not check[c] or i.size != 2 or mode_s[i[0]] < 0 or mode_s[i[0]] != mode_s[i[1]]:
            continue
        y = z[i[0]] - z[i[1]]
        want[i] = y @ np.linalg.solve(R[i[0]] + R[i[1]], y) > gate
    assert want.sum() >= 4 and (~want & (np.bincount(labels)[labels] == 2)).sum() >= 4
    np.testing.assert_array_equal(got, want)


# ------------------------------------------------------------------ plots of one period at different times
def _stacked_lsq(z, R, dt, v0, P_vv):
    """Reference for fuse_common_velocity: the state s = (p, v) at the cluster's time by a
    whitened stacked least squares (numpy's lstsq), the velocity prior as two more rows,
    and the covariance of s as the inverse of the whole 4×4 information matrix."""
    rows, rhs = [], []
    for zi, Ri, dti in zip(z, R, dt):
        W = np.linalg.inv(np.linalg.cholesky(Ri))  # W R W^T = I
        rows.append(W @ np.hstack([np.eye(2), dti * np.eye(2)]))
        rhs.append(W @ zi)
    Wv = np.linalg.inv(np.linalg.cholesky(P_vv))
    rows.append(Wv @ np.hstack([np.zeros((2, 2)), np.eye(2)]))
    rhs.append(Wv @ v0)
    A, b = np.vstack(rows), np.concatenate(rhs)
    s = np.linalg.lstsq(A, b, rcond=None)[0]
    cov = np.linalg.inv(A.T @ A)
    return s[:2], cov[:2, :2]


def test_common_velocity_fusion_equals_a_stacked_least_squares_per_cluster():
    rng = np.random.default_rng(11)
    R3 = three_radar_plots()
    n_clusters = 4
    labels = np.array([0, 0, 0, 2, 2, 3])  # cluster 1 has no plot
    z = rng.normal(0.0, 5e3, (labels.size, 2))
    R = np.concatenate([R3, R3[:2], R3[2:]])
    dt = np.array([-1.7, 0.4, 1.9, -2.0, 2.0, 0.0])
    v0 = rng.normal(0.0, 100.0, (n_clusters, 2))
    P_vv = np.array([np.diag([4e4, 3e4]), np.eye(2), [[2e4, 5e3], [5e3, 1e4]], np.eye(2) * 4e4])
    zf, Rf = fuse_common_velocity(labels, z, R, dt, v0, P_vv, n_clusters)
    for c in (0, 2, 3):
        m = labels == c
        z_ref, R_ref = _stacked_lsq(z[m], R[m], dt[m], v0[c], P_vv[c])
        np.testing.assert_allclose(zf[c], z_ref, rtol=0, atol=1e-6)
        np.testing.assert_allclose(Rf[c], R_ref, rtol=1e-9)
    assert np.isnan(zf[1]).all() and np.isnan(Rf[1]).all()
    # one plot at dt = 0: the plot itself, whatever the velocity
    np.testing.assert_allclose(zf[3], z[5], atol=1e-9)
    np.testing.assert_allclose(Rf[3], R[5], rtol=1e-9)


def test_common_velocity_fusion_at_one_time_is_the_matrix_fusion():
    R3 = three_radar_plots()
    z = np.array([[100.0, 50.0], [-30.0, 80.0], [60.0, -40.0]])
    labels = np.zeros(3, int)
    zf, Rf = fuse_common_velocity(labels, z, R3, np.zeros(3), np.zeros((1, 2)), np.eye(2)[None] * 4e4, 1)
    zm, Rm, _ = fuse_clusters(labels, z, R3, 1, "matrix")
    np.testing.assert_allclose(zf, zm, atol=1e-9)
    np.testing.assert_allclose(Rf, Rm, rtol=1e-9)


def test_common_velocity_fusion_is_honest_and_beats_aligning_each_plot_on_its_own():
    """A new target (velocity drawn from the prior the engine uses, v_max²/3 per axis) seen
    by three radars at different times of one period. The joint estimate's error has the
    covariance R_f it reports (whitened ≈ I). Aligning each plot to the cluster's time on
    its own, with the velocity's variance dt²·σ_v² added to its R as if independent (the
    engine's alignment with a track's velocity), gives a larger error: the velocity is one
    and the same for all three plots."""
    rng = np.random.default_rng(5)
    R3 = three_radar_plots()
    dt = np.array([-1.6, 0.3, 1.5])
    var_v = 350.0**2 / 3.0
    n = 20000
    v = rng.normal(0.0, np.sqrt(var_v), (n, 2))
    p = rng.normal(0.0, 1e4, (n, 2))
    noise = np.stack([rng.multivariate_normal([0, 0], r, n) for r in R3], axis=1)
    z = (p[:, None, :] + v[:, None, :] * dt[None, :, None] + noise).reshape(-1, 2)
    labels = np.repeat(np.arange(n), 3)
    R = np.tile(R3, (n, 1, 1))
    dts = np.tile(dt, n)
    zf, Rf = fuse_common_velocity(labels, z, R, dts, np.zeros((n, 2)), np.tile(np.eye(2) * var_v, (n, 1, 1)), n)
    e = zf - p
    Li = np.linalg.inv(np.linalg.cholesky(Rf[0]))
    np.testing.assert_allclose(Li @ (e.T @ e / n) @ Li.T, np.eye(2), atol=0.05)
    z_ind, _, _ = fuse_clusters(labels, z, R + dts[:, None, None] ** 2 * var_v * np.eye(2), n, "matrix")
    mse_joint = np.mean(np.sum(e**2, axis=1))
    mse_ind = np.mean(np.sum((z_ind - p) ** 2, axis=1))
    assert mse_joint < 0.5 * mse_ind, (mse_joint, mse_ind)  # 0.17 with this seed


def test_common_velocity_fusion_reads_covariances_as_symmetric():
    """A covariance given with unequal off-diagonal entries (rounding, a caller's slip) is
    taken as its symmetric part: the result does not depend on which triangle is used."""
    R3 = three_radar_plots()
    z = np.array([[100.0, 50.0], [-30.0, 80.0], [60.0, -40.0]])
    labels, dt = np.zeros(3, int), np.array([-1.5, 0.2, 1.4])
    P_vv = np.array([[[4e4, 9e3], [-1e3, 3e4]]])
    skew = R3.copy()
    skew[:, 0, 1] += 50.0
    skew[:, 1, 0] -= 50.0
    a = fuse_common_velocity(labels, z, skew, dt, np.zeros((1, 2)), P_vv, 1)
    b = fuse_common_velocity(labels, z, np.swapaxes(skew, 1, 2), dt, np.zeros((1, 2)), np.swapaxes(P_vv, 1, 2), 1)
    c = fuse_common_velocity(labels, z, R3, dt, np.zeros((1, 2)), 0.5 * (P_vv + np.swapaxes(P_vv, 1, 2)), 1)
    for x, y in ((a, b), (a, c)):
        np.testing.assert_allclose(x[0], y[0], atol=1e-9)
        np.testing.assert_allclose(x[1], y[1], rtol=1e-9)
