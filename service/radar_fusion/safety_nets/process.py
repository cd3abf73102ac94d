"""The safety nets as their own consumer: ``radar-fusion safety-nets`` (issue 16 item 2).

    <prefix>/fusion/tracks  →  decode (track_input.py) → SafetyNets.update → <prefix>/fusion/alerts/<kind>
                                                                            <prefix>/fusion/safety_nets/health

It reads the tracks topic like any consumer, on this host or another, and runs STCA,
APW, MSAW and the alert hooks exactly as the daemon ran them in process (the same
columns, the same alerts; ``safety-eval`` and a bus test prove it). Zenoh's callback
only queues the payload with its arrival time; one worker thread decodes, runs the
nets and publishes, so a slow period never blocks Zenoh (nor, through it, the daemon's
other subscribers). Beyond ``QUEUE_BYTES`` waiting, the oldest batch is dropped and
counted (``batches_dropped``).

Bad input never stops it: a payload that is not a TrackBatch is counted by reason on its
health key (``rejected``: ``oversize``, ``malformed_msgpack``, ``version``, ``schema``,
``out_of_order``) and logged at a bounded rate; an exception in the nets is counted as
``internal_error``. A batch older than the previous one is refused as ``out_of_order``;
``STREAM_RESTART_BATCHES`` of them in a row mean a new tracks stream (a daemon restarted
on older data, a replay): the open alerts are ended and the new stream is judged. So
does a track id of the previous batch that is a younger track now (a daemon restarted
without its state, its ids from 1 again, its time moving on).

``serve`` runs it as its child (:mod:`.supervisor`): the settings then come on stdin
(one JSON line) and the end of stdin means the parent is gone, however it died, so the
child never outlives it.

A hot-standby pair (``[redundancy]``, redundancy.py): TrackBatches carry the active's
epoch; a batch of an epoch below the highest seen is refused as ``stale_epoch`` (a stale
active's). Each daemon's child judges every batch of the active, so the standby's child
holds the same open alerts and alert ids; it publishes only the alerts of batches its
own parent published (``alerts_for_instance``), so after a take-over the alerts go on
from the new active's child with the same ids. A stand-alone safety-nets process
publishes for whichever active is current.
"""

from __future__ import annotations

import json
import logging
import os
import socket
import sys
import threading
import time
from collections import Counter, deque
from pathlib import Path
from typing import TYPE_CHECKING, Any

import msgpack
import numpy as np

from ..geo.coordinates import SystemPlane
from ..wire import ids_given_again
from .nets import ALERT_KINDS, SafetyNets
from .track_input import TrackBatchReader

if TYPE_CHECKING:
    import argparse

    from ..config import Settings

log = logging.getLogger("radar_fusion.safety_nets")

QUEUE_BYTES = 256 << 20
"""TrackBatch payloads waiting for the worker, bytes; beyond, the oldest is dropped (counted).
256 MiB is ~190 periods of 4,000 tracks (1.3 MB each). At real time the nets take a small
part of a period, so only a replay at full speed queues; there every period is judged, as
the daemon judged them in process (a bound in batches, 8, dropped periods of the demo's
replay and changed its alerts)."""
STREAM_RESTART_BATCHES = 3
#: a track's age may read this much younger in a later batch (rounding) and still be the
#: same track (wire.ids_given_again)
AGE_SLACK_S = 0.01
"""Consecutive out-of-order batches taken as a new tracks stream (see the module docstring)."""
LINGER_S = 0.3
"""At shutdown, wait until no batch has arrived for this long (at most 10×) before the last
drain: the daemon's final batches are in flight when it stops its child."""


def health_key(prefix: str) -> str:
    """The safety-nets process's health key: ``<prefix>/fusion/safety_nets/health``."""
    return f"{prefix}/fusion/safety_nets/health"


class SafetyNetsProcess:
    """One Zenoh session, one SafetyNets, one worker thread (see the module docstring)."""

    def __init__(
        self,
        settings: Settings,
        base_dir: Path | None = None,
        connect: list[str] | None = None,
        nets: SafetyNets | None = None,
        alerts_for_instance: str | None = None,
    ):
        self.settings = settings
        self.alerts_for_instance = alerts_for_instance  # a standby's child: only its parent's batches' alerts
        self.highest_epoch = 0
        self.prefix = settings.bus.prefix
        self.connect = connect
        plane = SystemPlane(settings.system.center_lat, settings.system.center_lon)
        self.nets = nets or SafetyNets.from_settings(settings, base_dir=base_dir)
        self.reader = TrackBatchReader(plane, [r.id for r in settings.radars])
        self.queue: deque[tuple[bytes, float]] = deque()
        self.queued_bytes = 0
        self._queue_lock = threading.Lock()
        self._wakeup = threading.Event()
        self.stop_event = threading.Event()
        self.stopped = threading.Event()
        self.started_wall = time.time()
        self.counters: Counter[str] = Counter(
            dict.fromkeys(
                (
                    "batches_received",
                    "batches_processed",
                    "batches_dropped",
                    "alerts_published",
                    "publish_errors",
                    "stream_restarts",
                    "alerts_withheld",
                ),
                0,
            )
        )
        self.rejected: Counter[str] = Counter()
        self.latency_ms: deque[float] = deque(maxlen=1000)  # arrival → the batch's alerts published
        self.processing_ms: deque[float] = deque(maxlen=1000)  # decode + nets
        self.newest_period: int | None = None
        self.newest_t: float | None = None
        self._out_of_order_run = 0
        self._ids_ages: tuple[np.ndarray, np.ndarray] | None = None  # the previous batch's track ids and ages
        self._batch_instance: str | None = None  # the stamp of the batch being judged
        self._session: Any = None
        self._sub: Any = None
        self._pubs: dict[str, Any] = {}
        self._worker: threading.Thread | None = None
        from ..bus import RateLimitedLog

        self._log_rejection = RateLimitedLog()

    # ------------------------------------------------------------- lifecycle
    def start(self) -> SafetyNetsProcess:
        from ..bus import client_config_for, dropping_sender, open_session, reliable_sender, zenoh_config

        bus, own = self.settings.bus, self.settings.safety_nets
        connect = self.connect or own.connect
        config_file = own.zenoh_config_file or bus.zenoh_config_file
        if connect:
            cfg = zenoh_config("client", connect=list(connect), config_file=config_file)
        elif own.zenoh_config_file:
            endpoints = bus.connect if bus.mode == "client" else bus.listen
            cfg = zenoh_config("client", connect=list(endpoints), config_file=config_file)
        else:
            cfg = client_config_for(bus)
        self._session = open_session(cfg)
        p = self.prefix
        for kind in ALERT_KINDS:
            self._pubs[kind] = reliable_sender(self._session, f"{p}/fusion/alerts/{kind}")
        self._pubs["health"] = dropping_sender(self._session, health_key(p))
        self._sub = self._session.declare_subscriber(f"{p}/fusion/tracks", self._on_sample)
        self._worker = threading.Thread(target=self._run, name="safety-nets", daemon=True)
        self._worker.start()
        self.publish_health()  # the first health says: subscribed, ready
        log.info("safety nets up: prefix=%s connect=%s", p, self.connect or "from the configuration")
        return self

    def stop(self, timeout_s: float = 10.0) -> None:
        """Judge what has arrived (waiting briefly for batches in flight), publish the
        final health, close the session."""
        self.stop_event.set()
        self._wakeup.set()
        if self._worker is not None:
            self._worker.join(timeout_s)
        if self._sub is not None:
            self._sub.undeclare()
            self._sub = None
        self.publish_health()
        self._pubs = {}
        if self._session is not None:
            self._session.close()
            self._session = None
        self.stopped.set()

    # ------------------------------------------------------------------ input
    def _on_sample(self, sample: Any) -> None:
        # Zenoh's thread: copy out and queue, nothing else
        self.offer(sample.payload.to_bytes(), time.monotonic())

    def offer(self, payload: bytes, arrived_s: float) -> None:
        """Queue one received TrackBatch payload (dropping the oldest beyond QUEUE_BATCHES)."""
        with self._queue_lock:
            self.counters["batches_received"] += 1
            self.queue.append((payload, arrived_s))
            self.queued_bytes += len(payload)
            while self.queued_bytes > QUEUE_BYTES and len(self.queue) > 1:
                self.queued_bytes -= len(self.queue.popleft()[0])
                self.counters["batches_dropped"] += 1
        self._wakeup.set()

    def _next(self) -> tuple[bytes, float] | None:
        with self._queue_lock:
            if not self.queue:
                return None
            item = self.queue.popleft()
            self.queued_bytes -= len(item[0])
            return item

    # ------------------------------------------------------------- processing
    def _run(self) -> None:
        last_health = time.monotonic()
        period_s = self.settings.bus.health_period_s
        while True:
            item = self._next()
            if item is None:
                if self.stop_event.is_set():
                    break
                self._wakeup.wait(0.05)
                self._wakeup.clear()
            else:
                self.process(*item)
            now = time.monotonic()
            if now - last_health >= period_s:
                self.publish_health()
                last_health = now
        # the daemon's last batches may still be on their way: wait for a quiet moment
        quiet_since = last = time.monotonic()
        seen = self.counters["batches_received"]
        while time.monotonic() - quiet_since < LINGER_S and time.monotonic() - last < 10 * LINGER_S:
            time.sleep(0.02)
            if self.counters["batches_received"] != seen:
                seen, quiet_since = self.counters["batches_received"], time.monotonic()
        while (item := self._next()) is not None:
            self.process(*item)

    def process(self, payload: bytes, arrived_s: float | None = None) -> list[dict]:
        """Decode one TrackBatch, run the safety nets, publish and return its alerts."""
        t0 = time.perf_counter()
        try:
            alerts = self._judge(payload)
        except Exception:  # a bug must not stop the safety nets; counted and logged
            log.exception("internal error while judging a TrackBatch")
            self._reject("internal_error", "see the log")
            return []
        if alerts is None:
            return []
        self.processing_ms.append(1e3 * (time.perf_counter() - t0))
        if self.alerts_for_instance is not None and self._batch_instance != self.alerts_for_instance:
            # a standby's child: its parent did not publish this batch; the nets judged it all
            # the same, so their alerts and ids go on if the parent takes over
            self.counters["alerts_withheld"] += len(alerts)
            self.counters["batches_processed"] += 1
            return []
        for alert in alerts:
            try:
                pub = self._pubs.get(alert["kind"])
                if pub is not None:
                    pub.put(msgpack.packb(alert, use_bin_type=True))
                    self.counters["alerts_published"] += 1
            except Exception:
                log.exception("publishing an alert failed")
                self.counters["publish_errors"] += 1
        if arrived_s is not None:
            self.latency_ms.append(1e3 * (time.monotonic() - arrived_s))
        self.counters["batches_processed"] += 1
        return alerts

    def _judge(self, payload: bytes) -> list[dict] | None:
        columns = self.reader.decode(payload)
        from ..wire import Rejection

        if isinstance(columns, Rejection):
            self._reject(columns.reason, columns.detail)
            return None
        alerts: list[dict] = []
        self._batch_instance = columns.instance
        if columns.epoch is not None:
            if columns.epoch < self.highest_epoch:
                self._reject("stale_epoch", f"period {columns.period} of epoch {columns.epoch} < {self.highest_epoch}")
                return None
            self.highest_epoch = columns.epoch
        if self.newest_t is not None and columns.t_s <= self.newest_t:
            self._out_of_order_run += 1
            if self._out_of_order_run < STREAM_RESTART_BATCHES:
                self._reject("out_of_order", f"period {columns.period} at t={columns.t_s} after t={self.newest_t}")
                return None
            log.warning("a new tracks stream (t went back to %s): the open alerts end", columns.t_s)
            self.counters["stream_restarts"] += 1
            alerts += self.nets.restart(self.newest_t)
        elif self.newest_t is not None and ids_given_again(
            self._ids_ages, columns.track_id, columns.age_s, AGE_SLACK_S
        ):
            log.warning("a new tracks stream (its track ids were given to new tracks): the open alerts end")
            self.counters["stream_restarts"] += 1
            alerts += self.nets.restart(self.newest_t)
        self._out_of_order_run = 0
        self._ids_ages = (columns.track_id.copy(), columns.age_s.copy())
        self.newest_period, self.newest_t = columns.period, columns.t_s
        alerts += self.nets.update(columns.t_s, columns)
        if columns.epoch is not None:
            for alert in alerts:
                alert["epoch"] = columns.epoch
        return alerts

    def _reject(self, reason: str, detail: str) -> None:
        self.rejected[reason] += 1
        self._log_rejection(reason, f"TrackBatch: {detail}")

    # ------------------------------------------------------------------ health
    def health_message(self) -> dict[str, Any]:
        now = time.time()
        lat = np.array(self.latency_ms)
        proc = np.array(self.processing_ms)
        counters = dict(self.counters)
        counters["queue_depth"] = len(self.queue)
        counters["model_fallbacks"] = self.reader.model_fallbacks
        counters.update({f"safety_nets_{k}": int(v) for k, v in self.nets.counters.items()})
        return {
            "v": 1,
            "t": now,
            "uptime_s": now - self.started_wall,
            "pid": os.getpid(),
            "host": socket.gethostname(),
            "counters": counters,
            "rejected": dict(self.rejected),
            "newest_period": self.newest_period,
            "newest_period_t": self.newest_t,
            "lag_s": (now - self.newest_t) if self.newest_t is not None else None,
            "active_alerts": len(self.nets.active_alerts),
            "alert_latency_ms_p50": float(np.percentile(lat, 50)) if lat.size else None,
            "alert_latency_ms_p99": float(np.percentile(lat, 99)) if lat.size else None,
            "processing_ms_p50": float(np.percentile(proc, 50)) if proc.size else None,
            "processing_ms_p99": float(np.percentile(proc, 99)) if proc.size else None,
            "hook_errors": dict(self.nets.hook_errors),
            "hook_load_errors": dict(self.nets.hooks.load_errors),
        }

    def publish_health(self) -> None:
        try:
            pub = self._pubs.get("health")
            if pub is not None:
                pub.put(msgpack.packb(self.health_message(), use_bin_type=True))
        except Exception:
            log.exception("publishing health failed")


# =========================================================================== command


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--config", help="the daemon's configuration TOML file (its [safety_nets], [system], [bus])")
    p.add_argument(
        "--connect",
        action="append",
        default=None,
        metavar="ENDPOINT",
        help="Zenoh endpoint to join, e.g. tcp/fusion-host:7447 (repeatable; default: [safety_nets] connect, "
        "else the configuration's [bus] connect endpoints, or its listen endpoints when the daemon embeds the "
        "router)",
    )
    p.add_argument("--log-level", default="INFO", help="DEBUG, INFO, WARNING, ERROR (default INFO)")
    p.add_argument("--log-format", choices=("text", "json"), default="text", help="text (default) or json")
    p.add_argument(
        "--settings-from-stdin",
        action="store_true",
        help="(used by serve) read the settings as one JSON line on stdin, and stop when stdin ends: "
        "the parent is gone",
    )


def run(args: argparse.Namespace) -> int:
    import gc
    import signal

    from ..config import ConfigError, load_settings, settings_from_dict
    from ..metrics import configure_logging

    configure_logging(args.log_level, args.log_format)
    stop = threading.Event()
    base_dir = None
    try:
        if args.settings_from_stdin:
            line = sys.stdin.buffer.readline()
            settings = settings_from_dict(json.loads(line), "<stdin>")
        elif args.config:
            settings = load_settings(args.config)
            base_dir = Path(args.config).resolve().parent
        else:
            print("safety-nets: --config FILE is required", file=sys.stderr)
            return 2
    except (ConfigError, ValueError) as exc:
        print(f"configuration error, not starting:\n{exc}", file=sys.stderr)
        return 2
    from .nets import check_maps

    problem = check_maps(settings, base_dir)
    if problem is not None:
        print(f"configuration error, not starting:\n{problem}", file=sys.stderr)
        return 2
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    if args.settings_from_stdin:
        threading.Thread(target=_watch_parent, args=(stop,), name="parent-watch", daemon=True).start()
    import zenoh

    red = settings.redundancy
    # serve's child in a hot-standby pair publishes the alerts of its own parent's batches only
    alerts_for = red.instance if args.settings_from_stdin and red.enabled else None
    service = SafetyNetsProcess(settings, base_dir=base_dir, connect=args.connect, alerts_for_instance=alerts_for)
    try:
        service.start()
    except zenoh.ZError as exc:
        print(f"cannot open the Zenoh session, not starting:\n{exc}", file=sys.stderr)
        return 3
    gc.collect()
    gc.freeze()  # as serve: the full GC passes walk only what the periods create
    try:
        while not stop.wait(0.5):
            pass
    finally:
        log.info("stopping: judging the batches received")
        done = threading.Thread(target=service.stop, daemon=True)
        done.start()
        done.join(15.0)
        if done.is_alive():  # e.g. the router died with the parent and a close hangs
            log.error("shutdown did not finish in 15 s; exiting")
            os._exit(1)
    return 0


def _watch_parent(stop: threading.Event) -> None:
    """Blocks on stdin, whose other end only the parent holds: EOF = the parent closed it
    (a clean stop) or died (any way, SIGKILL included)."""
    try:
        while sys.stdin.buffer.read(4096):
            pass
    except Exception:
        pass
    log.info("parent gone (stdin closed): stopping")
    stop.set()
