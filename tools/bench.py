"""Benchmark of the fusion engine alone (issues 3 and 4; DESIGN.md §4). A command, never a test.

``radar-fusion bench`` simulates the benchmark scenario
(:func:`radar_fusion.tools.simulate.scenario_for_benchmark`) for each size
``AIRCRAFTxRADARS`` and drives :class:`radar_fusion.engine.Engine` with its plot batches
and radar status messages in publish order (``ingest_plots`` then ``poll`` per batch,
``ingest_status`` per status, ``flush`` at the end), exactly as the daemon does, without a
bus. Safety nets are off. Each size is run with the live wild-plot gate on (the default
configuration) and off (issue 4).

What is measured and how:

* Only the engine calls are timed (``time.perf_counter`` around each ``ingest_plots``,
  ``ingest_status``, ``poll`` and ``flush``). Simulating the scenario, building the
  decoded batches and the ``RadarStatus`` objects happen before the clock starts.
* plots/s = plots offered to the engine / total engine time.
* Period time p50 / p99: ``PeriodOutput.processing_s`` (the engine's own timing of one
  closed period: prediction, clustering, fusion, filter update, life cycle, TrackBatch
  building). Periods that end in the first ``--warmup-s`` seconds of the scenario (track
  initiation) are left out of the percentiles and reported separately ("warm-up max").
* ingest µs/plot = time in ``ingest_plots`` / plots; ingest share = that time / engine time.
* Peak memory: every engine run is a fresh process (multiprocessing, spawn). The
  scenario is simulated in another fresh process and handed over in a pickle, so the
  engine process holds only the interpreter, the decoded input batches and the engine.
  After loading the input the process resets its peak-RSS mark (Linux
  ``/proc/self/clear_refs`` = 5) and reads ``VmHWM`` after the run: "peak RSS" is the
  process's peak resident memory during the engine run (input batches included; the
  "base" figure is the resident memory just before the run). Without
  ``clear_refs`` it falls back to ``getrusage(RUSAGE_SELF).ru_maxrss``.

Goals (issue 3): ≥ 100,000 plots/s at 4,000 aircraft × 10 radars; period p99 < 100 ms
at 4,000 aircraft; cost growing no faster than about linearly with the number of
aircraft. Figures from a shared machine are noisy: compare ratios from one run.

    radar-fusion bench [--sizes 100x3,1000x10] [--duration-s 120] [--seed 0]
                       [--no-gate-compare] [--out reports/bench.md] [--quick]
                       [--profile 4000x10]

Side by side with Stone Soup (issue 7): ``radar-fusion bench --report reports/bench``
(``--compare`` prints without writing) answers "more accurate? faster?" in one run. Per
case (each size, then real ADS-B flights over Switzerland, simulate's ``adsb`` preset),
in fresh processes: (a) the engine as above; (b) the whole daemon (``radar-fusion
serve``, its own process) over Zenoh fed by the replay tool at maximum speed (plots/s),
and again paced at ``--latency-speed`` (end-to-end latency p50/p99 from the input that
closes a period to its TrackBatch at a subscriber); (c) Stone Soup's GNN tracker on the
same plots (:mod:`radar_fusion.tools.baseline_stonesoup`; sizes whose estimated run time
exceeds ``--reference-budget-s`` are skipped and the estimate is shown); then accuracy
(position and velocity RMS, GOSPA, continuity, false tracks) of ours, Stone Soup and the
best single radar (the engine on one radar's plots alone), with the plots' measurement
noise and the posterior Cramér–Rao bound as the floor. The report directory gets
``report.md``, ``summary.md`` (the README table), ``results.json`` and PNGs; rerunning the
command refreshes all of it. See :data:`COMPARE_NOTES` for the exact definitions.
"""

from __future__ import annotations

import argparse
import datetime as _dt
import gc
import math
import multiprocessing
import os
import pickle
import platform
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any, Optional, Sequence

DEFAULT_SIZES = [(a, r) for a in (100, 1000, 4000) for r in (3, 10, 30)]
QUICK_SIZES = [(100, 3), (1000, 10)]
GOAL_PLOTS_PER_S = 100_000.0
GOAL_PLOTS_SIZE = (4000, 10)
GOAL_P99_MS = 100.0
GOAL_P99_AIRCRAFT = 4000


# =========================================================================== helpers


def parse_sizes(text: str) -> list[tuple[int, int]]:
    """``"100x3,1000x10"`` -> [(100, 3), (1000, 10)]; ``"none"`` -> [] (side by side: ADS-B case only)."""
    if text.strip().lower() == "none":
        return []
    sizes = []
    for part in text.split(","):
        part = part.strip().lower()
        if not part:
            continue
        try:
            a, r = part.split("x")
            size = (int(a), int(r))
        except ValueError:
            raise argparse.ArgumentTypeError(f"bad size {part!r}: expected AIRCRAFTxRADARS, e.g. 1000x10") from None
        if size[0] < 1 or not 1 <= size[1] <= 64:
            raise argparse.ArgumentTypeError(f"bad size {part!r}: need ≥ 1 aircraft and 1-64 radars")
        sizes.append(size)
    if not sizes:
        raise argparse.ArgumentTypeError("no sizes given")
    return sizes


def _percentile(values: Sequence[float], q: float) -> float:
    import numpy as np

    return float(np.percentile(np.asarray(values, float), q)) if len(values) else math.nan


def _rss_kb(field: str) -> Optional[int]:
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith(field + ":"):
                    return int(line.split()[1])
    except OSError:
        pass
    return None


def _reset_peak_rss() -> bool:
    try:
        with open("/proc/self/clear_refs", "w") as f:
            f.write("5")
        return True
    except OSError:
        return False


def _in_fresh_process(fn, *args):
    """Run ``fn(*args)`` in a new spawned interpreter and return its result."""
    with ProcessPoolExecutor(max_workers=1, mp_context=multiprocessing.get_context("spawn")) as pool:
        return pool.submit(fn, *args).result()


# =========================================================================== the two child jobs


def simulate_inputs(n_aircraft: int, n_radars: int, duration_s: float, seed: int, path: str) -> dict[str, Any]:
    """Simulate one size and pickle what the engine needs (config, batches, statuses in order)."""
    from radar_fusion.tools import simulate as sim_mod

    t0 = time.perf_counter()
    scenario = sim_mod.scenario_for_benchmark(n_aircraft, n_radars, duration_s, seed)
    sim = sim_mod.simulate(scenario, encode=False)
    info = _write_engine_inputs(scenario, sim, path)
    info["sim_s"] = time.perf_counter() - t0
    return info


def _write_engine_inputs(scenario, sim, path: str) -> dict[str, Any]:
    """Pickle the engine's inputs of a simulation (config, decoded batches, statuses in publish order)."""
    from radar_fusion.tools import simulate as sim_mod

    import dataclasses

    from radar_fusion import wire

    radar_index = {r.id: i for i, r in enumerate(scenario.radars)}
    rotation = {r.id: float(r.rotation_period_s) for r in scenario.radars}
    # Publish order as simulate() builds it: by time, a batch before the status of the same
    # sweep, then by radar.
    # The engine process gets what the daemon would decode, without the simulation's own
    # columns (target_index, wild): they would count in the engine's peak RSS.
    decoded = [f.name for f in dataclasses.fields(wire.DecodedPlots)]
    events: list[tuple] = [(c.t_pub_s, 0, c.radar_index, wire.DecodedPlots(**{k: getattr(c, k) for k in decoded}))
                           for c in sim.plot_columns]  # fmt: skip
    events += [(t, 1, radar_index[rid], (rid, t, kind, sector, rotation[rid] if kind == "north" else None))
               for (t, rid, kind, sector) in sim.statuses]  # fmt: skip
    events.sort(key=lambda e: e[:3])
    n_plots = sum(len(c) for c in sim.plot_columns)
    n_wild = int(sum(int(c.wild.sum()) for c in sim.plot_columns))
    data = {
        "config_toml": sim_mod.config_toml(scenario),
        "start_t_s": float(scenario.start_t_s),
        "events": [(e[1], e[3]) for e in events],
        "n_plots": n_plots,
    }
    with open(path, "wb") as f:
        pickle.dump(data, f, protocol=pickle.HIGHEST_PROTOCOL)
    return {"plots": n_plots, "wild_truth": n_wild, "batches": len(sim.plot_columns),
            "statuses": len(sim.statuses)}  # fmt: skip


def run_engine(path: str, gate: bool, warmup_s: float, profile_top: int = 0) -> dict[str, Any]:
    """Load the pickled inputs, run the engine on them and return the figures.

    With ``profile_top`` > 0 the run is under cProfile and the result carries the profile
    (top functions by cumulative time and a per-stage summary) instead of honest timings.
    """
    import tomllib

    import msgpack
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
    events = [
        (0, obj) if kind == 0 else
        (1, wire.RadarStatus(radar_id=obj[0], t=obj[1], kind=obj[2], sector=obj[3], rotation_period_s=obj[4]))
        for kind, obj in data["events"]
    ]  # fmt: skip
    del data["events"]
    gc.collect()
    gc.freeze()  # as `radar-fusion serve` does after start-up
    rss_base_kb = _rss_kb("VmRSS")
    hwm_reset = _reset_peak_rss()
    maxrss_before_kb = _maxrss_kb()

    ingest_plots, ingest_status, poll = engine.ingest_plots, engine.ingest_status, engine.poll
    perf = time.perf_counter
    t_ingest = t_status = t_poll = 0.0
    # Keep only each period's figures: holding every TrackBatch (thousands of dicts per
    # period) would make Python's cyclic GC slower and slower and distort the timings.
    periods: list[tuple[float, float, int, int]] = []  # (t_s, processing_ms, plots, tracks)

    msg_ms: list[float] = []  # TrackBatch dicts built from the columns and msgpack-encoded, per period

    def keep(outs) -> None:
        for o in outs:
            t0 = perf()
            msgpack.packb(o.track_batch, use_bin_type=True)  # what the daemon's publisher does
            msg_ms.append((perf() - t0) * 1e3)
            periods.append((o.t_s, o.processing_s * 1e3, o.n_plots, len(o.track_columns)))

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
                outs = None
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

    peak_kb = _rss_kb("VmHWM") if hwm_reset else None
    peak_source = "VmHWM after clear_refs"
    if peak_kb is None:
        peak_kb, peak_source = _maxrss_kb(), "ru_maxrss"
    warm_end = data["start_t_s"] + warmup_s
    steady = [p[1] for p in periods if p[0] >= warm_end]
    warm = [p[1] for p in periods if p[0] < warm_end]
    plots_per_period = [p[2] for p in periods if p[0] >= warm_end]
    tracks_per_period = [p[3] for p in periods if p[0] >= warm_end]
    status = engine.tracks.status
    n_plots = data["n_plots"]
    result = {
        "gate": gate,
        "plots": n_plots,
        "engine_s": t_total,
        "ingest_s": t_ingest,
        "status_s": t_status,
        "poll_s": t_poll,
        "plots_per_s": n_plots / t_total if t_total > 0 else math.nan,
        "ingest_us_per_plot": 1e6 * t_ingest / max(n_plots, 1),
        "ingest_share": t_ingest / t_total if t_total > 0 else math.nan,
        "periods": len(periods),
        "periods_steady": len(steady),
        "period_sum_ms": float(sum(p[1] for p in periods)),
        "steady_period_mean_ms": float(np.mean(steady)) if steady else math.nan,
        "p50_ms": _percentile(steady, 50),
        "p99_ms": _percentile(steady, 99),
        "msg_p50_ms": _percentile(msg_ms, 50),
        "msg_p99_ms": _percentile(msg_ms, 99),
        "max_ms": max(steady) if steady else math.nan,
        "warm_p50_ms": _percentile(warm, 50),
        "warm_max_ms": max(warm) if warm else math.nan,
        "plots_per_period": float(np.mean(plots_per_period)) if plots_per_period else math.nan,
        "tracks_per_period": float(np.mean(tracks_per_period)) if tracks_per_period else math.nan,
        "tracks_end": int(len(engine.tracks)),
        "confirmed_end": int((status == CONFIRMED).sum()),
        "wild_rejected": int(engine.counters.get("plots_wild", 0)),
        "plots_accepted": int(engine.counters.get("plots_accepted", 0)),
        "rss_base_mb": (rss_base_kb or 0) / 1024.0,
        "peak_rss_mb": (peak_kb or 0) / 1024.0,
        "peak_source": peak_source,
        "maxrss_before_mb": (maxrss_before_kb or 0) / 1024.0,
    }
    if profiler is not None:
        result["profile"] = _profile_summary(profiler, profile_top, t_total)
    return result


def _maxrss_kb() -> int:
    import resource

    return int(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss)  # kB on Linux


# Stages of the pipeline, as (label, module file, function name); indented = inside the one above.
STAGES = [
    ("ingest_plots (total)", "engine.py", "ingest_plots"),
    ("  wild-plot gate (LiveOutlierGate.filter)", "live_gate.py", "filter"),
    ("  coordinate conversion (polar_to_plane)", "coordinates.py", "polar_to_plane"),
    ("  period buffer add", "period_buffer.py", "add"),
    ("ingest_status", "engine.py", "ingest_status"),
    ("poll + flush: period buffer pop", "period_buffer.py", "pop_period"),
    ("poll + flush: _process_period (total)", "engine.py", "_process_period"),
    ("  prediction (Singer + altitude filters)", "singer_filter.py", "predict"),
    ("  clustering (cluster_plots)", "clustering.py", "cluster_plots"),
    ("  cluster fusion (fuse_clusters)", "fusion.py", "fuse_clusters"),
    ("  Kalman update (Singer + altitude)", "singer_filter.py", "update"),
    ("  initiation (two-point + altitude)", "singer_filter.py", "initiate"),
    ("  manoeuvre detection", "engine.py", "_detect_manoeuvres"),
    ("  life cycle (apply_life_cycle)", "track_management.py", "apply_life_cycle"),
    ("  TrackBatch building (TrackColumns.to_message, outside the period time)", "engine.py", "to_message"),
]


def _profile_summary(profiler, top: int, total_s: float) -> dict[str, Any]:
    import io
    import pstats

    stats = pstats.Stats(profiler)
    stage_rows = []
    for label, fname, func in STAGES:
        ct, calls = 0.0, 0
        for (file, _line, name), (_cc, nc, _tt, cum, _callers) in stats.stats.items():
            if name == func and os.path.basename(file) == fname:
                ct += cum
                calls += nc
        stage_rows.append((label, calls, ct))
    buf = io.StringIO()
    pstats.Stats(profiler, stream=buf).strip_dirs().sort_stats("cumulative").print_stats(top)
    prof_total = sum(tt for (_cc, _nc, tt, _ct, _c) in stats.stats.values())
    return {"stages": stage_rows, "text": buf.getvalue(), "profiled_total_s": prof_total, "wall_s": total_s}


# =========================================================================== formatting


def _fmt(v: float, digits: int = 0) -> str:
    if v is None or (isinstance(v, float) and math.isnan(v)):
        return "-"
    return f"{v:,.{digits}f}"


COLUMNS = [
    "aircraft", "radars", "plots", "plots/s", "p50 ms", "p99 ms", "warm-up max ms",
    "ingest µs/plot", "ingest share", "tracks end (conf.)", "peak RSS MB (base)", "gate off plots/s",
    "gate on/off",
]  # fmt: skip


def table_rows(rows: list[dict[str, Any]]) -> list[list[str]]:
    out = []
    for row in rows:
        on, off = row["on"], row.get("off")
        out.append([
            f"{row['aircraft']:,}", str(row["radars"]), f"{on['plots']:,}", _fmt(on["plots_per_s"]),
            _fmt(on["p50_ms"], 1), _fmt(on["p99_ms"], 1), _fmt(on["warm_max_ms"], 1),
            _fmt(on["ingest_us_per_plot"], 1), f"{100 * on['ingest_share']:.0f} %",
            f"{on['tracks_end']:,} ({on['confirmed_end']:,})",
            f"{on['peak_rss_mb']:.0f} ({on['rss_base_mb']:.0f})",
            _fmt(off["plots_per_s"]) if off else "-",
            f"{on['plots_per_s'] / off['plots_per_s']:.2f}" if off else "-",
        ])  # fmt: skip
    return out


def format_text_table(rows: list[dict[str, Any]]) -> str:
    body = table_rows(rows)
    widths = [max(len(c), *(len(r[i]) for r in body)) for i, c in enumerate(COLUMNS)]
    line = lambda cells: "  ".join(c.rjust(w) for c, w in zip(cells, widths))  # noqa: E731
    return "\n".join([line(COLUMNS), line(["-" * w for w in widths])] + [line(r) for r in body])


def format_md_table(rows: list[dict[str, Any]]) -> str:
    body = table_rows(rows)
    lines = ["| " + " | ".join(COLUMNS) + " |", "|" + "|".join("---:" for _ in COLUMNS) + "|"]
    lines += ["| " + " | ".join(r) + " |" for r in body]
    return "\n".join(lines)


def goal_lines(rows: list[dict[str, Any]]) -> list[str]:
    lines = []
    by_size = {(r["aircraft"], r["radars"]): r for r in rows}
    g = by_size.get(GOAL_PLOTS_SIZE)
    if g is None:
        lines.append(f"goal ≥ {GOAL_PLOTS_PER_S:,.0f} plots/s at {GOAL_PLOTS_SIZE[0]:,}×{GOAL_PLOTS_SIZE[1]}: "
                     "NOT MEASURED (size not in --sizes)")  # fmt: skip
    else:
        v = g["on"]["plots_per_s"]
        extra = ""
        if g.get("off"):
            v_off = g["off"]["plots_per_s"]
            extra = f"; gate off {v_off:,.0f} plots/s: {'met' if v_off >= GOAL_PLOTS_PER_S else 'not met'}"
        lines.append(f"goal ≥ {GOAL_PLOTS_PER_S:,.0f} plots/s at {GOAL_PLOTS_SIZE[0]:,}×{GOAL_PLOTS_SIZE[1]} "
                     f"(gate on): {v:,.0f} plots/s -> {'MET' if v >= GOAL_PLOTS_PER_S else 'NOT MET'} "
                     f"({v / GOAL_PLOTS_PER_S:.2f} of the goal){extra}")  # fmt: skip
    big = [r for r in rows if r["aircraft"] == GOAL_P99_AIRCRAFT]
    if not big:
        lines.append(f"goal period p99 < {GOAL_P99_MS:.0f} ms at {GOAL_P99_AIRCRAFT:,} aircraft: NOT MEASURED")
    for r in big:
        v = r["on"]["p99_ms"]
        lines.append(f"goal period p99 < {GOAL_P99_MS:.0f} ms at {r['aircraft']:,}×{r['radars']} (gate on): "
                     f"{v:.1f} ms -> {'MET' if v < GOAL_P99_MS else 'NOT MET'}")  # fmt: skip
    return lines


def scaling_lines(rows: list[dict[str, Any]]) -> list[str]:
    """Cost per aircraft from 1,000 to 4,000 aircraft at the same number of radars."""
    by_size = {(r["aircraft"], r["radars"]): r for r in rows}
    lines = []
    for radars in sorted({r["radars"] for r in rows}):
        a, b = by_size.get((1000, radars)), by_size.get((4000, radars))
        if not (a and b):
            continue
        ea, eb = a["on"], b["on"]
        # engine time per closed period (ingest + poll), and the period processing alone
        per_a = ea["engine_s"] / max(ea["periods"], 1)
        per_b = eb["engine_s"] / max(eb["periods"], 1)
        ua, ub = 1e6 * per_a / 1000, 1e6 * per_b / 4000
        pa, pb = ea["steady_period_mean_ms"], eb["steady_period_mean_ms"]
        exp_total = math.log(per_b / per_a) / math.log(4.0)
        exp_period = math.log(pb / pa) / math.log(4.0) if pa > 0 and pb > 0 else math.nan
        plots_ratio = eb["plots"] / ea["plots"]
        verdict = "about linear or better" if exp_total <= 1.15 else "WORSE than linear"
        lines.append(
            f"scaling ×{radars} radars, 1,000 -> 4,000 aircraft: engine time per period {1e3 * per_a:.1f} -> "
            f"{1e3 * per_b:.1f} ms = {ua:.1f} -> {ub:.1f} µs per aircraft (exponent {exp_total:.2f}); "
            f"period processing mean {pa:.1f} -> {pb:.1f} ms (exponent {exp_period:.2f}); "
            f"plots ×{plots_ratio:.2f}, µs/plot {1e6 * ea['engine_s'] / ea['plots']:.1f} -> "
            f"{1e6 * eb['engine_s'] / eb['plots']:.1f}: {verdict}"
        )  # fmt: skip
    return lines


def machine_lines() -> list[str]:
    import numpy as np

    try:
        affinity = len(os.sched_getaffinity(0))
    except AttributeError:
        affinity = os.cpu_count()
    rev = ""
    for where in (Path(__file__).resolve().parent, Path.cwd()):
        try:
            rev = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True,
                                 timeout=5, cwd=where).stdout.strip()  # fmt: skip
        except (OSError, subprocess.SubprocessError):
            rev = ""
        if rev:
            break
    load = " ".join(f"{x:.2f}" for x in os.getloadavg())
    return [
        f"machine: {platform.node()} {platform.machine()}, {affinity} usable cores (nproc), "
        f"load average {load}; shared machine: figures are noisy, compare ratios from one run",
        f"python {platform.python_version()}, numpy {np.__version__}"
        + (f", git {rev}" if rev else "") + f", {_dt.datetime.now(_dt.timezone.utc):%Y-%m-%d %H:%M} UTC",
    ]


# =========================================================================== side by side (issue 7)
#
# ``radar-fusion bench --report DIR`` (or ``--compare``): per case (a benchmark size, and
# the real ADS-B flights) each job below runs in its own fresh process:
#   simulate_case   simulation, recording, truth, engine inputs, measurement noise, PCRB
#   run_engine      (a) the engine alone, timed (above)
#   run_bus         (b) the daemon as its own process over Zenoh, fed by the replay tool
#   run_reference   (c) Stone Soup on the same plots (tools/baseline_stonesoup.py)
#   run_accuracy    the engine's tracks, and each radar alone, scored against truth

COMPARE_SIZES = [(50, 3), (100, 3), (1000, 10), (4000, 30)]
"""50×3 first: Stone Soup finishes it within the budget, and the larger sizes are estimated from it."""
GOAL_SPEEDUP = 30.0
GOAL_E2E_P99_MS = 250.0
GOAL_E2E_SIZE = (1000, 10)
ESASSP_3NM_M = 300.0
SCORE_FIELDS = (
    "pos_rms_m", "pos_rms_settled_m", "vel_rms_mps", "vel_rms_settled_mps", "gospa_mean_m",
    "gospa_missed_targets_mean", "gospa_false_tracks_mean", "track_ids_per_target_mean", "completeness_mean",
    "id_swaps", "false_tracks", "duplicate_tracks", "n_displayed_tracks", "n_detectable_targets",
)  # fmt: skip


def _case_label(case: dict[str, Any]) -> str:
    if case["kind"] == "adsb":
        return f"ADS-B {case['duration_s']:g} s"
    return f"{case['aircraft']:,}×{case['radars']}"


def _build_scenario(case: dict[str, Any], seed: int):
    from radar_fusion.tools import simulate as sim_mod

    if case["kind"] == "adsb":
        return sim_mod.adsb_scenario(seed=seed, duration_s=case["duration_s"], max_aircraft=case["max_aircraft"])
    return sim_mod.scenario_for_benchmark(case["aircraft"], case["radars"], case["duration_s"], seed)


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
    info = _write_engine_inputs(scenario, sim, os.path.join(case_dir, "engine.pkl"))
    settings = config.settings_from_dict(tomllib.loads(sim_mod.config_toml(scenario)), source="benchmark scenario")
    info.update(measurement_floor(sim, settings, settle_s))
    info.update(aircraft=len(scenario.targets), radars=len(scenario.radars), duration_s=float(scenario.duration_s),
                period_s=float(settings.system.period_s), sim_s=time.perf_counter() - t0)  # fmt: skip
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
    the engine's Singer model (its α and σ_m, Φ and Q from ``singer_filter``); measurements:
    every such plot of the aircraft, from all radars, at its own time with its own 2×2
    covariance R (sequential processing is the exact fused-measurement information);
    prior at the first plot (and again after a gap of more than 60 s without plots, when a
    tracker would have dropped the track): position from R, velocity variance
    max_speed²/3, acceleration σ_m². Covariance updates in Joseph form. The bound assumes perfect association, no false or wild plots and no radar bias,
    so it is a floor. It is evaluated at the period times (as the tracks are scored) while
    the aircraft is detectable, from ``settle_s`` after its first plot on, and reported as
    sqrt(mean(P_xx + P_yy)), comparable with the settled position RMS.
    """
    import numpy as np

    from radar_fusion.geo.coordinates import flight_level_to_altitude_m, polar_to_plane
    from radar_fusion.tracking.singer_filter import (
        DEFAULT_ALPHA_PER_S, DEFAULT_SIGMA_M_MPS2, singer_process_noise, singer_transition,
    )  # fmt: skip

    cols = [c for c in sim.plot_columns if len(c)]
    if not cols:
        return {"noise_rms_m": math.nan, "noise_model_rms_m": math.nan, "pcrb_pos_rms_m": math.nan}
    cat = lambda name: np.concatenate([getattr(c, name) for c in cols])  # noqa: E731
    radar = np.concatenate([np.full(len(c), c.radar_index) for c in cols])
    t, rng, az, fl, tgt, wild = (cat(k) for k in ("t_s", "range_m", "azimuth_deg", "fl", "target_index", "wild"))
    keep = (tgt >= 0) & ~wild
    t, rng, az, fl, tgt, radar = t[keep], rng[keep], az[keep], fl[keep], tgt[keep], radar[keep]
    x, y, cov, _g, valid = polar_to_plane(
        sim.plane, sim.sites, radar, rng, az, flight_level_to_altitude_m(fl),
        assumed_altitude_m=settings.tracking.assumed_altitude_ft * 0.3048, return_valid=True,
    )  # fmt: skip
    t, x, y, cov, tgt = t[valid], x[valid], y[valid], cov[valid], tgt[valid]
    truth = sim.truth_at(tgt, t)
    err2 = (x - truth["x_m"]) ** 2 + (y - truth["y_m"]) ** 2
    out = {
        "noise_rms_m": float(np.sqrt(np.mean(err2))),
        "noise_model_rms_m": float(np.sqrt(np.mean(cov[:, 0, 0] + cov[:, 1, 1]))),
        "noise_plots": int(t.size),
    }

    trk = settings.tracking
    gap_s = 60.0
    alpha = trk.alpha_per_s or DEFAULT_ALPHA_PER_S
    sigma_m = trk.sigma_m_mps2 or DEFAULT_SIGMA_M_MPS2
    order = np.lexsort((t, tgt))
    t, cov, tgt = t[order], cov[order], tgt[order]
    n = t.size
    first = np.r_[True, tgt[1:] != tgt[:-1]]
    start = np.flatnonzero(first)
    rank = np.arange(n) - np.repeat(start, np.diff(np.r_[start, n]))
    H = np.zeros((2, 6))
    H[0, 0] = H[1, 3] = 1.0
    P = np.zeros((n, 6, 6))

    def prior(i: np.ndarray) -> np.ndarray:
        p0 = np.zeros((i.size, 6, 6))
        p0[:, [0, 0, 3, 3], [0, 3, 0, 3]] = cov[i][:, [0, 0, 1, 1], [0, 1, 0, 1]]
        p0[:, 1, 1] = p0[:, 4, 4] = trk.max_speed_mps**2 / 3.0
        p0[:, 2, 2] = p0[:, 5, 5] = sigma_m**2
        return p0

    for r in range(int(rank.max()) + 1):
        idx = np.flatnonzero(rank == r)
        if r == 0:
            P[idx] = prior(idx)
            continue
        # after a gap longer than a track survives (the aircraft left coverage), the next
        # plot starts a new track: the bound restarts from the one-plot prior
        restart = t[idx] - t[idx - 1] > gap_s
        P[idx[restart]] = prior(idx[restart])
        idx = idx[~restart]
        dt = t[idx] - t[idx - 1]
        F = singer_transition(dt, alpha)
        Pp = F @ P[idx - 1] @ np.swapaxes(F, 1, 2) + singer_process_noise(dt, alpha, sigma_m)
        S = Pp[:, [0, 0, 3, 3], [0, 3, 0, 3]].reshape(-1, 2, 2) + cov[idx]
        K = Pp @ H.T @ np.linalg.inv(S)
        IKH = np.eye(6) - K @ H
        # Joseph form: stays symmetric positive semi-definite in floating point
        P[idx] = IKH @ Pp @ np.swapaxes(IKH, 1, 2) + K @ cov[idx] @ np.swapaxes(K, 1, 2)
    # evaluation at the period times
    period_s = float(settings.system.period_s)
    sc = sim.scenario
    times = np.arange(math.ceil(sc.start_t_s / period_s), math.floor((sc.start_t_s + sc.duration_s) / period_s) + 1)
    times = times * period_s
    tr = sim.truth
    var_sum, count = 0.0, 0
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
        ok = (q >= tt[0]) & (q <= tt[-1])
        q = q[ok]
        lo = np.clip(np.searchsorted(tt, q, side="right") - 1, 0, tt.size - 1)
        hi = np.clip(lo + 1, 0, tt.size - 1)
        q = q[det[lo] & det[hi]]
        if q.size == 0:
            continue
        j = s + np.searchsorted(t[s:e], q, side="right") - 1
        q, j = q[q - t[j] <= gap_s], j[q - t[j] <= gap_s]  # no plot for longer: no track to bound
        if q.size == 0:
            continue
        dt = q - t[j]
        F = singer_transition(dt, alpha)
        Pq = F @ P[j] @ np.swapaxes(F, 1, 2) + singer_process_noise(dt, alpha, sigma_m)
        var_sum += float(np.sum(Pq[:, 0, 0] + Pq[:, 3, 3]))
        count += q.size
    out["pcrb_pos_rms_m"] = math.sqrt(var_sum / count) if count else math.nan
    out["pcrb_points"] = count
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
        (0, obj) if kind == 0 else
        (1, wire.RadarStatus(radar_id=obj[0], t=obj[1], kind=obj[2], sector=obj[3], rotation_period_s=obj[4]))
        for kind, obj in data["events"]
    ]  # fmt: skip


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


def run_accuracy(case_dir: str, settle_s: float, png_prefix: Optional[str] = None) -> dict[str, Any]:
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
    key = lambda rid: (_nan_last(out["single"][rid]["pos_rms_settled_m"]), _nan_last(out["single"][rid]["pos_rms_m"]))  # noqa: E731
    out["best_single_radar"] = best = min(out["single"], key=key) if out["single"] else None
    if best is not None:
        out["same_aircraft"] = same_aircraft_rms(scores.targets, per_target[best])
    return out


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


def run_reference(case_dir: str, settle_s: float, budget_s: float, q_m2ps3: float,
                  png_prefix: Optional[str] = None) -> dict[str, Any]:
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
    rss_base_kb = _rss_kb("VmRSS")
    hwm_reset = _reset_peak_rss()
    run = bs.run_stonesoup(settings, plot_batches, bs.StoneSoupParams(q_m2ps3=q_m2ps3), time_budget_s=budget_s)
    peak_kb = _rss_kb("VmHWM") if hwm_reset else _maxrss_kb()
    out = {
        "version": bs.version(), "completed": run.completed, "run_s": run.run_s, "plots": run.plots_used,
        "plots_processed": run.plots_processed, "plots_per_s": run.plots_per_s, "steps": run.steps,
        "tracks_started": run.tracks_started, "peak_rss_mb": (peak_kb or 0) / 1024.0,
        "rss_base_mb": (rss_base_kb or 0) / 1024.0, "q_m2ps3": q_m2ps3,
    }  # fmt: skip
    if run.completed:
        truth = ev.load_truth(os.path.join(case_dir, "truth.csv"))
        scores = ev.evaluate(run.batches, truth, ev.EvalParams(settle_s=settle_s))
        out["scores"] = _summary(scores, settled_from)
        if png_prefix:
            ev.plot(run.batches, truth, png_prefix + "_stonesoup.png", scores)
    return out


def _closable_after(records, settings) -> "Any":
    """Per message: the event time up to which every period may close once it is processed
    (the period buffer's rule: min over live radars' watermarks − allowed lateness), as a
    running maximum; periods ending at or before it have all their inputs."""
    import numpy as np

    from radar_fusion.wire import Rejection, decode_plot_batch

    index = {r.id: i for i, r in enumerate(settings.radars)}
    wm = np.full(len(index), -math.inf)
    timeout, lateness = settings.system.radar_timeout_s, settings.system.allowed_lateness_s
    out = np.full(len(records), -math.inf)
    best = -math.inf
    for i, rec in enumerate(records):
        parts = rec.key.split("/")
        r = index.get(parts[-2])
        if r is not None:
            if parts[-1] == "plots":
                d = decode_plot_batch(rec.payload)
                t_ev = float(d.t_s.max()) if not isinstance(d, Rejection) and len(d) else rec.t_s
            else:
                t_ev = rec.t_s
            wm[r] = max(wm[r], t_ev)
            live = np.isfinite(wm) & (wm >= wm.max() - timeout)
            best = max(best, float(wm[live].min()) - lateness)
        out[i] = best
    return out


def run_bus(case_dir: str, speed: Optional[float], warmup_s: float, timeout_s: float) -> dict[str, Any]:
    """(b) The daemon (``radar-fusion serve``, its own process, embedded router on a free
    127.0.0.1 port) fed by the replay tool (:func:`replay.replay_records`, a client
    session), the track batches received by a subscriber on another client session.

    Publish time of a message = when its ``put`` returned; receive time = when the
    subscriber's callback ran (both ``time.monotonic``, one clock for every process on
    Linux). After the recording, one heartbeat status per radar (event time last + one
    period + the allowed lateness + 0.5 s) closes the last periods, so every period
    ends the normal way. plots/s = plots / (last TrackBatch received − first message
    sent). Latency of period k = receive time of its TrackBatch − publish time of the
    message that let it close (the first after which every live radar's watermark has
    passed the period's end + the allowed lateness: the last input the period waits
    for); periods ending in the first ``warmup_s`` are left out.
    """
    import signal
    import subprocess as sp

    import msgpack
    import numpy as np

    from radar_fusion import wire
    from radar_fusion.bus import open_session, zenoh_config
    from radar_fusion.config import load_settings
    from radar_fusion.tools.demo import free_tcp_port
    from radar_fusion.recording import Record, read_recording
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
    t_hb = max(t_last, records[-1].t_s) + period_s + settings.system.allowed_lateness_s + 0.5
    for r in settings.radars:
        msg = {"v": wire.WIRE_VERSION, "radar_id": r.id, "t": t_hb, "kind": "heartbeat"}
        records.append(Record(t_hb, f"radar/{r.id}/status", wire.encode(msg)))
    closable = _closable_after(records, settings)
    last_period = int(math.floor(t_last / period_s))

    log_path = Path(case_dir, f"daemon_{port}.log")
    with open(log_path, "w") as log:
        daemon = sp.Popen([sys.executable, "-m", "radar_fusion.cli", "serve", "--config", str(cfg_path),
                           "--log-level", "WARNING"], stdout=log, stderr=sp.STDOUT)  # fmt: skip
    received: list[tuple[float, bytes]] = []
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
        sub = session.declare_subscriber(f"{prefix}/fusion/tracks",
                                         lambda s: received.append((time.monotonic(), s.payload.to_bytes())))  # fmt: skip
        time.sleep(1.0)  # subscriptions propagate through the router
        pub_s: list[float] = []

        def timed(recs):
            for rec in recs:
                yield rec
                pub_s.append(time.monotonic())

        t_start = time.monotonic()
        replay_records(session, timed(records), prefix, speed)
        t_sent = time.monotonic()

        def last_seen() -> bool:
            return any(msgpack.unpackb(p, raw=False).get("period", -1) >= last_period for _, p in received[-3:])

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
    lat_ms, warm_end = [], records[0].t_s + warmup_s
    for t_r, b in batches:
        end_s = (b["period"] + 1) * period_s
        i = int(np.searchsorted(closable, end_s - 1e-9, side="left"))
        if end_s >= warm_end and i < pub.size:
            lat_ms.append(1e3 * (t_r - pub[i]))
    return {
        "speed": speed, "plots": n_plots, "messages": len(records), "batches_received": len(batches),
        "completed": bool(done), "send_s": t_sent - t_start, "wall_s": t_done - t_start,
        "plots_per_s": n_plots / (t_done - t_start) if done else math.nan,
        "e2e_p50_ms": _percentile(lat_ms, 50), "e2e_p99_ms": _percentile(lat_ms, 99),
        "e2e_max_ms": max(lat_ms) if lat_ms else math.nan, "e2e_periods": len(lat_ms),
        "daemon_peak_rss_mb": (peak_kb or 0) / 1024.0,
    }  # fmt: skip


def _estimate_reference_s(cost: Optional[tuple[float, str]], plots: int, tracks: float) -> Optional[float]:
    """Stone Soup's run time scales with plots × tracks (every plot is hypothesised against
    every track, every track is predicted at every step): estimate from a measured case."""
    if cost is None or not (tracks > 0):
        return None
    return cost[0] * plots * tracks


def _run_compare(args: argparse.Namespace, sizes: list[tuple[int, int]], duration_s: float, tmp: str) -> int:
    import shutil

    from radar_fusion.tools import baseline_stonesoup as bs

    report_dir = Path(args.report) if args.report else None
    if report_dir:
        report_dir.mkdir(parents=True, exist_ok=True)
    use_ref = not args.no_reference and bs.available()
    header = machine_lines() + [
        f"stonesoup {bs.version()}" + ("" if use_ref else " (reference not run: "
                                       + ("--no-reference)" if args.no_reference else "not importable)")),
        f"{duration_s:g} s simulated per size, seed {args.seed}; warm-up {args.warmup_s:g} s left out of the "
        f"latency percentiles; accuracy settled after {args.settle_s:g} s",
    ]  # fmt: skip
    print("\n".join(header), flush=True)
    cases = [{"kind": "benchmark", "aircraft": n, "radars": r, "duration_s": duration_s} for n, r in sizes]
    if not args.no_adsb:
        cases.append({"kind": "adsb", "duration_s": args.adsb_duration_s, "max_aircraft": args.adsb_aircraft})
    if not cases:
        print("bench: nothing to compare (--sizes none and --no-adsb)", file=sys.stderr)
        return 2
    rows: list[dict[str, Any]] = []
    ref_cost: Optional[tuple[float, str]] = None
    t_bench = time.perf_counter()
    for c, case in enumerate(cases):
        label = _case_label(case)
        case_dir = os.path.join(tmp, f"case{c}")
        os.makedirs(case_dir, exist_ok=True)
        png = str(report_dir / ("adsb" if case["kind"] == "adsb" else f"size{c}")) if report_dir and (
            case["kind"] == "adsb" or c == 0) else None  # fmt: skip
        row: dict[str, Any] = {"label": label, "case": case}
        row["sim"] = sim = _in_fresh_process(simulate_case, case, args.seed, case_dir, args.settle_s)
        print(f"{label}: {sim['aircraft']:,} aircraft, {sim['radars']} radars, {sim['plots']:,} plots "
              f"(simulated in {sim['sim_s']:.1f} s)", flush=True)  # fmt: skip
        row["engine"] = eng = _in_fresh_process(run_engine, os.path.join(case_dir, "engine.pkl"), True, args.warmup_s, 0)
        print(f"  (a) engine: {eng['plots_per_s']:,.0f} plots/s, period p50 {eng['p50_ms']:.1f} / p99 "
              f"{eng['p99_ms']:.1f} ms, peak RSS {eng['peak_rss_mb']:.0f} MB", flush=True)  # fmt: skip
        if not args.no_bus:
            row["bus"] = b = _in_fresh_process(run_bus, case_dir, None, args.warmup_s, args.bus_timeout_s)
            print(f"  (b) daemon over Zenoh, replay at max speed: {b['plots_per_s']:,.0f} plots/s "
                  f"({b['wall_s']:.1f} s), daemon peak RSS {b['daemon_peak_rss_mb']:.0f} MB", flush=True)  # fmt: skip
            if args.latency_speed > 0:
                row["bus_paced"] = bp = _in_fresh_process(run_bus, case_dir, args.latency_speed, args.warmup_s,
                                                          args.bus_timeout_s)  # fmt: skip
                print(f"      replay at {args.latency_speed:g}× real time: end-to-end p50 {bp['e2e_p50_ms']:.1f} / "
                      f"p99 {bp['e2e_p99_ms']:.1f} ms over {bp['e2e_periods']} periods", flush=True)  # fmt: skip
        if use_ref:
            est = _estimate_reference_s(ref_cost, sim["plots"], eng["tracks_per_period"])
            if est is not None and est > args.reference_budget_s:
                row["reference"] = {"skipped": True, "estimate_s": est, "estimated_from": ref_cost[1],
                                    "plots_per_s": sim["plots"] / est}  # fmt: skip
                print(f"  (c) Stone Soup: skipped, estimated {est / 60:.0f} min (> budget "
                      f"{args.reference_budget_s / 60:.0f} min) from the {ref_cost[1]} run", flush=True)  # fmt: skip
            else:
                ref = _in_fresh_process(run_reference, case_dir, args.settle_s, args.reference_budget_s,
                                        args.ss_q, png)  # fmt: skip
                row["reference"] = ref
                if ref["plots_processed"] > 0 and eng["tracks_per_period"] > 0:
                    # a run stopped at the budget still measures the cost (optimistically for
                    # Stone Soup: its first part, during initiation, holds fewer tracks)
                    ref_cost = (ref["run_s"] / (ref["plots_processed"] * eng["tracks_per_period"]),
                                label + ("" if ref["completed"] else " (partial)"))
                print(f"  (c) Stone Soup {ref['version']}: {ref['plots_per_s']:,.1f} plots/s "
                      f"({ref['run_s']:.0f} s{'' if ref['completed'] else ', stopped at the budget'}), "
                      f"peak RSS {ref['peak_rss_mb']:.0f} MB; ours/reference {eng['plots_per_s'] / ref['plots_per_s']:,.0f}×",
                      flush=True)  # fmt: skip
        if not args.no_accuracy:
            row["accuracy"] = acc = _in_fresh_process(run_accuracy, case_dir, args.settle_s, png)
            o = acc["ours"]
            print(f"  accuracy: ours pos RMS {o['pos_rms_m']:.0f} m (settled {o['pos_rms_settled_m']:.0f}), GOSPA "
                  f"{o['gospa_mean_m']:.0f} m; best single radar {acc['best_single_radar']}; plot noise "
                  f"{sim['noise_rms_m']:.0f} m, PCRB {sim['pcrb_pos_rms_m']:.0f} m", flush=True)  # fmt: skip
        rows.append(row)
        shutil.rmtree(case_dir, ignore_errors=True)
    wall = time.perf_counter() - t_bench
    speed_md, acc_md, goals = compare_tables(rows, args)
    print()
    print(speed_md)
    print()
    print(acc_md)
    print()
    print("\n".join(goals))
    print(f"(benchmark wall time {wall:.0f} s)")
    if report_dir:
        write_report(report_dir, header, rows, args, speed_md, acc_md, goals, wall)
        print(f"wrote {report_dir}/report.md, summary.md, results.json and PNGs")
    return 0


def _f(v: Any, digits: int = 0, suffix: str = "") -> str:
    if v is None or (isinstance(v, float) and (math.isnan(v) or math.isinf(v))):
        return "-"
    return f"{v:,.{digits}f}{suffix}"


def _ratio(ours: Any, ref: dict[str, Any] | None) -> str:
    if not ref or not ref.get("plots_per_s") or ours is None or math.isnan(ours):
        return "-"
    r = ours / ref["plots_per_s"]
    return f"{r:,.0f}×" + (" (est.)" if ref.get("skipped") else "")


def compare_tables(rows: list[dict[str, Any]], args: argparse.Namespace) -> tuple[str, str, list[str]]:
    """The speed table, the accuracy table (Markdown) and the goal lines."""
    speed_cols = ["case", "plots", "engine plots/s", "period p50 / p99 ms", "engine peak RSS MB",
                  "daemon plots/s (max speed)", f"end-to-end p50 / p99 ms ({args.latency_speed:g}×)",
                  "daemon peak RSS MB", "Stone Soup plots/s", "Stone Soup peak RSS MB",
                  "engine / Stone Soup", "daemon / Stone Soup"]  # fmt: skip
    lines = ["| " + " | ".join(speed_cols) + " |", "|" + "|".join(["---"] + ["---:"] * (len(speed_cols) - 1)) + "|"]
    for row in rows:
        e, b, bp, ref = row["engine"], row.get("bus"), row.get("bus_paced"), row.get("reference")
        if ref is None:
            ref_cell, ref_rss = "not run", "-"
        elif ref.get("skipped"):
            ref_cell, ref_rss = f"skipped (est. {_f(ref['plots_per_s'], 1)}, {ref['estimate_s'] / 60:.0f} min)", "-"
        else:
            ref_cell = _f(ref["plots_per_s"], 1) + ("" if ref["completed"] else " (partial)")
            ref_rss = _f(ref["peak_rss_mb"])
        lines.append("| " + " | ".join([
            row["label"], f"{row['sim']['plots']:,}", _f(e["plots_per_s"]),
            f"{_f(e['p50_ms'], 1)} / {_f(e['p99_ms'], 1)}", _f(e["peak_rss_mb"]),
            _f(b["plots_per_s"]) if b else "-",
            f"{_f(bp['e2e_p50_ms'], 1)} / {_f(bp['e2e_p99_ms'], 1)}" if bp else "-",
            _f(b["daemon_peak_rss_mb"]) if b else "-", ref_cell, ref_rss,
            _ratio(e["plots_per_s"], ref), _ratio(b["plots_per_s"] if b else None, ref),
        ]) + " |")  # fmt: skip
    speed_md = "\n".join(lines)

    acc_cols = ["case", "tracker", "pos RMS m", "settled pos RMS m", "vel RMS m/s", "GOSPA m", "settled GOSPA m",
                "missed / false per time", "ids per target", "completeness", "id swaps", "false tracks",
                "duplicates"]  # fmt: skip
    lines = ["| " + " | ".join(acc_cols) + " |", "|" + "|".join(["---", "---"] + ["---:"] * (len(acc_cols) - 2)) + "|"]

    def score_row(label: str, name: str, s: dict[str, Any]) -> str:
        return "| " + " | ".join([
            label, name, _f(s["pos_rms_m"]), _f(s["pos_rms_settled_m"]), _f(s["vel_rms_mps"], 1),
            _f(s["gospa_mean_m"]), _f(s.get("gospa_settled_mean_m")),
            f"{_f(s['gospa_missed_targets_mean'], 2)} / {_f(s['gospa_false_tracks_mean'], 2)}",
            _f(s["track_ids_per_target_mean"], 2), _f(100 * s["completeness_mean"], 1, " %"), str(s["id_swaps"]),
            str(s["false_tracks"]), str(s["duplicate_tracks"]),
        ]) + " |"  # fmt: skip

    for row in rows:
        acc, ref, sim = row.get("accuracy"), row.get("reference"), row["sim"]
        if acc:
            lines.append(score_row(row["label"], "ours (daemon's engine)", acc["ours"]))
        if ref and ref.get("scores"):
            lines.append(score_row(row["label"], "Stone Soup GNN (CV)", ref["scores"]))
        if acc and acc.get("best_single_radar"):
            rid = acc["best_single_radar"]
            lines.append(score_row(row["label"], f"best single radar ({rid}, ours on it alone)", acc["single"][rid]))
            same = acc.get("same_aircraft") or {}
            if same.get("aircraft"):
                blank_s = " | ".join(["-"] * (len(acc_cols) - 3))
                lines.append(f"| {row['label']} | same {same['aircraft']} aircraft: fused / {rid} alone | "
                             f"{_f(same['fused_m'])} / {_f(same['single_m'])} | {blank_s} |")  # fmt: skip
        blank = " | ".join(["-"] * (len(acc_cols) - 4))
        lines.append(f"| {row['label']} | measurement noise (plot RMS; model) | {_f(sim['noise_rms_m'])} "
                     f"| {_f(sim['noise_model_rms_m'])} | {blank} |")  # fmt: skip
        lines.append(f"| {row['label']} | PCRB floor (Singer, settled) | - | {_f(sim['pcrb_pos_rms_m'])} | {blank} |")
    acc_md = "\n".join(lines)
    return speed_md, acc_md, goal_lines_compare(rows)


def goal_lines_compare(rows: list[dict[str, Any]]) -> list[str]:
    """Issue 7's goals, each MET / NOT MET / NOT MEASURED, from this run's figures."""
    out = []
    verdict = lambda ok: "MET" if ok else "NOT MET"  # noqa: E731
    for row in rows:
        ref, e, b = row.get("reference"), row["engine"], row.get("bus")
        if not ref:
            out.append(f"{row['label']}: ≥ {GOAL_SPEEDUP:.0f}× Stone Soup: NOT MEASURED")
            continue
        r_e = e["plots_per_s"] / ref["plots_per_s"]
        note = " (Stone Soup estimated, not run)" if ref.get("skipped") else ""
        txt = f"{row['label']}: engine {r_e:,.0f}× Stone Soup{note}"
        ok = r_e >= GOAL_SPEEDUP
        if b and not math.isnan(b["plots_per_s"]):
            r_b = b["plots_per_s"] / ref["plots_per_s"]
            txt += f", whole daemon {r_b:,.0f}×"
            ok = ok and r_b >= GOAL_SPEEDUP
        out.append(f"{txt} -> ≥ {GOAL_SPEEDUP:.0f}× {verdict(ok)}")
        acc = row.get("accuracy")
        if acc and ref.get("scores"):
            o, s = acc["ours"], ref["scores"]
            ok_g = o["gospa_mean_m"] <= s["gospa_mean_m"]
            ok_gs = o["gospa_settled_mean_m"] <= s["gospa_settled_mean_m"]
            ok_p = o["pos_rms_m"] <= s["pos_rms_m"]
            out.append(f"{row['label']}: at least as accurate as Stone Soup: GOSPA {o['gospa_mean_m']:.0f} vs "
                       f"{s['gospa_mean_m']:.0f} m {verdict(ok_g)} (after the settling time "
                       f"{o['gospa_settled_mean_m']:.0f} vs {s['gospa_settled_mean_m']:.0f} m {verdict(ok_gs)}); "
                       f"position RMS {o['pos_rms_m']:.0f} vs {s['pos_rms_m']:.0f} m {verdict(ok_p)}")  # fmt: skip
    big = [r for r in rows if r["case"].get("aircraft") == 4000 and r["case"]["kind"] == "benchmark"]
    if not big:
        out.append(f"engine ≥ {GOAL_PLOTS_PER_S:,.0f} plots/s at 4,000 tracks: NOT MEASURED")
    for r in big:
        v = r["engine"]["plots_per_s"]
        out.append(f"engine ≥ {GOAL_PLOTS_PER_S:,.0f} plots/s at {r['label']}: {v:,.0f} -> {verdict(v >= GOAL_PLOTS_PER_S)}")
    e2e = [r for r in rows if (r["case"].get("aircraft"), r["case"].get("radars")) == GOAL_E2E_SIZE]
    if not e2e or not e2e[0].get("bus_paced"):
        out.append(f"end-to-end p99 < {GOAL_E2E_P99_MS:.0f} ms at 1,000×10: NOT MEASURED")
    else:
        v = e2e[0]["bus_paced"]["e2e_p99_ms"]
        out.append(f"end-to-end p99 < {GOAL_E2E_P99_MS:.0f} ms at 1,000×10: {v:.0f} ms -> {verdict(v < GOAL_E2E_P99_MS)}")
    for row in rows:
        acc = row.get("accuracy")
        if not acc or not acc.get("best_single_radar"):
            continue
        o, one = acc["ours"], acc["single"][acc["best_single_radar"]]
        same = acc.get("same_aircraft") or {}
        ok1 = o["pos_rms_m"] < one["pos_rms_m"]
        ok2 = o["pos_rms_m"] <= ESASSP_3NM_M / 3.0
        txt = (f"{row['label']}: fused position RMS {o['pos_rms_m']:.0f} m < best single radar "
               f"({acc['best_single_radar']}) {one['pos_rms_m']:.0f} m {verdict(ok1)}")
        if same.get("aircraft"):
            txt += (f"; on the {same['aircraft']} aircraft it tracks: fused {same['fused_m']:.0f} m vs "
                    f"{same['single_m']:.0f} m {verdict(same['fused_m'] < same['single_m'])}")
        out.append(txt + f"; ≤ {ESASSP_3NM_M / 3:.0f} m (a third of ESASSP 3 NM) {verdict(ok2)}")
    return out


def write_report(report_dir: Path, header: list[str], rows: list[dict[str, Any]], args: argparse.Namespace,
                 speed_md: str, acc_md: str, goals: list[str], wall_s: float) -> None:
    """report.md, summary.md (the README table), results.json, throughput.png, accuracy.png."""
    import json

    _plot_throughput(rows, report_dir / "throughput.png")
    (report_dir / "accuracy.png").unlink(missing_ok=True)  # a figure of an earlier run must not stay
    _plot_accuracy(rows, report_dir / "accuracy.png")
    losses = [g for g in goals if "NOT MET" in g]
    pngs = sorted(p.name for p in report_dir.glob("*_ours.png")) + sorted(p.name for p in report_dir.glob("*_stonesoup.png"))
    cmd = "radar-fusion bench " + " ".join(sys.argv[2:]) if len(sys.argv) > 2 else "radar-fusion bench --report DIR"
    md = ["# radar-fusion side by side: ours vs Stone Soup", "", f"Command: `{cmd}`", ""]
    md += [f"- {h}" for h in header] + [f"- benchmark wall time {wall_s:.0f} s", ""]
    md += ["## Speed", "", speed_md, "", "![throughput](throughput.png)", ""]
    md += ["## Accuracy", "", acc_md, ""]
    md += ["![accuracy](accuracy.png)", ""] if (report_dir / "accuracy.png").exists() else []
    md += [f"![{p}]({p})" for p in pngs] + [""]
    md += ["## Goals (issue 7)", ""] + [f"- {g}" for g in goals] + [""]
    md += ["## Where ours loses", ""] + ([f"- {g}" for g in losses] or ["- nowhere in this run"]) + [""]
    md += ["## How it is measured", ""] + [f"- {n}" for n in COMPARE_NOTES] + [""]
    (report_dir / "report.md").write_text("\n".join(md) + "\n")
    (report_dir / "summary.md").write_text(summary_table(rows, header) + "\n")
    (report_dir / "results.json").write_text(json.dumps({"header": header, "rows": rows, "goals": goals},
                                                        indent=1, default=float))  # fmt: skip


COMPARE_NOTES = [
    "Every job runs in a fresh process per case: simulation, (a) engine, (b) daemon, (c) Stone Soup, accuracy.",
    "(a) engine: engine calls only, wild-plot gate on, safety nets off (see `radar-fusion bench --help`).",
    "(b) daemon: `radar-fusion serve` as its own process (embedded Zenoh router on 127.0.0.1, safety nets on), "
    "the replay tool publishing the simulated recording from a client session, a subscriber on another; "
    "plots/s at max replay speed = plots / (last TrackBatch received − first message sent); end-to-end "
    "latency with the replay paced at the given speed (1× = real time): TrackBatch received − publish time of "
    "the message that let the period close (the last input it waits for, about `allowed_lateness_s` after "
    "the period's last plot in event time); periods of the warm-up are left out. Peak RSS: the daemon's VmHWM.",
    "(c) Stone Soup (tools/baseline_stonesoup.py): Kalman CV, GNNWith2DAssignment with a Mahalanobis "
    "DistanceHypothesiser at the engine's gate, MultiMeasurementInitiator (3 updates), UpdateTimeDeleter; "
    "plots converted by radar_fusion.geo.coordinates with the engine's covariances, processed in time order; "
    "its time covers conversion, detections, tracker and output. No Mode S identity (ours uses it). Sizes "
    "whose estimated run time (∝ plots × tracks, from the last measured size) exceeds the budget are skipped.",
    "Accuracy: tools/evaluate.py at every period time (gate 2 km, GOSPA c = 2 km, p = 2); best single radar = "
    "the engine run on one radar's plots alone, the radar with the lowest settled position RMS.",
    "Measurement noise: RMS horizontal error of the non-wild plots against truth (radar biases included); "
    "model: the RMS the plot covariances predict. PCRB: posterior Cramér–Rao bound (Tichavský 1998) for the "
    "engine's Singer model with every plot's covariance, perfect association, no bias: the floor for aircraft "
    "that manoeuvre as the model says (σ_m = 2.5 m/s²). Straight-flying aircraft accelerate less than that, so "
    "a tracker can come out at or a little below this line on mostly straight traffic.",
    "Best single radar on the same aircraft: a radar alone tracks only its own coverage, often the easier "
    "aircraft near it; the 'same aircraft' row compares fused and single-radar RMS on the aircraft both track, "
    "weighted by the periods the single radar covers each.",
    "Shared 2-core machine: absolute figures are noisy; compare ratios within one run.",
]


def summary_table(rows: list[dict[str, Any]], header: list[str]) -> str:
    """A short Markdown table for the README: speed and accuracy per case."""
    cols = ["case", "engine plots/s", "daemon plots/s", "e2e p99 ms", "Stone Soup plots/s", "ours/SS",
            "pos RMS ours / SS / best radar m", "GOSPA ours / SS m (settled)", "PCRB m"]  # fmt: skip
    lines = [f"_{header[0].split(';')[0]}; {header[1]}_", "",
             "| " + " | ".join(cols) + " |", "|" + "|".join(["---"] + ["---:"] * (len(cols) - 1)) + "|"]  # fmt: skip
    for row in rows:
        e, b, bp, ref, acc = (row.get(k) for k in ("engine", "bus", "bus_paced", "reference", "accuracy"))
        s = ref.get("scores") if ref else None
        one = acc["single"][acc["best_single_radar"]] if acc and acc.get("best_single_radar") else None
        ref_cell = "-" if not ref else (f"~{ref['plots_per_s']:,.1f} (est.)" if ref.get("skipped")
                                        else _f(ref["plots_per_s"], 1))  # fmt: skip
        lines.append("| " + " | ".join([
            row["label"], _f(e["plots_per_s"]), _f(b["plots_per_s"]) if b else "-",
            _f(bp["e2e_p99_ms"]) if bp else "-", ref_cell, _ratio(e["plots_per_s"], ref),
            " / ".join([_f(acc["ours"]["pos_rms_m"]) if acc else "-", _f(s["pos_rms_m"]) if s else "-",
                        _f(one["pos_rms_m"]) if one else "-"]),
            " / ".join([_f(acc["ours"]["gospa_mean_m"]) if acc else "-", _f(s["gospa_mean_m"]) if s else "-"])
            + " (" + " / ".join([_f(acc["ours"].get("gospa_settled_mean_m")) if acc else "-",
                                 _f(s.get("gospa_settled_mean_m")) if s else "-"]) + ")",
            _f(row["sim"]["pcrb_pos_rms_m"]),
        ]) + " |")  # fmt: skip
    return "\n".join(lines)


def _plot_throughput(rows: list[dict[str, Any]], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    labels = [r["label"] for r in rows]
    series = [
        ("engine", [r["engine"]["plots_per_s"] for r in rows], "C0", None),
        ("daemon over Zenoh", [r["bus"]["plots_per_s"] if r.get("bus") else math.nan for r in rows], "C1", None),
        ("Stone Soup", [r["reference"]["plots_per_s"] if r.get("reference") else math.nan for r in rows], "C2", None),
    ]
    fig, ax = plt.subplots(figsize=(9, 4.8), dpi=110)
    x = np.arange(len(rows))
    w = 0.27
    for k, (name, vals, colour, _) in enumerate(series):
        bars = ax.bar(x + (k - 1) * w, vals, w, label=name, color=colour)
        if name == "Stone Soup":
            for bar, r in zip(bars, rows):
                if r.get("reference", {}).get("skipped"):
                    bar.set_hatch("//")
                    bar.set_alpha(0.5)
    ax.set_yscale("log")
    ax.set_xticks(x, labels)
    ax.set_ylabel("plots per second (log)")
    ax.set_title("Throughput on the same plots (hatched: Stone Soup estimated, not run)")
    ax.grid(True, axis="y", which="both", lw=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def _plot_accuracy(rows: list[dict[str, Any]], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    rows = [r for r in rows if r.get("accuracy")]
    if not rows:
        return
    labels = [r["label"] for r in rows]

    def get(r, who, key):
        if who == "ours":
            return r["accuracy"]["ours"][key]
        if who == "ss":
            s = (r.get("reference") or {}).get("scores")
            return s[key] if s else math.nan
        rid = r["accuracy"]["best_single_radar"]
        return r["accuracy"]["single"][rid][key] if rid else math.nan

    fig, (a1, a2) = plt.subplots(1, 2, figsize=(12, 4.8), dpi=110)
    x = np.arange(len(rows))
    w = 0.27
    for k, (who, name, colour) in enumerate([("ours", "ours", "C0"), ("ss", "Stone Soup", "C2"),
                                             ("one", "best single radar", "C7")]):  # fmt: skip
        a1.bar(x + (k - 1) * w, [get(r, who, "pos_rms_settled_m") for r in rows], w, label=name, color=colour)
        a2.bar(x + (k - 1) * w, [get(r, who, "gospa_mean_m") for r in rows], w, label=name, color=colour)
    a1.plot(x, [r["sim"]["noise_rms_m"] for r in rows], "kx", ms=9, label="plot noise RMS")
    a1.plot(x, [r["sim"]["pcrb_pos_rms_m"] for r in rows], "r_", ms=22, mew=2.5, label="PCRB floor")
    a1.axhline(ESASSP_3NM_M / 3.0, color="0.5", ls="--", lw=0.8, label="ESASSP 3 NM / 3")
    a1.set_ylabel("settled horizontal position RMS (m)")
    a2.set_ylabel("GOSPA mean (m, c = 2 km, p = 2)")
    for a in (a1, a2):
        a.set_xticks(x, labels)
        a.grid(True, axis="y", lw=0.3)
        a.set_ylim(0, a.get_ylim()[1] * 1.35)
        a.legend(fontsize=7, loc="upper left", ncol=2)
    fig.suptitle("Accuracy on the same plots")
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


# =========================================================================== command


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Arguments of ``radar-fusion bench``."""
    parser.add_argument("--sizes", type=parse_sizes, default=None,
                        help="comma-separated AIRCRAFTxRADARS (default: 100,1000,4000 × 3,10,30)")
    parser.add_argument("--duration-s", type=float, default=None, help="simulated seconds per size (default 120)")
    parser.add_argument("--seed", type=int, default=0, help="scenario seed (default 0)")
    parser.add_argument("--warmup-s", type=float, default=30.0,
                        help="leave periods of the first N s out of the latency percentiles (default 30)")
    parser.add_argument("--no-gate-compare", action="store_true",
                        help="run with the wild-plot gate on only (default: on and off, issue 4)")
    parser.add_argument("--out", default=None, help="also write a Markdown report here (e.g. reports/bench.md)")
    parser.add_argument("--quick", action="store_true", help="100x3 and 1000x10 only, 60 s")
    parser.add_argument("--profile", type=parse_sizes, default=None, metavar="SIZE",
                        help="instead of the table: cProfile the engine on this size (gate on), "
                             "print the stage summary and the top functions by cumulative time")
    parser.add_argument("--profile-top", type=int, default=30, help="functions listed by --profile (default 30)")
    g = parser.add_argument_group("side by side with Stone Soup (issue 7)")
    g.add_argument("--report", default=None, metavar="DIR",
                   help="run the side-by-side comparison and write DIR/report.md, summary.md, results.json and PNGs "
                        "(default sizes 50x3,100x3,1000x10,4000x30 plus the ADS-B flights)")
    g.add_argument("--compare", action="store_true", help="run the side-by-side comparison, print only")
    g.add_argument("--no-bus", action="store_true", help="comparison without (b), the daemon over Zenoh")
    g.add_argument("--no-reference", action="store_true", help="comparison without (c), Stone Soup")
    g.add_argument("--no-accuracy", action="store_true", help="comparison without the accuracy scoring")
    g.add_argument("--no-adsb", action="store_true", help="comparison without the real ADS-B flights case")
    g.add_argument("--adsb-duration-s", type=float, default=300.0,
                   help="length of the ADS-B case from 11:30 UTC (default 300)")
    g.add_argument("--adsb-aircraft", type=int, default=80, help="at most this many ADS-B flights (default 80)")
    g.add_argument("--latency-speed", type=float, default=1.0,
                   help="replay speed of the end-to-end latency run (default 1 = real time; 0 = skip it)")
    g.add_argument("--bus-timeout-s", type=float, default=600.0,
                   help="give up waiting for the daemon's last TrackBatch after this long (default 600)")
    g.add_argument("--reference-budget-s", type=float, default=600.0,
                   help="Stone Soup time budget per case: sizes estimated above it are skipped, a run is stopped "
                        "there (default 600)")
    g.add_argument("--ss-q", type=float, default=100.0,
                   help="Stone Soup CV spectral density q, m²/s³ (default 100, tuned: see baseline_stonesoup)")
    g.add_argument("--settle-s", type=float, default=30.0,
                   help="accuracy: settled figures leave out each track's first N s (default 30)")


def run(args: argparse.Namespace) -> int:
    duration_s = args.duration_s if args.duration_s is not None else (60.0 if args.quick else 120.0)
    sizes = args.sizes or (QUICK_SIZES if args.quick else DEFAULT_SIZES)
    if duration_s <= args.warmup_s:
        print(f"bench: --duration-s ({duration_s:g}) must exceed --warmup-s ({args.warmup_s:g})", file=sys.stderr)
        return 2
    with tempfile.TemporaryDirectory(prefix="radar-fusion-bench-") as tmp:
        if args.profile:
            return _run_profile(args, args.profile[0], duration_s, tmp)
        if getattr(args, "report", None) or getattr(args, "compare", False):
            return _run_compare(args, COMPARE_SIZES if args.sizes is None else args.sizes, duration_s, tmp)
        return _run_table(args, sizes, duration_s, tmp)


def _run_profile(args: argparse.Namespace, size: tuple[int, int], duration_s: float, tmp: str) -> int:
    n, r = size
    path = os.path.join(tmp, f"{n}x{r}.pkl")
    print(f"bench --profile: simulating {n:,} aircraft × {r} radars, {duration_s:g} s ...", flush=True)
    info = _in_fresh_process(simulate_inputs, n, r, duration_s, args.seed, path)
    print(f"  {info['plots']:,} plots in {info['batches']:,} batches (simulated in {info['sim_s']:.1f} s)", flush=True)
    res = _in_fresh_process(run_engine, path, True, args.warmup_s, args.profile_top)
    prof = res["profile"]
    print(f"\nengine under cProfile: {res['engine_s']:.2f} s ({res['plots_per_s']:,.0f} plots/s with profiler "
          f"overhead), {res['periods']} periods\n")  # fmt: skip
    print("stage                                          calls    cum s   share")
    for label, calls, ct in prof["stages"]:
        print(f"{label:<44} {calls:>8,} {ct:>8.2f} {100 * ct / res['engine_s']:>6.1f} %")
    print()
    print(prof["text"])
    return 0


def _run_table(args: argparse.Namespace, sizes: list[tuple[int, int]], duration_s: float, tmp: str) -> int:
    header = machine_lines()
    print("\n".join(header))
    print(f"engine benchmark: {len(sizes)} sizes, {duration_s:g} s simulated each, seed {args.seed}, "
          f"warm-up {args.warmup_s:g} s left out of the percentiles, safety nets off, "
          f"gate {'on only' if args.no_gate_compare else 'on and off'}", flush=True)  # fmt: skip
    rows = []
    t_bench = time.perf_counter()
    for n, r in sizes:
        path = os.path.join(tmp, f"{n}x{r}.pkl")
        info = _in_fresh_process(simulate_inputs, n, r, duration_s, args.seed, path)
        row = {"aircraft": n, "radars": r, "sim": info}
        row["on"] = _in_fresh_process(run_engine, path, True, args.warmup_s, 0)
        if not args.no_gate_compare:
            row["off"] = _in_fresh_process(run_engine, path, False, args.warmup_s, 0)
        os.unlink(path)
        rows.append(row)
        on = row["on"]
        msg = (f"  {n:>5,} × {r:>2}: {on['plots']:>9,} plots in {info['batches']:,} batches "
               f"({on['plots'] / max(info['batches'], 1):.1f}/batch), {on['periods']} periods, "
               f"gate on {on['engine_s']:.2f} s "
               f"({on['plots_per_s']:,.0f} plots/s, p99 {on['p99_ms']:.1f} ms; TrackBatch build+encode p50/p99 "
               f"{on['msg_p50_ms']:.1f}/{on['msg_p99_ms']:.1f} ms; {on['wild_rejected']:,} wild "
               f"rejected of {info['wild_truth']:,} simulated)")  # fmt: skip
        if row.get("off"):
            msg += f"; gate off {row['off']['engine_s']:.2f} s ({row['off']['plots_per_s']:,.0f} plots/s)"
        print(msg + f"  [simulated in {info['sim_s']:.1f} s]", flush=True)

    table = format_text_table(rows)
    goals = goal_lines(rows)
    scaling = scaling_lines(rows)
    notes = [
        "plots/s, p50/p99, ingest, tracks and RSS are with the wild-plot gate on (the default configuration); "
        "gate on/off = plots/s with the gate / plots/s without it (< 1: the gate costs throughput).",
        f"p50/p99: PeriodOutput.processing_s of the periods after the first {args.warmup_s:g} s "
        f"(about {rows[0]['on']['periods_steady']} periods per size, so p99 is close to the maximum); "
        "warm-up max: the slowest period of the warm-up.",
        "peak RSS: peak resident memory of the fresh engine process during the run "
        f"({rows[0]['on']['peak_source']}); base: resident just before the run "
        "(interpreter, libraries and the decoded input batches).",
    ]
    print()
    print(table)
    print()
    for line in goals + scaling + notes:
        print(line)
    print(f"(benchmark wall time {time.perf_counter() - t_bench:.0f} s)")
    if args.out:
        out = Path(args.out)
        out.parent.mkdir(parents=True, exist_ok=True)
        md = ["# radar-fusion engine benchmark", ""] + [f"- {h}" for h in header] + [
            f"- {duration_s:g} s simulated per size, seed {args.seed}, safety nets off", "",
            format_md_table(rows), "", "## Goals", ""] + [f"- {g}" for g in goals] + [
            "", "## Scaling", ""] + [f"- {s}" for s in scaling] + ["", "## Notes", ""] + [f"- {x}" for x in notes]
        out.write_text("\n".join(md) + "\n")
        print(f"wrote {out}")
    return 0


def main(argv: Optional[Sequence[str]] = None) -> int:
    parser = argparse.ArgumentParser(prog="radar-fusion bench", description=__doc__.split("\n")[0])
    add_arguments(parser)
    return run(parser.parse_args(argv))


if __name__ == "__main__":
    raise SystemExit(main())
