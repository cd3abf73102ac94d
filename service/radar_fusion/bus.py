"""The daemon's I/O shell on Eclipse Zenoh (DESIGN.md §2): subscribe, decode, route, publish.

Zenoh delivers samples on its own threads; the subscriber callbacks only put the raw
payload on a bounded queue (blocking briefly when it is full, which pushes back on
senders that publish with congestion control BLOCK). One processing thread decodes,
validates, hands plots to the :class:`~radar_fusion.engine.Engine`, closes periods and
packs their TrackBatch; one publishing thread sends what the engine returns and the
health snapshots, so that a consumer that stalls its link (Zenoh then blocks every put
towards it, for up to its ``wait_before_close``) never holds up ingest or period
processing:

    <prefix>/radar/*/plots   → Engine.ingest_plots     <prefix>/fusion/tracks        ← TrackBatch
    <prefix>/radar/*/status  → Engine.ingest_status    <prefix>/fusion/alerts/<kind> ← Alert
                                                       <prefix>/fusion/health        ← Health

With ``[redundancy] enabled`` (redundancy.py) the daemon is one of a hot-standby pair:
it also publishes its track state on ``<prefix>/fusion/state`` while active, and while
standby applies the active's instead of closing periods itself.

Nothing a sender does can stop the processing thread: every decode or validation
failure becomes a counted rejection, visible on the health key and logged at a
bounded rate.
"""

from __future__ import annotations

import gc
import json
import logging
import math
import queue
import threading
import time
from collections import Counter
from collections.abc import Callable
from pathlib import Path
from typing import Any, cast

import msgpack
import zenoh

from . import wire_bytes
from .config import BusConfig, Settings
from .engine import Engine, PeriodOutput
from .engine.state import StateMismatch, load_state, restore, save_state, set_state_aside, snapshot
from .engine.state import decode as decode_state
from .metrics import DaemonMetrics
from .redundancy import Election, ElectionOnBus, Role, default_instance
from .safety_nets import SafetyNets
from .safety_nets.process import health_key
from .safety_nets.supervisor import SafetyNetsChild
from .wire import DecodedPlots, RadarStatus, Rejection, decode_message, decode_plot_batch

log = logging.getLogger("radar_fusion.bus")

_zenoh_log_initialised = False


def zenoh_config(
    mode: str = "client",
    listen: list[str] | None = None,
    connect: list[str] | None = None,
    multicast_scouting: bool = False,
    config_file: str | None = None,
    lease_s: float | None = None,
) -> zenoh.Config:
    """A zenoh.Config for the given role; a JSON5 file (TLS, ACL) may provide the rest.
    ``lease_s``: how long a silent link lives (Zenoh's default is 10 s)."""
    cfg = zenoh.Config.from_file(config_file) if config_file else zenoh.Config()
    cfg.insert_json5("mode", json.dumps(mode))
    if listen is not None:
        cfg.insert_json5("listen/endpoints", json.dumps(listen))
    if connect is not None:
        cfg.insert_json5("connect/endpoints", json.dumps(connect))
    cfg.insert_json5("scouting/multicast/enabled", "true" if multicast_scouting else "false")
    if lease_s is not None:
        cfg.insert_json5("transport/link/tx/lease", str(int(lease_s * 1000)))
    return cfg


def open_session(cfg: zenoh.Config) -> zenoh.Session:
    global _zenoh_log_initialised
    if not _zenoh_log_initialised:
        zenoh.init_log_from_env_or("error")
        _zenoh_log_initialised = True
    return zenoh.open(cfg)


def client_config_for(bus: BusConfig) -> zenoh.Config:
    """Config for a tool (replay, record, bridge) that joins the daemon described by ``bus``."""
    endpoints = bus.connect if bus.mode == "client" else bus.listen
    return zenoh_config("client", connect=list(endpoints), config_file=bus.zenoh_config_file)


def tool_client_config(config_path: str | None, connect: list[str] | None, prefix: str | None):
    """Session config and key prefix for a tool (replay, record): from the daemon's
    config file if given, ``connect`` endpoints overriding; defaults tcp/127.0.0.1:7447, 'atc'."""
    from .config import load_settings

    if config_path:
        settings = load_settings(config_path)
        # --connect replaces the endpoints only: TLS, ACL identities and the rest of the
        # daemon's zenoh_config_file still apply (issue 13: replay/record could not join a TLS bus)
        cfg = (
            client_config_for(settings.bus)
            if not connect
            else zenoh_config("client", connect=connect, config_file=settings.bus.zenoh_config_file)
        )
        return cfg, prefix or settings.bus.prefix
    return zenoh_config("client", connect=connect or ["tcp/127.0.0.1:7447"]), prefix or "atc"


def batch_head(payload: bytes) -> dict[str, Any]:
    """A TrackBatch's fields but its tracks, from its bytes: the head and the tail are
    read, the tracks between only skipped."""
    unpacker = msgpack.Unpacker(raw=False, max_buffer_size=max(len(payload), 1 << 20))
    unpacker.feed(payload)
    fields: dict[str, Any] = {}
    for _ in range(unpacker.read_map_header()):
        key = unpacker.unpack()
        if key == "tracks":
            unpacker.skip()
        else:
            fields[key] = unpacker.unpack()
    return fields


def batch_stamp(payload: bytes) -> tuple[str, int, int] | None:
    """(instance, epoch, period) of a TrackBatch's bytes (:func:`batch_head`), or None
    without a stamp."""
    fields = batch_head(payload)
    instance, epoch, period = fields.get("instance"), fields.get("epoch"), fields.get("period")
    if isinstance(instance, str) and type(epoch) is int and type(period) is int:
        return instance, epoch, period
    return None


class Sender:
    """Puts on one key expression (reliable, Zenoh's default) without a declared publisher.

    A declared ``zenoh.Publisher`` interns its key expression on the wire as a numeric
    scope. A router that receives data with a scope it does not know drops it, with
    "Route data with unknown scope" (eclipse-zenoh/zenoh#980, open): CI lost part of a
    full-speed replay that way (test_faults, scopes 8 and 9 of the replaying session).
    One path to it, from Zenoh's source: undeclaring a publisher undeclares its scope at
    Control priority, which may pass data still queued at Data priority; on loopback I
    could not make it happen. A put carries the whole key, so no message depends on a
    declaration; on loopback it is about as fast (2 kB payloads: 2.2-2.8e5 puts/s against
    2.8e5 through a publisher)."""

    __slots__ = ("_session", "congestion_control", "key_expr")

    def __init__(self, session: zenoh.Session, key: str, congestion_control: zenoh.CongestionControl):
        self._session = session
        self.key_expr = zenoh.KeyExpr(key)
        self.congestion_control = congestion_control

    def put(self, payload: bytes) -> None:
        self._session.put(self.key_expr, payload, congestion_control=self.congestion_control)


def reliable_sender(session: zenoh.Session, key: str) -> Sender:
    """Plots, tracks and alerts are sent reliably with congestion control BLOCK (DESIGN.md §3)."""
    return Sender(session, key, zenoh.CongestionControl.BLOCK)


def dropping_sender(session: zenoh.Session, key: str) -> Sender:
    """Health and standby state: each message is whole and the next replaces it, so a slow
    consumer makes the sender drop rather than wait (congestion control DROP)."""
    return Sender(session, key, zenoh.CongestionControl.DROP)


class _Oversize(bytes):
    """Stands for a payload refused as oversize on Zenoh's thread, before any copy (a
    distinct object: a real empty payload is the interned b"")."""


_OVERSIZE = _Oversize()


#: a received message decoded and validated: plots, a status, why it is refused, or None
#: (a key that is neither)
Decoded = DecodedPlots | RadarStatus | Rejection | None


class RateLimitedLog:
    """Log a rejection at most once per interval per reason, with the count since."""

    def __init__(self, interval_s: float = 10.0):
        self.interval_s = interval_s
        self._last: dict[str, float] = {}
        self._suppressed: Counter = Counter()

    def __call__(self, reason: str, detail: str) -> None:
        now = time.monotonic()
        if now - self._last.get(reason, -1e9) >= self.interval_s:
            extra = f" (+{self._suppressed[reason]} more since last report)" if self._suppressed[reason] else ""
            log.warning("rejected: %s: %s%s", reason, detail, extra)
            self._last[reason] = now
            self._suppressed[reason] = 0
        else:
            self._suppressed[reason] += 1


class FusionDaemon:
    """The fusion daemon: one Zenoh session, one engine, a processing and a publishing thread,
    and by default the safety nets as a supervised child process (``safety_nets``)."""

    safety_nets_ready_timeout_s = 30.0  # a fresh interpreter's imports take ~3 s on 2 shared cores
    # After handing a period's output to an idle publishing thread, the processing thread
    # waits (at most this long: a consumer that stalls its link blocks the put) for the
    # TrackBatch's put to return, instead of going on with the messages that queued up
    # meanwhile while the publisher waits for the interpreter (5 ms, Python's switch
    # interval, at 20,000x30) and then puts against it.
    handover_wait_s = 0.02

    def __init__(
        self,
        settings: Settings,
        queue_size: int = 50_000,
        idle_flush_s: float | None = None,
        base_dir: Path | None = None,
        outbox_size: int = 1024,
        safety_nets: str | None = None,
        log_format: str = "text",
        state_dir: Path | None = None,
        state_interval_s: float = 0.0,
        timing_log: Path | None = None,
    ):
        self.settings = settings
        self.prefix = settings.bus.prefix
        # A hot-standby pair (redundancy.py): without it this daemon is simply the active
        red = settings.redundancy
        self.instance = red.instance or default_instance()
        if red.enabled and red.instance is None:  # the child learns whose alerts it publishes
            settings = settings.model_copy(update={"redundancy": red.model_copy(update={"instance": self.instance})})
        self.election = (
            Election(self.instance, time.monotonic(), red.settle_s, handover_s=red.handover_s) if red.enabled else None
        )
        self.role: Role = "standby" if red.enabled else "active"
        self.epoch = 0  # the epoch this daemon publishes under while active (0: no redundancy)
        self._control: queue.SimpleQueue = queue.SimpleQueue()  # election events, others' states
        self._election_bus: ElectionOnBus | None = None
        self._published_seen: int | None = None  # the newest period another active published
        self._not_before_period: int | None = None  # after a take-over: periods up to it were published
        self.redundancy_counters: Counter[str] = Counter(
            dict.fromkeys(
                (
                    "states_published",
                    "states_applied",
                    "states_refused",
                    "periods_not_republished",
                    "outputs_withheld",
                    "state_bytes",
                ),
                0,
            )
        )
        # Where the safety nets run: "child" (their own process, started here), "in_process"
        # (on the processing thread) or "external" (none here); default [safety_nets] process.
        self.safety_nets_mode = (safety_nets or settings.safety_nets.process).replace("-", "_")
        if self.safety_nets_mode not in ("child", "in_process", "external"):
            raise ValueError(f"safety_nets must be child, in_process or external, not {safety_nets!r}")
        # base_dir: where the config file lives; relative areas/MSA file paths resolve there
        in_process = self.safety_nets_mode == "in_process"
        self.engine = Engine(settings, safety_nets=SafetyNets.from_settings(settings, base_dir) if in_process else None)
        wire_bytes.warm_up()  # the plot decoder's compiled parser, now rather than at the first batch
        self.safety_nets_child: SafetyNetsChild | None = None
        if self.safety_nets_mode == "child":
            self.safety_nets_child = SafetyNetsChild(settings, base_dir, log_format=log_format)
        self.safety_nets_health: dict[str, Any] | None = None  # the newest from our child
        self._safety_nets_ready = threading.Event()
        # state_dir: the engine's tracks are written there after the periods it publishes (at
        # most every state_interval_s, wall clock) and read back at start (engine/state.py)
        self.state_dir = state_dir
        self.state_interval_s = state_interval_s
        self.tracks_restored: int | None = None
        self.state_set_aside: Path | None = None
        if state_dir is not None:
            try:
                self.tracks_restored = load_state(self.engine, state_dir)
            except StateMismatch as exc:
                # another configuration's state (radars or filter changed) or a damaged file:
                # a surveillance service starts anyway, without it, and keeps the file aside
                self.state_set_aside = set_state_aside(state_dir)
                log.warning(
                    "state not restored, the daemon starts without it (%s); set aside as %s", exc, self.state_set_aside
                )
        self.states_saved = 0
        self._state_saved_at = -math.inf
        self.queue: queue.Queue = queue.Queue(maxsize=queue_size)
        self.stop_event = threading.Event()
        self.stopped = threading.Event()
        self.started_wall = time.time()
        # No message for this long (wall clock): close the periods still buffered.
        self.idle_flush_s = idle_flush_s or max(3.0 * settings.system.period_s, 10.0)
        self.messages_received = 0
        self.messages_processed = 0
        self.batches_published = 0
        self.overload = 0  # messages refused on Zenoh's threads for a full queue
        self._overload_counted = 0  # ... of which the processing thread has told the engine
        self._arrivals_lock = threading.Lock()  # Zenoh may call back on several threads
        # Outputs wait here for the publishing thread; when it is full the oldest is dropped.
        self.outbox: queue.Queue = queue.Queue(maxsize=outbox_size)
        self.outputs_dropped = 0
        self.publish_errors = 0
        self._put_done = threading.Event()  # the publishing thread put a TrackBatch (or withheld it)
        self._clock_suspect: dict[str, bool] = {}  # per radar, as last logged
        self._health_pending = False  # a periodic health snapshot waits in the outbox
        self._last_processed = time.monotonic()
        self._log_rejection = RateLimitedLog()
        self._session: zenoh.Session | None = None
        self._subs: list[Any] = []
        self._pubs: dict[str, Sender] = {}
        self._thread: threading.Thread | None = None
        self._publisher: threading.Thread | None = None
        self.on_output: Callable[[PeriodOutput], None] | None = None
        self.metrics = DaemonMetrics(settings.metrics.listen)  # private registry; served when listen is set
        # serve --timing-log: each published period's path through the daemon, timestamped
        self.timing_log = timing_log
        self._timing_file: Any = None
        # the last input processed: arrived, taken from the queue, decoded, ingested
        self._closing: tuple[float, float, float, float] | None = None
        self._timings: dict[int, dict[str, float]] = {}  # period → stamps so far (processing → publishing thread)
        self._gc_s = 0.0  # with timing_log: time in the garbage collector so far (any thread)
        self._gc_started_s = 0.0

    # ------------------------------------------------------------- lifecycle
    def start(self) -> FusionDaemon:
        bus = self.settings.bus
        lease_s = self.settings.redundancy.lease_s if self.election is not None else None
        cfg = zenoh_config(bus.mode, bus.listen, bus.connect, bus.multicast_scouting, bus.zenoh_config_file, lease_s)
        self.metrics.start()
        if self.timing_log is not None:
            self._timing_file = open(self.timing_log, "w", buffering=1)  # noqa: SIM115 (closed by stop)
            gc.callbacks.append(self._gc_timer)
        self._session = open_session(cfg)
        p = self.prefix
        self._pubs["tracks"] = reliable_sender(self._session, f"{p}/fusion/tracks")
        self._pubs["health"] = dropping_sender(self._session, f"{p}/fusion/health")
        if self.election is not None:
            # a state is whole: one a slow standby misses is replaced by the next (DROP, not BLOCK)
            self._pubs["state"] = dropping_sender(self._session, f"{p}/fusion/state")
            remote = zenoh.Locality.REMOTE
            for key, callback in (("state", self._on_state), ("tracks", self._on_tracks)):
                sub = self._session.declare_subscriber(f"{p}/fusion/{key}", callback, allowed_origin=remote)
                self._subs.append(sub)
            self._election_bus = ElectionOnBus(self._session, p, self.instance, self._on_election)
            # what is on the bus now, before any decision (then settle_s from here)
            self._election_bus.scan(timeout_s=10.0)
            assert self.election is not None
            self.election.started_s = time.monotonic()
        if self.safety_nets_mode == "in_process":
            for kind in ("stca", "apw", "msaw"):
                self._pubs[kind] = reliable_sender(self._session, f"{p}/fusion/alerts/{kind}")
        elif self.safety_nets_child is not None:
            # The child joins this session's router (or the routers it connects to), then
            # says it is ready with its first health; the processing thread waits for that
            # (bounded) before its first period, so that the child judges the first periods
            # too. Plots received meanwhile wait in the input queue.
            self._subs.append(self._session.declare_subscriber(health_key(p), self._on_safety_nets_health))
            self.safety_nets_child.start()
        else:
            log.warning("safety nets: external; this daemon runs none (a radar-fusion safety-nets must run elsewhere)")
        # One subscriber for plots and status: its callback sees a sender's messages in
        # the order they were sent, so a north marker never overtakes the plots before it.
        self._subs.append(self._session.declare_subscriber(f"{p}/radar/*/*", self._on_sample))
        self._publisher = threading.Thread(target=self._publish_loop, name="fusion-publish", daemon=True)
        self._publisher.start()
        self._thread = threading.Thread(target=self._run, name="fusion-engine", daemon=True)
        self._thread.start()
        log.info("fusion daemon up: mode=%s listen=%s connect=%s prefix=%s", bus.mode, bus.listen, bus.connect, p)
        return self

    def stop(self, timeout_s: float = 30.0) -> None:
        """Drain what was received, flush the open periods, publish them, close the session."""
        if self.safety_nets_child is not None:
            self.safety_nets_child.no_more_restarts()  # it judges the last periods, then stops
        self.stop_event.set()
        if self._thread is not None:
            self._thread.join(timeout_s)
            if self._thread.is_alive():  # said, not silent: these messages will not be processed
                log.error(
                    "processing not finished %.0f s after the stop: %d received messages not processed, "
                    "the open periods not published",
                    timeout_s,
                    self.queue.qsize(),
                )
        if self._publisher is not None:
            try:
                self.outbox.put(None, timeout=timeout_s)  # after the last batches and the final health
            except queue.Full:
                log.error("publishing thread stuck; %d outputs not sent", self.outbox.qsize())
            self._publisher.join(timeout_s)
        if self.safety_nets_child is not None:  # after the last batches: it judges them, then exits
            self.safety_nets_child.stop()
        if self._election_bus is not None:
            self._election_bus.close()
            self._election_bus = None
        for sub in self._subs:
            sub.undeclare()
        self._subs = []
        self._pubs = {}
        if self._session is not None:
            self._session.close()
            self._session = None
        self.metrics.close()
        if self._timing_file is not None:
            self._timing_file.close()
            self._timing_file = None
            gc.callbacks.remove(self._gc_timer)
        self.stopped.set()

    def __enter__(self) -> FusionDaemon:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def _on_safety_nets_health(self, sample: zenoh.Sample) -> None:
        """The child's health (Zenoh's thread): kept for this daemon's health; the first says it is ready."""
        child = self.safety_nets_child
        try:
            health = msgpack.unpackb(sample.payload.to_bytes(), raw=False)
            if child is None or not isinstance(health, dict) or health.get("pid") != child.pid:
                return  # another safety-nets process on the bus
        except Exception:
            return
        self.safety_nets_health = health
        self._safety_nets_ready.set()

    # ------------------------------------------------------------- redundancy
    def _on_election(self, kind: str, instance: str, epoch: int, alive: bool) -> None:
        self._control.put((kind, instance, epoch, alive))  # Zenoh's thread: hand over

    def _on_state(self, sample: zenoh.Sample) -> None:
        self._control.put(("state", sample.payload.to_bytes()))

    def _on_tracks(self, sample: zenoh.Sample) -> None:
        """Another active's TrackBatch: only its stamp and period are wanted."""
        try:
            stamp = batch_stamp(sample.payload.to_bytes())
        except Exception:
            return
        if stamp is not None:
            self._control.put(("tracks", *stamp))

    def _redundancy_step(self) -> None:
        """The processing thread's turn at the election: what the bus showed, then the rules."""
        election = self.election
        if election is None:
            return
        while True:
            try:
                item = self._control.get_nowait()
            except queue.Empty:
                break
            kind = item[0]
            if kind == "member":
                election.member_seen(item[1], item[3])
            elif kind == "active":
                election.active_seen(item[1], item[2], item[3], time.monotonic())
            elif kind == "tracks":
                instance, epoch, period = item[1:]
                election.epoch_seen(instance, epoch)
                if epoch >= election.highest_epoch:
                    self._saw_published(period)
            elif kind == "state":
                self._take_state(item[1])  # decides first: an active may have to stand down
        self._decide()  # on everything the bus showed, not event by event (a member seen before its active token)

    def _decide(self) -> None:
        election = self.election
        assert election is not None
        decision = election.decide(time.monotonic())
        if decision == "take_over":
            self.epoch = election.took_over(time.time())
            self.role = "active"
            self._not_before_period = self._published_seen
            if self._election_bus is not None:
                self._election_bus.declare_active(self.epoch)
            log.warning(
                "%s is the active now, epoch %d (periods up to %s were published before)",
                self.instance,
                self.epoch,
                self._published_seen,
            )
        elif decision == "stand_down":
            election.stood_down()
            self.role = "standby"
            if self._election_bus is not None:
                self._election_bus.withdraw_active()
            log.warning("%s stands down: an active of epoch %d is on the bus", self.instance, election.highest_epoch)

    def _saw_published(self, period: int) -> None:
        """Another active published ``period`` (its TrackBatch, or the state after it)."""
        self._published_seen = period if self._published_seen is None else max(period, self._published_seen)

    def _take_state(self, payload: bytes) -> None:
        """Another active's state: a standby applies it (its tracks become the active's)."""
        election = self.election
        assert election is not None
        try:
            state = decode_state(payload)
            epoch, instance, period = state.get("epoch"), state.get("instance"), state.get("period")
            if type(epoch) is not int or not isinstance(instance, str):
                raise StateMismatch("a state without an active's epoch and instance")
        except StateMismatch as exc:
            self.redundancy_counters["states_refused"] += 1
            self._log_rejection("state", str(exc))
            return
        election.epoch_seen(instance, epoch)
        if epoch < election.highest_epoch:
            self.redundancy_counters["states_refused"] += 1
            self._log_rejection("state", f"a stale active's state (epoch {epoch} < {election.highest_epoch})")
            return
        self._decide()  # an active that sees a newer active stands down before it applies its state
        if self.role != "standby":
            return
        try:
            restore(self.engine, state, replace=True)
        except StateMismatch as exc:
            self.redundancy_counters["states_refused"] += 1
            self._log_rejection("state", str(exc))
            return
        self.redundancy_counters["states_applied"] += 1
        self._save_state(payload)  # a pair restarted whole comes back with its tracks on either host
        if type(period) is int:
            self._saw_published(period)

    # ------------------------------------------------------------------ input
    def _on_sample(self, sample: zenoh.Sample) -> None:
        # Zenoh's thread: copy out and hand over, nothing else. An oversize payload is not
        # copied (bounded memory): an empty stand-in of the same verdict is queued instead,
        # so the processing thread counts it as "oversize" in order with the rest.
        size = len(sample.payload)
        payload = sample.payload.to_bytes() if size <= self.settings.bus.max_payload_bytes else _OVERSIZE
        item = (str(sample.key_expr), payload, time.monotonic())
        with self._arrivals_lock:
            self.messages_received += 1
        try:
            self.queue.put(item, timeout=2.0)
        except queue.Full:
            with self._arrivals_lock:
                self.overload += 1

    def _handle(self, key: str, payload: bytes) -> None:
        """Decode, validate and ingest one received message (the two stages in one call)."""
        self._ingest(key, self._decode(key, payload))

    def _decode(self, key: str, payload: bytes) -> Decoded:
        """What a message says, checked against the wire contract (no state is touched);
        None for a key that is neither plots nor status."""
        kind = key.rpartition("/")[2]
        if kind not in ("plots", "status"):
            return None
        max_bytes = self.settings.bus.max_payload_bytes
        if payload is _OVERSIZE:
            return Rejection("oversize", f"more than {max_bytes} bytes on {key}")
        if kind == "plots":
            return decode_plot_batch(payload, max_bytes)
        # decode_message returns an instance of the model it is given (or a Rejection)
        return cast("RadarStatus | Rejection", decode_message(payload, RadarStatus, max_bytes))

    def _ingest(self, key: str, decoded: Decoded) -> None:
        """Hand a decoded message to the engine, or count why not."""
        radar_id = key.split("/")[-2]
        if decoded is None:
            self._reject(Rejection("schema", f"unknown key {key}"), radar_id)
        elif isinstance(decoded, Rejection):
            self._reject(decoded, radar_id)
        elif decoded.radar_id != radar_id:
            self._reject(Rejection("key_mismatch", f"{decoded.radar_id} on {key}"), radar_id)
        elif isinstance(decoded, RadarStatus):
            self.engine.ingest_status(decoded)
        else:
            self.engine.ingest_plots(decoded)
            for reason, n in decoded.rejected.items():
                self._log_rejection(reason, f"{n} plot(s) of {radar_id} seq {decoded.seq}")

    def _reject(self, rejection: Rejection, radar_id: str) -> None:
        if rejection.reason != "unknown_radar" and radar_id not in self.engine.radar_index:
            rejection = Rejection("unknown_radar", radar_id)
        self.engine.reject(rejection.reason, 1, radar_id)
        self._log_rejection(rejection.reason, f"{radar_id}: {rejection.detail}")

    # ------------------------------------------------------------- processing
    def _run(self) -> None:
        deadline = time.monotonic() + self.safety_nets_ready_timeout_s
        while self.safety_nets_child is not None and not self._safety_nets_ready.wait(0.05):
            if self.stop_event.is_set() or time.monotonic() > deadline:
                break
        if self.safety_nets_child is not None and not self._safety_nets_ready.is_set():
            log.error(
                "safety-nets child not ready after %.0f s: the tracks go on without it for now",
                self.safety_nets_ready_timeout_s,
            )
        last_health = 0.0
        processed_at_flush = 0  # messages_processed when the open periods were last flushed
        while True:
            stopping = self.stop_event.is_set()
            try:
                self._process_safely(*self.queue.get(timeout=0.05))
                for _ in range(1000):  # drain a burst before polling the engine
                    self._process_safely(*self.queue.get_nowait())
            except queue.Empty:
                pass
            self._count_overload()
            self._guarded(self._redundancy_step, "the redundancy step")
            if self.role == "active":  # a standby closes no period: it applies the active's state
                self._guarded(self._poll, "closing a period")
            idle_s = time.monotonic() - self._last_processed
            if self.role == "active" and self.messages_processed > processed_at_flush and idle_s > self.idle_flush_s:
                self._guarded(lambda: self._poll(flush=True), "flushing the open periods")
                processed_at_flush = self.messages_processed
            now = time.monotonic()
            if now - last_health >= self.settings.bus.health_period_s:
                health = self.health_message()
                self._check_clocks(health)
                if not self._health_pending:  # one at a time while the publisher is held up
                    self._health_pending = True
                    self._emit(("health", health))
                last_health = now
            if stopping and self.queue.empty():
                break
        self._count_overload()
        self._redundancy_step()
        if self.role == "active" and not (self.election is not None and self.election.members):
            self._poll(flush=True)
        # (with a standby on the bus the open periods are left to it: it takes over with its
        # own plots of them, instead of periods closed early without their late plots)
        health = self.health_message()
        self._check_clocks(health)
        self._emit(("health", health))  # the final health, after the last batches

    def _count_overload(self) -> None:
        """Hand the overload refusals of Zenoh's threads to the engine's counters (the
        engine is only ever touched by the processing thread)."""
        n = self.overload - self._overload_counted
        if n:
            self._overload_counted += n
            self.engine.reject("overload", n)

    def _guarded(self, step: Callable[[], object], what: str) -> None:
        """One step of the processing loop: a bug in it must not end the loop (the daemon
        would stay on the bus, silent); it is logged and counted as an internal error."""
        try:
            step()
        except Exception:
            log.exception("internal error while %s", what)
            self.engine.reject("internal_error")

    def _process_safely(self, key: str, payload: bytes, arrived_s: float | None = None) -> None:
        taken_s = time.monotonic()
        decoded_s = math.nan
        try:
            decoded = self._decode(key, payload)
            decoded_s = time.monotonic()
            self._ingest(key, decoded)
        except Exception:  # a bug must not take the daemon down; it is counted and logged
            log.exception("internal error while processing %s", key)
            self.engine.reject("internal_error")
        self.messages_processed += 1
        self._last_processed = time.monotonic()
        if arrived_s is not None:  # monotonic time the Zenoh callback queued it
            self.metrics.observe_ingest(self._last_processed - arrived_s)
            self._closing = (arrived_s, taken_s, decoded_s, self._last_processed)

    def _gc_timer(self, phase: str, info: dict[str, Any]) -> None:
        """gc.callbacks entry (with timing_log): the time spent collecting garbage."""
        if phase == "start":
            self._gc_started_s = time.monotonic()
        else:
            self._gc_s += time.monotonic() - self._gc_started_s

    def _poll(self, flush: bool = False) -> None:
        """Close the periods the watermarks allow (``flush``: every buffered one) and hand
        their outputs over; with ``timing_log``, each period's stamps so far."""
        poll_s = time.monotonic()
        outputs = self.engine.flush() if flush else self.engine.poll()
        if self._timing_file is not None and outputs:
            engine_done_s = time.monotonic()
            arrived_s, taken_s, decoded_s, ingested_s = self._closing or (math.nan,) * 4
            for out in outputs:
                self._timings[out.period] = {
                    "period": out.period,
                    "arrived_s": arrived_s,  # the input processed last before the period closed
                    "taken_s": taken_s,
                    "decoded_s": decoded_s,
                    "ingested_s": ingested_s,
                    "poll_s": poll_s,
                    "engine_done_s": engine_done_s,
                    "engine_s": out.processing_s,
                    "queue_depth": self.queue.qsize(),
                    "gc_at_poll_s": self._gc_s,
                    "periods_in_poll": len(outputs),
                }
        self._publish(outputs)

    def _check_clocks(self, health: dict[str, Any]) -> None:
        """Log each radar whose clock became suspect, or good again (the engine's estimates,
        as the health snapshot carries them)."""
        limit_s = self.settings.system.clock_offset_limit_s
        for rid in self.engine.radar_ids:
            radar = health["radars"][rid]
            was, now = self._clock_suspect.get(rid, False), bool(radar["clock_suspect"])
            if now and not was:
                log.warning(
                    "radar %s: clock offset %.1f s against the other radars (limit %.1f s)",
                    rid,
                    radar["clock_offset_s"],
                    limit_s,
                )
            elif was and not now:
                log.info("radar %s: clock back within %.1f s of the other radars", rid, limit_s)
            self._clock_suspect[rid] = now

    # ------------------------------------------------------------- publishing
    def _publish(self, outputs: list[PeriodOutput]) -> None:
        publisher_idle = self.outbox.empty()
        self._put_done.clear()
        for out in outputs:
            self.metrics.observe_period(out.processing_s)
            if self._not_before_period is not None and out.period <= self._not_before_period:
                # after a take-over: the lost active published this period already
                self.redundancy_counters["periods_not_republished"] += 1
                self._timings.pop(out.period, None)
                continue
            if self.election is not None:
                out.track_columns.epoch, out.track_columns.instance = self.epoch, self.instance
                for alert in out.alerts:
                    alert["epoch"] = self.epoch
            # Packed here, before the hand-over (with the stamp above): on the publishing
            # thread the packing shared the interpreter with this thread's next work, the
            # messages that queued up during the period, and waited for its turn.
            _ = out.track_batch_bytes
            if (stamps := self._timings.get(out.period)) is not None:
                stamps["emitted_s"] = time.monotonic()
            self._emit(out)
        if not outputs:
            return
        if publisher_idle and self._publisher is not None:
            self._put_done.wait(self.handover_wait_s)
        data = None
        if self.election is not None:
            # after the period's TrackBatch: a standby that saw the batch but not this state
            # (the active died between) recomputes the period without publishing it again
            data = snapshot(self.engine, outputs[-1].period, self.epoch, self.instance)
            self._emit(("state", data, self.epoch))
        self._save_state(data)  # after the hand-over: tracks never wait for it

    def _save_state(self, data: bytes | None = None) -> None:
        """With ``--state-dir``: write the engine's state (or ``data``, the state just applied)
        at most every ``state_interval_s``."""
        if self.state_dir is not None:
            now = time.monotonic()
            if now - self._state_saved_at >= self.state_interval_s:
                save_state(self.engine, self.state_dir, data)
                self.states_saved += 1
                self._state_saved_at = now

    def _emit(self, item: Any) -> None:
        """Hand an output to the publishing thread; never waits (drops the oldest when full)."""
        try:
            self.outbox.put_nowait(item)
        except queue.Full:
            try:
                dropped = self.outbox.get_nowait()
                if isinstance(dropped, tuple):  # a health snapshot or a state: a newer one will follow
                    if dropped[0] == "health":
                        self._health_pending = False
                else:
                    self.outputs_dropped += 1
                    self._timings.pop(dropped.period, None)
            except queue.Empty:
                pass
            self.outbox.put_nowait(item)

    def _publish_loop(self) -> None:
        while True:
            item = self.outbox.get()
            if item is None:
                return
            if isinstance(item, tuple) and item[0] == "health":  # a snapshot taken by the processing thread
                self._health_pending = False
                self.publish_health(item[1])
                continue
            if isinstance(item, tuple):  # ("state", bytes, epoch): for the standbys
                if self._still_active(item[2]):
                    try:
                        self._pubs["state"].put(item[1])
                        self.redundancy_counters["states_published"] += 1
                        self.redundancy_counters["state_bytes"] = len(item[1])  # the newest
                    except Exception:
                        log.exception("publishing the state failed")
                        self.publish_errors += 1
                continue
            out: PeriodOutput = item
            stamps = self._timings.pop(out.period, None)  # every way out of here drops them
            if self.election is not None and not self._still_active(out.track_columns.epoch):
                self.redundancy_counters["outputs_withheld"] += 1  # it stood down meanwhile
                self._put_done.set()
                continue
            try:
                payload = out.track_batch_bytes  # packed from the columns by the processing thread
                if stamps is not None:
                    stamps.update(picked_s=time.monotonic(), bytes=len(payload))
                self._pubs["tracks"].put(payload)
                self._put_done.set()
                if stamps is not None:
                    stamps.update(put_s=time.monotonic(), gc_at_put_s=self._gc_s)
                for alert in out.alerts:
                    self._pubs[alert["kind"]].put(msgpack.packb(alert, use_bin_type=True))
                self.batches_published += 1
                if self.on_output is not None:
                    self.on_output(out)
            except Exception:
                log.exception("publishing period %s failed", out.period)
                self.publish_errors += 1
            if stamps is not None and self._timing_file is not None:
                stamps["done_s"] = time.monotonic()
                self._timing_file.write(json.dumps(stamps) + "\n")

    def _still_active(self, epoch: int | None) -> bool:
        """Whether an output stamped ``epoch`` may still go out: this daemon is still that active."""
        return self.role == "active" and epoch == self.epoch

    def health_message(self) -> dict[str, Any]:
        h = self.engine.health()
        now = time.time()
        newest = h.pop("newest_period_t")
        h["counters"].update(
            messages_received=self.messages_received,
            messages_processed=self.messages_processed,
            queue_depth=self.queue.qsize(),
            batches_published=self.batches_published,
            outbox_depth=self.outbox.qsize(),
            outputs_dropped=self.outputs_dropped,
            publish_errors=self.publish_errors,
        )
        if self.election is not None:
            h["counters"].update(
                self.redundancy_counters,
                takeovers=self.election.takeovers,
                stand_downs=self.election.stand_downs,
            )
        if self.state_dir is not None:  # serve --state-dir
            h["counters"].update(
                states_saved=self.states_saved,
                tracks_restored=self.tracks_restored or 0,
                states_set_aside=int(self.state_set_aside is not None),
            )
        health = {
            "v": 1,
            "t": now,
            "uptime_s": now - self.started_wall,
            **h,
            "lag_s": (now - newest) if newest else None,
            "role": self.role,
            "epoch": self.epoch,
            "instance": self.instance,
        }
        health["safety_nets"] = self.safety_nets_status()
        child = self.safety_nets_child
        if child is not None:
            counters = h["counters"]
            counters["safety_nets_process_restarts"] = child.restarts
            relayed = self.safety_nets_health
            if relayed is not None and isinstance(relayed.get("counters"), dict):
                # the child's event counts, under the names they had in process (safety_nets_<name>)
                counters.update(
                    {k: v for k, v in relayed["counters"].items() if k.startswith("safety_nets_") and type(v) is int}
                )
        return health

    def safety_nets_status(self) -> dict[str, Any]:
        """Where the safety nets run and, for a child, whether it runs (health ``safety_nets``)."""
        status: dict[str, Any] = {"process": self.safety_nets_mode}
        child = self.safety_nets_child
        if child is not None:
            status.update(child.status())
            relayed = self.safety_nets_health
            status["health_age_s"] = (
                (time.time() - relayed["t"]) if relayed and type(relayed.get("t")) is float else None
            )
        return status

    def publish_health(self, health: dict[str, Any] | None = None) -> None:
        """Publish a health message: ``health`` (a snapshot), or one built now. Its
        publication counters are those of the moment it goes out."""
        try:
            health = self.health_message() if health is None else health
            health["counters"].update(
                batches_published=self.batches_published,
                outbox_depth=self.outbox.qsize(),
                outputs_dropped=self.outputs_dropped,
                publish_errors=self.publish_errors,
            )
            self.metrics.update_health(health)
            self._pubs["health"].put(msgpack.packb(health, use_bin_type=True))
        except Exception:
            log.exception("publishing health failed")
