"""Short Term Conflict Alert [STCA-SPEC]: linear and turn prediction, current proximity.

The conflict test itself (exact on piecewise-linear paths) is
:func:`~radar_fusion.safety_nets.prediction.segment_conflicts`; the minima may differ
per airspace volume (``stca_overrides``, e.g. 3 NM in a TMA, 5 NM en route).

Pair pruning (no all-pairs matrix)
----------------------------------
Let m_i = p_i + v_i T/2 be the midpoint of track i's linear predicted segment. Every
point of the segment is within |v_i| T/2 of m_i, so if the pair is ever closer than S
within [0, T], |m_i − m_j| < S + (|v_i| + |v_j|) T/2. A k-d tree search on the
midpoints with that bound (S_max, the largest horizontal minimum or proximity threshold
in use, for S; :func:`candidate_pairs`, the tracks grouped by speed) therefore returns
*every* pair that the linear filter could flag — pruning loses no conflict. A turning
path has arc length |v| T and is not a straight segment, so pairs with a turning member
come from a second search around current positions with S_max + (|v_i| + |v_j|) T (each
aircraft moves at most |v| T from where it is). The current proximity test (t = 0) is
covered because |m_i − m_j| ≤ |d0| + (|v_i| + |v_j|) T/2.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np
from scipy.spatial import cKDTree

from ..geo.coordinates import SystemPlane
from ..geo.units import FT_PER_FL, M_PER_NM
from ..tracking.association import sorted_unique
from .config import SafetyNetsConfig
from .life_cycle import Hit
from .polygon import Polygon, ring_xy
from .prediction import (
    eligible,
    horizontal_paths,
    moving,
    segment_conflicts,
    selected_fl,
    turn_rate_rps,
    vertical_paths,
)

if TYPE_CHECKING:
    from ..engine.columns import TrackColumns


class Stca:
    """STCA over all eligible tracks of a period; ``last_candidate_pairs`` is the pair count after pruning."""

    def __init__(self, config: SafetyNetsConfig, plane: SystemPlane) -> None:
        self.config = config
        self._overrides = [
            (Polygon([(ring_xy(plane, [(lon, lat) for lat, lon in o.polygon_latlon_deg]), [])]), o)
            for o in config.stca_overrides
        ]
        self.last_candidate_pairs = 0

    def _pair_minima(
        self, tr: TrackColumns, e: np.ndarray, ia: np.ndarray, ib: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """Horizontal (m) and vertical (ft) minima per pair: the first override volume holding both."""
        cfg = self.config
        h = np.full(ia.shape[0], cfg.stca_h_min_nm * M_PER_NM)
        v = np.full(ia.shape[0], cfg.stca_v_min_ft)
        if not self._overrides or ia.size == 0:
            return h, v
        # every volume each track is in (volumes may overlap or nest): a pair takes the
        # first listed that holds both, not the first of each track's own
        xy = np.column_stack([tr.x_m[e], tr.y_m[e]])
        fl = tr.fl[e]
        inside = np.column_stack(
            [poly.contains(xy) & ~(fl < o.lower_fl) & ~(fl > o.upper_fl) for poly, o in self._overrides]
        )  # (tracks, volumes)
        both = inside[ia] & inside[ib]
        held = both.any(axis=1)
        first = np.argmax(both, axis=1)
        h_vol = np.array([o.h_min_nm * M_PER_NM for _, o in self._overrides])
        v_vol = np.array([o.v_min_ft for _, o in self._overrides])
        h[held], v[held] = h_vol[first[held]], v_vol[first[held]]
        return h, v

    def hits(self, tr: TrackColumns, accel: np.ndarray) -> list[Hit]:
        """This period's STCA hits; ``accel`` is the vertical acceleration per track (fpm/s)."""
        cfg = self.config
        elig = eligible(tr) & moving(tr)
        if cfg.stca_unknown_fl == "ignore":
            elig &= np.isfinite(tr.fl)
        e = np.flatnonzero(elig)
        self.last_candidate_pairs = 0
        if e.size < 2:
            return []
        T = cfg.look_ahead_s
        speed = np.hypot(tr.vx_mps[e], tr.vy_mps[e])
        s_max = max([cfg.stca_h_min_nm] + [o.h_min_nm for o in cfg.stca_overrides]) * M_PER_NM
        if cfg.stca_proximity_h_nm is not None:
            s_max = max(s_max, cfg.stca_proximity_h_nm * M_PER_NM)
        w = turn_rate_rps(tr, e, cfg)
        # pruning: linear paths via segment midpoints, turning tracks via current positions
        mid = np.column_stack([tr.x_m[e] + tr.vx_mps[e] * T / 2, tr.y_m[e] + tr.vy_mps[e] * T / 2])
        p0 = np.column_stack([tr.x_m[e], tr.y_m[e]])
        pairs = candidate_pairs(mid, p0, speed, w != 0.0, s_max, T)
        if pairs.size:  # the same Mode S address twice is a duplicate track, not a pair
            ms = tr.mode_s[e]
            pairs = pairs[~((ms[pairs[:, 0]] >= 0) & (ms[pairs[:, 0]] == ms[pairs[:, 1]]))]
        if pairs.size == 0:
            return []
        n_knots = max(1, int(math.ceil(T / cfg.prediction_step_s)))
        knots = np.linspace(0.0, T, n_knots + 1)
        fl = tr.fl[e]
        z, bent = vertical_paths(
            np.nan_to_num(fl * FT_PER_FL), tr.vrate_fpm[e], accel[e], selected_fl(tr, e), knots, cfg, return_bent=True
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

        x_lin, y_lin, x_turn, y_turn = horizontal_paths(
            tr.x_m[e], tr.y_m[e], tr.vx_mps[e], tr.vy_mps[e], w, knots, math.radians(cfg.turn_max_heading_change_deg)
        )
        h_min, v_min = self._pair_minima(tr, e, ia, ib)
        v_eff = np.maximum(v_min - cfg.stca_v_tolerance_ft, 0.0)
        dz = z[ib] - z[ia]
        dz[unknown[ia] | unknown[ib]] = 0.0  # only with stca_unknown_fl == "conflict"
        # linear prediction filter: one segment [0, T] when both vertical paths are straight
        # (the relative motion is then exactly linear), the knots otherwise
        lin: dict[str, np.ndarray] = {}
        seg = bent[ia] | bent[ib]
        for sel, cols in ((~seg, [0, n_knots]), (seg, slice(None))):
            if not sel.any():
                continue
            a1, b1 = ia[sel], ib[sel]
            r = segment_conflicts(
                (x_lin[b1] - x_lin[a1])[:, cols],
                (y_lin[b1] - y_lin[a1])[:, cols],
                dz[sel][:, cols],
                knots[cols],
                h_min[sel],
                v_eff[sel],
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
        prox_h = h_min if cfg.stca_proximity_h_nm is None else np.full(ia.size, cfg.stca_proximity_h_nm * M_PER_NM)
        prox_v = v_eff if cfg.stca_proximity_v_ft is None else np.full(ia.size, cfg.stca_proximity_v_ft)
        d0 = np.hypot(x_lin[ib, 0] - x_lin[ia, 0], y_lin[ib, 0] - y_lin[ia, 0])
        prox = (d0 < prox_h) & (np.abs(dz[:, 0]) < prox_v)
        hit = np.flatnonzero(conflict | prox)
        # the hits as Python lists first: thousands a period in dense traffic, and indexing
        # numpy arrays one scalar at a time cost more than the whole prediction above
        ids = tr.track_id[e]
        id_a, id_b = ids[ia[hit]], ids[ib[hit]]
        mv, tv = fig["min_vsep_ft"][hit], fig["t_violation_s"][hit]
        columns = zip(
            np.minimum(id_a, id_b).tolist(),
            np.maximum(id_a, id_b).tolist(),
            fig["t_cpa_s"][hit].tolist(),
            fig["min_sep_m"][hit].tolist(),
            np.where(np.isfinite(mv), mv, np.abs(dz[hit, 0])).tolist(),
            np.where(np.isfinite(tv), tv, 0.0).tolist(),
            prox[hit].tolist(),
            strict=True,
        )
        out = []
        for lo, hi, t_cpa, sep, vsep, t_viol, immediate in columns:
            figures = {"time_to_cpa_s": t_cpa, "min_sep_m": sep, "min_vsep_ft": vsep, "time_to_violation_s": t_viol}
            out.append(Hit(("stca", lo, hi), "stca", [lo, hi], figures, immediate=immediate))
        return out


#: speed classes of the pair search: up to 32 m/s, then 32-64, 64-128 m/s, ... (see candidate_pairs)
_SPEED_CLASS_MPS = 32.0


def candidate_pairs(
    mid_xy_m: np.ndarray, xy_m: np.ndarray, speed_mps: np.ndarray, turning: np.ndarray, s_max_m: float, T_s: float
) -> np.ndarray:
    """The pairs (i < j, shape (K, 2), int64, sorted by i then j) that pruning keeps
    (module docstring), each with its own speeds:

        |m_i - m_j| < S_max + (|v_i| + |v_j|) T/2 + 1 m      (linear paths, midpoints m)
        |p_i - p_j| < S_max + (|v_i| + |v_j|) T + 1 m        (i or j turning, positions p)

    The tracks are grouped by speed (up to 32 m/s, 32-64, 64-128 m/s, ...); each pair of
    groups is searched once with its groups' top speeds (one k-d tree per group), and the
    pairs are then cut to the bound of their own speeds. With one radius from the fastest
    track of the period, a few tentative-turned-confirmed tracks at 1-10 km/s made a
    20,000-track period search 1.7-3 million pairs (4.5-14 s; issue 16); every pair
    either bound drops still has neither a conflict nor a proximity alert.
    """
    n = xy_m.shape[0]
    level = np.ceil(np.log2(np.maximum(speed_mps / _SPEED_CLASS_MPS, 1.0))).astype(np.int64)
    top = _SPEED_CLASS_MPS * 2.0 ** level.astype(float)  # every speed of a group is below its top
    groups = [np.flatnonzero(level == lv) for lv in np.unique(level).tolist()]
    keys = []
    for pts, factor, only_turning in ((mid_xy_m, 0.5, False), (xy_m, 1.0, True)):
        trees = [cKDTree(pts[g]) for g in groups]
        for a, ga in enumerate(groups):
            src = ga[turning[ga]] if only_turning else ga
            if src.size == 0:
                continue
            tree_a = cKDTree(pts[src]) if only_turning else trees[a]
            for b, gb in enumerate(groups):
                if not only_turning and b < a:
                    continue  # (a, b) and (b, a) are the same pairs of groups
                r = s_max_m + (top[ga[0]] + top[gb[0]]) * factor * T_s + 1.0
                if b == a and not only_turning:  # within a group: each pair once, no distances kept
                    found = tree_a.query_pairs(r, output_type="ndarray")
                    i, j = ga[found[:, 0]], ga[found[:, 1]]
                    dist = np.hypot(pts[i, 0] - pts[j, 0], pts[i, 1] - pts[j, 1])
                else:
                    found = tree_a.sparse_distance_matrix(trees[b], r, output_type="ndarray")
                    i, j, dist = src[found["i"]], gb[found["j"]], found["v"]
                reach = s_max_m + (speed_mps[i] + speed_mps[j]) * factor * T_s + 1.0
                keep = (i != j) & (dist <= reach)
                i, j = i[keep], j[keep]
                keys.append(np.minimum(i, j).astype(np.int64) * n + np.maximum(i, j))
    key = sorted_unique(np.concatenate(keys)) if keys else np.zeros(0, np.int64)
    return np.column_stack([key // n, key % n])
