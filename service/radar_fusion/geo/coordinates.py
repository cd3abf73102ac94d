"""Coordinate conversion: radar polar measurements <-> the common system plane.

Every function is vectorised over arrays of plots. Plots of many radars come mixed in
one call; ``radar_index`` (an int array, one entry per plot) says which row of a
:class:`RadarSites` each plot belongs to.

Frames and conventions
----------------------
* Geodetic positions are on the WGS-84 ellipsoid (degrees; heights in metres above the
  ellipsoid).
* The *system plane* is an oblique stereographic projection of WGS-84 centred at the
  system centre (PROJ ``sterea``: the ellipsoid is mapped conformally onto the Gauss
  conformal sphere, which is projected stereographically), scale factor k0 = 1 at the
  centre, no false easting/northing: x east and y north *at the centre*, metres.
  Away from the centre grid north differs from true north by the meridian convergence
  and the scale factor grows as k ~ 1 + d^2 / (4 R^2) (about 1.001 at 400 km).
* A radar measures slant range rho (antenna to target, metres) and azimuth theta
  (degrees from true north, clockwise, at the antenna).

Slant range -> ground range (the EUROCONTROL spherical model)
---------------------------------------------------------------
Around each radar the earth is taken as a sphere of the *Gaussian mean radius of
curvature* at the site latitude, R = sqrt(M N) = a sqrt(1 - e^2) / (1 - e^2 sin^2 phi)
(M meridian, N prime-vertical radius). It is azimuth-independent, so one radius per
site is precomputed. With a = R + h_r (antenna height) and b = R + h_t (target height)
the law of cosines in the plane of the antenna, the target and the earth's centre is

    rho^2 = a^2 + b^2 - 2 a b cos(gamma)  =  (a - b)^2 + 4 a b sin^2(gamma / 2),

where gamma is the angle at the earth's centre. The half-angle form is used in both
directions because it keeps full precision at short range. The ground range (arc length
on the sphere of radius R) is g = R gamma. The target's latitude/longitude are then
found by walking g metres along the geodesic on WGS-84 from the site with initial
azimuth theta (``pyproj.Geod.fwd``); the inverse uses ``pyproj.Geod.inv``. Using the
same sphere and the same geodesic both ways makes :func:`geodetic_to_polar` the exact
inverse of :func:`polar_to_plane` (round trip well below a millimetre).

Heights are the target's height above the ellipsoid. Mode C gives pressure altitude;
:func:`mode_c_height_m` takes it as the height, or converts it with the day's temperature
and QNH where they are configured (no geoid correction: the geoid lies some tens of metres
off the ellipsoid, inside the height's 60 m), and the plot covariance carries its error
(:data:`MODE_C_HEIGHT_SIGMA_FRACTION`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np
import pyproj
from numpy.typing import NDArray

from .air_data import height_of_pressure_altitude_m
from .units import M_PER_FL

__all__ = [
    "WGS84_GEOD",
    "RadarSites",
    "SystemPlane",
    "altitude_m_to_flight_level",
    "conformal_sphere_destination",
    "conformal_sphere_polar",
    "flight_level_to_altitude_m",
    "gaussian_earth_radius_m",
    "geodetic_to_polar",
    "ground_to_slant_range",
    "mark_unconverted",
    "mode_c_height_m",
    "plane_to_ground_polar",
    "polar_to_plane",
    "radial_to_plane",
    "slant_to_ground_range",
]

WGS84_GEOD = pyproj.Geod(ellps="WGS84")
"""Geodesic calculator on the WGS-84 ellipsoid (Karney's algorithms, nm accuracy)."""

_WGS84_A_M: float = WGS84_GEOD.a
_WGS84_E2: float = WGS84_GEOD.es


def gaussian_earth_radius_m(lat_deg: np.ndarray | float) -> NDArray[np.float64]:
    """Gaussian mean radius of curvature of WGS-84 at latitude ``lat_deg``.

    R = sqrt(M N) = a sqrt(1 - e^2) / (1 - e^2 sin^2 phi), where M is the meridian and
    N the prime-vertical radius of curvature. It is the radius of the sphere that best
    fits the ellipsoid around that latitude in all directions (≈ 6 381 km at 45°).
    """
    s = np.sin(np.radians(np.asarray(lat_deg, dtype=float)))
    radius_m: NDArray[np.float64] = _WGS84_A_M * np.sqrt(1.0 - _WGS84_E2) / (1.0 - _WGS84_E2 * s * s)
    return radius_m


class SystemPlane:
    """The system plane: oblique stereographic projection of WGS-84 at the system centre.

    PROJ ``+proj=sterea +lat_0=<lat> +lon_0=<lon> +k_0=1 +x_0=0 +y_0=0 +ellps=WGS84``
    (the "double" stereographic used by ARTAS-like systems: conformal, so a small
    circle stays a circle, with point scale k0 = 1 at the centre). x is east and y is
    north at the centre, in metres.
    """

    def __init__(self, center_lat_deg: float, center_lon_deg: float) -> None:
        if not (-90.0 < float(center_lat_deg) < 90.0):
            raise ValueError(f"center_lat_deg must be in (-90, 90), got {center_lat_deg}")
        if not np.isfinite(center_lon_deg):
            raise ValueError(f"center_lon_deg must be finite, got {center_lon_deg}")
        self.center_lat_deg = float(center_lat_deg)
        # Normalised to [-180, 180).
        self.center_lon_deg = (float(center_lon_deg) + 180.0) % 360.0 - 180.0
        self.proj = pyproj.Proj(
            proj="sterea",
            lat_0=self.center_lat_deg,
            lon_0=self.center_lon_deg,
            k_0=1.0,
            x_0=0.0,
            y_0=0.0,
            ellps="WGS84",
            units="m",
        )

        # The Gauss conformal sphere under the projection (PROJ's pj_gauss_ini, as sterea
        # uses it): radius R_c = a sqrt(1 - e^2) / (1 - e^2 sin^2 phi0) (the Gaussian radius
        # at the centre) and the centre's conformal latitude chi0 = asin(sin(phi0) / C),
        # C = sqrt(1 + e^2 cos^4(phi0) / (1 - e^2)). See :meth:`to_conformal_sphere`.
        phi0 = math.radians(self.center_lat_deg)
        c_gauss = math.sqrt(1.0 + _WGS84_E2 * math.cos(phi0) ** 4 / (1.0 - _WGS84_E2))
        self.conformal_radius_m = _WGS84_A_M * math.sqrt(1.0 - _WGS84_E2) / (1.0 - _WGS84_E2 * math.sin(phi0) ** 2)
        self.conformal_center_lat_rad = math.asin(math.sin(phi0) / c_gauss)
        # the rest of pj_gauss_ini, for :meth:`to_plane_and_factors`: the exponent C of the
        # longitude and the latitude series, half C e and the constant K that puts phi0 at chi0
        e = math.sqrt(_WGS84_E2)
        self._gauss_c = c_gauss
        self._gauss_ratexp = 0.5 * c_gauss * e
        es0 = e * math.sin(phi0)
        self._gauss_k = math.tan(0.5 * self.conformal_center_lat_rad + 0.25 * math.pi) / (
            math.tan(0.5 * phi0 + 0.25 * math.pi) ** c_gauss * ((1.0 - es0) / (1.0 + es0)) ** self._gauss_ratexp
        )

    def __repr__(self) -> str:
        return f"SystemPlane(center_lat_deg={self.center_lat_deg!r}, center_lon_deg={self.center_lon_deg!r})"

    def to_conformal_sphere(self, x_m: Any, y_m: Any) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Plane (x_m, y_m) -> (conformal latitude chi, longitude Lambda from the centre),
        radians, on the Gauss conformal sphere the projection is built on: the inverse of
        the stereographic projection of a sphere of radius R_c (``conformal_radius_m``),
        k0 = 1, centred at chi0 (Snyder 1987, eq. 21-15, 20-14, 20-15 with R = R_c):

            r = |(x, y)|,  c = 2 atan(r / (2 R_c)),
            sin chi = cos c sin chi0 + y sin c cos chi0 / r,
            Lambda = atan2(x sin c, r cos chi0 cos c - y sin chi0 sin c).

        Pure numpy (no PROJ call). The ellipsoid -> sphere map is conformal with a scale
        within ~1e-6 of 1 for a few hundred km around the centre, so great-circle
        distances and azimuths on this sphere are the WGS-84 geodesic's to well under a
        metre and 1e-4 degree there (tests/test_coordinates.py measures it against
        ``Geod.inv``): :func:`plane_to_ground_polar`.
        """
        x = np.asarray(x_m, dtype=float)
        y = np.asarray(y_m, dtype=float)
        r = np.hypot(x, y)
        c = 2.0 * np.arctan(r / (2.0 * self.conformal_radius_m))
        sin_c, cos_c = np.sin(c), np.cos(c)
        s0, c0 = math.sin(self.conformal_center_lat_rad), math.cos(self.conformal_center_lat_rad)
        y_over_r = np.divide(y, r, out=np.zeros_like(r), where=r > 0.0)
        chi = np.arcsin(np.clip(cos_c * s0 + y_over_r * sin_c * c0, -1.0, 1.0))
        lam = np.arctan2(x * sin_c, r * c0 * cos_c - y * s0 * sin_c)
        return chi, lam

    def to_plane(self, lat_deg: Any, lon_deg: Any) -> tuple[np.ndarray, np.ndarray]:
        """Geodetic (degrees) -> plane (x_m east, y_m north), arrays in and out."""
        lat = np.asarray(lat_deg, dtype=float)
        lon = np.asarray(lon_deg, dtype=float)
        x_m, y_m = self.proj(lon, lat, errcheck=False)
        return np.asarray(x_m, dtype=float), np.asarray(y_m, dtype=float)

    def to_geodetic(self, x_m: Any, y_m: Any) -> tuple[np.ndarray, np.ndarray]:
        """Plane (x_m, y_m) -> geodetic (lat_deg, lon_deg), arrays in and out: PROJ's own
        sterea inverse (sterea.cpp, gauss.cpp's pj_inv_gauss) in numpy, not a call into
        PROJ, as :meth:`to_plane_and_factors` is its forward. The plane point goes to the
        conformal sphere (:meth:`to_conformal_sphere`), then back through the Gauss map:
        lambda = lambda0 + Lambda / C and phi by PROJ's fixed point (tolerance 1e-14 rad, at
        most 20 steps; 3-5 here),

            phi <- 2 atan(((tan(chi/2 + pi/4) / K)^(1/C)) ((1 - e sin phi) / (1 + e sin phi))^(-e/2)) - pi/2.

        Against PROJ's inverse (tests/test_coordinates.py): 1e-13 degree out to 2,000 km;
        4,000 points in 0.6 ms where the PROJ call took 1.7 ms (the output's latitudes and
        longitudes every period, and the Mode S velocities' convergence)."""
        x = np.asarray(x_m, dtype=float)
        y = np.asarray(y_m, dtype=float)
        bad = ~(np.isfinite(x) & np.isfinite(y))  # a diverged position has no place on the earth: NaN
        if bad.any():
            x, y = np.where(bad, 0.0, x), np.where(bad, 0.0, y)
        chi, lam = self.to_conformal_sphere(x, y)
        lon = np.mod(self.center_lon_deg + np.degrees(lam / self._gauss_c) + 180.0, 360.0) - 180.0
        num = (np.tan(0.5 * chi + 0.25 * math.pi) / self._gauss_k) ** (1.0 / self._gauss_c)
        e = math.sqrt(_WGS84_E2)
        phi = np.array(chi, dtype=float, copy=True)
        for _ in range(20):
            es = e * np.sin(phi)
            new = 2.0 * np.arctan(num * ((1.0 - es) / (1.0 + es)) ** (-0.5 * e)) - 0.5 * math.pi
            done = not np.any(np.abs(new - phi) >= 1e-14)  # NaN in, NaN out: done
            phi = new
            if done:
                break
        lon = np.where(lon >= 180.0, lon - 360.0, lon)  # the mod rounds a hair west of -180 up to 180
        lat_deg = np.where(bad, np.nan, np.degrees(phi))
        return np.asarray(lat_deg, dtype=float), np.asarray(np.where(bad, np.nan, lon), dtype=float)

    def from_conformal_sphere(self, chi_rad: Any, lam_rad: Any) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """(conformal latitude, longitude from the centre) on the Gauss conformal sphere ->
        plane (x_m, y_m): the stereographic projection of that sphere, the inverse of
        :meth:`to_conformal_sphere` (Snyder 1987, eq. 21-4, 21-2, 21-3 with R = R_c, k0 = 1):

            k = 2 / (1 + sin chi0 sin chi + cos chi0 cos chi cos Lambda),
            x = R_c k cos chi sin Lambda,  y = R_c k (cos chi0 sin chi - sin chi0 cos chi cos Lambda).
        """
        chi, lam = np.asarray(chi_rad, dtype=float), np.asarray(lam_rad, dtype=float)
        s0, c0 = math.sin(self.conformal_center_lat_rad), math.cos(self.conformal_center_lat_rad)
        cos_chi, cos_lam = np.cos(chi), np.cos(lam)
        k = 2.0 / (1.0 + s0 * np.sin(chi) + c0 * cos_chi * cos_lam)
        x_m: NDArray[np.float64] = self.conformal_radius_m * k * cos_chi * np.sin(lam)
        y_m: NDArray[np.float64] = self.conformal_radius_m * k * (c0 * np.sin(chi) - s0 * cos_chi * cos_lam)
        return x_m, y_m

    def to_plane_and_factors(
        self, lat_deg: Any, lon_deg: Any
    ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        """Geodetic (degrees) -> plane (x_m, y_m), with the meridian convergence (degrees, as
        :meth:`grid_convergence_deg`) and the point scale factor k there, in one numpy pass:
        PROJ's own formulas for ``sterea`` (gauss.cpp, sterea.cpp), not a call into PROJ.

        The Gauss map onto the conformal sphere of radius R_c (``conformal_radius_m``),

            chi = 2 atan(K tan(phi/2 + pi/4)^C ((1 - e sin phi) / (1 + e sin phi))^(C e / 2)) - pi/2,
            Lambda = C (lambda - lambda0),

        then the sphere's stereographic projection (:meth:`from_conformal_sphere`). Both
        factors follow in closed form, the map being conformal: the Gauss map keeps the
        meridians (Lambda depends on lambda alone), so the convergence is the angle of the
        image of d/dchi in the plane, c = -atan2(dx/dchi, dy/dchi); the scale is the
        stereographic's 2 / D times the Gauss map's R_c C cos chi / (N cos phi) (a parallel's
        radius on the sphere over the ellipsoid's, N the prime-vertical radius). Against PROJ
        (to_plane, get_factors): nanometres and ~1e-10 relative (tests/test_coordinates.py);
        2.6 → 0.9 ms for 8,000 points, the two PROJ calls it replaces in
        :func:`radial_to_plane` (a projection, and a second one a step north for the factors).
        At a pole k is NaN (cos phi = 0)."""
        phi = np.radians(np.asarray(lat_deg, dtype=float))
        lam = self._gauss_c * np.radians(
            np.mod(np.asarray(lon_deg, dtype=float) - self.center_lon_deg + 180.0, 360.0) - 180.0
        )
        sin_phi = np.sin(phi)
        es = math.sqrt(_WGS84_E2) * sin_phi
        chi = (
            2.0
            * np.arctan(
                self._gauss_k
                * np.tan(0.5 * phi + 0.25 * math.pi) ** self._gauss_c
                * ((1.0 - es) / (1.0 + es)) ** self._gauss_ratexp
            )
            - 0.5 * math.pi
        )
        d, u, v, convergence_deg = self._stereographic_terms(chi, lam)
        x_m: NDArray[np.float64] = 2.0 * self.conformal_radius_m * u / d
        y_m: NDArray[np.float64] = 2.0 * self.conformal_radius_m * v / d
        n_m = _WGS84_A_M / np.sqrt(1.0 - _WGS84_E2 * sin_phi * sin_phi)
        k: NDArray[np.float64] = (2.0 / d) * self.conformal_radius_m * self._gauss_c * np.cos(chi) / (n_m * np.cos(phi))
        return x_m, y_m, convergence_deg, k

    def _stereographic_terms(
        self, chi: NDArray[np.float64], lam: NDArray[np.float64]
    ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        """The conformal sphere's stereographic projection at (chi, Lambda): D (the scale is
        2 / D), u and v (x = 2 R_c u / D, y = 2 R_c v / D), and the meridian convergence in
        degrees, c = −atan2(dx/dchi, dy/dchi) (to_plane_and_factors' closed form)."""
        s0, c0 = math.sin(self.conformal_center_lat_rad), math.cos(self.conformal_center_lat_rad)
        sin_chi, cos_chi = np.sin(chi), np.cos(chi)
        sin_lam, cos_lam = np.sin(lam), np.cos(lam)
        d = 1.0 + s0 * sin_chi + c0 * cos_chi * cos_lam
        u = cos_chi * sin_lam
        v = c0 * sin_chi - s0 * cos_chi * cos_lam
        d_chi = s0 * cos_chi - c0 * sin_chi * cos_lam  # dD/dchi; below D² times dx/dchi, dy/dchi (over 2 R_c)
        dx = -sin_chi * sin_lam * d - u * d_chi
        dy = (c0 * cos_chi + s0 * sin_chi * cos_lam) * d - v * d_chi
        return d, u, v, -np.degrees(np.arctan2(dx, dy))

    def velocity_frame(self, x_m: Any, y_m: Any) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """At plane points, for velocities: the meridian convergence (degrees, exact, as
        :meth:`to_plane_and_factors` gives it) and the point scale of the sphere's stereographic projection,
        k = 1 + r² / (4 R_c²), without the Gauss map's own scale, which is 1 to 2e-6 within
        600 km of the centre (tests/test_coordinates.py): no latitude, so no fixed point.
        For the Mode S velocities of every period (ground_velocity_to_plane), where 2e-6 is
        0.5 mm/s at 250 m/s against the reports' 0.5 m/s."""
        x = np.asarray(x_m, dtype=float)
        y = np.asarray(y_m, dtype=float)
        convergence_deg = self._stereographic_terms(*self.to_conformal_sphere(x, y))[3]
        k: NDArray[np.float64] = 1.0 + (x * x + y * y) / (4.0 * self.conformal_radius_m**2)
        return convergence_deg, k

    def grid_convergence_deg(self, lat_deg: Any, lon_deg: Any) -> np.ndarray:
        """Meridian convergence c at the given points, degrees.

        A true bearing (clockwise from true north) becomes the grid bearing
        (clockwise from the plane's +y axis) ``true - c``; c > 0 east of the centre.
        """
        lat = np.asarray(lat_deg, dtype=float)
        lon = np.asarray(lon_deg, dtype=float)
        f = self.proj.get_factors(lon, lat, errcheck=False)
        return np.asarray(f.meridian_convergence, dtype=float)

    def scale_factor(self, lat_deg: Any, lon_deg: Any) -> np.ndarray:
        """Point scale factor k (plane metres per ellipsoid metre; 1 at the centre)."""
        lat = np.asarray(lat_deg, dtype=float)
        lon = np.asarray(lon_deg, dtype=float)
        f = self.proj.get_factors(lon, lat, errcheck=False)
        # Conformal projection: meridional and parallel scales are equal.
        return np.asarray(f.meridional_scale, dtype=float)


class RadarSites:
    """Per-radar parameters as numpy arrays (row i = radar index i).

    Attributes (all shape (M,)): ``lat_deg``, ``lon_deg``, ``alt_m`` (antenna height
    above the ellipsoid), ``sigma_range_m``, ``sigma_azimuth_deg`` (1-sigma measurement
    noise), ``sigma_azimuth_rad``, ``earth_radius_m`` (Gaussian mean radius at the site,
    see :func:`gaussian_earth_radius_m`), and ``ids`` (tuple of radar ids, or indices
    as strings when none were given).
    """

    def __init__(
        self,
        lat_deg: Sequence[float] | np.ndarray,
        lon_deg: Sequence[float] | np.ndarray,
        alt_m: Sequence[float] | np.ndarray,
        sigma_range_m: Sequence[float] | np.ndarray,
        sigma_azimuth_deg: Sequence[float] | np.ndarray,
        ids: Sequence[str] | None = None,
    ) -> None:
        arrays = [
            np.array(v, dtype=float, ndmin=1) for v in (lat_deg, lon_deg, alt_m, sigma_range_m, sigma_azimuth_deg)
        ]
        n = arrays[0].shape[0]
        for name, arr in zip(("lat_deg", "lon_deg", "alt_m", "sigma_range_m", "sigma_azimuth_deg"), arrays):
            if arr.shape != (n,):
                raise ValueError(f"{name} must be a 1-D sequence of length {n}, got shape {arr.shape}")
            if not np.all(np.isfinite(arr)):
                raise ValueError(f"{name} must be finite")
        self.lat_deg, self.lon_deg, self.alt_m, self.sigma_range_m, self.sigma_azimuth_deg = arrays
        if np.any(np.abs(self.lat_deg) >= 90.0):
            raise ValueError("radar latitude must be in (-90, 90)")
        if np.any(self.sigma_range_m < 0.0) or np.any(self.sigma_azimuth_deg < 0.0):
            raise ValueError("sigmas must be non-negative")
        self.sigma_azimuth_rad = np.radians(self.sigma_azimuth_deg)
        self.earth_radius_m = gaussian_earth_radius_m(self.lat_deg)
        if ids is None:
            self.ids: tuple[str, ...] = tuple(str(i) for i in range(n))
        else:
            self.ids = tuple(str(i) for i in ids)
            if len(self.ids) != n:
                raise ValueError(f"ids must have length {n}")
        for arr in (*arrays, self.sigma_azimuth_rad, self.earth_radius_m):
            arr.setflags(write=False)

    @classmethod
    def from_configs(cls, configs: Sequence[Any]) -> RadarSites:
        """Build from objects with attributes ``lat_deg``, ``lon_deg``, ``alt_m``,
        ``sigma_range_m``, ``sigma_azimuth_deg`` (``lat``/``lon`` are accepted in place
        of ``lat_deg``/``lon_deg``, as in the daemon's TOML ``[[radars]]`` table) and
        optionally ``id``."""

        def get(c: Any, *names: str) -> Any:
            for name in names:
                if hasattr(c, name):
                    return getattr(c, name)
            raise AttributeError(f"radar config {c!r} has none of {names}")

        configs = list(configs)
        ids = [c.id for c in configs] if all(hasattr(c, "id") for c in configs) else None
        return cls(
            lat_deg=[get(c, "lat_deg", "lat") for c in configs],
            lon_deg=[get(c, "lon_deg", "lon") for c in configs],
            alt_m=[get(c, "alt_m") for c in configs],
            sigma_range_m=[get(c, "sigma_range_m") for c in configs],
            sigma_azimuth_deg=[get(c, "sigma_azimuth_deg") for c in configs],
            ids=ids,
        )

    def __len__(self) -> int:
        return int(self.lat_deg.shape[0])

    def __repr__(self) -> str:
        return f"RadarSites(n={len(self)}, ids={self.ids!r})"

    def index_of(self, radar_id: str) -> int:
        """Row index of radar ``radar_id``."""
        return self.ids.index(str(radar_id))

    def plane_positions(self, plane: SystemPlane) -> tuple[np.ndarray, np.ndarray]:
        """Site positions in ``plane`` (x_m, y_m), shape (M,)."""
        return plane.to_plane(self.lat_deg, self.lon_deg)

    def check_index(self, radar_index: Any) -> np.ndarray:
        """Return ``radar_index`` as an int array, raising ValueError if out of range."""
        idx = np.asarray(radar_index)
        if idx.size and not np.issubdtype(idx.dtype, np.integer):
            raise ValueError(f"radar_index must be integers, got dtype {idx.dtype}")
        idx = idx.astype(np.intp, copy=False)
        if idx.size and (idx.min() < 0 or idx.max() >= len(self)):
            raise ValueError(f"radar_index out of range [0, {len(self)})")
        return idx


def slant_to_ground_range(
    earth_radius_m: np.ndarray,
    antenna_alt_m: np.ndarray,
    target_alt_m: np.ndarray,
    range_m: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Ground range on the sphere of radius R from slant range, with partial derivatives.

    With a = R + h_r, b = R + h_t, rho the slant range (all broadcast arrays):

        sin(gamma/2) = sqrt((rho^2 - (a - b)^2) / (4 a b)),   g = R gamma,
        dg/drho = R rho / (a b sin gamma),
        dg/dh_t = R (a cos gamma - b) / (a b sin gamma).

    Impossible geometry is clamped: if rho < |a - b| (slant range shorter than the height
    difference, e.g. a wrong Mode C or a primary plot inside the assumed-altitude
    "cone") the ground range is 0 (target overhead the site); if rho > a + b it is
    pi R. Both cases, and non-finite inputs, come back with ``valid = False`` and NaN
    derivatives. At gamma = 0 exactly (rho = |a - b|) the derivatives are infinite:
    the linearisation breaks down in the cone of silence, and the value says so.

    Returns (ground_range_m, valid, dground_drange, dground_dheight).
    """
    r = np.asarray(earth_radius_m, dtype=float)
    a = r + np.asarray(antenna_alt_m, dtype=float)
    b = r + np.asarray(target_alt_m, dtype=float)
    rho = np.asarray(range_m, dtype=float)
    ab = a * b
    with np.errstate(invalid="ignore", divide="ignore"):
        s2 = (rho * rho - (a - b) ** 2) / (4.0 * ab)
        valid = np.isfinite(s2) & (s2 >= 0.0) & (s2 <= 1.0) & (rho >= 0.0)
        s2c = np.clip(np.where(np.isfinite(s2), s2, 0.0), 0.0, 1.0)
        gamma = 2.0 * np.arcsin(np.sqrt(s2c))
        ground_m = r * gamma
        ground_m = np.where(np.isfinite(s2), ground_m, np.nan)
        sin_g = np.sin(gamma)
        d_rho = r * rho / (ab * sin_g)
        d_h = r * (a * np.cos(gamma) - b) / (ab * sin_g)
    d_rho = np.where(valid, d_rho, np.nan)
    d_h = np.where(valid, d_h, np.nan)
    return ground_m, valid, d_rho, d_h


def ground_to_slant_range(
    earth_radius_m: np.ndarray,
    antenna_alt_m: np.ndarray,
    target_alt_m: np.ndarray,
    ground_range_m: np.ndarray,
) -> np.ndarray:
    """Slant range from ground range (exact inverse of :func:`slant_to_ground_range`).

    rho = sqrt((a - b)^2 + 4 a b sin^2(gamma/2)), gamma = g / R, a = R + h_r, b = R + h_t.
    """
    r = np.asarray(earth_radius_m, dtype=float)
    a = r + np.asarray(antenna_alt_m, dtype=float)
    b = r + np.asarray(target_alt_m, dtype=float)
    half = 0.5 * np.asarray(ground_range_m, dtype=float) / r
    s = np.sin(half)
    rho2: NDArray[np.float64] = (a - b) ** 2 + 4.0 * a * b * s * s
    return np.sqrt(rho2)


def radial_to_plane(
    plane: SystemPlane,
    sites: RadarSites,
    idx: NDArray[np.intp],
    theta_deg: NDArray[np.float64],
    ground_m: NDArray[np.float64],
    var_r_m2: NDArray[np.float64],
    var_c_m2: NDArray[np.float64],
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """A point ``ground_m`` along the geodesic from site ``idx`` at azimuth ``theta_deg``,
    with variances along (``var_r_m2``) and across (``var_c_m2``) the radial line at the
    target (ground metres) -> plane (x_m, y_m) and covariance (n, 2, 2), as documented in
    :func:`polar_to_plane` (forward azimuth at the target, meridian convergence, k^2)."""
    lon_t, lat_t, back_az_deg = WGS84_GEOD.fwd(sites.lon_deg[idx], sites.lat_deg[idx], theta_deg, ground_m)
    lon_t = np.asarray(lon_t, dtype=float)
    lat_t = np.asarray(lat_t, dtype=float)
    back_az_deg = np.asarray(back_az_deg, dtype=float)
    x_m, y_m, convergence_deg, k = plane.to_plane_and_factors(lat_t, lon_t)

    # Direction of the radial line at the target. At g = 0 the back azimuth is
    # meaningless; the site-side azimuth is used there (clamped plots only).
    forward_az_deg = np.where(ground_m > 0.0, back_az_deg + 180.0, theta_deg)
    beta = np.radians(forward_az_deg - convergence_deg)
    sb, cb = np.sin(beta), np.cos(beta)

    k2 = k * k
    cov = np.empty((ground_m.shape[0], 2, 2), dtype=float)
    cov[:, 0, 0] = k2 * (var_r_m2 * sb * sb + var_c_m2 * cb * cb)
    cov[:, 1, 1] = k2 * (var_r_m2 * cb * cb + var_c_m2 * sb * sb)
    cov[:, 0, 1] = cov[:, 1, 0] = k2 * (var_r_m2 - var_c_m2) * sb * cb
    return x_m, y_m, cov


def mark_unconverted(
    x_m: np.ndarray,
    y_m: np.ndarray,
    cov: np.ndarray,
    ground_m: np.ndarray,
    rho: np.ndarray,
    sigma_rho: np.ndarray,
    finite_in: np.ndarray,
    valid: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The conversions' common end for plots that did not convert: an impossible geometry
    (``finite_in & ~valid``) stays at the site with an isotropic covariance of its whole
    slant range; a non-finite input (``~finite_in``) becomes NaN throughout."""
    clamped = finite_in & ~valid
    if np.any(clamped):
        cov[clamped] = (rho[clamped] ** 2 + sigma_rho[clamped] ** 2)[:, None, None] * np.eye(2)
    if not np.all(finite_in):
        bad = ~finite_in
        x_m = np.where(bad, np.nan, x_m)
        y_m = np.where(bad, np.nan, y_m)
        ground_m = np.where(bad, np.nan, ground_m)
        cov[bad] = np.nan
    return x_m, y_m, cov, ground_m


#: the least cross-range variance of a plot (1 m): only a plot within a few hundred metres
#: of its antenna (g·σ_θ under a metre) is placed more precisely across the beam, where
#: (g σ_θ)² would make its covariance singular against the range's (a plot at 1e-9 m gave
#: a NaN track)
MIN_CROSS_RANGE_VAR_M2 = 1.0


#: 1-sigma error of a Mode C level taken as a height, as a fraction of the height: Mode C is
#: pressure altitude, and on a day ΔT off ISA a level lies ΔT/T_isa higher, 0.4 % per kelvin
#: (geo.air_data.height_of_pressure_altitude_m: FL360 656 m higher at ISA+15). 3 %: ±7.5 K,
#: mid-latitude days. Near the antenna that error becomes ground range (dg/dh ~ h/g): real
#: data, Jahorina's 4CA9F6 at FL360 passing 4 km from the antenna, whose plots, taken with
#: 60 m, put it at 139 instead of its own 205 m/s, its track refusing its BDS 5,0 reports
MODE_C_HEIGHT_SIGMA_FRACTION = 0.03
#: ... and where the day's temperature is configured (:func:`mode_c_height_m`): the air
#: departs from one temperature deviation at every level and place by a few kelvin, 1 %
MODE_C_HEIGHT_SIGMA_FRACTION_WITH_MET = 0.01


def mode_c_height_m(fl: Any, temperature_deviation_k: float | None = None, qnh_hpa: float | None = None) -> np.ndarray:
    """Mode C flight level -> height above mean sea level, m. Without the day's met data
    (both None) the pressure altitude itself, fl × 30.48 (:func:`flight_level_to_altitude_m`);
    with it, the level's height on a day ``temperature_deviation_k`` off ISA at every level
    (0 if None) with sea-level pressure ``qnh_hpa`` (1013.25 if None), by the hypsometric
    equation (geo.air_data.height_of_pressure_altitude_m). NaN passes through."""
    pressure_altitude_m = flight_level_to_altitude_m(fl)
    if temperature_deviation_k is None and qnh_hpa is None:
        return pressure_altitude_m
    return height_of_pressure_altitude_m(
        pressure_altitude_m,
        0.0 if temperature_deviation_k is None else float(temperature_deviation_k),
        1013.25 if qnh_hpa is None else float(qnh_hpa),
    )


def polar_to_plane(
    plane: SystemPlane,
    sites: RadarSites,
    radar_index: Any,
    range_m: Any,
    azimuth_deg: Any,
    altitude_m: Any,
    assumed_altitude_m: float = 3000.0,
    sigma_unknown_altitude_m: float = 3000.0,
    sigma_known_altitude_m: float = 60.0,
    sigma_known_altitude_fraction: float = MODE_C_HEIGHT_SIGMA_FRACTION,
    *,
    return_valid: bool = False,
) -> tuple[np.ndarray, ...]:
    """Radar plots (slant range, azimuth, height) -> system plane position and covariance.

    Parameters (all per plot, shape (N,)):
        radar_index: row of ``sites`` that produced each plot.
        range_m: slant range from the antenna, metres.
        azimuth_deg: from true north at the antenna, clockwise, degrees.
        altitude_m: target height above the ellipsoid, metres; NaN when unknown.
        assumed_altitude_m: height used for plots without altitude (primary-only plots).
        sigma_unknown_altitude_m / sigma_known_altitude_m: 1-sigma height error used
            for the covariance of plots without / with altitude.
        sigma_known_altitude_fraction: with altitude, the height error also grows by this
            fraction of the height: hypot(sigma_known_altitude_m, fraction · h), the
            pressure altitude's departure from the height on a non-ISA day
            (:data:`MODE_C_HEIGHT_SIGMA_FRACTION`).
        return_valid: also return the ``valid`` mask (see below).

    Position. Ground range g from the spherical law of cosines on the site's Gaussian
    sphere (:func:`slant_to_ground_range`); then ``Geod.fwd`` walks g along the WGS-84
    geodesic from the site with initial azimuth theta, and the result is projected into
    ``plane``.

    Covariance (linearised, 2x2 in plane metres). In the local frame at the target:

        along-range  var_r = (dg/drho * sigma_rho)^2 + (dg/dh_t * sigma_h)^2
        cross-range  var_c = (R sin(gamma) * sigma_theta)^2

    (sigma_h: with Mode C hypot(sigma_known_altitude_m, sigma_known_altitude_fraction · h),
    without it sigma_unknown_altitude_m; dg/dh_t ~ −(h_t − h_r)/g grows without bound
    towards the zenith, where a few hundred metres of height become a kilometre of range.)

    (R sin gamma is the geodesic's lateral displacement per radian of azimuth on the
    sphere; it equals g to 0.1 % at 250 NM, i.e. var_c ~ (g sigma_theta)^2.) The
    along-range direction at the target is its forward azimuth alpha_t = back azimuth
    from ``Geod.fwd`` + 180° (this carries the direction change along the geodesic);
    in the plane it points at grid bearing beta = alpha_t - c, c the meridian
    convergence of the stereographic plane at the target
    (:meth:`SystemPlane.to_plane_and_factors`, PROJ's formulas). With
    u = (sin beta, cos beta), v = (cos beta, -sin beta) and k the point scale factor:

        cov_xy = k^2 (var_r u u^T + var_c v v^T).

    Assumption for plots without altitude: the target flies at ``assumed_altitude_m``
    with 1-sigma ``sigma_unknown_altitude_m``; the error this causes in the ground range
    enters var_r through dg/dh_t (it is small far out and large close to the radar).

    Impossible geometry (slant range shorter than the height difference between antenna
    and target): the ground range is clamped to 0, the plot is placed at the site, and
    its covariance is isotropic with variance rho^2 + sigma_rho^2 per axis (the target
    is somewhere within the slant range of the antenna), so fusion gives it almost no
    weight. Such plots, and plots with non-finite or negative range or non-finite azimuth (which give NaN
    position and covariance), have ``valid = False``.

    Returns ``(x_m, y_m, cov_xy_m2 (N,2,2), ground_range_m)``, plus ``valid`` (N,) bool
    when ``return_valid`` is true.
    """
    idx = sites.check_index(radar_index)
    rho = np.asarray(range_m, dtype=float)
    theta_deg = np.asarray(azimuth_deg, dtype=float)
    h_t = np.asarray(altitude_m, dtype=float)
    rho, theta_deg, h_t, idx = np.broadcast_arrays(rho, theta_deg, h_t, idx)
    rho = rho.reshape(-1)
    theta_deg = theta_deg.reshape(-1)
    h_t = h_t.reshape(-1)
    idx = idx.reshape(-1)
    n = rho.shape[0]
    if n == 0:
        empty = np.empty(0, dtype=float)
        out = (empty, empty.copy(), np.empty((0, 2, 2), dtype=float), empty.copy())
        return (*out, np.empty(0, dtype=bool)) if return_valid else out

    known = np.isfinite(h_t)
    h_used = np.where(known, h_t, float(assumed_altitude_m))
    sigma_h = np.where(
        known,
        np.hypot(float(sigma_known_altitude_m), float(sigma_known_altitude_fraction) * np.abs(h_used)),
        float(sigma_unknown_altitude_m),
    )

    r_m = sites.earth_radius_m[idx]
    h_r = sites.alt_m[idx]
    finite_in = np.isfinite(rho) & np.isfinite(theta_deg) & (rho >= 0.0)
    rho_safe = np.where(finite_in, rho, 0.0)
    theta_safe = np.where(finite_in, theta_deg, 0.0)

    ground_m, valid, d_rho, d_h = slant_to_ground_range(r_m, h_r, h_used, rho_safe)
    valid &= finite_in

    sigma_rho = sites.sigma_range_m[idx]
    sigma_theta = sites.sigma_azimuth_rad[idx]
    var_r = (d_rho * sigma_rho) ** 2 + (d_h * sigma_h) ** 2
    var_c = np.maximum((r_m * np.sin(ground_m / r_m) * sigma_theta) ** 2, MIN_CROSS_RANGE_VAR_M2)
    x_m, y_m, cov = radial_to_plane(plane, sites, idx, theta_safe, ground_m, var_r, var_c)

    x_m, y_m, cov, ground_m = mark_unconverted(x_m, y_m, cov, ground_m, rho, sigma_rho, finite_in, valid)
    if return_valid:
        return x_m, y_m, cov, ground_m, valid
    return x_m, y_m, cov, ground_m


def geodetic_to_polar(
    sites: RadarSites,
    radar_index: Any,
    lat_deg: Any,
    lon_deg: Any,
    altitude_m: Any,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Target position -> what radar ``radar_index`` measures (noise-free).

    ``Geod.inv`` from the site to the target gives the azimuth theta (true north,
    clockwise, in [0, 360)) and the geodesic length g on WGS-84; the slant range is
    rho = sqrt((a - b)^2 + 4 a b sin^2(g / 2R)) on the site's Gaussian sphere
    (a = R + h_r, b = R + h_t). This is the exact inverse of :func:`polar_to_plane`.
    A NaN altitude gives a NaN slant range (truth always has a height).

    Returns (range_m slant, azimuth_deg, ground_range_m), each (N,).
    """
    idx = sites.check_index(radar_index)
    lat = np.asarray(lat_deg, dtype=float)
    lon = np.asarray(lon_deg, dtype=float)
    h_t = np.asarray(altitude_m, dtype=float)
    lat, lon, h_t, idx = (a.reshape(-1) for a in np.broadcast_arrays(lat, lon, h_t, idx))
    az_deg, _back_az, ground_m = WGS84_GEOD.inv(sites.lon_deg[idx], sites.lat_deg[idx], lon, lat)
    az_deg = np.mod(np.asarray(az_deg, dtype=float), 360.0)
    ground_m = np.asarray(ground_m, dtype=float)
    bad = ~(np.isfinite(lat) & np.isfinite(lon))
    if np.any(bad):
        az_deg[bad] = np.nan
        ground_m[bad] = np.nan
    range_m = ground_to_slant_range(sites.earth_radius_m[idx], sites.alt_m[idx], h_t, ground_m)
    return range_m, az_deg, ground_m


def plane_to_ground_polar(
    plane: SystemPlane,
    site_chi_rad: NDArray[np.float64],
    site_lam_rad: NDArray[np.float64],
    x_m: Any,
    y_m: Any,
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Plane positions -> ground range (m) and azimuth (degrees, [0, 360)) from sites
    given on the conformal sphere (``plane.to_conformal_sphere`` of their plane
    positions; ``site_*`` broadcast against ``x_m``/``y_m``), without PROJ: a fast
    stand-in for ``to_geodetic`` + ``Geod.inv`` (:func:`geodetic_to_polar`) where many
    (site, point) pairs are needed, e.g. to gate plots against tracks.

    On the sphere of radius R_c, with dchi, dLambda the differences from the site
    (haversine and the initial great-circle bearing):

        g = 2 R_c asin(sqrt(sin^2(dchi/2) + cos chi_s cos chi sin^2(dLambda/2))),
        theta = atan2(sin dLambda cos chi, cos chi_s sin chi - sin chi_s cos chi cos dLambda).

    Against ``Geod.inv``, for sites within 500 km of the plane's centre and points 0-250
    km from them: < 1 m and < 1e-4 degree (tests/test_coordinates.py), far below a
    radar's noise (>= 20 m, 0.03 degree).
    """
    chi, lam = plane.to_conformal_sphere(x_m, y_m)
    return conformal_sphere_polar(plane.conformal_radius_m, site_chi_rad, site_lam_rad, chi, lam)


def conformal_sphere_polar(
    radius_m: float, site_chi_rad: Any, site_lam_rad: Any, chi_rad: Any, lam_rad: Any
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The formulas of :func:`plane_to_ground_polar` for points already on the conformal
    sphere (``SystemPlane.to_conformal_sphere``), so that each point is mapped once for
    all the sites it is seen from. Returns (ground_m, azimuth_deg)."""
    chi, lam = np.asarray(chi_rad, dtype=float), np.asarray(lam_rad, dtype=float)
    site_chi = np.asarray(site_chi_rad, dtype=float)
    d_lam = lam - np.asarray(site_lam_rad, dtype=float)
    cos_s, cos_t = np.cos(site_chi), np.cos(chi)
    hav = np.sin(0.5 * (chi - site_chi)) ** 2 + cos_s * cos_t * np.sin(0.5 * d_lam) ** 2
    ground_m: NDArray[np.float64] = 2.0 * radius_m * np.arcsin(np.sqrt(np.clip(hav, 0.0, 1.0)))
    az = np.arctan2(np.sin(d_lam) * cos_t, cos_s * np.sin(chi) - np.sin(site_chi) * cos_t * np.cos(d_lam))
    az_deg: NDArray[np.float64] = np.mod(np.degrees(az), 360.0)
    return ground_m, az_deg


def conformal_sphere_destination(
    radius_m: float, site_chi_rad: Any, site_lam_rad: Any, azimuth_deg: Any, ground_m: Any
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The point ``ground_m`` from a site at initial bearing ``azimuth_deg`` along the great
    circle of the conformal sphere (the inverse of :func:`conformal_sphere_polar`), with
    delta = g / R_c:

        sin chi = sin chi_s cos delta + cos chi_s sin delta cos theta,
        Lambda = Lambda_s + atan2(sin theta sin delta cos chi_s, cos delta - sin chi_s sin chi).

    Returns (chi_rad, lam_rad); ``SystemPlane.from_conformal_sphere`` puts it in the plane."""
    theta = np.radians(np.asarray(azimuth_deg, dtype=float))
    delta = np.asarray(ground_m, dtype=float) / radius_m
    site_chi = np.asarray(site_chi_rad, dtype=float)
    sin_s, cos_s = np.sin(site_chi), np.cos(site_chi)
    sin_chi = np.clip(sin_s * np.cos(delta) + cos_s * np.sin(delta) * np.cos(theta), -1.0, 1.0)
    lam = np.asarray(site_lam_rad, dtype=float) + np.arctan2(
        np.sin(theta) * np.sin(delta) * cos_s, np.cos(delta) - sin_s * sin_chi
    )
    chi: NDArray[np.float64] = np.arcsin(sin_chi)
    return chi, lam


def ground_velocity_to_plane(
    plane: SystemPlane, x_m: Any, y_m: Any, speed_mps: Any, track_deg: Any, altitude_m: Any
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """An aircraft's own ground speed and true track angle (Mode S BDS 5,0: GNSS or
    inertial, at the aircraft) at the plane position (x_m, y_m) and altitude -> its
    velocity (vx, vy) in the system plane, m/s.

    The track turns from true to grid bearing by the meridian convergence c there,
    beta = track - c (:meth:`SystemPlane.grid_convergence_deg`); the speed scales by the
    plane's point scale k and by R / (R + h): plot positions are on the ellipsoid under
    the aircraft (the ground range of the spherical model above), which moves R / (R + h)
    as fast as the aircraft at height h (0.17 % slower at FL350), R the Gaussian radius at
    the plane's centre (R_c; at the aircraft's latitude it differs by 1e-6 of R / (R + h)
    within 600 km). c and k from :meth:`SystemPlane.velocity_frame` (k to 2e-6).
    NaN altitude: taken as 0."""
    convergence_deg, k = plane.velocity_frame(x_m, y_m)
    radius_m = plane.conformal_radius_m
    h = np.nan_to_num(np.asarray(altitude_m, dtype=float), nan=0.0)
    speed = np.asarray(speed_mps, dtype=float) * k * radius_m / (radius_m + h)
    beta = np.radians(np.asarray(track_deg, dtype=float) - convergence_deg)
    return speed * np.sin(beta), speed * np.cos(beta)


def flight_level_to_altitude_m(fl: Any) -> np.ndarray:
    """Flight level (100 ft units) -> altitude in metres: alt_m = fl * 30.48.

    Assumption: pressure altitude is used as height above the ellipsoid, with no
    QNH, temperature or geoid correction (errors of a few hundred metres are possible;
    the covariance's altitude term carries them, :data:`MODE_C_HEIGHT_SIGMA_FRACTION`).
    NaN passes through.
    """
    return np.asarray(fl, dtype=float) * M_PER_FL


def altitude_m_to_flight_level(alt_m: Any) -> np.ndarray:
    """Altitude in metres -> flight level (100 ft units): fl = alt_m / 30.48.

    Same assumption as :func:`flight_level_to_altitude_m` (no pressure correction);
    not rounded; NaN passes through.
    """
    return np.asarray(alt_m, dtype=float) / M_PER_FL
