"""Radar simulator: plots and radar status messages exactly as radar front-ends publish them.

``radar-fusion simulate --scenario demo --out DIR [--seed N] [--duration-s S]`` writes

* ``DIR/plots.rec``  -- a recording (:mod:`radar_fusion.recording`) of every
  ``radar/<id>/plots`` (PlotBatch) and ``radar/<id>/status`` (RadarStatus) message, in
  publish-time order, record time = publish time (event time);
* ``DIR/truth.csv``  -- the ground truth, one row per target per second while it exists:
  ``t_s,target_id,mode_s,callsign,lat_deg,lon_deg,alt_ft,x_m,y_m,vx_mps,vy_mps,vrate_fpm,detectable``
  (``x_m``/``y_m``/``vx_mps``/``vy_mps`` in the system plane of the scenario centre,
  :class:`radar_fusion.geo.coordinates.SystemPlane`; ``mode_s`` 6 hex digits or empty;
  ``detectable`` 1 when at least one radar covers the target: within its instrumented
  range, above its radar horizon and outside its cone of silence);
* ``DIR/config.toml`` -- a daemon configuration for the scenario (loads with
  :func:`radar_fusion.config.load_settings`).

Radar model
-----------
Each antenna turns clockwise at a constant rate. Its beam azimuth (degrees, continuous,
"unwrapped") is ``A(t) = 360 (t - t_start) / T_rot + phase``, the true azimuth of the beam
``A(t) mod 360``; north crossings are at ``A = 360 k``. The phase is random per radar
unless given. A target is seen when the beam passes its azimuth: the crossing solves
``A(t) = 360 n + az(t)`` with ``az`` the target's (continuously unwrapped) azimuth from
the site. It starts from the previous scan's azimuth and is iterated twice with the
target's position at the estimated time (the target's angular rate is far below the
beam's, so this converges to micro-seconds). The plot time is that crossing time: every
radar has its own clock phase, there is no common scan time.

At the crossing the target is *in coverage* when its slant range is within the radar's
``max_range_m``, it is above the radar horizon (4/3 earth: ground range <=
sqrt(2 k R h_radar) + sqrt(2 k R h_target)) and its elevation is below
``max_elevation_deg`` (cone of silence). It is then detected with probability
``rates.pd`` (secondary) or ``rates.pd_psr`` (primary-only plots). The measurement is
``range = rho + range_bias_m + N(0, sigma_range_m)``, ``azimuth = az + azimuth_bias_deg +
N(0, sigma_azimuth_deg)`` (noise-free rho/az from :func:`coordinates.geodetic_to_polar`).

Report kind and identity: a Mode S target seen by a Mode S radar gives ``modes`` plots
(Mode S address, Mode 3/A, Mode C quantised to 25 ft when the target reports 25 ft,
else 100 ft); a transponder seen by a radar with a primary gives ``cmb`` when the
primary also detected it (probability ``pd_psr``), else ``ssr``; a target without a
transponder, or any target seen by a primary-only radar, gives ``psr`` plots (no
identity, no flight level). Mode C is present on a plot with probability ``p_mode_c``
when the target reports altitude. Every plot of a target carries the radar's track
number for it (stable per aircraft per radar).

False plots: Poisson(``false_plots_per_scan``) per revolution, uniform over the coverage
area (range density ∝ r), no identity, kind ``psr`` (``ssr`` on a secondary-only radar).
Wild plots: isolated (probability ``wild_plot_prob`` per plot) and in runs (probability
``wild_run_prob`` per target per scan of a run of ``wild_run_scans`` consecutive scans
with one constant error): a gross error of ``wild_range_m`` (uniform, random sign) in
range or of ``wild_azimuth_deg`` in azimuth, keeping the aircraft's identity and track
number. Measurements beyond the instrumented range are not reported.

Publication: the revolution is divided into ``n_sectors`` sectors. The plots of a
sector are published as one PlotBatch at the end of its sweep (``seq`` +1 each message
per radar, from 0; a sector without plots still gives an empty batch), followed, at the
same time, by a RadarStatus for the crossing: ``"north"`` (sector 0, with
``rotation_period_s``) at north, ``"sector"`` (with the sector number) elsewhere.
Messages of all radars are merged in time order. Only sectors whose sweep ends inside
``[start_t_s, start_t_s + duration_s]`` are published.

Targets
-------
* Synthetic flight plans (:class:`FlightPlan`): start position in the system plane,
  heading, speed and altitude, then legs of constant turn rate (positive = right,
  clockwise) and constant vertical rate. Positions are exact closed forms (a circular
  arc per turn), so the state is sampled exactly at any time.
* Real ADS-B flights (:func:`adsb_targets`, the table in
  ``../shared/data/adsb/switzerland_2018-08-01.json.gz``): positions are the C2 cubic
  spline in the system plane through the 10 s samples (evaluated as a cubic Hermite
  with the spline's knot velocities), so the truth passes exactly through the table's
  positions; altitude is a cubic Hermite through the reported altitudes with the
  reported vertical rates as slopes. Stale samples (a repeated position, chord speed
  more than 35 % off the reported groundspeed on both sides) are dropped first. Note
  that the table's positions jitter along track by ~50 m (chord speeds scatter by
  ~10 % around the groundspeed), so an interpolating truth has acceleration spikes of
  1-2 g between samples; evaluate trackers on these flights with that in mind.

Scenario TOML format (``--scenario path/to/file.toml``)
------------------------------------------------------
::

    [scenario]
    name = "my-scenario"          # optional
    center_lat = 46.8             # system-plane centre, degrees
    center_lon = 8.2
    start_utc = "2018-08-01T08:00:00Z"   # or start_t_s = 1533110400.0
    duration_s = 540.0
    seed = 1
    period_s = 4.0                # optional; default = shortest rotation period

    [rates]                       # optional, defaults for every radar (see Rates)
    pd = 0.95
    pd_psr = 0.85
    p_mode_c = 0.99
    false_plots_per_scan = 1.0
    wild_plot_prob = 0.002
    wild_run_prob = 0.0005
    wild_run_scans = [3, 5]
    wild_range_m = [2000.0, 8000.0]
    wild_azimuth_deg = [1.0, 4.0]

    [[radars]]
    id = "north"
    lat = 47.3
    lon = 8.2
    alt_m = 800.0
    rotation_period_s = 4.0
    sigma_range_m = 40.0
    sigma_azimuth_deg = 0.06
    range_bias_m = 30.0           # optional, default 0
    azimuth_bias_deg = 0.03       # optional, default 0
    max_range_m = 250000.0
    psr = true                    # has a primary radar (optional, default true)
    ssr = true                    # has a secondary radar (optional, default true)
    mode_s = true                 # Mode S interrogator (optional, default true)
    n_sectors = 32                # optional
    start_phase_deg = 0.0         # optional; default random
    max_elevation_deg = 40.0      # optional (cone of silence)
    sac = 1                       # optional
    sic = 1                       # optional
    rates = { pd = 0.9 }          # optional: overrides of [rates] for this radar

    [[targets]]
    id = "T01"
    callsign = "SWR123"           # optional
    mode_s = "4B1805"             # optional (6 hex digits): Mode S transponder
    mode3a = "2341"               # optional, 4 octal digits
    transponder = "modes"         # optional: "modes", "modeac", "none" (default from mode_s/mode3a)
    mode_c = true                 # optional, reports altitude
    alt_quantum_ft = 25           # optional, 25 or 100
    start_x_m = -60000.0          # or start_lat / start_lon
    start_y_m = 20000.0
    t_offset_s = 0.0              # appears this long after the start
    heading_deg = 90.0
    speed_mps = 230.0
    alt_ft = 35000.0
    legs = [
        { duration_s = 120.0 },
        { duration_s = 60.0, turn_rate_dps = 3.0 },
        { duration_s = 200.0, vrate_fpm = -2000.0 },
    ]

    [adsb]                        # optional: add real flights from the ADS-B table
    max_aircraft = 40             # flights airborne in [start, start + duration]
    path = "../shared/data/adsb/switzerland_2018-08-01.json.gz"   # optional

Python API: :func:`preset`, :func:`scenario_for_benchmark`, :func:`load_scenario`,
:func:`simulate` -> :class:`Simulation`, :func:`write_outputs`, :func:`read_truth`.
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import datetime as _dt
import functools
import gzip
import json
import math
import sys
import time
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Optional, Sequence

import msgpack
import numpy as np
from scipy.interpolate import CubicSpline

from radar_fusion import wire
from radar_fusion.geo.coordinates import (
    WGS84_GEOD,
    RadarSites,
    SystemPlane,
    geodetic_to_polar,
)
from radar_fusion.recording import RecordingWriter

__all__ = [
    "Rates",
    "RadarSpec",
    "Leg",
    "FlightPlan",
    "SampledPath",
    "Target",
    "Scenario",
    "Trajectories",
    "PlotColumns",
    "Truth",
    "Simulation",
    "preset",
    "PRESETS",
    "demo_scenario",
    "adsb_scenario",
    "adsb_targets",
    "scenario_for_benchmark",
    "load_scenario",
    "simulate",
    "write_outputs",
    "write_truth",
    "read_truth",
    "config_toml",
    "add_arguments",
    "run",
]

FT_M = 0.3048
NM_M = 1852.0
KT_MPS = NM_M / 3600.0
FPM_MPS = FT_M / 60.0
EPOCH_2018_08_01_08Z = 1533110400.0
"""2018-08-01 08:00:00 UTC, the default scenario start (the day of the ADS-B table)."""

PROJECT_ROOT = Path(__file__).resolve().parents[1]
ADSB_TABLE = PROJECT_ROOT.parent / "shared" / "data" / "adsb" / "switzerland_2018-08-01.json.gz"
TRUTH_COLUMNS = (
    "t_s", "target_id", "mode_s", "callsign", "lat_deg", "lon_deg", "alt_ft",
    "x_m", "y_m", "vx_mps", "vy_mps", "vrate_fpm", "detectable",
)  # fmt: skip

KIND_PSR, KIND_SSR, KIND_CMB, KIND_MODES = (wire.KIND_CODES[k] for k in ("psr", "ssr", "cmb", "modes"))
KIND_NAMES = {code: name for name, code in wire.KIND_CODES.items()}
_TRANSPONDERS = {"none": 0, "modeac": 1, "modes": 2}
_EFFECTIVE_EARTH_K = 4.0 / 3.0


# =========================================================================== scenario model


@dataclass(frozen=True)
class Rates:
    """Detection, clutter and gross-error rates of a radar (scenario default or per radar)."""

    pd: float = 0.95
    """probability that a transponder in coverage gives a secondary plot in a scan"""
    pd_psr: float = 0.85
    """primary detection probability: primary-only plots, and the share of ``cmb`` plots"""
    p_mode_c: float = 0.99
    """probability that a plot of an altitude-reporting target carries its flight level"""
    false_plots_per_scan: float = 1.0
    """mean number of false plots per revolution (Poisson), uniform over the coverage"""
    wild_plot_prob: float = 0.002
    """probability that a plot is an isolated wild plot"""
    wild_run_prob: float = 0.0005
    """probability per target and scan that a run of wild plots starts"""
    wild_run_scans: tuple[int, int] = (3, 5)
    """run length in scans, uniform between the two (inclusive)"""
    wild_range_m: tuple[float, float] = (2000.0, 8000.0)
    """magnitude of a wild range error, uniform between the two, random sign"""
    wild_azimuth_deg: tuple[float, float] = (1.0, 4.0)
    """magnitude of a wild azimuth error, uniform between the two, random sign"""


@dataclass(frozen=True)
class RadarSpec:
    """One simulated radar: site, antenna, accuracy, systematic errors and capabilities."""

    id: str
    lat_deg: float
    lon_deg: float
    alt_m: float = 0.0
    rotation_period_s: float = 4.0
    sigma_range_m: float = 50.0
    sigma_azimuth_deg: float = 0.07
    range_bias_m: float = 0.0
    azimuth_bias_deg: float = 0.0
    max_range_m: float = 250.0 * NM_M
    psr: bool = True
    ssr: bool = True
    mode_s: bool = True
    n_sectors: int = 32
    start_phase_deg: Optional[float] = None
    max_elevation_deg: float = 40.0
    sac: Optional[int] = None
    sic: Optional[int] = None
    rates: Optional[Rates] = None

    def __post_init__(self) -> None:
        if not (self.psr or self.ssr):
            raise ValueError(f"radar {self.id}: needs a primary (psr) or a secondary (ssr)")
        if not (1 <= self.n_sectors <= 256):
            raise ValueError(f"radar {self.id}: n_sectors must be in 1..256")
        if self.rotation_period_s <= 0:
            raise ValueError(f"radar {self.id}: rotation_period_s must be > 0")


@dataclass(frozen=True)
class Leg:
    """A piece of a flight plan flown at constant turn rate and vertical rate."""

    duration_s: float
    turn_rate_dps: float = 0.0
    """degrees per second, positive = right turn (heading increasing, clockwise)"""
    vrate_fpm: float = 0.0
    """feet per minute, positive = climb"""


@dataclass(frozen=True)
class FlightPlan:
    """Synthetic kinematics: a start state in the system plane and a list of legs.

    Speed is constant; the aircraft exists from ``t_offset_s`` after the scenario start
    until the end of its last leg.
    """

    start_x_m: float
    start_y_m: float
    heading_deg: float
    speed_mps: float
    alt_ft: float
    legs: tuple[Leg, ...]
    t_offset_s: float = 0.0

    @property
    def duration_s(self) -> float:
        return float(sum(leg.duration_s for leg in self.legs))


@dataclass(frozen=True)
class SampledPath:
    """Recorded kinematics (e.g. ADS-B): samples of position, altitude and velocity.

    The truth passes through every sample: positions by the C2 cubic spline in the
    system plane, altitude by a cubic Hermite with ``vrate_fpm`` as slopes.
    ``groundspeed_kt``/``track_deg`` are the reported velocity (kept for reference and
    used to drop stale samples when the table is read)."""

    t_s: np.ndarray
    lat_deg: np.ndarray
    lon_deg: np.ndarray
    alt_ft: np.ndarray
    groundspeed_kt: np.ndarray
    track_deg: np.ndarray
    vrate_fpm: np.ndarray


@dataclass(frozen=True)
class Target:
    """One aircraft: identity, transponder, and either a flight plan or a sampled path."""

    target_id: str
    callsign: Optional[str] = None
    mode_s: Optional[int] = None
    """24-bit Mode S address, or None"""
    mode3a: Optional[int] = None
    """Mode 3/A code as an integer (0..0o7777), or None"""
    transponder: str = "modes"
    """"modes" (Mode S), "modeac" (Mode A/C only) or "none" (primary only)"""
    mode_c: bool = True
    alt_quantum_ft: float = 100.0
    """Mode C quantum: 100 ft, or 25 ft for Mode S transponders that report it"""
    plan: Optional[FlightPlan] = None
    path: Optional[SampledPath] = None

    def __post_init__(self) -> None:
        if (self.plan is None) == (self.path is None):
            raise ValueError(f"target {self.target_id}: give exactly one of plan and path")
        if self.transponder not in _TRANSPONDERS:
            raise ValueError(f"target {self.target_id}: transponder must be one of {list(_TRANSPONDERS)}")
        if self.transponder == "modes" and self.mode_s is None:
            raise ValueError(f"target {self.target_id}: a Mode S transponder needs a mode_s address")
        if self.alt_quantum_ft not in (25.0, 100.0):
            raise ValueError(f"target {self.target_id}: alt_quantum_ft must be 25 or 100")


@dataclass
class Scenario:
    """Everything :func:`simulate` needs."""

    name: str
    center_lat_deg: float
    center_lon_deg: float
    radars: list[RadarSpec]
    targets: list[Target]
    start_t_s: float = EPOCH_2018_08_01_08Z
    duration_s: float = 540.0
    seed: int = 0
    period_s: Optional[float] = None
    """fusion period written to config.toml; None = the shortest rotation period"""
    rates: Rates = field(default_factory=Rates)

    @property
    def effective_period_s(self) -> float:
        shortest = min(r.rotation_period_s for r in self.radars)
        return shortest if self.period_s is None else min(float(self.period_s), shortest)

    def rates_of(self, radar: RadarSpec) -> Rates:
        return radar.rates if radar.rates is not None else self.rates


# =========================================================================== kinematics


@dataclass
class KinematicState:
    """Truth state of targets at query times (all arrays of the query's shape)."""

    x_m: np.ndarray
    y_m: np.ndarray
    alt_m: np.ndarray
    vx_mps: np.ndarray
    vy_mps: np.ndarray
    vz_mps: np.ndarray
    active: np.ndarray


def _arc_displacement(v: np.ndarray, psi: np.ndarray, omega: np.ndarray, tau: np.ndarray):
    """Displacement (dx east, dy north) after tau s at speed v from heading psi (rad),
    turning at omega rad/s: exact circular arc, stable at omega -> 0.

    x(tau) = v (cos psi - cos(psi + omega tau)) / omega = v tau sin(psi + omega tau / 2) sinc,
    y(tau) = v (sin(psi + omega tau) - sin psi) / omega = v tau cos(psi + omega tau / 2) sinc,
    sinc = sin(omega tau / 2) / (omega tau / 2).
    """
    half = 0.5 * omega * tau
    s = np.sinc(half / np.pi)
    mid = psi + half
    return v * tau * np.sin(mid) * s, v * tau * np.cos(mid) * s


def _hermite(s, h, p0, p1, m0, m1):
    """Cubic Hermite value and derivative at normalised s in [0, 1], interval length h."""
    s2, s3 = s * s, s * s * s
    val = (2 * s3 - 3 * s2 + 1) * p0 + (s3 - 2 * s2 + s) * h * m0 + (-2 * s3 + 3 * s2) * p1 + (s3 - s2) * h * m1
    der = ((6 * s2 - 6 * s) * p0 + (3 * s2 - 4 * s + 1) * h * m0 + (-6 * s2 + 6 * s) * p1 + (3 * s2 - 2 * s) * h * m1) / h
    return val, der


class Trajectories:
    """Vectorised truth kinematics of all targets of a scenario, exact at any time.

    :meth:`state` takes arrays of target indices and times (any mix) and returns the
    plane position, altitude and velocities; outside a target's life the state is
    extrapolated (constant velocity) and ``active`` is False.
    """

    def __init__(self, targets: Sequence[Target], plane: SystemPlane, start_t_s: float) -> None:
        n = len(targets)
        self.n = n
        self.t_begin_s = np.empty(n)
        self.t_end_s = np.empty(n)
        self._synthetic = np.array([t.plan is not None for t in targets], bool)
        self._local = np.empty(n, np.intp)
        syn = [i for i in range(n) if self._synthetic[i]]
        smp = [i for i in range(n) if not self._synthetic[i]]
        self._local[syn] = np.arange(len(syn))
        self._local[smp] = np.arange(len(smp))
        self._build_segments([targets[i].plan for i in syn], start_t_s)
        if syn:
            self.t_begin_s[syn] = self._seg_t0[:, 0]
            self.t_end_s[syn] = self._syn_t_end
        self._build_knots([targets[i].path for i in smp], plane)
        if smp:
            self.t_begin_s[smp] = self._k_t[self._k_off[:-1]]
            self.t_end_s[smp] = self._k_t[self._k_off[1:] - 1]

    # ----------------------------------------------------------------- synthetic plans
    def _build_segments(self, plans: list[FlightPlan], start_t_s: float) -> None:
        m = len(plans)
        n_seg = max([len(p.legs) for p in plans] + [1])
        shape = (m, n_seg)
        self._seg_t0 = np.full(shape, np.inf)
        self._seg_x0, self._seg_y0, self._seg_psi0 = np.zeros(shape), np.zeros(shape), np.zeros(shape)
        self._seg_omega, self._seg_v, self._seg_h0, self._seg_vz = (np.zeros(shape) for _ in range(4))
        self._syn_t_end = np.empty(m)
        if m == 0:
            return
        # Legs are chained for all plans at once, leg by leg (plans without leg j keep
        # their end state).
        n_legs = np.array([len(p.legs) for p in plans])
        dur = np.zeros(shape)
        omega = np.zeros(shape)
        vz = np.zeros(shape)
        for i, p in enumerate(plans):
            if not p.legs:
                raise ValueError("a flight plan needs at least one leg")
            dur[i, : len(p.legs)] = [leg.duration_s for leg in p.legs]
            omega[i, : len(p.legs)] = [math.radians(leg.turn_rate_dps) for leg in p.legs]
            vz[i, : len(p.legs)] = [leg.vrate_fpm * FPM_MPS for leg in p.legs]
        t = start_t_s + np.array([p.t_offset_s for p in plans], float)
        x = np.array([p.start_x_m for p in plans], float)
        y = np.array([p.start_y_m for p in plans], float)
        psi = np.radians([p.heading_deg for p in plans])
        v = np.array([p.speed_mps for p in plans], float)
        h = np.array([p.alt_ft for p in plans], float) * FT_M
        for j in range(n_seg):
            has = j < n_legs
            self._seg_t0[has, j] = t[has]
            self._seg_x0[:, j], self._seg_y0[:, j], self._seg_psi0[:, j] = x, y, psi
            self._seg_omega[:, j], self._seg_v[:, j], self._seg_h0[:, j], self._seg_vz[:, j] = omega[:, j], v, h, vz[:, j]
            dx, dy = _arc_displacement(v, psi, omega[:, j], dur[:, j])
            x, y = x + dx, y + dy
            psi = psi + omega[:, j] * dur[:, j]
            h = h + vz[:, j] * dur[:, j]
            t = t + dur[:, j]
        self._syn_t_end = t

    def _state_synthetic(self, rows: np.ndarray, t: np.ndarray):
        k = (t[:, None] >= self._seg_t0[rows]).sum(axis=1) - 1
        k = np.maximum(k, 0)
        tau = t - self._seg_t0[rows, k]
        v, psi0, om = self._seg_v[rows, k], self._seg_psi0[rows, k], self._seg_omega[rows, k]
        dx, dy = _arc_displacement(v, psi0, om, tau)
        psi = psi0 + om * tau
        vz = self._seg_vz[rows, k]
        return (
            self._seg_x0[rows, k] + dx,
            self._seg_y0[rows, k] + dy,
            self._seg_h0[rows, k] + vz * tau,
            v * np.sin(psi),
            v * np.cos(psi),
            vz,
        )

    # ----------------------------------------------------------------- sampled paths
    def _build_knots(self, paths: list[SampledPath], plane: SystemPlane) -> None:
        m = len(paths)
        sizes = np.array([len(p.t_s) for p in paths], np.intp)
        if np.any(sizes < 2):
            raise ValueError("a sampled path needs at least two samples")
        self._k_off = np.concatenate([[0], np.cumsum(sizes)]).astype(np.intp)
        if m == 0:
            self._k_t = np.zeros(0)
            return
        cat = lambda name: np.concatenate([np.asarray(getattr(p, name), float) for p in paths])  # noqa: E731
        t, lat, lon = cat("t_s"), cat("lat_deg"), cat("lon_deg")
        x, y = plane.to_plane(lat, lon)
        # Knot velocities: those of the C2 cubic spline through the positions (the
        # smoothest interpolant; the reported groundspeed/track disagree with the
        # positions' spacing by up to ~15 % in real ADS-B, and forcing them as slopes
        # would create large spurious accelerations between the samples).
        vx, vy = np.empty_like(x), np.empty_like(y)
        for a, b in zip(self._k_off[:-1], self._k_off[1:]):
            bc = "not-a-knot" if b - a >= 4 else "natural"
            spline = CubicSpline(t[a:b], np.column_stack([x[a:b], y[a:b]]), bc_type=bc)
            v = spline(t[a:b], 1)
            vx[a:b], vy[a:b] = v[:, 0], v[:, 1]
        # Altitude: the reported vertical rates as slopes, unless they disagree with the
        # altitude samples by more than 1,000 ft/min (then the centred chord rate).
        row = np.repeat(np.arange(m), sizes)
        lo, hi = self._k_off[row], self._k_off[row + 1] - 1
        i = np.arange(t.shape[0])
        ia, ib = np.maximum(i - 1, lo), np.minimum(i + 1, hi)
        z = cat("alt_ft") * FT_M
        vz = cat("vrate_fpm") * FPM_MPS
        chord = (z[ib] - z[ia]) / (t[ib] - t[ia])
        vz = np.where(np.abs(vz - chord) > 1000.0 * FPM_MPS, chord, vz)
        self._k_t, self._k_x, self._k_y = t, x, y
        self._k_vx, self._k_vy = vx, vy
        self._k_z, self._k_vz = z, vz
        self._k_tmin = float(t.min())
        self._k_span = float(t.max() - t.min()) + 10.0
        self._k_key = row * self._k_span + (t - self._k_tmin)

    def _state_sampled(self, rows: np.ndarray, t: np.ndarray):
        lo, hi = self._k_off[rows], self._k_off[rows + 1]
        tc = np.clip(t, self._k_t[lo], self._k_t[hi - 1])
        j = np.searchsorted(self._k_key, rows * self._k_span + (tc - self._k_tmin), side="right") - 1
        j = np.clip(j, lo, hi - 2)
        h = self._k_t[j + 1] - self._k_t[j]
        s = (tc - self._k_t[j]) / h
        x, vx = _hermite(s, h, self._k_x[j], self._k_x[j + 1], self._k_vx[j], self._k_vx[j + 1])
        y, vy = _hermite(s, h, self._k_y[j], self._k_y[j + 1], self._k_vy[j], self._k_vy[j + 1])
        z, vz = _hermite(s, h, self._k_z[j], self._k_z[j + 1], self._k_vz[j], self._k_vz[j + 1])
        extra = t - tc  # constant-velocity extrapolation outside the samples
        return x + vx * extra, y + vy * extra, z + vz * extra, vx, vy, vz

    # ----------------------------------------------------------------- public
    def state(self, index: Any, t_s: Any) -> KinematicState:
        """Truth state of targets ``index`` at times ``t_s`` (broadcast, flattened)."""
        idx, t = np.broadcast_arrays(np.asarray(index, np.intp), np.asarray(t_s, float))
        idx, t = idx.reshape(-1), t.reshape(-1)
        out = [np.empty(t.shape[0]) for _ in range(6)]
        syn = self._synthetic[idx]
        for mask, fn in ((syn, self._state_synthetic), (~syn, self._state_sampled)):
            if np.any(mask):
                vals = fn(self._local[idx[mask]], t[mask])
                for o, v in zip(out, vals):
                    o[mask] = v
        active = (t >= self.t_begin_s[idx]) & (t <= self.t_end_s[idx])
        return KinematicState(*out, active=active)


# =========================================================================== simulation results


@dataclass
class PlotColumns:
    """The plots of one published PlotBatch as numpy columns (for benchmarks without msgpack).

    Missing values: ``fl`` NaN, ``mode3a``/``mode_s``/``track_no`` -1; ``kind`` uses
    :data:`wire.KIND_CODES`; ``target_index`` is the true target (row of
    ``Scenario.targets``), -1 for false plots; ``wild`` marks gross errors.
    """

    radar_id: str
    radar_index: int
    seq: int
    t_pub_s: float
    t_s: np.ndarray
    range_m: np.ndarray
    azimuth_deg: np.ndarray
    fl: np.ndarray
    mode3a: np.ndarray
    mode_s: np.ndarray
    track_no: np.ndarray
    kind: np.ndarray
    target_index: np.ndarray
    wild: np.ndarray

    def __len__(self) -> int:
        return int(self.t_s.shape[0])

    def to_decoded(self) -> wire.DecodedPlots:
        """The same plots as :func:`wire.decode_plot_batch` would return them."""
        return wire.DecodedPlots(
            radar_id=self.radar_id, seq=self.seq, t_s=self.t_s, range_m=self.range_m,
            azimuth_deg=self.azimuth_deg, fl=self.fl, mode3a=self.mode3a, mode_s=self.mode_s,
            track_no=self.track_no, kind=self.kind,
        )  # fmt: skip


@dataclass
class Truth:
    """Ground truth sampled every second while each target exists (row arrays)."""

    t_s: np.ndarray
    target_index: np.ndarray
    target_id: np.ndarray
    mode_s: np.ndarray
    """6 hex digits or "" (str array)"""
    callsign: np.ndarray
    lat_deg: np.ndarray
    lon_deg: np.ndarray
    alt_ft: np.ndarray
    x_m: np.ndarray
    y_m: np.ndarray
    vx_mps: np.ndarray
    vy_mps: np.ndarray
    vrate_fpm: np.ndarray
    detectable: np.ndarray

    def __len__(self) -> int:
        return int(self.t_s.shape[0])


@dataclass
class Simulation:
    """Result of :func:`simulate`.

    ``messages``: (t_s, key relative to the prefix, payload) in publish order;
    ``plot_columns``: one :class:`PlotColumns` per PlotBatch message, same order;
    ``statuses``: (t_s, radar_id, kind, sector) of every RadarStatus message;
    ``truth``: :class:`Truth`; ``trajectories``: exact truth at any time;
    ``radar_phase_deg``: antenna phase per radar (beam azimuth at ``start_t_s``).
    """

    scenario: Scenario
    plane: SystemPlane
    sites: RadarSites
    trajectories: Trajectories
    radar_phase_deg: np.ndarray
    messages: list[tuple[float, str, bytes]]
    plot_columns: list[PlotColumns]
    statuses: list[tuple[float, str, str, int]]
    truth: Truth
    stats: dict[str, dict[str, int]]

    def beam_azimuth_deg(self, radar_index: int, t_s: Any) -> np.ndarray:
        """Beam azimuth of a radar at times ``t_s``: 360 ((t - t0)/T mod 1) + phase, mod 360."""
        r = self.scenario.radars[radar_index]
        t = np.asarray(t_s, float)
        return np.mod(360.0 * np.mod((t - self.scenario.start_t_s) / r.rotation_period_s, 1.0)
                      + self.radar_phase_deg[radar_index], 360.0)  # fmt: skip

    def truth_at(self, target_index: Any, t_s: Any) -> dict[str, np.ndarray]:
        """Exact truth (lat_deg, lon_deg, alt_ft, x_m, y_m, vx_mps, vy_mps, vrate_fpm, active)."""
        st = self.trajectories.state(target_index, t_s)
        lat, lon = self.plane.to_geodetic(st.x_m, st.y_m)
        return dict(lat_deg=lat, lon_deg=lon, alt_ft=st.alt_m / FT_M, x_m=st.x_m, y_m=st.y_m,
                    vx_mps=st.vx_mps, vy_mps=st.vy_mps, vrate_fpm=st.vz_mps / FPM_MPS, active=st.active)  # fmt: skip

    def all_plots(self) -> PlotColumns:
        """All plots of all radars in one :class:`PlotColumns` (publish order; the radar of
        each plot is not kept: use :attr:`plot_columns` for per-radar work)."""
        cols = self.plot_columns
        cat = lambda name: np.concatenate([getattr(c, name) for c in cols]) if cols else np.zeros(0)  # noqa: E731
        return PlotColumns(
            radar_id="*", radar_index=-1, seq=-1, t_pub_s=math.nan,
            **{name: cat(name) for name in ("t_s", "range_m", "azimuth_deg", "fl", "mode3a", "mode_s",
                                            "track_no", "kind", "target_index", "wild")},
        )  # fmt: skip


# =========================================================================== radar model


def _wrap180(a: np.ndarray) -> np.ndarray:
    return np.mod(a + 180.0, 360.0) - 180.0


def _coverage(spec: RadarSpec, earth_radius_m: float, slant_m, ground_m, alt_m) -> np.ndarray:
    """In range, above the radar horizon (4/3 earth) and below the cone of silence."""
    a = earth_radius_m + spec.alt_m
    b = earth_radius_m + alt_m
    with np.errstate(invalid="ignore", divide="ignore"):
        sin_el = (b * b - a * a - slant_m * slant_m) / (2.0 * a * slant_m)
    ke = _EFFECTIVE_EARTH_K * earth_radius_m
    horizon_m = np.sqrt(2.0 * ke * max(spec.alt_m, 0.0)) + np.sqrt(2.0 * ke * np.maximum(alt_m, 0.0))
    return (
        (slant_m <= spec.max_range_m)
        & (ground_m <= horizon_m)
        & (sin_el <= math.sin(math.radians(spec.max_elevation_deg)))
    )


def _wild_offsets(rng: np.random.Generator, rates: Rates, n_scans: int, n: int):
    """Per (scan, target): wild range and azimuth offsets (0 where not wild) and flag."""
    d_range = np.zeros((n_scans, n))
    d_az = np.zeros((n_scans, n))

    def draw(k: int):
        use_range = rng.random(k) < 0.5
        sign = np.where(rng.random(k) < 0.5, -1.0, 1.0)
        mag_r = rng.uniform(*rates.wild_range_m, size=k)
        mag_a = rng.uniform(*rates.wild_azimuth_deg, size=k)
        return np.where(use_range, sign * mag_r, 0.0), np.where(use_range, 0.0, sign * mag_a)

    # runs first, isolated wild plots on top
    s, i = np.nonzero(rng.random((n_scans, n)) < rates.wild_run_prob)
    if s.size:
        lo, hi = rates.wild_run_scans
        length = rng.integers(lo, hi + 1, size=s.size)
        dr, da = draw(s.size)
        for step in range(int(length.max())):
            m = (step < length) & (s + step < n_scans)
            d_range[s[m] + step, i[m]] = dr[m]
            d_az[s[m] + step, i[m]] = da[m]
    s, i = np.nonzero(rng.random((n_scans, n)) < rates.wild_plot_prob)
    if s.size:
        dr, da = draw(s.size)
        d_range[s, i], d_az[s, i] = dr, da
    return d_range, d_az, (d_range != 0.0) | (d_az != 0.0)


class _TargetTable:
    """Per-target identity columns (arrays indexed by target)."""

    def __init__(self, targets: Sequence[Target]) -> None:
        self.transponder = np.array([_TRANSPONDERS[t.transponder] for t in targets], np.int8)
        self.mode_s = np.array([-1 if t.mode_s is None else t.mode_s for t in targets], np.int64)
        self.mode3a = np.array([-1 if t.mode3a is None else t.mode3a for t in targets], np.int64)
        self.mode_c = np.array([t.mode_c and t.transponder != "none" for t in targets], bool)
        self.q25 = np.array([t.alt_quantum_ft == 25.0 for t in targets], bool)


def _radar_plots(
    sim_ctx: dict, r: int, spec: RadarSpec, rates: Rates, phase_deg: float, rng: np.random.Generator
) -> dict[str, np.ndarray]:
    """All plots (true, wild and false) of radar ``r`` over the scenario, as columns."""
    traj: Trajectories = sim_ctx["traj"]
    plane: SystemPlane = sim_ctx["plane"]
    sites: RadarSites = sim_ctx["sites"]
    tt: _TargetTable = sim_ctx["targets"]
    t_start, t_end = sim_ctx["t_start"], sim_ctx["t_end"]
    period = spec.rotation_period_s
    n = traj.n
    # Only targets that can come within range during the scenario are followed
    # (a plane-distance bound: at most 350 m/s from their position at the start).
    sx, sy = sites.plane_positions(plane)
    st0 = traj.state(np.arange(n), np.full(n, t_start))
    reach_m = 1.02 * spec.max_range_m + 10_000.0 + 350.0 * (t_end - t_start)
    idx = np.nonzero(np.hypot(st0.x_m - sx[r], st0.y_m - sy[r]) <= reach_m)[0]
    n_followed = idx.size

    def beam_angle(t):
        return 360.0 * (t - t_start) / period + phase_deg

    def beam_time(angle):
        return t_start + (angle - phase_deg) * period / 360.0

    def polar(t):
        st = traj.state(idx, t)
        lat, lon = plane.to_geodetic(st.x_m, st.y_m)
        rho, az, g = geodetic_to_polar(sites, np.full(n_followed, r), lat, lon, st.alt_m)
        return rho, az, g, st

    # ---- beam crossings, one per target per step (a scan of that target)
    cols: dict[str, list] = {k: [] for k in ("tgt", "step", "t", "rho", "az", "g", "alt", "active")}
    if n_followed:
        _, lift, _, _ = polar(np.full(n_followed, t_start))
        n_rev = np.ceil((beam_angle(t_start) - lift) / 360.0)
        step = 0
        while True:
            t_c = beam_time(360.0 * n_rev + lift)
            if np.all(t_c >= t_end + period):
                break
            for _ in range(2):
                _, az, _, _ = polar(t_c)
                lift = lift + _wrap180(az - lift)
                t_c = beam_time(360.0 * n_rev + lift)
            rho, az, g, st = polar(t_c)
            lift = lift + _wrap180(az - lift)
            keep = (t_c >= t_start) & (t_c < t_end)
            if np.any(keep):
                cols["tgt"].append(idx[keep])
                cols["step"].append(np.full(int(keep.sum()), step))
                for k, v in (("t", t_c), ("rho", rho), ("az", az), ("g", g), ("alt", st.alt_m), ("active", st.active)):
                    cols[k].append(v[keep])
            n_rev += 1.0
            step += 1
    c = {k: (np.concatenate(v) if v else np.zeros(0, dtype=np.intp if k in ("tgt", "step") else float))
         for k, v in cols.items()}  # fmt: skip
    c["active"] = c["active"].astype(bool)
    m = c["t"].shape[0]
    tgt = c["tgt"].astype(np.intp)

    # ---- detection, kind and identity
    cover = c["active"] & _coverage(spec, float(sites.earth_radius_m[r]), c["rho"], c["g"], c["alt"])
    tr = tt.transponder[tgt]
    ssr_path = spec.ssr & (tr > 0)
    psr_path = ~ssr_path & spec.psr
    pd = np.where(ssr_path, rates.pd, np.where(psr_path, rates.pd_psr, 0.0))
    detected = cover & (rng.random(m) < pd)
    kind = np.where(
        ssr_path,
        np.where(spec.mode_s & (tr == 2), KIND_MODES, np.where(spec.psr & (rng.random(m) < rates.pd_psr), KIND_CMB, KIND_SSR)),
        KIND_PSR,
    ).astype(np.int8)
    secondary = kind != KIND_PSR
    mode3a = np.where(secondary, tt.mode3a[tgt], -1)
    mode_s = np.where(kind == KIND_MODES, tt.mode_s[tgt], -1)
    quantum_ft = np.where((kind == KIND_MODES) & tt.q25[tgt], 25.0, 100.0)
    has_fl = secondary & tt.mode_c[tgt] & (rng.random(m) < rates.p_mode_c)
    fl = np.where(has_fl, np.round(c["alt"] / FT_M / quantum_ft) * quantum_ft / 100.0, np.nan)
    track_numbers = rng.permutation(max(4095, n))[:n].astype(np.int64) + 1
    track_no = track_numbers[tgt] if n else np.zeros(0, np.int64)

    # ---- measurement noise, bias and wild plots
    n_scans = int(math.ceil(sim_ctx["duration_s"] / period)) + 4
    d_range, d_az, wild_tab = _wild_offsets(rng, rates, n_scans, n)
    step = np.minimum(c["step"].astype(np.intp), n_scans - 1)
    wild = wild_tab[step, tgt] if m else np.zeros(0, bool)
    range_m = c["rho"] + spec.range_bias_m + rng.normal(0.0, spec.sigma_range_m, m) + (d_range[step, tgt] if m else 0.0)
    az_deg = c["az"] + spec.azimuth_bias_deg + rng.normal(0.0, spec.sigma_azimuth_deg, m) + (d_az[step, tgt] if m else 0.0)
    reported = detected & (range_m > 0.0) & (range_m <= spec.max_range_m)

    # ---- false plots: Poisson per revolution, uniform over the coverage disc
    rev0 = math.floor(beam_angle(t_start) / 360.0)
    rev1 = math.ceil(beam_angle(t_end) / 360.0)
    counts = rng.poisson(rates.false_plots_per_scan, size=max(rev1 - rev0, 0))
    k = int(counts.sum())
    rev = np.repeat(np.arange(rev0, rev1), counts)
    f_az = rng.uniform(0.0, 360.0, k)
    r_min = 2000.0
    f_range = np.sqrt(rng.uniform(r_min**2, spec.max_range_m**2, k))
    f_t = beam_time(360.0 * rev + f_az)
    f_keep = (f_t >= t_start) & (f_t < t_end)

    sel = np.nonzero(reported)[0]
    out = {
        "t_s": np.concatenate([c["t"][sel], f_t[f_keep]]),
        "range_m": np.concatenate([range_m[sel], f_range[f_keep]]),
        "azimuth_deg": np.concatenate([az_deg[sel], f_az[f_keep]]),
        "fl": np.concatenate([fl[sel], np.full(int(f_keep.sum()), np.nan)]),
        "mode3a": np.concatenate([mode3a[sel], np.full(int(f_keep.sum()), -1)]).astype(np.int64),
        "mode_s": np.concatenate([mode_s[sel], np.full(int(f_keep.sum()), -1)]).astype(np.int64),
        "track_no": np.concatenate([track_no[sel], np.full(int(f_keep.sum()), -1)]).astype(np.int64),
        "kind": np.concatenate([kind[sel], np.full(int(f_keep.sum()), KIND_PSR if spec.psr else KIND_SSR, np.int8)]),
        "target_index": np.concatenate([tgt[sel], np.full(int(f_keep.sum()), -1)]).astype(np.int64),
        "wild": np.concatenate([wild[sel], np.zeros(int(f_keep.sum()), bool)]),
    }
    az = np.mod(out["azimuth_deg"], 360.0)
    out["azimuth_deg"] = np.where(az >= 360.0, 0.0, az)
    order = np.argsort(out["t_s"], kind="stable")
    out = {k2: v[order] for k2, v in out.items()}
    out["_stats"] = {
        "crossings_in_coverage": int(cover.sum()),
        "detections": int(detected.sum()),
        "target_plots": int(sel.size),
        "wild_plots": int(wild[sel].sum()),
        "false_plots": int(f_keep.sum()),
    }
    return out


# =========================================================================== msgpack encoding


def _packed_key(name: str) -> np.ndarray:
    return np.frombuffer(msgpack.packb(name), np.uint8)


_HEX_ASCII = np.frombuffer(b"0123456789ABCDEF", np.uint8)
_KIND3 = np.zeros((5, 4), np.uint8)
for _code, _name in ((KIND_PSR, "psr"), (KIND_SSR, "ssr"), (KIND_CMB, "cmb")):
    _KIND3[_code] = np.frombuffer(msgpack.packb(_name), np.uint8)


def _pack_plots(cols: dict[str, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """msgpack-encode every plot as a map, vectorised over plots.

    Each plot is built from fixed-width byte blocks (key + value), one per field, and a
    mask drops the blocks of absent fields (``fl`` NaN, ``mode3a``/``mode_s``/``track_no``
    -1). Floats are float64 (0xcb), ``mode3a`` uint16 (0xcd), ``track_no`` uint32
    (0xce), strings fixstr: valid msgpack that decodes to the same values as
    :func:`wire.encode` of the same dict. Returns (bytes as uint8, offsets (n+1,)).
    """
    n = cols["t_s"].shape[0]
    blocks: list[tuple[np.ndarray, Optional[np.ndarray]]] = []

    def block(key: str, tag: Optional[int], value: np.ndarray, present: Optional[np.ndarray]) -> None:
        kb = _packed_key(key)
        width = kb.size + (1 if tag is not None else 0) + value.shape[1]
        b = np.empty((n, width), np.uint8)
        b[:, : kb.size] = kb
        o = kb.size
        if tag is not None:
            b[:, o] = tag
            o += 1
        b[:, o:] = value
        blocks.append((b, present))

    def f64(a):
        return np.ascontiguousarray(a, dtype=">f8").view(np.uint8).reshape(n, 8)

    fl_ok = np.isfinite(cols["fl"])
    m3_ok = cols["mode3a"] >= 0
    ms_ok = cols["mode_s"] >= 0
    tn_ok = cols["track_no"] >= 0
    is5 = cols["kind"] == KIND_MODES
    count = 4 + fl_ok.astype(np.uint8) + m3_ok + ms_ok + tn_ok
    blocks.append(((0x80 | count).astype(np.uint8).reshape(n, 1), None))
    block("t", 0xCB, f64(cols["t_s"]), None)
    block("range_m", 0xCB, f64(cols["range_m"]), None)
    block("azimuth_deg", 0xCB, f64(cols["azimuth_deg"]), None)
    block("fl", 0xCB, f64(np.where(fl_ok, cols["fl"], 0.0)), fl_ok)
    m3 = np.where(m3_ok, cols["mode3a"], 0).astype(">u2").view(np.uint8).reshape(n, 2)
    block("mode3a", 0xCD, m3, m3_ok)
    ms = np.where(ms_ok, cols["mode_s"], 0)
    digits = (ms[:, None] >> np.array([20, 16, 12, 8, 4, 0])) & 0xF
    block("mode_s", 0xA6, _HEX_ASCII[digits], ms_ok)
    tn = np.where(tn_ok, cols["track_no"], 0).astype(">u4").view(np.uint8).reshape(n, 4)
    block("track_no", 0xCE, tn, tn_ok)
    block("kind", None, _KIND3[np.where(is5, 0, cols["kind"])], ~is5)
    block("kind", None, np.broadcast_to(np.frombuffer(msgpack.packb("modes"), np.uint8), (n, 6)), is5)
    data = np.concatenate([b for b, _ in blocks], axis=1)
    mask = np.concatenate(
        [np.ones(b.shape, bool) if p is None else np.broadcast_to(p[:, None], b.shape) for b, p in blocks], axis=1
    )
    lengths = mask.sum(axis=1)
    offsets = np.concatenate([[0], np.cumsum(lengths)]).astype(np.intp)
    return data[mask], offsets


def _array_header(n: int) -> bytes:
    if n < 16:
        return bytes([0x90 | n])
    if n < 1 << 16:
        return b"\xdc" + n.to_bytes(2, "big")
    return b"\xdd" + n.to_bytes(4, "big")


def _batch_payload(radar_id: str, seq: int, plot_bytes: bytes, n: int) -> bytes:
    head = msgpack.packb({"v": wire.WIRE_VERSION, "radar_id": radar_id, "seq": seq, "plots": []})
    # the empty array is the last byte (0x90) of ``head``: replace it with the plots
    return head[:-1] + _array_header(n) + plot_bytes


# =========================================================================== simulate


def _mode_s_str(a: np.ndarray) -> np.ndarray:
    return np.array(["" if v < 0 else f"{int(v):06X}" for v in a], dtype=object)


def _covered_by_any(sim_ctx: dict, radars: Sequence[RadarSpec], lat, lon, alt_m, x_m, y_m) -> np.ndarray:
    """True where at least one radar covers the point (range, horizon, cone of silence)."""
    sites: RadarSites = sim_ctx["sites"]
    sx, sy = sites.plane_positions(sim_ctx["plane"])
    out = np.zeros(lat.shape[0], bool)
    for r, spec in enumerate(radars):
        # plane distance prefilter (the plane's scale error is < 1 % at these distances)
        cand = np.nonzero(~out & (np.hypot(x_m - sx[r], y_m - sy[r]) <= 1.02 * spec.max_range_m + 5000.0))[0]
        if cand.size == 0:
            continue
        rho, _az, g = geodetic_to_polar(sites, np.full(cand.size, r), lat[cand], lon[cand], alt_m[cand])
        out[cand] |= _coverage(spec, float(sites.earth_radius_m[r]), rho, g, alt_m[cand])
    return out


def _sample_truth(sim_ctx: dict, scenario: Scenario) -> Truth:
    traj: Trajectories = sim_ctx["traj"]
    times = scenario.start_t_s + np.arange(0.0, math.floor(scenario.duration_s) + 1.0)
    tgt, tk = np.meshgrid(np.arange(traj.n), times, indexing="ij")
    tgt, tk = tgt.reshape(-1), tk.reshape(-1)
    st = traj.state(tgt, tk)
    keep = st.active
    tgt, tk = tgt[keep], tk[keep]
    x, y, alt = st.x_m[keep], st.y_m[keep], st.alt_m[keep]
    lat, lon = sim_ctx["plane"].to_geodetic(x, y)
    det = _covered_by_any(sim_ctx, scenario.radars, lat, lon, alt, x, y)
    ids = np.array([t.target_id for t in scenario.targets], dtype=object)
    ms = _mode_s_str(np.array([-1 if t.mode_s is None else t.mode_s for t in scenario.targets], np.int64))
    cs = np.array([t.callsign or "" for t in scenario.targets], dtype=object)
    return Truth(
        t_s=tk, target_index=tgt, target_id=ids[tgt] if tgt.size else np.zeros(0, object),
        mode_s=ms[tgt] if tgt.size else np.zeros(0, object), callsign=cs[tgt] if tgt.size else np.zeros(0, object),
        lat_deg=lat, lon_deg=lon, alt_ft=alt / FT_M, x_m=x, y_m=y,
        vx_mps=st.vx_mps[keep], vy_mps=st.vy_mps[keep], vrate_fpm=st.vz_mps[keep] / FPM_MPS, detectable=det,
    )  # fmt: skip


def simulate(scenario: Scenario, *, encode: bool = True) -> Simulation:
    """Simulate every radar over the scenario.

    ``encode=False`` skips building msgpack payloads (``messages`` is then empty) for
    benchmarks that only use :attr:`Simulation.plot_columns`.
    """
    if not scenario.radars:
        raise ValueError("a scenario needs at least one radar")
    plane = SystemPlane(scenario.center_lat_deg, scenario.center_lon_deg)
    sites = RadarSites.from_configs(scenario.radars)
    traj = Trajectories(scenario.targets, plane, scenario.start_t_s)
    t_start = float(scenario.start_t_s)
    t_end = t_start + float(scenario.duration_s)
    ctx = dict(traj=traj, plane=plane, sites=sites, targets=_TargetTable(scenario.targets),
               t_start=t_start, t_end=t_end, duration_s=float(scenario.duration_s))  # fmt: skip
    seeds = np.random.SeedSequence(scenario.seed).spawn(len(scenario.radars) + 1)
    phase_rng = np.random.default_rng(seeds[0])
    phases = np.array([
        phase_rng.uniform(0.0, 360.0) if r.start_phase_deg is None else float(r.start_phase_deg) % 360.0
        for r in scenario.radars
    ])  # fmt: skip

    # per radar: batches and status events; merged afterwards
    ev_t: list[np.ndarray] = []
    ev_radar: list[np.ndarray] = []
    ev_sub: list[np.ndarray] = []  # 0 batch, 1 status (batch first at equal time)
    ev_ref: list[np.ndarray] = []  # index into the radar's batch / status list
    batches: list[list[PlotColumns]] = []
    payloads: list[list[bytes]] = []
    status_rows: list[list[tuple]] = []
    stats: dict[str, dict[str, int]] = {}
    for r, spec in enumerate(scenario.radars):
        rng = np.random.default_rng(seeds[r + 1])
        p = _radar_plots(ctx, r, spec, scenario.rates_of(spec), float(phases[r]), rng)
        stats[spec.id] = p.pop("_stats")
        period, phase = spec.rotation_period_s, float(phases[r])
        width = 360.0 / spec.n_sectors
        angle = lambda t: 360.0 * (t - t_start) / period + phase  # noqa: E731
        btime = lambda a: t_start + (a - phase) * period / 360.0  # noqa: E731
        q_first = math.floor(angle(t_start) / width)
        q_last = math.floor(angle(t_end) / width) - 1
        sweeps = np.arange(q_first, q_last + 1)
        t_pub = btime((sweeps + 1) * width)
        q_plot = np.floor(angle(p["t_s"]) / width)
        bounds = np.searchsorted(q_plot, np.concatenate([sweeps, [q_last + 1]]), side="left")
        if encode:
            data, offsets = _pack_plots(p)
        rb, rp, rs = [], [], []
        for b, q in enumerate(sweeps):
            lo, hi = int(bounds[b]), int(bounds[b + 1])
            cols = PlotColumns(spec.id, r, b, float(t_pub[b]), **{k: v[lo:hi] for k, v in p.items()})
            rb.append(cols)
            if encode:
                rp.append(_batch_payload(spec.id, b, data[offsets[lo]:offsets[hi]].tobytes(), hi - lo))
            sector = int((q + 1) % spec.n_sectors)
            rs.append((float(t_pub[b]), spec.id, "north" if sector == 0 else "sector", sector))
        stats[spec.id]["batches"] = len(rb)
        stats[spec.id]["published_plots"] = int(sum(len(x) for x in rb))
        batches.append(rb)
        payloads.append(rp)
        status_rows.append(rs)
        nb = len(rb)
        ev_t += [t_pub, t_pub]
        ev_radar += [np.full(nb, r), np.full(nb, r)]
        ev_sub += [np.zeros(nb, np.int8), np.ones(nb, np.int8)]
        ev_ref += [np.arange(nb), np.arange(nb)]

    t_all = np.concatenate(ev_t)
    radar_all, sub_all, ref_all = np.concatenate(ev_radar), np.concatenate(ev_sub), np.concatenate(ev_ref)
    order = np.lexsort((sub_all, radar_all, t_all))
    messages: list[tuple[float, str, bytes]] = []
    plot_columns: list[PlotColumns] = []
    statuses: list[tuple[float, str, str, int]] = []
    for i in order.tolist():
        r, k = int(radar_all[i]), int(ref_all[i])
        spec = scenario.radars[r]
        if sub_all[i] == 0:
            plot_columns.append(batches[r][k])
            if encode:
                messages.append((float(t_all[i]), f"radar/{spec.id}/plots", payloads[r][k]))
        else:
            row = status_rows[r][k]
            statuses.append(row)
            if encode:
                msg = {"v": wire.WIRE_VERSION, "radar_id": spec.id, "t": row[0], "kind": row[2], "sector": row[3]}
                if row[2] == "north":
                    msg["rotation_period_s"] = float(spec.rotation_period_s)
                messages.append((row[0], f"radar/{spec.id}/status", wire.encode(msg)))

    truth = _sample_truth(ctx, scenario)
    return Simulation(
        scenario=scenario, plane=plane, sites=sites, trajectories=traj, radar_phase_deg=phases,
        messages=messages, plot_columns=plot_columns, statuses=statuses, truth=truth, stats=stats,
    )  # fmt: skip


# =========================================================================== outputs


def _fmt(v: float, digits: int) -> str:
    return f"{v:.{digits}f}"


def write_truth(truth: Truth, path: str | Path) -> None:
    """Write the truth CSV (header :data:`TRUTH_COLUMNS`)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(TRUTH_COLUMNS)
        w.writerows(
            zip(
                [_fmt(v, 3) for v in truth.t_s.tolist()],
                truth.target_id.tolist(),
                truth.mode_s.tolist(),
                truth.callsign.tolist(),
                [_fmt(v, 7) for v in truth.lat_deg.tolist()],
                [_fmt(v, 7) for v in truth.lon_deg.tolist()],
                [_fmt(v, 1) for v in truth.alt_ft.tolist()],
                [_fmt(v, 2) for v in truth.x_m.tolist()],
                [_fmt(v, 2) for v in truth.y_m.tolist()],
                [_fmt(v, 3) for v in truth.vx_mps.tolist()],
                [_fmt(v, 3) for v in truth.vy_mps.tolist()],
                [_fmt(v, 1) for v in truth.vrate_fpm.tolist()],
                truth.detectable.astype(np.int8).tolist(),
            )
        )


def read_truth(path: str | Path) -> Truth:
    """Read a truth CSV written by :func:`write_truth` (``target_index`` is the order of
    first appearance of each target id)."""
    with open(path, newline="") as f:
        reader = csv.reader(f)
        header = next(reader)
        missing = set(TRUTH_COLUMNS) - set(header)
        if missing:
            raise ValueError(f"{path}: truth CSV lacks columns {sorted(missing)}")
        rows = list(reader)
    col = {name: [row[i] for row in rows] for i, name in enumerate(header)}
    ids = np.array(col["target_id"], dtype=object)
    _, first, inverse = np.unique(ids.astype(str), return_index=True, return_inverse=True)
    rank = np.argsort(np.argsort(first, kind="stable"), kind="stable")
    num = lambda name: np.array(col[name], dtype=float)  # noqa: E731
    return Truth(
        t_s=num("t_s"), target_index=rank[inverse.reshape(-1)] if rows else np.zeros(0, np.intp), target_id=ids,
        mode_s=np.array(col["mode_s"], dtype=object), callsign=np.array(col["callsign"], dtype=object),
        lat_deg=num("lat_deg"), lon_deg=num("lon_deg"), alt_ft=num("alt_ft"), x_m=num("x_m"), y_m=num("y_m"),
        vx_mps=num("vx_mps"), vy_mps=num("vy_mps"), vrate_fpm=num("vrate_fpm"),
        detectable=np.array([v.strip() in ("1", "true", "True") for v in col["detectable"]], bool),
    )  # fmt: skip


def _toml_value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (int, np.integer)):
        return str(int(v))
    if isinstance(v, (float, np.floating)):
        return repr(float(v))
    if isinstance(v, str):
        return json.dumps(v)
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    raise TypeError(f"cannot write {type(v).__name__} to TOML")


def config_toml(scenario: Scenario) -> str:
    """A daemon configuration (DESIGN.md §3) for this scenario: the radars as the daemon
    knows them (site, accuracy, rotation; not their biases, which it cannot know)."""
    lines = [
        f"# radar-fusion daemon configuration for simulated scenario {scenario.name!r} (seed {scenario.seed})",
        "[system]",
        f"center_lat = {_toml_value(float(scenario.center_lat_deg))}",
        f"center_lon = {_toml_value(float(scenario.center_lon_deg))}",
        f"period_s = {_toml_value(float(scenario.effective_period_s))}",
        "",
        "[bus]",
        'mode = "router"',
        'listen = ["tcp/127.0.0.1:7447"]',
        "connect = []",
        'prefix = "atc"',
    ]
    for spec in scenario.radars:
        lines += ["", "[[radars]]"]
        items = [
            ("id", spec.id), ("lat", float(spec.lat_deg)), ("lon", float(spec.lon_deg)), ("alt_m", float(spec.alt_m)),
            ("sigma_range_m", float(spec.sigma_range_m)), ("sigma_azimuth_deg", float(spec.sigma_azimuth_deg)),
            ("rotation_period_s", float(spec.rotation_period_s)), ("max_range_m", float(spec.max_range_m)),
        ]  # fmt: skip
        if spec.sac is not None and spec.sic is not None:
            items += [("sac", spec.sac), ("sic", spec.sic)]
        lines += [f"{k} = {_toml_value(v)}" for k, v in items]
    return "\n".join(lines) + "\n"


def write_outputs(simulation: Simulation, out_dir: str | Path, *, gzip_recording: bool = False) -> dict[str, Path]:
    """Write plots.rec (or plots.rec.gz), truth.csv and config.toml into ``out_dir``."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    sc = simulation.scenario
    if not simulation.messages and simulation.plot_columns:
        raise ValueError("this simulation was run with encode=False: no messages to record")
    rec_path = out / ("plots.rec.gz" if gzip_recording else "plots.rec")
    meta = {
        "generator": "radar-fusion simulate",
        "scenario": sc.name,
        "seed": int(sc.seed),
        "start_t_s": float(sc.start_t_s),
        "duration_s": float(sc.duration_s),
        "center_lat": float(sc.center_lat_deg),
        "center_lon": float(sc.center_lon_deg),
        "radars": [r.id for r in sc.radars],
        "n_targets": len(sc.targets),
    }
    with RecordingWriter(rec_path, meta) as w:
        for t_s, key, payload in simulation.messages:
            w.write(t_s, key, payload)
    truth_path = out / "truth.csv"
    write_truth(simulation.truth, truth_path)
    cfg_path = out / "config.toml"
    cfg_path.write_text(config_toml(sc), encoding="utf-8")
    return {"recording": rec_path, "truth": truth_path, "config": cfg_path}


# =========================================================================== targets: helpers


def _mode3a_codes(rng: np.random.Generator, n: int) -> np.ndarray:
    reserved = np.array([0o7500, 0o7600, 0o7700, 0o7000, 0o2000, 0o1200])
    pool = np.setdiff1d(np.arange(0o0100, 0o10000), reserved)
    if n <= pool.size:
        return rng.choice(pool, size=n, replace=False)
    return rng.choice(pool, size=n, replace=True)


def _mode_s_addresses(rng: np.random.Generator, n: int) -> np.ndarray:
    """Distinct random 24-bit addresses (in the ICAO blocks of European states)."""
    return 0x300000 + rng.choice(0x0FFFFF, size=n, replace=False)


def _plan_toward(point_xy: tuple[float, float], heading_deg: float, speed_mps: float, t_cross_s: float,
                 alt_ft: float, total_s: float, vrate_fpm: float = 0.0) -> FlightPlan:
    """A straight flight that passes ``point_xy`` at ``t_cross_s`` after the start."""
    psi = math.radians(heading_deg)
    x0 = point_xy[0] - speed_mps * t_cross_s * math.sin(psi)
    y0 = point_xy[1] - speed_mps * t_cross_s * math.cos(psi)
    return FlightPlan(x0, y0, heading_deg, speed_mps, alt_ft, (Leg(total_s, 0.0, vrate_fpm),))


# =========================================================================== presets


def demo_scenario(seed: int = 1, duration_s: float = 540.0, start_t_s: float = EPOCH_2018_08_01_08Z) -> Scenario:
    """3 radars (4, 8, 12 s) around a centre in Switzerland and 28 aircraft.

    Traffic: straight legs (incl. 120 and 260 m/s), rate-one (3 °/s) and 1.5 °/s turns,
    a racetrack, an S-turn, climbs and descents of 1,500-2,500 ft/min (some while
    turning), three crossing pairs (same point, same level, same time), three close
    parallel pairs 1, 2 and 3 NM apart, Mode S and Mode A/C-only transponders, one
    without Mode C and one primary-only target. Small false/wild plot rates.
    """
    rng = np.random.default_rng(10_000 + seed)
    center = (46.8, 8.2)
    plane = SystemPlane(*center)

    def site(bearing_deg: float, dist_m: float) -> tuple[float, float]:
        lat, lon = plane.to_geodetic(dist_m * math.sin(math.radians(bearing_deg)),
                                     dist_m * math.cos(math.radians(bearing_deg)))  # fmt: skip
        return float(lat), float(lon)

    rates = Rates(pd=0.95, pd_psr=0.85, p_mode_c=0.99, false_plots_per_scan=1.0,
                  wild_plot_prob=0.002, wild_run_prob=0.0005, wild_run_scans=(3, 5))  # fmt: skip
    radars = [
        RadarSpec("app", *site(330.0, 45_000.0), alt_m=900.0, rotation_period_s=4.0, sigma_range_m=30.0,
                  sigma_azimuth_deg=0.06, range_bias_m=40.0, azimuth_bias_deg=0.03, max_range_m=100 * NM_M,
                  psr=True, ssr=True, mode_s=True, n_sectors=16, sac=1, sic=1),
        RadarSpec("east", *site(90.0, 70_000.0), alt_m=1600.0, rotation_period_s=8.0, sigma_range_m=50.0,
                  sigma_azimuth_deg=0.07, range_bias_m=-60.0, azimuth_bias_deg=-0.04, max_range_m=200 * NM_M,
                  psr=True, ssr=True, mode_s=True, n_sectors=32, sac=1, sic=2),
        RadarSpec("south", *site(220.0, 65_000.0), alt_m=1700.0, rotation_period_s=12.0, sigma_range_m=70.0,
                  sigma_azimuth_deg=0.08, range_bias_m=25.0, azimuth_bias_deg=0.05, max_range_m=250 * NM_M,
                  psr=False, ssr=True, mode_s=True, n_sectors=32, sac=1, sic=3),
    ]  # fmt: skip
    total = duration_s + 60.0
    targets: list[Target] = []
    addr = iter(_mode_s_addresses(rng, 64).tolist())
    codes = iter(_mode3a_codes(rng, 64).tolist())

    def add(name: str, plan: FlightPlan, transponder: str = "modes", mode_c: bool = True, q25: bool = False) -> None:
        k = len(targets) + 1
        targets.append(Target(
            target_id=f"T{k:02d}", callsign=name if transponder == "modes" else None,
            mode_s=next(addr) if transponder == "modes" else None,
            mode3a=next(codes) if transponder != "none" else None, transponder=transponder,
            mode_c=mode_c and transponder != "none", alt_quantum_ft=25.0 if q25 else 100.0, plan=plan,
        ))  # fmt: skip

    km = 1000.0
    # straight legs
    add("SWR101", FlightPlan(-70 * km, 40 * km, 90.0, 230.0, 35000.0, (Leg(total),)), q25=True)
    add("DLH202", FlightPlan(65 * km, 25 * km, 270.0, 240.0, 37000.0, (Leg(total),)))
    add("EZY303", FlightPlan(-60 * km, -60 * km, 45.0, 210.0, 33000.0, (Leg(total),)), transponder="modeac")
    add("AFR404", FlightPlan(-20 * km, 75 * km, 170.0, 260.0, 39000.0, (Leg(total),)), q25=True)
    add("BAW505", FlightPlan(20 * km, -70 * km, 355.0, 120.0, 10000.0, (Leg(total),)))
    # turns: rate-one and 1.5 deg/s
    add("SWR606", FlightPlan(-50 * km, 10 * km, 80.0, 180.0, 24000.0,
                             (Leg(120.0), Leg(60.0, 3.0), Leg(total - 180.0))))  # fmt: skip
    add("KLM707", FlightPlan(40 * km, -30 * km, 0.0, 200.0, 28000.0,
                             (Leg(90.0), Leg(60.0, -1.5), Leg(total - 150.0))), transponder="modeac")  # fmt: skip
    add("SWR808", FlightPlan(10 * km, 45 * km, 90.0, 130.0, 15000.0,
                             (Leg(60.0), Leg(60.0, 3.0), Leg(60.0), Leg(60.0, 3.0), Leg(60.0), Leg(60.0, 3.0),
                              Leg(total - 360.0))))  # racetrack  # fmt: skip
    add("AUA909", FlightPlan(-40 * km, -25 * km, 60.0, 220.0, 30000.0,
                             (Leg(60.0), Leg(40.0, -1.5), Leg(80.0, 1.5), Leg(40.0, -1.5), Leg(total - 220.0))))  # fmt: skip
    # climbs and descents
    add("EDW110", FlightPlan(-30 * km, -55 * km, 20.0, 150.0, 10000.0,
                             (Leg(450.0, 0.0, 2000.0), Leg(total - 450.0))), q25=True)  # fmt: skip
    add("SWR211", FlightPlan(60 * km, 60 * km, 225.0, 200.0, 33000.0,
                             (Leg(30.0), Leg(432.0, 0.0, -2500.0), Leg(total - 462.0))))  # fmt: skip
    add("DLH312", FlightPlan(0.0, -40 * km, 300.0, 170.0, 12000.0,
                             (Leg(60.0), Leg(120.0, 1.5, 1500.0), Leg(240.0, 0.0, 1500.0), Leg(total - 420.0))))  # fmt: skip
    add("EZY413", FlightPlan(50 * km, -5 * km, 200.0, 180.0, 26000.0,
                             (Leg(100.0), Leg(60.0, -3.0, -1800.0), Leg(200.0, 0.0, -1800.0), Leg(total - 360.0))),
        transponder="modeac")  # fmt: skip
    # crossings: same point, same level, same time, different identity
    add("SWR514", _plan_toward((5 * km, 5 * km), 45.0, 220.0, 250.0, 31000.0, total))
    add("BAW615", _plan_toward((5 * km, 5 * km), 135.0, 210.0, 250.0, 31000.0, total))
    add("AFR716", _plan_toward((-15 * km, 20 * km), 180.0, 230.0, 350.0, 29000.0, total))
    add("RYR817", _plan_toward((-15 * km, 20 * km), 270.0, 200.0, 350.0, 29000.0, total), transponder="modeac")
    add("DLH918", _plan_toward((25 * km, -15 * km), 10.0, 240.0, 180.0, 35000.0, total))
    add("SWR019", _plan_toward((25 * km, -15 * km), 40.0, 230.0, 180.0, 35000.0, total))
    # close parallel pairs (1, 2 and 3 NM apart)
    for k, (sep_nm, hdg, x0, y0, fl_a, fl_b, sp, tr_b) in enumerate((
        (1.0, 100.0, -60 * km, -15 * km, 33000.0, 34000.0, 220.0, "modes"),
        (2.0, 290.0, 60 * km, -45 * km, 36000.0, 36000.0, 235.0, "modes"),
        (3.0, 200.0, 15 * km, 70 * km, 32000.0, 32000.0, 215.0, "modeac"),
    )):  # fmt: skip
        psi = math.radians(hdg)
        dx, dy = sep_nm * NM_M * math.cos(psi), -sep_nm * NM_M * math.sin(psi)  # perpendicular, to the right
        add(f"PAR{k}A", FlightPlan(x0, y0, hdg, sp, fl_a, (Leg(total),)))
        add(f"PAR{k}B", FlightPlan(x0 + dx, y0 + dy, hdg, sp, fl_b, (Leg(total),)), transponder=tr_b)
    # Mode A without Mode C; primary only; fast climber with 25 ft reports
    add("NOC001", FlightPlan(-55 * km, 55 * km, 135.0, 160.0, 20000.0, (Leg(total),)), transponder="modeac",
        mode_c=False)
    add("PSR001", FlightPlan(30 * km, 20 * km, 250.0, 125.0, 12000.0, (Leg(200.0), Leg(60.0, 1.5), Leg(total - 260.0))),
        transponder="none")  # fmt: skip
    add("SWR999", FlightPlan(-10 * km, -65 * km, 5.0, 190.0, 16000.0,
                             (Leg(300.0, 0.0, 2500.0), Leg(total - 300.0))), q25=True)  # fmt: skip
    return Scenario("demo", center[0], center[1], radars, targets, start_t_s=start_t_s, duration_s=duration_s,
                    seed=seed, period_s=4.0, rates=rates)  # fmt: skip


def _wgs84_inv(lon1, lat1, lon2, lat2):
    return WGS84_GEOD.inv(lon1, lat1, lon2, lat2)


@functools.lru_cache(maxsize=2)
def _adsb_table(path: str) -> dict[str, np.ndarray]:
    """The ADS-B table as columns sorted by (icao24, time)."""
    with gzip.open(path, "rt", encoding="utf-8") as f:
        rows = json.load(f)
    if not isinstance(rows, list):
        raise ValueError(f"{path}: expected a JSON list of records")
    get = lambda k, dtype=float: np.array([r.get(k) for r in rows], dtype=dtype)  # noqa: E731
    cols = {
        "t_s": get("timestamp") / 1000.0,
        "icao24": np.array([str(r.get("icao24") or "") for r in rows]),
        "callsign": np.array([str(r.get("callsign") or "").strip() for r in rows]),
        "lat_deg": get("latitude"),
        "lon_deg": get("longitude"),
        "alt_ft": get("altitude"),
        "groundspeed_kt": get("groundspeed"),
        "track_deg": get("track"),
        "vrate_fpm": get("vertical_rate"),
    }
    good = np.ones(len(rows), bool)
    for k in ("t_s", "lat_deg", "lon_deg", "alt_ft", "groundspeed_kt", "track_deg"):
        good &= np.isfinite(cols[k])
    cols["vrate_fpm"] = np.where(np.isfinite(cols["vrate_fpm"]), cols["vrate_fpm"], 0.0)
    order = np.lexsort((cols["t_s"], cols["icao24"]))
    order = order[good[order]]
    cols = {k: v[order] for k, v in cols.items()}
    # Stale or misplaced positions: a sample is dropped when every chord to its
    # neighbours (same aircraft, <= 30 s apart) implies a speed more than 35 % off the
    # reported groundspeed (typically a repeated position at the start of a track).
    # Aircraft with more than 20 % of such samples are dropped entirely.
    icao, t = cols["icao24"], cols["t_s"]
    _, _, dist_m = _wgs84_inv(cols["lon_deg"][:-1], cols["lat_deg"][:-1], cols["lon_deg"][1:], cols["lat_deg"][1:])
    dt = np.diff(t)
    chord = (icao[1:] == icao[:-1]) & (dt > 0) & (dt <= 30.0)
    gs_mps = 0.5 * (cols["groundspeed_kt"][1:] + cols["groundspeed_kt"][:-1]) * KT_MPS
    with np.errstate(invalid="ignore", divide="ignore"):
        off = np.abs(dist_m / np.where(chord, dt, 1.0) / np.maximum(gs_mps, 1.0) - 1.0) > 0.35
    n = t.size
    good_chords = np.zeros(n, np.int32)
    np.add.at(good_chords, np.nonzero(chord & ~off)[0], 1)
    np.add.at(good_chords, np.nonzero(chord & ~off)[0] + 1, 1)
    bad = good_chords == 0
    uniq, inverse = np.unique(icao, return_inverse=True)
    bad_share = np.bincount(inverse, weights=bad, minlength=uniq.size) / np.bincount(inverse, minlength=uniq.size)
    keep = ~bad & (bad_share[inverse] <= 0.2)
    return {k: v[keep] for k, v in cols.items()}


def adsb_targets(start_t_s: float, duration_s: float, max_aircraft: int = 80, path: str | Path | None = None,
                 max_gap_s: float = 30.0, min_overlap_s: float = 60.0, seed: int = 0) -> list[Target]:
    """Real flights of the ADS-B table airborne in ``[start_t_s, start_t_s + duration_s]``.

    Per aircraft, the samples are split at gaps longer than ``max_gap_s``; the piece
    with the longest overlap with the window is kept (if it overlaps at least
    ``min_overlap_s``), with one sample beyond each end of the window. At most
    ``max_aircraft`` flights, those longest in the window first. Identity: Mode S
    address from icao24, callsign from the table, a Mode 3/A code drawn per aircraft.
    """
    tab = _adsb_table(str(path or ADSB_TABLE))
    w0, w1 = float(start_t_s), float(start_t_s) + float(duration_s)
    icao = tab["icao24"]
    t = tab["t_s"]
    starts = np.concatenate([[0], np.nonzero(icao[1:] != icao[:-1])[0] + 1, [icao.size]])
    found: list[tuple[float, str, int, int]] = []
    for a, b in zip(starts[:-1], starts[1:]):
        ta = t[a:b]
        if ta[-1] < w0 or ta[0] > w1:
            continue
        cuts = np.concatenate([[0], np.nonzero(np.diff(ta) > max_gap_s)[0] + 1, [ta.size]])
        best = None
        for c0, c1 in zip(cuts[:-1], cuts[1:]):
            overlap = min(ta[c1 - 1], w1) - max(ta[c0], w0)
            if overlap >= min_overlap_s and c1 - c0 >= 2 and (best is None or overlap > best[0]):
                best = (overlap, c0, c1)
        if best is None:
            continue
        overlap, c0, c1 = best
        seg = ta[c0:c1]
        lo = max(int(np.searchsorted(seg, w0, side="right")) - 1, 0)
        hi = min(int(np.searchsorted(seg, w1, side="left")) + 1, seg.size)
        if hi - lo >= 2:
            found.append((float(overlap), str(icao[a]), int(a + c0 + lo), int(a + c0 + hi)))
    found.sort(key=lambda f: (-f[0], f[1]))
    found = sorted(found[:max_aircraft], key=lambda f: f[1])
    rng = np.random.default_rng(seed)
    codes = _mode3a_codes(rng, len(found))
    out = []
    for (_, icao24, a, b), code in zip(found, codes.tolist()):
        callsign = str(tab["callsign"][a]) or None
        path_ = SampledPath(**{k: tab[k][a:b].copy() for k in
                               ("t_s", "lat_deg", "lon_deg", "alt_ft", "groundspeed_kt", "track_deg", "vrate_fpm")})  # fmt: skip
        out.append(Target(target_id=icao24, callsign=callsign, mode_s=int(icao24, 16), mode3a=int(code),
                          transponder="modes", mode_c=True, alt_quantum_ft=25.0, path=path_))  # fmt: skip
    return out


ADSB_DEFAULT_START_T_S = 1533123000.0
"""2018-08-01 11:30 UTC: the busiest 20 minutes of the ADS-B table (74 aircraft)."""


def adsb_scenario(seed: int = 1, duration_s: float = 1200.0, start_t_s: float = ADSB_DEFAULT_START_T_S,
                  max_aircraft: int = 80, path: str | Path | None = None) -> Scenario:
    """Real flights over Switzerland seen by 4 radars placed around it.

    The sites are near the Swiss en-route radar sites (La Dôle, Lägern, Monte Lema,
    Weissfluhjoch, approximate positions); the radar parameters are invented.
    """
    rates = Rates(pd=0.95, pd_psr=0.8, p_mode_c=0.99, false_plots_per_scan=2.0,
                  wild_plot_prob=0.002, wild_run_prob=0.0005)  # fmt: skip
    radars = [
        RadarSpec("ladole", 46.4253, 6.1005, alt_m=1680.0, rotation_period_s=8.0, sigma_range_m=50.0,
                  sigma_azimuth_deg=0.07, range_bias_m=35.0, azimuth_bias_deg=0.03, max_range_m=250 * NM_M,
                  psr=True, sac=2, sic=1),
        RadarSpec("laegern", 47.4822, 8.3961, alt_m=866.0, rotation_period_s=4.0, sigma_range_m=30.0,
                  sigma_azimuth_deg=0.05, range_bias_m=-20.0, azimuth_bias_deg=-0.02, max_range_m=150 * NM_M,
                  psr=True, n_sectors=16, sac=2, sic=2),
        RadarSpec("lema", 46.0416, 8.8336, alt_m=1620.0, rotation_period_s=12.0, sigma_range_m=60.0,
                  sigma_azimuth_deg=0.08, range_bias_m=50.0, azimuth_bias_deg=0.04, max_range_m=250 * NM_M,
                  psr=False, sac=2, sic=3),
        RadarSpec("weissfluh", 46.8334, 9.8063, alt_m=2840.0, rotation_period_s=6.0, sigma_range_m=45.0,
                  sigma_azimuth_deg=0.06, range_bias_m=-30.0, azimuth_bias_deg=0.02, max_range_m=200 * NM_M,
                  psr=False, sac=2, sic=4),
    ]  # fmt: skip
    targets = adsb_targets(start_t_s, duration_s, max_aircraft=max_aircraft, path=path, seed=seed)
    return Scenario("adsb", 46.8, 8.2, radars, targets, start_t_s=start_t_s, duration_s=duration_s, seed=seed,
                    period_s=4.0, rates=rates)  # fmt: skip


def scenario_for_benchmark(n_aircraft: int = 1000, n_radars: int = 10, duration_s: float = 120.0, seed: int = 0,
                           area_per_aircraft_km2: float = 250.0, coverage_multiplicity: float = 3.0) -> Scenario:
    """A scalable random scenario for benchmarks.

    Density: one aircraft per ``area_per_aircraft_km2`` (250 km²: a dense core area) in a
    disc of radius R = sqrt(n A / pi). Radars on a sunflower pattern inside the disc,
    with a range r = 1.1 R sqrt(m / n_radars) clamped to [150 km, 250 NM] so that each
    aircraft is covered by about m = ``coverage_multiplicity`` radars; when the range
    clamps, the disc is resized to R = r / (1.1 sqrt(m / n_radars)) to keep that
    coverage (denser traffic with few radars, sparser with many radars and few
    aircraft). Traffic:
    random positions and headings, FL100-FL400, 120-260 m/s; 60 % straight, 20 %
    turning (1.5 or 3 °/s), 20 % climbing/descending (1,500-2,500 ft/min); 90 % Mode S.
    """
    rng = np.random.default_rng(seed)
    radius_m = math.sqrt(n_aircraft * area_per_aircraft_km2 / math.pi) * 1000.0
    factor = 1.1 * math.sqrt(coverage_multiplicity / max(n_radars, 1))
    range_m = float(np.clip(radius_m * factor, 150_000.0, 250 * NM_M))
    radius_m = range_m / factor  # keeps the coverage multiplicity when the range clamps
    center = (50.0, 5.0)
    plane = SystemPlane(*center)
    place_r = radius_m * (0.35 if n_radars <= 3 else 0.8)
    i = np.arange(n_radars)
    rr = place_r * np.sqrt((i + 0.5) / n_radars) if n_radars > 1 else np.zeros(1)
    th = np.radians(i * 137.50776405)
    lat, lon = plane.to_geodetic(rr * np.sin(th), rr * np.cos(th))
    periods = np.array([4.0, 5.0, 6.0, 8.0, 10.0, 12.0])
    radars = [
        RadarSpec(f"r{k:02d}", float(lat[k]), float(lon[k]), alt_m=float(rng.uniform(200.0, 1500.0)),
                  rotation_period_s=float(periods[k % periods.size]), sigma_range_m=float(rng.uniform(30.0, 80.0)),
                  sigma_azimuth_deg=float(rng.uniform(0.04, 0.1)), range_bias_m=float(rng.normal(0.0, 30.0)),
                  azimuth_bias_deg=float(rng.normal(0.0, 0.02)), max_range_m=range_m, psr=bool(k % 2 == 0),
                  n_sectors=32, sac=10 + k // 200, sic=k % 200)
        for k in range(n_radars)
    ]  # fmt: skip
    # aircraft
    n = n_aircraft
    rad = radius_m * np.sqrt(rng.random(n))
    ang = rng.uniform(0.0, 2.0 * math.pi, n)
    x0, y0 = rad * np.sin(ang), rad * np.cos(ang)
    hdg = rng.uniform(0.0, 360.0, n)
    fl = rng.integers(10, 41, n) * 10
    speed = np.clip(120.0 + (fl - 100) / 300.0 * 110.0 + rng.normal(0.0, 15.0, n), 120.0, 260.0)
    kind = rng.random(n)
    t_first = rng.uniform(0.0, 0.5 * duration_s, n)
    turn = rng.choice([-3.0, -1.5, 1.5, 3.0], n)
    t_turn = rng.uniform(20.0, 60.0, n)
    vr = rng.uniform(1500.0, 2500.0, n) * np.where(fl > 250, -1.0, 1.0)
    t_climb = rng.uniform(60.0, 120.0, n)
    total = duration_s + 60.0
    modes = rng.random(n) < 0.9
    addrs = _mode_s_addresses(rng, n)
    codes = _mode3a_codes(rng, n)
    targets = []
    for k in range(n):
        if kind[k] < 0.6:
            legs = (Leg(total),)
        elif kind[k] < 0.8:
            legs = (Leg(float(t_first[k])), Leg(float(t_turn[k]), float(turn[k])), Leg(total))
        else:
            legs = (Leg(float(t_first[k])), Leg(float(t_climb[k]), 0.0, float(vr[k])), Leg(total))
        plan = FlightPlan(float(x0[k]), float(y0[k]), float(hdg[k]), float(speed[k]), float(fl[k] * 100), legs)
        targets.append(Target(
            target_id=f"A{k:05d}", callsign=f"BM{k:05d}" if modes[k] else None,
            mode_s=int(addrs[k]) if modes[k] else None, mode3a=int(codes[k]),
            transponder="modes" if modes[k] else "modeac", alt_quantum_ft=25.0 if modes[k] else 100.0, plan=plan,
        ))  # fmt: skip
    rates = Rates(pd=0.95, pd_psr=0.85, false_plots_per_scan=2.0, wild_plot_prob=0.001, wild_run_prob=0.0002)
    return Scenario(f"benchmark-{n_aircraft}x{n_radars}", center[0], center[1], radars, targets,
                    start_t_s=EPOCH_2018_08_01_08Z, duration_s=float(duration_s), seed=seed,
                    period_s=min(r.rotation_period_s for r in radars), rates=rates)  # fmt: skip


PRESETS = {
    "demo": demo_scenario,
    "adsb": adsb_scenario,
    "benchmark": scenario_for_benchmark,
}


def preset(name: str, **overrides: Any) -> Scenario:
    """A named scenario (``demo``, ``adsb``, ``benchmark``).

    ``overrides`` go to the preset's builder when it takes them (e.g. ``seed``,
    ``duration_s``, ``start_t_s``, ``max_aircraft`` for adsb, ``n_aircraft``/``n_radars``
    for benchmark); any other :class:`Scenario` field (``rates``, ``period_s``, ``name``,
    ``radars``, ``targets``) replaces the built scenario's.
    """
    try:
        builder = PRESETS[name]
    except KeyError:
        raise ValueError(f"unknown scenario preset {name!r}; presets: {sorted(PRESETS)}") from None
    import inspect

    params = set(inspect.signature(builder).parameters)
    scenario_fields = {f.name for f in dataclasses.fields(Scenario)}
    build_kw = {k: v for k, v in overrides.items() if k in params}
    rest = {k: v for k, v in overrides.items() if k not in params}
    unknown = set(rest) - scenario_fields
    if unknown:
        raise TypeError(f"preset {name!r}: unknown overrides {sorted(unknown)}")
    scenario = builder(**build_kw)
    return dataclasses.replace(scenario, **rest) if rest else scenario


# =========================================================================== TOML scenarios


def _parse_utc(s: str) -> float:
    return _dt.datetime.fromisoformat(s.replace("Z", "+00:00")).astimezone(_dt.timezone.utc).timestamp()


def _rates_from(d: dict[str, Any], base: Rates) -> Rates:
    known = {f.name for f in dataclasses.fields(Rates)}
    unknown = set(d) - known
    if unknown:
        raise ValueError(f"unknown rates fields {sorted(unknown)}")
    vals = {k: (tuple(v) if isinstance(v, list) else v) for k, v in d.items()}
    return dataclasses.replace(base, **vals)


def load_scenario(path: str | Path) -> Scenario:
    """Read a scenario TOML file (format in the module docstring)."""
    path = Path(path)
    data = tomllib.loads(path.read_text(encoding="utf-8"))
    sc = data.get("scenario", {})
    try:
        center = (float(sc["center_lat"]), float(sc["center_lon"]))
    except KeyError as exc:
        raise ValueError(f"{path}: [scenario] needs {exc.args[0]}") from None
    plane = SystemPlane(*center)
    if "start_utc" in sc:
        start = _parse_utc(str(sc["start_utc"]))
    else:
        start = float(sc.get("start_t_s", EPOCH_2018_08_01_08Z))
    duration = float(sc.get("duration_s", 540.0))
    seed = int(sc.get("seed", 0))
    rates = _rates_from(data.get("rates", {}), Rates())
    radars = []
    radar_fields = {f.name for f in dataclasses.fields(RadarSpec)}
    for i, rd in enumerate(data.get("radars", [])):
        rd = dict(rd)
        rd["lat_deg"] = rd.pop("lat", rd.get("lat_deg"))
        rd["lon_deg"] = rd.pop("lon", rd.get("lon_deg"))
        if "rates" in rd:
            rd["rates"] = _rates_from(rd["rates"], rates)
        unknown = set(rd) - radar_fields
        if unknown:
            raise ValueError(f"{path}: radars[{i}]: unknown fields {sorted(unknown)}")
        radars.append(RadarSpec(**rd))
    targets = []
    for i, td in enumerate(data.get("targets", [])):
        td = dict(td)
        try:
            if "start_lat" in td:
                x0, y0 = plane.to_plane(float(td.pop("start_lat")), float(td.pop("start_lon")))
                x0, y0 = float(x0), float(y0)
            else:
                x0, y0 = float(td.pop("start_x_m")), float(td.pop("start_y_m"))
            legs = tuple(Leg(**leg) for leg in td.pop("legs"))
            plan = FlightPlan(x0, y0, float(td.pop("heading_deg")), float(td.pop("speed_mps")),
                              float(td.pop("alt_ft")), legs, float(td.pop("t_offset_s", 0.0)))  # fmt: skip
            mode_s = td.pop("mode_s", None)
            mode3a = td.pop("mode3a", None)
            mode_s = int(mode_s, 16) if isinstance(mode_s, str) else mode_s
            mode3a = int(mode3a, 8) if isinstance(mode3a, str) else mode3a
            default_tr = "modes" if mode_s is not None else ("modeac" if mode3a is not None else "none")
            targets.append(Target(
                target_id=str(td.pop("id")), callsign=td.pop("callsign", None), mode_s=mode_s, mode3a=mode3a,
                transponder=td.pop("transponder", default_tr), mode_c=bool(td.pop("mode_c", True)),
                alt_quantum_ft=float(td.pop("alt_quantum_ft", 100.0)), plan=plan,
            ))  # fmt: skip
        except (KeyError, TypeError) as exc:
            raise ValueError(f"{path}: targets[{i}]: {exc}") from None
        if td:
            raise ValueError(f"{path}: targets[{i}]: unknown fields {sorted(td)}")
    if "adsb" in data:
        ad = data["adsb"]
        targets += adsb_targets(start, duration, max_aircraft=int(ad.get("max_aircraft", 80)),
                                path=ad.get("path"), seed=seed)  # fmt: skip
    if not radars:
        raise ValueError(f"{path}: no [[radars]]")
    period = sc.get("period_s")
    return Scenario(str(sc.get("name", path.stem)), center[0], center[1], radars, targets, start_t_s=start,
                    duration_s=duration, seed=seed, period_s=None if period is None else float(period), rates=rates)  # fmt: skip


# =========================================================================== command line


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Arguments of ``radar-fusion simulate``."""
    parser.add_argument("--scenario", default="demo",
                        help=f"preset name ({', '.join(sorted(PRESETS))}) or a scenario TOML file (default demo)")  # fmt: skip
    parser.add_argument("--out", required=True, help="output directory (plots.rec, truth.csv, config.toml)")
    parser.add_argument("--seed", type=int, default=None, help="random seed (default: the scenario's)")
    parser.add_argument("--duration-s", type=float, default=None, help="simulated duration in seconds")
    parser.add_argument("--start-utc", default=None, help="scenario start, ISO 8601 UTC (presets only)")
    parser.add_argument("--aircraft", type=int, default=None,
                        help="adsb: at most this many flights; benchmark: number of aircraft")  # fmt: skip
    parser.add_argument("--radars", type=int, default=None, help="benchmark: number of radars")
    parser.add_argument("--gzip", action="store_true", help="write plots.rec.gz (gzip-compressed recording)")


def run(args: argparse.Namespace) -> int:
    """Build the scenario, simulate it and write the outputs; prints a one-line summary."""
    t0 = time.perf_counter()
    try:
        if args.scenario in PRESETS:
            kw: dict[str, Any] = {}
            if args.seed is not None:
                kw["seed"] = args.seed
            if args.duration_s is not None:
                kw["duration_s"] = args.duration_s
            if args.start_utc is not None:
                kw["start_t_s"] = _parse_utc(args.start_utc)
            if args.aircraft is not None:
                kw["max_aircraft" if args.scenario == "adsb" else "n_aircraft"] = args.aircraft
            if args.radars is not None:
                kw["n_radars"] = args.radars
            scenario = preset(args.scenario, **kw)
        else:
            scenario = load_scenario(args.scenario)
            if args.seed is not None:
                scenario.seed = args.seed
            if args.duration_s is not None:
                scenario.duration_s = args.duration_s
        simulation = simulate(scenario)
        paths = write_outputs(simulation, args.out, gzip_recording=args.gzip)
    except (OSError, ValueError, TypeError, tomllib.TOMLDecodeError) as exc:
        print(f"simulate: {exc}", file=sys.stderr)
        return 2
    n_plots = sum(len(c) for c in simulation.plot_columns)
    print(
        f"simulate: scenario {scenario.name!r}: {len(scenario.radars)} radars, {len(scenario.targets)} targets, "
        f"{scenario.duration_s:.0f} s, {n_plots} plots in {len(simulation.messages)} messages "
        f"-> {paths['recording']}, {paths['truth']}, {paths['config']} ({time.perf_counter() - t0:.1f} s)"
    )
    return 0


def main(argv: Optional[Sequence[str]] = None) -> int:
    parser = argparse.ArgumentParser(prog="radar-fusion simulate", description=__doc__.split("\n")[0])
    add_arguments(parser)
    return run(parser.parse_args(argv))


if __name__ == "__main__":
    raise SystemExit(main())
