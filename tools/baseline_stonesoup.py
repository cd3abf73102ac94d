"""Reference tracker: Stone Soup's GNN multi-target tracker on the same plots (issue 7).

``stonesoup`` (PyPI, optional extra ``baseline``) configured as a fair multi-sensor
tracker, the way its documentation composes one:

* Measurements: every plot is converted to the daemon's system plane with the same code
  and the same per-plot covariance as the engine (:func:`radar_fusion.geo.coordinates.polar_to_plane`,
  Mode C via :func:`~radar_fusion.geo.coordinates.mode_c_height_m` (with the configured met), the configured
  height for plots without Mode C); each :class:`~stonesoup.types.detection.Detection`
  carries its own ``LinearGaussian`` measurement model (H picks x and y, R = the plot's
  2×2 covariance). Plots beyond a radar's ``max_range_m`` are dropped as the engine does.
* Motion: Kalman filter (``KalmanPredictor`` / ``KalmanUpdater``) with a
  constant-velocity model per axis, state (x, vx, y, vy), white-acceleration spectral
  density ``q_m2ps3`` (tuned for Stone Soup on a separate scenario, see
  :class:`StoneSoupParams`).
* Association: ``GNNWith2DAssignment`` over a ``DistanceHypothesiser`` with the
  Mahalanobis distance, gated at the engine's gate (√χ²₂, ``gate_chi2`` = 13.8 → 3.71).
  Stone Soup's GNN is purely kinematic: it does not use Mode S / Mode 3/A identity, which
  the engine does (a difference in information, stated in the report).
* Initiation: ``MultiMeasurementInitiator``: one-plot holding tracks (position from the
  plot, velocity prior N(0, max_speed²/3) per axis, as the engine's one-plot tracks),
  released as tracks after ``min_points`` updates (the engine confirms after 3).
* Deletion: ``UpdateTimeDeleter`` for tracks and holding tracks.
* Time order: the plots of all radars are sorted by time and cut into steps: a step is a
  run of consecutive plots of one radar, cut at fusion-period boundaries and after a
  quarter of that radar's rotation (so a step never holds two plots of one aircraft from
  one radar, and no prediction ever goes backwards in time). Each step is one
  ``MultiTargetTracker.update_tracker(time, detections)`` call, ``time`` = its last plot's
  time; every detection is predicted to its own time. This is what Stone Soup's
  time-ordered multi-sensor feeders do, with at least as few steps.

Output: at every fusion-period boundary (event time k·period_s, the engine's period
grid) each live track's newest state is extrapolated to the boundary along its velocity
and emitted in a TrackBatch-like dict (``t``, ``period``, ``tracks`` with ``track_id``,
``status``, ``x_m``, ``y_m``, ``vx_mps``, ``vy_mps``), which
:func:`radar_fusion.tools.evaluate.evaluate` scores like the daemon's output. A track is
``coasting`` when its last update is older than ``coast_after_scans`` × the longest
rotation period, else ``confirmed`` (the evaluation's RMS counts confirmed states only,
as for the engine).

Timing covers everything from the decoded plots to the emitted batches: conversion,
building Stone Soup detections and models, the tracker steps and the output.
"""

from __future__ import annotations

import datetime as _dt
import math
import time
from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from radar_fusion.geo.coordinates import RadarSites, SystemPlane, mode_c_height_m, polar_to_plane
from radar_fusion.geo.units import M_PER_FT

_EPOCH = _dt.datetime(1970, 1, 1)


def available() -> bool:
    """True when ``stonesoup`` can be imported."""
    try:
        import stonesoup  # noqa: F401
    except ImportError:
        return False
    return True


def version() -> str:
    try:
        from importlib.metadata import version as _v

        return _v("stonesoup")
    except Exception:  # not installed
        return "not installed"


@dataclass(frozen=True)
class StoneSoupParams:
    """Tuning of the reference tracker (defaults: see the module docstring)."""

    q_m2ps3: float = 100.0
    """CV white-acceleration spectral density, m²/s³, tuned for Stone Soup on a separate
    scenario (``scenario_for_benchmark(30, 3, 90 s, seed 11)``; the benchmark uses other
    seeds): GOSPA 2,673 / 1,909 / 1,245 / 1,262 / 1,349 m, position RMS 218 / 185 / 119 /
    122 / 140 m and duplicate tracks 24 / 9 / 0 / 0 / 0 for q = 4 / 25 / 100 / 250 / 1000.
    Smaller q lets 3°/s turns leave the gate (new tracks beside the old ones)."""
    gate_chi2: float = 13.8
    """association gate on the squared Mahalanobis distance (the engine's default)"""
    min_points: int = 3
    """updates of a holding track before it becomes a track (the engine confirms after 3)"""
    max_speed_mps: float = 350.0
    """one-plot velocity prior: uniform up to this speed per axis → variance max²/3"""
    delete_after_scans: float = 2.5
    """a track is deleted this many longest-rotation periods after its last update"""
    holding_delete_after_scans: float = 1.5
    """a holding track is deleted this many longest-rotation periods after its last update"""
    coast_after_scans: float = 1.5
    """a track is reported ``coasting`` this many longest-rotation periods after its last update"""
    trim_history: bool = True
    """drop track states older than the deletion window (keeping the last update): a
    long-running tracker needs bounded memory, and ``UpdateTimeDeleter`` scans a track's
    whole history at every step, which otherwise makes the run time grow with the square
    of its length"""


@dataclass
class ConvertedPlots:
    """Plots of all radars in the system plane, sorted by time."""

    t_s: np.ndarray
    x_m: np.ndarray
    y_m: np.ndarray
    cov_m2: np.ndarray  # (N, 2, 2)
    radar: np.ndarray  # radar index
    n_offered: int  # plots offered (before range / validity checks)


def convert_plots(settings, plot_batches: Iterable[Any]) -> ConvertedPlots:
    """Convert decoded plot batches (``wire.DecodedPlots``) as the engine does; sort by time."""
    plane = SystemPlane(settings.system.center_lat, settings.system.center_lon)
    sites = RadarSites.from_configs(settings.radars)
    index = {r.id: i for i, r in enumerate(settings.radars)}
    max_range = np.array([r.max_range_m for r in settings.radars])
    assumed_altitude_m = settings.tracking.assumed_altitude_ft * M_PER_FT
    parts: list[tuple[np.ndarray, ...]] = []
    n_offered = 0
    for b in plot_batches:
        n = len(b)
        n_offered += n
        i = index.get(b.radar_id)
        if i is None or n == 0:
            continue
        keep = np.flatnonzero(np.isfinite(b.t_s) & (b.range_m <= max_range[i]))
        if keep.size == 0:
            continue
        x, y, cov, _g, valid = polar_to_plane(
            plane,
            sites,
            np.full(keep.size, i),
            b.range_m[keep],
            b.azimuth_deg[keep],
            mode_c_height_m(b.fl[keep], *settings.tracking.mode_c_met()),
            assumed_altitude_m=assumed_altitude_m,
            sigma_known_altitude_fraction=settings.tracking.mode_c_sigma_fraction(),
            return_valid=True,
        )
        parts.append((b.t_s[keep][valid], x[valid], y[valid], cov[valid], np.full(int(valid.sum()), i)))
    if not parts:
        z = np.zeros(0)
        return ConvertedPlots(z, z, z, np.zeros((0, 2, 2)), np.zeros(0, np.int64), n_offered)
    t, x, y, cov, radar = (np.concatenate([p[k] for p in parts]) for k in range(5))
    order = np.lexsort((radar, t))
    return ConvertedPlots(t[order], x[order], y[order], cov[order], radar[order].astype(np.int64), n_offered)


def time_ordered_steps(plots: ConvertedPlots, rotation_s: np.ndarray, period_s: float) -> list[tuple[int, int]]:
    """[start, stop) index ranges of the steps (see the module docstring)."""
    n = plots.t_s.shape[0]
    if n == 0:
        return []
    period = np.floor(plots.t_s / period_s).astype(np.int64)
    cut = np.zeros(n, bool)
    cut[0] = True
    cut[1:] = (plots.radar[1:] != plots.radar[:-1]) | (period[1:] != period[:-1])
    starts = np.flatnonzero(cut).tolist()
    steps = []
    ends = starts[1:] + [n]
    t = plots.t_s
    for s, e in zip(starts, ends):
        span = 0.25 * float(rotation_s[plots.radar[s]])
        while e - s > 1 and t[e - 1] - t[s] > span:  # rare: one radar alone for a long stretch
            cut_at = s + int(np.searchsorted(t[s:e], t[s] + span, side="right"))
            steps.append((s, cut_at))
            s = cut_at
        steps.append((s, e))
    return steps


def _datetime(t_s: float) -> _dt.datetime:
    return _EPOCH + _dt.timedelta(seconds=float(t_s))


@dataclass
class ReferenceRun:
    """Result of :func:`run_stonesoup`."""

    batches: list[dict]
    plots_offered: int
    plots_used: int
    steps: int
    run_s: float
    tracks_started: int
    completed: bool = True
    """False when ``time_budget_s`` stopped the run early (figures cover the processed part)"""
    plots_processed: int = 0
    params: StoneSoupParams = field(default_factory=StoneSoupParams)

    @property
    def plots_per_s(self) -> float:
        return self.plots_processed / self.run_s if self.run_s > 0 else math.nan


def build_tracker(params: StoneSoupParams, longest_rotation_s: float):
    """The Stone Soup components, composed as in its multi-target tutorials."""
    from stonesoup.dataassociator.neighbour import GNNWith2DAssignment
    from stonesoup.deleter.time import UpdateTimeDeleter
    from stonesoup.hypothesiser.distance import DistanceHypothesiser
    from stonesoup.initiator.simple import MultiMeasurementInitiator
    from stonesoup.measures import Mahalanobis
    from stonesoup.models.transition.linear import CombinedLinearGaussianTransitionModel, ConstantVelocity
    from stonesoup.predictor.kalman import KalmanPredictor
    from stonesoup.tracker.simple import MultiTargetTracker
    from stonesoup.types.array import CovarianceMatrix, StateVector
    from stonesoup.types.state import GaussianState
    from stonesoup.updater.kalman import KalmanUpdater

    transition = CombinedLinearGaussianTransitionModel(
        [ConstantVelocity(params.q_m2ps3), ConstantVelocity(params.q_m2ps3)]
    )
    predictor = KalmanPredictor(transition)
    updater = KalmanUpdater(measurement_model=None)  # each detection carries its own model
    gate = math.sqrt(params.gate_chi2)

    def hypothesiser():
        return DistanceHypothesiser(predictor, updater, measure=Mahalanobis(), missed_distance=gate)

    v2 = params.max_speed_mps**2 / 3.0
    prior = GaussianState(StateVector([0.0, 0.0, 0.0, 0.0]), CovarianceMatrix(np.diag([0.0, v2, 0.0, v2])))
    initiator = MultiMeasurementInitiator(
        prior_state=prior,
        deleter=UpdateTimeDeleter(_dt.timedelta(seconds=params.holding_delete_after_scans * longest_rotation_s)),
        data_associator=GNNWith2DAssignment(hypothesiser()),
        updater=updater,
        min_points=params.min_points,
    )
    return MultiTargetTracker(
        initiator=initiator,
        deleter=UpdateTimeDeleter(_dt.timedelta(seconds=params.delete_after_scans * longest_rotation_s)),
        detector=None,
        data_associator=GNNWith2DAssignment(hypothesiser()),
        updater=updater,
    )


def _trim(tracks, oldest: _dt.datetime, update_type) -> None:
    """Drop each track's states before ``oldest``, but never its last update."""
    for track in tracks:
        states = track.states
        n = 0
        while n < len(states) - 1 and states[n].timestamp < oldest:
            n += 1
        last_update = next((i for i in range(len(states) - 1, -1, -1) if isinstance(states[i], update_type)), None)
        if last_update is not None:
            n = min(n, last_update)
        if n > 0:
            del states[:n]
            del track.metadatas[:n]


def run_stonesoup(
    settings,
    plot_batches: Iterable[Any],
    params: StoneSoupParams | None = None,
    time_budget_s: float | None = None,
) -> ReferenceRun:
    """Track ``plot_batches`` (``wire.DecodedPlots`` of the radars in ``settings``) with Stone Soup.

    With ``time_budget_s`` the run stops after that much time (``completed`` False); the
    figures then cover the plots processed so far.
    """
    from stonesoup.models.measurement.linear import LinearGaussian
    from stonesoup.types.array import CovarianceMatrix, StateVector
    from stonesoup.types.detection import Detection
    from stonesoup.types.update import Update

    params = params or StoneSoupParams()
    perf = time.perf_counter
    t0 = perf()
    period_s = float(settings.system.period_s)
    rotation_s = np.array([r.rotation_period_s for r in settings.radars], float)
    longest = float(rotation_s.max())
    coast_after_s = params.coast_after_scans * longest
    plots = convert_plots(settings, plot_batches)
    steps = time_ordered_steps(plots, rotation_s, period_s)
    tracker = build_tracker(params, longest)

    ids: dict[str, int] = {}
    batches: list[dict] = []
    next_period = int(math.floor(plots.t_s[0] / period_s)) if steps else 0

    def emit_until(t_s: float) -> None:
        """Emit every period boundary at or before ``t_s``."""
        nonlocal next_period
        while (next_period + 1) * period_s <= t_s:
            b = (next_period + 1) * period_s
            out = []
            for track in tracker.tracks:
                tid = ids.setdefault(track.id, len(ids) + 1)
                st = track.state
                sv = np.asarray(st.state_vector, float).ravel()
                dt = b - (st.timestamp - _EPOCH).total_seconds()
                last_update = None
                for s in reversed(track.states):
                    if isinstance(s, Update):
                        last_update = (s.timestamp - _EPOCH).total_seconds()
                        break
                coasting = last_update is None or b - last_update > coast_after_s
                out.append(
                    {
                        "track_id": tid,
                        "status": "coasting" if coasting else "confirmed",
                        "x_m": float(sv[0] + sv[1] * dt),
                        "y_m": float(sv[2] + sv[3] * dt),
                        "vx_mps": float(sv[1]),
                        "vy_mps": float(sv[3]),
                    }
                )
            batches.append({"t": b, "period": next_period, "tracks": out, "ended": []})
            next_period += 1

    keep_s = (params.delete_after_scans + 1.0) * longest
    processed = 0
    completed = True
    mapping = (0, 2)
    for k, (s, e) in enumerate(steps):
        emit_until(float(plots.t_s[s]))
        dets = set()
        for j in range(s, e):
            model = LinearGaussian(ndim_state=4, mapping=mapping, noise_covar=CovarianceMatrix(plots.cov_m2[j]))
            dets.add(
                Detection(
                    StateVector([plots.x_m[j], plots.y_m[j]]),
                    timestamp=_datetime(plots.t_s[j]),
                    measurement_model=model,
                )
            )
        step_time = _datetime(plots.t_s[e - 1])
        tracker.update_tracker(step_time, dets)
        processed += e - s
        if params.trim_history and k % 64 == 63:
            _trim(tracker.tracks, step_time - _dt.timedelta(seconds=keep_s), Update)
        if time_budget_s is not None and perf() - t0 > time_budget_s:
            completed = e == plots.t_s.shape[0]
            break
    if steps and completed:
        emit_until(math.floor(float(plots.t_s[-1]) / period_s) * period_s + period_s)
    run_s = perf() - t0
    return ReferenceRun(
        batches=batches,
        plots_offered=plots.n_offered,
        plots_used=int(plots.t_s.shape[0]),
        steps=len(steps),
        run_s=run_s,
        tracks_started=len(ids),
        completed=completed,
        plots_processed=processed,
        params=params,
    )
