"""The fusion engine: plots in, track batches and alerts out. No bus, no clock, no files.

Pipeline per radar batch (``ingest_plots``), cheap and constant per batch:
    semantic checks (unknown radar, duplicates, late/future, beyond range, buffer limit)
    → per-period buffer with event-time watermarks (period_buffer.py)

Pipeline per closed period (``poll``), all plots and all tracks at once in numpy arrays:
    live wild-plot gate per radar track, in time order (Hu 2013, outliers.py)
    → coordinate conversion to the system plane (coordinates.py)
    → Singer prediction of every track to the period's reference time (singer_filter.py)
    → time alignment + k-means clustering seeded by the tracks (clustering.py, Shu §2)
    → inverse-variance fusion of each cluster (fusion.py, Shu eq. 5-6)
    → Kalman update / two-point initiation / new tentative tracks (Shu eq. 7-11, §4)
    → track life cycle (track_management.py) → TrackColumns (→ TrackBatch on demand)
    → safety nets (safety_nets.py) → alerts

Gating and converting per period rather than per batch costs one vectorised pass over
the period's plots instead of a fixed overhead per batch (at 4,000 aircraft and 10
radars that overhead was three quarters of the engine's time).

The daemon (bus.py), the replay-driven tests and the benchmark all drive this class
the same way: ``ingest_plots`` / ``ingest_status`` as messages arrive, then ``poll``.
"""

from __future__ import annotations

import math
import time
from collections import Counter, deque
from dataclasses import dataclass, field
from functools import cached_property
from itertools import repeat
from typing import Any, Optional

import numpy as np
from threadpoolctl import threadpool_limits

from ..tracking.clustering import ClusteringParams, cluster_plots
from ..config import Settings
from ..geo.coordinates import RadarSites, SystemPlane, flight_level_to_altitude_m, polar_to_plane
from ..tracking.fusion import fuse_clusters
from ..tracking.live_gate import LiveOutlierGate
from .columns import ConvertedPlots, PlotChunk, RadarNames, TrackColumns
from .period_buffer import PeriodBuffer
from ..tracking.singer_filter import DEFAULT_ALPHA_PER_S, DEFAULT_SIGMA_M_MPS2, AltitudeFilter, SingerFilter, inv_2x2
from ..tracking.track_management import (
    CONFIRMED,
    STATUS_NAMES,
    LifeCycle,
    TrackTable,
    apply_life_cycle,
    cov_pos_m2,
    cov_vel,
    position_m,
    velocity_mps,
)
from ..geo.units import FT_PER_FL, M_PER_FT
from ..wire import DecodedPlots, RadarStatus, mode_s_to_str

#: consecutive batches of a radar refused whole as too far in the future after which its
#: new time base is accepted (a radar back from an outage longer than the future limit)
FUTURE_RELOCK_BATCHES = 8


@dataclass
class PeriodOutput:
    """What one closed period produced: every track as columns, and alerts.

    ``track_batch`` is the TrackBatch message (a wire-contract dict), built from the
    columns on first use: that is the I/O side's work (the daemon builds and encodes it
    on its worker thread right after the period), not the engine's, and ``processing_s``
    does not include it. ``radar-fusion bench`` reports both figures.
    """

    period: int
    t_s: float
    track_columns: "TrackColumns"
    alerts: list[dict[str, Any]] = field(default_factory=list)
    processing_s: float = 0.0
    n_plots: int = 0

    @cached_property
    def track_batch(self) -> dict[str, Any]:
        return self.track_columns.to_message()


@dataclass
class RadarState:
    last_seq: Optional[int] = None
    recent_seqs: deque = field(default_factory=lambda: deque(maxlen=4096))
    recent_set: set = field(default_factory=set)
    plots: int = 0
    batches: int = 0
    seq_gaps: int = 0
    out_of_order: int = 0
    rejected: Counter = field(default_factory=Counter)
    rotation_period_s: Optional[float] = None
    wild: int = 0
    future_streak: int = 0  # consecutive batches refused whole as plot_future


class Engine:
    """Sans-I/O multi-radar fusion engine (DESIGN.md §2)."""

    def __init__(self, settings: Settings, safety_nets: Any = None):
        # One BLAS thread: the engine's linear algebra is thousands of tiny matrices, for
        # which OpenBLAS's worker threads only contend (measured on 2 cores: a
        # (6×30)·(30×4,000) product takes 0.19 ms on one thread, 2.4 ms on two).
        threadpool_limits(limits=1, user_api="blas")
        self.settings = settings
        sysc, trk = settings.system, settings.tracking
        self.radar_ids = [r.id for r in settings.radars]
        if len(self.radar_ids) > 64:
            raise ValueError("at most 64 radars (sources are a 64-bit mask)")
        self.radar_index = {rid: i for i, rid in enumerate(self.radar_ids)}
        self.max_range_m = np.array([r.max_range_m for r in settings.radars])
        self.plane = SystemPlane(sysc.center_lat, sysc.center_lon)
        self.sites = RadarSites.from_configs(settings.radars)
        self.filter = SingerFilter(
            alpha_per_s=trk.alpha_per_s or DEFAULT_ALPHA_PER_S, sigma_m_mps2=trk.sigma_m_mps2 or DEFAULT_SIGMA_M_MPS2
        )
        self.alt_filter = AltitudeFilter()
        self.rules = LifeCycle(
            confirm_updates=trk.confirm_updates,
            confirm_window_s=trk.confirm_window_s,
            coast_after_scans=trk.coast_after_scans,
            delete_tentative_after_scans=trk.delete_tentative_after_scans,
            delete_after_scans=trk.delete_after_scans,
            coast_after_s=trk.coast_after_s,
            delete_tentative_after_s=trk.delete_tentative_after_s,
            delete_after_s=trk.delete_after_s,
        )
        self.rotation_s = np.array([r.rotation_period_s for r in settings.radars])
        self.clustering = ClusteringParams(
            gate_chi2=trk.gate_chi2, new_target_gate_m=trk.new_target_gate_m, max_speed_mps=trk.max_speed_mps
        )
        self.assumed_altitude_m = trk.assumed_altitude_ft * M_PER_FT
        # how far past the newest watermark an event time may lie (see _future_limit_s)
        self.future_margin_s = min(sysc.max_future_s, sysc.radar_timeout_s)
        self.manoeuvre_sigma_factor = trk.manoeuvre_sigma_factor
        self.manoeuvre_on, self.manoeuvre_off = trk.manoeuvre_nis_on, trk.manoeuvre_nis_off
        self.nis_fading = trk.manoeuvre_nis_fading
        # wide velocity prior of a one-plot track: uniform speed up to max_speed per axis
        self.one_plot_vel_var = trk.max_speed_mps**2 / 3.0
        out = settings.outliers
        self.outlier_gate = (
            LiveOutlierGate(window=out.window, k=out.k, threshold=out.threshold, relock_after=out.relock_after)
            if out.enabled
            else None
        )
        self.buffer = PeriodBuffer(
            period_s=sysc.period_s,
            allowed_lateness_s=sysc.allowed_lateness_s,
            radar_timeout_s=sysc.radar_timeout_s,
            n_radars=len(self.radar_ids),
            max_plots_per_radar=sysc.max_buffered_plots_per_radar,
        )
        self.tracks = TrackTable()
        self.track_t_s: Optional[float] = None  # reference time of the newest closed period
        self.radars = [RadarState() for _ in self.radar_ids]
        self.counters: Counter = Counter()
        self.rejected: Counter = Counter()
        self.safety_nets = safety_nets
        self.periods_closed = 0
        self.processing_s: deque = deque(maxlen=1000)
        self._names = RadarNames(self.radar_ids, self.plane)

    # ================================================================== input
    def reject(self, reason: str, n: int = 1, radar_id: Optional[str] = None) -> None:
        """Count ``n`` rejections (also those the codec made before the engine saw them)."""
        if n <= 0:
            return
        self.rejected[reason] += n
        if radar_id in self.radar_index:
            self.radars[self.radar_index[radar_id]].rejected[reason] += n

    def ingest_status(self, status: RadarStatus) -> None:
        i = self.radar_index.get(status.radar_id)
        if i is None:
            self.reject("unknown_radar")
            return
        radar = self.radars[i]
        if status.t > self._future_limit_s(i) and radar.future_streak < FUTURE_RELOCK_BATCHES:
            self.reject("status_future", radar_id=status.radar_id)
            radar.future_streak += 1
            return
        radar.future_streak = 0
        self.counters["status_messages"] += 1
        if status.rotation_period_s is not None:
            self.radars[i].rotation_period_s = status.rotation_period_s
        self.buffer.advance_watermark(i, status.t)

    def _future_limit_s(self, i: int) -> float:
        """Latest plausible event time from radar ``i``; later is refused as
        ``plot_future``. A clock jump or a forged time must not push a watermark ahead:
        beyond ``radar_timeout_s`` past the others it would make them all look silent,
        close every period on this radar alone and turn their good plots late.

        The limit is the newest watermark of all radars (this one included) plus
        min(max_future_s, radar_timeout_s): a radar's time advances by about a rotation
        per rotation, and one back from an outage is in step with the others again. A
        radar with no other radar to follow that comes back after a longer outage is
        re-locked by :meth:`ingest_plots` after ``FUTURE_RELOCK_BATCHES`` batches.
        """
        newest = float(self.buffer.watermark_s.max())
        return newest + self.future_margin_s if math.isfinite(newest) else math.inf

    def ingest_plots(self, batch: DecodedPlots) -> int:
        """Check, gate, convert and buffer one radar's batch; returns plots accepted."""
        self.counters["batches_received"] += 1
        for reason, n in batch.rejected.items():
            self.reject(reason, n, batch.radar_id)
        i = self.radar_index.get(batch.radar_id)
        if i is None:
            self.reject("unknown_radar", 1)
            return 0
        radar = self.radars[i]
        if batch.seq in radar.recent_set:
            self.reject("duplicate", 1, batch.radar_id)
            return 0
        if len(radar.recent_seqs) == radar.recent_seqs.maxlen:
            radar.recent_set.discard(radar.recent_seqs[0])
        radar.recent_seqs.append(batch.seq)
        radar.recent_set.add(batch.seq)
        if radar.last_seq is None or batch.seq > radar.last_seq:
            if radar.last_seq is not None and batch.seq > radar.last_seq + 1:
                radar.seq_gaps += batch.seq - radar.last_seq - 1
            radar.last_seq = batch.seq
        else:
            radar.out_of_order += 1
            self.counters["batches_out_of_order"] += 1
        radar.batches += 1
        n_in = len(batch)
        if n_in == 0:
            return 0
        self.counters["plots_received"] += n_in
        buf = self.buffer
        t_s, range_m = batch.t_s, batch.range_m
        t_min_s, t_max_s = float(t_s.min()), float(t_s.max())
        closed_s, future_s = buf.closed_until_s, self._future_limit_s(i)
        if not math.isfinite(buf.watermark_s[i]):  # a first batch: also against its own start
            future_s = min(future_s, t_min_s + self.future_margin_s)
        if radar.future_streak >= FUTURE_RELOCK_BATCHES:
            # This radar's time has stayed ahead, consistently: it came back after an
            # outage (or its clock was set right); follow it from this batch on.
            future_s = math.inf
            radar.future_streak = 0
            self.counters["radar_time_relocks"] += 1
        if t_min_s >= closed_s and t_max_s <= future_s and float(range_m.max()) <= self.max_range_m[i]:
            idx = slice(None)  # the usual case: the whole batch is good (no copies)
            n_ok = n_in
            radar.future_streak = 0
        else:
            keep = range_m <= self.max_range_m[i]
            self.reject("plot_beyond_max_range", n_in - int(keep.sum()), batch.radar_id)
            late = t_s < closed_s
            self.reject("plot_late", int((late & keep).sum()), batch.radar_id)
            keep &= ~late
            future = t_s > future_s
            self.reject("plot_future", int((future & keep).sum()), batch.radar_id)
            keep &= ~future
            idx = np.flatnonzero(keep)
            n_ok = int(idx.size)
            radar.future_streak = radar.future_streak + 1 if n_ok == 0 and future.any() else 0
            if n_ok == 0:
                return 0
            t_min_s, t_max_s = float(t_s[idx].min()), float(t_s[idx].max())
        room = buf.room(i)
        if n_ok > room:
            # Bounded memory: a radar far ahead of the others (or flooding) may not fill
            # the buffer without limit. The earliest plots are kept.
            self.reject("buffer_full", n_ok - max(room, 0), batch.radar_id)
            buf.advance_watermark(i, t_max_s)  # valid plots: the radar's time has moved on
            if room <= 0:
                return 0
            idx = (np.arange(n_in) if isinstance(idx, slice) else idx)[np.argsort(t_s[idx], kind="stable")[:room]]
            n_ok = room
            t_min_s, t_max_s = float(t_s[idx].min()), float(t_s[idx].max())
        buf.add(
            PlotChunk(t_s[idx], range_m[idx], batch.azimuth_deg[idx], batch.fl[idx], np.full(n_ok, i, np.int64),
                      batch.mode_s[idx], batch.mode3a[idx], batch.track_no[idx]),
            i, t_min_s,
        )
        buf.advance_watermark(i, t_max_s)
        radar.plots += n_ok
        self.counters["plots_accepted"] += n_ok
        return n_ok

    def _gate_and_convert(self, raw: PlotChunk) -> ConvertedPlots:
        """The closing period's plots: the live wild-plot gate (Hu 2013, outliers.py) in
        time order per radar track, then conversion to the system plane
        (coordinates.py) — one vectorised pass over all radars."""
        if self.outlier_gate is not None and len(raw):
            keys = _track_keys(raw.radar, raw.track_no, raw.mode_s)
            has_key = np.flatnonzero(keys >= 0)
            if has_key.size:
                ok = self.outlier_gate.filter(keys[has_key], raw.t_s[has_key], raw.range_m[has_key],
                                              raw.azimuth_deg[has_key])
                if not ok.all():
                    wild = has_key[~ok]
                    self.counters["plots_wild"] += int(wild.size)
                    for r, n in zip(*np.unique(raw.radar[wild], return_counts=True)):
                        self.radars[int(r)].wild += int(n)
                    keep = np.ones(len(raw), bool)
                    keep[wild] = False
                    raw = raw.select(keep)
        altitude_m = flight_level_to_altitude_m(raw.fl)
        x_m, y_m, cov_m2, _ = polar_to_plane(
            self.plane, self.sites, raw.radar, raw.range_m, raw.azimuth_deg, altitude_m,
            assumed_altitude_m=self.assumed_altitude_m,
        )
        return ConvertedPlots(raw.t_s, x_m, y_m, cov_m2, raw.radar, raw.mode_s, raw.mode3a, raw.fl)

    # ================================================================= output
    def poll(self) -> list[PeriodOutput]:
        """Close every period the watermarks allow; returns their outputs in order."""
        outputs = []
        while True:
            if len(self.tracks) == 0:
                self.buffer.skip_empty_to_data()
            popped = self.buffer.pop_period()
            if popped is None:
                return outputs
            outputs.append(self._process_period(*popped))

    def flush(self) -> list[PeriodOutput]:
        """Close every period that holds buffered plots (at shutdown or end of a replay)."""
        outputs = self.poll()
        while self.buffer.buffered_plots:
            self.buffer.skip_empty_to_data()
            popped = self.buffer.pop_period(force=True)
            if popped is None:
                break
            outputs.append(self._process_period(*popped))
        return outputs

    # ============================================================== the period
    def _predict(self, x, P, alt_x, alt_P, dt_s, manoeuvre):
        """Singer prediction (Shu eq. 8, 11) over per-track ``dt_s``, with raised process
        noise for manoeuvring tracks: Q grows with σ_m² (Shu §4), so adding (k²−1)·Q gives
        the prediction of a Singer model whose σ_m is k times larger."""
        x, P = self.filter.predict(x, P, dt_s)
        if manoeuvre.any():
            q = self.filter.process_noise(np.broadcast_to(dt_s, manoeuvre.shape)[manoeuvre])
            P[manoeuvre] += (self.manoeuvre_sigma_factor**2 - 1.0) * q
        alt_x, alt_P = self.alt_filter.predict(alt_x, alt_P, dt_s)
        return x, P, alt_x, alt_P

    def _process_period(self, period: int, t_ref_s: float, raw: PlotChunk) -> PeriodOutput:
        """One period. Each track's state is kept at its own time (its latest update):
        it is predicted to the period's reference time for association and for output,
        and updated at the mean time of its own cluster's plots, so that a measurement is
        never moved in time with the very velocity it is meant to correct."""
        t0 = time.perf_counter()
        plots = self._gate_and_convert(raw)
        tracks = self.tracks
        # 1. Predict every track to the reference time: for association (Shu eq. 8, 11).
        ref = self._predict(tracks.x, tracks.P, tracks.alt_x, tracks.alt_P, t_ref_s - tracks.t_state_s,
                            tracks.manoeuvre)
        x_ref, P_ref = ref[0], ref[1]
        changed = np.empty(0, np.int64)  # rows updated or created in this period
        sources_mask = np.zeros(len(tracks), np.uint64)
        n_new = 0

        if len(plots):
            # 2. Time alignment and clustering seeded by the tracks (Shu §2).
            xy = np.stack([plots.x_m, plots.y_m], axis=1)
            res = cluster_plots(
                xy, plots.cov_m2, plots.t_s, plots.radar, plots.mode_s, plots.mode3a,
                position_m(x_ref), velocity_mps(x_ref), cov_pos_m2(P_ref), cov_vel(P_ref),
                tracks.mode_s, tracks.mode3a, t_ref_s, self.clustering,
            )
            n_clusters = len(res.cluster_track)
            self.counters["plots_redundant"] += int(res.redundant.sum())
            self.counters["plots_unused"] += int(((res.labels < 0) & ~res.redundant).sum())
            used = res.labels >= 0
            lab = res.labels[used]
            n_in = np.bincount(lab, minlength=n_clusters)
            valid = n_in > 0
            # 3. Each cluster's measurement time: the mean time of its plots. Plots are
            #    aligned to it (a one-plot cluster needs no alignment at all) with the
            #    track's velocity, or none for a new target (Shu §2, 时空对准).
            t_c = np.bincount(lab, weights=plots.t_s[used], minlength=n_clusters) / np.maximum(n_in, 1)
            row_of_plot = res.cluster_track[lab]
            dt_p = t_c[lab] - plots.t_s[used]
            # a padding row (-1) stands for "no track": zero velocity, wide velocity prior
            v_pad = np.concatenate([velocity_mps(x_ref), np.zeros((1, 2))])
            pvv_pad = np.concatenate([cov_vel(P_ref), self.one_plot_vel_var * np.eye(2)[None]])
            v, p_vv = v_pad[row_of_plot], pvv_pad[row_of_plot]
            z_plot = xy[used] + v * dt_p[:, None]
            R_plot = plots.cov_m2[used] + dt_p[:, None, None] ** 2 * p_vv
            # 4. Fuse each cluster (Shu eq. 5-6 or its full-covariance form).
            z_m, R_m2, _ = fuse_clusters(lab, z_plot, R_plot, n_clusters, self.settings.tracking.fusion_method)
            fl_sum = np.bincount(lab, weights=np.nan_to_num(plots.fl[used]), minlength=n_clusters)
            fl_n = np.bincount(lab, weights=np.isfinite(plots.fl[used]).astype(float), minlength=n_clusters)
            cluster_fl = np.where(fl_n > 0, fl_sum / np.maximum(fl_n, 1), np.nan)
            cluster_mode_s = np.full(n_clusters, -1, np.int64)
            np.maximum.at(cluster_mode_s, lab, plots.mode_s[used])
            cluster_mode3a = np.full(n_clusters, -1, np.int64)
            np.maximum.at(cluster_mode3a, lab, plots.mode3a[used])
            cluster_revisit_s = np.full(n_clusters, np.inf)
            np.minimum.at(cluster_revisit_s, lab, self.rotation_s[plots.radar[used]])
            cluster_sources = np.zeros(n_clusters, np.uint64)
            np.bitwise_or.at(cluster_sources, lab, np.left_shift(np.uint64(1), plots.radar[used].astype(np.uint64)))

            # 5a. Clusters of existing tracks: predict each to its cluster's time, then the
            #     Kalman update (Shu eq. 7, 9, 10) or the two-point initiation (§4).
            matched = np.flatnonzero(valid & (res.cluster_track >= 0))
            rows = res.cluster_track[matched]
            if rows.size:
                x_c, P_c, ax_c, aP_c = self._predict(
                    tracks.x[rows], tracks.P[rows], tracks.alt_x[rows], tracks.alt_P[rows],
                    t_c[matched] - tracks.t_state_s[rows], tracks.manoeuvre[rows],
                )
                init = tracks.initiated[rows]
                if init.any():
                    x, P, nu, S = self.filter.update(x_c[init], P_c[init], z_m[matched[init]], R_m2[matched[init]])
                    x_c[init], P_c[init] = x, P
                    self._detect_manoeuvres(rows[init], nu, S)
                two = ~init
                if two.any():
                    x, P = self.filter.initiate(
                        tracks.z1_m[rows[two]], tracks.R1_m2[rows[two]], z_m[matched[two]], R_m2[matched[two]],
                        t_c[matched[two]] - tracks.t_state_s[rows[two]],
                    )
                    x_c[two], P_c[two] = x, P
                    tracks.initiated[rows[two]] = True
                tracks.x[rows], tracks.P[rows] = x_c, P_c
                tracks.alt_x[rows], tracks.alt_P[rows] = self.alt_filter.update(ax_c, aP_c, cluster_fl[matched])
                tracks.t_state_s[rows] = t_c[matched]
                tracks.updates[rows] += 1
                tracks.last_update_t_s[rows] = t_ref_s
                ms = cluster_mode_s[matched]
                tracks.mode_s[rows] = np.where(ms >= 0, ms, tracks.mode_s[rows])
                m3 = cluster_mode3a[matched]
                tracks.mode3a[rows] = np.where(m3 >= 0, m3, tracks.mode3a[rows])
                sources_mask[rows] = cluster_sources[matched]
                tracks.revisit_s[rows] = cluster_revisit_s[matched]
                changed = rows

            # 5b. Clusters no track claims: new tentative tracks (Shu §2 cases 1 and 3),
            #     holding their one fused measurement and a wide velocity prior.
            new_cl = np.flatnonzero(valid & (res.cluster_track < 0))
            n_new = int(new_cl.size)
            if n_new:
                new = tracks.append(n_new)
                changed = np.concatenate([changed, np.arange(new.start, new.stop)])
                x = np.zeros((n_new, 6))
                x[:, 0], x[:, 3] = z_m[new_cl, 0], z_m[new_cl, 1]
                P = np.zeros((n_new, 6, 6))
                P[:, 0, 0], P[:, 0, 3] = R_m2[new_cl, 0, 0], R_m2[new_cl, 0, 1]
                P[:, 3, 0], P[:, 3, 3] = R_m2[new_cl, 1, 0], R_m2[new_cl, 1, 1]
                P[:, 1, 1] = P[:, 4, 4] = self.one_plot_vel_var
                P[:, 2, 2] = P[:, 5, 5] = self.filter.sigma_m_mps2**2
                tracks.x[new], tracks.P[new] = x, P
                tracks.t_state_s[new] = t_c[new_cl]
                tracks.z1_m[new], tracks.R1_m2[new] = z_m[new_cl], R_m2[new_cl]
                tracks.alt_x[new], tracks.alt_P[new] = self.alt_filter.initiate(cluster_fl[new_cl])
                tracks.updates[new] = 1
                tracks.first_t_s[new] = tracks.last_update_t_s[new] = t_ref_s
                tracks.mode_s[new] = cluster_mode_s[new_cl]
                tracks.mode3a[new] = cluster_mode3a[new_cl]
                tracks.revisit_s[new] = cluster_revisit_s[new_cl]
                sources_mask = np.concatenate([sources_mask, cluster_sources[new_cl]])
            self.counters["plots_fused"] += int(used.sum())
        tracks.sources = sources_mask
        self.counters["tracks_initiated"] += n_new
        self.track_t_s = t_ref_s

        # 6. Output: every track predicted to the period's reference time. A track that
        #    got no plot still has the state predicted in step 1; only the updated and
        #    the new ones are predicted again.
        out = [np.concatenate([a, np.empty((len(tracks) - len(a),) + a.shape[1:])]) for a in ref]
        if changed.size:
            pred = self._predict(tracks.x[changed], tracks.P[changed], tracks.alt_x[changed], tracks.alt_P[changed],
                                 t_ref_s - tracks.t_state_s[changed], tracks.manoeuvre[changed])
            for a, b in zip(out, pred):
                a[changed] = b
        # 7. Track life cycle: confirm, coast, end.
        ids = tracks.track_id
        ended = apply_life_cycle(tracks, t_ref_s, self.rules)
        self.counters["tracks_ended"] += int(ended.size)
        if ended.size:
            alive = ~np.isin(ids, ended)
            out = [a[alive] for a in out]
        columns = self._track_columns(period, t_ref_s, ended, out[0], out[1], out[2])
        alerts = self._safety_nets(columns) if self.safety_nets is not None else []
        dt = time.perf_counter() - t0
        self.processing_s.append(dt)
        self.periods_closed += 1
        self.counters["periods_closed"] += 1
        return PeriodOutput(period, t_ref_s, columns, alerts, dt, len(plots))

    def _detect_manoeuvres(self, rows: np.ndarray, nu: np.ndarray, S: np.ndarray) -> None:
        """Adaptive process noise (not in Shu 2007; a standard extension for ATC turns).

        A Singer filter tuned for the quiet flight that dominates en-route traffic
        (σ_m ≈ 2.5 m/s²) lags a rate-one turn at jet speed (≈ 10 m/s²). The normalised
        innovation squared νᵀS⁻¹ν is χ² with 2 dof (mean 2) while the model holds; its
        fading average rising above ``manoeuvre_on`` marks a manoeuvre, and the track is
        then predicted with σ_m multiplied by ``manoeuvre_sigma_factor`` until the
        average falls below ``manoeuvre_off``.
        """
        nis = np.einsum("ni,nij,nj->n", nu, inv_2x2(S), nu)
        tr = self.tracks
        avg = self.nis_fading * tr.nis_avg[rows] + (1.0 - self.nis_fading) * nis
        tr.nis_avg[rows] = avg
        man = tr.manoeuvre[rows]
        tr.manoeuvre[rows] = np.where(man, avg > self.manoeuvre_off, avg > self.manoeuvre_on)

    def _track_columns(self, period: int, t_ref_s: float, ended: np.ndarray, x, P, alt_x) -> "TrackColumns":
        tr = self.tracks
        return TrackColumns(
            period=period, t_s=t_ref_s, track_id=tr.track_id.copy(), status=tr.status.copy(), x=x,
            cov_xy=np.stack([P[:, 0, 0], P[:, 0, 3], P[:, 3, 3]], axis=1), fl=alt_x[:, 0].copy(),
            vrate_fpm=alt_x[:, 1] * FT_PER_FL * 60.0, sources=tr.sources.copy(), mode3a=tr.mode3a.copy(),
            mode_s=tr.mode_s.copy(), updates=tr.updates.copy(), age_s=t_ref_s - tr.first_t_s, ended=ended,
            names=self._names,
        )

    def _safety_nets(self, columns: TrackColumns) -> list[dict[str, Any]]:
        # the safety nets read the period's columns as they are (they judge every track
        # that is not tentative, see safety_nets.prediction.eligible)
        return self.safety_nets.update(columns.t_s, columns)

    # ================================================================= health
    def health(self) -> dict[str, Any]:
        """Counters and per-radar state for the health message (wire.Health fields)."""
        live = self.buffer.live_mask()
        radars = {}
        for i, rid in enumerate(self.radar_ids):
            r = self.radars[i]
            wm = self.buffer.watermark_s[i]
            radars[rid] = {
                "live": bool(live[i]), "watermark_t": float(wm) if math.isfinite(wm) else None,
                "plots": r.plots, "batches": r.batches, "last_seq": r.last_seq, "seq_gaps": r.seq_gaps,
                "rejected": dict(r.rejected), "wild": r.wild,
            }
        proc = np.array(self.processing_s) * 1e3
        counters = dict(self.counters)
        counters["tracks_confirmed"] = int((self.tracks.status == CONFIRMED).sum())
        counters["plots_buffered"] = self.buffer.buffered_plots
        if self.safety_nets is not None:  # its event counts, as safety_nets_<name>
            counters.update({f"safety_nets_{k}": int(v) for k, v in self.safety_nets.counters.items()})
        return {
            "counters": counters,
            "rejected": dict(self.rejected),
            "radars": radars,
            "periods_closed": self.periods_closed,
            "tracks": len(self.tracks),
            "processing_ms_p50": float(np.percentile(proc, 50)) if proc.size else None,
            "processing_ms_p99": float(np.percentile(proc, 99)) if proc.size else None,
            "newest_period_t": self.track_t_s,
        }


def _track_keys(radar: np.ndarray, track_no: np.ndarray, mode_s: np.ndarray) -> np.ndarray:
    """Key of a radar track for the wild-plot gate: radar × (track number, else Mode S)."""
    key = np.where(track_no >= 0, track_no, np.where(mode_s >= 0, mode_s + (1 << 33), -1))
    return np.where(key >= 0, (radar.astype(np.int64) << np.int64(40)) + key, -1)

