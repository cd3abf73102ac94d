"""Wild-plot (outlier) rejection after Hu 2013 (the paper's batch method), with the K-MODF baseline.

Hu Kui, "Radar data outlier elimination method based on soft-weighted k-mean distance
outlier factor", Ordnance Industry Automation 2013(4), doi:10.7690/bgzd.2013.04.019.
Equation numbers below are the paper's.

Batch pipeline (one pipeline, two weightings):

1. Edge-weight factor W(i) over the v detection windows that contain sample i:
   * ``"soft"`` (Hu, eq. 1): W(i) = |sum_j (s_i - E_j) / (sigma_j + eps*delta(sigma_j))|,
   * ``"kmodf"`` (Zhan et al.'s K-MODF as Hu describes it): the same sum of hard weights,
     +1 when s_i equals window j's maximum, -1 when it equals its minimum, else 0.
   Windows: the series has n - v + 1 windows of width v, window j = samples [j, j+v).
   Sample i belongs to windows j = i-v+1 .. i; near the two ends of the series, where
   fewer than v windows exist, the first (last) window is counted repeatedly so every
   sample sums exactly v terms. E_j is the window mean, sigma_j its population standard
   deviation (divisor v).
2. Edge points: the samples of large W. Sample i is an edge point when
   W(i) >= quantile(W, edge_quantile) and W(i)/v >= edge_level (both configurable).
3. Segmentation: each maximal run of consecutive edge points opens a sub-sequence, which
   continues over the non-edge samples that follow it up to the next edge point. A
   sub-sequence is therefore "[edge run][plain run]"; only the first one may lack its
   edge run. This keeps a wild run and its return to the trajectory in one pattern
   (its height, eq. 2, is then the size of the jump).
4. Features of each sub-sequence: height (eq. 2), length (eq. 3), mean (eq. 4),
   standard deviation (eq. 5; 0 for a sub-sequence of one sample, where eq. 5 is 0/0).
5. Min-max normalisation of each feature over all sub-sequences (eq. 6).
6. k-mean distance (mean distance to the k nearest other points, the paper's definition
   after its k-distance conditions 1 and 2) in the 4-D feature space C and in each 1-D
   subspace C1..C4, each vector normalised with eq. 6.
7. Outlier factor OF(p) = dist(p) + max_i dist_i(p) (eq. 7), in [0, 2].
8. Decision rule (the paper stops at "larger OF, more likely wild"): a sub-sequence is
   wild when OF > median(OF) + of_sigma * 1.4826 * MAD(OF) (or OF > of_threshold if
   given), its edge run has at most max_wild_length samples, and the edge run has
   trajectory samples on both sides (it neither opens nor closes the series: at the
   ends of a ramp the first and last samples are extremes of every window, and a
   departure cannot be told from a trend there). The wild samples are
   the samples of the edge run of a wild sub-sequence; its plain run, the trajectory
   after the return, is kept.

Baseline: :func:`innovation_gate_3sigma`, a constant-velocity Kalman predictor on the
series that flags samples whose innovation exceeds 3 sigma and does not update on them.

The live variant the engine runs, causal with zero delay, is
:class:`radar_fusion.tracking.live_gate.LiveOutlierGate`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view
from numpy.typing import NDArray

__all__ = [
    "OutlierAnalysis",
    "OutlierParams",
    "analyse",
    "decide_wild",
    "detect_outliers",
    "edge_points",
    "hard_edge_weight",
    "innovation_gate_3sigma",
    "k_distance",
    "k_mean_distance",
    "minmax_normalise",
    "outlier_factor",
    "segment_at_edges",
    "soft_edge_weight",
    "subsequence_features",
    "window_start_indices",
]

METHODS = ("soft", "kmodf")


@dataclass(frozen=True)
class OutlierParams:
    """Parameters of the batch method (soft-weighted or K-MODF).

    window: v of eq. 1, width of each detection window (samples).
    edge_quantile: samples with W at or above this quantile of W are edge points.
    edge_level: and W(i)/v must also reach this level (mean weight per window).
    k: neighbours of the k-distance / k-mean distance.
    of_sigma: c of the decision rule OF > median + c * 1.4826 * MAD.
    of_threshold: absolute OF threshold; replaces the robust rule when not None.
    max_wild_length: longest edge run (samples) a wild sub-sequence may have.
    epsilon: the small constant eps of eq. 1 and eq. 6.
    """

    window: int = 12
    edge_quantile: float = 0.9
    edge_level: float = 0.0
    k: int = 5
    of_sigma: float = 6.0
    of_threshold: float | None = None
    max_wild_length: int = 8
    epsilon: float = 1e-9


@dataclass
class OutlierAnalysis:
    """Every intermediate result of :func:`analyse`, for tests and plots.

    weight: W(i) per sample (eq. 1 or the K-MODF hard form).
    edge: edge-point mask per sample.
    starts, stops: sub-sequence p covers samples [starts[p], stops[p]).
    edge_stops: the edge run of sub-sequence p is [starts[p], edge_stops[p]).
    features: (m, 4) raw height, length, mean, std (eq. 2-5).
    features_normalised: (m, 4) after eq. 6.
    distances: (m, 5) normalised k-mean distances: [dist, dist_1..dist_4].
    outlier_factor: (m,) OF (eq. 7).
    threshold: the OF threshold the decision used.
    wild_subsequence: (m,) decision per sub-sequence.
    wild: (n,) wild-sample mask.
    """

    weight: np.ndarray
    edge: np.ndarray
    starts: np.ndarray
    stops: np.ndarray
    edge_stops: np.ndarray
    features: np.ndarray
    features_normalised: np.ndarray
    distances: np.ndarray
    outlier_factor: np.ndarray
    threshold: float
    wild_subsequence: np.ndarray
    wild: np.ndarray


def window_start_indices(n: int, v: int) -> NDArray[np.intp]:
    """(n, v) start index of each of the v windows summed for each sample (eq. 1).

    Window j covers samples [j, j + v). For sample i the windows are j = i-v+1 .. i,
    clipped to the existing windows 0 .. n-v, so near the ends the first or last
    window is repeated and each sample still sums v terms, all of which contain it.
    """
    if v < 2 or v > n:
        raise ValueError(f"window v={v} must satisfy 2 <= v <= n={n}")
    i = np.arange(n)[:, None]
    m = np.arange(v)[None, :]
    starts: NDArray[np.intp] = np.clip(i - v + 1 + m, 0, n - v)
    return starts


def soft_edge_weight(s: np.ndarray, v: int, epsilon: float = 1e-9) -> NDArray[np.float64]:
    """Soft edge-weight factor W(i) = |sum_j w_j(i)|, w_j(i) = (s_i-E_j)/(sigma_j+eps*delta) (eq. 1).

    E_j, sigma_j: mean and population standard deviation of window j; delta(sigma_j) = 1
    when sigma_j = 0 (then s_i = E_j and w_j(i) = 0), else 0.
    """
    s = np.asarray(s, dtype=float)
    win = sliding_window_view(s, v)
    mean_j = win.mean(axis=1)
    std_j = win.std(axis=1)
    denom_j = std_j + epsilon * (std_j == 0.0)
    j = window_start_indices(s.size, v)
    w = (s[:, None] - mean_j[j]) / denom_j[j]
    total: NDArray[np.float64] = w.sum(axis=1)
    return np.abs(total)


def hard_edge_weight(s: np.ndarray, v: int) -> NDArray[np.float64]:
    """K-MODF hard edge-weight factor W(i) = |sum_j w_j(i)| over the same windows as eq. 1.

    w_j(i) = +1 if s_i is the maximum of window j, -1 if it is the minimum, 0 otherwise
    (and 0 in a constant window, where the maximum equals the minimum).
    """
    s = np.asarray(s, dtype=float)
    win = sliding_window_view(s, v)
    max_j = win.max(axis=1)
    min_j = win.min(axis=1)
    j = window_start_indices(s.size, v)
    si = s[:, None]
    varies = max_j[j] > min_j[j]
    w = np.where(varies & (si == max_j[j]), 1, 0) - np.where(varies & (si == min_j[j]), 1, 0)
    total: NDArray[np.int64] = w.sum(axis=1)
    return np.abs(total).astype(float)


def edge_points(weight: np.ndarray, v: int, edge_quantile: float, edge_level: float) -> NDArray[np.bool_]:
    """Edge points, "the points of large W" (text after eq. 1).

    Rule: W(i) >= quantile(W, edge_quantile) and W(i) / v >= edge_level, and W(i) > 0.
    """
    weight = np.asarray(weight, dtype=float)
    q: float = np.quantile(weight, edge_quantile)  # a numpy.float64, a subclass of float
    return (weight >= q) & (weight / v >= edge_level) & (weight > 0.0)


def segment_at_edges(edge: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Split the series into sub-sequences "[edge run][plain run]".

    Returns (starts, stops, edge_stops): sub-sequence p covers [starts[p], stops[p]) and
    its leading run of edge points covers [starts[p], edge_stops[p]) (empty for a first
    sub-sequence that begins with plain samples).
    """
    edge = np.asarray(edge, dtype=bool)
    n = edge.size
    prev = np.concatenate(([False], edge[:-1]))
    run_starts = np.flatnonzero(edge & ~prev)
    starts = run_starts if (run_starts.size and run_starts[0] == 0) else np.concatenate(([0], run_starts))
    starts = starts.astype(np.int64)
    stops = np.concatenate((starts[1:], [n])).astype(np.int64)
    # Length of the edge run at the head of each sub-sequence.
    nxt = np.concatenate((edge[1:], [False]))
    run_ends = np.flatnonzero(edge & ~nxt) + 1  # exclusive ends of edge runs
    edge_stops = starts.copy()
    has_run = edge[starts]
    # The k-th edge run belongs to the k-th sub-sequence that starts with an edge point.
    edge_stops[has_run] = run_ends
    return starts, stops, edge_stops


def subsequence_features(s: np.ndarray, starts: np.ndarray, stops: np.ndarray) -> np.ndarray:
    """(m, 4) height, length, mean, standard deviation of each sub-sequence (eq. 2-5).

    h = s_last - s_first (eq. 2); l = number of samples (eq. 3); mean (eq. 4); sample
    standard deviation with divisor l - 1 (eq. 5), defined as 0 when l = 1.
    """
    s = np.asarray(s, dtype=float)
    starts = np.asarray(starts, dtype=np.int64)
    stops = np.asarray(stops, dtype=np.int64)
    length = (stops - starts).astype(float)
    height = s[stops - 1] - s[starts]
    csum = np.concatenate(([0.0], np.cumsum(s)))
    mean = (csum[stops] - csum[starts]) / length
    # Sum of squared deviations per sub-sequence without a Python loop.
    seg_id = np.repeat(np.arange(starts.size), stops - starts)
    dev2 = (s[starts[0] : stops[-1]] - mean[seg_id]) ** 2
    ss = np.bincount(seg_id, weights=dev2, minlength=starts.size)
    std = np.where(length > 1, np.sqrt(ss / np.maximum(length - 1.0, 1.0)), 0.0)
    return np.column_stack((height, length, mean, std))


def minmax_normalise(c: np.ndarray, epsilon: float = 1e-9) -> NDArray[np.float64]:
    """d(c) = (c - min c) / (max c - min c + eps * delta(c)), per column (eq. 6)."""
    c = np.asarray(c, dtype=float)
    lo: NDArray[np.float64] = c.min(axis=0)
    span = c.max(axis=0) - lo
    normalised: NDArray[np.float64] = (c - lo) / (span + epsilon * (span == 0.0))
    return normalised


def _pairwise_distances(x: np.ndarray) -> NDArray[np.float64]:
    x = np.asarray(x, dtype=float)
    if x.ndim == 1:
        x = x[:, None]
    diff = x[:, None, :] - x[None, :, :]
    squared: NDArray[np.float64] = (diff * diff).sum(axis=2)
    return np.sqrt(squared)


def k_distance(x: np.ndarray, k: int) -> np.ndarray:
    """k-distance of each point (conditions 1 and 2 after eq. 6): its k-th smallest
    distance to the other points (Euclidean; x is (m, d) or (m,))."""
    d = _pairwise_distances(x)
    m = d.shape[0]
    if not 1 <= k <= m - 1:
        raise ValueError(f"k={k} needs 1 <= k <= m-1 with m={m} points")
    np.fill_diagonal(d, np.inf)
    return np.partition(d, k - 1, axis=1)[:, k - 1]


def k_mean_distance(x: np.ndarray, k: int) -> NDArray[np.float64]:
    """k-mean distance (1/k) * sum_{j=1..k} dist_j(p): mean of the k smallest distances
    from each point to the other points."""
    d = _pairwise_distances(x)
    m = d.shape[0]
    if not 1 <= k <= m - 1:
        raise ValueError(f"k={k} needs 1 <= k <= m-1 with m={m} points")
    np.fill_diagonal(d, np.inf)
    kmd: NDArray[np.float64] = np.partition(d, k - 1, axis=1)[:, :k].mean(axis=1)
    return kmd


def outlier_factor(features_normalised: np.ndarray, k: int, epsilon: float = 1e-9) -> tuple[np.ndarray, np.ndarray]:
    """OF(p) = dist(p) + max_i dist_i(p) (eq. 7).

    dist: k-mean distance in the 4-D space C, dist_i: in the 1-D subspace C_i, each
    vector min-max normalised (eq. 6). Returns (OF, distances (m, 5)). k is reduced to
    m - 1 when there are fewer than k + 1 sub-sequences.
    """
    f = np.asarray(features_normalised, dtype=float)
    m = f.shape[0]
    if m < 2:
        return np.zeros(m), np.zeros((m, 5))
    kk = min(k, m - 1)
    cols = [k_mean_distance(f, kk)] + [k_mean_distance(f[:, i], kk) for i in range(f.shape[1])]
    dist = minmax_normalise(np.column_stack(cols), epsilon)
    of = dist[:, 0] + dist[:, 1:].max(axis=1)
    return of, dist


def decide_wild(
    of: np.ndarray, edge_run_length: np.ndarray, params: OutlierParams, interior: np.ndarray | None = None
) -> tuple[np.ndarray, float]:
    """Decision rule: wild when OF > threshold and 1 <= edge run length <= max_wild_length
    (and, when `interior` is given, the edge run has trajectory samples on both sides).

    threshold = params.of_threshold if set, else median(OF) + of_sigma * 1.4826 * MAD(OF).
    Returns (wild mask per sub-sequence, threshold).
    """
    of = np.asarray(of, dtype=float)
    if params.of_threshold is not None:
        thr = float(params.of_threshold)
    elif of.size:
        med = float(np.median(of))
        mad = float(np.median(np.abs(of - med)))
        thr = med + params.of_sigma * 1.4826 * mad
    else:
        thr = np.inf
    run = np.asarray(edge_run_length)
    wild = (of > thr) & (run >= 1) & (run <= params.max_wild_length)
    if interior is not None:
        wild &= np.asarray(interior, dtype=bool)
    return wild, thr


def analyse(
    s: np.ndarray, t: np.ndarray | None = None, method: str = "soft", params: OutlierParams | None = None
) -> OutlierAnalysis:
    """Run the whole batch pipeline on series s and return every intermediate result.

    s: the measurement series s_1..s_n (e.g. azimuth in degrees) in time order.
    t: its time codes; only used to sort the samples when given (the method works on
    the sample order, the paper assumes a constant interval).
    method: "soft" (Hu 2013, eq. 1) or "kmodf" (hard weights).
    """
    if method not in METHODS:
        raise ValueError(f"method must be one of {METHODS}, got {method!r}")
    p = params or OutlierParams()
    s = np.asarray(s, dtype=float)
    order = None
    if t is not None:
        order = np.argsort(np.asarray(t, dtype=float), kind="stable")
        s = s[order]
    if method == "soft":
        weight = soft_edge_weight(s, p.window, p.epsilon)
    else:
        weight = hard_edge_weight(s, p.window)
    edge = edge_points(weight, p.window, p.edge_quantile, p.edge_level)
    starts, stops, edge_stops = segment_at_edges(edge)
    feats = subsequence_features(s, starts, stops)
    feats_n = minmax_normalise(feats, p.epsilon)
    of, dist = outlier_factor(feats_n, p.k, p.epsilon)
    # A departure needs a trajectory before and after it: an edge run that opens the
    # series (the end of a ramp is an extreme of every window) or closes it is kept.
    interior = (starts > 0) & (stops > edge_stops)
    wild_sub, thr = decide_wild(of, edge_stops - starts, p, interior)
    wild = np.zeros(s.size, dtype=bool)
    for a, b in zip(starts[wild_sub], edge_stops[wild_sub]):
        wild[a:b] = True
    if order is not None:
        unsorted = np.empty_like(wild)
        unsorted[order] = wild
        wild = unsorted
        w_un = np.empty_like(weight)
        w_un[order] = weight
        e_un = np.empty_like(edge)
        e_un[order] = edge
        weight, edge = w_un, e_un
    return OutlierAnalysis(
        weight, edge, starts, stops, edge_stops, feats, feats_n, dist, of, float(thr), wild_sub, wild
    )


def detect_outliers(
    s: np.ndarray, t: np.ndarray | None = None, method: str = "soft", params: OutlierParams | None = None
) -> np.ndarray:
    """Boolean mask of the wild samples of s (True = remove); see :func:`analyse`."""
    return analyse(s, t, method, params).wild


def innovation_gate_3sigma(
    s: np.ndarray,
    t: np.ndarray | None = None,
    sigma: float | None = None,
    accel_sigma: float | None = None,
    gate_sigma: float = 3.0,
    max_misses: int = 8,
) -> np.ndarray:
    """Baseline: constant-velocity Kalman predictor, flag |innovation| > gate_sigma * sqrt(S).

    State [s, ds/dt]; white-acceleration process noise of spectral density accel_sigma^2.
    A flagged sample is not used for the update; after max_misses consecutive flags the
    filter restarts on the current sample (so a genuine jump is eventually followed).
    sigma: measurement noise; estimated from the series when None as
    1.4826 * MAD(second differences) / sqrt(6). accel_sigma: process-noise acceleration
    density; when None, 0.1 * sigma / dt^2 (a slowly varying rate).
    Returns the boolean mask of flagged samples.
    """
    s = np.asarray(s, dtype=float)
    n = s.size
    if t is None:
        t = np.arange(n, dtype=float)
    t = np.asarray(t, dtype=float)
    dt_med = float(np.median(np.diff(t))) if n > 1 else 1.0
    if sigma is None:
        d2 = np.diff(s, 2)
        sigma = 1.4826 * float(np.median(np.abs(d2 - np.median(d2)))) / np.sqrt(6.0)
        sigma = max(sigma, 1e-12)
    if accel_sigma is None:
        accel_sigma = 0.1 * sigma / dt_med**2
    r = sigma**2
    q = accel_sigma**2
    flagged = np.zeros(n, dtype=bool)
    if n == 0:
        return flagged
    x = np.array([s[0], 0.0])
    p = np.diag([r, (10.0 * sigma / dt_med) ** 2 + 1.0])
    t_prev = t[0]
    misses = 0
    for i in range(1, n):
        dt = t[i] - t_prev
        f = np.array([[1.0, dt], [0.0, 1.0]])
        qm = q * np.array([[dt**3 / 3.0, dt**2 / 2.0], [dt**2 / 2.0, dt]])
        xp = f @ x
        pp = f @ p @ f.T + qm
        innov = s[i] - xp[0]
        s_var = pp[0, 0] + r
        if innov * innov > gate_sigma**2 * s_var:
            flagged[i] = True
            misses += 1
            if misses > max_misses:
                # Restart on the new level: the jump has persisted.
                x = np.array([s[i], 0.0])
                p = np.diag([r, (10.0 * sigma / dt_med) ** 2 + 1.0])
                t_prev = t[i]
                misses = 0
                flagged[i] = False
            else:
                x, p = xp, pp
                t_prev = t[i]
            continue
        misses = 0
        gain = pp[:, 0] / s_var
        x = xp + gain * innov
        p = pp - np.outer(gain, pp[0, :])
        t_prev = t[i]
    return flagged
