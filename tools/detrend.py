"""Robust trend of a radar track in the radar plane, and the range / azimuth residuals
of its plots about it: what ``radar-fusion clean`` analyses instead of the raw series
(why: the :mod:`radar_fusion.tools.clean` docstring). The robust z-score that confirms
a gross error is here too."""

from __future__ import annotations

import numpy as np


def robust_trend_xy(
    t_s: np.ndarray, x_m: np.ndarray, y_m: np.ndarray, neighbours: int, iterations: int = 2
) -> tuple[np.ndarray, np.ndarray]:
    """Robust local-quadratic trend (LOWESS, Cleveland 1979) of a radar-plane path x(t), y(t).

    For each plot i, x and y are fitted by weighted least squares with a quadratic in time
    over its ``neighbours`` nearest plots in time, tricube weights in |t_j - t_i| / h_i
    (h_i: the distance to the furthest of them), times a robustness weight per plot, the
    bisquare (1 - (d_j / 6 median d)^2)^2 of its 2-D residual d_j. The first residual of a
    plot is the smaller of its distances to :func:`_repeated_median_line` (breakdown 50 %:
    a run of wild plots shorter than half the neighbourhood cannot pull it, where an
    unweighted quadratic bends to it) and to the unweighted quadratic (which follows a
    turn that the line cuts); then ``iterations`` + 1 rounds of fit and re-weighting.
    t_s must be sorted. Returns the trend at each plot's time.
    """
    t = np.asarray(t_s, float)
    n = t.size
    q = max(3, min(n, neighbours))
    # Band of candidate neighbours: the q nearest in time lie within q indices either side.
    j = np.arange(n)[:, None] + np.arange(-q + 1, q)[None, :]
    valid = (j >= 0) & (j < n)
    j = np.clip(j, 0, n - 1)
    dt = np.where(valid, t[j] - t[:, None], np.inf)
    h = np.partition(np.abs(dt), q - 1, axis=1)[:, q - 1]
    h = np.where(np.isfinite(h) & (h > 0), h * 1.0001, 1.0)
    u = np.where(valid, dt / h[:, None], 0.0)
    base = np.where(valid, np.clip(1.0 - np.abs(u) ** 3, 0.0, None) ** 3, 0.0)
    powers = np.stack((np.ones_like(u), u, u * u), axis=2)  # (n, band, 3)
    xy = np.stack((x_m, y_m), axis=1)[j]  # (n, band, 2)
    # Starting residual: the smaller of the distances to the repeated-median line (not
    # pulled by a wild run) and to the unweighted quadratic (follows a turn).
    line = np.column_stack((_repeated_median_line(t, x_m, q), _repeated_median_line(t, y_m, q)))
    a = np.einsum("ij,ijk,ijl->ikl", base, powers, powers) + 1e-9 * np.eye(3)
    plain = np.linalg.solve(a, np.einsum("ij,ijk,ijc->ikc", base, powers, xy))[:, 0, :]
    plain = np.where(np.isfinite(plain), plain, line)
    trend = line
    for it in range(iterations + 1):
        d = np.hypot(x_m - trend[:, 0], y_m - trend[:, 1])
        if it == 0:
            d = np.minimum(d, np.hypot(x_m - plain[:, 0], y_m - plain[:, 1]))
        scale = 6.0 * float(np.median(d))
        robust = np.clip(1.0 - (d / scale) ** 2, 0.0, None) ** 2 if scale > 0 else np.ones(n)
        w = base * robust[j]
        a = np.einsum("ij,ijk,ijl->ikl", w, powers, powers) + 1e-9 * np.eye(3)
        b = np.einsum("ij,ijk,ijc->ikc", w, powers, xy)
        fit = np.linalg.solve(a, b)[:, 0, :]
        ok = np.isfinite(fit).all(axis=1) & (w.sum(axis=1) > 0)
        trend = np.where(ok[:, None], fit, trend)
    return trend[:, 0], trend[:, 1]


def _repeated_median_line(t_s: np.ndarray, s: np.ndarray, q: int) -> np.ndarray:
    """Siegel's repeated-median line through the q plots around each plot, at its time.

    Window of plot i: q consecutive plots centred on i (shifted inside the series at its
    ends). slope = median_j median_k (s_k - s_j) / (t_k - t_j); level at t_i = median_j of
    s_j - slope (t_j - t_i). Plots at equal times give no slope and are skipped.
    """
    n = s.size
    start = np.clip(np.arange(n) - q // 2, 0, n - q)
    idx = start[:, None] + np.arange(q)[None, :]  # (n, q)
    tw = t_s[idx] - t_s[:, None]
    sw = s[idx]
    dtt = tw[:, None, :] - tw[:, :, None]
    with np.errstate(divide="ignore", invalid="ignore"):
        pair = np.where(dtt != 0.0, (sw[:, None, :] - sw[:, :, None]) / dtt, np.nan)
    slope = _nanmedian_last(_nanmedian_last(pair))
    slope = np.where(np.isfinite(slope), slope, 0.0)
    return np.median(sw - slope[:, None] * tw, axis=1)


def _nanmedian_last(a: np.ndarray) -> np.ndarray:
    """Median over the last axis ignoring NaN (NaN where a row has none); np.nanmedian
    goes through masked arrays and is ~20x slower on many short rows."""
    srt = np.sort(a, axis=-1)  # NaN sort last
    count = (~np.isnan(a)).sum(axis=-1, keepdims=True)
    lo = np.take_along_axis(srt, np.maximum(count - 1, 0) // 2, axis=-1)  # equal for odd counts
    hi = np.take_along_axis(srt, np.minimum(count // 2, a.shape[-1] - 1), axis=-1)
    return np.where(count > 0, 0.5 * (lo + hi), np.nan)[..., 0]


def polar_residuals(
    t_s: np.ndarray, range_m: np.ndarray, azimuth_deg: np.ndarray, neighbours: int
) -> tuple[np.ndarray, np.ndarray]:
    """Range (m) and azimuth (deg) of each plot minus those of the robust radar-plane trend."""
    az = np.deg2rad(azimuth_deg)
    x, y = range_m * np.sin(az), range_m * np.cos(az)
    xt, yt = robust_trend_xy(t_s, x, y, neighbours)
    range_res = range_m - np.hypot(xt, yt)
    az_res = (azimuth_deg - np.rad2deg(np.arctan2(xt, yt)) + 180.0) % 360.0 - 180.0
    return range_res, az_res


def robust_z(s: np.ndarray) -> np.ndarray:
    """|s - median| / (1.4826 MAD): deviation in robust standard deviations (inf when MAD = 0)."""
    dev = np.abs(s - np.median(s))
    scale = 1.4826 * float(np.median(dev))
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(dev > 0, dev / scale, 0.0) if scale > 0 else np.where(dev > 0, np.inf, 0.0)
