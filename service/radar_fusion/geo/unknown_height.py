"""Plots without a height: the ground ranges, and their moments, over every possible height.

A primary plot has no Mode C: its slant range fixes the target on a circle in the radar's
vertical plane, and the ground range depends on the height. Over an unknown height
between MIN_UNKNOWN_ALTITUDE_M and MAX_UNKNOWN_ALTITUDE_M (the ground to FL450) the
ground range spans an interval; :func:`ground_range_for_unknown_height` gives its exact
mean and variance (a uniform height, integrated by Gauss-Legendre), and
:func:`polar_to_plane_unknown_height` the plane position and covariance that follow, for
a plot no track can lend a height to (tracking/primary_height.py). Geometry as in
coordinates.py: the site's Gaussian sphere.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import numpy as np
from numpy.typing import NDArray

from .coordinates import (
    MIN_CROSS_RANGE_VAR_M2,
    RadarSites,
    SystemPlane,
    mark_unconverted,
    radial_to_plane,
    slant_to_ground_range,
)
from .units import M_PER_FL

__all__ = [
    "MAX_UNKNOWN_ALTITUDE_M",
    "MIN_UNKNOWN_ALTITUDE_M",
    "GroundRangeInterval",
    "UnknownHeightPlots",
    "ground_range_for_unknown_height",
    "polar_to_plane_unknown_height",
    "unknown_height_plots",
]

MIN_UNKNOWN_ALTITUDE_M: float = 0.0
"""Lowest height of a plot without Mode C: the ground at sea level (0 ft). Heights are
above the ellipsoid; the geoid is within ~100 m of it in Europe, which the interval's
~14 km width makes irrelevant."""
MAX_UNKNOWN_ALTITUDE_M: float = 450.0 * M_PER_FL
"""Highest height of a plot without Mode C: FL450 (13 716 m), the ceiling of civil
traffic (the top of RVSM airspace is FL410; business jets cruise up to FL450-FL510 but
rarely). A primary-only target above it converts with a ground range too long by at
most (h - FL450)/tan(elevation), which the variance does not cover."""

# Gauss-Legendre nodes for the moments over the height interval (see
# ground_range_for_unknown_height: the integrand is analytic, 16 nodes give ~1e-12).
_GL_X, _GL_W = np.polynomial.legendre.leggauss(16)


class GroundRangeInterval(NamedTuple):
    """What the slant range of a plot without height says about its ground range, for a
    height uniform over the feasible interval (:func:`ground_range_for_unknown_height`).
    All fields (N,)."""

    ground_min_m: NDArray[np.float64]
    """Shortest possible ground range (0 when the slant range is inside the interval's
    "cone": the target may be overhead)."""
    ground_max_m: NDArray[np.float64]
    """Longest possible ground range."""
    ground_mean_m: NDArray[np.float64]
    """Mean ground range over uniform heights: where the plot is put."""
    ground_var_m2: NDArray[np.float64]
    """Variance of the ground range over uniform heights (radial direction)."""
    altitude_low_m: NDArray[np.float64]
    """Feasible heights: [min_altitude_m, max_altitude_m] clipped to [h_r - rho, h_r + rho]."""
    altitude_high_m: NDArray[np.float64]
    dground_drange: NDArray[np.float64]
    """dg/drho at the middle of the feasible height interval (for the range noise)."""
    valid: NDArray[np.bool_]
    """Finite positive slant range and a non-empty feasible height interval."""


def ground_range_for_unknown_height(
    earth_radius_m: Any,
    antenna_alt_m: Any,
    range_m: Any,
    min_altitude_m: Any = MIN_UNKNOWN_ALTITUDE_M,
    max_altitude_m: Any = MAX_UNKNOWN_ALTITUDE_M,
) -> GroundRangeInterval:
    """Ground range of a plot whose height is only known to lie in [min, max] altitude.

    Same sphere and law of cosines as :func:`slant_to_ground_range` (a = R + h_r,
    b = R + h). A height with |h - h_r| > rho is impossible (the slant range is shorter
    than the height difference), so the interval is clipped to
    [h_lo, h_hi] = [max(h_min, h_r - rho), min(h_max, h_r + rho)]. The height is taken as
    uniform over [h_lo, h_hi]; the ground range g(h) is then a random variable with

        E[g] = (1 / (h_hi - h_lo)) ∫ g(h) dh,   Var[g] = (1 / (h_hi - h_lo)) ∫ (g(h) - E[g])^2 dh.

    g(h) is not linear in h (near the radar it is ~ sqrt(rho^2 - h^2)), so these are not
    the mid-point and (g_max - g_min)^2 / 12 of a uniform ground range: 14 km from the
    radar the uniform-in-g figures would misplace the plot by ~1 km. They are computed
    exactly by substituting h = h_r + rho sin(psi): then rho^2 - (a - b)^2 = rho^2 cos^2 psi,

        g(psi) = 2 R arcsin(rho cos(psi) / (2 sqrt(a b))),   dh = rho cos(psi) dpsi,

    which is analytic even where the interval reaches the cone (g ~ sqrt(h_r + rho - h)
    there in h), so 16-node Gauss-Legendre in psi is exact to ~1e-12 relative.

    g(h) peaks where the line of sight is horizontal at the target, b = sqrt(a^2 - rho^2)
    (a little below the antenna): ``ground_max_m`` is g there when that height is in the
    interval, else the larger end value; ``ground_min_m`` is the smaller end value.

    Arguments broadcast; all in metres. Rows with non-finite or non-positive slant range
    or an empty feasible interval have ``valid = False`` and NaN moments.
    """
    r, h_r, rho, h_min, h_max = np.broadcast_arrays(
        *(np.asarray(v, dtype=float) for v in (earth_radius_m, antenna_alt_m, range_m, min_altitude_m, max_altitude_m))
    )
    r, h_r, rho, h_min, h_max = (v.reshape(-1) for v in (r, h_r, rho, h_min, h_max))
    with np.errstate(invalid="ignore"):
        h_lo = np.maximum(h_min, h_r - rho)
        h_hi = np.minimum(h_max, h_r + rho)
        valid = np.isfinite(rho) & (rho > 0.0) & np.isfinite(h_lo) & np.isfinite(h_hi) & (h_lo <= h_hi)
    rho_s = np.where(valid, rho, 1.0)
    h_lo = np.where(valid, h_lo, h_r)
    h_hi = np.where(valid, h_hi, h_r)
    a = r + h_r

    psi_lo = np.arcsin(np.clip((h_lo - h_r) / rho_s, -1.0, 1.0))
    psi_hi = np.arcsin(np.clip((h_hi - h_r) / rho_s, -1.0, 1.0))
    psi = 0.5 * (psi_lo + psi_hi)[:, None] + 0.5 * (psi_hi - psi_lo)[:, None] * _GL_X[None, :]  # (n, k)
    b = r[:, None] + h_r[:, None] + rho_s[:, None] * np.sin(psi)
    cos_psi = np.cos(psi)
    arg = np.clip(rho_s[:, None] * cos_psi / (2.0 * np.sqrt(a[:, None] * b)), 0.0, 1.0)
    g_nodes = 2.0 * r[:, None] * np.arcsin(arg)
    w = _GL_W[None, :] * cos_psi  # uniform in h: dh ∝ cos(psi) dpsi
    w_sum = w.sum(axis=1)
    degenerate = ~(w_sum > 0.0)  # h_lo == h_hi at the cone: g = 0 there
    w_sum = np.where(degenerate, 1.0, w_sum)
    mean_m = np.where(degenerate, g_nodes[:, 0], (w * g_nodes).sum(axis=1) / w_sum)
    var_m2 = np.where(degenerate, 0.0, (w * (g_nodes - mean_m[:, None]) ** 2).sum(axis=1) / w_sum)

    g_at_lo = slant_to_ground_range(r, h_r, h_lo, rho_s)[0]
    g_at_hi = slant_to_ground_range(r, h_r, h_hi, rho_s)[0]
    with np.errstate(invalid="ignore"):
        h_peak = np.sqrt(a * a - rho_s * rho_s) - r  # NaN beyond the antenna's horizon sphere
    peak_inside = (h_peak > h_lo) & (h_peak < h_hi)
    g_peak = slant_to_ground_range(r, h_r, np.where(peak_inside, h_peak, h_lo), rho_s)[0]
    g_min = np.minimum(g_at_lo, g_at_hi)
    g_max = np.where(peak_inside, np.maximum(np.maximum(g_at_lo, g_at_hi), g_peak), np.maximum(g_at_lo, g_at_hi))
    d_rho = slant_to_ground_range(r, h_r, 0.5 * (h_lo + h_hi), rho_s)[2]

    def masked(v: NDArray[np.float64]) -> NDArray[np.float64]:
        out: NDArray[np.float64] = np.where(valid, v, np.nan)
        return out

    return GroundRangeInterval(
        masked(g_min),
        masked(g_max),
        masked(mean_m),
        masked(var_m2),
        masked(h_lo),
        masked(h_hi),
        masked(d_rho),
        valid,
    )


class UnknownHeightPlots(NamedTuple):
    """Plots without height converted at the mean ground range over every possible height,
    with the covariance split in its two parts (:func:`unknown_height_plots`)."""

    x_m: NDArray[np.float64]
    y_m: NDArray[np.float64]
    cov_noise_m2: NDArray[np.float64]
    """(N, 2, 2) the measurement noise alone: along-range (dg/drho sigma_rho)^2, cross-range
    (R sin(E[g]/R) sigma_theta)^2. Two plots of one radar of one aircraft share their height,
    so the difference of their positions has only this part (their velocity is exact)."""
    cov_height_m2: NDArray[np.float64]
    """(N, 2, 2) the unknown height's part: Var_h[g] along the radial (rank one, k^2 u u^T
    Var_h[g]); along the cross-range, Var_h[g] sigma_theta^2 (second order) is kept in
    ``cov_noise_m2``. Common to every plot of one aircraft from one radar: a bias."""
    ground_m: NDArray[np.float64]
    valid: NDArray[np.bool_]


def unknown_height_plots(
    plane: SystemPlane,
    sites: RadarSites,
    radar_index: Any,
    range_m: Any,
    azimuth_deg: Any,
    min_altitude_m: float = MIN_UNKNOWN_ALTITUDE_M,
    max_altitude_m: float = MAX_UNKNOWN_ALTITUDE_M,
    *,
    reference_altitude_m: float | None = None,
) -> UnknownHeightPlots:
    """Plots without height (no Mode C, no track altitude) -> plane position at the mean
    ground range E[g] of :func:`ground_range_for_unknown_height`, along the geodesic at
    their azimuth, and the covariance in two parts, built as in :func:`polar_to_plane`
    (radial / cross-range frame at the target, meridian convergence, scale factor k):

        noise   var_r = (dg/drho * sigma_rho)^2       (dg/drho at mid-height)
                var_c = ((R sin(E[g]/R))^2 + Var_h[g]) * sigma_theta^2   (~ E[g^2] sigma_theta^2)
        height  var_r = Var_h[g],  var_c = 0

    (height and measurement noise independent). With ``reference_altitude_m`` h_ref the
    plot is put at g(h_ref) instead (the ground range at that height, as
    :func:`polar_to_plane` converts at an assumed height, dg/drho taken there too) and the height's part is the
    second moment about it, Var_h[g] + (E[g] - g(h_ref))^2, along the radial: the same
    spread of possible positions, about another point. Their sum is the covariance of one plot
    over every height (:func:`polar_to_plane_unknown_height`); a track built from such
    plots of one radar filters with the noise part and carries the height part as a
    common bias (engine.py, initiation.floor_covariance). Plots with no feasible height
    (slant range shorter than min_altitude_m - h_r) are put at the site with isotropic
    variance rho^2 + sigma_rho^2 per axis (in the noise part) and ``valid = False``, as
    :func:`polar_to_plane` clamps; non-finite or negative input gives NaN and
    ``valid = False``.
    """
    idx = sites.check_index(radar_index)
    rho, theta_deg, idx = (
        v.reshape(-1) for v in np.broadcast_arrays(np.asarray(range_m, float), np.asarray(azimuth_deg, float), idx)
    )
    finite_in = np.isfinite(rho) & np.isfinite(theta_deg) & (rho >= 0.0)
    rho_safe = np.where(finite_in, rho, 0.0)
    theta_safe = np.where(finite_in, theta_deg, 0.0)
    r_m = sites.earth_radius_m[idx]
    iv = ground_range_for_unknown_height(r_m, sites.alt_m[idx], rho_safe, min_altitude_m, max_altitude_m)
    valid = iv.valid & finite_in
    ground_m = np.where(valid, iv.ground_mean_m, 0.0)
    var_g = np.where(valid, iv.ground_var_m2, 0.0)
    d_rho_mid = iv.dground_drange
    if reference_altitude_m is not None:
        g_ref, ok_ref, d_rho_ref, _ = slant_to_ground_range(
            r_m, sites.alt_m[idx], np.full(rho_safe.shape, reference_altitude_m), rho_safe
        )
        g_ref = np.where(ok_ref, g_ref, ground_m)
        d_rho_mid = np.where(ok_ref, d_rho_ref, d_rho_mid)
        var_g = var_g + (ground_m - g_ref) ** 2
        ground_m = np.where(valid, g_ref, 0.0)
    sigma_rho = sites.sigma_range_m[idx]
    sigma_theta = sites.sigma_azimuth_rad[idx]
    # dg/drho is infinite only if the whole feasible interval sits on the cone (h_lo = h_hi
    # = h_r + rho); there 1 (the flat, level value) stands in.
    d_rho = np.where(valid & np.isfinite(d_rho_mid), d_rho_mid, 1.0)
    var_c = np.maximum(((r_m * np.sin(ground_m / r_m)) ** 2 + var_g) * sigma_theta**2, MIN_CROSS_RANGE_VAR_M2)
    x_m, y_m, cov = radial_to_plane(plane, sites, idx, theta_safe, ground_m, (d_rho * sigma_rho) ** 2, var_c)
    # the height part k^2 Var_h[g] u u^T: the same radial line converted with (1, 0)
    _, _, radial = radial_to_plane(plane, sites, idx, theta_safe, ground_m, np.ones_like(var_g), np.zeros_like(var_g))
    cov_h = radial * var_g[:, None, None]
    x_m, y_m, cov, ground_m = mark_unconverted(x_m, y_m, cov, ground_m, rho, sigma_rho, finite_in, valid)
    cov_h[~valid] = 0.0
    if not np.all(finite_in):
        cov_h[~finite_in] = np.nan
    return UnknownHeightPlots(x_m, y_m, cov, cov_h, ground_m, valid)


def polar_to_plane_unknown_height(
    plane: SystemPlane,
    sites: RadarSites,
    radar_index: Any,
    range_m: Any,
    azimuth_deg: Any,
    min_altitude_m: float = MIN_UNKNOWN_ALTITUDE_M,
    max_altitude_m: float = MAX_UNKNOWN_ALTITUDE_M,
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.bool_]]:
    """Plots without height (no Mode C, no track altitude) -> plane position and a
    covariance that spans every possible height in [min_altitude_m, max_altitude_m]: the
    sum of the two parts of :func:`unknown_height_plots`,

        along-range  var_r = Var_h[g] + (dg/drho * sigma_rho)^2      (dg/drho at mid-height)
        cross-range  var_c = ((R sin(E[g]/R))^2 + Var_h[g]) * sigma_theta^2   (~ E[g^2] sigma_theta^2)

    Returns ``(x_m, y_m, cov_xy_m2 (N,2,2), ground_range_m, valid)``, the same shapes as
    ``polar_to_plane(..., return_valid=True)``, so the rows can replace its rows.
    """
    p = unknown_height_plots(plane, sites, radar_index, range_m, azimuth_deg, min_altitude_m, max_altitude_m)
    return p.x_m, p.y_m, p.cov_noise_m2 + p.cov_height_m2, p.ground_m, p.valid
