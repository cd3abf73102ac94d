"""Tests of radar_fusion.geo.coordinates against independent computations.

The references written here do not call the module's maths: the earth radius comes from
the ellipsoid's radii of curvature, the ground range from the arccos form of the law of
cosines (the module uses the half-angle form), slant range is checked against the 3-D
distance in ECEF, the plane against geodesic distances and the stereographic scale
law, and covariances against Monte Carlo spreads of noisy measurements converted by a
converter written in this file.
"""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pyproj
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import integrate

from radar_fusion.geo.coordinates import (
    RadarSites,
    SystemPlane,
    altitude_m_to_flight_level,
    conformal_sphere_destination,
    conformal_sphere_polar,
    flight_level_to_altitude_m,
    gaussian_earth_radius_m,
    geodetic_to_polar,
    ground_to_slant_range,
    ground_velocity_to_plane,
    polar_to_plane,
)
from radar_fusion.geo.unknown_height import (
    MAX_UNKNOWN_ALTITUDE_M,
    ground_range_for_unknown_height,
    polar_to_plane_unknown_height,
    unknown_height_plots,
)

NM = 1852.0
GEOD = pyproj.Geod(ellps="WGS84")
A_M = 6378137.0
F = 1.0 / 298.257223563
E2 = F * (2.0 - F)
B_M = A_M * (1.0 - F)

CENTER_LAT, CENTER_LON = 50.0, 5.0


# --------------------------------------------------------------------------- references
def ref_radius(lat_deg):
    """sqrt(M N) from the meridian and prime-vertical radii of curvature."""
    s2 = np.sin(np.radians(lat_deg)) ** 2
    m = A_M * (1.0 - E2) / (1.0 - E2 * s2) ** 1.5
    n = A_M / np.sqrt(1.0 - E2 * s2)
    return np.sqrt(m * n)


def ref_ground_from_slant(r, h_r, h_t, rho):
    a, b = r + h_r, r + h_t
    return r * np.arccos((a * a + b * b - rho * rho) / (2.0 * a * b))


def ref_slant_from_ground(r, h_r, h_t, g):
    a, b = r + h_r, r + h_t
    return np.sqrt(a * a + b * b - 2.0 * a * b * np.cos(g / r))


def ref_transformer(lat0=CENTER_LAT, lon0=CENTER_LON):
    return pyproj.Transformer.from_crs(
        "EPSG:4326",
        f"+proj=sterea +lat_0={lat0} +lon_0={lon0} +k=1 +x_0=0 +y_0=0 +ellps=WGS84 +units=m",
        always_xy=True,
    )


def ref_polar_to_xy(tr, site_lat, site_lon, site_alt, rho, az_deg, h_t):
    """Independent conversion (no module code): arccos law of cosines, Geod.fwd, sterea."""
    n = np.size(rho)
    r = ref_radius(site_lat)
    g = ref_ground_from_slant(r, site_alt, h_t, rho)
    lon, lat, _ = GEOD.fwd(np.full(n, site_lon), np.full(n, site_lat), az_deg, g)
    x, y = tr.transform(lon, lat)
    return np.asarray(x), np.asarray(y), g


def sites_5():
    return RadarSites(
        lat_deg=[50.0, 51.8, 47.9, 52.5, 49.2],
        lon_deg=[5.0, 8.2, 3.1, 1.0, 9.9],
        alt_m=[120.0, 850.0, 15.0, 0.0, 2200.0],
        sigma_range_m=[50.0, 30.0, 70.0, 40.0, 60.0],
        sigma_azimuth_deg=[0.1, 0.07, 0.15, 0.09, 0.12],
        ids=["r0", "r1", "r2", "r3", "r4"],
    )


def site_300km_from_center():
    lon, lat, _ = GEOD.fwd(CENTER_LON, CENTER_LAT, 60.0, 300e3)
    return RadarSites([lat], [lon], [300.0], [30.0], [0.08])


def targets_from(sites, idx, ground_m, az_deg):
    lon, lat, _ = GEOD.fwd(sites.lon_deg[idx], sites.lat_deg[idx], az_deg, ground_m)
    return np.asarray(lat), np.asarray(lon)


def whitened(cov_emp, cov_model):
    l_inv = np.linalg.inv(np.linalg.cholesky(cov_model))
    return l_inv @ cov_emp @ l_inv.T


# --------------------------------------------------------------------------- earth radius
def test_gaussian_radius_known_values():
    # Equator: M = a(1-e^2), N = a -> sqrt(MN) = b. Pole: M = N = a^2/b.
    assert gaussian_earth_radius_m(0.0) == pytest.approx(B_M, abs=1e-6)
    assert gaussian_earth_radius_m(89.999999) == pytest.approx(A_M**2 / B_M, abs=1e-3)
    lats = np.linspace(-80, 80, 17)
    np.testing.assert_allclose(gaussian_earth_radius_m(lats), ref_radius(lats), rtol=1e-13)
    np.testing.assert_allclose(sites_5().earth_radius_m, ref_radius(sites_5().lat_deg), rtol=1e-13)


# --------------------------------------------------------------------------- round trips
def _grid_targets():
    sites = sites_5()
    ground = np.array([1.0, 5.0, 30.0, 100.0, 180.0, 250.0]) * NM
    az = np.arange(0.0, 360.0, 22.5) + 0.3
    alt = np.array([0.0, 500.0, 3000.0, 10668.0, 13000.0])
    i, g, a, h = np.meshgrid(np.arange(len(sites)), ground, az, alt, indexing="ij")
    i, g, a, h = i.ravel(), g.ravel(), a.ravel(), h.ravel()
    lat, lon = targets_from(sites, i, g, a)
    return sites, i, lat, lon, h, g, a


def test_round_trip_geodetic_polar_plane_geodetic_grid():
    sites, idx, lat, lon, h, g, a = _grid_targets()
    plane = SystemPlane(CENTER_LAT, CENTER_LON)
    rho, az, ground = geodetic_to_polar(sites, idx, lat, lon, h)
    x, y, cov, ground2, valid = polar_to_plane(plane, sites, idx, rho, az, h, return_valid=True)
    assert valid.all()
    lat2, lon2 = plane.to_geodetic(x, y)
    err_m = GEOD.inv(lon, lat, lon2, lat2)[2]
    assert np.max(err_m) < 1e-3
    np.testing.assert_allclose(ground2, ground, atol=1e-3)
    # The polar values themselves agree with the independent Geod/law-of-cosines route.
    np.testing.assert_allclose(ground, g, atol=1e-6)
    np.testing.assert_allclose(np.mod(az - a + 180.0, 360.0) - 180.0, 0.0, atol=1e-9)
    r = ref_radius(sites.lat_deg[idx])
    np.testing.assert_allclose(rho, ref_slant_from_ground(r, sites.alt_m[idx], h, g), atol=1e-6)
    assert np.all(np.isfinite(cov))


@settings(max_examples=60, deadline=None)
@given(
    site_lat=st.floats(-70.0, 70.0),
    site_lon=st.floats(-179.0, 179.0),
    site_alt=st.floats(0.0, 3000.0),
    slant_nm=st.floats(1.0, 250.0),
    az=st.floats(0.0, 359.999),
    alt=st.floats(0.0, 15000.0),
)
def test_round_trip_polar_plane_polar_property(site_lat, site_lon, site_alt, slant_nm, az, alt):
    rho = slant_nm * NM
    if rho <= abs(alt - site_alt) + 1.0:  # impossible geometry, covered elsewhere
        alt = site_alt
    sites = RadarSites([site_lat], [site_lon], [site_alt], [50.0], [0.1])
    # Plane centred 2 degrees away so the site is not at the centre.
    plane = SystemPlane(float(np.clip(site_lat + 2.0, -80, 80)), site_lon - 2.0)
    x, y, _, ground = polar_to_plane(plane, sites, [0], [rho], [az], [alt])
    lat, lon = plane.to_geodetic(x, y)
    rho2, az2, ground2 = geodetic_to_polar(sites, [0], lat, lon, [alt])
    assert abs(rho2[0] - rho) < 1e-3
    assert abs(ground2[0] - ground[0]) < 1e-3
    # Azimuth error expressed as a cross-range distance.
    daz = (az2[0] - az + 180.0) % 360.0 - 180.0
    assert abs(np.radians(daz) * ground[0]) < 1e-3


# --------------------------------------------------------------------------- ground range
def test_ground_range_matches_independent_spherical_formula_and_geodesic():
    sites = sites_5()
    plane = SystemPlane(CENTER_LAT, CENTER_LON)
    rng = np.random.default_rng(7)
    n = 2000
    idx = rng.integers(0, 5, n)
    rho = rng.uniform(1.0, 250.0, n) * NM
    az = rng.uniform(0.0, 360.0, n)
    h = rng.uniform(0.0, 13000.0, n)
    h = np.where(rho > np.abs(h - sites.alt_m[idx]) + 10.0, h, sites.alt_m[idx])
    x, y, _, ground = polar_to_plane(plane, sites, idx, rho, az, h)
    r = ref_radius(sites.lat_deg[idx])
    np.testing.assert_allclose(ground, ref_ground_from_slant(r, sites.alt_m[idx], h, rho), atol=1e-3)
    # The target lies at that geodesic distance and initial azimuth from the site.
    lat, lon = plane.to_geodetic(x, y)
    az_g, _, dist = GEOD.inv(sites.lon_deg[idx], sites.lat_deg[idx], lon, lat)
    np.testing.assert_allclose(dist, ground, atol=1e-3)
    np.testing.assert_allclose((az_g - az + 180.0) % 360.0 - 180.0, 0.0, atol=1e-7)
    # Textbook limit h_r = h_t = 0: the chord rho subtends g = 2 R asin(rho / 2R).
    sea = RadarSites([50.0], [5.0], [0.0], [1.0], [0.1])
    chord = np.array([10.0, 100.0, 250.0]) * NM
    _, _, _, g0 = polar_to_plane(plane, sea, [0, 0, 0], chord, [0.0, 90.0, 180.0], [0.0, 0.0, 0.0])
    r0 = ref_radius(50.0)
    np.testing.assert_allclose(g0, 2 * r0 * np.arcsin(chord / (2 * r0)), atol=1e-6)


def test_slant_range_matches_ecef_distance_on_the_ellipsoid():
    """The spherical model (Gaussian radius at the site) vs the true 3-D distance in
    ECEF between antenna and target: within 1 m out to 250 NM."""
    sites, idx, lat, lon, h, _g, _a = _grid_targets()
    rho, _, _ = geodetic_to_polar(sites, idx, lat, lon, h)
    to_ecef = pyproj.Transformer.from_crs("+proj=longlat +ellps=WGS84", "+proj=geocent +ellps=WGS84", always_xy=True)
    p_site = np.array(to_ecef.transform(sites.lon_deg[idx], sites.lat_deg[idx], sites.alt_m[idx]))
    p_tgt = np.array(to_ecef.transform(lon, lat, h))
    d = np.linalg.norm(p_tgt - p_site, axis=0)
    assert np.max(np.abs(rho - d)) < 1.0


def test_short_range_close_to_flat_earth():
    sites = RadarSites([50.0], [5.0], [100.0], [50.0], [0.1])
    plane = SystemPlane(CENTER_LAT, CENTER_LON)
    rho = np.array([5000.0, 10000.0, 20000.0])
    h = np.array([1100.0, 2100.0, 3100.0])
    _, _, _, ground = polar_to_plane(plane, sites, [0, 0, 0], rho, [10.0, 20.0, 30.0], h)
    flat = np.sqrt(rho**2 - (h - 100.0) ** 2)
    # The flat-earth leg lives at the mean height of antenna and target; brought down to
    # the sphere it shrinks by the factor R / (R + mean height): g ~ flat (1 - h_mean / R).
    shortening = flat * 0.5 * (h + 100.0) / ref_radius(50.0)
    assert np.all(shortening > 0.4)
    np.testing.assert_allclose(flat - ground, shortening, atol=0.05)


# --------------------------------------------------------------------------- the plane
def test_plane_axes_and_round_trip():
    plane = SystemPlane(CENTER_LAT, CENTER_LON)
    x, y = plane.to_plane(CENTER_LAT, CENTER_LON)
    assert abs(x) < 1e-6 and abs(y) < 1e-6
    lon_n, lat_n, _ = GEOD.fwd(CENTER_LON, CENTER_LAT, 0.0, 10e3)
    lon_e, lat_e, _ = GEOD.fwd(CENTER_LON, CENTER_LAT, 90.0, 10e3)
    xn, yn = plane.to_plane(lat_n, lon_n)
    xe, ye = plane.to_plane(lat_e, lon_e)
    assert abs(xn) < 1e-3 and yn == pytest.approx(10e3, abs=0.01)
    assert abs(ye) < 10e3 * 1e-3 and xe == pytest.approx(10e3, abs=0.01)  # east: geodesic bends
    rng = np.random.default_rng(3)
    lat = rng.uniform(44.0, 56.0, 1000)
    lon = rng.uniform(-4.0, 14.0, 1000)
    x, y = plane.to_plane(lat, lon)
    lat2, lon2 = plane.to_geodetic(x, y)
    np.testing.assert_allclose(lat2, lat, atol=1e-10)
    np.testing.assert_allclose(lon2, lon, atol=1e-10)


@pytest.mark.parametrize("dist_m", [500.0, 100e3, 300e3, 600e3])
def test_plane_local_scale_is_stereographic(dist_m):
    """Distances between nearby points in the plane vs Geod.inv: conformal (same scale in
    every direction) with k = 1 / cos^2(c / 2), c = d / R, the spherical stereographic law
    with k0 = 1 (Gaussian sphere at the centre)."""
    plane = SystemPlane(CENTER_LAT, CENTER_LON)
    bearings = np.arange(0.0, 360.0, 30.0)
    lon0, lat0, _ = GEOD.fwd(np.full(12, CENTER_LON), np.full(12, CENTER_LAT), bearings, np.full(12, dist_m))
    x0, y0 = plane.to_plane(lat0, lon0)
    k_expected = 1.0 / np.cos(dist_m / ref_radius(CENTER_LAT) / 2.0) ** 2
    for direction in (0.0, 45.0, 90.0, 135.0):
        lon1, lat1, _ = GEOD.fwd(lon0, lat0, np.full(12, direction), np.full(12, 20.0))
        x1, y1 = plane.to_plane(lat1, lon1)
        d_plane = np.hypot(x1 - x0, y1 - y0)
        d_geod = GEOD.inv(lon0, lat0, lon1, lat1)[2]
        np.testing.assert_allclose(d_plane / d_geod, k_expected, rtol=5e-6)


# --------------------------------------------------------------------------- covariance
def _monte_carlo(sites, plane, rho, az, h_true, n_draws, seed, h_used=None, sigma_h=None, **kw):
    """Empirical covariance of plane positions from noisy (range, azimuth[, height]) draws,
    converted by the independent reference converter."""
    rng = np.random.default_rng(seed)
    tr = ref_transformer(plane.center_lat_deg, plane.center_lon_deg)
    site = (float(sites.lat_deg[0]), float(sites.lon_deg[0]), float(sites.alt_m[0]))
    rho_n = rho + rng.normal(0.0, sites.sigma_range_m[0], n_draws)
    az_n = az + rng.normal(0.0, sites.sigma_azimuth_deg[0], n_draws)
    if sigma_h is None:
        h_meas = np.full(n_draws, h_true)
        x, y, _ = ref_polar_to_xy(tr, *site, rho_n, az_n, h_meas)
    else:
        # The true height is random around the assumed one; the slant range is what the
        # radar measures of that true target; the converter only knows h_used.
        h_t = h_true + rng.normal(0.0, sigma_h, n_draws)
        g_true = ref_ground_from_slant(ref_radius(site[0]), site[2], h_true, rho)
        rho_t = ref_slant_from_ground(ref_radius(site[0]), site[2], h_t, g_true)
        rho_n = rho_t + rng.normal(0.0, sites.sigma_range_m[0], n_draws)
        x, y, _ = ref_polar_to_xy(tr, *site, rho_n, az_n, np.full(n_draws, h_used))
    return np.cov(np.vstack([x, y]))


def test_cross_range_sigma_at_100nm_is_323m():
    plane = SystemPlane(CENTER_LAT, CENTER_LON)
    sites = RadarSites([CENTER_LAT], [CENTER_LON], [0.0], [50.0], [0.1])
    _, _, cov, _ground = polar_to_plane(plane, sites, [0], [100 * NM], [90.0], [0.0])
    eig = np.linalg.eigvalsh(cov[0])
    assert np.sqrt(eig[1]) == pytest.approx(100 * NM * np.radians(0.1), abs=1.0)  # 323.2 m
    assert np.sqrt(eig[1]) == pytest.approx(323.2, abs=1.0)
    assert np.sqrt(eig[0]) == pytest.approx(50.0, rel=0.01)


def test_covariance_monte_carlo_site_at_center_100nm():
    plane = SystemPlane(CENTER_LAT, CENTER_LON)
    sites = RadarSites([CENTER_LAT], [CENTER_LON], [100.0], [50.0], [0.1])
    rho, az, h = 100 * NM, 30.0, 9000.0
    # the draws' height is exact: the Mode C height's error is left out (tested on its own,
    # test_covariance_monte_carlo_mode_c_height_error_near_the_zenith)
    _, _, cov, _ = polar_to_plane(plane, sites, [0], [rho], [az], [h], sigma_known_altitude_fraction=0.0)
    emp = _monte_carlo(sites, plane, rho, az, h, 20000, seed=11)
    np.testing.assert_allclose(whitened(emp, cov[0]), np.eye(2), atol=0.05)


def test_covariance_monte_carlo_200nm_site_300km_off_center_rotation_matters():
    plane = SystemPlane(CENTER_LAT, CENTER_LON)
    sites = site_300km_from_center()
    rho, az, h = 200 * NM, 20.0, 11000.0
    x, y, cov, _ = polar_to_plane(plane, sites, [0], [rho], [az], [h], sigma_known_altitude_fraction=0.0)
    emp = _monte_carlo(sites, plane, rho, az, h, 20000, seed=12)
    np.testing.assert_allclose(whitened(emp, cov[0]), np.eye(2), atol=0.05)

    # The test has power: the target's grid convergence (measured here numerically)
    # is several degrees, and ignoring it would fail the same check.
    tr = ref_transformer()
    lon_t, lat_t = tr.transform(x, y, direction="INVERSE")
    lon_n, lat_n, _ = GEOD.fwd(lon_t, lat_t, [0.0], [100.0])
    xn, yn = tr.transform(lon_n, lat_n)
    conv = np.arctan2(xn[0] - x[0], yn[0] - y[0])  # grid bearing of true north
    assert abs(np.degrees(conv)) > 3.0
    c, s = np.cos(conv), np.sin(conv)
    rot = np.array([[c, s], [-s, c]])  # undo the convergence
    wrong = rot @ cov[0] @ rot.T
    assert np.max(np.abs(whitened(emp, wrong) - np.eye(2))) > 0.2


def test_covariance_monte_carlo_unknown_altitude_close_range():
    plane = SystemPlane(CENTER_LAT, CENTER_LON)
    sites = RadarSites(*[[v] for v in (51.0, 7.0, 100.0, 20.0, 0.1)])
    assumed, sigma_h = 3000.0, 500.0
    g_nom = ref_ground_from_slant(ref_radius(51.0), 100.0, assumed, 20 * NM)
    rho = float(ref_slant_from_ground(ref_radius(51.0), 100.0, assumed, g_nom))
    az = 250.0
    _, _, cov, _ = polar_to_plane(
        plane,
        sites,
        [0],
        [rho],
        [az],
        [np.nan],
        assumed_altitude_m=assumed,
        sigma_unknown_altitude_m=sigma_h,
    )
    emp = _monte_carlo(sites, plane, rho, az, assumed, 20000, seed=13, h_used=assumed, sigma_h=sigma_h)
    np.testing.assert_allclose(whitened(emp, cov[0]), np.eye(2), atol=0.05)
    # The altitude term dominates the range noise here (else the test would not test it).
    _, _, cov_known, _ = polar_to_plane(plane, sites, [0], [rho], [az], [assumed], sigma_known_altitude_m=0.0)
    assert np.trace(cov[0]) - np.trace(cov_known[0]) > 2.0 * sites.sigma_range_m[0] ** 2


def test_unknown_altitude_inflates_along_range_variance_only():
    plane = SystemPlane(CENTER_LAT, CENTER_LON)
    sites = sites_5()
    idx = np.array([0, 0, 2, 2])
    rho = np.array([15.0, 200.0, 15.0, 200.0]) * NM
    az = np.array([45.0, 45.0, 300.0, 300.0])
    x_k, y_k, cov_k, g = polar_to_plane(plane, sites, idx, rho, az, np.full(4, 3000.0))
    x_u, y_u, cov_u, _ = polar_to_plane(plane, sites, idx, rho, az, np.full(4, np.nan))
    # NaN altitude -> the assumed 3000 m: same position.
    np.testing.assert_allclose(x_u, x_k, atol=1e-6)
    np.testing.assert_allclose(y_u, y_k, atol=1e-6)
    assert np.all(np.linalg.det(cov_u) > np.linalg.det(cov_k))
    # The added part is rank one, along the radial line: its major axis points from the
    # site to the target (in the plane, within the small bending of the geodesic).
    diff = cov_u - cov_k
    ev, vec = np.linalg.eigh(diff)
    assert np.all(np.abs(ev[:, 0]) < 1e-9 * ev[:, 1])
    sx, sy = plane.to_plane(sites.lat_deg[idx], sites.lon_deg[idx])
    radial = np.stack([x_k - sx, y_k - sy], axis=1)
    radial /= np.linalg.norm(radial, axis=1, keepdims=True)
    cos_angle = np.abs(np.sum(vec[:, :, 1] * radial, axis=1))
    assert np.all(cos_angle > np.cos(np.radians(1.0)))
    # Its size: (dg/dh)^2 (3000^2 - 60^2) with the small-angle derivative
    # dg/dh ~ -(dh / g + g / 2R) (the second term is the earth's curvature).
    dh = 3000.0 - sites.alt_m[idx]
    r = ref_radius(sites.lat_deg[idx])
    dg_dh = dh / g + g / (2.0 * r)
    k2 = (plane.scale_factor(*plane.to_geodetic(x_k, y_k))) ** 2
    np.testing.assert_allclose(ev[:, 1], k2 * dg_dh**2 * (3000.0**2 - 60.0**2), rtol=0.02)
    # Close in (15 NM) it dominates the range noise; at 200 NM it is small beside the
    # cross-range variance.
    assert ev[0, 1] > 10 * sites.sigma_range_m[0] ** 2
    assert ev[0, 1] > 5 * ev[1, 1]
    assert ev[1, 1] < 0.1 * np.trace(cov_k[1])


# --------------------------------------------------------------------------- edge cases
def test_nan_and_impossible_geometry():
    plane = SystemPlane(CENTER_LAT, CENTER_LON)
    sites = sites_5()
    idx = np.array([0, 0, 0, 1, 1])
    rho = np.array([100e3, np.nan, 2000.0, 50e3, -5.0])
    az = np.array([10.0, 10.0, 10.0, np.nan, 10.0])
    h = np.array([np.nan, 5000.0, 9000.0, 5000.0, 5000.0])
    x, y, cov, ground, valid = polar_to_plane(plane, sites, idx, rho, az, h, return_valid=True)
    assert valid.tolist() == [True, False, False, False, False]
    assert np.all(np.isfinite([x[0], y[0], ground[0]])) and np.all(np.isfinite(cov[0]))
    for i in (1, 3, 4):
        assert np.isnan(x[i]) and np.isnan(y[i]) and np.all(np.isnan(cov[i]))
    # Slant range 2 km to a target 8.9 km above the antenna: clamped onto the site,
    # with a wide isotropic covariance.
    sx, sy = plane.to_plane(sites.lat_deg[0], sites.lon_deg[0])
    assert ground[2] == 0.0
    assert abs(x[2] - sx) < 1e-3 and abs(y[2] - sy) < 1e-3
    np.testing.assert_allclose(cov[2], (2000.0**2 + 50.0**2) * np.eye(2))
    # geodetic_to_polar: NaN height -> NaN slant range, azimuth still defined.
    r, a, g = geodetic_to_polar(sites, [0, 0], [50.5, 50.5], [5.5, 5.5], [np.nan, 1000.0])
    assert np.isnan(r[0]) and np.isfinite(r[1]) and np.isfinite(a[0]) and g[0] == g[1]
    # Empty input (a radar with no plots this period).
    x0, y0, c0, g0, v0 = polar_to_plane(plane, sites, np.array([], int), [], [], [], return_valid=True)
    assert x0.shape == y0.shape == g0.shape == v0.shape == (0,) and c0.shape == (0, 2, 2)
    r0, a0, gg0 = geodetic_to_polar(sites, np.array([], int), [], [], [])
    assert r0.shape == a0.shape == gg0.shape == (0,)
    with pytest.raises(ValueError):
        polar_to_plane(plane, sites, [5], [1e4], [0.0], [0.0])
    with pytest.raises(ValueError):
        geodetic_to_polar(sites, [-1], [50.0], [5.0], [0.0])


def test_flight_level_helpers():
    assert flight_level_to_altitude_m(350) == pytest.approx(350 * 100 * 0.3048)
    assert float(flight_level_to_altitude_m(100)) == pytest.approx(3048.0)
    assert float(altitude_m_to_flight_level(10668.0)) == pytest.approx(350.0)
    out = flight_level_to_altitude_m(np.array([np.nan, 0.0, 410.0]))
    assert np.isnan(out[0]) and out[1] == 0.0 and out[2] == pytest.approx(12496.8)
    assert np.isnan(altitude_m_to_flight_level(np.nan))


def test_radar_sites_from_configs_and_validation():
    cfgs = [
        SimpleNamespace(id="alpha", lat_deg=50.0, lon_deg=5.0, alt_m=10.0, sigma_range_m=50.0, sigma_azimuth_deg=0.1),
        SimpleNamespace(id="bravo", lat=51.0, lon=6.0, alt_m=20.0, sigma_range_m=40.0, sigma_azimuth_deg=0.2),
    ]
    s = RadarSites.from_configs(cfgs)
    assert len(s) == 2 and s.ids == ("alpha", "bravo") and s.index_of("bravo") == 1
    np.testing.assert_array_equal(s.lat_deg, [50.0, 51.0])
    np.testing.assert_allclose(s.sigma_azimuth_rad, np.radians([0.1, 0.2]))
    px, py = s.plane_positions(SystemPlane(50.0, 5.0))
    assert abs(px[0]) < 1e-6 and py[1] > 100e3
    with pytest.raises(ValueError):
        RadarSites([50.0, 51.0], [5.0], [0.0], [1.0], [0.1])
    with pytest.raises(ValueError):
        RadarSites([50.0], [5.0], [0.0], [-1.0], [0.1])


# --------------------------------------------------------------------------- vectorisation
def test_vectorised_10000_plots_5_radars_equals_per_plot_loop():
    plane = SystemPlane(CENTER_LAT, CENTER_LON)
    sites = sites_5()
    rng = np.random.default_rng(5)
    n = 10_000
    idx = rng.integers(0, 5, n)
    rho = rng.uniform(2.0, 250.0, n) * NM
    az = rng.uniform(0.0, 360.0, n)
    h = np.where(rng.random(n) < 0.3, np.nan, rng.uniform(1000.0, 12000.0, n))
    x, y, cov, ground, valid = polar_to_plane(plane, sites, idx, rho, az, h, return_valid=True)
    assert x.shape == (n,) and cov.shape == (n, 2, 2)
    # A few short-range plots are inside the impossible cone (slant < height difference).
    h_used = np.where(np.isnan(h), 3000.0, h)
    inside = rho < np.abs(h_used - sites.alt_m[idx])
    assert inside.any() and np.array_equal(valid, ~inside)
    lat_t, lon_t = plane.to_geodetic(x, y)
    r2, a2, _g2 = geodetic_to_polar(sites, idx, lat_t, lon_t, np.where(np.isnan(h), 3000.0, h))
    tr = ref_transformer()
    for i in np.concatenate([rng.choice(n, 40, replace=False), np.flatnonzero(inside)[:3]]):
        xi, yi, ci, _gi = polar_to_plane(plane, sites, [idx[i]], [rho[i]], [az[i]], [h[i]])
        assert xi[0] == pytest.approx(x[i], abs=1e-6) and yi[0] == pytest.approx(y[i], abs=1e-6)
        np.testing.assert_allclose(ci[0], cov[i], rtol=1e-9)
        ri, ai, _ = geodetic_to_polar(sites, [idx[i]], [lat_t[i]], [lon_t[i]], [np.nan_to_num(h[i], nan=3000.0)])
        assert ri[0] == pytest.approx(r2[i], abs=1e-6) and ai[0] == pytest.approx(a2[i], abs=1e-9)
        if inside[i]:
            continue
        # ... and with the independent reference converter.
        k = idx[i]
        xr, yr, gr = ref_polar_to_xy(
            tr,
            sites.lat_deg[k],
            sites.lon_deg[k],
            sites.alt_m[k],
            np.array([rho[i]]),
            np.array([az[i]]),
            np.array([np.nan_to_num(h[i], nan=3000.0)]),
        )
        assert abs(xr[0] - x[i]) < 1e-3 and abs(yr[0] - y[i]) < 1e-3 and abs(gr[0] - ground[i]) < 1e-3
    np.testing.assert_allclose(r2[valid], rho[valid], atol=1e-3)


def test_to_plane_and_factors_match_proj():
    """The plane position, meridian convergence and scale factor from PROJ's sterea
    formulas in numpy agree with PROJ itself (an independent computation: its projection
    and its numerical get_factors) across a 600 km plane, also near the pole and across
    the antimeridian."""
    rng = np.random.default_rng(3)
    for lat0, lon0 in [(45.0, 15.0), (-33.9, 151.2), (88.5, 0.0), (41.3, 2.1), (-17.0, 179.0)]:
        plane = SystemPlane(lat0, lon0)
        lat = np.clip(lat0 + rng.uniform(-3.0, 3.0, 500), -89.5, 89.95)
        lon = lon0 + rng.uniform(-4.0, 4.0, 500)
        x_m, y_m = plane.to_plane(lat, lon)
        x2_m, y2_m, conv_deg, k = plane.to_plane_and_factors(lat, lon)
        np.testing.assert_allclose(x2_m, x_m, rtol=0, atol=1e-6)
        np.testing.assert_allclose(y2_m, y_m, rtol=0, atol=1e-6)
        f = plane.proj.get_factors(lon, lat)
        np.testing.assert_allclose(k, f.meridional_scale, rtol=1e-9)
        np.testing.assert_allclose(conv_deg, f.meridian_convergence, rtol=0, atol=1e-8)


def test_to_geodetic_matches_proj_inverse():
    """The plane -> geodetic inverse in numpy (PROJ's sterea and Gauss formulas, a fixed
    point for the latitude) agrees with PROJ's own inverse to 1e-11 degree (a micrometre)
    out to 2,000 km from the centre, also near the pole, on the equator and across the
    antimeridian; scalars in give 0-d arrays out, as PROJ's call did."""
    rng = np.random.default_rng(5)
    for lat0, lon0 in [(45.0, 15.0), (-33.9, 151.2), (88.5, 0.0), (0.0, 0.0), (-17.0, 179.0)]:
        plane = SystemPlane(lat0, lon0)
        x_m = np.concatenate([[0.0], rng.uniform(-2e6, 2e6, 500)])
        y_m = np.concatenate([[0.0], rng.uniform(-2e6, 2e6, 500)])
        lat, lon = plane.to_geodetic(x_m, y_m)
        lon_ref, lat_ref = plane.proj(x_m, y_m, inverse=True)
        np.testing.assert_allclose(lat, lat_ref, rtol=0, atol=1e-11)
        np.testing.assert_allclose((lon - np.asarray(lon_ref) + 180.0) % 360.0 - 180.0, 0.0, atol=1e-11)
        assert np.all((lon >= -180.0) & (lon < 180.0))
    lat1, lon1 = SystemPlane(41.3, 2.1).to_geodetic(12_000.0, -3_000.0)
    assert isinstance(lat1, np.ndarray) and lat1.shape == () and lon1.shape == ()
    # a diverged position (inf or NaN) has no latitude or longitude, never a finite one
    lat2, lon2 = SystemPlane(45.0, 15.0).to_geodetic([np.inf, 0.0, np.nan, 1e3], [0.0, -np.inf, 0.0, 1e3])
    assert np.isnan(lat2[:3]).all() and np.isnan(lon2[:3]).all() and np.isfinite([lat2[3], lon2[3]]).all()
    # just west of the antimeridian: -180, not +180
    assert SystemPlane(0.0, -180.0).to_geodetic(-1.6e-9, 0.0)[1] == -180.0


# --------------------------------------------------------------------------- plots without height
FT = 0.3048
FL450_M = 45_000 * FT
TO_ECEF = pyproj.Transformer.from_crs("+proj=longlat +ellps=WGS84", "+proj=geocent +ellps=WGS84", always_xy=True)


def ecef_truth(site_lat, site_lon, site_alt, ground_m, az_deg, h_t):
    """A target h_t above the ellipsoid, ground_m along the geodesic at az_deg from the site:
    its lat/lon, the true slant range (3-D ECEF distance on the ellipsoid, no sphere) and
    the azimuth (Geod.inv), and its plane position (independent sterea transformer)."""
    n = np.size(ground_m)
    lon, lat, _ = GEOD.fwd(np.full(n, site_lon), np.full(n, site_lat), az_deg, ground_m)
    p_site = np.array(TO_ECEF.transform(np.full(n, site_lon), np.full(n, site_lat), np.full(n, site_alt)))
    p_tgt = np.array(TO_ECEF.transform(lon, lat, h_t))
    rho = np.linalg.norm(p_tgt - p_site, axis=0)
    az, _, _ = GEOD.inv(np.full(n, site_lon), np.full(n, site_lat), lon, lat)
    x, y = ref_transformer().transform(lon, lat)
    return np.asarray(lat), np.asarray(lon), rho, np.mod(az, 360.0), np.asarray(x), np.asarray(y)


def test_true_height_recovers_position_fl0_to_fl450_2_to_200_km():
    """Targets at FL0..FL450, 2-200 km out, true slant range from ECEF: converted at their
    true height they land within a metre or two of where they are (sphere vs ellipsoid)."""
    plane = SystemPlane(CENTER_LAT, CENTER_LON)
    for lat0, lon0, alt0 in [(CENTER_LAT, CENTER_LON, 50.0), (51.0, 7.0, 850.0)]:
        sites = RadarSites([lat0], [lon0], [alt0], [50.0], [0.1])
        g, fl, az = np.meshgrid(
            [2e3, 5e3, 10e3, 40e3, 100e3, 200e3], np.arange(0, 451, 50), np.arange(5.0, 360.0, 40.0), indexing="ij"
        )
        g, h, az = g.ravel(), fl.ravel() * 100 * FT, az.ravel()
        _, _, rho, az_t, x_t, y_t = ecef_truth(lat0, lon0, alt0, g, az, h)
        x, y, _, _, valid = polar_to_plane(plane, sites, np.zeros(g.size, int), rho, az_t, h, return_valid=True)
        assert valid.all()
        err = np.hypot(x - x_t, y - y_t)
        assert np.max(err) < 2.0, np.max(err)


def test_fl300_40km_track_height_within_metres_10000ft_off_by_hundreds():
    plane = SystemPlane(CENTER_LAT, CENTER_LON)
    h_r, sigma_rho = 50.0, 50.0
    sites = RadarSites([CENTER_LAT], [CENTER_LON], [h_r], [sigma_rho], [0.08])
    h_true = 30_000 * FT
    az = np.array([30.0, 150.0, 260.0])
    _, _, rho, az_t, x_t, y_t = ecef_truth(CENTER_LAT, CENTER_LON, h_r, np.full(3, 40e3), az, np.full(3, h_true))
    idx = np.zeros(3, int)
    # At the (track's predicted) true height: within a few metres.
    x, y, _, _ = polar_to_plane(plane, sites, idx, rho, az_t, np.full(3, h_true))
    assert np.max(np.hypot(x - x_t, y - y_t)) < 3.0
    # At the 10,000 ft assumption: the ground range is too long by what the independent
    # arccos law of cosines says, about 900 m.
    assumed = 10_000 * FT
    x_a, y_a, _, _ = polar_to_plane(plane, sites, idx, rho, az_t, np.full(3, np.nan), assumed_altitude_m=assumed)
    err_a = np.hypot(x_a - x_t, y_a - y_t)
    expected = ref_ground_from_slant(ref_radius(CENTER_LAT), h_r, assumed, rho) - 40e3
    np.testing.assert_allclose(err_a, expected, atol=2.0)
    assert np.all((err_a > 500.0) & (err_a < 1500.0)), err_a
    # With the 0-FL450 interval the truth is inside the interval and its covariance.
    xu, yu, cov_u, _, valid = polar_to_plane_unknown_height(plane, sites, idx, rho, az_t)
    iv = ground_range_for_unknown_height(sites.earth_radius_m[0], h_r, rho)
    assert valid.all() and np.all((iv.ground_min_m < 40e3) & (iv.ground_max_m > 40e3))
    d = np.stack([x_t - xu, y_t - yu], axis=1)
    maha2 = np.einsum("ni,nij,nj->n", d, np.linalg.inv(cov_u), d)
    assert np.all(maha2 < 4.0), maha2


def _mc_ground_over_uniform_heights(r, h_r, rho, n, seed, h_max=FL450_M):
    """Ground ranges of targets at heights uniform in [0, h_max] that the radar could see
    at slant range rho (|h - h_r| <= rho: rejection), by the arccos law of cosines."""
    rng = np.random.default_rng(seed)
    h = rng.uniform(0.0, h_max, n)
    h = h[np.abs(h - h_r) <= rho]
    return ref_ground_from_slant(r, h_r, h, rho)


@pytest.mark.filterwarnings("ignore::scipy.integrate.IntegrationWarning")
@pytest.mark.parametrize(
    ("h_r", "rho"),
    [(50.0, 2e3), (50.0, 9e3), (50.0, 14e3), (850.0, 14.6e3), (50.0, 40e3), (850.0, 100e3), (50.0, 200e3)],
)
def test_unknown_height_moments_match_monte_carlo_and_quadrature(h_r, rho):
    r = float(ref_radius(CENTER_LAT))
    iv = ground_range_for_unknown_height(r, h_r, rho)
    assert iv.valid.all()
    n = 400_000
    g = _mc_ground_over_uniform_heights(r, h_r, rho, n, seed=int(rho) + int(h_r))
    mean_mc, var_mc = g.mean(), g.var()
    se_mean = np.sqrt(var_mc / g.size)
    se_var = np.sqrt((np.mean((g - mean_mc) ** 4) - var_mc**2) / g.size)
    assert abs(iv.ground_mean_m[0] - mean_mc) < 4.0 * se_mean
    assert abs(iv.ground_var_m2[0] - var_mc) < 4.0 * se_var
    # The interval holds every sample and its ends are reached.
    assert iv.ground_min_m[0] <= g.min() + 1e-6 and g.max() <= iv.ground_max_m[0] + 1e-6
    span = iv.ground_max_m[0] - iv.ground_min_m[0]
    assert g.min() - iv.ground_min_m[0] < 0.01 * span and iv.ground_max_m[0] - g.max() < 1e-3 * span
    # Never negative; never beyond the arc under a sea-level chord rho (a, b >= R).
    assert iv.ground_min_m[0] >= 0.0 and iv.ground_max_m[0] <= 2.0 * r * np.arcsin(rho / (2.0 * r))
    # Adaptive quadrature of the same integrals in h (to 1e-10): the 16-node rule is exact.
    lo, hi = max(0.0, h_r - rho), min(FL450_M, h_r + rho)
    assert iv.altitude_low_m[0] == pytest.approx(lo) and iv.altitude_high_m[0] == pytest.approx(hi)
    m_q = integrate.quad(lambda h: ref_ground_from_slant(r, h_r, h, rho), lo, hi, epsabs=0, epsrel=1e-10, limit=200)[
        0
    ] / (hi - lo)
    v_q = integrate.quad(
        lambda h: (np.nan_to_num(ref_ground_from_slant(r, h_r, h, rho)) - m_q) ** 2,
        lo,
        hi,
        epsabs=0,
        epsrel=1e-10,
        limit=200,
    )[0] / (hi - lo)
    assert iv.ground_mean_m[0] == pytest.approx(m_q, rel=1e-9, abs=1e-6)
    assert iv.ground_var_m2[0] == pytest.approx(v_q, rel=1e-6)


def test_unknown_height_uniform_in_ground_range_would_be_wrong_close_in():
    """The test above has power: near the radar g(h) ~ sqrt(rho^2 - h^2) is far from
    linear, and the mid-point and (span)^2/12 of a uniform ground range miss the Monte
    Carlo by hundreds of standard errors (at 14 km the mid-point is ~2.7 km short)."""
    r = float(ref_radius(CENTER_LAT))
    iv = ground_range_for_unknown_height(r, 50.0, 14e3)
    g = _mc_ground_over_uniform_heights(r, 50.0, 14e3, 400_000, seed=1)
    mid = 0.5 * (iv.ground_min_m[0] + iv.ground_max_m[0])
    assert abs(mid - g.mean()) > 2000.0
    assert abs((iv.ground_max_m[0] - iv.ground_min_m[0]) ** 2 / 12.0 - g.var()) > 0.2 * g.var()


@pytest.mark.parametrize(("rho", "az"), [(40e3, 70.0), (120e3, 200.0)])
def test_unknown_height_plane_covariance_monte_carlo(rho, az):
    """Plane mean and covariance of the true positions behind one measured (rho, theta):
    height uniform in the feasible interval, range and azimuth noise, each draw converted
    by the independent reference converter; site 300 km off the plane's centre."""
    plane = SystemPlane(CENTER_LAT, CENTER_LON)
    sites = site_300km_from_center()
    lat0, lon0, h_r = float(sites.lat_deg[0]), float(sites.lon_deg[0]), float(sites.alt_m[0])
    x, y, cov, _, valid = polar_to_plane_unknown_height(plane, sites, [0], [rho], [az])
    assert valid[0]
    rng = np.random.default_rng(int(rho))
    n = 40_000
    h = rng.uniform(0.0, FL450_M, n)
    rho_t = rho - rng.normal(0.0, sites.sigma_range_m[0], n)
    az_t = az - rng.normal(0.0, sites.sigma_azimuth_deg[0], n)
    xs, ys, _ = ref_polar_to_xy(ref_transformer(), lat0, lon0, h_r, rho_t, az_t, h)
    d = np.stack([xs - x[0], ys - y[0]])
    emp = np.cov(d)
    np.testing.assert_allclose(whitened(emp, cov[0]), np.eye(2), atol=0.05)
    # Mean: within 4 standard errors along each axis.
    se = np.sqrt(np.diag(cov[0]) / n)
    assert np.all(np.abs(d.mean(axis=1)) < 4.0 * se)
    if rho < 100e3:  # here the height interval dominates the range noise (the test has power)
        assert np.max(np.linalg.eigvalsh(cov[0])) > 50.0 * sites.sigma_range_m[0] ** 2


def test_unknown_height_near_radar_within_physical_bounds():
    """A plot 2 km from the radar (slant) without height: never a negative ground range,
    never one beyond the slant range; 10,000 ft would put it on the site."""
    plane = SystemPlane(CENTER_LAT, CENTER_LON)
    h_r = 50.0
    sites = RadarSites([CENTER_LAT], [CENTER_LON], [h_r], [30.0], [0.08])
    sx, sy = sites.plane_positions(plane)
    rho = np.array([300.0, 1000.0, 2000.0, 2500.0, 3000.0])
    az = np.array([0.0, 45.0, 100.0, 210.0, 333.0])
    idx = np.zeros(rho.size, int)
    x, y, cov, ground, valid = polar_to_plane_unknown_height(plane, sites, idx, rho, az)
    iv = ground_range_for_unknown_height(sites.earth_radius_m[0], h_r, rho)
    assert valid.all()
    assert np.all(iv.ground_min_m >= 0.0) and np.all(iv.ground_max_m <= rho)
    assert np.all((ground >= iv.ground_min_m) & (ground <= iv.ground_max_m))
    dist = np.hypot(x - sx[0], y - sy[0])
    assert np.all(dist <= rho) and np.all(dist > 0.5 * rho)
    assert np.all(np.linalg.eigvalsh(cov) > 0.0)
    # An aircraft on the ground 2.5 km out (truth from ECEF) is inside the interval and
    # its covariance; converted at its track's height (0 m) it is exact to a metre.
    _, _, rho_g, az_g, x_t, y_t = ecef_truth(CENTER_LAT, CENTER_LON, h_r, [2500.0], [120.0], [0.0])
    xg, yg, cg, _, _ = polar_to_plane_unknown_height(plane, sites, [0], rho_g, az_g)
    dg = np.array([x_t[0] - xg[0], y_t[0] - yg[0]])
    assert dg @ np.linalg.solve(cg[0], dg) < 9.0
    xk, yk, _, _ = polar_to_plane(plane, sites, [0], rho_g, az_g, [0.0])
    assert np.hypot(xk[0] - x_t[0], yk[0] - y_t[0]) < 1.0
    # The 10,000 ft assumption: impossible geometry up to 3 km, clamped onto the site;
    # at 3 km slant, 10,000 ft pulls the plot to a ground range of ~350 m.
    _, _, _, g_a, v_a = polar_to_plane(
        plane, sites, idx, rho, az, np.full(rho.size, np.nan), assumed_altitude_m=10_000 * FT, return_valid=True
    )
    assert not v_a[:4].any() and np.all(g_a[:4] == 0.0) and v_a[4] and g_a[4] < 0.2 * rho[4]


def test_unknown_height_edge_cases():
    plane = SystemPlane(CENTER_LAT, CENTER_LON)
    sites = RadarSites([CENTER_LAT], [CENTER_LON], [0.0], [30.0], [0.08])
    rho = np.array([500.0, np.nan, -1.0, 50e3, 0.0])
    az = np.array([10.0, 10.0, 10.0, np.nan, 10.0])
    # Heights of 1-2 km: a 500 m slant range is impossible -> site, isotropic, invalid.
    x, y, cov, g, valid = polar_to_plane_unknown_height(plane, sites, np.zeros(5, int), rho, az, 1000.0, 2000.0)
    assert valid.tolist() == [False, False, False, False, False]
    assert g[0] == 0.0 and abs(x[0]) < 1e-6 and abs(y[0]) < 1e-6
    np.testing.assert_allclose(cov[0], (500.0**2 + 30.0**2) * np.eye(2))
    for i in (1, 2, 3):
        assert np.isnan(x[i]) and np.isnan(g[i]) and np.all(np.isnan(cov[i]))
    # One height (min = max): the moments are that height's ground range, variance 0.
    iv = ground_range_for_unknown_height(sites.earth_radius_m[0], 0.0, [40e3], 9000.0, 9000.0)
    g_ref = ref_ground_from_slant(ref_radius(CENTER_LAT), 0.0, 9000.0, 40e3)
    assert iv.ground_mean_m[0] == pytest.approx(g_ref, abs=1e-6) and iv.ground_var_m2[0] == pytest.approx(0, abs=1e-6)
    assert iv.ground_min_m[0] == pytest.approx(g_ref, abs=1e-6) == iv.ground_max_m[0]
    # Empty input.
    out = polar_to_plane_unknown_height(plane, sites, np.array([], int), [], [])
    assert out[0].shape == (0,) and out[2].shape == (0, 2, 2) and out[4].shape == (0,)
    assert pytest.approx(FL450_M) == MAX_UNKNOWN_ALTITUDE_M


# --------------------------------------------------------------------------- fast polar coordinates
@pytest.mark.parametrize("center_lat", [41.3, 50.0, 62.0])
def test_conformal_sphere_polar_matches_geod_inv_over_the_coverage(center_lat):
    """The primary-height picker's polar coordinates of a track from a radar (the plane
    mapped to the projection's conformal sphere, great-circle formulas, no PROJ call)
    against Geod.inv on WGS-84 after PROJ's inverse projection: sites up to 500 km from the
    plane's centre, targets 0-250 km from them at FL0-FL450. Stated tolerance: ground and
    slant range within 1 m, azimuth within 1e-4 degree (a radar's noise is >= 20 m and
    0.03 degree; the gate is 4 sigma)."""
    plane = SystemPlane(center_lat, 8.0)
    rng = np.random.default_rng(int(center_lat))
    worst_g = worst_rho = worst_az = 0.0
    for site_dist_m in (0.0, 150e3, 300e3, 500e3):
        for site_bearing in range(0, 360, 60):
            lon_s, lat_s, _ = GEOD.fwd(8.0, center_lat, site_bearing, site_dist_m)
            sites = RadarSites([lat_s], [lon_s], [rng.uniform(0.0, 2500.0)], [50.0], [0.08])
            n = 400
            g = np.concatenate([[0.0, 50.0], rng.uniform(100.0, 250e3, n - 2)])
            az = rng.uniform(0.0, 360.0, n)
            h = rng.uniform(0.0, FL450_M, n)
            lon_t, lat_t, _ = GEOD.fwd(np.full(n, lon_s), np.full(n, lat_s), az, g)
            x, y = ref_transformer(center_lat, 8.0).transform(lon_t, lat_t)
            # exact: the module's own Geod path (PROJ inverse, Geod.inv, Gaussian sphere)
            rho_ref, az_ref, g_ref = geodetic_to_polar(sites, np.zeros(n, int), *plane.to_geodetic(x, y), h)
            sx, sy = sites.plane_positions(plane)
            s_chi, s_lam = plane.to_conformal_sphere(sx, sy)
            g_fast, az_fast = conformal_sphere_polar(
                plane.conformal_radius_m, s_chi, s_lam, *plane.to_conformal_sphere(x, y)
            )
            rho_fast = ground_to_slant_range(sites.earth_radius_m[0], sites.alt_m[0], h, g_fast)
            far = g > 1000.0  # the azimuth of a point under the antenna is meaningless
            worst_g = max(worst_g, float(np.max(np.abs(g_fast - g_ref))))
            worst_rho = max(worst_rho, float(np.max(np.abs(rho_fast - rho_ref))))
            d_az = np.mod(az_fast - az_ref + 180.0, 360.0) - 180.0
            worst_az = max(worst_az, float(np.max(np.abs(d_az[far]))))
    assert worst_g < 1.0 and worst_rho < 1.0 and worst_az < 1e-4, (worst_g, worst_rho, worst_az)


def test_conformal_sphere_round_trips_and_destination_inverts_polar():
    plane = SystemPlane(CENTER_LAT, CENTER_LON)
    rng = np.random.default_rng(5)
    x, y = rng.uniform(-6e5, 6e5, 200), rng.uniform(-6e5, 6e5, 200)
    chi, lam = plane.to_conformal_sphere(x, y)
    xb, yb = plane.from_conformal_sphere(chi, lam)
    assert np.max(np.hypot(xb - x, yb - y)) < 1e-6
    s_chi, s_lam = plane.to_conformal_sphere(2e4, -3e4)
    g, az = conformal_sphere_polar(plane.conformal_radius_m, s_chi, s_lam, chi, lam)
    c2, l2 = conformal_sphere_destination(plane.conformal_radius_m, s_chi, s_lam, az, g)
    x2, y2 = plane.from_conformal_sphere(c2, l2)
    assert np.max(np.hypot(x2 - x, y2 - y)) < 1e-3


# --------------------------------------------------------------------------- height spread, split
def test_unknown_height_plots_at_a_reference_height_and_their_spread_about_it():
    """A primary plot converted at the assumed height with its spread over every height
    apart: the position is the independent arccos + Geod.fwd one at that height, the noise
    part is polar_to_plane's without the height term, and the spread's radial second
    moment is E[(g(h) - g(h_ref))^2] over a uniform h in [0, FL450] by quadrature of the
    independent law of cosines; the true position of a FL300-400 aircraft lies inside
    3 sigma of it, not inside 3 sigma of the assumed height's noise."""
    plane = SystemPlane(CENTER_LAT, CENTER_LON)
    h_r = 600.0
    sites = RadarSites([CENTER_LAT], [CENTER_LON], [h_r], [60.0], [0.08])
    h_ref = 10_000 * FT
    g = np.array([20e3, 40e3, 80e3])
    az = np.array([10.0, 135.0, 250.0])
    h_true = np.array([30_000, 35_000, 40_000]) * FT
    _, _, rho, az_t, x_t, y_t = ecef_truth(CENTER_LAT, CENTER_LON, h_r, g, az, h_true)
    u = unknown_height_plots(plane, sites, np.zeros(3, int), rho, az_t, reference_altitude_m=h_ref)
    x_ref, y_ref, g_ref = ref_polar_to_xy(ref_transformer(), CENTER_LAT, CENTER_LON, h_r, rho, az_t, h_ref)
    assert np.max(np.hypot(u.x_m - x_ref, u.y_m - y_ref)) < 0.01
    _, _, cov_noise, _ = polar_to_plane(
        plane,
        sites,
        np.zeros(3, int),
        rho,
        az_t,
        np.full(3, np.nan),
        assumed_altitude_m=h_ref,
        sigma_unknown_altitude_m=0.0,
    )
    np.testing.assert_allclose(u.cov_noise_m2, cov_noise, rtol=0.02)
    r = ref_radius(CENTER_LAT)
    for i in range(3):
        m2, _ = integrate.quad(lambda h, i=i: (ref_ground_from_slant(r, h_r, h, rho[i]) - g_ref[i]) ** 2, 0.0, FL450_M)
        radial = np.array([x_t[i] - u.x_m[i], y_t[i] - u.y_m[i]])
        radial /= np.linalg.norm(radial)
        along_m2 = radial @ u.cov_height_m2[i] @ radial
        assert abs(along_m2 / (m2 / FL450_M) - 1.0) < 0.01, (along_m2, m2 / FL450_M)
        err = np.hypot(x_t[i] - u.x_m[i], y_t[i] - u.y_m[i])
        assert err > 3.0 * np.sqrt(radial @ u.cov_noise_m2[i] @ radial)
        assert err < 3.0 * np.sqrt(along_m2)


def test_ground_velocity_to_plane_matches_a_geodesic_step_projected_by_proj():
    """A Mode S ground speed and true track angle at height h -> system-plane velocity:
    against the aircraft's sub-point moved along the geodesic of that azimuth
    (pyproj.Geod.fwd) by speed · R / (R + h) over 0.2 s and both ends projected by PROJ
    (plane.proj), at points up to 300 km from the centre in every direction."""
    plane = SystemPlane(41.3, 2.1)
    geod = pyproj.Geod(ellps="WGS84")
    rng = np.random.default_rng(4)
    n = 60
    x_m, y_m = rng.uniform(-300e3, 300e3, n), rng.uniform(-300e3, 300e3, n)
    speed_mps, track_deg = rng.uniform(60.0, 300.0, n), rng.uniform(0.0, 360.0, n)
    alt_m = rng.choice([np.nan, 0.0, 3000.0, 11000.0], n)
    vx, vy = ground_velocity_to_plane(plane, x_m, y_m, speed_mps, track_deg, alt_m)
    lat, lon = plane.to_geodetic(x_m, y_m)
    radius_m = gaussian_earth_radius_m(lat)
    dt_s = 0.2
    ground_m = speed_mps * dt_s * radius_m / (radius_m + np.nan_to_num(alt_m))
    lon2, lat2, _ = geod.fwd(lon, lat, track_deg, ground_m)
    lon1, lat1, _ = geod.fwd(lon, lat, track_deg + 180.0, ground_m)  # centred difference
    xa, ya = plane.proj(lon1, lat1)
    xb, yb = plane.proj(lon2, lat2)
    np.testing.assert_allclose(vx, (np.asarray(xb) - xa) / (2 * dt_s), atol=2e-3)
    np.testing.assert_allclose(vy, (np.asarray(yb) - ya) / (2 * dt_s), atol=2e-3)
    # far from the centre the grid bearing is off the true one by the convergence: 2.4° at 300 km
    # east (3.6° of longitude at 41.3°N, c ≈ Δλ sin φ)
    east = ground_velocity_to_plane(plane, 300e3, 0.0, 250.0, 0.0, 0.0)
    assert 2.2 < -np.degrees(np.arctan2(east[0], east[1])) < 2.5


def test_isa_at_published_levels():
    """The ICAO standard atmosphere (Doc 7488) at its published points: 238.42 hPa and
    −54.34 °C at FL350, 226.32 hPa at the tropopause (11 km), 147.48 hPa at FL450."""
    from radar_fusion.geo.air_data import isa_pressure_pa, isa_temperature_k

    h = np.array([0.0, 350 * 30.48, 11_000.0, 450 * 30.48])
    np.testing.assert_allclose(isa_pressure_pa(h), [101_325.0, 23_842.0, 22_632.0, 14_748.0], atol=3.0)
    np.testing.assert_allclose(isa_temperature_k(h), [288.15, 218.81, 216.65, 216.65], atol=0.01)


def test_true_airspeed_of_an_indicated_one():
    """At sea level in ISA the calibrated airspeed is the true one; slow, at altitude, TAS =
    CAS sqrt(ρ0/ρ) (the incompressible limit, ρ = p / (R T)); Mach 0.78 at FL350 (449.6 kt
    true) is the 264 kt indicated of the flight manuals; a day 10 K warmer makes the same
    indicated airspeed sqrt(T + 10 / T) faster; and the inverse gives the IAS back."""
    from radar_fusion.geo import air_data as ad

    kt = 1852.0 / 3600.0
    cas = np.array([60.0, 150.0, 250.0, 340.0]) * kt
    np.testing.assert_allclose(ad.true_airspeed_mps(cas, 0.0), cas, rtol=1e-12)
    h = 3048.0  # FL100
    t_k, p_pa = 288.15 - 0.0065 * h, 101_325.0 * (1.0 - 0.0065 * h / 288.15) ** 5.25588
    rho_ratio = (p_pa / t_k) / (101_325.0 / 288.15)
    assert ad.true_airspeed_mps(60.0 * kt, h) == pytest.approx(60.0 * kt / math.sqrt(rho_ratio), rel=1e-3)
    fl350 = 350 * 30.48
    tas_m078 = 0.78 * math.sqrt(1.4 * 287.05287 * 218.808)
    assert tas_m078 / kt == pytest.approx(449.6, abs=0.2)
    assert ad.indicated_airspeed_mps(tas_m078, fl350) / kt == pytest.approx(264.0, abs=1.5)
    warm = ad.true_airspeed_mps(264.0 * kt, fl350, 10.0) / ad.true_airspeed_mps(264.0 * kt, fl350)
    assert warm == pytest.approx(math.sqrt((218.808 + 10.0) / 218.808), rel=1e-12)
    for dev_k in (0.0, -15.0, 20.0):
        tas = ad.true_airspeed_mps(cas, fl350, dev_k)
        np.testing.assert_allclose(ad.indicated_airspeed_mps(tas, fl350, dev_k), cas, rtol=1e-10)


def test_height_of_a_pressure_altitude_against_the_hypsometric_integral():
    """A Mode C level's height above sea level on a non-ISA day, against the hypsometric
    equation integrated numerically over pressure: z = ∫ R T(p) / (g p) dp from the level's
    pressure up to QNH, with T(p) = T_isa + ΔT at the pressure altitude of p (ISA's inverse,
    written here from Doc 7488's two layers). Below and above the tropopause, warm and cold
    days, QNH off standard; and the inverse gives the level back."""
    from scipy.integrate import quad

    from radar_fusion.geo import air_data as ad

    R, G, T0, L, P0 = 287.05287, 9.80665, 288.15, -0.0065, 101_325.0
    T11 = T0 + L * 11_000.0
    P11 = P0 * (T11 / T0) ** (-G / (L * R))

    def isa_h_of_p(p):
        if p >= P11:
            return (T0 / L) * ((p / P0) ** (-L * R / G) - 1.0)
        return 11_000.0 - R * T11 / G * math.log(p / P11)

    def isa_p_of_h(h):
        if h < 11_000.0:
            return P0 * ((T0 + L * h) / T0) ** (-G / (L * R))
        return P11 * math.exp(-G * (h - 11_000.0) / (R * T11))

    def thickness_m(p_low_pa, p_high_pa, dev_k):  # the hypsometric equation, over pressure
        def t_of_p(p):
            return max(T0 + L * min(isa_h_of_p(p), 11_000.0), T11) + dev_k

        return quad(lambda p: R * t_of_p(p) / (G * p), p_low_pa, p_high_pa, limit=200)[0]

    for dev_k, qnh_hpa in ((0.0, 1013.25), (15.0, 1013.25), (-20.0, 1013.25), (8.0, 1031.0), (-5.0, 990.0)):
        for fl in (10.0, 100.0, 300.0, 360.0, 450.0):
            h = fl * 30.48
            want = thickness_m(isa_p_of_h(h), qnh_hpa * 100.0, dev_k)
            got = float(ad.height_of_pressure_altitude_m(h, dev_k, qnh_hpa))
            assert got == pytest.approx(want, abs=0.05), (dev_k, qnh_hpa, fl)
            assert float(ad.pressure_altitude_of_height_m(got, dev_k, qnh_hpa)) == pytest.approx(h, abs=1e-6)
    # the figures the code's comments give
    assert float(ad.height_of_pressure_altitude_m(360 * 30.48, 15.0)) - 360 * 30.48 == pytest.approx(656, abs=1)
    assert float(ad.height_of_pressure_altitude_m(300 * 30.48, 5.0)) - 300 * 30.48 == pytest.approx(178, abs=1)


def test_covariance_monte_carlo_mode_c_height_error_near_the_zenith():
    """A plot with Mode C at FL360 8 km (ground) from the antenna: its true height lies
    off the Mode C one by hypot(60 m, 3 % of it) (the pressure altitude on a day off ISA,
    coordinates.MODE_C_HEIGHT_SIGMA_FRACTION); the empirical covariance of the positions the
    independent converter gives, the true slant range measured and the Mode C height used,
    whitens to the identity with polar_to_plane's. The height term is most of it there: with
    60 m alone the along-range variance is several times too small."""
    from radar_fusion.geo.coordinates import MODE_C_HEIGHT_SIGMA_FRACTION

    plane = SystemPlane(CENTER_LAT, CENTER_LON)
    sites = RadarSites(*[[v] for v in (51.0, 7.0, 1900.0, 20.0, 0.05)])
    h_mode_c = 360 * 30.48
    rho = float(ref_slant_from_ground(ref_radius(51.0), 1900.0, h_mode_c, 8000.0))
    az = 150.0
    sigma_h = math.hypot(60.0, MODE_C_HEIGHT_SIGMA_FRACTION * h_mode_c)
    _, _, cov, _ = polar_to_plane(plane, sites, [0], [rho], [az], [h_mode_c])
    emp = _monte_carlo(sites, plane, rho, az, h_mode_c, 20000, seed=17, h_used=h_mode_c, sigma_h=sigma_h)
    np.testing.assert_allclose(whitened(emp, cov[0]), np.eye(2), atol=0.06)
    _, _, cov_60, _ = polar_to_plane(plane, sites, [0], [rho], [az], [h_mode_c], sigma_known_altitude_fraction=0.0)
    assert np.trace(emp) > 5.0 * np.trace(cov_60[0])


def test_the_velocity_frame_is_the_exact_factors_but_for_the_gauss_maps_own_scale():
    """SystemPlane.velocity_frame against the exact factors (to_geodetic, then
    to_plane_and_factors): the same convergence, and a scale within 2.5e-6 over ±600 km (the
    Gauss map's own, left out), 1e-8 within 20 km of the centre;
    ground_velocity_to_plane with it against the exact path (k and the Gaussian radius at the
    aircraft's latitude): within 2 mm/s at 250 m/s, FL350."""
    from radar_fusion.geo.coordinates import SystemPlane, gaussian_earth_radius_m, ground_velocity_to_plane

    plane = SystemPlane(41.3, 2.1)
    rng = np.random.default_rng(4)
    x, y = rng.uniform(-600e3, 600e3, 2000), rng.uniform(-600e3, 600e3, 2000)
    x[:50], y[:50] = rng.uniform(-15e3, 15e3, 50), rng.uniform(-15e3, 15e3, 50)
    lat, lon = plane.to_geodetic(x, y)
    _, _, c_exact, k_exact = plane.to_plane_and_factors(lat, lon)
    c, k = plane.velocity_frame(x, y)
    np.testing.assert_allclose(c, c_exact, atol=1e-12)
    assert np.abs(k / k_exact - 1.0).max() < 2.5e-6
    near = np.hypot(x, y) < 20e3
    assert near.any() and np.abs(k[near] / k_exact[near] - 1.0).max() < 1e-8
    h = 350 * 30.48
    track = rng.uniform(0.0, 360.0, x.size)
    vx, vy = ground_velocity_to_plane(plane, x, y, 250.0, track, h)
    r = gaussian_earth_radius_m(lat)
    speed = 250.0 * k_exact * r / (r + h)
    beta = np.radians(track - c_exact)
    assert np.hypot(vx - speed * np.sin(beta), vy - speed * np.cos(beta)).max() < 2e-3
