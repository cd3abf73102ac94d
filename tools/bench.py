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
    """``"100x3,1000x10"`` -> [(100, 3), (1000, 10)]."""
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
    radar_index = {r.id: i for i, r in enumerate(scenario.radars)}
    rotation = {r.id: float(r.rotation_period_s) for r in scenario.radars}
    # Publish order as simulate() builds it: by time, a batch before the status of the same
    # sweep, then by radar.
    events: list[tuple] = [(c.t_pub_s, 0, c.radar_index, c.to_decoded()) for c in sim.plot_columns]
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
            "statuses": len(sim.statuses), "sim_s": time.perf_counter() - t0}  # fmt: skip


def run_engine(path: str, gate: bool, warmup_s: float, profile_top: int = 0) -> dict[str, Any]:
    """Load the pickled inputs, run the engine on them and return the figures.

    With ``profile_top`` > 0 the run is under cProfile and the result carries the profile
    (top functions by cumulative time and a per-stage summary) instead of honest timings.
    """
    import tomllib

    import numpy as np

    from radar_fusion import config, wire
    from radar_fusion.engine import Engine
    from radar_fusion.track_management import CONFIRMED

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
    rss_base_kb = _rss_kb("VmRSS")
    hwm_reset = _reset_peak_rss()
    maxrss_before_kb = _maxrss_kb()

    ingest_plots, ingest_status, poll = engine.ingest_plots, engine.ingest_status, engine.poll
    perf = time.perf_counter
    t_ingest = t_status = t_poll = 0.0
    # Keep only each period's figures: holding every TrackBatch (thousands of dicts per
    # period) would make Python's cyclic GC slower and slower and distort the timings.
    periods: list[tuple[float, float, int, int]] = []  # (t_s, processing_ms, plots, tracks)

    def keep(outs) -> None:
        periods.extend((o.t_s, o.processing_s * 1e3, o.n_plots, len(o.track_batch["tracks"])) for o in outs)

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
    ("  wild-plot gate (LiveOutlierGate.filter)", "outliers.py", "filter"),
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
    ("  TrackBatch building (_track_batch)", "engine.py", "_track_batch"),
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


def run(args: argparse.Namespace) -> int:
    duration_s = args.duration_s if args.duration_s is not None else (60.0 if args.quick else 120.0)
    sizes = args.sizes or (QUICK_SIZES if args.quick else DEFAULT_SIZES)
    if duration_s <= args.warmup_s:
        print(f"bench: --duration-s ({duration_s:g}) must exceed --warmup-s ({args.warmup_s:g})", file=sys.stderr)
        return 2
    with tempfile.TemporaryDirectory(prefix="radar-fusion-bench-") as tmp:
        if args.profile:
            return _run_profile(args, args.profile[0], duration_s, tmp)
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
               f"({on['plots_per_s']:,.0f} plots/s, p99 {on['p99_ms']:.1f} ms, {on['wild_rejected']:,} wild "
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
