"""Tests of radar_fusion.tracking.primary_height: which track's altitude a primary plot
(no Mode C) is converted at.

Truth is built without the module's geometry: targets are placed with ``Geod.fwd``, their
true slant range is the 3-D ECEF distance on the WGS-84 ellipsoid, their azimuth comes
from ``Geod.inv``, and track positions from an independent ``sterea`` transformer.
"""

from __future__ import annotations

import numpy as np
import pyproj
import pytest

from radar_fusion.geo.coordinates import RadarSites, SystemPlane, polar_to_plane
from radar_fusion.tracking.primary_height import primary_plot_altitude

FT = 0.3048
FL = 100 * FT
LAT0, LON0 = 41.3, 2.1
GEOD = pyproj.Geod(ellps="WGS84")
TO_ECEF = pyproj.Transformer.from_crs("+proj=longlat +ellps=WGS84", "+proj=geocent +ellps=WGS84", always_xy=True)
TO_PLANE = pyproj.Transformer.from_crs(
    "EPSG:4326", f"+proj=sterea +lat_0={LAT0} +lon_0={LON0} +k=1 +x_0=0 +y_0=0 +ellps=WGS84 +units=m", always_xy=True
)
SIGMA_RHO_M, SIGMA_AZ_DEG = 50.0, 0.08


def radar(lat=LAT0, lon=LON0, alt=50.0):
    return RadarSites([lat], [lon], [alt], [SIGMA_RHO_M], [SIGMA_AZ_DEG])


def place(site_lat, site_lon, ground_m, az_deg):
    n = np.size(ground_m)
    lon, lat, _ = GEOD.fwd(np.full(n, site_lon), np.full(n, site_lat), az_deg, ground_m)
    return np.asarray(lat), np.asarray(lon)


def measure(site_lat, site_lon, site_alt, lat, lon, h):
    """What a radar measures of targets at (lat, lon, h): ECEF slant range, Geod azimuth."""
    n = np.size(lat)
    p_site = np.array(TO_ECEF.transform(np.full(n, site_lon), np.full(n, site_lat), np.full(n, site_alt)))
    p_tgt = np.array(TO_ECEF.transform(lon, lat, h))
    az, _, _ = GEOD.inv(np.full(n, site_lon), np.full(n, site_lat), lon, lat)
    return np.linalg.norm(p_tgt - p_site, axis=0), np.mod(az, 360.0)


def plane_xy(lat, lon):
    x, y = TO_PLANE.transform(lon, lat)
    return np.stack([np.asarray(x), np.asarray(y)], axis=-1).reshape(-1, 2)


def iso(n, sigma_m):
    return np.repeat((sigma_m**2 * np.eye(2))[None], n, axis=0)


def test_two_tracks_nearly_same_azimuth_each_primary_plot_gets_its_own_height():
    plane, sites = SystemPlane(LAT0, LON0), radar()
    # A FL300 and B FL200 on nearly one azimuth (slant ranges ~270 m apart, 1.7 sigma of
    # the track); C primary-only (no altitude); D elsewhere.
    g = np.array([40e3, 40.3e3, 60e3, 25e3])
    az = np.array([45.0, 45.05, 120.0, 300.0])
    h = np.array([300 * FL, 200 * FL, 250 * FL, 200 * FL])
    lat, lon = place(LAT0, LON0, g, az)
    track_alt = np.array([h[0], h[1], np.nan, h[3]])
    # Plots: A, B, C with a 1-sigma error each; a plot far from any track; a Mode C plot at A.
    rho, az_m = measure(LAT0, LON0, 50.0, lat[:3], lon[:3], h[:3])
    lat_f, lon_f = place(LAT0, LON0, [80e3], [200.0])
    rho_f, az_f = measure(LAT0, LON0, 50.0, lat_f, lon_f, [5000.0])
    plot_rho = np.concatenate([rho + SIGMA_RHO_M, rho_f, rho[:1]])
    plot_az = np.concatenate([az_m - SIGMA_AZ_DEG, az_f, az_m[:1]])
    has_c = np.array([False, False, False, False, True])
    res = primary_plot_altitude(
        plane, sites, np.zeros(5, int), plot_rho, plot_az, has_c, plane_xy(lat, lon), track_alt, iso(4, 150.0)
    )
    assert res.track_index.tolist() == [0, 1, 2, -1, -1]
    np.testing.assert_array_equal(res.altitude_m[:2], h[:2])
    assert np.all(np.isnan(res.altitude_m[2:]))

    # Converted at the picked height, the noise-free plots of A and B land within metres
    # of the aircraft; at the 10,000 ft guess A is ~900 m out and B ~350 m.
    truth = plane_xy(lat[:2], lon[:2])
    x, y, _, _ = polar_to_plane(plane, sites, [0, 0], rho[:2], az_m[:2], res.altitude_m[:2])
    assert np.max(np.hypot(x - truth[:, 0], y - truth[:, 1])) < 3.0
    xa, ya, _, _ = polar_to_plane(plane, sites, [0, 0], rho[:2], az_m[:2], [np.nan] * 2, assumed_altitude_m=10_000 * FT)
    err_a = np.hypot(xa - truth[:, 0], ya - truth[:, 1])
    assert err_a[0] > 800.0 and err_a[1] > 250.0, err_a


def test_vertical_stack_is_told_apart_by_slant_range():
    """FL350 over FL200 at one ground position 40 km out: their slant ranges differ by
    ~1 km, so each primary plot finds its own track although the tracks coincide in the plane."""
    plane, sites = SystemPlane(LAT0, LON0), radar()
    lat, lon = place(LAT0, LON0, [40e3, 40e3], [80.0, 80.0])
    h = np.array([350 * FL, 200 * FL])
    rho, az = measure(LAT0, LON0, 50.0, lat, lon, h)
    assert abs(rho[0] - rho[1]) > 900.0
    res = primary_plot_altitude(
        plane, sites, [0, 0], rho[::-1], az[::-1], [False, False], plane_xy(lat, lon), h, iso(2, 150.0)
    )
    assert res.track_index.tolist() == [1, 0]
    np.testing.assert_array_equal(res.altitude_m, h[::-1])


@pytest.mark.parametrize(("gate_sigmas", "expected"), [(1.0, 1 - np.exp(-0.5)), (2.0, 1 - np.exp(-2.0))])
def test_gate_is_a_normalised_distance_chi2_two_dof(gate_sigmas, expected):
    """Aircraft 3 degrees apart (>= 2 km, 8 sigma), FL0-FL450, 40-240 km out, each seen with
    radar noise by a track with an anisotropic position error drawn from its covariance:
    the share of plots inside a gate of g sigmas is the chi-square(2) probability
    1 - exp(-g^2 / 2), and no plot takes another aircraft's track."""
    plane, sites = SystemPlane(LAT0, LON0), radar()
    rng = np.random.default_rng(int(10 * gate_sigmas))
    sx, sy, rxy = 250.0, 120.0, 0.4
    cov = np.array([[sx**2, rxy * sx * sy], [rxy * sx * sy, sy**2]])
    az = np.arange(0.0, 360.0, 3.0)
    n = az.size
    matched = []
    for _scene in range(20):
        g = rng.uniform(40e3, 240e3, n)
        h = rng.uniform(0.0, 450 * FL, n)
        lat, lon = place(LAT0, LON0, g, az + rng.uniform(-0.2, 0.2, n))
        rho, az_m = measure(LAT0, LON0, 50.0, lat, lon, h)
        rho = rho + rng.normal(0.0, SIGMA_RHO_M, n)
        az_m = az_m + rng.normal(0.0, SIGMA_AZ_DEG, n)
        xy = plane_xy(lat, lon) + rng.multivariate_normal(np.zeros(2), cov, n)
        res = primary_plot_altitude(
            plane,
            sites,
            np.zeros(n, int),
            rho,
            az_m,
            np.zeros(n, bool),
            xy,
            h,
            np.repeat(cov[None], n, axis=0),
            gate_sigmas=gate_sigmas,
        )
        ok = res.track_index >= 0
        assert np.all(res.track_index[ok] == np.flatnonzero(ok))  # never another aircraft's track
        matched.append(ok)
    share = np.concatenate(matched)
    se = np.sqrt(expected * (1 - expected) / share.size)
    assert abs(share.mean() - expected) < 4.0 * se, (share.mean(), expected, se)


def test_primary_only_track_keeps_its_plots_whatever_their_height():
    plane, sites = SystemPlane(LAT0, LON0), radar()
    # C: a primary-only track (no altitude) 60 km out; E: FL300, 3 km beyond it on the same azimuth.
    lat, lon = place(LAT0, LON0, [60e3, 63e3], [200.0, 200.0])
    heights = np.array([0.0, 150 * FL, 300 * FL, 450 * FL])
    rho, az = measure(LAT0, LON0, 50.0, np.repeat(lat[:1], 4), np.repeat(lon[:1], 4), heights)
    rho_e, az_e = measure(LAT0, LON0, 50.0, lat[1:], lon[1:], [300 * FL])
    res = primary_plot_altitude(
        plane,
        sites,
        np.zeros(5, int),
        np.concatenate([rho, rho_e]),
        np.concatenate([az, az_e]),
        np.zeros(5, bool),
        plane_xy(lat, lon),
        [np.nan, 300 * FL],
        iso(2, 150.0),
    )
    assert res.track_index.tolist() == [0, 0, 0, 0, 1]
    assert np.all(np.isnan(res.altitude_m[:4])) and res.altitude_m[4] == 300 * FL


def test_plot_time_offset_uses_the_track_velocity():
    """A track at 250 m/s outbound predicted to the period time; its plot is 4 s later,
    1 km further out: it gates only when the motion over those 4 s is accounted for."""
    plane, sites = SystemPlane(LAT0, LON0), radar()
    lat, lon = place(LAT0, LON0, [50e3, 51e3], [10.0, 10.0])
    xy = plane_xy(lat, lon)
    vel = (xy[1] - xy[0]) / 4.0  # 250 m/s along the radial
    assert np.linalg.norm(vel) == pytest.approx(250.0, rel=0.01)
    rho, az = measure(LAT0, LON0, 50.0, lat[1:], lon[1:], [300 * FL])
    common = (plane, sites, [0], rho, az, [False], xy[:1], [300 * FL], iso(1, 100.0))
    moving = primary_plot_altitude(*common, track_velocity_mps=vel[None], plot_dt_s=[4.0])
    assert moving.track_index.tolist() == [0]
    assert primary_plot_altitude(*common).track_index.tolist() == [-1]


def test_wrap_at_north_and_edge_cases():
    plane, sites = SystemPlane(LAT0, LON0), radar()
    lat, lon = place(LAT0, LON0, [30e3], [359.97])
    rho, az = measure(LAT0, LON0, 50.0, lat, lon, [200 * FL])
    xy = plane_xy(lat, lon)
    res = primary_plot_altitude(plane, sites, [0], rho, np.mod(az + 0.05, 360.0), [False], xy, [200 * FL], iso(1, 150))
    assert res.track_index.tolist() == [0] and res.altitude_m[0] == 200 * FL
    # No tracks; only NaN tracks; NaN plot; all plots with Mode C.
    empty = primary_plot_altitude(plane, sites, [0], rho, az, [False], np.empty((0, 2)), [], np.empty((0, 2, 2)))
    assert empty.track_index.tolist() == [-1] and np.isnan(empty.altitude_m[0])
    nan_tr = primary_plot_altitude(plane, sites, [0], rho, az, [False], [[np.nan, np.nan]], [1.0], iso(1, 150))
    assert nan_tr.track_index.tolist() == [-1]
    nan_plot = primary_plot_altitude(
        plane, sites, [0, 0], [np.nan, rho[0]], [0.0, az[0]], [False, True], xy, [1.0], iso(1, 150)
    )
    assert nan_plot.track_index.tolist() == [-1, -1]
    with pytest.raises(ValueError):
        primary_plot_altitude(plane, sites, [0, 0], rho, az, [False], xy, [1.0], iso(1, 150))


def test_dense_traffic_two_radars_each_plot_its_own_track():
    """800 aircraft within 60 km of two radars 30 km apart (4 km apart on average, far
    denser than any terminal area), FL0-FL450, a fifth of the tracks without altitude,
    noisy plots and tracks: 99 % of the primary plots find their own aircraft's track (the
    rest are true ambiguities: two aircraft a few hundred metres apart at slant ranges
    within the noise), and converted at that height they land within the radar noise,
    several times closer than at the 10,000 ft guess."""
    lon1, lat1, _ = GEOD.fwd(LON0, LAT0, 90.0, 30e3)
    sites = RadarSites([LAT0, lat1], [LON0, lon1], [50.0, 400.0], [SIGMA_RHO_M] * 2, [SIGMA_AZ_DEG] * 2)
    plane = SystemPlane(LAT0, LON0)
    rng = np.random.default_rng(42)
    n = 800
    lat, lon = place(LAT0, LON0, 60e3 * np.sqrt(rng.random(n)), rng.uniform(0.0, 360.0, n))
    h = rng.uniform(0.0, 450 * FL, n)
    track_alt = np.where(rng.random(n) < 0.2, np.nan, h + rng.normal(0.0, 30.0, n))
    xy = plane_xy(lat, lon) + rng.normal(0.0, 80.0, (n, 2))
    radar_idx = np.repeat([0, 1], n)
    owner = np.tile(np.arange(n), 2)
    rho = np.empty(2 * n)
    az = np.empty(2 * n)
    for r in (0, 1):
        rr, aa = measure(sites.lat_deg[r], sites.lon_deg[r], sites.alt_m[r], lat, lon, h)
        rho[r * n : (r + 1) * n] = rr + rng.normal(0.0, SIGMA_RHO_M, n)
        az[r * n : (r + 1) * n] = aa + rng.normal(0.0, SIGMA_AZ_DEG, n)
    res = primary_plot_altitude(
        plane,
        sites,
        radar_idx,
        rho,
        az,
        np.zeros(2 * n, bool),
        xy,
        track_alt,
        iso(n, 80.0),
        track_altitude_var_m2=np.full(n, 30.0**2),
    )
    own = res.track_index == owner
    assert own.mean() > 0.99, own.mean()
    assert np.mean((res.track_index >= 0) & ~own) < 0.01
    # Conversion of the plots whose track has an altitude: at the picked height vs at 10,000 ft.
    use = own & np.isfinite(res.altitude_m)
    truth = plane_xy(lat, lon)[owner[use]]
    x, y, _, _ = polar_to_plane(plane, sites, radar_idx[use], rho[use], az[use], res.altitude_m[use])
    xa, ya, _, _ = polar_to_plane(
        plane, sites, radar_idx[use], rho[use], az[use], np.full(use.sum(), np.nan), assumed_altitude_m=10_000 * FT
    )
    rms_picked = np.sqrt(np.mean((x - truth[:, 0]) ** 2 + (y - truth[:, 1]) ** 2))
    rms_guess = np.sqrt(np.nanmean((xa - truth[:, 0]) ** 2 + (ya - truth[:, 1]) ** 2))
    # Radar noise alone: ~50 m in range, ~0.08 deg x 35 km ~ 50 m across.
    assert rms_picked < 120.0 and rms_guess > 5.0 * rms_picked, (rms_picked, rms_guess)


def test_reach_is_each_tracks_own_and_holds_every_pair_by_brute_force():
    """The candidate search (tracks grouped by reach, one k-d tree per group) returns
    exactly the pairs a brute-force loop over every (plot, track) finds within
    half + 1 km + speed |dt| + gate sqrt(spread + var), however wide a few tracks are."""
    from radar_fusion.tracking.primary_height import _within_reach

    rng = np.random.default_rng(7)
    n, m = 400, 120
    xy = rng.uniform(-300e3, 300e3, (n, 2))
    speed = rng.uniform(0.0, 300.0, n)
    spread = rng.uniform(50.0, 500.0, n) ** 2
    speed[:5] = [2e3, 5e3, 1e4, 0.0, 0.0]  # wild tentative tracks, as at 20,000 aircraft
    spread[3:8] = [3e4**2, 7e4**2, 1e3**2, 1e4**2, 5e4**2]
    pxy = rng.uniform(-300e3, 300e3, (m, 2))
    half = rng.uniform(0.0, 5e3, m)
    dt = rng.uniform(0.0, 4.0, m)
    var = rng.uniform(50.0, 900.0, m) ** 2
    pair_p, pair_t = _within_reach(xy, speed, spread, pxy, half, dt, var, 4.0)
    dist = np.hypot(xy[None, :, 0] - pxy[:, None, 0], xy[None, :, 1] - pxy[:, None, 1])
    reach = half[:, None] + 1e3 + speed[None] * dt[:, None] + 4.0 * np.sqrt(spread[None] + var[:, None])
    want = {(int(i), int(j)) for i, j in zip(*np.nonzero(dist <= reach))}
    assert set(zip(pair_p.tolist(), pair_t.tolist())) == want
    assert len(pair_p) == len(want) and np.all(np.diff(pair_p) >= 0)


def test_far_track_gated_by_the_plots_azimuth_noise_is_found():
    """340 km out, 0.1 deg of azimuth noise is 590 m across: a track 2 km across the
    plot's azimuth (3.4 sigma, inside a 4-sigma gate) must be a candidate although its own
    position spread is small; the search once reached only 1 km plus the range noise
    (1.6 km here) unless some other track widened it."""
    sites = RadarSites([LAT0], [LON0], [50.0], [SIGMA_RHO_M], [0.1])
    plane = SystemPlane(LAT0, LON0)
    lat, lon = place(LAT0, LON0, [340e3], [30.0])
    rho, az = measure(LAT0, LON0, 50.0, lat, lon, [350 * FL])
    plot_az = az + np.degrees(2.0e3 / 340e3)
    res = primary_plot_altitude(plane, sites, [0], rho, plot_az, [False], plane_xy(lat, lon), [350 * FL], iso(1, 30.0))
    assert res.track_index.tolist() == [0]
