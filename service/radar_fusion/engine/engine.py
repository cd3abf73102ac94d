"""The fusion engine: plots in, track batches and alerts out. No bus, no clock, no files.

Per radar message (``ingest_plots`` / ``ingest_status``), cheap and constant per batch:
    clock check and admission (admission.py): unknown radar, duplicates, late / future,
    beyond range, buffer limit, each refusal counted
    → per-period buffer with event-time watermarks (period_buffer.py)

Per closed period (``poll``), all plots and all tracks at once in numpy arrays, one named
step each (``_process_period`` reads as this list):
    gate      live wild-plot gate per radar track, in time order (Hu 2013, live_gate.py),
              then conversion to the system plane (geo/coordinates.py)
    predict   every track to the period's reference time (Shu eq. 8, 11, singer_filter.py;
              raised noise while manoeuvring, manoeuvre.py), or with ``tracking.filter =
              "imm"`` the IMM's mixing and per-model prediction (imm.py)
    associate time alignment + k-means clustering seeded by the tracks (Shu §2, clustering.py;
              the gates and track clusters in association.py)
    fuse      inverse-variance fusion of each cluster at its own time (Shu eq. 5-6, fusion.py);
              the radars' registration learns from the clusters (registration.py)
    update    Kalman update of the tracks that got a cluster (Shu eq. 7, 9, 10), or their
              two-point initiation (Shu §4, initiation.py); manoeuvre detection (or the
              IMM's per-model update and mode probabilities); the registration learns from
              the quiet tracks' innovations, and each track's sensitivity to the radars'
              biases follows its update (registration.py, the two-stage section)
    initiate  new tentative tracks from the clusters no track claims (Shu §2 cases 1, 3)
    merge     tracks with one Mode S address become one, with the oldest id
    manage    the track life cycle: confirm, coast, end (track_management.py)
    output    TrackColumns at the reference time (→ TrackBatch on demand), safety nets
    follow    the registration's correction for the next period; every track moved by its
              change, as if its plots had all been corrected with the new estimate

Gating and converting per period rather than per batch costs one vectorised pass over
the period's plots instead of a fixed overhead per batch (at 4,000 aircraft and 10
radars that overhead was three quarters of the engine's time).

The daemon (bus.py), the replay-driven tests and the benchmark all drive this class
the same way: ``ingest_plots`` / ``ingest_status`` as messages arrive, then ``poll``.
Process-wide settings (one BLAS thread, the garbage collector) belong to the process's
entry point (cli.py), not here.
"""

from __future__ import annotations

import math
import time
from collections import Counter, deque
from typing import Any

import numpy as np

from ..config import Settings
from ..geo.air_data import true_airspeed_mps
from ..geo.coordinates import (
    RadarSites,
    SystemPlane,
    ground_velocity_to_plane,
    mode_c_height_m,
    polar_to_plane,
)
from ..geo.units import FT_PER_FL, M_PER_FL, M_PER_FT
from ..geo.unknown_height import unknown_height_plots
from ..safety_nets import SafetyNets
from ..tracking import association, live_gate
from ..tracking import registration as reg_kernels
from ..tracking.clustering import ClusterResult, cluster_plots
from ..tracking.fusion import (
    consensus_outliers,
    contradicting_pairs,
    fuse_clusters,
    fuse_common_velocity,
    leave_one_out_outliers,
)
from ..tracking.imm import MANOEUVRE, QUIET, Evidence, IMMFilter, IMMState
from ..tracking.initiation import (
    floor_covariance,
    one_point_initiation,
    three_point_d2,
    two_point_initiation,
    unknown_velocity_var_m2ps2,
)
from ..tracking.live_gate import LiveOutlierGate, radar_track_keys
from ..tracking.manoeuvre import ManoeuvreDetector
from ..tracking.primary_height import primary_plot_altitude
from ..tracking.registration import RadarRegistration
from ..tracking.singer_filter import AltitudeFilter, SingerFilter, inv_2x2
from ..tracking.track_management import (
    CONFIRMED,
    TENTATIVE,
    AddressMemory,
    TrackTable,
    apply_life_cycle,
    cov_pos_m2,
    cov_vel,
    log_miss_probability,
    merge_same_address,
    position_m,
    radar_count,
    velocity_mps,
)
from ..wire import DecodedPlots, RadarStatus
from .admission import Admission, ClockCheck
from .columns import ClusterMeasurements, ConvertedPlots, PeriodOutput, PlotChunk, Prediction, RadarNames, TrackColumns
from .period_buffer import PeriodBuffer


def _mean_known(label: np.ndarray, values: np.ndarray, n: int) -> np.ndarray:
    """Per label 0..n-1, the mean of its finite values (NaN: none known), e.g. a cluster's
    Mode C flight level or Mode S roll angle from the plots that carry one."""
    known = np.bincount(label, weights=np.isfinite(values).astype(float), minlength=n)
    total = np.bincount(label, weights=np.nan_to_num(values), minlength=n)
    return np.where(known > 0, total / np.maximum(known, 1), np.nan)


class Engine:
    """Sans-I/O multi-radar fusion engine (DESIGN.md §2)."""

    def __init__(self, settings: Settings, safety_nets: SafetyNets | None = None):
        self.settings = settings
        sysc, trk = settings.system, settings.tracking
        self.radar_ids = [r.id for r in settings.radars]
        if len(self.radar_ids) > 64:
            raise ValueError("at most 64 radars (sources are a 64-bit mask)")
        self.radar_index = {rid: i for i, rid in enumerate(self.radar_ids)}
        self.plane = SystemPlane(sysc.center_lat, sysc.center_lon)
        self.sites = RadarSites.from_configs(settings.radars)
        self.site_xy_m = np.column_stack(self.sites.plane_positions(self.plane))
        self.rotation_s = np.array([r.rotation_period_s for r in settings.radars])
        self.max_range_m = np.array([r.max_range_m for r in settings.radars])
        self.pd = np.array([r.pd for r in settings.radars])
        self.filter = SingerFilter(alpha_per_s=trk.alpha_per_s, sigma_m_mps2=trk.sigma_m_mps2)
        self.alt_filter = AltitudeFilter()
        # filter = "imm": the IMM (imm.py) replaces the Singer filter's manoeuvre detector;
        # tr.x, tr.P then hold its combined estimate (eq. 7-8), the models their own columns
        self.imm = (
            IMMFilter(trk.imm, threads=trk.imm_threads) if trk.filter == "imm" else None
        )  # compiles its loops (imm.py)
        association.warm_up()  # the other compiled loops, now rather than in the first period
        live_gate.warm_up()
        self.manoeuvres = ManoeuvreDetector(
            sigma_factor=trk.manoeuvre_sigma_factor,
            nis_on=trk.manoeuvre_nis_on,
            nis_off=trk.manoeuvre_nis_off,
            nis_fading=trk.manoeuvre_nis_fading,
        )
        self.clustering = settings.clustering
        self.rules = settings.life_cycle
        self.address_memory = AddressMemory()
        self.assumed_altitude_m = trk.assumed_altitude_ft * M_PER_FT
        self.mode_c_met = trk.mode_c_met()  # the day's temperature and QNH, if configured
        self.mode_c_sigma_fraction = trk.mode_c_sigma_fraction()
        self.one_plot_vel_var_m2ps2 = unknown_velocity_var_m2ps2(self.clustering.max_speed_mps)
        self.outlier_gate = LiveOutlierGate.from_params(settings.outliers) if settings.outliers.enabled else None
        self.buffer = PeriodBuffer(
            period_s=sysc.period_s,
            allowed_lateness_s=sysc.allowed_lateness_s,
            radar_timeout_s=sysc.radar_timeout_s,
            n_radars=len(self.radar_ids),
            max_plots_per_radar=sysc.max_buffered_plots_per_radar,
            lateness_memory_s=sysc.lateness_memory_s,
        )
        self.counters: Counter[str] = Counter()
        self.rejected: Counter[str] = Counter()
        # how far past the newest watermark an event time may lie (Admission._future_limit_s)
        self.admission = Admission(
            self.radar_ids,
            np.array([r.max_range_m for r in settings.radars]),
            self.buffer,
            future_margin_s=min(sysc.max_future_s, sysc.radar_timeout_s),
            counters=self.counters,
            rejected=self.rejected,
        )
        self.radars = self.admission.radars
        self.registration = RadarRegistration(settings.registration, self.plane, self.sites)
        self._reg_applied = self.registration.correction()
        # the period's Mode S plots the live gate refused that carry a velocity (_gate)
        self._refused_velocity: PlotChunk | None = None
        self._reg_next_t_s = -math.inf
        self._reg_fed_t_s = -math.inf  # the period whose plots _register fed (its innovations too)
        self.clock = ClockCheck(len(self.radar_ids))
        # the two-stage registration (registration.py): each track's sensitivity to every
        # radar's biases, for its innovations and to follow the applied correction
        reg = settings.registration
        two_stage = reg.enabled and reg.track_innovations and len(self.radar_ids) > 1
        self.tracks = TrackTable(
            self.imm.n_models if self.imm is not None else 0, len(self.radar_ids) if two_stage else 0
        )
        if two_stage:
            reg_kernels.warm_up()
        # the wind shared by the aircraft of each layer (engine._air_velocity_and_wind): x, y
        # in the system plane, m/s, and the time of its latest samples; NaN: none yet
        n_layers = 1 + int(50_000.0 // (self.imm.params.wind_layer_ft if self.imm is not None else 50_000.0))
        self.layer_wind_mps = np.full((n_layers, 2), np.nan)
        self.layer_wind_t_s = np.full(n_layers, np.nan)
        self._layer_winds_t_s = -math.inf  # when _layer_winds last ran
        self.track_t_s: float | None = None  # reference time of the newest closed period
        self.safety_nets = safety_nets
        self.periods_closed = 0
        self.processing_s: deque[float] = deque(maxlen=1000)
        self._names = RadarNames(self.radar_ids, self.plane)

    # ================================================================== input
    def reject(self, reason: str, n: int = 1, radar_id: str | None = None) -> None:
        """Count ``n`` rejections (also those the codec or the bus made before the engine saw them)."""
        self.admission.reject(reason, n, radar_id)

    def ingest_status(self, status: RadarStatus) -> None:
        """A radar's north marker, sector crossing or heartbeat (moves its watermark)."""
        i = self.radar_index.get(status.radar_id)
        if i is not None:
            self.clock.observe(i, status.t, self.buffer.watermark_s)
        self.admission.admit_status(status)

    def ingest_plots(self, batch: DecodedPlots) -> int:
        """Check and buffer one radar's batch; returns the plots accepted."""
        i = self.radar_index.get(batch.radar_id)
        if i is not None and len(batch):
            self.clock.observe(i, float(batch.t_s.max()), self.buffer.watermark_s)
        return self.admission.admit_plots(batch)

    # ================================================================= output
    def poll(self) -> list[PeriodOutput]:
        """Close every period the watermarks allow; returns their outputs in order."""
        outputs: list[PeriodOutput] = []
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
    def _process_period(self, period: int, t_ref_s: float, raw: PlotChunk) -> PeriodOutput:
        """One period, as the named steps of the module docstring.

        Each track's state is kept at its own time (its latest update): it is predicted
        to the period's reference time for association and for output, and updated at the
        mean time of its own cluster's plots, so that a measurement is never moved in time
        with the very velocity it is meant to correct.
        """
        t0 = time.perf_counter()
        pred = self._predict(t_ref_s)
        plots = self._gate(raw, pred, t_ref_s)
        changed = np.empty(0, np.int64)  # rows updated or created in this period
        absorbed = np.empty(0, np.int64)  # rows whose plot another track now holds (_code_alternatives)
        self.tracks.sources = np.zeros(len(self.tracks), np.uint64)
        if len(plots):
            clusters = self._fuse(plots, self._associate(plots, pred, t_ref_s), pred, t_ref_s)
            self._refuse_impossible_pairs(clusters)
            self._hold_far(clusters)
            absorbed = self._code_alternatives(clusters)
            changed = np.concatenate([self._update(clusters, t_ref_s, pred), self._initiate(clusters, t_ref_s)])
        if self._refused_velocity is not None:
            changed = np.union1d(changed, self._update_velocity_of_refused())
        self.track_t_s = t_ref_s
        out = self._predict_changed(pred, changed, t_ref_s)
        out, merged = self._merge_identities(out, absorbed)
        ids = self.tracks.track_id.copy()  # the rows of ``out``, before the life cycle drops any
        ended = self._manage(t_ref_s)
        if ended.size:
            alive = ~np.isin(ids, ended)
            out = out.select(alive)
        columns = self._output(period, t_ref_s, np.concatenate([merged, ended]), out)
        self._follow_registration()
        # the safety nets judge every track that is not tentative (safety_nets.prediction.eligible)
        alerts = self.safety_nets.update(t_ref_s, columns) if self.safety_nets is not None else []
        dt = time.perf_counter() - t0
        self.processing_s.append(dt)
        self.periods_closed += 1
        self.counters["periods_closed"] += 1
        return PeriodOutput(period, t_ref_s, columns, alerts, dt, len(plots))

    # ------------------------------------------------------------------ gate
    def _gate(self, raw: PlotChunk, pred: Prediction, t_ref_s: float) -> ConvertedPlots:
        """The closing period's plots: the live wild-plot gate (Hu 2013, live_gate.py) in
        time order per radar track, then conversion to the system plane
        (geo/coordinates.py) — one vectorised pass over all radars.

        A plot without Mode C (a primary plot) is converted at the predicted altitude of the
        track it may belong to (primary_height.py; issue 15: converted at a guessed height,
        the plots of a high aircraft missed its track and started a shadow track beside it);
        with no such track, at the configured assumed height, its covariance split in the
        measurement noise (``cov_m2``) and the spread of its ground range over every height
        from the ground to FL450 (``height_cov_m2``, geo.unknown_height.unknown_height_plots).
        The spread is common to all plots of one aircraft from one radar: a track made of
        such plots filters with the noise and keeps the spread as the floor of its position
        covariance (``_floor_no_height``), so the aircraft's first plot with a height (an
        SSR's) joins it rather than start a second track; a cluster mixing both kinds fuses
        with the spread added. (Spreading every such plot's covariance over the heights,
        polar_to_plane_unknown_height, was measured on the demo: 85 -> 98 m position RMS,
        its wide radial gates letting clutter in.)"""
        # registration (registration.py): each radar's estimated biases (``_reg_applied``, taken
        # at the end of the previous period, _follow_registration) are removed from the plots
        # below (and from those the live gate refuses, _track_expects)
        if self.outlier_gate is not None and len(raw):
            keys = radar_track_keys(raw.radar, raw.track_no, raw.mode_s)
            has_key = np.flatnonzero(keys >= 0)
            if has_key.size:
                radar = raw.radar[has_key]
                ok = self.outlier_gate.filter(
                    keys[has_key],
                    raw.t_s[has_key],
                    raw.range_m[has_key],
                    raw.azimuth_deg[has_key],
                    self.sites.sigma_range_m[radar],
                    self.sites.sigma_azimuth_rad[radar],
                    self.rotation_s[radar],
                )
                wild = has_key[~ok]
                if wild.size:  # a track of the plot's identity may expect it (a turn the gate cannot see)
                    expected = self._track_expects(raw, wild, pred, t_ref_s)
                    self.counters["plots_wild_overruled"] += int(expected.sum())
                    wild = wild[~expected]
                if wild.size:
                    self.counters["plots_wild"] += int(wild.size)
                    self._address_seen(raw.mode_s[wild], raw.t_s[wild])
                    for r, n in zip(*np.unique(raw.radar[wild], return_counts=True)):
                        self.radars[int(r)].wild += int(n)
                    keep = np.ones(len(raw), bool)
                    keep[wild] = False
                    self._refused_velocity = self._refused_with_velocity(raw, ~keep)
                    raw = raw.select(keep)
        range_m, azimuth_deg, t_s = self.registration.correct(
            raw.radar, raw.range_m, raw.azimuth_deg, raw.t_s, bias=self._reg_applied
        )
        assert t_s is not None
        # a corrected time stays in its period: tracks are never predicted backwards
        t_s = np.clip(t_s, t_ref_s - self.settings.system.period_s, t_ref_s)
        altitude_m = mode_c_height_m(raw.fl, *self.mode_c_met)
        no_c = ~np.isfinite(altitude_m)
        if no_c.any() and len(self.tracks):
            pick = primary_plot_altitude(
                self.plane,
                self.sites,
                raw.radar,
                range_m,
                azimuth_deg,
                ~no_c,
                position_m(pred.x),
                mode_c_height_m(pred.alt_x[:, 0], *self.mode_c_met),
                cov_pos_m2(pred.P),
                track_velocity_mps=velocity_mps(pred.x),
                plot_dt_s=t_s - t_ref_s,
                track_altitude_var_m2=pred.alt_P[:, 0, 0] * M_PER_FL**2,
            )
            altitude_m = np.where(no_c, pick.altitude_m, altitude_m)
            self.counters["plots_primary_track_height"] += int(np.isfinite(altitude_m[no_c]).sum())
        x_m, y_m, cov_m2 = self._to_plane(raw.radar, range_m, azimuth_deg, altitude_m)
        # A primary plot (no Mode C, no identity) no track lends a height to: at the assumed
        # height, the noise in cov_m2 and the spread over every height apart
        # (geo/unknown_height.py). (At the mean ground range over every height instead, the
        # demo's primary-only FL120 aircraft and its Mode A-only FL200 one, seen by three
        # radars, went from 78 / 105 m to 915 / 629 m position RMS, the radars' means
        # disagreeing; the primary-high scenario's FL300-400 ones from 1,050-1,300 m to
        # 480-770 m.) An SSR plot without Mode C keeps the assumed height's covariance: with
        # the spread, that Mode A-only aircraft went to 551 m and the demo's GOSPA from 385
        # to 1,306 m.
        height_cov_m2 = np.zeros_like(cov_m2)
        no_h = np.flatnonzero(~np.isfinite(altitude_m) & (raw.mode3a < 0) & (raw.mode_s < 0))
        if no_h.size:
            u = unknown_height_plots(
                self.plane,
                self.sites,
                raw.radar[no_h],
                range_m[no_h],
                azimuth_deg[no_h],
                reference_altitude_m=self.assumed_altitude_m,
            )
            x_m[no_h], y_m[no_h], cov_m2[no_h], height_cov_m2[no_h] = u.x_m, u.y_m, u.cov_noise_m2, u.cov_height_m2
        # raw.fl stays NaN: the altitude filter is never updated with its own prediction
        return ConvertedPlots(
            t_s,
            x_m,
            y_m,
            cov_m2,
            raw.radar,
            raw.mode_s,
            raw.mode3a,
            raw.fl,
            range_m,
            azimuth_deg,
            altitude_m,
            raw.roll_deg,
            raw.ground_speed_mps,
            raw.track_angle_deg,
            height_cov_m2,
            raw.magnetic_heading_deg,
            raw.indicated_airspeed_mps,
        )

    def _to_plane(
        self, radar: np.ndarray, range_m: np.ndarray, azimuth_deg: np.ndarray, altitude_m: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Plots (registration-corrected range and azimuth, height) -> plane position and
        covariance (geo/coordinates.polar_to_plane), with the configured assumed height for
        plots without one and the Mode C height's error (``mode_c_sigma_fraction``)."""
        x_m, y_m, cov_m2, _ = polar_to_plane(
            self.plane,
            self.sites,
            radar,
            range_m,
            azimuth_deg,
            altitude_m,
            assumed_altitude_m=self.assumed_altitude_m,
            sigma_known_altitude_fraction=self.mode_c_sigma_fraction,
        )
        return x_m, y_m, cov_m2

    def _address_seen(self, mode_s: np.ndarray, t_s: np.ndarray) -> None:
        """Plots refused as wild (the live gate, a consensus outlier) that carry the Mode S
        address of a track: the aircraft replied to that radar, which has not missed it. Their
        time is the track's ``address_seen_t_s``, which :meth:`_manage`'s early end counts as
        seen (1,000×10 with 3 % wild plots: a 6 s radar's aircraft whose two plots in three
        scans were wild and the one between missed lost its track, shown again 8 s later)."""
        tr = self.tracks
        plot, row = association.address_pairs(mode_s, np.ones(mode_s.size, bool), tr.mode_s, np.ones(len(tr), bool))
        np.fmax.at(tr.address_seen_t_s, row, t_s[plot])

    def _track_expects(self, raw: PlotChunk, idx: np.ndarray, pred: Prediction, t_ref_s: float) -> np.ndarray:
        """Of the plots ``idx`` the live gate refused, those a track of their identity expects:
        inside ``gate_chi2`` of its prediction (aligned to the period's time with its
        velocity, association.align_to_reference): where it is established, of any of its IMM
        models but the manoeuvre model, whose gate at a 12 s scan spans kilometres (through it
        a plot 2 km off was taken in straight flight, and in a turn lost the track); where it
        is tentative, of its combined prediction (:meth:`_gate_models`). The identity: the
        plot's Mode S address; without one, its identity code (Mode 3/A, not an emergency or
        conspicuity code) on a track without an address. The gate sees one radar's recent
        plots and no turn until it has refused one: a 12 s radar's aircraft 27 s into a
        1.5°/s turn was 1.2 km off its straight window, refused at 6.5 noise scales, and its
        SSR-only track, 24 s without a plot, was lost (4,000×10, A00981: 19 % of the turning
        error). Measured over every refusal (4,000×10 60 s; 1,000×10 120 s with 3 % wild
        plots, seeds 0 and 2): of the good plots refused 28 of 29, 41 of 42 and 44 of 44 lie in
        such a gate, of the wild ones 0 of 143, 6 of 1,340 and 7 of 1,374. (K,) bool."""
        out = np.zeros(idx.size, bool)
        tr = self.tracks
        if not len(tr) or not idx.size:
            return out
        ms, code = raw.mode_s[idx], raw.mode3a[idx]
        by_address = (ms[:, None] >= 0) & (ms[:, None] == tr.mode_s[None, :])
        by_code = (
            (ms[:, None] < 0)
            & association.is_identity_code(code)[:, None]
            & (code[:, None] == tr.mode3a[None, :])
            & (tr.mode_s[None, :] < 0)
        )
        k, rows = np.nonzero(by_address | by_code)
        if not k.size:
            return out
        i = idx[k]
        range_m, azimuth_deg, t_s = self.registration.correct(
            raw.radar[i], raw.range_m[i], raw.azimuth_deg[i], raw.t_s[i], bias=self._reg_applied
        )
        assert t_s is not None
        x_m, y_m, cov_m2 = self._to_plane(
            raw.radar[i], range_m, azimuth_deg, mode_c_height_m(raw.fl[i], *self.mode_c_met)
        )
        z, R = association.align_to_reference(
            np.column_stack([x_m, y_m]), cov_m2, t_s, t_ref_s, velocity_mps(pred.x[rows]), cov_vel(pred.P[rows])
        )
        models = self._gate_models(pred)
        if models is None:
            xy, cov = position_m(pred.x[rows])[:, None, :], cov_pos_m2(pred.P[rows])[:, None]
        else:
            turns = np.arange(models[0].shape[1]) != MANOEUVRE
            xy, cov = models[0][rows][:, turns], models[1][rows][:, turns]
        y = z[:, None, :] - xy
        S = cov + R[:, None]
        d2 = association.mahalanobis2_2x2(y.reshape(-1, 2), S.reshape(-1, 2, 2)).reshape(y.shape[:2]).min(axis=1)
        np.logical_or.at(out, k, d2 <= self.clustering.gate_chi2)
        return out

    # --------------------------------------------------------------- predict
    def _predict_rows(self, rows: Any, dt_s: np.ndarray) -> Prediction:
        """Singer and altitude prediction of the tracks ``rows`` over per-track ``dt_s``
        (Shu eq. 8, 11), with raised process noise for the manoeuvring ones; with the IMM,
        its mixing and per-model prediction (imm.py eq. 1-4), x and P their combination."""
        tr = self.tracks
        gate_xy = gate_cov = None
        if self.imm is not None:
            # what association and fusion read: each model's position and its covariance (the
            # gates), the combined position and velocity (imm.IMMFilter.predict_gate)
            state = IMMState(tr.x_models[rows], tr.P_models[rows], tr.mu[rows])
            x, P, gate_xy, gate_cov = self.imm.predict_gate(state, dt_s)
        else:
            x, P = self.manoeuvres.predict(self.filter, tr.x[rows], tr.P[rows], dt_s, tr.manoeuvre[rows])
        alt_x, alt_P = self.alt_filter.predict(tr.alt_x[rows], tr.alt_P[rows], dt_s)
        return Prediction(x, P, alt_x, alt_P, gate_xy, gate_cov)

    def _imm_initiate(self, rows: Any, x: np.ndarray, P: np.ndarray) -> None:
        """With the IMM, new (or two-point initiated) states x, P in every model, prior μ."""
        if self.imm is not None:
            st = self.imm.initiate(x, P)
            self.tracks.x_models[rows], self.tracks.P_models[rows], self.tracks.mu[rows] = (
                st.x_models,
                st.P_models,
                st.mu,
            )

    def _predict(self, t_ref_s: float) -> Prediction:
        """Every track predicted to the reference time, for association."""
        return self._predict_rows(slice(None), t_ref_s - self.tracks.t_state_s)

    def _predict_changed(self, pred: Prediction, changed: np.ndarray, t_ref_s: float) -> Prediction:
        """Every track at the reference time, for output: a track that got no plot keeps
        the state of ``_predict``; only the updated and the new ones are predicted again.
        The result's rows are the track table's. With the IMM, the rows predicted again
        hold P's x-y block only (imm.predict_position), NaN elsewhere: the output reads
        x and that block (TrackColumns.cov_xy), and nothing else reads this P."""
        n = len(self.tracks)
        out = [
            np.concatenate([a, np.empty((n - len(a),) + a.shape[1:])]) for a in (pred.x, pred.P, pred.alt_x, pred.alt_P)
        ]
        if changed.size:
            dt_s = t_ref_s - self.tracks.t_state_s[changed]
            if self.imm is not None:
                tr = self.tracks
                x, P = self.imm.predict_position_rows(IMMState(tr.x_models, tr.P_models, tr.mu), changed, dt_s)
                alt_x, alt_P = self.alt_filter.predict(tr.alt_x[changed], tr.alt_P[changed], dt_s)
                again = Prediction(x, P, alt_x, alt_P)
            else:
                again = self._predict_rows(changed, dt_s)
            for a, b in zip(out, (again.x, again.P, again.alt_x, again.alt_P)):
                a[changed] = b
        x, P, alt_x, alt_P = out
        return Prediction(x, P, alt_x, alt_P)

    # ------------------------------------------------------------- associate
    def _gate_models(self, pred: Prediction) -> tuple[np.ndarray, np.ndarray] | None:
        """With the IMM, each track's model-conditioned predicted positions and covariances
        for the gate (imm.py, "Gating"): an established track (confirmed or coasting) takes
        a plot that any of its models expects, so that the second scan into a turn still
        joins it; a tentative track gates on its combined prediction only, so that clutter
        does not confirm it (with every track's models, the primary-high scenario confirmed
        a clutter track in 2 of its 3 test seeds)."""
        if pred.gate_xy is None or pred.gate_cov is None:
            return None
        xy, cov = pred.gate_xy, pred.gate_cov
        young = np.flatnonzero(self.tracks.status == TENTATIVE)
        xy[young] = position_m(pred.x[young])[:, None, :]
        cov[young] = cov_pos_m2(pred.P[young])[:, None]
        return xy, cov

    def _associate(self, plots: ConvertedPlots, pred: Prediction, t_ref_s: float) -> ClusterResult:
        """Time alignment and k-means clustering seeded by the tracks (Shu §2); a plot with a
        live track's Mode S address goes to that track (association.identity_pairs)."""
        tr = self.tracks
        res = cluster_plots(
            plots.xy_m,
            plots.cov_m2,
            plots.t_s,
            plots.radar,
            plots.mode_s,
            plots.mode3a,
            position_m(pred.x),
            velocity_mps(pred.x),
            cov_pos_m2(pred.P),
            cov_vel(pred.P),
            tr.mode_s,
            tr.mode3a,
            t_ref_s,
            self.clustering,
            track_last_xy_m=position_m(tr.x),
            track_last_cov_m2=cov_pos_m2(tr.P),
            track_last_t_s=tr.t_state_s,
            track_velocity_known=tr.velocity_known,
            track_models=self._gate_models(pred),
            track_alt=self._alternatives(),
        )
        self.counters["plots_redundant"] += int(res.redundant.sum())
        self.counters["plots_unused"] += int(((res.labels < 0) & ~res.redundant).sum())
        return res

    def _alternatives(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None:
        """The measurement a one-plot track holds beside its own from its own radars' previous
        scan (``held_*`` at or before its state's time, of the state's radars:
        track_management.merge_same_address), with the time after it within which it is kept
        (``far_hold_scans`` revisit times, as :meth:`_hold_far` keeps it); None when no track
        holds one. The aircraft's next plot joins the track when within reach of either, since
        one of the two is wild (association.reach_either); :meth:`_hold_far` then pairs it with
        the one it reaches. Alternatives of other radars (two one-plot tracks of one period) are
        left out: their next plots choose only when they reach the state, as before."""
        tr = self.tracks
        if not self.clustering.far_hold or not len(tr):
            return None
        alt = tr.held_alternative & ~tr.velocity_known & tr.held_own_radars
        if not alt.any():
            return None
        window_s = self.clustering.far_hold_scans * tr.revisit_s
        return tr.held_z_m, np.nan_to_num(tr.held_R_m2), np.where(alt, tr.held_t_s, np.nan), window_s

    # ------------------------------------------------------------------ fuse
    def _fuse(self, plots: ConvertedPlots, res: ClusterResult, pred: Prediction, t_ref_s: float) -> ClusterMeasurements:
        """One measurement per cluster, at the mean time of its plots (Shu eq. 5-6).

        Plots are aligned to that time (a one-plot cluster needs no alignment at all) with
        the velocity of the cluster's track (Shu §2, 时空对准). With the matrix fusion, a
        cluster without a velocity (a new target, a track of one update) is fused with the
        velocity its plots share estimated beside the position (fusion.fuse_common_velocity).
        """
        n_clusters = len(res.cluster_track)
        used = res.labels >= 0
        if plots.height_cov_m2 is not None and n_clusters:
            # A new target's primary plot without any height beside a plot with one adds
            # nothing the other does not know better, and, aligned in time with no velocity
            # (below), its height's error pulled the fused position by up to half its spread
            # (issue 15: ~430 m, then a two-point velocity off by 100s of m/s): left out.
            spread = np.trace(plots.height_cov_m2, axis1=1, axis2=2) > 0.0
            c = np.where(used, res.labels, 0)
            with_h = np.bincount(c[used & ~spread], minlength=n_clusters) > 0
            drop = used & spread & with_h[c] & (res.cluster_track[c] < 0)
            if drop.any():
                used = used & ~drop
                self.counters["plots_primary_left_out"] += int(drop.sum())
        # Without a velocity (a new target, or a track of one update) the plots are fused at
        # zero speed, so the fused position is where the aircraft was at the plots' mean time
        # weighted as the fusion weighs them (1/trace R): at their plain mean time instead,
        # a precise plot early and a coarse one late put it up to a second of flight off.
        no_v = np.ones(n_clusters, bool)
        has_track = res.cluster_track >= 0
        no_v[has_track] = ~self.tracks.velocity_known[res.cluster_track[has_track]]
        # a padding row (-1) stands for "no track": zero velocity, wide velocity prior
        v_pad = np.concatenate([velocity_mps(pred.x), np.zeros((1, 2))])
        pvv_pad = np.concatenate([cov_vel(pred.P), self.one_plot_vel_var_m2ps2 * np.eye(2)[None]])

        def align(used: np.ndarray) -> tuple[np.ndarray, ...]:
            lab = res.labels[used]
            n_in = np.bincount(lab, minlength=n_clusters)
            t_c = np.bincount(lab, weights=plots.t_s[used], minlength=n_clusters) / np.maximum(n_in, 1)
            if no_v.any():
                w = 1.0 / np.trace(plots.cov_m2[used], axis1=1, axis2=2)
                w_sum = np.bincount(lab, weights=w, minlength=n_clusters)
                t_w = np.bincount(lab, weights=w * plots.t_s[used], minlength=n_clusters) / np.where(
                    w_sum > 0, w_sum, 1
                )
                t_c = np.where(no_v & (w_sum > 0), t_w, t_c)
            row_of_plot = res.cluster_track[lab]
            dt_p = t_c[lab] - plots.t_s[used]
            v, p_vv = v_pad[row_of_plot], pvv_pad[row_of_plot]
            z_plot = plots.xy_m[used] + v * dt_p[:, None]
            R_plot = plots.cov_m2[used] + dt_p[:, None, None] ** 2 * p_vv
            return lab, n_in, t_c, row_of_plot, v, z_plot, R_plot

        lab, n_in, t_c, row_of_plot, v, z_plot, R_plot = align(used)
        # A cluster without a velocity has no prediction to gate its plots: of three plots or
        # more, the one the others contradict beyond the gate is a wild plot, dropped and
        # counted (fusion.leave_one_out_outliers); the rest are aligned again without it.
        gate_chi2 = self.clustering.gate_chi2
        wild = leave_one_out_outliers(lab, z_plot, R_plot, no_v, n_clusters, gate_chi2)
        if wild.any():
            self.counters["plots_new_target_outliers"] += int(wild.sum())
            used[np.flatnonzero(used)[wild]] = False
            lab, n_in, t_c, row_of_plot, v, z_plot, R_plot = align(used)
        # Two plots of one address in such a cluster that contradict each other: one is wild,
        # and two cannot tell which (fusion.contradicting_pairs); fused, the track starts
        # half the wild error off and its two-point velocity with it. Both are left out this
        # period, counted: the next period's plots start or continue the track. (A plot that
        # a track of one update could not reach from its first measurement is not in its
        # cluster: association's identity gate keeps it out.)
        if self.clustering.drop_contradicting_pairs:
            pair = contradicting_pairs(lab, z_plot, R_plot, plots.mode_s[used], no_v, n_clusters, gate_chi2)
            if pair.any():
                self.counters["plots_contradicting_pairs"] += int(pair.sum())
                used[np.flatnonzero(used)[pair]] = False
                lab, n_in, t_c, row_of_plot, v, z_plot, R_plot = align(used)
        # Two plots without a Mode S address (a code is reused, not an identity) in a cluster
        # without a velocity that contradict each other: as far as they can tell, two targets.
        # Fused, a wild plot beside a good one made a track half the wild error off that the
        # two radars confirmed at once (issue 15 item 7: 2.4 km, shown until it coasted out).
        # Split, each plot is a one-radar update: of a new target, two tentative tracks; of a
        # track of one update, the plot nearer its prediction stays and the other starts a
        # tentative track. A wild one ends unconfirmed, and two aircraft with one code that
        # share a cluster each keep a track.
        if self.clustering.split_contradicting_factor > 0:
            no_address = np.where(plots.mode_s[used] < 0, 0, -1)
            # a plot without any height: the spread of its ground range over every height too
            R_test = R_plot if plots.height_cov_m2 is None else R_plot + plots.height_cov_m2[used]
            split_chi2 = self.clustering.split_contradicting_factor * gate_chi2
            pair = contradicting_pairs(lab, z_plot, R_test, no_address, no_v, n_clusters, split_chi2)
            if pair.any():
                p = np.flatnonzero(pair)
                p = p[np.argsort(lab[p], kind="stable")]
                first, second = p[0::2], p[1::2]
                # a track of one update keeps the plot nearer its prediction; the other starts a target
                d2 = res.plot_d2[used]
                swap = has_track[lab[first]] & (d2[first] > d2[second])
                second = np.where(swap, first, second)
                k = second.size
                res.labels[np.flatnonzero(used)[second]] = n_clusters + np.arange(k)
                res.cluster_track = np.concatenate([res.cluster_track, np.full(k, -1, res.cluster_track.dtype)])
                n_clusters += k
                no_v = np.concatenate([no_v, np.ones(k, bool)])
                has_track = np.concatenate([has_track, np.zeros(k, bool)])
                self.counters["plots_contradicting_split"] += 2 * k
                lab, n_in, t_c, row_of_plot, v, z_plot, R_plot = align(used)
        # A plot that joined from outside the gate of the track's combined prediction (by
        # its Mode S address, or inside an IMM turn model's gate) and that the cluster's
        # in-gate radars contradict is a wild plot, not a manoeuvre: dropped and counted
        # (fusion.consensus_outliers), by address or by model gate.
        outlier = consensus_outliers(
            lab, z_plot, R_plot, res.plot_d2[used] > self.clustering.suspect_chi2, n_clusters, self.clustering.gate_chi2
        )
        if outlier.any():
            self._address_seen(plots.mode_s[used][outlier], plots.t_s[used][outlier])
            by_address = int((plots.mode_s[used][outlier] >= 0).sum())
            self.counters["plots_identity_outliers"] += by_address
            self.counters["plots_model_gate_outliers"] += int(outlier.sum()) - by_address
            keep = ~outlier
            used[np.flatnonzero(used)[outlier]] = False
            lab, row_of_plot, v, z_plot, R_plot = lab[keep], row_of_plot[keep], v[keep], z_plot[keep], R_plot[keep]
            n_in = np.bincount(lab, minlength=n_clusters)
        # A plot that joined its track from outside the χ² gate of its combined prediction
        # (by its Mode S address, or inside an IMM turn model's gate) counts as if it lay on
        # the gate's edge (R scaled by d²/gate, a Huber-type bound): one wild
        # plot moves the track no more than a plot at the gate's edge would, while a genuine
        # manoeuvre pulls it scan after scan, and its NIS switches manoeuvre noise on.
        self._register(plots, res, used, lab, row_of_plot, z_plot, R_plot, v, t_ref_s)
        # every plot of the cluster far beyond every model's gate (_hold_far): such a cluster is
        # held, not fused, and keeps its plots' own noise (a two-point start may come of it)
        near = res.plot_d2_gate[used] <= self.clustering.far_gate_factor * self.clustering.gate_chi2
        if self.clustering.far_accel_mps2 > 0:
            near &= ~self._beyond_any_manoeuvre(res, used, row_of_plot, pred, plots.t_s[used])
        far = (np.bincount(lab, weights=near, minlength=n_clusters) == 0) & (n_in > 0) & has_track
        beyond = np.where(far[lab], 1.0, np.fmax(res.plot_d2[used] / self.clustering.gate_chi2, 1.0))
        R_plot = R_plot * beyond[:, None, None]
        R_own = plots.cov_m2[used] * beyond[:, None, None]  # the same, not aligned in time
        cluster_h_cov = self._height_spread(plots, res, used, lab, n_in, (R_plot, R_own), pred)
        z_m, R_m2, _ = fuse_clusters(lab, z_plot, R_plot, n_clusters, self.settings.tracking.fusion_method)
        # Without a velocity, the plots of a cluster taken at different times share one
        # unknown velocity, not one each: the position is estimated together with it and the
        # velocity marginalised out (fusion.fuse_common_velocity; the matrix form only). Its
        # covariance stays the one above, as if each plot had a velocity of its own: some
        # ten times the joint one, and what lets the track's next scans mend a first
        # position that a wild plot pulled, which two plots cannot tell from noise
        # (3 % wild plots, 50x3: velocity +20 % against +32 % with the joint covariance).
        joint = np.flatnonzero(no_v & (n_in > 1))
        if joint.size and self.settings.tracking.fusion_method == "matrix":
            compact = np.full(n_clusters, -1, np.intp)  # those clusters only, numbered 0..
            compact[joint] = np.arange(joint.size)
            sel = compact[lab] >= 0
            idx = np.flatnonzero(used)[sel]
            z_m[joint], _ = fuse_common_velocity(
                compact[lab[sel]],
                plots.xy_m[idx],
                R_own[sel],
                plots.t_s[idx] - t_c[lab[sel]],
                v_pad[res.cluster_track[joint]],
                pvv_pad[res.cluster_track[joint]],
                joint.size,
            )
        bias_sens, all_heights = self._bias_sensitivity(plots, used, lab, v, R_plot, n_clusters)
        dap_v_mps, dap_age_s = self._dap_velocity(plots, used, lab, t_c, n_clusters)
        air_v_mps, air_age_s = self._air_velocity(plots, used, lab, t_c, z_m, n_clusters)
        roll_used = plots.roll_deg[used]
        self.counters["plots_roll"] += int(np.isfinite(roll_used).sum())
        mode_s = np.full(n_clusters, -1, np.int64)
        np.maximum.at(mode_s, lab, plots.mode_s[used])
        mode3a = np.full(n_clusters, -1, np.int64)
        np.maximum.at(mode3a, lab, plots.mode3a[used])
        revisit_s = np.full(n_clusters, np.inf)
        np.minimum.at(revisit_s, lab, self.rotation_s[plots.radar[used]])
        sources = np.zeros(n_clusters, np.uint64)
        np.bitwise_or.at(sources, lab, np.left_shift(np.uint64(1), plots.radar[used].astype(np.uint64)))
        self.counters["plots_fused"] += int(used.sum())
        return ClusterMeasurements(
            track_row=res.cluster_track,
            valid=n_in > 0,
            t_s=t_c,
            z_m=z_m,
            R_m2=R_m2,
            fl=_mean_known(lab, plots.fl[used], n_clusters),
            mode_s=mode_s,
            mode3a=mode3a,
            revisit_s=revisit_s,
            sources=sources,
            roll_deg=_mean_known(lab, roll_used, n_clusters),
            dap_v_mps=dap_v_mps,
            dap_age_s=dap_age_s,
            air_v_mps=air_v_mps,
            air_age_s=air_age_s,
            height_cov_m2=cluster_h_cov,
            far=far,
            bias_sens=bias_sens,
            all_heights=all_heights,
        )

    def _bias_sensitivity(
        self,
        plots: ConvertedPlots,
        used: np.ndarray,
        lab: np.ndarray,
        v_mps: np.ndarray,
        R_plot: np.ndarray,
        n_clusters: int,
    ) -> tuple[reg_kernels.ClusterSensitivity | None, np.ndarray | None]:
        """Per cluster, the fused position's sensitivity to each radar's biases (the
        two-stage registration, registration.py): F = S_c^-1 sum_i W_i J_i, W_i = R_i^-1 the
        weights the fusion gave the plots (Shu eq. 5-6), J_i the plot's Jacobian
        (RegistrationGeometry.jacobian, with the velocity it was aligned with), placed at its
        radar's columns; sparse over the radars (registration.ClusterSensitivity): the matrix fusion's
        (with ``fusion_method`` "scalar", or a new target's cluster fused with its common
        velocity, an approximation). And whether every plot of the cluster has Mode C (a plot
        without it is converted at a guessed height: no bias evidence). None, None with the
        two-stage registration off."""
        m = self.tracks.n_radars
        if not m:
            return None, None
        radar = plots.radar[used]
        altitude_m = plots.altitude_m[used]
        jac = self.registration.geometry.jacobian(
            radar,
            plots.range_m[used],
            plots.azimuth_deg[used],
            altitude_m,
            plots.xy_m[used, 0],
            plots.xy_m[used, 1],
            v_mps if self.registration.params.estimate_time_offset else None,
            self.assumed_altitude_m,
        )
        sens = reg_kernels.ClusterSensitivity(
            *reg_kernels.cluster_sensitivity(
                lab.astype(np.intp), radar.astype(np.intp), np.ascontiguousarray(R_plot), jac, n_clusters, m
            )
        )
        no_height = np.bincount(lab, weights=~np.isfinite(altitude_m), minlength=n_clusters)
        return sens, no_height == 0

    def _dap_velocity(
        self, plots: ConvertedPlots, used: np.ndarray, lab: np.ndarray, t_c: np.ndarray, n_clusters: int
    ) -> tuple[np.ndarray | None, np.ndarray | None]:
        """Per cluster, the aircraft's own velocity from the Mode S BDS 5,0 reports among its
        plots (ground speed and true track angle), in the system plane, and how long before
        the cluster's time it held (the report's mean age, ``velocity_age_s``, plus the
        cluster's time less the plot's); NaN for a cluster without one. The reports of one
        cluster (several radars reading one register within a scan) are averaged as vectors
        at the cluster's position (geo.coordinates.ground_velocity_to_plane); (None, None)
        without the IMM or with ``velocity_dap`` off."""
        if self.imm is None or not self.imm.params.velocity_dap or plots.ground_speed_mps is None:
            return None, None
        assert plots.track_angle_deg is not None
        idx = np.flatnonzero(used)
        have = np.isfinite(plots.ground_speed_mps[idx]) & np.isfinite(plots.track_angle_deg[idx])
        if not have.any():
            return None, None
        self.counters["plots_velocity"] += int(have.sum())
        i, lb = idx[have], lab[have]
        track_rad = np.radians(plots.track_angle_deg[i])
        count = np.bincount(lb, minlength=n_clusters).astype(float)
        east = np.bincount(lb, plots.ground_speed_mps[i] * np.sin(track_rad), n_clusters)
        north = np.bincount(lb, plots.ground_speed_mps[i] * np.cos(track_rad), n_clusters)
        lag = np.bincount(lb, t_c[lb] - plots.t_s[i], n_clusters)
        alt = _mean_known(lb, plots.altitude_m[i], n_clusters)
        k = np.flatnonzero(count > 0)
        speed = np.hypot(east[k], north[k]) / count[k]
        track_deg = np.degrees(np.arctan2(east[k], north[k]))
        xy = (
            np.bincount(lb, plots.x_m[i], n_clusters)[k] / count[k],
            np.bincount(lb, plots.y_m[i], n_clusters)[k] / count[k],
        )
        v = np.full((n_clusters, 2), np.nan)
        v[k, 0], v[k, 1] = ground_velocity_to_plane(self.plane, *xy, speed, track_deg, alt[k])
        age = np.full(n_clusters, np.nan)
        age[k] = self.imm.params.velocity_age_s + lag[k] / count[k]
        return v, age

    def _air_velocity(
        self,
        plots: ConvertedPlots,
        used: np.ndarray,
        lab: np.ndarray,
        t_c: np.ndarray,
        z_m: np.ndarray,
        n_clusters: int,
    ) -> tuple[np.ndarray | None, np.ndarray | None]:
        """Per cluster, the aircraft's air vector from the Mode S BDS 6,0 reports among its
        plots, in the system plane at the cluster's position ``z_m``, and its age, as
        :meth:`_dap_velocity` does for BDS 5,0: the true heading is the reports' mean
        magnetic heading (as unit vectors) plus ``magnetic_declination_deg``; the true
        airspeed that of their mean indicated one at their mean pressure altitude (Mode C) in
        ISA (geo.air_data.true_airspeed_mps; one conversion per cluster, not per plot: the
        reports of a cluster are one aircraft's within a scan; a cluster whose headings
        disagree by more than 5° has none); a report without Mode C, or
        with an IAS below ``air_min_ias_mps``, is not used. The age is ``air_velocity_age_s``
        plus the cluster's time less the plots'. (None, None) without the IMM or with
        ``velocity_dap`` or ``velocity_air`` off."""
        if (
            self.imm is None
            or not (self.imm.params.velocity_dap and self.imm.params.velocity_air)
            or plots.magnetic_heading_deg is None
            or plots.indicated_airspeed_mps is None
        ):
            return None, None
        idx = np.flatnonzero(used)
        heading, ias, fl = plots.magnetic_heading_deg[idx], plots.indicated_airspeed_mps[idx], plots.fl[idx]
        have = np.isfinite(heading) & (ias >= self.imm.params.air_min_ias_mps) & np.isfinite(fl)  # NaN: False
        if not have.any():
            return None, None
        self.counters["plots_air_velocity"] += int(have.sum())
        i, lb = idx[have], lab[have]
        p = self.imm.params
        heading_rad = np.radians(heading[have])
        count = np.bincount(lb, minlength=n_clusters).astype(float)
        east = np.bincount(lb, np.sin(heading_rad), n_clusters)
        north = np.bincount(lb, np.cos(heading_rad), n_clusters)
        # the reports of one cluster are one aircraft's within a scan: headings that disagree
        # by more than a few degrees (their mean unit vector shorter than cos 5°) hold a
        # misread one, and the cluster has no air vector (a third of a 90° error is 108 m/s)
        k = np.flatnonzero(count > 0)
        agree = np.hypot(east[k], north[k]) >= count[k] * math.cos(math.radians(5.0))
        self.counters["air_clusters_disagreeing"] += int((~agree).sum())
        k = k[agree]
        n_k = count[k]
        ias_k = np.bincount(lb, ias[have], n_clusters)[k] / n_k
        alt_k = np.bincount(lb, fl[have], n_clusters)[k] / n_k * M_PER_FL
        # the day's temperature, if configured, turns the indicated airspeed into the true one
        # (else ISA's: the wind learnt takes the 1 % a 5 K warmer day makes)
        temperature_dev_k = self.mode_c_met[0] or 0.0
        lag_k = np.bincount(lb, t_c[lb] - plots.t_s[i], n_clusters)[k] / n_k
        true_deg = np.degrees(np.arctan2(east[k], north[k])) + p.magnetic_declination_deg
        v = np.full((n_clusters, 2), np.nan)
        v[k, 0], v[k, 1] = ground_velocity_to_plane(
            self.plane, z_m[k, 0], z_m[k, 1], true_airspeed_mps(ias_k, alt_k, temperature_dev_k), true_deg, alt_k
        )
        age = np.full(n_clusters, np.nan)
        age[k] = p.air_velocity_age_s + lag_k
        return v, age

    def _air_velocity_and_wind(
        self, cl: ClusterMeasurements, matched: np.ndarray, rows: np.ndarray, dap_used: np.ndarray
    ) -> np.ndarray:
        """The tracks ``rows`` (just updated with their clusters ``matched``, and ``dap_used``
        of them with their cluster's BDS 5,0 report, :meth:`_update_velocity`) whose cluster
        carries an air vector (BDS 6,0, :meth:`_air_velocity`):

        * with a BDS 5,0 report the update took, and the track not manoeuvring (|acceleration|
          below ``wind_sample_max_accel_mps2``): a wind sample, the ground velocity less the
          air vector, each taken back to the cluster's time with the track's acceleration
          (v(t) = v(t − age) + age · a). A sample above ``wind_max_mps``, or farther than
          ``wind_sample_gate_mps`` from the track's own wind (or, for its first, from its
          layer's), is refused (``wind_samples_refused``: a misread heading, an airspeed of a
          take-off roll); the track's wind follows the others, w ← w + (1 − exp(−Δt /
          ``wind_time_constant_s``)) (sample − w), the first taken as it is;
        * without one: the air vector plus the wind is a measurement of the velocity, the
          IMM's velocity update (imm.IMMFilter.velocity_update_rows) with σ² =
          ``air_velocity_sigma_mps``² per axis. The wind is the track's own if no older than
          ``wind_max_age_s`` and taken within ``wind_max_climb_ft`` of the track's level,
          else its layer's (:meth:`_layer_winds`), with ``wind_layer_sigma_mps``² more per
          axis. A measurement beyond ``air_gate_chi2`` of the combined state's velocity
          (H P Hᵀ + R, H = v − age·acc) is refused before the update (counted with
          ``velocity_reports_refused``): the update's own gate asks whether any model takes
          it, and the manoeuvre model took headings 90° off.

        Returns the rows the second updated."""
        assert self.imm is not None and cl.air_v_mps is not None and cl.air_age_s is not None
        p = self.imm.params
        tr = self.tracks
        air = cl.air_v_mps[matched]
        has_air = np.isfinite(air[:, 0])
        has_dap = np.isin(rows, dap_used)
        t_s = cl.t_s[matched]
        # wind samples
        s = np.flatnonzero(has_air & has_dap)
        if s.size:
            assert cl.dap_v_mps is not None and cl.dap_age_s is not None
            r, k = rows[s], matched[s]
            acc = tr.x[r][:, [2, 5]]  # the Singer state's acceleration
            calm = np.hypot(acc[:, 0], acc[:, 1]) < p.wind_sample_max_accel_mps2
            r, k, acc = r[calm], k[calm], acc[calm]
            sample = (cl.dap_v_mps[k] + cl.dap_age_s[k, None] * acc) - (cl.air_v_mps[k] + cl.air_age_s[k, None] * acc)
            ref, own = self._wind_to_use(r, cl.t_s[k])
            off = np.hypot(sample[:, 0] - ref[:, 0], sample[:, 1] - ref[:, 1])
            ok = (np.hypot(sample[:, 0], sample[:, 1]) <= p.wind_max_mps) & ~(off > p.wind_sample_gate_mps)
            self.counters["wind_samples_refused"] += int((~ok).sum())
            r, k, sample, own = r[ok], k[ok], sample[ok], own[ok]
            dt = cl.t_s[k] - tr.wind_t_s[r]
            gain = np.where(own, 1.0 - np.exp(-np.maximum(np.nan_to_num(dt), 0.0) / p.wind_time_constant_s), 1.0)
            prior = np.where(own[:, None], tr.wind_mps[r], sample)
            tr.wind_mps[r] = prior + gain[:, None] * (sample - prior)
            tr.wind_t_s[r] = cl.t_s[k]
            tr.wind_fl[r] = tr.alt_x[r, 0]
            tr.wind_air_deg[r] = np.degrees(np.arctan2(cl.air_v_mps[k, 0], cl.air_v_mps[k, 1]))
            self.counters["wind_samples"] += int(r.size)
        self._layer_winds(float(np.max(t_s)) if t_s.size else math.nan)
        # the air vector plus the wind, where no BDS 5,0 report measured the velocity
        a = np.flatnonzero(has_air & ~has_dap)
        wind, own = self._wind_to_use(rows[a], t_s[a])
        known = np.isfinite(wind[:, 0])
        a, wind, own = a[known], wind[known], own[known]
        if not a.size:
            return rows[:0]
        r, k = rows[a], matched[a]
        var = self._air_velocity_var(r, cl.air_v_mps[k], own)
        R = var[:, None, None] * np.eye(2)
        z = cl.air_v_mps[k] + wind
        age = cl.air_age_s[k]
        # the combined state's gate (the update's asks whether any one model takes it)
        H = np.zeros((r.size, 2, 6))
        H[:, 0, 1] = H[:, 1, 4] = 1.0
        H[:, 0, 2] = H[:, 1, 5] = -age
        acc = tr.x[r][:, [2, 5]]
        nu = z - np.einsum("kij,kj->ki", H, tr.x[r])
        S = np.einsum("kij,kjl,kml->kim", H, tr.P[r], H) + R
        S += p.velocity_age_sigma_s**2 * acc[:, :, None] * acc[:, None, :]
        far = np.einsum("ki,kij,kj->k", nu, inv_2x2(S), nu) > p.air_gate_chi2
        self.counters["velocity_reports_refused"] += int(far.sum())
        keep = ~far
        self.counters["updates_velocity_air_layer_wind"] += int((~own[keep]).sum())
        return self._velocity_update_rows(r[keep], z[keep], R[keep], age[keep], "updates_velocity_air")

    def _air_velocity_var(self, rows: np.ndarray, air_v_mps: np.ndarray, own: np.ndarray) -> np.ndarray:
        """(n,) variance per axis, m²/s², of the air vector ``air_v_mps`` (n, 2) plus the wind of
        the tracks ``rows`` as a velocity: ``air_velocity_sigma_mps``², and where the wind is
        the track's ``own`` (:meth:`_wind_to_use`) the part of the air vector's own error it no
        longer absorbs. That error, ε |v_a| (ε = ``air_rotation_error_rel``: the day's
        temperature off ISA scales the airspeed, a heading error turns it), turns with the
        heading; the wind took it up at the heading ψ₀ of its latest sample (``wind_air_deg``),
        so at ψ it leaves |ε v_a (e^{i(ψ−ψ₀)} − 1)| = 2 |sin((ψ − ψ₀)/2)| ε |v_a|. Where the
        wind is the layer's, it holds none of this aircraft's error: ``wind_layer_sigma_mps``²
        instead."""
        assert self.imm is not None
        p = self.imm.params
        psi_deg = np.degrees(np.arctan2(air_v_mps[:, 0], air_v_mps[:, 1]))
        half_turn = np.radians(psi_deg - self.tracks.wind_air_deg[rows]) / 2.0
        turned = np.nan_to_num(2.0 * np.sin(half_turn) * p.air_rotation_error_rel * np.hypot(*air_v_mps.T))
        return np.asarray(p.air_velocity_sigma_mps**2 + np.where(own, turned**2, p.wind_layer_sigma_mps**2))

    def _wind_to_use(self, rows: np.ndarray, t_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The wind (n, 2) the tracks ``rows`` take at ``t_s``: their own where it is valid
        (:meth:`_own_wind_valid`), else their layer's (:meth:`_wind_layer`, :meth:`_layer_winds`);
        NaN with neither. And (n,) whether it is their own."""
        own = self._own_wind_valid(rows, t_s)
        layer = self._wind_layer(rows)
        shared = np.where((layer >= 0)[:, None], self.layer_wind_mps[np.maximum(layer, 0)], np.nan)
        return np.where(own[:, None], self.tracks.wind_mps[rows], shared), own

    def _own_wind_valid(self, rows: np.ndarray, t_s: np.ndarray) -> np.ndarray:
        """Whether the tracks ``rows`` have a wind of their own to use at ``t_s``: taken no
        longer than ``wind_max_age_s`` ago and within ``wind_max_climb_ft`` of their level."""
        assert self.imm is not None
        p = self.imm.params
        tr = self.tracks
        own = t_s - tr.wind_t_s[rows] <= p.wind_max_age_s  # NaN (no wind yet) compares False
        climbed_fl = np.abs(tr.alt_x[rows, 0] - tr.wind_fl[rows])
        return np.asarray(own & ~(climbed_fl > p.wind_max_climb_ft / FT_PER_FL))  # NaN level: kept

    def _wind_layer(self, rows: np.ndarray) -> np.ndarray:
        """The wind layer of the tracks ``rows`` by their flight level (``wind_layer_ft``), −1
        without one."""
        assert self.imm is not None
        fl = self.tracks.alt_x[rows, 0]
        layer = np.floor(np.nan_to_num(fl, nan=-1.0) * FT_PER_FL / self.imm.params.wind_layer_ft).astype(np.int64)
        return np.where(np.isfinite(fl), np.clip(layer, 0, self.layer_wind_t_s.size - 1), -1)

    def _layer_winds(self, t_s: float) -> None:
        """Each layer's wind, at most every ``wind_layer_update_s``: the median, per axis, of
        the own winds of its tracks that hold one (:meth:`_own_wind_valid`), a layer by each
        track's level. A median of tracks, not a running mean of samples: a track whose wind
        is wrong (a misread register it took first) does not carry the layer with it. A layer
        with no such track keeps its wind for ``wind_layer_keep_s``, then has none."""
        assert self.imm is not None
        p = self.imm.params
        if not math.isfinite(t_s) or t_s - self._layer_winds_t_s < p.wind_layer_update_s:
            return
        self._layer_winds_t_s = t_s
        tr = self.tracks
        rows = np.flatnonzero(np.isfinite(tr.wind_t_s[: len(tr)]))
        rows = rows[self._own_wind_valid(rows, np.full(rows.size, t_s))]
        layer = self._wind_layer(rows)
        rows, layer = rows[layer >= 0], layer[layer >= 0]
        stale = t_s - self.layer_wind_t_s > p.wind_layer_keep_s
        self.layer_wind_mps[stale] = np.nan
        self.layer_wind_t_s[stale] = np.nan
        if not rows.size:
            return
        order = np.argsort(layer, kind="stable")
        rows, layer = rows[order], layer[order]
        starts = np.flatnonzero(np.r_[True, layer[1:] != layer[:-1]])
        for lo, hi in zip(starts, np.r_[starts[1:], layer.size], strict=True):
            self.layer_wind_mps[layer[lo]] = np.median(tr.wind_mps[rows[lo:hi]], axis=0)
            self.layer_wind_t_s[layer[lo]] = t_s

    def _beyond_any_manoeuvre(
        self, res: ClusterResult, used: np.ndarray, row_of_plot: np.ndarray, pred: Prediction, t_plot_s: np.ndarray
    ) -> np.ndarray:
        """The used plots, of tracks with a velocity, that no manoeuvre of at most
        ``far_accel_mps2`` since the track's update could have put where they are:

            |y| > ½ a_max Δt² + sqrt(gate_chi2) σ_y,

        y the plot (aligned to t_ref) less the combined prediction, σ_y² = yᵀ S y / |y|² the
        innovation variance along y (S = the prediction's position covariance plus the
        plot's), Δt = the plot's time − the track's update time (from the plot's time to
        t_ref both move with the track's velocity). A high-noise manoeuvre model's gate
        after a scan or two of a far radar holds plots a kilometre off; a turn no aircraft
        flies is no reason to take one (issue 15 item 7: one such plot flipped a straight
        track to the manoeuvre model and took it 1.1-1.8 km off for 20 s). Such a plot
        counts as far (_hold_far)."""
        row = row_of_plot
        out = np.zeros(row.shape[0], bool)
        trk = np.flatnonzero(row >= 0)
        if not trk.size:
            return out
        r = row[trk]
        known = self.tracks.velocity_known[r]
        trk, r = trk[known], r[known]
        if not trk.size:
            return out
        idx = np.flatnonzero(used)[trk]
        y = res.aligned_xy_m[idx] - position_m(pred.x[r])
        S = res.aligned_cov_m2[idx] + cov_pos_m2(pred.P[r])
        dist2 = np.einsum("ki,ki->k", y, y)
        var_y = np.einsum("ki,kij,kj->k", y, S, y) / np.maximum(dist2, 1e-9)
        dt_s = np.maximum(t_plot_s[trk] - self.tracks.t_state_s[r], 0.0)
        reach = 0.5 * self.clustering.far_accel_mps2 * dt_s**2 + np.sqrt(self.clustering.gate_chi2 * var_y)
        out[trk] = np.sqrt(dist2) > reach
        return out

    def _height_spread(
        self,
        plots: ConvertedPlots,
        res: ClusterResult,
        used: np.ndarray,
        lab: np.ndarray,
        n_in: np.ndarray,
        R_plots: tuple[np.ndarray, ...],
        pred: Prediction,
    ) -> np.ndarray | None:
        """Where the spread over every height of a primary plot without any height goes
        (``plots.height_cov_m2``, geo.unknown_height): into its covariance, each of
        ``R_plots`` (in place), into the floor of its track's covariance (returned per
        cluster), or nowhere.

        * A cluster with a plot with a height (Mode C, an SSR's): that plot fixes the ground
          range; the spread joins the primary plot's covariance, so that it hardly weighs
          radially.
        * The one plot of a cluster, for a new target or a track that does not know its
          position much better than the spread along it (e1^T P e1 >= l1 / 2, l1 the
          spread's main axis: a track built from this radar's plots of this kind, floored
          at the spread of its previous plot, which grows as the aircraft comes closer; a
          strict e1^T P e1 >= l1 let such a track lose its floor, and the aircraft's first
          SSR plot 940 m away start a shadow): the spread is common to all
          the plots that track gets from that radar, so the cluster keeps it apart and it
          floors the track's covariance (_floor_no_height, initiation.floor_covariance).
        * Otherwise (plots of two radars, or a track they have triangulated to better than
          half the spread): the assumed
          height's noise alone, as before. Two radars' spreads are not common, but adding
          them made the demo's primary-only FL120 aircraft (near the assumed 10,000 ft) go
          from 78 to 244 m position RMS: its position then hangs on the azimuths only. The
          height such a track could be given from its radars' disagreement is not estimated.

        Returns None when the period has no such plot."""
        if plots.height_cov_m2 is None:
            return None
        h_cov = plots.height_cov_m2[used]
        spread = h_cov[:, 0, 0] + h_cov[:, 1, 1] > 0.0
        hp = np.flatnonzero(spread)
        if not hp.size:
            return None
        n_clusters = len(res.cluster_track)
        c = lab[hp]
        with_h = np.bincount(lab[~spread], minlength=n_clusters) > 0
        for R_plot in R_plots:
            R_plot[hp[with_h[c]]] += h_cov[hp[with_h[c]]]
        row = res.cluster_track[c]
        own = (n_in[c] == 1) & ~np.isfinite(np.concatenate([pred.alt_x[:, 0], [np.nan]])[row])
        tracked = own & (row >= 0)
        if tracked.any():
            lam, vec = np.linalg.eigh(h_cov[hp[tracked]])
            e1 = vec[:, :, 1]
            along = np.einsum("ni,nij,nj->n", e1, cov_pos_m2(pred.P[row[tracked]]), e1)
            own[np.flatnonzero(tracked)[along < 0.5 * lam[:, 1]]] = False
        cluster_h_cov = np.zeros((n_clusters, 2, 2))
        cluster_h_cov[c[own]] = h_cov[hp[own]]
        return cluster_h_cov

    def _register(
        self,
        plots: ConvertedPlots,
        res: ClusterResult,
        used: np.ndarray,
        lab: np.ndarray,
        row_of_plot: np.ndarray,
        z_plot: np.ndarray,
        R_plot: np.ndarray,
        v_mps: np.ndarray,
        t_ref_s: float,
    ) -> None:
        """Feed the registration (registration.py) with the period's aligned plots of
        established tracks, every ``update_interval_s``: only plots that joined their track
        inside the χ² gate, so that a wild plot or an identity join is no bias evidence."""
        reg = self.registration
        if not reg.params.enabled or t_ref_s < self._reg_next_t_s:
            return
        self._reg_next_t_s = t_ref_s + reg.params.update_interval_s
        self._reg_fed_t_s = t_ref_s
        status = np.concatenate([self.tracks.status, [TENTATIVE]])  # row -1: a new target
        established = status[row_of_plot] != TENTATIVE
        # a plot without any height is no bias evidence: its ground range is the height's guess
        inside = (res.plot_d2[used] <= self.clustering.gate_chi2) & np.isfinite(plots.altitude_m[used])
        reg.update(
            t_ref_s,
            plots.radar[used],
            plots.range_m[used],
            plots.azimuth_deg[used],
            plots.altitude_m[used],
            z_plot,
            R_plot,
            np.where(established & inside, lab, -1),
            velocity_mps=v_mps,
            applied=self._reg_applied,
            assumed_altitude_m=self.assumed_altitude_m,
        )

    def _hold_far(self, cl: ClusterMeasurements) -> None:
        """A track's cluster far beyond every gate is held for a scan, not fused (in place).

        Such a cluster joined its track by the Mode S address alone, at d² above
        ``far_gate_factor`` × ``gate_chi2`` of the combined prediction and of every IMM
        model's (``cl.far``; in a turn a turn model expects the plots, so they are not far).
        One scan cannot tell a wild plot from a wrong track (a two-point velocity from a wild
        plot, a manoeuvre no model foresaw); fused at the gate's edge, one wild plot of a
        precise radar had a young track fly at 700-1,000 m/s for half a minute (issue 15
        item 7: 3 % wild plots at 1,000×10, settled velocity +82 %). So is a cluster that
        would make a young track faster than any aircraft, or whose report refutes a young
        track's first two-point start (:meth:`_too_fast`). Held instead:

        * the track coasts; the measurement is kept (``held_*``) for ``far_hold_scans`` of
          the track's revisit time;
        * a later cluster inside the gates: the held one was a wild plot, dropped and
          counted (``plots_far_dropped``), unless the track has one measurement and the
          cluster's report refutes the start from it and not the start from the held one, or
          refutes both and the held one is the nearer (:meth:`_first_refuted`), or the held
          one is an alternative first point (:meth:`_choose_first`);
        * a later far cluster within reach of the held one (the distance an aircraft at
          ``max_speed_mps`` flies between them, plus sqrt(gate_chi2) σ of their noise): the
          track was wrong; it is initiated again from the two by the two-point initiation
          (Shu §4), keeping its id and identity (``tracks_far_reinitiated``), unless the
          track has one measurement and the cluster's report refutes the pair, once per track
          (``pairs_refuted``: the new cluster is held in its place);
        * a later far cluster out of reach of the held one: that one replaces it.
        """
        if not self.clustering.far_hold or cl.far is None or not len(self.tracks):
            return
        tr = self.tracks
        k = np.flatnonzero(cl.valid & (cl.track_row >= 0))
        rows = cl.track_row[k]
        held = np.isfinite(tr.held_t_s[rows]) & (
            cl.t_s[k] - tr.held_t_s[rows] <= self.clustering.far_hold_scans * tr.revisit_s[rows]
        )
        held &= tr.mode_s[rows] >= 0  # an address's; a code's alternative is _code_alternatives' (cleared below)
        far = (cl.far[k] & tr.initiated[rows]) | self._too_fast(cl, k, rows, held)
        # a track of one measurement with another of its time held beside it (not a far one,
        # which is later than the state): the new one chooses
        choose = held & ~far & ~tr.initiated[rows] & (tr.updates[rows] == 1)
        later = choose & ~tr.held_alternative[rows]  # held after the state: too fast from it
        choose &= tr.held_alternative[rows]
        if choose.any():
            self._choose_first(cl, k[choose], rows[choose])
        if later.any():
            later[later] = self._first_refuted(cl, k[later], rows[later])
            choose |= later
        near_after_held = held & ~far & ~choose
        if near_after_held.any():
            self.counters["plots_far_dropped"] += int(near_after_held.sum())
        tr.held_t_s[rows[~far]] = np.nan
        if not far.any():
            return
        kf, rf, hf = k[far], rows[far], held[far]
        pair = hf & ~self._beyond_reach(
            tr.held_z_m[rf], np.nan_to_num(tr.held_R_m2[rf]), tr.held_t_s[rf], cl.z_m[kf], cl.R_m2[kf], cl.t_s[kf]
        )
        # A first measurement's alternative (held at or before the state's time) and a far
        # cluster of its own radars only agree as one radar's run of wild plots would (one
        # constant error for several scans): that is no other radar's word against the first.
        # Unless the state is of those radars too, their next scan (_alternatives): a run
        # would have given it the same error, so the state is the isolated wild plot.
        alternative = tr.held_alternative[rf]
        pair &= ~alternative | ((cl.sources[kf] & ~tr.held_sources[rf]) != 0) | tr.held_own_radars[rf]
        if pair.any():
            # a track of one measurement, once: the aircraft's own velocity refutes the pair, so
            # the held one is wild as well (two wild plots in a row, 1,000×10 seed 1: a start
            # 290 m/s off); the new one is held in its place (a misread register costs a scan)
            q = np.flatnonzero(pair & ~tr.initiated[rf] & ~tr.start_refuted[rf])
            if q.size:
                rq = rf[q]
                held_point = (tr.held_z_m[rq], tr.held_R_m2[rq], tr.held_t_s[rq])
                pair[q[self._start_refuted(cl, kf[q], rq, held_point, "pairs_refuted")]] = False
        if pair.any():
            rp = rf[pair]
            self._initiate_from_held(cl, kf[pair], rp)
            tr.held_t_s[rp] = np.nan
            self.counters["tracks_far_reinitiated"] += int(pair.sum())
        kh, rh = kf[~pair], rf[~pair]
        if kh.size:
            tr.held_z_m[rh], tr.held_R_m2[rh], tr.held_t_s[rh] = cl.z_m[kh], cl.R_m2[kh], cl.t_s[kh]
            tr.held_sources[rh] = cl.sources[kh]
            cl.valid[kh] = False
            self.counters["plots_far_held"] += int(kh.size)

    def _choose_first(self, cl: ClusterMeasurements, k: np.ndarray, rows: np.ndarray) -> None:
        """Tracks of one measurement (rows ``rows``) that hold another of its time beside it
        (``held_*``: two one-plot tracks of one address merged,
        track_management.merge_same_address), and their next clusters ``k``: the first
        measurement of the two-point initiation (Shu §4) is the one of the two nearer the new
        cluster by :meth:`_start_d2` (with the aircraft's own velocity where the cluster reports
        it, else as a target without a track; the smaller d², the nearest neighbour: the
        Gaussian likelihood's ln det S would favour the later of the two by its shorter Δt
        alone, and that prior is a gate's, not a model of speeds). Two plots of one address 5 km
        apart in one period, one of them wild, were a coin toss: the wild one kept, its
        two-point velocity with the aircraft's next plot was 250 m/s off and the track 0.6-2.7 km
        off for 20 s (issue 15 item 7, 3 % wild plots); without the report the nearer of two
        one-plot positions was still the wild one for a start 342 m/s off (1,000×10 seed 1). A
        report that refutes both is taken for a misread register and left out. The held one
        chosen: the track is initiated from it (as :meth:`_hold_far` re-initiates),
        counted ``tracks_first_replaced``."""
        d2_held, d2_first, _, _ = self._held_or_first_d2(cl, k, rows)
        better = d2_held < d2_first
        if better.any():
            self._initiate_from_held(cl, k[better], rows[better])
            self.counters["tracks_first_replaced"] += int(better.sum())

    def _held_or_first_d2(
        self, cl: ClusterMeasurements, k: np.ndarray, rows: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """For tracks of one measurement (rows ``rows``) that hold another (``held_*``) and
        their next clusters ``k``: :meth:`_start_d2` of the cluster from the held measurement
        and from the first, with the cluster's reported velocity (:meth:`_reported_velocity`).
        A report that refutes both (each beyond ``gate_chi2``) is no word on either, a misread
        register: those rows are taken as without a report. Returns d²(held), d²(first), whether
        a report was used, and whether one was set aside as misread."""
        tr = self.tracks
        z, R, t = cl.z_m[k], cl.R_m2[k], cl.t_s[k]
        v, Rv = self._reported_velocity(cl, k, rows)

        def both() -> np.ndarray:
            return np.stack([
                self._start_d2(tr.held_z_m[rows], tr.held_R_m2[rows], tr.held_t_s[rows], z, R, t, v, Rv),
                self._start_d2(tr.z1_m[rows], tr.R1_m2[rows], tr.t_state_s[rows], z, R, t, v, Rv),
            ])  # fmt: skip

        d2_held, d2_first = both()
        misread = np.isfinite(v[:, 0]) & (np.minimum(d2_held, d2_first) > self.clustering.gate_chi2)
        if misread.any():
            v[misread] = np.nan
            d2_held, d2_first = np.where(misread, both(), (d2_held, d2_first))
        return d2_held, d2_first, np.isfinite(v[:, 0]), misread

    def _start_d2(
        self,
        z0: np.ndarray,
        R0: np.ndarray,
        t0: np.ndarray,
        z: np.ndarray,
        R: np.ndarray,
        t: np.ndarray,
        v: np.ndarray,
        Rv: np.ndarray,
    ) -> np.ndarray:
        """d² of a measurement z (R, at t) from an earlier one z₀ (R₀, at t₀) as the two points
        of a two-point initiation (Shu §4), for an aircraft whose velocity is reported as v
        (covariance R_v, :meth:`_reported_velocity`):

            d² = yᵀ S⁻¹ y,   y = z − z₀ − v Δt,   S = R₀ + R + Δt² R_v,   Δt = t − t₀;

        where v is NaN, as a target without a track: v = 0, R_v = (v_max²/3) I
        (initiation.unknown_velocity_var_m2ps2). (n,)."""
        known = np.isfinite(v[:, 0])
        v = np.where(known[:, None], v, 0.0)
        Rv = np.where(known[:, None, None], Rv, self.one_plot_vel_var_m2ps2 * np.eye(2))
        dt = t - t0
        y = z - z0 - v * dt[:, None]
        S = R0 + R + (dt**2)[:, None, None] * Rv
        return association.mahalanobis2_2x2(y, S)

    def _first_refuted(self, cl: ClusterMeasurements, k: np.ndarray, rows: np.ndarray) -> np.ndarray:
        """Tracks of one measurement (rows ``rows``) that hold a later one, too fast from the
        first (:meth:`_too_fast`: one of the two is wild, or their baseline was short), and
        their next clusters ``k``, within reach of the first: is the first refuted, the held
        one not, by the aircraft's own velocity (:meth:`_reported_velocity`) where the cluster
        reports it? Each is tested as the first point of the two-point initiation (Shu §4),

            d² = yᵀ S⁻¹ y,   y = z − z₀ − v Δt₀,   S = R₀ + R + Δt₀² R_v,   Δt₀ = t − t₀,

        against ``gate_chi2``; where the first is outside and the held one inside, the track is
        initiated from the held one (:meth:`_initiate_from_held`, ``tracks_first_refuted``).
        Without this the held one was dropped as the wild one, and a wild first plot 2.6 km
        off gave the two-point start a velocity 229 m/s off and the track 2.5 km off for three
        periods (issue 15 item 7, 3 % wild plots, 1,000×10 seed 0: 72 % of the velocity
        excess over the clean twin). Where the report refutes both (a misread register), the
        nearer of the two is chosen as :meth:`_choose_first` chooses without a report (keeping
        the first, a wild first plot and a misread register gave a start 100 m/s off); with no
        report, or one that refutes neither, the first is kept, as before. (K,) bool."""
        d2_held, d2_first, reported, misread = self._held_or_first_d2(cl, k, rows)
        gate = self.clustering.gate_chi2
        better = (reported & (d2_first > gate) & (d2_held <= gate)) | (misread & (d2_held < d2_first))
        if better.any():
            self._initiate_from_held(cl, k[better], rows[better])
            self.counters["tracks_first_refuted"] += int(better.sum())
        return better

    def _start_refuted(
        self,
        cl: ClusterMeasurements,
        k: np.ndarray,
        rows: np.ndarray,
        point: tuple[np.ndarray, np.ndarray, np.ndarray],
        counter: str,
    ) -> np.ndarray:
        """Does the aircraft's own velocity, as the clusters ``k`` report it
        (:meth:`_reported_velocity`), refute the two-point start of their tracks ``rows`` from
        ``point`` (z₀, R₀, t₀) to them: :meth:`_start_d2` beyond ``gate_chi2``? A track so
        refused is marked (``start_refuted``: once per track, :meth:`_too_fast`, :meth:`_hold_far`)
        and counted under ``counter``. (K,) bool; False without a report."""
        v, Rv = self._reported_velocity(cl, k, rows)
        d2 = self._start_d2(*point, cl.z_m[k], cl.R_m2[k], cl.t_s[k], v, Rv)
        refuted: np.ndarray = np.isfinite(v[:, 0]) & (d2 > self.clustering.gate_chi2)
        self.tracks.start_refuted[rows[refuted]] = True
        self.counters[counter] += int(refuted.sum())
        return refuted

    def _reported_velocity(
        self, cl: ClusterMeasurements, k: np.ndarray, rows: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """The aircraft's own ground velocity (n, 2) and its covariance (n, 2, 2) as the
        clusters ``k`` of the tracks ``rows`` report it: BDS 5,0 (:meth:`_velocity_R` plus
        ``velocity_birth_sigma_mps``², nothing has checked it yet), else the air vector plus
        the wind the track would take (:meth:`_wind_to_use`; σ as in
        :meth:`_air_velocity_and_wind`); NaN with neither (or without the IMM)."""
        v = np.full((k.size, 2), np.nan)
        Rv = np.full((k.size, 2, 2), np.nan)
        if self.imm is None:
            return v, Rv
        p = self.imm.params
        dap = np.zeros(k.size, bool) if cl.dap_v_mps is None else np.isfinite(cl.dap_v_mps[k, 0])
        if dap.any():
            assert cl.dap_v_mps is not None
            v[dap] = cl.dap_v_mps[k[dap]]
            Rv[dap] = self._velocity_R(v[dap]) + p.velocity_birth_sigma_mps**2 * np.eye(2)
        a = np.zeros(0, np.intp) if cl.air_v_mps is None else np.flatnonzero(~dap & np.isfinite(cl.air_v_mps[k, 0]))
        if a.size:
            assert cl.air_v_mps is not None
            wind, own = self._wind_to_use(rows[a], cl.t_s[k[a]])
            v[a] = cl.air_v_mps[k[a]] + wind
            Rv[a] = self._air_velocity_var(rows[a], cl.air_v_mps[k[a]], own)[:, None, None] * np.eye(2)
        return v, Rv

    def _initiate_from_held(self, cl: ClusterMeasurements, k: np.ndarray, rows: np.ndarray) -> None:
        """Clusters ``k`` initiate their tracks (rows ``rows``) by the two-point initiation
        (Shu §4) from the measurement each track holds (``held_*``), not from its first one."""
        tr = self.tracks
        self._initiate_from(cl, k, tr.held_z_m[rows], tr.held_R_m2[rows], tr.held_t_s[rows])

    @staticmethod
    def _initiate_from(
        cl: ClusterMeasurements, k: np.ndarray, z0_m: np.ndarray, R0_m2: np.ndarray, t0_s: np.ndarray
    ) -> None:
        """Clusters ``k`` initiate their tracks by the two-point initiation (Shu §4) from the
        measurements z0_m (R0_m2, at t0_s): ``_update`` takes the first point from
        ``cl.t0_s``, ``cl.z0_m``, ``cl.R0_m2``."""
        n = cl.track_row.shape[0]
        if cl.t0_s is None:
            cl.t0_s, cl.z0_m, cl.R0_m2 = np.full(n, np.nan), np.full((n, 2), np.nan), np.full((n, 2, 2), np.nan)
        assert cl.z0_m is not None and cl.R0_m2 is not None
        cl.t0_s[k], cl.z0_m[k], cl.R0_m2[k] = t0_s, z0_m, R0_m2

    def _too_fast(self, cl: ClusterMeasurements, k: np.ndarray, rows: np.ndarray, held: np.ndarray) -> np.ndarray:
        """Of the track clusters ``k`` (their tracks' rows ``rows``) that carry their track's
        Mode S address, those that would make a young track fly faster than any aircraft
        (``max_speed_mps``): held like far ones (:meth:`_hold_far`). ``held``: the tracks that
        hold a measurement in its window.

        * A track of one update: its two-point velocity (Shu §4, before the prior of
          ``[tracking] two_point_prior`` draws it towards zero) would be the distance from
          its first measurement over the time between them. Two plots 2-3 s apart from two
          radars give a velocity of σ ~150 m/s, and with a wild one among them the track flew
          at 350-750 m/s (1,000x10, 3 % wild plots). A good pair that seems too fast only
          because it is short waits a scan and pairs over a longer baseline. So does, once per
          track and within ``far_hold_scans`` revisit times of the first, a pair whose start
          the cluster's own velocity report refutes (:meth:`_reported_velocity`,
          :meth:`_start_d2` beyond ``gate_chi2``; counted ``starts_refuted``): one of the two is
          wild, and the next cluster chooses (:meth:`_first_refuted`); a misread register
          costs that scan.
        * A track of fewer than ``too_fast_young_updates`` updates: its velocity still rests on
          those few measurements, and its gates are so wide that a wild plot 3 km off lies
          inside them (d² 9.8 on one traced track); the update is tried on a copy of the
          track and refused when the speed after it is too high."""
        out = np.zeros(k.size, bool)
        tr = self.tracks
        # the track's own address: the plot is this aircraft's or a wild one (without it, a
        # plot too far is another object's, and _refuse_impossible_pairs gives it a track)
        own = (cl.mode_s[k] >= 0) & (cl.mode_s[k] == tr.mode_s[rows])
        one = np.flatnonzero(own & ~tr.initiated[rows] & (tr.updates[rows] >= 1))
        if one.size:
            dt_s = cl.t_s[k[one]] - tr.t_state_s[rows[one]]
            dist_m = np.hypot(*(cl.z_m[k[one]] - tr.z1_m[rows[one]]).T)
            out[one] = (dt_s > 0) & (dist_m > self.clustering.max_speed_mps * dt_s)
            self.counters["plots_too_fast"] += int(out.sum())
            # the aircraft's own velocity refutes the two-point start: held, once per track and
            # only within the time a held measurement is kept (a plot at that spacing comes
            # while it is held, and chooses between the two, _first_refuted; past it the held
            # one would lapse unused while the track ages towards its end); with a measurement
            # held, the cluster chooses instead
            window_s = self.clustering.far_hold_scans * tr.revisit_s[rows[one]]
            ask = one[(dt_s > 0) & (dt_s <= window_s) & ~out[one] & ~tr.start_refuted[rows[one]] & ~held[one]]
            if ask.size:
                r = rows[ask]
                first_point = (tr.z1_m[r], tr.R1_m2[r], tr.t_state_s[r])
                out[ask[self._start_refuted(cl, k[ask], r, first_point, "starts_refuted")]] = True
        young = np.flatnonzero(own & tr.initiated[rows] & (tr.updates[rows] < self.clustering.too_fast_young_updates))
        if young.size:
            r, kk = rows[young], k[young]
            dt_s = cl.t_s[kk] - tr.t_state_s[r]
            if self.imm is not None:
                trial = IMMState(tr.x_models[r], tr.P_models[r], tr.mu[r])  # copies (indexed by rows)
                x = self.imm.predict_update(trial, dt_s, cl.z_m[kk], cl.R_m2[kk])[1]
            else:
                xp, Pp = self.manoeuvres.predict(self.filter, tr.x[r], tr.P[r], dt_s, tr.manoeuvre[r])
                x = self.filter.update(xp, Pp, cl.z_m[kk], cl.R_m2[kk])[0]
            fast = np.hypot(*velocity_mps(x).T) > self.clustering.max_speed_mps
            out[young] = fast
            self.counters["plots_too_fast"] += int(fast.sum())
        return out

    # ---------------------------------------------------------------- update
    def _update(self, cl: ClusterMeasurements, t_ref_s: float, pred: Prediction) -> np.ndarray:
        """Tracks that got a cluster: each is predicted to its cluster's time, then the
        Kalman update (Shu eq. 7, 9, 10), or, at its second measurement, the two-point
        initiation (Shu §4). With the two-stage registration, the innovations of quiet
        tracks inform it first, and each track's sensitivity to the biases follows its
        update (:meth:`_innovations_to_registration`, :meth:`_update_bias_sens`). ``pred``:
        the period's prediction of every track. Returns the rows updated."""
        matched = np.flatnonzero(cl.valid & (cl.track_row >= 0))
        rows = cl.track_row[matched]
        if not rows.size:
            return rows.astype(np.int64)
        tr = self.tracks
        dt_s = cl.t_s[matched] - tr.t_state_s[rows]
        x_c = np.empty((rows.size,) + tr.x.shape[1:])
        P_c = np.empty((rows.size,) + tr.P.shape[1:])
        z_m, R_m2 = cl.z_m[matched], cl.R_m2[matched]
        init = tr.initiated[rows]
        if self.imm is not None:
            init &= ~self._birth_velocity_refuted(cl, matched, rows)
        again = None  # clusters that re-initiate their track from a held measurement (_hold_far)
        if cl.t0_s is not None:
            again = np.isfinite(cl.t0_s[matched])
            init &= ~again
        if init.any() and cl.bias_sens is not None:
            self._innovations_to_registration(cl, matched[init], rows[init], pred, t_ref_s)
        if init.any():
            # With the IMM, per model only: its output is the combination after the update,
            # so the combined prediction at the cluster's time is not computed. Only the
            # rows it updates are predicted (the two-point ones below start afresh).
            r = rows[init]
            if self.imm is not None:
                # in place: the rows r of the table's model columns become their updated states
                state = IMMState(tr.x_models, tr.P_models, tr.mu)
                # a Mode S roll angle: evidence of the mode beside the position (eq. 5)
                roll = evidence = have = None
                if cl.roll_deg is not None and self.imm.params.roll_dap:
                    have = np.isfinite(cl.roll_deg[matched[init]])
                    if have.any():
                        roll = self.imm.roll_log_likelihoods(cl.roll_deg[matched[init]], tr.x[r, 1], tr.x[r, 4])
                        evidence = Evidence(np.zeros(r.size), weight=(~tr.roll_distrust[r]).astype(float))
                x_c[init], P_c[init] = self.imm.predict_update_rows(
                    state, r, dt_s[init], z_m[init], R_m2[init], roll, evidence
                )
                if evidence is not None and have is not None:
                    self._check_roll(r[have], evidence.log_bayes_factor[have])
            else:
                x, P = self.manoeuvres.predict(self.filter, tr.x[rows], tr.P[rows], dt_s, tr.manoeuvre[rows])
                x, P, nu, S = self.filter.update(x[init], P[init], z_m[init], R_m2[init])
                x_c[init], P_c[init] = x, P
                tr.nis_avg[r], tr.manoeuvre[r] = self.manoeuvres.detect(tr.nis_avg[r], tr.manoeuvre[r], nu, S)
        two = ~init
        if two.any():
            # A first position without any height and a second with one (an SSR's): the
            # first one's height error does not cancel in their difference, so it enters
            # with its whole covariance, floor included (_floor_no_height), not its noise.
            R1 = tr.R1_m2[rows[two]]
            biased = ~np.isfinite(tr.alt_x[rows[two], 0]) & np.isfinite(cl.fl[matched[two]])
            if biased.any():
                R1 = np.where(biased[:, None, None], cov_pos_m2(tr.P[rows[two]]), R1)
            z1, t1 = tr.z1_m[rows[two]], tr.t_state_s[rows[two]]
            if again is not None and again.any():
                a, ma = again[two], matched[two]
                assert cl.z0_m is not None and cl.R0_m2 is not None and cl.t0_s is not None
                z1, R1, t1 = z1.copy(), R1.copy(), t1.copy()
                z1[a], R1[a], t1[a] = cl.z0_m[ma[a]], cl.R0_m2[ma[a]], cl.t0_s[ma[a]]
            x, P = two_point_initiation(
                z1,
                R1,
                z_m[two],
                R_m2[two],
                cl.t_s[matched[two]] - t1,
                self.filter.sigma_m_mps2,
                self.one_plot_vel_var_m2ps2 if self.settings.tracking.two_point_prior else None,
            )
            x_c[two], P_c[two] = x, P
            tr.initiated[rows[two]] = True
            self._imm_initiate(rows[two], x, P)
        tr.x[rows], tr.P[rows] = x_c, P_c
        if cl.bias_sens is not None:
            self._update_bias_sens(cl, matched, rows, init)
        dap_used = rows[:0]
        if cl.dap_v_mps is not None:
            dap_used = self._update_velocity(cl, matched, rows)
        if cl.air_v_mps is not None:
            self._air_velocity_and_wind(cl, matched, rows, dap_used)
        alt_x, alt_P = self.alt_filter.predict(tr.alt_x[rows], tr.alt_P[rows], dt_s)
        tr.alt_x[rows], tr.alt_P[rows] = self.alt_filter.update(alt_x, alt_P, cl.fl[matched])
        self._floor_no_height(rows, cl.height_cov_m2, matched)
        tr.t_state_s[rows] = cl.t_s[matched]
        tr.updates[rows] += 1
        tr.last_update_t_s[rows] = t_ref_s
        tr.mode_s[rows] = np.where(cl.mode_s[matched] >= 0, cl.mode_s[matched], tr.mode_s[rows])
        tr.mode3a[rows] = np.where(cl.mode3a[matched] >= 0, cl.mode3a[matched], tr.mode3a[rows])
        tr.sources[rows] = tr.update_sources[rows] = cl.sources[matched]
        tr.seen_by[rows] |= cl.sources[matched]
        tr.revisit_s[rows] = cl.revisit_s[matched]
        return rows.astype(np.int64)

    def _innovations_to_registration(
        self, cl: ClusterMeasurements, matched: np.ndarray, rows: np.ndarray, pred: Prediction, t_ref_s: float
    ) -> None:
        """The two-stage registration's evidence (registration.py): the innovation of each
        track about to be Kalman-updated, nu = z_f - x^-_p (its prediction to the cluster's
        time, from the period's: x^-_p = p + v (t_c - t_ref)), with covariance P^-_pp + R_f
        and sensitivity F - B to the biases. Only quiet tracks (the IMM's quiet mode at
        ``innovation_quiet_prob`` or above; the Singer filter: no manoeuvre detected) of three
        updates or more, whose cluster's plots all have Mode C, in a period whose plots the
        registration learns from (``update_interval_s``)."""
        reg = self.registration
        assert cl.bias_sens is not None and cl.all_heights is not None
        if self._reg_fed_t_s != t_ref_s:
            return
        tr = self.tracks
        if self.imm is not None:
            quiet = tr.mu[rows, QUIET] >= reg.params.innovation_quiet_prob
        else:
            quiet = ~tr.manoeuvre[rows]
        use = quiet & (tr.updates[rows] >= 3) & cl.all_heights[matched]
        use &= ~np.isnan(tr.bias_sens[rows, 0, 0, 0])  # a sensitivity not known (a state read without it)
        k, r = matched[use], rows[use]
        part = reg.rotating_subset(tr.track_id[r], r.size)  # at most max_clusters_per_update
        if part is not None:
            k, r = k[part], r[part]
        if not r.size:
            return
        dt_s = (cl.t_s[k] - t_ref_s)[:, None]
        nu = cl.z_m[k] - (position_m(pred.x[r]) + velocity_mps(pred.x[r]) * dt_s)
        cov = cov_pos_m2(pred.P[r]) + cl.R_m2[k]
        reg.update_from_innovations(t_ref_s, cl.bias_sens, k, tr.bias_sens, r, nu, cov, applied=self._reg_applied)

    def _update_bias_sens(
        self, cl: ClusterMeasurements, matched: np.ndarray, rows: np.ndarray, init: np.ndarray
    ) -> None:
        """Each updated track's sensitivity to the radars' biases, B (2, R, 4) of its position
        (registration.py, the two-stage section). A Kalman update x+ = x- + K (z_f - x-_p)
        gives B+ = B- + K (F - B-), K the gain on the position: P+_pp R_f^-1 for a Kalman
        filter, and for the IMM the mode-weighted sum of its models' gains, sum_j mu_j
        P+_j,pp R_f^-1 (each model updates from the same mixed sensitivity; the mode
        probabilities' own dependence on z is left out). A track's prediction keeps B (the
        velocity's sensitivity is left out: it changes slowly with the radars that see the
        track). The two-point initiation (Shu §4) takes its position from the second
        measurement: B = F (with ``two_point_prior`` the first pulls it a little: left out).
        A track whose B is not known (NaN: a state read without it) takes the update's F."""
        assert cl.bias_sens is not None
        tr = self.tracks
        if init.any():
            k, r = matched[init], rows[init]
            unknown = np.isnan(tr.bias_sens[r, 0, 0, 0])  # a state read without it: the update's F
            if unknown.any():
                tr.bias_sens[r[unknown]] = cl.bias_sens.dense(k[unknown], tr.n_radars)
                k, r = k[~unknown], r[~unknown]
            if self.imm is not None:
                cov_post, weight = tr.P_models, tr.mu
            else:
                cov_post, weight = tr.P[:, None], np.ones((len(tr), 1))
            reg_kernels.update_sensitivity(
                tr.bias_sens,
                r,
                cov_post,
                weight,
                np.ascontiguousarray(cl.R_m2[k]),
                cl.bias_sens.values,
                cl.bias_sens.radars,
                k,
            )
        two = ~init
        if two.any():
            tr.bias_sens[rows[two]] = cl.bias_sens.dense(matched[two], tr.n_radars)

    def _follow_registration(self) -> None:
        """At the end of a period: the registration's correction for the next period's plots
        (``_reg_applied``). With the two-stage registration, every track follows its change
        dc: moved by -sum_r B_r dc_r (B its sensitivity to the biases, ``bias_sens``), as if
        all its plots had been corrected with the new estimate (Friedland 1969's corrected
        estimate x = x_bias-free + B b, b now c_new); so is the first measurement of a track
        of one update (its B is that measurement's). Without this, a track kept for minutes
        what it learnt from plots corrected with older estimates (the bench's ADS-B case,
        straight flight: 23.2 m, 21.2 m with the true biases removed from the start). Not
        moved, each being used within a scan or two: a measurement held beside a track
        (_hold_far, or an alternative first point), the first measurement of a track of two
        updates, and the address memory's last positions. A track whose B is not known
        (NaN) is not moved."""
        new = self.registration.correction()
        tr = self.tracks
        if tr.n_radars and len(tr):
            delta = new - self._reg_applied
            if np.any(delta != 0.0):
                shift = -(tr.bias_sens.reshape(len(tr), 2, -1) @ delta.reshape(-1))
                shift[~np.isfinite(shift)] = 0.0  # a sensitivity not known (NaN): not moved
                tr.x[:, 0] += shift[:, 0]
                tr.x[:, 3] += shift[:, 1]
                if tr.n_models:
                    tr.x_models[:, :, 0] += shift[:, None, 0]
                    tr.x_models[:, :, 3] += shift[:, None, 1]
                one = tr.updates == 1
                tr.z1_m[one] += shift[one]
        self._reg_applied = new

    def _birth_velocity_refuted(self, cl: ClusterMeasurements, matched: np.ndarray, rows: np.ndarray) -> np.ndarray:
        """At the second update of a track that started with the aircraft's own velocity
        (_initiate): is that velocity refuted by the two positions, (z₂ − z₁)/dt outside
        the χ² gate of (R₁ + R₂)/dt² + its own covariance? Nothing checked the report when it
        started the track (a misread register, a speed of 0 from an aircraft in the air); such
        a track is initiated again from the two positions (Shu §4), as any other. (K,) bool."""
        tr = self.tracks
        out = np.zeros(rows.size, bool)
        b = np.flatnonzero(tr.initiated[rows] & (tr.updates[rows] == 1))
        if not b.size:
            return out
        r = rows[b]
        dt_s = cl.t_s[matched[b]] - tr.t_state_s[r]
        ok = dt_s > 0.0
        if not ok.any():
            return out
        b, r, dt_s = b[ok], r[ok], dt_s[ok]
        nu = (cl.z_m[matched[b]] - tr.z1_m[r]) / dt_s[:, None] - velocity_mps(tr.x[r])
        C = (tr.R1_m2[r] + cl.R_m2[matched[b]]) / (dt_s**2)[:, None, None] + cov_vel(tr.P[r])
        d2 = np.einsum("ki,kij,kj->k", nu, inv_2x2(C), nu)
        out[b] = d2 > self.clustering.gate_chi2
        self.counters["tracks_birth_velocity_refuted"] += int(out.sum())
        return out

    def _update_velocity(
        self, cl: ClusterMeasurements, matched: np.ndarray, rows: np.ndarray, birth: bool = False
    ) -> np.ndarray:
        """The tracks ``rows`` (just updated with their clusters ``matched``) whose cluster
        carries the aircraft's own velocity (Mode S BDS 5,0, ``_dap_velocity``): the IMM's
        second update with it (imm.IMMFilter.velocity_update_rows). Its covariance is the
        ground speed's σ along the track and the track angle's across it (speed × σ, never
        below the speed's σ: slow, the direction is as uncertain as the speed). Returns the
        rows updated."""
        assert self.imm is not None and cl.dap_v_mps is not None and cl.dap_age_s is not None
        has = np.isfinite(cl.dap_v_mps[matched, 0])
        if not has.any():
            return rows[:0]
        p = self.imm.params
        r, k = rows[has], matched[has]
        v = cl.dap_v_mps[k]
        R = self._velocity_R(v)
        if birth:  # nothing to check a new track's report against: it starts less sure of it
            R += p.velocity_birth_sigma_mps**2 * np.eye(2)
        return self._velocity_update_rows(r, v, R, cl.dap_age_s[k], "updates_velocity")

    def _velocity_update_rows(
        self, rows: np.ndarray, v: np.ndarray, R: np.ndarray, age_s: np.ndarray, counter: str
    ) -> np.ndarray:
        """The IMM's velocity update of the tracks ``rows`` with reports v, R, ``age_s`` old
        (imm.IMMFilter.velocity_update_rows) and their combined x, P; the reports used counted
        under ``counter``, the others as refused. Returns the rows updated."""
        assert self.imm is not None
        tr = self.tracks
        state = IMMState(tr.x_models, tr.P_models, tr.mu)
        x, P, used = self.imm.velocity_update_rows(state, rows, v, R, age_s)
        tr.x[rows], tr.P[rows] = x, P
        self.counters[counter] += int(used.sum())
        self.counters["velocity_reports_refused"] += int((~used).sum())
        updated: np.ndarray = rows[used]
        return updated

    def _velocity_R(self, v: np.ndarray) -> np.ndarray:
        """The covariance (n, 2, 2) of velocity reports v (n, 2): the ground speed's σ along
        the track, the track angle's across it (speed × σ, never below the speed's σ: slow,
        the direction is as uncertain as the speed)."""
        assert self.imm is not None
        p = self.imm.params
        speed = np.hypot(v[:, 0], v[:, 1])
        # the track's direction; at a standstill (an aircraft on the ground, or opposite
        # reports averaged) any unit vector: R is then σ² I
        along = np.where(speed[:, None] > 1e-3, v / np.maximum(speed, 1e-3)[:, None], np.array([1.0, 0.0]))
        across = np.stack([along[:, 1], -along[:, 0]], axis=1)
        cross_var = np.maximum(speed * math.radians(p.velocity_track_sigma_deg), p.velocity_speed_sigma_mps) ** 2
        R: np.ndarray = p.velocity_speed_sigma_mps**2 * along[:, :, None] * along[:, None, :]
        R += cross_var[:, None, None] * across[:, :, None] * across[:, None, :]
        return R

    def _refused_with_velocity(self, raw: PlotChunk, refused: np.ndarray) -> PlotChunk | None:
        """Of the plots ``refused`` by the live gate, the Mode S ones that carry the aircraft's
        own velocity (``velocity_from_refused_plots``): kept for :meth:`_update_velocity_of_refused`."""
        if self.imm is None or not self.imm.params.velocity_dap or not self.imm.params.velocity_from_refused_plots:
            return None
        keep = refused & (raw.mode_s >= 0) & np.isfinite(raw.ground_speed_mps) & np.isfinite(raw.track_angle_deg)
        return raw.select(keep) if keep.any() else None

    def _update_velocity_of_refused(self) -> np.ndarray:
        """The velocity of the period's Mode S plots whose position the live gate refused,
        for the live track of each address whose velocity is known (the older of two, as
        association.address_pairs takes; the reply is the aircraft's, only the plot's
        position is off): the IMM's velocity update
        (imm.IMMFilter.velocity_update_rows) at the track's own time, the report
        ``velocity_age_s`` old at its plot's time, so ``velocity_age_s`` + (the track's time −
        the plot's) before the state (negative: after it; the state's acceleration carries
        it). One report a track, its latest. Converted at the track's position
        (geo.coordinates.ground_velocity_to_plane). Returns the rows updated."""
        assert self.imm is not None
        chunk, self._refused_velocity = self._refused_velocity, None
        tr = self.tracks
        if chunk is None or not len(tr):
            return np.empty(0, np.int64)
        self.counters["plots_velocity_refused_position"] += len(chunk)
        p, t = association.address_pairs(chunk.mode_s, np.ones(len(chunk), bool), tr.mode_s, tr.velocity_known)
        if not p.size:
            return np.empty(0, np.int64)
        latest = np.argsort(chunk.t_s[p], kind="stable")[::-1]
        _, first = np.unique(t[latest], return_index=True)  # each track's latest report
        i, rows = p[latest[first]], t[latest[first]]
        alt_m = mode_c_height_m(chunk.fl[i], *self.mode_c_met)
        vx, vy = ground_velocity_to_plane(
            self.plane, tr.x[rows, 0], tr.x[rows, 3], chunk.ground_speed_mps[i], chunk.track_angle_deg[i], alt_m
        )
        v = np.stack([vx, vy], axis=1)
        age_s = self.imm.params.velocity_age_s + (tr.t_state_s[rows] - chunk.t_s[i])
        return self._velocity_update_rows(rows, v, self._velocity_R(v), age_s, "updates_velocity_refused_position")

    def _check_roll(self, rows: np.ndarray, log_bf: np.ndarray) -> None:
        """The roll reports' check, per track: s ← memory · s + log BF, the Bayes factor by
        which the report made the track's position more likely (imm.Evidence). Reports the
        positions keep contradicting (a transponder's roll stuck or wrong) are set aside below
        ``roll_distrust_below`` and count again above ``roll_trust_above``."""
        assert self.imm is not None
        p, tr = self.imm.params, self.tracks
        distrusted = tr.roll_distrust[rows]
        self.counters["updates_roll"] += int((~distrusted).sum())
        tr.roll_check[rows] = check = p.roll_check_memory * tr.roll_check[rows] + log_bf
        now = np.where(distrusted, check < p.roll_trust_above, check < p.roll_distrust_below)
        self.counters["tracks_roll_set_aside"] += int((now & ~distrusted).sum())
        tr.roll_distrust[rows] = now

    def _refuse_impossible_pairs(self, cl: ClusterMeasurements) -> None:
        """A one-plot track without altitude and a second cluster without any height: their
        two positions share the unknown height's error, so their difference has the noise
        alone (R1 + R2), and a pair further apart than ``max_speed_mps`` dt plus
        sqrt(gate_chi2) noise standard deviations (largest eigenvalue) is no aircraft. The
        χ² gate of the one-plot track spans every height (its covariance floor) and, near
        a radar, kilometres: primary clutter paired inside it at 800-1,500 m/s and was
        confirmed. Such a cluster starts a track of its own instead (in place)."""
        if cl.height_cov_m2 is None:
            return
        tr = self.tracks
        k = np.flatnonzero(cl.valid & (cl.track_row >= 0))
        rows = cl.track_row[k]
        no_h_cluster = np.trace(cl.height_cov_m2[k], axis1=1, axis2=2) > 0.0
        pair = ~tr.initiated[rows] & ~np.isfinite(tr.alt_x[rows, 0]) & no_h_cluster
        if not pair.any():
            return
        k, rows = k[pair], rows[pair]
        far = self._beyond_reach(tr.z1_m[rows], tr.R1_m2[rows], tr.t_state_s[rows], cl.z_m[k], cl.R_m2[k], cl.t_s[k])
        if far.any():
            cl.track_row[k[far]] = -1
            self.counters["primary_pairs_refused"] += int(far.sum())

    # ------------------------------------------------ one identity code, a wild early plot
    def _code_alternatives(self, cl: ClusterMeasurements) -> np.ndarray:
        """An SSR aircraft (no Mode S address, no velocity report) with a wild plot among its
        first two: one plot cannot tell which is wild. Where the second was out of reach of
        the first, each started a one-plot track of the aircraft's code, and the third plot
        joined one of them by the association's nearest neighbour; where it was within reach,
        the two made a two-point start (Shu §4) flying the wild plot's error over one scan
        (2-6 km / 12 s), and the third plot missed it and started a track of its own. Either
        way the aircraft's next plot missed the wrong start's gate too, started yet another
        track, and the aircraft was confirmed 24-36 s late (issue 15 item 7, 3 % wild plots,
        1,000×10: seeds 2 and 3, most of their settled GOSPA excess over the clean twin). The
        fourth plot tells, by which three of the plots lie on one straight line
        (initiation.three_point_d2 within ``gate_chi2``, the near-constant-velocity model's
        white acceleration: :meth:`_on_line`). Tracks of one identity code (Mode 3/A, not in
        association.NON_IDENTITY_MODE3A), none with a Mode S address; in place, three steps
        (``code_alternatives``):

        * :meth:`_restart_from_code_alternative`: a new cluster on the line from the plot a
          young track holds beside it through the track's own measurement joins the track,
          which starts again from the held plot;
        * :meth:`_first_from_code_track`: a cluster making a one-plot track's two-point start,
          on the line from a young track's first plot through the one plot: that first plot
          becomes the start's first point, and the young track is removed;
        * :meth:`_hold_code_alternative`: a cluster joining one of two one-plot tracks out of
          reach of each other: the other's plot is held beside it, and the other is removed.

        A track that takes over another keeps the older id. Returns the rows to remove
        (:meth:`_merge_identities`)."""
        tr = self.tracks
        if not self.clustering.code_alternatives or not len(tr):
            return np.empty(0, np.int64)
        matched = np.zeros(len(tr), bool)
        matched[cl.track_row[cl.valid & (cl.track_row >= 0)]] = True
        self._restart_from_code_alternative(cl, matched)
        first = self._first_from_code_track(cl, matched)
        return np.concatenate([first, self._hold_code_alternative(cl, matched)])

    def _on_line(
        self,
        first: tuple[np.ndarray, np.ndarray, np.ndarray],
        second: tuple[np.ndarray, np.ndarray, np.ndarray],
        third: tuple[np.ndarray, np.ndarray, np.ndarray],
    ) -> np.ndarray:
        """initiation.three_point_d2 of three measurements (z, R, t), with the white
        acceleration density 2ασ_m² of the near-constant-velocity model (the IMM's quiet one,
        else the Singer filter's). (n,)."""
        if self.imm is not None:
            q = 2.0 * self.imm.params.quiet_alpha_per_s * self.imm.params.quiet_sigma_m_mps2**2
        else:
            q = 2.0 * self.filter.alpha_per_s * self.filter.sigma_m_mps2**2
        return three_point_d2(*first, *second, *third, q)

    def _young_code_pairs(self, cand: np.ndarray, k: np.ndarray, code_k: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """All pairs (track row, cluster) of the tracks ``cand`` and clusters ``k`` (their codes
        ``code_k``) with one code."""
        i, j = np.nonzero(self.tracks.mode3a[cand][:, None] == code_k[None, :])
        return cand[i], k[j]

    @staticmethod
    def _nearest_pairs(r: np.ndarray, k: np.ndarray, d2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Of the pairs (r, k), the nearest by d² first, each r and each k once."""
        take_r: list[int] = []
        take_k: list[int] = []
        for j in np.argsort(d2, kind="stable"):
            if r[j] not in take_r and k[j] not in take_k:
                take_r.append(int(r[j]))
                take_k.append(int(k[j]))
        return np.asarray(take_r, np.int64), np.asarray(take_k, np.int64)

    def _take_over(self, r: int, i: int) -> None:
        """Track row ``r`` takes over the aircraft of row ``i`` (removed by the caller): the
        radars that saw it, and its id where older (ids are issued in order)."""
        tr = self.tracks
        tr.seen_by[r] |= tr.seen_by[i]
        if tr.track_id[i] < tr.track_id[r]:
            tr.track_id[r], tr.track_id[i] = tr.track_id[i], tr.track_id[r]

    def _code_clusters_of_one_plot_tracks(self, cl: ClusterMeasurements) -> tuple[np.ndarray, np.ndarray]:
        """The clusters joining one-plot tracks without a Mode S address and their rows,
        cluster and track carrying one identity code, not yet given another first point."""
        tr = self.tracks
        k = np.flatnonzero(cl.valid & (cl.track_row >= 0))
        if cl.t0_s is not None:
            k = k[~np.isfinite(cl.t0_s[k])]
        rows = cl.track_row[k]
        sel = (
            ~tr.initiated[rows]
            & (tr.updates[rows] == 1)
            & (tr.mode_s[rows] < 0)
            & (cl.mode_s[k] < 0)
            & association.is_identity_code(tr.mode3a[rows])
            & (cl.mode3a[k] == tr.mode3a[rows])
        )
        return k[sel], rows[sel]

    def _restart_from_code_alternative(self, cl: ClusterMeasurements, matched: np.ndarray) -> None:
        """Young tracks (two updates, unmatched this period) that hold an alternative first
        plot (:meth:`_hold_code_alternative`), and new clusters of their code: a cluster on
        the line from the held plot through the track's measurement (:meth:`_on_line`) joins
        the track, which starts again from the held plot by the two-point initiation
        (Shu §4; ``tracks_code_restarted``): the track's own first plot was the wild one."""
        tr = self.tracks
        cand = np.flatnonzero(
            tr.initiated & (tr.updates == 2) & (tr.status == TENTATIVE) & (tr.mode_s < 0) & tr.held_alternative
            & ~matched & association.is_identity_code(tr.mode3a)
        )  # fmt: skip
        new = np.flatnonzero(cl.valid & (cl.track_row < 0) & (cl.mode_s < 0))
        if not cand.size or not new.size:
            return
        r, k = self._young_code_pairs(cand, new, cl.mode3a[new])
        later = cl.t_s[k] > tr.t_state_s[r]
        r, k = r[later], k[later]
        if not r.size:
            return
        d2 = self._on_line(
            (tr.held_z_m[r], tr.held_R_m2[r], tr.held_t_s[r]),
            (position_m(tr.x[r]), cov_pos_m2(tr.P[r]), tr.t_state_s[r]),
            (cl.z_m[k], cl.R_m2[k], cl.t_s[k]),
        )
        ok = d2 <= self.clustering.gate_chi2
        rr, kk = self._nearest_pairs(r[ok], k[ok], d2[ok])
        if not rr.size:
            return
        cl.track_row[kk] = rr
        matched[rr] = True
        self._initiate_from_held(cl, kk, rr)
        tr.held_t_s[rr] = np.nan
        self.counters["tracks_code_restarted"] += int(rr.size)

    def _first_from_code_track(self, cl: ClusterMeasurements, matched: np.ndarray) -> np.ndarray:
        """Clusters making the two-point start of a one-plot track (:meth:`_code_clusters_of_one_plot_tracks`),
        and young tracks of their code (two updates, unmatched this period, their first plot
        earlier than the one plot): where the cluster lies on the line from the young track's
        first plot through the one plot (:meth:`_on_line`), the young track's second plot was
        the wild one and the one plot the aircraft's next, which missed the young track's
        gate. The one-plot track starts from the young track's first plot instead of its own
        (two-point initiation, Shu §4), counts that plot as an update, and takes the young
        track over (``tracks_code_first``). Returns the young tracks' rows, to remove."""
        tr = self.tracks
        k, rows = self._code_clusters_of_one_plot_tracks(cl)
        cand = np.flatnonzero(
            tr.initiated & (tr.updates == 2) & (tr.status == TENTATIVE) & (tr.mode_s < 0) & ~matched
            & np.isfinite(tr.t1_s) & association.is_identity_code(tr.mode3a)
        )  # fmt: skip
        if not k.size or not cand.size:
            return np.empty(0, np.int64)
        young, j = self._young_code_pairs(cand, np.arange(k.size), tr.mode3a[rows])
        r = rows[j]
        earlier = (tr.t1_s[young] < tr.t_state_s[r]) & (tr.t_state_s[young] < tr.t_state_s[r])
        young, j, r = young[earlier], j[earlier], r[earlier]
        if not young.size:
            return np.empty(0, np.int64)
        one_plot = (tr.z1_m[r], tr.R1_m2[r], tr.t_state_s[r])
        cluster = (cl.z_m[k[j]], cl.R_m2[k[j]], cl.t_s[k[j]])
        d2 = self._on_line((tr.z1_m[young], tr.R1_m2[young], tr.t1_s[young]), one_plot, cluster)
        # and not on the line from the young track's own second point: then its first plot
        # was the wild one (the first plot weighs only τ₂/τ₁ in d², ⅓-¼ after a missed scan;
        # a review's grid, a wild first plot and a scan missed: 43 bad starts against 15
        # without the rule, 20 with this test)
        d2_second = self._on_line(
            (position_m(tr.x[young]), cov_pos_m2(tr.P[young]), tr.t_state_s[young]), one_plot, cluster
        )
        ok = (d2 <= self.clustering.gate_chi2) & (d2_second > self.clustering.gate_chi2)
        yy, jj = self._nearest_pairs(young[ok], j[ok], d2[ok])
        if not yy.size:
            return yy
        kk, rr = k[jj], rows[jj]
        self._initiate_from(cl, kk, tr.z1_m[yy], tr.R1_m2[yy], tr.t1_s[yy])
        tr.updates[rr] += 1  # the young track's first plot: the aircraft's, on the line
        for r_, y_ in zip(rr, yy):
            self._take_over(int(r_), int(y_))
        self.counters["tracks_code_first"] += int(yy.size)
        return yy

    def _hold_code_alternative(self, cl: ClusterMeasurements, matched: np.ndarray) -> np.ndarray:
        """Clusters joining a one-plot track (:meth:`_code_clusters_of_one_plot_tracks`), and
        another unmatched one-plot track of that code whose plot is out of reach of the
        first's (:meth:`_beyond_reach`: one of the two is wild) and within reach of the
        cluster: the other's plot is held beside the track (``held_*``, before its state's
        time: an alternative first point, :meth:`_restart_from_code_alternative`), and the
        track takes the other over (``tracks_code_alternatives``). The track's two-point
        start (Shu §4) still pairs the cluster with its own plot. Returns the rows taken
        over, to remove."""
        tr = self.tracks
        k, rows = self._code_clusters_of_one_plot_tracks(cl)
        lone = np.flatnonzero(~tr.initiated & (tr.updates == 1) & (tr.mode_s < 0) & ~matched)
        if not k.size or not lone.size:
            return np.empty(0, np.int64)
        absorbed: list[int] = []
        for kk, r in zip(k, rows):  # a handful per period at most
            c = lone[(tr.mode3a[lone] == tr.mode3a[r]) & ~np.isin(lone, absorbed)]
            if not c.size:
                continue
            other = (tr.z1_m[c], tr.R1_m2[c], tr.t_state_s[c])
            apart = self._beyond_reach(*other, tr.z1_m[r], tr.R1_m2[r], tr.t_state_s[r])
            reach = ~self._beyond_reach(*other, cl.z_m[kk], cl.R_m2[kk], cl.t_s[kk])
            c = c[apart & reach]
            if not c.size:
                continue
            i = int(c[np.argmax(tr.t_state_s[c])])
            tr.held_z_m[r], tr.held_R_m2[r], tr.held_t_s[r] = tr.z1_m[i], tr.R1_m2[i], tr.t_state_s[i]
            tr.held_sources[r] = tr.update_sources[i]
            self._take_over(int(r), i)
            absorbed.append(i)
        self.counters["tracks_code_alternatives"] += len(absorbed)
        return np.asarray(absorbed, np.int64)

    def _beyond_reach(
        self,
        z_a_m: np.ndarray,
        R_a_m2: np.ndarray,
        t_a_s: np.ndarray,
        z_b_m: np.ndarray,
        R_b_m2: np.ndarray,
        t_b_s: np.ndarray,
    ) -> np.ndarray:
        """Pairs of measurements (n, 2) with covariances (n, 2, 2) (either side may be one
        measurement (2,), (2, 2) for all n) further apart than an
        aircraft flies between their times at ``max_speed_mps``, plus sqrt(gate_chi2)
        standard deviations of their noise along its largest direction (the largest
        eigenvalue of R_a + R_b): no one aircraft's."""
        noise_m = np.sqrt(np.linalg.eigvalsh(R_a_m2 + R_b_m2)[:, -1])
        reach_m = self.clustering.max_speed_mps * np.abs(t_b_s - t_a_s) + math.sqrt(self.clustering.gate_chi2) * noise_m
        return np.asarray(np.hypot(*(z_b_m - z_a_m).T) > reach_m)

    def _floor_no_height(self, rows: np.ndarray, height_cov_m2: np.ndarray | None, clusters: np.ndarray) -> None:
        """A track that has no altitude after its update, from a cluster of plots without
        any height: its position covariance is kept at least the unknown height's part of
        its plots' error (initiation.floor_covariance; issue 15: converted at a guessed
        height, such a track sat up to a kilometre beside its aircraft and the aircraft's
        first SSR plots started a second track). The initiation spans every height so."""
        if height_cov_m2 is None or not rows.size:
            return
        tr = self.tracks
        B = height_cov_m2[clusters]
        sel = ~np.isfinite(tr.alt_x[rows, 0]) & (np.trace(B, axis1=1, axis2=2) > 0.0)
        if not sel.any():
            return
        r = rows[sel]
        tr.P[r] = floor_covariance(tr.P[r], B[sel])
        if self.imm is not None:
            tr.P_models[r] = floor_covariance(tr.P_models[r], B[sel])

    # -------------------------------------------------------------- initiate
    def _initiate(self, cl: ClusterMeasurements, t_ref_s: float) -> np.ndarray:
        """Clusters no track claims (Shu §2 cases 1 and 3): new tentative tracks holding
        their one fused measurement and a wide velocity prior (initiation.py). Returns
        their rows."""
        new_cl = np.flatnonzero(cl.valid & (cl.track_row < 0))
        n_new = int(new_cl.size)
        self.counters["tracks_initiated"] += n_new
        if not n_new:
            return np.empty(0, np.int64)
        tr = self.tracks
        new = tr.append(n_new)
        tr.x[new], tr.P[new] = one_point_initiation(
            cl.z_m[new_cl], cl.R_m2[new_cl], self.one_plot_vel_var_m2ps2, self.filter.sigma_m_mps2
        )
        self._imm_initiate(new, tr.x[new], tr.P[new])
        tr.t_state_s[new] = cl.t_s[new_cl]
        tr.z1_m[new], tr.R1_m2[new], tr.t1_s[new] = cl.z_m[new_cl], cl.R_m2[new_cl], cl.t_s[new_cl]
        if cl.bias_sens is not None:
            tr.bias_sens[new] = cl.bias_sens.dense(new_cl, tr.n_radars)
        tr.alt_x[new], tr.alt_P[new] = self.alt_filter.initiate(cl.fl[new_cl])
        self._floor_no_height(np.arange(new.start, new.stop), cl.height_cov_m2, new_cl)
        if cl.dap_v_mps is not None:
            # the aircraft's own velocity: known from the first plots, no two-point start needed;
            # only where two radars agree on the position (one plot may be a wild one, and a
            # track with a velocity gates the next plots tightly: the true ones would start
            # another track beside it)
            agree = radar_count(cl.sources[new_cl]) >= 2
            used = self._update_velocity(
                cl, new_cl[agree], np.arange(new.start, new.stop, dtype=np.int64)[agree], birth=True
            )
            tr.initiated[used] = True
            self.counters["tracks_initiated_with_velocity"] += int(used.size)
        tr.updates[new] = 1
        tr.first_t_s[new] = tr.last_update_t_s[new] = t_ref_s
        tr.mode_s[new] = cl.mode_s[new_cl]
        tr.mode3a[new] = cl.mode3a[new_cl]
        tr.revisit_s[new] = cl.revisit_s[new_cl]
        tr.sources[new] = tr.seen_by[new] = tr.update_sources[new] = cl.sources[new_cl]
        if len(self.address_memory):  # an address seen again soon after its track ended: its id back
            old_id = self.address_memory.recall(
                cl.mode_s[new_cl],
                cl.z_m[new_cl],
                cl.R_m2[new_cl],
                cl.t_s[new_cl],
                self.clustering.max_speed_mps,
                self.rules.reacquire_within_s,
            )
            back = old_id >= 0
            if back.any():
                rows = np.arange(new.start, new.stop)[back]
                tr.track_id[rows] = old_id[back]  # a new track otherwise: its age and M-of-N window start now
                self.counters["tracks_reacquired"] += int(back.sum())
        return np.arange(new.start, new.stop, dtype=np.int64)

    # ----------------------------------------------------------------- merge
    def _merge_identities(self, out: Prediction, absorbed: np.ndarray) -> tuple[Prediction, np.ndarray]:
        """Two tracks never carry one Mode S address at once: they become one, with the
        oldest id (track_management.merge_same_address). Association already sends a live
        track's address to that track (association.identity_pairs), so this is rare: two
        new tracks started on one address in the same period, or a track that acquired its
        address late. First, the rows ``absorbed`` (one-plot tracks whose plot another track
        of their code holds, :meth:`_code_alternatives`) are removed. Returns ``out``
        without the merged-away rows, and their ids."""
        gone = np.empty(0, np.int64)
        if absorbed.size:
            keep = np.ones(len(self.tracks), bool)
            keep[absorbed] = False
            gone = self.tracks.track_id[absorbed].copy()
            self.tracks.keep(keep)
            out = out.select(keep)
        keep, merged = merge_same_address(self.tracks, self.rules.confirm_updates, (out.x, out.P, out.alt_x, out.alt_P))
        if merged.size:
            self.counters["tracks_merged"] += int(merged.size)
            out = out.select(keep)
        return out, np.concatenate([gone, merged])

    # ---------------------------------------------------------------- manage
    def _manage(self, t_ref_s: float) -> np.ndarray:
        """Track life cycle (track_management.py): confirm, coast, end. Returns ended ids."""
        tr = self.tracks
        if self.rules.reacquire_within_s > 0:
            # where the address was last seen: a measurement held far from the track
            # (_hold_far) is newer than its state, and the aircraft's plots resume from there
            held = np.isfinite(tr.held_t_s) & ~tr.held_alternative  # a far one, not an alternative first
            snap = (
                tr.track_id.copy(),
                tr.mode_s.copy(),
                np.where(held[:, None], tr.held_z_m, position_m(tr.x)),
                np.where(held[:, None, None], tr.held_R_m2, cov_pos_m2(tr.P)),
                np.where(held, tr.held_t_s, tr.t_state_s),
            )
        log_miss = None
        if self.rules.end_miss_probability > 0 and len(tr):
            xy_m = position_m(tr.x) + velocity_mps(tr.x) * (t_ref_s - tr.t_state_s)[:, None]
            swept_until_s = np.minimum(self.buffer.watermark_s, t_ref_s)  # deterministic: not past the period
            # a measurement held far from the track (_hold_far) is its address seen, not missed
            far_held = np.isfinite(tr.held_t_s) & ~tr.held_alternative
            seen_t_s = np.where(far_held, np.fmax(tr.last_update_t_s, tr.held_t_s), tr.last_update_t_s)
            seen_t_s = np.fmax(seen_t_s, tr.address_seen_t_s)  # its address refused as wild: seen
            log_miss = log_miss_probability(
                tr.seen_by,
                xy_m,
                seen_t_s,
                swept_until_s,
                self.site_xy_m,
                self.max_range_m,
                self.rotation_s,
                self.pd,
            )
        ended = apply_life_cycle(tr, t_ref_s, self.rules, log_miss, self.counters)
        self.counters["tracks_ended"] += int(ended.size)
        if self.rules.reacquire_within_s > 0:
            if ended.size:
                gone = np.isin(snap[0], ended)
                self.address_memory.remember(*(a[gone] for a in snap))
            self.address_memory.forget_older_than(t_ref_s - self.rules.reacquire_within_s)
        return ended

    # ---------------------------------------------------------------- output
    def _output(self, period: int, t_ref_s: float, ended: np.ndarray, out: Prediction) -> TrackColumns:
        tr = self.tracks
        x, P, alt_x = out.x, out.P, out.alt_x
        t_track_s = None
        # A track of one update has no velocity yet (initiation.py: its velocity is the wide
        # prior): it is reported where and when it was measured, velocity nil, not carried
        # to t_ref at zero speed. A Mode S address, or two radars beside a transponder reply,
        # confirm it at once (track_management.apply_life_cycle).
        young = np.flatnonzero(~tr.velocity_known)
        # nor a vertical rate before its second update: a track started with the aircraft's
        # own horizontal velocity (_initiate) has one, and only the altitude filter's prior rate
        one = np.flatnonzero(tr.updates == 1)
        if one.size:
            alt_x = alt_x.copy()
            alt_x[one, 1] = np.nan
        if young.size:
            x, P = x.copy(), P.copy()
            x[young] = tr.x[young]
            x[young[:, None], [1, 2, 4, 5]] = np.nan
            P[young] = tr.P[young]
            alt_x[young, 0] = tr.alt_x[young, 0]
            t_track_s = np.full(len(tr), t_ref_s)
            t_track_s[young] = tr.t_state_s[young]
        manoeuvre_prob = None
        if self.imm is not None:  # μ of the latest update predicted to t_ref (imm.py eq. 1), like x
            pi = self.imm.transition_matrix(t_ref_s - tr.t_state_s)
            manoeuvre_prob = 1.0 - np.einsum("ni,nij->nj", tr.mu, pi)[:, QUIET]
        return TrackColumns(
            period=period,
            t_s=t_ref_s,
            track_id=tr.track_id.copy(),
            status=tr.status.copy(),
            x=x,
            cov_xy=np.stack([P[:, 0, 0], P[:, 0, 3], P[:, 3, 3]], axis=1),
            fl=alt_x[:, 0].copy(),
            vrate_fpm=alt_x[:, 1] * FT_PER_FL * 60.0,
            sources=tr.sources.copy(),
            mode3a=tr.mode3a.copy(),
            mode_s=tr.mode_s.copy(),
            updates=tr.updates.copy(),
            age_s=t_ref_s - tr.first_t_s,
            ended=ended,
            names=self._names,
            manoeuvre_prob=manoeuvre_prob,
            t_track_s=t_track_s,
        )

    # ================================================================= health
    def health(self) -> dict[str, Any]:
        """Counters and per-radar state for the health message (wire.Health fields)."""
        live = self.buffer.live_mask()
        offsets_s = self.clock.offsets_s()
        registration = self.registration.estimates()
        limit_s = self.settings.system.clock_offset_limit_s
        radars = {}
        for i, rid in enumerate(self.radar_ids):
            r = self.radars[i]
            wm = self.buffer.watermark_s[i]
            radars[rid] = {
                "live": bool(live[i]),
                "watermark_t": float(wm) if math.isfinite(wm) else None,
                "lateness_s": float(self.buffer.lateness_s[i]),
                "plots": r.plots,
                "batches": r.batches,
                "last_seq": r.last_seq,
                "seq_gaps": r.seq_gaps,
                "seq_restarts": r.seq_restarts,
                "rejected": dict(r.rejected),
                "wild": r.wild,
                "clock_offset_s": offsets_s[i],
                "clock_suspect": (offset_s := offsets_s[i]) is not None and abs(offset_s) > limit_s,
                "registration": registration[rid],
            }
        proc = np.array(self.processing_s) * 1e3
        counters = dict(self.counters)
        counters["tracks_confirmed"] = int((self.tracks.status == CONFIRMED).sum())
        counters["plots_buffered"] = self.buffer.buffered_plots
        # the two-stage registration's evidence: tracks' innovations taken, and left out by its gate
        counters["registration_innovations_used"] = self.registration.innovations_used
        counters["registration_innovations_gated"] = self.registration.innovations_gated
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
