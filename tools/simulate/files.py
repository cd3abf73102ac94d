"""The simulator's files: the scenario TOML it reads (format in the
:mod:`radar_fusion.tools.simulate` docstring) and what it writes, ``plots.rec`` (the
recording), ``truth.csv`` (:func:`radar_fusion.tools.truth.write_truth`) and
``config.toml`` (a daemon configuration for the scenario)."""

from __future__ import annotations

import dataclasses
import datetime as _dt
import json
import tomllib
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from radar_fusion.geo.coordinates import SystemPlane
from radar_fusion.recording import RecordingWriter

from ..truth import write_truth
from .adsb import adsb_targets
from .scenario import EPOCH_2018_08_01_08Z, FlightPlan, Leg, RadarSpec, Rates, Scenario, Target

if TYPE_CHECKING:
    from .simulation import Simulation


# =========================================================================== outputs


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
    knows them (site, accuracy, rotation; not their biases, which it cannot know), and the
    day's temperature and QNH (an ANSP's met office gives them; Mode C is pressure altitude)."""
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
        "",
        "[tracking]",
        "# the simulated day's temperature and QNH, as a met office gives them: Mode C is pressure altitude",
        f"temperature_deviation_k = {_toml_value(float(scenario.atmosphere.temperature_deviation_k))}",
        f"qnh_hpa = {_toml_value(float(scenario.atmosphere.qnh_hpa))}",
    ]
    for spec in scenario.radars:
        lines += ["", "[[radars]]"]
        items = [
            ("id", spec.id),
            ("lat", float(spec.lat_deg)),
            ("lon", float(spec.lon_deg)),
            ("alt_m", float(spec.alt_m)),
            ("sigma_range_m", float(spec.sigma_range_m)),
            ("sigma_azimuth_deg", float(spec.sigma_azimuth_deg)),
            ("rotation_period_s", float(spec.rotation_period_s)),
            ("max_range_m", float(spec.max_range_m)),
            # what the daemon is told of the radar's detection (the simulated rates)
            ("pd", float((spec.rates or scenario.rates).pd if spec.ssr else (spec.rates or scenario.rates).pd_psr)),
        ]
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


# =========================================================================== TOML scenarios


def parse_utc(s: str) -> float:
    return _dt.datetime.fromisoformat(s.replace("Z", "+00:00")).astimezone(_dt.UTC).timestamp()


def _rates_from(d: dict[str, Any], base: Rates) -> Rates:
    known = {f.name for f in dataclasses.fields(Rates)}
    unknown = set(d) - known
    if unknown:
        raise ValueError(f"unknown rates fields {sorted(unknown)}")
    vals: dict[str, Any] = {k: (tuple(v) if isinstance(v, list) else v) for k, v in d.items()}
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
        start = parse_utc(str(sc["start_utc"]))
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
                px, py = plane.to_plane(float(td.pop("start_lat")), float(td.pop("start_lon")))
                x0, y0 = float(px), float(py)
            else:
                x0, y0 = float(td.pop("start_x_m")), float(td.pop("start_y_m"))
            legs = tuple(Leg(**leg) for leg in td.pop("legs"))
            plan = FlightPlan(
                x0,
                y0,
                float(td.pop("heading_deg")),
                float(td.pop("speed_mps")),
                float(td.pop("alt_ft")),
                legs,
                float(td.pop("t_offset_s", 0.0)),
            )
            mode_s = td.pop("mode_s", None)
            mode3a = td.pop("mode3a", None)
            mode_s = int(mode_s, 16) if isinstance(mode_s, str) else mode_s
            mode3a = int(mode3a, 8) if isinstance(mode3a, str) else mode3a
            default_tr = "modes" if mode_s is not None else ("modeac" if mode3a is not None else "none")
            targets.append(
                Target(
                    target_id=str(td.pop("id")),
                    callsign=td.pop("callsign", None),
                    mode_s=mode_s,
                    mode3a=mode3a,
                    transponder=td.pop("transponder", default_tr),
                    mode_c=bool(td.pop("mode_c", True)),
                    alt_quantum_ft=float(td.pop("alt_quantum_ft", 100.0)),
                    plan=plan,
                )
            )
        except (KeyError, TypeError) as exc:
            raise ValueError(f"{path}: targets[{i}]: {exc}") from None
        if td:
            raise ValueError(f"{path}: targets[{i}]: unknown fields {sorted(td)}")
    if "adsb" in data:
        ad = data["adsb"]
        targets += adsb_targets(
            start, duration, max_aircraft=int(ad.get("max_aircraft", 80)), path=ad.get("path"), seed=seed
        )
    if not radars:
        raise ValueError(f"{path}: no [[radars]]")
    period = sc.get("period_s")
    return Scenario(
        str(sc.get("name", path.stem)),
        center[0],
        center[1],
        radars,
        targets,
        start_t_s=start,
        duration_s=duration,
        seed=seed,
        period_s=None if period is None else float(period),
        rates=rates,
    )
