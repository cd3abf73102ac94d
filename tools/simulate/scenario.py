"""The scenario model: radars (site, antenna, accuracy, biases, rates), aircraft (identity,
transponder) and how they fly (a synthetic flight plan or a recorded path).

Everything :func:`radar_fusion.tools.simulate.simulate` needs is one :class:`Scenario`.
Builders of scenarios: :mod:`.presets` (named scenarios), :mod:`.adsb` (real flights),
:mod:`.files` (scenario TOML files).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from radar_fusion.geo.units import M_PER_NM

EPOCH_2018_08_01_08Z = 1533110400.0
"""2018-08-01 08:00:00 UTC, the default scenario start (the day of the ADS-B table)."""
TRANSPONDER_CODES = {"none": 0, "modeac": 1, "modes": 2}
"""Transponder kinds of :attr:`Target.transponder`, as the codes the radar model uses."""


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
    roll_prob: float = 0.25
    """probability that a Mode S plot carries the aircraft's roll angle (BDS 5,0): a Mode S
    radar reads the register every few scans among the others it extracts; on the Barcelona
    hour 22-25 % of each aircraft's plots carry one (every fourth scan)"""
    sigma_roll_deg: float = 1.0
    """noise of the reported roll angle, degrees (then rounded to the register's 45/256°)"""
    sigma_ground_speed_mps: float = 0.5
    """noise of the ground speed the plots with a roll angle also report (BDS 5,0), m/s (then
    rounded to the register's 2 kt)"""
    sigma_track_angle_deg: float = 0.2
    """noise of the true track angle reported beside it, degrees (then rounded to the
    register's 90/512°)"""
    dap_age_s: tuple[float, float] = (0.15, 1.85)
    """how much older a BDS 5,0 report's ground speed and track are than its plot, s, uniform
    between the two. The aircraft refreshes the register at least every 1.3 s (ICAO Doc 9871)
    and its own sensors add their latency: on the Barcelona hour the reported track angle in
    turns matches the plots' course 1.0 s (± 0.1) before the plot, with a spread of about
    0.5 s (σ; 0.4-0.6 from the residuals against the turn rate), which this uniform has"""
    heading_prob: float = 0.9
    """probability that a Mode S plot carries the aircraft's magnetic heading and indicated
    airspeed (BDS 6,0): on the Barcelona hour 89 % of the Mode S plots carry its heading,
    independently of BDS 5,0 (both on 18 %)"""
    sigma_heading_deg: float = 0.3
    """noise of the reported heading, degrees (then rounded to the register's 90/512°)"""
    sigma_ias_mps: float = 0.5
    """noise of the reported indicated airspeed, m/s (then rounded to the register's 1 kt)"""
    air_age_s: tuple[float, float] = (-1.85, -0.15)
    """how much older a BDS 6,0 report's heading and airspeed are than its plot, s, uniform
    between the two: negative, the heading leads. On the Barcelona hour the air vector plus
    the wind matches the BDS 5,0 ground velocity best with the heading of 2 s (± 0.5) before
    the BDS 5,0 read, whose track runs 1.0 s behind the plots' course: the heading leads the
    course by about 1 s (the aircraft yaws into a turn before its velocity turns)"""
    wild_errors: bool = True
    """False: the wild plots are drawn as usual but their gross errors are not applied, so the
    simulation is the clean twin of the one with them (the same noise, detections and false
    plots, plot for plot): what the wild plots cost is then measured on the same draws"""


@dataclass(frozen=True)
class Atmosphere:
    """The day's wind and temperature, over the whole scenario: what separates the air
    vector an aircraft reports (BDS 6,0) from its ground velocity (BDS 5,0, the plots)."""

    wind_from_deg: float = 280.0
    """direction the wind blows from, degrees clockwise from true north"""
    wind_surface_mps: float = 5.0
    """wind speed at the surface, m/s"""
    wind_shear_mps_per_km: float = 2.5
    """its growth with height, m/s per km (35 m/s at 12 km with the defaults: a jet-stream
    level wind, so that a climbing aircraft's wind changes)"""
    temperature_deviation_k: float = 5.0
    """the day's temperature less ISA's at every height, K: the true airspeed of an
    indicated one is then 1 % off ISA's, and every Mode C level lies higher than its
    pressure altitude (178 m at FL300); the daemon's configuration carries it, as a met
    office gives it (files.config_toml)"""
    qnh_hpa: float = 1013.25
    """the day's sea-level pressure, hPa: Mode C is pressure altitude above 1013.25 hPa's
    level, 8 m lower per hPa above it"""
    local_wind_sigma_mps: float = 2.0
    """σ per axis of each aircraft's own departure from the layer's wind, m/s, constant over
    its flight (the wind is not one field: on the Barcelona hour aircraft of one layer
    differ by a few m/s)"""
    heading_bias_sigma_deg: float = 0.5
    """σ of each aircraft's constant heading error, degrees (compass and installation): on
    the Barcelona hour the air vector plus the layer's wind misses the BDS 5,0 velocity by
    2.1 m/s median, 4.3 RMS, where the registers' steps alone make 1 m/s"""

    def aircraft_errors(self, n_targets: int, seed: int) -> np.ndarray:
        """Each aircraft's own wind departure (east, north, m/s) and heading error (degrees),
        (n_targets, 3), from a generator of their own (``seed`` and a fixed key: the other
        draws of the seed stay as they were)."""
        rng = np.random.default_rng([seed, 6060])
        out = np.empty((n_targets, 3))
        out[:, :2] = rng.normal(0.0, self.local_wind_sigma_mps, (n_targets, 2))
        out[:, 2] = rng.normal(0.0, self.heading_bias_sigma_deg, n_targets)
        return out

    def wind_mps(self, alt_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The wind's east and north components at heights ``alt_m``, m/s (it blows towards
        ``wind_from_deg`` + 180°)."""
        speed = self.wind_surface_mps + self.wind_shear_mps_per_km * np.maximum(alt_m, 0.0) / 1000.0
        to_rad = np.radians(self.wind_from_deg + 180.0)
        return speed * np.sin(to_rad), speed * np.cos(to_rad)


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
    max_range_m: float = 250.0 * M_PER_NM
    psr: bool = True
    ssr: bool = True
    mode_s: bool = True
    n_sectors: int = 32
    start_phase_deg: float | None = None
    max_elevation_deg: float = 40.0
    sac: int | None = None
    sic: int | None = None
    rates: Rates | None = None

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

    The truth passes through every sample (for ADS-B flights the samples are already the
    smoothed path, tools/smoothing.py): positions by the C2 cubic spline in the system
    plane, altitude by a cubic Hermite with ``vrate_fpm`` as slopes.
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
    callsign: str | None = None
    mode_s: int | None = None
    """24-bit Mode S address, or None"""
    mode3a: int | None = None
    """Mode 3/A code as an integer (0..0o7777), or None"""
    transponder: str = "modes"
    """"modes" (Mode S), "modeac" (Mode A/C only) or "none" (primary only)"""
    mode_c: bool = True
    alt_quantum_ft: float = 100.0
    """Mode C quantum: 100 ft, or 25 ft for Mode S transponders that report it"""
    plan: FlightPlan | None = None
    path: SampledPath | None = None

    def __post_init__(self) -> None:
        if (self.plan is None) == (self.path is None):
            raise ValueError(f"target {self.target_id}: give exactly one of plan and path")
        if self.transponder not in TRANSPONDER_CODES:
            raise ValueError(f"target {self.target_id}: transponder must be one of {list(TRANSPONDER_CODES)}")
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
    period_s: float | None = None
    """fusion period written to config.toml; None = the shortest rotation period"""
    rates: Rates = field(default_factory=Rates)
    atmosphere: Atmosphere = field(default_factory=Atmosphere)

    @property
    def effective_period_s(self) -> float:
        shortest = min(r.rotation_period_s for r in self.radars)
        return shortest if self.period_s is None else min(float(self.period_s), shortest)

    def rates_of(self, radar: RadarSpec) -> Rates:
        return radar.rates if radar.rates is not None else self.rates


# =========================================================================== identities


def mode3a_codes(rng: np.random.Generator, n: int) -> np.ndarray:
    """Random Mode 3/A codes, distinct while the pool lasts, avoiding the emergency and special codes."""
    reserved = np.array([0o7500, 0o7600, 0o7700, 0o7000, 0o2000, 0o1200])
    pool = np.setdiff1d(np.arange(0o0100, 0o10000), reserved)
    if n <= pool.size:
        return rng.choice(pool, size=n, replace=False)
    return rng.choice(pool, size=n, replace=True)


def mode_s_addresses(rng: np.random.Generator, n: int) -> np.ndarray:
    """Distinct random 24-bit addresses (in the ICAO blocks of European states)."""
    return 0x300000 + rng.choice(0x0FFFFF, size=n, replace=False)
