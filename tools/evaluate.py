"""Score recorded system tracks against simulation truth (DESIGN.md §4).

``radar-fusion evaluate --tracks REC --truth truth.csv [--png out.png]`` reads the
``fusion/tracks`` messages of a recording and the simulator's truth CSV and prints a
table. The same figures are available from Python (the demo, the end-to-end test and
the benchmarks pass decoded batches in memory)::

    batches = load_tracks("run.rec")        # list of TrackBatch dicts
    truth = load_truth("truth.csv")         # Truth
    scores = evaluate(batches, truth, EvalParams())
    print(format_table(scores))
    plot(batches, truth, "run.png", scores)

The truth type, its CSV reader and its interpolation live in :mod:`radar_fusion.tools.truth`,
the cut-off assignment and GOSPA in :mod:`radar_fusion.tools.gospa`; both are imported here.

Definitions (every figure is taken at the batch times, i.e. each TrackBatch's ``t``):

* Truth at a batch time: each target's rows (one per second) are interpolated linearly
  in time (position and velocity) to the batch time. A target exists at ``t`` when ``t``
  lies between two of its rows at most ``truth_max_gap_s`` apart (or on a row). It is
  *detectable* at ``t`` when the rows on both sides of ``t`` have ``detectable = 1``.
* Displayed tracks: tracks whose status is ``confirmed`` or ``coasting`` (tentative tracks
  are not shown to a controller and are ignored, except to date a track's start).
* A track reported at its own time t_k ≠ the batch time (a track of one update, shown
  where and when it was measured, with no velocity yet) is scored against the truth at
  t_k: it is moved by the displacement, from t_k to the batch time, of the target
  nearest to it at t_k, and then treated like the others. Its velocity is nil: velocity
  errors are taken over the pairs whose track sends one.
* Association: per batch, existing truth targets (detectable or not) and displayed
  tracks are paired by the optimal assignment (``scipy.optimize.linear_sum_assignment``)
  that minimises Σ min(d, gate)² over pairs, where d is the horizontal distance in the
  system plane; pairs with d ≥ ``gate_m`` are dropped. (This is GOSPA's assignment with
  c = gate, p = 2.) Each batch is split into the connected components of the graph
  "d < gate", which gives the same optimum and keeps 1,000 tracks fast. With
  ``keep_previous`` (default, as in CLEAR MOT, Bernardin & Stiefelhagen 2008) a pair of
  the previous batch still closer than the gate is kept before the others are assigned,
  so two aircraft crossing (e.g. at different levels) do not swap their tracks in the
  score when the tracker kept them apart.
* Each displayed track in a batch is then exactly one of: *assigned* (to a detectable
  target), *excused* (assigned to a target no radar can see, e.g. a track coasting
  after the aircraft left coverage: neither rewarded nor penalised), *duplicate*
  (unassigned but closer than the gate to a target that has its own track), *false*
  (none of these).
* Position / velocity error of a pair: e_pos = |(x, y)_track − (x, y)_truth| in metres,
  e_vel = |(vx, vy)_track − (vx, vy)_truth| in m/s. RMS = sqrt(mean(e²)), p95 = the 95th
  percentile of e, over all associated pairs whose track status is in ``rms_statuses``
  (default: confirmed only). "Settled" figures leave out each track's first
  ``settle_s`` seconds, counted from its first appearance in the batches (any status).
* Straight flight and turns: a pair is *straight* when its target's truth turn rate at
  the batch time (:func:`truth_turn_rate_deg_s`) is below ``straight_below_deg_s`` and
  *turning* when it is above ``turning_above_deg_s``, both among the settled pairs. A
  turning pair is in the turn's *onset* when its target has been turning (rate above
  ``straight_below_deg_s`` at every batch time since) for less than ``turn_onset_s``
  seconds, counted from the first batch time of the turn, else in its *steady* part.
  ``turning_outward_mean_m`` is the mean, over the turning pairs, of the track's offset
  across the truth's direction of flight towards the outside of the turn: a filter that
  is late into a turn flies wide of it, a positive offset.
* GOSPA (García-Fernández, Rahmathullah, Svensson 2017, α = 2), per batch, between the
  detectable truth targets X (|X| = m) and the displayed, non-excused tracks Y
  (|Y| = n)::

      d_p^(c,2)(X, Y) = ( min_γ Σ_{(i,j)∈γ} d(x_i, y_j)^p + c^p/2·(m − |γ|) + c^p/2·(n − |γ|) )^(1/p)

  over partial assignments γ using only pairs with d < c. The three terms are the
  localisation, missed and false parts (in m^p); they are reported as time means, as
  shares of the mean of d^p, and as mean counts of missed targets / false tracks.
* Continuity, per truth target: the distinct track ids ever associated with it (ideal
  1); its *id changes*, the times the associated track id differs from the previous
  associated one; its *completeness*, the fraction of the batch times at which it is
  detectable that it is associated with a displayed track.
* ID swaps: the times a track id is associated with a different target from the one it
  was last associated with (a track jumping from one aircraft to another).
* False tracks: displayed track ids classified *false* in more than ``false_fraction``
  of the batches in which they are displayed. Duplicate tracks: displayed track ids
  classified *duplicate* in at least one batch. Both are also given as per-time means
  (the mean number of false / duplicate tracks per batch).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import msgpack
import numpy as np
import numpy.typing as npt
from scipy.spatial import cKDTree

from ..cli import positive_float
from ..recording import read_recording
from .gospa import Gospa, cutoff_assignment, gospa
from .truth import TRUTH_COLUMNS, Truth, TruthAtTimes, as_truth, interpolate_truth, load_truth

__all__ = [
    "DISPLAYED_STATUSES",
    "TRACKS_KEY",
    "TRUTH_COLUMNS",
    "EvalParams",
    "Gospa",
    "Scores",
    "TargetScore",
    # the truth and the metric this module scores with (their homes: truth.py, gospa.py)
    "Truth",
    "TruthAtTimes",
    "add_arguments",
    "as_truth",
    "cutoff_assignment",
    "evaluate",
    "format_table",
    "gospa",
    "interpolate_truth",
    "load_tracks",
    "load_truth",
    "plot",
    "run",
]

TRACKS_KEY = "fusion/tracks"
DISPLAYED_STATUSES = ("confirmed", "coasting")

# Classification of a displayed track in one batch.
ASSIGNED, EXCUSED, DUPLICATE, FALSE = 0, 1, 2, 3


# --------------------------------------------------------------------------- inputs


def load_tracks(path: str | Path, key: str = TRACKS_KEY) -> list[dict]:
    """The decoded TrackBatch dicts of a recording (messages on ``key``), sorted by ``t``."""
    batches = []
    for rec in read_recording(path):
        if rec.key == key or rec.key.endswith("/" + key):
            obj = msgpack.unpackb(rec.payload, raw=False)
            if isinstance(obj, dict) and "tracks" in obj:
                batches.append(obj)
    batches.sort(key=lambda b: float(b["t"]))
    return batches


# --------------------------------------------------------------------------- scores


@dataclass(frozen=True)
class EvalParams:
    """Evaluation parameters (see the module docstring for their role)."""

    gate_m: float = 2000.0
    settle_s: float = 30.0
    gospa_c_m: float = 2000.0
    gospa_p: float = 2.0
    false_fraction: float = 0.5
    truth_max_gap_s: float = 10.0
    rms_statuses: tuple[str, ...] = ("confirmed",)
    keep_previous: bool = True
    turning_above_deg_s: float = 1.5
    straight_below_deg_s: float = 0.3
    turn_onset_s: float = 24.0


@dataclass
class TargetScore:
    """Continuity and accuracy figures of one truth target."""

    target_id: str
    mode_s: str
    callsign: str
    detectable_batches: int
    covered_batches: int
    completeness: float
    track_ids: list[int]
    n_track_ids: int
    id_changes: int
    swaps_involved: int
    pos_rms_m: float


@dataclass
class Scores:
    """All figures of one evaluation; ``*_per_time`` arrays are aligned with ``times_s``."""

    params: EvalParams
    n_batches: int
    n_truth_targets: int
    n_detectable_targets: int
    n_displayed_tracks: int
    n_pairs: int
    n_pairs_settled: int
    pos_rms_m: float
    pos_p95_m: float
    vel_rms_mps: float
    vel_p95_mps: float
    pos_rms_settled_m: float
    pos_p95_settled_m: float
    vel_rms_settled_mps: float
    vel_p95_settled_mps: float
    pos_rms_straight_m: float
    pos_rms_turning_m: float
    n_pairs_straight: int
    n_pairs_turning: int
    pos_rms_turn_onset_m: float
    pos_rms_turn_steady_m: float
    n_pairs_turn_onset: int
    turning_outward_mean_m: float
    gospa_mean_m: float
    gospa_localisation_mean: float
    gospa_missed_mean: float
    gospa_false_mean: float
    gospa_missed_targets_mean: float
    gospa_false_tracks_mean: float
    track_ids_per_target_mean: float
    id_changes: int
    id_swaps: int
    completeness_mean: float
    missed_targets_per_time_mean: float
    detectable_targets_per_time_mean: float
    false_tracks: int
    false_tracks_per_time_mean: float
    duplicate_tracks: int
    duplicate_tracks_per_time_mean: float
    false_track_ids: list[int]
    duplicate_track_ids: list[int]
    targets: list[TargetScore]
    times_s: np.ndarray = field(repr=False)
    gospa_per_time_m: np.ndarray = field(repr=False)
    gospa_localisation_per_time: np.ndarray = field(repr=False)
    gospa_missed_per_time: np.ndarray = field(repr=False)
    gospa_false_per_time: np.ndarray = field(repr=False)

    def summary(self) -> dict[str, Any]:
        """The scalar figures (and per-target details) as a JSON-friendly dict."""
        out = {}
        for k, v in asdict(self).items():
            if isinstance(v, np.ndarray):
                continue
            out[k] = v
        return json.loads(json.dumps(out, default=float, allow_nan=True))


def turn_age_at(turn_deg_s: np.ndarray, times_s: np.ndarray, turning_above_deg_s: float) -> np.ndarray:
    """Seconds each target has been turning at each batch time, (K, T): the time since the
    first batch time of the run of batch times, up to this one, at which its turn rate's
    magnitude is above ``turning_above_deg_s``; NaN where it is not turning (or has no rate).
    A turn under way at the first batch time counts from that time."""
    k, n = turn_deg_s.shape
    with np.errstate(invalid="ignore"):
        turning = np.abs(turn_deg_s) > turning_above_deg_s  # NaN: not turning
    # index of the latest batch time, up to each one, at which the target was not turning
    last_off = np.maximum.accumulate(np.where(turning, -1, np.arange(n)[None, :]), axis=1)
    start = np.minimum(last_off + 1, n - 1) if n else last_off
    age = times_s[None, :] - times_s[start] if n else np.zeros((k, 0))
    return np.where(turning, age, np.nan)


def truth_turn_rate_deg_s(vx_mps: np.ndarray, vy_mps: np.ndarray, times_s: np.ndarray) -> np.ndarray:
    """Turn rate of each truth target at each batch time, deg/s (positive = right turn),
    from the truth velocities already interpolated to the batch times: the heading
    psi = atan2(vx, vy) unwrapped along time, differentiated by central differences
    (one-sided at the ends). (K, T) arrays; NaN where the target does not exist at a time
    or a neighbour, or moves slower than 5 m/s (no heading)."""
    out = np.full(vx_mps.shape, np.nan)
    if times_s.shape[0] < 2:
        return out
    speed = np.hypot(vx_mps, vy_mps)
    psi = np.arctan2(vx_mps, vy_mps)
    psi = np.where(speed > 5.0, psi, np.nan)
    # unwrap ignores NaN poorly: unwrap the steps instead
    step = np.diff(psi, axis=1)
    step = (step + np.pi) % (2 * np.pi) - np.pi
    dt = np.diff(times_s)
    rate = step / dt  # rad/s between consecutive times
    out[:, 1:-1] = 0.5 * (rate[:, 1:] + rate[:, :-1])
    out[:, 0] = rate[:, 0]
    out[:, -1] = rate[:, -1]
    return np.degrees(out)


def _rms(e: np.ndarray) -> float:
    return float(np.sqrt(np.mean(e**2))) if e.size else math.nan


def _p95(e: np.ndarray) -> float:
    return float(np.percentile(e, 95)) if e.size else math.nan


def _associate(
    truth_xy: np.ndarray,
    track_xy: np.ndarray,
    tgt_idx: np.ndarray,
    track_ids: np.ndarray,
    previous: Mapping[int, int],
    params: EvalParams,
) -> tuple[np.ndarray, np.ndarray]:
    """One batch's association: (local truth index, local track index) of each pair.

    With ``params.keep_previous``, a pair of the previous batch whose distance is still
    below the gate is kept first; the remaining targets and tracks are paired by
    :func:`cutoff_assignment` (gate, p = 2).
    """
    m, n = truth_xy.shape[0], track_xy.shape[0]
    keep_i = np.zeros(0, np.intp)
    keep_j = np.zeros(0, np.intp)
    if params.keep_previous and previous and m and n:
        local = np.full(int(tgt_idx.max()) + 1, -1, np.intp)
        local[tgt_idx] = np.arange(m)
        prev_global = np.fromiter((previous.get(v, -1) for v in track_ids.tolist()), np.intp, n)
        ok = (prev_global >= 0) & (prev_global < local.shape[0])
        prev_local = np.where(ok, local[np.clip(prev_global, 0, local.shape[0] - 1)], -1)
        cand_j = np.flatnonzero(prev_local >= 0)
        cand_i = prev_local[cand_j]
        d = np.hypot(*(track_xy[cand_j] - truth_xy[cand_i]).T) if cand_j.size else np.zeros(0)
        keep_i, keep_j = cand_i[d < params.gate_m], cand_j[d < params.gate_m]
    free_i = np.setdiff1d(np.arange(m), keep_i)
    free_j = np.setdiff1d(np.arange(n), keep_j)
    ai, aj, _ = cutoff_assignment(truth_xy[free_i], track_xy[free_j], params.gate_m, 2.0)
    return np.concatenate((keep_i, free_i[ai])), np.concatenate((keep_j, free_j[aj]))


def _batch_columns(batch: Mapping[str, Any]) -> tuple[np.ndarray, ...]:
    """ids, x, y, vx, vy (NaN where nil: velocity not known yet), status and each track's own
    time t (the batch's where the track carries none)."""
    tracks = batch.get("tracks") or []
    n = len(tracks)
    nan = math.nan
    ids = np.fromiter((tr["track_id"] for tr in tracks), np.int64, n)
    x = np.fromiter((tr["x_m"] for tr in tracks), float, n)
    y = np.fromiter((tr["y_m"] for tr in tracks), float, n)
    vx = np.fromiter((nan if tr.get("vx_mps") is None else tr["vx_mps"] for tr in tracks), float, n)
    vy = np.fromiter((nan if tr.get("vy_mps") is None else tr["vy_mps"] for tr in tracks), float, n)
    status = np.array([tr["status"] for tr in tracks], dtype=object) if n else np.zeros(0, object)
    t_batch = float(batch["t"])
    t = np.fromiter((t_batch if tr.get("t") is None else tr["t"] for tr in tracks), float, n)
    return ids, x, y, vx, vy, status, t


def _to_batch_time(
    x: np.ndarray, y: np.ndarray, t_track: np.ndarray, truth: Truth, tat: Any, b: int, t_batch: float, max_gap_s: float
) -> None:
    """Tracks reported at their own time t_k (one update: where and when they were measured,
    no velocity yet) are scored against the truth at t_k: each is moved, in place, by the
    displacement from t_k to the batch time of the target nearest to it at t_k, so that its
    error to that target at the batch time is its error at t_k."""
    early = np.flatnonzero(t_track != t_batch)
    if not early.size:
        return
    tk, inv = np.unique(t_track[early], return_inverse=True)
    at_k = interpolate_truth(truth, tk, max_gap_s)
    for j, k in enumerate(early):
        col = inv[j]
        ok = np.flatnonzero(at_k.exists[:, col] & tat.exists[:, b])
        if not ok.size:
            continue
        d = np.hypot(at_k.x_m[ok, col] - x[k], at_k.y_m[ok, col] - y[k])
        i = ok[int(np.argmin(d))]
        x[k] += tat.x_m[i, b] - at_k.x_m[i, col]
        y[k] += tat.y_m[i, b] - at_k.y_m[i, col]


def evaluate(batches: Sequence[Mapping[str, Any]], truth: Truth | Any, params: EvalParams | None = None) -> Scores:
    """Score decoded TrackBatch dicts against truth (definitions in the module docstring)."""
    params = params or EvalParams()
    truth = as_truth(truth)
    batches = sorted(batches, key=lambda b: float(b["t"]))
    times = np.array([float(b["t"]) for b in batches])
    tat = interpolate_truth(truth, times, params.truth_max_gap_s)
    n_targets, n_times = truth.n_targets, times.shape[0]
    turn_deg_s = truth_turn_rate_deg_s(tat.vx_mps, tat.vy_mps, times)
    turn_age_s = turn_age_at(turn_deg_s, times, params.straight_below_deg_s)
    c, p = params.gospa_c_m, params.gospa_p
    rms_statuses = set(params.rms_statuses)

    first_seen: dict[int, float] = {}
    previous: dict[int, int] = {}  # track id -> target index, associations of the previous batch
    # Per-pair records (concatenated at the end).
    pair_batch, pair_target, pair_track, pair_epos, pair_evel, pair_settled, pair_rms = [], [], [], [], [], [], []
    pair_turn, pair_turn_age, pair_outward = [], [], []
    # Per displayed track and batch: its id and its classification.
    cls_ids, cls_kind = [], []
    g_dist = np.zeros(n_times)
    g_loc = np.zeros(n_times)
    g_mis = np.zeros(n_times)
    g_fal = np.zeros(n_times)
    g_nmis = np.zeros(n_times)
    g_nfal = np.zeros(n_times)
    missed_per_time = np.zeros(n_times)
    covered = np.zeros((n_targets, n_times), bool)

    for b, batch in enumerate(batches):
        t = times[b]
        ids, x, y, vx, vy, status, t_track = _batch_columns(batch)
        _to_batch_time(x, y, t_track, truth, tat, b, t, params.truth_max_gap_s)
        for tid in ids.tolist():
            first_seen.setdefault(tid, t)
        disp = np.isin(status, DISPLAYED_STATUSES) if ids.size else np.zeros(0, bool)
        d_idx = np.flatnonzero(disp)
        tgt_idx = np.flatnonzero(tat.exists[:, b])
        truth_xy = np.column_stack((tat.x_m[tgt_idx, b], tat.y_m[tgt_idx, b]))
        track_xy = np.column_stack((x[d_idx], y[d_idx]))
        ai, aj = _associate(truth_xy, track_xy, tgt_idx, ids[d_idx], previous, params)
        a_tgt, a_trk = tgt_idx[ai], d_idx[aj]
        previous = dict(zip(ids[a_trk].tolist(), a_tgt.tolist()))

        # Classification of every displayed track.
        kind = np.full(d_idx.shape[0], FALSE, np.int8)
        det_of_pair = tat.detectable[a_tgt, b]
        kind[aj[det_of_pair]] = ASSIGNED
        kind[aj[~det_of_pair]] = EXCUSED
        unassigned = kind == FALSE
        if unassigned.any() and ai.size:
            assigned_tgt_xy = truth_xy[ai]
            near = cKDTree(assigned_tgt_xy).query(track_xy[unassigned], distance_upper_bound=params.gate_m)[0]
            dup = np.flatnonzero(unassigned)[near < params.gate_m]
            kind[dup] = DUPLICATE
        cls_ids.append(ids[d_idx])
        cls_kind.append(kind)
        covered[a_tgt[det_of_pair], b] = True
        missed_per_time[b] = np.count_nonzero(tat.detectable[:, b]) - np.count_nonzero(det_of_pair)

        # Errors of the associated pairs.
        dx_m, dy_m = x[a_trk] - tat.x_m[a_tgt, b], y[a_trk] - tat.y_m[a_tgt, b]
        e_pos = np.hypot(dx_m, dy_m)
        e_vel = np.hypot(vx[a_trk] - tat.vx_mps[a_tgt, b], vy[a_trk] - tat.vy_mps[a_tgt, b])
        age = t - np.array([first_seen[int(v)] for v in ids[a_trk]]) if a_trk.size else np.zeros(0)
        pair_batch.append(np.full(a_trk.shape[0], b))
        pair_target.append(a_tgt)
        pair_track.append(ids[a_trk])
        pair_epos.append(e_pos)
        pair_evel.append(e_vel)
        pair_turn.append(np.abs(turn_deg_s[a_tgt, b]))
        pair_turn_age.append(turn_age_s[a_tgt, b])
        # across the truth's velocity, positive to its right; times the turn's sign (a right
        # turn's inside is on the right), negated: positive outside the turn
        t_vx, t_vy = tat.vx_mps[a_tgt, b], tat.vy_mps[a_tgt, b]
        with np.errstate(invalid="ignore", divide="ignore"):
            right_m = (dx_m * t_vy - dy_m * t_vx) / np.hypot(t_vx, t_vy)
        pair_outward.append(-np.sign(turn_deg_s[a_tgt, b]) * right_m)
        pair_settled.append(age >= params.settle_s)
        pair_rms.append(np.isin(status[a_trk], list(rms_statuses)) if a_trk.size else np.zeros(0, bool))

        # GOSPA: detectable targets vs displayed tracks that are not excused.
        det_tgt = np.flatnonzero(tat.detectable[:, b])
        g = gospa(
            np.column_stack((tat.x_m[det_tgt, b], tat.y_m[det_tgt, b])),
            track_xy[kind != EXCUSED],
            c,
            p,
        )
        g_dist[b], g_loc[b], g_mis[b], g_fal[b] = g.distance_m, g.localisation, g.missed, g.false
        g_nmis[b], g_nfal[b] = g.n_missed, g.n_false

    def cat(parts: list[Any], dtype: npt.DTypeLike) -> np.ndarray:
        return np.concatenate(parts).astype(dtype) if parts else np.zeros(0, dtype)

    pb, pt, pk = cat(pair_batch, np.int64), cat(pair_target, np.int64), cat(pair_track, np.int64)
    epos, evel = cat(pair_epos, float), cat(pair_evel, float)
    settled, in_rms = cat(pair_settled, bool), cat(pair_rms, bool)
    turn = cat(pair_turn, float)
    turn_age = cat(pair_turn_age, float)
    outward = cat(pair_outward, float)

    # ID swaps (track side): consecutive associations of a track id with different targets.
    order = np.lexsort((pb, pk))
    k_sorted, t_sorted = pk[order], pt[order]
    same_track = k_sorted[1:] == k_sorted[:-1]
    swap_mask = same_track & (t_sorted[1:] != t_sorted[:-1])
    swaps_involved = np.bincount(t_sorted[1:][swap_mask], minlength=n_targets) + np.bincount(
        t_sorted[:-1][swap_mask], minlength=n_targets
    )
    # ID changes (target side): consecutive associations of a target with different track ids.
    order = np.lexsort((pb, pt))
    t2, k2 = pt[order], pk[order]
    change_mask = (t2[1:] == t2[:-1]) & (k2[1:] != k2[:-1])
    id_changes = np.bincount(t2[1:][change_mask], minlength=n_targets)

    # Per-track classification over life.
    all_ids = cat(cls_ids, np.int64)
    all_kind = cat(cls_kind, np.int8)
    uid, inv = np.unique(all_ids, return_inverse=True)
    displayed_n = np.bincount(inv, minlength=uid.shape[0])
    false_n = np.bincount(inv, weights=(all_kind == FALSE), minlength=uid.shape[0])
    dup_n = np.bincount(inv, weights=(all_kind == DUPLICATE), minlength=uid.shape[0])
    false_ids = uid[false_n > params.false_fraction * displayed_n]
    dup_ids = uid[dup_n > 0]
    per_time_false = np.array([np.count_nonzero(k == FALSE) for k in cls_kind]) if cls_kind else np.zeros(0)
    per_time_dup = np.array([np.count_nonzero(k == DUPLICATE) for k in cls_kind]) if cls_kind else np.zeros(0)

    # Per-target details.
    targets = []
    det_n = tat.detectable.sum(axis=1)
    cov_n = covered.sum(axis=1)
    pos_sq_sum = np.bincount(pt, weights=epos**2, minlength=n_targets)
    pair_n = np.bincount(pt, minlength=n_targets)
    pairs_by_target = np.unique(np.column_stack((pt, pk)), axis=0) if pt.size else np.zeros((0, 2), np.int64)
    for i in range(n_targets):
        tids = pairs_by_target[pairs_by_target[:, 0] == i, 1].tolist()
        targets.append(
            TargetScore(
                target_id=truth.target_ids[i],
                mode_s=truth.target_mode_s[i],
                callsign=truth.target_callsign[i],
                detectable_batches=int(det_n[i]),
                covered_batches=int(cov_n[i]),
                completeness=float(cov_n[i] / det_n[i]) if det_n[i] else math.nan,
                track_ids=[int(v) for v in tids],
                n_track_ids=len(tids),
                id_changes=int(id_changes[i]),
                swaps_involved=int(swaps_involved[i]),
                pos_rms_m=float(math.sqrt(pos_sq_sum[i] / pair_n[i])) if pair_n[i] else math.nan,
            )
        )
    seen = [ts for ts in targets if ts.detectable_batches > 0]
    mean = lambda a: float(np.mean(a)) if len(a) else math.nan
    sel, sel_s = in_rms, in_rms & settled
    sel_straight = sel_s & (turn < params.straight_below_deg_s)  # NaN (no rate) is in neither
    sel_turning = sel_s & (turn > params.turning_above_deg_s)
    sel_onset = sel_turning & (turn_age < params.turn_onset_s)
    sel_steady = sel_turning & (turn_age >= params.turn_onset_s)
    v_known = np.isfinite(evel)  # a track of one update sends no velocity: none to score

    return Scores(
        params=params,
        n_batches=n_times,
        n_truth_targets=n_targets,
        n_detectable_targets=len(seen),
        n_displayed_tracks=int(uid.shape[0]),
        n_pairs=int(np.count_nonzero(sel)),
        n_pairs_settled=int(np.count_nonzero(sel_s)),
        pos_rms_m=_rms(epos[sel]),
        pos_p95_m=_p95(epos[sel]),
        vel_rms_mps=_rms(evel[sel & v_known]),
        vel_p95_mps=_p95(evel[sel & v_known]),
        pos_rms_settled_m=_rms(epos[sel_s]),
        pos_p95_settled_m=_p95(epos[sel_s]),
        vel_rms_settled_mps=_rms(evel[sel_s & v_known]),
        vel_p95_settled_mps=_p95(evel[sel_s & v_known]),
        pos_rms_straight_m=_rms(epos[sel_straight]),
        pos_rms_turning_m=_rms(epos[sel_turning]),
        n_pairs_straight=int(np.count_nonzero(sel_straight)),
        n_pairs_turning=int(np.count_nonzero(sel_turning)),
        pos_rms_turn_onset_m=_rms(epos[sel_onset]),
        pos_rms_turn_steady_m=_rms(epos[sel_steady]),
        n_pairs_turn_onset=int(np.count_nonzero(sel_onset)),
        turning_outward_mean_m=mean(outward[sel_turning]),
        gospa_mean_m=mean(g_dist),
        gospa_localisation_mean=mean(g_loc),
        gospa_missed_mean=mean(g_mis),
        gospa_false_mean=mean(g_fal),
        gospa_missed_targets_mean=mean(g_nmis),
        gospa_false_tracks_mean=mean(g_nfal),
        track_ids_per_target_mean=mean([ts.n_track_ids for ts in seen]),
        id_changes=int(id_changes.sum()),
        id_swaps=int(np.count_nonzero(swap_mask)),
        completeness_mean=mean([ts.completeness for ts in seen]),
        missed_targets_per_time_mean=mean(missed_per_time),
        detectable_targets_per_time_mean=mean(tat.detectable.sum(axis=0)),
        false_tracks=int(false_ids.shape[0]),
        false_tracks_per_time_mean=mean(per_time_false),
        duplicate_tracks=int(dup_ids.shape[0]),
        duplicate_tracks_per_time_mean=mean(per_time_dup),
        false_track_ids=[int(v) for v in false_ids],
        duplicate_track_ids=[int(v) for v in dup_ids],
        targets=targets,
        times_s=times,
        gospa_per_time_m=g_dist,
        gospa_localisation_per_time=g_loc,
        gospa_missed_per_time=g_mis,
        gospa_false_per_time=g_fal,
    )


# --------------------------------------------------------------------------- output


def format_table(scores: Scores) -> str:
    """A plain-text table of the headline figures, with the parameters used."""
    s, pr = scores, scores.params
    total = s.gospa_localisation_mean + s.gospa_missed_mean + s.gospa_false_mean
    share = (lambda v: f"{100.0 * v / total:5.1f} %") if total > 0 else (lambda v: "    -  ")
    f = lambda v, unit="", fmt="{:.1f}": (
        ("n/a" if v is None or (isinstance(v, float) and math.isnan(v)) else fmt.format(v)) + unit
    )
    rows = [
        (
            "batches / truth targets (detectable) / displayed tracks",
            f"{s.n_batches} / {s.n_truth_targets} ({s.n_detectable_targets}) / {s.n_displayed_tracks}",
        ),
        (
            f"association: gate {pr.gate_m:.0f} m; RMS over status {'+'.join(pr.rms_statuses)}; pairs (settled)",
            f"{s.n_pairs} ({s.n_pairs_settled})",
        ),
        ("horizontal position RMS / p95", f"{f(s.pos_rms_m)} m / {f(s.pos_p95_m)} m"),
        ("velocity RMS / p95", f"{f(s.vel_rms_mps)} m/s / {f(s.vel_p95_mps)} m/s"),
        (
            f"after {pr.settle_s:.0f} s settling: position RMS / p95",
            f"{f(s.pos_rms_settled_m)} m / {f(s.pos_p95_settled_m)} m",
        ),
        (
            f"after {pr.settle_s:.0f} s settling: velocity RMS / p95",
            f"{f(s.vel_rms_settled_mps)} m/s / {f(s.vel_p95_settled_mps)} m/s",
        ),
        (
            f"settled position RMS straight (< {pr.straight_below_deg_s:g} deg/s) / "
            f"turning (> {pr.turning_above_deg_s:g} deg/s); pairs",
            f"{f(s.pos_rms_straight_m)} m / {f(s.pos_rms_turning_m)} m; {s.n_pairs_straight} / {s.n_pairs_turning}",
        ),
        (
            f"  turning in the first {pr.turn_onset_s:g} s of a turn / after; pairs; mean offset outside the turn",
            f"{f(s.pos_rms_turn_onset_m)} m / {f(s.pos_rms_turn_steady_m)} m; {s.n_pairs_turn_onset} / "
            f"{s.n_pairs_turning - s.n_pairs_turn_onset}; {f(s.turning_outward_mean_m)} m",
        ),
        (
            f"GOSPA mean (c = {pr.gospa_c_m:.0f} m, p = {pr.gospa_p:g}, alpha = 2; "
            f"{s.detectable_targets_per_time_mean:.1f} targets/time)",
            f"{f(s.gospa_mean_m)} m",
        ),
        (
            "  share of mean d^p: localisation / missed / false",
            f"{share(s.gospa_localisation_mean)} / {share(s.gospa_missed_mean)} / {share(s.gospa_false_mean)}",
        ),
        (
            "  mean missed targets / false tracks per time",
            f"{s.gospa_missed_targets_mean:.2f} / {s.gospa_false_tracks_mean:.2f}",
        ),
        ("track ids per target (mean, ideal 1)", f(s.track_ids_per_target_mean, fmt="{:.2f}")),
        ("id changes (target side) / id swaps (track side)", f"{s.id_changes} / {s.id_swaps}"),
        ("completeness (mean over targets)", f(100.0 * s.completeness_mean, " %")),
        ("missed targets per time (association)", f(s.missed_targets_per_time_mean, fmt="{:.2f}")),
        (
            f"false tracks (false > {100 * pr.false_fraction:.0f} % of life) / per time",
            f"{s.false_tracks} / {s.false_tracks_per_time_mean:.2f}",
        ),
        ("duplicate tracks / per time", f"{s.duplicate_tracks} / {s.duplicate_tracks_per_time_mean:.2f}"),
    ]
    width = max(len(r[0]) for r in rows)
    lines = [f"{name.ljust(width)}  {value.strip()}" for name, value in rows]
    bad = [t for t in s.targets if t.detectable_batches and (t.n_track_ids != 1 or t.completeness < 0.9)]
    if bad:
        lines.append("")
        lines.append("targets with more than one track id, none, or completeness < 90 %:")
        lines.append(
            f"  {'target':>12} {'mode_s':>7} {'callsign':>9} {'ids':>4} {'changes':>7} {'swaps':>5} "
            f"{'complete':>8} {'pos RMS m':>9}"
        )
        for t in bad[:20]:
            lines.append(
                f"  {t.target_id:>12} {t.mode_s:>7} {t.callsign:>9} {t.n_track_ids:>4} {t.id_changes:>7} "
                f"{t.swaps_involved:>5} {100 * t.completeness:>7.1f}% {t.pos_rms_m:>9.1f}"
            )
        if len(bad) > 20:
            lines.append(f"  ... and {len(bad) - 20} more")
    return "\n".join(lines)


def plot(batches: Sequence[Mapping[str, Any]], truth: Any, path: str | Path, scores: Scores | None = None) -> Path:
    """Write a PNG: truth as lines, displayed track positions as dots coloured by track id (km)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    truth = as_truth(truth)
    if scores is None:
        scores = evaluate(batches, truth)
    fig, ax = plt.subplots(figsize=(9, 8), dpi=110)
    for i, (s, e) in enumerate(zip(truth.start, truth.stop)):
        ax.plot(
            truth.x_m[s:e] / 1e3,
            truth.y_m[s:e] / 1e3,
            "-",
            color="0.35",
            lw=0.8,
            zorder=1,
            label="truth" if i == 0 else None,
        )
    xs, ys, ids = [], [], []
    for batch in batches:
        tid, x, y, _, _, status, _ = _batch_columns(batch)
        disp = np.isin(status, DISPLAYED_STATUSES) if tid.size else np.zeros(0, bool)
        xs.append(x[disp])
        ys.append(y[disp])
        ids.append(tid[disp])
    if xs:
        x, y, tid = np.concatenate(xs), np.concatenate(ys), np.concatenate(ids)
        # Colour by track id: golden-ratio hues, so consecutive ids get distant colours.
        from matplotlib.colors import hsv_to_rgb

        hue = (tid * 0.6180339887) % 1.0
        colour = hsv_to_rgb(np.column_stack((hue, np.full(hue.shape, 0.85), np.full(hue.shape, 0.8))))
        size = 10.0 if x.size < 5000 else 3.0
        ax.scatter(x / 1e3, y / 1e3, s=size, c=colour, zorder=2, linewidths=0, label="tracks (colour = track id)")
        last = {int(k): (xx, yy) for k, xx, yy in zip(tid, x, y)}
        if len(last) <= 40:  # label each track at its last position
            for k, (xx, yy) in last.items():
                ax.annotate(str(k), (xx / 1e3, yy / 1e3), fontsize=7, xytext=(3, 3), textcoords="offset points")
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("x east, system plane (km)")
    ax.set_ylabel("y north, system plane (km)")
    ax.grid(True, lw=0.3)
    ax.legend(loc="best", fontsize=8, markerscale=3)
    ax.set_title(
        f"pos RMS {scores.pos_rms_m:.0f} m (settled {scores.pos_rms_settled_m:.0f} m), "
        f"vel RMS {scores.vel_rms_mps:.1f} m/s, GOSPA {scores.gospa_mean_m:.0f} m\n"
        f"ids/target {scores.track_ids_per_target_mean:.2f}, swaps {scores.id_swaps}, "
        f"completeness {100 * scores.completeness_mean:.1f} %, false {scores.false_tracks}, "
        f"duplicate {scores.duplicate_tracks}",
        fontsize=10,
    )
    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, format="png")
    plt.close(fig)
    return path


# --------------------------------------------------------------------------- command line


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of ``radar-fusion evaluate``."""
    d = EvalParams()
    parser.add_argument("--tracks", required=True, help="recording holding fusion/tracks messages")
    parser.add_argument("--truth", required=True, help="truth CSV written by the simulator")
    parser.add_argument("--png", default=None, help="write a plot of truth and tracks to this PNG")
    parser.add_argument("--json", default=None, help="write the figures (and per-target details) as JSON")
    parser.add_argument(
        "--gate-m", type=positive_float, default=d.gate_m, help="association gate, metres (%(default)s)"
    )
    parser.add_argument(
        "--settle-s",
        type=float,
        default=d.settle_s,
        help="skip each track's first seconds for the settled figures (%(default)s)",
    )
    parser.add_argument(
        "--gospa-c-m", type=positive_float, default=d.gospa_c_m, help="GOSPA cut-off c, metres (%(default)s)"
    )
    parser.add_argument("--gospa-p", type=positive_float, default=d.gospa_p, help="GOSPA order p (%(default)s)")
    parser.add_argument(
        "--false-fraction",
        type=float,
        default=d.false_fraction,
        help="a track is false when unassociated for more than this fraction of its life",
    )
    parser.add_argument(
        "--no-keep-previous",
        dest="keep_previous",
        action="store_false",
        help="associate each batch from scratch instead of keeping last batch's pairs",
    )


def not_comparable(batches: Sequence[Mapping[str, Any]], truth: Truth) -> str | None:
    """Why the tracks cannot be scored against the truth in the system plane, or None:
    their times do not overlap, or the two planes differ (the daemon's centre is not the
    simulation's). Positions are compared in the plane (x_m, y_m): with the daemon's
    centre moved 0.2°, tracks 17 m from their aircraft on the ground scored 1,405 m,
    and another scenario's truth gave a table of n/a, both with exit 0. The planes are
    checked on the ground: each of up to 200 track positions against the truth nearest
    it at that time, by geodesic distance from their latitudes and longitudes, and by
    distance in the plane."""
    from radar_fusion.geo.coordinates import WGS84_GEOD

    t_batches = np.array([float(b["t"]) for b in batches])
    lo, hi = float(np.nanmin(truth.t_s)), float(np.nanmax(truth.t_s))
    if t_batches.max() < lo or t_batches.min() > hi:
        return (
            f"the tracks' times ({t_batches.min():.0f}-{t_batches.max():.0f} s) and the truth's "
            f"({lo:.0f}-{hi:.0f} s) do not overlap"
        )
    if not (np.isfinite(truth.lat_deg).any() and np.isfinite(truth.lon_deg).any()):
        return None
    ground, plane = [], []
    step = max(1, len(batches) // 20)
    for b in batches[::step]:
        t = float(b["t"])
        rows = [(tr["lat_deg"], tr["lon_deg"], tr["x_m"], tr["y_m"]) for tr in b.get("tracks", [])[:10]]
        if not rows or not lo <= t <= hi:
            continue
        near = np.flatnonzero(np.abs(truth.t_s - t) <= 0.5)  # the truth's rows of that second
        if near.size == 0:
            continue
        for lat, lon, x, y in rows:
            _, _, g = WGS84_GEOD.inv(
                np.full(near.size, lon), np.full(near.size, lat), truth.lon_deg[near], truth.lat_deg[near]
            )
            k = int(np.nanargmin(g))
            ground.append(float(g[k]))
            plane.append(float(np.hypot(x - truth.x_m[near[k]], y - truth.y_m[near[k]])))
    if len(ground) < 5:
        return None
    g_m, p_m = float(np.median(ground)), float(np.median(plane))
    if p_m > 3.0 * g_m + 500.0:
        return (
            f"the tracks' system plane is not the truth's: the tracks lie a median {g_m:,.0f} m from their nearest "
            f"aircraft on the ground but {p_m:,.0f} m in the plane (the daemon's centre is not the simulation's)"
        )
    return None


def run(args: argparse.Namespace) -> int:
    """Run ``radar-fusion evaluate``: print the table, optionally write PNG and JSON."""
    params = EvalParams(
        gate_m=args.gate_m,
        settle_s=args.settle_s,
        gospa_c_m=args.gospa_c_m,
        gospa_p=args.gospa_p,
        false_fraction=getattr(args, "false_fraction", EvalParams.false_fraction),
        keep_previous=getattr(args, "keep_previous", EvalParams.keep_previous),
    )
    batches = load_tracks(args.tracks)
    truth = load_truth(args.truth)
    if not batches:
        print(f"{args.tracks}: no {TRACKS_KEY} messages")
        return 1
    why = not_comparable(batches, truth)
    if why is not None:
        print(f"evaluate: {args.tracks} against {args.truth}: {why}; not scoring them", file=sys.stderr)
        return 2
    scores = evaluate(batches, truth, params)
    print(format_table(scores))
    if args.png:
        print(f"plot written to {plot(batches, truth, args.png, scores)}")
    if getattr(args, "json", None):
        Path(args.json).write_text(json.dumps(scores.summary(), indent=1))
    return 0


def main(argv: Iterable[str] | None = None) -> int:
    """Standalone entry point (``python -m radar_fusion.tools.evaluate``)."""
    parser = argparse.ArgumentParser(prog="radar-fusion evaluate", description=__doc__.split("\n")[0])
    add_arguments(parser)
    return run(parser.parse_args(list(argv) if argv is not None else None))


if __name__ == "__main__":
    raise SystemExit(main())
