"""Tests of radar_fusion.tracking.outliers (Hu 2013): equations by hand, decision rule, the
reproduction (soft >= K-MODF on runs), and the live gate."""

import math

import numpy as np
import pytest

from radar_fusion.tools.outlier_experiment import evaluate, make_scenario, run_method, score
from radar_fusion.tracking.live_gate import LiveOutlierGate
from radar_fusion.tracking.outliers import (
    OutlierParams,
    analyse,
    decide_wild,
    edge_points,
    hard_edge_weight,
    innovation_gate_3sigma,
    k_distance,
    k_mean_distance,
    minmax_normalise,
    outlier_factor,
    segment_at_edges,
    soft_edge_weight,
    subsequence_features,
)

TINY = [1.0, 2.0, 2.0, 9.0, 3.0, 4.0, 4.0]
V = 3


def _windows_of(i, n, v):
    """The v windows summed for sample i: starts i-v+1..i clipped to 0..n-v."""
    return [min(max(i - v + 1 + m, 0), n - v) for m in range(v)]


def _mean(xs):
    return sum(xs) / len(xs)


def _pstd(xs):
    mu = _mean(xs)
    return math.sqrt(sum((x - mu) ** 2 for x in xs) / len(xs))


def test_eq1_soft_weight_by_hand():
    n = len(TINY)
    expected = []
    for i in range(n):
        total = 0.0
        for j in _windows_of(i, n, V):
            win = TINY[j : j + V]
            sd = _pstd(win)
            total += (TINY[i] - _mean(win)) / (sd + (1e-9 if sd == 0 else 0.0))
        expected.append(abs(total))
    got = soft_edge_weight(np.array(TINY), V)
    np.testing.assert_allclose(got, expected, rtol=1e-12)
    # The spike at index 3 has the largest weight; window 3 of the sample 3 sum, by hand:
    # window [9,3,4]: mean 16/3, std sqrt(((11/3)^2+(7/3)^2+(4/3)^2)/3)
    sd = math.sqrt(((11 / 3) ** 2 + (7 / 3) ** 2 + (4 / 3) ** 2) / 3)
    # Sample 0 sums the first window v times (series end); among interior samples
    # the spike has the largest weight.
    assert got[1:6].argmax() == 2
    assert abs((9 - 16 / 3) / sd - 11 / math.sqrt(62.0)) < 1e-12


def test_eq1_delta_guard_constant_window():
    s = np.array([5.0, 5.0, 5.0, 5.0, 6.0])
    w = soft_edge_weight(s, 3, epsilon=1e-6)
    assert np.all(np.isfinite(w))
    # Sample 0 sums window 0 three times: constant, so (5-5)/(0+eps) = 0.
    assert w[0] == 0.0


def test_kmodf_hard_weight_by_hand():
    n = len(TINY)
    expected = []
    for i in range(n):
        total = 0
        for j in _windows_of(i, n, V):
            win = TINY[j : j + V]
            if max(win) > min(win):
                total += (TINY[i] == max(win)) - (TINY[i] == min(win))
        expected.append(abs(total))
    np.testing.assert_array_equal(hard_edge_weight(np.array(TINY), V), expected)
    # The spike is the maximum of all three windows that contain it.
    assert hard_edge_weight(np.array(TINY), V)[3] == 3


def test_edge_rule_and_segmentation():
    w = np.array([0.0, 1.0, 5.0, 6.0, 0.5, 0.2, 7.0, 0.1])
    edge = edge_points(w, v=2, edge_quantile=0.6, edge_level=1.0)
    # quantile 0.6 of w (linear interpolation) = 1.0; and w/2 >= 1 -> w >= 2.
    np.testing.assert_array_equal(edge, [0, 0, 1, 1, 0, 0, 1, 0])
    starts, stops, edge_stops = segment_at_edges(edge)
    np.testing.assert_array_equal(starts, [0, 2, 6])
    np.testing.assert_array_equal(stops, [2, 6, 8])
    np.testing.assert_array_equal(edge_stops, [0, 4, 7])


def test_eq2_to_eq5_features_by_hand():
    s = np.array([1.0, 2.0, 2.0, 9.0, 3.0, 4.0, 4.0])
    starts, stops = np.array([0, 3, 6]), np.array([3, 6, 7])
    f = subsequence_features(s, starts, stops)
    for p, (a, b) in enumerate(zip(starts, stops)):
        seg = list(s[a:b])
        h = seg[-1] - seg[0]
        length = len(seg)
        mu = sum(seg) / length
        sd = math.sqrt(sum((x - mu) ** 2 for x in seg) / (length - 1)) if length > 1 else 0.0
        np.testing.assert_allclose(f[p], [h, length, mu, sd], rtol=1e-12)
    np.testing.assert_allclose(f[1], [-5.0, 3.0, 16 / 3, math.sqrt(31.0 / 3.0)], rtol=1e-12)


def test_eq6_minmax_with_constant_column():
    c = np.array([[1.0, 7.0], [3.0, 7.0], [2.0, 7.0]])
    d = minmax_normalise(c, epsilon=1e-3)
    np.testing.assert_allclose(d[:, 0], [0.0, 1.0, 0.5])
    np.testing.assert_allclose(d[:, 1], [0.0, 0.0, 0.0])


def test_k_distance_and_k_mean_distance_by_hand():
    x = np.array([0.0, 1.0, 3.0, 7.0])
    # distances from 0: 1,3,7; from 1: 1,2,6; from 3: 3,2,4; from 7: 7,6,4
    np.testing.assert_allclose(k_distance(x, 2), [3.0, 2.0, 3.0, 6.0])
    np.testing.assert_allclose(k_mean_distance(x, 2), [2.0, 1.5, 2.5, 5.0])
    # Ties: condition 1 and 2 give the tied distance as the k-distance.
    np.testing.assert_allclose(k_distance(np.array([0.0, 1.0, -1.0, 5.0]), 2)[0], 1.0)


def test_eq7_outlier_factor_by_hand():
    f = np.array([[0.0, 0.0, 0.0, 0.0], [0.1, 0.0, 0.1, 0.0], [0.0, 0.1, 0.0, 0.1], [1.0, 1.0, 1.0, 1.0]])
    k = 1
    cols = []
    pts = [list(r) for r in f]

    # Independent: plain loops for 4-D and each 1-D k-mean distance (k = 1).
    def nn(points, i):
        return min(math.dist(points[i], points[j]) for j in range(len(points)) if j != i)

    cols.append([nn(pts, i) for i in range(4)])
    for dim in range(4):
        sub = [[r[dim]] for r in pts]
        cols.append([nn(sub, i) for i in range(4)])
    norm = []
    for c in cols:
        lo, hi = min(c), max(c)
        norm.append([(v - lo) / (hi - lo) for v in c])
    expected = [norm[0][i] + max(norm[d][i] for d in range(1, 5)) for i in range(4)]
    of, _dist = outlier_factor(f, k)
    np.testing.assert_allclose(of, expected, rtol=1e-9)
    assert of.argmax() == 3 and abs(of[3] - 2.0) < 1e-9


def test_decision_rule():
    of = np.array([0.1, 0.12, 0.11, 0.09, 0.1, 1.5, 1.6, 0.13])
    run = np.array([0, 1, 1, 2, 1, 1, 20, 1])
    wild, thr = decide_wild(of, run, OutlierParams(of_sigma=6.0, max_wild_length=8))
    med = np.median(of)
    assert thr == pytest.approx(med + 6.0 * 1.4826 * np.median(np.abs(of - med)))
    # Index 6 has a large OF but its edge run is too long to be a wild run.
    np.testing.assert_array_equal(wild, [0, 0, 0, 0, 0, 1, 0, 0])
    wild_abs, thr_abs = decide_wild(of, run, OutlierParams(of_threshold=0.115))
    assert thr_abs == 0.115
    np.testing.assert_array_equal(wild_abs, [0, 1, 0, 0, 0, 1, 0, 1])


def test_analyse_on_reproduction_series():
    sc = make_scenario(7)
    a = analyse(sc.azimuth_deg, sc.t_s, method="soft")
    assert a.wild[sc.wild].mean() >= 0.9
    assert (a.wild & ~sc.wild).sum() <= 6
    # Sub-sequences tile the series; wild samples lie in the edge runs of wild ones.
    assert a.starts[0] == 0 and a.stops[-1] == sc.t_s.size
    np.testing.assert_array_equal(a.starts[1:], a.stops[:-1])
    assert a.edge[a.wild].all()


def test_soft_at_least_as_good_as_kmodf_on_runs():
    soft_tp = kmodf_tp = 0
    for seed in range(6):
        sc = make_scenario(seed)
        soft_tp += score(run_method("soft", sc), sc)["tp_run"]
        kmodf_tp += score(run_method("kmodf", sc), sc)["tp_run"]
    assert soft_tp >= kmodf_tp
    assert soft_tp > 0


def test_reproduction_summary_soft_finds_wild_points():
    r = evaluate(5, first_seed=40)
    assert r["soft"]["recall"] >= 0.9
    assert r["soft"]["precision"] >= 0.8
    assert r["soft"]["recall_runs"] >= r["kmodf"]["recall_runs"]


def test_innovation_gate_flags_spike_not_ramp():
    rng = np.random.default_rng(1)
    s = np.linspace(0.0, 10.0, 400) + rng.normal(0, 0.05, 400)
    s[150] += 1.0
    flagged = innovation_gate_3sigma(s, sigma=0.05)
    assert flagged[150]
    assert flagged.sum() <= 5


# ---------------------------------------------------------------- live gate
SCAN_S = 4.0


def _track(n, turn_deg_s=0.0, turn=(0.0, 0.0), seed=0, scan_s=SCAN_S, speed_mps=200.0):
    """Range/azimuth plots of a 200 m/s aircraft (``speed_mps``), 4 s scans (``scan_s``),
    optional coordinated turn while turn[0] <= t < turn[1]; 50 m and 0.07° of noise."""
    rng = np.random.default_rng(seed)
    x, y, hd = 20000.0, 40000.0, math.radians(90.0)
    t = np.arange(n) * scan_s
    xs, ys = [], []
    for ti in t:
        xs.append(x)
        ys.append(y)
        rate = math.radians(turn_deg_s) if turn[0] <= ti < turn[1] else 0.0
        for _ in range(round(scan_s * 10)):
            hd += rate * 0.1
            x += speed_mps * math.sin(hd) * 0.1
            y += speed_mps * math.cos(hd) * 0.1
    xs, ys = np.array(xs), np.array(ys)
    r = np.hypot(xs, ys) + rng.normal(0, 50.0, n)
    az = np.degrees(np.arctan2(xs, ys)) + rng.normal(0, 0.07, n)
    return t, r, az


def _feed(gate, key, t, r, az):
    return np.array([gate.filter(np.array([key]), t[i : i + 1], r[i : i + 1], az[i : i + 1])[0] for i in range(t.size)])


def test_live_gate_rejects_isolated_wild_and_run_of_five():
    t, r, az = _track(40, seed=2)
    r = r.copy()
    r[12] += 3000.0
    r[20:25] -= 2500.0  # run of 5 wild plots
    gate = LiveOutlierGate()
    acc = _feed(gate, 5, t, r, az)
    assert not acc[12]
    assert not acc[20:25].any()
    # Every genuine plot is accepted, including the ones right after the run.
    genuine = np.ones(40, dtype=bool)
    genuine[12] = False
    genuine[20:25] = False
    assert acc[genuine].all()


def test_live_gate_accepts_coordinated_turn():
    for seed in range(5):
        t, r, az = _track(60, turn_deg_s=3.0, turn=(80.0, 170.0), seed=seed)
        assert _feed(LiveOutlierGate(), 9, t, r, az).all()


def test_live_gate_takes_the_plot_after_a_long_silence_whatever_the_aircraft_did():
    """A radar track silent 40 s (the antenna's cone of silence; real data: Jahorina's
    4CA9F6 came out of it 42 s later) while the aircraft turned 90° at 2.5°/s: its next plot
    lies some 6 km off the window's line, and is taken (the window restarts after
    max_gap_s, 30 s, and max_gap_scans of its radar's rotation). With a 60 s limit it was
    refused; within 30 s a wild plot still is, and after a 12 s radar's two missed scans
    (36 s, under four rotations)."""
    t, r, az = _track(60, turn_deg_s=2.5, turn=(84.0, 120.0), seed=3)
    keep = (t < 84.0) | (t >= 120.0)
    t, r, az = t[keep], r[keep], az[keep]
    first_after = int(np.flatnonzero(t >= 120.0)[0])
    assert t[first_after] - t[first_after - 1] == 40.0
    assert _feed(LiveOutlierGate(), 1, t, r, az).all()
    assert not _feed(LiveOutlierGate(max_gap_s=60.0), 1, t, r, az)[first_after]
    # a wild plot 3 km off after 16 s of silence (three missed scans) is still refused
    t2, r2, az2 = _track(40, seed=4)
    keep2 = (t2 < 60.0) | (t2 >= 76.0)
    t2, r2, az2 = t2[keep2], r2[keep2].copy(), az2[keep2]
    after = int(np.flatnonzero(t2 >= 76.0)[0])
    r2[after] += 3000.0
    acc = _feed(LiveOutlierGate(), 2, t2, r2, az2)
    assert not acc[after] and acc[np.arange(t2.size) != after].all()
    # a 12 s radar's two missed scans (36 s) keep its window (max_gap_scans, 4 rotations):
    # a wild plot 3 km off after them is refused; with the 30 s alone it was taken
    t3, r3, az3 = _track(30, seed=5, scan_s=12.0)
    keep3 = (t3 < 120.0) | (t3 >= 144.0)
    t3, r3, az3 = t3[keep3], r3[keep3].copy(), az3[keep3]
    after3 = int(np.flatnonzero(t3 >= 144.0)[0])
    assert t3[after3] - t3[after3 - 1] == 36.0
    r3[after3] += 3000.0

    def feed_with_rotation(gate):
        one = np.ones(1)
        return np.array(
            [gate.filter(np.array([3]), t3[i : i + 1], r3[i : i + 1], az3[i : i + 1], rotation_s=12.0 * one)[0]
             for i in range(t3.size)]
        )  # fmt: skip

    acc3 = feed_with_rotation(LiveOutlierGate())
    assert not acc3[after3] and acc3[np.arange(t3.size) != after3].all()
    assert feed_with_rotation(LiveOutlierGate(max_gap_scans=0.0))[after3]


def test_live_gate_wild_plots_in_a_turn():
    """A 12 s radar's track turning at 1.5°/s from its fourth scan, 20 noise draws (issue 15
    item 7; seen at 1,000x10 with 3 % wild plots: an aircraft's track coasted out):

    * a wild plot 3.2 km short in range as the turn starts: it is refused, and so is the
      turn's next plot when the line misses it (14 of 20 draws), but not the ones after:
      the arc is tried with each plot kept aside left out in turn. With the wild plot in
      every arc, the turn's plots were refused until the re-lock, four scans on;
    * a wild plot 2.4 km short deep in the turn: the window's line, bent by the turn,
      widened the gate and took it in every draw; the arc through the newest plots refuses
      it, and no good plot is refused."""
    start = []
    for seed in range(20):
        # a 12 s radar's track, straight, then turning at 1.5°/s from 36 s (the fourth scan on)
        t, r, az = _track(14, turn_deg_s=1.5, turn=(36.0, math.inf), seed=seed, scan_s=12.0, speed_mps=150.0)
        wild_early, wild_deep = r.copy(), r.copy()
        wild_early[4] -= 3200.0
        wild_deep[9] -= 2400.0
        sigma = (np.full(1, 50.0), np.full(1, math.radians(0.07)))
        for rr, wild in ((wild_early, 4), (wild_deep, 9)):
            gate = LiveOutlierGate()
            acc = np.array(
                [
                    gate.filter(np.array([1]), t[i : i + 1], rr[i : i + 1], az[i : i + 1], *sigma)[0]
                    for i in range(t.size)
                ]
            )
            assert not acc[wild]
            good = np.ones(t.size, bool)
            good[wild] = False
            if wild == 4:
                good[5] = False
                start.append(acc[5])
            assert acc[good].all(), (seed, wild, acc.astype(int))
    assert sum(start) >= 3  # the turn's first plot after the wild one passes in some draws (6 of 20)


def test_live_gate_good_plot_after_a_wild_one_in_a_young_turn():
    """A 12 s radar's track turning at 1.5°/s from its second scan: the window holds four
    plots (too few for the bent-window arc), the fifth is wild (3.2 km short), the sixth is
    good. The window's line misses the sixth (24 s of turn since the window's last plot),
    and the arc through the window and the wild plot kept aside misses it too; the arc
    through the window alone, the one plot kept aside left out, takes it. Before, with the
    plot kept aside in every arc, it was refused in 19 of 20 draws and the track coasted
    two scans: the 1,000×10 wild twin's worst aircraft (seed 2, A00738, 752 m RMS against
    208 m without the wild plots; GOSPA 1.198× the clean twin, now 1.169×)."""
    sigma = (np.full(1, 50.0), np.full(1, math.radians(0.07)))
    passed = 0
    for seed in range(20):
        t, r, az = _track(9, turn_deg_s=1.5, turn=(12.0, math.inf), seed=seed, scan_s=12.0, speed_mps=150.0)
        r = r.copy()
        r[4] -= 3200.0
        gate = LiveOutlierGate()
        acc = np.array(
            [gate.filter(np.array([1]), t[i : i + 1], r[i : i + 1], az[i : i + 1], *sigma)[0] for i in range(t.size)]
        )
        assert acc[:4].all() and not acc[4]
        assert acc[6:].all()
        passed += int(acc[5])
    assert passed >= 18, passed  # 18 of 20 here


def test_live_gate_accepts_persistent_change():
    t, r, az = _track(40, seed=4)
    r = r.copy()
    r[20:] += 4000.0  # the track genuinely jumps (e.g. the radar re-associated it)
    gate = LiveOutlierGate(relock_after=6)
    acc = _feed(gate, 1, t, r, az)
    assert not acc[20:25].any()
    assert acc[25:].all()
    assert gate.relocked == 1


def test_live_gate_disabled_and_multi_plot_batches():
    t, r, az = _track(20, seed=5)
    r = r.copy()
    r[15] += 5000.0
    assert LiveOutlierGate(enabled=False).filter(np.full(20, 3), t, r, az).all()
    # The whole track in one batch: plots are decided in time order, shuffled input.
    perm = np.random.default_rng(0).permutation(20)
    acc = LiveOutlierGate().filter(np.full(20, 3)[perm], t[perm], r[perm], az[perm])
    expected = np.ones(20, dtype=bool)
    expected[15] = False
    np.testing.assert_array_equal(acc[np.argsort(perm)], expected)


def test_live_gate_batches_give_the_verdicts_of_plot_by_plot():
    """Six radar tracks interleaved, with wild plots, a run that relocks and a gap that
    restarts a track, fed in shuffled batches of any size (several plots of a track in one
    batch) and then one plot at a time: the same verdicts and counts (each track's plots
    are decided in time order, the tracks independently)."""
    rng = np.random.default_rng(11)
    keys, ts, rs, azs = [], [], [], []
    for key in range(6):
        t, r, az = _track(60, turn_deg_s=2.0 if key % 2 else 0.0, turn=(100.0, 150.0), seed=20 + key)
        r = r.copy()
        wild = rng.random(60) < 0.06
        r[wild] += rng.choice([-1, 1], wild.sum()) * rng.uniform(1500, 4000, wild.sum())
        if key == 2:
            r[35:] += 4000.0  # a genuine jump: relocks
        if key == 4:
            t = np.where(np.arange(60) >= 30, t + 120.0, t)  # a gap beyond max_gap_s
        keys.append(np.full(60, key))
        ts.append(t + key * 0.1)
        rs.append(r)
        azs.append(az)
    key, t, r, az = (np.concatenate(a) for a in (keys, ts, rs, azs))
    by_time = np.argsort(t, kind="stable")
    one = LiveOutlierGate()
    single = np.empty(t.size, bool)
    for i in by_time:
        single[i] = one.filter(key[i : i + 1], t[i : i + 1], r[i : i + 1], az[i : i + 1])[0]
    batched_gate = LiveOutlierGate()
    batched = np.empty(t.size, bool)
    start = 0
    while start < t.size:
        part = by_time[start : start + int(rng.integers(1, 40))]
        shuffled = rng.permutation(part)
        batched[shuffled] = batched_gate.filter(key[shuffled], t[shuffled], r[shuffled], az[shuffled])
        start += part.size
    np.testing.assert_array_equal(batched, single)
    assert (batched_gate.rejected, batched_gate.relocked) == (one.rejected, one.relocked)
    assert one.relocked >= 1 and 5 <= one.rejected <= 40


def test_live_gate_memory_is_bounded():
    gate = LiveOutlierGate(max_keys=500, evict_after_s=100.0)
    rng = np.random.default_rng(0)
    for step in range(20):
        keys = rng.integers(0, 10**9, 300).astype(np.int64)
        t = np.full(300, step * 4.0)
        gate.filter(keys, t, rng.uniform(1e4, 1e5, 300), rng.uniform(0, 360, 300))
        assert gate.n_keys <= 500 and gate.capacity <= 500
    assert gate.evicted >= 20 * 300 - 500
    # Keys not seen for evict_after_s are evicted.
    gate.filter(np.array([1], dtype=np.int64), np.array([1000.0]), np.array([5e4]), np.array([10.0]))
    assert gate.n_keys == 1


# _kmd_one's fit arguments for the line alone (quadratic, max_accel_mps2, var_cap) and no
# bound on the plots that are not neighbours (resid_max)
LINE = (False, 0.0, math.inf)
NO_MAX = (math.inf,)


def test_live_gate_ratio_against_a_hand_computation():
    """The live gate's standardised k-mean distance (live_gate._kmd_one) against the
    same rule written independently: np.polyfit's line through the window, the median
    residual scale, the window carried forward and the k nearest."""
    from radar_fusion.tracking.live_gate import _kmd_one

    rng = np.random.default_rng(3)
    w, k, floor = 8, 3, 150.0
    win_t = np.sort(rng.uniform(0.0, 40.0, (5, w)), axis=1)
    vx, vy = rng.uniform(-250, 250, (2, 5, 1))
    win_x = 1e4 + vx * win_t + rng.normal(0, 80, (5, w))
    win_y = -2e4 + vy * win_t + rng.normal(0, 80, (5, w))
    count = np.array([8, 4, 6, 2, 8])
    t = win_t[np.arange(5), count - 1] + 4.0
    x = win_x[np.arange(5), count - 1] + vx[:, 0] * 4.0 + np.array([30.0, -2000.0, 500.0, 0.0, 9000.0])
    y = win_y[np.arange(5), count - 1] + vy[:, 0] * 4.0
    scratch = (np.empty(w), np.empty(w), np.empty(w))
    got = np.array(
        [
            _kmd_one(
                i, t[i], x[i], y[i], count[i], win_t, win_x, win_y, k, floor, floor, *LINE, count[i], *NO_MAX, *scratch
            )[0]
            for i in range(5)
        ]
    )
    for i in range(5):
        m = count[i]
        ts, xs, ys = win_t[i, :m], win_x[i, :m], win_y[i, :m]
        if m < k:
            assert got[i] == math.inf
            continue
        bx, ax = np.polyfit(ts, xs, 1)
        by, ay = np.polyfit(ts, ys, 1)
        res2 = (xs - (ax + bx * ts)) ** 2 + (ys - (ay + by * ts)) ** 2
        scale2 = np.median(res2) / math.log(2.0) * m / max(m - 2, 1)
        dist = np.hypot(x[i] - (xs + bx * (t[i] - ts)), y[i] - (ys + by * (t[i] - ts)))
        want = np.sort(dist)[:k].mean() / math.sqrt(scale2 + floor**2)
        assert got[i] == pytest.approx(want, rel=1e-9)
    assert got[1] > 6.0 and got[4] > 6.0 and got[0] < 6.0  # the jumps are wild, the on-track plot is not
    # Along and across the beam by different scales: every offset rotated into the new
    # plot's (radial, cross) frame by an explicit rotation matrix and divided by its
    # scale; the residual scale and the k-mean distance in those units, the floor 1.
    s_r, s_c = 60.0, 400.0
    got2 = np.array(
        [
            _kmd_one(
                i, t[i], x[i], y[i], count[i], win_t, win_x, win_y, k, s_r, s_c, *LINE, count[i], *NO_MAX, *scratch
            )[0]
            for i in range(5)
        ]
    )
    for i in range(5):
        m = count[i]
        if m < k:
            assert got2[i] == math.inf
            continue
        ts, xs, ys = win_t[i, :m], win_x[i, :m], win_y[i, :m]
        bx, ax = np.polyfit(ts, xs, 1)
        by, ay = np.polyfit(ts, ys, 1)
        phi = math.atan2(x[i], y[i])  # the beam's azimuth, clockwise from +y
        rot = np.array([[math.sin(phi), math.cos(phi)], [math.cos(phi), -math.sin(phi)]])  # rows: radial, cross
        unit = np.diag([1.0 / s_r, 1.0 / s_c]) @ rot
        res = unit @ np.vstack([xs - (ax + bx * ts), ys - (ay + by * ts)])
        scale2 = np.median((res**2).sum(axis=0)) / math.log(2.0) * m / max(m - 2, 1)
        off = unit @ np.vstack([x[i] - (xs + bx * (t[i] - ts)), y[i] - (ys + by * (t[i] - ts))])
        want = np.sort(np.hypot(*off))[:k].mean() / math.sqrt(scale2 + 1.0)
        assert got2[i] == pytest.approx(want, rel=1e-9)


def test_live_gate_arc_ratio_against_a_hand_computation():
    """The quadratic (a turn's arc) of live_gate._kmd_one against np.polyfit of degree 2 in
    the new plot's (radial, cross) frame scaled by the noise: the window's neighbours
    carried forward along the fitted arc, the median residual scale over m − 3 degrees of
    freedom capped at var_cap, the k nearest among the first n_near plots only; inf when
    the arc's acceleration is beyond max_accel_mps2 or a plot past n_near is more than
    resid_max noise units off it."""
    from radar_fusion.tracking.live_gate import _kmd_one

    rng = np.random.default_rng(11)
    w, k, s_r, s_c = 12, 3, 60.0, 250.0
    n = 6
    win_t = np.sort(rng.uniform(0.0, 90.0, (n, w)), axis=1)
    ax_, ay_ = rng.uniform(-3.0, 3.0, (2, n, 1))  # m/s², a turn's centripetal acceleration
    vx, vy = rng.uniform(-200, 200, (2, n, 1))
    win_x = 5e4 + vx * win_t + 0.5 * ax_ * win_t**2 + rng.normal(0, 60, (n, w))
    win_y = 8e4 + vy * win_t + 0.5 * ay_ * win_t**2 + rng.normal(0, 60, (n, w))
    count = np.array([12, 9, 7, 10, 12, 8])
    n_near = count - 2  # the last two stand for the plots kept aside
    t = win_t[np.arange(n), count - 1] + 8.0
    x = 5e4 + vx[:, 0] * t + 0.5 * ax_[:, 0] * t**2 + np.array([40.0, -900.0, 0.0, 3000.0, 100.0, -60.0])
    y = 8e4 + vy[:, 0] * t + 0.5 * ay_[:, 0] * t**2
    scratch = (np.empty(w), np.empty(w), np.empty(w))
    var_cap = np.array([math.inf, math.inf, 0.2, math.inf, math.inf, math.inf])
    for i in range(n):
        m = count[i]
        ts, xs, ys = win_t[i, :m], win_x[i, :m], win_y[i, :m]
        phi = math.atan2(x[i], y[i])
        unit = np.diag([1.0 / s_r, 1.0 / s_c]) @ np.array(
            [[math.sin(phi), math.cos(phi)], [math.cos(phi), -math.sin(phi)]]
        )
        a_b = unit @ np.vstack([xs, ys])  # the window in noise units, along and across the beam
        new = unit @ np.array([x[i], y[i]])
        fits = [np.polyfit(ts - t[i], a_b[r], 2) for r in range(2)]
        f = np.vstack([np.polyval(c, ts - t[i]) for c in fits])
        f_new = np.array([np.polyval(c, 0.0) for c in fits])
        res2 = ((a_b - f) ** 2).sum(axis=0)
        accel_mps2 = np.hypot(*(np.linalg.inv(unit) @ np.array([2 * fits[0][0], 2 * fits[1][0]])))
        scale2 = min(np.median(res2) / math.log(2.0) * m / (m - 3), var_cap[i])
        carried = a_b[:, : n_near[i]] + (f_new[:, None] - f[:, : n_near[i]])
        dist = np.hypot(*(new[:, None] - carried))
        want = np.sort(dist)[:k].mean() / math.sqrt(scale2 + 1.0)
        args = (i, t[i], x[i], y[i], m, win_t, win_x, win_y, k, s_r, s_c, True)
        got = _kmd_one(*args, 10.0, var_cap[i], n_near[i], math.inf, *scratch)[0]
        assert got == pytest.approx(want, rel=1e-7)
        # the bounds: an arc harder than the bound, or a plot past n_near off the fit
        assert _kmd_one(*args, 0.99 * accel_mps2, var_cap[i], n_near[i], math.inf, *scratch)[0] == math.inf
        near_bound = _kmd_one(*args, 1.01 * accel_mps2, var_cap[i], n_near[i], math.inf, *scratch)[0]
        assert near_bound == pytest.approx(want, rel=1e-7)
        worst = math.sqrt(res2[n_near[i] :].max())
        assert _kmd_one(*args, 10.0, var_cap[i], n_near[i], 0.99 * worst, *scratch)[0] == math.inf
        assert _kmd_one(*args, 10.0, var_cap[i], n_near[i], 1.01 * worst, *scratch)[0] == pytest.approx(want, rel=1e-7)


@pytest.mark.slow
def test_live_gate_keeps_the_plots_of_turns_on_simulated_traffic():
    """300 aircraft seen by ten radars of 4-12 s scans for 180 s, 3 % wild plots (the
    simulator's, flagged): the line alone through a window that a turn has bent refused
    good plots, at a turn's end above all (the window curved, the aircraft straight
    again) until its re-lock, six scans on; with the arc tried on a refused plot that
    follows a refused one, far fewer good plots are refused and not one more wild plot
    passes (measured: 28 → 6 good plots refused of 25,400; 668 of 809 wild plots refused
    either way; with the arc judging a bent window and the plots kept aside left out in
    turn, 8 good and 675 wild refused)."""
    import dataclasses

    from radar_fusion.tools import simulate as sim_mod
    from radar_fusion.tracking.live_gate import radar_track_keys

    sc = sim_mod.scenario_for_benchmark(300, 10, 180.0, 0)
    sc = dataclasses.replace(sc, rates=dataclasses.replace(sc.rates, wild_plot_prob=0.03))
    sim = sim_mod.simulate(sc, encode=False)
    sigma_r = np.array([r.sigma_range_m for r in sc.radars])
    sigma_a = np.radians([r.sigma_azimuth_deg for r in sc.radars])
    line, arc = LiveOutlierGate(max_accel_mps2=0.0), LiveOutlierGate()
    refused = {"line": [0, 0], "arc": [0, 0]}  # good, wild
    n_wild = 0
    for c in sim.plot_columns:
        keys = radar_track_keys(np.full(len(c.t_s), c.radar_index), np.asarray(c.track_no), np.asarray(c.mode_s))
        h = np.flatnonzero((keys >= 0) & (np.asarray(c.target_index) >= 0))
        if not h.size:
            continue
        ri = c.radar_index
        args = (
            keys[h],
            c.t_s[h],
            c.range_m[h],
            c.azimuth_deg[h],
            np.full(h.size, sigma_r[ri]),
            np.full(h.size, sigma_a[ri]),
        )
        wild = np.asarray(c.wild)[h].astype(bool)
        n_wild += int(wild.sum())
        for name, gate in (("line", line), ("arc", arc)):
            ok = gate.filter(*args)
            refused[name][0] += int((~ok & ~wild).sum())
            refused[name][1] += int((~ok & wild).sum())
    assert n_wild > 500
    assert refused["line"][0] >= 15  # the line's failure in turns is there to be mended
    assert refused["arc"][0] <= 0.4 * refused["line"][0]
    assert refused["arc"][1] >= refused["line"][1] >= 0.8 * n_wild


def _plain_kmd(t, x, y, pts, k, s_r, s_c, quadratic, max_accel_mps2, var_cap, n_near, resid_max):
    """live_gate._kmd_one written plainly: the window ``pts`` [(t, x, y)] in the new plot's
    beam frame scaled by the noise, np.polyfit of degree 1 (or 2 for the arc), the median
    scale, the neighbours carried along the fit. Returns (ratio, scale²)."""
    p = np.array(pts)
    m = len(p)
    rho = math.hypot(x, y)
    unit = np.array([[x / rho / s_r, y / rho / s_r], [-y / rho / s_c, x / rho / s_c]])
    a_b = unit @ p[:, 1:].T
    new = unit @ np.array([x, y])
    ts = p[:, 0] - t
    if quadratic and (m < 4 or np.ptp(ts) == 0):
        return math.inf, math.inf
    deg = 2 if quadratic else (1 if np.ptp(ts) > 0 else 0)
    fits = [np.polyfit(ts, a_b[r], deg) for r in range(2)]
    if deg == 2 and math.hypot(2 * fits[0][0] * s_r, 2 * fits[1][0] * s_c) > max_accel_mps2:
        return math.inf, math.inf
    f = np.vstack([np.polyval(c, ts) for c in fits])
    f0 = np.array([np.polyval(c, 0.0) for c in fits])
    r2 = ((a_b - f) ** 2).sum(axis=0)
    if np.any(r2[n_near:] > resid_max**2):
        return math.inf, math.inf
    var = min(np.median(r2) / math.log(2.0) * m / max(m - (3.0 if deg == 2 else 2.0), 1.0), var_cap)
    if n_near < k:
        return math.inf, var
    carried = a_b[:, :n_near] + (f0[:, None] - f[:, :n_near])
    return np.sort(np.hypot(*(new[:, None] - carried)))[:k].mean() / math.sqrt(var + 1.0), var


class _PlainGate:
    """LiveOutlierGate's decisions (live_gate._decide_in_order) written plainly, one plot at a
    time: a deque of the accepted plots per key, a list of the refused ones kept aside."""

    def __init__(self, gate):
        self.g, self.win, self.pend, self.last = gate, {}, {}, {}

    def filter(self, keys, ts, xs, ys, s_r, s_c):
        from collections import deque

        from radar_fusion.tracking.live_gate import ARC_PLOTS, BENT_ARC_PLOTS, BENT_VAR, CURVED_VAR

        g = self.g
        accept = np.ones(len(keys), bool)
        for i in np.lexsort((ts, keys)):
            key, t, x, y = int(keys[i]), ts[i], xs[i], ys[i]
            win = self.win.setdefault(key, deque(maxlen=g.window))
            pend = self.pend.setdefault(key, [])
            if t - self.last.get(key, -np.inf) > g.max_gap_s:
                win.clear()
                pend.clear()
            ok = True
            if len(win) >= g.min_history:
                ratio, var_line = _plain_kmd(
                    t, x, y, list(win), g.k, s_r[i], s_c[i], False, 0.0, math.inf, len(win), math.inf
                )
                ok = ratio <= g.threshold
                if ok and var_line > BENT_VAR and len(win) >= 5 and not pend and g.max_accel_mps2 > 0:
                    newest = list(win)[-min(len(win), BENT_ARC_PLOTS) :]
                    args = (g.k, s_r[i], s_c[i], True, g.max_accel_mps2, var_line, len(newest), math.inf)
                    ratio_arc, var_arc = _plain_kmd(t, x, y, newest, *args)
                    ok = not (var_arc < var_line and ratio_arc > g.threshold)
                if not ok and pend and g.max_accel_mps2 > 0:
                    newest = list(win)[-min(len(win), ARC_PLOTS) :]
                    args = (g.k, s_r[i], s_c[i], True, g.max_accel_mps2, var_line, len(newest), 0.5 * g.threshold)
                    # all kept aside, then each left out in turn
                    for left in [None] + list(range(len(pend))):
                        if len(pend) == 1 and left == 0 and var_line <= CURVED_VAR:
                            continue  # the window's own arc only for a window that shows a curve
                        aside = [q for j, q in enumerate(pend) if j != left]
                        if _plain_kmd(t, x, y, newest + aside, *args)[0] <= g.threshold:
                            ok = True
                            win.extend(aside)
                            break
            if not ok:
                if len(pend) >= g.relock_after - 1:
                    keep = min(len(pend), g.window - 1)
                    win.clear()
                    win.extend(pend[len(pend) - keep :])
                    ok = True
                else:
                    pend.append((t, x, y))
            if ok:
                win.append((t, x, y))
                pend.clear()
            self.last[key] = max(self.last.get(key, -np.inf), t)
            accept[i] = ok
        return accept


@pytest.mark.parametrize(
    "params", [{}, {"min_history": 2, "k": 2}, {"window": 4}, {"relock_after": 2}, {"max_accel_mps2": 0.0}]
)
def test_live_gate_against_a_plain_reimplementation(params):
    """The compiled gate against _PlainGate on six radar tracks of 8-12 s scans, coordinated
    turns (1.7-3.4°/s at 100-150 m/s, up to 9 m/s²), jumps, gaps and 8 % gross errors over
    100 batches: the same verdict for every plot, and after every batch the same window (with
    the refused plots kept aside that fitted a turn's arc: 12 times over the five settings),
    the same number kept aside, and a ring whose head is its count until it wraps."""
    for seed in range(3):
        rng = np.random.default_rng(seed)
        gate = LiveOutlierGate(**params, evict_after_s=1e9)
        plain = _PlainGate(LiveOutlierGate(**params, evict_after_s=1e9))
        n_keys = 6
        pos = rng.uniform(-2e5, 2e5, (n_keys, 2))
        heading = rng.uniform(0, 2 * math.pi, n_keys)
        vel = rng.uniform(100, 150, (n_keys, 1)) * np.column_stack((np.sin(heading), np.cos(heading)))
        omega = np.zeros(n_keys)  # rad/s, a coordinated turn's rate
        t_key = np.zeros(n_keys)
        for _ in range(100):
            keys, ts, xs, ys = [], [], [], []
            for key in range(n_keys):
                for _ in range(int(rng.integers(0, 3))):
                    dt = rng.uniform(8, 12) if rng.random() > 0.02 else 70.0  # now and then a gap
                    t_key[key] += dt
                    if rng.random() < 0.15:  # a turn begins or ends
                        omega[key] = rng.choice([-1.0, 1.0]) * rng.uniform(0.03, 0.06) if omega[key] == 0 else 0.0
                    a = omega[key] * dt / 2  # moved along the chord of the arc
                    vel[key] = [math.cos(a) * vel[key, 0] - math.sin(a) * vel[key, 1],
                                math.sin(a) * vel[key, 0] + math.cos(a) * vel[key, 1]]  # fmt: skip
                    pos[key] += vel[key] * dt
                    vel[key] = [math.cos(a) * vel[key, 0] - math.sin(a) * vel[key, 1],
                                math.sin(a) * vel[key, 0] + math.cos(a) * vel[key, 1]]  # fmt: skip
                    if rng.random() < 0.03:  # the radar track jumps
                        pos[key] += rng.uniform(-2e4, 2e4, 2)
                    p = pos[key] + rng.normal(0, 60, 2)
                    if rng.random() < 0.08:  # a gross error
                        p = p + rng.normal(0, 3000, 2)
                    keys.append(key)
                    ts.append(t_key[key])
                    xs.append(p[0])
                    ys.append(p[1])
            if not keys:
                continue
            keys, ts, xs, ys = np.array(keys, np.int64), np.array(ts), np.array(xs), np.array(ys)
            rng_m, az_deg = np.hypot(xs, ys), np.degrees(np.arctan2(xs, ys))
            s_r, s_az = np.full(keys.size, 40.0), np.full(keys.size, math.radians(0.03))
            got = gate.filter(keys, ts, rng_m, az_deg, s_r, s_az)
            x, y = rng_m * np.sin(np.radians(az_deg)), rng_m * np.cos(np.radians(az_deg))
            want = plain.filter(keys, ts, x, y, np.maximum(150.0, s_r), np.maximum(150.0, rng_m * s_az))
            np.testing.assert_array_equal(got, want)
            for key in range(n_keys):
                at = np.searchsorted(gate._skeys, key)
                if at >= gate._skeys.size or gate._skeys[at] != key:
                    continue
                row = gate._srows[at]
                c, h, w = gate._count[row], gate._head[row], gate.window
                ring = [(h - c + j) % w for j in range(c)]
                mine = np.column_stack((gate._t[row, ring], gate._x[row, ring], gate._y[row, ring]))
                theirs = np.array(list(plain.win.get(key, []))).reshape(-1, 3)
                np.testing.assert_allclose(mine, theirs, rtol=1e-12)
                assert c == w or h == c
                assert gate._npend[row] == len(plain.pend.get(key, []))


def test_live_gate_standardises_with_the_plots_noise_at_long_range():
    """A radar track 300 km out from a radar of 0.1° and 50 m noise: across the beam its
    plots spread by 520 m, along it by 50 m. Standardised by that noise (σ_ρ along, ρ σ_θ
    across, each at least the 150 m floor), every good plot of 40 scans passes over 20
    seeds, and gross errors of the simulator's, 2 km in range (its smallest: 40 σ) and
    2° in azimuth (10 km across: 20 σ), are still refused. (Across the beam the gate now
    needs about 10 σ there: 1°, 5 km, is refused for most seeds, not all.) Standardised by
    the 150 m floor both ways (the gate without the radar's noise), good plots are refused:
    the spread is 3.5× the floor, and a window of four can fit them by chance too well."""
    sigma_r_m, sigma_az_rad = 50.0, math.radians(0.1)

    def far_track(seed):
        rng = np.random.default_rng(seed)
        t = np.arange(40) * 5.0
        xs = 180_000.0 + 220.0 * t  # eastbound, ~300 km out
        ys = np.full_like(t, 240_000.0)
        r = np.hypot(xs, ys) + rng.normal(0.0, sigma_r_m, t.size)
        az = np.degrees(np.arctan2(xs, ys)) + np.degrees(rng.normal(0.0, sigma_az_rad, t.size))
        return t, r, az

    def feed(t, r, az, with_noise):
        gate = LiveOutlierGate()
        noise = (sigma_r_m, sigma_az_rad) if with_noise else (None, None)
        return np.array(
            [gate.filter(np.array([7]), t[i : i + 1], r[i : i + 1], az[i : i + 1], *noise)[0] for i in range(t.size)]
        )

    refused_without = 0
    for seed in range(20):
        t, r, az = far_track(seed)
        assert feed(t, r, az, with_noise=True).all(), seed
        refused_without += int((~feed(t, r, az, with_noise=False)).sum())
        r_wild, az_wild = r.copy(), az.copy()
        r_wild[25] += 2000.0
        az_wild[31] += 2.0
        acc = feed(t, r_wild, az_wild, with_noise=True)
        assert not acc[25] and not acc[31], seed
        assert acc[(np.arange(40) != 25) & (np.arange(40) != 31)].all(), seed
    assert refused_without >= 1, refused_without  # 2 of 800 with these seeds
