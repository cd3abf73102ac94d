"""The engine benchmark's two jobs, each run in a fresh process: simulate a size and
pickle the engine's inputs; load them and run the engine on them, timed (or profiled).
What is measured and how: the :mod:`radar_fusion.tools.bench` docstring."""

from __future__ import annotations

import gc
import math
import multiprocessing
import os
import pickle
import time
from collections.abc import Sequence
from concurrent.futures import ProcessPoolExecutor
from typing import Any


def percentile(values: Sequence[float], q: float) -> float:
    import numpy as np

    return float(np.percentile(np.asarray(values, float), q)) if len(values) else math.nan


def rss_kb(field: str) -> int | None:
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith(field + ":"):
                    return int(line.split()[1])
    except OSError:
        pass
    return None


def reset_peak_rss() -> bool:
    try:
        with open("/proc/self/clear_refs", "w") as f:
            f.write("5")
        return True
    except OSError:
        return False


def in_fresh_process(fn, *args):
    """Run ``fn(*args)`` in a new spawned interpreter and return its result; the child
    gets the process-wide settings of every radar-fusion entry point (cli.process_settings:
    one BLAS thread, freed memory kept for reuse)."""
    from radar_fusion.cli import process_settings

    with ProcessPoolExecutor(
        max_workers=1, mp_context=multiprocessing.get_context("spawn"), initializer=process_settings
    ) as pool:
        return pool.submit(fn, *args).result()


# =========================================================================== the two child jobs


def simulate_inputs(n_aircraft: int, n_radars: int, duration_s: float, seed: int, path: str) -> dict[str, Any]:
    """Simulate one size and pickle what the engine needs (config, batches, statuses in order)."""
    from radar_fusion.tools import simulate as sim_mod

    t0 = time.perf_counter()
    scenario = sim_mod.scenario_for_benchmark(n_aircraft, n_radars, duration_s, seed)
    sim = sim_mod.simulate(scenario, encode=False)
    info = write_engine_inputs(scenario, sim, path)
    info["sim_s"] = time.perf_counter() - t0
    return info


def write_engine_inputs(scenario, sim, path: str) -> dict[str, Any]:
    """Pickle the engine's inputs of a simulation (config, decoded batches, statuses in publish order)."""
    import dataclasses

    from radar_fusion import wire
    from radar_fusion.tools import simulate as sim_mod

    radar_index = {r.id: i for i, r in enumerate(scenario.radars)}
    rotation = {r.id: float(r.rotation_period_s) for r in scenario.radars}
    # Publish order as simulate() builds it: by time, a batch before the status of the same
    # sweep, then by radar.
    # The engine process gets what the daemon would decode, without the simulation's own
    # columns (target_index, wild): they would count in the engine's peak RSS.
    decoded = [f.name for f in dataclasses.fields(wire.DecodedPlots)]
    events: list[tuple] = [
        (c.t_pub_s, 0, c.radar_index, wire.DecodedPlots(**{k: getattr(c, k) for k in decoded}))
        for c in sim.plot_columns
    ]
    events += [
        (t, 1, radar_index[rid], (rid, t, kind, sector, rotation[rid] if kind == "north" else None))
        for (t, rid, kind, sector) in sim.statuses
    ]
    events.sort(key=lambda e: e[:3])
    n_plots = sum(len(c) for c in sim.plot_columns)
    n_wild = int(sum(int(c.wild.sum()) for c in sim.plot_columns))
    data = {
        "config_toml": sim_mod.config_toml(scenario),
        "start_t_s": float(scenario.start_t_s),
        "duration_s": float(scenario.duration_s),
        "events": [(e[1], e[3]) for e in events],
        "n_plots": n_plots,
    }
    with open(path, "wb") as f:
        pickle.dump(data, f, protocol=pickle.HIGHEST_PROTOCOL)
    return {"plots": n_plots, "wild_truth": n_wild, "batches": len(sim.plot_columns), "statuses": len(sim.statuses)}


def run_engine(path: str, gate: bool, warmup_s: float, profile_top: int = 0) -> dict[str, Any]:
    """Load the pickled inputs, run the engine on them and return the figures.

    With ``profile_top`` > 0 the run is under cProfile and the result carries the profile
    (top functions by cumulative time and a per-stage summary) instead of honest timings.
    """
    import tomllib

    import numpy as np

    from radar_fusion import config, wire
    from radar_fusion.engine import Engine
    from radar_fusion.tracking.track_management import CONFIRMED

    with open(path, "rb") as f:
        data = pickle.load(f)
    raw = tomllib.loads(data["config_toml"])
    raw.setdefault("outliers", {})["enabled"] = bool(gate)
    settings = config.settings_from_dict(raw, source="benchmark scenario")
    engine = Engine(settings, safety_nets=None)
    events: list[tuple[int, Any]] = [  # (0, PlotColumns) or (1, RadarStatus)
        (0, obj)
        if kind == 0
        else (1, wire.RadarStatus(radar_id=obj[0], t=obj[1], kind=obj[2], sector=obj[3], rotation_period_s=obj[4]))
        for kind, obj in data["events"]
    ]
    del data["events"]
    gc.collect()
    gc.freeze()  # as `radar-fusion serve` does after start-up
    rss_base_kb = rss_kb("VmRSS")
    hwm_reset = reset_peak_rss()
    maxrss_before_kb = maxrss_kb()

    ingest_plots, ingest_status, poll = engine.ingest_plots, engine.ingest_status, engine.poll
    perf = time.perf_counter
    t_ingest = t_status = t_poll = 0.0
    # Keep only each period's figures: holding every TrackBatch (thousands of dicts per
    # period) would make Python's cyclic GC slower and slower and distort the timings.
    periods: list[tuple[float, float, int, int]] = []  # (t_s, processing_ms, plots, tracks)
    rss_mb: list[tuple[float, float]] = []  # (t_s, resident MB) after each period: memory bounded?

    msg_ms: list[float] = []  # TrackBatch msgpack-encoded from the columns, per period

    def keep(outs) -> None:
        for o in outs:
            t0 = perf()
            _ = o.track_batch_bytes  # what the daemon's publisher sends
            msg_ms.append((perf() - t0) * 1e3)
            periods.append((o.t_s, o.processing_s * 1e3, o.n_plots, len(o.track_columns)))
        if outs:
            rss_mb.append((outs[-1].t_s, (rss_kb("VmRSS") or 0) / 1024.0))

    profiler = None
    if profile_top:
        import cProfile

        profiler = cProfile.Profile()
        profiler.enable()
    for kind, obj in events:
        if kind == 0:
            t0 = perf()
            ingest_plots(obj)
            t1 = perf()
            outs = poll()
            t2 = perf()
            t_ingest += t1 - t0
            t_poll += t2 - t1
            if outs:
                keep(outs)
                del outs
        else:
            t0 = perf()
            ingest_status(obj)
            t_status += perf() - t0
    t0 = perf()
    outs = engine.flush()
    t_poll += perf() - t0
    keep(outs)
    t_total = t_ingest + t_status + t_poll  # engine calls only (the bookkeeping above is left out)
    if profiler is not None:
        profiler.disable()

    peak_kb = rss_kb("VmHWM") if hwm_reset else None
    peak_source = "VmHWM after clear_refs"
    if peak_kb is None:
        peak_kb, peak_source = maxrss_kb(), "ru_maxrss"
    warm_end = data["start_t_s"] + warmup_s
    steady = [p[1] for p in periods if p[0] >= warm_end]
    warm = [p[1] for p in periods if p[0] < warm_end]
    plots_per_period = [p[2] for p in periods if p[0] >= warm_end]
    tracks_per_period = [p[3] for p in periods if p[0] >= warm_end]
    status = engine.tracks.status
    n_plots = data["n_plots"]
    period_s = float(settings.system.period_s)
    rss_steady = [m for t, m in rss_mb if t >= warm_end]
    result = {
        "gate": gate,
        "plots": n_plots,
        "engine_s": t_total,
        "ingest_s": t_ingest,
        "status_s": t_status,
        "poll_s": t_poll,
        "plots_per_s": n_plots / t_total if t_total > 0 else math.nan,
        "period_s": period_s,
        "duration_s": float(data.get("duration_s", len(periods) * period_s)),
        "real_time_x": float(data.get("duration_s", len(periods) * period_s)) / t_total if t_total > 0 else math.nan,
        "ingest_us_per_plot": 1e6 * t_ingest / max(n_plots, 1),
        "ingest_share": t_ingest / t_total if t_total > 0 else math.nan,
        "periods": len(periods),
        "periods_steady": len(steady),
        "period_sum_ms": float(sum(p[1] for p in periods)),
        "steady_period_mean_ms": float(np.mean(steady)) if steady else math.nan,
        "p50_ms": percentile(steady, 50),
        "p99_ms": percentile(steady, 99),
        "msg_p50_ms": percentile(msg_ms, 50),
        "msg_p99_ms": percentile(msg_ms, 99),
        "max_ms": max(steady) if steady else math.nan,
        "warm_p50_ms": percentile(warm, 50),
        "warm_max_ms": max(warm) if warm else math.nan,
        "plots_per_period": float(np.mean(plots_per_period)) if plots_per_period else math.nan,
        "tracks_per_period": float(np.mean(tracks_per_period)) if tracks_per_period else math.nan,
        "tracks_end": len(engine.tracks),
        "confirmed_end": int((status == CONFIRMED).sum()),
        "wild_rejected": int(engine.counters.get("plots_wild", 0)),
        "plots_accepted": int(engine.counters.get("plots_accepted", 0)),
        "rss_base_mb": (rss_base_kb or 0) / 1024.0,
        "peak_rss_mb": (peak_kb or 0) / 1024.0,
        "rss_steady_first_mb": rss_steady[0] if rss_steady else math.nan,
        "rss_end_mb": rss_steady[-1] if rss_steady else math.nan,
        "peak_source": peak_source,
        "maxrss_before_mb": (maxrss_before_kb or 0) / 1024.0,
    }
    if profiler is not None:
        result["profile"] = _profile_summary(profiler, profile_top, t_total)
    return result


def maxrss_kb() -> int:
    import resource

    return int(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss)  # kB on Linux


# Stages of the pipeline, as (label, module file, function name); indented = inside the one above.
STAGES = [
    ("ingest_plots (total)", "engine.py", "ingest_plots"),
    ("  clock check (ClockCheck.observe)", "admission.py", "observe"),
    ("  admission + period buffer add (admit_plots)", "admission.py", "admit_plots"),
    ("ingest_status", "engine.py", "ingest_status"),
    ("poll + flush: period buffer pop", "period_buffer.py", "pop_period"),
    ("poll + flush: _process_period (total)", "engine.py", "_process_period"),
    ("  gate: wild-plot gate (LiveOutlierGate.filter)", "live_gate.py", "filter"),
    ("  gate: coordinate conversion (polar_to_plane)", "coordinates.py", "polar_to_plane"),
    ("  predict (all tracks to the reference time)", "engine.py", "_predict"),
    ("  associate (cluster_plots)", "clustering.py", "cluster_plots"),
    ("  fuse (_fuse, with fuse_clusters)", "engine.py", "_fuse"),
    ("  update (Kalman, two-point initiation, manoeuvres)", "engine.py", "_update"),
    ("  initiate (new tentative tracks)", "engine.py", "_initiate"),
    ("  manage (apply_life_cycle)", "engine.py", "_manage"),
    ("  output: updated tracks predicted again", "engine.py", "_predict_changed"),
    ("  TrackBatch building (TrackColumns.to_message, outside the period time)", "columns.py", "to_message"),
]


def _profile_summary(profiler, top: int, total_s: float) -> dict[str, Any]:
    import io
    import pstats

    stats = pstats.Stats(profiler)
    func_stats = stats.stats  # type: ignore[attr-defined]  # typeshed's pstats.Stats does not declare .stats
    stage_rows = []
    for label, fname, func in STAGES:
        ct, calls = 0.0, 0
        for (file, _line, name), (_cc, nc, _tt, cum, _callers) in func_stats.items():
            if name == func and os.path.basename(file) == fname:
                ct += cum
                calls += nc
        stage_rows.append((label, calls, ct))
    buf = io.StringIO()
    pstats.Stats(profiler, stream=buf).strip_dirs().sort_stats("cumulative").print_stats(top)
    prof_total = sum(tt for (_cc, _nc, tt, _ct, _c) in func_stats.values())
    return {"stages": stage_rows, "text": buf.getvalue(), "profiled_total_s": prof_total, "wall_s": total_s}
