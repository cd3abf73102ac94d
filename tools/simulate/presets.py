"""Named scenarios: ``demo`` (3 radars, 28 aircraft flying every kind of manoeuvre),
``adsb`` (real flights over Switzerland, 4 radars) and ``benchmark`` (scalable random
traffic), and :func:`preset` to build one by name with overrides."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from radar_fusion.geo.coordinates import SystemPlane
from radar_fusion.geo.units import M_PER_NM
from radar_fusion.tracking.singer_filter import G0_MPS2

from .adsb import ADSB_DEFAULT_START_T_S, adsb_targets
from .scenario import (
    EPOCH_2018_08_01_08Z,
    FlightPlan,
    Leg,
    RadarSpec,
    Rates,
    Scenario,
    Target,
    mode3a_codes,
    mode_s_addresses,
)

#: the steepest bank of a routine civil turn (ICAO Doc 8168: rate one or 25°, whichever is less)
MAX_BANK_DEG = 25.0


def _plan_toward(
    point_xy: tuple[float, float],
    heading_deg: float,
    speed_mps: float,
    t_cross_s: float,
    alt_ft: float,
    total_s: float,
    vrate_fpm: float = 0.0,
) -> FlightPlan:
    """A straight flight that passes ``point_xy`` at ``t_cross_s`` after the start."""
    psi = math.radians(heading_deg)
    x0 = point_xy[0] - speed_mps * t_cross_s * math.sin(psi)
    y0 = point_xy[1] - speed_mps * t_cross_s * math.cos(psi)
    return FlightPlan(x0, y0, heading_deg, speed_mps, alt_ft, (Leg(total_s, 0.0, vrate_fpm),))


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
        lat, lon = plane.to_geodetic(
            dist_m * math.sin(math.radians(bearing_deg)), dist_m * math.cos(math.radians(bearing_deg))
        )
        return float(lat), float(lon)

    rates = Rates(
        pd=0.95,
        pd_psr=0.85,
        p_mode_c=0.99,
        false_plots_per_scan=1.0,
        wild_plot_prob=0.002,
        wild_run_prob=0.0005,
        wild_run_scans=(3, 5),
    )
    radars = [
        RadarSpec(
            "app",
            *site(330.0, 45_000.0),
            alt_m=900.0,
            rotation_period_s=4.0,
            sigma_range_m=30.0,
            sigma_azimuth_deg=0.06,
            range_bias_m=40.0,
            azimuth_bias_deg=0.03,
            max_range_m=100 * M_PER_NM,
            psr=True,
            ssr=True,
            mode_s=True,
            n_sectors=16,
            sac=1,
            sic=1,
        ),
        RadarSpec(
            "east",
            *site(90.0, 70_000.0),
            alt_m=1600.0,
            rotation_period_s=8.0,
            sigma_range_m=50.0,
            sigma_azimuth_deg=0.07,
            range_bias_m=-60.0,
            azimuth_bias_deg=-0.04,
            max_range_m=200 * M_PER_NM,
            psr=True,
            ssr=True,
            mode_s=True,
            n_sectors=32,
            sac=1,
            sic=2,
        ),
        RadarSpec(
            "south",
            *site(220.0, 65_000.0),
            alt_m=1700.0,
            rotation_period_s=12.0,
            sigma_range_m=70.0,
            sigma_azimuth_deg=0.08,
            range_bias_m=25.0,
            azimuth_bias_deg=0.05,
            max_range_m=250 * M_PER_NM,
            psr=False,
            ssr=True,
            mode_s=True,
            n_sectors=32,
            sac=1,
            sic=3,
        ),
    ]
    total = duration_s + 60.0
    targets: list[Target] = []
    addr = iter(mode_s_addresses(rng, 64).tolist())
    codes = iter(mode3a_codes(rng, 64).tolist())

    def add(name: str, plan: FlightPlan, transponder: str = "modes", mode_c: bool = True, q25: bool = False) -> None:
        k = len(targets) + 1
        targets.append(
            Target(
                target_id=f"T{k:02d}",
                callsign=name if transponder == "modes" else None,
                mode_s=next(addr) if transponder == "modes" else None,
                mode3a=next(codes) if transponder != "none" else None,
                transponder=transponder,
                mode_c=mode_c and transponder != "none",
                alt_quantum_ft=25.0 if q25 else 100.0,
                plan=plan,
            )
        )

    km = 1000.0
    # straight legs
    add("SWR101", FlightPlan(-70 * km, 40 * km, 90.0, 230.0, 35000.0, (Leg(total),)), q25=True)
    add("DLH202", FlightPlan(65 * km, 25 * km, 270.0, 240.0, 37000.0, (Leg(total),)))
    add("EZY303", FlightPlan(-60 * km, -60 * km, 45.0, 210.0, 33000.0, (Leg(total),)), transponder="modeac")
    add("AFR404", FlightPlan(-20 * km, 75 * km, 170.0, 260.0, 39000.0, (Leg(total),)), q25=True)
    add("BAW505", FlightPlan(20 * km, -70 * km, 355.0, 120.0, 10000.0, (Leg(total),)))
    # turns: rate-one and 1.5 deg/s
    add("SWR606", FlightPlan(-50 * km, 10 * km, 80.0, 180.0, 24000.0, (Leg(120.0), Leg(60.0, 3.0), Leg(total - 180.0))))
    add(
        "KLM707",
        FlightPlan(40 * km, -30 * km, 0.0, 200.0, 28000.0, (Leg(90.0), Leg(60.0, -1.5), Leg(total - 150.0))),
        transponder="modeac",
    )
    add(
        "SWR808",
        FlightPlan(
            10 * km,
            45 * km,
            90.0,
            130.0,
            15000.0,
            (Leg(60.0), Leg(60.0, 3.0), Leg(60.0), Leg(60.0, 3.0), Leg(60.0), Leg(60.0, 3.0), Leg(total - 360.0)),
        ),
    )  # racetrack
    add(
        "AUA909",
        FlightPlan(
            -40 * km,
            -25 * km,
            60.0,
            220.0,
            30000.0,
            (Leg(60.0), Leg(40.0, -1.5), Leg(80.0, 1.5), Leg(40.0, -1.5), Leg(total - 220.0)),
        ),
    )
    # climbs and descents
    add(
        "EDW110",
        FlightPlan(-30 * km, -55 * km, 20.0, 150.0, 10000.0, (Leg(450.0, 0.0, 2000.0), Leg(total - 450.0))),
        q25=True,
    )
    add(
        "SWR211",
        FlightPlan(60 * km, 60 * km, 225.0, 200.0, 33000.0, (Leg(30.0), Leg(432.0, 0.0, -2500.0), Leg(total - 462.0))),
    )
    add(
        "DLH312",
        FlightPlan(
            0.0,
            -40 * km,
            300.0,
            170.0,
            12000.0,
            (Leg(60.0), Leg(120.0, 1.5, 1500.0), Leg(240.0, 0.0, 1500.0), Leg(total - 420.0)),
        ),
    )
    add(
        "EZY413",
        FlightPlan(
            50 * km,
            -5 * km,
            200.0,
            180.0,
            26000.0,
            (Leg(100.0), Leg(60.0, -3.0, -1800.0), Leg(200.0, 0.0, -1800.0), Leg(total - 360.0)),
        ),
        transponder="modeac",
    )
    # crossings: same point, same level, same time, different identity
    add("SWR514", _plan_toward((5 * km, 5 * km), 45.0, 220.0, 250.0, 31000.0, total))
    add("BAW615", _plan_toward((5 * km, 5 * km), 135.0, 210.0, 250.0, 31000.0, total))
    add("AFR716", _plan_toward((-15 * km, 20 * km), 180.0, 230.0, 350.0, 29000.0, total))
    add("RYR817", _plan_toward((-15 * km, 20 * km), 270.0, 200.0, 350.0, 29000.0, total), transponder="modeac")
    add("DLH918", _plan_toward((25 * km, -15 * km), 10.0, 240.0, 180.0, 35000.0, total))
    add("SWR019", _plan_toward((25 * km, -15 * km), 40.0, 230.0, 180.0, 35000.0, total))
    # close parallel pairs (1, 2 and 3 NM apart)
    for k, (sep_nm, hdg, x0, y0, fl_a, fl_b, sp, tr_b) in enumerate(
        (
            (1.0, 100.0, -60 * km, -15 * km, 33000.0, 34000.0, 220.0, "modes"),
            (2.0, 290.0, 60 * km, -45 * km, 36000.0, 36000.0, 235.0, "modes"),
            (3.0, 200.0, 15 * km, 70 * km, 32000.0, 32000.0, 215.0, "modeac"),
        )
    ):
        psi = math.radians(hdg)
        dx, dy = sep_nm * M_PER_NM * math.cos(psi), -sep_nm * M_PER_NM * math.sin(psi)  # perpendicular, to the right
        add(f"PAR{k}A", FlightPlan(x0, y0, hdg, sp, fl_a, (Leg(total),)))
        add(f"PAR{k}B", FlightPlan(x0 + dx, y0 + dy, hdg, sp, fl_b, (Leg(total),)), transponder=tr_b)
    # Mode A without Mode C; primary only; fast climber with 25 ft reports
    add(
        "NOC001",
        FlightPlan(-55 * km, 55 * km, 135.0, 160.0, 20000.0, (Leg(total),)),
        transponder="modeac",
        mode_c=False,
    )
    add(
        "PSR001",
        FlightPlan(30 * km, 20 * km, 250.0, 125.0, 12000.0, (Leg(200.0), Leg(60.0, 1.5), Leg(total - 260.0))),
        transponder="none",
    )
    add(
        "SWR999",
        FlightPlan(-10 * km, -65 * km, 5.0, 190.0, 16000.0, (Leg(300.0, 0.0, 2500.0), Leg(total - 300.0))),
        q25=True,
    )
    return Scenario(
        "demo",
        center[0],
        center[1],
        radars,
        targets,
        start_t_s=start_t_s,
        duration_s=duration_s,
        seed=seed,
        period_s=4.0,
        rates=rates,
    )


def adsb_scenario(
    seed: int = 1,
    duration_s: float = 1200.0,
    start_t_s: float = ADSB_DEFAULT_START_T_S,
    max_aircraft: int = 80,
    path: str | Path | None = None,
) -> Scenario:
    """Real flights over Switzerland seen by 4 radars placed around it.

    The sites are near the Swiss en-route radar sites (La Dôle, Lägern, Monte Lema,
    Weissfluhjoch, approximate positions); the radar parameters are invented.
    """
    rates = Rates(
        pd=0.95, pd_psr=0.8, p_mode_c=0.99, false_plots_per_scan=2.0, wild_plot_prob=0.002, wild_run_prob=0.0005
    )
    radars = [
        RadarSpec(
            "ladole",
            46.4253,
            6.1005,
            alt_m=1680.0,
            rotation_period_s=8.0,
            sigma_range_m=50.0,
            sigma_azimuth_deg=0.07,
            range_bias_m=35.0,
            azimuth_bias_deg=0.03,
            max_range_m=250 * M_PER_NM,
            psr=True,
            sac=2,
            sic=1,
        ),
        RadarSpec(
            "laegern",
            47.4822,
            8.3961,
            alt_m=866.0,
            rotation_period_s=4.0,
            sigma_range_m=30.0,
            sigma_azimuth_deg=0.05,
            range_bias_m=-20.0,
            azimuth_bias_deg=-0.02,
            max_range_m=150 * M_PER_NM,
            psr=True,
            n_sectors=16,
            sac=2,
            sic=2,
        ),
        RadarSpec(
            "lema",
            46.0416,
            8.8336,
            alt_m=1620.0,
            rotation_period_s=12.0,
            sigma_range_m=60.0,
            sigma_azimuth_deg=0.08,
            range_bias_m=50.0,
            azimuth_bias_deg=0.04,
            max_range_m=250 * M_PER_NM,
            psr=False,
            sac=2,
            sic=3,
        ),
        RadarSpec(
            "weissfluh",
            46.8334,
            9.8063,
            alt_m=2840.0,
            rotation_period_s=6.0,
            sigma_range_m=45.0,
            sigma_azimuth_deg=0.06,
            range_bias_m=-30.0,
            azimuth_bias_deg=0.02,
            max_range_m=200 * M_PER_NM,
            psr=False,
            sac=2,
            sic=4,
        ),
    ]
    targets = adsb_targets(start_t_s, duration_s, max_aircraft=max_aircraft, path=path, seed=seed)
    return Scenario(
        "adsb",
        46.8,
        8.2,
        radars,
        targets,
        start_t_s=start_t_s,
        duration_s=duration_s,
        seed=seed,
        period_s=4.0,
        rates=rates,
    )


def scenario_for_benchmark(
    n_aircraft: int = 1000,
    n_radars: int = 10,
    duration_s: float = 120.0,
    seed: int = 0,
    area_per_aircraft_km2: float = 250.0,
    coverage_multiplicity: float = 3.0,
) -> Scenario:
    """A scalable random scenario for benchmarks.

    Density: one aircraft per ``area_per_aircraft_km2`` (250 km²: a dense core area) in a
    disc of radius R = sqrt(n A / pi). Radars on a sunflower pattern inside the disc,
    with a range r = 1.1 R sqrt(m / n_radars) clamped to [150 km, 250 NM] so that each
    aircraft is covered by about m = ``coverage_multiplicity`` radars; when the range
    clamps, the disc is resized to R = r / (1.1 sqrt(m / n_radars)) to keep that
    coverage (denser traffic with few radars, sparser with many radars and few
    aircraft). Traffic:
    random positions and headings, FL100-FL400, 120-260 m/s; 60 % straight, 20 %
    turning (half rate or rate one, 1.5 or 3 °/s, at most a 25° bank), 20 %
    climbing/descending (1,500-2,500 ft/min); 90 % Mode S.

    Turns are flown as ICAO's rule for instrument procedures has them (Doc 8168, PANS-OPS
    Vol. I): at the chosen rate or at a 25° bank, whichever needs less bank.  In a
    coordinated turn at bank φ the rate is ω = g tan φ / v, so a 25° bank gives 2.2 °/s at
    120 m/s and 1.1 °/s at 240 m/s; rate one at 240 m/s would need a 52° bank, which
    airliners do not fly.
    """
    rng = np.random.default_rng(seed)
    radius_m = math.sqrt(n_aircraft * area_per_aircraft_km2 / math.pi) * 1000.0
    factor = 1.1 * math.sqrt(coverage_multiplicity / max(n_radars, 1))
    range_m = float(np.clip(radius_m * factor, 150_000.0, 250 * M_PER_NM))
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
        RadarSpec(
            f"r{k:02d}",
            float(lat[k]),
            float(lon[k]),
            alt_m=float(rng.uniform(200.0, 1500.0)),
            rotation_period_s=float(periods[k % periods.size]),
            sigma_range_m=float(rng.uniform(30.0, 80.0)),
            sigma_azimuth_deg=float(rng.uniform(0.04, 0.1)),
            range_bias_m=float(rng.normal(0.0, 30.0)),
            azimuth_bias_deg=float(rng.normal(0.0, 0.02)),
            max_range_m=range_m,
            psr=bool(k % 2 == 0),
            n_sectors=32,
            sac=10 + k // 200,
            sic=k % 200,
        )
        for k in range(n_radars)
    ]
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
    max_rate_dps = np.degrees(G0_MPS2 * math.tan(math.radians(MAX_BANK_DEG)) / speed)
    turn = np.sign(turn) * np.minimum(np.abs(turn), max_rate_dps)
    t_turn = rng.uniform(20.0, 60.0, n)
    vr = rng.uniform(1500.0, 2500.0, n) * np.where(fl > 250, -1.0, 1.0)
    t_climb = rng.uniform(60.0, 120.0, n)
    total = duration_s + 60.0
    modes = rng.random(n) < 0.9
    addrs = mode_s_addresses(rng, n)
    codes = mode3a_codes(rng, n)
    targets = []
    for k in range(n):
        legs: tuple[Leg, ...]
        if kind[k] < 0.6:
            legs = (Leg(total),)
        elif kind[k] < 0.8:
            legs = (Leg(float(t_first[k])), Leg(float(t_turn[k]), float(turn[k])), Leg(total))
        else:
            legs = (Leg(float(t_first[k])), Leg(float(t_climb[k]), 0.0, float(vr[k])), Leg(total))
        plan = FlightPlan(float(x0[k]), float(y0[k]), float(hdg[k]), float(speed[k]), float(fl[k] * 100), legs)
        targets.append(
            Target(
                target_id=f"A{k:05d}",
                callsign=f"BM{k:05d}" if modes[k] else None,
                mode_s=int(addrs[k]) if modes[k] else None,
                mode3a=int(codes[k]),
                transponder="modes" if modes[k] else "modeac",
                alt_quantum_ft=25.0 if modes[k] else 100.0,
                plan=plan,
            )
        )
    rates = Rates(pd=0.95, pd_psr=0.85, false_plots_per_scan=2.0, wild_plot_prob=0.001, wild_run_prob=0.0002)
    return Scenario(
        f"benchmark-{n_aircraft}x{n_radars}",
        center[0],
        center[1],
        radars,
        targets,
        start_t_s=EPOCH_2018_08_01_08Z,
        duration_s=float(duration_s),
        seed=seed,
        period_s=min(r.rotation_period_s for r in radars),
        rates=rates,
    )


def primary_high_scenario(
    seed: int = 1, duration_s: float = 300.0, start_t_s: float = EPOCH_2018_08_01_08Z
) -> Scenario:
    """High traffic seen by a primary-only radar (issue 15, item 1): the ground range of a
    primary plot depends on the height it is converted at, and at FL300-400 20-80 km out a
    guessed height puts it hundreds of metres to over a kilometre off.

    Radars: ``psr`` at the centre, primary only (no Mode C, no identity: every plot it
    makes is a ``psr`` plot), 4 s, sigma 60 m / 0.08 deg, 80 NM; ``msr`` 50 km east, a
    Mode S / SSR radar without a primary, 5 s, whose coverage is cut at 70 km so that the
    aircraft west of the primary are outside it. Pd 0.9 (secondary and primary), 3 false
    plots per scan per radar (primary clutter, uniform over the coverage), few wild plots.

    Ten aircraft at FL300-FL400 flying chords of the 20-80 km ring around the primary
    (at 190-250 m/s they stay within it for the 300 s): five Mode S and one Mode A/C
    inside both coverages (their primary plots must join the secondary track), two
    Mode S aircraft outside the SSR's coverage and two without transponder (primary
    only: each must keep one track), one of them turning, one pair on top of each other
    (FL310 under FL370, 1 NM apart) and one descending.
    """
    rng = np.random.default_rng(20_000 + seed)
    center = (47.3, 8.5)
    plane = SystemPlane(*center)
    km = 1000.0

    def site(x_m: float, y_m: float) -> tuple[float, float]:
        lat, lon = plane.to_geodetic(x_m, y_m)
        return float(lat), float(lon)

    rates = Rates(
        pd=0.9,
        pd_psr=0.9,
        p_mode_c=0.99,
        false_plots_per_scan=3.0,
        wild_plot_prob=0.001,
        wild_run_prob=0.0,
    )
    radars = [
        RadarSpec(
            "psr",
            *site(0.0, 0.0),
            alt_m=600.0,
            rotation_period_s=4.0,
            sigma_range_m=60.0,
            sigma_azimuth_deg=0.08,
            range_bias_m=20.0,
            azimuth_bias_deg=0.02,
            max_range_m=80 * M_PER_NM,
            psr=True,
            ssr=False,
            mode_s=False,
            n_sectors=16,
            sac=3,
            sic=1,
        ),
        RadarSpec(
            "msr",
            *site(50 * km, 0.0),
            alt_m=900.0,
            rotation_period_s=5.0,
            sigma_range_m=40.0,
            sigma_azimuth_deg=0.05,
            range_bias_m=-25.0,
            azimuth_bias_deg=-0.02,
            max_range_m=70 * km,
            psr=False,
            ssr=True,
            mode_s=True,
            n_sectors=32,
            sac=3,
            sic=2,
        ),
    ]
    total = duration_s + 60.0
    targets: list[Target] = []
    addr = iter(mode_s_addresses(rng, 16).tolist())
    codes = iter(mode3a_codes(rng, 16).tolist())

    def add(name: str, plan: FlightPlan, transponder: str = "modes") -> None:
        k = len(targets) + 1
        targets.append(
            Target(
                target_id=f"H{k:02d}",
                callsign=name if transponder == "modes" else None,
                mode_s=next(addr) if transponder == "modes" else None,
                mode3a=next(codes) if transponder != "none" else None,
                transponder=transponder,
                mode_c=transponder != "none",
                plan=plan,
            )
        )

    half = 0.5 * duration_s

    def chord(bearing_deg: float, r0_m: float, heading_deg: float, speed_mps: float, alt_ft: float) -> FlightPlan:
        """A straight flight crossing the point at ``r0_m`` and ``bearing_deg`` from the
        primary at mid-scenario (headings near the tangent keep it in the 20-80 km ring)."""
        b = math.radians(bearing_deg)
        return _plan_toward((r0_m * math.sin(b), r0_m * math.cos(b)), heading_deg, speed_mps, half, alt_ft, total)

    # seen by both radars: their primary plots must join the secondary track
    add("SWR301", chord(45.0, 40 * km, 135.0, 230.0, 30000.0))
    add("DLH352", chord(100.0, 55 * km, 10.0, 240.0, 35000.0))
    add("AFR383", chord(150.0, 30 * km, 240.0, 220.0, 38000.0))
    add("KLM404", chord(70.0, 65 * km, 340.0, 250.0, 40000.0))
    add("EZY321", chord(120.0, 45 * km, 210.0, 200.0, 32000.0), transponder="modeac")
    add("BAW310", chord(20.0, 50 * km, 290.0, 210.0, 31000.0))
    # primary only: west of the primary, outside the SSR's coverage (one turning) ...
    add("RYR336", chord(270.0, 40 * km, 160.0, 230.0, 33600.0))
    straight = chord(240.0, 35 * km, 330.0, 240.0, 39000.0)
    add("UAE390", dataclasses.replace(straight, legs=(Leg(100.0), Leg(60.0, -1.5), Leg(total - 160.0))))
    # ... and without transponder: 1 NM beside BAW310 (outward) at FL370, and a descent
    add("PSR370", chord(20.0, 50 * km + M_PER_NM, 290.0, 210.0, 37000.0), transponder="none")
    add(
        "PSR345",
        dataclasses.replace(
            chord(200.0, 35 * km, 290.0, 190.0, 36000.0), legs=(Leg(60.0), Leg(150.0, 0.0, -1500.0), Leg(total - 210.0))
        ),
        transponder="none",
    )
    return Scenario(
        "primary-high",
        center[0],
        center[1],
        radars,
        targets,
        start_t_s=start_t_s,
        duration_s=duration_s,
        seed=seed,
        period_s=4.0,
        rates=rates,
    )


PRESETS: dict[str, Callable[..., Scenario]] = {
    "demo": demo_scenario,
    "adsb": adsb_scenario,
    "benchmark": scenario_for_benchmark,
    "primary-high": primary_high_scenario,
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
