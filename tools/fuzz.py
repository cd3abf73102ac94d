"""`radar-fusion fuzz`: hostile traffic over a real Zenoh bus into the daemon, at any count.

    radar-fusion fuzz --count 100000            # issue 13: >= 100,000 hostile messages
    radar-fusion fuzz --count 2000 --seed 7     # what the default test run sends

The daemon (:class:`radar_fusion.bus.FusionDaemon`, in process, its own router on a free
127.0.0.1 port) receives the demo scenario's good traffic, split in half around
``--count`` hostile messages on every key it subscribes to: random bytes, truncated and
bit-flipped msgpack, trailing garbage, replayed sequence numbers, plots with wrong types,
NaN/inf, negative ranges, azimuths outside [0, 360), unknown or oversize radar ids, huge
array and map claims, oversize payloads (mutations that happen to decode as valid new
data are not hostile and are skipped). The same messages are first fed to a replica of
the daemon without Zenoh, which gives the rejection counts to expect.

Checks (exit status 1 when one fails; :func:`failures` lists them):
  * the daemon's thread is alive at the end and received every message (reliable, BLOCK);
  * every rejection is counted by a listed reason (``wire.REJECTION_REASONS``), at least
    one per hostile message, and per reason as many as the replica counted (plot_late and
    plot_future depend on when periods closed and are not compared);
  * oversize and unknown_radar as many as were sent on such keys;
  * the good traffic is untouched: every good plot accepted, every radar's batches counted,
    no sequence gap; its tracks are still accurate after the hostile half (>= 10 confirmed,
    settled position RMS < 200 m against the truth).

``tests/test_fuzz.py`` runs it with 2,000 hostile messages; this command is the long run,
outside the default test suite.
"""

from __future__ import annotations

import argparse
import math
import random
import sys
import time
import tomllib
from dataclasses import dataclass, field
from typing import Any

import msgpack

from radar_fusion import wire

MAX_PAYLOAD_BYTES = 64 << 10
PLOT_FIELDS = (
    "t", "range_m", "azimuth_deg", "fl", "mode3a", "mode_s", "track_no", "kind",
    "roll_deg", "ground_speed_mps", "track_angle_deg", "magnetic_heading_deg", "indicated_airspeed_mps",
)  # fmt: skip
HOSTILE_VALUES: list[Any] = [
    None,
    True,
    -1,
    2**64 - 1,
    -(2**63),
    1.5,
    math.nan,
    math.inf,
    -math.inf,
    "",
    "x" * 300,
    b"\x00\xff",
    [],
    [1, [2, [3]]],
    {"a": {"b": None}},
    -5.0,
    360.0,
    1e300,
    0.0,
]
#: distinct oversize payloads, reused (100,000 messages would otherwise hold ~500 MB of them)
N_OVERSIZE_PAYLOADS = 16


def pack(obj: Any) -> bytes:
    return msgpack.packb(obj, use_bin_type=True)


def good_plot(t_s: float, range_m: float = 120_000.0, azimuth_deg: float = 45.0) -> dict[str, Any]:
    return {
        "t": t_s,
        "range_m": range_m,
        "azimuth_deg": azimuth_deg,
        "fl": 350.0,
        "mode3a": 0o1234,
        "mode_s": "4CA1F3",
        "track_no": 17,
        "kind": "cmb",
        "roll_deg": -12.5,
        "ground_speed_mps": 231.5,
        "track_angle_deg": 272.8125,
        "magnetic_heading_deg": 268.59375,
        "indicated_airspeed_mps": 128.6,
    }


def hostile_messages(
    rng: random.Random,
    prefix: str,
    sent: list[tuple[str, bytes]],
    seen_seq: dict[str, set[int]],
    n: int,
    radar_ids: list[str],
    t0_s: float,
) -> tuple[list[tuple[str, bytes, str]], int]:
    """``n`` (key, payload, category) on every key the daemon subscribes to
    (<prefix>/radar/*/*), derived from the good messages already ``sent`` (keys without the
    prefix). Mutations that decode as valid new data of a configured radar (a bit flip in
    a float, say) are not hostile and are skipped. Returns the messages and the number
    skipped."""
    ids = radar_ids
    keys = [f"radar/{r}/{k}" for r in ids for k in ("plots", "status")] * 4 + [
        "radar/intruder/plots",
        "radar/intruder/status",
        f"radar/{'r' * 60}/plots",
        f"radar/{ids[0]}/config",
        f"radar/{ids[1]}/plots2",
        "radar/APP/plots",
    ]
    oversize = [rng.randbytes(MAX_PAYLOAD_BYTES + rng.randint(1, 1 << 16)) for _ in range(N_OVERSIZE_PAYLOADS)]
    out: list[tuple[str, bytes, str]] = []
    skipped = 0
    while len(out) < n:
        key = rng.choice(keys)
        good_key, good = rng.choice(sent)
        kind = rng.random()
        if kind < 0.15:
            cat, payload = "random bytes", rng.randbytes(rng.randrange(0, 300))
        elif kind < 0.30:
            cat, payload = "truncated", good[: rng.randrange(0, len(good))]
        elif kind < 0.50:
            cat, b = "bit flips", bytearray(good)
            for _ in range(rng.randint(1, 4)):
                b[rng.randrange(len(b))] ^= 1 << rng.randrange(8)
            payload, key = bytes(b), good_key
        elif kind < 0.55:
            cat, payload = "trailing garbage", good + rng.randbytes(rng.randint(1, 8))
        elif kind < 0.65:
            cat, payload, key = "duplicate seq", good, good_key
        elif kind < 0.90:
            cat = "wrong fields"
            radar = key.split("/")[1] if rng.random() < 0.8 else rng.choice(ids + ["intruder"])
            plots = [
                dict(good_plot(t0_s + rng.uniform(0, 120)), **{rng.choice(PLOT_FIELDS): rng.choice(HOSTILE_VALUES)})
                for _ in range(rng.randint(0, 6))
            ] + [good_plot(t0_s + 60.0)] * rng.randint(0, 2)
            msg: dict[str, Any] = {
                "v": 1,
                "radar_id": radar,
                "seq": rng.choice(sorted(seen_seq.get(radar, {0}))),
                "plots": plots,
                "t": t0_s + 60.0,
                "kind": "north",
            }
            field_name = rng.choice(["v", "radar_id", "seq", "plots", "t", "kind", None])
            if field_name:
                msg[field_name] = rng.choice(HOSTILE_VALUES + [rng.randint(2, 99)])
            payload = pack(msg)
        elif kind < 0.95:
            cat = "huge claims"
            payload = rng.choice(
                [
                    b"\xdd\xff\xff\xff\xff",
                    b"\xdf\x7f\xff\xff\xff",
                    b"\x91" * 5000,
                    pack({"v": 1, "radar_id": ids[0], "seq": 1, "plots": [0] * 20_001}),
                ]
            )
        else:
            cat, payload = "oversize", rng.choice(oversize)
        parts = key.split("/")
        if parts[1] in ids and parts[2] in ("plots", "status") and cat != "oversize":
            d = (
                wire.decode_plot_batch(payload, MAX_PAYLOAD_BYTES)
                if parts[2] == "plots"
                else wire.decode_message(payload, wire.RadarStatus, MAX_PAYLOAD_BYTES)
            )
            valid = not isinstance(d, wire.Rejection) and getattr(d, "radar_id", None) == parts[1]
            if valid and (parts[2] == "status" or getattr(d, "seq", None) not in seen_seq[parts[1]]):
                skipped += 1
                continue
        out.append((f"{prefix}/{key}", payload, cat))
    return out, skipped


@dataclass
class BusFuzzResult:
    """What one run sent and what the daemon counted (the inputs of :func:`failures`)."""

    n_hostile: int
    n_good: int
    skipped_valid: int
    categories: dict[str, int]
    messages_received: int
    thread_alive: bool
    rejected: dict[str, int]
    replica_rejected: dict[str, int]
    expected_oversize: int
    expected_unknown_radar_min: int
    plots_accepted: int
    good_plots: int
    radar_batches: dict[str, tuple[int, int, int]]  # id: (counted, sent, seq gaps)
    batches_published: int
    batches_collected: int
    max_confirmed_after: int
    pos_rms_settled_m: float
    wall_s: float
    extra: dict[str, Any] = field(default_factory=dict)


def run_bus(n_hostile: int, seed: int = 20240808, port: int | None = None) -> BusFuzzResult:
    """Good traffic split around ``n_hostile`` hostile messages, into a daemon on its own
    router on 127.0.0.1 (``port``, or a free one); see the module docstring."""
    import socket

    from radar_fusion.bus import FusionDaemon, open_session, reliable_sender, zenoh_config
    from radar_fusion.config import settings_from_dict

    from . import evaluate as ev
    from . import simulate as sim
    from .demo import TrackCollector, wait_until

    wall0 = time.perf_counter()
    if port is None:
        with socket.socket() as s:
            s.bind(("127.0.0.1", 0))
            port = int(s.getsockname()[1])
    scenario = sim.preset("demo", seed=5, duration_s=120.0)
    simulation = sim.simulate(scenario)
    base = tomllib.loads(sim.config_toml(scenario))
    radar_ids = [r["id"] for r in base["radars"]]
    t0_s = scenario.start_t_s
    cfg = {
        **base,
        "bus": {
            **base["bus"],
            "mode": "router",
            "listen": [f"tcp/127.0.0.1:{port}"],
            "max_payload_bytes": MAX_PAYLOAD_BYTES,
            "health_period_s": 0.2,
        },
    }
    settings = settings_from_dict(cfg)
    prefix = settings.bus.prefix
    good = [(f"{prefix}/{key}", payload) for _, key, payload in simulation.messages]
    half = len(good) // 2
    seen_seq: dict[str, set[int]] = {r: set() for r in radar_ids}
    for key, payload in good[:half]:
        if key.endswith("/plots"):
            obj = msgpack.unpackb(payload)
            seen_seq[obj["radar_id"]].add(obj["seq"])
    rng = random.Random(seed)
    hostile, skipped = hostile_messages(
        rng, prefix, [(k[len(prefix) + 1 :], p) for k, p in good[:half]], seen_seq, n_hostile, radar_ids, t0_s
    )
    traffic = good[:half] + [(k, p) for k, p, _ in hostile] + good[half:]

    # The same decode/route/ingest path without Zenoh gives the counts to expect.
    replica = FusionDaemon(settings)
    for key, payload in traffic:
        replica._handle(key, payload)
        replica.engine.poll()

    daemon = FusionDaemon(settings).start()
    session = open_session(zenoh_config("client", connect=list(settings.bus.listen)))
    collector = TrackCollector(session, prefix)
    pubs: dict[str, Any] = {}
    try:
        time.sleep(0.3)
        for key, payload in traffic:
            pub = pubs.get(key) or pubs.setdefault(key, reliable_sender(session, key))
            pub.put(payload)
        wait_until(lambda: daemon.messages_processed >= len(traffic), 60 + len(traffic) / 1000)
        alive = daemon._thread is not None and daemon._thread.is_alive()
        wait_until(
            lambda: bool(collector.health) and collector.health[-1]["counters"]["messages_processed"] >= len(traffic),
            10,
        )
    finally:
        daemon.stop()
        wait_until(lambda: len(collector.batches) >= daemon.batches_published, 10)
        collector.close()
        session.close()
    health = collector.health[-1] if collector.health else {"rejected": {}, "counters": {}, "radars": {}}
    truth = simulation.truth  # already a Truth (tools/truth.py)
    after = [b for b in collector.batches if b["t"] > t0_s + 60.0 + 20.0]
    categories: dict[str, int] = {}
    for _, _, cat in hostile:
        categories[cat] = categories.get(cat, 0) + 1
    radar_batches = {}
    for rid in radar_ids:
        r = health["radars"].get(rid, {})
        sent = sum(1 for k, _ in good if k == f"{prefix}/radar/{rid}/plots")
        radar_batches[rid] = (int(r.get("batches", -1)), sent, int(r.get("seq_gaps", -1)))
    return BusFuzzResult(
        n_hostile=len(hostile),
        n_good=len(good),
        skipped_valid=skipped,
        categories=categories,
        messages_received=daemon.messages_received,
        thread_alive=alive,
        rejected=dict(health["rejected"]),
        replica_rejected=dict(replica.engine.rejected),
        expected_oversize=sum(
            1
            for k, _, cat in hostile
            if cat == "oversize" and k.split("/")[2] in radar_ids and k.split("/")[3] in ("plots", "status")
        ),
        expected_unknown_radar_min=sum(1 for k, *_ in hostile if k.split("/")[2] not in radar_ids),
        plots_accepted=int(health["counters"].get("plots_accepted", -1)),
        good_plots=sum(len(pc) for pc in simulation.plot_columns),
        radar_batches=radar_batches,
        batches_published=daemon.batches_published,
        batches_collected=len(collector.batches),
        max_confirmed_after=max((sum(t["status"] == "confirmed" for t in b["tracks"]) for b in after), default=0),
        pos_rms_settled_m=ev.evaluate(collector.batches, truth).pos_rms_settled_m if collector.batches else math.nan,
        wall_s=time.perf_counter() - wall0,
        extra={"traffic": len(traffic)},
    )


def failures(r: BusFuzzResult) -> list[str]:
    """The checks of the module docstring that fail (empty: all pass)."""
    out = []
    reasons = set(wire.REJECTION_REASONS)
    if not r.thread_alive:
        out.append("the daemon's processing thread died")
    if r.messages_received != r.extra["traffic"]:
        out.append(f"received {r.messages_received} of {r.extra['traffic']} messages")
    if not set(r.rejected) <= reasons:
        out.append(f"rejections by unlisted reasons: {sorted(set(r.rejected) - reasons)}")
    if r.rejected.get("oversize", 0) != r.expected_oversize:
        out.append(f"oversize counted {r.rejected.get('oversize', 0)}, sent {r.expected_oversize}")
    if r.rejected.get("unknown_radar", 0) < r.expected_unknown_radar_min:
        out.append(f"unknown_radar counted {r.rejected.get('unknown_radar', 0)} < {r.expected_unknown_radar_min} sent")
    for reason in reasons - {"plot_late", "plot_future"}:
        if r.rejected.get(reason, 0) != r.replica_rejected.get(reason, 0):
            out.append(f"{reason}: daemon {r.rejected.get(reason, 0)}, replica {r.replica_rejected.get(reason, 0)}")
    if sum(r.rejected.values()) < r.n_hostile:
        out.append(f"{sum(r.rejected.values())} rejections for {r.n_hostile} hostile messages")
    if r.plots_accepted != r.good_plots:
        out.append(f"good plots accepted {r.plots_accepted} of {r.good_plots}")
    for rid, (counted, sent, gaps) in r.radar_batches.items():
        if counted != sent or gaps != 0:
            out.append(f"radar {rid}: {counted} of {sent} batches, {gaps} sequence gaps")
    if not (r.batches_collected == r.batches_published > 20):
        out.append(f"track batches collected {r.batches_collected}, published {r.batches_published}")
    if r.max_confirmed_after < 10:
        out.append(f"only {r.max_confirmed_after} confirmed tracks after the hostile half")
    if not r.pos_rms_settled_m < 200.0:
        out.append(f"settled position RMS {r.pos_rms_settled_m:.0f} m after the hostile half (limit 200 m)")
    return out


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--count", type=int, default=100_000, help="hostile messages (default 100,000)")
    p.add_argument("--seed", type=int, default=20240808, help="random seed (default 20240808)")


def run(args: argparse.Namespace) -> int:
    from radar_fusion.cli import one_blas_thread

    one_blas_thread()
    r = run_bus(args.count, args.seed)
    cats = ", ".join(f"{k} {v:,}" for k, v in sorted(r.categories.items()))
    print(f"hostile messages: {r.n_hostile:,} ({cats}); skipped as valid: {r.skipped_valid:,}")
    print(f"good messages: {r.n_good:,}; received by the daemon: {r.messages_received:,}; wall time {r.wall_s:.1f} s")
    print(f"rejected by reason: {dict(sorted(r.rejected.items()))} (total {sum(r.rejected.values()):,})")
    print(
        f"good plots accepted {r.plots_accepted:,} of {r.good_plots:,}; track batches {r.batches_collected} of "
        f"{r.batches_published}; confirmed after the hostile half {r.max_confirmed_after}; settled position RMS "
        f"{r.pos_rms_settled_m:.0f} m"
    )
    bad = failures(r)
    for line in bad:
        print(f"FAIL: {line}")
    print("all checks passed" if not bad else f"{len(bad)} check(s) failed", file=sys.stdout)
    return 1 if bad else 0
