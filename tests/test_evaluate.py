"""Tests of the track evaluation tool (tools/evaluate.py) against independent computations."""

from __future__ import annotations

import argparse
import csv
import itertools
import math

import numpy as np
import pytest
from scipy.optimize import linear_sum_assignment

from radar_fusion import wire
from radar_fusion.recording import RecordingWriter
from radar_fusion.tools import evaluate as ev

T0 = 1_700_000_000.0


# --------------------------------------------------------------------------- helpers


def track(track_id, t, x_m, y_m, vx_mps=0.0, vy_mps=0.0, status="confirmed"):
    return {
        "track_id": int(track_id),
        "t": float(t),
        "status": status,
        "lat_deg": 0.0,
        "lon_deg": 0.0,
        "x_m": float(x_m),
        "y_m": float(y_m),
        "vx_mps": float(vx_mps),
        "vy_mps": float(vy_mps),
        "fl": None,
        "cov_xy": [1e4, 0.0, 1e4],
        "sources": ["r1"],
        "mode3a": None,
        "mode_s": None,
        "updates": 1,
        "age_s": 0.0,
    }


def batch(t, tracks, period=0):
    return {"v": 1, "t": float(t), "period": period, "tracks": tracks, "ended": []}


def straight_truth(targets, t_s, detectable=None):
    """targets: {id: (x0, y0, vx, vy)} → Truth with one row per second over t_s."""
    cols = {k: [] for k in ("t_s", "target_id", "x_m", "y_m", "vx_mps", "vy_mps", "detectable")}
    for tid, (x0, y0, vx, vy) in targets.items():
        for t in t_s:
            cols["t_s"].append(t)
            cols["target_id"].append(tid)
            cols["x_m"].append(x0 + vx * (t - T0))
            cols["y_m"].append(y0 + vy * (t - T0))
            cols["vx_mps"].append(vx)
            cols["vy_mps"].append(vy)
            cols["detectable"].append(1 if detectable is None else detectable(tid, t))
    return ev.Truth.from_columns(**cols)


def truth_pos(targets, tid, t):
    x0, y0, vx, vy = targets[tid]
    return x0 + vx * (t - T0), y0 + vy * (t - T0)


SECONDS = T0 + np.arange(0, 121.0)
BATCH_TIMES = T0 + 0.5 + 4.0 * np.arange(30)  # between truth rows: interpolation is exercised


# --------------------------------------------------------------------------- GOSPA


def gospa_brute(X, Y, c, p, alpha=2.0):
    """GOSPA by its original definition: all injections of the smaller set enumerated."""
    X, Y = np.asarray(X, float).reshape(-1, 2), np.asarray(Y, float).reshape(-1, 2)
    if X.shape[0] > Y.shape[0]:
        X, Y = Y, X
    m, n = X.shape[0], Y.shape[0]
    best = math.inf
    for perm in itertools.permutations(range(n), m):
        cost = sum(min(np.hypot(*(X[i] - Y[j])), c) ** p for i, j in enumerate(perm))
        best = min(best, cost)
    return (best + c**p / alpha * (n - m)) ** (1.0 / p)


@pytest.mark.parametrize("seed", range(40))
def test_gospa_matches_brute_force(seed):
    rng = np.random.default_rng(seed)
    m, n = rng.integers(0, 5, 2)
    c = float(rng.choice([300.0, 1000.0, 2000.0]))
    p = float(rng.choice([1.0, 2.0, 3.0]))
    X = rng.uniform(0, 3000, (m, 2))
    Y = rng.uniform(0, 3000, (n, 2))
    g = ev.gospa(X, Y, c, p)
    assert g.distance_m == pytest.approx(gospa_brute(X, Y, c, p), rel=1e-9, abs=1e-9)
    assert g.localisation + g.missed + g.false == pytest.approx(g.distance_m**p, rel=1e-9, abs=1e-6)
    assert g.n_assigned + g.n_missed == m and g.n_assigned + g.n_false == n
    assert g.missed == pytest.approx(c**p / 2 * g.n_missed) and g.false == pytest.approx(c**p / 2 * g.n_false)


def test_gospa_textbook_cases():
    c, p = 2000.0, 2.0
    truth3 = [[0, 0], [10_000, 0], [0, 10_000]]
    # No tracks: c^p/α per missed target.
    g = ev.gospa(truth3, np.zeros((0, 2)), c, p)
    assert g.missed == pytest.approx(3 * c**p / 2) and g.false == 0 and g.localisation == 0
    assert g.distance_m == pytest.approx(math.sqrt(3 * c**2 / 2))
    # No truth: c^p/α per false track.
    g = ev.gospa(np.zeros((0, 2)), truth3[:2], c, p)
    assert g.false == pytest.approx(2 * c**p / 2) and g.n_false == 2
    # Both empty, and perfect tracks: zero.
    assert ev.gospa(np.zeros((0, 2)), np.zeros((0, 2)), c, p).distance_m == 0
    assert ev.gospa(truth3, truth3, c, p).distance_m == pytest.approx(0)
    # One pair inside the cut-off: the distance itself.
    g = ev.gospa([[0, 0]], [[300, 400]], c, p)
    assert g.distance_m == pytest.approx(500) and g.n_assigned == 1
    # One pair beyond the cut-off: one missed + one false = c.
    g = ev.gospa([[0, 0]], [[5000, 0]], c, p)
    assert g.distance_m == pytest.approx(c) and g.n_missed == 1 and g.n_false == 1
    # p = 1: the missed/false cost is c/2 each.
    g = ev.gospa([[0, 0], [50_000, 0]], [[100, 0]], 1000.0, 1.0)
    assert g.distance_m == pytest.approx(100 + 500)


@pytest.mark.parametrize("seed", range(5))
def test_cutoff_assignment_matches_dense_assignment(seed):
    # Clustered points make components with several targets and tracks.
    rng = np.random.default_rng(100 + seed)
    centres = rng.uniform(0, 50_000, (6, 2))
    X = centres[rng.integers(0, 6, 30)] + rng.normal(0, 700, (30, 2))
    Y = centres[rng.integers(0, 6, 25)] + rng.normal(0, 700, (25, 2))
    c, p = 1500.0, 2.0
    i, j, d = ev.cutoff_assignment(X, Y, c, p)
    assert len(set(i)) == len(i) and len(set(j)) == len(j) and np.all(d < c)
    np.testing.assert_allclose(d, np.hypot(*(X[i] - Y[j]).T))
    dense = np.minimum(np.hypot(X[:, None, 0] - Y[None, :, 0], X[:, None, 1] - Y[None, :, 1]), c) ** p
    r, k = linear_sum_assignment(dense)
    # Same optimum: a full assignment pays c^p for every pair at or beyond the cut-off,
    # which the partial assignment leaves unassigned (c^p/2 + c^p/2).
    total = np.sum(d**p) + c**p * (min(len(X), len(Y)) - len(i))
    assert total == pytest.approx(dense[r, k].sum(), rel=1e-9)


# --------------------------------------------------------------------------- truth interpolation


def test_truth_interpolation_to_track_times():
    t = T0 + np.array([0.0, 1.0, 2.0, 3.0, 20.0, 21.0])
    cols = dict(
        t_s=t,
        target_id=["a"] * 6,
        x_m=(t - T0) ** 2,
        y_m=-(t - T0),
        vx_mps=2 * (t - T0),
        vy_mps=np.full(6, -1.0),
        detectable=[1, 1, 0, 1, 1, 1],
    )
    # Rows given in a shuffled order, plus a second target: sorting is the reader's job.
    perm = np.random.default_rng(0).permutation(6)
    shuffled = {k: np.asarray(v)[perm] for k, v in cols.items()}
    truth = ev.Truth.from_columns(**shuffled)
    times = T0 + np.array([-1.0, 0.5, 1.0, 1.5, 2.5, 3.0, 10.0, 20.5, 22.0])
    tat = ev.interpolate_truth(truth, times, max_gap_s=10.0)
    np.testing.assert_array_equal(tat.exists[0], [False, True, True, True, True, True, False, True, False])
    np.testing.assert_allclose(tat.x_m[0, 1:6], [0.5, 1.0, 2.5, 6.5, 9.0])  # linear between t² rows
    np.testing.assert_allclose(tat.y_m[0, 1:6], [-0.5, -1.0, -1.5, -2.5, -3.0])
    np.testing.assert_allclose(tat.vx_mps[0, [1, 3, 7]], [1.0, 3.0, 41.0])
    assert np.isnan(tat.x_m[0, 0]) and np.isnan(tat.x_m[0, 6])
    # Detectable only when the rows on both sides are: 1.5 (rows 1, 2) and 2.5 (rows 2, 3) are not.
    np.testing.assert_array_equal(tat.detectable[0], [False, True, True, False, False, True, False, True, False])


def test_load_truth_csv_and_row_dicts(tmp_path):
    path = tmp_path / "truth.csv"
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(ev.TRUTH_COLUMNS)
        for t in range(3):
            w.writerow([T0 + t, 7, "", "", 50.0, 8.0, 30000, 100.0 * t, 5.0, 100.0, 0.0, 0, 1])
            w.writerow([T0 + t, 9, "4CA123", "EIN12", 50.0, 8.0, 30000, 0.0, -5.0 * t, 0.0, -5.0, 0, t != 1])
    truth = ev.load_truth(path)
    assert truth.target_ids == ["7", "9"]
    assert truth.target_mode_s == ["", "4CA123"] and truth.target_callsign == ["", "EIN12"]
    np.testing.assert_allclose(truth.x_m[truth.start[0] : truth.stop[0]], [0, 100, 200])
    np.testing.assert_array_equal(truth.detectable[truth.start[1] : truth.stop[1]], [True, False, True])
    with open(path, newline="") as f:
        rows = [dict(r) for r in csv.DictReader(f)]
    again = ev.as_truth(rows)
    np.testing.assert_allclose(again.y_m, truth.y_m)


def test_load_truth_needs_only_the_scored_columns(tmp_path):
    """A hand-written truth CSV with the six columns scoring uses reads; the others come
    out empty (NaN, "", detectable), and a CSV without one of the six is refused."""
    path = tmp_path / "truth.csv"
    path.write_text("target_id,t_s,x_m,y_m,vx_mps,vy_mps\nB,11,5,6,0,1\nA,10,1,2,3,4\nB,10,5,5,0,1\n")
    truth = ev.load_truth(path)
    assert len(truth) == 3 and truth.n_targets == 2 and truth.target_ids == ["B", "A"]
    np.testing.assert_array_equal(truth.t_s, [10, 11, 10])  # by target (first appearance), then time
    np.testing.assert_array_equal(truth.target_index, [0, 0, 1])
    assert np.isnan(truth.lat_deg).all() and np.isnan(truth.alt_ft).all() and truth.detectable.all()
    assert truth.mode_s.tolist() == ["", "", ""] and truth.target_mode_s == ["", ""]
    path.write_text("target_id,t_s,x_m,y_m,vx_mps\nA,10,1,2,3\n")
    with pytest.raises(ValueError, match="vy_mps"):
        ev.load_truth(path)


# --------------------------------------------------------------------------- accuracy


def test_rms_with_constant_offset_and_known_noise():
    rng = np.random.default_rng(1)
    targets = {k: (k * 20_000.0, 0.0, 150.0, -40.0 + k) for k in range(8)}
    truth = straight_truth(targets, SECONDS)
    offset = np.array([120.0, -90.0])  # 150 m
    voffset = np.array([1.5, -2.0])
    sigma, vsigma = 60.0, 3.0
    batches, epos, evel, epos_settled = [], [], [], []
    for b, t in enumerate(BATCH_TIMES):
        trs = []
        for k in targets:
            if k == 7 and b < 5:
                continue  # track 7 starts late: its own settling clock
            x, y = truth_pos(targets, k, t)
            n = offset + rng.normal(0, sigma, 2)
            if t - (BATCH_TIMES[5] if k == 7 else BATCH_TIMES[0]) < 30.0:
                n = n + 800.0  # an initiation transient, inside the gate
            vn = voffset + rng.normal(0, vsigma, 2)
            trs.append(track(k + 100, t, x + n[0], y + n[1], targets[k][2] + vn[0], targets[k][3] + vn[1]))
            epos.append(np.hypot(*n))
            evel.append(np.hypot(*vn))
            if t - (BATCH_TIMES[5] if k == 7 else BATCH_TIMES[0]) >= 30.0:
                epos_settled.append(np.hypot(*n))
        trs.append(track(999, t, 1e6, 1e6, status="tentative"))  # never scored
        batches.append(batch(t, trs, b))
    s = ev.evaluate(batches, truth, ev.EvalParams(settle_s=30.0))
    epos, evel, epos_settled = map(np.asarray, (epos, evel, epos_settled))
    assert s.n_pairs == epos.size and s.n_pairs_settled == epos_settled.size
    assert s.pos_rms_m == pytest.approx(math.sqrt(np.mean(epos**2)), rel=1e-9)
    assert s.pos_p95_m == pytest.approx(np.percentile(epos, 95), rel=1e-9)
    assert s.vel_rms_mps == pytest.approx(math.sqrt(np.mean(evel**2)), rel=1e-9)
    assert s.vel_p95_mps == pytest.approx(np.percentile(evel, 95), rel=1e-9)
    assert s.pos_rms_settled_m == pytest.approx(math.sqrt(np.mean(epos_settled**2)), rel=1e-9)
    # And against the model: E|e|² = |offset|² + 2σ² after settling.
    assert s.pos_rms_settled_m == pytest.approx(math.sqrt(150.0**2 + 2 * sigma**2), rel=0.05)
    assert s.vel_rms_settled_mps == pytest.approx(math.sqrt(2.5**2 + 2 * vsigma**2), rel=0.1)
    assert s.false_tracks == 0 and s.duplicate_tracks == 0 and s.id_swaps == 0
    assert s.track_ids_per_target_mean == 1.0 and s.completeness_mean == pytest.approx((7 * 30 + 25) / (8 * 30))
    assert s.targets[7].completeness == pytest.approx(25 / 30)
    # GOSPA per time: every target assigned, so it is the root of the summed squared errors.
    b = 10
    d2 = sum(
        (tr["x_m"] - truth_pos(targets, tr["track_id"] - 100, BATCH_TIMES[b])[0]) ** 2
        + (tr["y_m"] - truth_pos(targets, tr["track_id"] - 100, BATCH_TIMES[b])[1]) ** 2
        for tr in batches[b]["tracks"]
        if tr["status"] == "confirmed"
    )
    assert s.gospa_per_time_m[b] == pytest.approx(math.sqrt(d2), rel=1e-9)


# --------------------------------------------------------------------------- continuity, false, duplicate


@pytest.mark.parametrize("keep_previous", [True, False])
def test_track_swapping_between_targets_is_a_swap(keep_previous):
    targets = {"A": (0.0, 0.0, 200.0, 0.0), "B": (0.0, 20_000.0, 200.0, 0.0)}
    truth = straight_truth(targets, SECONDS)
    batches = []
    for b, t in enumerate(BATCH_TIMES):
        first, second = ("A", "B") if b < 15 else ("B", "A")
        batches.append(
            batch(t, [track(1, t, *truth_pos(targets, first, t)), track(2, t, *truth_pos(targets, second, t))])
        )
    s = ev.evaluate(batches, truth, ev.EvalParams(keep_previous=keep_previous))
    assert s.id_swaps == 2  # both tracks jumped once
    assert s.id_changes == 2
    assert [t.n_track_ids for t in s.targets] == [2, 2] and s.track_ids_per_target_mean == 2.0
    assert [t.track_ids for t in s.targets] == [[1, 2], [1, 2]]
    assert s.pos_rms_m == pytest.approx(0.0, abs=1e-6)
    # A new id taking over a target (track break, no jump) is an id change, not a swap.
    broken = [batch(t, [track(1 if b < 15 else 3, t, *truth_pos(targets, "A", t))]) for b, t in enumerate(BATCH_TIMES)]
    s = ev.evaluate(broken, truth, ev.EvalParams(keep_previous=keep_previous))
    assert s.id_swaps == 0 and s.id_changes == 1 and s.targets[0].n_track_ids == 2


def test_crossing_targets_keep_their_tracks():
    # Two aircraft crossing (different levels); the tracker keeps them apart, its errors
    # make the per-batch nearest pairing flip at the crossing; keep_previous must not.
    targets = {"A": (-12_000.0, 0.0, 200.0, 0.0), "B": (12_000.0, 300.0, -200.0, 0.0)}
    truth = straight_truth(targets, SECONDS)
    batches = []
    for _b, t in enumerate(BATCH_TIMES):
        xa, ya = truth_pos(targets, "A", t)
        xb, yb = truth_pos(targets, "B", t)
        batches.append(batch(t, [track(1, t, xa, ya + 250.0, 200, 0), track(2, t, xb, yb - 250.0, -200, 0)]))
    assert ev.evaluate(batches, truth, ev.EvalParams(keep_previous=True)).id_swaps == 0
    # From scratch, both tracks jump to the other aircraft near the crossing and back after.
    assert ev.evaluate(batches, truth, ev.EvalParams(keep_previous=False)).id_swaps == 4


def test_duplicate_track_is_counted():
    targets = {"A": (0.0, 0.0, 200.0, 0.0), "B": (0.0, 30_000.0, 200.0, 0.0)}
    truth = straight_truth(targets, SECONDS)
    batches = []
    for b, t in enumerate(BATCH_TIMES):
        xa, ya = truth_pos(targets, "A", t)
        xb, yb = truth_pos(targets, "B", t)
        trs = [track(1, t, xa + 50, ya), track(2, t, xb, yb)]
        if 10 <= b < 20:
            trs.append(track(5, t, xa + 700, ya - 300, status="coasting" if b % 2 else "confirmed"))
        batches.append(batch(t, trs))
    s = ev.evaluate(batches, truth)
    assert s.duplicate_tracks == 1 and s.duplicate_track_ids == [5]
    assert s.duplicate_tracks_per_time_mean == pytest.approx(10 / 30)
    assert s.false_tracks == 0 and s.targets[0].track_ids == [1]
    # In GOSPA the duplicate is a false track: c^p/2 in each of its 10 batches.
    assert s.gospa_false_mean == pytest.approx(10 / 30 * 2000.0**2 / 2)


def test_false_track_far_from_everything_is_counted():
    targets = {"A": (0.0, 0.0, 200.0, 0.0)}
    truth = straight_truth(targets, SECONDS)
    batches = []
    for b, t in enumerate(BATCH_TIMES):
        trs = [track(1, t, *truth_pos(targets, "A", t))]
        trs.append(track(8, t, 400_000.0, -250_000.0 + 10 * b))
        if b < 10:  # track 1 is far off for 10 of its 30 batches: not a false track
            trs.append(track(9, t, *truth_pos(targets, "A", t)))
            trs[0] = track(1, t, 300_000.0, 0.0)
        batches.append(batch(t, trs))
    s = ev.evaluate(batches, truth, ev.EvalParams(keep_previous=False))
    assert s.false_track_ids == [8] and s.false_tracks == 1
    # Per time: track 8 always, track 1 for 10 batches.
    assert s.false_tracks_per_time_mean == pytest.approx((30 + 10) / 30)
    assert s.gospa_false_tracks_mean == pytest.approx((30 + 10) / 30)
    assert s.gospa_false_mean == pytest.approx((30 + 10) / 30 * 2000.0**2 / 2)
    assert s.gospa_missed_mean == 0
    assert s.targets[0].n_track_ids == 2 and s.targets[0].completeness == 1.0


def test_undetectable_target_neither_missed_nor_false():
    # Target A leaves coverage after 60 s; its track coasts 3 more batches (excused);
    # target B is never detectable and never tracked (not missed).
    targets = {"A": (0.0, 0.0, 200.0, 0.0), "B": (0.0, 50_000.0, 200.0, 0.0)}
    truth = straight_truth(targets, SECONDS, detectable=lambda tid, t: int(tid == "A" and t < T0 + 60))
    batches = []
    for _b, t in enumerate(BATCH_TIMES):
        trs = []
        if t < T0 + 60 + 12:
            trs.append(track(1, t, *truth_pos(targets, "A", t), status="confirmed" if t < T0 + 60 else "coasting"))
        batches.append(batch(t, trs))
    s = ev.evaluate(batches, truth)
    assert s.false_tracks == 0 and s.false_tracks_per_time_mean == 0
    assert s.gospa_mean_m == pytest.approx(0.0, abs=1e-9)
    assert s.missed_targets_per_time_mean == 0
    assert s.n_detectable_targets == 1 and s.completeness_mean == 1.0
    assert s.targets[1].detectable_batches == 0 and math.isnan(s.targets[1].completeness)


# --------------------------------------------------------------------------- end to end


def test_end_to_end_recording_run_and_png(tmp_path, capsys):
    targets = {"A": (-20_000.0, 0.0, 220.0, 10.0), "B": (10_000.0, 15_000.0, -150.0, -90.0)}
    truth_path = tmp_path / "truth.csv"
    with open(truth_path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(ev.TRUTH_COLUMNS)
        for t in SECONDS:
            for tid, (_x0, _y0, vx, vy) in targets.items():
                x, y = truth_pos(targets, tid, t)
                w.writerow([t, tid, "4CA123" if tid == "A" else "", "", 50, 8, 30000, x, y, vx, vy, 0, 1])
    rec_path = tmp_path / "run.rec.gz"
    rng = np.random.default_rng(7)
    with RecordingWriter(rec_path, meta={"test": True}) as rec:
        for b, t in enumerate(BATCH_TIMES):
            trs = []
            for k, tid in enumerate(targets):
                x, y = truth_pos(targets, tid, t)
                n = rng.normal(0, 80, 2)
                trs.append(wire.Track(**track(k + 1, t, x + n[0], y + n[1], targets[tid][2], targets[tid][3])))
            tb = wire.TrackBatch(t=float(t), period=b, tracks=trs, ended=[])
            rec.write(t, "radar/r1/status", b"\x80")  # another key: ignored
            rec.write(t, "fusion/tracks", wire.encode(tb))
    batches = ev.load_tracks(rec_path)
    assert len(batches) == len(BATCH_TIMES) and batches[0]["tracks"][0]["track_id"] == 1
    direct = ev.evaluate(batches, ev.load_truth(truth_path))
    assert 60 < direct.pos_rms_m < 140 and direct.id_swaps == 0 and direct.completeness_mean == 1.0

    parser = argparse.ArgumentParser()
    ev.add_arguments(parser)
    png = tmp_path / "out" / "eval.png"
    args = parser.parse_args(
        [
            "--tracks",
            str(rec_path),
            "--truth",
            str(truth_path),
            "--png",
            str(png),
            "--gospa-c-m",
            "1000",
            "--json",
            str(tmp_path / "scores.json"),
        ]
    )
    assert ev.run(args) == 0
    out = capsys.readouterr().out
    assert "GOSPA mean (c = 1000 m, p = 2, alpha = 2" in out and "position RMS" in out
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert f"{direct.pos_rms_m:.1f}" in out
    import json

    summary = json.loads((tmp_path / "scores.json").read_text())
    assert summary["pos_rms_m"] == pytest.approx(direct.pos_rms_m)
    assert summary["targets"][0]["mode_s"] == "4CA123"
    table = ev.format_table(direct)
    assert "duplicate tracks" in table and "id swaps" in table


def test_truth_turn_rate_is_the_analytic_rate_of_a_circle_across_north():
    """A circle flown at a known rate (right turn, through north, where the heading wraps
    from 359 to 0 degrees) and a straight leg: the rate the scorer splits RMS by is the
    analytic omega = v / r, and 0 on the straight leg."""
    rate_deg_s, speed_mps = 3.0, 200.0
    times = np.arange(0.0, 200.0, 4.0)
    psi = np.radians(300.0 + rate_deg_s * times)  # heading from north, clockwise: crosses 360 at t = 20 s
    vx, vy = speed_mps * np.sin(psi), speed_mps * np.cos(psi)
    straight_vx, straight_vy = np.full_like(times, 150.0), np.full_like(times, -80.0)
    got = ev.truth_turn_rate_deg_s(np.vstack([vx, straight_vx]), np.vstack([vy, straight_vy]), times)
    np.testing.assert_allclose(got[0], rate_deg_s, atol=1e-9)
    np.testing.assert_allclose(got[1], 0.0, atol=1e-9)
    # too slow for a heading: no rate
    slow = ev.truth_turn_rate_deg_s(np.full((1, 5), 1.0), np.full((1, 5), 1.0), np.arange(5.0))
    assert np.isnan(slow).all()


def test_a_track_at_its_own_earlier_time_is_scored_against_the_truth_then():
    """A track of one update is sent where and when it was measured (its ``t`` before the
    batch's, velocity nil). Exactly on the truth at its own time, it scores no error, though
    the aircraft has flown 600 m since; 50 m off it scores 50 m. Its nil velocity is left
    out of the velocity RMS, and it counts for GOSPA and completeness like any track."""
    targets = {"A": (0.0, 0.0, 200.0, 0.0), "B": (0.0, 20_000.0, 0.0, -150.0)}
    truth = straight_truth(targets, SECONDS)
    t_b = BATCH_TIMES[3]
    t_a, t_bb = t_b - 3.0, t_b - 1.5  # measured 3 s and 1.5 s before the batch time
    a = track(1, t_a, *truth_pos(targets, "A", t_a))
    a["vx_mps"] = a["vy_mps"] = None
    bx, by = truth_pos(targets, "B", t_bb)
    b = track(2, t_bb, bx + 30.0, by + 40.0)  # 50 m off the truth at its own time
    b["vx_mps"] = b["vy_mps"] = None
    s = ev.evaluate([batch(t_b, [a, b])], truth, ev.EvalParams(settle_s=0.0))
    assert s.n_pairs == 2 and s.track_ids_per_target_mean == 1.0 and s.completeness_mean == 1.0
    assert s.pos_rms_m == pytest.approx(math.sqrt((0.0 + 50.0**2) / 2), rel=1e-9)
    assert math.isnan(s.vel_rms_mps)  # no velocity to score
    # the same tracks stamped with the batch's time are 600 m and 225 m off: the own time counts
    a2, b2 = dict(a, t=t_b), dict(b, t=t_b)
    s2 = ev.evaluate([batch(t_b, [a2, b2])], truth, ev.EvalParams(settle_s=0.0))
    assert s2.pos_rms_m > 300.0


def test_turn_onset_and_steady_parts_and_the_offset_outside_the_turn():
    """Two aircraft fly straight for 40 s, then turn at 3°/s (one right, one left) for 80 s.
    Their tracks are 10 m ahead in straight flight, 80 m outside the turn in its first 24 s
    and 20 m outside after: the scorer splits the turning RMS into those two parts and
    finds the mean offset outside the turn, both turn directions alike."""
    speed_mps, rate_deg_s, t_turn = 150.0, 3.0, 40.0

    def state(sign, t_rel):
        """Exact position and velocity, heading 30° at first; sign +1 turns right."""
        psi0 = math.radians(30.0)
        w = sign * math.radians(rate_deg_s)
        if t_rel <= t_turn:
            psi, x, y = psi0, speed_mps * math.sin(psi0) * t_rel, speed_mps * math.cos(psi0) * t_rel
        else:
            x0, y0 = speed_mps * math.sin(psi0) * t_turn, speed_mps * math.cos(psi0) * t_turn
            psi = psi0 + w * (t_rel - t_turn)
            x = x0 - speed_mps / w * (math.cos(psi) - math.cos(psi0))
            y = y0 + speed_mps / w * (math.sin(psi) - math.sin(psi0))
        return x, y, speed_mps * math.sin(psi), speed_mps * math.cos(psi)

    origins = {"R": (+1, 0.0), "L": (-1, 60_000.0)}
    cols = {k: [] for k in ("t_s", "target_id", "x_m", "y_m", "vx_mps", "vy_mps", "detectable")}
    for tid, (sign, x_shift) in origins.items():
        for t in SECONDS:
            x, y, vx, vy = state(sign, t - T0)
            for k, v in zip(("t_s", "target_id", "x_m", "y_m", "vx_mps", "vy_mps", "detectable"),
                            (t, tid, x + x_shift, y, vx, vy, 1)):  # fmt: skip
                cols[k].append(v)
    truth = ev.Truth.from_columns(**cols)
    batches = []
    expect_onset, expect_steady, expect_straight = [], [], []
    for t in BATCH_TIMES:
        tracks = []
        for n, (sign, x_shift) in enumerate(origins.values()):
            x, y, vx, vy = state(sign, t - T0)
            ux, uy = vx / speed_mps, vy / speed_mps
            right = np.array([uy, -ux])  # unit vector to the right of the direction of flight
            since_turn = t - T0 - t_turn
            if since_turn < 0:
                d = 10.0 * np.array([ux, uy])  # ahead
                expect_straight.append(10.0)
            else:
                off = 80.0 if since_turn < 24.0 else 20.0
                d = -sign * off * right  # outside: left of a right turn, right of a left turn
                (expect_onset if off == 80.0 else expect_steady).append(off)
            tracks.append(track(n + 1, t, x + x_shift + d[0], y + d[1], vx, vy))
        batches.append(batch(t, tracks))
    s = ev.evaluate(batches, truth, ev.EvalParams(settle_s=0.0))
    # the batch at 40.5 s (0.5 s into the turn) already turns faster than 1.5°/s by central
    # differences, the one at 36.5 s is below the straight-flight threshold: no pair between
    assert s.n_pairs_turning == len(expect_onset) + len(expect_steady) == 2 * 20
    assert s.n_pairs_turn_onset == len(expect_onset) == 2 * 6
    assert s.pos_rms_turn_onset_m == pytest.approx(80.0, abs=1.5)
    assert s.pos_rms_turn_steady_m == pytest.approx(20.0, abs=1.5)
    expect_mean = (sum(expect_onset) + sum(expect_steady)) / (len(expect_onset) + len(expect_steady))
    assert s.turning_outward_mean_m == pytest.approx(expect_mean, abs=1.5)
    assert s.pos_rms_straight_m == pytest.approx(10.0, abs=0.5)
    assert "first 24 s of a turn" in ev.format_table(s)
    # 50 m inside the turn instead: the offset's sign follows
    inside = []
    for t in BATCH_TIMES:
        moved = []
        for n, (sign, x_shift) in enumerate(origins.values()):
            x, y, vx, vy = state(sign, t - T0)
            right = np.array([vy, -vx]) / speed_mps
            d = sign * 50.0 * right if t - T0 >= t_turn else np.zeros(2)
            moved.append(track(n + 1, t, x + x_shift + d[0], y + d[1], vx, vy))
        inside.append(batch(t, moved))
    s_in = ev.evaluate(inside, truth, ev.EvalParams(settle_s=0.0))
    assert s_in.turning_outward_mean_m == pytest.approx(-50.0, abs=1.5)


def test_turn_age_counts_from_the_first_batch_time_of_each_turn():
    times = np.array([0.0, 4.0, 8.0, 12.0, 16.0, 20.0, 24.0])
    rate = np.array(
        [
            [0.0, 0.1, 2.0, 2.0, -2.0, 0.0, 1.0],  # a turn from 8 s (a reversal is one turn), another at 24 s
            [3.0, 3.0, np.nan, 3.0, 3.0, 3.0, 3.0],  # turning from the start; no rate at 8 s ends the run
        ]
    )
    got = ev.turn_age_at(rate, times, 0.3)
    nan = np.nan
    np.testing.assert_array_equal(got[0], [nan, nan, 0.0, 4.0, 8.0, nan, 0.0])
    np.testing.assert_array_equal(got[1], [0.0, 4.0, nan, 0.0, 4.0, 8.0, 12.0])


@pytest.mark.parametrize("suffix", [".rec", ".rec.gz"])
def test_a_recording_cut_short_is_read_to_its_last_whole_record_and_says_so(tmp_path, caplog, suffix):
    """A recorder killed, a copy interrupted: msgpack's reader stopped at the cut without a
    word, and replay, evaluate and clean went on with part of a recording as if whole."""
    import gzip
    import logging

    from radar_fusion.recording import read_recording

    whole = tmp_path / f"whole{suffix}"
    with RecordingWriter(whole) as w:
        for k in range(50):
            w.write(1.7e9 + k, "radar/a/plots", bytes(range(200)))
    raw = gzip.decompress(whole.read_bytes()) if suffix.endswith(".gz") else whole.read_bytes()
    cut = tmp_path / f"cut{suffix}"
    part = raw[: len(raw) - 150]  # inside the last record's payload
    cut.write_bytes(gzip.compress(part) if suffix.endswith(".gz") else part)
    with caplog.at_level(logging.WARNING, logger="radar_fusion.recording"):
        assert len(list(read_recording(whole))) == 50 and not caplog.records
        assert len(list(read_recording(cut))) == 49
    assert len(caplog.records) == 1 and "cut short: 49 whole records read" in caplog.records[0].getMessage()
    bad = tmp_path / "bad.rec"
    with RecordingWriter(bad) as w:
        w.write(1.7e9, "radar/a/plots", b"x")
        w._f.write(w._packer.pack({"not": "a record"}))
    with pytest.raises(ValueError, match="record 2 is not"):
        list(read_recording(bad))


def test_tracks_of_another_plane_or_time_are_not_scored(demo_case):
    """Scores compare positions in the system plane: a daemon whose centre was moved 0.2°
    scored 1,405 m for tracks 17 m from their aircraft, and another scenario's truth gave
    a table of n/a, both with exit 0. Checked on the ground, by latitude and longitude."""
    from radar_fusion.engine import Engine
    from radar_fusion.tools.evaluate import not_comparable
    from radar_fusion.tools.replay import replay_into_engine

    settings, simulation = demo_case
    messages = simulation.messages[:3000]

    def batches(s):
        return [o.track_batch for o in replay_into_engine(Engine(s), messages)]

    truth = simulation.truth
    same = batches(settings)
    assert not_comparable(same, truth) is None
    system = settings.system.model_copy(update={"center_lat": settings.system.center_lat + 0.2})
    moved = batches(settings.model_copy(update={"system": system}))
    assert "system plane is not the truth's" in (not_comparable(moved, truth) or "")
    later = [{**b, "t": b["t"] + 86_400.0} for b in same]
    assert "do not overlap" in (not_comparable(later, truth) or "")
