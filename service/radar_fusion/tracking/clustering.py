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

Algorithm (``cluster_plots``), all array operations except where noted; steps 1-5, the
track clusters, are in association.py, step 6, the new targets, here:

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

from dataclasses import dataclass
from functools import cached_property

import numpy as np
from pydantic import BaseModel, ConfigDict, Field
from scipy.optimize import linear_sum_assignment
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from .association import (
    align_to_reference,
    assign_per_radar,
    first_per_group,
    gated_pairs,
    identity_compatible,
    sorted_unique,
    transfer_track_clusters,
    unique_inverse,
)
from .initiation import unknown_velocity_var_m2ps2

__all__ = ["CHI2_2DOF_P999", "ClusterResult", "ClusteringParams", "cluster_plots"]

#: 99.9 % quantile of the chi-square distribution with 2 degrees of freedom,
#: -2·ln(0.001) (= scipy.stats.chi2.ppf(0.999, 2)).
CHI2_2DOF_P999 = 13.815510557964274
CHI2_2DOF_P95 = 5.991464547107982  # −2 ln(0.05), the 95 % quantile of χ² with 2 dof

# Cost of a dummy "too expensive" entry in the small dense assignment problems of the
# new-target components; far above any squared distance inside a gate (< (20 km)²).
_BIG_COST = 1.0e18


class ClusteringParams(BaseModel):
    """Parameters of ``cluster_plots``: the ``[clustering]`` section of the configuration.

    Each default is the one the daemon runs; its reason is in the field's description.
    """

    model_config = ConfigDict(frozen=True, extra="forbid", allow_inf_nan=False)

    gate_chi2: float = Field(
        CHI2_2DOF_P999,
        gt=0,
        description="Mahalanobis gate d² ≤ gate_chi2 for a plot to join a track's cluster. Default 13.8155, the "
        "chi-square 99.9 % quantile for 2 dof: a correct plot falls outside the gate once in a thousand, which "
        "then costs at most one false new-target cluster.",
    )
    max_gate_m: float | None = Field(
        9_260.0,
        gt=0,
        description="Absolute cap on |aligned plot − predicted track position|, m, or none. Default 9,260 m (5 NM, "
        "the en-route separation minimum): a coasting track's covariance may grow to tens of km, and a gate wider "
        "than the separation minimum would capture the plots of a properly separated neighbour. It also bounds the "
        "k-d tree query radius.",
    )
    new_target_gate_m: float = Field(
        3_000.0,
        ge=0,
        description="Maximum distance between two plots of one new-target cluster, before the motion allowance, m. "
        "Default 3,000 m: the difference of two plots with cross-range σ ≈ 470 m each (0.1° azimuth noise at "
        "~145 NM) has σ ≈ 665 m, so 3,000 m is 4.5σ, which leaves room for the radars' relative biases (not "
        "estimated) of a few hundred metres; yet well under the 3 NM (5.6 km) terminal separation, so separated "
        "aircraft are not merged.",
    )
    max_speed_mps: float = Field(
        350.0,
        gt=0,
        description="Maximum ground speed of a target without a track, m/s. Two plots of one new target taken at "
        "t_p and t_q may be up to max_speed_mps·|t_p − t_q| further apart, and its velocity prior is "
        "initiation.unknown_velocity_var_m2ps2(max_speed_mps). Default 350 m/s (680 kt), above the ground speed "
        "of civil jets with a strong tail wind.",
    )
    max_iterations: int = Field(
        20,
        ge=0,
        description="Cap on the batched transfer rounds (track clusters) and on the sequential transfer sweeps "
        "(each new-target conflict component). Each round strictly decreases E, so the cap only bounds the worst "
        "case; 20 is far above the 1-3 rounds seen in practice.",
    )
    identity_association: bool = Field(
        True,
        description="A plot with the Mode S address of a live track joins that track, also outside the χ² gate, "
        "while it lies within what the aircraft could have flown at max_speed_mps since the track's last update "
        "(issue 15: after a turn the prediction runs straight on, and the plots of the turning aircraft started a "
        "second track with the same address). The address is the aircraft's own; ARTAS associates by it too.",
    )
    use_mode3a: bool = Field(
        True,
        description="Mode 3/A as a soft cue: a plot and a track (or two plots) without a Mode S address on both, "
        "whose codes are both known and differ, are not clustered together, unless either code is an emergency or "
        "conspicuity code (association.NON_IDENTITY_MODE3A). Set false to ignore Mode 3/A altogether.",
    )
    drop_contradicting_pairs: bool = Field(
        True,
        description="A cluster without a velocity (a new target, a track of one update) of exactly two plots "
        "with one Mode S address that contradict each other beyond gate_chi2 holds a wild plot, and two cannot "
        "tell which (fusion.contradicting_pairs): both are left out this period and the next period's plots start "
        "or continue the track. False fuses them: the track starts half the wild error off, and its two-point "
        "velocity with it (issue 15 item 7; 3 % wild plots, 1,000x10 120 s, seeds 0-2: position RMS against "
        "the clean twin +11.5/+7.7/+9.5 % -> +7.5/+3.7/+5.4 %)",
    )
    split_contradicting_factor: float = Field(
        4.0,
        ge=0.0,
        description="A cluster without a velocity (a new target, a track of one update) of exactly two plots "
        "without a Mode S address that contradict each other beyond split_contradicting_factor × gate_chi2 "
        "(fusion.contradicting_pairs) is split: each plot is an update of one radar, the track (if any) keeping "
        "the one nearer its prediction and the other starting a tentative track. Codes are reused, so the pair "
        "may be two aircraft, or one and a wild plot; fused, two radars confirm a track half the wild error off "
        "at once (issue 15 item 7). Default 4 (d beyond twice the gate's radius): a split of two good plots "
        "makes a second track of one aircraft, and in the clean twins of 1,000x10 seeds 0-2 one good pair lay "
        "at d² 14 (876 m, radar biases not yet registered) while every wild pair lay beyond 200. 0 = off.",
    )
    far_hold: bool = Field(
        True,
        description="A track's cluster whose every plot joined by its Mode S address alone, d² beyond "
        "far_gate_factor × gate_chi2 of every model, is held for one scan instead of fused (the track coasts): "
        "if the next scan's plots are within the gate, it was a wild plot and is dropped; if they are far too "
        "and agree with it, the track was wrong (a wrong two-point velocity, a manoeuvre no model foresaw) and "
        "is initiated again from the two, keeping its id (issue 15 item 7: one wild plot joining by its "
        "address had made a track fly at 700-1,000 m/s)",
    )
    far_gate_factor: float = Field(
        1.0,
        ge=1.0,
        description="far means d² > far_gate_factor × gate_chi2 against the combined prediction and every model's. "
        "Default 1: any plot that joined by its address alone, outside every gate (0.1 % of an aircraft's plots "
        "at the 99.9 % gate). The edge-of-gate weighting it replaced bounds a plot's pull relative to its own "
        "noise, not to the track's: a coasted track (wide covariance) took a plot 5.5 km off almost whole "
        "(4,000x10, 3 % wild plots: settled velocity +27 % against the clean run; held beyond 4x the gate +14 %, "
        "beyond 1x +6 %)",
    )
    suspect_chi2: float = Field(
        CHI2_2DOF_P95,
        gt=0,
        description="a plot of a track's cluster beyond this d² of the combined prediction is checked against the "
        "cluster's plots within it, and dropped when they contradict it beyond gate_chi2 "
        "(fusion.consensus_outliers). Default 5.99, the 95 % quantile: a wild plot of a far radar 870 m off, at "
        "d² 13.4, just inside the 99.9 % gate, beside another radar's plot at d² 0.6, was fused and flipped a "
        "straight track to its manoeuvre model (issue 15 item 7). Two good plots contradict each other beyond "
        "the gate once in a thousand pairs. Set gate_chi2 to check only plots beyond the gate",
    )
    far_accel_mps2: float = Field(
        10.0,
        ge=0,
        description="a plot of a track with a velocity is far, whatever a model's gate says, when no manoeuvre of "
        "at most this acceleration since the track's update (plus sqrt(gate_chi2) σ of the innovation) reaches it "
        "(engine._beyond_any_manoeuvre). Default 10 m/s², the live gate's max_accel_mps2: above a rate-one turn "
        "at 150 m/s (8 m/s²). 0: off (the models' gates alone)",
    )
    too_fast_young_updates: int = Field(
        4,
        ge=0,
        description="with far_hold: a cluster that would make a track of fewer updates than this fly faster than "
        "max_speed_mps is held like a far one (engine._too_fast), and so is one whose two-point velocity with a "
        "track's first measurement would. Default 4: the velocity of the first three updates rests on a few "
        "measurements and their gates are wide; 0 leaves the Kalman updates alone (the two-point check stays). "
        "1,000x10 with 3 % wild plots, the whole run: velocity +17 % -> +8 % against the clean run, GOSPA +18 % "
        "-> +12 %; the clean run itself 12.0 -> 11.7 m/s",
    )
    far_hold_scans: float = Field(
        2.5,
        gt=0,
        description="a held measurement is kept this many of the track's revisit times (one missed scan)",
    )
    code_alternatives: bool = Field(
        True,
        description="Two one-plot tracks without a Mode S address that carry one identity code (Mode 3/A, not "
        "an emergency or conspicuity code) and are further apart than an aircraft flies between them: one plot is "
        "wild. The aircraft's next plot joins one of them (the association's choice); the other one's plot is kept "
        "beside it, and where the plot after that misses the two-point track but lies on the straight line from "
        "the kept plot through the track's, the track starts again from the kept plot (engine._code_alternatives). "
        "An SSR-only aircraft seen by one 12 s radar whose second plot was wild was confirmed 36 s late (issue 15 "
        "item 7, 1,000x10 seed 2, 3 % wild plots)",
    )
    track_anchor_weight: float = Field(
        1.0,
        gt=0,
        description="Weight of a track's predicted point as a member of its own cluster (Shu §2.1: the "
        "representative 自成一类, forms a class by itself). It keeps the centroid of a track's cluster tied to the "
        "prediction; it must be > 0, otherwise a track with no plot would be an empty cluster with ρ_j = 0 that "
        "attracts any plot (the degenerate 'more clusters, lower E' behaviour of DESIGN.md §1).",
    )


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
    plot_d2:            (M,) squared Mahalanobis distance of each plot in a track cluster to
                        that track's prediction (NaN for other plots); above ``gate_chi2``
                        only for a plot that joined by its Mode S address.
    plot_d2_gate:       (M,) the smallest d² of that plot over the track's combined
                        prediction and each IMM model's (the gate's d²; plot_d2 without
                        the models): above ``gate_chi2`` only for a plot that joined by its
                        Mode S address where no model expected it.
    seed_labels, seed_cluster_track, sse_seed_m2:
                        the same for the initial (seed) assignment, before transfers.
    sse_m2 and the seed's three are computed on first access, from ``seed`` and the arrays
    above as they are then.
    """

    labels: np.ndarray
    cluster_track: np.ndarray
    aligned_xy_m: np.ndarray
    aligned_cov_m2: np.ndarray
    n_iterations: int
    redundant: np.ndarray
    plot_d2: np.ndarray
    plot_d2_gate: np.ndarray
    seed: _SeedRecord  # what the diagnostics below are computed from, on first access

    @property
    def n_clusters(self) -> int:
        return int(self.cluster_track.shape[0])

    # The diagnostics (tests, tools/bench_clustering.py): the engine reads none of them, so
    # they are computed on first access (1-2 ms a period at 4,000 tracks otherwise).
    @cached_property
    def sse_m2(self) -> float:
        return _sse_m2(self.labels, self.cluster_track, self.aligned_xy_m, self.seed.track_xy, self.seed.anchor_weight)

    @cached_property
    def _seed_clusters(self) -> tuple[np.ndarray, np.ndarray]:
        sd = self.seed
        return _labels_from_assignment(sd.assign, sd.pair_track, sd.new_idx, sd.new_labels, self.labels.shape[0])

    @property
    def seed_labels(self) -> np.ndarray:
        return self._seed_clusters[0]

    @property
    def seed_cluster_track(self) -> np.ndarray:
        return self._seed_clusters[1]

    @cached_property
    def sse_seed_m2(self) -> float:
        sd = self.seed
        seed_xy = self.aligned_xy_m.copy()
        seed_used = np.flatnonzero(sd.assign >= 0)
        seed_xy[seed_used] = sd.pair_xy[sd.assign[seed_used]]
        return _sse_m2(self.seed_labels, self.seed_cluster_track, seed_xy, sd.track_xy, sd.anchor_weight)


@dataclass(frozen=True)
class _SeedRecord:
    """The seed assignment (step 4, before transfers) and what E of eq. 2 needs, kept
    for :class:`ClusterResult`'s diagnostics."""

    assign: np.ndarray  # (M,) pair index of each plot in the seed, −1 none
    pair_track: np.ndarray
    pair_xy: np.ndarray
    new_idx: np.ndarray
    new_labels: np.ndarray  # the new-target seed labels
    track_xy: np.ndarray
    anchor_weight: float


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
        of_radar = np.flatnonzero(radar == r)
        onehot = np.zeros((n, n_clusters))
        placed = labels >= 0
        onehot[np.flatnonzero(placed), labels[placed]] = 1.0
        size = onehot.sum(axis=0)
        centroid = (onehot.T @ xy) / size[:, None]
        incompatible = (~compat[of_radar]).astype(float) @ onehot > 0
        diff = xy[of_radar, None, :] - centroid[None, :, :]
        cost = np.einsum("pkc,pkc->pk", diff, diff)
        cost[incompatible] = _BIG_COST
        rows, cols = linear_sum_assignment(cost)
        ok = ~incompatible[rows, cols]
        labels[of_radar[rows[ok]]] = cols[ok]
        rest = of_radar[labels[of_radar] < 0]
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
    ok &= identity_compatible(mode_s[a], mode_s[b], mode3a[a], mode3a[b], params.use_mode3a)
    a = a[ok]
    b = b[ok]
    graph = coo_matrix((np.ones(a.size), (a, b)), shape=(n, n))
    n_comp, comp = connected_components(graph, directed=False)
    size = np.bincount(comp, minlength=n_comp)
    degree = np.bincount(a, minlength=n) + np.bincount(b, minlength=n)
    simple = np.ones(n_comp, dtype=bool)
    simple[comp[degree != size[comp] - 1]] = False  # not a clique
    distinct = sorted_unique(comp.astype(np.int64) * n_radars + radar)
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
            s_lab, f_lab, k_sweeps = _kmeans_component(xy[nodes], radar[nodes], compat, params.max_iterations)
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
    cluster_tracks, inverse = unique_inverse(tracks_of_used)
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
    params: ClusteringParams | None = None,
    *,
    track_last_xy_m: np.ndarray | None = None,
    track_last_cov_m2: np.ndarray | None = None,
    track_last_t_s: np.ndarray | None = None,
    track_velocity_known: np.ndarray | None = None,
    track_models: tuple[np.ndarray, np.ndarray] | None = None,
    track_alt: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None = None,
) -> ClusterResult:
    """Align one period's plots to ``t_ref_s`` and cluster them (see the module docstring).

    Plots: positions (M, 2) in m, covariances (M, 2, 2) in m², detection times (M,) in s,
    radar index (M,), Mode S address (M,) int64 and Mode 3/A code (M,) int, −1 = none.
    Tracks, predicted to t_ref_s: position (N, 2), velocity (N, 2) in m/s, position and
    velocity covariances (N, 2, 2), Mode S / Mode 3/A identity (N,), −1 = unknown.
    Plots or tracks with non-finite values are ignored (plots get label −1).
    ``track_last_*``: each track's last measured position (N, 2), its covariance (N, 2, 2) and
    time (N,); given, a plot with a track's Mode S address joins it inside a sanity gate
    from the maximum speed (association.identity_pairs), not only inside the χ² gate.
    ``track_velocity_known`` (N,) bool, with ``track_last_*``: a track without a velocity yet
    takes only plots inside that sanity gate too (association.gated_pairs).
    ``track_models``: the IMM's model-conditioned positions (N, M, 2) and covariances
    (N, M, 2, 2); a plot is in a track's gate when it is in any model's
    (association.gated_pairs).
    ``track_alt``: with ``track_last_*``, a second measured position per track, its
    covariance, time (NaN: none) and how long after that time it serves, that the sanity
    gate accepts as well (association.reach_either).
    """
    params = ClusteringParams() if params is None else params
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
    last = None
    if track_last_xy_m is not None and track_last_cov_m2 is not None and track_last_t_s is not None:
        last = (
            np.asarray(track_last_xy_m, dtype=float).reshape(n_tracks, 2),
            np.asarray(track_last_cov_m2, dtype=float).reshape(n_tracks, 2, 2),
            np.asarray(track_last_t_s, dtype=float).reshape(n_tracks),
        )

    _, radar = unique_inverse(plot_radar_raw)
    radar = radar.reshape(n_plots).astype(np.intp)
    n_radars = int(radar.max()) + 1 if n_plots else 1
    dt_s = t_ref - plot_t
    plot_ok = np.isfinite(plot_xy).all(axis=1) & np.isfinite(plot_cov).all(axis=(1, 2)) & np.isfinite(dt_s)
    track_ok = (
        np.isfinite(track_xy).all(axis=1)
        & np.isfinite(track_v).all(axis=1)
        & np.isfinite(track_cp).all(axis=(1, 2))
        & np.isfinite(track_cv).all(axis=(1, 2))
    )

    # 1-3: candidate pairs, time alignment with the track's velocity, gating.
    pair_plot, pair_track, pair_xy, pair_cov, d2, d2_gate, cost = gated_pairs(
        plot_xy,
        plot_cov,
        plot_t,
        dt_s,
        plot_ok,
        plot_ms,
        plot_3a,
        track_xy,
        track_v,
        track_cp,
        track_cv,
        track_ok,
        track_ms,
        track_3a,
        t_ref,
        params,
        last,
        None if track_velocity_known is None else np.asarray(track_velocity_known, bool).reshape(n_tracks),
        track_models,
        track_alt,
    )
    pair_radar = radar[pair_plot]

    # 4: seed, nearest representative with one plot per radar per cluster.
    best = first_per_group(pair_plot, cost)  # each gated plot's nearest track (in cost)
    seed_assign = assign_per_radar(
        pair_plot, pair_track * n_radars + pair_radar, cost, n_plots, params.gate_chi2, best=best
    )
    # 5: transfers among the track clusters (eq. 3 corrected).
    assign, track_rounds = transfer_track_clusters(
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

    # Aligned positions: zero velocity (variance unknown_velocity_var_m2ps2 per axis) by
    # default; the assigned track's velocity for track clusters; the best gated track's
    # for the redundant plots.
    v_var = unknown_velocity_var_m2ps2(params.max_speed_mps)
    aligned_xy, aligned_cov = align_to_reference(plot_xy, plot_cov, plot_t, t_ref, np.zeros(2), v_var * np.eye(2))
    if pair_plot.size:
        aligned_xy[pair_plot[best]] = pair_xy[best]
        aligned_cov[pair_plot[best]] = pair_cov[best]
    used = np.flatnonzero(assign >= 0)
    aligned_xy[used] = pair_xy[assign[used]]
    aligned_cov[used] = pair_cov[assign[used]]
    redundant = in_gate & (assign < 0)
    plot_d2 = np.full(n_plots, np.nan)
    plot_d2[used] = d2[assign[used]]
    plot_d2_gate = np.full(n_plots, np.nan)
    plot_d2_gate[used] = d2_gate[assign[used]]

    labels, cluster_track = _labels_from_assignment(assign, pair_track, new_idx, new_labels, n_plots)
    return ClusterResult(
        labels=labels,
        cluster_track=cluster_track,
        aligned_xy_m=aligned_xy,
        aligned_cov_m2=aligned_cov,
        n_iterations=max(track_rounds, new_sweeps),
        redundant=redundant,
        plot_d2=plot_d2,
        plot_d2_gate=plot_d2_gate,
        seed=_SeedRecord(seed_assign, pair_track, pair_xy, new_idx, new_seed, track_xy, params.track_anchor_weight),
    )
