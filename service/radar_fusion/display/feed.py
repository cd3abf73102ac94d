"""From the bus to the page: decode, validate and reshape what the daemon publishes.

The display is a consumer like any other (DESIGN.md §2): it subscribes to
``<prefix>/fusion/tracks``, ``<prefix>/fusion/alerts/*``, ``<prefix>/fusion/health``
and ``<prefix>/radar/*/status``. Every message is validated against the wire contract
(``wire.py``); one that fails is counted by reason (``malformed_msgpack``, ``schema``,
``version``, ``oversize``, ``key_mismatch``) and skipped, never raised.

Nothing here touches the daemon's hot path. Zenoh's callback only copies the payload
into :class:`Feed`'s inbox (the newest TrackBatch replaces one not yet decoded: the
page wants the present, not a backlog; each replaced one is counted in
``tracks_coalesced``) and wakes one decoding thread, which turns messages into the
JSON frames the page draws and hands them to a sink (the web server's hub).

Track frames are columnar (one array per field, ``n`` entries each) so that the page
parses 4,000 tracks in one ``JSON.parse`` and loops over typed columns:

    {"type": "tracks", "t": ..., "period": ..., "n": N, "ended": [...],
     "id", "status" (0 confirmed, 1 coasting, 2 tentative), "x_m", "y_m", "vx_mps", "vy_mps",
     "fl", "vrate_fpm", "mode3a", "mode_s", "callsign", "lat_deg", "lon_deg",
     "sources", "updates", "age_s", "sigma_m", "manoeuvre_prob"}

``callsign`` is not in wire contract v1; a sender that adds it to a track (receivers
ignore unknown fields) has it shown in place of the Mode 3/A code.
"""

from __future__ import annotations

import json
import logging
import math
import threading
import time
from collections import Counter, deque
from collections.abc import Callable
from typing import Any

from pydantic import BaseModel, ValidationError

from ..bus import RateLimitedLog
from ..wire import WIRE_VERSION, Alert, Health, RadarStatus, Rejection, TrackBatch, ids_given_again, unpack

log = logging.getLogger("radar_fusion.display")

STATUS_CODES = {"confirmed": 0, "coasting": 1, "tentative": 2}
"""Track status as the page's small integers (its symbol table is indexed by them)."""
ALERT_STALE_PERIODS = 3.0
"""An alert not refreshed for this many periods is dropped (the daemon sends ``ongoing``
every period and ``ended`` at the end; this covers an ``ended`` that never arrived)."""
TRACKS_STALE_PERIODS = 3.0
"""No TrackBatch for this many periods of wall time: the picture is stale (the daemon
stopped, or the bus between): the page says so and greys it, rather than show it live."""
MAX_EVENT_T_S = 1e10
"""Event times a frame may carry (UTC epoch s, until 2286): a TrackBatch or an alert
beyond is refused (the page's clock cannot show it, and its alerts would outlive all)."""
AGE_SLACK_S = 0.1
"""A track's age in a frame is rounded to 0.1 s (tracks_frame): younger by more is another track."""
INBOX_LIMIT = 10_000
"""Alerts, health and status messages waiting to be decoded; beyond, the oldest are dropped."""
CALLSIGN_MAX_CHARS = 8


def _validate(payload: bytes, model: type[BaseModel], max_bytes: int) -> tuple[Any, Any] | Rejection:
    """(raw decoded map, validated model), or the Rejection a malformed message earns."""
    obj = unpack(payload, max_bytes)
    if isinstance(obj, Rejection):
        return obj
    if not isinstance(obj, dict):
        return Rejection("schema", f"expected a map, got {type(obj).__name__}")
    if type(obj.get("v")) is not int or obj.get("v") != WIRE_VERSION:
        return Rejection("version", f"v={obj.get('v')!r}")
    try:
        return obj, model.model_validate(obj)
    except ValidationError as exc:
        first = exc.errors()[0]
        return Rejection("schema", f"{'.'.join(map(str, first['loc']))}: {first['msg']}")


def _callsign(raw: Any) -> str | None:
    cs = raw.get("callsign") if isinstance(raw, dict) else None
    if isinstance(cs, str) and 0 < len(cs.strip()) <= CALLSIGN_MAX_CHARS:
        return cs.strip()
    return None


def _r(value: float | None, digits: int) -> float | None:
    return None if value is None else round(value, digits)


def tracks_frame(payload: bytes, max_bytes: int = 16 << 20) -> dict[str, Any] | Rejection:
    """A TrackBatch payload as the page's columnar frame (module docstring), or a Rejection."""
    checked = _validate(payload, TrackBatch, max_bytes)
    if isinstance(checked, Rejection):
        return checked
    raw, batch = checked
    if not 0.0 < batch.t < MAX_EVENT_T_S:
        return Rejection("schema", f"t: {batch.t} is no event time")
    tracks = batch.tracks
    raw_tracks = raw.get("tracks") or []
    return {
        "type": "tracks",
        "t": batch.t,
        "period": batch.period,
        "epoch": batch.epoch,
        "n": len(tracks),
        "ended": list(batch.ended),
        "id": [tr.track_id for tr in tracks],
        "status": [STATUS_CODES[tr.status] for tr in tracks],
        "x_m": [round(tr.x_m, 1) for tr in tracks],
        "y_m": [round(tr.y_m, 1) for tr in tracks],
        "vx_mps": [_r(tr.vx_mps, 2) for tr in tracks],
        "vy_mps": [_r(tr.vy_mps, 2) for tr in tracks],
        "fl": [_r(tr.fl, 1) for tr in tracks],
        "vrate_fpm": [_r(tr.vrate_fpm, 0) for tr in tracks],
        "mode3a": [tr.mode3a for tr in tracks],
        "mode_s": [tr.mode_s for tr in tracks],
        "callsign": [_callsign(r) for r in raw_tracks],
        "lat_deg": [round(tr.lat_deg, 5) for tr in tracks],
        "lon_deg": [round(tr.lon_deg, 5) for tr in tracks],
        "sources": [",".join(tr.sources) for tr in tracks],
        "updates": [tr.updates for tr in tracks],
        "age_s": [round(tr.age_s, 1) for tr in tracks],
        # 1-σ of the position: the square root of the covariance's mean diagonal
        "sigma_m": [round(math.sqrt(max(0.5 * (tr.cov_xy[0] + tr.cov_xy[2]), 0.0)), 1) for tr in tracks],
        "manoeuvre_prob": [_r(tr.manoeuvre_prob, 2) for tr in tracks],
    }


def decode_alert(payload: bytes, kind: str, max_bytes: int = 1 << 20) -> dict[str, Any] | Rejection:
    """An Alert from ``.../alerts/<kind>`` as a dict, or a Rejection (``key_mismatch``
    when the payload's kind is not the key's)."""
    checked = _validate(payload, Alert, max_bytes)
    if isinstance(checked, Rejection):
        return checked
    alert = checked[1]
    if alert.kind != kind:
        return Rejection("key_mismatch", f"{alert.kind} alert on the {kind} key")
    if not 0.0 < alert.t < MAX_EVENT_T_S:
        return Rejection("schema", f"t: {alert.t} is no event time")
    return alert.model_dump(mode="json")


def decode_health(payload: bytes, max_bytes: int = 4 << 20) -> dict[str, Any] | Rejection:
    checked = _validate(payload, Health, max_bytes)
    return checked if isinstance(checked, Rejection) else checked[1].model_dump(mode="json")


def decode_status(payload: bytes, radar_id: str, max_bytes: int = 1 << 16) -> dict[str, Any] | Rejection:
    checked = _validate(payload, RadarStatus, max_bytes)
    if isinstance(checked, Rejection):
        return checked
    status = checked[1]
    if status.radar_id != radar_id:
        return Rejection("key_mismatch", f"{status.radar_id} on the status key of {radar_id}")
    return status.model_dump(mode="json")


class AlertBook:
    """The alerts open now, by ``alert_id``: ``new`` and ``ongoing`` refresh one,
    ``ended`` removes it, and one not refreshed for :data:`ALERT_STALE_PERIODS` periods
    of event time (behind the newest track batch) is dropped, as is one stamped as many
    periods ahead of it (it would never be behind: one damaged alert shown for ever)."""

    def __init__(self, period_s: float) -> None:
        self.period_s = period_s
        self.active: dict[int, dict[str, Any]] = {}

    def apply(self, alert: dict[str, Any]) -> None:
        if alert["status"] == "ended":
            self.active.pop(alert["alert_id"], None)
        else:
            self.active[alert["alert_id"]] = alert

    def prune(self, now_t: float) -> bool:
        """Drop stale alerts at event time ``now_t``; True when any was dropped."""
        margin_s = ALERT_STALE_PERIODS * self.period_s
        stale = [k for k, a in self.active.items() if not now_t - margin_s <= a["t"] <= now_t + margin_s]
        for k in stale:
            del self.active[k]
        return bool(stale)

    def frame(self) -> dict[str, Any]:
        return {"type": "alerts", "alerts": sorted(self.active.values(), key=lambda a: a["alert_id"])}


Sink = Callable[[str, str], None]
"""Where frames go: ``sink(channel, json_text)``; channel is tracks, alerts, health or radars."""


class Feed:
    """The display's Zenoh subscriptions, its inbox and its decoding thread.

    ``Feed(session, prefix, period_s, sink).start()``; ``stats()`` returns its counters
    (messages by kind, rejections by reason, TrackBatches coalesced, decoding time).
    """

    def __init__(self, session: Any, prefix: str, period_s: float, sink: Sink, max_payload_bytes: int = 16 << 20):
        self.session = session
        self.prefix = prefix
        self.sink = sink
        self.max_payload_bytes = max_payload_bytes
        self.alerts = AlertBook(period_s)
        self.received: Counter[str] = Counter(dict.fromkeys(("tracks", "alerts", "health", "status"), 0))
        self.rejected: Counter[str] = Counter()
        self.tracks_coalesced = 0
        self.inbox_dropped = 0
        self.frames_built = 0
        self.decode_ms_last: float | None = None
        self.last_tracks_t: float | None = None
        self.last_tracks_n: int | None = None
        self.last_tracks_mono: float | None = None  # monotonic wall time of the newest TrackBatch shown
        self.period_s = period_s
        self._ids_ages: tuple[list[int], list[float]] | None = None  # the newest batch's track ids and ages
        self.stream_restarts = 0
        self.radar_status: dict[str, dict[str, Any]] = {}
        self.highest_epoch = 0  # a hot-standby pair's: what is below is a stale active's
        self._cond = threading.Condition()
        self._pending_tracks: bytes | None = None
        self._inbox: deque[tuple[str, bytes]] = deque()
        self._stop = False
        self._thread: threading.Thread | None = None
        self._subs: list[Any] = []
        self._log_rejection = RateLimitedLog()

    # ------------------------------------------------------------ lifecycle
    def start(self) -> Feed:
        self._thread = threading.Thread(target=self._run, name="display-decode", daemon=True)
        self._thread.start()
        import zenoh

        p = self.prefix
        # indirect=False: the callbacks (a copy and a notify) run on Zenoh's own thread, with no
        # Python thread of zenoh's in between (as tools/record.py). With zenoh's default indirect
        # threads, `radar-fusion display` stopped by SIGINT on a loaded machine aborted at exit
        # ("FATAL: exception not rethrown") in 2 of 20 runs; with direct callbacks, 0 of 20.
        self._subs = [
            self.session.declare_subscriber(key, zenoh.handlers.Callback(fn, indirect=False))
            for key, fn in (
                (f"{p}/fusion/tracks", self._on_tracks),
                (f"{p}/fusion/alerts/*", self._on_other),
                (f"{p}/fusion/health", self._on_other),
                (f"{p}/radar/*/status", self._on_other),
            )
        ]
        return self

    def stop(self) -> None:
        for sub in self._subs:
            sub.undeclare()
        self._subs = []
        with self._cond:
            self._stop = True
            self._cond.notify()
        if self._thread is not None:
            self._thread.join(5.0)

    # ------------------------------------------------------ Zenoh's threads
    def _on_tracks(self, sample: Any) -> None:
        if len(sample.payload) > self.max_payload_bytes:  # refused before any copy: bounded memory
            self._count(self.rejected, "oversize")
            return
        payload = sample.payload.to_bytes()
        with self._cond:
            self.received["tracks"] += 1
            if self._pending_tracks is not None:
                self.tracks_coalesced += 1
            self._pending_tracks = payload
            self._cond.notify()

    def _on_other(self, sample: Any) -> None:
        if len(sample.payload) > self.max_payload_bytes:
            self._count(self.rejected, "oversize")
            return
        item = (str(sample.key_expr), sample.payload.to_bytes())
        with self._cond:
            if len(self._inbox) >= INBOX_LIMIT:
                self._inbox.popleft()
                self.inbox_dropped += 1
            self._inbox.append(item)
            self._cond.notify()

    # ------------------------------------------------------ decoding thread
    def _run(self) -> None:
        while True:
            with self._cond:
                while not self._stop and self._pending_tracks is None and not self._inbox:
                    self._cond.wait()
                if self._stop:
                    return
                tracks, self._pending_tracks = self._pending_tracks, None
                items = list(self._inbox)
                self._inbox.clear()
            try:
                self.handle(items, tracks)
            except Exception:  # a bug must not stop the picture; it is counted and logged
                log.exception("display: decoding failed")
                self._count(self.rejected, "internal_error")

    def handle(self, items: list[tuple[str, bytes]], tracks: bytes | None) -> None:
        """Decode a batch of messages (alerts, health, status in arrival order, then the
        newest TrackBatch) and send the frames they change. Runs on the decoding thread;
        tests call it directly."""
        alerts_changed = radars_changed = False
        health: dict[str, Any] | None = None
        for key, payload in items:
            rel = key[len(self.prefix) + 1 :] if key.startswith(self.prefix + "/") else key
            parts = rel.split("/")
            if parts[:2] == ["fusion", "alerts"] and len(parts) == 3:
                self._count(self.received, "alerts")
                alert = decode_alert(payload, parts[2], self.max_payload_bytes)
                if self._ok(alert, key) and self._current(alert, key):
                    self.alerts.apply(alert)  # type: ignore[arg-type]
                    alerts_changed = True
            elif rel == "fusion/health":
                self._count(self.received, "health")
                decoded = decode_health(payload, self.max_payload_bytes)
                if self._ok(decoded, key) and decoded.get("role") != "standby":  # type: ignore[union-attr]
                    health = decoded  # type: ignore[assignment]  # a pair's: the active's is shown
            elif parts[0] == "radar" and len(parts) == 3 and parts[2] == "status":
                self._count(self.received, "status")
                status = decode_status(payload, parts[1], self.max_payload_bytes)
                if self._ok(status, key):
                    self.radar_status[parts[1]] = status  # type: ignore[assignment]
                    radars_changed = True
            else:
                self._ok(Rejection("schema", "not a key the display subscribes to"), key)
        if tracks is not None:
            t0 = time.perf_counter()
            frame = tracks_frame(tracks, self.max_payload_bytes)
            key = f"{self.prefix}/fusion/tracks"
            if self._ok(frame, key) and self._current(frame, key):
                assert isinstance(frame, dict)
                if ids_given_again(self._ids_ages, frame["id"], frame["age_s"], AGE_SLACK_S):
                    # the daemon restarted without its state: its ids from 1 again, on other
                    # aircraft; the old alerts and the page's trails are not theirs
                    self.stream_restarts += 1
                    frame["new_stream"] = True
                    alerts_changed |= bool(self.alerts.active)
                    self.alerts.active.clear()
                self._ids_ages = (frame["id"], frame["age_s"])
                self.last_tracks_t, self.last_tracks_n = frame["t"], frame["n"]
                self.last_tracks_mono = time.monotonic()
                alerts_changed |= self.alerts.prune(frame["t"])
                self.sink("tracks", json.dumps(frame, separators=(",", ":")))
                self.frames_built += 1
            self.decode_ms_last = (time.perf_counter() - t0) * 1e3
        if alerts_changed:
            self.sink("alerts", json.dumps(self.alerts.frame(), separators=(",", ":")))
        if radars_changed:
            self.sink("radars", json.dumps({"type": "radars", "status": self.radar_status}, separators=(",", ":")))
        if health is not None:
            self.sink("health", json.dumps({"type": "health", "health": health}, separators=(",", ":")))

    def _count(self, counter: Counter[str], name: str) -> None:
        with self._cond:  # stats() copies the counters from another thread
            counter[name] += 1

    def _current(self, message: Any, key: str) -> bool:
        """False for a message of an epoch below the highest seen: a stale active's, after
        a hot-standby pair's partition healed (counted ``stale_epoch``)."""
        epoch = message.get("epoch")
        if epoch is None:
            return True
        if epoch < self.highest_epoch:
            return self._ok(Rejection("stale_epoch", f"epoch {epoch} < {self.highest_epoch}"), key)
        self.highest_epoch = epoch
        return True

    def _ok(self, decoded: object, key: str) -> bool:
        if isinstance(decoded, Rejection):
            self._count(self.rejected, decoded.reason)
            self._log_rejection(decoded.reason, f"display skipped a message on {key}: {decoded.detail}")
            return False
        return True

    def stats(self) -> dict[str, Any]:
        with self._cond:
            return {
                "received": dict(self.received),
                "rejected": dict(self.rejected),
                "tracks_coalesced": self.tracks_coalesced,
                "inbox_dropped": self.inbox_dropped,
                "frames_built": self.frames_built,
                "decode_ms_last": self.decode_ms_last,
                "last_tracks_t": self.last_tracks_t,
                "last_tracks_n": self.last_tracks_n,
                # wall seconds since the newest TrackBatch, and beyond what the picture is stale
                "tracks_age_s": None if self.last_tracks_mono is None else time.monotonic() - self.last_tracks_mono,
                "tracks_stale_after_s": TRACKS_STALE_PERIODS * self.period_s,
                "stream_restarts": self.stream_restarts,
                "alerts_active": len(self.alerts.active),
            }
