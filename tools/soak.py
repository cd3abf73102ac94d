"""`radar-fusion soak`: replay a long recording through the daemon as fast as it takes it,
then check that no message was lost, that the daemon's resident memory stayed flat and
that period latency did not drift (issue 8, item 3).

    radar-fusion soak --generate out/soak --duration-s 3600 --aircraft 300    # simulate, then soak
    radar-fusion soak out/soak/plots.rec --config out/soak/config.toml        # soak a recording

The daemon. By default the soak starts ``radar-fusion serve --config CONFIG`` as a child
process on a free loopback port (router mode, health every 0.2 s, through the
``RADAR_FUSION_BUS__*`` environment overrides), so that the resident memory measured
(VmRSS of ``/proc/<pid>/status``, sampled every 0.5 s) is the daemon's alone. With
``--connect ENDPOINT`` it soaks a daemon that is already running instead (``--pid`` for
its memory); counters are then taken relative to their values at the start.

Flow control. The sender tracks each radar's newest time sent and so knows when a period
can close on the daemon's side (every radar past the period's end, as the daemon decides
for radars that deliver in order, engine/watermarks.py; simulated recordings do). It
sends until ``--lead-periods`` periods are closable but their TrackBatch has not come
back, then waits; it also goes on when the health key shows the daemon has processed
everything sent (a period with neither plot nor track publishes nothing). The daemon's
queue thus never holds more than about that many periods of traffic, however fast it is.

Checks (exit status 1 when one fails):
  * loss: per radar, the plot batches, plots, last sequence number and sequence gaps the
    daemon counted equal those sent; messages received = processed = sent; status
    messages counted = sent; no rejection; every TrackBatch published was received,
    periods strictly increasing, none dropped by the daemon's outbox;
  * memory: the daemon's own memory (VmRSS less RssShmem, see below) at the end is within
    max(10 %, 32 MiB) of its value after the first 10 % of the recording (start-up and
    warm-up excluded); VmRSS idle, warm, peak and end, its profile per tenth of the
    recording and the shared-memory part of that profile are reported;
  * latency: period latency = wall time from the send that made a period closable to the
    arrival of its TrackBatch; the p50 of the last 10 % of periods is within 1.5x (+5 ms)
    of the first 10 %'s (p99 is reported, not judged: the machines are shared).

Zenoh's shared memory in the daemon's RSS. Zenoh 1.x (``transport/shared_memory``, on
by default) sends a payload over 3,072 bytes between two sessions of one host through a
16 MiB shared-memory pool of the sender (plus a 1.25 MiB segment), made at its first such
message; the receiver maps it and VmRSS counts it whole (RssShmem), at once. The daemon
shows one pool from the start (its own: TrackBatches are larger than that) and one more
per local session that ever sends it a large message; on another host (radar front-ends
over TCP) there is none. This was the "20 MiB step at about 85 %" of the 3-hour soak
(500 aircraft, 6 radars, seed 1; issue 13): its first plot batch over 3,072 bytes
(3,287 bytes, r05) comes at 88.6 % of the recording, and there VmRSS went 200 -> 218 MiB,
all of it /dev/shm/<id>.zenoh mappings (16.0 + 1.25 MiB in smaps), heap and other
memory unchanged. With the soak's sender's shared memory off, the same run's profile was
192 197 197 203 203 204 204 204 205 205 MiB: no step. With 4 radars the first such batch
comes at 0.1 %, inside the warm-up. The pools are fixed in size and shared with their
sender, not memory the daemon grows, so the check and the slope leave them out and the
report shows them apart.

At the end one heartbeat per radar, a period and the lateness past its last message,
lets the daemon close the last periods without waiting for its idle flush (counted as
status messages sent).
"""

from __future__ import annotations

import argparse
import itertools
import json
import math
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from collections import Counter
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import msgpack
import numpy as np

MIB = 1 << 20


# =========================================================================== traffic


def soak_scenario(n_aircraft: int = 300, duration_s: float = 3600.0, n_radars: int = 4, seed: int = 1):
    """Steady traffic for a soak: about ``n_aircraft`` flights airborne over the covered
    disc at any time, each crossing it from edge to edge, new ones entering all the time,
    so that tracks start and end throughout the run while the track count stays level.

    Radars, disc and traffic mix as :func:`simulate.scenario_for_benchmark` for the same
    counts (disc radius taken from its start positions): FL100-FL400, 120-260 m/s, 60 %
    straight, 20 % one turn (±1.5 or ±3 °/s for 20-60 s), 20 % one climb or descent;
    90 % Mode S. Entries are uniform on the circle, heading to the centre ± 45°; a
    flight ends at the far edge (its chord length over its speed). The flights airborne
    at the start are placed uniformly along their chords.
    """
    from . import simulate as sim
    from .simulate.scenario import mode3a_codes, mode_s_addresses

    base = sim.scenario_for_benchmark(n_aircraft=n_aircraft, n_radars=n_radars, duration_s=duration_s, seed=seed)
    radius_m = max(math.hypot(t.plan.start_x_m, t.plan.start_y_m) for t in base.targets if t.plan is not None)
    rng = np.random.default_rng([seed, 0x50A4])

    def draw(n: int):
        fl = rng.integers(10, 41, n) * 10
        speed = np.clip(120.0 + (fl - 100) / 300.0 * 110.0 + rng.normal(0.0, 15.0, n), 120.0, 260.0)
        entry = rng.uniform(0.0, 2.0 * math.pi, n)  # bearing of the entry point from the centre
        dev = rng.uniform(-math.pi / 4, math.pi / 4, n)  # heading off the centre line
        chord_m = 2.0 * radius_m * np.cos(dev)
        heading = np.mod(np.degrees(entry + math.pi + dev), 360.0)
        x0, y0 = radius_m * np.sin(entry), radius_m * np.cos(entry)
        return fl, speed, heading, x0, y0, chord_m

    # mean life chord/speed -> arrival rate that keeps n_aircraft airborne
    fl, speed, heading, x0, y0, chord_m = draw(4096)
    rate_per_s = n_aircraft / float(np.mean(chord_m / speed))
    n_new = int(rng.poisson(rate_per_s * duration_s))
    n = n_aircraft + n_new
    fl, speed, heading, x0, y0, chord_m = draw(n)
    life_s = chord_m / speed
    t_offset = np.zeros(n)
    t_offset[n_aircraft:] = np.sort(rng.uniform(0.0, duration_s, n_new))
    # airborne at the start: somewhere along the chord
    u = rng.uniform(0.0, 1.0, n_aircraft)
    hd = np.radians(heading[:n_aircraft])
    x0[:n_aircraft] += u * chord_m[:n_aircraft] * np.sin(hd)
    y0[:n_aircraft] += u * chord_m[:n_aircraft] * np.cos(hd)
    life_s[:n_aircraft] *= 1.0 - u
    life_s = np.maximum(life_s, 30.0)
    kind = rng.random(n)
    t_man = rng.uniform(0.0, 1.0, n) * life_s
    turn = rng.choice([-3.0, -1.5, 1.5, 3.0], n)
    t_turn = rng.uniform(20.0, 60.0, n)
    vr = rng.uniform(1500.0, 2500.0, n) * np.where(fl > 250, -1.0, 1.0)
    t_climb = rng.uniform(60.0, 120.0, n)
    modes = rng.random(n) < 0.9
    addrs = mode_s_addresses(rng, n)
    codes = mode3a_codes(rng, n)
    targets = []
    for k in range(n):
        life = float(life_s[k])
        legs: tuple[sim.Leg, ...]
        if kind[k] < 0.6:
            legs = (sim.Leg(life),)
        else:
            t1 = float(t_man[k])
            man = (
                sim.Leg(float(t_turn[k]), float(turn[k]))
                if kind[k] < 0.8
                else sim.Leg(float(t_climb[k]), 0.0, float(vr[k]))
            )
            legs = (sim.Leg(t1), man, sim.Leg(max(life - t1 - man.duration_s, 1.0)))
        plan = sim.FlightPlan(
            float(x0[k]), float(y0[k]), float(heading[k]), float(speed[k]), float(fl[k] * 100), legs, float(t_offset[k])
        )
        targets.append(
            sim.Target(
                target_id=f"S{k:06d}",
                callsign=f"SK{k:05d}" if modes[k] else None,
                mode_s=int(addrs[k]) if modes[k] else None,
                mode3a=int(codes[k]),
                transponder="modes" if modes[k] else "modeac",
                alt_quantum_ft=25.0 if modes[k] else 100.0,
                plan=plan,
            )
        )
    return sim.Scenario(
        f"soak-{n_aircraft}x{n_radars}",
        base.center_lat_deg,
        base.center_lon_deg,
        base.radars,
        targets,
        start_t_s=base.start_t_s,
        duration_s=float(duration_s),
        seed=seed,
        period_s=base.period_s,
        rates=base.rates,
    )


def generate(
    out_dir: str | Path, n_aircraft: int = 300, duration_s: float = 3600.0, n_radars: int = 4, seed: int = 1
) -> tuple[Path, Path]:
    """Simulate :func:`soak_scenario`; write ``plots.rec`` and ``config.toml`` (no truth
    file: the soak does not score accuracy). Returns their paths."""
    from ..recording import RecordingWriter
    from . import simulate as sim

    scenario = soak_scenario(n_aircraft, duration_s, n_radars, seed)
    simulation = sim.simulate(scenario)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    rec, cfg = out / "plots.rec", out / "config.toml"
    meta = {
        "generator": "radar-fusion soak --generate",
        "scenario": scenario.name,
        "seed": seed,
        "start_t_s": scenario.start_t_s,
        "duration_s": duration_s,
        "n_targets": len(scenario.targets),
        "radars": [r.id for r in scenario.radars],
    }
    with RecordingWriter(rec, meta) as w:
        for t_s, key, payload in simulation.messages:
            w.write(t_s, key, payload)
    cfg.write_text(sim.config_toml(scenario), encoding="utf-8")
    return rec, cfg


# =========================================================================== the daemon


def rss_bytes(pid: int) -> int | None:
    """Resident set size of a process (VmRSS), or None when it is gone."""
    split = rss_split(pid)
    return None if split is None else split[0]


def rss_split(pid: int) -> tuple[int, int] | None:
    """(VmRSS, RssShmem) of a process in bytes, or None when it is gone. RssShmem is the
    part in shared-memory mappings: for the daemon, Zenoh's shared-memory pools (see the
    module docstring), fixed in size and shared with the session that made them."""
    found: dict[str, int] = {}
    try:
        with open(f"/proc/{pid}/status") as f:
            for line in f:
                name = line.split(":", 1)[0]
                if name in ("VmRSS", "RssShmem"):
                    found[name] = int(line.split()[1]) * 1024
    except OSError:
        return None
    if "VmRSS" not in found:
        return None
    return found["VmRSS"], found.get("RssShmem", 0)


class DaemonProcess:
    """`radar-fusion serve` as a child process, its own router on a free loopback port."""

    def __init__(self, config: str | Path, log_path: str | Path, health_period_s: float = 0.2):
        with socket.socket() as s:
            s.bind(("127.0.0.1", 0))
            port = s.getsockname()[1]
        self.endpoint = f"tcp/127.0.0.1:{port}"
        env = dict(
            os.environ,
            RADAR_FUSION_BUS__MODE="router",
            RADAR_FUSION_BUS__LISTEN=json.dumps([self.endpoint]),
            RADAR_FUSION_BUS__CONNECT="[]",
            RADAR_FUSION_BUS__HEALTH_PERIOD_S=str(health_period_s),
        )
        self._log = open(log_path, "wb")  # noqa: SIM115  # the daemon's log for its life; stop() closes it
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "radar_fusion.cli", "serve", "--config", str(config), "--log-level", "WARNING"],
            env=env,
            stdout=self._log,
            stderr=subprocess.STDOUT,
        )
        self.pid = self.proc.pid
        deadline = time.monotonic() + 60.0
        while True:  # until its router accepts connections
            if self.proc.poll() is not None:
                raise RuntimeError(f"daemon exited with status {self.proc.returncode}; see {log_path}")
            try:
                with socket.create_connection(("127.0.0.1", port), timeout=0.5):
                    break
            except OSError:
                if time.monotonic() > deadline:
                    self.stop()
                    raise RuntimeError(
                        f"daemon did not listen on {self.endpoint} within 60 s; see {log_path}"
                    ) from None
                time.sleep(0.1)

    def alive(self) -> bool:
        return self.proc.poll() is None

    def stop(self, timeout_s: float = 60.0) -> int:
        """SIGTERM (the daemon drains and flushes), then its exit status."""
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(timeout_s)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        self._log.close()
        return self.proc.returncode


# =========================================================================== the run


@dataclass
class SoakReport:
    """What a soak measured, and its verdicts (``checks``: name -> passed)."""

    recording: str
    wall_s: float = 0.0
    traffic_s: float = 0.0
    messages_sent: int = 0
    plots_sent: int = 0
    heartbeats_sent: int = 0
    sent: dict[str, dict[str, int | None]] = field(
        default_factory=dict
    )  # per radar: batches, plots, statuses, last_seq (None before any batch), seq_gaps
    daemon: dict[str, dict[str, Any]] = field(default_factory=dict)  # per radar, as counted by the daemon
    counters: dict[str, int] = field(default_factory=dict)  # daemon counters over the run
    rejected: dict[str, int] = field(default_factory=dict)
    track_batches_received: int = 0
    # idle, warm, peak, end (VmRSS); own_warm, own_end (less shared memory); shmem_end
    rss_mib: dict[str, float | None] = field(default_factory=dict)
    rss_slope_mib_per_h: float | None = None  # own memory, over the last 90 % of the traffic (per hour of traffic)
    rss_profile_mib: list[float] = field(default_factory=list)  # after each tenth of the recording
    rss_shmem_profile_mib: list[float] = field(default_factory=list)  # of which shared memory (Zenoh's pools)
    latency_ms: dict[str, float | None] = field(default_factory=dict)  # first/last 10 %: p50, p99
    tracks_mean: dict[str, float] = field(default_factory=dict)  # first/last 10 % of periods
    max_outstanding_periods: int = 0
    daemon_exit_status: int | None = None
    checks: dict[str, bool] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)

    @property
    def passed(self) -> bool:
        return bool(self.checks) and all(self.checks.values())


class _Monitor:
    """Subscribes to the daemon's track batches and health; wakes the sender on each."""

    def __init__(self, session, prefix: str):
        self.cond = threading.Condition()
        self.batches: list[tuple[int, float, float, int]] = []  # (period, t, arrival monotonic, n tracks)
        self.health: dict | None = None
        self.health_seen = 0
        self._subs = [
            session.declare_subscriber(f"{prefix}/fusion/tracks", self._on_tracks),
            session.declare_subscriber(f"{prefix}/fusion/health", self._on_health),
        ]

    def _on_tracks(self, sample) -> None:
        now = time.monotonic()
        b = msgpack.unpackb(sample.payload.to_bytes(), raw=False)
        with self.cond:
            self.batches.append((int(b["period"]), float(b["t"]), now, len(b["tracks"])))
            self.cond.notify_all()

    def _on_health(self, sample) -> None:
        h = msgpack.unpackb(sample.payload.to_bytes(), raw=False)
        with self.cond:
            self.health = h
            self.health_seen += 1
            self.cond.notify_all()

    def close(self) -> None:
        for sub in self._subs:
            sub.undeclare()


class _RssSampler(threading.Thread):
    def __init__(self, pid: int | None, progress, interval_s: float = 0.5):
        super().__init__(name="soak-rss", daemon=True)
        self.pid, self.progress, self.interval_s = pid, progress, interval_s
        # (fraction of the recording sent, VmRSS bytes, of which shared memory)
        self.samples: list[tuple[float, int, int]] = []
        self.stop_event = threading.Event()

    def sample(self) -> None:
        if self.pid is not None:
            split = rss_split(self.pid)
            if split is not None:
                self.samples.append((self.progress(), *split))

    def run(self) -> None:
        while not self.stop_event.wait(self.interval_s):
            self.sample()


def _percentiles_ms(values: list[float]) -> tuple[float | None, float | None]:
    if not values:
        return None, None
    a = np.array(values) * 1e3
    return float(np.percentile(a, 50)), float(np.percentile(a, 99))


def run_soak(
    recording: str | Path,
    config: str | Path,
    *,
    connect: str | None = None,
    pid: int | None = None,
    lead_periods: int = 2,
    stall_timeout_s: float = 120.0,
    log_path: str | Path | None = None,
    progress: bool = False,
) -> SoakReport:
    """Soak the daemon with ``recording`` (see the module docstring); returns the report."""
    from radar_fusion import wire
    from radar_fusion.bus import open_session, reliable_sender, zenoh_config
    from radar_fusion.config import load_settings

    from ..recording import read_recording

    settings = load_settings(config)
    prefix, period_s, lateness_s = settings.bus.prefix, settings.system.period_s, settings.system.allowed_lateness_s
    radar_ids = [r.id for r in settings.radars]
    n_records = sum(1 for r in read_recording(recording) if r.key.startswith("radar/"))
    report = SoakReport(recording=str(recording))

    daemon = None
    if connect is None:
        log_path = Path(log_path or Path(recording).with_name("soak-daemon.log"))
        daemon = DaemonProcess(config, log_path)
        endpoint, pid = daemon.endpoint, daemon.pid
    else:
        endpoint = connect
    session = open_session(zenoh_config("client", connect=[endpoint]))
    monitor = _Monitor(session, prefix)
    pubs: dict[str, Any] = {}
    sent_total = 0
    sampler = _RssSampler(pid, lambda: sent_total / max(n_records, 1))
    try:
        with monitor.cond:  # the first health: the daemon is up and we see its counters
            if not monitor.cond.wait_for(lambda: monitor.health is not None, 30.0):
                raise RuntimeError("no health message from the daemon within 30 s")
            base = monitor.health
        assert base is not None  # wait_for saw it set, and the monitor never resets it
        base_c, base_r = base["counters"], base["radars"]
        if pid is not None:
            idle = rss_bytes(pid)
            report.rss_mib["idle"] = idle / MIB if idle else None
        sampler.start()

        sent: dict[str, Counter] = {rid: Counter() for rid in radar_ids}
        last_seq: dict[str, int] = {}
        wm_s: dict[str, float] = {}
        ready_wall: dict[int, float] = {}  # period -> monotonic time it became closable
        last_ready: int | None = None
        k_start: int | None = None
        t_first = t_last = None
        t0_wall = time.monotonic()

        def outstanding() -> int:
            if last_ready is None or k_start is None:  # both set on the first radar message
                return 0
            got = monitor.batches[-1][0] if monitor.batches else k_start - 1
            return max(0, last_ready - max(got, k_start - 1))

        def processed() -> int:
            h = monitor.health
            return h["counters"].get("messages_processed", 0) - base_c.get("messages_processed", 0) if h else 0

        def publish(key: str, payload: bytes, t_s: float) -> None:
            nonlocal sent_total, last_ready, k_start
            with monitor.cond:
                waited = time.monotonic()
                while outstanding() >= lead_periods and processed() < sent_total:
                    if not monitor.cond.wait(0.5) and time.monotonic() - waited > stall_timeout_s:
                        raise RuntimeError(
                            f"the daemon made no progress for {stall_timeout_s:.0f} s "
                            f"({sent_total} sent, {processed()} processed)"
                        )
                    if daemon is not None and not daemon.alive():
                        raise RuntimeError(f"the daemon exited with status {daemon.proc.returncode}")
                report.max_outstanding_periods = max(report.max_outstanding_periods, outstanding())
            pub = pubs.get(key)
            if pub is None:
                pub = pubs[key] = reliable_sender(session, f"{prefix}/{key}")
            pub.put(payload)
            sent_total += 1
            radar = key.split("/")[1]
            wm_s[radar] = max(wm_s.get(radar, -math.inf), t_s)
            if radar in sent and len(wm_s) >= 1:
                closable_s = min(wm_s[r] for r in wm_s if r in sent)  # in-order radars: no lateness
                k_ready = math.floor(closable_s / period_s) - 1  # the last period ending at or before it
                if k_start is None or last_ready is None:  # both None until this first radar message
                    k_start = math.floor(t_s / period_s)
                    last_ready = k_start - 1
                if k_ready > last_ready:
                    now = time.monotonic()
                    with monitor.cond:
                        for k in range(last_ready + 1, k_ready + 1):
                            ready_wall[k] = now
                        last_ready = k_ready

        for i, rec in enumerate(read_recording(recording)):
            if not rec.key.startswith("radar/"):
                continue
            radar, kind = rec.key.split("/")[1:3]
            t_first = rec.t_s if t_first is None else t_first
            t_last = rec.t_s
            if kind == "plots" and radar in sent:
                obj = msgpack.unpackb(rec.payload, raw=False)
                seq = int(obj["seq"])
                if radar in last_seq and seq != last_seq[radar] + 1:
                    sent[radar]["seq_gaps"] += max(seq - last_seq[radar] - 1, 0)
                last_seq[radar] = seq
                sent[radar]["batches"] += 1
                sent[radar]["plots"] += len(obj["plots"])
            elif kind == "status" and radar in sent:
                sent[radar]["statuses"] += 1
            publish(rec.key, rec.payload, rec.t_s)
            if progress and i % 2000 == 0:
                print(
                    f"\rsoak: {100.0 * sent_total / n_records:5.1f} % sent, {len(monitor.batches)} track batches",
                    end="",
                    file=sys.stderr,
                    flush=True,
                )
        # one heartbeat per radar past the last period, instead of waiting for the idle flush
        t_end = (t_last or 0.0) + period_s + lateness_s + 0.001
        for rid in radar_ids:
            if sent[rid]:
                hb = wire.encode(wire.RadarStatus(radar_id=rid, t=t_end, kind="heartbeat"))
                publish(f"radar/{rid}/status", hb, t_end)
                sent[rid]["statuses"] += 1
                report.heartbeats_sent += 1
        if progress:
            print(file=sys.stderr)

        def settled() -> bool:
            h = monitor.health
            if h is None or processed() < sent_total or h["counters"].get("plots_buffered", 0):
                return False
            published = h["counters"].get("batches_published", 0) - base_c.get("batches_published", 0)
            return len(monitor.batches) >= published

        with monitor.cond:
            if not monitor.cond.wait_for(settled, stall_timeout_s):
                report.notes.append("the daemon did not settle (all processed, nothing buffered, all batches in)")
        report.wall_s = time.monotonic() - t0_wall
        sampler.stop_event.set()
        sampler.join()
        sampler.sample()
        final = monitor.health
    finally:
        sampler.stop_event.set()
        monitor.close()
        session.close()
        if daemon is not None:
            report.daemon_exit_status = daemon.stop()

    # ------------------------------------------------------------------ verdicts
    report.traffic_s = (t_last - t_first) if t_first is not None and t_last is not None else 0.0
    report.messages_sent = sent_total
    report.plots_sent = sum(c["plots"] for c in sent.values())
    report.sent = {rid: {**dict(c), "last_seq": last_seq.get(rid)} for rid, c in sent.items()}
    assert final is not None  # as base: set before the run, never reset
    fc = final["counters"]
    report.counters = {
        k: v - base_c.get(k, 0)
        for k, v in fc.items()
        if isinstance(v, int) and "depth" not in k and k not in ("tracks_confirmed", "plots_buffered")
    }
    report.rejected = {
        k: v - base["rejected"].get(k, 0) for k, v in final["rejected"].items() if v - base["rejected"].get(k, 0)
    }
    for rid in radar_ids:
        r, b = final["radars"][rid], base_r[rid]
        report.daemon[rid] = {
            "batches": r["batches"] - b["batches"],
            "plots": r["plots"] - b["plots"],
            "last_seq": r["last_seq"],
            "seq_gaps": r["seq_gaps"] - b["seq_gaps"],
        }
    per_radar_ok = all(
        report.daemon[rid]["batches"] == sent[rid]["batches"]
        and report.daemon[rid]["plots"] == sent[rid]["plots"]
        and report.daemon[rid]["seq_gaps"] == sent[rid]["seq_gaps"]
        and (sent[rid]["batches"] == 0 or report.daemon[rid]["last_seq"] == last_seq[rid])
        for rid in radar_ids
    )
    c = report.counters
    report.track_batches_received = len(monitor.batches)
    periods = [b[0] for b in monitor.batches]
    report.checks["no message lost"] = (
        per_radar_ok
        and c.get("messages_received") == sent_total
        and c.get("messages_processed") == sent_total
        and c.get("status_messages", 0) == sum(s["statuses"] for s in sent.values())
        and c.get("plots_received", 0) == report.plots_sent
        and not report.rejected
    )
    report.checks["every track batch received, in order"] = (
        report.track_batches_received == c.get("batches_published")
        and c.get("outputs_dropped", 0) == 0
        and all(a < b for a, b in itertools.pairwise(periods))
    )
    if daemon is not None:
        report.checks["daemon stopped cleanly"] = report.daemon_exit_status == 0

    summarise_memory(report, sampler.samples)

    lat = [(k, arr - ready_wall[k], n) for k, _t, arr, n in monitor.batches if k in ready_wall]
    if lat:
        m = max(len(lat) // 10, 1)
        first, last = lat[:m], lat[-m:]
        f50, f99 = _percentiles_ms([x[1] for x in first])
        l50, l99 = _percentiles_ms([x[1] for x in last])
        assert f50 is not None and l50 is not None  # first and last are not empty
        report.latency_ms = {"first_p50": f50, "first_p99": f99, "last_p50": l50, "last_p99": l99, "periods_each": m}
        report.tracks_mean = {
            "first": float(np.mean([x[2] for x in first])),
            "last": float(np.mean([x[2] for x in last])),
        }
        report.checks["latency did not drift"] = l50 <= 1.5 * f50 + 5.0
    return report


def summarise_memory(report: SoakReport, samples: list[tuple[float, int, int]]) -> None:
    """The memory figures and check of ``report`` from the RSS samples (fraction of the
    recording sent, VmRSS, of which shared memory; bytes). The profile and idle/warm/peak/
    end are VmRSS; the slope and the check are on VmRSS less the shared memory (the
    daemon's own memory: a Zenoh shared-memory pool is mapped whole, once, when a local
    session first sends it a large message, and is reported beside it)."""
    if not samples:
        return
    frac = np.array([s[0] for s in samples])
    rss = np.array([s[1] for s in samples]) / MIB
    shmem = np.array([s[2] for s in samples]) / MIB
    own = rss - shmem
    warm_i = min(int(np.searchsorted(frac, 0.1)), rss.size - 1)
    report.rss_mib.update(
        warm=float(rss[warm_i]),
        peak=float(rss.max()),
        end=float(rss[-1]),
        own_warm=float(own[warm_i]),
        own_end=float(own[-1]),
        shmem_end=float(shmem[-1]),
    )
    at = np.minimum(np.searchsorted(frac, np.arange(1, 11) / 10.0), rss.size - 1)
    report.rss_profile_mib = [round(float(v), 1) for v in rss[at]]
    report.rss_shmem_profile_mib = [round(float(v), 1) for v in shmem[at]]
    tail = frac >= 0.1
    if tail.sum() >= 3 and np.ptp(frac[tail]) > 0:
        slope_per_fraction = float(np.polyfit(frac[tail], own[tail], 1)[0])
        report.rss_slope_mib_per_h = slope_per_fraction * 3600.0 / max(report.traffic_s, 1e-9)
    warm, end = float(own[warm_i]), float(own[-1])
    report.checks["memory flat"] = end - warm <= max(0.10 * warm, 32.0)


def format_report(r: SoakReport) -> str:
    def mib(v):
        return "n/a" if v is None else f"{v:.0f} MiB"

    lines = [
        f"soak: {r.traffic_s:.0f} s of traffic in {r.wall_s:.0f} s "
        f"({r.traffic_s / max(r.wall_s, 1e-9):.1f}x real time): "
        f"{r.messages_sent} messages ({r.heartbeats_sent} end heartbeats), {r.plots_sent} plots, "
        f"{r.messages_sent / max(r.wall_s, 1e-9):.0f} msg/s, {r.plots_sent / max(r.wall_s, 1e-9):.0f} plots/s",
        "  per radar, sent vs counted by the daemon (batches / plots / last seq / seq gaps):",
    ]
    for rid, s in r.sent.items():
        d = r.daemon.get(rid, {})
        lines.append(
            f"    {rid:>8}: {s.get('batches', 0)}/{d.get('batches')}  {s.get('plots', 0)}/{d.get('plots')}  "
            f"{s.get('last_seq')}/{d.get('last_seq')}  {s.get('seq_gaps', 0)}/{d.get('seq_gaps')}"
        )
    c = r.counters
    lines += [
        f"  messages sent {r.messages_sent}, received {c.get('messages_received')}, "
        f"processed {c.get('messages_processed')}; "
        f"rejected {r.rejected or 'none'}",
        f"  track batches published {c.get('batches_published')}, received {r.track_batches_received}, "
        f"dropped by the outbox {c.get('outputs_dropped', 0)}; at most {r.max_outstanding_periods} periods outstanding",
        f"  daemon RSS: idle {mib(r.rss_mib.get('idle'))}, after 10 % {mib(r.rss_mib.get('warm'))}, "
        f"peak {mib(r.rss_mib.get('peak'))}, end {mib(r.rss_mib.get('end'))}",
        "  daemon RSS after each tenth of the recording: " + " ".join(f"{v:.0f}" for v in r.rss_profile_mib) + " MiB",
        "    of which Zenoh shared memory (RssShmem: pools mapped whole, once per local sender): "
        + " ".join(f"{v:.0f}" for v in r.rss_shmem_profile_mib)
        + " MiB",
        f"  daemon's own memory (RSS less shared memory): after 10 % {mib(r.rss_mib.get('own_warm'))}, "
        f"end {mib(r.rss_mib.get('own_end'))}"
        + (
            f"; slope over the last 90 %: {r.rss_slope_mib_per_h:+.1f} MiB per hour of traffic"
            if r.rss_slope_mib_per_h is not None
            else ""
        ),
    ]
    if r.latency_ms:
        L = r.latency_ms
        lines.append(
            f"  period latency (closable -> TrackBatch received), {L['periods_each']} periods each: "
            f"first 10 % p50 {L['first_p50']:.1f} ms p99 {L['first_p99']:.1f} ms; "
            f"last 10 % p50 {L['last_p50']:.1f} ms p99 {L['last_p99']:.1f} ms"
        )
        lines.append(
            f"  tracks per period: first 10 % {r.tracks_mean['first']:.0f}, last 10 % {r.tracks_mean['last']:.0f}"
        )
    for note in r.notes:
        lines.append(f"  note: {note}")
    lines.append("  checks: " + ", ".join(f"{name}: {'OK' if ok else 'FAILED'}" for name, ok in r.checks.items()))
    return "\n".join(lines)


# =========================================================================== command line


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("recording", nargs="?", help="recording to feed (default with --generate: DIR/plots.rec)")
    p.add_argument("--config", help="daemon configuration (default with --generate: DIR/config.toml)")
    p.add_argument("--generate", metavar="DIR", help="first simulate steady traffic into DIR (plots.rec, config.toml)")
    p.add_argument("--duration-s", type=float, default=3600.0, help="--generate: simulated duration (default 3600)")
    p.add_argument("--aircraft", type=int, default=300, help="--generate: aircraft airborne at any time (default 300)")
    p.add_argument("--radars", type=int, default=4, help="--generate: number of radars (default 4)")
    p.add_argument("--seed", type=int, default=1, help="--generate: random seed (default 1)")
    p.add_argument("--connect", help="soak a daemon already running at this Zenoh endpoint (default: start one)")
    p.add_argument("--pid", type=int, help="with --connect: the daemon's process id, to follow its memory")
    p.add_argument(
        "--lead-periods",
        type=int,
        default=2,
        help="closable periods the sender may be ahead of the track batches received (default 2)",
    )
    p.add_argument("--json", help="also write the report as JSON to this file")


def run(args: argparse.Namespace) -> int:
    if args.generate:
        t0 = time.perf_counter()
        rec, cfg = generate(args.generate, args.aircraft, args.duration_s, args.radars, args.seed)
        print(
            f"soak: simulated {args.duration_s:.0f} s, {args.aircraft} aircraft airborne, {args.radars} radars "
            f"-> {rec}, {cfg} ({time.perf_counter() - t0:.0f} s)"
        )
        recording, config = args.recording or rec, args.config or cfg
    else:
        recording, config = args.recording, args.config
    if not recording or not config:
        print("soak: give a recording and --config, or --generate DIR", file=sys.stderr)
        return 2
    report = run_soak(
        recording,
        config,
        connect=args.connect,
        pid=args.pid,
        lead_periods=args.lead_periods,
        progress=sys.stderr.isatty(),
    )
    print(format_report(report))
    if args.json:
        Path(args.json).write_text(json.dumps(asdict(report), indent=1), encoding="utf-8")
    return 0 if report.passed else 1
