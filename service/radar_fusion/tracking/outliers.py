"""Wild-plot (outlier) rejection after Hu 2013, with the K-MODF baseline and a live gate.

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

Live variant: :class:`LiveOutlierGate`, causal with zero delay, per-key bounded windows.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

__all__ = [
    "OutlierParams",
    "OutlierAnalysis",
    "window_start_indices",
    "soft_edge_weight",
    "hard_edge_weight",
    "edge_points",
    "segment_at_edges",
    "subsequence_features",
    "minmax_normalise",
    "k_distance",
    "k_mean_distance",
    "outlier_factor",
    "decide_wild",
    "analyse",
    "detect_outliers",
    "innovation_gate_3sigma",
    "LiveOutlierGate",
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


def window_start_indices(n: int, v: int) -> np.ndarray:
    """(n, v) start index of each of the v windows summed for each sample (eq. 1).

    Window j covers samples [j, j + v). For sample i the windows are j = i-v+1 .. i,
    clipped to the existing windows 0 .. n-v, so near the ends the first or last
    window is repeated and each sample still sums v terms, all of which contain it.
    """
    if v < 2 or v > n:
        raise ValueError(f"window v={v} must satisfy 2 <= v <= n={n}")
    i = np.arange(n)[:, None]
    m = np.arange(v)[None, :]
    return np.clip(i - v + 1 + m, 0, n - v)


def soft_edge_weight(s: np.ndarray, v: int, epsilon: float = 1e-9) -> np.ndarray:
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
    return np.abs(w.sum(axis=1))


def hard_edge_weight(s: np.ndarray, v: int) -> np.ndarray:
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
    return np.abs(w.sum(axis=1)).astype(float)


def edge_points(weight: np.ndarray, v: int, edge_quantile: float, edge_level: float) -> np.ndarray:
    """Edge points, "the points of large W" (text after eq. 1).

    Rule: W(i) >= quantile(W, edge_quantile) and W(i) / v >= edge_level, and W(i) > 0.
    """
    weight = np.asarray(weight, dtype=float)
    q = np.quantile(weight, edge_quantile)
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
    dev2 = (s[starts[0]:stops[-1]] - mean[seg_id]) ** 2
    ss = np.bincount(seg_id, weights=dev2, minlength=starts.size)
    std = np.where(length > 1, np.sqrt(ss / np.maximum(length - 1.0, 1.0)), 0.0)
    return np.column_stack((height, length, mean, std))


def minmax_normalise(c: np.ndarray, epsilon: float = 1e-9) -> np.ndarray:
    """d(c) = (c - min c) / (max c - min c + eps * delta(c)), per column (eq. 6)."""
    c = np.asarray(c, dtype=float)
    lo = c.min(axis=0)
    span = c.max(axis=0) - lo
    return (c - lo) / (span + epsilon * (span == 0.0))


def _pairwise_distances(x: np.ndarray) -> np.ndarray:
    x = np.asarray(x, dtype=float)
    if x.ndim == 1:
        x = x[:, None]
    diff = x[:, None, :] - x[None, :, :]
    return np.sqrt((diff * diff).sum(axis=2))


def k_distance(x: np.ndarray, k: int) -> np.ndarray:
    """k-distance of each point (conditions 1 and 2 after eq. 6): its k-th smallest
    distance to the other points (Euclidean; x is (m, d) or (m,))."""
    d = _pairwise_distances(x)
    m = d.shape[0]
    if not 1 <= k <= m - 1:
        raise ValueError(f"k={k} needs 1 <= k <= m-1 with m={m} points")
    np.fill_diagonal(d, np.inf)
    return np.partition(d, k - 1, axis=1)[:, k - 1]


def k_mean_distance(x: np.ndarray, k: int) -> np.ndarray:
    """k-mean distance (1/k) * sum_{j=1..k} dist_j(p): mean of the k smallest distances
    from each point to the other points."""
    d = _pairwise_distances(x)
    m = d.shape[0]
    if not 1 <= k <= m - 1:
        raise ValueError(f"k={k} needs 1 <= k <= m-1 with m={m} points")
    np.fill_diagonal(d, np.inf)
    return np.partition(d, k - 1, axis=1)[:, :k].mean(axis=1)


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


def decide_wild(of: np.ndarray, edge_run_length: np.ndarray, params: OutlierParams,
                interior: np.ndarray | None = None) -> tuple[np.ndarray, float]:
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


def analyse(s: np.ndarray, t: np.ndarray | None = None, method: str = "soft",
            params: OutlierParams | None = None) -> OutlierAnalysis:
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
    return OutlierAnalysis(weight, edge, starts, stops, edge_stops, feats, feats_n, dist, of,
                           float(thr), wild_sub, wild)


def detect_outliers(s: np.ndarray, t: np.ndarray | None = None, method: str = "soft",
                    params: OutlierParams | None = None) -> np.ndarray:
    """Boolean mask of the wild samples of s (True = remove); see :func:`analyse`."""
    return analyse(s, t, method, params).wild


def innovation_gate_3sigma(s: np.ndarray, t: np.ndarray | None = None, sigma: float | None = None,
                           accel_sigma: float | None = None, gate_sigma: float = 3.0,
                           max_misses: int = 8) -> np.ndarray:
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
        accel_sigma = 0.1 * sigma / dt_med ** 2
    r = sigma ** 2
    q = accel_sigma ** 2
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
        qm = q * np.array([[dt ** 3 / 3.0, dt ** 2 / 2.0], [dt ** 2 / 2.0, dt]])
        xp = f @ x
        pp = f @ p @ f.T + qm
        innov = s[i] - xp[0]
        s_var = pp[0, 0] + r
        if innov * innov > gate_sigma ** 2 * s_var:
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


class LiveOutlierGate:
    """Causal, zero-delay wild-plot gate for the engine, after Hu 2013's k-mean distance.

    Each key (a radar track: e.g. ``radar_index << 32 | track_no``, or the radar index
    and Mode S address packed the same way) keeps a ring buffer of its last `window`
    *accepted* plots as radar-plane x/y (x = range*sin(az), y = range*cos(az)) and time.
    A new plot is decided on arrival (delay 0) from past plots only:

    * its window is fitted with a constant-velocity line (least squares in time), and each
      past plot is carried forward to the new plot's time with that velocity;
    * the new plot is a sub-sequence of length one, so its height (eq. 2) and deviation
      (eq. 5) are 0 and only its level (eq. 4) can be outlying: its k-mean distance (the
      paper's mean distance to the k nearest points) to the carried-forward plots
      measures that, in metres;
    * as in eq. 1 the deviation is standardised, by sqrt(sigma_fit^2 + sigma_floor_m^2),
      where sigma_fit^2 is the window's residual variance about its line, from the
      median squared residual so one wild plot in the window cannot inflate it (it grows in a turn, so
      a manoeuvre widens the gate) and sigma_floor_m plays the role of eps*delta (radar
      noise; it also keeps a perfectly straight window from rejecting everything);
    * the plot is rejected when that ratio exceeds `threshold`.

    Rejected plots never enter the window, so a run of wild plots cannot drag it along.
    They are kept aside; after `relock_after` consecutive rejections the track is taken
    to have genuinely jumped, the window is replaced by the rejected plots and the plot is
    accepted (so a run of up to relock_after - 1 wild plots is rejected, and a persistent
    change is accepted from its relock_after-th plot on). Keys with fewer than
    `min_history` accepted plots, or whose last plot is older than `max_gap_s`, are
    accepted unconditionally (the window restarts).

    Memory is bounded: at most `max_keys` keys; keys not seen for `evict_after_s` are
    evicted, and if the table is still full the least recently seen keys are evicted.
    All work is vectorised across keys; plots of one key in one batch are processed in
    time order, one "round" per occurrence.
    """

    def __init__(self, window: int = 8, k: int = 3, threshold: float = 6.0, enabled: bool = True,
                 min_history: int = 4, sigma_floor_m: float = 150.0, relock_after: int = 6,
                 max_gap_s: float = 60.0, evict_after_s: float = 300.0, max_keys: int = 100_000):
        if window < 3:
            raise ValueError("window must be >= 3")
        if not 1 <= k <= min_history <= window:
            raise ValueError("need 1 <= k <= min_history <= window")
        if relock_after < 2:
            raise ValueError("relock_after must be >= 2")
        self.window = int(window)
        self.k = int(k)
        self.threshold = float(threshold)
        self.enabled = bool(enabled)
        self.min_history = int(min_history)
        self.sigma_floor_m = float(sigma_floor_m)
        self.relock_after = int(relock_after)
        self.max_gap_s = float(max_gap_s)
        self.evict_after_s = float(evict_after_s)
        self.max_keys = int(max_keys)
        self.rejected = 0
        self.relocked = 0
        self.evicted = 0
        # key → row index as two aligned sorted arrays: one vectorised searchsorted per
        # batch instead of a dict lookup per key
        self._skeys = np.empty(0, dtype=np.int64)
        self._srows = np.empty(0, dtype=np.int64)
        self._free: list[int] = []
        self._last_sweep_t = -np.inf
        self._alloc(min(1024, self.max_keys))

    # -- storage -------------------------------------------------------------------
    def _alloc(self, capacity: int) -> None:
        """Grow the per-key arrays to `capacity` rows, keeping the rows held."""
        old = getattr(self, "_cap", 0)
        w, p = self.window, self.relock_after - 1
        specs = {
            "_x": ((w,), 0.0, float), "_y": ((w,), 0.0, float), "_t": ((w,), 0.0, float),
            "_px": ((p,), 0.0, float), "_py": ((p,), 0.0, float), "_pt": ((p,), 0.0, float),
            "_count": ((), 0, np.int64), "_head": ((), 0, np.int64), "_npend": ((), 0, np.int64),
            "_last_t": ((), -np.inf, float), "_row_key": ((), -1, np.int64),
        }
        for name, (tail, fill, dtype) in specs.items():
            arr = np.full((capacity,) + tail, fill, dtype=dtype)
            if old:
                arr[:old] = getattr(self, name)
            setattr(self, name, arr)
        self._free.extend(range(capacity - 1, old - 1, -1))
        self._cap = capacity

    @property
    def n_keys(self) -> int:
        """Number of keys currently held."""
        return int(self._skeys.size)

    @property
    def capacity(self) -> int:
        """Rows allocated (never more than max_keys)."""
        return self._cap

    @property
    def memory_bytes(self) -> int:
        """Bytes held by the per-key arrays."""
        return sum(a.nbytes for a in (self._x, self._y, self._t, self._px, self._py, self._pt,
                                      self._count, self._head, self._npend, self._last_t, self._row_key))

    def _evict_rows(self, rows: np.ndarray) -> None:
        gone = np.isin(self._skeys, self._row_key[rows])
        self._skeys, self._srows = self._skeys[~gone], self._srows[~gone]
        self._free.extend(rows.tolist())
        self._row_key[rows] = -1
        self._count[rows] = 0
        self._npend[rows] = 0
        self._last_t[rows] = -np.inf
        self.evicted += int(rows.size)

    def _sweep(self, t_now: float) -> None:
        stale = np.flatnonzero((self._row_key >= 0) & (self._last_t < t_now - self.evict_after_s))
        if stale.size:
            self._evict_rows(stale)
        self._last_sweep_t = t_now

    def _rows_for(self, ukeys: np.ndarray, t_now: float) -> np.ndarray:
        rows = np.full(ukeys.size, -1, dtype=np.int64)
        if self._skeys.size:
            pos = np.minimum(np.searchsorted(self._skeys, ukeys), self._skeys.size - 1)
            found = self._skeys[pos] == ukeys
            rows[found] = self._srows[pos[found]]
        new = np.flatnonzero(rows < 0)
        if new.size == 0:
            return rows
        if new.size > len(self._free) and self._cap < self.max_keys:
            cap = self._cap
            while cap - self._skeys.size < new.size and cap < self.max_keys:
                cap = min(2 * cap, self.max_keys)
            self._alloc(cap)
        if new.size > len(self._free):
            self._sweep(t_now)
        if new.size > len(self._free):
            # Still full: evict the least recently seen keys not in this batch.
            held = np.flatnonzero(self._row_key >= 0)
            held = held[~np.isin(held, rows[rows >= 0])]
            need = min(new.size - len(self._free), held.size)
            oldest = held[np.argpartition(self._last_t[held], need - 1)[:need]] if need else held[:0]
            self._evict_rows(oldest)
        n_new = min(new.size, len(self._free))
        if n_new:
            new = new[:n_new]
            got = np.array([self._free.pop() for _ in range(n_new)], dtype=np.int64)
            new_keys = ukeys[new]
            self._row_key[got] = new_keys
            rows[new] = got
            order = np.argsort(new_keys)
            at = np.searchsorted(self._skeys, new_keys[order])
            self._skeys = np.insert(self._skeys, at, new_keys[order])
            self._srows = np.insert(self._srows, at, got[order])
        return rows  # keys beyond max_keys keep row -1: they are accepted untracked

    # -- decision ------------------------------------------------------------------
    def filter(self, keys: np.ndarray, t_s: np.ndarray, range_m: np.ndarray, azimuth_deg: np.ndarray) -> np.ndarray:
        """Boolean mask `accept` for a batch of plots (True = pass on to clustering).

        keys: int64 per plot; t_s: detection time (s); range_m; azimuth_deg (clockwise
        from north). Plots of one key are decided in time order; state is updated.
        """
        keys = np.asarray(keys, dtype=np.int64)
        n = keys.size
        accept = np.ones(n, dtype=bool)
        if not self.enabled or n == 0:
            return accept
        t_s = np.asarray(t_s, dtype=float)
        az = np.deg2rad(np.asarray(azimuth_deg, dtype=float))
        rng = np.asarray(range_m, dtype=float)
        x = rng * np.sin(az)
        y = rng * np.cos(az)
        t_now = float(t_s.max())
        if t_now - self._last_sweep_t > 0.25 * self.evict_after_s:
            self._sweep(t_now)
        # Sort by key then time; rank = occurrence of the plot within its key.
        order = np.lexsort((t_s, keys))
        ks = keys[order]
        first = np.concatenate(([True], ks[1:] != ks[:-1]))
        group = np.cumsum(first) - 1
        urows = self._rows_for(ks[first], t_now)
        rows = np.empty(n, dtype=np.int64)
        rank = np.empty(n, dtype=np.int64)
        rows[order] = urows[group]
        rank[order] = np.arange(n) - np.flatnonzero(first)[group]
        tracked = rows >= 0
        for r in range(int(rank.max()) + 1):
            sel = np.flatnonzero(tracked & (rank == r))
            if sel.size:
                accept[sel] = self._decide(rows[sel], t_s[sel], x[sel], y[sel])
        self.rejected += int(n - accept.sum())
        return accept

    def _decide(self, rows: np.ndarray, t: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Decide one plot per row (rows unique), update the rows, return accept."""
        w = self.window
        stale = (t - self._last_t[rows]) > self.max_gap_s
        if stale.any():
            self._count[rows[stale]] = 0
            self._head[rows[stale]] = 0
            self._npend[rows[stale]] = 0
        count = self._count[rows]
        gated = count >= self.min_history
        ok = np.ones(rows.size, dtype=bool)
        gi = np.flatnonzero(gated)
        if gi.size:
            gr = rows[gi]
            valid = np.arange(w)[None, :] < count[gi, None]
            m = count[gi].astype(float)
            dt = np.where(valid, self._t[gr] - t[gi, None], 0.0)  # <= 0 for past plots
            wx = np.where(valid, self._x[gr], 0.0)
            wy = np.where(valid, self._y[gr], 0.0)
            tbar = dt.sum(axis=1) / m
            xbar = wx.sum(axis=1) / m
            ybar = wy.sum(axis=1) / m
            dtc = np.where(valid, dt - tbar[:, None], 0.0)
            stt = (dtc * dtc).sum(axis=1)
            stt_safe = np.where(stt > 0.0, stt, 1.0)
            vx = np.where(stt > 0.0, (dtc * (wx - xbar[:, None])).sum(axis=1) / stt_safe, 0.0)
            vy = np.where(stt > 0.0, (dtc * (wy - ybar[:, None])).sum(axis=1) / stt_safe, 0.0)
            # Residual scale about the fitted line, robust to a wild plot that got in:
            # for 2-D Gaussian residuals E[r^2] = median(r^2) / ln 2; m/(m-2) for the fit.
            rx = wx - (xbar[:, None] + vx[:, None] * dtc)
            ry = wy - (ybar[:, None] + vy[:, None] * dtc)
            r2 = np.sort(np.where(valid, rx * rx + ry * ry, np.inf), axis=1)  # the window's m first
            mi = count[gi, None]
            median = 0.5 * (np.take_along_axis(r2, (mi - 1) // 2, 1) + np.take_along_axis(r2, mi // 2, 1))[:, 0]
            var_fit = median / np.log(2.0) * m / np.maximum(m - 2.0, 1.0)
            # Past plots carried forward to the new time: p_j + v * (t - t_j) = p_j - v * dt_j.
            ex = wx - vx[:, None] * dt
            ey = wy - vy[:, None] * dt
            d = np.hypot(x[gi, None] - ex, y[gi, None] - ey)
            d = np.where(valid, d, np.inf)
            kmd = np.partition(d, self.k - 1, axis=1)[:, :self.k].mean(axis=1)
            ratio = kmd / np.sqrt(var_fit + self.sigma_floor_m ** 2)
            ok[gi] = ratio <= self.threshold
        # Rejected plots: keep aside; relock after relock_after consecutive rejections.
        rej = np.flatnonzero(~ok)
        if rej.size:
            rr = rows[rej]
            npend = self._npend[rr]
            relock = npend >= self.relock_after - 1
            keep = ~relock
            if keep.any():
                kr, kp = rr[keep], npend[keep]
                self._px[kr, kp] = x[rej[keep]]
                self._py[kr, kp] = y[rej[keep]]
                self._pt[kr, kp] = t[rej[keep]]
                self._npend[kr] = kp + 1
            if relock.any():
                for r in rr[relock].tolist():
                    p = min(int(self._npend[r]), w - 1)
                    src = slice(int(self._npend[r]) - p, int(self._npend[r]))
                    self._x[r, :p] = self._px[r, src]
                    self._y[r, :p] = self._py[r, src]
                    self._t[r, :p] = self._pt[r, src]
                    self._count[r] = p
                    self._head[r] = p
                ok[rej[relock]] = True
                self.relocked += int(relock.sum())
        # Accepted plots enter the ring buffer.
        acc = np.flatnonzero(ok)
        if acc.size:
            ar = rows[acc]
            h = self._head[ar]
            self._x[ar, h] = x[acc]
            self._y[ar, h] = y[acc]
            self._t[ar, h] = t[acc]
            self._head[ar] = (h + 1) % w
            self._count[ar] = np.minimum(self._count[ar] + 1, w)
            self._npend[ar] = 0
        self._last_t[rows] = np.maximum(self._last_t[rows], t)
        return ok

    def reset(self) -> None:
        """Forget every key."""
        held = np.flatnonzero(self._row_key >= 0)
        self._evict_rows(held)
        self.evicted -= int(held.size)
