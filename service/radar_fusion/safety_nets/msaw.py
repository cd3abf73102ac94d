"""Minimum Safe Altitude Warning [MSAW-GUID]: below the terrain/obstacle map's minimum, or predicted to be."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from ..geo.coordinates import SystemPlane
from .areas import MsaMap
from .config import FT_PER_HPA, STANDARD_PRESSURE_HPA, SafetyNetsConfig
from .life_cycle import Hit
from .prediction import eligible, moving, sampled_paths

if TYPE_CHECKING:
    from ..engine.columns import TrackColumns


def msaw_hits(
    cfg: SafetyNetsConfig, msa_map: MsaMap, plane: SystemPlane, tr: TrackColumns, accel: np.ndarray
) -> list[Hit]:
    """[MSAW-GUID]: below the minimum safe altitude now, or predicted to be within the look-ahead.

    Altitude (ft) = 100·FL + (QNH − 1013.25)·27; the path is sampled every
    ``sample_step_s`` with the vertical prediction (rate, capture, selected level).
    Grid maps are looked up in lat/lon through the local Jacobian of the plane's
    inverse projection at each track (error ≪ a grid cell over the look-ahead).
    """
    e = np.flatnonzero(eligible(tr) & moving(tr) & np.isfinite(tr.fl))
    if e.size == 0:
        return []
    pred = sampled_paths(tr, e, accel, cfg.msaw_horizon_s, cfg)
    alt = pred.z_ft + (cfg.qnh_hpa - STANDARD_PRESSURE_HPA) * FT_PER_HPA
    cand = np.flatnonzero(alt.min(axis=1) < msa_map.max_alt_ft)  # cannot be below anything otherwise
    if cand.size == 0:
        return []
    m = pred.t_s.size
    xs, ys = pred.x_turn[cand], pred.y_turn[cand]
    pts = np.column_stack([xs.ravel(), ys.ravel()])
    latlon = None
    if msa_map.grid is not None:
        gx, gy = tr.x_m[e[cand]], tr.y_m[e[cand]]
        step = 1000.0
        lat0, lon0 = plane.to_geodetic(gx, gy)
        lat_x, lon_x = plane.to_geodetic(gx + step, gy)
        lat_y, lon_y = plane.to_geodetic(gx, gy + step)
        ddx, ddy = xs - gx[:, None], ys - gy[:, None]
        lat = lat0[:, None] + ((lat_x - lat0)[:, None] * ddx + (lat_y - lat0)[:, None] * ddy) / step
        lon = lon0[:, None] + ((lon_x - lon0)[:, None] * ddx + (lon_y - lon0)[:, None] * ddy) / step
        latlon = np.column_stack([lat.ravel(), lon.ravel()])
    msa, src = msa_map.lookup(pts, latlon)
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
            "area_id": msa_map.source_id(int(src[k, f])),
        }
        out.append(Hit(("msaw", tid), "msaw", [tid], figures))
    return out
