"""Height for plots without Mode C: the predicted altitude of the track a plot may belong to.

A primary (PSR) plot measures slant range rho and azimuth theta but no height. Its ground
range depends on the height it is converted at (rho^2 ~ g^2 + h^2 close in): at FL300
40 km out, converting at a guessed 10,000 ft puts it ~1 km too far out. If a track
predicted to the period's time is where the plot is, that track's altitude is the best
height to convert the plot at; otherwise the plot must be converted with the whole height
interval (geo.unknown_height.polar_to_plane_unknown_height).

The comparison is made where the plot was measured, in the radar's own polar
coordinates, so it needs no height for the plot: each track's position is converted to
what the plot's radar would measure of it: ground range g_t and azimuth theta_t by
great-circle formulas on the projection's conformal sphere
(``coordinates.conformal_sphere_polar``, each track mapped to that sphere once; within
1 m and 1e-4 deg of ``Geod.inv`` over the coverage), and the slant range rho_t from g_t
on the site's Gaussian sphere. The plot is then converted exactly (polar_to_plane) at
the chosen track's altitude.

* A track with an altitude h_t has one slant range. Its position covariance P (plane,
  2x2) is projected on the radial u and the cross-range v directions (from the site to
  the track in the plane): var_rho = (d rho/d g)^2 u^T P u + (d rho/d h)^2 var_h and
  var_theta = v^T P v / g_t^2, with d rho/d g = a b sin(g/R) / (R rho) and
  d rho/d h = (b - a cos(g/R)) / rho (a = R + h_r, b = R + h_t).
* A track without altitude may be at any height in [MIN, MAX]_UNKNOWN_ALTITUDE_M (0 ft,
  FL450): it spans the slant-range interval [rho_lo, rho_hi] over those heights (the
  minimum is at b = a cos(g/R) when that is inside), and the distance to it is the
  distance to the interval. It competes for plots like any track (a primary-only
  aircraft's plots stay with its own track), and gives them no altitude.
* A track moves between the period's reference time and the plot's time: with the plot's
  offset dt (``plot_dt_s``) and the track's plane velocity, rho_t += (d rho/d g)(u . v_t) dt
  and theta_t += (v . v_t) dt / g_t.

For plot i of radar r (sigma_rho, sigma_theta its noise) and candidate track j the
normalised distance is

    d^2 = max(|rho_i - rho_j| - halfwidth_j, 0)^2 / (sigma_rho^2 + var_rho_j)
        + wrap(theta_i - theta_j)^2 / (sigma_theta^2 + var_theta_j),

and a track gates the plot if d <= ``gate_sigmas``. Among the gated tracks the plot takes
the most likely, the smallest Gaussian negative log-likelihood

    (rho_i - rho_mid_j)^2 / S_rho_j + ln S_rho_j + dtheta^2 / S_theta_j + ln S_theta_j,

with S_rho_j = sigma_rho^2 + var_rho_j + halfwidth_j^2 / 3 (a track without altitude
spreads its slant range uniformly over its interval): so a plot right on a track with
altitude is not taken by a track without altitude whose wide interval also holds it,
as the bare distance to the interval (zero inside) would do. Candidates: the tracks in
the plane within reach of the plot's ground-range interval over [min, max] altitude, each
track with its own reach (its motion over the plot's time offset, its gate over its spread
and the plot's noise; k-d trees over the tracks grouped by reach, one ball query per plot
and group, all radars at once), of which the ``n_candidates`` nearest in the radar's
slant-range plane rho (sin theta, cos theta) compete (|p_i - p_j|^2 = drho^2 + 4 rho_i
rho_j sin^2(dtheta / 2) ~ drho^2 + (rho dtheta)^2, no wrap at north): O(M log N) for M
plots and N tracks, plus a few numpy operations per candidate pair (one ``Geod.inv`` per
(radar, track within the reach of its plots) pair and a k-d tree per radar before: ~20 ms
per period at 4,000 aircraft and 10 radars, now ~3-5 ms). One reach for all tracks, the
largest, grew faster than the traffic: at 20,000 aircraft a few tentative tracks tens of
kilometres wide or at several km/s gave every primary plot thousands of candidates
(~130 ms a period, up to 0.9 s; issue 16).
"""

from __future__ import annotations

import itertools
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from ..geo.coordinates import (
    RadarSites,
    SystemPlane,
    conformal_sphere_destination,
    conformal_sphere_polar,
    ground_to_slant_range,
    slant_to_ground_range,
)
from ..geo.unknown_height import MAX_UNKNOWN_ALTITUDE_M, MIN_UNKNOWN_ALTITUDE_M

__all__ = ["PrimaryHeight", "primary_plot_altitude"]

#: ground range below which a track's azimuth rate and cross-range variance are taken at
#: this range (a track right over the site has no defined azimuth)
_MIN_GROUND_M = 100.0


class PrimaryHeight(NamedTuple):
    """Per plot (M,): the track it was matched to and the altitude to convert it at."""

    track_index: NDArray[np.intp]
    """Row of the track arrays, -1 for plots with Mode C and for plots no track gates."""
    altitude_m: NDArray[np.float64]
    """The matched track's predicted altitude, metres; NaN where there is no match or the
    track has no altitude (then convert with the height interval)."""


def primary_plot_altitude(
    plane: SystemPlane,
    sites: RadarSites,
    plot_radar: Any,
    plot_range_m: Any,
    plot_azimuth_deg: Any,
    plot_has_altitude: Any,
    track_xy_m: Any,
    track_altitude_m: Any,
    track_cov_xy_m2: Any,
    *,
    track_velocity_mps: Any = None,
    plot_dt_s: Any = None,
    track_altitude_var_m2: Any = None,
    gate_sigmas: float = 4.0,
    n_candidates: int = 8,
    min_altitude_m: float = MIN_UNKNOWN_ALTITUDE_M,
    max_altitude_m: float = MAX_UNKNOWN_ALTITUDE_M,
) -> PrimaryHeight:
    """For each plot without height, the track it may belong to and its predicted altitude.

    Plots (M,): ``plot_radar`` (row of ``sites``), ``plot_range_m`` (slant), ``plot_azimuth_deg``,
    ``plot_has_altitude`` (bool: Mode C present; those plots are skipped), and optionally
    ``plot_dt_s`` (plot time minus the tracks' prediction time, s).
    Tracks (N,), predicted to one time: ``track_xy_m`` (N,2) plane position,
    ``track_altitude_m`` (N,) metres or NaN, ``track_cov_xy_m2`` (N,2,2) position
    covariance, optionally ``track_velocity_mps`` (N,2) plane velocity and
    ``track_altitude_var_m2`` (N,) altitude variance. Tracks with a non-finite position
    or covariance are ignored.

    ``gate_sigmas``: the gate on the normalised distance d (module docstring); 4 keeps a
    plot of the track with probability 1 - exp(-8) ~ 0.9997 when the errors are Gaussian
    and the covariances honest. ``n_candidates``: how many nearest tracks per plot are
    tried. ``min_altitude_m``/``max_altitude_m``: the heights a track without altitude may
    be at.
    """
    radar = sites.check_index(plot_radar).reshape(-1)
    rho_p = np.asarray(plot_range_m, dtype=float).reshape(-1)
    theta_p = np.radians(np.asarray(plot_azimuth_deg, dtype=float).reshape(-1))
    has_alt = np.asarray(plot_has_altitude, dtype=bool).reshape(-1)
    m = rho_p.shape[0]
    if not (radar.shape == theta_p.shape == has_alt.shape == (m,)):
        raise ValueError("plot arrays must all have the same length")
    dt_p = np.zeros(m) if plot_dt_s is None else np.broadcast_to(np.asarray(plot_dt_s, dtype=float), (m,))

    xy = np.asarray(track_xy_m, dtype=float).reshape(-1, 2)
    n = xy.shape[0]
    alt = np.asarray(track_altitude_m, dtype=float).reshape(n)
    cov = np.asarray(track_cov_xy_m2, dtype=float).reshape(n, 2, 2)
    vel = np.zeros((n, 2)) if track_velocity_mps is None else np.asarray(track_velocity_mps, float).reshape(n, 2)
    var_h = np.zeros(n) if track_altitude_var_m2 is None else np.asarray(track_altitude_var_m2, float).reshape(n)
    var_h = np.where(np.isfinite(var_h), var_h, 0.0)

    track_index = np.full(m, -1, dtype=np.intp)
    need = ~has_alt & np.isfinite(rho_p) & (rho_p > 0.0) & np.isfinite(theta_p) & np.isfinite(dt_p)
    usable = np.flatnonzero(
        np.all(np.isfinite(xy), axis=1) & np.all(np.isfinite(cov), axis=(1, 2)) & np.all(np.isfinite(vel), axis=1)
    )
    if not need.any() or usable.size == 0:
        return PrimaryHeight(track_index, np.full(m, np.nan))

    xy_u, alt_u, cov_u, vel_u, var_h_u = xy[usable], alt[usable], cov[usable], vel[usable], var_h[usable]
    known_u = np.isfinite(alt_u)
    # Each track on the projection's conformal sphere once; its polar coordinates from a
    # plot's radar by great-circle formulas (coordinates.conformal_sphere_polar: < 1 m and
    # 1e-4 deg from Geod.inv over the coverage), per candidate pair, not per (radar, track).
    chi_u, lam_u = plane.to_conformal_sphere(xy_u[:, 0], xy_u[:, 1])
    site_x, site_y = sites.plane_positions(plane)
    site_chi, site_lam = plane.to_conformal_sphere(site_x, site_y)
    r_c = plane.conformal_radius_m

    # Candidates, all radars at once: a plot lies in the plane within its ground-range
    # interval over [min, max] altitude along its azimuth. From the interval's middle
    # (put in the plane exactly, on the conformal sphere), half its width plus the track's
    # own reach (its motion over the plot's time offset, its gate over its position and
    # altitude spread and the plot's noise, range and across, and 1 km for the sphere's and
    # the plane's approximations: < 1 m per 100 km; the plane's scale k - 1 < 0.6 % of the
    # half width) holds every track that may gate the plot.
    plots = np.flatnonzero(need)
    rp, tp, pr = rho_p[plots], theta_p[plots], radar[plots]
    r_arr, h_arr = sites.earth_radius_m[pr], sites.alt_m[pr]
    h_top = np.minimum(max_altitude_m, h_arr + 0.999 * rp)
    g_low = slant_to_ground_range(r_arr, h_arr, np.full(plots.size, min_altitude_m), rp)[0]
    g_top = slant_to_ground_range(r_arr, h_arr, h_top, rp)[0]
    g_mid = 0.5 * (g_low + g_top)
    g_mid = np.where(np.isfinite(g_mid), g_mid, rp)
    g_half_m = 0.5 * np.abs(g_low - g_top)
    g_half_m = np.where(np.isfinite(g_half_m), g_half_m, rp)
    chi_m, lam_m = conformal_sphere_destination(r_c, site_chi[pr], site_lam[pr], np.degrees(tp), g_mid)
    where = np.stack(plane.from_conformal_sphere(chi_m, lam_m), axis=1)
    pair_p, pair_t = _within_reach(
        xy_u,
        np.hypot(vel_u[:, 0], vel_u[:, 1]),
        cov_u[:, 0, 0] + cov_u[:, 1, 1] + var_h_u,
        where,
        g_half_m,
        np.abs(dt_p[plots]),
        sites.sigma_range_m[pr] ** 2 + (sites.sigma_azimuth_rad[pr] * rp) ** 2,
        gate_sigmas,
    )
    if not pair_p.size:
        return PrimaryHeight(track_index, np.full(m, np.nan))

    # What the plot's radar measures of each candidate track (at min_altitude_m for a
    # track without altitude), and the slant-range interval of a track without altitude
    # over [min, max] altitude: its minimum over heights is at b = a cos(gamma) if inside.
    r_q = pr[pair_p]
    r_m, h_r = sites.earth_radius_m[r_q], sites.alt_m[r_q]
    known = known_u[pair_t]
    g_t, az_t_deg = conformal_sphere_polar(r_c, site_chi[r_q], site_lam[r_q], chi_u[pair_t], lam_u[pair_t])
    theta_t = np.radians(az_t_deg)
    h_t = np.where(known, alt_u[pair_t], min_altitude_m)
    rho_t = ground_to_slant_range(r_m, h_r, h_t, g_t)
    a = r_m + h_r
    gamma = g_t / r_m
    h_star = np.clip(a * np.cos(gamma) - r_m, min_altitude_m, max_altitude_m)
    rho_ends = [ground_to_slant_range(r_m, h_r, np.full(r_q.shape, h), g_t) for h in (min_altitude_m, max_altitude_m)]
    rho_star = ground_to_slant_range(r_m, h_r, h_star, g_t)
    rho_lo = np.where(known, rho_t, np.minimum(np.minimum(rho_ends[0], rho_ends[1]), rho_star))
    rho_hi = np.where(known, rho_t, np.maximum(rho_ends[0], rho_ends[1]))
    rho_mid, half_m = 0.5 * (rho_lo + rho_hi), 0.5 * (rho_hi - rho_lo)

    # Track uncertainty and motion in the radar's frame.
    b = r_m + np.where(known, alt_u[pair_t], 0.5 * (min_altitude_m + max_altitude_m))
    rho_b = ground_to_slant_range(r_m, h_r, b - r_m, g_t)
    drho_dg = np.where(rho_b > 0.0, a * b * np.sin(gamma) / (r_m * np.maximum(rho_b, 1e-9)), 1.0)
    drho_dh = np.where(rho_b > 0.0, (b - a * np.cos(gamma)) / np.maximum(rho_b, 1e-9), 1.0)
    xy_t = xy_u[pair_t]
    u = np.stack([xy_t[:, 0] - site_x[r_q], xy_t[:, 1] - site_y[r_q]], axis=1)
    u_norm = np.linalg.norm(u, axis=1, keepdims=True)
    # u: radial unit vector; its clockwise normal v = (uy, -ux) points where azimuth grows.
    u = np.where(u_norm > 0.0, u / np.where(u_norm > 0.0, u_norm, 1.0), np.array([0.0, 1.0]))
    g_safe = np.maximum(g_t, _MIN_GROUND_M)
    cov_t, vel_t = cov_u[pair_t], vel_u[pair_t]
    p_xx, p_xy, p_yy = cov_t[:, 0, 0], cov_t[:, 0, 1], cov_t[:, 1, 1]
    ux, uy = u[:, 0], u[:, 1]  # v = (uy, -ux)
    p_uu = ux * ux * p_xx + 2.0 * ux * uy * p_xy + uy * uy * p_yy
    p_vv = uy * uy * p_xx - 2.0 * ux * uy * p_xy + ux * ux * p_yy
    var_rho_t = drho_dg**2 * p_uu + np.where(known, drho_dh**2 * var_h_u[pair_t], 0.0)
    var_theta_t = p_vv / g_safe**2
    rho_rate = drho_dg * (ux * vel_t[:, 0] + uy * vel_t[:, 1])
    theta_rate = (uy * vel_t[:, 0] - ux * vel_t[:, 1]) / g_safe

    dt = dt_p[plots][pair_p]
    rho_q, theta_q = rp[pair_p], tp[pair_p]
    d_mid = rho_q - (rho_mid + rho_rate * dt)
    d_rho = np.maximum(np.abs(d_mid) - half_m, 0.0)
    d_theta = np.mod(theta_q - theta_t - theta_rate * dt + np.pi, 2.0 * np.pi) - np.pi
    s_rho = sites.sigma_range_m[r_q] ** 2 + var_rho_t
    s_theta = sites.sigma_azimuth_rad[r_q] ** 2 + var_theta_t
    with np.errstate(divide="ignore", invalid="ignore"):  # 0/0 (no noise, exact) is a distance 0
        d2 = np.where(d_rho == 0.0, 0.0, d_rho**2 / s_rho) + np.where(d_theta == 0.0, 0.0, d_theta**2 / s_theta)
    inside = np.isfinite(d2) & (d2 <= gate_sigmas**2)
    # Only the n_candidates nearest in the radar's slant-range plane rho (sin theta, cos theta)
    # compete: |p_i - p_j|^2 = drho^2 + 4 rho_i rho_j sin^2(dtheta / 2).
    polar_d2 = (rho_q - rho_mid) ** 2 + 4.0 * rho_q * rho_mid * np.sin(0.5 * (theta_q - theta_t)) ** 2
    order = np.lexsort((polar_d2, pair_p))
    first = np.searchsorted(pair_p[order], pair_p[order], side="left")
    rank = np.empty_like(order)
    rank[order] = np.arange(order.size) - first
    inside &= rank < int(n_candidates)
    # Choice among the gated: the Gaussian negative log-likelihood (a track without
    # altitude spreads its slant range uniformly over its interval: variance hw^2/3).
    s_rho_eff = s_rho + half_m**2 / 3.0
    with np.errstate(divide="ignore", invalid="ignore"):
        nll = d_mid**2 / s_rho_eff + np.log(s_rho_eff) + d_theta**2 / s_theta + np.log(s_theta)
    nll = np.where(inside, np.where(np.isnan(nll), -np.inf, nll), np.inf)
    # best per plot: sort the pairs by (plot, nll), take each plot's first
    order = np.lexsort((nll, pair_p))
    is_first = np.ones(order.size, bool)
    is_first[1:] = pair_p[order][1:] != pair_p[order][:-1]
    best = order[is_first]
    ok = inside[best]
    track_index[plots[pair_p[best[ok]]]] = usable[pair_t[best[ok]]]

    matched = track_index >= 0
    altitude_m = np.full(m, np.nan)
    altitude_m[matched] = alt[track_index[matched]]
    return PrimaryHeight(track_index, altitude_m)


def _within_reach(
    track_xy_m: NDArray[np.float64],
    track_speed_mps: NDArray[np.float64],
    track_spread_m2: NDArray[np.float64],
    plot_xy_m: NDArray[np.float64],
    plot_half_m: NDArray[np.float64],
    plot_abs_dt_s: NDArray[np.float64],
    plot_var_m2: NDArray[np.float64],
    gate_sigmas: float,
) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
    """The (plot, track) pairs, sorted by plot, with the track within the plot's reach:

        |xy_t - xy_p| <= half_p + 1 km + speed_t |dt_p| + gate sqrt(spread_t + var_p)

    (``track_spread_m2``: the trace of the track's position covariance plus its altitude
    variance; ``plot_var_m2``: the plot's range variance plus its azimuth variance times
    the squared range, the sum of its noise ellipse's axes). The tracks are
    grouped by their largest reach over the plots (1-2 km, 2-4 km, 4-8 km, ...), one k-d
    tree and one ball query per plot for each group, and the pairs are then cut to the
    exact reach. One reach for all tracks (the largest) made the search grow faster than
    the traffic: at 20,000 tracks a few tentative tracks with a position spread of tens of
    kilometres or a velocity of several km/s, and every primary plot had thousands of
    candidates (a second a period; issue 16)."""
    if not plot_xy_m.shape[0] or not track_xy_m.shape[0]:
        return np.zeros(0, np.intp), np.zeros(0, np.intp)
    reach_max = (
        1e3
        + track_speed_mps * float(np.max(plot_abs_dt_s))
        + gate_sigmas * np.sqrt(track_spread_m2 + float(np.max(plot_var_m2)))
    )
    level = np.ceil(np.log2(np.maximum(reach_max / 1e3, 1.0))).astype(np.intp)
    pp, tt = [], []
    for lv in np.unique(level).tolist():
        members = np.flatnonzero(level == lv)
        hits = cKDTree(track_xy_m[members]).query_ball_point(
            plot_xy_m, plot_half_m + 1e3 * 2.0**lv, return_sorted=False
        )
        lens = np.fromiter(map(len, hits), dtype=np.intp, count=len(hits))
        pp.append(np.repeat(np.arange(plot_xy_m.shape[0]), lens))
        tt.append(members[np.fromiter(itertools.chain.from_iterable(hits), dtype=np.intp, count=int(lens.sum()))])
    pair_p, pair_t = np.concatenate(pp), np.concatenate(tt)
    d = track_xy_m[pair_t] - plot_xy_m[pair_p]
    reach = (
        plot_half_m[pair_p]
        + 1e3
        + track_speed_mps[pair_t] * plot_abs_dt_s[pair_p]
        + gate_sigmas * np.sqrt(track_spread_m2[pair_t] + plot_var_m2[pair_p])
    )
    keep = np.hypot(d[:, 0], d[:, 1]) <= reach
    order = np.argsort(pair_p[keep], kind="stable")
    return pair_p[keep][order], pair_t[keep][order]
