"""`radar-fusion replay`: publish a recording to the bus, keeping its event-time order.

Messages go out in recording order with the recorded gaps between them divided by
``--speed`` (``max``: no waiting). Messages are sent reliably with congestion control BLOCK,
so a burst is slowed down by the bus rather than silently dropped (DESIGN.md §3).
"""

from __future__ import annotations

import argparse
import sys
import time
from collections import Counter
from collections.abc import Iterable

from ..recording import Record, read_recording


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("file", help="recording to publish (from `simulate`, `record` or `asterix-in --out`)")
    p.add_argument(
        "--speed", default="1", help="time scale: 1 = as recorded, 50 = fifty times faster, max = no waiting"
    )
    p.add_argument("--config", help="daemon config: connect to its bus endpoints and use its prefix")
    p.add_argument("--connect", action="append", help="Zenoh endpoint to connect to (default tcp/127.0.0.1:7447)")
    p.add_argument("--prefix", help="key prefix (default: the config's, else 'atc')")
    p.add_argument("--only", default="radar/", help="publish only keys starting with this (default radar/)")
    p.add_argument(
        "--force",
        action="store_true",
        help="replay a recording whose header names another site than --config's (its centre far away, none of "
        "its radars configured)",
    )


#: a recording centred farther than this from the config's centre is of another site
OTHER_SITE_M = 200_000.0


def other_site(file: str, config_path: str) -> str | None:
    """Why the recording ``file`` is not of ``config_path``'s site, from its header (what
    ``simulate`` writes: centre and radars), or None. Replayed into another site's daemon,
    its plots were taken by the radars of the same name there: tracks 16,600 km from their
    aircraft, and nothing said."""
    from radar_fusion.config import load_settings
    from radar_fusion.geo.coordinates import WGS84_GEOD
    from radar_fusion.recording import read_header

    meta = read_header(file).get("meta") or {}
    settings = load_settings(config_path)
    ids = {r.id for r in settings.radars}
    radars = meta.get("radars")
    if isinstance(radars, list) and radars and not ids & set(map(str, radars)):
        return f"{file}: its radars {radars} are none of the config's {sorted(ids)}"
    lat, lon = meta.get("center_lat"), meta.get("center_lon")
    if isinstance(lat, int | float) and isinstance(lon, int | float):
        c = settings.system
        _, _, dist_m = WGS84_GEOD.inv(c.center_lon, c.center_lat, float(lon), float(lat))
        if dist_m > OTHER_SITE_M:
            return (
                f"{file}: recorded for a site centred at ({lat}, {lon}), {dist_m / 1000:,.0f} km from the config's "
                f"centre ({c.center_lat}, {c.center_lon})"
            )
    return None


def parse_speed(text: str) -> float | None:
    if text == "max":
        return None
    speed = float(text)
    if not speed > 0:
        raise ValueError("--speed must be > 0 or 'max'")
    return speed


def replay_records(
    session, records: Iterable[Record], prefix: str, speed: float | None, only: str = "radar/", progress_total: int = 0
) -> Counter:
    """Publish records on ``session``; returns messages sent per key."""
    from radar_fusion.bus import Sender, reliable_sender

    pubs: dict[str, Sender] = {}
    sent: Counter = Counter()
    t0_rec = t0_wall = None
    show = progress_total > 0 and sys.stderr.isatty()
    try:
        for i, rec in enumerate(records):
            if not rec.key.startswith(only):
                continue
            if speed is not None:
                if t0_rec is None or t0_wall is None:  # both None until the first record
                    t0_rec, t0_wall = rec.t_s, time.monotonic()
                wait = t0_wall + (rec.t_s - t0_rec) / speed - time.monotonic()
                if wait > 0:
                    time.sleep(wait)
            pub = pubs.get(rec.key)
            if pub is None:
                pub = pubs[rec.key] = reliable_sender(session, f"{prefix}/{rec.key}")
            pub.put(rec.payload)
            sent[rec.key] += 1
            if show and i % 200 == 0:
                frac = i / progress_total
                print(f"\rreplay [{'#' * int(40 * frac):<40}] {100 * frac:5.1f}%", end="", file=sys.stderr)
    finally:
        if show:
            print(f"\rreplay [{'#' * 40}] 100.0%", file=sys.stderr)
    return sent


def run(args: argparse.Namespace) -> int:
    from radar_fusion.bus import open_session, tool_client_config

    speed = parse_speed(args.speed)
    if args.config and not args.force and (why := other_site(args.file, args.config)) is not None:
        print(f"replay: {why}; not replaying it (--force does)", file=sys.stderr)
        return 2
    cfg, prefix = tool_client_config(args.config, args.connect, args.prefix)
    total = sum(1 for _ in read_recording(args.file)) if sys.stderr.isatty() else 0
    session = open_session(cfg)
    try:
        sent = replay_records(session, read_recording(args.file), prefix, speed, args.only, total)
    finally:
        session.close()
    per_radar: Counter = Counter()
    for key, n in sent.items():
        per_radar[key] += n
    print(f"sent {sum(sent.values())} messages")
    for key in sorted(per_radar):
        print(f"  {prefix}/{key}: {per_radar[key]}")
    return 0


def ingest_record(engine, key: str, payload: bytes) -> None:
    """One recorded message into an Engine, decoded as the daemon decodes it (a refused one
    is counted by reason; a key that is neither plots nor status is ignored)."""
    from radar_fusion.wire import RadarStatus, Rejection, decode_message, decode_plot_batch

    if key.endswith("/plots"):
        plots = decode_plot_batch(payload)
        if isinstance(plots, Rejection):
            engine.reject(plots.reason)
        else:
            engine.ingest_plots(plots)
    elif key.endswith("/status"):
        status = decode_message(payload, RadarStatus)
        if isinstance(status, Rejection):
            engine.reject(status.reason)
        else:
            engine.ingest_status(status)


def replay_into_engine(engine, records: Iterable[tuple[float, str, bytes]], flush: bool = True) -> list:
    """Feed (t_s, key, payload) messages to an Engine in process, decoding them as the
    daemon does, polling after each; returns every PeriodOutput including the flush
    (without ``flush``: as a daemon killed after the last message would have left them).
    The same path as the bus minus Zenoh: for tests, experiments and benchmarks."""
    outputs = []
    for _t_s, key, payload in records:
        ingest_record(engine, key, payload)
        outputs += engine.poll()
    return (outputs + engine.flush()) if flush else outputs
