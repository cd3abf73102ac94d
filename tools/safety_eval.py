"""Safety-net evaluation: injected conflicts and non-conflicts, warning times, nuisance alerts.

``radar-fusion safety-eval`` builds each scenario as truth trajectories (a 4 Hz
kinematic integration: constant-rate turns, climbs and descents with an exponential
altitude capture), turns the truth into system tracks, runs :class:`SafetyNets` on them
period by period through its public API (``update`` with the period's
:class:`~radar_fusion.engine.columns.TrackColumns`), and prints per scenario and in total:

* conflict scenarios: detected or missed (an alert of the expected kind for the expected
  aircraft, issued before the truth loss of separation / area entry / MSA violation)
  and the warning time = truth loss time − time of the ``new`` alert;
* every scenario: nuisance alerts = ``new`` alerts that are not the injected conflict.

Goal (issue 5): every conflict detected, median warning ≥ 60 s, no nuisance alert.

Tracks come from one of two trackers (``--tracker``):

* ``engine`` (default; ``auto`` is the same): the project's own pipeline. Two rotating
  Mode S radars observe the truth (range σ 50/70 m, azimuth σ 0.08°/0.10°, Mode C flight
  level quantised to 100 ft), their plots go through ``Engine.ingest_plots`` / ``poll``
  (outlier gate, clustering, fusion, Singer filter, altitude filter, track management)
  and each period's TrackBatch, as the daemon publishes it, judged by the safety-nets
  process's own code (``SafetyNetsProcess.process``: decode, SafetyNets) — exactly what
  ``serve`` runs, without the bus (``--safety-nets in-process``: the nets attached to the
  engine, on its columns, as before issue 16; the figures are the same). The TrackBatch
  carries each track's Mode S address, so two tracks of one aircraft are never paired by STCA.
* ``emulated``: truth + tracker-like errors (position σ 100 m, velocity σ 5 m/s with a
  6 s lag, acceleration from that lag, flight level ±50 ft, vertical rate with an 8 s lag
  and σ 150 fpm), sent as TrackBatch-like track dicts and read back with
  ``TrackColumns.from_message``, as a consumer of the tracks topic would.
"""

from __future__ import annotations

import argparse
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from radar_fusion.config import settings_from_dict
from radar_fusion.engine import Engine, TrackColumns
from radar_fusion.geo.coordinates import RadarSites, SystemPlane, geodetic_to_polar
from radar_fusion.geo.units import FT_PER_FL, M_PER_FL, M_PER_NM
from radar_fusion.safety_nets import SafetyNets, SafetyNetsConfig, load_areas, load_msa
from radar_fusion.safety_nets.process import SafetyNetsProcess
from radar_fusion.wire import KIND_CODES, DecodedPlots

CENTER_LAT_DEG, CENTER_LON_DEG = 47.0, 8.0
PERIOD_S = 4.0
DT_S = 0.25
REPO = Path(__file__).resolve().parents[1]
AREAS_FILE = REPO / "deploy" / "areas-example.geojson"
MSA_FILE = REPO / "deploy" / "msa-example.geojson"


# --------------------------------------------------------------------------- truth


@dataclass
class Aircraft:
    """Initial state and manoeuvres; integrated by :func:`fly`."""

    name: str
    x_km: float
    y_km: float
    heading_deg: float  # true heading, clockwise from north (plane north at the centre)
    speed_mps: float
    fl: float
    turns: list[tuple[float, float, float]] = field(default_factory=list)  # (start_s, rate_dps (+ right), duration_s)
    climbs: list[tuple[float, float, float]] = field(default_factory=list)  # (start_s, rate_fpm (abs), target_fl)


@dataclass
class Truth:
    t_s: np.ndarray
    x_m: np.ndarray  # (A, T)
    y_m: np.ndarray
    vx_mps: np.ndarray
    vy_mps: np.ndarray
    ax_mps2: np.ndarray
    ay_mps2: np.ndarray
    fl: np.ndarray
    vrate_fpm: np.ndarray


def fly(aircraft: list[Aircraft], duration_s: float) -> Truth:
    """Integrate the aircraft at DT_S. Altitude capture: |rate| = min(rate, 6/min·|Δz|) (τ = 10 s)."""
    t = np.arange(0.0, duration_s + 1e-9, DT_S)
    A, T = len(aircraft), t.size
    out = {k: np.zeros((A, T)) for k in ("x", "y", "vx", "vy", "ax", "ay", "fl", "vr")}
    for a, ac in enumerate(aircraft):
        x, y, hdg, z = ac.x_km * 1000.0, ac.y_km * 1000.0, math.radians(ac.heading_deg), ac.fl * 100.0
        for k, tk in enumerate(t):
            rate_dps = sum(r for s, r, d in ac.turns if s <= tk < s + d)
            vr = 0.0
            active = [c for c in ac.climbs if c[0] <= tk]
            if active:
                _, rate, target = active[-1]
                dz = target * 100.0 - z
                vr = math.copysign(min(rate, 6.0 * abs(dz)), dz)
            w = math.radians(rate_dps)
            vx, vy = ac.speed_mps * math.sin(hdg), ac.speed_mps * math.cos(hdg)
            # d/dt (v sin h, v cos h) = (v cos h, −v sin h)·ω
            out["x"][a, k], out["y"][a, k], out["vx"][a, k], out["vy"][a, k] = x, y, vx, vy
            out["ax"][a, k], out["ay"][a, k] = vy * w, -vx * w
            out["fl"][a, k], out["vr"][a, k] = z / 100.0, vr
            x, y, hdg, z = x + vx * DT_S, y + vy * DT_S, hdg + w * DT_S, z + vr / 60.0 * DT_S
    return Truth(t, out["x"], out["y"], out["vx"], out["vy"], out["ax"], out["ay"], out["fl"], out["vr"])


@dataclass
class Scenario:
    name: str
    aircraft: list[Aircraft]
    duration_s: float
    kind: str | None  # expected alert kind, None for a non-conflict scenario
    involved: tuple[str, ...] = ()
    config: dict[str, Any] = field(default_factory=dict)


def scenarios() -> list[Scenario]:
    """The evaluation set (plane kilometres from the centre 47.0 N 8.0 E)."""
    apw = {"areas_file": str(AREAS_FILE)}
    msaw = {"msa_file": str(MSA_FILE)}
    return [
        Scenario(
            "head-on",
            [Aircraft("A", -50, 0.0, 90, 240, 200), Aircraft("B", 50, 0.5, 270, 240, 200)],
            300,
            "stca",
            ("A", "B"),
        ),
        Scenario(
            "crossing",
            [Aircraft("A", -52, 0, 90, 235, 240), Aircraft("B", 0, -50, 0, 225, 240)],
            320,
            "stca",
            ("A", "B"),
        ),
        Scenario(
            "overtaking",
            [Aircraft("A", -60, 0, 90, 250, 300), Aircraft("B", -20, 0.5, 90, 150, 300)],
            420,
            "stca",
            ("A", "B"),
        ),
        Scenario(
            "climbing through a level",
            [Aircraft("A", -45, 0, 90, 230, 110), Aircraft("B", 0, -45, 0, 230, 60, climbs=[(40, 2000, 150)])],
            300,
            "stca",
            ("A", "B"),
        ),
        Scenario(
            "turning into conflict",
            [Aircraft("A", -40, 0, 90, 230, 200), Aircraft("B", 40, -14.39, 0, 230, 200, turns=[(40, -3.0, 30)])],
            300,
            "stca",
            ("A", "B"),
        ),
        Scenario("heading into an area", [Aircraft("A", -5, -5, 60, 180, 80)], 320, "apw", ("A",), apw),
        Scenario(
            "descent towards high terrain",
            [Aircraft("A", 0, 10, 180, 150, 120, climbs=[(40, 1500, 60)])],
            320,
            "msaw",
            ("A",),
            msaw,
        ),
        # ---- no conflict
        Scenario(
            "parallel 6 NM apart",
            [Aircraft("A", -60, 0, 90, 240, 200), Aircraft("B", 60, 6 * M_PER_NM / 1000, 270, 240, 200)],
            320,
            None,
        ),
        Scenario(
            "levelling off 1,000 ft apart",
            [
                Aircraft("A", -60, 0, 90, 240, 150, climbs=[(0, 1500, 110)]),
                Aircraft("B", 60, 0.5, 270, 240, 60, climbs=[(0, 1500, 100)]),
            ],
            320,
            None,
        ),
        Scenario("over an area, above it", [Aircraft("A", -5, -5, 60, 180, 150)], 320, None, (), apw),
        Scenario("level above high terrain", [Aircraft("A", 0, 10, 180, 150, 130)], 320, None, (), msaw),
    ]


def truth_event_time(sc: Scenario, truth: Truth, plane: SystemPlane, cfg: SafetyNetsConfig) -> float | None:
    """When the injected event really happens (separation loss, area entry, MSA violation)."""
    if sc.kind == "stca":
        i, j = (next(k for k, a in enumerate(sc.aircraft) if a.name == n) for n in sc.involved)
        d = np.hypot(truth.x_m[i] - truth.x_m[j], truth.y_m[i] - truth.y_m[j])
        lost = (d < cfg.stca_h_min_nm * M_PER_NM) & (np.abs(truth.fl[i] - truth.fl[j]) * FT_PER_FL < cfg.stca_v_min_ft)
    elif sc.kind == "apw":
        if cfg.areas_file is None:
            raise ValueError(f"{sc.name}: an APW scenario needs areas_file")
        areas = load_areas(cfg.areas_file, plane)
        pts = np.column_stack([truth.x_m[0], truth.y_m[0]])
        lost = np.zeros(truth.t_s.size, bool)
        for a in areas:
            lost |= a.polygon.contains(pts) & (truth.fl[0] >= a.lower_fl) & (truth.fl[0] <= a.upper_fl)
    elif sc.kind == "msaw":
        if cfg.msa_file is None:
            raise ValueError(f"{sc.name}: an MSAW scenario needs msa_file")
        msa, _ = load_msa(cfg.msa_file, plane).lookup(np.column_stack([truth.x_m[0], truth.y_m[0]]), None)
        lost = truth.fl[0] * FT_PER_FL < msa
    else:
        return None
    return float(truth.t_s[np.argmax(lost)]) if lost.any() else None


# --------------------------------------------------------------------------- trackers


def run_emulated(truth: Truth, nets: SafetyNets, plane: SystemPlane, rng: np.random.Generator) -> tuple[list, dict]:
    """Tracks = truth + tracker-like errors (see the module docstring); track id = aircraft index + 1."""
    A = truth.x_m.shape[0]
    tau_v, tau_z = 6.0, 8.0
    vx_l, vy_l, vr_l = truth.vx_mps[:, 0].copy(), truth.vy_mps[:, 0].copy(), truth.vrate_fpm[:, 0].copy()
    alerts, step = [], int(round(PERIOD_S / DT_S))
    for k in range(truth.t_s.size):
        vx_l += (truth.vx_mps[:, k] - vx_l) * DT_S / tau_v
        vy_l += (truth.vy_mps[:, k] - vy_l) * DT_S / tau_v
        vr_l += (truth.vrate_fpm[:, k] - vr_l) * DT_S / tau_z
        if k == 0 or k % step:
            continue
        ax = (truth.vx_mps[:, k] - vx_l) / tau_v + rng.normal(0, 0.3, A)
        ay = (truth.vy_mps[:, k] - vy_l) / tau_v + rng.normal(0, 0.3, A)
        x = truth.x_m[:, k] + rng.normal(0, 100, A)
        y = truth.y_m[:, k] + rng.normal(0, 100, A)
        lat, lon = plane.to_geodetic(x, y)
        vx, vy = vx_l + rng.normal(0, 5, A), vy_l + rng.normal(0, 5, A)
        fl, vr = truth.fl[:, k] + rng.uniform(-0.5, 0.5, A), vr_l + rng.normal(0, 150, A)
        t_s = float(truth.t_s[k])
        tracks = [
            {
                "track_id": i + 1,
                "t": t_s,
                "status": "confirmed",
                "lat_deg": lat[i],
                "lon_deg": lon[i],
                "x_m": x[i],
                "y_m": y[i],
                "vx_mps": vx[i],
                "vy_mps": vy[i],
                "ax_mps2": ax[i],
                "ay_mps2": ay[i],
                "fl": fl[i],
                "vrate_fpm": vr[i],
            }
            for i in range(A)
        ]
        alerts += nets.update(t_s, TrackColumns.from_message(tracks, plane))
    return alerts, {i + 1: i for i in range(A)}


RADARS = [  # id, lat, lon, alt_m, sigma_range_m, sigma_azimuth_deg, rotation_period_s
    ("r1", 47.20, 8.30, 600.0, 50.0, 0.08, 4.0),
    ("r2", 46.60, 7.50, 1500.0, 70.0, 0.10, 5.0),
]


def run_engine(
    truth: Truth, nets: SafetyNets, plane: SystemPlane, rng: np.random.Generator, via: str = "process"
) -> tuple[list, dict]:
    """Plots from two rotating Mode S radars → the real Engine → the safety nets: ``via``
    ``process`` as the safety-nets process judges them (each period's TrackBatch bytes, as
    published, through :meth:`SafetyNetsProcess.process`, without the bus), ``in_process``
    attached to the engine (its own columns)."""
    settings = settings_from_dict(
        {
            "system": {"center_lat": CENTER_LAT_DEG, "center_lon": CENTER_LON_DEG, "period_s": PERIOD_S},
            "radars": [
                dict(
                    id=r[0],
                    lat=r[1],
                    lon=r[2],
                    alt_m=r[3],
                    sigma_range_m=r[4],
                    sigma_azimuth_deg=r[5],
                    rotation_period_s=r[6],
                )
                for r in RADARS
            ],
        }
    )
    engine = Engine(settings, safety_nets=nets if via == "in_process" else None)
    consumer = SafetyNetsProcess(settings, nets=nets) if via == "process" else None
    sites = RadarSites.from_configs(settings.radars)
    A = truth.x_m.shape[0]
    t0 = 1.7e9
    mode_s = np.arange(A, dtype=np.int64) + 0x3C0000
    events = []  # (t_end_of_scan, radar index, scan start)
    for ri, r in enumerate(RADARS):
        s = 0.0
        while s + r[6] <= truth.t_s[-1]:
            events.append((s + r[6], ri, s))
            s += r[6]
    events.sort()
    seqs = [0] * len(RADARS)
    alerts, id_map = [], {}
    for _, ri, s in events:
        rot = RADARS[ri][6]
        k0 = int(round(s / DT_S))
        lat, lon = plane.to_geodetic(truth.x_m[:, k0], truth.y_m[:, k0])
        _, az, _ = geodetic_to_polar(sites, np.full(A, ri), lat, lon, truth.fl[:, k0] * M_PER_FL)
        t_det = s + az / 360.0 * rot  # when the beam sweeps each aircraft
        k = np.clip(np.round(t_det / DT_S).astype(int), 0, truth.t_s.size - 1)
        lat, lon = plane.to_geodetic(truth.x_m[np.arange(A), k], truth.y_m[np.arange(A), k])
        fl = truth.fl[np.arange(A), k]
        rng_m, az, _ = geodetic_to_polar(sites, np.full(A, ri), lat, lon, fl * M_PER_FL)
        rng_m = rng_m + rng.normal(0, RADARS[ri][4], A)
        az = np.mod(az + rng.normal(0, RADARS[ri][5], A), 360.0)
        order = np.argsort(t_det)
        batch = DecodedPlots(
            radar_id=RADARS[ri][0],
            seq=seqs[ri],
            t_s=t0 + t_det[order],
            range_m=rng_m[order],
            azimuth_deg=az[order],
            fl=np.round(fl[order]),
            mode3a=np.full(A, -1, np.int64),
            mode_s=mode_s[order],
            track_no=np.full(A, -1, np.int64),
            kind=np.full(A, KIND_CODES["modes"], np.int8),
            roll_deg=np.full(A, np.nan),
            ground_speed_mps=np.full(A, np.nan),
            track_angle_deg=np.full(A, np.nan),
            magnetic_heading_deg=np.full(A, np.nan),
            indicated_airspeed_mps=np.full(A, np.nan),
        )
        seqs[ri] += 1
        engine.ingest_plots(batch)
        for out in engine.poll():
            for trk in out.track_batch["tracks"]:
                if trk.get("mode_s"):
                    id_map[trk["track_id"]] = int(trk["mode_s"], 16) - 0x3C0000
            judged = consumer.process(out.track_batch_bytes) if consumer is not None else out.alerts
            for a in judged:
                alerts.append({**a, "t": a["t"] - t0})
    return alerts, id_map


# --------------------------------------------------------------------------- evaluation


@dataclass
class Result:
    scenario: str
    kind: str | None
    detected: bool | None
    warning_s: float | None
    nuisance: int
    alerts: list = field(default_factory=list)


def evaluate_scenario(sc: Scenario, tracker: str, seed: int, via: str = "process") -> Result:
    plane = SystemPlane(CENTER_LAT_DEG, CENTER_LON_DEG)
    cfg = SafetyNetsConfig.model_validate({**sc.config, "load_entry_point_hooks": False})
    nets = SafetyNets(cfg, plane)
    truth = fly(sc.aircraft, sc.duration_s)
    rng = np.random.default_rng(seed)
    if tracker == "engine":
        alerts, id_map = run_engine(truth, nets, plane, rng, via)
    else:
        alerts, id_map = run_emulated(truth, nets, plane, rng)
    names = [a.name for a in sc.aircraft]
    t_event = truth_event_time(sc, truth, plane, cfg)
    detected, warning, nuisance = (None, None, 0)
    if sc.kind is not None:
        detected = False
    for a in alerts:
        if a["status"] != "new":
            continue
        who = tuple(sorted(names[id_map[t]] if t in id_map else f"?{t}" for t in a["track_ids"]))
        match = sc.kind == a["kind"] and who == tuple(sorted(sc.involved))
        if match and detected is False and t_event is not None and a["t"] <= t_event:
            detected, warning = True, t_event - a["t"]
        elif not match:
            nuisance += 1
    return Result(sc.name, sc.kind, detected, warning, nuisance, alerts)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--tracker",
        choices=("auto", "engine", "emulated"),
        default="auto",
        help="engine (= auto, the default): plots through the real Engine; emulated: truth + tracker errors",
    )
    parser.add_argument(
        "--safety-nets",
        choices=("process", "in-process"),
        default="process",
        help="with the engine: process (default, what serve runs) = each period's TrackBatch bytes judged by "
        "the safety-nets process's code (decode, SafetyNets), without the bus; in-process = the nets attached "
        "to the engine, on its own columns",
    )
    parser.add_argument("--seeds", type=int, default=3, help="noise seeds per scenario (default 3)")
    parser.add_argument("--alerts", action="store_true", help="print every new/ended alert")


def run(args: argparse.Namespace) -> int:
    tracker = "engine" if args.tracker == "auto" else args.tracker
    via = args.safety_nets.replace("-", "_")
    print(
        f"safety-net evaluation: tracker = {tracker}"
        + (
            " (real Engine on simulated Mode S plots of 2 radars)"
            if tracker == "engine"
            else " (truth + emulated tracker errors: σ 100 m, 5 m/s, ±50 ft, lagged velocity and vertical rate)"
        )
    )
    if tracker == "engine":
        print(
            "safety nets: "
            + (
                "as the safety-nets process runs them, on each period's TrackBatch as published"
                if via == "process"
                else "in process, on the engine's own columns"
            )
        )
        print(
            "(STCA gets each track's Mode S address from the engine, so duplicate tracks of one aircraft are "
            "not paired)"
        )
    print(
        f"period {PERIOD_S:.0f} s, seeds {args.seeds}, defaults: {SafetyNetsConfig().look_ahead_s:.0f} s look-ahead, "
        f"{SafetyNetsConfig().stca_h_min_nm} NM / {SafetyNetsConfig().stca_v_min_ft:.0f} ft"
    )
    header = f"{'scenario':32} {'kind':5} {'detected':>9} {'warning s (per seed)':>24} {'nuisance':>8}"
    print(header)
    print("-" * len(header))
    warnings, n_conf, n_det, n_nuis = [], 0, 0, 0
    for sc in scenarios():
        res = [evaluate_scenario(sc, tracker, seed, via) for seed in range(1, args.seeds + 1)]
        nuis = sum(r.nuisance for r in res)
        n_nuis += nuis
        if sc.kind:
            det = sum(bool(r.detected) for r in res)
            n_conf += len(res)
            n_det += det
            ws = [r.warning_s for r in res if r.warning_s is not None]
            warnings += ws
            wtxt = " ".join(f"{w:.0f}" for w in ws) or "-"
            dtxt = "detected" if det == len(res) else f"missed {len(res) - det}/{len(res)}"
        else:
            wtxt, dtxt = "-", "(none)"
        print(f"{sc.name:32} {sc.kind or '-':5} {dtxt:>9} {wtxt:>24} {nuis:>8}")
        if args.alerts:
            for r in res[:1]:
                for a in r.alerts:
                    if a["status"] in ("new", "ended"):
                        figs = {
                            k: (round(v, 1) if isinstance(v, float) else v)
                            for k, v in a.items()
                            if k not in ("v", "kind", "alert_id", "t", "track_ids", "status")
                        }
                        print(
                            f"    t={a['t']:6.0f} {a['kind']:4} #{a['alert_id']} {a['status']:6} "
                            f"tracks {a['track_ids']} {figs}"
                        )
    print("-" * len(header))
    med = float(np.median(warnings)) if warnings else float("nan")
    summary = f"median {med:.0f} s, min {min(warnings, default=float('nan')):.0f} s"
    print(f"{'total':32} {'':5} {n_det:>4}/{n_conf:<4} {summary:>24} {n_nuis:>8}")
    ok = n_det == n_conf and med >= 60.0 and n_nuis == 0
    print(f"goal (all detected, median warning >= 60 s, no nuisance): {'MET' if ok else 'NOT MET'}")
    return 0 if ok else 1


def main() -> int:  # pragma: no cover - convenience for python -m
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_arguments(p)
    return run(p.parse_args())


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
