"""The volumes the safety nets watch: APW areas and the minimum-safe-altitude map.

Both are read once, when :class:`~radar_fusion.safety_nets.SafetyNets` is built, from
GeoJSON ([lon, lat] positions) into the system plane; a bad file raises ``ValueError``
naming the file and the feature, so the daemon refuses to start on it.
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..geo.coordinates import SystemPlane
from .polygon import Polygon


@dataclass
class Area:
    """An APW volume: lateral polygon (system plane) and vertical band [lower_fl, upper_fl]."""

    area_id: str
    polygon: Polygon
    lower_fl: float
    upper_fl: float


def _read_json(path: Path) -> Any:
    try:
        return json.loads(Path(path).read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise ValueError(f"{path}: file not found") from None
    except json.JSONDecodeError as exc:
        raise ValueError(f"{path}: not valid JSON: {exc}") from None


def _features(doc: Any, path: Path) -> list[dict]:
    if not isinstance(doc, dict) or doc.get("type") != "FeatureCollection":
        raise ValueError(f"{path}: expected a GeoJSON FeatureCollection")
    return list(doc.get("features") or [])


def load_areas(path: str | Path, plane: SystemPlane) -> list[Area]:
    """APW volumes from a GeoJSON FeatureCollection of (Multi)Polygons ([lon, lat] order).

    Feature properties: ``id`` (or the feature's ``id``; required, unique), ``lower_fl``
    (default −20, the surface) and ``upper_fl`` (default 1300, unlimited), inclusive.
    """
    path = Path(path)
    areas: list[Area] = []
    for k, feat in enumerate(_features(_read_json(path), path)):
        props = feat.get("properties") or {}
        area_id = props.get("id", feat.get("id"))
        if area_id is None:
            raise ValueError(f"{path}: feature {k} has no id")
        try:
            poly = Polygon.from_geojson(plane, feat.get("geometry") or {})
        except ValueError as exc:
            raise ValueError(f"{path}: feature {area_id!r}: {exc}") from None
        lower, upper = float(props.get("lower_fl", -20.0)), float(props.get("upper_fl", 1300.0))
        if not lower <= upper:
            raise ValueError(f"{path}: feature {area_id!r}: lower_fl > upper_fl")
        areas.append(Area(str(area_id), poly, lower, upper))
    ids = [a.area_id for a in areas]
    if len(set(ids)) != len(ids):
        raise ValueError(f"{path}: area ids must be unique")
    return areas


class MsaMap:
    """Minimum safe altitude (ft, QNH) as polygons in the plane or a lat/lon grid.

    Polygons: the MSA at a point is the largest ``min_alt_ft`` of the polygons holding
    it. Grid: cell (i, j) covers latitudes lat0 + [i, i+1)·dlat and longitudes
    lon0 + [j, j+1)·dlon (row 0 is the southern edge); NaN cells have no minimum.
    Points outside every polygon or the grid have no minimum (−inf).
    """

    def __init__(
        self,
        polygons: Sequence[tuple[str, Polygon, float]] = (),
        grid: dict[str, Any] | None = None,
    ) -> None:
        self.polygons = list(polygons)
        self.grid = grid
        maxima = [m for _, _, m in self.polygons]
        if grid is not None:
            g = grid["min_alt_ft"]
            if np.any(np.isfinite(g)):
                maxima.append(float(np.nanmax(g)))
        self.max_alt_ft = max(maxima) if maxima else -math.inf

    def lookup(self, plane_xy: np.ndarray, latlon: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
        """MSA (ft) and the id of the polygon/grid that sets it, for (M, 2) points."""
        m = plane_xy.shape[0]
        msa = np.full(m, -np.inf)
        src = np.full(m, -1, dtype=np.int64)
        for k, (_, poly, alt) in enumerate(self.polygons):
            x0, y0, x1, y1 = poly.bbox
            box = (plane_xy[:, 0] >= x0) & (plane_xy[:, 0] <= x1) & (plane_xy[:, 1] >= y0) & (plane_xy[:, 1] <= y1)
            if not box.any():
                continue
            idx = np.flatnonzero(box)
            inside = idx[poly.contains(plane_xy[idx])]
            better = inside[alt > msa[inside]]
            msa[better] = alt
            src[better] = k
        if self.grid is not None and latlon is not None and m:
            g = self.grid
            i = np.floor((latlon[:, 0] - g["lat0_deg"]) / g["dlat_deg"]).astype(np.int64)
            j = np.floor((latlon[:, 1] - g["lon0_deg"]) / g["dlon_deg"]).astype(np.int64)
            rows, cols = g["min_alt_ft"].shape
            ok = (i >= 0) & (i < rows) & (j >= 0) & (j < cols)
            val = np.full(m, -np.inf)
            val[ok] = g["min_alt_ft"][i[ok], j[ok]]
            val[~np.isfinite(val)] = -np.inf
            better = val > msa
            msa[better] = val[better]
            src[better] = len(self.polygons)
        return msa, src

    def source_id(self, k: int) -> str:
        return self.polygons[k][0] if 0 <= k < len(self.polygons) else "grid"


def load_msa(path: str | Path, plane: SystemPlane) -> MsaMap:
    """Read a minimum-safe-altitude map.

    Either a GeoJSON FeatureCollection of (Multi)Polygons with properties ``id`` and
    ``min_alt_ft`` (feet above mean sea level), or a JSON object
    ``{"type": "MsaGrid", "lat0_deg", "lon0_deg", "dlat_deg", "dlon_deg",
    "min_alt_ft": [[row 0 (south) ...], ...]}`` (null for no minimum).
    """
    path = Path(path)
    doc = _read_json(path)
    if isinstance(doc, dict) and doc.get("type") == "MsaGrid":
        try:
            grid: dict[str, Any] = {k: float(doc[k]) for k in ("lat0_deg", "lon0_deg", "dlat_deg", "dlon_deg")}
            arr = np.array([[np.nan if v is None else float(v) for v in row] for row in doc["min_alt_ft"]], float)
        except (KeyError, TypeError, ValueError) as exc:
            raise ValueError(f"{path}: bad MsaGrid: {exc}") from None
        if arr.ndim != 2 or arr.size == 0 or grid["dlat_deg"] <= 0 or grid["dlon_deg"] <= 0:
            raise ValueError(f"{path}: MsaGrid needs a non-empty 2-D min_alt_ft and positive steps")
        grid["min_alt_ft"] = arr
        return MsaMap(grid=grid)
    polys = []
    for k, feat in enumerate(_features(doc, path)):
        props = feat.get("properties") or {}
        pid = str(props.get("id", feat.get("id", f"msa{k}")))
        if "min_alt_ft" not in props:
            raise ValueError(f"{path}: feature {pid!r} has no min_alt_ft")
        try:
            poly = Polygon.from_geojson(plane, feat.get("geometry") or {})
        except ValueError as exc:
            raise ValueError(f"{path}: feature {pid!r}: {exc}") from None
        polys.append((pid, poly, float(props["min_alt_ft"])))
    return MsaMap(polygons=polys)
