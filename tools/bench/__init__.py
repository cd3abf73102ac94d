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

World scale (issue 16 item 4): ``radar-fusion bench --sizes 4000x10,20000x30
--no-gate-compare`` (about a minute at 120 s) adds, per size, the period p99 as a share
of the period and how many times faster than real time the engine ran (simulated
seconds / engine seconds), and for 20,000 × 30 a verdict: every period, the warm-up's
included, processed within the period, with the peak RSS and the resident memory after
the warm-up and at the end (flat: memory bounded). The daemon's end-to-end figures at
that size: ``--compare --sizes 20000x30 --no-reference --no-accuracy --no-adsb`` (3-4
minutes at 60 s). Neither is in the default sizes.

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
command refreshes all of it. See :data:`.report.COMPARE_NOTES` for the exact definitions.

Modules: this one is the command; :mod:`.engine_run` the engine's jobs (inputs, timed
run, profile), :mod:`.compare` the side-by-side jobs (daemon over Zenoh, Stone Soup,
accuracy, PCRB), :mod:`.report` the tables, goals, Markdown report and PNGs.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path

from .compare import COMPARE_SIZES, run_compare, run_wild_twin
from .engine_run import in_fresh_process, run_engine, simulate_inputs
from .report import format_md_table, format_text_table, goal_lines, machine_lines, scaling_lines

DEFAULT_SIZES = [(a, r) for a in (100, 1000, 4000) for r in (3, 10, 30)]
QUICK_SIZES = [(100, 3), (1000, 10)]


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


# =========================================================================== command


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Arguments of ``radar-fusion bench``."""
    parser.add_argument(
        "--sizes",
        type=parse_sizes,
        default=None,
        help="comma-separated AIRCRAFTxRADARS (default: 100,1000,4000 × 3,10,30)",
    )
    parser.add_argument("--duration-s", type=float, default=None, help="simulated seconds per size (default 120)")
    parser.add_argument("--seed", type=int, default=0, help="scenario seed (default 0)")
    parser.add_argument(
        "--warmup-s",
        type=float,
        default=30.0,
        help="leave periods of the first N s out of the latency percentiles (default 30)",
    )
    parser.add_argument(
        "--no-gate-compare",
        action="store_true",
        help="run with the wild-plot gate on only (default: on and off, issue 4)",
    )
    parser.add_argument("--out", default=None, help="also write a Markdown report here (e.g. reports/bench.md)")
    parser.add_argument("--quick", action="store_true", help="100x3 and 1000x10 only, 60 s")
    parser.add_argument(
        "--profile",
        type=parse_sizes,
        default=None,
        metavar="SIZE",
        help="instead of the table: cProfile the engine on this size (gate on), "
        "print the stage summary and the top functions by cumulative time",
    )
    parser.add_argument("--profile-top", type=int, default=30, help="functions listed by --profile (default 30)")
    g = parser.add_argument_group("side by side with Stone Soup (issue 7)")
    g.add_argument(
        "--report",
        default=None,
        metavar="DIR",
        help="run the side-by-side comparison and write DIR/report.md, summary.md, results.json and PNGs "
        "(default sizes 50x3,100x3,1000x10,4000x30 plus the ADS-B flights)",
    )
    g.add_argument("--compare", action="store_true", help="run the side-by-side comparison, print only")
    g.add_argument("--no-bus", action="store_true", help="comparison without (b), the daemon over Zenoh")
    g.add_argument("--no-reference", action="store_true", help="comparison without (c), Stone Soup")
    g.add_argument("--no-accuracy", action="store_true", help="comparison without the accuracy scoring")
    g.add_argument("--no-adsb", action="store_true", help="comparison without the real ADS-B flights case")
    g.add_argument(
        "--adsb-duration-s", type=float, default=300.0, help="length of the ADS-B case from 11:30 UTC (default 300)"
    )
    g.add_argument("--adsb-aircraft", type=int, default=80, help="at most this many ADS-B flights (default 80)")
    g.add_argument(
        "--sectors",
        type=int,
        default=None,
        help="every simulated radar publishes this many sector messages (plot batches) per turn "
        "(default: the scenario's, 16-32); fewer, longer sectors make the data older at a display",
    )
    g.add_argument(
        "--latency-speed",
        type=float,
        default=1.0,
        help="replay speed of the end-to-end latency run (default 1 = real time; 0 = skip it)",
    )
    g.add_argument(
        "--safety-nets",
        choices=("child", "in-process", "external"),
        default="child",
        help="(b): where the daemon runs the safety nets (serve --safety-nets; default child, serve's default)",
    )
    g.add_argument(
        "--bus-timeout-s",
        type=float,
        default=600.0,
        help="give up waiting for the daemon's last TrackBatch after this long (default 600)",
    )
    g.add_argument(
        "--reference-budget-s",
        type=float,
        default=600.0,
        help="Stone Soup time budget per case: sizes estimated above it are skipped, a run is stopped "
        "there (default 600)",
    )
    g.add_argument(
        "--ss-q",
        type=float,
        default=100.0,
        help="Stone Soup CV spectral density q, m²/s³ (default 100, tuned: see baseline_stonesoup)",
    )
    g.add_argument(
        "--wild-twin",
        type=float,
        default=None,
        metavar="PROB",
        help="instead: each size with this wild-plot probability against its clean twin (the same simulation "
        "without the gross errors), accuracy side by side (issue 15 item 7; default sizes 1000x10)",
    )
    g.add_argument(
        "--settle-s",
        type=float,
        default=30.0,
        help="accuracy: settled figures leave out each track's first N s (default 30)",
    )


def run(args: argparse.Namespace) -> int:
    duration_s = args.duration_s if args.duration_s is not None else (60.0 if args.quick else 120.0)
    sizes = args.sizes or (QUICK_SIZES if args.quick else DEFAULT_SIZES)
    if duration_s <= args.warmup_s:
        print(f"bench: --duration-s ({duration_s:g}) must exceed --warmup-s ({args.warmup_s:g})", file=sys.stderr)
        return 2
    with tempfile.TemporaryDirectory(prefix="radar-fusion-bench-") as tmp:
        if args.profile:
            return _run_profile(args, args.profile[0], duration_s, tmp)
        if getattr(args, "wild_twin", None) is not None:
            return run_wild_twin(args, args.sizes or [(1000, 10)], duration_s, tmp)
        if getattr(args, "report", None) or getattr(args, "compare", False):
            return run_compare(args, COMPARE_SIZES if args.sizes is None else args.sizes, duration_s, tmp)
        return _run_table(args, sizes, duration_s, tmp)


def _run_profile(args: argparse.Namespace, size: tuple[int, int], duration_s: float, tmp: str) -> int:
    n, r = size
    path = os.path.join(tmp, f"{n}x{r}.pkl")
    print(f"bench --profile: simulating {n:,} aircraft × {r} radars, {duration_s:g} s ...", flush=True)
    info = in_fresh_process(simulate_inputs, n, r, duration_s, args.seed, path)
    print(f"  {info['plots']:,} plots in {info['batches']:,} batches (simulated in {info['sim_s']:.1f} s)", flush=True)
    res = in_fresh_process(run_engine, path, True, args.warmup_s, args.profile_top)
    prof = res["profile"]
    print(
        f"\nengine under cProfile: {res['engine_s']:.2f} s ({res['plots_per_s']:,.0f} plots/s with profiler "
        f"overhead), {res['periods']} periods\n"
    )
    print("stage                                          calls    cum s   share")
    for label, calls, ct in prof["stages"]:
        print(f"{label:<44} {calls:>8,} {ct:>8.2f} {100 * ct / res['engine_s']:>6.1f} %")
    print()
    print(prof["text"])
    return 0


def _run_table(args: argparse.Namespace, sizes: list[tuple[int, int]], duration_s: float, tmp: str) -> int:
    header = machine_lines()
    print("\n".join(header))
    print(
        f"engine benchmark: {len(sizes)} sizes, {duration_s:g} s simulated each, seed {args.seed}, "
        f"warm-up {args.warmup_s:g} s left out of the percentiles, safety nets off, "
        f"gate {'on only' if args.no_gate_compare else 'on and off'}",
        flush=True,
    )
    rows = []
    t_bench = time.perf_counter()
    for n, r in sizes:
        path = os.path.join(tmp, f"{n}x{r}.pkl")
        info = in_fresh_process(simulate_inputs, n, r, duration_s, args.seed, path)
        row = {"aircraft": n, "radars": r, "sim": info}
        row["on"] = in_fresh_process(run_engine, path, True, args.warmup_s, 0)
        if not args.no_gate_compare:
            row["off"] = in_fresh_process(run_engine, path, False, args.warmup_s, 0)
        os.unlink(path)
        rows.append(row)
        on = row["on"]
        msg = (
            f"  {n:>5,} × {r:>2}: {on['plots']:>9,} plots in {info['batches']:,} batches "
            f"({on['plots'] / max(info['batches'], 1):.1f}/batch), {on['periods']} periods, "
            f"gate on {on['engine_s']:.2f} s "
            f"({on['plots_per_s']:,.0f} plots/s, p99 {on['p99_ms']:.1f} ms; TrackBatch build+encode p50/p99 "
            f"{on['msg_p50_ms']:.1f}/{on['msg_p99_ms']:.1f} ms; {on['wild_rejected']:,} wild "
            f"rejected of {info['wild_truth']:,} simulated)"
        )
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
        md = (
            ["# radar-fusion engine benchmark", ""]
            + [f"- {h}" for h in header]
            + [
                f"- {duration_s:g} s simulated per size, seed {args.seed}, safety nets off",
                "",
                format_md_table(rows),
                "",
                "## Goals",
                "",
            ]
            + [f"- {g}" for g in goals]
            + ["", "## Scaling", ""]
            + [f"- {s}" for s in scaling]
            + ["", "## Notes", ""]
            + [f"- {x}" for x in notes]
        )
        out.write_text("\n".join(md) + "\n")
        print(f"wrote {out}")
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="radar-fusion bench", description=__doc__.split("\n")[0])
    add_arguments(parser)
    return run(parser.parse_args(argv))
