"""Time alignment and k-means clustering of one scan period's plots (Shu et al. 2007, §2).

Each period the engine holds the plots of all radars in the common system plane and the
existing tracks predicted to the period's reference time ``t_ref``.  This module decides
which plots belong to the same aircraft; the fusion module then combines each cluster
(Shu eq. 5-6) and the filter updates the cluster's track.

Notation (Shu §2.1): a cluster ``C_i`` holds ``N_i`` points ``p`` with mean

    m_i = (1/N_i) · Σ_{p∈C_i} p                                       (eq. 1)

and the clustering minimises the sum of squared errors

    E = Σ_i Σ_{p∈C_i} |p − m_i|²                                      (eq. 2)

by single-point transfers (Shu §2.3, Duda & Hart's iterative optimisation).  Moving p
out of its cluster i lowers E by ρ_i and moving it into cluster j raises E by ρ_j, with

    ρ_i = N_i/(N_i − 1) · |p − m_i|²     (the cluster that holds p)
    ρ_j = N_j/(N_j + 1) · |p − m_j|²     (j ≠ i)                      (eq. 3, corrected)

so the transfer to the j of smallest ρ_j decreases E exactly when ρ_j < ρ_i.  Shu's
printed eq. 3 swaps the two factors (DESIGN.md §1); ``transfer_rho`` implements the
corrected form and the tests prove it against a brute-force E.

The number of clusters is *not* chosen by minimising E (E falls monotonically with k,
DESIGN.md §1).  It follows Shu's three cases (§2): one cluster per existing track that
receives plots (case 2), plus new-target clusters built from the plots outside every
track's gate (case 1; case 3 when there are no tracks).

Algorithm (``cluster_plots``), all array operations except where noted:

1. Time alignment ("时空对准", §2): a plot considered for track j is moved to ``t_ref``
   with the track's velocity, ``z + v_j·(t_ref − t_p)``, covariance
   ``R + (t_ref − t_p)²·P_vv,j`` (``align_to_reference``).
2. Candidate (plot, track) pairs from a k-d tree query with a per-track radius that bounds
   the gate; no M×N matrix is built.
3. Gating of the candidate pairs: Mahalanobis distance d² = yᵀS⁻¹y ≤ ``gate_chi2`` with
   y = aligned plot − predicted track position and S = P_pos,j + R_aligned, optional
   absolute cap |y| ≤ ``max_gate_m``, Mode S / Mode 3/A identity compatibility.
4. Seed (Shu §2.1 last paragraph): every track is a representative and forms a class with
   its predicted point; each gated plot joins the nearest representative (in d²) subject
   to one plot per radar per cluster.  Per radar this is an assignment problem; plots
   whose best track is not wanted by any other plot of the same radar are assigned
   directly, the rest (connected components of the plot–slot graph that contain a
   conflict) are solved exactly in one sparse Jonker–Volgenant call, with a dummy
   "unassigned" option of cost ``gate_chi2`` per plot (global nearest neighbour).
5. Transfers (Shu §2.3 with eq. 3 corrected), batched: ρ is computed for every candidate
   (plot, other gated track cluster) pair at once; the improving moves that keep one plot
   per radar per cluster are filtered to a set touching each cluster at most once (each
   move must be the best-gain move of both its source and its target cluster), so their
   gains add exactly and E strictly decreases; repeat until no move or ``max_iterations``.
6. Plots outside every track gate: zero-velocity alignment and a new-target gate in
   metres widened by the motion allowance ``max_speed_mps·|t_p − t_q|`` between two plots;
   connected components of the compatibility graph that are cliques with one plot per
   radar become one cluster each (vectorised); the rare other components are clustered
   by Shu's sequential k-means (seed from the radar with most plots, per-radar
   assignment, then single transfers by eq. 3), in a loop over those components only.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np
from scipy.optimize import linear_sum_assignment
from scipy.sparse import coo_matrix, csr_matrix
from scipy.sparse.csgraph import connected_components, min_weight_full_bipartite_matching
from scipy.spatial import cKDTree

__all__ = [
    "CHI2_2DOF_P999",
    "ClusteringParams",
    "ClusterResult",
    "align_to_reference",
    "transfer_rho",
    "cluster_plots",
]

#: 99.9 % quantile of the chi-square distribution with 2 degrees of freedom,
#: -2·ln(0.001) (= scipy.stats.chi2.ppf(0.999, 2)).
CHI2_2DOF_P999 = 13.815510557964274

# Cost of a dummy "too expensive" entry in the small dense assignment problems of the
# new-target components; far above any squared distance inside a gate (< (20 km)²).
_BIG_COST = 1.0e18


@dataclass(frozen=True)
class ClusteringParams:
    """Parameters of ``cluster_plots``.

    gate_chi2:
        Mahalanobis gate d² ≤ gate_chi2 for a plot to join a track's cluster.  Default
        13.8155 = chi-square 99.9 % quantile for 2 dof: a correct plot falls outside the
        gate once in a thousand, which then costs at most one false new-target cluster.
    max_gate_m:
        Absolute cap on |aligned plot − predicted track position| in metres, or None.
        Default 9,260 m (5 NM, the en-route separation minimum): a coasting track's
        covariance may grow to tens of km, and a gate wider than the separation minimum
        would capture the plots of a properly separated neighbour.  It also bounds the
        k-d tree query radius.
    new_target_gate_m:
        Maximum distance between two plots of one new-target cluster, before the motion
        allowance.  Default 2,000 m: about 3σ of the difference of two plots with
        cross-range σ ≈ 470 m each (0.1° azimuth noise at ~145 NM), yet well under the
        3 NM (5.6 km) terminal separation, so separated aircraft are not merged.
    max_speed_mps:
        Maximum ground speed assumed for a target without a track.  Two plots of one new
        target taken at t_p and t_q may be up to max_speed_mps·|t_p − t_q| further apart;
        a plot aligned to t_ref with zero velocity carries the per-axis velocity variance
        max_speed_mps²/2 (worst-case speed, uniformly distributed heading).  Default
        350 m/s (680 kt), above the ground speed of civil jets with a strong tail wind.
    max_iterations:
        Cap on the batched transfer rounds (track clusters) and on the sequential transfer
        sweeps (each new-target conflict component).  Each round strictly decreases E, so
        the cap only bounds the worst case; 20 is far above the 1-3 rounds seen in
        practice.
    use_mode3a:
        If True, a plot and a track (or two plots) whose Mode 3/A codes are both known
        and differ are never clustered together.  Set False to tolerate squawk changes.
    track_anchor_weight:
        Weight of a track's predicted point as a member of its own cluster (Shu §2.1: the
        representative "自成一类", forms a class by itself).  It keeps the centroid of a
        track's cluster tied to the prediction; it must be > 0, otherwise a track with no
        plot would be an empty cluster with ρ_j = 0 that attracts any plot (the
        degenerate "more clusters, lower E" behaviour of DESIGN.md §1).
    """

    gate_chi2: float = CHI2_2DOF_P999
    max_gate_m: float | None = 9_260.0
    new_target_gate_m: float = 2_000.0
    max_speed_mps: float = 350.0
    max_iterations: int = 20
    use_mode3a: bool = True
    track_anchor_weight: float = 1.0

    def __post_init__(self) -> None:
        if not self.gate_chi2 > 0:
            raise ValueError("gate_chi2 must be > 0")
        if self.max_gate_m is not None and not self.max_gate_m > 0:
            raise ValueError("max_gate_m must be > 0 or None")
        if not self.new_target_gate_m >= 0:
            raise ValueError("new_target_gate_m must be >= 0")
        if not self.max_speed_mps >= 0:
            raise ValueError("max_speed_mps must be >= 0")
        if self.max_iterations < 0:
            raise ValueError("max_iterations must be >= 0")
        if not self.track_anchor_weight > 0:
            raise ValueError("track_anchor_weight must be > 0")


@dataclass
class ClusterResult:
    """Clusters of one period.

    labels:             (M,) int, cluster index of each plot, −1 if the plot is not used
                        (redundant, or non-finite input).
    cluster_track:      (K,) int, index of the existing track of each cluster, −1 for a
                        new-target cluster.  Track clusters come first, in track order.
    aligned_xy_m:       (M, 2) plot positions aligned to t_ref for the final assignment
                        (track velocity for track clusters and redundant plots, zero
                        velocity for new-target clusters).
    aligned_cov_m2:     (M, 2, 2) matching covariances, R + (t_ref − t_p)²·P_vv.
    n_iterations:       transfer rounds that moved at least one plot (the larger of the
                        track-phase rounds and the new-target sweeps).
    sse_m2:             E of eq. 2 for the final clusters, each track cluster counting its
                        predicted point with weight ``track_anchor_weight``.
    redundant:          (M,) bool, plot inside some track's gate but left out because
                        that radar's slot in every such cluster is taken (duplicate).
    seed_labels, seed_cluster_track, sse_seed_m2:
                        the same for the initial (seed) assignment, before transfers.
    """

    labels: np.ndarray
    cluster_track: np.ndarray
    aligned_xy_m: np.ndarray
    aligned_cov_m2: np.ndarray
    n_iterations: int
    sse_m2: float
    redundant: np.ndarray
    seed_labels: np.ndarray
    seed_cluster_track: np.ndarray
    sse_seed_m2: float

    @property
    def n_clusters(self) -> int:
        return int(self.cluster_track.shape[0])


def align_to_reference(
    xy_m: np.ndarray,
    cov_m2: np.ndarray,
    t_s: np.ndarray,
    t_ref_s: float,
    v_mps: np.ndarray,
    cov_vel_m2ps2: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """Bring plots to the reference time with a constant velocity (Shu §2, 时空对准).

    With dt = t_ref − t_p:  z' = z + v·dt,   R' = R + dt²·P_vv.

    ``v_mps`` is (2,) or (M, 2) and ``cov_vel_m2ps2`` (2, 2) or (M, 2, 2), broadcast over
    the M plots.  For a target without a track use v = 0 and a velocity covariance that
    covers the unknown motion.  Returns (aligned xy (M, 2), aligned covariance (M, 2, 2)).
    """
    xy = np.asarray(xy_m, dtype=float)
    cov = np.asarray(cov_m2, dtype=float)
    dt_s = float(t_ref_s) - np.asarray(t_s, dtype=float)
    aligned_xy = xy + np.asarray(v_mps, dtype=float) * dt_s[..., None]
    aligned_cov = cov + (dt_s * dt_s)[..., None, None] * np.asarray(cov_vel_m2ps2, dtype=float)
    return aligned_xy, aligned_cov


def transfer_rho(
    p_xy: np.ndarray, centroid_xy: np.ndarray, n_members: np.ndarray, own: np.ndarray
) -> np.ndarray:
    """ρ of Shu eq. 3 in its corrected form (Duda & Hart), vectorised.

    own = True  (p is in the cluster):  ρ_i = N_i/(N_i − 1)·|p − m_i|²  (0 when N_i ≤ 1)
    own = False (another cluster):      ρ_j = N_j/(N_j + 1)·|p − m_j|²

    ρ_i is the decrease of E (eq. 2) when p leaves its cluster, ρ_j the increase when p
    joins cluster j; N may be a (possibly fractional) total weight.
    """
    d = np.asarray(p_xy, dtype=float) - np.asarray(centroid_xy, dtype=float)
    d2 = np.einsum("...k,...k->...", d, d)
    n = np.asarray(n_members, dtype=float)
    own = np.asarray(own, dtype=bool)
    with np.errstate(divide="ignore", invalid="ignore"):
        factor = np.where(own, np.where(n > 1, n / (n - 1.0), 0.0), n / (n + 1.0))
    return factor * d2


# --------------------------------------------------------------------------------------
# small vectorised helpers


def _lambda_max_2x2(cov: np.ndarray) -> np.ndarray:
    """Largest eigenvalue of symmetric 2×2 matrices (…, 2, 2)."""
    a = cov[..., 0, 0]
    c = cov[..., 1, 1]
    b = 0.5 * (cov[..., 0, 1] + cov[..., 1, 0])
    half_diff = 0.5 * (a - c)
    return 0.5 * (a + c) + np.sqrt(half_diff * half_diff + b * b)


def _mahalanobis2_2x2(y: np.ndarray, s: np.ndarray) -> np.ndarray:
    """yᵀS⁻¹y for (G, 2) residuals and (G, 2, 2) covariances; +inf where S is not PD."""
    a = s[:, 0, 0]
    c = s[:, 1, 1]
    b = 0.5 * (s[:, 0, 1] + s[:, 1, 0])
    det = a * c - b * b
    y0 = y[:, 0]
    y1 = y[:, 1]
    num = c * y0 * y0 - 2.0 * b * y0 * y1 + a * y1 * y1
    with np.errstate(divide="ignore", invalid="ignore"):
        d2 = num / det
    return np.where((det > 0) & (a > 0), d2, np.inf)


def _identity_compatible(
    s1: np.ndarray, s2: np.ndarray, a1: np.ndarray, a2: np.ndarray, use_mode3a: bool
) -> np.ndarray:
    """Mode S (and optionally Mode 3/A) codes agree or at least one is unknown (−1)."""
    ok = (s1 < 0) | (s2 < 0) | (s1 == s2)
    if use_mode3a:
        ok &= (a1 < 0) | (a2 < 0) | (a1 == a2)
    return ok


def _first_per_group(group: np.ndarray, key: np.ndarray) -> np.ndarray:
    """Index of the element of smallest key in each group (groups given by ``group``)."""
    order = np.lexsort((key, group))
    g_sorted = group[order]
    first = np.ones(order.shape[0], dtype=bool)
    first[1:] = g_sorted[1:] != g_sorted[:-1]
    return order[first]


# --------------------------------------------------------------------------------------
# track phase


def _candidate_pairs(
    plot_xy: np.ndarray,
    plot_cov: np.ndarray,
    dt_s: np.ndarray,
    plot_ok: np.ndarray,
    track_xy: np.ndarray,
    track_v: np.ndarray,
    track_cov_pos: np.ndarray,
    track_cov_vel: np.ndarray,
    track_ok: np.ndarray,
    params: ClusteringParams,
) -> tuple[np.ndarray, np.ndarray]:
    """(plot, track) pairs that may pass the gate, from one k-d tree query.

    The aligned residual is y = z_p + v_j·dt_p − x_j, so |y| ≤ r_j implies
    |z_p − c_j| ≤ r_j + |v_j|·h with c_j = x_j − v_j·dt_mid and h the half-range of dt.
    The Euclidean bound of the gate is r_j = sqrt(gate·λmax(S)) with
    λmax(S) ≤ λmax(P_pos,j) + max_p λmax(R_p) + max|dt|²·λmax(P_vv,j), capped by
    max_gate_m.
    """
    plot_idx = np.flatnonzero(plot_ok)
    track_idx = np.flatnonzero(track_ok)
    empty = np.empty(0, dtype=np.intp)
    if plot_idx.size == 0 or track_idx.size == 0:
        return empty, empty
    dt = dt_s[plot_idx]
    dt_lo = float(dt.min())
    dt_hi = float(dt.max())
    dt_mid = 0.5 * (dt_lo + dt_hi)
    dt_half = 0.5 * (dt_hi - dt_lo)
    dt_abs = max(abs(dt_lo), abs(dt_hi))
    lam_r = float(_lambda_max_2x2(plot_cov[plot_idx]).max())
    lam_p = _lambda_max_2x2(track_cov_pos[track_idx])
    lam_v = _lambda_max_2x2(track_cov_vel[track_idx])
    radius = np.sqrt(params.gate_chi2 * (lam_p + lam_r + dt_abs * dt_abs * lam_v))
    if params.max_gate_m is not None:
        radius = np.minimum(radius, params.max_gate_m)
    v = track_v[track_idx]
    speed = np.hypot(v[:, 0], v[:, 1])
    radius = radius + speed * dt_half
    radius = radius * (1.0 + 1e-9) + 1e-6  # rounding margin; the exact gate follows
    centres = track_xy[track_idx] - v * dt_mid
    tree = cKDTree(plot_xy[plot_idx])
    hits = tree.query_ball_point(centres, radius, return_sorted=False)
    lens = np.fromiter(map(len, hits), dtype=np.intp, count=len(hits))
    total = int(lens.sum())
    flat = np.fromiter(itertools.chain.from_iterable(hits), dtype=np.intp, count=total)
    pair_plot = plot_idx[flat]
    pair_track = np.repeat(track_idx, lens)
    return pair_plot, pair_track


def _assign_per_radar(
    pair_plot: np.ndarray,
    pair_slot: np.ndarray,
    pair_cost: np.ndarray,
    n_plots: int,
    dummy_cost: float,
) -> np.ndarray:
    """Min-cost assignment of plots to (track, radar) slots, at most one plot per slot.

    Leaving a plot out costs ``dummy_cost``.  Returns, for each of the n_plots plots, the
    index of its chosen pair or −1.  A connected component of the plot–slot graph in
    which no two plots share their best slot is solved by taking each plot's best pair
    (the sum of the per-plot minima is a lower bound, so it is optimal); the components
    with a conflict are solved together by one sparse LAPJV call.
    """
    assign = np.full(n_plots, -1, dtype=np.intp)
    if pair_plot.size == 0:
        return assign
    best = _first_per_group(pair_plot, pair_cost)
    slots, slot_id = np.unique(pair_slot, return_inverse=True)
    n_slots = slots.shape[0]
    demand = np.bincount(slot_id[best], minlength=n_slots)
    if not np.any(demand > 1):
        assign[pair_plot[best]] = best
        return assign

    plots_u, plot_id = np.unique(pair_plot, return_inverse=True)
    n_pu = plots_u.shape[0]
    graph = coo_matrix(
        (np.ones(pair_plot.shape[0]), (plot_id, n_pu + slot_id)),
        shape=(n_pu + n_slots, n_pu + n_slots),
    )
    _, comp = connected_components(graph, directed=False)
    bad_comp = np.zeros(int(comp.max()) + 1, dtype=bool)
    bad_comp[comp[n_pu + np.flatnonzero(demand > 1)]] = True
    plot_bad = bad_comp[comp[:n_pu]]

    easy = best[~plot_bad[plot_id[best]]]
    assign[pair_plot[easy]] = easy

    hard_pairs = np.flatnonzero(plot_bad[plot_id])
    hard_plots_u, rows = np.unique(plot_id[hard_pairs], return_inverse=True)
    hard_slots_u, cols = np.unique(slot_id[hard_pairs], return_inverse=True)
    n_rows = hard_plots_u.shape[0]
    n_cols = hard_slots_u.shape[0]
    # Weights are offset by +1 so that no weight is zero (LAPJVsp ignores zeros); every
    # row is matched exactly once, so the offset adds the same constant to every solution.
    data = np.concatenate([pair_cost[hard_pairs] + 1.0, np.full(n_rows, dummy_cost + 1.0)])
    r_all = np.concatenate([rows, np.arange(n_rows)])
    c_all = np.concatenate([cols, n_cols + np.arange(n_rows)])
    matrix = csr_matrix((data, (r_all, c_all)), shape=(n_rows, n_cols + n_rows))
    m_rows, m_cols = min_weight_full_bipartite_matching(matrix)
    real = m_cols < n_cols
    m_rows = m_rows[real]
    m_cols = m_cols[real]
    # Map the matched (row, col) back to pair indices through a sorted key.
    key = rows.astype(np.int64) * n_cols + cols
    order = np.argsort(key)
    pos = np.searchsorted(key[order], m_rows.astype(np.int64) * n_cols + m_cols)
    chosen = hard_pairs[order[pos]]
    assign[pair_plot[chosen]] = chosen
    return assign


def _transfer_track_clusters(
    assign: np.ndarray,
    pair_plot: np.ndarray,
    pair_track: np.ndarray,
    pair_radar: np.ndarray,
    pair_xy: np.ndarray,
    track_xy: np.ndarray,
    n_radars: int,
    anchor_weight: float,
    max_iterations: int,
) -> tuple[np.ndarray, int]:
    """Batched transfer test (eq. 3 corrected) among the track clusters.

    Cluster j holds its predicted point (weight ``anchor_weight``) and its assigned
    aligned plots; W_j is the total weight and m_j the weighted centroid (eq. 1).  A plot
    may only move to another track whose gate it passed and whose slot for the plot's
    radar is free.  Returns the new assignment (pair index per plot) and the number of
    rounds that moved plots.
    """
    assign = assign.copy()
    n_tracks = track_xy.shape[0]
    n_plots = assign.shape[0]
    if max_iterations == 0 or pair_plot.size == 0:
        return assign, 0
    # Only plots with at least two gated tracks can ever move.
    n_pairs_of_plot = np.bincount(pair_plot, minlength=n_plots)
    movable = np.flatnonzero(n_pairs_of_plot[pair_plot] >= 2)
    if movable.size == 0:
        return assign, 0

    plot_track = np.full(n_plots, -1, dtype=np.intp)
    used = np.flatnonzero(assign >= 0)
    plot_track[used] = pair_track[assign[used]]
    # Positions relative to a local origin keep the centroid sums well conditioned.
    origin = track_xy.mean(axis=0)
    txy = track_xy - origin
    pxy = pair_xy - origin
    weight = np.full(n_tracks, anchor_weight, dtype=float)
    weight += np.bincount(plot_track[used], minlength=n_tracks)
    sums = anchor_weight * txy
    sums[:, 0] += np.bincount(plot_track[used], weights=pxy[assign[used], 0], minlength=n_tracks)
    sums[:, 1] += np.bincount(plot_track[used], weights=pxy[assign[used], 1], minlength=n_tracks)
    occupied = np.zeros((n_tracks, n_radars), dtype=bool)
    occupied[pair_track[assign[used]], pair_radar[assign[used]]] = True

    mv_plot = pair_plot[movable]
    mv_track = pair_track[movable]
    mv_radar = pair_radar[movable]
    rounds = 0
    for _ in range(max_iterations):
        cur = assign[mv_plot]
        cand = (cur >= 0) & (mv_track != plot_track[mv_plot]) & ~occupied[mv_track, mv_radar]
        if not np.any(cand):
            break
        c_pair = movable[cand]
        c_cur = cur[cand]
        src = pair_track[c_cur]
        dst = mv_track[cand]
        centroid = sums / weight[:, None]
        rho_src = transfer_rho(pxy[c_cur], centroid[src], weight[src], True)
        rho_dst = transfer_rho(pxy[c_pair], centroid[dst], weight[dst], False)
        gain = rho_src - rho_dst
        better = gain > 1e-9 * (rho_src + rho_dst) + 1e-6
        if not np.any(better):
            break
        c_pair = c_pair[better]
        c_cur = c_cur[better]
        src = src[better]
        dst = dst[better]
        gain = gain[better]
        # Keep the moves that are the best of both their clusters: they touch disjoint
        # clusters, so applied together they decrease E by exactly the sum of the gains.
        rank = np.empty(gain.shape[0], dtype=np.intp)
        rank[np.argsort(-gain, kind="stable")] = np.arange(gain.shape[0])
        best_rank = np.full(n_tracks, gain.shape[0], dtype=np.intp)
        np.minimum.at(best_rank, src, rank)
        np.minimum.at(best_rank, dst, rank)
        acc = (best_rank[src] == rank) & (best_rank[dst] == rank)
        c_pair = c_pair[acc]
        c_cur = c_cur[acc]
        src = src[acc]
        dst = dst[acc]
        radar = pair_radar[c_pair]
        weight[src] -= 1.0
        weight[dst] += 1.0
        sums[src] -= pxy[c_cur]
        sums[dst] += pxy[c_pair]
        occupied[src, radar] = False
        occupied[dst, radar] = True
        moved_plots = pair_plot[c_pair]
        assign[moved_plots] = c_pair
        plot_track[moved_plots] = dst
        rounds += 1
    return assign, rounds


# --------------------------------------------------------------------------------------
# new-target phase


def _kmeans_component(
    xy: np.ndarray, radar: np.ndarray, compat: np.ndarray, max_iterations: int
) -> tuple[np.ndarray, np.ndarray, int]:
    """Sequential constrained k-means of one small new-target component (Shu §2.3).

    ``compat[a, b]`` says plots a and b may share a cluster (different radars, identity,
    distance); the diagonal is True.  Seed: the plots of the radar with most plots open
    one cluster each; the plots of every further radar are assigned to the clusters by a
    dense assignment on squared distance to the centroid (only clusters whose members are
    all compatible), the rest open new clusters.  Then Shu's steps 3-6: each plot in turn
    moves to the compatible cluster of smallest ρ_j when ρ_j < ρ_i (eq. 3 corrected),
    until a sweep moves nothing or ``max_iterations`` sweeps.  This Python loop runs only
    over the plots of the rare conflicting components.
    """
    n = xy.shape[0]
    radars, counts = np.unique(radar, return_counts=True)
    radar_order = radars[np.lexsort((radars, -counts))]
    labels = np.full(n, -1, dtype=np.intp)
    first = np.flatnonzero(radar == radar_order[0])
    labels[first] = np.arange(first.size)
    n_clusters = first.size
    for r in radar_order[1:]:
        members = np.flatnonzero(radar == r)
        onehot = np.zeros((n, n_clusters))
        placed = labels >= 0
        onehot[np.flatnonzero(placed), labels[placed]] = 1.0
        size = onehot.sum(axis=0)
        centroid = (onehot.T @ xy) / size[:, None]
        incompatible = (~compat[members]).astype(float) @ onehot > 0
        diff = xy[members, None, :] - centroid[None, :, :]
        cost = np.einsum("pkc,pkc->pk", diff, diff)
        cost[incompatible] = _BIG_COST
        rows, cols = linear_sum_assignment(cost)
        ok = ~incompatible[rows, cols]
        labels[members[rows[ok]]] = cols[ok]
        rest = members[labels[members] < 0]
        labels[rest] = n_clusters + np.arange(rest.size)
        n_clusters += rest.size
    seed = labels.copy()

    # Shu steps 3-6 on plain Python lists: the component is small, and numpy's per-call
    # overhead would dominate.
    lab = labels.tolist()
    px = xy[:, 0].tolist()
    py = xy[:, 1].tolist()
    rad = radar.tolist()
    compat_rows = compat.tolist()
    members: list[set[int]] = [set() for _ in range(n_clusters)]
    for p, c in enumerate(lab):
        members[c].add(p)
    sx = [sum(px[q] for q in m) for m in members]
    sy = [sum(py[q] for q in m) for m in members]
    sweeps = 0
    for _ in range(max_iterations):
        moved = False
        for p in range(n):
            i = lab[p]
            n_i = len(members[i])
            if n_i <= 1:
                continue  # ρ_i = 0: leaving a singleton never lowers E
            dx = px[p] - sx[i] / n_i
            dy = py[p] - sy[i] / n_i
            rho_i = n_i / (n_i - 1.0) * (dx * dx + dy * dy)
            best_j = -1
            best_rho = rho_i - (1e-9 * rho_i + 1e-6)
            row = compat_rows[p]
            for j in range(n_clusters):
                m_j = members[j]
                n_j = len(m_j)
                if j == i or n_j == 0:
                    continue
                if any(rad[q] == rad[p] or not row[q] for q in m_j):
                    continue
                dx = px[p] - sx[j] / n_j
                dy = py[p] - sy[j] / n_j
                rho_j = n_j / (n_j + 1.0) * (dx * dx + dy * dy)
                if rho_j < best_rho:
                    best_rho = rho_j
                    best_j = j
            if best_j >= 0:
                members[i].discard(p)
                members[best_j].add(p)
                sx[i] -= px[p]
                sy[i] -= py[p]
                sx[best_j] += px[p]
                sy[best_j] += py[p]
                lab[p] = best_j
                moved = True
        if not moved:
            break
        sweeps += 1
    labels = np.asarray(lab, dtype=np.intp)
    # Compact the labels (a cluster may have emptied).
    _, labels = np.unique(labels, return_inverse=True)
    _, seed = np.unique(seed, return_inverse=True)
    return seed, labels, sweeps


def _cluster_new_targets(
    xy: np.ndarray,
    t_s: np.ndarray,
    radar: np.ndarray,
    mode_s: np.ndarray,
    mode3a: np.ndarray,
    n_radars: int,
    params: ClusteringParams,
) -> tuple[np.ndarray, np.ndarray, int]:
    """Cluster the plots outside every track gate among themselves (Shu cases 1 and 3).

    Two plots may share a cluster iff they come from different radars, their identities
    are compatible and |z_p − z_q| ≤ new_target_gate_m + max_speed_mps·|t_p − t_q|
    (measurement spread plus the distance the target can fly between the detections; a
    cluster is complete-linkage in this relation).  Returns (seed labels, labels, sweeps)
    with labels 0..K−1.
    """
    n = xy.shape[0]
    if n == 0:
        empty = np.empty(0, dtype=np.intp)
        return empty, empty, 0
    span_s = float(t_s.max() - t_s.min())
    r_max = params.new_target_gate_m + params.max_speed_mps * span_s
    tree = cKDTree(xy)
    pairs = tree.query_pairs(r_max * (1.0 + 1e-9) + 1e-6, output_type="ndarray")
    a = pairs[:, 0]
    b = pairs[:, 1]
    dist = np.hypot(xy[a, 0] - xy[b, 0], xy[a, 1] - xy[b, 1])
    limit = params.new_target_gate_m + params.max_speed_mps * np.abs(t_s[a] - t_s[b])
    ok = (dist <= limit) & (radar[a] != radar[b])
    ok &= _identity_compatible(mode_s[a], mode_s[b], mode3a[a], mode3a[b], params.use_mode3a)
    a = a[ok]
    b = b[ok]
    graph = coo_matrix((np.ones(a.size), (a, b)), shape=(n, n))
    n_comp, comp = connected_components(graph, directed=False)
    size = np.bincount(comp, minlength=n_comp)
    degree = np.bincount(a, minlength=n) + np.bincount(b, minlength=n)
    simple = np.ones(n_comp, dtype=bool)
    simple[comp[degree != size[comp] - 1]] = False  # not a clique
    distinct = np.unique(comp.astype(np.int64) * n_radars + radar)
    simple &= np.bincount(distinct // n_radars, minlength=n_comp) == size  # radar repeated

    labels = np.full(n, -1, dtype=np.intp)
    seed = np.full(n, -1, dtype=np.intp)
    simple_ids = np.flatnonzero(simple)
    remap = np.full(n_comp, -1, dtype=np.intp)
    remap[simple_ids] = np.arange(simple_ids.size)
    in_simple = simple[comp]
    labels[in_simple] = remap[comp[in_simple]]
    seed[in_simple] = labels[in_simple]
    n_final = simple_ids.size
    n_seed = simple_ids.size
    sweeps = 0
    complex_ids = np.flatnonzero(~simple)
    if complex_ids.size:
        node_order = np.argsort(comp, kind="stable")
        node_start = np.concatenate([[0], np.cumsum(size)])
        edge_comp = comp[a]
        edge_order = np.argsort(edge_comp, kind="stable")
        edge_start = np.concatenate([[0], np.cumsum(np.bincount(edge_comp, minlength=n_comp))])
        local = np.empty(n, dtype=np.intp)
        for c in complex_ids:  # rare: components with a conflict
            nodes = node_order[node_start[c] : node_start[c + 1]]
            local[nodes] = np.arange(nodes.size)
            edges = edge_order[edge_start[c] : edge_start[c + 1]]
            compat = np.eye(nodes.size, dtype=bool)
            compat[local[a[edges]], local[b[edges]]] = True
            compat[local[b[edges]], local[a[edges]]] = True
            s_lab, f_lab, k_sweeps = _kmeans_component(
                xy[nodes], radar[nodes], compat, params.max_iterations
            )
            seed[nodes] = n_seed + s_lab
            labels[nodes] = n_final + f_lab
            n_seed += int(s_lab.max()) + 1
            n_final += int(f_lab.max()) + 1
            sweeps = max(sweeps, k_sweeps)
    return seed, labels, sweeps


# --------------------------------------------------------------------------------------
# assembly


def _labels_from_assignment(
    assign: np.ndarray,
    pair_track: np.ndarray,
    new_idx: np.ndarray,
    new_labels: np.ndarray,
    n_plots: int,
) -> tuple[np.ndarray, np.ndarray]:
    """Cluster labels (track clusters first, in track order, then new targets)."""
    labels = np.full(n_plots, -1, dtype=np.intp)
    used = np.flatnonzero(assign >= 0)
    tracks_of_used = pair_track[assign[used]]
    cluster_tracks, inverse = np.unique(tracks_of_used, return_inverse=True)
    labels[used] = inverse
    k_tracks = cluster_tracks.size
    n_new = int(new_labels.max()) + 1 if new_labels.size else 0
    labels[new_idx] = k_tracks + new_labels
    cluster_track = np.concatenate([cluster_tracks, np.full(n_new, -1, dtype=np.intp)])
    return labels, cluster_track.astype(np.intp)


def _sse_m2(
    labels: np.ndarray,
    cluster_track: np.ndarray,
    point_xy: np.ndarray,
    track_xy: np.ndarray,
    anchor_weight: float,
) -> float:
    """E of eq. 2 with each track cluster's predicted point as a weighted member."""
    k = cluster_track.shape[0]
    if k == 0:
        return 0.0
    used = labels >= 0
    lab = labels[used]
    pts = point_xy[used]
    origin = pts.mean(axis=0)
    pts = pts - origin
    weight = np.bincount(lab, minlength=k).astype(float)
    sx = np.bincount(lab, weights=pts[:, 0], minlength=k)
    sy = np.bincount(lab, weights=pts[:, 1], minlength=k)
    has = cluster_track >= 0
    anchors = track_xy[cluster_track[has]] - origin
    weight[has] += anchor_weight
    sx[has] += anchor_weight * anchors[:, 0]
    sy[has] += anchor_weight * anchors[:, 1]
    centroid = np.stack([sx / weight, sy / weight], axis=1)
    d = pts - centroid[lab]
    e = float(np.einsum("ij,ij->", d, d))
    da = anchors - centroid[has]
    e += float(anchor_weight * np.einsum("ij,ij->", da, da))
    return e


def cluster_plots(
    plot_xy_m: np.ndarray,
    plot_cov_m2: np.ndarray,
    plot_t_s: np.ndarray,
    plot_radar: np.ndarray,
    plot_mode_s: np.ndarray,
    plot_mode3a: np.ndarray,
    track_xy_m: np.ndarray,
    track_v_mps: np.ndarray,
    track_cov_pos_m2: np.ndarray,
    track_cov_vel: np.ndarray,
    track_mode_s: np.ndarray,
    track_mode3a: np.ndarray,
    t_ref_s: float,
    params: ClusteringParams = ClusteringParams(),
) -> ClusterResult:
    """Align one period's plots to ``t_ref_s`` and cluster them (see the module docstring).

    Plots: positions (M, 2) in m, covariances (M, 2, 2) in m², detection times (M,) in s,
    radar index (M,), Mode S address (M,) int64 and Mode 3/A code (M,) int, −1 = none.
    Tracks, predicted to t_ref_s: position (N, 2), velocity (N, 2) in m/s, position and
    velocity covariances (N, 2, 2), Mode S / Mode 3/A identity (N,), −1 = unknown.
    Plots or tracks with non-finite values are ignored (plots get label −1).
    """
    plot_xy = np.asarray(plot_xy_m, dtype=float).reshape(-1, 2)
    n_plots = plot_xy.shape[0]
    plot_cov = np.asarray(plot_cov_m2, dtype=float).reshape(n_plots, 2, 2)
    plot_t = np.asarray(plot_t_s, dtype=float).reshape(n_plots)
    plot_radar_raw = np.asarray(plot_radar).reshape(n_plots)
    plot_ms = np.asarray(plot_mode_s, dtype=np.int64).reshape(n_plots)
    plot_3a = np.asarray(plot_mode3a, dtype=np.int64).reshape(n_plots)
    track_xy = np.asarray(track_xy_m, dtype=float).reshape(-1, 2)
    n_tracks = track_xy.shape[0]
    track_v = np.asarray(track_v_mps, dtype=float).reshape(n_tracks, 2)
    track_cp = np.asarray(track_cov_pos_m2, dtype=float).reshape(n_tracks, 2, 2)
    track_cv = np.asarray(track_cov_vel, dtype=float).reshape(n_tracks, 2, 2)
    track_ms = np.asarray(track_mode_s, dtype=np.int64).reshape(n_tracks)
    track_3a = np.asarray(track_mode3a, dtype=np.int64).reshape(n_tracks)
    t_ref = float(t_ref_s)

    _, radar = np.unique(plot_radar_raw, return_inverse=True)
    radar = radar.reshape(n_plots).astype(np.intp)
    n_radars = int(radar.max()) + 1 if n_plots else 1
    dt_s = t_ref - plot_t
    plot_ok = (
        np.isfinite(plot_xy).all(axis=1)
        & np.isfinite(plot_cov).all(axis=(1, 2))
        & np.isfinite(dt_s)
    )
    track_ok = (
        np.isfinite(track_xy).all(axis=1)
        & np.isfinite(track_v).all(axis=1)
        & np.isfinite(track_cp).all(axis=(1, 2))
        & np.isfinite(track_cv).all(axis=(1, 2))
    )

    # 1-3: candidate pairs, time alignment with the track's velocity, gating.
    pair_plot, pair_track = _candidate_pairs(
        plot_xy, plot_cov, dt_s, plot_ok, track_xy, track_v, track_cp, track_cv, track_ok, params
    )
    pair_xy, pair_cov = align_to_reference(
        plot_xy[pair_plot],
        plot_cov[pair_plot],
        plot_t[pair_plot],
        t_ref,
        track_v[pair_track],
        track_cv[pair_track],
    )
    resid = pair_xy - track_xy[pair_track]
    d2 = _mahalanobis2_2x2(resid, track_cp[pair_track] + pair_cov)
    gated = d2 <= params.gate_chi2
    if params.max_gate_m is not None:
        gated &= np.hypot(resid[:, 0], resid[:, 1]) <= params.max_gate_m
    gated &= _identity_compatible(
        plot_ms[pair_plot],
        track_ms[pair_track],
        plot_3a[pair_plot],
        track_3a[pair_track],
        params.use_mode3a,
    )
    pair_plot = pair_plot[gated]
    pair_track = pair_track[gated]
    pair_xy = pair_xy[gated]
    pair_cov = pair_cov[gated]
    d2 = d2[gated]
    pair_radar = radar[pair_plot]

    # 4: seed, nearest representative with one plot per radar per cluster.
    seed_assign = _assign_per_radar(
        pair_plot, pair_track * n_radars + pair_radar, d2, n_plots, params.gate_chi2
    )
    # 5: transfers among the track clusters (eq. 3 corrected).
    assign, track_rounds = _transfer_track_clusters(
        seed_assign,
        pair_plot,
        pair_track,
        pair_radar,
        pair_xy,
        track_xy,
        n_radars,
        params.track_anchor_weight,
        params.max_iterations,
    )

    # 6: new targets, plots outside every gate, aligned with zero velocity.
    in_gate = np.zeros(n_plots, dtype=bool)
    in_gate[pair_plot] = True
    new_idx = np.flatnonzero(plot_ok & ~in_gate)
    new_seed, new_labels, new_sweeps = _cluster_new_targets(
        plot_xy[new_idx],
        plot_t[new_idx],
        radar[new_idx],
        plot_ms[new_idx],
        plot_3a[new_idx],
        n_radars,
        params,
    )

    # Aligned positions: zero velocity (variance max_speed²/2 per axis) by default; the
    # assigned track's velocity for track clusters; the best gated track's for the
    # redundant plots.
    v_var = 0.5 * params.max_speed_mps**2
    aligned_xy, aligned_cov = align_to_reference(
        plot_xy, plot_cov, plot_t, t_ref, np.zeros(2), v_var * np.eye(2)
    )
    if pair_plot.size:
        best = _first_per_group(pair_plot, d2)
        aligned_xy[pair_plot[best]] = pair_xy[best]
        aligned_cov[pair_plot[best]] = pair_cov[best]
    used = np.flatnonzero(assign >= 0)
    aligned_xy[used] = pair_xy[assign[used]]
    aligned_cov[used] = pair_cov[assign[used]]
    redundant = in_gate & (assign < 0)

    labels, cluster_track = _labels_from_assignment(
        assign, pair_track, new_idx, new_labels, n_plots
    )
    seed_labels, seed_cluster_track = _labels_from_assignment(
        seed_assign, pair_track, new_idx, new_seed, n_plots
    )
    seed_xy = aligned_xy.copy()
    seed_used = np.flatnonzero(seed_assign >= 0)
    seed_xy[seed_used] = pair_xy[seed_assign[seed_used]]
    w = params.track_anchor_weight
    return ClusterResult(
        labels=labels,
        cluster_track=cluster_track,
        aligned_xy_m=aligned_xy,
        aligned_cov_m2=aligned_cov,
        n_iterations=max(track_rounds, new_sweeps),
        sse_m2=_sse_m2(labels, cluster_track, aligned_xy, track_xy, w),
        redundant=redundant,
        seed_labels=seed_labels,
        seed_cluster_track=seed_cluster_track,
        sse_seed_m2=_sse_m2(seed_labels, seed_cluster_track, seed_xy, track_xy, w),
    )
