"""Tests of radar_fusion.tracking.clustering: time alignment and k-means clustering (Shu 2007 §2).

Each test compares with known truth or with an independent computation written here with
plain loops (brute-force E of eq. 2, dense assignment by scipy's linear_sum_assignment).
"""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from scipy.optimize import linear_sum_assignment

from radar_fusion.tracking.association import align_to_reference, assign_per_radar, transfer_rho, unique_inverse
from radar_fusion.tracking.clustering import CHI2_2DOF_P999, ClusteringParams, cluster_plots

T_REF = 100.0
NM_M = 1852.0


# --------------------------------------------------------------------------------------
# helpers


def brute_force_sse(points_by_cluster):
    """E of eq. 2 by plain loops; each cluster is a list of (x, y, weight)."""
    e = 0.0
    for pts in points_by_cluster:
        w_sum = sum(w for _, _, w in pts)
        mx = sum(w * x for x, _, w in pts) / w_sum
        my = sum(w * y for _, y, w in pts) / w_sum
        for x, y, w in pts:
            e += w * ((x - mx) ** 2 + (y - my) ** 2)
    return e


def result_sse(labels, cluster_track, plots, tracks, anchor_weight=1.0):
    """E of a labelling, with positions aligned here (z + v_j·dt) and track anchors."""
    xy, _, t, *_ = plots
    t_xy, t_v = tracks[0], tracks[1]
    clusters = []
    for c, j in enumerate(cluster_track):
        pts = []
        for p in range(len(labels)):
            if labels[p] != c:
                continue
            if j >= 0:
                dt = T_REF - t[p]
                pts.append((xy[p, 0] + t_v[j, 0] * dt, xy[p, 1] + t_v[j, 1] * dt, 1.0))
            else:
                pts.append((xy[p, 0], xy[p, 1], 1.0))
        if j >= 0:
            pts.append((t_xy[j, 0], t_xy[j, 1], anchor_weight))
        clusters.append(pts)
    return brute_force_sse(clusters)


def make_tracks(xy, v=None, sigma_pos_m=150.0, sigma_vel_mps=10.0, mode_s=None, mode3a=None):
    xy = np.asarray(xy, dtype=float).reshape(-1, 2)
    n = xy.shape[0]
    v = np.zeros((n, 2)) if v is None else np.asarray(v, dtype=float).reshape(n, 2)
    cp = np.tile(sigma_pos_m**2 * np.eye(2), (n, 1, 1))
    cv = np.tile(sigma_vel_mps**2 * np.eye(2), (n, 1, 1))
    ms = np.full(n, -1, dtype=np.int64) if mode_s is None else np.asarray(mode_s, np.int64)
    m3 = np.full(n, -1, dtype=np.int64) if mode3a is None else np.asarray(mode3a, np.int64)
    return xy, v, cp, cv, ms, m3


NO_TRACKS = make_tracks(np.zeros((0, 2)))


def make_plots(xy, radar, t=None, sigma_m=100.0, mode_s=None, mode3a=None):
    xy = np.asarray(xy, dtype=float).reshape(-1, 2)
    m = xy.shape[0]
    t = np.full(m, T_REF) if t is None else np.asarray(t, dtype=float)
    cov = np.tile(sigma_m**2 * np.eye(2), (m, 1, 1))
    ms = np.full(m, -1, dtype=np.int64) if mode_s is None else np.asarray(mode_s, np.int64)
    m3 = np.full(m, -1, dtype=np.int64) if mode3a is None else np.asarray(mode3a, np.int64)
    return xy, cov, t, np.asarray(radar), ms, m3


def run(plots, tracks, params=None):
    return cluster_plots(*plots, *tracks, T_REF, params)


def clusters_of(res):
    return [set(np.flatnonzero(res.labels == c)) for c in range(res.n_clusters)]


# --------------------------------------------------------------------------------------
# eq. 3 (corrected) and E (eq. 2)


def test_eq3_corrected_move_decreases_brute_force_e_and_printed_form_does_not():
    rng = np.random.default_rng(7)
    printed_wrong = 0
    checked_moves = 0
    for _ in range(300):
        k = int(rng.integers(2, 5))
        sizes = rng.integers(1, 5, size=k)
        centres = rng.normal(scale=3.0, size=(k, 2))
        clusters = [list(centres[i] + rng.normal(size=(sizes[i], 2))) for i in range(k)]
        i = int(rng.integers(k))
        if len(clusters[i]) < 2:
            continue
        p = clusters[i][int(rng.integers(len(clusters[i])))]
        means = [np.mean(c, axis=0) for c in clusters]

        def e_of(cl):
            return brute_force_sse([[(q[0], q[1], 1.0) for q in c] for c in cl])

        e_before = e_of(clusters)
        rho_i = float(transfer_rho(p, means[i], len(clusters[i]), True))
        for j in range(k):
            if j == i:
                continue
            moved = [list(c) for c in clusters]
            moved[i] = [q for q in clusters[i] if q is not p]
            moved[j] = clusters[j] + [p]
            delta = e_of(moved) - e_before
            rho_j = float(transfer_rho(p, means[j], len(clusters[j]), False))
            # ρ_j − ρ_i is exactly the change of E.
            assert delta == pytest.approx(rho_j - rho_i, rel=1e-9, abs=1e-9)
            if rho_j < rho_i:
                assert delta < 0
                checked_moves += 1
            # The printed eq. 3 swaps the factors.
            ni, nj = len(clusters[i]), len(clusters[j])
            rho_i_printed = ni / (ni + 1) * float(np.sum((p - means[i]) ** 2))
            rho_j_printed = nj / (nj - 1) * float(np.sum((p - means[j]) ** 2)) if nj > 1 else 0.0
            if rho_j_printed < rho_i_printed and delta >= 0:
                printed_wrong += 1
    assert checked_moves > 20
    assert printed_wrong > 0


def test_eq3_best_move_chosen_by_rho_is_the_best_brute_force_move():
    rng = np.random.default_rng(11)
    for _ in range(100):
        k = 4
        clusters = [list(rng.normal(loc=rng.normal(scale=2, size=2), size=(3, 2))) for _ in range(k)]
        p = clusters[0][0]
        means = [np.mean(c, axis=0) for c in clusters]
        rho = [float(transfer_rho(p, means[j], 3, False)) for j in range(1, k)]
        deltas = []
        for j in range(1, k):
            moved = [list(c) for c in clusters]
            moved[0] = clusters[0][1:]
            moved[j] = clusters[j] + [p]
            deltas.append(brute_force_sse([[(q[0], q[1], 1) for q in c] for c in moved]))
        assert int(np.argmin(rho)) == int(np.argmin(deltas))


def random_dense_scenario(rng, n_targets=12, n_radars=3, spacing_m=1500.0, pd=0.7):
    """Targets on a tight grid with noisy tracks and missed detections (free radar slots),
    so that assignments are contested and transfers possible."""
    side = int(np.ceil(np.sqrt(n_targets)))
    grid = np.array([(i * spacing_m, j * spacing_m) for i in range(side) for j in range(side)])
    pos = grid[:n_targets] + rng.normal(scale=200.0, size=(n_targets, 2))
    vel = rng.normal(scale=150.0, size=(n_targets, 2))
    xy, rad, t, truth = [], [], [], []
    for r in range(n_radars):
        tp = T_REF - rng.uniform(0.0, 4.0, n_targets)
        xy.append(pos - vel * (T_REF - tp)[:, None] + rng.normal(scale=300.0, size=(n_targets, 2)))
        rad.append(np.full(n_targets, r))
        t.append(tp)
        truth.append(np.arange(n_targets))
    seen = rng.random(n_radars * n_targets) < pd
    plots = make_plots(np.concatenate(xy)[seen], np.concatenate(rad)[seen], np.concatenate(t)[seen], sigma_m=300.0)
    tracks = make_tracks(
        pos + rng.normal(scale=200.0, size=pos.shape),
        vel + rng.normal(scale=10.0, size=vel.shape),
        sigma_pos_m=200.0,
    )
    return plots, tracks, np.concatenate(truth)[seen]


def test_result_e_not_above_seed_e_and_matches_brute_force():
    rng = np.random.default_rng(5)
    strictly_lower = 0
    for _ in range(40):
        plots, tracks, _ = random_dense_scenario(rng)
        res = run(plots, tracks)
        e_final = result_sse(res.labels, res.cluster_track, plots, tracks)
        e_seed = result_sse(res.seed_labels, res.seed_cluster_track, plots, tracks)
        assert res.sse_m2 == pytest.approx(e_final, rel=1e-9, abs=1e-6)
        assert res.sse_seed_m2 == pytest.approx(e_seed, rel=1e-9, abs=1e-6)
        assert e_final <= e_seed * (1 + 1e-12) + 1e-6
        if res.n_iterations > 0:
            assert e_final < e_seed
            strictly_lower += 1
    # The scenario is contested enough that the transfers do act.
    assert strictly_lower > 0


def test_result_keeps_constraints_in_contested_scenarios():
    rng = np.random.default_rng(9)
    params = ClusteringParams()
    for _ in range(30):
        plots, tracks, _ = random_dense_scenario(rng, n_targets=16, n_radars=4, spacing_m=1200.0)
        res = run(plots, tracks, params)
        xy, cov, t, radar, *_ = plots
        for c, members in enumerate(clusters_of(res)):
            radars = [radar[p] for p in members]
            assert len(radars) == len(set(radars))
            j = res.cluster_track[c]
            if j < 0:
                continue
            for p in members:  # every member passes the gate of its track (independent check)
                dt = T_REF - t[p]
                y = xy[p] + tracks[1][j] * dt - tracks[0][j]
                s = tracks[2][j] + cov[p] + dt * dt * tracks[3][j]
                assert y @ np.linalg.solve(s, y) <= params.gate_chi2 + 1e-9


# --------------------------------------------------------------------------------------
# the per-radar assignment against an independent dense solver


def test_per_radar_assignment_is_optimal_against_dense_lsa():
    rng = np.random.default_rng(3)
    gate = 10.0
    for _ in range(200):
        n_plots, n_slots = int(rng.integers(1, 7)), int(rng.integers(1, 6))
        mask = rng.random((n_plots, n_slots)) < 0.6
        cost = rng.uniform(0.0, gate, size=(n_plots, n_slots))
        pp, ss = np.nonzero(mask)
        assign = assign_per_radar(pp, ss, cost[pp, ss], n_plots, gate)
        # Validity: one plot per slot, only allowed pairs.
        chosen = assign[assign >= 0]
        assert len(set(ss[chosen])) == chosen.size
        ours = sum(cost[pp[a], ss[a]] if a >= 0 else gate for a in assign)
        # Independent: dense matrix with one private "unassigned" column per plot.
        dense = np.full((n_plots, n_slots + n_plots), 1e9)
        dense[pp, ss] = cost[pp, ss]
        dense[np.arange(n_plots), n_slots + np.arange(n_plots)] = gate
        r, c = linear_sum_assignment(dense)
        assert ours == pytest.approx(dense[r, c].sum(), rel=1e-12, abs=1e-9)


# --------------------------------------------------------------------------------------
# scenarios with known truth


def test_well_separated_targets_three_radars_with_and_without_tracks():
    rng = np.random.default_rng(1)
    n = 50
    pos = rng.uniform(0, 400e3, size=(n, 2))
    # Keep targets at least 20 km apart.
    keep = [0]
    for i in range(1, n):
        if np.min(np.hypot(*(pos[keep] - pos[i]).T)) > 20e3:
            keep.append(i)
    pos = pos[keep]
    n = pos.shape[0]
    vel = rng.normal(scale=150.0, size=(n, 2))
    xy, rad, t, truth = [], [], [], []
    for r in range(3):
        tp = T_REF - rng.uniform(0, 4, n)
        xy.append(pos - vel * (T_REF - tp)[:, None] + rng.normal(scale=100.0, size=(n, 2)))
        rad.append(np.full(n, r))
        t.append(tp)
        truth.append(np.arange(n))
    truth = np.concatenate(truth)
    plots = make_plots(np.concatenate(xy), np.concatenate(rad), np.concatenate(t))
    for tracks in (make_tracks(pos, vel), NO_TRACKS):
        res = run(plots, tracks)
        assert res.n_clusters == n
        assert np.all(res.labels >= 0) and not res.redundant.any()
        for members in clusters_of(res):
            assert len({truth[p] for p in members}) == 1
            assert sorted(plots[3][p] for p in members) == [0, 1, 2]
        if tracks[0].shape[0]:
            assert np.array_equal(res.cluster_track[res.labels], truth)
        else:
            assert np.all(res.cluster_track == -1)  # case 3: all new


def parallel_pair(rng, with_mode_s, sigma_m=300.0):
    """Two aircraft 1 NM apart flying parallel (east), three radars, plots at random times."""
    pos = np.array([[0.0, 0.0], [0.0, NM_M]])
    vel = np.array([[230.0, 0.0], [230.0, 0.0]])
    xy, rad, t, truth = [], [], [], []
    for r in range(3):
        tp = T_REF - rng.uniform(0, 4, 2)
        xy.append(pos - vel * (T_REF - tp)[:, None] + rng.normal(scale=sigma_m, size=(2, 2)))
        rad.append([r, r])
        t.append(tp)
        truth.append([0, 1])
    truth = np.concatenate(truth)
    ms = np.array([0xABC001, 0xABC002])[truth] if with_mode_s else None
    plots = make_plots(np.concatenate(xy), np.concatenate(rad), np.concatenate(t), sigma_m, ms)
    tracks = make_tracks(
        pos + rng.normal(scale=150.0, size=(2, 2)),
        vel,
        mode_s=[0xABC001, 0xABC002] if with_mode_s else None,
    )
    return plots, tracks, truth


def test_parallel_tracks_one_nm_apart():
    rng = np.random.default_rng(2)
    n_trials = 300
    for _ in range(n_trials):
        plots, tracks, truth = parallel_pair(rng, with_mode_s=True)
        res = run(plots, tracks)
        for members in clusters_of(res):
            assert len({truth[p] for p in members}) == 1  # never mixed
        used = res.labels >= 0
        on_track = res.cluster_track[res.labels[used]]
        # Never on the other aircraft's track (a plot outside its own gate, 0.1 %, starts
        # a new-target cluster instead).
        assert np.all((on_track == truth[used]) | (on_track == -1))
    right = 0
    total = 0
    for _ in range(n_trials):
        plots, tracks, truth = parallel_pair(rng, with_mode_s=False)
        res = run(plots, tracks)
        ok = res.labels >= 0
        got = np.where(ok, res.cluster_track[np.maximum(res.labels, 0)], -2)
        right += int(np.sum(got == truth))
        total += truth.size
        for members in clusters_of(res):
            assert len({plots[3][p] for p in members}) == len(members)
    rate = right / total
    print(f"parallel 1 NM, sigma 300 m, no Mode S: {rate:.3%} of plots on their own track")
    assert rate > 0.95


def crossing_pair(rng, with_mode_s):
    """Two aircraft at the crossing point of perpendicular routes, 150 m apart."""
    pos = np.array([[0.0, 0.0], [150.0, 0.0]])
    vel = np.array([[230.0, 0.0], [0.0, 230.0]])
    xy, rad, t, truth = [], [], [], []
    for r in range(3):
        tp = T_REF - rng.uniform(0, 4, 2)
        xy.append(pos - vel * (T_REF - tp)[:, None] + rng.normal(scale=150.0, size=(2, 2)))
        rad.append([r, r])
        t.append(tp)
        truth.append([0, 1])
    truth = np.concatenate(truth)
    ms = np.array([0x4CA001, 0x4CA002])[truth] if with_mode_s else None
    plots = make_plots(np.concatenate(xy), np.concatenate(rad), np.concatenate(t), 150.0, ms)
    tracks = make_tracks(pos, vel, mode_s=[0x4CA001, 0x4CA002] if with_mode_s else None)
    return plots, tracks, truth


def test_crossing_aircraft_one_plot_per_radar_and_identity():
    rng = np.random.default_rng(4)
    for with_mode_s in (False, True):
        for _ in range(100):
            plots, tracks, truth = crossing_pair(rng, with_mode_s)
            res = run(plots, tracks)
            for members in clusters_of(res):
                radars = [plots[3][p] for p in members]
                assert len(radars) == len(set(radars))
            if with_mode_s:
                assert np.all(res.labels >= 0)
                assert np.array_equal(res.cluster_track[res.labels], truth)


def test_case1_new_target_beyond_tracks_forms_new_cluster():
    pos = np.array([[0.0, 0.0], [50e3, 0.0], [0.0, 80e3]])  # third target has no track
    xy = np.concatenate([pos + [20.0 * r, -10.0 * r] for r in range(3)])
    rad = np.repeat([0, 1, 2], 3)
    res = run(make_plots(xy, rad), make_tracks(pos[:2]))
    assert res.n_clusters == 3
    assert sorted(res.cluster_track.tolist()) == [-1, 0, 1]
    new = np.flatnonzero(res.cluster_track == -1)[0]
    assert set(np.flatnonzero(res.labels == new)) == {2, 5, 8}


def test_case3_no_tracks_all_new_and_case2_no_new_cluster():
    pos = np.array([[0.0, 0.0], [50e3, 0.0], [0.0, 80e3]])
    xy = np.concatenate([pos + [30.0 * r, 15.0 * r] for r in range(3)])
    rad = np.repeat([0, 1, 2], 3)
    plots = make_plots(xy, rad)
    res3 = run(plots, NO_TRACKS)
    assert res3.n_clusters == 3 and np.all(res3.cluster_track == -1)
    for members in clusters_of(res3):
        assert len({p % 3 for p in members}) == 1
    res2 = run(plots, make_tracks(pos))
    assert res2.n_clusters == 3
    assert np.all(res2.cluster_track >= 0)
    assert np.array_equal(res2.cluster_track[res2.labels], np.tile([0, 1, 2], 3))


def test_close_new_targets_without_tracks_are_split_one_plot_per_radar():
    rng = np.random.default_rng(6)
    right = 0
    for _ in range(50):
        pos = np.array([[0.0, 0.0], [1500.0, 0.0]])  # inside the 2 km new-target gate
        xy = np.concatenate([pos + rng.normal(scale=100.0, size=(2, 2)) for _ in range(3)])
        rad = np.repeat([0, 1, 2], 2)
        res = run(make_plots(xy, rad), NO_TRACKS)
        assert res.n_clusters >= 2
        for members in clusters_of(res):
            assert len({rad[p] for p in members}) == len(members)
        right += res.n_clusters == 2 and all(len({p % 2 for p in m}) == 1 for m in clusters_of(res))
    assert right >= 45


def test_duplicate_plot_in_track_gate_is_redundant_not_a_new_cluster():
    track = make_tracks([[10e3, 10e3]])
    xy = [[10e3 + 50, 10e3], [10e3 - 200, 10e3 + 100], [10e3, 10e3 - 60], [10e3 + 30, 10e3 + 30]]
    rad = [0, 0, 1, 2]  # radar 0 reports twice
    res = run(make_plots(xy, rad), track)
    assert res.n_clusters == 1 and res.cluster_track[0] == 0
    assert res.labels.tolist() == [0, -1, 0, 0]  # the farther duplicate is left out
    assert res.redundant.tolist() == [False, True, False, False]


def test_time_alignment_lands_on_truth():
    v = np.array([250.0 * np.cos(0.3), 250.0 * np.sin(0.3)])
    truth_ref = np.array([40e3, -7e3])
    t_p = T_REF - 3.0
    z = truth_ref - v * 3.0  # where the aircraft was at detection time
    r = np.array([[400.0, 50.0], [50.0, 900.0]])
    p_vv = np.array([[25.0, 0.0], [0.0, 16.0]])
    a_xy, a_cov = align_to_reference(z[None], r[None], np.array([t_p]), T_REF, v, p_vv)
    np.testing.assert_allclose(a_xy[0], truth_ref, atol=1e-9)
    np.testing.assert_allclose(a_cov[0], r + 9.0 * p_vv)
    # The same through cluster_plots: the aligned plot of the assigned track is the truth.
    res = run(
        make_plots(z[None], [0], t=[t_p]),
        make_tracks(truth_ref[None], v[None]),
    )
    assert res.labels[0] == 0 and res.cluster_track[0] == 0
    np.testing.assert_allclose(res.aligned_xy_m[0], truth_ref, atol=1e-9)
    np.testing.assert_allclose(res.aligned_cov_m2[0], 100.0**2 * np.eye(2) + 9.0 * 10.0**2 * np.eye(2))


def test_gate_ten_sigma_starts_new_cluster_two_sigma_joins():
    tracks = make_tracks([[0.0, 0.0]], sigma_pos_m=150.0)
    sigma_s = np.sqrt(150.0**2 + 100.0**2)  # S = P_pos + R, isotropic
    res = run(make_plots([[10 * sigma_s, 0.0]], [0]), tracks)
    assert res.n_clusters == 1 and res.cluster_track[0] == -1 and res.labels[0] == 0
    assert not res.redundant[0]
    res = run(make_plots([[2 * sigma_s, 0.0]], [0]), tracks)
    assert res.cluster_track.tolist() == [0] and res.labels[0] == 0
    # 2 dof chi-square gate: d² = 13 passes, d² = 14.5 does not.
    for d2, joins in ((13.0, True), (14.5, False)):
        res = run(make_plots([[np.sqrt(d2) * sigma_s, 0.0]], [0]), tracks)
        assert (res.cluster_track[0] == 0) == joins
    assert pytest.approx(-2 * np.log(0.001)) == CHI2_2DOF_P999


def test_absolute_gate_cap_in_metres():
    tracks = make_tracks([[0.0, 0.0]], sigma_pos_m=5000.0)  # diverged track, huge gate
    plots = make_plots([[8000.0, 0.0]], [0])
    assert run(plots, tracks).cluster_track.tolist() == [0]
    capped = ClusteringParams(max_gate_m=5000.0)
    assert run(plots, tracks, capped).cluster_track.tolist() == [-1]


def test_identity_mode_s_and_mode3a():
    tracks = make_tracks([[0.0, 0.0]], mode_s=[0x3C0001], mode3a=[0o1234])
    near = [[100.0, 0.0]]
    # Different Mode S: never joins, even on top of the track.
    res = run(make_plots(near, [0], mode_s=[0x3C0002]), tracks)
    assert res.cluster_track.tolist() == [-1]
    # Same Mode S or none: joins.
    assert run(make_plots(near, [0], mode_s=[0x3C0001]), tracks).cluster_track.tolist() == [0]
    assert run(make_plots(near, [0]), tracks).cluster_track.tolist() == [0]
    # Different Mode 3/A without an address on both: kept apart by default, joins when the
    # check is off.
    plots = make_plots(near, [0], mode3a=[0o4321])
    assert run(plots, tracks).cluster_track.tolist() == [-1]
    assert run(plots, tracks, ClusteringParams(use_mode3a=False)).cluster_track.tolist() == [0]
    # The address decides when both have one: a squawk change is the same aircraft.
    plots = make_plots(near, [0], mode_s=[0x3C0001], mode3a=[0o4321])
    assert run(plots, tracks).cluster_track.tolist() == [0]
    # Emergency and conspicuity codes are no identity: a track squawking 1234 that turns
    # to 7700, and a 7000 plot, may be the same aircraft.
    for code in (0o7700, 0o7600, 0o7500, 0o7000, 0o2000, 0o1200):
        assert run(make_plots(near, [0], mode3a=[code]), tracks).cluster_track.tolist() == [0], oct(code)
    # Two new plots with different Mode S never share a cluster.
    res = run(make_plots([[0.0, 0.0], [50.0, 0.0]], [0, 1], mode_s=[1, 2]), NO_TRACKS)
    assert res.n_clusters == 2


def test_new_target_gate_grows_with_time_difference():
    # Two radars see a new 300 m/s target 3 s apart: 900 m of motion plus 1.5 km noise.
    xy = [[0.0, 0.0], [2400.0, 0.0]]
    params = ClusteringParams(new_target_gate_m=1600.0, max_speed_mps=350.0)
    res = run(make_plots(xy, [0, 1], t=[T_REF - 3.5, T_REF - 0.5]), NO_TRACKS, params)
    assert res.n_clusters == 1  # 2400 ≤ 1600 + 350·3
    res = run(make_plots(xy, [0, 1], t=[T_REF - 1.0, T_REF - 0.5]), NO_TRACKS, params)
    assert res.n_clusters == 2  # 2400 > 1600 + 350·0.5


def test_empty_and_invalid_inputs():
    res = run(make_plots(np.zeros((0, 2)), np.zeros(0, int)), NO_TRACKS)
    assert res.n_clusters == 0 and res.labels.shape == (0,)
    res = run(make_plots(np.zeros((0, 2)), np.zeros(0, int)), make_tracks([[0.0, 0.0]]))
    assert res.n_clusters == 0
    res = run(make_plots([[np.nan, 0.0], [0.0, 0.0]], [0, 1]), make_tracks([[0.0, 0.0]]))
    assert res.labels.tolist() == [-1, 0] and not res.redundant.any()


def test_brute_force_small_exhaustive_e_check():
    """On tiny problems, no single feasible transfer from the result lowers E."""
    rng = np.random.default_rng(8)
    params = ClusteringParams()
    for _ in range(40):
        plots, tracks, _ = random_dense_scenario(rng, n_targets=4, n_radars=3, spacing_m=900.0)
        res = run(plots, tracks, params)
        xy, cov, t, radar, *_ = plots
        e0 = result_sse(res.labels, res.cluster_track, plots, tracks)
        track_cluster = {int(j): c for c, j in enumerate(res.cluster_track) if j >= 0}
        for p, j in itertools.product(range(len(res.labels)), range(tracks[0].shape[0])):
            c_from = res.labels[p]
            if c_from < 0 or res.cluster_track[c_from] < 0 or res.cluster_track[c_from] == j:
                continue
            dt = T_REF - t[p]
            y = xy[p] + tracks[1][j] * dt - tracks[0][j]
            s = tracks[2][j] + cov[p] + dt * dt * tracks[3][j]
            if y @ np.linalg.solve(s, y) > params.gate_chi2:
                continue
            c_to = track_cluster.get(j)
            if c_to is not None and any(radar[q] == radar[p] for q in np.flatnonzero(res.labels == c_to)):
                continue
            labels = res.labels.copy()
            cluster_track = res.cluster_track.copy()
            if c_to is None:
                cluster_track = np.append(cluster_track, j)
                c_to = cluster_track.size - 1
            labels[p] = c_to
            assert result_sse(labels, cluster_track, plots, tracks) >= e0 - 1e-6


# --------------------------------------------------------------------------------------
# identity association (issue 15): a plot with a live track's Mode S address joins it


def run_last(plots, tracks, last_xy, last_t, params=None):
    n = np.asarray(last_xy, float).reshape(-1, 2).shape[0]
    return cluster_plots(
        *plots,
        *tracks,
        T_REF,
        params,
        track_last_xy_m=np.asarray(last_xy, float).reshape(n, 2),
        track_last_cov_m2=np.tile(150.0**2 * np.eye(2), (n, 1, 1)),
        track_last_t_s=np.asarray(last_t, float),
    )


def test_a_plot_with_the_address_of_a_turning_track_joins_it_outside_the_gate():
    """The track was last seen 12 s ago at the origin flying east at 200 m/s; its
    prediction is 2.4 km east. The aircraft turned north: its plot is 2 km north-east of
    the origin, 2.2 km from the prediction (χ² d² ≈ 100 with σ 150 m): outside the gate,
    but well within 12 s × 350 m/s of where it was last seen."""
    tracks = make_tracks([[2400.0, 0.0]], v=[[200.0, 0.0]], mode_s=[0x4B1234])
    plot_xy = [[1400.0, 1400.0]]
    plain = run(make_plots(plot_xy, [0], mode_s=[0x4B1234]), tracks)
    assert plain.cluster_track.tolist() == [-1]  # without the identity rule: a new track
    res = run_last(make_plots(plot_xy, [0], mode_s=[0x4B1234]), tracks, [[0.0, 0.0]], [T_REF - 12.0])
    assert res.cluster_track.tolist() == [0] and res.labels.tolist() == [0]
    # the rule can be switched off
    off = ClusteringParams(identity_association=False)
    res = run_last(make_plots(plot_xy, [0], mode_s=[0x4B1234]), tracks, [[0.0, 0.0]], [T_REF - 12.0], off)
    assert res.cluster_track.tolist() == [-1]
    # a plot without the address stays a new target
    res = run_last(make_plots(plot_xy, [0]), tracks, [[0.0, 0.0]], [T_REF - 12.0])
    assert res.cluster_track.tolist() == [-1]


def test_the_sanity_gate_refuses_an_address_too_far_to_have_been_flown():
    tracks = make_tracks([[2400.0, 0.0]], v=[[200.0, 0.0]], mode_s=[0x4B1234])
    # 12 s at 350 m/s is 4.2 km, plus 3·sqrt(100² + 150²) = 541 m: a plot 4.9 km away is refused
    res = run_last(make_plots([[0.0, 4_900.0]], [0], mode_s=[0x4B1234]), tracks, [[0.0, 0.0]], [T_REF - 12.0])
    assert res.cluster_track.tolist() == [-1]
    res = run_last(make_plots([[0.0, 4_600.0]], [0], mode_s=[0x4B1234]), tracks, [[0.0, 0.0]], [T_REF - 12.0])
    assert res.cluster_track.tolist() == [0]


def test_a_plot_with_an_address_goes_to_its_track_not_to_a_nearer_anonymous_one():
    """Track 0 (no address) sits on the plot; track 1 carries the plot's address, 600 m
    away (inside both gates). By distance the plot is track 0's; by identity, track 1's."""
    tracks = make_tracks([[0.0, 0.0], [600.0, 0.0]], mode_s=[-1, 0x4B1234])
    plots = make_plots([[10.0, 0.0]], [0], mode_s=[0x4B1234])
    res = run_last(plots, tracks, [[0.0, 0.0], [600.0, 0.0]], [T_REF - 4.0, T_REF - 4.0])
    assert res.cluster_track[res.labels[0]] == 1
    # with two plots of two radars, each track keeps the right one
    plots = make_plots([[10.0, 0.0], [20.0, 0.0]], [0, 1], mode_s=[0x4B1234, -1])
    res = run_last(plots, tracks, [[0.0, 0.0], [600.0, 0.0]], [T_REF - 4.0, T_REF - 4.0])
    assert [int(res.cluster_track[lab]) for lab in res.labels] == [1, 0]


def test_a_plot_a_turn_model_expects_joins_outside_the_combined_gate():
    """IMM gating (imm.py, "Gating"): the combined prediction (the quiet model's, σ 150 m)
    is at the origin; a right-turn model predicts the aircraft 600 m north, σ 150 m. A
    plot 900 m north (σ 100 m) is d² = 900²/(150² + 100²) ≈ 24.9 from the combined
    prediction, outside its 99.9 % gate (13.8), and d² ≈ 2.8 from the turn model's."""
    tracks = make_tracks([[0.0, 0.0]], sigma_pos_m=150.0)
    plot = make_plots([[0.0, 900.0]], [0])
    s2 = 150.0**2 + 100.0**2
    plain = run(plot, tracks)
    assert plain.cluster_track.tolist() == [-1]  # combined gate only: a new target
    models_xy = np.array([[[0.0, 0.0], [0.0, 600.0], [0.0, -600.0]]])  # quiet, right, left
    models_cov = np.tile(150.0**2 * np.eye(2), (1, 3, 1, 1))
    res = cluster_plots(*plot, *tracks, T_REF, None, track_models=(models_xy, models_cov))
    assert res.cluster_track.tolist() == [0] and res.labels.tolist() == [0]
    # the d² reported is the combined prediction's (beyond the gate: weighed and checked as such)
    assert res.plot_d2[0] == pytest.approx(900.0**2 / s2) and res.plot_d2[0] > CHI2_2DOF_P999
    # a plot no model expects stays out
    far = cluster_plots(*make_plots([[900.0, 0.0]], [0]), *tracks, T_REF, None, track_models=(models_xy, models_cov))
    assert far.cluster_track.tolist() == [-1]


def test_plot_search_finds_exactly_the_pairs_within_each_radius() -> None:
    """The candidate search (association._within_radius, a grid) against all pairs by brute
    force: clustered and scattered points, radii from 0 to beyond the whole area and
    infinite, centres outside it, points exactly on a circle (|p − c| = r is in, as in a
    k-d tree's ball)."""
    from radar_fusion.tracking.association import _within_radius

    rng = np.random.default_rng(5)
    for n_p, n_c in ((0, 5), (5, 0), (1, 1), (400, 300), (3000, 1000)):
        xy = np.concatenate([rng.normal(0.0, 3e4, (n_p // 2, 2)), rng.uniform(-2e5, 2e5, (n_p - n_p // 2, 2))])
        centres = rng.uniform(-2.5e5, 2.5e5, (n_c, 2))
        radius = rng.choice([0.0, 500.0, 3000.0, 2e4, 1e6, np.inf], n_c, p=[0.1, 0.3, 0.3, 0.2, 0.09, 0.01])
        radius = radius * rng.uniform(0.5, 1.0, n_c)
        if n_p and n_c:  # a point exactly on a centre's circle (dx = r, dy = 0, exact in binary)
            xy[0], centres[0], radius[0] = [1000.0, 2000.0], [500.0, 2000.0], 500.0
        got_p, got_c = _within_radius(xy, centres, radius)
        d2 = ((xy[None, :, :] - centres[:, None, :]) ** 2).sum(axis=2)
        want_c, want_p = np.nonzero(d2 <= radius[:, None] ** 2)
        assert sorted(zip(got_c.tolist(), got_p.tolist())) == sorted(zip(want_c.tolist(), want_p.tolist()))
        assert (np.diff(got_c) >= 0).all()  # grouped by centre, in order
        if n_p and n_c:
            assert (0, 0) in set(zip(got_c.tolist(), got_p.tolist()))


def test_model_gates_take_the_smallest_distance_over_the_models() -> None:
    """association._min_model_d2 against the Mahalanobis distance of each model computed
    with numpy (np.linalg.solve), a non-positive-definite model counting as +inf."""
    from radar_fusion.tracking.association import _min_model_d2

    rng = np.random.default_rng(8)
    n_t, m, n_p = 20, 6, 300
    model_xy = rng.normal(0.0, 500.0, (n_t, m, 2))
    a = rng.normal(size=(n_t, m, 2, 2)) * 100.0
    model_cov = a @ np.swapaxes(a, 2, 3) + 10.0 * np.eye(2)
    model_cov[3, 2] = -1e7 * np.eye(2)  # not positive definite, whatever the plot's covariance
    track = rng.integers(0, n_t, n_p)
    xy = model_xy[track, 0] + rng.normal(0.0, 300.0, (n_p, 2))
    b = rng.normal(size=(n_p, 2, 2)) * 50.0
    cov = b @ np.swapaxes(b, 1, 2) + np.eye(2)
    d2 = rng.uniform(0.0, 40.0, n_p)
    want = d2.copy()
    for j in range(m):
        S = model_cov[track, j] + cov
        y = xy - model_xy[track, j]
        pd = np.linalg.eigvalsh(S).min(axis=1) > 0
        dj = np.where(pd, np.einsum("pi,pi->p", y, np.linalg.solve(S, y[:, :, None])[:, :, 0]), np.inf)
        want = np.minimum(want, dj)
    got = _min_model_d2(d2, xy, cov, track.astype(np.int64), model_xy, model_cov)
    np.testing.assert_allclose(got, want, rtol=1e-9)
    assert (got < d2).any() and (got == d2).any()


def test_unique_inverse_is_numpys_unique():
    """The bincount path gives np.unique's values and inverse; keys outside its range
    (negative, or sparse) take np.unique's own path with the same result."""
    rng = np.random.default_rng(11)
    cases = [
        rng.integers(0, 10, 8000),
        rng.integers(0, 4000, 8000),
        rng.integers(0, 10**9, 500),
        rng.integers(-5, 5, 300),
        np.array([7]),
        np.zeros(0, np.int64),
    ]
    for a in cases:
        u, inv = unique_inverse(a)
        u_np, inv_np = np.unique(a, return_inverse=True)
        np.testing.assert_array_equal(u, u_np)
        np.testing.assert_array_equal(inv, inv_np.reshape(-1))
        np.testing.assert_array_equal(u[inv], a)
