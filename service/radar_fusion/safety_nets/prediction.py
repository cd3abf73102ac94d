"""Predicted paths of the tracks, and the exact conflict test on them (STCA, APW, MSAW).

Prediction model (shared by the three functions)
================================================
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
cleared level (``TrackColumns.selected_fl``, e.g. Mode S BDS 4,0 or the flight plan's CFL)
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
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from ..tracking.track_management import TENTATIVE
from .config import SafetyNetsConfig

if TYPE_CHECKING:  # the engine's column type; imported for annotations only (engine → config → here)
    from ..engine.columns import TrackColumns

HISTORY_PERIODS = 4
"""Vertical rates kept per track for the level-off anticipation, periods."""


# --------------------------------------------------------------------------- track columns


def eligible(tr: TrackColumns) -> np.ndarray:
    """The tracks the safety nets judge, bool per track.

    ``tr.safety_eligible`` when the columns carry it (built from a received TrackBatch:
    status ``confirmed`` only), else every track that is not tentative (the engine's
    columns: confirmed or coasting, so that an alert survives a missed scan).
    """
    if tr.safety_eligible is not None:
        return tr.safety_eligible
    return tr.status != TENTATIVE


def selected_fl(tr: TrackColumns, idx: np.ndarray) -> np.ndarray:
    """Selected or cleared flight levels of tracks ``idx`` (NaN unknown; all NaN without the column)."""
    if tr.selected_fl is None:
        return np.full(idx.shape[0], np.nan)
    return tr.selected_fl[idx]


def moving(tr: TrackColumns) -> np.ndarray:
    """Tracks with a finite position and velocity, the only ones a path can be predicted for."""
    return np.isfinite(tr.x_m) & np.isfinite(tr.y_m) & np.isfinite(tr.vx_mps) & np.isfinite(tr.vy_mps)


# --------------------------------------------------------------------------- vertical history


class VerticalRateHistory:
    """The last vertical rates per track, for the level-off anticipation.

    ``update`` once per period with every track; it returns the vertical acceleration
    (fpm/s) per track: the least-squares slope of vertical rate over time through the
    last ``HISTORY_PERIODS`` periods (NaN with fewer than 3 finite rates).
    """

    def __init__(self) -> None:
        # rows sorted by track id
        self._hist_ids = np.zeros(0, np.int64)
        self._hist_t = np.zeros((0, HISTORY_PERIODS))
        self._hist_vr = np.zeros((0, HISTORY_PERIODS))

    def update(self, t_s: float, track_id: np.ndarray, vrate_fpm: np.ndarray) -> np.ndarray:
        n = track_id.shape[0]
        t_hist = np.full((n, HISTORY_PERIODS), np.nan)
        vr_hist = np.full((n, HISTORY_PERIODS), np.nan)
        if self._hist_ids.size and n:
            pos = np.clip(np.searchsorted(self._hist_ids, track_id), 0, self._hist_ids.size - 1)
            known = self._hist_ids[pos] == track_id
            t_hist[known] = self._hist_t[pos[known]]
            vr_hist[known] = self._hist_vr[pos[known]]
        t_hist = np.roll(t_hist, -1, axis=1)
        vr_hist = np.roll(vr_hist, -1, axis=1)
        t_hist[:, -1] = t_s
        vr_hist[:, -1] = vrate_fpm
        order = np.argsort(track_id, kind="stable")
        self._hist_ids = track_id[order]
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


# --------------------------------------------------------------------------- paths


@dataclass
class Prediction:
    """Predicted paths of the eligible tracks at common times ``t_s`` (shape (M,))."""

    t_s: np.ndarray
    x_lin: np.ndarray  # (E, M)
    y_lin: np.ndarray
    x_turn: np.ndarray
    y_turn: np.ndarray
    z_ft: np.ndarray  # (E, M) altitude (100·FL) in feet; NaN unknown


def turn_rate_rps(tr: TrackColumns, idx: np.ndarray, cfg: SafetyNetsConfig) -> np.ndarray:
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


def horizontal_paths(
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


def vertical_paths(
    z0_ft: np.ndarray,
    vrate_fpm: np.ndarray,
    accel_fpm_s: np.ndarray,
    sel_fl: np.ndarray,
    t: np.ndarray,
    cfg: SafetyNetsConfig,
    return_bent: bool = False,
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


def sampled_paths(
    tr: TrackColumns, e: np.ndarray, accel: np.ndarray, horizon_s: float, cfg: SafetyNetsConfig
) -> Prediction:
    """Paths of tracks ``e`` every ``sample_step_s`` up to ``horizon_s`` (APW, MSAW)."""
    t = np.arange(0.0, horizon_s + 1e-9, cfg.sample_step_s)
    if t[-1] < horizon_s - 1e-9:
        t = np.append(t, horizon_s)
    w = turn_rate_rps(tr, e, cfg)
    x_lin, y_lin, x_turn, y_turn = horizontal_paths(
        tr.x_m[e], tr.y_m[e], tr.vx_mps[e], tr.vy_mps[e], w, t, math.radians(cfg.turn_max_heading_change_deg)
    )
    z = vertical_paths(tr.fl[e] * 100.0, tr.vrate_fpm[e], accel[e], selected_fl(tr, e), t, cfg)
    return Prediction(t, x_lin, y_lin, x_turn, y_turn, z)


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
