"""Radar model: beam crossings, coverage, detection, report kind and identity, measurement
noise and biases, wild plots and false plots, for one radar over a whole scenario.

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
else 100 ft; Mode C is the pressure altitude of the truth's height on the scenario's day,
``Atmosphere.temperature_deviation_k`` off ISA with ``Atmosphere.qnh_hpa``, geo.air_data:
FL300 is 178 m below the truth's height at ISA+5; the daemon is told the day's figures
(files.config_toml), so it converts Mode C back (to the quantum), while its plot covariance keeps
1 % of the height for real days' uneven air, coordinates.MODE_C_HEIGHT_SIGMA_FRACTION_WITH_MET:
each aircraft's own air, 2.5 K off the day's, was simulated and left out, docs/measurements.md,
"Mode C is pressure altitude"); a transponder seen by a radar with a primary gives ``cmb`` when the
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
number. With ``wild_errors`` false the same draws are made and no error is applied: the
clean twin of the run, plot for plot.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from radar_fusion import wire
from radar_fusion.geo.air_data import indicated_airspeed_mps, pressure_altitude_of_height_m
from radar_fusion.geo.coordinates import RadarSites, SystemPlane, gaussian_earth_radius_m, geodetic_to_polar
from radar_fusion.geo.units import M_PER_FT, MPS_PER_KT
from radar_fusion.tracking.coordinated_turn import bank_of_turn_deg

from .scenario import TRANSPONDER_CODES, Atmosphere, RadarSpec, Rates, Target
from .trajectories import Trajectories

KIND_PSR, KIND_SSR, KIND_CMB, KIND_MODES = (wire.KIND_CODES[k] for k in ("psr", "ssr", "cmb", "modes"))
KIND_NAMES = {code: name for name, code in wire.KIND_CODES.items()}
_EFFECTIVE_EARTH_K = 4.0 / 3.0


def _wrap180(a: np.ndarray) -> np.ndarray:
    return np.mod(a + 180.0, 360.0) - 180.0


def coverage(spec: RadarSpec, earth_radius_m: float, slant_m, ground_m, alt_m) -> np.ndarray:
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


def _roll_reports(
    traj: Trajectories, tgt: np.ndarray, t_s: np.ndarray, mode_s: np.ndarray, rates: Rates, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray]:
    """The roll angle a Mode S plot reports (BDS 5,0), degrees, positive right wing down;
    NaN on the plots that carry none (``rates.roll_prob`` of the Mode S ones); and the rows
    that carry one (:func:`_velocity_reports` gives them the register's other fields).

    The truth's roll is the bank of a coordinated turn at its turn rate, tan φ = v ψ̇ / g
    (ψ̇ the heading rate, clockwise positive, from the velocity 0.5 s either side), plus
    ``rates.sigma_roll_deg`` of noise, rounded to the register's 45/256°. The draws come
    from their own generator (``rng`` spawned by the caller), so every other draw of the
    radar, and with them all plots, stay those of the same seed without roll reports."""
    out = np.full(t_s.shape[0], np.nan)
    carry = np.flatnonzero(mode_s & (rng.random(t_s.shape[0]) < rates.roll_prob))
    if not carry.size:
        return out, carry
    a = traj.state(tgt[carry], t_s[carry] - 0.5)
    b = traj.state(tgt[carry], t_s[carry] + 0.5)
    heading_rate_rad_s = np.angle(np.exp(1j * (np.arctan2(b.vx_mps, b.vy_mps) - np.arctan2(a.vx_mps, a.vy_mps))))
    speed_mps = 0.5 * (np.hypot(a.vx_mps, a.vy_mps) + np.hypot(b.vx_mps, b.vy_mps))
    roll = bank_of_turn_deg(speed_mps, heading_rate_rad_s)
    roll += rng.normal(0.0, rates.sigma_roll_deg, carry.size)
    out[carry] = np.clip(np.round(roll * 256.0 / 45.0) * 45.0 / 256.0, -90.0, 90.0)
    return out, carry


def _velocity_reports(
    traj: Trajectories,
    plane: SystemPlane,
    tgt: np.ndarray,
    t_s: np.ndarray,
    carry: np.ndarray,
    rates: Rates,
    rng: np.random.Generator,
) -> tuple[np.ndarray, np.ndarray]:
    """The ground speed (m/s) and true track angle (degrees clockwise from true north,
    [0, 360)) of the BDS 5,0 reads ``carry`` (the plots with a roll angle); NaN elsewhere.

    The register holds the aircraft's velocity of a moment before the read: the truth's
    velocity at t − age, age uniform over ``rates.dap_age_s`` (the register's refresh and the
    avionics' latency, measured on the Barcelona hour). The truth moves in the system
    plane; its true track is the grid bearing atan2(vx, vy) plus the meridian convergence c
    there (grid = true − c, :meth:`SystemPlane.grid_convergence_deg`), its ground speed the
    plane speed over the point scale k, times (R + h) / R: the plane position is the point on
    the ellipsoid under the aircraft, which at height h moves (R + h) / R as fast (R the
    Gaussian radius; ``coordinates.ground_velocity_to_plane`` turns it back). Then
    ``rates.sigma_ground_speed_mps`` and ``rates.sigma_track_angle_deg`` of noise, rounded
    to the register's 2 kt and 90/512°. ``rng``: the roll's generator after its draws, so
    the roll and every other draw of the seed stay as they were."""
    speed_out, track_out = np.full(t_s.shape[0], np.nan), np.full(t_s.shape[0], np.nan)
    if not carry.size:
        return speed_out, track_out
    age_s = rng.uniform(*rates.dap_age_s, carry.size)
    speed, track, _ = _true_ground_velocity(traj, plane, tgt[carry], t_s[carry] - age_s)
    speed += rng.normal(0.0, rates.sigma_ground_speed_mps, carry.size)
    track += rng.normal(0.0, rates.sigma_track_angle_deg, carry.size)
    speed_out[carry] = np.clip(np.round(speed / MPS_PER_KT / 2.0), 0.0, 1023.0) * 2.0 * MPS_PER_KT
    track_out[carry] = np.mod(np.round(track * 512.0 / 90.0), 2048.0) * 90.0 / 512.0
    return speed_out, track_out


def _true_ground_velocity(
    traj: Trajectories, plane: SystemPlane, tgt: np.ndarray, t_s: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The truth's ground speed (m/s) and true track (degrees, clockwise from true north) at
    ``t_s``, and its altitude (m): the plane velocity turned to true north by the meridian
    convergence c there (grid = true − c, :meth:`SystemPlane.grid_convergence_deg`), its
    speed over the point scale k, times (R + h) / R (the plane position is the point on the
    ellipsoid under the aircraft, which at height h moves (R + h) / R as fast; R the
    Gaussian radius; ``coordinates.ground_velocity_to_plane`` turns it back)."""
    st = traj.state(tgt, t_s)
    lat, lon = plane.to_geodetic(st.x_m, st.y_m)
    _, _, convergence_deg, k = plane.to_plane_and_factors(lat, lon)
    radius_m = gaussian_earth_radius_m(lat)
    speed = np.hypot(st.vx_mps, st.vy_mps) / k * (radius_m + st.alt_m) / radius_m
    track = np.degrees(np.arctan2(st.vx_mps, st.vy_mps)) + convergence_deg
    return speed, track, st.alt_m


def _air_reports(
    traj: Trajectories,
    plane: SystemPlane,
    tgt: np.ndarray,
    t_s: np.ndarray,
    mode_s: np.ndarray,
    rates: Rates,
    atmosphere: Atmosphere,
    aircraft_errors: np.ndarray,
    rng: np.random.Generator,
) -> tuple[np.ndarray, np.ndarray]:
    """The magnetic heading (degrees, [0, 360)) and indicated airspeed (m/s) a Mode S plot
    reports (BDS 6,0, ICAO Doc 9871 table A-2-96); NaN on the plots that carry none (all but
    ``rates.heading_prob`` of the Mode S ones, drawn apart from BDS 5,0's: on the Barcelona
    hour the two registers are read independently, 90 % and 21 % of the plots).

    The air vector is the ground velocity less the wind: the truth's true ground velocity
    (:func:`_true_ground_velocity`) at t − age, age uniform over ``rates.air_age_s``, less
    ``atmosphere``'s wind at the truth's height and the aircraft's own departure from it
    (``aircraft_errors``, :meth:`Atmosphere.aircraft_errors`). Its direction is the true
    heading (the simulated site's magnetic declination is 0, so the magnetic heading is the
    true one), plus the aircraft's constant heading error, its
    length the true airspeed, which the day's temperature (ISA + ``temperature_deviation_k``)
    turns into the calibrated airspeed the register holds (geo.air_data). Then
    ``rates.sigma_heading_deg`` and ``rates.sigma_ias_mps`` of noise, rounded to the
    register's 90/512° and 1 kt. ``rng``: a generator of their own, so every other draw of
    the seed stays as it was."""
    heading_out, ias_out = np.full(t_s.shape[0], np.nan), np.full(t_s.shape[0], np.nan)
    carry = np.flatnonzero(mode_s & (rng.random(t_s.shape[0]) < rates.heading_prob))
    if not carry.size:
        return heading_out, ias_out
    age_s = rng.uniform(*rates.air_age_s, carry.size)
    speed, track_deg, alt_m = _true_ground_velocity(traj, plane, tgt[carry], t_s[carry] - age_s)
    wind_e, wind_n = atmosphere.wind_mps(alt_m)
    own = aircraft_errors[tgt[carry]]
    air_e = speed * np.sin(np.radians(track_deg)) - wind_e - own[:, 0]
    air_n = speed * np.cos(np.radians(track_deg)) - wind_n - own[:, 1]
    heading = np.degrees(np.arctan2(air_e, air_n)) + own[:, 2]
    heading += rng.normal(0.0, rates.sigma_heading_deg, carry.size)
    dev_k = atmosphere.temperature_deviation_k
    pressure_alt_m = pressure_altitude_of_height_m(alt_m, dev_k, atmosphere.qnh_hpa)
    ias = indicated_airspeed_mps(np.hypot(air_e, air_n), pressure_alt_m, dev_k)
    ias += rng.normal(0.0, rates.sigma_ias_mps, carry.size)
    heading_out[carry] = np.mod(np.round(heading * 512.0 / 90.0), 2048.0) * 90.0 / 512.0
    ias_out[carry] = np.clip(np.round(ias / MPS_PER_KT), 1.0, 1023.0) * MPS_PER_KT
    return heading_out, ias_out


class TargetTable:
    """Per-target identity columns (arrays indexed by target)."""

    def __init__(self, targets: Sequence[Target]) -> None:
        self.transponder = np.array([TRANSPONDER_CODES[t.transponder] for t in targets], np.int8)
        self.mode_s = np.array([-1 if t.mode_s is None else t.mode_s for t in targets], np.int64)
        self.mode3a = np.array([-1 if t.mode3a is None else t.mode3a for t in targets], np.int64)
        self.mode_c = np.array([t.mode_c and t.transponder != "none" for t in targets], bool)
        self.q25 = np.array([t.alt_quantum_ft == 25.0 for t in targets], bool)


def radar_plots(
    sim_ctx: dict, r: int, spec: RadarSpec, rates: Rates, phase_deg: float, rng: np.random.Generator
) -> tuple[dict[str, np.ndarray], dict[str, int]]:
    """All plots (true, wild and false) of radar ``r`` over the scenario, as columns; and
    the radar's counts (crossings in coverage, detections, target, wild and false plots)."""
    traj: Trajectories = sim_ctx["traj"]
    plane: SystemPlane = sim_ctx["plane"]
    sites: RadarSites = sim_ctx["sites"]
    tt: TargetTable = sim_ctx["targets"]
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
        step_no = 0
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
                cols["step"].append(np.full(int(keep.sum()), step_no))
                for k, v in (("t", t_c), ("rho", rho), ("az", az), ("g", g), ("alt", st.alt_m), ("active", st.active)):
                    cols[k].append(v[keep])
            n_rev += 1.0
            step_no += 1
    c = {
        k: (np.concatenate(v) if v else np.zeros(0, dtype=np.intp if k in ("tgt", "step") else float))
        for k, v in cols.items()
    }
    c["active"] = c["active"].astype(bool)
    m = c["t"].shape[0]
    tgt = c["tgt"].astype(np.intp)

    # ---- detection, kind and identity
    cover = c["active"] & coverage(spec, float(sites.earth_radius_m[r]), c["rho"], c["g"], c["alt"])
    tr = tt.transponder[tgt]
    ssr_path = spec.ssr & (tr > 0)
    psr_path = ~ssr_path & spec.psr
    pd = np.where(ssr_path, rates.pd, np.where(psr_path, rates.pd_psr, 0.0))
    detected = cover & (rng.random(m) < pd)
    kind = np.where(
        ssr_path,
        np.where(
            spec.mode_s & (tr == 2), KIND_MODES, np.where(spec.psr & (rng.random(m) < rates.pd_psr), KIND_CMB, KIND_SSR)
        ),
        KIND_PSR,
    ).astype(np.int8)
    secondary = kind != KIND_PSR
    mode3a = np.where(secondary, tt.mode3a[tgt], -1)
    mode_s = np.where(kind == KIND_MODES, tt.mode_s[tgt], -1)
    quantum_ft = np.where((kind == KIND_MODES) & tt.q25[tgt], 25.0, 100.0)
    has_fl = secondary & tt.mode_c[tgt] & (rng.random(m) < rates.p_mode_c)
    atmosphere: Atmosphere = sim_ctx["atmosphere"]
    dev_k = atmosphere.temperature_deviation_k
    pressure_alt_m = pressure_altitude_of_height_m(c["alt"], dev_k, atmosphere.qnh_hpa)
    fl = np.where(has_fl, np.round(pressure_alt_m / M_PER_FT / quantum_ft) * quantum_ft / 100.0, np.nan)
    track_numbers = rng.permutation(max(4095, n))[:n].astype(np.int64) + 1
    track_no = track_numbers[tgt] if n else np.zeros(0, np.int64)

    # ---- measurement noise, bias and wild plots
    n_scans = int(math.ceil(sim_ctx["duration_s"] / period)) + 4
    d_range, d_az, wild_tab = _wild_offsets(rng, rates, n_scans, n)
    if not rates.wild_errors:  # the clean twin: the same draws, no gross error
        d_range[:], d_az[:], wild_tab[:] = 0.0, 0.0, False
    step = np.minimum(c["step"].astype(np.intp), n_scans - 1)
    wild = wild_tab[step, tgt] if m else np.zeros(0, bool)
    range_m = c["rho"] + spec.range_bias_m + rng.normal(0.0, spec.sigma_range_m, m) + (d_range[step, tgt] if m else 0.0)
    az_deg = (
        c["az"] + spec.azimuth_bias_deg + rng.normal(0.0, spec.sigma_azimuth_deg, m) + (d_az[step, tgt] if m else 0.0)
    )
    reported = detected & (range_m > 0.0) & (range_m <= spec.max_range_m)
    # the Mode S BDS 5,0 reads: roll, then ground speed and track on the same plots, drawn
    # from one spawned generator (the radar's own draws stay those of the seed)
    dap_rng = rng.spawn(1)[0]
    roll_deg, dap = _roll_reports(traj, tgt, c["t"], kind == KIND_MODES, rates, dap_rng)
    ground_speed_mps, track_angle_deg = _velocity_reports(traj, plane, tgt, c["t"], dap, rates, dap_rng)
    # BDS 6,0: heading and airspeed, from a second spawned generator
    magnetic_heading_deg, ias_mps = _air_reports(
        traj, plane, tgt, c["t"], kind == KIND_MODES, rates, atmosphere, sim_ctx["aircraft_air_errors"],
        rng.spawn(1)[0],
    )  # fmt: skip

    # ---- false plots: Poisson per revolution, uniform over the coverage disc
    rev0 = math.floor(beam_angle(t_start) / 360.0)
    rev1 = math.ceil(beam_angle(t_end) / 360.0)
    counts = rng.poisson(rates.false_plots_per_scan, size=max(rev1 - rev0, 0))
    n_false = int(counts.sum())
    rev = np.repeat(np.arange(rev0, rev1), counts)
    f_az = rng.uniform(0.0, 360.0, n_false)
    r_min = 2000.0
    f_range = np.sqrt(rng.uniform(r_min**2, spec.max_range_m**2, n_false))
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
        "roll_deg": np.concatenate([roll_deg[sel], np.full(int(f_keep.sum()), np.nan)]),
        "ground_speed_mps": np.concatenate([ground_speed_mps[sel], np.full(int(f_keep.sum()), np.nan)]),
        "track_angle_deg": np.concatenate([track_angle_deg[sel], np.full(int(f_keep.sum()), np.nan)]),
        "magnetic_heading_deg": np.concatenate([magnetic_heading_deg[sel], np.full(int(f_keep.sum()), np.nan)]),
        "indicated_airspeed_mps": np.concatenate([ias_mps[sel], np.full(int(f_keep.sum()), np.nan)]),
    }
    az = np.mod(out["azimuth_deg"], 360.0)
    out["azimuth_deg"] = np.where(az >= 360.0, 0.0, az)
    order = np.argsort(out["t_s"], kind="stable")
    out = {k2: v[order] for k2, v in out.items()}
    stats = {
        "crossings_in_coverage": int(cover.sum()),
        "detections": int(detected.sum()),
        "target_plots": int(sel.size),
        "wild_plots": int(wild[sel].sum()),
        "false_plots": int(f_keep.sum()),
    }
    return out, stats
