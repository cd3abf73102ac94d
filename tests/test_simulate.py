"""Tests of the radar simulator (tools/simulate/), each against an independent computation.

The expected values are recomputed here from first principles: beam azimuth from the
north markers, polar truth with pyproj's geodesic and the spherical slant-range formula,
straight-line and circular-arc kinematics in closed form, and the ADS-B table read with
gzip + json.
"""

from __future__ import annotations

import argparse
import dataclasses
import gzip
import itertools
import json
import math
import tomllib

import msgpack
import numpy as np
import pyproj
import pytest

from radar_fusion import config, wire
from radar_fusion.geo.coordinates import SystemPlane
from radar_fusion.geo.units import M_PER_FT, MPS_PER_KT
from radar_fusion.recording import read_recording
from radar_fusion.tools import simulate as sim
from radar_fusion.tools.truth import load_truth

GEOD = pyproj.Geod(ellps="WGS84")


# --------------------------------------------------------------------------- helpers


@pytest.fixture(scope="module")
def demo():
    return sim.simulate(sim.preset("demo", seed=3, duration_s=240.0))


def straight_scenario(
    rates: sim.Rates, n_targets: int = 60, duration_s: float = 300.0, seed: int = 5, **radar_kw
) -> sim.Scenario:
    """One radar at the centre, targets flying straight and level 60-180 km away."""
    rng = np.random.default_rng(seed)
    radar = sim.RadarSpec(
        **{
            **dict(
                id="r1",
                lat_deg=47.0,
                lon_deg=8.0,
                alt_m=500.0,
                rotation_period_s=4.0,
                sigma_range_m=60.0,
                sigma_azimuth_deg=0.08,
                range_bias_m=45.0,
                azimuth_bias_deg=-0.05,
                max_range_m=400_000.0,
                n_sectors=16,
                start_phase_deg=None,
            ),
            **radar_kw,
        }
    )
    targets = []
    for k in range(n_targets):
        r, b = rng.uniform(60_000, 180_000), rng.uniform(0, 2 * math.pi)
        plan = sim.FlightPlan(
            r * math.sin(b),
            r * math.cos(b),
            float(rng.uniform(0, 360)),
            float(rng.uniform(120, 260)),
            float(rng.integers(200, 400) * 100),
            (sim.Leg(duration_s + 60.0),),
        )
        targets.append(sim.Target(f"S{k:03d}", mode_s=0x400000 + k, mode3a=0o1000 + k, plan=plan))
    return sim.Scenario("straight", 47.0, 8.0, [radar], targets, duration_s=duration_s, seed=seed, rates=rates)


def straight_truth(scenario: sim.Scenario, target_index: np.ndarray, t_s: np.ndarray):
    """Closed-form position of straight, level flights -> (lat, lon, alt_m)."""
    plans = [scenario.targets[i].plan for i in target_index]
    tau = t_s - scenario.start_t_s
    psi = np.radians([p.heading_deg for p in plans])
    v = np.array([p.speed_mps for p in plans])
    x = np.array([p.start_x_m for p in plans]) + v * tau * np.sin(psi)
    y = np.array([p.start_y_m for p in plans]) + v * tau * np.cos(psi)
    lat, lon = SystemPlane(scenario.center_lat_deg, scenario.center_lon_deg).to_geodetic(x, y)
    return lat, lon, np.array([p.alt_ft for p in plans]) * 0.3048


def polar_truth(radar: sim.RadarSpec, lat, lon, alt_m):
    """Azimuth by the WGS-84 geodesic, slant range on the site's Gaussian sphere."""
    az, _, g = GEOD.inv(np.full(lat.size, radar.lon_deg), np.full(lat.size, radar.lat_deg), lon, lat)
    a_, e2 = GEOD.a, GEOD.es
    s = math.sin(math.radians(radar.lat_deg))
    r_earth = a_ * math.sqrt(1 - e2) / (1 - e2 * s * s)
    a, b = r_earth + radar.alt_m, r_earth + alt_m
    rho = np.sqrt((a - b) ** 2 + 4 * a * b * np.sin(g / (2 * r_earth)) ** 2)
    return rho, np.mod(az, 360.0)


def wrap180(a):
    return np.mod(np.asarray(a) + 180.0, 360.0) - 180.0


def plots_of(simulation: sim.Simulation, radar_id: str) -> sim.PlotColumns:
    cols = [c for c in simulation.plot_columns if c.radar_id == radar_id]
    cat = {
        name: np.concatenate([getattr(c, name) for c in cols])
        for name in (
            "t_s",
            "range_m",
            "azimuth_deg",
            "fl",
            "mode3a",
            "mode_s",
            "track_no",
            "kind",
            "roll_deg",
            "ground_speed_mps",
            "track_angle_deg",
            "target_index",
            "wild",
        )
    }
    return sim.PlotColumns(radar_id=radar_id, radar_index=-1, seq=-1, t_pub_s=math.nan, **cat)


# --------------------------------------------------------------------------- sweep timing


def test_plot_times_follow_the_antenna_sweep(demo):
    sc = demo.scenario
    statuses = [(t, rid, kind) for t, rid, kind, _ in demo.statuses]
    for _r, radar in enumerate(sc.radars):
        period = radar.rotation_period_s
        north = np.array([t for t, rid, kind in statuses if rid == radar.id and kind == "north"])
        assert np.allclose(np.diff(north), period, atol=1e-6)
        # phase from the north markers alone: beam azimuth is 0 at a north crossing
        phase = np.mod(-360.0 * (north[0] - sc.start_t_s) / period, 360.0)
        p = plots_of(demo, radar.id)
        beam = np.mod(360.0 * np.mod((p.t_s - sc.start_t_s) / period, 1.0) + phase, 360.0)
        resid = wrap180(p.azimuth_deg - beam)
        good = ~p.wild
        tol = abs(radar.azimuth_bias_deg) + 5.0 * radar.sigma_azimuth_deg
        assert np.all(np.abs(resid[good]) < tol), (radar.id, np.abs(resid[good]).max())

        # consecutive plots of a target: whole rotations apart, plus its angular motion
        true = (p.target_index >= 0) & good
        for tgt in np.unique(p.target_index[true]):
            m = true & (p.target_index == tgt)
            t, az = p.t_s[m], p.azimuth_deg[m]
            if t.size < 2:
                continue
            dt = np.diff(t)
            d_az = wrap180(np.diff(az))
            k = np.round((dt - period * d_az / 360.0) / period)
            assert np.all(k >= 1)
            expected = k * period + period * d_az / 360.0
            assert np.all(np.abs(dt - expected) < period * 7.0 * radar.sigma_azimuth_deg / 360.0 + 1e-6)


def test_plot_time_is_the_crossing_of_the_true_azimuth():
    sc = straight_scenario(
        sim.Rates(pd=1.0, false_plots_per_scan=0.0, wild_plot_prob=0.0, wild_run_prob=0.0),
        n_targets=10,
        duration_s=60.0,
        sigma_azimuth_deg=0.001,
        azimuth_bias_deg=0.0,
        start_phase_deg=123.0,
    )
    s = sim.simulate(sc)
    p = plots_of(s, "r1")
    lat, lon, alt = straight_truth(sc, p.target_index, p.t_s)
    _, az_true = polar_truth(sc.radars[0], lat, lon, alt)
    beam = np.mod(360.0 * (p.t_s - sc.start_t_s) / 4.0 + 123.0, 360.0)
    # float64 epoch seconds resolve 2.4e-7 s: 2e-5 degrees of beam at 90 deg/s
    assert np.max(np.abs(wrap180(beam - az_true))) < 5e-5


# --------------------------------------------------------------------------- measurement model


def test_noise_and_bias_statistics_match_the_radar():
    rates = sim.Rates(pd=1.0, false_plots_per_scan=0.0, wild_plot_prob=0.0, wild_run_prob=0.0)
    sc = straight_scenario(rates)
    s = sim.simulate(sc, encode=False)
    radar = sc.radars[0]
    p = plots_of(s, "r1")
    assert p.t_s.size > 4000 and np.all(p.target_index >= 0)
    lat, lon, alt = straight_truth(sc, p.target_index, p.t_s)
    rho, az = polar_truth(radar, lat, lon, alt)
    dr = p.range_m - rho
    da = wrap180(p.azimuth_deg - az)
    n = dr.size
    assert abs(dr.mean() - radar.range_bias_m) < 4 * radar.sigma_range_m / math.sqrt(n)
    assert abs(da.mean() - radar.azimuth_bias_deg) < 4 * radar.sigma_azimuth_deg / math.sqrt(n)
    assert dr.std() == pytest.approx(radar.sigma_range_m, rel=0.06)
    assert da.std() == pytest.approx(radar.sigma_azimuth_deg, rel=0.06)
    assert abs(np.corrcoef(dr, da)[0, 1]) < 0.06


def test_detection_rate_and_false_plot_rate():
    rates = sim.Rates(pd=0.8, false_plots_per_scan=3.0, wild_plot_prob=0.0, wild_run_prob=0.0)
    sc = straight_scenario(rates, n_targets=50, duration_s=400.0)
    s = sim.simulate(sc, encode=False)
    p = plots_of(s, "r1")
    scans = sc.duration_s / sc.radars[0].rotation_period_s
    opportunities = len(sc.targets) * scans  # every target is in coverage all the time
    n_true = int((p.target_index >= 0).sum())
    assert abs(n_true / opportunities - 0.8) < 4 * math.sqrt(0.8 * 0.2 / opportunities) + 1.0 / scans
    false = p.target_index < 0
    expected = 3.0 * scans
    assert abs(false.sum() - expected) < 4 * math.sqrt(expected) + 3
    # false plots: no identity, uniform over the coverage disc
    assert np.all(p.mode_s[false] < 0) and np.all(p.mode3a[false] < 0) and np.all(np.isnan(p.fl[false]))
    assert np.all(p.track_no[false] < 0) and np.all(p.kind[false] == wire.KIND_CODES["psr"])
    assert np.all((p.range_m[false] > 0) & (p.range_m[false] <= sc.radars[0].max_range_m))
    u = (p.range_m[false] / sc.radars[0].max_range_m) ** 2  # uniform on [~0, 1] for an area-uniform density
    assert abs(u.mean() - 0.5) < 0.1 and abs(p.azimuth_deg[false].mean() - 180.0) < 30.0


def test_wild_plots_where_injected_with_runs_and_identity_kept():
    rates = sim.Rates(
        pd=1.0,
        false_plots_per_scan=0.0,
        wild_plot_prob=0.01,
        wild_run_prob=0.01,
        wild_run_scans=(3, 5),
        wild_range_m=(3000.0, 6000.0),
        wild_azimuth_deg=(2.0, 4.0),
    )
    sc = straight_scenario(rates, n_targets=40, duration_s=300.0)
    s = sim.simulate(sc, encode=False)
    radar = sc.radars[0]
    p = plots_of(s, "r1")
    lat, lon, alt = straight_truth(sc, p.target_index, p.t_s)
    rho, az = polar_truth(radar, lat, lon, alt)
    dr = p.range_m - rho - radar.range_bias_m
    da = wrap180(p.azimuth_deg - az - radar.azimuth_bias_deg)
    gross = (np.abs(dr) > 3000.0 - 6 * radar.sigma_range_m) | (np.abs(da) > 2.0 - 6 * radar.sigma_azimuth_deg)
    assert p.wild.sum() > 50
    assert np.array_equal(gross, p.wild)
    # identity and the radar's track number are those of the aircraft
    for tgt in np.unique(p.target_index):
        m = p.target_index == tgt
        assert np.unique(p.track_no[m]).size == 1
        assert np.all(p.mode_s[m] == sc.targets[tgt].mode_s)
    # runs: several consecutive scans of one aircraft with the same gross error
    longest = 0
    for tgt in np.unique(p.target_index[p.wild]):
        m = p.target_index == tgt
        w, e = p.wild[m], np.round(dr[m] / 500.0) + 1000 * np.round(da[m] / 0.5)
        run = 1
        for i in range(1, w.size):
            run = run + 1 if (w[i] and w[i - 1] and e[i] == e[i - 1]) else 1
            longest = max(longest, run if w[i] else 0)
    assert longest >= 3


def test_clean_twin_is_the_same_simulation_without_the_gross_errors():
    """Rates.wild_errors false (bench --wild-twin): the same draws, so every plot that is not
    wild is the same plot (time, range, azimuth, identity, kind) in both runs, false plots
    included, and each wild plot differs from its twin by one gross error, in range or in
    azimuth, of a magnitude within the configured bounds."""
    import dataclasses

    rates = sim.Rates(pd=0.9, false_plots_per_scan=2.0, wild_plot_prob=0.05, wild_run_prob=0.01)
    sc = straight_scenario(rates, n_targets=30, duration_s=200.0)
    twin_sc = dataclasses.replace(sc, rates=dataclasses.replace(rates, wild_errors=False))
    wild, twin = plots_of(sim.simulate(sc, encode=False), "r1"), plots_of(sim.simulate(twin_sc, encode=False), "r1")
    assert wild.wild.sum() > 100 and not twin.wild.any()
    key = lambda p: {(round(float(t), 9), int(i)): j for j, (t, i) in enumerate(zip(p.t_s, p.target_index)) if i >= 0}
    kw, kt = key(wild), key(twin)
    assert set(kw) <= set(kt)  # the twin also has the plots a wild range error put out of coverage
    iw = np.array([kw[k] for k in kw])
    it = np.array([kt[k] for k in kw])
    good = ~wild.wild[iw]
    for col in ("range_m", "azimuth_deg", "mode_s", "mode3a", "kind", "track_no"):
        assert np.array_equal(getattr(wild, col)[iw[good]], getattr(twin, col)[it[good]]), col
    assert np.array_equal(wild.fl[iw], twin.fl[it], equal_nan=True)
    dr = wild.range_m[iw[~good]] - twin.range_m[it[~good]]
    da = wrap180(wild.azimuth_deg[iw[~good]] - twin.azimuth_deg[it[~good]])
    in_range = (np.abs(dr) >= rates.wild_range_m[0] - 1e-6) & (np.abs(dr) <= rates.wild_range_m[1] + 1e-6)
    in_az = (np.abs(da) >= rates.wild_azimuth_deg[0] - 1e-9) & (np.abs(da) <= rates.wild_azimuth_deg[1] + 1e-9)
    assert np.all((in_range & (np.abs(da) < 1e-9)) | (in_az & (dr == 0.0)))
    fw, ft = wild.target_index < 0, twin.target_index < 0  # false plots: the same ones
    assert np.array_equal(wild.range_m[fw], twin.range_m[ft]) and np.array_equal(wild.t_s[fw], twin.t_s[ft])


def test_identity_mode_c_and_report_kinds(demo):
    from radar_fusion.geo.air_data import pressure_altitude_of_height_m

    sc = demo.scenario
    atm = sc.atmosphere
    assert atm.temperature_deviation_k > 0.0
    checked = set()
    n_fl = [0, 0]
    n_high = 0
    for _r, radar in enumerate(sc.radars):
        p = plots_of(demo, radar.id)
        true = p.target_index >= 0
        kinds = {wire.KIND_CODES[k]: k for k in ("psr", "ssr", "cmb", "modes")}
        for tgt in np.unique(p.target_index[true]):
            target = sc.targets[tgt]
            m = true & (p.target_index == tgt)
            names = {kinds[k] for k in p.kind[m].tolist()}
            if target.transponder == "none":
                assert names == {"psr"} and radar.psr
                assert np.all(p.mode3a[m] < 0) and np.all(np.isnan(p.fl[m]))
                continue
            if target.transponder == "modes" and radar.mode_s:
                assert names == {"modes"} and np.all(p.mode_s[m] == target.mode_s)
            else:
                assert names <= ({"ssr", "cmb"} if radar.psr else {"ssr"}) and np.all(p.mode_s[m] < 0)
            assert np.all(p.mode3a[m] == target.mode3a)
            fl = p.fl[m]
            if not target.mode_c:
                assert np.all(np.isnan(fl))
                continue
            assert np.isfinite(fl).mean() > 0.6
            n_fl[0] += int(np.isfinite(fl).sum())
            n_fl[1] += fl.size
            q = 0.25 if (target.alt_quantum_ft == 25 and names == {"modes"}) else 1.0
            f = fl[np.isfinite(fl)]
            assert np.allclose(f / q, np.round(f / q))
            # quantisation: within half a quantum of the pressure altitude of the true height at
            # the plot time on the scenario's day (geo.air_data, checked against the hypsometric
            # equation in test_coordinates.py); ISA+5 puts it below the height
            st = demo.truth_at(np.full(m.sum(), tgt), p.t_s[m])
            dev_k = atm.temperature_deviation_k
            pressure_ft = pressure_altitude_of_height_m(st["alt_ft"] * 0.3048, dev_k, atm.qnh_hpa) / 0.3048
            err = (fl - pressure_ft / 100.0)[np.isfinite(fl)]
            assert np.all(np.abs(err) <= q / 2 + 1e-9)
            high = np.isfinite(fl) & (st["alt_ft"] > 20_000.0)
            assert np.all(fl[high] < st["alt_ft"][high] / 100.0 - 1.0)  # over 100 ft below, as on a warm day
            n_high += int(high.sum())
            checked.add(int(tgt))
    assert len(checked) >= 20 and n_high > 100
    assert n_fl[0] / n_fl[1] > 0.97  # p_mode_c = 0.99


def test_roll_reports_are_the_bank_of_the_true_turn(demo):
    """Mode S plots carry the roll angle of BDS 5,0 on ``roll_prob`` of them (0.25), others
    never; the value is the bank of a coordinated turn at the truth's heading rate, tan φ =
    v ψ̇ / g, here from the truth's velocity 1 s either side (the simulator takes 0.5 s),
    within the 1° noise and the register's 45/256° steps, signed right wing down."""
    n_modes = n_roll = 0
    err, bank = [], []
    for radar in demo.scenario.radars:
        p = plots_of(demo, radar.id)
        is_modes = p.kind == wire.KIND_CODES["modes"]
        has = np.isfinite(p.roll_deg)
        assert not (has & ~is_modes).any()  # only Mode S plots: the register is read by Mode S
        n_modes += int(is_modes.sum())
        n_roll += int(has.sum())
        roll = p.roll_deg[has]
        assert np.allclose(roll * 256.0 / 45.0, np.round(roll * 256.0 / 45.0))
        tgt, t = p.target_index[has], p.t_s[has]
        a, b = demo.truth_at(tgt, t - 1.0), demo.truth_at(tgt, t + 1.0)
        turn = wrap180(np.degrees(np.arctan2(b["vx_mps"], b["vy_mps"]) - np.arctan2(a["vx_mps"], a["vy_mps"])))
        speed = 0.5 * (np.hypot(a["vx_mps"], a["vy_mps"]) + np.hypot(b["vx_mps"], b["vy_mps"]))
        expect = np.degrees(np.arctan(speed * np.radians(turn / 2.0) / 9.80665))
        steady = a["active"] & b["active"]
        err.append((roll - expect)[steady])
        bank.append(expect[steady])
    e, bk = np.concatenate(err), np.concatenate(bank)
    assert 0.22 < n_roll / n_modes < 0.28
    turning = np.abs(bk) > 10.0
    assert turning.sum() > 20 and (bk > 10).any() and (bk < -10).any()  # turns both ways
    # 1° noise: within 4° but at a turn's start or end inside the 2 s window
    assert np.mean(np.abs(e) < 4.0) > 0.98
    assert abs(float(np.median(e[turning]))) < 0.5 and 0.7 < float(np.std(e[np.abs(e) < 4.0])) < 1.3


def geodetic_velocity_of_truth(simulation: sim.Simulation, tgt: np.ndarray, t_s: np.ndarray, half_s: float = 0.5):
    """Each target's ground speed (m/s) and true track angle (degrees) at t_s, from its
    geodetic truth alone: the WGS-84 geodesic between its positions ``half_s`` either side
    (the chord of an arc has the direction of the tangent at its middle), the distance on
    the ellipsoid scaled to the aircraft's height, (r + h) / r with a 6,371 km Earth (a
    GNSS ground speed is the antenna's, above the point under it); and whether the truth
    is active from 1.5 s before to 0.5 s after."""
    a, b = simulation.truth_at(tgt, t_s - half_s), simulation.truth_at(tgt, t_s + half_s)
    az_deg, _, dist_m = GEOD.inv(a["lon_deg"], a["lat_deg"], b["lon_deg"], b["lat_deg"])
    h_m = 0.5 * (a["alt_ft"] + b["alt_ft"]) * M_PER_FT
    active = simulation.truth_at(tgt, t_s - 1.5)["active"] & simulation.truth_at(tgt, t_s + 0.5)["active"]
    speed_mps = dist_m / (2.0 * half_s) * (6_371_000.0 + h_m) / 6_371_000.0
    return speed_mps, np.mod(az_deg, 360.0), active


def test_ground_speed_and_track_ride_with_the_roll_and_are_the_truths_velocity(demo):
    """The Mode S plots with a roll angle (the BDS 5,0 read) and only they carry the
    register's ground speed and true track angle, in its steps (2 kt, 90/512°, [0, 360)).
    Against the geodetic truth (geodetic_velocity_of_truth, true north at the aircraft, not
    the plane's y axis): in straight flight within 0.5 m/s and 0.2° of noise and the steps;
    in turns, late by the register's age, U(0.15, 1.85 s): the track lags the truth's by
    1.0 s of its heading rate on average."""
    n_dap = n_straight = 0
    e_gs, e_trk, e_turn, rate_turn = [], [], [], []
    for radar in demo.scenario.radars:
        p = plots_of(demo, radar.id)
        has = np.isfinite(p.ground_speed_mps)
        assert (np.isfinite(p.track_angle_deg) == has).all() and (np.isfinite(p.roll_deg) == has).all()
        n_dap += int(has.sum())
        gs, trk = p.ground_speed_mps[has], p.track_angle_deg[has]
        assert np.allclose(gs / MPS_PER_KT / 2.0, np.round(gs / MPS_PER_KT / 2.0), rtol=0, atol=1e-9)
        assert np.array_equal(trk * 512.0 / 90.0, np.round(trk * 512.0 / 90.0))
        assert ((trk >= 0.0) & (trk < 360.0)).all()
        tgt, t = p.target_index[has], p.t_s[has]
        speed, track, active = geodetic_velocity_of_truth(demo, tgt, t)
        # the heading rate over the register's ages (°/s), from the geodesics 1 s apart
        _, before, _ = geodetic_velocity_of_truth(demo, tgt, t - 1.0)
        rate = wrap180(track - before)
        straight = active & (np.abs(rate) < 0.02)
        n_straight += int(straight.sum())
        e_gs.append((gs - speed)[straight])
        e_trk.append(wrap180(trk - track)[straight])
        turning = active & (np.abs(rate) > 0.5)
        e_turn.append(wrap180(trk - track)[turning])
        rate_turn.append(rate[turning])
    assert n_dap > 300 and n_straight > 0.7 * n_dap
    eg, et = np.concatenate(e_gs), np.concatenate(e_trk)
    # noise 0.5 m/s and 0.2°, plus the steps' uniform rounding (1.03 m/s, 0.18°: 0.30 m/s, 0.05° RMS)
    assert 0.45 < float(np.sqrt(np.mean(eg**2))) < 0.75 and abs(float(np.mean(eg))) < 0.1
    assert 0.15 < float(np.sqrt(np.mean(et**2))) < 0.3 and abs(float(np.mean(et))) < 0.05
    assert np.abs(eg).max() < 3.0 and np.abs(et).max() < 1.0
    et_turn, r_turn = np.concatenate(e_turn), np.concatenate(rate_turn)
    assert et_turn.size > 20
    lag_s = -float(np.sum(et_turn * r_turn) / np.sum(r_turn**2))  # least squares: error = -lag x rate
    assert 0.75 < lag_s < 1.25, lag_s


def test_ground_speed_and_track_without_noise_or_age_are_the_truth_to_the_step(demo):
    """With no noise and no age the register holds the truth's velocity at the plot's time,
    rounded: within half a step (1 kt, 45/512°) of the geodetic truth (here from positions
    0.05 s either side), but for a hair; and every other column of the simulation, the roll angles
    too, is the same as with them (their draws come after all others)."""
    rates = dataclasses.replace(
        demo.scenario.rates, sigma_ground_speed_mps=0.0, sigma_track_angle_deg=0.0, dap_age_s=(0.0, 0.0)
    )
    exact = sim.simulate(dataclasses.replace(demo.scenario, rates=rates))
    for radar in demo.scenario.radars:
        p, q = plots_of(demo, radar.id), plots_of(exact, radar.id)
        for name in ("t_s", "range_m", "azimuth_deg", "fl", "mode3a", "mode_s", "kind", "roll_deg", "target_index"):
            assert getattr(p, name).tobytes() == getattr(q, name).tobytes(), name
        has = np.isfinite(q.ground_speed_mps)
        assert (np.isfinite(p.ground_speed_mps) == has).all()
        speed, track, active = geodetic_velocity_of_truth(exact, q.target_index[has], q.t_s[has], half_s=0.05)
        assert active.mean() > 0.9
        e_gs, e_trk = (q.ground_speed_mps[has] - speed)[active], wrap180(q.track_angle_deg[has] - track)[active]
        assert (np.abs(e_gs) < MPS_PER_KT + 0.01).all()
        assert (np.abs(e_trk) < 45.0 / 512.0 + 0.005).all()


# --------------------------------------------------------------------------- messages


def test_messages_ordered_sequenced_and_decodable(demo):
    msgs = demo.messages
    times = np.array([m[0] for m in msgs])
    assert np.all(np.diff(times) >= 0)
    last_seq: dict[str, int] = {}
    n_plots = 0
    batches = iter(demo.plot_columns)
    status_kinds: dict[str, list] = {}
    for t_s, key, payload in msgs:
        _, radar_id, what = key.split("/")
        if what == "plots":
            d = wire.decode_plot_batch(payload)
            assert not isinstance(d, wire.Rejection), d
            assert d.rejected == {} and d.radar_id == radar_id
            assert d.seq == last_seq.get(radar_id, -1) + 1
            last_seq[radar_id] = d.seq
            assert np.all(d.t_s <= t_s + 1e-9) and np.all(np.diff(d.t_s) >= 0)
            cols = next(batches)  # the columns are the same plots, same order
            assert cols.seq == d.seq and cols.radar_id == radar_id
            for name in ("t_s", "range_m", "azimuth_deg", "mode3a", "mode_s", "track_no", "kind"):
                assert np.array_equal(getattr(cols, name), getattr(d, name)), name
            assert np.array_equal(np.isnan(cols.fl), np.isnan(d.fl)) and np.allclose(cols.fl, d.fl, equal_nan=True)
            n_plots += len(d)
        else:
            st = wire.decode_message(payload, wire.RadarStatus)
            assert not isinstance(st, wire.Rejection), st
            assert st.t == t_s and st.radar_id == radar_id
            status_kinds.setdefault(radar_id, []).append((st.kind, st.sector, st.rotation_period_s))
    assert n_plots == sum(len(c) for c in demo.plot_columns) > 2000
    for radar in demo.scenario.radars:
        seq = status_kinds[radar.id]
        n = radar.n_sectors
        sectors = [s for _, s, _ in seq]
        assert all((b - a) % n == 1 for a, b in itertools.pairwise(sectors))
        for kind, sector, rot in seq:
            assert (kind == "north") == (sector == 0)
            assert rot == (radar.rotation_period_s if kind == "north" else None)


def test_vectorised_encoder_matches_wire_encode(demo):
    plot_msgs = [m for m in demo.messages if m[1].endswith("/plots")]
    assert len(plot_msgs) == len(demo.plot_columns)
    for (_, key, payload), cols in list(zip(plot_msgs, demo.plot_columns))[:600]:
        plots = []
        for i in range(len(cols)):
            p = {"t": float(cols.t_s[i]), "range_m": float(cols.range_m[i]), "azimuth_deg": float(cols.azimuth_deg[i])}
            if np.isfinite(cols.fl[i]):
                p["fl"] = float(cols.fl[i])
            if cols.mode3a[i] >= 0:
                p["mode3a"] = int(cols.mode3a[i])
            if cols.mode_s[i] >= 0:
                p["mode_s"] = f"{int(cols.mode_s[i]):06X}"
            if cols.track_no[i] >= 0:
                p["track_no"] = int(cols.track_no[i])
            p["kind"] = sim.KIND_NAMES[int(cols.kind[i])]
            for name in (
                "roll_deg",
                "ground_speed_mps",
                "track_angle_deg",
                "magnetic_heading_deg",
                "indicated_airspeed_mps",
            ):
                if np.isfinite(getattr(cols, name)[i]):
                    p[name] = float(getattr(cols, name)[i])
            plots.append(p)
        ref = wire.encode({"v": 1, "radar_id": cols.radar_id, "seq": cols.seq, "plots": plots})
        assert key == f"radar/{cols.radar_id}/plots"
        assert msgpack.unpackb(payload) == msgpack.unpackb(ref)
        wire.PlotBatch.model_validate(msgpack.unpackb(payload))


# --------------------------------------------------------------------------- truth and kinematics


def test_truth_velocities_match_finite_differences(demo):
    tr = demo.truth
    for tgt in np.unique(tr.target_index):
        m = tr.target_index == tgt
        t, x, y = tr.t_s[m], tr.x_m[m], tr.y_m[m]
        vx = (x[2:] - x[:-2]) / (t[2:] - t[:-2])
        vy = (y[2:] - y[:-2]) / (t[2:] - t[:-2])
        # exact except next to a change of turn rate, where the acceleration jumps and
        # the centred difference is off by up to a h / 4 (a = v omega <= 14 m/s^2, h = 1 s)
        err = np.hypot(vx - tr.vx_mps[m][1:-1], vy - tr.vy_mps[m][1:-1])
        n_legs = len(demo.scenario.targets[tgt].plan.legs)
        assert np.sum(err > 0.1) <= 2 * n_legs and np.max(err) < 3.6
        vz = (tr.alt_ft[m][2:] - tr.alt_ft[m][:-2]) / (t[2:] - t[:-2]) * 60.0
        off = np.abs(vz - tr.vrate_fpm[m][1:-1]) > 1.0  # only at the few leg changes
        assert off.sum() <= 6
        speed = np.hypot(tr.vx_mps[m], tr.vy_mps[m])
        assert np.all((speed > 119.0) & (speed < 261.0))
    # lat/lon and plane agree
    plane = SystemPlane(demo.scenario.center_lat_deg, demo.scenario.center_lon_deg)
    x, y = plane.to_plane(tr.lat_deg, tr.lon_deg)
    assert np.max(np.hypot(x - tr.x_m, y - tr.y_m)) < 0.01


def test_coordinated_turn_is_a_circular_arc():
    plan = sim.FlightPlan(
        0.0, 0.0, 90.0, 180.0, 20000.0, (sim.Leg(10.0), sim.Leg(60.0, 3.0, 1500.0), sim.Leg(30.0, -1.5))
    )
    sc = sim.Scenario(
        "turn", 47.0, 8.0, [sim.RadarSpec("r", 47.0, 8.0)], [sim.Target("T", mode_s=1, plan=plan)], duration_s=100.0
    )
    traj = sim.Trajectories(sc.targets, SystemPlane(47.0, 8.0), sc.start_t_s)
    radius = 180.0 / math.radians(3.0)
    t = sc.start_t_s + np.array([10.0, 40.0, 70.0])
    st = traj.state(np.zeros(3, int), t)
    # heading east, right turn: centre of the circle is due south of the turn entry
    cx, cy = 1800.0, -radius
    assert np.allclose(np.hypot(st.x_m - cx, st.y_m - cy), radius, atol=1e-6)
    assert np.allclose([st.x_m[-1], st.y_m[-1]], [1800.0, -2 * radius], atol=1e-6)  # 180 degrees later
    assert np.allclose([st.vx_mps[-1], st.vy_mps[-1]], [-180.0, 0.0], atol=1e-9)
    assert st.alt_m[-1] == pytest.approx(20000.0 * 0.3048 + 60.0 * 1500.0 * 0.3048 / 60.0)
    assert traj.t_end_s[0] == sc.start_t_s + 100.0 and st.active.all()


def test_demo_has_every_kind_of_flight():
    sc = sim.preset("demo")
    demo = sim.simulate(sc, encode=False)
    assert len(sc.targets) >= 24 and len(sc.radars) == 3 and 480 <= sc.duration_s <= 600
    assert all(4.0 <= r.rotation_period_s <= 12.0 for r in sc.radars)
    legs = [leg for t in sc.targets for leg in t.plan.legs]
    rates = {abs(leg.turn_rate_dps) for leg in legs}
    assert {1.5, 3.0} <= rates
    assert any(1500 <= abs(leg.vrate_fpm) <= 2500 for leg in legs if leg.vrate_fpm > 0)
    assert any(1500 <= abs(leg.vrate_fpm) <= 2500 for leg in legs if leg.vrate_fpm < 0)
    transponders = {t.transponder for t in sc.targets}
    assert {"modes", "modeac"} <= transponders
    # crossings (same point, same level) and close parallel pairs, from the truth
    tr = demo.truth
    ids = np.unique(tr.target_index)
    min_sep = {}
    for t_s in np.unique(tr.t_s):
        m = tr.t_s == t_s
        x, y, a, k = tr.x_m[m], tr.y_m[m], tr.alt_ft[m], tr.target_index[m]
        d = np.hypot(x[:, None] - x[None, :], y[:, None] - y[None, :])
        same_level = np.abs(a[:, None] - a[None, :]) < 100
        d[~same_level | np.eye(k.size, dtype=bool)] = np.inf
        for i, j in zip(*np.nonzero(d < 6 * 1852.0)):
            key = (int(k[i]), int(k[j]))
            min_sep[key] = min(min_sep.get(key, np.inf), d[i, j])
    assert sum(v < 100.0 for v in min_sep.values()) >= 3 * 2  # 3 crossings (same point, level, time), both orders
    parallel = [v for v in min_sep.values() if 0.9 * 1852.0 < v < 3.1 * 1852.0]
    assert len(parallel) >= 2 * 2  # the 2 and 3 NM same-level pairs (the 1 NM pair is 1,000 ft apart)
    assert len(ids) == len(demo.scenario.targets)


def test_adsb_preset_follows_the_table(shared_data):
    """The truth is the smoothed ADS-B path (tools/smoothing.py): near the table's fixes,
    not through them (they jitter along track by tens of metres)."""
    with gzip.open(shared_data / "adsb" / "switzerland_2018-08-01.json.gz", "rt") as f:
        rows = json.load(f)
    sc = sim.preset("adsb", duration_s=300.0, max_aircraft=15)
    assert 10 <= len(sc.targets) <= 15
    s = sim.simulate(sc)
    tr = s.truth
    table = {(r["icao24"], r["timestamp"] / 1000.0): r for r in rows}
    dist_m, dalt_ft = [], []
    for k in range(len(tr)):
        r = table.get((tr.target_id[k], tr.t_s[k]))
        if r is None or r["latitude"] is None:
            continue
        _, _, d = GEOD.inv(r["longitude"], r["latitude"], tr.lon_deg[k], tr.lat_deg[k])
        dist_m.append(d)
        dalt_ft.append(abs(tr.alt_ft[k] - r["altitude"]))
        assert tr.mode_s[k] == r["icao24"].upper()
    dist_m, dalt_ft = np.array(dist_m), np.array(dalt_ft)
    assert dist_m.size > 200
    # the fixes scatter along track by ~50 m (up to a second of timing jitter at ~230 m/s)
    assert np.median(dist_m) < 40.0 and np.mean(dist_m < 250.0) > 0.95
    # altitude: 25 ft quanta, smoothed
    assert np.median(dalt_ft) < 25.0 and np.mean(dalt_ft < 100.0) > 0.95
    assert len(sc.radars) in (3, 4) and s.truth.detectable.mean() > 0.95
    assert sum(len(c) for c in s.plot_columns) > 1000


def test_outputs_config_and_truth_round_trip(demo, tmp_path):
    paths = sim.write_outputs(demo, tmp_path)
    settings = config.load_settings(paths["config"])
    assert [r.id for r in settings.radars] == [r.id for r in demo.scenario.radars]
    assert settings.system.period_s <= settings.shortest_rotation_s
    for cfg, spec in zip(settings.radars, demo.scenario.radars):
        assert (cfg.lat, cfg.lon, cfg.rotation_period_s, cfg.sigma_range_m) == (
            spec.lat_deg,
            spec.lon_deg,
            spec.rotation_period_s,
            spec.sigma_range_m,
        )
    recs = list(read_recording(paths["recording"]))
    assert [(r.t_s, r.key, r.payload) for r in recs] == demo.messages
    truth = load_truth(paths["truth"])
    header = paths["truth"].read_text().splitlines()[0]
    assert header == "t_s,target_id,mode_s,callsign,lat_deg,lon_deg,alt_ft,x_m,y_m,vx_mps,vy_mps,vrate_fpm,detectable"
    assert len(truth) == len(demo.truth)
    assert np.array_equal(truth.target_id, demo.truth.target_id)
    assert np.allclose(truth.x_m, demo.truth.x_m, atol=0.01) and np.allclose(
        truth.lat_deg, demo.truth.lat_deg, atol=1e-7
    )
    assert np.array_equal(truth.detectable, demo.truth.detectable)
    # one truth type: the CSV reads back into what the simulator built, every column
    assert np.allclose(truth.alt_ft, demo.truth.alt_ft, atol=0.05)
    assert np.allclose(truth.vrate_fpm, demo.truth.vrate_fpm, atol=0.05)
    assert np.array_equal(truth.mode_s, demo.truth.mode_s) and np.array_equal(truth.callsign, demo.truth.callsign)
    assert np.array_equal(truth.start, demo.truth.start) and np.array_equal(truth.stop, demo.truth.stop)
    assert truth.target_ids == demo.truth.target_ids and truth.target_mode_s == demo.truth.target_mode_s
    # every demo target flies from the start, so the CSV's target order is the scenario's
    assert np.array_equal(truth.target_index, demo.truth.target_index)
    assert demo.truth.target_ids == [t.target_id for t in demo.scenario.targets]


def test_plot_columns_are_the_engines_decoded_plots(demo):
    """A simulated batch is a wire.DecodedPlots with the simulation's columns on top, so it goes
    to the engine as it is and the engine takes every plot of it."""
    from radar_fusion.engine import Engine

    raw = tomllib.loads(sim.config_toml(demo.scenario))
    raw["outliers"] = {"enabled": False}  # the live wild-plot gate would hold some back
    settings = config.settings_from_dict(raw, source="test")
    engine = Engine(settings, safety_nets=None)
    batches = [c for c in demo.plot_columns[:200] if len(c)]
    assert batches and all(isinstance(c, wire.DecodedPlots) for c in batches)
    assert sum(engine.ingest_plots(c) for c in batches) == sum(len(c) for c in batches)


def test_scenario_toml_and_command_line(tmp_path):
    text = """
[scenario]
name = "tiny"
center_lat = 46.8
center_lon = 8.2
start_utc = "2018-08-01T09:00:00Z"
duration_s = 60.0
seed = 4

[rates]
false_plots_per_scan = 0.0
wild_run_scans = [2, 3]

[[radars]]
id = "a"
lat = 47.2
lon = 8.0
alt_m = 700.0
rotation_period_s = 5.0
sigma_range_m = 40.0
sigma_azimuth_deg = 0.05
rates = { pd = 1.0 }

[[targets]]
id = "T1"
mode_s = "4B1805"
mode3a = "2341"
start_lat = 46.8
start_lon = 8.2
heading_deg = 90.0
speed_mps = 200.0
alt_ft = 30000.0
legs = [ { duration_s = 20.0 }, { duration_s = 60.0, turn_rate_dps = 3.0 } ]
"""
    path = tmp_path / "tiny.toml"
    path.write_text(text)
    sc = sim.load_scenario(path)
    assert sc.start_t_s == 1533114000.0 and sc.radars[0].rates.pd == 1.0 and sc.rates.wild_run_scans == (2, 3)
    t = sc.targets[0]
    assert t.mode_s == 0x4B1805 and t.mode3a == 0o2341 and t.transponder == "modes"
    assert abs(t.plan.start_x_m) < 1e-6 and abs(t.plan.start_y_m) < 1e-6
    s = sim.simulate(sc)
    p = plots_of(s, "a")
    assert (p.target_index == 0).sum() == 12  # pd = 1: one plot per 5 s rotation
    parser = argparse.ArgumentParser()
    sim.add_arguments(parser)
    args = parser.parse_args(["--scenario", str(path), "--out", str(tmp_path / "out"), "--duration-s", "30"])
    assert sim.run(args) == 0
    assert config.load_settings(tmp_path / "out" / "config.toml").radars[0].id == "a"
    assert (tmp_path / "out" / "plots.rec").stat().st_size > 0
    bad = tmp_path / "bad.toml"
    bad.write_text(text.replace("heading_deg", "headin_deg"))
    with pytest.raises(ValueError):
        sim.load_scenario(bad)


def test_benchmark_generator_size_and_coverage():
    for n_aircraft, n_radars in ((4000, 10), (4000, 30), (100, 3)):
        sc = sim.scenario_for_benchmark(n_aircraft, n_radars, 120.0, seed=1)
        assert len(sc.targets) == n_aircraft and len(sc.radars) == n_radars
        assert len({r.id for r in sc.radars}) == n_radars
        # each aircraft covered by ~2-5 radars on average (geodesic distance vs range)
        plane = SystemPlane(sc.center_lat_deg, sc.center_lon_deg)
        lat, lon = plane.to_geodetic([t.plan.start_x_m for t in sc.targets], [t.plan.start_y_m for t in sc.targets])
        seen = np.zeros(n_aircraft)
        for r in sc.radars:
            _, _, d = GEOD.inv(np.full(n_aircraft, r.lon_deg), np.full(n_aircraft, r.lat_deg), lon, lat)
            seen += d < r.max_range_m
        assert 2.0 <= seen.mean() <= 5.0 and (seen == 0).mean() < 0.05
    s = sim.simulate(sim.scenario_for_benchmark(300, 3, 24.0, seed=2), encode=False)
    n = sum(len(c) for c in s.plot_columns)
    assert 300 * 3 * 24.0 / 12.0 < n < 300 * 3 * 24.0 / 4.0 * 1.2
    assert s.messages == [] and len(s.statuses) == len(s.plot_columns)
