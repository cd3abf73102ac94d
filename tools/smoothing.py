"""Robust smoothing of recorded flight paths (ADS-B fixes) before they become truth.

ADS-B state vectors repeat stale fixes and carry up to about a second of timing jitter,
so their positions scatter along track by tens of metres (occasionally hundreds). A path
that interpolates them has "accelerations" of 1-2 g between the fixes that no aircraft
flies, and every figure scored against it partly measures that noise. Here each flight
is smoothed instead:

1. repeated stale fixes (the same position reported again) are dropped
   (:func:`drop_stale_fixes`);
2. per axis, in a local plane, a cubic smoothing spline in time is fitted
   (:func:`scipy.interpolate.make_smoothing_spline`, which minimises
   ``sum w_i (y_i - f(t_i))**2 + lam * integral f''(t)**2 dt``), robustly: iteratively
   reweighted, first with Huber then with Tukey bisquare weights of the fix's residual
   over a robust scale (the median residual), so a gross outlier ends with weight 0 and
   does not bend the path (:func:`robust_smoothing_spline`);
3. the truth position is the spline, the truth velocity its derivative.

The smoothing factor comes from the expected fix error and a process noise: the cubic
smoothing spline is the posterior mean (RTS smoother) of a near-constant-velocity model
with white acceleration of spectral density ``q`` observed with noise ``sigma`` per axis
(Wahba 1978), for ``lam = sigma**2 / q``. Defaults: ``sigma`` = 40 m horizontal
(28 m per axis), ``q`` = 5 m^2/s^3 -- a compromise: with fixes 10 s apart, following
a turn entry (a step of several m/s^2) and averaging the jitter pull opposite ways; at
this setting an abrupt 6 m/s^2 turn entry is cut by about 50 m and the jitter is
reduced by about a third (tests/test_smoothing.py).

:func:`second_difference_accel_mps2` gives the acceleration statistics used to show the
result is physically plausible (raw fixes vs smoothed path).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.interpolate import BSpline, make_lsq_spline, make_smoothing_spline

HORIZONTAL_FIX_SIGMA_M = 40.0
"""Expected horizontal RMS error of an ADS-B fix (timing jitter along track)."""
HORIZONTAL_ACCEL_PSD_M2PS3 = 5.0
"""White-acceleration spectral density of the horizontal smoothing model, m^2/s^3."""
VERTICAL_FIX_SIGMA_M = 8.0
"""Expected RMS error of a reported altitude (25 ft quanta plus timing jitter in climbs)."""
VERTICAL_ACCEL_PSD_M2PS3 = 0.5
"""White-acceleration spectral density of the vertical smoothing model, m^2/s^3."""
STALE_TOLERANCE_M = 1.0
"""A fix within this distance of the previous kept fix repeats a stale position."""

_HUBER_K = 1.345
_BISQUARE_C = 4.685
_CHI_MEDIAN = {1: 0.6744897501960817, 2: 1.1774100225154747, 3: 1.5381722544550522}
"""Median of the chi distribution with d degrees of freedom (the norm of a standard normal d-vector)."""


def smoothing_lambda(fix_sigma_m: float, accel_psd_m2ps3: float, n_axes: int = 1) -> float:
    """``lam`` of :func:`make_smoothing_spline` for a fix error ``fix_sigma_m`` (RMS over
    ``n_axes`` axes together) and white acceleration ``accel_psd_m2ps3`` per axis."""
    return float(fix_sigma_m) ** 2 / n_axes / float(accel_psd_m2ps3)


def drop_stale_fixes(t_s: np.ndarray, x_m: np.ndarray, y_m: np.ndarray, tol_m: float = STALE_TOLERANCE_M) -> np.ndarray:
    """Mask of the fixes to keep: times strictly increasing, and no fix within ``tol_m``
    of the previous kept fix (a repeated, stale position; a moving aircraft has moved).

    A run of repeats is dropped after its first fix (the first report of the position is
    the fresh one)."""
    t, x, y = (np.asarray(a, float) for a in (t_s, x_m, y_m))
    keep = np.zeros(t.shape[0], bool)
    last = -1
    for i in range(t.shape[0]):
        if last >= 0 and (t[i] <= t[last] or np.hypot(x[i] - x[last], y[i] - y[last]) <= tol_m):
            continue
        keep[i] = True
        last = i
    return keep


def _fit(t: np.ndarray, values: np.ndarray, w: np.ndarray, lam: float) -> BSpline:
    if t.shape[0] >= 5:
        return make_smoothing_spline(t, values, w=np.maximum(w, 1e-9), lam=lam)
    # too few fixes for a cubic smoothing spline: a weighted straight line
    knots = np.r_[t[0], t[0], t[-1], t[-1]]
    return make_lsq_spline(t, values, knots, k=1, w=np.maximum(w, 1e-9))


def robust_smoothing_spline(
    t_s: np.ndarray,
    values: np.ndarray,
    lam: float,
    scale_floor: float,
    huber_iterations: int = 8,
    max_bisquare_iterations: int = 10,
    max_run: int = 2,
) -> tuple[BSpline, np.ndarray]:
    """Robust cubic smoothing spline of ``values`` (shape (n,) or (n, d)) in ``t_s``.

    Iteratively reweighted: the residual of a fix is the norm over the d axes; its scale
    is the median residual over the median of a chi_d variable (floored at
    ``scale_floor``: the fix errors are heavy-tailed, and a scale below the expected
    error would reject ordinary jitter); Huber iterations (k = 1.345, convex: a unique
    fit that follows the manoeuvres and that a single outlier cannot capture), then
    Tukey bisquare weights (c = 4.685) until they settle, which reject gross outliers
    (weight 0) -- except in runs of more than ``max_run`` consecutive fixes, which keep
    their Huber weights. Returns the spline and the final weights (0 = rejected)."""
    t = np.asarray(t_s, float)
    v = np.asarray(values, float)
    vv = v.reshape(t.shape[0], -1)
    d = vv.shape[1]
    w = np.ones(t.shape[0])
    spline = _fit(t, v, w, lam)
    for it in range(huber_iterations + max_bisquare_iterations):
        r = np.linalg.norm(vv - np.asarray(spline(t)).reshape(vv.shape), axis=1)
        scale = max(float(np.median(r)) / _CHI_MEDIAN.get(d, float(np.sqrt(d))), float(scale_floor))
        huber = np.minimum(1.0, _HUBER_K * scale / np.maximum(r, 1e-12))
        if it < huber_iterations:
            w_new = huber
        else:
            u = r / (_BISQUARE_C * scale)
            w_new = np.where(u < 1.0, (1.0 - u * u) ** 2, 0.0)
            # a run of consecutive rejections is a manoeuvre the fit has not followed
            # (rejecting it would cut the corner), not independent gross errors
            in_run = _in_runs(w_new == 0.0, max_run)
            w_new[in_run] = huber[in_run]
        converged = np.max(np.abs(w_new - w)) < 1e-3
        w = w_new
        spline = _fit(t, v, w, lam)
        if converged and it >= huber_iterations:
            break
    return spline, w


def _in_runs(flag: np.ndarray, max_run: int) -> np.ndarray:
    """True where ``flag`` is part of a run of more than ``max_run`` consecutive Trues."""
    f = np.r_[False, flag, False].astype(np.int8)
    edges = np.diff(f)
    starts, stops = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)
    out = np.zeros(flag.shape[0], bool)
    for a, b in zip(starts.tolist(), stops.tolist()):
        if b - a > max_run:
            out[a:b] = True
    return out


def second_difference_accel_mps2(t_s: np.ndarray, *axes_m: np.ndarray) -> np.ndarray:
    """Magnitude of the second-difference acceleration at the interior samples:
    ``2 ((p[i+1] - p[i]) / dt2 - (p[i] - p[i-1]) / dt1) / (dt1 + dt2)``, over the axes."""
    t = np.asarray(t_s, float)
    if t.shape[0] < 3:
        return np.zeros(0)
    dt1, dt2 = np.diff(t)[:-1], np.diff(t)[1:]
    sq = np.zeros(t.shape[0] - 2)
    for p in axes_m:
        p = np.asarray(p, float)
        a = 2.0 * ((p[2:] - p[1:-1]) / dt2 - (p[1:-1] - p[:-2]) / dt1) / (dt1 + dt2)
        sq += a * a
    return np.sqrt(sq)


@dataclass
class SmoothedFlight:
    """A flight smoothed in a local plane: the kept fixes, their robust weights and the splines."""

    t_s: np.ndarray
    """times of the kept fixes (stale repeats dropped)"""
    x_m: np.ndarray
    y_m: np.ndarray
    z_m: np.ndarray
    weight_xy: np.ndarray
    """final robust weight of each kept fix horizontally (0 = rejected as an outlier)"""
    weight_z: np.ndarray
    n_stale: int
    """number of fixes dropped as stale repeats"""
    spline_xy: BSpline
    spline_z: BSpline

    def position(self, t_s: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Smoothed (x_m, y_m, z_m) at ``t_s``."""
        t = np.asarray(t_s, float)
        xy = np.asarray(self.spline_xy(t))
        return xy[..., 0], xy[..., 1], np.asarray(self.spline_z(t))

    def velocity(self, t_s: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Derivative of the smoothed path (vx_mps, vy_mps, vz_mps) at ``t_s``."""
        t = np.asarray(t_s, float)
        vxy = np.asarray(self.spline_xy(t, 1))
        return vxy[..., 0], vxy[..., 1], np.asarray(self.spline_z(t, 1))

    def residual_m(self) -> np.ndarray:
        """Horizontal distance of each kept fix from the smoothed path."""
        x, y, _ = self.position(self.t_s)
        return np.hypot(self.x_m - x, self.y_m - y)


def smooth_flight(
    t_s: np.ndarray,
    x_m: np.ndarray,
    y_m: np.ndarray,
    z_m: np.ndarray,
    fix_sigma_m: float = HORIZONTAL_FIX_SIGMA_M,
    accel_psd_m2ps3: float = HORIZONTAL_ACCEL_PSD_M2PS3,
    vertical_sigma_m: float = VERTICAL_FIX_SIGMA_M,
    vertical_accel_psd_m2ps3: float = VERTICAL_ACCEL_PSD_M2PS3,
) -> SmoothedFlight:
    """Drop stale repeats, then fit the robust smoothing splines of (x, y) together (shared
    weights: a bad fix is bad in both axes) and of altitude ``z_m``, in metres."""
    t, x, y, z = (np.asarray(a, float) for a in (t_s, x_m, y_m, z_m))
    keep = drop_stale_fixes(t, x, y)
    t, x, y, z = t[keep], x[keep], y[keep], z[keep]
    if t.shape[0] < 2:
        raise ValueError("a flight needs at least two distinct fixes to smooth")
    lam_xy = smoothing_lambda(fix_sigma_m, accel_psd_m2ps3, n_axes=2)
    spline_xy, w_xy = robust_smoothing_spline(t, np.column_stack([x, y]), lam_xy, scale_floor=fix_sigma_m)
    lam_z = smoothing_lambda(vertical_sigma_m, vertical_accel_psd_m2ps3)
    spline_z, w_z = robust_smoothing_spline(t, z, lam_z, scale_floor=vertical_sigma_m)
    return SmoothedFlight(t, x, y, z, w_xy, w_z, int((~keep).sum()), spline_xy, spline_z)
