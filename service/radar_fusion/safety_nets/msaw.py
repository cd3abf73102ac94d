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
    ``sample_step_s`` with the vertical prediction (rate, capture, selected level), and
    the path between two samples is tested against each MSA polygon's edges (a corner
    clipped between samples: the altitude there interpolated between them).
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
    first = np.argmax(below, axis=1)
    t_first = np.where(below.any(axis=1), pred.t_s[first], np.inf)
    min_alt = msa[np.arange(cand.size), first]
    area = src[np.arange(cand.size), first]
    if m > 1 and msa_map.polygons:
        # a polygon's corner clipped between two samples that are both outside it (at
        # 250 m/s a 2 s step is 500 m): the boundary crossed below its minimum
        p0 = np.column_stack([xs[:, :-1].ravel(), ys[:, :-1].ravel()])
        p1 = np.column_stack([xs[:, 1:].ravel(), ys[:, 1:].ravel()])
        a0, a1 = alt[cand][:, :-1].ravel(), alt[cand][:, 1:].ravel()
        seg_lo, seg_hi = np.minimum(p0, p1), np.maximum(p0, p1)
        t0_s, dt_s = np.tile(pred.t_s[:-1], cand.size), np.tile(np.diff(pred.t_s), cand.size)
        path = np.repeat(np.arange(cand.size), m - 1)
        for j, (_, poly, min_alt_ft) in enumerate(msa_map.polygons):
            x0, y0, x1, y1 = poly.bbox
            near = np.flatnonzero(
                (seg_hi[:, 0] >= x0) & (seg_lo[:, 0] <= x1) & (seg_hi[:, 1] >= y0) & (seg_lo[:, 1] <= y1)
                & (np.minimum(a0, a1) < min_alt_ft)
            )  # fmt: skip
            if near.size == 0:
                continue
            u = poly.first_crossing(p0[near], p1[near])
            hit = np.isfinite(u)
            u = np.where(hit, u, 0.0)
            low = hit & (a0[near] + u * (a1[near] - a0[near]) < min_alt_ft)
            t_cross = np.full(cand.size, np.inf)
            np.minimum.at(t_cross, path[near[low]], t0_s[near[low]] + u[low] * dt_s[near[low]])
            sooner = t_cross < t_first
            t_first[sooner], min_alt[sooner], area[sooner] = t_cross[sooner], min_alt_ft, j
    out = []
    for k in np.flatnonzero(np.isfinite(t_first)):
        tid = int(tr.track_id[e[cand[k]]])
        figures = {
            "time_to_violation_s": float(t_first[k]),
            "min_alt_ft": float(min_alt[k]),
            "area_id": msa_map.source_id(int(area[k])),
        }
        out.append(Hit(("msaw", tid), "msaw", [tid], figures))
    return out
