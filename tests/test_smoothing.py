"""Robust smoothing of ADS-B fixes into truth (tools/smoothing.py, tools/simulate/adsb.py).

The synthetic tests know the true path in closed form (heading piecewise linear in time,
position by fine numerical integration); the real-data tests recompute residuals and
accelerations from the JSON table and the targets' paths with pyproj, independently of
the code under test.
"""

from __future__ import annotations

import gzip
import json

import numpy as np
import pyproj
import pytest
from scipy.interpolate import CubicSpline

from radar_fusion.tools import smoothing
from radar_fusion.tools.simulate import adsb

SPEED_MPS = 230.0
FIX_PERIOD_S = 10.0
JITTER_SIGMA_S = 0.25
"""Timing jitter of the synthetic fixes: normal, clipped to +-1 s (the along-track error
is SPEED_MPS * JITTER_SIGMA_S = 57.5 m RMS, as in the real table)."""
# (duration_s, turn rate deg/s): straight, a 1.5 deg/s turn (an airliner at 25 deg of bank,
# 6 m/s^2), straight, a turn back, straight
LEGS = ((300.0, 0.0), (60.0, 1.5), (200.0, 0.0), (40.0, -1.5), (300.0, 0.0))


def _known_path():
    """Fine grid of the true state: heading piecewise linear, position by trapezoid integration."""
    dt_s = 0.01
    t = np.arange(0.0, sum(d for d, _ in LEGS) + dt_s / 2, dt_s)
    rate = np.zeros_like(t)
    t0 = 0.0
    for d, r in LEGS:
        rate[(t >= t0) & (t < t0 + d)] = np.radians(r)
        t0 += d
    psi = np.radians(60.0) + np.concatenate([[0.0], np.cumsum(0.5 * (rate[1:] + rate[:-1]) * dt_s)])
    vx, vy = SPEED_MPS * np.sin(psi), SPEED_MPS * np.cos(psi)
    x = np.concatenate([[0.0], np.cumsum(0.5 * (vx[1:] + vx[:-1]) * dt_s)])
    y = np.concatenate([[0.0], np.cumsum(0.5 * (vy[1:] + vy[:-1]) * dt_s)])
    z = 9000.0 + 5.0 * t  # a 5 m/s (~1,000 ft/min) climb
    return t, x, y, z, vx, vy


def _noisy_fixes(seed: int):
    """Fixes every 10 s: the true position at a jittered time, 4 stale repeats, one 2 km outlier."""
    t, x, y, z, _, _ = _known_path()
    rng = np.random.default_rng(seed)
    tf = np.arange(0.0, t[-1] + 1e-9, FIX_PERIOD_S)
    tj = np.clip(tf + np.clip(rng.normal(0.0, JITTER_SIGMA_S, tf.size), -1.0, 1.0), 0.0, t[-1])
    fx, fy, fz = np.interp(tj, t, x), np.interp(tj, t, y), np.interp(tj, t, z)
    fz = np.round(fz / (25 * 0.3048)) * (25 * 0.3048)  # 25 ft quanta
    stale = np.array([7, 25, 40, 80])  # the previous position reported again
    fx[stale], fy[stale], fz[stale] = fx[stale - 1], fy[stale - 1], fz[stale - 1]
    outlier = 55
    fx[outlier] += 2000.0
    return tf, fx, fy, fz, stale, outlier


def test_second_difference_accel_is_exact_on_a_parabola():
    t = np.array([0.0, 1.0, 3.5, 4.0, 10.0, 12.5])
    ax, ay = 1.5, -2.0  # p = p0 + v t + a t^2 / 2: any three points give a exactly
    x = 3.0 + 100.0 * t + 0.5 * ax * t**2
    y = -7.0 + 20.0 * t + 0.5 * ay * t**2
    a = smoothing.second_difference_accel_mps2(t, x, y)
    np.testing.assert_allclose(a, np.full(4, np.hypot(ax, ay)), rtol=1e-9)


def test_stale_repeats_and_non_increasing_times_are_dropped():
    t = np.array([0.0, 10.0, 20.0, 30.0, 30.0, 40.0, 50.0])
    x = np.array([0.0, 2300.0, 2300.0, 6900.0, 7000.0, 9200.0, 9200.6])
    y = np.zeros_like(x)
    # 20 s repeats the 10 s position, 50 s the 40 s one (within 1 m); the second 30 s fix
    # is not later than the first
    expected = np.array([True, True, False, True, False, True, False])
    np.testing.assert_array_equal(smoothing.drop_stale_fixes(t, x, y), expected)


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_smoothed_path_follows_the_known_motion(seed):
    t, x, y, z, vx, vy = _known_path()
    tf, fx, fy, fz, stale, outlier = _noisy_fixes(seed)
    flight = smoothing.smooth_flight(tf, fx, fy, fz)
    # the four stale repeats are gone, the outlier is rejected
    assert flight.n_stale == stale.size
    assert not np.isin(tf[stale], flight.t_s).any()
    assert flight.weight_xy[np.searchsorted(flight.t_s, tf[outlier])] == 0.0

    # scored every second away from the ends (a smoother has no data beyond them)
    q = np.arange(30.0, t[-1] - 30.0, 1.0)
    kx, ky, kz = np.interp(q, t, x), np.interp(q, t, y), np.interp(q, t, z)
    kvx, kvy = np.interp(q, t, vx), np.interp(q, t, vy)
    sx, sy, sz = flight.position(q)
    svx, svy, _ = flight.velocity(q)
    err_m = np.hypot(sx - kx, sy - ky)
    fix_error_m = SPEED_MPS * JITTER_SIGMA_S  # 57.5 m RMS along track per fix
    # 10 s fixes leave little room between following a 6 m/s^2 turn and averaging the
    # jitter out: the smoothed path is better than a single fix, never off by more than
    # three fix errors, and the 2 km outlier moves it by less than a tenth of that
    assert np.sqrt(np.mean(err_m**2)) < fix_error_m
    assert err_m.max() < 3.0 * fix_error_m
    near_outlier = np.abs(q - tf[outlier]) <= 20.0
    assert err_m[near_outlier].max() < 0.1 * 2000.0
    # velocity from the derivative: within 2.5 % of the speed RMS, 12 % at worst (the
    # chord speed between two fixes scatters by 57.5 * sqrt(2) / 10 s = 8 m/s = 3.5 %)
    verr_mps = np.hypot(svx - kvx, svy - kvy)
    assert np.sqrt(np.mean(verr_mps**2)) < 0.025 * SPEED_MPS
    assert verr_mps.max() < 0.12 * SPEED_MPS
    # altitude: within the 25 ft quantum (7.6 m)
    assert np.abs(sz - kz).max() < 25 * 0.3048

    # an interpolating spline through the same fixes (the truth before) is much worse
    keep = np.setdiff1d(np.arange(tf.size), stale)
    old = CubicSpline(tf[keep], np.column_stack([fx[keep], fy[keep]]))(q)
    old_err_m = np.hypot(old[:, 0] - kx, old[:, 1] - ky)
    assert np.sqrt(np.mean(err_m**2)) < 0.5 * np.sqrt(np.mean(old_err_m**2))


def test_clean_fixes_are_reproduced():
    """Without jitter the smoothing must not distort the path (the turn included)."""
    t, x, y, z, _, _ = _known_path()
    tf = np.arange(0.0, t[-1] + 1e-9, FIX_PERIOD_S)
    flight = smoothing.smooth_flight(tf, np.interp(tf, t, x), np.interp(tf, t, y), np.interp(tf, t, z))
    assert (flight.weight_xy > 0).all()
    q = np.arange(30.0, t[-1] - 30.0, 1.0)
    sx, sy, _ = flight.position(q)
    # a 1.5 deg/s turn bends the path by v * w * dt^2 / 8 = 7.5 m between 10 s fixes
    # and starts with an abrupt 6 m/s^2 step in acceleration, which the smoothing spreads
    # over several seconds (about 50 m of corner cut); elsewhere it is exact
    assert np.hypot(sx - np.interp(q, t, x), sy - np.interp(q, t, y)).max() < 60.0


# --------------------------------------------------------------------------- real flights

START_T_S = adsb.ADSB_DEFAULT_START_T_S
DURATION_S = 600.0
N_AIRCRAFT = 30


@pytest.fixture
def real(shared_data):
    with gzip.open(shared_data / "adsb" / "switzerland_2018-08-01.json.gz", "rt") as f:
        rows = json.load(f)
    fixes: dict[str, list[tuple[float, float, float]]] = {}
    for r in rows:
        if r.get("latitude") is None or r.get("longitude") is None:
            continue
        fixes.setdefault(r["icao24"], []).append((r["timestamp"] / 1000.0, r["latitude"], r["longitude"]))
    targets = adsb.adsb_targets(START_T_S, DURATION_S, max_aircraft=N_AIRCRAFT)
    return fixes, targets


def test_real_flights_residual_and_accelerations(real):
    fixes, targets = real
    geod = pyproj.Geod(ellps="WGS84")
    residual_m, a_raw, a_smooth = [], [], []
    for tgt in targets:
        p = tgt.path
        f = np.array(sorted(fixes[tgt.target_id]))
        f = f[(f[:, 0] >= p.t_s[0]) & (f[:, 0] <= p.t_s[-1])]
        # the path is sampled every second from a fix time: the fixes' times are on it
        j = np.searchsorted(p.t_s, f[:, 0])
        on = np.abs(p.t_s[np.clip(j, 0, p.t_s.size - 1)] - f[:, 0]) < 1e-6
        f, j = f[on], j[on]
        _, _, d = geod.inv(f[:, 2], f[:, 1], p.lon_deg[j], p.lat_deg[j])
        residual_m.append(d)
        # accelerations in an azimuthal equidistant plane at the flight (pyproj, not the code's plane)
        proj = pyproj.Proj(proj="aeqd", lat_0=float(p.lat_deg.mean()), lon_0=float(p.lon_deg.mean()), ellps="WGS84")
        rx, ry = proj(f[:, 2], f[:, 1])
        moved = np.r_[True, np.hypot(np.diff(rx), np.diff(ry)) > 1.0]  # stale repeats are no acceleration
        a_raw.append(smoothing.second_difference_accel_mps2(f[moved, 0], rx[moved], ry[moved]))
        sx, sy = proj(p.lon_deg, p.lat_deg)
        a_smooth.append(smoothing.second_difference_accel_mps2(p.t_s, sx, sy))
    r = np.concatenate(residual_m)
    assert r.size > 1000
    inliers = r[r < 200.0]
    # most fixes lie within 200 m of the path, and those scatter about it by 20-60 m RMS
    assert inliers.size > 0.9 * r.size
    assert 20.0 < np.sqrt(np.mean(inliers**2)) < 60.0
    p95_raw = np.percentile(np.concatenate(a_raw), 95)
    p95_smooth = np.percentile(np.concatenate(a_smooth), 95)
    assert p95_smooth < 3.0  # physically plausible: an airliner in a 25 deg bank pulls 4.6 m/s^2
    assert p95_smooth < p95_raw / 5.0

    # the bench's figures are the same quantities
    stats = adsb.adsb_smoothing_stats(START_T_S, DURATION_S, max_aircraft=N_AIRCRAFT)
    assert stats["flights"] == len(targets)
    assert stats["residual_median_m"] == pytest.approx(np.median(r), rel=0.1)
    assert stats["accel_p95_smoothed_1s_mps2"] == pytest.approx(p95_smooth, rel=0.1)
