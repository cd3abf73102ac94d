"""Area Proximity Warning [APW-GUID]: a track inside a notified volume, or predicted to enter it."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from ..geo.units import FT_PER_FL
from .areas import Area
from .config import SafetyNetsConfig
from .life_cycle import Hit
from .prediction import eligible, moving, sampled_paths

if TYPE_CHECKING:
    from ..engine.columns import TrackColumns


def apw_hits(cfg: SafetyNetsConfig, areas: list[Area], tr: TrackColumns, accel: np.ndarray) -> list[Hit]:
    """[APW-GUID]: inside a volume now, or predicted to enter it within the look-ahead.

    The horizontal path is the turn prediction for turning tracks, linear otherwise;
    samples every ``sample_step_s``; inside = in the polygon and lower ≤ FL ≤ upper. A
    path between two samples that crosses the polygon's boundary enters it there too
    (a corner clipped between samples, both outside: at 250 m/s a 2 s step is 500 m),
    when the level there, interpolated between the samples, is inside the volume's band.
    """
    e = np.flatnonzero(eligible(tr) & moving(tr))
    if e.size == 0:
        return []
    pred = sampled_paths(tr, e, accel, cfg.apw_horizon_s, cfg)
    xs, ys, fl = pred.x_turn, pred.y_turn, pred.z_ft / FT_PER_FL
    xmin, xmax, ymin, ymax = xs.min(axis=1), xs.max(axis=1), ys.min(axis=1), ys.max(axis=1)
    out = []
    for area in areas:
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
        t_in = np.where(inside.any(axis=1), pred.t_s[np.argmax(inside, axis=1)], np.inf)
        if m > 1:  # the boundary crossed between two samples
            xc, yc = xs[cand], ys[cand]
            p0 = np.column_stack([xc[:, :-1].ravel(), yc[:, :-1].ravel()])
            p1 = np.column_stack([xc[:, 1:].ravel(), yc[:, 1:].ravel()])
            u = area.polygon.first_crossing(p0, p1).reshape(cand.size, m - 1)
            # the level where the path crosses the edge, between the samples' (as MSAW): a
            # descent that crosses above the volume and is inside its band only later is no entry
            f_cross = f[:, :-1] + np.where(np.isfinite(u), u, 0.0) * (f[:, 1:] - f[:, :-1])
            with np.errstate(invalid="ignore"):
                in_band = (f_cross >= area.lower_fl) & (f_cross <= area.upper_fl)
            if cfg.apw_unknown_fl_inside:
                in_band |= ~np.isfinite(f_cross)
            t_cross = pred.t_s[:-1] + np.where(in_band, u, np.inf) * np.diff(pred.t_s)
            t_in = np.minimum(t_in, t_cross.min(axis=1))
        for k in np.flatnonzero(np.isfinite(t_in)):
            tid = int(tr.track_id[e[cand[k]]])
            figures = {"area_id": area.area_id, "time_to_entry_s": float(t_in[k])}
            out.append(Hit(("apw", tid, area.area_id), "apw", [tid], figures))
    return out
