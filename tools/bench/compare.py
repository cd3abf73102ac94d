"""Side by side with Stone Soup (issue 7): ``radar-fusion bench --report DIR`` (or ``--compare``).

Per case (a benchmark size, and the real ADS-B flights) each job below runs in its own
fresh process:

    simulate_case   simulation, recording, truth, engine inputs, measurement noise, PCRB
    run_engine      (a) the engine alone, timed (:mod:`.engine_run`)
    run_bus         (b) the daemon as its own process over Zenoh, fed by the replay tool
    run_reference   (c) Stone Soup on the same plots (tools/baseline_stonesoup.py)
    run_accuracy    the engine's tracks, and each radar alone, scored against truth

The tables, goals and report: :mod:`.report`.
"""

from __future__ import annotations

import argparse
import contextlib
import gc
import math
import os
import pickle
import sys
import time
from pathlib import Path
from typing import Any

from .engine_run import (
    in_fresh_process,
    maxrss_kb,
    percentile,
    reset_peak_rss,
    rss_kb,
    run_engine,
    write_engine_inputs,
)
from .report import compare_tables, machine_lines, truth_lines, write_report

COMPARE_SIZES = [(50, 3), (100, 3), (1000, 10), (4000, 30)]
"""50×3 first: Stone Soup finishes it within the budget, and the larger sizes are estimated from it."""
#: the PCRB with the radars' offsets unknown is one covariance over all the aircraft's states
#: (9 each), updated per plot: evaluated up to this many aircraft (50×3 and the ADS-B case;
#: 100×3 over 60 s took 39 s, 50×3 about 3 s)
JOINT_BOUND_MAX_AIRCRAFT = 60
SCORE_FIELDS = (
    "pos_rms_m",
    "pos_rms_settled_m",
    "vel_rms_mps",
    "vel_rms_settled_mps",
    "pos_rms_straight_m",
    "pos_rms_turning_m",
    "n_pairs_turning",
    "pos_rms_turn_onset_m",
    "pos_rms_turn_steady_m",
    "n_pairs_turn_onset",
    "turning_outward_mean_m",
    "gospa_mean_m",
    "gospa_missed_targets_mean",
    "gospa_false_tracks_mean",
    "track_ids_per_target_mean",
    "completeness_mean",
    "id_swaps",
    "false_tracks",
    "duplicate_tracks",
    "n_displayed_tracks",
    "n_detectable_targets",
)


def _case_label(case: dict[str, Any]) -> str:
    sectors = f", {case['sectors']} sectors" if case.get("sectors") else ""
    if case["kind"] == "adsb":
        return f"ADS-B {case['duration_s']:g} s{sectors}"
    return f"{case['aircraft']:,}×{case['radars']}{sectors}"


def _build_scenario(case: dict[str, Any], seed: int):
    import dataclasses

    from radar_fusion.tools import simulate as sim_mod

    if case["kind"] == "adsb":
        scenario = sim_mod.adsb_scenario(seed=seed, duration_s=case["duration_s"], max_aircraft=case["max_aircraft"])
    else:
        scenario = sim_mod.scenario_for_benchmark(case["aircraft"], case["radars"], case["duration_s"], seed)
    if case.get("sectors"):  # every radar publishes this many sector messages per turn
        radars = [dataclasses.replace(r, n_sectors=case["sectors"]) for r in scenario.radars]
        scenario = dataclasses.replace(scenario, radars=radars)
    if case.get("wild_plot_prob") is not None:  # --wild-twin: the wild run, or its clean twin
        wild = {"wild_plot_prob": case["wild_plot_prob"], "wild_errors": case.get("wild_errors", True)}
        radars = [r if r.rates is None else dataclasses.replace(r, rates=dataclasses.replace(r.rates, **wild))
                  for r in scenario.radars]  # fmt: skip
        scenario = dataclasses.replace(scenario, rates=dataclasses.replace(scenario.rates, **wild), radars=radars)
    return scenario


def _summary(scores, settled_from_s: float) -> dict[str, Any]:
    """The scalar scores, plus GOSPA averaged over the period times from ``settled_from_s``
    on (after every tracker has had time to start its tracks)."""
    import numpy as np

    out = {k: getattr(scores, k) for k in SCORE_FIELDS}
    late = scores.times_s >= settled_from_s
    out["gospa_settled_mean_m"] = float(np.mean(scores.gospa_per_time_m[late])) if late.any() else math.nan
    return out


def simulate_case(case: dict[str, Any], seed: int, case_dir: str, settle_s: float) -> dict[str, Any]:
    """Simulate a case; write plots.rec, truth.csv, config.toml and engine.pkl into ``case_dir``;
    return the input figures with the measurement noise and the PCRB floor."""
    import tomllib

    from radar_fusion import config
    from radar_fusion.tools import simulate as sim_mod

    t0 = time.perf_counter()
    scenario = _build_scenario(case, seed)
    sim = sim_mod.simulate(scenario, encode=True)
    sim_mod.write_outputs(sim, case_dir)
    info = write_engine_inputs(scenario, sim, os.path.join(case_dir, "engine.pkl"))
    settings = config.settings_from_dict(tomllib.loads(sim_mod.config_toml(scenario)), source="benchmark scenario")
    info.update(measurement_floor(sim, settings, settle_s))
    info.update(
        aircraft=len(scenario.targets),
        radars=len(scenario.radars),
        duration_s=float(scenario.duration_s),
        period_s=float(settings.system.period_s),
        sim_s=time.perf_counter() - t0,
    )
    if case["kind"] == "adsb":
        from radar_fusion.tools.simulate.adsb import adsb_smoothing_stats

        # the truth is the smoothed ADS-B path: how far it is from the fixes, and how
        # physically plausible it is (accelerations) compared with the raw fixes
        info["truth_smoothing"] = adsb_smoothing_stats(
            scenario.start_t_s, scenario.duration_s, max_aircraft=case["max_aircraft"]
        )
    return info


def measurement_floor(sim, settings, settle_s: float) -> dict[str, Any]:
    """Measurement noise of the plots and the posterior Cramér–Rao bound (PCRB) of the tracks.

    Noise: every plot of a real aircraft that is not a simulated gross error, converted to
    the system plane as the engine does, against the exact truth at the plot's time:
    horizontal RMS error (radar biases included) and the RMS the plot covariances predict.

    PCRB: Tichavský, Muravchik & Nehorai (1998). For a linear Gaussian model the recursion
    J_{k+1} = D22 − D21 (J_k + D11)⁻¹ D12 (D11 = ΦᵀQ⁻¹Φ, D12 = −ΦᵀQ⁻¹, D22 = Q⁻¹ + HᵀR⁻¹H)
    is, by the matrix inversion lemma, J_{k+1} = (Φ J_k⁻¹ Φᵀ + Q)⁻¹ + HᵀR_{k+1}⁻¹H, which is
    evaluated in that covariance form (Q is nearly singular for plots a few ms apart). Model:
    the filter's model of straight flight, a Singer model (Φ and Q from ``singer_filter``):
    with the IMM its quiet model (``[tracking.imm] quiet_*``), with the Singer filter its α and
    σ_m. A bound for that model, it is a floor for straight flight, where the truth follows it;
    in turns no single model's bound applies. There the same recursion is the bound of a
    filter told the turn: a turn of known rate only rotates the velocity (coordinated_turn.py
    eq. 2), so with isotropic process noise it carries the same information as straight
    flight but for the plots' covariances R seen at other angles, which are the same plots
    here. Evaluated at the times in turns (truth turn rate above ``turning_above_deg_s``,
    1.5°/s as ``evaluate`` splits them), it is the floor that the plots' geometry sets for the
    turning figures: the aircraft that turn are not those that fly straight, and their
    plots are not as good (their range, their radars). Measurements:
    every such plot of the aircraft, from all radars, at its own time with its own 2×2
    covariance R (sequential processing is the exact fused-measurement information);
    prior at the first plot (and again after a gap of more than 60 s without plots, when a
    tracker would have dropped the track): position from R, velocity variance
    max_speed²/3, acceleration σ_m². Covariance updates in Joseph form. The bound assumes perfect
    association, no false or wild plots and no radar bias,
    so it is a floor. It is evaluated at the period times (as the tracks are scored) while
    the aircraft is detectable, from ``settle_s`` after its first plot on, and reported as
    sqrt(mean(P_xx + P_yy)), comparable with the settled position RMS; over the times in
    straight flight alone (truth turn rate below ``EvalParams.straight_below_deg_s``, 0.3°/s,
    as ``evaluate`` splits them),
    comparable with the settled straight-flight RMS; and over the times in turns,
    comparable with the settled turning RMS.

    The same bound with the aircraft's own velocity too (``pcrb_velocity_*``): each plot's
    Mode S BDS 5,0 ground speed and track, where the simulator gave one, as a second update
    at the plot's time (its age unknown, as to the engine: see below). The engine takes
    those reports (imm.IMMFilter.velocity_update_rows), so this is the bound of everything
    it is given; the plots' alone undercounts it (straight flight came out at 0.58-0.77× that
    one). Then each plot's BDS 6,0 heading and airspeed, where the simulator gave them, as a
    third update: the air vector, with the wind known (see below; the engine takes them with
    the wind it learns, engine.Engine._air_velocity_and_wind). Reports on wild plots are left
    out with their plots.
    """
    import numpy as np

    from radar_fusion.geo.air_data import indicated_airspeed_mps, pressure_altitude_of_height_m, true_airspeed_mps
    from radar_fusion.geo.coordinates import mode_c_height_m, polar_to_plane
    from radar_fusion.geo.units import M_PER_FT
    from radar_fusion.tools.evaluate import EvalParams
    from radar_fusion.tracking.initiation import unknown_velocity_var_m2ps2
    from radar_fusion.tracking.singer_filter import singer_process_noise, singer_transition

    straight_below_deg_s, turning_above_deg_s = EvalParams().straight_below_deg_s, EvalParams().turning_above_deg_s

    cols = [c for c in sim.plot_columns if len(c)]
    if not cols:
        return {"noise_rms_m": math.nan, "noise_model_rms_m": math.nan, "pcrb_pos_rms_m": math.nan}
    cat = lambda name: np.concatenate([getattr(c, name) for c in cols])
    radar = np.concatenate([np.full(len(c), c.radar_index) for c in cols])
    t, rng, az, fl, tgt, wild = (cat(k) for k in ("t_s", "range_m", "azimuth_deg", "fl", "target_index", "wild"))
    gs_mps = cat("ground_speed_mps")
    heading_deg = cat("magnetic_heading_deg")
    keep = (tgt >= 0) & ~wild
    t, rng, az, fl, tgt, radar = t[keep], rng[keep], az[keep], fl[keep], tgt[keep], radar[keep]
    gs_mps, heading_deg = gs_mps[keep], heading_deg[keep]
    x, y, cov, _g, valid = polar_to_plane(
        sim.plane,
        sim.sites,
        radar,
        rng,
        az,
        mode_c_height_m(fl, *settings.tracking.mode_c_met()),
        assumed_altitude_m=settings.tracking.assumed_altitude_ft * M_PER_FT,
        sigma_known_altitude_fraction=settings.tracking.mode_c_sigma_fraction(),
        return_valid=True,
    )
    t, x, y, cov, tgt = t[valid], x[valid], y[valid], cov[valid], tgt[valid]
    gs_mps, heading_deg = gs_mps[valid], heading_deg[valid]
    radar, rng, az, fl = radar[valid], rng[valid], az[valid], fl[valid]
    truth = sim.truth_at(tgt, t)
    err2 = (x - truth["x_m"]) ** 2 + (y - truth["y_m"]) ** 2
    out = {
        "noise_rms_m": float(np.sqrt(np.mean(err2))),
        "noise_model_rms_m": float(np.sqrt(np.mean(cov[:, 0, 0] + cov[:, 1, 1]))),
        "noise_plots": int(t.size),
    }

    trk = settings.tracking
    gap_s = 60.0
    if trk.filter == "imm":
        alpha, sigma_m = trk.imm.quiet_alpha_per_s, trk.imm.quiet_sigma_m_mps2
    else:
        alpha, sigma_m = trk.alpha_per_s, trk.sigma_m_mps2
    order = np.lexsort((t, tgt))
    t, cov, tgt, gs_mps, heading_deg = t[order], cov[order], tgt[order], gs_mps[order], heading_deg[order]
    radar, rng, az, fl, x, y = radar[order], rng[order], az[order], fl[order], x[order], y[order]
    n = t.size
    atmosphere = sim.scenario.atmosphere
    D = 9  # the Singer state (6), the aircraft's own wind departure (2) and heading error (1)
    # The aircraft's own velocity (Mode S BDS 5,0) on the plots that carry it: the truth's
    # velocity an age τ before the plot, τ uniform over the simulator's dap_age_s and not
    # known to any tracker (nothing on the wire says it). To first order v(t − τ) = v(t) −
    # τ̄ a(t) − (τ − τ̄) a(t) (as the engine's update, imm.IMMFilter.velocity_update_rows):
    # H picks v − τ̄ a, and the unknown part of the age adds var(τ) a aᵀ to the report's
    # noise (a the truth's acceleration: a bound told the turn); the noise itself is the
    # simulator's with the register's rounding (2 kt and 90/512°, uniform: step²/12) along
    # and across the track.
    rates = sim.scenario.rates
    kt_mps = 1852.0 / 3600.0

    def aged_report(has: np.ndarray, age_range_s: tuple[float, float]):
        """H (v − τ̄ a), the truth at the mean age τ̄ before the plots ``has``, its
        acceleration (the velocity 1 s apart: a chord) and var(τ), τ uniform over the range."""
        lo_s, hi_s = age_range_s
        mean_s = 0.5 * (lo_s + hi_s)
        Hr = np.zeros((int(has.sum()), 2, D))
        Hr[:, 0, 1] = Hr[:, 1, 4] = 1.0
        Hr[:, 0, 2] = Hr[:, 1, 5] = -mean_s
        truth_r = sim.truth_at(tgt[has], t[has] - mean_s)
        early, late = (sim.truth_at(tgt[has], t[has] - mean_s + d) for d in (-0.5, 0.5))
        acc_r = np.stack([late["vx_mps"] - early["vx_mps"], late["vy_mps"] - early["vy_mps"]], axis=1)
        return Hr, truth_r, acc_r, (hi_s - lo_s) ** 2 / 12.0

    def report_cov(along_r, var_along_r, var_across_r, acc_r, age_var_s2):
        """R of reports with ``var_along_r`` along the unit vectors ``along_r`` and
        ``var_across_r`` across them, plus the ages' spread times the acceleration; and the
        across unit vectors (along turned 90° right)."""
        across_r = np.stack([along_r[:, 1], -along_r[:, 0]], axis=1)
        R = var_along_r[..., None, None] * along_r[:, :, None] * along_r[:, None, :]
        R += var_across_r[:, None, None] * across_r[:, :, None] * across_r[:, None, :]
        R += age_var_s2 * acc_r[:, :, None] * acc_r[:, None, :]
        return R, across_r

    has_v = np.isfinite(gs_mps)
    Hv, tv, acc, age_var_s2 = aged_report(has_v, rates.dap_age_s)
    speed = np.maximum(np.hypot(tv["vx_mps"], tv["vy_mps"]), 1e-3)
    along = np.stack([tv["vx_mps"], tv["vy_mps"]], axis=1) / speed[:, None]
    var_along = np.full(speed.size, rates.sigma_ground_speed_mps**2 + (2.0 * kt_mps) ** 2 / 12.0)
    var_across = speed**2 * np.radians(np.hypot(rates.sigma_track_angle_deg, (90.0 / 512.0) / math.sqrt(12.0))) ** 2
    Rv, _ = report_cov(along, var_along, var_across, acc, age_var_s2)
    # The aircraft's heading and airspeed (BDS 6,0) on the plots that carry them: the air
    # vector, the truth's velocity less the wind, of an age τ uniform over the simulator's
    # air_age_s (H picks v − τ̄ a; var(τ) a aᵀ as above). The layers' wind known: one field
    # over the coverage, which every aircraft's reports measure (the engine learns it per
    # layer), so a bound may take it as given, and the day's temperature off ISA likewise;
    # not each aircraft's own departure from the wind, o (2), nor its heading error δ, two
    # more states of the bound, constant, from priors of the simulator's σ
    # (Atmosphere.local_wind_sigma_mps, heading_bias_sigma_deg): H adds −o and δ TAS r̂ (r̂
    # the air vector turned 90° right). The noise: the simulator's heading σ with the
    # register's 90/512° across the air vector, and its IAS σ with the 1 kt step along it
    # times dTAS/dIAS at the truth's height.
    has_a = np.isfinite(heading_deg)
    Ha, ta, acc_a, air_var_s2 = aged_report(has_a, rates.air_age_s)
    Ha[:, 0, 6] = Ha[:, 1, 7] = -1.0
    alt_a = ta["alt_ft"] * M_PER_FT
    # the wind (east, north: true) in the plane's grid: turned by the meridian convergence c
    # (a true bearing β is the grid bearing β − c)
    wind_e, wind_n = atmosphere.wind_mps(alt_a)
    c_rad = np.radians(sim.plane.velocity_frame(ta["x_m"], ta["y_m"])[0])
    wind_x = wind_e * np.cos(c_rad) - wind_n * np.sin(c_rad)
    wind_y = wind_n * np.cos(c_rad) + wind_e * np.sin(c_rad)
    air = np.stack([ta["vx_mps"] - wind_x, ta["vy_mps"] - wind_y], axis=1)
    tas = np.maximum(np.hypot(air[:, 0], air[:, 1]), 1e-3)
    dev_k = atmosphere.temperature_deviation_k
    # the IAS's noise along the air vector: times dTAS/dIAS there (a central difference), at
    # the pressure altitude of the truth's height on the day
    alt_a = pressure_altitude_of_height_m(alt_a, dev_k, atmosphere.qnh_hpa)
    ias_a = indicated_airspeed_mps(tas, alt_a, dev_k)
    tas_per_ias = true_airspeed_mps(ias_a + 0.5, alt_a, dev_k) - true_airspeed_mps(ias_a - 0.5, alt_a, dev_k)
    var_a_along = tas_per_ias**2 * (rates.sigma_ias_mps**2 + kt_mps**2 / 12.0)
    var_a_across = tas**2 * np.radians(np.hypot(rates.sigma_heading_deg, (90.0 / 512.0) / math.sqrt(12.0))) ** 2
    Ra, a_across = report_cov(air / tas[:, None], var_a_along, var_a_across, acc_a, air_var_s2)
    Ha[:, :, 8] = tas[:, None] * a_across
    v_row = np.full(n, -1)
    v_row[has_v] = np.arange(int(has_v.sum()))
    a_row = np.full(n, -1)
    a_row[has_a] = np.arange(int(has_a.sum()))
    first = np.r_[True, tgt[1:] != tgt[:-1]]
    start = np.flatnonzero(first)
    rank = np.arange(n) - np.repeat(start, np.diff(np.r_[start, n]))
    # where the bound starts from the one-plot prior: an aircraft's first plot, and its first
    # after a gap longer than a track survives (it left coverage: the next plot starts a track)
    starts = (rank == 0) | (np.r_[False, np.diff(t)] > gap_s)
    H = np.zeros((2, D))
    H[0, 0] = H[1, 3] = 1.0

    def prior(i: np.ndarray) -> np.ndarray:
        p0 = np.zeros((i.size, D, D))
        p0[:, [0, 0, 3, 3], [0, 3, 0, 3]] = cov[i][:, [0, 0, 1, 1], [0, 1, 0, 1]]
        p0[:, 1, 1] = p0[:, 4, 4] = unknown_velocity_var_m2ps2(settings.clustering.max_speed_mps)
        p0[:, 2, 2] = p0[:, 5, 5] = sigma_m**2
        p0[:, 6, 6] = p0[:, 7, 7] = atmosphere.local_wind_sigma_mps**2
        p0[:, 8, 8] = math.radians(atmosphere.heading_bias_sigma_deg) ** 2
        return p0

    def transition(dt: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Φ and Q of the state: Singer's model (singer_filter), the aircraft's own wind
        departure and heading error constant."""
        F = np.zeros((dt.size, D, D))
        F[:, :6, :6] = singer_transition(dt, alpha)
        F[:, 6, 6] = F[:, 7, 7] = F[:, 8, 8] = 1.0
        Q = np.zeros((dt.size, D, D))
        Q[:, :6, :6] = singer_process_noise(dt, alpha, sigma_m)
        return F, Q

    def joseph(Pp: np.ndarray, Hm: np.ndarray, R: np.ndarray) -> np.ndarray:
        """Covariance update in Joseph form: stays symmetric positive semi-definite in floating point."""
        S = Hm @ Pp @ np.swapaxes(Hm, -1, -2) + R
        K = Pp @ np.swapaxes(Hm, -1, -2) @ np.linalg.inv(S)
        IKH = np.eye(D) - K @ Hm
        out: np.ndarray = IKH @ Pp @ np.swapaxes(IKH, 1, 2) + K @ R @ np.swapaxes(K, 1, 2)
        return out

    def recursion(with_velocity: bool) -> np.ndarray:
        P = np.zeros((n, D, D))

        def velocity_update(i: np.ndarray) -> None:
            j = i[v_row[i] >= 0] if with_velocity else i[:0]
            if j.size:
                P[j] = joseph(P[j], Hv[v_row[j]], Rv[v_row[j]])
            j = i[a_row[i] >= 0] if with_velocity else i[:0]
            if j.size:
                P[j] = joseph(P[j], Ha[a_row[j]], Ra[a_row[j]])

        for r in range(int(rank.max()) + 1):
            idx = np.flatnonzero(rank == r)
            restart = starts[idx]
            P[idx[restart]] = prior(idx[restart])
            velocity_update(idx[restart])
            idx = idx[~restart]
            if not idx.size:
                continue
            F, Q = transition(t[idx] - t[idx - 1])
            Pp = F @ P[idx - 1] @ np.swapaxes(F, 1, 2) + Q
            P[idx] = joseph(Pp, H, cov[idx])
            velocity_update(idx)
        return P

    def joint_recursion() -> np.ndarray:
        """The bound with the velocity reports and the radars' range and azimuth offsets
        unknown: one covariance over every aircraft's state and every radar's two offsets,
        the plots of all aircraft in time order. A plot of radar r measures its aircraft's
        position plus J_r b_r (J_r: registration.RegistrationGeometry.jacobian, the columns
        of the two offsets the simulator injects), so it informs the offsets, and through
        them every other aircraft that radar sees. Each aircraft's block is kept at the time
        of its last plot (predicted, rows and columns, when its next one comes); a new or
        restarted aircraft's position is its first plot less J_r b_r, which ties it to the
        offsets from the start. The offsets' prior is the engine's own
        (``[registration] prior_sigma_*``: weak, a few times the simulator's biases); no
        gain or time offset (the simulator has none, though the engine estimates them, so
        this bound is still below what a tracker that does not know that can reach).
        Returns each plot's marginal block (n, D, D), as ``recursion``; the evaluation
        predicts it to the period times, so the plots of other aircraft between an aircraft's
        last plot and a period time, which inform the offsets too, are left out of that
        time's bound (a slightly higher bound: 101.82 against 101.63 m on two aircraft and two
        radars, 55.91 against 55.86 m on ten and three)."""
        from radar_fusion.tracking.registration import AZIMUTH_OFFSET, RANGE_OFFSET, RegistrationGeometry

        targets, blk = np.unique(tgt, return_inverse=True)
        n_radars = len(sc.radars)
        reg = settings.registration
        jac = RegistrationGeometry(sim.plane, sim.sites).jacobian(
            radar,
            rng,
            az,
            mode_c_height_m(fl, *settings.tracking.mode_c_met()),
            x,
            y,
            assumed_altitude_m=settings.tracking.assumed_altitude_ft * M_PER_FT,
        )[:, :, [RANGE_OFFSET, AZIMUTH_OFFSET]]
        b0 = targets.size * D
        N = b0 + 2 * n_radars
        P = np.zeros((N, N))
        P[b0:, b0:] = np.diag(
            np.tile([reg.prior_sigma_range_offset_m**2, reg.prior_sigma_azimuth_offset_deg**2], n_radars)
        )
        out = np.zeros((n, D, D))

        def update(PH: np.ndarray, S: np.ndarray) -> None:
            P[...] -= PH @ np.linalg.solve(S, PH.T)  # P − P Hᵀ S⁻¹ H P

        for step, j in enumerate(np.argsort(t, kind="stable")):
            s0 = int(blk[j]) * D
            st, pos = slice(s0, s0 + D), [s0, s0 + 3]
            b = b0 + 2 * int(radar[j])
            bs, Jb = slice(b, b + 2), jac[j]
            if starts[j]:
                P[st, :] = 0.0
                P[:, st] = 0.0
                P[st, st] = prior(np.array([j]))[0]
                c = -Jb @ P[bs, :]  # the position z − J b − n against everything
                P[pos, :] = c
                P[:, pos] = c.T
                P[np.ix_(pos, pos)] = cov[j] + Jb @ P[bs, bs] @ Jb.T
            else:
                F, Q = (m[0] for m in transition(np.array([t[j] - t[j - 1]])))
                P[st, :] = F @ P[st, :]
                P[:, st] = P[:, st] @ F.T
                P[st, st] += Q
                PH = P[:, pos] + P[:, bs] @ Jb.T
                update(PH, PH[pos] + Jb @ PH[bs] + cov[j])
            for row, Hm, Rm in ((v_row[j], Hv, Rv), (a_row[j], Ha, Ra)):
                if row >= 0:
                    PH = P[:, st] @ Hm[row].T
                    update(PH, Hm[row] @ PH[st] + Rm[row])
            if step % 256 == 255:
                P[...] = 0.5 * (P + P.T)
            out[j] = P[st, st]
        return out

    # the plots' bound and the bound with the velocity reports (the same where none carries one);
    # with few aircraft, that one with the radars' offsets unknown too (its covariance grows
    # with the square of the aircraft)
    bounds = [recursion(with_velocity=False), recursion(with_velocity=True)]
    sc = sim.scenario
    joint = np.unique(tgt).size <= JOINT_BOUND_MAX_AIRCRAFT
    if joint:
        bounds.append(joint_recursion())
    # evaluation at the period times
    period_s = float(settings.system.period_s)
    times = np.arange(math.ceil(sc.start_t_s / period_s), math.floor((sc.start_t_s + sc.duration_s) / period_s) + 1)
    times = times * period_s
    tr = sim.truth
    var_sum, count = np.zeros(len(bounds)), 0
    straight_sum, straight_count = np.zeros(len(bounds)), 0
    turning_sum, turning_count = np.zeros(len(bounds)), 0
    for k, s in enumerate(start.tolist()):
        e = start[k + 1] if k + 1 < start.size else n
        target = int(tgt[s])
        q = times[times >= t[s] + settle_s]
        if q.size == 0:
            continue
        rows = tr.target_index == target
        tt, det = tr.t_s[rows], tr.detectable[rows]
        if tt.size == 0:
            continue
        heading = np.unwrap(np.arctan2(tr.vx_mps[rows], tr.vy_mps[rows]))
        rate_deg_s = np.abs(np.degrees(np.gradient(heading, tt))) if tt.size > 1 else np.zeros(tt.size)
        ok = (q >= tt[0]) & (q <= tt[-1])
        q = q[ok]
        lo = np.clip(np.searchsorted(tt, q, side="right") - 1, 0, tt.size - 1)
        hi = np.clip(lo + 1, 0, tt.size - 1)
        seen = det[lo] & det[hi]
        rate_q = np.maximum(rate_deg_s[lo], rate_deg_s[hi])[seen]
        q, straight, turning = q[seen], rate_q < straight_below_deg_s, rate_q > turning_above_deg_s
        if q.size == 0:
            continue
        j = s + np.searchsorted(t[s:e], q, side="right") - 1
        near = q - t[j] <= gap_s  # no plot for longer: no track to bound
        q, j, straight, turning = q[near], j[near], straight[near], turning[near]
        if q.size == 0:
            continue
        F, Qq = transition(q - t[j])
        for b, Pb in enumerate(bounds):
            Pq = F @ Pb[j] @ np.swapaxes(F, 1, 2) + Qq
            v = Pq[:, 0, 0] + Pq[:, 3, 3]
            var_sum[b] += float(np.sum(v))
            straight_sum[b] += float(np.sum(v[straight]))
            turning_sum[b] += float(np.sum(v[turning]))
        count += q.size
        straight_count += int(straight.sum())
        turning_count += int(turning.sum())
    rms = lambda total, c: [math.sqrt(x / c) if c else math.nan for x in total]
    out["pcrb_pos_rms_m"], out["pcrb_velocity_pos_rms_m"], *bias = rms(var_sum, count)
    out["pcrb_points"] = count
    out["pcrb_straight_pos_rms_m"], out["pcrb_velocity_straight_pos_rms_m"], *bias_straight = rms(
        straight_sum, straight_count
    )
    out["pcrb_turning_pos_rms_m"], out["pcrb_velocity_turning_pos_rms_m"], *bias_turning = rms(
        turning_sum, turning_count
    )
    if joint:
        out["pcrb_offsets_pos_rms_m"] = bias[0]
        out["pcrb_offsets_straight_pos_rms_m"] = bias_straight[0]
        out["pcrb_offsets_turning_pos_rms_m"] = bias_turning[0]
    out["pcrb_turning_points"] = turning_count
    out["pcrb_velocity_reports"] = int(has_v.sum())
    out["pcrb_air_reports"] = int(has_a.sum())
    return out


def _engine_settings(data: dict[str, Any], gate: bool = True):
    import tomllib

    from radar_fusion import config

    raw = tomllib.loads(data["config_toml"])
    raw.setdefault("outliers", {})["enabled"] = bool(gate)
    return config.settings_from_dict(raw, source="benchmark scenario")


def _decoded_events(data: dict[str, Any]) -> list[tuple[int, Any]]:
    from radar_fusion import wire

    return [
        (0, obj)
        if kind == 0
        else (1, wire.RadarStatus(radar_id=obj[0], t=obj[1], kind=obj[2], sector=obj[3], rotation_period_s=obj[4]))
        for kind, obj in data["events"]
    ]


def _run_engine_batches(settings, events) -> list[dict]:
    from radar_fusion.engine import Engine

    engine = Engine(settings, safety_nets=None)
    batches: list[dict] = []
    for kind, obj in events:
        if kind == 0:
            engine.ingest_plots(obj)
            batches.extend(o.track_batch for o in engine.poll())
        else:
            engine.ingest_status(obj)
    batches.extend(o.track_batch for o in engine.flush())
    return batches


def run_accuracy(case_dir: str, settle_s: float, png_prefix: str | None = None) -> dict[str, Any]:
    """Score the engine's tracks and each radar alone (the engine with that radar only) against truth."""
    from radar_fusion.tools import evaluate as ev

    with open(os.path.join(case_dir, "engine.pkl"), "rb") as f:
        data = pickle.load(f)
    settings = _engine_settings(data)
    events = _decoded_events(data)
    truth = ev.load_truth(os.path.join(case_dir, "truth.csv"))
    params = ev.EvalParams(settle_s=settle_s)
    batches = _run_engine_batches(settings, events)
    scores = ev.evaluate(batches, truth, params)
    settled_from = data["start_t_s"] + settle_s
    out: dict[str, Any] = {"ours": _summary(scores, settled_from), "single": {}}
    if png_prefix:
        ev.plot(batches, truth, png_prefix + "_ours.png", scores)
    del batches
    per_target = {}
    for radar in settings.radars:
        one = settings.model_copy(update={"radars": [radar]})
        evs = [(k, o) for k, o in events if (o.radar_id == radar.id)]
        s1 = ev.evaluate(_run_engine_batches(one, evs), truth, params)
        out["single"][radar.id] = _summary(s1, settled_from)
        per_target[radar.id] = s1.targets
    key = lambda rid: (_nan_last(out["single"][rid]["pos_rms_settled_m"]), _nan_last(out["single"][rid]["pos_rms_m"]))
    out["best_single_radar"] = best = min(out["single"], key=key) if out["single"] else None
    if best is not None:
        out["same_aircraft"] = same_aircraft_rms(scores.targets, per_target[best])
    return out


def run_accuracy_ours(case_dir: str, settle_s: float) -> dict[str, Any]:
    """Score the engine's tracks of a case against truth (no single-radar runs)."""
    from radar_fusion.tools import evaluate as ev

    with open(os.path.join(case_dir, "engine.pkl"), "rb") as f:
        data = pickle.load(f)
    scores = ev.evaluate(
        _run_engine_batches(_engine_settings(data), _decoded_events(data)),
        ev.load_truth(os.path.join(case_dir, "truth.csv")),
        ev.EvalParams(settle_s=settle_s),
    )
    return _summary(scores, data["start_t_s"] + settle_s)


def run_wild_twin(args: argparse.Namespace, sizes: list[tuple[int, int]], duration_s: float, tmp: str) -> int:
    """Issue 15 item 7: each size with ``wild_plot_prob`` = ``args.wild_twin`` against its
    clean twin, the same simulation (seed, noise, detections, false plots) with the wild
    plots' gross errors not applied (``Rates.wild_errors``), so that the difference is the
    wild plots' alone and not another draw of the noise (two simulations with different
    wild rates draw different noise: at 1,000×10, 120 s, seed 0 that alone moved GOSPA 5 %)."""
    from .report import wild_twin_lines

    print("\n".join(machine_lines()), flush=True)
    print(
        f"wild plots against their clean twin (issue 15 item 7): wild_plot_prob {args.wild_twin:g}, "
        f"{duration_s:g} s simulated per size, seed {args.seed}, accuracy settled after {args.settle_s:g} s",
        flush=True,
    )
    rows = []
    t_bench = time.perf_counter()
    for n, r in sizes:
        row: dict[str, Any] = {"label": f"{n:,}×{r}"}
        for name, errors in (("twin", False), ("wild", True)):
            case = {"kind": "benchmark", "aircraft": n, "radars": r, "duration_s": duration_s, "sectors": None}
            case.update(wild_plot_prob=args.wild_twin, wild_errors=errors)
            case_dir = os.path.join(tmp, f"{n}x{r}_{name}")
            os.makedirs(case_dir, exist_ok=True)
            row[name + "_sim"] = in_fresh_process(simulate_case, case, args.seed, case_dir, args.settle_s)
            row[name] = in_fresh_process(run_accuracy_ours, case_dir, args.settle_s)
        print(
            f"  {row['label']}: {row['wild_sim']['plots']:,} plots, {row['wild_sim']['wild_truth']:,} of them wild "
            f"(twin: {row['twin_sim']['wild_truth']})",
            flush=True,
        )
        rows.append(row)
    print()
    for line in wild_twin_lines(rows):
        print(line)
    print(f"(wall time {time.perf_counter() - t_bench:.0f} s)")
    return 0


def same_aircraft_rms(fused_targets, single_targets) -> dict[str, Any]:
    """Fused vs single-radar position RMS on the same aircraft: the aircraft both track,
    each weighted by the number of period times the single radar's track covers it (a
    single radar sees only its own coverage, often the aircraft near it, so its overall
    RMS is over an easier population). Per-aircraft RMS as in ``TargetScore.pos_rms_m``
    (every associated pair, any status)."""
    fused = {t.target_id: t for t in fused_targets}
    num_f = num_s = den = 0.0
    n = 0
    for t in single_targets:
        f = fused.get(t.target_id)
        if f is None or not (t.covered_batches > 0) or math.isnan(t.pos_rms_m) or math.isnan(f.pos_rms_m):
            continue
        w = float(t.covered_batches)
        num_f += w * f.pos_rms_m**2
        num_s += w * t.pos_rms_m**2
        den += w
        n += 1
    if den == 0:
        return {"fused_m": math.nan, "single_m": math.nan, "aircraft": 0}
    return {"fused_m": math.sqrt(num_f / den), "single_m": math.sqrt(num_s / den), "aircraft": n}


def _nan_last(v: float) -> float:
    return math.inf if v is None or math.isnan(v) else v


def run_reference(
    case_dir: str, settle_s: float, budget_s: float, q_m2ps3: float, png_prefix: str | None = None
) -> dict[str, Any]:
    """(c) Stone Soup on the same plots, timed, then scored against truth."""
    from radar_fusion.tools import baseline_stonesoup as bs
    from radar_fusion.tools import evaluate as ev

    with open(os.path.join(case_dir, "engine.pkl"), "rb") as f:
        data = pickle.load(f)
    settings = _engine_settings(data)
    plot_batches = [obj for kind, obj in _decoded_events(data) if kind == 0]
    settled_from = data["start_t_s"] + settle_s
    del data
    gc.collect()
    rss_base_kb = rss_kb("VmRSS")
    hwm_reset = reset_peak_rss()
    run = bs.run_stonesoup(settings, plot_batches, bs.StoneSoupParams(q_m2ps3=q_m2ps3), time_budget_s=budget_s)
    peak_kb = rss_kb("VmHWM") if hwm_reset else maxrss_kb()
    out = {
        "version": bs.version(),
        "completed": run.completed,
        "run_s": run.run_s,
        "plots": run.plots_used,
        "plots_processed": run.plots_processed,
        "plots_per_s": run.plots_per_s,
        "steps": run.steps,
        "tracks_started": run.tracks_started,
        "peak_rss_mb": (peak_kb or 0) / 1024.0,
        "rss_base_mb": (rss_base_kb or 0) / 1024.0,
        "q_m2ps3": q_m2ps3,
    }
    if run.completed:
        truth = ev.load_truth(os.path.join(case_dir, "truth.csv"))
        scores = ev.evaluate(run.batches, truth, ev.EvalParams(settle_s=settle_s))
        out["scores"] = _summary(scores, settled_from)
        if png_prefix:
            ev.plot(run.batches, truth, png_prefix + "_stonesoup.png", scores)
    return out


def _closable_after(records, settings) -> Any:
    """Per message: the event time up to which every period may close once it is processed
    (the period buffer's rule, engine/watermarks.py: over the live radars, watermark less
    the radar's own lateness), as a running maximum; periods ending at or before it have
    all their inputs."""
    import numpy as np

    from radar_fusion.engine.watermarks import Watermarks
    from radar_fusion.wire import Rejection, decode_plot_batch

    index = {r.id: i for i, r in enumerate(settings.radars)}
    sysc = settings.system
    marks = Watermarks(len(index), sysc.allowed_lateness_s, sysc.radar_timeout_s, sysc.lateness_memory_s)
    out = np.full(len(records), -math.inf)
    best = -math.inf
    for i, rec in enumerate(records):
        parts = rec.key.split("/")
        r = index.get(parts[-2])
        if r is not None:
            if parts[-1] == "plots":
                d = decode_plot_batch(rec.payload)
                if not isinstance(d, Rejection) and len(d):
                    marks.arrived(r, float(d.t_s.min()))
                    marks.advance(r, float(d.t_s.max()))
                else:
                    marks.advance(r, rec.t_s)
            else:
                marks.advance(r, rec.t_s)
            best = max(best, marks.closable_until_s())
        out[i] = best
    return out


def run_bus(
    case_dir: str, speed: float | None, warmup_s: float, timeout_s: float, safety_nets: str = "child"
) -> dict[str, Any]:
    """(b) The daemon (``radar-fusion serve``, its own process, embedded router on a free
    127.0.0.1 port) fed by the replay tool (:func:`replay.replay_records`, a client
    session), the track batches received by a subscriber on another client session.

    Publish time of a message = when its ``put`` returned; receive time = when the
    subscriber's callback ran (both ``time.monotonic``, one clock for every process on
    Linux). After the recording, one heartbeat status per radar (event time last + one
    period + the allowed lateness + 0.5 s) closes the last periods, so every period
    ends the normal way. plots/s = plots / (last TrackBatch received − first message
    sent). Latency of period k = receive time of its TrackBatch − publish time of the
    message that let it close (the first after which every live radar's watermark less
    its lateness has passed the period's end: the last input the period waits for);
    periods ending in the first ``warmup_s`` are left out, and so are the periods only the
    final heartbeats let close (``e2e_all_*`` keep them). ``e2e_parts_ms``: that latency
    cut into its parts (:data:`E2E_PARTS`) by the daemon's stamps (serve --timing-log). Data age (paced runs) = a
    TrackBatch's receive time − its reference time ``t`` on the replay's clock, over the
    periods after the warm-up that a recorded message let close (not the final heartbeats).

    Alerts (``safety_nets``: where serve runs them, ``serve --safety-nets``): the same
    subscriber receives them. Alert latency after its TrackBatch, per period with alerts =
    receive time of the period's last alert − receive time of its TrackBatch (in process
    they are published right after it); alert end-to-end = the last alert's receive time −
    the publish time of the input that closed the period. The safety-nets child's own
    figures (a TrackBatch's arrival to its alerts published, over its last 1,000 batches)
    come from its final health message.
    """
    import signal
    import subprocess as sp

    import msgpack
    import numpy as np

    from radar_fusion import wire
    from radar_fusion.bus import open_session, zenoh_config
    from radar_fusion.config import load_settings
    from radar_fusion.recording import Record, read_recording
    from radar_fusion.tools.demo import free_tcp_port
    from radar_fusion.tools.replay import replay_records

    port = free_tcp_port()
    endpoint = f"tcp/127.0.0.1:{port}"
    text = Path(case_dir, "config.toml").read_text()
    cfg_path = Path(case_dir, f"bus_{port}.toml")
    cfg_path.write_text(text.replace('listen = ["tcp/127.0.0.1:7447"]', f'listen = ["{endpoint}"]'))
    settings = load_settings(cfg_path)
    prefix = settings.bus.prefix
    records = list(read_recording(Path(case_dir, "plots.rec")))
    n_plots = 0
    t_last = -math.inf
    for rec in records:
        if rec.key.endswith("/plots"):
            d = wire.decode_plot_batch(rec.payload)
            if not isinstance(d, wire.Rejection) and len(d):
                n_plots += len(d)
                t_last = max(t_last, float(d.t_s.max()))
    period_s = settings.system.period_s
    n_recorded = len(records)  # the heartbeats below follow
    t_hb = max(t_last, records[-1].t_s) + period_s + settings.system.allowed_lateness_s + 0.5
    for r in settings.radars:
        msg = {"v": wire.WIRE_VERSION, "radar_id": r.id, "t": t_hb, "kind": "heartbeat"}
        records.append(Record(t_hb, f"radar/{r.id}/status", wire.encode(msg)))
    closable = _closable_after(records, settings)
    last_period = int(math.floor(t_last / period_s))

    log_path = Path(case_dir, f"daemon_{port}.log")
    timing_path = Path(case_dir, f"timing_{port}.jsonl")
    with open(log_path, "w") as log:
        daemon = sp.Popen(
            [
                sys.executable,
                "-m",
                "radar_fusion.cli",
                "serve",
                "--config",
                str(cfg_path),
                "--log-level",
                "WARNING",
                "--safety-nets",
                safety_nets,
                "--timing-log",
                str(timing_path),
            ],
            stdout=log,
            stderr=sp.STDOUT,
        )
    received: list[tuple[float, bytes]] = []
    alerts_received: list[tuple[float, bytes]] = []
    nets_health: list[bytes] = []
    daemon_health: list[bytes] = []
    session = None
    try:
        deadline = time.monotonic() + 30.0
        while session is None:
            try:
                session = open_session(zenoh_config("client", connect=[endpoint]))
            except Exception:
                if time.monotonic() > deadline or daemon.poll() is not None:
                    raise RuntimeError(f"daemon did not come up; see {log_path}") from None
                time.sleep(0.2)
        sub = session.declare_subscriber(
            f"{prefix}/fusion/tracks", lambda s: received.append((time.monotonic(), s.payload.to_bytes()))
        )
        alert_sub = session.declare_subscriber(
            f"{prefix}/fusion/alerts/*", lambda s: alerts_received.append((time.monotonic(), s.payload.to_bytes()))
        )
        health_sub = session.declare_subscriber(
            f"{prefix}/fusion/safety_nets/health", lambda s: nets_health.append(s.payload.to_bytes())
        )
        daemon_health_sub = session.declare_subscriber(
            f"{prefix}/fusion/health", lambda s: daemon_health.append(s.payload.to_bytes())
        )
        time.sleep(1.0)  # subscriptions propagate through the router
        pub_s: list[float] = []

        def timed(recs):
            for rec in recs:
                yield rec
                pub_s.append(time.monotonic())

        t_start = time.monotonic()
        replay_records(session, timed(records), prefix, speed)
        t_sent = time.monotonic()

        periods_seen: list[int] = []  # of received[:len(periods_seen)], each read once

        def last_seen() -> bool:
            # each TrackBatch's period read once, from its head (the tracks skipped): decoding
            # the newest three whole every 20 ms took most of a core from the daemon measured
            periods_seen.extend(_period_of(p) for _, p in received[len(periods_seen) : len(received)])
            return max(periods_seen, default=-1) >= last_period

        deadline = time.monotonic() + timeout_s
        while not last_seen() and time.monotonic() < deadline and daemon.poll() is None:
            time.sleep(0.02)
        peak_kb = None
        try:
            with open(f"/proc/{daemon.pid}/status") as f:
                peak_kb = next((int(line.split()[1]) for line in f if line.startswith("VmHWM:")), None)
        except OSError:
            pass
        sub.undeclare()
        if daemon.poll() is None:  # stopped while we listen: the child's last alerts and final health
            daemon.send_signal(signal.SIGINT)
            with contextlib.suppress(sp.TimeoutExpired):
                daemon.wait(30)
        time.sleep(0.5)
        alert_sub.undeclare()
        health_sub.undeclare()
        daemon_health_sub.undeclare()
    finally:
        if session is not None:
            session.close()
        if daemon.poll() is None:
            daemon.send_signal(signal.SIGINT)
            try:
                daemon.wait(30)
            except sp.TimeoutExpired:
                daemon.kill()
                daemon.wait()
        cfg_path.unlink(missing_ok=True)
    batches = [(t_r, msgpack.unpackb(p, raw=False)) for t_r, p in received]
    done = [t_r for t_r, b in batches if b.get("period", -1) >= last_period]
    t_done = done[0] if done else math.nan
    pub = np.asarray(pub_s)
    lat_ms, lat_all_ms, warm_end = [], [], records[0].t_s + warmup_s
    stamps = _read_timing(timing_path)
    parts: dict[str, list[float]] = {}
    for t_r, b in batches:
        end_s = (b["period"] + 1) * period_s
        i = int(np.searchsorted(closable, end_s - 1e-9, side="left"))
        if end_s >= warm_end and i < pub.size:
            lat_all_ms.append(1e3 * (t_r - pub[i]))
            if i >= n_recorded:
                # closed by the final heartbeats (as for the data age below): they close the
                # last two periods at once, the second's latency then holds the first's
                # processing too, where live radars would have closed them one by one
                continue
            lat_ms.append(1e3 * (t_r - pub[i]))
            if (st := stamps.get(b["period"])) is not None:
                for name, ms in e2e_parts_ms(st, float(pub[i]), t_r).items():
                    parts.setdefault(name, []).append(ms)
    # Data age at a display (issue 16 item 5): a TrackBatch's receive time minus its reference
    # time t, on the replay's clock. Paced replay publishes each record at a fixed offset from
    # its own time, so wall = event time + the median offset of the records as published.
    # Periods that only the final heartbeats let close are left out: at the end of a
    # recording they wait for the heartbeat, where live radars would have gone on.
    age_ms: list[float] = []
    age_t: list[float] = []
    if speed and pub.size:
        n_pub = pub.size
        offset_s = float(np.median(pub - np.array([r.t_s for r in records[:n_pub]]) / speed))
        for t_r, b in batches:
            closed_by = int(np.searchsorted(closable, (b["period"] + 1) * period_s - 1e-9, side="left"))
            if float(b["t"]) >= warm_end and closed_by < n_recorded:
                age_t.append(float(b["t"]))
                age_ms.append(1e3 * (t_r - (offset_s + float(b["t"]) / speed)))
    batch_rx = {float(b["t"]): t_r for t_r, b in batches}
    last_alert: dict[float, float] = {}
    n_alerts = 0
    for t_r, p in alerts_received:
        a = msgpack.unpackb(p, raw=False)
        n_alerts += 1
        last_alert[float(a["t"])] = max(last_alert.get(float(a["t"]), -math.inf), t_r)
    after_ms, alert_e2e_ms = [], []
    for t_ref, t_a in last_alert.items():
        if t_ref not in batch_rx or t_ref < warm_end:
            continue
        after_ms.append(1e3 * (t_a - batch_rx[t_ref]))
        b = next((b for _, b in batches if float(b["t"]) == t_ref), None)
        if b is not None:
            i = int(np.searchsorted(closable, (b["period"] + 1) * period_s - 1e-9, side="left"))
            if i < pub.size:
                alert_e2e_ms.append(1e3 * (t_a - pub[i]))
    child = msgpack.unpackb(nets_health[-1], raw=False) if nets_health else {}
    # the daemon's final health (published after its last batches): plots refused as late,
    # and each radar's lateness at the end
    final = msgpack.unpackb(daemon_health[-1], raw=False) if daemon_health else {}
    plots_late = final.get("rejected", {}).get("plot_late", 0) if final else None
    plots_accepted = final.get("counters", {}).get("plots_accepted") if final else None
    lateness_s = {rid: r.get("lateness_s") for rid, r in final.get("radars", {}).items()} if final else {}
    return {
        "safety_nets": safety_nets,
        "alert_messages": n_alerts,
        "alert_periods": len(after_ms),
        "alert_after_batch_p50_ms": percentile(after_ms, 50),
        "alert_after_batch_p99_ms": percentile(after_ms, 99),
        "alert_after_batch_max_ms": max(after_ms) if after_ms else math.nan,
        "alert_e2e_p50_ms": percentile(alert_e2e_ms, 50),
        "alert_e2e_p99_ms": percentile(alert_e2e_ms, 99),
        "nets_latency_p50_ms": child.get("alert_latency_ms_p50"),
        "nets_latency_p99_ms": child.get("alert_latency_ms_p99"),
        "nets_processing_p99_ms": child.get("processing_ms_p99"),
        "nets_batches_processed": child.get("counters", {}).get("batches_processed"),
        "nets_batches_dropped": child.get("counters", {}).get("batches_dropped"),
        "nets_rejected": child.get("rejected"),
        "speed": speed,
        "plots": n_plots,
        "messages": len(records),
        "batches_received": len(batches),
        "completed": bool(done),
        "send_s": t_sent - t_start,
        "wall_s": t_done - t_start,
        "plots_per_s": n_plots / (t_done - t_start) if done else math.nan,
        "e2e_p50_ms": percentile(lat_ms, 50),
        "e2e_p99_ms": percentile(lat_ms, 99),
        "e2e_max_ms": max(lat_ms) if lat_ms else math.nan,
        "e2e_periods": len(lat_ms),
        "e2e_all_p99_ms": percentile(lat_all_ms, 99),
        "e2e_all_max_ms": max(lat_all_ms) if lat_all_ms else math.nan,
        "e2e_all_periods": len(lat_all_ms),
        "e2e_parts_ms": {name: (percentile(v, 50), percentile(v, 99)) for name, v in parts.items()},
        "data_age_p50_ms": percentile(age_ms, 50),
        "data_age_p99_ms": percentile(age_ms, 99),
        "data_age_max_ms": max(age_ms) if age_ms else math.nan,
        "plots_late": plots_late,
        "plots_accepted": plots_accepted,
        "radar_lateness_s": lateness_s,
        "data_age_periods": len(age_ms),
        "data_age": list(zip(age_t, age_ms)),  # (TrackBatch t, age ms), for a closer look
        "daemon_peak_rss_mb": (peak_kb or 0) / 1024.0,
    }


#: the parts of the end-to-end latency, in path order: (name, from stamp, to stamp); "pub"
#: is the replay's put of the input that let the period close, "rx" the subscriber's receipt
#: of its TrackBatch, the rest the daemon's stamps (serve --timing-log, bus.FusionDaemon._poll)
E2E_PARTS = (
    ("replay put -> daemon callback", "pub", "arrived_s"),
    ("input queue wait", "arrived_s", "taken_s"),
    ("decode + validate", "taken_s", "decoded_s"),
    ("admit (engine.ingest_*)", "decoded_s", "ingested_s"),
    ("later inputs before the poll", "ingested_s", "poll_s"),
    ("engine period", "poll_s", "engine_done_s"),
    ("TrackBatch build + encode", "engine_done_s", "emitted_s"),
    ("outbox wait", "emitted_s", "picked_s"),
    ("zenoh put", "picked_s", "put_s"),
    ("put returned -> subscriber", "put_s", "rx"),
    ("end to end", "pub", "rx"),
    ("(garbage collection, poll to put)", "gc_at_poll_s", "gc_at_put_s"),
)


def _period_of(payload: bytes) -> int:
    """A TrackBatch's period, read without decoding its tracks (−1 if none)."""
    from radar_fusion.bus import batch_head

    period = batch_head(payload).get("period")
    return period if type(period) is int else -1


def _read_timing(path: Path) -> dict[int, dict[str, float]]:
    """The daemon's per-period stamps (serve --timing-log), by period; {} without the file."""
    import json

    out: dict[int, dict[str, float]] = {}
    with contextlib.suppress(OSError):
        for line in path.read_text().splitlines():
            with contextlib.suppress(ValueError):
                st = json.loads(line)
                out[int(st["period"])] = st
    return out


def e2e_parts_ms(stamps: dict[str, float], pub_s: float, rx_s: float) -> dict[str, float]:
    """One period's end-to-end latency cut into :data:`E2E_PARTS`, in ms (NaN where a stamp is missing)."""
    at = {**stamps, "pub": pub_s, "rx": rx_s}
    return {name: 1e3 * (at.get(b, math.nan) - at.get(a, math.nan)) for name, a, b in E2E_PARTS}


def parts_lines(b: dict[str, Any]) -> list[str]:
    """The end-to-end breakdown of a run_bus result, one line per part (p50 / p99 ms)."""
    parts = b.get("e2e_parts_ms") or {}
    return [f"{name:<32} p50 {p50:8.1f} / p99 {p99:8.1f} ms" for name, (p50, p99) in parts.items()]


def late_line(b: dict[str, Any]) -> str:
    """Plots refused as late by the daemon and each radar's lateness at the end, one phrase."""
    if b.get("plots_late") is None:
        return "no final health received"
    n_in = (b["plots_accepted"] or 0) + b["plots_late"]
    share = 100.0 * b["plots_late"] / n_in if n_in else 0.0
    lateness = ", ".join(f"{rid} {v:g}" for rid, v in b["radar_lateness_s"].items() if v is not None)
    return f"{b['plots_late']:,} plots late of {n_in:,} ({share:.3f} %); lateness s {lateness or 'n/a'}"


def alert_line(b: dict[str, Any]) -> str:
    """The alert latency figures of a run_bus result, one line."""
    line = (
        f"alerts: {b['alert_messages']:,} messages; their period's last alert after its TrackBatch p50 "
        f"{b['alert_after_batch_p50_ms']:.1f} / p99 {b['alert_after_batch_p99_ms']:.1f} / max "
        f"{b['alert_after_batch_max_ms']:.1f} ms over {b['alert_periods']} periods; alert end-to-end p50 "
        f"{b['alert_e2e_p50_ms']:.1f} / p99 {b['alert_e2e_p99_ms']:.1f} ms"
    )
    if b.get("nets_latency_p99_ms") is not None:
        line += (
            f"; safety-nets process: arrival to alerts published p50 {b['nets_latency_p50_ms']:.1f} / p99 "
            f"{b['nets_latency_p99_ms']:.1f} ms (judging p99 {b['nets_processing_p99_ms']:.1f} ms), "
            f"{b['nets_batches_processed']} batches, {b['nets_batches_dropped']} dropped, rejected "
            f"{b['nets_rejected'] or 0}"
        )
    return line


def _estimate_reference_s(cost: tuple[float, str] | None, plots: int, tracks: float) -> float | None:
    """Stone Soup's run time scales with plots × tracks (every plot is hypothesised against
    every track, every track is predicted at every step): estimate from a measured case."""
    if cost is None or not (tracks > 0):
        return None
    return cost[0] * plots * tracks


def run_compare(args: argparse.Namespace, sizes: list[tuple[int, int]], duration_s: float, tmp: str) -> int:
    import shutil

    from radar_fusion.tools import baseline_stonesoup as bs

    report_dir = Path(args.report) if args.report else None
    if report_dir:
        report_dir.mkdir(parents=True, exist_ok=True)
    use_ref = not args.no_reference and bs.available()
    header = machine_lines() + [
        f"stonesoup {bs.version()}"
        + (
            "" if use_ref else " (reference not run: " + ("--no-reference)" if args.no_reference else "not importable)")
        ),
        f"{duration_s:g} s simulated per size, seed {args.seed}; warm-up {args.warmup_s:g} s left out of the "
        f"latency percentiles; accuracy settled after {args.settle_s:g} s",
    ]
    print("\n".join(header), flush=True)
    sectors = getattr(args, "sectors", None)
    cases = [
        {"kind": "benchmark", "aircraft": n, "radars": r, "duration_s": duration_s, "sectors": sectors}
        for n, r in sizes
    ]
    if not args.no_adsb:
        cases.append(
            {
                "kind": "adsb",
                "duration_s": args.adsb_duration_s,
                "max_aircraft": args.adsb_aircraft,
                "sectors": sectors,
            }
        )
    if not cases:
        print("bench: nothing to compare (--sizes none and --no-adsb)", file=sys.stderr)
        return 2
    rows: list[dict[str, Any]] = []
    ref_cost: tuple[float, str] | None = None
    t_bench = time.perf_counter()
    for c, case in enumerate(cases):
        label = _case_label(case)
        case_dir = os.path.join(tmp, f"case{c}")
        os.makedirs(case_dir, exist_ok=True)
        png = (
            str(report_dir / ("adsb" if case["kind"] == "adsb" else f"size{c}"))
            if report_dir and (case["kind"] == "adsb" or c == 0)
            else None
        )
        row: dict[str, Any] = {"label": label, "case": case}
        row["sim"] = sim = in_fresh_process(simulate_case, case, args.seed, case_dir, args.settle_s)
        print(
            f"{label}: {sim['aircraft']:,} aircraft, {sim['radars']} radars, {sim['plots']:,} plots "
            f"(simulated in {sim['sim_s']:.1f} s)",
            flush=True,
        )
        for line in truth_lines([row]):
            print("  " + line, flush=True)
        row["engine"] = eng = in_fresh_process(run_engine, os.path.join(case_dir, "engine.pkl"), True, args.warmup_s, 0)
        print(
            f"  (a) engine: {eng['plots_per_s']:,.0f} plots/s, period p50 {eng['p50_ms']:.1f} / p99 "
            f"{eng['p99_ms']:.1f} ms, peak RSS {eng['peak_rss_mb']:.0f} MB",
            flush=True,
        )
        if not args.no_bus:
            nets = args.safety_nets
            row["bus"] = b = in_fresh_process(run_bus, case_dir, None, args.warmup_s, args.bus_timeout_s, nets)
            print(
                f"  (b) daemon over Zenoh (safety nets {nets}), replay at max speed: {b['plots_per_s']:,.0f} plots/s "
                f"({b['wall_s']:.1f} s), daemon peak RSS {b['daemon_peak_rss_mb']:.0f} MB; "
                f"{b['alert_messages']:,} alert messages",
                flush=True,
            )
            if args.latency_speed > 0:
                row["bus_paced"] = bp = in_fresh_process(
                    run_bus, case_dir, args.latency_speed, args.warmup_s, args.bus_timeout_s, nets
                )
                print(
                    f"      replay at {args.latency_speed:g}× real time: end-to-end p50 {bp['e2e_p50_ms']:.1f} / "
                    f"p99 {bp['e2e_p99_ms']:.1f} ms over {bp['e2e_periods']} periods (with the final heartbeats' "
                    f"{bp['e2e_all_periods'] - bp['e2e_periods']}: p99 {bp['e2e_all_p99_ms']:.1f} / max "
                    f"{bp['e2e_all_max_ms']:.1f} ms); data age (TrackBatch "
                    f"received minus its t) p50 {bp['data_age_p50_ms'] / 1e3:.2f} / p99 "
                    f"{bp['data_age_p99_ms'] / 1e3:.2f} / max {bp['data_age_max_ms'] / 1e3:.2f} s over "
                    f"{bp['data_age_periods']} periods; {late_line(bp)}",
                    flush=True,
                )
                print("      " + alert_line(bp), flush=True)
                if bp.get("e2e_parts_ms"):
                    print("      end-to-end by part (the daemon's stamps, serve --timing-log):", flush=True)
                    for line in parts_lines(bp):
                        print("        " + line, flush=True)
        if use_ref:
            est = _estimate_reference_s(ref_cost, sim["plots"], eng["tracks_per_period"])
            if ref_cost is not None and est is not None and est > args.reference_budget_s:  # est needs ref_cost
                row["reference"] = {
                    "skipped": True,
                    "estimate_s": est,
                    "estimated_from": ref_cost[1],
                    "plots_per_s": sim["plots"] / est,
                }
                print(
                    f"  (c) Stone Soup: skipped, estimated {est / 60:.0f} min (> budget "
                    f"{args.reference_budget_s / 60:.0f} min) from the {ref_cost[1]} run",
                    flush=True,
                )
            else:
                ref = in_fresh_process(run_reference, case_dir, args.settle_s, args.reference_budget_s, args.ss_q, png)
                row["reference"] = ref
                if ref["plots_processed"] > 0 and eng["tracks_per_period"] > 0:
                    # a run stopped at the budget still measures the cost (optimistically for
                    # Stone Soup: its first part, during initiation, holds fewer tracks)
                    ref_cost = (
                        ref["run_s"] / (ref["plots_processed"] * eng["tracks_per_period"]),
                        label + ("" if ref["completed"] else " (partial)"),
                    )
                print(
                    f"  (c) Stone Soup {ref['version']}: {ref['plots_per_s']:,.1f} plots/s "
                    f"({ref['run_s']:.0f} s{'' if ref['completed'] else ', stopped at the budget'}), "
                    f"peak RSS {ref['peak_rss_mb']:.0f} MB; "
                    f"ours/reference {eng['plots_per_s'] / ref['plots_per_s']:,.0f}×",
                    flush=True,
                )
        if not args.no_accuracy:
            row["accuracy"] = acc = in_fresh_process(run_accuracy, case_dir, args.settle_s, png)
            o = acc["ours"]
            print(
                f"  accuracy: ours pos RMS {o['pos_rms_m']:.0f} m (settled {o['pos_rms_settled_m']:.0f}), GOSPA "
                f"{o['gospa_mean_m']:.0f} m; best single radar {acc['best_single_radar']}; plot noise "
                f"{sim['noise_rms_m']:.0f} m, PCRB {sim['pcrb_pos_rms_m']:.0f} m "
                f"(straight flight {sim.get('pcrb_straight_pos_rms_m', math.nan):.0f} m)",
                flush=True,
            )
        rows.append(row)
        shutil.rmtree(case_dir, ignore_errors=True)
    wall = time.perf_counter() - t_bench
    speed_md, acc_md, goals = compare_tables(rows, args)
    print()
    print(speed_md)
    print()
    print(acc_md)
    print()
    print("\n".join(truth_lines(rows) + goals))
    print(f"(benchmark wall time {wall:.0f} s)")
    if report_dir:
        write_report(report_dir, header, rows, args, speed_md, acc_md, goals, wall)
        print(f"wrote {report_dir}/report.md, summary.md, results.json and PNGs")
    return 0
