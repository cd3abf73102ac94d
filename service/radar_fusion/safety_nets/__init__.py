"""Ground-based safety nets on the fused tracks: STCA, APW and MSAW (DESIGN.md §2, §3).

The engine calls :meth:`SafetyNets.update` once per closed period with the system tracks
as numpy columns (:class:`TrackArrays`); it returns the Alert messages of that period
(``new``, ``ongoing`` and ``ended``) as dicts that follow ``wire.Alert`` (v = 1), which the
daemon publishes on ``<prefix>/fusion/alerts/<kind>``. No I/O happens here except reading
the area and minimum-safe-altitude files once, at construction.

References
----------
* [STCA-SPEC] EUROCONTROL Specification for Short Term Conflict Alert
  (EUROCONTROL-SPEC-0107, ed. 1.0, 2007) and the EUROCONTROL Guidelines for STCA, Part I-III
  (2017); Part III / the guidance appendix "Reference STCA system" describes the fine
  filters used here: a *linear prediction filter* (horizontal and vertical linear
  prediction over a look-ahead time, conflict when both separations are predicted below
  their thresholds at the same time), a *current proximity filter* (separations below
  thresholds now) and a *manoeuvre (turn) prediction* for turning aircraft, followed by
  *alert confirmation* over successive cycles to suppress nuisance alerts. Parameters
  may differ per airspace volume (e.g. 3 NM in a TMA, 5 NM en route).
* [APW-GUID] EUROCONTROL Guidelines for Area Proximity Warning, Part I-III (2017): warn
  when a track is inside, or is predicted to penetrate within the look-ahead, a notified
  volume (lateral polygon, lower and upper level).
* [MSAW-GUID] EUROCONTROL Guidelines for Minimum Safe Altitude Warning, Part I-III
  (EUROCONTROL-GUID-160, 2017): warn when a track is below, or its predicted path
  (horizontal prediction plus linear vertical prediction with its vertical rate) will
  descend below, the minimum safe altitude of the terrain/obstacle map.

Prediction model (shared by the three functions)
------------------------------------------------
Horizontal, in the system plane. *Linear*: p(t) = p0 + v t. *Turn*: the track's turn
rate from the Singer state is ω = (vx·ay − vy·ax)/|v|² (the z component of v×a over
|v|²; ω > 0 is a left, counter-clockwise turn). A track with |ω| ≥ ``turn_min_dps`` is
predicted along the circular arc (|ω| capped at ``turn_max_dps``) until its heading has
changed by ``turn_max_heading_change_deg``, then straight on:

    v(t) = R(ω t) v0,   p(t) = p0 + (1/ω) [[sin ωt, −(1 − cos ωt)], [1 − cos ωt, sin ωt]] v0.

Vertical, in feet. A rate below ``level_vrate_fpm`` in magnitude (tracker noise on a
level aircraft) counts as level; otherwise z(t) = z0 + ż t. *Level-off anticipation*:
the vertical rates of the last few periods are kept per track; when their least-squares
slope (the vertical acceleration, fpm/s) opposes the rate and exceeds
``capture_min_fpm_per_s``, the aircraft is capturing a level and is predicted to
decelerate uniformly until its rate is zero, then stay level. A known selected or
cleared level (``TrackArrays.selected_fl``, e.g. Mode S BDS 4,0 or the flight plan's CFL)
caps the prediction, as [STCA-SPEC] recommends for reducing level-off nuisance alerts.

STCA conflict test (exact for piecewise-linear paths)
-----------------------------------------------------
The predicted paths are evaluated at knots t_k = k·``prediction_step_s`` over the
look-ahead T and taken as linear between knots (exact for linear prediction; for a turn
the chord error is v·ω·Δt²/8, ≈ 40 m at 250 m/s, 3 °/s, Δt = 5 s). On a segment, the
relative position is d(τ) = d_k + w τ and the relative height h(τ) = h_k + u τ, so

    horizontal loss  |d_k + w τ|² < S²  ⇔  |w|² τ² + 2 (d_k·w) τ + |d_k|² − S² < 0,
    vertical loss    |h_k + u τ| < V    ⇔  τ between (−V − h_k)/u and (V − h_k)/u,

and the pair is in conflict on the segment where both intervals and [0, Δt] overlap.
The earliest such time is the *time to violation*; the horizontal closest point of
approach (CPA) on each segment is τ* = clip(−d_k·w/|w|², 0, Δt), and the smallest
|d(τ*)| over the segments is ``min_sep_m`` at ``time_to_cpa_s``; ``min_vsep_ft`` is the
smallest vertical separation while the conflict lasts. V is the vertical minimum less
``stca_v_tolerance_ft`` (altitude quantisation: Mode C reports are ±50 ft, so two
aircraft correctly 1,000 ft apart can read 900 ft).

Pair pruning (no all-pairs matrix)
----------------------------------
Let m_i = p_i + v_i T/2 be the midpoint of track i's linear predicted segment. Every
point of the segment is within |v_i| T/2 of m_i, so if the pair is ever closer than S
within [0, T], |m_i − m_j| < S + (|v_i| + |v_j|) T/2 ≤ S + v_max T, with v_max the
fastest eligible ground speed of the period. ``cKDTree.query_pairs`` on the midpoints
with r = S_max + v_max T (S_max the largest horizontal minimum or proximity threshold in
use) therefore returns *every* pair that the linear filter could flag — pruning loses
no conflict. A turning path has arc length |v| T and is not a straight segment, so pairs
with a turning member come from a second query around current positions with
r = S_max + 2 v_max T (each aircraft moves at most |v| T from where it is). The current
proximity test (t = 0) is covered because |m_i − m_j| ≤ |d0| + v_max T.

Alert life cycle
----------------
A *hit* is one function's finding for one key — (stca, track pair), (apw, track, area),
(msaw, track) — in one period. A key becomes an alert (status ``new``, fresh
``alert_id``) after hits in ``*_confirm_periods`` consecutive periods (the alert
confirmation of [STCA-SPEC]); an STCA conflict predicted more than ``stca_far_s`` ahead,
where the prediction is least certain, needs ``stca_confirm_periods_far``; a
current-proximity hit (separation already lost) is confirmed at once. While hits continue the alert is ``ongoing`` with refreshed figures;
after ``clear_periods`` consecutive periods without a hit, or as soon as one of its
tracks is gone, it is ``ended``. Alert ids are unique for the life of the process and
never reused.

Hooks
-----
:func:`load_hooks` discovers Python entry points in two groups: ``radar_fusion.alert_consumers``
(callables receiving each alert dict) and ``radar_fusion.alert_functions`` (objects, or
classes instantiated with ``(config, plane)``, with ``update(t_s, tracks) -> list[dict]``;
their alerts are validated against ``wire.Alert`` and published as they are). A hook
that raises is caught, logged at a bounded rate and counted in ``hook_errors``; it never
stops the daemon.
"""

from __future__ import annotations

import inspect
import itertools
import json
import logging
import math
from dataclasses import dataclass, field
from importlib import metadata
from pathlib import Path
from typing import Any, Callable, Literal, Optional, Sequence

import numpy as np
from matplotlib.path import Path as MplPath
from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator
from scipy.spatial import cKDTree

from ..geo.coordinates import SystemPlane
from ..wire import Alert

__all__ = [
    "NM_M",
    "FT_PER_HPA",
    "StcaAreaOverride",
    "SafetyNetsConfig",
    "TrackArrays",
    "Area",
    "MsaMap",
    "load_areas",
    "load_msa",
    "Hooks",
    "load_hooks",
    "SafetyNets",
    "CONSUMER_GROUP",
    "FUNCTION_GROUP",
]

log = logging.getLogger(__name__)

NM_M = 1852.0
"""One international nautical mile in metres."""
FT_M = 0.3048
FT_PER_HPA = 27.0
"""Pressure-altitude change per hPa near mean sea level, ICAO standard atmosphere (≈ 8.2 m)."""
STANDARD_PRESSURE_HPA = 1013.25

CONSUMER_GROUP = "radar_fusion.alert_consumers"
FUNCTION_GROUP = "radar_fusion.alert_functions"

_HISTORY = 4  # vertical-rate history kept per track, periods


# --------------------------------------------------------------------------- configuration


class StcaAreaOverride(BaseModel):
    """STCA minima for one airspace volume (e.g. 3 NM in a TMA) [STCA-SPEC]."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)
    name: str
    polygon_latlon_deg: list[tuple[float, float]] = Field(
        min_length=3, description="the volume's lateral boundary, [lat, lon] vertices in degrees"
    )
    lower_fl: float = Field(-20.0, description="lower limit (flight level), inclusive")
    upper_fl: float = Field(1300.0, description="upper limit (flight level), inclusive")
    h_min_nm: float = Field(gt=0, le=20, description="horizontal minimum inside the volume")
    v_min_ft: float = Field(1000.0, gt=0, le=5000, description="vertical minimum inside the volume")


class SafetyNetsConfig(BaseModel):
    """The ``[safety_nets]`` section of the daemon configuration (all fields defaulted)."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    # common
    look_ahead_s: float = Field(120.0, gt=0, le=600, description="prediction horizon (STCA; APW/MSAW default)")
    prediction_step_s: float = Field(5.0, gt=0, le=30, description="STCA knot spacing of predicted paths")
    sample_step_s: float = Field(2.0, gt=0, le=30, description="APW/MSAW sampling step along predicted paths")
    clear_periods: int = Field(2, ge=1, description="periods without a hit before an alert ends")
    level_vrate_fpm: float = Field(
        400.0, ge=0, description="|vertical rate| below this counts as level flight (tracker noise)"
    )
    level_off_anticipation: bool = Field(True, description="predict level-off from the vertical deceleration")
    capture_min_fpm_per_s: float = Field(
        40.0, gt=0, description="vertical deceleration that signals a level capture (fpm per second)"
    )
    turn_min_dps: float = Field(1.0, gt=0, description="turn rate above which turn prediction is used, deg/s")
    turn_max_dps: float = Field(6.0, gt=0, description="turn rates are capped at this, deg/s")
    turn_max_heading_change_deg: float = Field(
        90.0, gt=0, le=360, description="a predicted turn stops after this heading change"
    )
    load_entry_point_hooks: bool = Field(True, description="discover alert hooks from Python entry points")

    # STCA
    stca_enabled: bool = True
    stca_h_min_nm: float = Field(5.0, gt=0, le=20, description="horizontal separation minimum")
    stca_v_min_ft: float = Field(1000.0, gt=0, le=5000, description="vertical separation minimum")
    stca_v_tolerance_ft: float = Field(
        100.0, ge=0, le=500, description="subtracted from vertical minima for altitude quantisation"
    )
    stca_overrides: list[StcaAreaOverride] = Field(
        default_factory=list, description="per-volume minima; a pair uses the first volume that holds both tracks"
    )
    stca_proximity_h_nm: Optional[float] = Field(
        None, gt=0, description="current proximity filter, horizontal (default: the pair's minimum)"
    )
    stca_proximity_v_ft: Optional[float] = Field(
        None, gt=0, description="current proximity filter, vertical (default: the pair's minimum less tolerance)"
    )
    stca_confirm_periods: int = Field(2, ge=1, description="consecutive predicted-conflict periods before alerting")
    stca_far_s: float = Field(
        60.0, ge=0, description="a predicted violation further ahead than this needs stca_confirm_periods_far"
    )
    stca_confirm_periods_far: int = Field(
        4, ge=1, description="consecutive periods to confirm a conflict predicted beyond stca_far_s"
    )
    stca_unknown_fl: Literal["ignore", "conflict"] = Field(
        "ignore", description="tracks without a flight level: not eligible, or vertically in conflict with all"
    )

    # APW
    apw_enabled: bool = True
    areas_file: Optional[Path] = Field(None, description="GeoJSON of APW volumes (properties id, lower_fl, upper_fl)")
    apw_look_ahead_s: Optional[float] = Field(None, gt=0, le=600, description="default: look_ahead_s")
    apw_confirm_periods: int = Field(2, ge=1)
    apw_unknown_fl_inside: bool = Field(
        False, description="a track without a flight level counts as inside every volume's vertical band"
    )

    # MSAW
    msaw_enabled: bool = True
    msa_file: Optional[Path] = Field(
        None, description="GeoJSON polygons with property min_alt_ft, or a JSON MsaGrid"
    )
    msaw_look_ahead_s: Optional[float] = Field(None, gt=0, le=600, description="default: look_ahead_s")
    msaw_confirm_periods: int = Field(2, ge=1)
    qnh_hpa: float = Field(
        STANDARD_PRESSURE_HPA, ge=900, le=1100, description="altitude = 100·FL + (QNH − 1013.25)·27 ft"
    )

    @model_validator(mode="after")
    def _turn_rates(self) -> "SafetyNetsConfig":
        if self.turn_max_dps < self.turn_min_dps:
            raise ValueError("turn_max_dps must be at least turn_min_dps")
        return self

    @property
    def apw_horizon_s(self) -> float:
        return self.apw_look_ahead_s if self.apw_look_ahead_s is not None else self.look_ahead_s

    @property
    def msaw_horizon_s(self) -> float:
        return self.msaw_look_ahead_s if self.msaw_look_ahead_s is not None else self.look_ahead_s


# --------------------------------------------------------------------------- track columns


@dataclass
class TrackArrays:
    """The system tracks of one period as columns (N tracks).

    ``fl`` is the flight level (100 ft units), ``vrate_fpm`` the vertical rate (ft/min),
    both NaN when unknown; ``ax_mps2``/``ay_mps2`` the Singer acceleration state (used
    for the turn rate); ``selected_fl`` an optional selected/cleared level (NaN unknown);
    ``mode_s`` the optional 24-bit Mode S address (−1 unknown): two tracks with the same
    address are one aircraft (a duplicate track), never an STCA pair.
    """

    track_id: np.ndarray
    confirmed: np.ndarray
    x_m: np.ndarray
    y_m: np.ndarray
    vx_mps: np.ndarray
    vy_mps: np.ndarray
    ax_mps2: np.ndarray
    ay_mps2: np.ndarray
    fl: np.ndarray
    vrate_fpm: np.ndarray
    lat_deg: np.ndarray
    lon_deg: np.ndarray
    selected_fl: Optional[np.ndarray] = None
    mode_s: Optional[np.ndarray] = None

    def __post_init__(self) -> None:
        self.track_id = np.asarray(self.track_id, dtype=np.int64).reshape(-1)
        n = self.track_id.shape[0]
        self.confirmed = np.asarray(self.confirmed, dtype=bool).reshape(-1)
        for name in ("x_m", "y_m", "vx_mps", "vy_mps", "ax_mps2", "ay_mps2", "fl", "vrate_fpm", "lat_deg", "lon_deg"):
            setattr(self, name, np.asarray(getattr(self, name), dtype=float).reshape(-1))
        if self.selected_fl is None:
            self.selected_fl = np.full(n, np.nan)
        else:
            self.selected_fl = np.asarray(self.selected_fl, dtype=float).reshape(-1)
        if self.mode_s is None:
            self.mode_s = np.full(n, -1, dtype=np.int64)
        else:
            self.mode_s = np.asarray(self.mode_s, dtype=np.int64).reshape(-1)
        for name in ("confirmed", "x_m", "y_m", "vx_mps", "vy_mps", "ax_mps2", "ay_mps2", "fl", "vrate_fpm",
                     "lat_deg", "lon_deg", "selected_fl", "mode_s"):
            if getattr(self, name).shape != (n,):
                raise ValueError(f"TrackArrays.{name} must have shape ({n},), got {getattr(self, name).shape}")

    def __len__(self) -> int:
        return int(self.track_id.shape[0])

    @classmethod
    def empty(cls) -> "TrackArrays":
        z = np.zeros(0)
        return cls(np.zeros(0, np.int64), np.zeros(0, bool), z, z, z, z, z, z, z, z, z, z)

    @classmethod
    def from_tracks(cls, tracks: Sequence[Any]) -> "TrackArrays":
        """Columns from wire ``Track`` models or dicts (e.g. a received TrackBatch)."""

        def get(tr: Any, name: str, default: Any = None) -> Any:
            v = tr.get(name, default) if isinstance(tr, dict) else getattr(tr, name, default)
            return default if v is None else v

        n = len(tracks)

        def col(name: str, default: float = math.nan) -> np.ndarray:
            return np.fromiter((float(get(t, name, default)) for t in tracks), float, n)

        return cls(
            mode_s=np.fromiter((int(get(t, "mode_s"), 16) if get(t, "mode_s") else -1 for t in tracks),
                               np.int64, n),
            track_id=np.fromiter((int(get(t, "track_id")) for t in tracks), np.int64, n),
            confirmed=np.fromiter((get(t, "status") == "confirmed" for t in tracks), bool, n),
            x_m=col("x_m"), y_m=col("y_m"), vx_mps=col("vx_mps"), vy_mps=col("vy_mps"),
            ax_mps2=col("ax_mps2", 0.0), ay_mps2=col("ay_mps2", 0.0),
            fl=col("fl"), vrate_fpm=col("vrate_fpm"), lat_deg=col("lat_deg"), lon_deg=col("lon_deg"),
        )


# --------------------------------------------------------------------------- areas and MSA map


def _ring_path(plane: SystemPlane, ring_lonlat: Sequence[Sequence[float]]) -> MplPath:
    arr = np.asarray(ring_lonlat, dtype=float)
    if arr.ndim != 2 or arr.shape[0] < 3 or arr.shape[1] < 2:
        raise ValueError("a polygon ring needs at least 3 [lon, lat] positions")
    x, y = plane.to_plane(arr[:, 1], arr[:, 0])
    return MplPath(np.column_stack([x, y]))


@dataclass
class _Polygon:
    """A polygon in the system plane: exterior rings (one per part) and their holes."""

    parts: list[tuple[MplPath, list[MplPath]]]
    bbox: tuple[float, float, float, float] = field(init=False)

    def __post_init__(self) -> None:
        v = np.vstack([p.vertices for p, _ in self.parts])
        self.bbox = (float(v[:, 0].min()), float(v[:, 1].min()), float(v[:, 0].max()), float(v[:, 1].max()))

    def contains(self, xy: np.ndarray) -> np.ndarray:
        """Point-in-polygon for an (M, 2) array (even-odd per ring, holes excluded)."""
        inside = np.zeros(xy.shape[0], dtype=bool)
        if xy.shape[0] == 0:
            return inside
        for outer, holes in self.parts:
            m = outer.contains_points(xy)
            for h in holes:
                m &= ~h.contains_points(xy)
            inside |= m
        return inside

    @classmethod
    def from_geojson(cls, plane: SystemPlane, geometry: dict) -> "_Polygon":
        gtype = geometry.get("type")
        coords = geometry.get("coordinates")
        if gtype == "Polygon":
            polys = [coords]
        elif gtype == "MultiPolygon":
            polys = coords
        else:
            raise ValueError(f"geometry type {gtype!r} is not Polygon or MultiPolygon")
        parts = [(_ring_path(plane, p[0]), [_ring_path(plane, h) for h in p[1:]]) for p in polys]
        return cls(parts)


@dataclass
class Area:
    """An APW volume: lateral polygon (system plane) and vertical band [lower_fl, upper_fl]."""

    area_id: str
    polygon: _Polygon
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
            poly = _Polygon.from_geojson(plane, feat.get("geometry") or {})
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
        polygons: Sequence[tuple[str, _Polygon, float]] = (),
        grid: Optional[dict[str, Any]] = None,
    ) -> None:
        self.polygons = list(polygons)
        self.grid = grid
        maxima = [m for _, _, m in self.polygons]
        if grid is not None:
            g = grid["min_alt_ft"]
            if np.any(np.isfinite(g)):
                maxima.append(float(np.nanmax(g)))
        self.max_alt_ft = max(maxima) if maxima else -math.inf

    def lookup(self, plane_xy: np.ndarray, latlon: Optional[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
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
            grid = {k: float(doc[k]) for k in ("lat0_deg", "lon0_deg", "dlat_deg", "dlon_deg")}
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
            poly = _Polygon.from_geojson(plane, feat.get("geometry") or {})
        except ValueError as exc:
            raise ValueError(f"{path}: feature {pid!r}: {exc}") from None
        polys.append((pid, poly, float(props["min_alt_ft"])))
    return MsaMap(polygons=polys)


# --------------------------------------------------------------------------- hooks


@dataclass
class Hooks:
    """Site plug-ins: alert consumers and extra alert functions, by entry-point name."""

    consumers: list[tuple[str, Callable[[dict], Any]]] = field(default_factory=list)
    functions: list[tuple[str, Any]] = field(default_factory=list)
    load_errors: dict[str, str] = field(default_factory=dict)


def _entry_points(group: str) -> list[Any]:
    eps = metadata.entry_points()
    if hasattr(eps, "select"):
        return list(eps.select(group=group))
    return list(eps.get(group, []))  # type: ignore[union-attr]  # Python < 3.10 API


def load_hooks(config: Optional[SafetyNetsConfig] = None, plane: Optional[SystemPlane] = None) -> Hooks:
    """Discover hooks through ``importlib.metadata`` entry points.

    ``radar_fusion.alert_consumers``: each entry point loads a callable ``f(alert_dict)``
    (a class is instantiated with no arguments first). ``radar_fusion.alert_functions``:
    each loads an object with ``update(t_s, tracks) -> list[dict]``, or a class, which is
    instantiated as ``cls(config, plane)`` when it takes two arguments, else ``cls()``.
    An entry point that fails to load is logged and listed in ``load_errors``.
    """
    hooks = Hooks()
    for group in (CONSUMER_GROUP, FUNCTION_GROUP):
        for ep in _entry_points(group):
            name = f"{group}:{ep.name}"
            try:
                obj = ep.load()
                if inspect.isclass(obj):
                    if group == FUNCTION_GROUP and _positional_arity(obj) >= 2:
                        obj = obj(config, plane)
                    else:
                        obj = obj()
                if group == CONSUMER_GROUP:
                    if not callable(obj):
                        raise TypeError("alert consumer is not callable")
                    hooks.consumers.append((ep.name, obj))
                else:
                    if not callable(getattr(obj, "update", None)):
                        raise TypeError("alert function has no update(t_s, tracks)")
                    hooks.functions.append((ep.name, obj))
            except Exception as exc:  # a broken plug-in must not stop the daemon
                hooks.load_errors[name] = f"{type(exc).__name__}: {exc}"
                log.error("safety-net hook %s failed to load: %s", name, exc)
    return hooks


def _positional_arity(cls: type) -> int:
    try:
        params = list(inspect.signature(cls).parameters.values())
    except (TypeError, ValueError):
        return 0
    if any(p.kind == p.VAR_POSITIONAL for p in params):
        return 2
    return sum(p.kind in (p.POSITIONAL_ONLY, p.POSITIONAL_OR_KEYWORD) for p in params)


# --------------------------------------------------------------------------- prediction


@dataclass
class _Prediction:
    """Predicted paths of the eligible tracks at common times ``t_s`` (shape (M,))."""

    t_s: np.ndarray
    x_lin: np.ndarray  # (E, M)
    y_lin: np.ndarray
    x_turn: np.ndarray
    y_turn: np.ndarray
    z_ft: np.ndarray  # (E, M) altitude (100·FL) in feet; NaN unknown


def _turn_rate_rps(tr: TrackArrays, idx: np.ndarray, cfg: SafetyNetsConfig) -> np.ndarray:
    """ω = (vx·ay − vy·ax)/|v|² (rad/s), zero below ``turn_min_dps``, capped at ``turn_max_dps``."""
    vx, vy = tr.vx_mps[idx], tr.vy_mps[idx]
    ax = np.nan_to_num(tr.ax_mps2[idx])
    ay = np.nan_to_num(tr.ay_mps2[idx])
    v2 = vx * vx + vy * vy
    with np.errstate(invalid="ignore", divide="ignore"):
        w = np.where(v2 > 25.0, (vx * ay - vy * ax) / v2, 0.0)  # below 5 m/s no heading
    w = np.nan_to_num(w)
    w = np.where(np.abs(w) >= math.radians(cfg.turn_min_dps), w, 0.0)
    cap = math.radians(cfg.turn_max_dps)
    return np.clip(w, -cap, cap)


def _horizontal_paths(
    x0: np.ndarray, y0: np.ndarray, vx: np.ndarray, vy: np.ndarray, w: np.ndarray, t: np.ndarray, max_turn_rad: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Linear and turn-predicted positions at times ``t`` for each track, (E, M) each.

    Turn: arc p0 + (1/ω)[[sin ωt, −(1−cos ωt)], [1−cos ωt, sin ωt]] v0 while |ω t| ≤
    max_turn_rad, then straight on with the velocity rotated by the turn so far.
    """
    tt = t[None, :]
    x_lin = x0[:, None] + vx[:, None] * tt
    y_lin = y0[:, None] + vy[:, None] * tt
    turning = w != 0.0
    x_turn, y_turn = x_lin.copy(), y_lin.copy()
    if turning.any():
        k = np.flatnonzero(turning)
        wk = w[k][:, None]
        t_end = (max_turn_rad / np.abs(w[k]))[:, None]
        ta = np.minimum(tt, t_end)  # time on the arc
        s, c1 = np.sin(wk * ta), 1.0 - np.cos(wk * ta)
        vxk, vyk = vx[k][:, None], vy[k][:, None]
        xa = x0[k][:, None] + (vxk * s - vyk * c1) / wk
        ya = y0[k][:, None] + (vxk * c1 + vyk * s) / wk
        # velocity at the end of the arc, then straight
        cw, sw = np.cos(wk * ta), np.sin(wk * ta)
        vxe, vye = vxk * cw - vyk * sw, vxk * sw + vyk * cw
        rest = tt - ta
        x_turn[k] = xa + vxe * rest
        y_turn[k] = ya + vye * rest
    return x_lin, y_lin, x_turn, y_turn


def _vertical_paths(
    z0_ft: np.ndarray, vrate_fpm: np.ndarray, accel_fpm_s: np.ndarray, sel_fl: np.ndarray, t: np.ndarray,
    cfg: SafetyNetsConfig, return_bent: bool = False,
) -> Any:
    """Predicted altitude (ft) at times ``t``: level / linear / capture, capped at a selected level.

    Rates with |ż| < level_vrate_fpm are taken as zero. With a capture deceleration a
    (opposing ż, |a| ≥ capture_min_fpm_per_s), z(t) = z0 + (ż τ + a τ²/2)/60 with
    τ = min(t, −ż/a): uniform deceleration to a level. With ``return_bent`` also returns
    a boolean per track: True where the path is not one straight line (capture or cap).
    """
    rate = np.where(np.isfinite(vrate_fpm) & (np.abs(vrate_fpm) >= cfg.level_vrate_fpm), vrate_fpm, 0.0)
    tt = t[None, :]
    z = z0_ft[:, None] + rate[:, None] * tt / 60.0
    bent = np.zeros(z0_ft.shape[0], dtype=bool)
    if cfg.level_off_anticipation:
        a = np.nan_to_num(accel_fpm_s)
        cap = (rate * a < 0.0) & (np.abs(a) >= cfg.capture_min_fpm_per_s)
        if cap.any():
            k = np.flatnonzero(cap)
            tau = np.minimum(tt, (-rate[k] / a[k])[:, None])
            z[k] = z0_ft[k][:, None] + (rate[k][:, None] * tau + 0.5 * a[k][:, None] * tau * tau) / 60.0
            bent[k] = True
    sel = sel_fl * 100.0
    up = np.isfinite(sel) & (rate > 0) & (sel > z0_ft)
    down = np.isfinite(sel) & (rate < 0) & (sel < z0_ft)
    if up.any():
        z[up] = np.minimum(z[up], sel[up][:, None])
    if down.any():
        z[down] = np.maximum(z[down], sel[down][:, None])
    bent |= up | down
    return (z, bent) if return_bent else z


def segment_conflicts(
    dx: np.ndarray, dy: np.ndarray, dz: np.ndarray, t_knots: np.ndarray, h_min_m: np.ndarray, v_min_ft: np.ndarray
) -> dict[str, np.ndarray]:
    """Conflict test and CPA figures for K pairs on piecewise-linear relative paths.

    ``dx, dy`` (m) and ``dz`` (ft) are the relative positions at the knots, shape
    (K, S+1); ``h_min_m``, ``v_min_ft`` the thresholds per pair, shape (K,). On segment
    k (duration Δ) the relative motion is d_k + w τ, h_k + u τ (see the module docstring):
    horizontal loss where |w|²τ² + 2(d_k·w)τ + |d_k|² − S² < 0, vertical loss where
    |h_k + uτ| < V; a conflict where both hold for some τ in [0, Δ].

    Returns arrays (K,): ``conflict`` (bool), ``t_violation_s`` (first time both are lost,
    NaN if none), ``t_cpa_s`` and ``min_sep_m`` (horizontal CPA over [t_0, t_S]),
    ``min_vsep_ft`` (smallest |dz| while in conflict, NaN if none).
    """
    dt = np.diff(t_knots)[None, :]
    x0, y0, z0 = dx[:, :-1], dy[:, :-1], dz[:, :-1]
    wx, wy, u = (dx[:, 1:] - x0) / dt, (dy[:, 1:] - y0) / dt, (dz[:, 1:] - z0) / dt
    S = h_min_m[:, None]
    V = v_min_ft[:, None]
    a = wx * wx + wy * wy
    b = 2.0 * (x0 * wx + y0 * wy)
    c = x0 * x0 + y0 * y0 - S * S
    moving = a > 1e-12
    with np.errstate(invalid="ignore", divide="ignore"):
        disc = b * b - 4.0 * a * c
        sq = np.sqrt(np.maximum(disc, 0.0))
        a_safe = np.where(moving, a, 1.0)
        h_lo = np.where(moving, (-b - sq) / (2.0 * a_safe), np.where(c < 0, 0.0, np.inf))
        h_hi = np.where(moving, (-b + sq) / (2.0 * a_safe), np.where(c < 0, np.inf, -np.inf))
        h_lo = np.where(moving & (disc <= 0.0), np.inf, h_lo)
        h_hi = np.where(moving & (disc <= 0.0), -np.inf, h_hi)
        vmov = np.abs(u) > 1e-12
        u_safe = np.where(vmov, u, 1.0)
        r1, r2 = (-V - z0) / u_safe, (V - z0) / u_safe
        inside_v = np.abs(z0) < V
        v_lo = np.where(vmov, np.minimum(r1, r2), np.where(inside_v, 0.0, np.inf))
        v_hi = np.where(vmov, np.maximum(r1, r2), np.where(inside_v, np.inf, -np.inf))
    lo = np.maximum(np.maximum(h_lo, v_lo), 0.0)
    hi = np.minimum(np.minimum(h_hi, v_hi), dt)
    seg_conf = lo < hi
    conflict = seg_conf.any(axis=1)
    first = np.argmax(seg_conf, axis=1)
    rows = np.arange(dx.shape[0])
    t_viol = np.where(conflict, t_knots[:-1][first] + lo[rows, first], np.nan)
    # vertical separation at the ends of each conflict sub-interval (and 0 if it crosses)
    lo_c = np.where(seg_conf, lo, 0.0)
    hi_c = np.where(seg_conf, hi, 0.0)
    za, zb = z0 + u * lo_c, z0 + u * hi_c
    vs = np.where(za * zb <= 0.0, 0.0, np.minimum(np.abs(za), np.abs(zb)))
    vs = np.where(seg_conf, vs, np.inf)
    min_vsep = vs.min(axis=1)
    min_vsep = np.where(conflict, min_vsep, np.nan)
    # horizontal CPA per segment
    with np.errstate(invalid="ignore", divide="ignore"):
        tau = np.where(moving, np.clip(-(x0 * wx + y0 * wy) / a_safe, 0.0, dt), 0.0)
    cx, cy = x0 + wx * tau, y0 + wy * tau
    d2 = cx * cx + cy * cy
    kbest = np.argmin(d2, axis=1)
    return {
        "conflict": conflict,
        "t_violation_s": t_viol,
        "t_cpa_s": t_knots[:-1][kbest] + tau[rows, kbest],
        "min_sep_m": np.sqrt(d2[rows, kbest]),
        "min_vsep_ft": min_vsep,
    }


# --------------------------------------------------------------------------- the safety nets


@dataclass
class _AlertState:
    kind: str
    track_ids: list[int]
    hits: int = 0  # consecutive periods with a hit
    misses: int = 0  # consecutive periods without a hit (active alerts)
    alert_id: Optional[int] = None  # set when confirmed
    figures: dict[str, Any] = field(default_factory=dict)


@dataclass
class _Hit:
    key: tuple
    kind: str
    track_ids: list[int]
    figures: dict[str, Any]
    immediate: bool = False


class SafetyNets:
    """STCA, APW and MSAW over the fused tracks, with the alert life cycle and hooks.

    ``SafetyNets(config, plane)``; then once per closed period
    ``alerts = nets.update(t_s, tracks)``. ``counters`` and ``hook_errors`` feed the
    health message; ``last_candidate_pairs`` is the STCA pair count after pruning.
    """

    def __init__(
        self,
        config: Optional[SafetyNetsConfig] = None,
        plane: Optional[SystemPlane] = None,
        hooks: Optional[Hooks] = None,
        base_dir: Optional[Path] = None,
    ) -> None:
        self.config = config or SafetyNetsConfig()
        if plane is None:
            raise ValueError("SafetyNets needs the system plane")
        self.plane = plane
        cfg = self.config

        def resolve(p: Optional[Path]) -> Optional[Path]:
            if p is None:
                return None
            return p if p.is_absolute() or base_dir is None else Path(base_dir) / p

        self.areas: list[Area] = load_areas(resolve(cfg.areas_file), plane) if cfg.areas_file else []
        self.msa: Optional[MsaMap] = load_msa(resolve(cfg.msa_file), plane) if cfg.msa_file else None
        self._overrides = [
            (
                _Polygon([(_ring_path(plane, [(lon, lat) for lat, lon in o.polygon_latlon_deg]), [])]),
                o,
            )
            for o in cfg.stca_overrides
        ]
        if hooks is None:
            hooks = load_hooks(cfg, plane) if cfg.load_entry_point_hooks else Hooks()
        self.hooks = hooks
        self.hook_errors: dict[str, int] = {}
        self.counters: dict[str, int] = {
            "periods": 0,
            "hits_stca": 0, "hits_apw": 0, "hits_msaw": 0,
            "alerts_new": 0, "alerts_ended": 0,
            "hook_alerts": 0, "hook_alerts_invalid": 0, "hook_errors": 0,
        }
        self.last_candidate_pairs = 0
        self._states: dict[tuple, _AlertState] = {}
        self._next_alert_id = 1
        # vertical-rate history, rows sorted by track id
        self._hist_ids = np.zeros(0, np.int64)
        self._hist_t = np.zeros((0, _HISTORY))
        self._hist_vr = np.zeros((0, _HISTORY))

    @classmethod
    def from_settings(cls, settings: Any, base_dir: Optional[Path] = None) -> "SafetyNets":
        """Build from the daemon's ``Settings`` (``safety_nets`` dict and ``system`` centre)."""
        cfg = SafetyNetsConfig.model_validate(settings.safety_nets or {})
        plane = SystemPlane(settings.system.center_lat, settings.system.center_lon)
        return cls(cfg, plane, base_dir=base_dir)

    # ------------------------------------------------------------------ per period

    def update(self, t_s: float, tracks: TrackArrays) -> list[dict]:
        """Run the safety nets for one closed period; return this period's Alert dicts."""
        cfg = self.config
        self.counters["periods"] += 1
        accel = self._update_vertical_history(float(t_s), tracks)
        hits: list[_Hit] = []
        if cfg.stca_enabled and len(tracks):
            hits += self._stca(tracks, accel)
        if cfg.apw_enabled and self.areas and len(tracks):
            hits += self._apw(tracks, accel)
        if cfg.msaw_enabled and self.msa is not None and len(tracks):
            hits += self._msaw(tracks, accel)
        alerts = self._life_cycle(float(t_s), hits, tracks)
        for name, fn in self.hooks.functions:
            try:
                produced = fn.update(t_s, tracks) or []
            except Exception as exc:
                self._hook_failed(name, exc)
                continue
            for a in produced:
                try:
                    alerts.append(Alert.model_validate(a).model_dump(exclude_none=True))
                    self.counters["hook_alerts"] += 1
                except ValidationError as exc:
                    self.counters["hook_alerts_invalid"] += 1
                    self._hook_failed(name, exc)
        for name, consumer in self.hooks.consumers:
            for a in alerts:
                try:
                    consumer(dict(a))
                except Exception as exc:
                    self._hook_failed(name, exc)
        return alerts

    def _hook_failed(self, name: str, exc: BaseException) -> None:
        n = self.hook_errors.get(name, 0) + 1
        self.hook_errors[name] = n
        self.counters["hook_errors"] += 1
        if n <= 3 or n % 1000 == 0:  # bounded log rate
            log.error("safety-net hook %s failed (%d so far): %s: %s", name, n, type(exc).__name__, exc)

    # ------------------------------------------------------------------ vertical history

    def _update_vertical_history(self, t_s: float, tr: TrackArrays) -> np.ndarray:
        """Keep the last vertical rates per track; return the vertical acceleration (fpm/s).

        The acceleration is the least-squares slope of vertical rate over time through
        the last ``_HISTORY`` periods (NaN with fewer than 3 finite rates).
        """
        n = len(tr)
        t_hist = np.full((n, _HISTORY), np.nan)
        vr_hist = np.full((n, _HISTORY), np.nan)
        if self._hist_ids.size and n:
            pos = np.clip(np.searchsorted(self._hist_ids, tr.track_id), 0, self._hist_ids.size - 1)
            known = self._hist_ids[pos] == tr.track_id
            t_hist[known] = self._hist_t[pos[known]]
            vr_hist[known] = self._hist_vr[pos[known]]
        t_hist = np.roll(t_hist, -1, axis=1)
        vr_hist = np.roll(vr_hist, -1, axis=1)
        t_hist[:, -1] = t_s
        vr_hist[:, -1] = tr.vrate_fpm
        order = np.argsort(tr.track_id, kind="stable")
        self._hist_ids = tr.track_id[order]
        self._hist_t = t_hist[order]
        self._hist_vr = vr_hist[order]
        ok = np.isfinite(t_hist) & np.isfinite(vr_hist)
        cnt = ok.sum(axis=1)
        w = ok.astype(float)
        with np.errstate(invalid="ignore", divide="ignore"):
            tm = np.nansum(np.where(ok, t_hist, 0.0), axis=1) / cnt
            vm = np.nansum(np.where(ok, vr_hist, 0.0), axis=1) / cnt
            dt = np.where(ok, t_hist - tm[:, None], 0.0)
            dv = np.where(ok, vr_hist - vm[:, None], 0.0)
            slope = (w * dt * dv).sum(axis=1) / (w * dt * dt).sum(axis=1)
        return np.where(cnt >= 3, slope, np.nan)

    # ------------------------------------------------------------------ STCA

    def _pair_minima(self, tr: TrackArrays, e: np.ndarray, ia: np.ndarray, ib: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Horizontal (m) and vertical (ft) minima per pair: the first override volume holding both."""
        cfg = self.config
        h = np.full(ia.shape[0], cfg.stca_h_min_nm * NM_M)
        v = np.full(ia.shape[0], cfg.stca_v_min_ft)
        if not self._overrides or ia.size == 0:
            return h, v
        region = np.full(e.size, -1, dtype=np.int64)
        xy = np.column_stack([tr.x_m[e], tr.y_m[e]])
        fl = tr.fl[e]
        for r in range(len(self._overrides) - 1, -1, -1):  # first listed wins
            poly, o = self._overrides[r]
            inside = poly.contains(xy) & ~(fl < o.lower_fl) & ~(fl > o.upper_fl)
            region[inside] = r
        same = (region[ia] == region[ib]) & (region[ia] >= 0)
        for r, (_, o) in enumerate(self._overrides):
            m = same & (region[ia] == r)
            h[m] = o.h_min_nm * NM_M
            v[m] = o.v_min_ft
        return h, v

    def _stca(self, tr: TrackArrays, accel: np.ndarray) -> list[_Hit]:
        cfg = self.config
        finite = np.isfinite(tr.x_m) & np.isfinite(tr.y_m) & np.isfinite(tr.vx_mps) & np.isfinite(tr.vy_mps)
        elig = tr.confirmed & finite
        if cfg.stca_unknown_fl == "ignore":
            elig &= np.isfinite(tr.fl)
        e = np.flatnonzero(elig)
        self.last_candidate_pairs = 0
        if e.size < 2:
            return []
        T = cfg.look_ahead_s
        speed = np.hypot(tr.vx_mps[e], tr.vy_mps[e])
        v_max = float(speed.max())
        s_max = max([cfg.stca_h_min_nm] + [o.h_min_nm for o in cfg.stca_overrides]) * NM_M
        if cfg.stca_proximity_h_nm is not None:
            s_max = max(s_max, cfg.stca_proximity_h_nm * NM_M)
        w = _turn_rate_rps(tr, e, cfg)
        # pruning: linear paths via segment midpoints, turning tracks via current positions
        mid = np.column_stack([tr.x_m[e] + tr.vx_mps[e] * T / 2, tr.y_m[e] + tr.vy_mps[e] * T / 2])
        pairs = cKDTree(mid).query_pairs(s_max + v_max * T + 1.0, output_type="ndarray")
        turning = np.flatnonzero(w != 0.0)
        if turning.size:
            p0 = np.column_stack([tr.x_m[e], tr.y_m[e]])
            near = cKDTree(p0).query_ball_point(p0[turning], s_max + 2.0 * v_max * T + 1.0)
            lens = np.fromiter(map(len, near), dtype=np.int64, count=len(near))
            j = np.fromiter(itertools.chain.from_iterable(near), dtype=np.int64, count=int(lens.sum()))
            i = np.repeat(turning.astype(np.int64), lens)
            if (i != j).any():
                ex = np.sort(np.column_stack([i, j])[i != j], axis=1)
                pairs = np.vstack([pairs.reshape(-1, 2).astype(np.int64), ex]) if pairs.size else ex
                # unique pairs via one int64 key each (np.unique(axis=0) sorts a void dtype: 10x slower)
                key = np.unique(pairs[:, 0] * np.int64(e.size) + pairs[:, 1])
                pairs = np.column_stack([key // e.size, key % e.size])
        if pairs.size:  # the same Mode S address twice is a duplicate track, not a pair
            ms = tr.mode_s[e]
            pairs = pairs[~((ms[pairs[:, 0]] >= 0) & (ms[pairs[:, 0]] == ms[pairs[:, 1]]))]
        if pairs.size == 0:
            return []
        n_knots = max(1, int(math.ceil(T / cfg.prediction_step_s)))
        knots = np.linspace(0.0, T, n_knots + 1)
        fl = tr.fl[e]
        z, bent = _vertical_paths(
            np.nan_to_num(fl * 100.0), tr.vrate_fpm[e], accel[e], tr.selected_fl[e], knots, cfg, return_bent=True
        )
        unknown = ~np.isfinite(fl)
        # vertical pruning (exact): between knots the paths are linear, so a pair whose
        # vertical path ranges over the look-ahead stay apart by at least the largest
        # vertical minimum can have neither a conflict nor a proximity alert
        v_gate = max([cfg.stca_v_min_ft] + [o.v_min_ft for o in cfg.stca_overrides])
        if cfg.stca_proximity_v_ft is not None:
            v_gate = max(v_gate, cfg.stca_proximity_v_ft)
        z_lo, z_hi = z.min(axis=1), z.max(axis=1)
        a0, b0 = pairs[:, 0], pairs[:, 1]
        gap = np.maximum(z_lo[b0] - z_hi[a0], z_lo[a0] - z_hi[b0])
        pairs = pairs[(gap < v_gate) | unknown[a0] | unknown[b0]]
        if pairs.size == 0:
            return []
        ia, ib = pairs[:, 0], pairs[:, 1]
        self.last_candidate_pairs = int(ia.size)

        x_lin, y_lin, x_turn, y_turn = _horizontal_paths(
            tr.x_m[e], tr.y_m[e], tr.vx_mps[e], tr.vy_mps[e], w, knots, math.radians(cfg.turn_max_heading_change_deg)
        )
        h_min, v_min = self._pair_minima(tr, e, ia, ib)
        v_eff = np.maximum(v_min - cfg.stca_v_tolerance_ft, 0.0)
        dz = z[ib] - z[ia]
        dz[unknown[ia] | unknown[ib]] = 0.0  # only with stca_unknown_fl == "conflict"
        # linear prediction filter: one segment [0, T] when both vertical paths are straight
        # (the relative motion is then exactly linear), the knots otherwise
        lin = {}
        seg = bent[ia] | bent[ib]
        for sel, cols in ((~seg, [0, n_knots]), (seg, slice(None))):
            if not sel.any():
                continue
            a1, b1 = ia[sel], ib[sel]
            r = segment_conflicts(
                (x_lin[b1] - x_lin[a1])[:, cols], (y_lin[b1] - y_lin[a1])[:, cols], dz[sel][:, cols],
                knots[cols], h_min[sel], v_eff[sel],
            )
            for k, v in r.items():
                lin.setdefault(k, np.empty(ia.size, dtype=v.dtype))[sel] = v
        conflict = lin["conflict"].copy()
        fig = {k: v.copy() for k, v in lin.items() if k != "conflict"}
        tp = np.flatnonzero((w[ia] != 0.0) | (w[ib] != 0.0))
        if tp.size:
            a2, b2 = ia[tp], ib[tp]
            turn = segment_conflicts(
                x_turn[b2] - x_turn[a2], y_turn[b2] - y_turn[a2], dz[tp], knots, h_min[tp], v_eff[tp]
            )
            better = turn["conflict"] & (~conflict[tp] | (turn["t_violation_s"] < fig["t_violation_s"][tp]))
            sel = tp[better]
            for k in fig:
                fig[k][sel] = turn[k][better]
            conflict[tp] |= turn["conflict"]
        # current proximity filter: separation lost now (confirmed at once)
        prox_h = h_min if cfg.stca_proximity_h_nm is None else np.full(ia.size, cfg.stca_proximity_h_nm * NM_M)
        prox_v = v_eff if cfg.stca_proximity_v_ft is None else np.full(ia.size, cfg.stca_proximity_v_ft)
        d0 = np.hypot(x_lin[ib, 0] - x_lin[ia, 0], y_lin[ib, 0] - y_lin[ia, 0])
        prox = (d0 < prox_h) & (np.abs(dz[:, 0]) < prox_v)
        hit = np.flatnonzero(conflict | prox)
        self.counters["hits_stca"] += int(hit.size)
        out = []
        ids = tr.track_id[e]
        for k in hit:
            i, j = sorted((int(ids[ia[k]]), int(ids[ib[k]])))
            tv = fig["t_violation_s"][k]
            mv = fig["min_vsep_ft"][k]
            figures = {
                "time_to_cpa_s": float(fig["t_cpa_s"][k]),
                "min_sep_m": float(fig["min_sep_m"][k]),
                "min_vsep_ft": float(mv) if np.isfinite(mv) else float(abs(dz[k, 0])),
                "time_to_violation_s": float(tv) if np.isfinite(tv) else 0.0,
            }
            out.append(_Hit(("stca", i, j), "stca", [i, j], figures, immediate=bool(prox[k])))
        return out

    # ------------------------------------------------------------------ APW / MSAW

    def _sampled_paths(self, tr: TrackArrays, e: np.ndarray, accel: np.ndarray, horizon_s: float) -> _Prediction:
        cfg = self.config
        t = np.arange(0.0, horizon_s + 1e-9, cfg.sample_step_s)
        if t[-1] < horizon_s - 1e-9:
            t = np.append(t, horizon_s)
        w = _turn_rate_rps(tr, e, cfg)
        x_lin, y_lin, x_turn, y_turn = _horizontal_paths(
            tr.x_m[e], tr.y_m[e], tr.vx_mps[e], tr.vy_mps[e], w, t, math.radians(cfg.turn_max_heading_change_deg)
        )
        z = _vertical_paths(tr.fl[e] * 100.0, tr.vrate_fpm[e], accel[e], tr.selected_fl[e], t, cfg)
        return _Prediction(t, x_lin, y_lin, x_turn, y_turn, z)

    def _apw(self, tr: TrackArrays, accel: np.ndarray) -> list[_Hit]:
        """[APW-GUID]: inside a volume now, or predicted to enter it within the look-ahead.

        The horizontal path is the turn prediction for turning tracks, linear otherwise;
        samples every ``sample_step_s``; inside = in the polygon and lower ≤ FL ≤ upper.
        """
        cfg = self.config
        finite = np.isfinite(tr.x_m) & np.isfinite(tr.y_m) & np.isfinite(tr.vx_mps) & np.isfinite(tr.vy_mps)
        e = np.flatnonzero(tr.confirmed & finite)
        if e.size == 0:
            return []
        pred = self._sampled_paths(tr, e, accel, cfg.apw_horizon_s)
        xs, ys, fl = pred.x_turn, pred.y_turn, pred.z_ft / 100.0
        xmin, xmax, ymin, ymax = xs.min(axis=1), xs.max(axis=1), ys.min(axis=1), ys.max(axis=1)
        out = []
        for area in self.areas:
            x0, y0, x1, y1 = area.polygon.bbox
            cand = np.flatnonzero((xmax >= x0) & (xmin <= x1) & (ymax >= y0) & (ymin <= y1))
            if cand.size == 0:
                continue
            m = pred.t_s.size
            pts = np.column_stack([xs[cand].ravel(), ys[cand].ravel()])
            lat_in = area.polygon.contains(pts).reshape(cand.size, m)
            f = fl[cand]
            with np.errstate(invalid="ignore"):
                vert = (f >= area.lower_fl) & (f <= area.upper_fl)
            if cfg.apw_unknown_fl_inside:
                vert |= ~np.isfinite(f)
            inside = lat_in & vert
            any_in = inside.any(axis=1)
            first = np.argmax(inside, axis=1)
            for k in np.flatnonzero(any_in):
                tid = int(tr.track_id[e[cand[k]]])
                figures = {"area_id": area.area_id, "time_to_entry_s": float(pred.t_s[first[k]])}
                out.append(_Hit(("apw", tid, area.area_id), "apw", [tid], figures))
        self.counters["hits_apw"] += len(out)
        return out

    def _msaw(self, tr: TrackArrays, accel: np.ndarray) -> list[_Hit]:
        """[MSAW-GUID]: below the minimum safe altitude now, or predicted to be within the look-ahead.

        Altitude (ft) = 100·FL + (QNH − 1013.25)·27; the path is sampled every
        ``sample_step_s`` with the vertical prediction (rate, capture, selected level).
        Grid maps are looked up in lat/lon through the local Jacobian of the plane's
        inverse projection at each track (error ≪ a grid cell over the look-ahead).
        """
        cfg = self.config
        assert self.msa is not None
        finite = np.isfinite(tr.x_m) & np.isfinite(tr.y_m) & np.isfinite(tr.vx_mps) & np.isfinite(tr.vy_mps)
        e = np.flatnonzero(tr.confirmed & finite & np.isfinite(tr.fl))
        if e.size == 0:
            return []
        pred = self._sampled_paths(tr, e, accel, cfg.msaw_horizon_s)
        alt = pred.z_ft + (cfg.qnh_hpa - STANDARD_PRESSURE_HPA) * FT_PER_HPA
        cand = np.flatnonzero(alt.min(axis=1) < self.msa.max_alt_ft)  # cannot be below anything otherwise
        if cand.size == 0:
            return []
        m = pred.t_s.size
        xs, ys = pred.x_turn[cand], pred.y_turn[cand]
        pts = np.column_stack([xs.ravel(), ys.ravel()])
        latlon = None
        if self.msa.grid is not None:
            gx, gy = tr.x_m[e[cand]], tr.y_m[e[cand]]
            step = 1000.0
            lat0, lon0 = self.plane.to_geodetic(gx, gy)
            lat_x, lon_x = self.plane.to_geodetic(gx + step, gy)
            lat_y, lon_y = self.plane.to_geodetic(gx, gy + step)
            ddx, ddy = xs - gx[:, None], ys - gy[:, None]
            lat = lat0[:, None] + ((lat_x - lat0)[:, None] * ddx + (lat_y - lat0)[:, None] * ddy) / step
            lon = lon0[:, None] + ((lon_x - lon0)[:, None] * ddx + (lon_y - lon0)[:, None] * ddy) / step
            latlon = np.column_stack([lat.ravel(), lon.ravel()])
        msa, src = self.msa.lookup(pts, latlon)
        msa, src = msa.reshape(cand.size, m), src.reshape(cand.size, m)
        below = alt[cand] < msa
        any_b = below.any(axis=1)
        first = np.argmax(below, axis=1)
        out = []
        for k in np.flatnonzero(any_b):
            tid = int(tr.track_id[e[cand[k]]])
            f = first[k]
            figures = {
                "time_to_violation_s": float(pred.t_s[f]),
                "min_alt_ft": float(msa[k, f]),
                "area_id": self.msa.source_id(int(src[k, f])),
            }
            out.append(_Hit(("msaw", tid), "msaw", [tid], figures))
        self.counters["hits_msaw"] += len(out)
        return out

    # ------------------------------------------------------------------ life cycle

    def _confirm_needed(self, hit: _Hit) -> int:
        """Consecutive hits needed; a far STCA prediction (less certain) needs more [STCA-SPEC]."""
        c = self.config
        if hit.kind == "stca":
            far = hit.figures.get("time_to_violation_s", 0.0) > c.stca_far_s
            return c.stca_confirm_periods_far if far else c.stca_confirm_periods
        return {"apw": c.apw_confirm_periods, "msaw": c.msaw_confirm_periods}[hit.kind]

    def _message(self, st: _AlertState, t_s: float, status: str) -> dict:
        msg = {"v": 1, "kind": st.kind, "alert_id": st.alert_id, "t": t_s, "track_ids": list(st.track_ids),
               "status": status}
        msg.update(st.figures)
        return msg

    def _life_cycle(self, t_s: float, hits: list[_Hit], tracks: TrackArrays) -> list[dict]:
        """Confirmation, new / ongoing / ended, stable ids (see the module docstring)."""
        alerts: list[dict] = []
        present = set(tracks.track_id.tolist())
        hit_keys = set()
        for h in hits:
            hit_keys.add(h.key)
            st = self._states.get(h.key)
            if st is None:
                st = self._states[h.key] = _AlertState(h.kind, h.track_ids)
            st.hits += 1
            st.misses = 0
            st.figures = h.figures
            if st.alert_id is not None:
                alerts.append(self._message(st, t_s, "ongoing"))
            elif h.immediate or st.hits >= self._confirm_needed(h):
                st.alert_id = self._next_alert_id
                self._next_alert_id += 1
                self.counters["alerts_new"] += 1
                alerts.append(self._message(st, t_s, "new"))
        for key in list(self._states):
            if key in hit_keys:
                continue
            st = self._states[key]
            if st.alert_id is None:  # an unconfirmed run is broken
                del self._states[key]
                continue
            st.hits = 0
            st.misses += 1
            gone = any(tid not in present for tid in st.track_ids)
            if gone or st.misses >= self.config.clear_periods:
                alerts.append(self._message(st, t_s, "ended"))
                self.counters["alerts_ended"] += 1
                del self._states[key]
            else:
                alerts.append(self._message(st, t_s, "ongoing"))
        return alerts

    @property
    def active_alerts(self) -> list[dict]:
        """The confirmed alerts currently open (for a health or status view)."""
        return [
            {"kind": s.kind, "alert_id": s.alert_id, "track_ids": list(s.track_ids), **s.figures}
            for s in self._states.values()
            if s.alert_id is not None
        ]
