"""The Stone Soup reference tracker and the side-by-side benchmark (issue 7)."""

from __future__ import annotations

import json
import math
import tomllib

import numpy as np
import pytest

pytest.importorskip("stonesoup")

import itertools

from radar_fusion import config
from radar_fusion.tools import baseline_stonesoup as bs
from radar_fusion.tools import bench
from radar_fusion.tools import simulate as sm
from radar_fusion.tools.bench import compare


def _small_case(n_aircraft: int = 8, n_radars: int = 3, duration_s: float = 48.0, seed: int = 3):
    scenario = sm.scenario_for_benchmark(n_aircraft, n_radars, duration_s, seed)
    sim = sm.simulate(scenario, encode=False)
    settings = config.settings_from_dict(tomllib.loads(sm.config_toml(scenario)))
    return scenario, sim, settings


def _steady_flight(n_aircraft, n_radars, duration_s, seed, turn_rate_dps, roll_prob=None):
    """The benchmark scenario with every aircraft on one leg at ``turn_rate_dps`` (0: straight)
    for the whole run, and optionally the share of Mode S plots with a BDS 5,0 (``roll_prob``):
    (scenario, simulation, settings)."""
    import dataclasses

    from radar_fusion.tools.simulate.scenario import Leg

    scenario = sm.scenario_for_benchmark(n_aircraft, n_radars, duration_s, seed)
    legs = (Leg(duration_s + 60.0, turn_rate_dps),)
    targets = [dataclasses.replace(tg, plan=dataclasses.replace(tg.plan, legs=legs)) for tg in scenario.targets]
    rates = scenario.rates if roll_prob is None else dataclasses.replace(scenario.rates, roll_prob=roll_prob)
    scenario = dataclasses.replace(scenario, targets=targets, rates=rates)
    sim = sm.simulate(scenario, encode=False)
    return scenario, sim, config.settings_from_dict(tomllib.loads(sm.config_toml(scenario)))


@pytest.fixture(scope="module")
def case():
    return _small_case(n_aircraft=6, duration_s=40.0)


def test_steps_are_time_ordered_single_radar_and_within_periods(case):
    _scenario, sim, settings = case
    plots = bs.convert_plots(settings, sim.plot_columns)
    assert plots.t_s.size == sum(len(c) for c in sim.plot_columns)  # all inside range, all valid
    assert np.all(np.diff(plots.t_s) >= 0)
    rotation = np.array([r.rotation_period_s for r in settings.radars])
    steps = bs.time_ordered_steps(plots, rotation, settings.system.period_s)
    assert steps[0][0] == 0 and steps[-1][1] == plots.t_s.size
    assert all(a[1] == b[0] for a, b in itertools.pairwise(steps))  # contiguous cover
    period = np.floor(plots.t_s / settings.system.period_s)
    for s, e in steps:
        assert np.unique(plots.radar[s:e]).size == 1
        assert np.unique(period[s:e]).size == 1
        assert plots.t_s[e - 1] - plots.t_s[s] <= 0.25 * rotation[plots.radar[s]]


def test_plots_beyond_max_range_are_dropped_as_the_engine_does(case):
    _scenario, sim, settings = case
    batch = next(c for c in sim.plot_columns if len(c) >= 2)
    radar = next(r for r in settings.radars if r.id == batch.radar_id)
    batch.range_m[0] = radar.max_range_m + 1.0
    plots = bs.convert_plots(settings, [batch])
    assert plots.n_offered == len(batch)
    assert plots.t_s.size == len(batch) - 1
    assert batch.t_s[0] not in plots.t_s or np.count_nonzero(batch.t_s == batch.t_s[0]) > 1


def test_stonesoup_tracks_a_small_scenario(case):
    scenario, sim, settings = case
    run = bs.run_stonesoup(settings, sim.plot_columns)
    assert run.completed and run.plots_processed == run.plots_used > 0
    assert run.batches, "no track batches emitted"
    period_s = settings.system.period_s
    assert all(abs(b["t"] / period_s - round(b["t"] / period_s)) < 1e-9 for b in run.batches)
    # Independent check against the exact truth (not tools/evaluate.py): at the last
    # batches every aircraft in coverage has a confirmed track near it, and the matched
    # position error is of the order of the plot noise (50-80 m range, 0.04-0.1° azimuth).
    errors = []
    for batch in run.batches[-3:]:
        tracks = [t for t in batch["tracks"] if t["status"] == "confirmed"]
        assert tracks
        xy = np.array([[t["x_m"], t["y_m"]] for t in tracks])
        truth = sim.truth_at(np.arange(len(scenario.targets)), np.full(len(scenario.targets), batch["t"]))
        for k in range(len(scenario.targets)):
            if not truth["active"][k]:
                continue
            d = np.hypot(xy[:, 0] - truth["x_m"][k], xy[:, 1] - truth["y_m"][k]).min()
            errors.append(d)
    errors = np.asarray(errors)
    assert errors.size >= 2 * len(scenario.targets)
    assert np.mean(errors < 1000.0) >= 0.9, errors
    rms = math.sqrt(np.mean(errors[errors < 1000.0] ** 2))
    assert 5.0 < rms < 300.0, rms


def test_time_budget_stops_the_run_early(case):
    _scenario, sim, settings = case
    run = bs.run_stonesoup(settings, sim.plot_columns, time_budget_s=0.0)
    assert not run.completed
    assert 0 < run.plots_processed < run.plots_used


def test_pcrb_is_a_floor_that_falls_with_more_radars():
    floors = {}
    for radars in (1, 3):
        _scenario, sim, settings = _small_case(n_aircraft=6, n_radars=radars, duration_s=60.0, seed=5)
        floors[radars] = compare.measurement_floor(sim, settings, settle_s=20.0)
    for f in floors.values():
        assert f["pcrb_points"] > 0 and f["pcrb_pos_rms_m"] > 0.0
        # simulated noise without gross errors matches what the covariances predict (biases add a little)
        assert 0.8 * f["noise_model_rms_m"] < f["noise_rms_m"] < 1.6 * f["noise_model_rms_m"]
    # With one 4 s radar the Singer model's prediction to the period time can exceed one
    # plot's error; three radars' plots bring the floor well below it.
    assert floors[3]["pcrb_pos_rms_m"] < 0.8 * floors[3]["noise_model_rms_m"]
    assert floors[3]["pcrb_pos_rms_m"] < 0.8 * floors[1]["pcrb_pos_rms_m"]
    # the model of the bound is the filter's straight-flight model: with the IMM its quiet
    # model, the same bound as a single Singer filter of the quiet model's α and σ_m
    assert settings.tracking.filter == "imm"
    imm = settings.tracking.imm
    singer = settings.model_copy(
        update={
            "tracking": settings.tracking.model_copy(
                update={
                    "filter": "singer",
                    "alpha_per_s": imm.quiet_alpha_per_s,
                    "sigma_m_mps2": imm.quiet_sigma_m_mps2,
                }
            )
        }
    )
    same = compare.measurement_floor(sim, singer, settle_s=20.0)
    assert same["pcrb_pos_rms_m"] == floors[3]["pcrb_pos_rms_m"]
    assert 0.0 < floors[3]["pcrb_straight_pos_rms_m"] < floors[3]["noise_model_rms_m"]


def test_accuracy_job_scores_ours_and_each_radar_alone(tmp_path):
    case = {"kind": "benchmark", "aircraft": 6, "radars": 2, "duration_s": 40.0}
    info = compare.simulate_case(case, 4, str(tmp_path), settle_s=10.0)
    assert info["plots"] > 0 and info["radars"] == 2
    assert 0 < info["pcrb_pos_rms_m"] < info["noise_rms_m"]
    acc = compare.run_accuracy(str(tmp_path), settle_s=10.0)
    ours = acc["ours"]
    assert set(acc["single"]) == {"r00", "r01"}
    assert acc["best_single_radar"] in acc["single"]
    assert ours["n_displayed_tracks"] >= 6 and ours["completeness_mean"] > 0.5
    assert 10.0 < ours["pos_rms_m"] < 300.0
    # GOSPA after the settling time leaves out the track-initiation periods
    assert ours["gospa_settled_mean_m"] <= ours["gospa_mean_m"]
    same = acc["same_aircraft"]
    assert same["aircraft"] > 0 and same["fused_m"] > 0 and same["single_m"] > 0


@pytest.mark.bus
@pytest.mark.slow
def test_bench_side_by_side_end_to_end(tmp_path, capsys):
    report = tmp_path / "report"
    rc = bench.main(
        [
            "--report",
            str(report),
            "--sizes",
            "6x2",
            "--duration-s",
            "20",
            "--warmup-s",
            "6",
            "--settle-s",
            "8",
            "--no-adsb",
            "--no-accuracy",
            "--latency-speed",
            "0",
            "--bus-timeout-s",
            "60",
        ]
    )
    assert rc == 0
    for name in ("report.md", "summary.md", "results.json", "throughput.png"):
        assert (report / name).stat().st_size > 0, name
    results = json.loads((report / "results.json").read_text())
    (row,) = results["rows"]
    assert row["engine"]["plots_per_s"] > 0
    assert row["bus"]["completed"] and row["bus"]["plots_per_s"] > 0
    assert row["bus"]["plots"] == row["sim"]["plots"]
    assert row["bus"]["e2e_periods"] > 0 and row["bus"]["e2e_p50_ms"] > 0  # a figure for the report, not a goal
    assert "bus_paced" not in row  # --latency-speed 0
    assert row["reference"]["completed"] and row["reference"]["plots_per_s"] > 0
    assert row["reference"]["scores"]["n_displayed_tracks"] > 0
    assert "accuracy" not in row  # --no-accuracy
    md = (report / "report.md").read_text()
    assert "Stone Soup" in md and "| 6×2 |" in md
    assert "engine / Stone Soup" in capsys.readouterr().out


@pytest.mark.parametrize("turn_rate_dps", [0.0, 2.0])
def test_pcrb_in_turns_is_taken_at_the_times_the_truth_turns(turn_rate_dps):
    """The bound over the turning times (truth above evaluate's 1.5°/s) beside the one over
    straight flight: with every aircraft turning at 2°/s all the time, every settled time is
    a turning one (the turning bound is the whole one, no straight time); flying straight,
    there is no turning time."""
    _scenario, sim, settings = _steady_flight(6, 3, 60.0, 5, turn_rate_dps)
    f = compare.measurement_floor(sim, settings, settle_s=20.0)
    assert f["pcrb_points"] > 20
    if turn_rate_dps:
        assert f["pcrb_turning_points"] == f["pcrb_points"]
        assert f["pcrb_turning_pos_rms_m"] == pytest.approx(f["pcrb_pos_rms_m"], rel=1e-12)
        assert math.isnan(f["pcrb_straight_pos_rms_m"])
    else:
        assert f["pcrb_turning_points"] == 0 and math.isnan(f["pcrb_turning_pos_rms_m"])
        assert f["pcrb_straight_pos_rms_m"] == pytest.approx(f["pcrb_pos_rms_m"], rel=1e-12)


def _singer_van_loan(dt_s: float, alpha_per_s: float, sigma_m_mps2: float) -> tuple[np.ndarray, np.ndarray]:
    """Φ and Q of Singer's model per axis (position, velocity, acceleration; acceleration
    noise of spectral density 2 α σ_m²) by Van Loan's matrix exponential: independent of
    singer_filter's closed forms."""
    from scipy.linalg import expm

    A = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [0.0, 0.0, -alpha_per_s]])
    G = np.zeros((3, 3))
    G[2, 2] = 2.0 * alpha_per_s * sigma_m_mps2**2
    M = expm(np.block([[-A, G], [np.zeros((3, 3)), A.T]]) * dt_s)
    phi = M[3:, 3:].T
    return phi, phi @ M[:3, 3:]


@pytest.mark.parametrize("turn_rate_dps", [0.0, 2.0])
def test_pcrb_with_velocity_reports_against_a_kalman_filter_of_the_same_measurements(turn_rate_dps):
    """The bound with the aircraft's own velocity reports (BDS 5,0 and 6,0) recomputed for one
    aircraft seen by two radars, flying straight or turning: a covariance-only Kalman filter
    over its plots in time order, Φ and Q by Van Loan, each plot's position with its
    converted covariance, then, where the plot carries one, its velocity report (its age
    unknown: the simulator's mean a) as v − a·acc with the report's noise along the track
    (speed σ and the 2 kt step) and across it (speed × the track angle's σ and the 90/512°
    step), and the age's spread times the acceleration a aᵀ (a = v ω across the track in a
    turn of rate ω, nothing flying straight); then, where it carries them, its heading and
    airspeed as the air vector (the truth's velocity less the scenario's wind, known) with
    the heading's σ and step across the air vector, the IAS σ and 1 kt step times TAS/IAS
    along it (times dTAS/dIAS), the wind turned to the plane's grid by the meridian
    convergence, and the air ages' spread the same way, the aircraft's own departure from the
    wind and its heading error two unknown constants of the state (their priors the
    simulator's σ); predicted to every settled period time:
    the same RMS as measurement_floor's, with and without the reports; the reports bring it
    well below the plots' own bound."""
    from radar_fusion.geo.air_data import indicated_airspeed_mps, pressure_altitude_of_height_m, true_airspeed_mps
    from radar_fusion.geo.coordinates import mode_c_height_m, polar_to_plane
    from radar_fusion.geo.units import M_PER_FT
    from radar_fusion.tracking.initiation import unknown_velocity_var_m2ps2

    scenario, sim, settings = _steady_flight(1, 2, 90.0, 2, turn_rate_dps, roll_prob=0.5)
    settle_s = 20.0
    f = compare.measurement_floor(sim, settings, settle_s=settle_s)
    assert f["pcrb_velocity_reports"] > 5 and f["pcrb_air_reports"] > 20

    cols = [c for c in sim.plot_columns if len(c)]
    cat = lambda name: np.concatenate([getattr(c, name) for c in cols])
    radar = np.concatenate([np.full(len(c), c.radar_index) for c in cols])
    keep = (cat("target_index") == 0) & ~cat("wild")
    t, gs, heading = cat("t_s")[keep], cat("ground_speed_mps")[keep], cat("magnetic_heading_deg")[keep]
    age_s = float(np.mean(scenario.rates.dap_age_s))
    _x, _y, cov, _g, valid = polar_to_plane(
        sim.plane,
        sim.sites,
        radar[keep],
        cat("range_m")[keep],
        cat("azimuth_deg")[keep],
        mode_c_height_m(cat("fl")[keep], *settings.tracking.mode_c_met()),
        assumed_altitude_m=settings.tracking.assumed_altitude_ft * M_PER_FT,
        sigma_known_altitude_fraction=settings.tracking.mode_c_sigma_fraction(),
        return_valid=True,
    )
    assert valid.all()
    assert settings.tracking.mode_c_met() == (scenario.atmosphere.temperature_deviation_k, scenario.atmosphere.qnh_hpa)
    order = np.argsort(t, kind="stable")
    t, gs, heading, cov = t[order], gs[order], heading[order], cov[order]
    assert np.all(np.diff(t) < 60.0)  # no gap: one track throughout
    imm, rates = settings.tracking.imm, scenario.rates
    alpha, sigma_m = imm.quiet_alpha_per_s, imm.quiet_sigma_m_mps2

    atm = scenario.atmosphere

    def bound(with_velocity: bool) -> float:
        # the state: x, vx, ax, y, vy, ay, then the aircraft's own wind departure (2) and
        # heading error (radians), constant
        pos = [0, 3]
        P = np.zeros((9, 9))
        P[np.ix_(pos, pos)] = cov[0]
        P[1, 1] = P[4, 4] = unknown_velocity_var_m2ps2(settings.clustering.max_speed_mps)
        P[2, 2] = P[5, 5] = sigma_m**2
        P[6, 6] = P[7, 7] = atm.local_wind_sigma_mps**2
        P[8, 8] = np.radians(atm.heading_bias_sigma_deg) ** 2
        history = []

        def update(P: np.ndarray, H: np.ndarray, R: np.ndarray) -> np.ndarray:
            K = P @ H.T @ np.linalg.inv(H @ P @ H.T + R)
            return (np.eye(9) - K @ H) @ P

        def predict(P: np.ndarray, dt_s: float) -> np.ndarray:
            phi, q = _singer_van_loan(dt_s, alpha, sigma_m)
            F, Q = np.eye(9), np.zeros((9, 9))
            F[:6, :6], Q[:6, :6] = np.kron(np.eye(2), phi), np.kron(np.eye(2), q)
            return F @ P @ F.T + Q

        for i in range(t.size):
            if i:
                P = predict(P, t[i] - t[i - 1])
                P = update(P, np.eye(9)[pos], cov[i])
            if with_velocity and np.isfinite(gs[i]):
                H = np.zeros((2, 9))
                H[0, 1] = H[1, 4] = 1.0
                H[0, 2] = H[1, 5] = -age_s
                v = sim.truth_at(np.array([0]), np.array([t[i] - age_s]))
                u = np.array([v["vx_mps"][0], v["vy_mps"][0]])
                speed = float(np.hypot(*u))
                u /= speed
                w = np.array([u[1], -u[0]])
                var_u = rates.sigma_ground_speed_mps**2 + (2.0 * 1852.0 / 3600.0) ** 2 / 12.0
                var_w = (speed * np.radians(1.0)) ** 2 * (rates.sigma_track_angle_deg**2 + (90.0 / 512.0) ** 2 / 12.0)
                lo, hi = scenario.rates.dap_age_s
                var_w += (hi - lo) ** 2 / 12.0 * (speed * np.radians(turn_rate_dps)) ** 2
                P = update(P, H, var_u * np.outer(u, u) + var_w * np.outer(w, w))
            if with_velocity and np.isfinite(heading[i]):
                lo, hi = rates.air_age_s
                a_s = 0.5 * (lo + hi)
                H = np.zeros((2, 9))
                H[0, 1] = H[1, 4] = 1.0
                H[0, 2] = H[1, 5] = -a_s
                H[0, 6] = H[1, 7] = -1.0
                v = sim.truth_at(np.array([0]), np.array([t[i] - a_s]))
                alt_m = v["alt_ft"][0] * 0.3048
                wind_e, wind_n = scenario.atmosphere.wind_mps(np.array([alt_m]))
                lat, lon = sim.plane.to_geodetic(v["x_m"], v["y_m"])
                c = np.radians(sim.plane.to_plane_and_factors(lat, lon)[2][0])  # grid = true − c
                wind = np.array(
                    [wind_e[0] * np.cos(c) - wind_n[0] * np.sin(c), wind_n[0] * np.cos(c) + wind_e[0] * np.sin(c)]
                )
                ground = np.array([v["vx_mps"][0], v["vy_mps"][0]])
                air = ground - wind
                tas = float(np.hypot(*air))
                u, g = air / tas, ground / float(np.hypot(*ground))
                w = np.array([u[1], -u[0]])
                H[:, 8] = tas * w  # the heading error turns the air vector to the right
                dev_k = scenario.atmosphere.temperature_deviation_k
                alt_m = float(pressure_altitude_of_height_m(alt_m, dev_k, scenario.atmosphere.qnh_hpa))
                ias = float(indicated_airspeed_mps(tas, alt_m, dev_k))
                # dTAS/dIAS by a wider difference than the bound's (the same slope to 1e-6)
                slope = (true_airspeed_mps(ias + 2.0, alt_m, dev_k) - true_airspeed_mps(ias - 2.0, alt_m, dev_k)) / 4.0
                var_u = slope**2 * (rates.sigma_ias_mps**2 + (1852.0 / 3600.0) ** 2 / 12.0)
                var_w = (tas * np.radians(1.0)) ** 2 * (rates.sigma_heading_deg**2 + (90.0 / 512.0) ** 2 / 12.0)
                acc = float(np.hypot(*ground)) * np.radians(turn_rate_dps) * np.array([g[1], -g[0]])
                R = var_u * np.outer(u, u) + var_w * np.outer(w, w) + (hi - lo) ** 2 / 12.0 * np.outer(acc, acc)
                P = update(P, H, R)
            history.append(P)
        period = settings.system.period_s
        q = np.arange(math.ceil(scenario.start_t_s / period), math.floor((scenario.start_t_s + 90.0) / period) + 1)
        q = q * period
        q = q[q >= t[0] + settle_s]
        total = 0.0
        for tq in q:
            j = np.searchsorted(t, tq, side="right") - 1
            Pq = predict(history[j], tq - t[j])
            total += Pq[0, 0] + Pq[3, 3]
        return math.sqrt(total / q.size)

    # (measurement_floor takes the acceleration from the truth's velocity 1 s apart, a chord:
    # 1e-5 of the bound in the turn; without the air reports the bound would be 32.5 m)
    assert f["pcrb_pos_rms_m"] == pytest.approx(bound(False), rel=1e-6)
    assert f["pcrb_velocity_pos_rms_m"] == pytest.approx(bound(True), rel=5e-5)
    assert f["pcrb_velocity_pos_rms_m"] < 0.8 * f["pcrb_pos_rms_m"]


def test_pcrb_with_the_radars_offsets_unknown_against_a_joint_kalman_filter():
    """The bound with the radars' range and azimuth offsets unknown recomputed: two aircraft
    seen by two radars (no Mode S velocity reports, so the plots alone), one dense Kalman
    filter over both aircraft's Singer states (Φ and Q by Van Loan) and the radars' two
    offsets each (prior: the engine's [registration] prior sigmas), the plots in time order,
    each measuring its aircraft's position plus J b of its radar, J by finite differences of
    polar_to_plane; an aircraft enters at its first plot with a position variance of 1e10 m²
    (the bound puts it at the plot exactly). Predicted to every settled period time: the same
    RMS as measurement_floor's. The offsets known (a prior of a millimetre) give the plots'
    own bound back, and unknown ones raise it."""
    import dataclasses

    from radar_fusion.geo.coordinates import mode_c_height_m, polar_to_plane
    from radar_fusion.geo.units import M_PER_FT
    from radar_fusion.tracking.initiation import unknown_velocity_var_m2ps2

    scenario, _sim, settings = _steady_flight(2, 2, 60.0, 3, 0.0, roll_prob=0.0)
    scenario = dataclasses.replace(scenario, rates=dataclasses.replace(scenario.rates, heading_prob=0.0))
    sim = sm.simulate(scenario, encode=False)
    settle_s = 20.0
    f = compare.measurement_floor(sim, settings, settle_s=settle_s)
    assert f["pcrb_velocity_reports"] == 0 and f["pcrb_air_reports"] == 0
    assert f["pcrb_velocity_pos_rms_m"] == f["pcrb_pos_rms_m"]

    cols = [c for c in sim.plot_columns if len(c)]
    cat = lambda name: np.concatenate([getattr(c, name) for c in cols])
    radar = np.concatenate([np.full(len(c), c.radar_index) for c in cols])
    keep = (cat("target_index") >= 0) & ~cat("wild")
    t, tgt, rng_m, az_deg = cat("t_s")[keep], cat("target_index")[keep], cat("range_m")[keep], cat("azimuth_deg")[keep]
    radar, alt_m = radar[keep], mode_c_height_m(cat("fl")[keep], *settings.tracking.mode_c_met())
    assumed_m = settings.tracking.assumed_altitude_ft * M_PER_FT
    fraction = settings.tracking.mode_c_sigma_fraction()
    convert = lambda r, a: polar_to_plane(
        sim.plane, sim.sites, radar, r, a, alt_m, assumed_altitude_m=assumed_m, sigma_known_altitude_fraction=fraction
    )
    x, y, cov, _g = convert(rng_m, az_deg)
    # J by finite differences: a metre of range, a thousandth of a degree of azimuth
    dr, da = convert(rng_m + 1.0, az_deg)[:2], convert(rng_m, az_deg + 1e-3)[:2]
    J = np.stack([np.stack([dr[0] - x, dr[1] - y], 1), np.stack([(da[0] - x) / 1e-3, (da[1] - y) / 1e-3], 1)], 2)
    order = np.argsort(t, kind="stable")
    imm, reg = settings.tracking.imm, settings.registration
    alpha, sigma_m = imm.quiet_alpha_per_s, imm.quiet_sigma_m_mps2
    assert set(np.unique(tgt)) == {0, 1} and set(np.unique(radar)) == {0, 1}

    def joint(prior_range_m: float, prior_az_deg: float) -> float:
        n = 2 * 6 + 2 * 2
        P = np.zeros((n, n))
        P[12:, 12:] = np.diag([prior_range_m**2, prior_az_deg**2] * 2)
        last = [None, None]
        history: list[list[tuple[float, np.ndarray]]] = [[], []]
        for i in order:
            a, r = int(tgt[i]), int(radar[i])
            s = slice(6 * a, 6 * a + 6)
            if last[a] is None:
                P[s, :] = P[:, s] = 0.0
                P[s, s] = np.diag([1e10, unknown_velocity_var_m2ps2(settings.clustering.max_speed_mps), sigma_m**2] * 2)
            else:
                phi, q = _singer_van_loan(t[i] - last[a], alpha, sigma_m)
                F, Q = np.eye(n), np.zeros((n, n))
                F[s, s], Q[s, s] = np.kron(np.eye(2), phi), np.kron(np.eye(2), q)
                P = F @ P @ F.T + Q
            H = np.zeros((2, n))
            H[0, 6 * a] = H[1, 6 * a + 3] = 1.0
            H[:, 12 + 2 * r : 14 + 2 * r] = J[i]
            K = P @ H.T @ np.linalg.inv(H @ P @ H.T + cov[i])
            P = (np.eye(n) - K @ H) @ P
            P = 0.5 * (P + P.T)
            last[a] = t[i]
            history[a].append((t[i], P[s, s].copy()))
        period = settings.system.period_s
        q = np.arange(math.ceil(scenario.start_t_s / period), math.floor((scenario.start_t_s + 60.0) / period) + 1)
        q = q * period
        total, count = 0.0, 0
        for a in (0, 1):
            times = np.array([h[0] for h in history[a]])
            for tq in q[q >= times[0] + settle_s]:
                j = np.searchsorted(times, tq, side="right") - 1
                phi, qq = _singer_van_loan(tq - times[j], alpha, sigma_m)
                F, Q = np.kron(np.eye(2), phi), np.kron(np.eye(2), qq)
                Pq = F @ history[a][j][1] @ F.T + Q
                total += Pq[0, 0] + Pq[3, 3]
                count += 1
        return math.sqrt(total / count)

    unknown = joint(reg.prior_sigma_range_offset_m, reg.prior_sigma_azimuth_offset_deg)
    assert f["pcrb_offsets_pos_rms_m"] == pytest.approx(unknown, rel=1e-4)
    assert f["pcrb_offsets_pos_rms_m"] > 1.02 * f["pcrb_pos_rms_m"]
    known = joint(1e-3, 1e-6)
    assert known == pytest.approx(f["pcrb_pos_rms_m"], rel=1e-4)


@pytest.mark.parametrize("turn_rate_dps", [0.0, 2.0])
def test_the_bounds_velocity_report_model_matches_the_simulated_reports(turn_rate_dps):
    """The measurement model the bound gives each velocity report (measurement_floor: the
    truth's velocity at the mean age before the plot, noise along the track of the speed's σ
    and 2 kt step, across it of the speed times the track's σ and 90/512° step, plus the ages'
    spread times the acceleration) against the simulator's own reports: one aircraft over
    1,500 s, straight or turning at 2°/s, a report on every Mode S plot (320 and 645 of
    them), converted to the plane as the engine converts them
    (ground_velocity_to_plane). The residuals' mean is near zero and their variance along and
    across the track within 15 % of the model's."""
    from radar_fusion.geo.coordinates import flight_level_to_altitude_m, ground_velocity_to_plane

    scenario, sim, _settings = _steady_flight(1, 2, 1500.0, 2, turn_rate_dps, roll_prob=1.0)
    p = sim.all_plots()
    has = np.isfinite(p.ground_speed_mps) & (p.target_index == 0)
    assert has.sum() > 100
    rates = scenario.rates
    lo, hi = rates.dap_age_s
    t = p.t_s[has] - 0.5 * (lo + hi)
    truth = sim.truth_at(np.zeros(t.size, np.int64), t)
    vx, vy = ground_velocity_to_plane(
        sim.plane, truth["x_m"], truth["y_m"], p.ground_speed_mps[has], p.track_angle_deg[has],
        flight_level_to_altitude_m(p.fl[has]),
    )  # fmt: skip
    speed = np.hypot(truth["vx_mps"], truth["vy_mps"])
    u = np.stack([truth["vx_mps"], truth["vy_mps"]], axis=1) / speed[:, None]
    w = np.stack([u[:, 1], -u[:, 0]], axis=1)
    res = np.stack([vx - truth["vx_mps"], vy - truth["vy_mps"]], axis=1)
    along, across = np.sum(res * u, axis=1), np.sum(res * w, axis=1)
    var_along = rates.sigma_ground_speed_mps**2 + (2.0 * 1852.0 / 3600.0) ** 2 / 12.0
    accel = speed * np.radians(turn_rate_dps)  # a coordinated turn's acceleration, across the track
    var_across = (speed * np.radians(1.0)) ** 2 * (rates.sigma_track_angle_deg**2 + (90.0 / 512.0) ** 2 / 12.0)
    var_across += (hi - lo) ** 2 / 12.0 * accel**2
    assert abs(np.mean(along)) < 0.15 and abs(np.mean(across)) < 0.1 * math.sqrt(np.mean(var_across)) + 0.15
    assert np.var(along) == pytest.approx(var_along, rel=0.15)
    assert np.var(across) == pytest.approx(np.mean(var_across), rel=0.15)


@pytest.mark.parametrize("turn_rate_dps", [0.0, 2.0])
def test_the_bounds_air_report_model_matches_the_simulated_reports(turn_rate_dps):
    """The model the bound gives each BDS 6,0 report (measurement_floor: the truth's velocity
    at the mean air age, less the scenario's wind and the aircraft's own departure from it,
    as heading (plus its heading error) and true airspeed; the heading's
    σ and 90/512° step across, the IAS σ and 1 kt step along, the ages' spread times the
    acceleration) against the simulator's reports of four aircraft over 1,500 s, straight or
    turning at 2°/s: the heading residual's mean near zero and its variance within 15 % of
    the model's; the IAS residual (against the truth's TAS made indicated in the day's
    temperature) likewise."""
    from radar_fusion.geo.air_data import indicated_airspeed_mps, pressure_altitude_of_height_m

    scenario, sim, _settings = _steady_flight(4, 2, 1500.0, 2, turn_rate_dps)
    p = sim.all_plots()
    has = np.isfinite(p.magnetic_heading_deg) & (p.target_index >= 0)
    assert has.sum() > 800
    rates, atm = scenario.rates, scenario.atmosphere
    lo, hi = rates.air_age_s
    t = p.t_s[has] - 0.5 * (lo + hi)
    truth = sim.truth_at(p.target_index[has], t)
    alt_m = truth["alt_ft"] * 0.3048
    # the wind blows from wind_from_deg: towards it + 180°
    wind = atm.wind_surface_mps + atm.wind_shear_mps_per_km * alt_m / 1000.0
    to = math.radians(atm.wind_from_deg + 180.0)
    # true ground velocity: the plane's turned by the meridian convergence (as BDS 5,0's)
    lat, lon = sim.plane.to_geodetic(truth["x_m"], truth["y_m"])
    _, _, convergence_deg, k = sim.plane.to_plane_and_factors(lat, lon)
    r_m = 6_371_000.0
    speed = np.hypot(truth["vx_mps"], truth["vy_mps"]) / k * (r_m + alt_m) / r_m
    track = np.radians(np.degrees(np.arctan2(truth["vx_mps"], truth["vy_mps"])) + convergence_deg)
    # each aircraft's own departure from the wind and heading error (Atmosphere.aircraft_errors)
    own = atm.aircraft_errors(len(scenario.targets), scenario.seed)[p.target_index[has]]
    air_e = speed * np.sin(track) - wind * math.sin(to) - own[:, 0]
    air_n = speed * np.cos(track) - wind * math.cos(to) - own[:, 1]
    tas = np.hypot(air_e, air_n)
    true_heading = np.degrees(np.arctan2(air_e, air_n)) + own[:, 2]
    d_heading = (p.magnetic_heading_deg[has] - true_heading + 180.0) % 360.0 - 180.0
    # the IAS of the TAS at the pressure altitude of the truth's height on the day
    air_dev_k = atm.temperature_deviation_k
    pressure_alt_m = pressure_altitude_of_height_m(alt_m, air_dev_k, atm.qnh_hpa)
    d_ias = p.indicated_airspeed_mps[has] - indicated_airspeed_mps(tas, pressure_alt_m, air_dev_k)
    rate_rad_s = math.radians(turn_rate_dps)
    var_heading = rates.sigma_heading_deg**2 + (90.0 / 512.0) ** 2 / 12.0
    var_heading += math.degrees(rate_rad_s) ** 2 * (hi - lo) ** 2 / 12.0  # the age's spread in a turn
    var_ias = rates.sigma_ias_mps**2 + (1852.0 / 3600.0) ** 2 / 12.0
    # in a turn with wind the airspeed changes too (the turn's acceleration, across the ground
    # track, has a part along the air vector): the age's spread times it, in indicated terms
    along = speed * rate_rad_s * np.sin(track - np.arctan2(air_e, air_n))
    ias_per_tas = indicated_airspeed_mps(tas, pressure_alt_m, air_dev_k) / tas
    var_ias += float(np.mean((ias_per_tas * along) ** 2)) * (hi - lo) ** 2 / 12.0
    assert abs(np.mean(d_heading)) < 0.05 + 0.1 * math.sqrt(var_heading)
    assert np.var(d_heading) == pytest.approx(var_heading, rel=0.15)
    assert abs(np.mean(d_ias)) < 0.1
    assert np.var(d_ias) == pytest.approx(var_ias, rel=0.15)
