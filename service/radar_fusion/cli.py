"""The `radar-fusion` command: the daemon and its tools, one subcommand each.

    radar-fusion demo                       the whole system on a simulated scenario, in one go
    radar-fusion serve --config FILE        the fusion daemon (and its safety-nets child)
    radar-fusion safety-nets --config FILE  STCA / APW / MSAW on the tracks topic, as their own process
    radar-fusion display --config FILE      the live situation display in a browser
    radar-fusion simulate ...               write a recording of simulated radar plots + truth
    radar-fusion replay FILE ...            publish a recording to the bus
    radar-fusion record --out FILE ...      write what the bus carries to a recording
    radar-fusion evaluate ...               score recorded tracks against truth
    ...

Run any subcommand with --help for its options.
"""

from __future__ import annotations

import argparse
import gc
import importlib
import logging
import math
import os
import signal
import sys
import threading
from typing import Any


def positive_float(text: str) -> float:
    """An argparse type: a finite number above 0 (NaN, 0 and negatives refused when parsed)."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"{text!r}: must be a finite number above 0")
    return value


#: the daemons: an exception of theirs is a crash their supervisor restarts (systemd stops
#: restarting on exit code 2, a configuration error), never a one-line tool error
LONG_RUNNING = frozenset({"serve", "safety-nets", "display"})

# subcommand: (module, add-arguments function, run function, one-line help)
SUBCOMMANDS = {
    "demo": (
        "radar_fusion.tools.demo",
        "add_arguments",
        "run",
        "run the whole system once on a simulated 3-radar scenario and print its accuracy",
    ),
    "serve": (
        "radar_fusion.cli",
        "_serve_arguments",
        "_serve",
        "run the fusion daemon (embedded Zenoh router by default)",
    ),
    "safety-nets": (
        "radar_fusion.safety_nets.process",
        "add_arguments",
        "run",
        "STCA, APW and MSAW as a consumer of the tracks: alerts and their own health (serve starts one by default)",
    ),
    "display": (
        "radar_fusion.display.command",
        "add_arguments",
        "run",
        "the live situation display in a browser: tracks, alerts and health from the bus over a WebSocket",
    ),
    "simulate": (
        "radar_fusion.tools.simulate",
        "add_arguments",
        "run",
        "simulate radars over flight plans or real ADS-B flights; write plots, truth and a config",
    ),
    "replay": (
        "radar_fusion.tools.replay",
        "add_arguments",
        "run",
        "publish a recording to the bus at recorded speed, scaled, or as fast as possible",
    ),
    "record": (
        "radar_fusion.tools.record",
        "add_arguments",
        "run",
        "subscribe to bus keys and write what arrives to a recording",
    ),
    "evaluate": (
        "radar_fusion.tools.evaluate",
        "add_arguments",
        "run",
        "score recorded tracks against truth (RMS, GOSPA, continuity) and plot them",
    ),
    "bench": (
        "radar_fusion.tools.bench",
        "add_arguments",
        "run",
        "benchmark the engine (plots/s, period latency, memory) on growing scenarios",
    ),
    "outliers": (
        "radar_fusion.tools.outlier_experiment",
        "add_arguments",
        "run",
        "reproduce Hu 2013's wild-plot experiment: soft-weighted vs K-MODF vs 3-sigma gate",
    ),
    "clean": (
        "radar_fusion.tools.clean",
        "add_arguments",
        "run",
        "remove wild plots from a recording per radar track (Hu 2013); write it and a report",
    ),
    "safety-eval": (
        "radar_fusion.tools.safety_eval",
        "add_arguments",
        "run",
        "evaluate STCA / APW / MSAW on scenarios with and without conflicts",
    ),
    "asterix-in": (
        "radar_fusion.tools.asterix_bridge",
        "add_arguments_in",
        "run_in",
        "feed ASTERIX CAT048/CAT034 (UDP or files) onto the bus",
    ),
    "asterix-out": (
        "radar_fusion.tools.asterix_bridge",
        "add_arguments_out",
        "run_out",
        "write the fused tracks as ASTERIX CAT062 (UDP or file)",
    ),
    "soak": (
        "radar_fusion.tools.soak",
        "add_arguments",
        "run",
        "replay a long recording through the daemon as fast as it takes it; check no loss, flat memory, no drift",
    ),
    "fuzz": (
        "radar_fusion.tools.fuzz",
        "add_arguments",
        "run",
        "hostile traffic (default 100,000 messages) over a real Zenoh bus into the daemon; check nothing is lost",
    ),
    "identity": (
        "radar_fusion.tools.identity",
        "add_arguments",
        "run",
        "Mode S identity of the tracks on an ASTERIX recording (default the Barcelona hour): ids per segment",
    ),
    "schemas": ("radar_fusion.cli", "_schemas_arguments", "_schemas", "write the wire contract's JSON Schema files"),
}


def _serve_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--config", required=True, help="daemon configuration TOML file (see deploy/*.toml)")
    p.add_argument("--log-level", default="INFO", help="DEBUG, INFO, WARNING, ERROR (default INFO)")
    p.add_argument(
        "--log-format",
        choices=("text", "json"),
        default="text",
        help="text (default) or json: one JSON object per line (time, level, logger, message, extra fields)",
    )
    p.add_argument(
        "--safety-nets",
        choices=("child", "in-process", "external"),
        default=None,
        help="where the safety nets run (default: [safety_nets] process, itself default child): child = "
        "`radar-fusion safety-nets` as a supervised child process; in-process = on the daemon's processing "
        "thread; external = none here (run `radar-fusion safety-nets` elsewhere)",
    )
    p.add_argument(
        "--state-dir",
        default=None,
        help="keep the tracks across a restart: write the engine's state here after the periods it "
        "publishes and read it back at start (same configuration; engine/state.py)",
    )
    p.add_argument(
        "--state-interval-s",
        type=float,
        default=0.0,
        help="write the state at most this often, wall clock (default 0: after every period)",
    )
    p.add_argument(
        "--timing-log",
        default=None,
        help="write one JSON line per published period to this file: monotonic timestamps of its path "
        "through the daemon, from the input that closed it to the TrackBatch's put (radar-fusion bench)",
    )


def _serve_preflight(settings: Any, args: argparse.Namespace) -> str | None:
    """What would make serve fail after it started, asked before: the safety nets' maps (in
    a child they died at every start, serve running on without STCA, APW and MSAW), and a
    state directory that cannot be written (every period's save failed)."""
    from pathlib import Path

    mode = args.safety_nets.replace("-", "_") if args.safety_nets else settings.safety_nets.process
    if mode != "external":
        from .safety_nets.nets import check_maps

        problem = check_maps(settings, Path(args.config).resolve().parent)
        if problem is not None:
            return problem
    if args.state_dir is not None:
        probe = Path(args.state_dir) / ".write-test"
        try:
            probe.parent.mkdir(parents=True, exist_ok=True)
            probe.write_bytes(b"")
            probe.unlink()
        except OSError as exc:
            return f"--state-dir {args.state_dir}: cannot be written: {exc.strerror or exc}"
    return None


def _serve(args: argparse.Namespace) -> int:
    from .bus import FusionDaemon
    from .config import ConfigError, load_settings
    from .metrics import configure_logging

    configure_logging(args.log_level, args.log_format)
    try:
        settings = load_settings(args.config)
    except ConfigError as exc:
        print(f"configuration error, not starting:\n{exc}", file=sys.stderr)
        return 2
    from pathlib import Path

    problem = _serve_preflight(settings, args)
    if problem is not None:
        print(f"configuration error, not starting:\n{problem}", file=sys.stderr)
        return 2
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())

    import zenoh

    daemon = FusionDaemon(
        settings,
        base_dir=Path(args.config).resolve().parent,
        state_dir=None if args.state_dir is None else Path(args.state_dir),
        state_interval_s=args.state_interval_s,
        safety_nets=args.safety_nets,
        timing_log=None if args.timing_log is None else Path(args.timing_log),
        log_format=args.log_format,
    )
    if daemon.tracks_restored is not None:
        logging.getLogger("radar_fusion").info("restored %d tracks from %s", daemon.tracks_restored, args.state_dir)
    try:
        daemon.start()
    except zenoh.ZError as exc:  # the listen port is taken, no router at the connect endpoints, ...
        print(f"cannot open the Zenoh session (bus mode {settings.bus.mode}), not starting:\n{exc}", file=sys.stderr)
        daemon.stop(timeout_s=1.0)
        return 3
    except OSError as exc:  # the metrics endpoint's port is taken (or the timing log cannot be written)
        print(f"cannot start ({exc.strerror or exc}), not starting", file=sys.stderr)
        daemon.stop(timeout_s=1.0)
        return 3
    # Latency: move everything loaded so far (modules, config, the session) out of the
    # garbage collector's reach, so its full passes only walk what the periods create
    # (a full pass over the ~10^5 start-up objects showed as 50-100 ms period spikes).
    gc.collect()
    gc.freeze()
    try:
        while not stop.wait(0.5):
            pass
    finally:
        logging.getLogger("radar_fusion").info("stopping: flushing open periods")
        daemon.stop()
    return 0


def _schemas_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", default="schemas", help="directory for the *.schema.json files (default ./schemas)")


def _schemas(args: argparse.Namespace) -> int:
    from .schemas import write_schemas

    for path in write_schemas(args.out):
        print(path)
    return 0


def build_parser(only: str | None = None) -> argparse.ArgumentParser:
    """The parser; with ``only``, the arguments of that subcommand alone, so that starting
    one (the daemon above all) does not import every other tool (seconds on a small machine)."""
    parser = argparse.ArgumentParser(
        prog="radar-fusion",
        description="Multi-radar data fusion and tracking for air traffic control, on an Eclipse Zenoh bus.",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog="Start with `radar-fusion demo`. Each subcommand has its own --help.",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for name, (module, add_fn, run_fn, help_text) in SUBCOMMANDS.items():
        if only is not None and name != only:
            sub.add_parser(name, help=help_text, description=help_text)
            continue
        p = sub.add_parser(name, help=help_text, description=help_text)
        mod = importlib.import_module(module)
        getattr(mod, add_fn)(p)
        p.set_defaults(_run=(module, run_fn))
    return parser


def one_blas_thread() -> None:
    """Process-wide: one BLAS thread. The engine's linear algebra is thousands of tiny
    matrices, for which OpenBLAS's worker threads only contend (measured on 2 cores: a
    (6×30)·(30×4,000) product takes 0.19 ms on one thread, 2.4 ms on two). numpy is
    imported first: threadpoolctl limits only the libraries already loaded."""
    import numpy  # noqa: F401  # loads OpenBLAS, so that the limit below applies to it
    from threadpoolctl import threadpool_limits

    threadpool_limits(limits=1, user_api="blas")


# glibc's mallopt parameters (malloc.h)
_M_TRIM_THRESHOLD = -1
_M_MMAP_THRESHOLD = -3


def reuse_freed_memory() -> None:
    """Process-wide, with glibc: freed blocks of up to 32 MiB stay in the heap for the
    next allocation instead of going back to the kernel. Each step of a period makes
    numpy temporaries of 0.1-10 MB (a stack of 6×6 covariances is 1.2 MB at 4,000
    tracks); above glibc's default threshold (128 kB, adapting upwards only as far as the
    largest block freed so far) each was a fresh mmap whose pages the kernel faulted in
    and zeroed at first touch, and unmapped again when freed. Measured at 4,000 aircraft ×
    10 radars, one engine run: 227,000 → 42,000 page faults, engine CPU time about 0.75×.
    The heap keeps up to 256 MiB free at its top before it is trimmed. Elsewhere (no
    glibc) nothing changes."""
    import ctypes
    import ctypes.util

    try:
        mallopt = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6").mallopt
    except (OSError, AttributeError):
        return
    mallopt.argtypes = [ctypes.c_int, ctypes.c_int]
    mallopt.restype = ctypes.c_int
    mallopt(_M_MMAP_THRESHOLD, 32 << 20)  # glibc's largest allowed on 64-bit
    mallopt(_M_TRIM_THRESHOLD, 256 << 20)


def process_settings() -> None:
    """Every process-wide setting of a radar-fusion process: :func:`one_blas_thread`,
    :func:`reuse_freed_memory` (the garbage collector's freeze is the daemon's, after
    start-up)."""
    one_blas_thread()
    reuse_freed_memory()


def main(argv: list[str] | None = None) -> int:
    process_settings()
    argv = sys.argv[1:] if argv is None else list(argv)
    only = argv[0] if argv and argv[0] in SUBCOMMANDS else None
    args = build_parser(only).parse_args(argv)
    module, run_fn = args._run
    if args.command in LONG_RUNNING:
        return int(getattr(importlib.import_module(module), run_fn)(args) or 0)
    try:
        return int(getattr(importlib.import_module(module), run_fn)(args) or 0)
    except KeyboardInterrupt:
        return 130
    except Exception as exc:  # a tool's input not what it should be: said in a line, not a traceback
        if os.environ.get("RADAR_FUSION_TRACEBACK"):
            raise
        print(
            f"radar-fusion {args.command}: {type(exc).__name__}: {exc}\n(RADAR_FUSION_TRACEBACK=1 shows where)",
            file=sys.stderr,
        )
        return 2 if isinstance(exc, OSError | ValueError | EOFError) else 1


if __name__ == "__main__":
    sys.exit(main())
