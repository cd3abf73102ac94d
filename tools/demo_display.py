"""`radar-fusion demo --display`: the demo as a live picture, until Ctrl-C.

The daemon on an embedded Zenoh router (127.0.0.1, a free port), the situation display
beside it as one more client of that router, and the simulated scenario replayed in a
loop at ``--speed`` (default 4×: one period a second with the demo's 4 s period).

Each loop shifts the recording's event times by the scenario's length plus
:data:`LOOP_GAP_S` and continues every radar's sequence numbers, so the daemon sees
one radar feed that goes on (loop k+1's plots are neither ``plot_late`` nor
``duplicate``); the aircraft start again from their first positions and the tracks of
the previous loop coast and end. The gap stays below the daemon's ``max_future_s`` so the
first plots of a loop are not refused as implausibly far ahead.

The demo's config gets two fictitious APW volumes and an MSA map (the ones of
``deploy/areas-example.geojson`` and ``deploy/msa-example.geojson``, around the demo's
centre), so that the picture shows them and the safety nets watch them.
"""

from __future__ import annotations

import argparse
import json
import signal
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import msgpack

LOOP_GAP_S = 30.0
"""Event-time gap between two loops of the scenario, seconds."""
DEFAULT_SPEED = 4.0


def _square(lon0: float, lat0: float, lon1: float, lat1: float) -> dict:
    ring = [[lon0, lat0], [lon1, lat0], [lon1, lat1], [lon0, lat1], [lon0, lat0]]
    return {"type": "Polygon", "coordinates": [ring]}


DEMO_AREAS = {
    "type": "FeatureCollection",
    "name": "fictitious APW volumes of the demo (as deploy/areas-example.geojson)",
    "features": [
        {
            "type": "Feature",
            "properties": {"id": "LSR-EX1", "lower_fl": -20, "upper_fl": 95},
            "geometry": _square(8.10, 47.10, 8.35, 47.25),
        },
        {
            "type": "Feature",
            "properties": {"id": "LSD-EX2", "lower_fl": 100, "upper_fl": 200},
            "geometry": _square(7.60, 46.80, 7.80, 46.90),
        },
    ],
}
DEMO_MSA = {
    "type": "FeatureCollection",
    "name": "fictitious minimum safe altitudes of the demo, ft AMSL (as deploy/msa-example.geojson)",
    "features": [
        {
            "type": "Feature",
            "properties": {"id": "PLATEAU-EX", "min_alt_ft": 4500},
            "geometry": _square(7.4, 46.75, 8.6, 47.4),
        },
        {
            "type": "Feature",
            "properties": {"id": "ALPS-EX1", "min_alt_ft": 10000},
            "geometry": _square(7.8, 46.55, 8.2, 46.75),
        },
    ],
}


def shifted(key: str, payload: bytes, dt_s: float, seq_offset: int) -> bytes:
    """A recorded plots or status message moved ``dt_s`` later in event time, its
    sequence number ``seq_offset`` on."""
    obj = msgpack.unpackb(payload, raw=False)
    if key.endswith("/plots"):
        obj["seq"] += seq_offset
        for plot in obj["plots"]:
            plot["t"] += dt_s
    elif key.endswith("/status"):
        obj["t"] += dt_s
    return msgpack.packb(obj, use_bin_type=True)


def looped(records: list, loop: int, span_s: float, seq_span: dict[str, int]) -> Iterator[tuple[float, str, bytes]]:
    """Loop ``loop`` of the recording: (recorded time shifted, key, shifted payload)."""
    dt_s = loop * span_s
    for rec in records:
        if not rec.key.startswith("radar/"):
            continue
        radar = rec.key.split("/")[1]
        payload = rec.payload if loop == 0 else shifted(rec.key, rec.payload, dt_s, loop * seq_span.get(radar, 0))
        yield rec.t_s + dt_s, rec.key, payload


def sequence_spans(records: list) -> dict[str, int]:
    """Per radar, one more than its highest sequence number: the offset of each loop."""
    spans: dict[str, int] = {}
    for rec in records:
        if rec.key.endswith("/plots"):
            radar = rec.key.split("/")[1]
            seq = int(msgpack.unpackb(rec.payload, raw=False)["seq"])
            spans[radar] = max(spans.get(radar, 0), seq + 1)
    return spans


def run_display(args: argparse.Namespace) -> int:
    import sys

    import zenoh

    from radar_fusion.bus import FusionDaemon, Sender, open_session, reliable_sender, zenoh_config
    from radar_fusion.config import load_settings
    from radar_fusion.display import DisplayServer, parse_listen

    from ..recording import read_recording
    from . import simulate as sim
    from .demo import free_tcp_port
    from .replay import parse_speed

    try:
        host, http_port = parse_listen(args.listen)
        speed = parse_speed(args.speed) if args.speed else DEFAULT_SPEED
    except ValueError as exc:
        print(exc, file=sys.stderr)
        return 2
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    print(f"simulating scenario '{args.scenario}' (seed {args.seed}) ...", flush=True)
    simulation = sim.simulate(sim.preset(args.scenario, seed=args.seed))
    sim.write_outputs(simulation, out)
    (out / "areas.geojson").write_text(json.dumps(DEMO_AREAS, indent=1), encoding="utf-8")
    (out / "msa.geojson").write_text(json.dumps(DEMO_MSA, indent=1), encoding="utf-8")
    settings = load_settings(out / "config.toml")
    bus_port = free_tcp_port()
    endpoint = f"tcp/127.0.0.1:{bus_port}"
    settings = settings.model_copy(
        update={
            "bus": settings.bus.model_copy(update={"mode": "router", "listen": [endpoint]}),
            "safety_nets": settings.safety_nets.model_copy(
                update={"areas_file": out / "areas.geojson", "msa_file": out / "msa.geojson"}
            ),
        }
    )
    records = list(read_recording(out / "plots.rec"))
    span_s = max(r.t_s for r in records) - min(r.t_s for r in records) + LOOP_GAP_S
    seq_span = sequence_spans(records)

    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    daemon = FusionDaemon(settings).start()
    display = DisplayServer(settings, host, http_port, zenoh_config("client", connect=[endpoint]), base_dir=out)
    try:
        display.start()
    except (OSError, zenoh.ZError) as exc:
        print(f"cannot start the display on {args.listen}: {exc} (try --listen 127.0.0.1:0)", file=sys.stderr)
        daemon.stop()
        return 3
    session = open_session(zenoh_config("client", connect=[endpoint]))
    pubs: dict[str, Sender] = {}
    loops = 0
    try:
        speed_text = "as fast as possible" if speed is None else f"at {speed:g}x"
        print(f"fusion daemon on an embedded Zenoh router at {endpoint}")
        print(f"situation display: {display.url}")
        print(
            f"replaying {len(settings.radars)} radars, {len(set(simulation.truth.target_id.tolist()))} aircraft "
            f"({span_s - LOOP_GAP_S:.0f} s of traffic) {speed_text}, in a loop; Ctrl-C to stop",
            flush=True,
        )
        time.sleep(0.3)  # the subscriptions reach the router
        t0_wall, t0_rec = time.monotonic(), records[0].t_s
        while not stop.is_set():
            for t_s, key, payload in looped(records, loops, span_s, seq_span):
                if speed is not None:
                    wait_s = t0_wall + (t_s - t0_rec) / speed - time.monotonic()
                    if wait_s > 0 and stop.wait(wait_s):
                        break
                elif stop.is_set():
                    break
                pub = pubs.get(key)
                if pub is None:
                    pub = pubs[key] = reliable_sender(session, f"{settings.bus.prefix}/{key}")
                pub.put(payload)
            else:
                loops += 1
                print(f"loop {loops} done; starting again", flush=True)
    finally:
        session.close()
        display.stop()
        daemon.stop(timeout_s=10.0)
    print(f"stopped after {loops} full loop(s)")
    return 0
