"""The fixed part of the picture, in system-plane metres: range rings, a lat/lon grid,
the radar sites and the APW / MSAW areas of the daemon's configuration.

Computed once from the configuration with the daemon's own projection
(:class:`~radar_fusion.geo.coordinates.SystemPlane`, centred at ``[system]
center_lat/center_lon``) and sent to the page as JSON, so the page draws tracks
(which carry plane ``x_m``/``y_m``) and the map in one frame and does no geodesy.

Range rings are geodesic circles around the system centre (every ``ring_step_nm``),
projected point by point: the plane's scale grows away from the centre (k ≈ 1.001 at
400 km), so a ring of 200 NM is drawn where a track 200 NM out is, not at 200·1852 m
of plane distance. Grid lines are meridians and parallels sampled every
``GRID_SAMPLE_DEG`` and projected the same way: they curve as on the daemon's plane.

A bad areas or MSA file does not stop the display (the daemon refuses to start on it,
so a controller would learn it there): the scene carries a warning and no areas.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from ..config import Settings
from ..geo.coordinates import WGS84_GEOD, SystemPlane
from ..geo.units import M_PER_NM
from ..safety_nets.areas import load_areas, load_msa
from ..safety_nets.polygon import Polygon

RING_POINTS = 180
"""Vertices per range ring (every 2°): below a pixel of error at any useful zoom."""
GRID_SAMPLE_DEG = 0.1
"""Spacing of the projected points along a grid line, degrees."""
MAX_EXTENT_M = 1_000_000.0
"""The scene covers at most this far from the centre, whatever the radars' ranges."""


def _round(values: np.ndarray) -> list[float]:
    """Plane metres to the metre: the page draws pixels of at least tens of metres."""
    return np.round(values, 0).tolist()


def coverage_extent_m(settings: Settings) -> float:
    """How far from the centre the picture reaches: the farthest radar coverage edge."""
    plane = SystemPlane(settings.system.center_lat, settings.system.center_lon)
    lat = np.array([r.lat for r in settings.radars])
    lon = np.array([r.lon for r in settings.radars])
    x_m, y_m = plane.to_plane(lat, lon)
    reach_m = np.hypot(x_m, y_m) + np.array([r.max_range_m for r in settings.radars])
    return float(min(reach_m.max(), MAX_EXTENT_M))


def range_rings(plane: SystemPlane, extent_m: float, ring_step_nm: float) -> list[dict[str, Any]]:
    """Geodesic circles every ``ring_step_nm`` around the centre, out to ``extent_m``."""
    rings = []
    az_deg = np.linspace(0.0, 360.0, RING_POINTS, endpoint=False)
    n = int(extent_m // (ring_step_nm * M_PER_NM))
    for k in range(1, n + 1):
        dist_m = k * ring_step_nm * M_PER_NM
        lon, lat, _ = WGS84_GEOD.fwd(
            np.full(RING_POINTS, plane.center_lon_deg),
            np.full(RING_POINTS, plane.center_lat_deg),
            az_deg,
            np.full(RING_POINTS, dist_m),
        )
        x_m, y_m = plane.to_plane(lat, lon)
        rings.append({"range_nm": k * ring_step_nm, "x": _round(x_m), "y": _round(y_m)})
    return rings


def grid_step_deg(extent_m: float) -> float:
    """A round grid spacing giving some 4 to 12 lines across the picture."""
    span_deg = 2.0 * extent_m / 111_000.0
    for step in (0.1, 0.25, 0.5, 1.0, 2.0, 5.0, 10.0):
        if span_deg / step <= 12:
            return step
    return 10.0


def lat_lon_grid(plane: SystemPlane, extent_m: float) -> list[dict[str, Any]]:
    """Meridians and parallels every :func:`grid_step_deg` over the picture, projected."""
    step = grid_step_deg(extent_m)
    lat0, lon0 = plane.center_lat_deg, plane.center_lon_deg
    dlat = extent_m / 111_000.0
    dlon = dlat / max(math.cos(math.radians(lat0)), 0.05)
    lat_lo, lat_hi = max(lat0 - dlat, -89.0), min(lat0 + dlat, 89.0)
    lon_lo, lon_hi = lon0 - dlon, lon0 + dlon
    lines = []
    along_lat = np.arange(lat_lo, lat_hi + GRID_SAMPLE_DEG / 2, GRID_SAMPLE_DEG)
    along_lon = np.arange(lon_lo, lon_hi + GRID_SAMPLE_DEG / 2, GRID_SAMPLE_DEG)
    for lon_deg in np.arange(math.ceil(lon_lo / step) * step, lon_hi, step).tolist():
        x_m, y_m = plane.to_plane(along_lat, np.full(along_lat.shape, lon_deg))
        lines.append({"kind": "meridian", "deg": round(lon_deg, 6), "x": _round(x_m), "y": _round(y_m)})
    for lat_deg in np.arange(math.ceil(lat_lo / step) * step, lat_hi, step).tolist():
        x_m, y_m = plane.to_plane(np.full(along_lon.shape, lat_deg), along_lon)
        lines.append({"kind": "parallel", "deg": round(lat_deg, 6), "x": _round(x_m), "y": _round(y_m)})
    return lines


def _polygon_rings(poly: Polygon) -> list[dict[str, list[float]]]:
    """Every ring of a polygon (exteriors and holes; the page fills them even-odd)."""
    rings = []
    for outer, holes in poly.parts:
        for ring in (outer, *holes):
            rings.append({"x": _round(ring[:, 0]), "y": _round(ring[:, 1])})
    return rings


def build_scene(settings: Settings, base_dir: Path | None = None, ring_step_nm: float = 10.0) -> dict[str, Any]:
    """The scene as a JSON-ready dict (see the module docstring); ``base_dir`` is where
    relative ``areas_file`` / ``msa_file`` paths resolve (the config file's directory)."""
    plane = SystemPlane(settings.system.center_lat, settings.system.center_lon)
    extent_m = coverage_extent_m(settings)
    lat = np.array([r.lat for r in settings.radars])
    lon = np.array([r.lon for r in settings.radars])
    rx_m, ry_m = plane.to_plane(lat, lon)
    radars = [
        {
            "id": r.id,
            "x_m": round(float(x), 0),
            "y_m": round(float(y), 0),
            "max_range_m": r.max_range_m,
            "rotation_period_s": r.rotation_period_s,
        }
        for r, x, y in zip(settings.radars, rx_m, ry_m)
    ]
    warnings: list[str] = []
    nets = settings.safety_nets

    def resolve(p: Path) -> Path:
        return p if p.is_absolute() or base_dir is None else Path(base_dir) / p

    apw: list[dict[str, Any]] = []
    if nets.areas_file is not None:
        try:
            for area in load_areas(resolve(nets.areas_file), plane):
                apw.append(
                    {
                        "id": area.area_id,
                        "lower_fl": area.lower_fl,
                        "upper_fl": area.upper_fl,
                        "rings": _polygon_rings(area.polygon),
                    }
                )
        except ValueError as exc:
            warnings.append(f"APW areas not shown: {exc}")
    msa: list[dict[str, Any]] = []
    if nets.msa_file is not None:
        try:
            msa_map = load_msa(resolve(nets.msa_file), plane)
            for area_id, poly, min_alt_ft in msa_map.polygons:
                msa.append({"id": area_id, "min_alt_ft": min_alt_ft, "rings": _polygon_rings(poly)})
            if msa_map.grid is not None:
                warnings.append("the MSA grid is not drawn (only MSA polygons are)")
        except ValueError as exc:
            warnings.append(f"MSA areas not shown: {exc}")
    return {
        "v": 1,
        "center_lat_deg": plane.center_lat_deg,
        "center_lon_deg": plane.center_lon_deg,
        "period_s": settings.system.period_s,
        "level_vrate_fpm": nets.level_vrate_fpm,
        "extent_m": round(extent_m, 0),
        "ring_step_nm": ring_step_nm,
        "rings": range_rings(plane, extent_m, ring_step_nm),
        "grid": lat_lon_grid(plane, extent_m),
        "radars": radars,
        "apw_areas": apw,
        "msa_areas": msa,
        "warnings": warnings,
    }
