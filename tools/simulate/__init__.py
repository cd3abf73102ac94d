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

How a radar sees the targets (beam crossings, coverage, detection, kinds, noise, biases,
wild and false plots): :mod:`.radar_model`; how the plots are published (sectors,
PlotBatch and RadarStatus messages): :mod:`.simulation`.


Targets
-------
* Synthetic flight plans (:class:`FlightPlan`): start position in the system plane,
  heading, speed and altitude, then legs of constant turn rate (positive = right,
  clockwise) and constant vertical rate. Positions are exact closed forms (a circular
  arc per turn), so the state is sampled exactly at any time.
* Real ADS-B flights (:func:`adsb_targets`, the table in
  ``../shared/data/adsb/switzerland_2018-08-01.json.gz``): the fixes jitter along track by
  ~50 m and repeat stale positions, so an interpolating truth would have acceleration
  spikes of 1-2 g between samples (DESIGN.md §4). Each flight is smoothed first
  (tools/smoothing.py: stale repeats dropped, a robust smoothing spline in a local plane,
  residual ~30 m for the inliers); the path is that spline sampled every second, with the
  velocity from its derivative, and the radars are simulated from it.

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

Python API (this module): :func:`preset`, :func:`scenario_for_benchmark`, :func:`load_scenario`,
:func:`simulate` -> :class:`Simulation`, :func:`write_outputs`; the truth it writes is read
back with :func:`radar_fusion.tools.truth.load_truth`.

Modules: :mod:`.scenario` (the scenario model), :mod:`.trajectories` (truth kinematics),
:mod:`.radar_model` (one radar's plots), :mod:`.encoding` (vectorised msgpack),
:mod:`.simulation` (:func:`simulate`, its results), :mod:`.presets` (named scenarios),
:mod:`.adsb` (real flights), :mod:`.files` (scenario TOML, plots.rec, truth.csv, config.toml).
"""

from __future__ import annotations

import argparse
import sys
import time
import tomllib
from collections.abc import Sequence
from typing import Any

from .adsb import ADSB_DEFAULT_START_T_S, ADSB_TABLE, adsb_targets
from .files import config_toml, load_scenario, parse_utc, write_outputs
from .presets import PRESETS, adsb_scenario, demo_scenario, preset, scenario_for_benchmark
from .radar_model import KIND_CMB, KIND_MODES, KIND_NAMES, KIND_PSR, KIND_SSR
from .scenario import (
    EPOCH_2018_08_01_08Z,
    FlightPlan,
    Leg,
    RadarSpec,
    Rates,
    SampledPath,
    Scenario,
    Target,
)
from .simulation import PlotColumns, Simulation, simulate
from .trajectories import KinematicState, Trajectories

__all__ = [
    "ADSB_DEFAULT_START_T_S",
    "ADSB_TABLE",
    "EPOCH_2018_08_01_08Z",
    "KIND_CMB",
    "KIND_MODES",
    "KIND_NAMES",
    "KIND_PSR",
    "KIND_SSR",
    "PRESETS",
    "FlightPlan",
    "KinematicState",
    "Leg",
    "PlotColumns",
    "RadarSpec",
    "Rates",
    "SampledPath",
    "Scenario",
    "Simulation",
    "Target",
    "Trajectories",
    "add_arguments",
    "adsb_scenario",
    "adsb_targets",
    "config_toml",
    "demo_scenario",
    "load_scenario",
    "preset",
    "run",
    "scenario_for_benchmark",
    "simulate",
    "write_outputs",
]


# =========================================================================== command line


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Arguments of ``radar-fusion simulate``."""
    parser.add_argument(
        "--scenario",
        default="demo",
        help=f"preset name ({', '.join(sorted(PRESETS))}) or a scenario TOML file (default demo)",
    )
    parser.add_argument("--out", required=True, help="output directory (plots.rec, truth.csv, config.toml)")
    parser.add_argument("--seed", type=int, default=None, help="random seed (default: the scenario's)")
    parser.add_argument("--duration-s", type=float, default=None, help="simulated duration in seconds")
    parser.add_argument("--start-utc", default=None, help="scenario start, ISO 8601 UTC (presets only)")
    parser.add_argument(
        "--aircraft", type=int, default=None, help="adsb: at most this many flights; benchmark: number of aircraft"
    )
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
                kw["start_t_s"] = parse_utc(args.start_utc)
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


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="radar-fusion simulate", description=__doc__.split("\n")[0])
    add_arguments(parser)
    return run(parser.parse_args(argv))
