"""Online radar registration: each radar's systematic errors, from the aircraft several radars see.

Bias model (per radar r; Burke 1966, Dana 1990, Helmick & Rice 1993, Zhou, Leung & Yip 1997)
----------------------------------------------------------------------------------------------
A radar reports, for a target at true slant range rho, true azimuth theta and true time t,

    rho_m   = (1 + gain_r) rho + range_offset_r             (gain_r dimensionless; kept in ppm)
    theta_m = theta + azimuth_offset_r
    t_m     = t + time_offset_r

plus zero-mean noise. The correction (:meth:`RadarRegistration.correct`) inverts it:
rho = (rho_m - range_offset) / (1 + gain), theta = theta_m - azimuth_offset, t = t_m - time_offset.

Linearisation in the system plane (:meth:`RegistrationGeometry.jacobian`)
------------------------------------------------------------------------
A plot converted by :func:`radar_fusion.geo.coordinates.polar_to_plane` and aligned to its
cluster's time t_c with the velocity v of its track (z = z(t_m) + v (t_c - t_m), as the
engine's fusion step does) moves with the biases b_r = (range_offset_m, gain_ppm,
azimuth_offset_deg, time_offset_s) as z_m = z_true + J b_r + O(b^2), the columns of J being

    dz/d range_offset  = k g' u                          g' = dg/drho (EUROCONTROL sphere)
    dz/d gain_ppm      = k g' rho 1e-6 u
    dz/d azimuth_deg   = k R sin(g / R) (pi / 180) w     R sin(g/R): lateral shift per radian
    dz/d time_offset   = -v                              (the plot is aligned from the wrong time)

with g the ground range, R the site's Gaussian earth radius, k the point scale of the
stereographic plane (k = 1 + d^2 / 4R0^2, d the distance from the plane's centre, R0 the
conformal sphere's radius), u = (sin beta, cos beta) the radial unit vector at the target and
w = (cos beta, -sin beta) the cross-range one (azimuth grows clockwise). beta, the grid
bearing of the radial line at the target, comes without a second geodesic: the stereographic
projection maps great circles to circles, and for a circular arc the chord's direction is the
mean of the two end tangents, so beta = 2 beta_chord - beta_site, beta_site = theta - c_site
(c_site the site's meridian convergence; the map is conformal, so true azimuths become grid
bearings by subtracting c). The test checks J against finite differences of polar_to_plane.

Estimation: target positions eliminated exactly (Zhou, Leung & Yip 1997, linearised)
------------------------------------------------------------------------------------
The plots i of one cluster c (one aircraft, one period, several radars) are
z_i = p_c + J_i b + n_i, n_i ~ N(0, R_i), with p_c the unknown aircraft position. The joint
weighted least-squares (maximum-likelihood for Gaussian noise) over (p_c, b) eliminates p_c
in closed form, p_c = S_c^-1 sum_i W_i (z_i - J_i b), W_i = R_i^-1, S_c = sum_i W_i, leaving
the normal equations of b alone (a Schur complement; this is the exact treatment of the
common target, not the sum of pairwise differences, which would count plots twice):

    I_c = sum_i J_i^T W_i J_i - T_c^T S_c^-1 T_c,        T_c = sum_i W_i J_i
    y_c = sum_i J_i^T W_i z_i - T_c^T S_c^-1 m_c,        m_c = sum_i W_i z_i

A one-plot cluster gives I_c = 0: only aircraft seen by at least two radars inform.
Each plot's residual against the others' fused position (leave-one-out, with its
covariance R_i + S_{c,-i}^-1) is gated at a chi^2 bound first, so a mis-associated plot is
dropped before it biases anything.

Recursion: exponentially weighted least squares in information form with a stabilising prior
(Ljung & Soederstroem 1983 ch. 5 for exponential forgetting; Kulhavy & Zarrop 1993 for
forgetting towards a prior, which keeps the information matrix bounded below: no wind-up)

    Lambda_k = lam Lambda_{k-1} + (1 - lam) Lambda_0 + sum_c I_c,   lam = exp(-dt / tau)
    eta_k    = lam eta_{k-1}                         + sum_c y_c,     (prior mean 0)
    b_k = Lambda_k^-1 eta_k,   cov(b_k) = Lambda_k^-1,

Lambda_0 = diag(1 / sigma_prior^2). The memory is one (4M x 4M) matrix and one vector whatever
the run length; old data fade with time constant tau, so slow drift is followed; the prior
always weighs as one prior (sum of (1 - lam) lam^j = 1), so a direction the data do not
excite relaxes to 0 with the prior's sigma instead of blowing up.

Two-stage: the tracks' innovations (Friedland 1969; Ignagni 1981)
------------------------------------------------------------------
A cluster's plots say more than their differences: their fused position z_f = S_c^-1 sum_i
W_i z_i, which updates the aircraft's track, moves with the biases as z_f = p + F b + n_f,
F = S_c^-1 sum_i W_i J_i, and the track's predicted position carries the biases of every
plot it was built from, x^-_p = p + B b + e (B (2, 4M): the track's sensitivity to the
biases, engine._update carries it through each update as B+ = (I - K) B- + K F, K the
update's gain on the position). So the track's innovation

    nu = z_f - x^-_p = (F - B) b + (n_f - e),        cov S = P^-_pp + R_f

is a linear measurement of the biases with a known matrix, independent of the clusters'
own differences above (those are orthogonal to the fused mean). This is the bias stage of
Friedland's two-stage filter: for constant biases the sum of the innovations' information,
(F - B)^T S^-1 (F - B), is what an augmented filter over every track's state and the biases
would gain from them (Ignagni 1981). It is what the clusters alone lack: an aircraft seen
by one radar in one period and by another in the next gives nothing as a cluster (one radar
each), while its innovation sets the second radar's plots against a track made of the
first's. A track of one radar only has F = B: no information, as it should be. The engine
feeds only what keeps the model honest: tracks in their quiet mode (IMM probability
``innovation_quiet_prob``; a manoeuvre's innovations are the motion's, not the radars'),
with three updates or more (a velocity and a sensitivity of their own), every plot of the
cluster with Mode C, and the innovation inside ``innovation_gate_chi2``
(:meth:`RadarRegistration.update_from_innovations`). As the plots are corrected by c (the
applied correction) and the tracks follow it (engine._follow_registration moves each track
by -B (c_new - c_old)), nu = (F - B)(b - c) + noise: the information vector takes
(F - B)^T S^-1 (nu + (F - B) c). Without a reference radar, the time columns of F - B are
centred over the radars: the clock offset common to all of them stays unobservable, as it
is (F's time columns carry the velocity the plots were aligned with and B leaves the
velocity's sensitivity out, so they are only nearly balanced, and thousands of innovations
pulled the common offset by 0.1-1.7 s on the demo before).

Observability and how it is pinned
----------------------------------
Polar biases of radars at distinct sites are observable from relative residuals (Dana 1990):
the same range offset on two radars shifts their plots along two different radials, the same
azimuth offset rotates their pictures about two different centres (a net translation of
offset x baseline). Only the time offset common to all radars is not: it moves every aligned
plot by the same -v tau. The weak zero-mean prior pins it, so the reported time offsets are
relative to the radars' (prior-weighted) mean, and a clock error shared by all radars stays
in the tracks. Weakly excited combinations (range offset against gain over a short range
spread; azimuth against time offset for tangential traffic) are shrunk towards 0 by the
same prior. ``reference_radar_id`` instead fixes one radar's biases at 0 (a surveyed or
ADS-B-calibrated reference): the others are then relative to it. Absolute accuracy needs
such a reference; relative registration is what removes the shadows and the fused errors.
"""

from __future__ import annotations

import math
from typing import Any, NamedTuple

import numpy as np
import numpy.typing as npt
from numpy.typing import NDArray
from pydantic import BaseModel, ConfigDict, Field

from ..geo.coordinates import RadarSites, SystemPlane, gaussian_earth_radius_m, slant_to_ground_range
from .association import unique_inverse
from .compiled import compiled

__all__ = [
    "BIAS_NAMES",
    "N_BIAS",
    "ClusterSensitivity",
    "RadarRegistration",
    "RegistrationGeometry",
    "RegistrationParams",
    "cluster_sensitivity",
    "update_sensitivity",
    "warm_up",
]

BIAS_NAMES = ("range_offset_m", "range_gain_ppm", "azimuth_offset_deg", "time_offset_s")
"""The per-radar bias components, in the order of the state vector (and of J's columns)."""
N_BIAS = len(BIAS_NAMES)
RANGE_OFFSET, RANGE_GAIN, AZIMUTH_OFFSET, TIME_OFFSET = range(N_BIAS)
_PPM = 1e-6
_PINNED_PRIOR_FACTOR = 1e12  # information multiplier of a reference radar's prior: fixed at 0


class RegistrationParams(BaseModel):
    """Parameters of :class:`RadarRegistration` (a ``[registration]`` section of the configuration)."""

    model_config = ConfigDict(frozen=True, extra="forbid", allow_inf_nan=False)

    enabled: bool = Field(
        True,
        description="estimate and correct. Default on: corrections only start once a radar's estimate rests on "
        "min_plots plots, and with unbiased radars the estimates stay within their noise of 0",
    )
    forgetting_time_s: float = Field(
        1800.0,
        gt=0,
        description="time constant tau of the exponential forgetting, s. Default 30 min: radar biases drift over "
        "hours (temperature, maintenance), and 30 min of traffic averages the noise down to a few metres; it does not "
        "slow the start (information accumulates from the first period)",
    )
    update_interval_s: float = Field(
        0.0,
        ge=0,
        description="the engine feeds the estimator at most one period in this interval (0: every period). "
        "Default every period: on the demo (3 radars, 540 s) one period in 20 s left the range offsets 20-30 % "
        "off and the tracks at 83.9 m RMS, every period gave 73.0 m; the update is capped at "
        "max_clusters_per_update clusters, a few ms a period",
    )
    min_plots: float = Field(
        30.0,
        ge=0,
        description="effective (forgetting-weighted) number of a radar's plots in multi-radar clusters before its "
        "correction is applied. Default 30, a floor: james_stein decides how much of a young estimate to apply. "
        "It was 300 (a few minutes of a dozen shared aircraft) without it, and on the bench's 180 s ADS-B case the "
        "radars' biases then stayed in the tracks for most of the run (straight flight 1.50x its PCRB; 1.28x now)",
    )
    james_stein: bool = Field(
        True,
        description="apply each radar's estimate shrunk towards 0 by the positive-part James-Stein factor "
        "(RadarRegistration.applied_share): an estimate within its noise of 0 little, a significant one almost "
        "whole. On the bench's 180 s ADS-B case, straight flight against its PCRB: biased radars 1.50 -> 1.28, "
        "the same radars without bias 1.17 either way (applied whole from 30 plots on: 1.26 and 1.24, the "
        "unbiased radars' own estimation noise added to their plots). False: the estimate whole",
    )
    empirical_bayes_gain_time: bool = Field(
        True,
        description="apply a radar's range gain and time offset only as far as the data show them: each gets a "
        "zero-mean prior whose variance is estimated from the data, tau² = max(0, b² − σ²) (empirical Bayes, "
        "RadarRegistration.correction), so one within its noise of 0 is held at 0 and the radar's other "
        "corrections are taken as if it were known to be 0 (the range offset and the gain correlate at about "
        "−0.9 over the ranges of one radar's traffic, so the offset is far better known with the gain held). "
        "Offsets of range and azimuth every radar has; a gain or a clock offset is a fault that the estimate "
        "shows when it is there. On the bench's 180 s ADS-B case, straight flight against its PCRB: biased "
        "radars 1.28 -> 1.24, the same radars without bias 1.17 -> 1.15 (with the gain and the time offset held "
        "at 0 outright: 1.22 and 1.18). False: every estimate applied as it stands",
    )
    estimate_time_offset: bool = Field(
        True,
        description="estimate each radar's time-stamping offset too (needs the tracks' velocities). Relative "
        "offsets are observable from aircraft flying in different directions; the common one is not (see the module)",
    )
    prior_sigma_range_offset_m: float = Field(
        100.0, gt=0, description="prior sigma of a range offset, m: weak (a bias over 100 m would be a fault)"
    )
    prior_sigma_range_gain_ppm: float = Field(
        300.0, gt=0, description="prior sigma of a range gain, ppm (300 ppm = 30 m at 100 km): weak"
    )
    prior_sigma_azimuth_offset_deg: float = Field(
        0.2, gt=0, description="prior sigma of an azimuth offset, deg (0.2 deg = 350 m at 100 km): weak"
    )
    prior_sigma_time_offset_s: float = Field(
        0.5,
        gt=0,
        description="prior sigma of a time offset, s: weak, and the value the unobservable common offset is pinned "
        "to 0 with",
    )
    residual_gate_chi2: float = Field(
        25.0,
        gt=0,
        description="squared Mahalanobis distance (2 dof) of a plot from the rest of its cluster above which it is "
        "left out. Default 25 (p = 4e-6 for a correct plot): drops mis-associations, keeps biased plots while the "
        "estimate is still far off",
    )
    track_innovations: bool = Field(
        True,
        description="learn from the tracks' innovations too (the two-stage filter of the module docstring: each "
        "track carries its sensitivity to the biases, follows the applied correction as it changes, and its "
        "innovations inform the estimate beside the clusters' differences). On the bench's 180 s ADS-B case, "
        "straight flight against its PCRB: biased radars 1.24 -> 1.17, the same radars without bias 1.15 -> 1.15. "
        "False: the clusters' differences alone, and the tracks keep what they learnt from plots corrected with "
        "older estimates",
    )
    innovation_gate_chi2: float = Field(
        9.21,
        gt=0,
        description="squared Mahalanobis distance (2 dof) of a track's innovation above which it is left out. "
        "Default 9.21 (p = 0.01 for a correct one): a plot of a manoeuvre the quiet model missed is no bias "
        "evidence",
    )
    innovation_quiet_prob: float = Field(
        0.9,
        ge=0,
        le=1,
        description="the IMM's probability of its quiet mode at or above which a track's innovation is used "
        "(the Singer filter: no manoeuvre detected). Default 0.9",
    )
    use_plots_without_altitude: bool = Field(
        False,
        description="use plots without Mode C. Default off: their ground range rests on an assumed height, an error "
        "that is systematic per aircraft and would be taken for a range bias",
    )
    max_clusters_per_update: int = Field(
        1000,
        ge=1,
        description="multi-radar clusters used per period at most (a rotating subset beyond, so every aircraft "
        "contributes in turn), and as many tracks' innovations (track_innovations). Default 1000: with a 30-minute "
        "memory that is far more information than the noise needs, and it bounds the cost per period (about 15 ms "
        "at 40,000 plots) whatever the traffic",
    )
    reference_radar_id: str | None = Field(
        None,
        description="a radar whose biases are fixed at 0 (surveyed, or calibrated against ADS-B); the others are "
        "then estimated relative to it. Default none: every radar carries the weak prior",
    )


def _wrap_pi(a: NDArray[np.float64]) -> NDArray[np.float64]:
    wrapped: NDArray[np.float64] = np.mod(a + np.pi, 2.0 * np.pi) - np.pi
    return wrapped


def _group_sum(keys: NDArray[np.intp], values: NDArray[np.float64], n_groups: int) -> NDArray[np.float64]:
    """Sum ``values`` (n, ...) over equal ``keys`` -> (n_groups, ...), one bincount per element."""
    flat = values.reshape(values.shape[0], int(np.prod(values.shape[1:])))
    out = np.empty((n_groups, flat.shape[1]))
    for col in range(flat.shape[1]):  # over matrix elements (<= 16), not plots
        out[:, col] = np.bincount(keys, weights=flat[:, col], minlength=n_groups)
    return out.reshape((n_groups,) + values.shape[1:])


def _compact(labels: NDArray[np.intp]) -> tuple[NDArray[np.intp], int]:
    """Non-negative labels renumbered 0..k-1 in their order; returns (labels, k)
    (association.unique_inverse: one bincount for the engine's compact cluster indices)."""
    present, new = unique_inverse(labels)
    return new.astype(np.intp), int(present.size)


def _inv_2x2(m: NDArray[np.float64]) -> NDArray[np.float64]:
    a, b, c, d = m[:, 0, 0], m[:, 0, 1], m[:, 1, 0], m[:, 1, 1]
    det = a * d - b * c
    inv = np.empty_like(m)
    inv[:, 0, 0], inv[:, 0, 1], inv[:, 1, 0], inv[:, 1, 1] = d / det, -b / det, -c / det, a / det
    return inv


def _chol_2x2(m: NDArray[np.float64]) -> NDArray[np.float64]:
    """Lower Cholesky factor L (L L^T = m) of a stack of SPD 2x2 matrices."""
    l11 = np.sqrt(m[:, 0, 0])
    l21 = m[:, 1, 0] / l11
    l22 = np.sqrt(np.maximum(m[:, 1, 1] - l21 * l21, 0.0))
    out = np.zeros_like(m)
    out[:, 0, 0], out[:, 1, 0], out[:, 1, 1] = l11, l21, l22
    return out


class RegistrationGeometry:
    """The per-radar constants of the linearisation: site positions and meridian convergence
    in the system plane, the site's Gaussian earth radius and the plane's sphere radius."""

    def __init__(self, plane: SystemPlane, sites: RadarSites) -> None:
        self.plane = plane
        self.sites = sites
        self.site_x_m, self.site_y_m = sites.plane_positions(plane)
        self.site_convergence_rad = np.radians(plane.grid_convergence_deg(sites.lat_deg, sites.lon_deg))
        self.sphere_radius_m = float(gaussian_earth_radius_m(plane.center_lat_deg))

    def jacobian(
        self,
        radar_index: npt.ArrayLike,
        range_m: npt.ArrayLike,
        azimuth_deg: npt.ArrayLike,
        altitude_m: npt.ArrayLike,
        x_m: npt.ArrayLike,
        y_m: npt.ArrayLike,
        velocity_mps: npt.ArrayLike | None = None,
        assumed_altitude_m: float = 3000.0,
    ) -> NDArray[np.float64]:
        """J (n, 2, 4): d(x_m, y_m)/d(range_offset_m, range_gain_ppm, azimuth_offset_deg, time_offset_s)
        of plots at plane positions (x_m, y_m) (module docstring). ``altitude_m`` NaN: the
        engine's ``assumed_altitude_m`` is used, as polar_to_plane does. ``velocity_mps`` (n, 2)
        is the velocity the plot was aligned in time with; None gives a zero time column.
        Plots in the cone of silence (no valid ground range) get NaN rows."""
        idx = self.sites.check_index(radar_index)
        rho = np.asarray(range_m, dtype=float)
        theta = np.radians(np.asarray(azimuth_deg, dtype=float))
        h_t = np.asarray(altitude_m, dtype=float)
        h_t = np.where(np.isfinite(h_t), h_t, assumed_altitude_m)
        x = np.asarray(x_m, dtype=float)
        y = np.asarray(y_m, dtype=float)
        r_site_m = self.sites.earth_radius_m[idx]
        ground_m, valid, dg_drho, _ = slant_to_ground_range(r_site_m, self.sites.alt_m[idx], h_t, rho)
        dx, dy = x - self.site_x_m[idx], y - self.site_y_m[idx]
        beta_site = theta - self.site_convergence_rad[idx]
        beta_chord = np.arctan2(dx, dy)
        beta = np.where(ground_m > 0.0, beta_chord + _wrap_pi(beta_chord - beta_site), beta_site)
        k = 1.0 + (x * x + y * y) / (4.0 * self.sphere_radius_m**2)
        radial = np.stack([np.sin(beta), np.cos(beta)], axis=-1)  # u
        cross = np.stack([np.cos(beta), -np.sin(beta)], axis=-1)  # w
        d_range = (k * dg_drho)[:, None] * radial
        jac = np.zeros((idx.shape[0], 2, N_BIAS))
        jac[:, :, RANGE_OFFSET] = d_range
        jac[:, :, RANGE_GAIN] = d_range * (rho * _PPM)[:, None]
        jac[:, :, AZIMUTH_OFFSET] = (k * r_site_m * np.sin(ground_m / r_site_m) * np.pi / 180.0)[:, None] * cross
        if velocity_mps is not None:
            jac[:, :, TIME_OFFSET] = -np.asarray(velocity_mps, dtype=float).reshape(-1, 2)
        jac[~valid] = np.nan
        return jac


class RadarRegistration:
    """Recursive estimate of every radar's range offset, range gain, azimuth offset and time
    offset (module docstring for the model, the equations and the observability).

    Per period, after clustering and time alignment: :meth:`update` with the period's plots
    and their cluster labels. Before converting the next period's plots: :meth:`correct`.
    :meth:`estimates` gives the values and sigmas per radar for the health message.
    """

    def __init__(self, params: RegistrationParams, plane: SystemPlane, sites: RadarSites) -> None:
        self.params = params
        self.geometry = RegistrationGeometry(plane, sites)
        self.n_radars = len(sites)
        self.ids = sites.ids
        n_state = N_BIAS * self.n_radars
        prior_sigma = np.array(
            [
                params.prior_sigma_range_offset_m,
                params.prior_sigma_range_gain_ppm,
                params.prior_sigma_azimuth_offset_deg,
                params.prior_sigma_time_offset_s,
            ]
        )
        prior_info = np.tile(1.0 / prior_sigma**2, (self.n_radars, 1))
        if params.reference_radar_id is not None:
            prior_info[sites.index_of(params.reference_radar_id)] *= _PINNED_PRIOR_FACTOR
        self.prior_information = np.diag(prior_info.reshape(n_state))
        self.information = self.prior_information.copy()  # Lambda_k
        self.information_vector = np.zeros(n_state)  # eta_k
        self.bias = np.zeros((self.n_radars, N_BIAS))  # b_k, rows = radars, columns = BIAS_NAMES
        self.sigma = np.tile(prior_sigma, (self.n_radars, 1))
        self.refresh_covariance()  # covariance: of b (4M, 4M), Λ⁻¹
        self.effective_plots = np.zeros(self.n_radars)  # forgetting-weighted count of plots used
        self.t_last_s: float | None = None
        self.updates = 0
        self.plots_used = 0
        self.plots_gated = 0
        self.innovations_used = 0
        self.innovations_gated = 0

    # ----------------------------------------------------------------- estimate
    def update(
        self,
        t_s: float,
        radar_index: npt.ArrayLike,
        range_m: npt.ArrayLike,
        azimuth_deg: npt.ArrayLike,
        altitude_m: npt.ArrayLike,
        xy_m: npt.ArrayLike,
        cov_m2: npt.ArrayLike,
        labels: npt.ArrayLike,
        velocity_mps: npt.ArrayLike | None = None,
        applied: npt.ArrayLike | None = None,
        assumed_altitude_m: float = 3000.0,
    ) -> int:
        """One period. Per plot (n,): ``radar_index``; ``range_m``, ``azimuth_deg`` as converted
        (corrected ones if a correction was applied); ``altitude_m`` (NaN without Mode C);
        ``xy_m`` (n, 2) the plane position aligned to its cluster's time and ``cov_m2``
        (n, 2, 2) its covariance (alignment included); ``labels`` the cluster of each plot, -1
        for a plot not to use (pass only clusters of established tracks); ``velocity_mps``
        (n, 2) the velocity the plot was aligned with (None: no time offset information);
        ``applied`` (M, 4) the biases :meth:`correct` removed from these plots (None: raw
        plots). ``t_s`` is the period's time, for the forgetting. Returns the plots used."""
        if not self.params.enabled:
            return 0
        idx = self.geometry.sites.check_index(radar_index).reshape(-1)
        lab = np.asarray(labels).astype(np.intp).reshape(-1)
        z = np.asarray(xy_m, dtype=float).reshape(-1, 2)
        cov = np.asarray(cov_m2, dtype=float).reshape(-1, 2, 2)
        rho = np.asarray(range_m, dtype=float).reshape(-1)
        az = np.asarray(azimuth_deg, dtype=float).reshape(-1)
        alt = np.asarray(altitude_m, dtype=float).reshape(-1)
        vel = None
        if velocity_mps is not None and self.params.estimate_time_offset:
            vel = np.asarray(velocity_mps, dtype=float).reshape(-1, 2)
        self._forget(float(t_s))
        self.updates += 1

        use = (lab >= 0) & np.all(np.isfinite(z), axis=1) & np.all(np.isfinite(cov), axis=(1, 2))
        use &= np.isfinite(rho) & np.isfinite(az)
        if not self.params.use_plots_without_altitude:
            use &= np.isfinite(alt)
        if vel is not None:
            use &= np.all(np.isfinite(vel), axis=1)
        sel = np.flatnonzero(use)
        c, k_clusters = _compact(lab[sel])
        multi = self._multi_radar(c, idx[sel], k_clusters)
        sel, c = sel[multi], c[multi]
        c, k_clusters = _compact(c)
        part = self.rotating_subset(c, k_clusters)
        if part is not None:
            sel, c = sel[part], c[part]
            c, k_clusters = _compact(c)
        jac = self.geometry.jacobian(
            idx[sel],
            rho[sel],
            az[sel],
            alt[sel],
            z[sel, 0],
            z[sel, 1],
            None if vel is None else vel[sel],
            assumed_altitude_m,
        )
        ok = np.all(np.isfinite(jac), axis=(1, 2))
        sel, jac, c = sel[ok], jac[ok], c[ok]
        r, z, w = idx[sel], z[sel], _inv_2x2(cov[sel])
        if applied is not None:  # back to the raw plot (to first order): z_raw = z_corrected + J b_applied
            z = z + np.einsum("nab,nb->na", jac, np.asarray(applied, dtype=float).reshape(self.n_radars, N_BIAS)[r])
        # each cluster's plots shifted by their mean (numerics only: the elimination of p_c is
        # invariant to a shift per cluster)
        n_c = np.bincount(c, minlength=k_clusters)
        z = z - (_group_sum(c, z, k_clusters) / np.maximum(n_c, 1)[:, None])[c]

        keep = self._multi_radar(c, r, k_clusters)
        if keep.any():  # leave-one-out residual gate, at the current estimate
            d2 = self._leave_one_out_d2(c, z - np.einsum("nab,nb->na", jac, self.bias[r]), w, k_clusters)
            gated = keep & ~(d2 <= self.params.residual_gate_chi2)
            self.plots_gated += int(gated.sum())
            keep &= ~gated
            keep &= self._multi_radar(c, r, k_clusters, keep)
        n_used = int(keep.sum())
        if n_used:
            info, vec = self._normal_equations(c[keep], r[keep], z[keep], w[keep], jac[keep], k_clusters)
            self.information += info
            self.information_vector += vec
            self.effective_plots += np.bincount(r[keep], minlength=self.n_radars)
            self.plots_used += n_used
        self._solve()
        return n_used

    def update_from_innovations(
        self,
        t_s: float,
        cluster_sens: ClusterSensitivity,
        clusters: NDArray[np.intp],
        track_sens: NDArray[np.float64],
        rows: NDArray[np.intp],
        innovation_m: npt.ArrayLike,
        cov_m2: npt.ArrayLike,
        applied: npt.ArrayLike | None = None,
    ) -> int:
        """Tracks' innovations (the two-stage section of the module docstring). Per track
        (n,): its fused measurement's sensitivity F, of cluster ``clusters`` in
        ``cluster_sens`` (:func:`cluster_sensitivity`), and its own B = ``track_sens[rows]``
        ((.., 2, M, 4));
        ``innovation_m`` (n, 2) the fused measurement minus the track's predicted position
        (the plots corrected by ``applied`` (M, 4), the track following it) and ``cov_m2``
        (n, 2, 2) the innovation's covariance P^-_pp + R_f without the biases'. Each is
        gated first against what the estimate so far predicts of it, y - m b, y = nu + m c
        and m = F - B, with covariance S + m Cov(b) m^T (the bias still unknown is part of
        the innovation: an innovation carrying a large bias is no outlier before the bias is
        learnt), at ``innovation_gate_chi2``. Those inside add m^T S^-1 m to the information
        and m^T S^-1 y to its vector. Returns the innovations used."""
        if not self.params.enabled or not self.params.track_innovations:
            return 0
        self._forget(float(t_s))
        nu = np.ascontiguousarray(innovation_m, dtype=float).reshape(-1, 2)
        n = nu.shape[0]
        if not n:
            return 0
        n_state = N_BIAS * self.n_radars
        c = np.zeros(n_state) if applied is None else np.asarray(applied, dtype=float).reshape(n_state)
        m = _innovation_sensitivity(
            cluster_sens.values,
            cluster_sens.radars,
            np.asarray(clusters, np.intp),
            track_sens,
            np.asarray(rows, np.intp),
            -1 if self.params.estimate_time_offset else TIME_OFFSET,
        )  # (n, 2, 4M)
        if self.time_offsets_relative and self.params.estimate_time_offset:
            # the clock offset common to every radar is not observable (module docstring): the
            # innovations must not inform it. m's time columns are only nearly balanced (F's
            # with the alignment velocity, B's without the velocity's own sensitivity), and
            # thousands of them pulled the common offset by 0.1-1.7 s: taken out exactly.
            t_cols = m[:, :, TIME_OFFSET::N_BIAS]
            t_cols -= t_cols.mean(axis=2, keepdims=True)
        s = np.asarray(cov_m2, dtype=float).reshape(n, 2, 2)
        y = nu + m @ c
        predicted = s + np.einsum("nak,nbk->nab", m @ self.covariance, m)
        r = y - m @ self.bias.reshape(n_state)
        ok = np.all(np.isfinite(y), axis=1) & np.all(np.isfinite(s), axis=(1, 2)) & np.all(np.isfinite(m), axis=(1, 2))
        ok &= (s[:, 0, 0] > 0.0) & (s[:, 0, 0] * s[:, 1, 1] - s[:, 0, 1] * s[:, 1, 0] > 0.0)  # positive definite
        d2 = np.full(n, np.inf)
        d2[ok] = np.einsum("na,nab,nb->n", r[ok], _inv_2x2(predicted[ok]), r[ok])
        inside = (d2 >= 0.0) & (d2 <= self.params.innovation_gate_chi2)
        self.innovations_gated += int(np.count_nonzero(~inside))
        n_used = int(np.count_nonzero(inside))
        if n_used:
            lt = np.swapaxes(_chol_2x2(_inv_2x2(s[inside])), 1, 2)  # S^-1 = L L^T: L^T m, L^T y
            g = (lt @ m[inside]).reshape(2 * n_used, n_state)
            h = np.einsum("nab,nb->na", lt, y[inside]).reshape(2 * n_used)
            self.information += g.T @ g
            self.information_vector += g.T @ h
            self.innovations_used += n_used
            self._solve()
        return n_used

    def rotating_subset(self, keys: NDArray[np.intp], n: int) -> NDArray[np.bool_] | None:
        """Of ``n`` items (clusters, or tracks' innovations) with integer ``keys``, those this
        update takes when there are more than ``max_clusters_per_update``: every stride-th
        key, the stride's phase moving with each update, so that every aircraft contributes
        in turn. None: all of them."""
        stride = -(-n // self.params.max_clusters_per_update)  # ceil
        if stride <= 1:
            return None
        out: NDArray[np.bool_] = (keys + self.updates) % stride == 0
        return out

    def _forget(self, t_s: float) -> None:
        """Lambda <- lam Lambda + (1 - lam) Lambda_0, eta <- lam eta, lam = exp(-dt / tau)."""
        dt_s = 0.0 if self.t_last_s is None else max(t_s - self.t_last_s, 0.0)
        self.t_last_s = t_s if self.t_last_s is None else max(t_s, self.t_last_s)
        lam = float(np.exp(-dt_s / self.params.forgetting_time_s))
        self.information = lam * self.information + (1.0 - lam) * self.prior_information
        self.information_vector *= lam
        self.effective_plots *= lam

    def _multi_radar(
        self, c: NDArray[np.intp], r: NDArray[np.intp], k: int, mask: NDArray[np.bool_] | None = None
    ) -> NDArray[np.bool_]:
        """Plots (of ``mask``) whose cluster holds plots (of ``mask``) of at least two radars."""
        m = np.ones(c.shape[0], bool) if mask is None else mask
        seen = np.zeros(k * self.n_radars, bool)
        seen[c[m] * self.n_radars + r[m]] = True
        n_radars_in = seen.reshape(k, self.n_radars).sum(axis=1)
        out: NDArray[np.bool_] = m & (n_radars_in[c] >= 2)
        return out

    @staticmethod
    def _leave_one_out_d2(
        c: NDArray[np.intp], e: NDArray[np.float64], w: NDArray[np.float64], k: int
    ) -> NDArray[np.float64]:
        """d_i^T (R_i + S_{-i}^-1)^-1 d_i, d_i = e_i - S_{-i}^-1 (m_c - W_i e_i): each plot against
        the fused position of the rest of its cluster (inf for a plot alone in its cluster)."""
        s_c = _group_sum(c, w, k)
        we = np.einsum("nab,nb->na", w, e)
        m_c = _group_sum(c, we, k)
        s_rest = s_c[c] - w
        det = s_rest[:, 0, 0] * s_rest[:, 1, 1] - s_rest[:, 0, 1] * s_rest[:, 1, 0]
        alone = ~(det > 1e-12 * np.einsum("naa->n", s_c[c]) ** 2)
        s_rest[alone] = np.eye(2)
        p_rest_cov = _inv_2x2(s_rest)
        d = e - np.einsum("nab,nb->na", p_rest_cov, m_c[c] - we)
        d2: NDArray[np.float64] = np.einsum("na,nab,nb->n", d, _inv_2x2(_inv_2x2(w) + p_rest_cov), d)
        d2[alone] = np.inf
        return d2

    def _normal_equations(
        self,
        c: NDArray[np.intp],
        r: NDArray[np.intp],
        z: NDArray[np.float64],
        w: NDArray[np.float64],
        jac: NDArray[np.float64],
        k: int,
    ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """sum_c I_c and sum_c y_c of the module docstring, with p_c eliminated (Schur complement).
        ``c`` need not be compact (clusters left empty by the gate are dropped here)."""
        m, n_state = self.n_radars, N_BIAS * self.n_radars
        c, k = _compact(c)
        wj = w @ jac  # W_i J_i, (n, 2, 4)
        jt = np.swapaxes(jac, 1, 2)
        info = np.zeros((n_state, n_state))
        diag_blocks = _group_sum(r, jt @ wj, m)  # sum_i J_i^T W_i J_i per radar, (M, 4, 4)
        for i in range(m):  # over radars, not plots
            info[i * N_BIAS : (i + 1) * N_BIAS, i * N_BIAS : (i + 1) * N_BIAS] = diag_blocks[i]
        vec = _group_sum(r, np.einsum("nba,nb->na", wj, z), m).reshape(n_state)  # sum_i J_i^T W_i z_i
        t_blocks = _group_sum(c * m + r, wj, k * m).reshape(k, m, 2, N_BIAS)  # T_c by radar block
        t_c = np.transpose(t_blocks, (0, 2, 1, 3)).reshape(k, 2, n_state)
        s_c = _group_sum(c, w, k)
        m_c = _group_sum(c, np.einsum("nab,nb->na", w, z), k)
        chol = _chol_2x2(_inv_2x2(s_c))  # S_c^-1 = L L^T
        lt = np.swapaxes(chol, 1, 2)
        g = (lt @ t_c).reshape(2 * k, n_state)  # L^T T_c, stacked
        h = np.einsum("kab,kb->ka", lt, m_c).reshape(2 * k)  # L^T m_c
        info -= g.T @ g
        vec -= g.T @ h
        return 0.5 * (info + info.T), vec

    def refresh_covariance(self) -> None:
        """``covariance`` = Λ⁻¹ of the current information (after :meth:`update`, and after a
        restart loads the information: engine/state.py)."""
        cov = np.linalg.inv(self.information)
        self.covariance = 0.5 * (cov + cov.T)

    def _solve(self) -> None:
        self.refresh_covariance()
        cov = self.covariance
        self.bias = (cov @ self.information_vector).reshape(self.n_radars, N_BIAS)
        self.sigma = np.sqrt(np.maximum(np.diag(cov), 0.0)).reshape(self.n_radars, N_BIAS)
        if self.time_offsets_relative:
            # the common time offset is unobservable and pinned to 0 by the prior (module docs):
            # the time offsets are relative to the radars' mean, and so is their sigma
            t_cols = np.arange(self.n_radars) * N_BIAS + TIME_OFFSET
            centre = np.eye(self.n_radars) - 1.0 / self.n_radars
            cov_rel = centre @ cov[np.ix_(t_cols, t_cols)] @ centre
            self.sigma[:, TIME_OFFSET] = np.sqrt(np.maximum(np.diag(cov_rel), 0.0))
        if not self.params.estimate_time_offset:
            self.bias[:, TIME_OFFSET] = 0.0

    @property
    def time_offsets_relative(self) -> bool:
        """Without a reference radar the common time offset is not observable (module docs):
        the time offsets and their sigmas (``_solve``) are those relative to the radars' mean."""
        return self.params.reference_radar_id is None and self.n_radars > 1

    def _bias_as_seen(self) -> NDArray[np.float64]:
        """(M, 4) the estimate as the data show it: the time offsets relative to the radars'
        mean where they are known only so (:attr:`time_offsets_relative`), as their sigmas are."""
        b = self.bias.copy()
        if self.time_offsets_relative:
            b[:, TIME_OFFSET] -= b[:, TIME_OFFSET].mean()
        return b

    # ----------------------------------------------------------------- correct
    def applied_mask(self) -> NDArray[np.bool_]:
        """(M,) radars whose correction is applied: enabled and at least ``min_plots`` plots."""
        out: NDArray[np.bool_] = np.full(self.n_radars, self.params.enabled) & (
            self.effective_plots >= self.params.min_plots
        )
        return out

    def applied_share(self) -> NDArray[np.float64]:
        """(M,) the share of each radar's estimate :meth:`correction` removes: the positive-part
        James-Stein factor (James & Stein 1961; Efron & Morris 1973) of its p estimated
        components (4, or 3 without the time offset) against their sigmas,

            s_r = max(0, 1 − (p − 2) / d²_r),   d²_r = Σ_j (b_rj / σ_rj)²,

        with ``james_stein``, else 1. An estimate within its noise of 0 is applied little or
        not at all (unbiased radars: its full value added its own noise to every plot), a
        significant one almost whole; the factor dominates the estimate itself in mean squared
        error for p ≥ 3. 0 for radars not yet applied (:meth:`applied_mask`). Without a
        reference radar a time offset's b_rj and σ_rj are those relative to the radars' mean,
        as in :meth:`gain_and_time_as_seen`: σ_rj is the relative sigma (``_solve``), and a
        common offset, which the data do not show, must not make a radar's estimate look
        significant against it."""
        share = np.where(self.applied_mask(), 1.0, 0.0)
        if not self.params.james_stein:
            return share
        on = np.ones(N_BIAS, bool)
        on[TIME_OFFSET] = self.params.estimate_time_offset
        b = self._bias_as_seen()
        with np.errstate(divide="ignore", invalid="ignore"):
            d2 = np.sum(np.where(self.sigma[:, on] > 0, (b[:, on] / self.sigma[:, on]) ** 2, 0.0), axis=1)
            factor = np.where(d2 > 0, np.clip(1.0 - (int(on.sum()) - 2) / d2, 0.0, 1.0), 0.0)
        out: NDArray[np.float64] = share * factor
        return out

    def correction(self) -> NDArray[np.float64]:
        """(M, 4) biases :meth:`correct` removes now: each radar's estimate (with
        ``empirical_bayes_gain_time``, :meth:`gain_and_time_as_seen`) times its
        :meth:`applied_share` (zero rows for radars not yet applied)."""
        bias = self.gain_and_time_as_seen() if self.params.empirical_bayes_gain_time else self.bias
        out: NDArray[np.float64] = bias * self.applied_share()[:, None]
        return out

    def gain_and_time_as_seen(self) -> NDArray[np.float64]:
        """(M, 4) the estimate with each range gain and time offset given a zero-mean prior of
        the variance the data show, an empirical Bayes estimate (Efron & Morris 1973; Carlin &
        Louis 2000 §3.3): from the estimate b_k and its variance σ_k² (the diagonal of Λ⁻¹),

            τ_k² = max(0, b_k² − σ_k²),        b_EB = (Λ + D)⁻¹ η,   D = diag(1 / τ_k²),

        D being 0 on the range and azimuth offsets (left as estimated). Without a reference
        radar a time offset's b and σ are those relative to the radars' mean (the common
        offset is not observable, and the absolute σ is the prior's). A component with
        τ_k² = 0 (within its noise of 0) is held at 0 (infinite precision: it is dropped from
        the system, and the others are solved given it), as is a time offset not estimated.
        A component well above its noise is barely moved (τ² ≫ σ² adds little precision)."""
        b = self.bias.reshape(-1)
        b_seen, var_seen = self._bias_as_seen().reshape(-1), np.diag(self.covariance).copy()
        if self.time_offsets_relative:  # their significance is that of the relative offsets
            t_cols = np.arange(self.n_radars) * N_BIAS + TIME_OFFSET
            var_seen[t_cols] = self.sigma[:, TIME_OFFSET] ** 2
        tau2 = np.maximum(b_seen * b_seen - var_seen, 0.0)
        extra = np.tile(np.isin(np.arange(N_BIAS), [RANGE_GAIN, TIME_OFFSET]), self.n_radars)
        held = extra & (tau2 <= 1e-9 * var_seen)
        if not self.params.estimate_time_offset:
            held |= np.tile(np.arange(N_BIAS) == TIME_OFFSET, self.n_radars)
        keep = np.flatnonzero(~held)
        soft = extra & ~held  # a gain or time offset the data show: its prior's precision 1/τ²
        precision = np.zeros(b.size)
        precision[soft] = 1.0 / tau2[soft]
        out = np.zeros(b.size)
        out[keep] = np.linalg.solve(
            self.information[np.ix_(keep, keep)] + np.diag(precision[keep]), self.information_vector[keep]
        )
        return out.reshape(self.n_radars, N_BIAS)

    def correct(
        self,
        radar_index: npt.ArrayLike,
        range_m: npt.ArrayLike,
        azimuth_deg: npt.ArrayLike,
        t_s: npt.ArrayLike | None = None,
        bias: npt.ArrayLike | None = None,
    ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64] | None]:
        """Remove the biases (``bias`` (M, 4), default :meth:`correction`) from raw plots:
        rho = (rho_m - range_offset) / (1 + gain), theta = theta_m - azimuth_offset (in [0, 360)),
        t = t_m - time_offset. Returns (range_m, azimuth_deg, t_s or None)."""
        b = self.correction() if bias is None else np.asarray(bias, dtype=float).reshape(self.n_radars, N_BIAS)
        idx = self.geometry.sites.check_index(radar_index)
        rb = b[idx]
        rho = (np.asarray(range_m, dtype=float) - rb[..., RANGE_OFFSET]) / (1.0 + rb[..., RANGE_GAIN] * _PPM)
        az = np.mod(np.asarray(azimuth_deg, dtype=float) - rb[..., AZIMUTH_OFFSET], 360.0)
        az = np.where(az >= 360.0, 0.0, az)
        t = None if t_s is None else np.asarray(t_s, dtype=float) - rb[..., TIME_OFFSET]
        return rho, az, t

    # ----------------------------------------------------------------- report
    def estimates(self) -> dict[str, dict[str, Any]]:
        """Per radar id: each bias and its 1-sigma (``<name>`` and ``<name>_sigma``, time offset None
        when not estimated; without a reference radar the time offsets and their sigmas are
        relative to the radars' mean), the effective plot count, whether the correction is
        applied and the share of the estimate it removes (:meth:`applied_share`), and what the
        correction removes of each (``applied_<name>``, :meth:`correction`: with
        ``empirical_bayes_gain_time`` a gain or clock offset within its noise is held at 0 and
        the others follow). Plain floats and bools: ready for the health message."""
        applied, share = self.applied_mask(), self.applied_share()
        removed = self.correction()
        out: dict[str, dict[str, Any]] = {}
        for i, rid in enumerate(self.ids):
            row: dict[str, Any] = {}
            for j, name in enumerate(BIAS_NAMES):
                on = j != TIME_OFFSET or self.params.estimate_time_offset
                row[name] = float(self.bias[i, j]) if on else None
                row[_sigma_name(name)] = float(self.sigma[i, j]) if on else None
                row[f"applied_{name}"] = float(removed[i, j]) if on else None
            row["plots"] = float(self.effective_plots[i])
            row["applied"] = bool(applied[i])
            row["applied_share"] = float(share[i])
            out[rid] = row
        return out


# ------------------------------------------------------------ the two-stage kernels (compiled)
class ClusterSensitivity(NamedTuple):
    """Each cluster's fused position's sensitivity F to the biases of the radars that saw it,
    sparse: an aircraft is seen by a few of the radars (about three of 30 at world scale).
    ``values`` (K, 2, S, 4): F's columns of the cluster's s-th radar, ``radars`` (K, S) that
    radar's index, -1 past the cluster's own (S the most radars of any one cluster). F is
    zero for every other radar."""

    values: NDArray[np.float64]
    radars: NDArray[np.intp]

    @classmethod
    def from_dense(cls, dense: NDArray[np.float64]) -> ClusterSensitivity:
        """From (K, 2, M, 4): every radar a slot of every cluster."""
        k, m = dense.shape[0], dense.shape[2]
        return cls(np.ascontiguousarray(dense, dtype=float), np.tile(np.arange(m, dtype=np.intp), (k, 1)))

    def dense(self, clusters: NDArray[np.intp], n_radars: int) -> NDArray[np.float64]:
        """F of the clusters ``clusters`` over all ``n_radars`` radars, (n, 2, M, 4)."""
        return _densify(self.values, self.radars, np.asarray(clusters, np.intp), n_radars)


def warm_up() -> None:
    """Run the compiled two-stage loops once on one plot and one track, so that they are
    compiled (or loaded from the cache) now, not in the first period (association.warm_up)."""
    values, radars = cluster_sensitivity(
        np.zeros(1, np.intp), np.zeros(1, np.intp), np.eye(2)[None].copy(), np.zeros((1, 2, N_BIAS)), 1, 1
    )
    rows = np.zeros(1, np.intp)
    track = _densify(values, radars, rows, 1)
    _innovation_sensitivity(values, radars, rows, track, rows, -1)
    update_sensitivity(
        track, rows, np.zeros((1, 1, 6, 6)), np.ones((1, 1)), np.eye(2)[None].copy(), values, radars, rows
    )


@compiled
def cluster_sensitivity(
    labels: NDArray[np.intp],
    radar: NDArray[np.intp],
    cov_m2: NDArray[np.float64],
    jac: NDArray[np.float64],
    n_clusters: int,
    n_radars: int,
) -> tuple[NDArray[np.float64], NDArray[np.intp]]:
    """F per cluster, its fused position's sensitivity to each radar's biases, S_c^-1 sum_i
    W_i J_i over its plots (W_i = cov_i^-1 the fusion's weights, Shu eq. 5-6; J_i (n, 2, 4)
    the plot's Jacobian, placed at its radar's columns), as the ``values`` and ``radars`` of
    a :class:`ClusterSensitivity`. A plot with a non-finite Jacobian row (the cone of
    silence) adds its weight but no sensitivity; a cluster whose summed weight is not a
    covariance's inverse gets none."""
    n_bias = jac.shape[2]
    n = labels.shape[0]
    slot_of = np.full((n_clusters, n_radars), -1, np.intp)
    count = np.zeros(n_clusters, np.intp)
    slot = np.empty(n, np.intp)
    for i in range(n):
        c, r = labels[i], radar[i]
        if slot_of[c, r] < 0:
            slot_of[c, r] = count[c]
            count[c] += 1
        slot[i] = slot_of[c, r]
    n_slots = max(1, count.max()) if n_clusters else 1
    radars = np.full((n_clusters, n_slots), -1, np.intp)
    for c in range(n_clusters):
        for r in range(n_radars):
            if slot_of[c, r] >= 0:
                radars[c, slot_of[c, r]] = r
    s = np.zeros((n_clusters, 2, 2))
    wj = np.zeros((n_clusters, 2, n_slots, n_bias))
    for i in range(n):
        c, k = labels[i], slot[i]
        _, w00, w01, w11 = _inv_sym_2x2(cov_m2[i, 0, 0], cov_m2[i, 0, 1], cov_m2[i, 1, 1])
        s[c, 0, 0] += w00
        s[c, 0, 1] += w01
        s[c, 1, 1] += w11
        for j in range(n_bias):
            j0, j1 = jac[i, 0, j], jac[i, 1, j]
            if math.isfinite(j0) and math.isfinite(j1):
                wj[c, 0, k, j] += w00 * j0 + w01 * j1
                wj[c, 1, k, j] += w01 * j0 + w11 * j1
    for c in range(n_clusters):
        ok, i00, i01, i11 = _inv_sym_2x2(s[c, 0, 0], s[c, 0, 1], s[c, 1, 1])
        if not ok:
            wj[c] = 0.0  # an empty cluster, or a covariance that is not one: no sensitivity known
            continue
        for k in range(n_slots):
            for j in range(n_bias):
                u, v = wj[c, 0, k, j], wj[c, 1, k, j]
                f0, f1 = i00 * u + i01 * v, i01 * u + i11 * v
                finite = math.isfinite(f0) and math.isfinite(f1)
                wj[c, 0, k, j] = f0 if finite else 0.0
                wj[c, 1, k, j] = f1 if finite else 0.0
    return wj, radars


@compiled
def _inv_sym_2x2(a: float, b: float, d: float) -> tuple[bool, float, float, float]:
    """The inverse (i00, i01, i11) of the symmetric 2x2 [[a, b], [b, d]], and whether it is
    a covariance's (det > 0, a > 0, finite): the compiled loops' one 2x2 inverse."""
    det = a * d - b * b
    return det > 0.0 and a > 0.0 and math.isfinite(det), d / det, -b / det, a / det


@compiled
def _cluster_dense(values: NDArray[np.float64], radars: NDArray[np.intp], c: int, out: NDArray[np.float64]) -> None:
    """Cluster ``c``'s F over all radars into ``out`` (2, M, 4): zero for the radars it lacks."""
    out[:] = 0.0
    for k in range(radars.shape[1]):
        r = radars[c, k]
        if r < 0:
            break
        out[:, r, :] = values[c, :, k, :]


@compiled
def _densify(
    values: NDArray[np.float64], radars: NDArray[np.intp], clusters: NDArray[np.intp], n_radars: int
) -> NDArray[np.float64]:
    """:meth:`ClusterSensitivity.dense`: (n, 2, M, 4), zero for the radars a cluster lacks."""
    out = np.empty((clusters.shape[0], 2, n_radars, values.shape[3]))
    for i in range(clusters.shape[0]):
        _cluster_dense(values, radars, clusters[i], out[i])
    return out


@compiled
def update_sensitivity(
    track_sens: NDArray[np.float64],
    rows: NDArray[np.intp],
    cov_post: NDArray[np.float64],
    weight: NDArray[np.float64],
    cov_meas: NDArray[np.float64],
    cluster_values: NDArray[np.float64],
    cluster_radars: NDArray[np.intp],
    clusters: NDArray[np.intp],
) -> None:
    """In place, per updated track: B[row] += K (F[cluster] - B[row]), K the gain of its
    update on the position, K = sum_j weight[row, j] P+_j,pp R^-1 with P+_j = ``cov_post[row,
    j]`` (6, 6) (Singer order: the position at 0 and 3; the IMM's models and their
    probabilities, or the one filter with weight 1) and R = ``cov_meas`` (n, 2, 2) the fused
    measurement's covariance (engine._update_bias_sens). F as a :class:`ClusterSensitivity`'s
    ``values`` and ``radars``."""
    n_radars, n_bias = track_sens.shape[2], track_sens.shape[3]
    f = np.zeros((2, n_radars, n_bias))
    for i in range(rows.shape[0]):
        t, c = rows[i], clusters[i]
        p00 = p01 = p11 = 0.0
        for j in range(cov_post.shape[1]):
            w = weight[t, j]
            p00 += w * cov_post[t, j, 0, 0]
            p01 += w * cov_post[t, j, 0, 3]
            p11 += w * cov_post[t, j, 3, 3]
        ok, r00, r01, r11 = _inv_sym_2x2(cov_meas[i, 0, 0], cov_meas[i, 0, 1], cov_meas[i, 1, 1])
        if not ok:
            continue  # no gain known: the track keeps its sensitivity
        k00, k01 = p00 * r00 + p01 * r01, p00 * r01 + p01 * r11
        k10, k11 = p01 * r00 + p11 * r01, p01 * r01 + p11 * r11
        if not (math.isfinite(k00) and math.isfinite(k01) and math.isfinite(k10) and math.isfinite(k11)):
            continue
        _cluster_dense(cluster_values, cluster_radars, c, f)
        for r in range(n_radars):
            for j in range(n_bias):
                e0 = f[0, r, j] - track_sens[t, 0, r, j]
                e1 = f[1, r, j] - track_sens[t, 1, r, j]
                track_sens[t, 0, r, j] += k00 * e0 + k01 * e1
                track_sens[t, 1, r, j] += k10 * e0 + k11 * e1


@compiled
def _innovation_sensitivity(
    cluster_values: NDArray[np.float64],
    cluster_radars: NDArray[np.intp],
    clusters: NDArray[np.intp],
    track_sens: NDArray[np.float64],
    rows: NDArray[np.intp],
    held_column: int,
) -> NDArray[np.float64]:
    """m = F[cluster] - B[row] per innovation, (n, 2, 4M) with the columns radar-major as the
    state's; F as a :class:`ClusterSensitivity`'s ``values`` and ``radars``. The bias column
    ``held_column`` (the time offset when it is not estimated; -1: none) is left at 0."""
    n = rows.shape[0]
    n_radars, n_bias = track_sens.shape[2], track_sens.shape[3]
    m = np.zeros((n, 2, n_radars * n_bias))
    f = np.zeros((2, n_radars, n_bias))
    for i in range(n):
        t = rows[i]
        _cluster_dense(cluster_values, cluster_radars, clusters[i], f)
        for r in range(n_radars):
            for j in range(n_bias):
                m[i, 0, r * n_bias + j] = f[0, r, j] - track_sens[t, 0, r, j]
                m[i, 1, r * n_bias + j] = f[1, r, j] - track_sens[t, 1, r, j]
        if held_column >= 0:
            for r in range(n_radars):
                m[i, 0, r * n_bias + held_column] = 0.0
                m[i, 1, r * n_bias + held_column] = 0.0
    return m


def _sigma_name(name: str) -> str:
    """range_offset_m -> range_offset_sigma_m (the unit stays last)."""
    stem, unit = name.rsplit("_", 1)
    return f"{stem}_sigma_{unit}"
