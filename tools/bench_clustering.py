"""Benchmark of radar_fusion.tracking.clustering.cluster_plots (a benchmark, not a test).

Scenario per period: targets at random positions in a 400 km square with random headings
and speeds 100-250 m/s; radars at random positions in the square, each covering a disc
(default 120 km, so ~3 radars see a target with 10 radars); one plot per radar per
covered target with Pd 0.9, detection time uniform in the 4 s period, polar noise
(σ_range 50 m, σ_azimuth 0.08°) turned into a 2×2 covariance; 2 % false plots per radar;
70 % of targets carry a Mode S address, 90 % a Mode 3/A code.  Steady state: every target
has a track predicted to t_ref with position error σ 150 m and velocity error σ 10 m/s.
With ``--no-tracks`` the period has no tracks (Shu's case 3, first period).

Prints, per (targets, radars): plots per period, clustering time p50/p99 in ms, and the
fraction of target plots put in the cluster of their own target.

    python tools/bench_clustering.py [--periods 20] [--no-tracks] [--coverage-km 120]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from radar_fusion.tracking.clustering import ClusteringParams, cluster_plots

SQUARE_M = 400_000.0
PERIOD_S = 4.0
SIGMA_RANGE_M = 50.0
SIGMA_AZ_RAD = np.deg2rad(0.08)
PD = 0.9
FALSE_FRACTION = 0.02


def make_period(rng, n_targets, n_radars, coverage_m, with_tracks=True):
    """One period's plots and tracks; returns (plot arrays, track arrays, truth, t_ref)."""
    t_ref = 1000.0
    pos = rng.uniform(0.0, SQUARE_M, size=(n_targets, 2))
    heading = rng.uniform(0.0, 2 * np.pi, n_targets)
    speed = rng.uniform(100.0, 250.0, n_targets)
    vel = np.stack([speed * np.sin(heading), speed * np.cos(heading)], axis=1)
    mode_s = np.where(rng.random(n_targets) < 0.7, rng.permutation(n_targets) + 0x400000, -1)
    mode3a = np.where(rng.random(n_targets) < 0.9, rng.integers(0, 4096, n_targets), -1)
    radar_xy = rng.uniform(0.0, SQUARE_M, size=(n_radars, 2))

    xy, cov, t, rad, truth = [], [], [], [], []
    for r in range(n_radars):
        d = np.hypot(*(pos - radar_xy[r]).T)
        seen = np.flatnonzero((d < coverage_m) & (rng.random(n_targets) < PD))
        n_false = rng.poisson(FALSE_FRACTION * max(seen.size, 1))
        tp = t_ref - rng.uniform(0.0, PERIOD_S, seen.size + n_false)
        true_xy = pos[seen] - vel[seen] * (t_ref - tp[: seen.size, None])
        ang = rng.uniform(0, 2 * np.pi, n_false)
        rr = coverage_m * np.sqrt(rng.random(n_false))
        false_xy = radar_xy[r] + np.stack([rr * np.sin(ang), rr * np.cos(ang)], axis=1)
        p = np.concatenate([true_xy, false_xy])
        rel = p - radar_xy[r]
        rng_m = np.maximum(np.hypot(rel[:, 0], rel[:, 1]), 1000.0)
        az = np.arctan2(rel[:, 0], rel[:, 1])
        # Polar covariance rotated to x/y: radial unit (sin az, cos az), cross (cos az, -sin az).
        u = np.stack([np.sin(az), np.cos(az)], axis=1)
        w = np.stack([np.cos(az), -np.sin(az)], axis=1)
        s_cross = rng_m * SIGMA_AZ_RAD
        c = (SIGMA_RANGE_M**2) * u[:, :, None] * u[:, None, :] + (s_cross**2)[:, None, None] * w[:, :, None] * w[
            :, None, :
        ]
        noise = (
            rng.normal(size=(p.shape[0], 1)) * SIGMA_RANGE_M * u
            + rng.normal(size=(p.shape[0], 1)) * s_cross[:, None] * w
        )
        xy.append(p + noise)
        cov.append(c)
        t.append(tp)
        rad.append(np.full(p.shape[0], r))
        truth.append(np.concatenate([seen, np.full(n_false, -1)]))
    xy = np.concatenate(xy)
    cov = np.concatenate(cov)
    t = np.concatenate(t)
    rad = np.concatenate(rad)
    truth = np.concatenate(truth)
    is_true = truth >= 0
    p_ms = np.full(xy.shape[0], -1, dtype=np.int64)
    p_3a = np.full(xy.shape[0], -1, dtype=np.int64)
    p_ms[is_true] = mode_s[truth[is_true]]
    p_3a[is_true] = mode3a[truth[is_true]]

    if with_tracks:
        n = n_targets
        t_xy = pos + rng.normal(scale=150.0, size=(n, 2))
        t_v = vel + rng.normal(scale=10.0, size=(n, 2))
        t_cp = np.broadcast_to(150.0**2 * np.eye(2), (n, 2, 2)).copy()
        t_cv = np.broadcast_to(15.0**2 * np.eye(2), (n, 2, 2)).copy()
        t_ms, t_3a = mode_s.copy(), mode3a.copy()
    else:
        t_xy = np.zeros((0, 2))
        t_v = np.zeros((0, 2))
        t_cp = np.zeros((0, 2, 2))
        t_cv = np.zeros((0, 2, 2))
        t_ms = np.zeros(0, dtype=np.int64)
        t_3a = np.zeros(0, dtype=np.int64)
    plots = (xy, cov, t, rad, p_ms, p_3a)
    tracks = (t_xy, t_v, t_cp, t_cv, t_ms, t_3a)
    return plots, tracks, truth, t_ref


def score(result, truth, with_tracks):
    """Fraction of target plots in their own target's cluster."""
    is_true = truth >= 0
    lab = result.labels
    if with_tracks:
        ok = lab[is_true] >= 0
        got = np.full(is_true.sum(), -2)
        got[ok] = result.cluster_track[lab[is_true][ok]]
        return float(np.mean(got == truth[is_true]))
    # No tracks: a plot is right if its cluster holds plots of its target only and all of them.
    tl = truth[is_true]
    ll = lab[is_true]
    used = ll >= 0
    pairs = np.unique(np.stack([ll[used], tl[used]], axis=1), axis=0)
    targets_per_label = np.bincount(pairs[:, 0], minlength=max(int(lab.max()) + 1, 1))
    labels_per_target = np.bincount(pairs[:, 1], minlength=int(truth.max()) + 1)
    right = np.zeros(tl.size, dtype=bool)
    right[used] = (targets_per_label[ll[used]] == 1) & (labels_per_target[tl[used]] == 1)
    return float(np.mean(right))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--periods", type=int, default=20)
    ap.add_argument("--coverage-km", type=float, default=120.0)
    ap.add_argument("--no-tracks", action="store_true")
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args(argv)
    rng = np.random.default_rng(args.seed)
    params = ClusteringParams()
    with_tracks = not args.no_tracks
    print(
        f"clustering benchmark: {'steady state (tracks)' if with_tracks else 'no tracks (case 3)'}, "
        f"coverage {args.coverage_km:.0f} km, {args.periods} periods per row"
    )
    print(f"{'targets':>8} {'radars':>6} {'plots':>7} {'p50 ms':>8} {'p99 ms':>8} {'correct':>8} {'iters':>5}")
    for n_targets in (100, 1000, 4000):
        for n_radars in (3, 10, 30):
            times, fracs, n_plots, iters = [], [], [], []
            for k in range(args.periods + 1):
                plots, tracks, truth, t_ref = make_period(rng, n_targets, n_radars, args.coverage_km * 1e3, with_tracks)
                t0 = time.perf_counter()
                res = cluster_plots(*plots, *tracks, t_ref, params)
                dt = time.perf_counter() - t0
                if k == 0:
                    continue  # warm-up
                times.append(dt * 1e3)
                fracs.append(score(res, truth, with_tracks))
                n_plots.append(plots[0].shape[0])
                iters.append(res.n_iterations)
            print(
                f"{n_targets:>8} {n_radars:>6} {int(np.mean(n_plots)):>7} "
                f"{np.percentile(times, 50):>8.2f} {np.percentile(times, 99):>8.2f} "
                f"{np.mean(fracs):>8.4f} {max(iters):>5}"
            )


if __name__ == "__main__":
    main()
