"""Plots to tracks (Shu 2007 §2, case 2): gating and the track clusters of k-means.

Steps 1-5 of the algorithm in clustering.py, whose module docstring has the notation
(eq. 1-3): time alignment of a plot with a track's velocity, candidate pairs from a k-d
tree, the Mahalanobis gate with identity compatibility, the seed assignment with one
plot per radar per cluster (global nearest neighbour, Jonker-Volgenant), and the batched
transfers between track clusters by the corrected eq. 3.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike
from scipy.sparse import coo_matrix, csr_matrix
from scipy.sparse.csgraph import connected_components, min_weight_full_bipartite_matching

from .compiled import compiled

if TYPE_CHECKING:
    from .clustering import ClusteringParams

__all__ = ["align_to_reference", "assign_per_radar", "gated_pairs", "transfer_rho", "transfer_track_clusters"]


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


def transfer_rho(p_xy: ArrayLike, centroid_xy: ArrayLike, n_members: ArrayLike, own: ArrayLike) -> np.ndarray:
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
    return np.asarray(factor * d2)


# --------------------------------------------------------------------------------------
# small vectorised helpers


def lambda_max_2x2(cov: np.ndarray) -> np.ndarray:
    """Largest eigenvalue of symmetric 2×2 matrices (…, 2, 2)."""
    a = cov[..., 0, 0]
    c = cov[..., 1, 1]
    b = 0.5 * (cov[..., 0, 1] + cov[..., 1, 0])
    half_diff = 0.5 * (a - c)
    return np.asarray(0.5 * (a + c) + np.sqrt(half_diff * half_diff + b * b))


def mahalanobis2_2x2(y: np.ndarray, s: np.ndarray) -> np.ndarray:
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


def warm_up() -> None:
    """Run the compiled loops of this module once, on one track and one plot: numba
    compiles them (or loads them from its cache) at their first call, which would
    otherwise fall in the first period a daemon processes (Engine calls this)."""
    one = np.zeros((1, 2))
    _within_radius(one, one, np.ones(1))
    _min_model_d2(np.zeros(1), one, np.eye(2)[None], np.zeros(1, np.int64), one[:, None], np.eye(2)[None, None])


@compiled
def _min_model_d2(
    d2: np.ndarray, xy: np.ndarray, cov: np.ndarray, track: np.ndarray, model_xy: np.ndarray, model_cov: np.ndarray
) -> np.ndarray:
    """Per pair, the smallest of d2 and of yᵀS⁻¹y over the track's models, with y = xy −
    model_xy[track, j] and S = model_cov[track, j] + cov (mahalanobis2_2x2's rule: a model
    whose S is not positive definite gives +inf)."""
    out = d2.copy()
    for p in range(d2.shape[0]):
        t = track[p]
        for j in range(model_xy.shape[1]):
            a = model_cov[t, j, 0, 0] + cov[p, 0, 0]
            c = model_cov[t, j, 1, 1] + cov[p, 1, 1]
            b = 0.5 * (model_cov[t, j, 0, 1] + cov[p, 0, 1] + model_cov[t, j, 1, 0] + cov[p, 1, 0])
            det = a * c - b * b
            if not (det > 0.0 and a > 0.0):
                continue
            y0 = xy[p, 0] - model_xy[t, j, 0]
            y1 = xy[p, 1] - model_xy[t, j, 1]
            v = (c * y0 * y0 - 2.0 * b * y0 * y1 + a * y1 * y1) / det
            if v < out[p]:
                out[p] = v
    return out


#: Mode 3/A codes that say nothing of who flies (ICAO Doc 8168 / the European code plan):
#: emergency 7700, radio failure 7600, unlawful interference 7500 (a squawk an aircraft
#: changes *to*), the conspicuity codes 7000 (VFR, Europe), 2000 (entering SSR airspace),
#: 1200 (VFR, North America) and 0000. They never make two reports incompatible.
NON_IDENTITY_MODE3A = np.array([0o7700, 0o7600, 0o7500, 0o7000, 0o2000, 0o1200, 0o0000], dtype=np.int64)


def is_identity_code(code: np.ndarray) -> np.ndarray:
    """(n,) bool: a known Mode 3/A code that names an aircraft (not one of
    :data:`NON_IDENTITY_MODE3A`)."""
    code = np.asarray(code)
    return np.asarray((code >= 0) & ~np.isin(code, NON_IDENTITY_MODE3A))


def identity_compatible(s1: np.ndarray, s2: np.ndarray, a1: np.ndarray, a2: np.ndarray, use_mode3a: bool) -> np.ndarray:
    """May two reports be one aircraft by their identities (−1 unknown)?

    The Mode S address decides: two different addresses are two aircraft, the same address
    one (whatever the Mode 3/A codes say: a squawk change is an instruction, not a new
    aircraft). Without an address on both, Mode 3/A is a soft cue (codes are reused and
    changed): two different codes keep reports apart only when both are known and neither
    is one of :data:`NON_IDENTITY_MODE3A`.
    """
    ok = (s1 < 0) | (s2 < 0) | (s1 == s2)
    if use_mode3a:
        by_address = (s1 >= 0) & (s2 >= 0)
        same_or_unknown = (a1 < 0) | (a2 < 0) | (a1 == a2)
        generic = np.isin(a1, NON_IDENTITY_MODE3A) | np.isin(a2, NON_IDENTITY_MODE3A)
        ok &= by_address | same_or_unknown | generic
    return np.asarray(ok)


def identity_pairs(
    plot_ms: np.ndarray,
    plot_ok: np.ndarray,
    plot_xy: np.ndarray,
    plot_cov: np.ndarray,
    plot_t: np.ndarray,
    track_ms: np.ndarray,
    track_ok: np.ndarray,
    last_xy: np.ndarray,
    last_cov: np.ndarray,
    last_t: np.ndarray,
    max_speed_mps: float,
    alt: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """(plot, track) pairs of one Mode S address, inside a sanity gate from the maximum speed.

    A plot that carries the address of a live track belongs to that track, even when a
    manoeuvre has taken it out of the statistical gate (the prediction ran straight on
    while the aircraft turned): the address is the aircraft's own. The only check is that
    the aircraft could have flown there: the plot lies within

        max_speed · |t_plot − t_last| + 3·sqrt(λ_max(R_plot) + λ_max(P_last))

    of the track's last measured position (its state at its own time t_last), which
    refuses a corrupted or duplicated address far away. With two live tracks on one
    address (until the engine merges them), the older (its row comes first) is taken.
    ``alt``: a second measured position per track (positions, covariances, times, NaN time:
    none; and how long after its time it serves) that the plot may be within reach of
    instead (:func:`reach_either`).
    """
    p, t = address_pairs(plot_ms, plot_ok, track_ms, track_ok)
    ok = reach_either(plot_xy[p], plot_cov[p], plot_t[p], (last_xy, last_cov, last_t), alt, t, max_speed_mps)
    return p[ok], t[ok]


def reach_either(
    plot_xy: np.ndarray,
    plot_cov: np.ndarray,
    plot_t: np.ndarray,
    last: tuple[np.ndarray, np.ndarray, np.ndarray],
    alt: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None,
    track: np.ndarray,
    max_speed_mps: float,
) -> np.ndarray:
    """:func:`within_reach` of each plot from its track's (``track``) last measured position
    or from its alternative one (``alt``: positions, covariances, times and how long after
    its time each serves; where its time is finite and the plot within that time): a track
    of one plot that holds a contradicting plot of the same address beside it
    (track_management.merge_same_address) does not know which of the two is the wild one."""
    lx, lc, lt = last
    ok = within_reach(plot_xy, plot_cov, plot_t, lx[track], lc[track], lt[track], max_speed_mps)
    if alt is not None:
        ax, ac, at, window_s = alt
        has = np.isfinite(at[track]) & ~ok & (plot_t - at[track] <= window_s[track])
        if has.any():
            i, ti = np.flatnonzero(has), track[has]
            ok[i] = within_reach(plot_xy[i], plot_cov[i], plot_t[i], ax[ti], ac[ti], at[ti], max_speed_mps)
    return ok


def address_pairs(
    plot_ms: np.ndarray, plot_ok: np.ndarray, track_ms: np.ndarray, track_ok: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """(plot, track) pairs of one Mode S address among the plots and tracks ``*_ok``, with
    no gate; with two such tracks on one address (until the engine merges them), the older
    (its row comes first) is taken."""
    has = np.flatnonzero(plot_ok & (plot_ms >= 0))
    rows = np.flatnonzero(track_ok & (track_ms >= 0))
    empty = np.empty(0, dtype=np.intp)
    if not has.size or not rows.size:
        return empty, empty
    order = rows[np.argsort(track_ms[rows], kind="stable")]
    keys = track_ms[order]
    at = np.minimum(np.searchsorted(keys, plot_ms[has]), keys.size - 1)
    hit = keys[at] == plot_ms[has]
    return has[hit].astype(np.intp), order[at[hit]].astype(np.intp)


def within_reach(
    plot_xy: np.ndarray,
    plot_cov: np.ndarray,
    plot_t: np.ndarray,
    last_xy: np.ndarray,
    last_cov: np.ndarray,
    last_t: np.ndarray,
    max_speed_mps: float,
) -> np.ndarray:
    """Could the aircraft have flown from its track's last measured position to the plot?

    Pairwise (K,) over aligned rows: |plot − last| ≤ max_speed · |t_plot − t_last|
    + 3·sqrt(λ_max(R_plot) + λ_max(P_last)), the sanity gate of :func:`identity_pairs`.
    """
    margin_m = 3.0 * np.sqrt(lambda_max_2x2(plot_cov) + lambda_max_2x2(last_cov))
    reach_m = max_speed_mps * np.abs(plot_t - last_t) + margin_m
    d = plot_xy - last_xy
    return np.asarray(np.hypot(d[:, 0], d[:, 1]) <= reach_m)


def sorted_unique(a: np.ndarray) -> np.ndarray:
    """The distinct values of ``a``, sorted: np.unique's result by a sort and a neighbour
    comparison, as np.unique's hash path (numpy >= 2.3) is several times slower on the
    millions of int64 keys of 4,000 tracks (STCA's pairs, the new-target clustering)."""
    key = np.sort(a, axis=None)
    return key[np.r_[True, key[1:] != key[:-1]]] if key.size else key


def unique_inverse(a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``np.unique(a, return_inverse=True)`` for the engine's non-negative integer keys
    (plot, track and slot indices): by one bincount when their range is at most a few times
    their number, ~10× faster at a period's size (numpy's sort of 8,000 keys: 0.26-0.44
    ms; this 0.03-0.04); other input goes to np.unique."""
    a = np.asarray(a)
    if a.size and a.ndim == 1 and np.issubdtype(a.dtype, np.integer):
        lo, hi = int(a.min()), int(a.max())
        if lo >= 0 and hi <= 4 * a.size + 1024:
            present = np.bincount(a, minlength=hi + 1) > 0
            new = np.cumsum(present) - 1
            return np.flatnonzero(present).astype(a.dtype, copy=False), new[a]
    u, inv = np.unique(a, return_inverse=True)
    return u, inv.reshape(-1)


def first_per_group(group: np.ndarray, key: np.ndarray) -> np.ndarray:
    """Index of the element of smallest key in each group (groups given by ``group``)."""
    order = np.lexsort((key, group))
    g_sorted = group[order]
    first = np.ones(order.shape[0], dtype=bool)
    first[1:] = g_sorted[1:] != g_sorted[:-1]
    return order[first]


# --------------------------------------------------------------------------------------
# track phase


def candidate_pairs(
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
    lam_r = float(lambda_max_2x2(plot_cov[plot_idx]).max())
    lam_p = lambda_max_2x2(track_cov_pos[track_idx])
    lam_v = lambda_max_2x2(track_cov_vel[track_idx])
    radius = np.sqrt(params.gate_chi2 * (lam_p + lam_r + dt_abs * dt_abs * lam_v))
    if params.max_gate_m is not None:
        radius = np.minimum(radius, params.max_gate_m)
    v = track_v[track_idx]
    speed = np.hypot(v[:, 0], v[:, 1])
    radius = radius + speed * dt_half
    radius = radius * (1.0 + 1e-9) + 1e-6  # rounding margin; the exact gate follows
    centres = track_xy[track_idx] - v * dt_mid
    xy = np.ascontiguousarray(plot_xy[plot_idx], dtype=np.float64)
    flat, owner = _within_radius(xy, np.ascontiguousarray(centres, dtype=np.float64), radius)
    return plot_idx[flat], track_idx[owner]


@compiled
def _within_radius(xy: np.ndarray, centres: np.ndarray, radius: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Every (point, centre) pair with |xy_p − c_j| ≤ radius_j: points (P, 2), centres
    (C, 2), radius (C,). Returns point and centre indices, grouped by centre in order.

    A uniform grid over the points' extent, cells of the median radius (larger where that
    would make more than 4 cells a point), the points counting-sorted by cell; each centre
    scans the rows of cells its square covers, each row one contiguous run of points. Like
    a k-d tree's ball query, without a Python list per centre (scipy's cKDTree returns
    one, and flattening them took half of this step at 4,000 tracks)."""
    n_p, n_c = xy.shape[0], centres.shape[0]
    if n_p == 0 or n_c == 0:
        return np.empty(0, np.int64), np.empty(0, np.int64)
    x_min, y_min = xy[:, 0].min(), xy[:, 1].min()
    w, h = xy[:, 0].max() - x_min, xy[:, 1].max() - y_min
    max_cells = 4 * n_p + 64
    finite = radius[np.isfinite(radius)]
    cell = max(np.median(finite) if finite.size else 1.0, 1.0, np.sqrt(w * h / max_cells), (w + h) / max_cells)
    nx = int(w / cell) + 1
    ny = int(h / cell) + 1
    start = np.zeros(nx * ny + 1, np.int64)
    key = np.empty(n_p, np.int64)
    for p in range(n_p):
        key[p] = int((xy[p, 1] - y_min) / cell) * nx + int((xy[p, 0] - x_min) / cell)
        start[key[p] + 1] += 1
    for i in range(nx * ny):
        start[i + 1] += start[i]
    order = np.empty(n_p, np.int64)
    fill = start[:-1].copy()
    for p in range(n_p):  # counting sort, stable: the points of a cell in index order
        order[fill[key[p]]] = p
        fill[key[p]] += 1
    total = 0
    out_p = np.empty(0, np.int64)
    out_c = np.empty(0, np.int64)
    at = 0
    for stage in range(2):  # count, then fill
        if stage == 1:
            out_p = np.empty(total, np.int64)
            out_c = np.empty(total, np.int64)
        for c in range(n_c):
            r = radius[c]
            cx, cy = centres[c, 0], centres[c, 1]
            if not (r >= 0.0 and np.isfinite(cx) and np.isfinite(cy)):
                continue  # no gate, or no position: no candidate
            if np.isinf(r):
                gx0, gx1, gy0, gy1 = 0, nx - 1, 0, ny - 1
            else:  # the cells of the square about the circle, clipped to the grid
                gx0 = int(max(np.floor((cx - r - x_min) / cell), 0.0))
                gx1 = int(min(np.floor((cx + r - x_min) / cell), nx - 1.0))
                gy0 = int(max(np.floor((cy - r - y_min) / cell), 0.0))
                gy1 = int(min(np.floor((cy + r - y_min) / cell), ny - 1.0))
            if gx0 > gx1 or gy0 > gy1:
                continue
            r2 = r * r
            for gy in range(gy0, gy1 + 1):
                for q in range(start[gy * nx + gx0], start[gy * nx + gx1 + 1]):
                    p = order[q]
                    dx = xy[p, 0] - cx
                    dy = xy[p, 1] - cy
                    if dx * dx + dy * dy <= r2:
                        if stage == 0:
                            total += 1
                        else:
                            out_p[at] = p
                            out_c[at] = c
                            at += 1
    return out_p, out_c


def assign_per_radar(
    pair_plot: np.ndarray,
    pair_slot: np.ndarray,
    pair_cost: np.ndarray,
    n_plots: int,
    dummy_cost: float,
    best: np.ndarray | None = None,
) -> np.ndarray:
    """Min-cost assignment of plots to (track, radar) slots, at most one plot per slot.

    Leaving a plot out costs ``dummy_cost``.  Returns, for each of the n_plots plots, the
    index of its chosen pair or −1.  A connected component of the plot–slot graph in
    which no two plots share their best slot is solved by taking each plot's best pair
    (the sum of the per-plot minima is a lower bound, so it is optimal); the components
    with a conflict are solved together by one sparse LAPJV call.  ``best``: each plot's
    cheapest pair, ``first_per_group(pair_plot, pair_cost)``, when the caller has it.
    """
    assign = np.full(n_plots, -1, dtype=np.intp)
    if pair_plot.size == 0:
        return assign
    if best is None:
        best = first_per_group(pair_plot, pair_cost)
    slots, slot_id = unique_inverse(pair_slot)
    n_slots = slots.shape[0]
    demand = np.bincount(slot_id[best], minlength=n_slots)
    if not np.any(demand > 1):
        assign[pair_plot[best]] = best
        return assign

    plots_u, plot_id = unique_inverse(pair_plot)
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
    hard_plots_u, rows = unique_inverse(plot_id[hard_pairs])
    hard_slots_u, cols = unique_inverse(slot_id[hard_pairs])
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


def transfer_track_clusters(
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


#: assignment cost factor of a pair whose plot carries its track's Mode S address: such a
#: pair is preferred to every pair without it (costs of other pairs are d² ≥ 0), while the
#: order by d² among a track's own-address plots is kept
IDENTITY_COST_FACTOR = 1.0e-6


def _gate_d2(
    d2: np.ndarray,
    xy: np.ndarray,
    cov: np.ndarray,
    track: np.ndarray,
    models: tuple[np.ndarray, np.ndarray] | None,
) -> np.ndarray:
    """The gate's d² of (plot, track) pairs: the smallest over the combined prediction's
    ``d2`` and each IMM model's (:func:`_min_model_d2`), or ``d2`` itself without models."""
    if models is None or not track.size:
        return d2
    return _min_model_d2(
        d2,
        np.ascontiguousarray(xy, dtype=np.float64),
        np.ascontiguousarray(cov, dtype=np.float64),
        np.ascontiguousarray(track, dtype=np.int64),
        np.ascontiguousarray(models[0], dtype=np.float64),
        np.ascontiguousarray(models[1], dtype=np.float64),
    )


def gated_pairs(
    plot_xy: np.ndarray,
    plot_cov: np.ndarray,
    plot_t: np.ndarray,
    dt_s: np.ndarray,
    plot_ok: np.ndarray,
    plot_ms: np.ndarray,
    plot_3a: np.ndarray,
    track_xy: np.ndarray,
    track_v: np.ndarray,
    track_cp: np.ndarray,
    track_cv: np.ndarray,
    track_ok: np.ndarray,
    track_ms: np.ndarray,
    track_3a: np.ndarray,
    t_ref: float,
    params: ClusteringParams,
    last: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
    velocity_known: np.ndarray | None = None,
    models: tuple[np.ndarray, np.ndarray] | None = None,
    alt: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Steps 1-3 of clustering.py: candidate (plot, track) pairs, each plot aligned to
    t_ref with the track's velocity, kept when inside the Mahalanobis gate (and the
    absolute cap) with compatible identities. Returns the kept pairs' plot and track
    indices, aligned positions and covariances, d², the smallest d² over the combined
    prediction and every model's (d² itself without ``models``; above ``gate_chi2`` only for
    a plot that joined by its address alone), and the assignment cost: that smallest d²,
    scaled by :data:`IDENTITY_COST_FACTOR` for a plot with its track's Mode S address.

    ``last``: the tracks' last measured positions, their covariances and times. With it
    (and ``params.identity_association``), a plot with a live track's address joins that
    track inside the sanity gate of :func:`identity_pairs` even outside the statistical
    gate, and is offered to no other track.

    ``velocity_known`` (N,) bool, with ``last``: a track whose velocity is not known yet
    (one update: its velocity is the wide prior, so its χ² gate reaches kilometres) takes
    a plot only where the aircraft could have flown from its one measured position
    (:func:`within_reach`): two clutter plots of two radars must not confirm a track by
    falling within each other's prior, nor make it fly at Mach 5. ``alt``: a second measured
    position per track (NaN time: none; with how long after its time it serves) that serves
    as well as the last one for that reach and for :func:`identity_pairs` (:func:`reach_either`).

    ``models``: the IMM's model-conditioned predicted positions (N, M, 2) and covariances
    (N, M, 2, 2) (imm.py, "Gating"). With them, the gate and the assignment cost take the
    smallest d² over the combined prediction and every model's, so a plot joins a track
    when any of its models expects it there: the second scan into a turn, far from the
    quiet model's prediction but where a turn model put it. The d² returned stays the
    combined prediction's: a plot beyond that gate is weighed and checked against the
    other radars as a plot beyond the gate (fusion.consensus_outliers), since a wild plot
    can fall where a turn model expects the aircraft. For a track whose models should not
    widen its gate, pass its combined prediction as every model's.
    """
    radius_cp = track_cp
    if models is not None:
        # the k-d tree's radius covers every model's gate: λmax(P_j) + |x_j − x|² as an
        # isotropic bound about the combined prediction (the exact gates follow)
        spread = np.sum((models[0] - track_xy[:, None, :]) ** 2, axis=2)
        lam = (lambda_max_2x2(models[1].reshape(-1, 2, 2)).reshape(spread.shape) + spread).max(axis=1)
        radius_cp = track_cp + (np.maximum(lam - lambda_max_2x2(track_cp), 0.0))[:, None, None] * np.eye(2)
    pair_plot, pair_track = candidate_pairs(
        plot_xy, plot_cov, dt_s, plot_ok, track_xy, track_v, radius_cp, track_cv, track_ok, params
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
    d2 = mahalanobis2_2x2(resid, track_cp[pair_track] + pair_cov)
    d2_gate = _gate_d2(d2, pair_xy, pair_cov, pair_track, models)
    gated = d2_gate <= params.gate_chi2
    if params.max_gate_m is not None:
        gated &= np.hypot(resid[:, 0], resid[:, 1]) <= params.max_gate_m
    gated &= identity_compatible(
        plot_ms[pair_plot],
        track_ms[pair_track],
        plot_3a[pair_plot],
        track_3a[pair_track],
        params.use_mode3a,
    )
    if last is not None and velocity_known is not None:
        young = ~np.asarray(velocity_known, bool)[pair_track]
        if young.any():
            pp, pt = pair_plot[young], pair_track[young]
            gated[young] &= reach_either(plot_xy[pp], plot_cov[pp], plot_t[pp], last, alt, pt, params.max_speed_mps)
    pair_plot = pair_plot[gated]
    pair_track = pair_track[gated]
    pair_xy = pair_xy[gated]
    pair_cov = pair_cov[gated]
    d2 = d2[gated]
    d2_gate = d2_gate[gated]
    if last is not None and params.identity_association:
        id_plot, id_track = identity_pairs(
            plot_ms, plot_ok, plot_xy, plot_cov, plot_t, track_ms, track_ok, *last, params.max_speed_mps, alt
        )
        # a plot of a live track's address is offered to that track only (identity_pairs
        # gives a plot at most one track: its address's)
        id_track_of_plot = np.full(plot_xy.shape[0], -1, np.intp)
        id_track_of_plot[id_plot] = id_track
        own_id = id_track_of_plot[pair_plot]
        keep = (own_id < 0) | (own_id == pair_track)
        gated_own = np.zeros(plot_xy.shape[0], bool)
        gated_own[pair_plot[own_id == pair_track]] = True
        new = ~gated_own[id_plot]
        add_plot, add_track = id_plot[new], id_track[new]
        add_xy, add_cov = align_to_reference(
            plot_xy[add_plot], plot_cov[add_plot], plot_t[add_plot], t_ref, track_v[add_track], track_cv[add_track]
        )
        add_d2 = mahalanobis2_2x2(add_xy - track_xy[add_track], track_cp[add_track] + add_cov)
        # outside every gate, or kept out by max_gate_m or Mode 3/A
        add_d2_gate = _gate_d2(add_d2, add_xy, add_cov, add_track, models)
        pair_plot = np.concatenate([pair_plot[keep], add_plot])
        pair_track = np.concatenate([pair_track[keep], add_track])
        pair_xy = np.concatenate([pair_xy[keep], add_xy])
        pair_cov = np.concatenate([pair_cov[keep], add_cov])
        d2 = np.concatenate([d2[keep], add_d2])
        d2_gate = np.concatenate([d2_gate[keep], add_d2_gate])
    own = (plot_ms[pair_plot] >= 0) & (plot_ms[pair_plot] == track_ms[pair_track])
    cost = np.where(own, d2_gate * IDENTITY_COST_FACTOR, d2_gate)
    return pair_plot, pair_track, pair_xy, pair_cov, d2, d2_gate, cost
