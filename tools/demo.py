"""`radar-fusion demo`: the whole system, once, on a fresh machine, with no arguments.

1. simulate a 3-radar scenario with ≥ 24 aircraft (turns, climbs, crossings, close pairs);
2. start the fusion daemon on an embedded Zenoh router (127.0.0.1, a free port);
3. replay the simulated plots through the bus as fast as the bus takes them;
4. record the published track batches and alerts;
5. score the tracks against the truth and print the table; write a PNG.

With ``--display`` it is a live picture instead: the daemon, the situation display
(``radar-fusion display``) beside it, and the scenario replayed at ``--speed`` (default
4× in this mode) in a loop until Ctrl-C; the plain demo is unchanged.
"""

from __future__ import annotations

import argparse
import socket
import time
from pathlib import Path

import msgpack


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--out", default="out/demo", help="directory for the recording, truth, tracks and plot (default out/demo)"
    )
    p.add_argument("--scenario", default="demo", help="simulator preset (default demo)")
    p.add_argument("--seed", type=int, default=1, help="random seed of the simulation (default 1)")
    p.add_argument(
        "--speed", default=None, help="replay speed: max or a factor such as 50 (default max; with --display 4)"
    )
    p.add_argument(
        "--display",
        action="store_true",
        help="start the situation display beside the demo, print its URL and loop the scenario until Ctrl-C",
    )
    p.add_argument(
        "--listen", default="127.0.0.1:8080", help="with --display: HOST:PORT of the web page (default 127.0.0.1:8080)"
    )


def free_tcp_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class TrackCollector:
    """Subscribes to the daemon's outputs; keeps decoded track batches and alerts and records them."""

    def __init__(self, session, prefix: str, writer=None):
        self.batches: list[dict] = []
        self.alerts: list[dict] = []
        self.health: list[dict] = []
        self.prefix = prefix
        self.writer = writer
        self._subs = [
            session.declare_subscriber(f"{prefix}/fusion/tracks", self._on_tracks),
            session.declare_subscriber(f"{prefix}/fusion/alerts/*", self._on_alert),
            session.declare_subscriber(f"{prefix}/fusion/health", self._on_health),
        ]

    def _record(self, sample) -> bytes:
        payload = sample.payload.to_bytes()
        if self.writer is not None:
            self.writer.write(time.time(), str(sample.key_expr)[len(self.prefix) + 1 :], payload)
        return payload

    def _on_tracks(self, sample) -> None:
        self.batches.append(msgpack.unpackb(self._record(sample), raw=False))

    def _on_alert(self, sample) -> None:
        self.alerts.append(msgpack.unpackb(self._record(sample), raw=False))

    def _on_health(self, sample) -> None:
        self.health.append(msgpack.unpackb(sample.payload.to_bytes(), raw=False))

    def close(self) -> None:
        for sub in self._subs:
            sub.undeclare()
        if self.writer is not None:
            self.writer.close()


def wait_until(predicate, timeout_s: float, step_s: float = 0.05) -> bool:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(step_s)
    return predicate()


def run_pipeline(settings, plots_recording: Path, speed=None, tracks_recording: Path | None = None):
    """Daemon on an embedded router + replay through a client session; returns (collector, daemon, sent)."""
    from radar_fusion.bus import FusionDaemon, open_session, zenoh_config

    from ..recording import RecordingWriter, read_recording
    from .replay import replay_records

    daemon = FusionDaemon(settings).start()
    session = open_session(zenoh_config("client", connect=list(settings.bus.listen)))
    writer = RecordingWriter(tracks_recording, meta={"prefix": settings.bus.prefix}) if tracks_recording else None
    collector = TrackCollector(session, settings.bus.prefix, writer)
    try:
        time.sleep(0.3)  # let the subscriptions propagate through the router
        sent = replay_records(session, read_recording(plots_recording), settings.bus.prefix, speed)
        n_sent = sum(sent.values())
        wait_until(lambda: daemon.messages_processed >= n_sent, timeout_s=60)
        daemon.stop()  # drains, flushes the open periods and publishes them
        wait_until(lambda: len(collector.batches) >= daemon.batches_published, timeout_s=10)
    finally:
        if not daemon.stopped.is_set():
            daemon.stop()
        collector.close()
        session.close()
    return collector, daemon, n_sent


def run(args: argparse.Namespace) -> int:
    from radar_fusion.config import load_settings

    from . import evaluate as ev
    from . import simulate as sim
    from .replay import parse_speed

    if args.display:
        from .demo_display import run_display

        return run_display(args)
    speed = args.speed or "max"
    t_start = time.perf_counter()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    print(f"[1/4] simulating scenario '{args.scenario}' (seed {args.seed}) ...")
    simulation = sim.simulate(sim.preset(args.scenario, seed=args.seed))
    sim.write_outputs(simulation, out)
    settings = load_settings(out / "config.toml")
    port = free_tcp_port()
    settings = settings.model_copy(
        update={"bus": settings.bus.model_copy(update={"mode": "router", "listen": [f"tcp/127.0.0.1:{port}"]})}
    )
    n_radars, n_targets = len(settings.radars), len(set(simulation.truth.target_id.tolist()))
    print(f"      {n_radars} radars, {n_targets} aircraft, {len(simulation.messages)} messages -> {out}/plots.rec")
    print(f"[2/4] fusion daemon on an embedded Zenoh router at tcp/127.0.0.1:{port}; replaying at speed {speed} ...")
    t_replay = time.perf_counter()
    collector, daemon, n_sent = run_pipeline(settings, out / "plots.rec", parse_speed(speed), out / "tracks.rec")
    dt_replay = time.perf_counter() - t_replay
    health = daemon.health_message()
    c = health["counters"]
    print(
        f"      {n_sent} messages in {dt_replay:.1f} s; plots accepted {c.get('plots_accepted', 0)}, "
        f"wild {c.get('plots_wild', 0)}, rejected {sum(health['rejected'].values())}; "
        f"{len(collector.batches)} track batches, {len(collector.alerts)} alert messages"
    )
    print(f"      period processing p50 {health['processing_ms_p50']:.1f} ms, p99 {health['processing_ms_p99']:.1f} ms")
    print("[3/4] evaluating tracks against truth ...")
    truth = ev.load_truth(out / "truth.csv")
    scores = ev.evaluate(collector.batches, truth)
    print(ev.format_table(scores))
    if collector.alerts:
        print("alerts (new):")
        for a in collector.alerts:
            if a.get("status") == "new":
                extra = {
                    k: round(v, 1) if isinstance(v, float) else v
                    for k, v in a.items()
                    if k
                    in (
                        "time_to_cpa_s",
                        "min_sep_m",
                        "min_vsep_ft",
                        "area_id",
                        "time_to_entry_s",
                        "time_to_violation_s",
                        "min_alt_ft",
                    )
                    and v is not None
                }
                print(f"  {a['kind'].upper():5} tracks {a['track_ids']} at t={a['t']:.0f} {extra}")
    print("[4/4] plotting ...")
    ev.plot(collector.batches, truth, out / "tracks.png")
    print(f"      {out}/tracks.png, {out}/tracks.rec")
    print(f"demo finished in {time.perf_counter() - t_start:.1f} s")
    return 0
