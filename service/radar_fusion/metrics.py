"""Observability: the daemon's Prometheus metrics endpoint and structured (JSON) logs.

Metrics (one private registry per daemon, served on ``[metrics] listen`` when set):

    radar_fusion_<counter>_total          each health counter (messages_received, batches_received,
                                          plots_received, plots_accepted, periods_closed, ...)
    radar_fusion_rejected_total{reason}   every rejection by reason (plot_late, schema, ...)
    radar_fusion_radar_live{radar}        1 while a radar holds periods open, else 0
    radar_fusion_radar_*{radar}           per-radar plots, batches, seq gaps, wild plots,
                                          rejections by reason, watermark (event time),
                                          clock offset and clock-suspect flag
    radar_fusion_tracks, _tracks_confirmed, _plots_buffered, _queue_depth, _lag_seconds,
    radar_fusion_uptime_seconds           gauges
    radar_fusion_period_processing_seconds    histogram: engine time per closed period
    radar_fusion_ingest_latency_seconds       histogram: message arrival → decoded and ingested

Counters and gauges come from the daemon's health message (the same figures as on the
``<prefix>/fusion/health`` key), snapshotted each time it is published, so a scrape is at
most ``[bus] health_period_s`` old; the histograms are observed as the events happen.
"""

from __future__ import annotations

import json
import logging
import math
import re
import sys
import threading
import time
from collections.abc import Iterator
from datetime import UTC, datetime
from typing import Any
from wsgiref.simple_server import WSGIServer

from prometheus_client import CollectorRegistry, Histogram, start_http_server
from prometheus_client.core import CounterMetricFamily, GaugeMetricFamily
from prometheus_client.registry import Collector

log = logging.getLogger("radar_fusion.metrics")

NAMESPACE = "radar_fusion"
# Health counters that are levels, not event counts (every other one is exported as a
# Prometheus counter: a new level in health["counters"] must be listed here).
GAUGE_COUNTERS = frozenset({"tracks_confirmed", "plots_buffered", "queue_depth", "outbox_depth", "state_bytes"})
PERIOD_BUCKETS_S = (0.001, 0.0025, 0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1.0, 2.5, 5.0)
INGEST_BUCKETS_S = (0.0001, 0.00025, 0.0005, 0.001, 0.0025, 0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1.0, 2.5, 5.0)
_RADAR_COUNTERS = {  # health radars[<id>] field → metric name suffix, help
    "plots": ("radar_plots", "plots of the radar accepted into the period buffer"),
    "batches": ("radar_batches", "plot batches received from the radar"),
    "seq_gaps": ("radar_seq_gaps", "missing sequence numbers in the radar's batches"),
    "seq_restarts": ("radar_seq_restarts", "times the radar's batch numbering started again (a front-end restart)"),
    "wild": ("radar_wild_plots", "plots of the radar rejected as wild by the outlier gate"),
}


def parse_listen(listen: str) -> tuple[str, int]:
    """``"127.0.0.1:9108"`` / ``"[::1]:9108"`` / ``":9108"`` (all interfaces) → (host, port)."""
    host, sep, port = listen.rpartition(":")
    if not sep or not port.isdigit() or not 0 < int(port) < 65536:
        raise ValueError(f"metrics listen address must be HOST:PORT, got {listen!r}")
    host = host.strip("[]") or "0.0.0.0"
    return host, int(port)


def _metric_name(text: str) -> str:
    return re.sub(r"[^a-zA-Z0-9_]", "_", text)


def _number(value: Any) -> float | None:
    if isinstance(value, bool):
        return float(value)
    if isinstance(value, (int, float)) and math.isfinite(value):
        return float(value)
    return None


class _HealthCollector(Collector):
    """Renders the newest health snapshot as Prometheus counters and gauges."""

    def __init__(self, metrics: DaemonMetrics):
        self.metrics = metrics

    def collect(self) -> Iterator[Any]:
        health = self.metrics.health
        if health is None:
            return
        ns = NAMESPACE
        for name, value in sorted(health.get("counters", {}).items()):
            v = _number(value)
            if v is None:
                continue
            if name in GAUGE_COUNTERS:
                yield GaugeMetricFamily(f"{ns}_{_metric_name(name)}", f"health counter {name} (a level)", value=v)
            else:
                yield CounterMetricFamily(f"{ns}_{_metric_name(name)}", f"health counter {name}", value=v)
        rejected = CounterMetricFamily(f"{ns}_rejected", "messages or plots refused, by reason", labels=["reason"])
        for reason, n in sorted(health.get("rejected", {}).items()):
            rejected.add_metric([reason], float(n))
        yield rejected

        radars = health.get("radars", {})
        live = GaugeMetricFamily(f"{ns}_radar_live", "1 while the radar is live (holds periods open)", labels=["radar"])
        watermark = GaugeMetricFamily(
            f"{ns}_radar_watermark_timestamp_seconds",
            "event time (UTC epoch s) of the radar's newest plot or status",
            labels=["radar"],
        )
        clock = GaugeMetricFamily(
            f"{ns}_radar_clock_offset_seconds",
            "estimated clock offset of the radar against the other radars",
            labels=["radar"],
        )
        suspect = GaugeMetricFamily(
            f"{ns}_radar_clock_suspect", "1 when the radar's clock offset exceeds the limit", labels=["radar"]
        )
        per_radar = {
            field: CounterMetricFamily(f"{ns}_{name}", text, labels=["radar"])
            for field, (name, text) in _RADAR_COUNTERS.items()
        }
        radar_rejected = CounterMetricFamily(
            f"{ns}_radar_rejected", "refused plots or messages of the radar", labels=["radar", "reason"]
        )
        for rid, r in sorted(radars.items()):
            live.add_metric([rid], 1.0 if r.get("live") else 0.0)
            wm = _number(r.get("watermark_t"))
            if wm is not None:
                watermark.add_metric([rid], wm)
            offset_s = _number(r.get("clock_offset_s"))
            if offset_s is not None:
                clock.add_metric([rid], offset_s)
            if "clock_suspect" in r:
                suspect.add_metric([rid], 1.0 if r["clock_suspect"] else 0.0)
            for field, family in per_radar.items():
                v = _number(r.get(field))
                if v is not None:
                    family.add_metric([rid], v)
            for reason, n in sorted((r.get("rejected") or {}).items()):
                radar_rejected.add_metric([rid, reason], float(n))
        yield live
        yield watermark
        yield clock
        yield suspect
        yield from per_radar.values()
        yield radar_rejected

        for key, name, text in (
            ("tracks", "tracks", "system tracks held (all statuses)"),
            ("lag_s", "lag_seconds", "wall time minus the reference time of the newest closed period"),
            ("uptime_s", "uptime_seconds", "seconds since the daemon started"),
            ("t", "health_timestamp_seconds", "wall time (UTC epoch s) of this health snapshot"),
        ):
            v = _number(health.get(key))
            if v is not None:
                yield GaugeMetricFamily(f"{ns}_{name}", text, value=v)
        # a hot-standby pair (redundancy.py): alarm when no instance, or two, report active
        if health.get("role") in ("active", "standby"):
            yield GaugeMetricFamily(
                f"{ns}_active",
                "1 while this daemon publishes (the active of a pair, or alone), 0 as a standby",
                value=1.0 if health["role"] == "active" else 0.0,
            )
        epoch = _number(health.get("epoch"))
        if epoch is not None:
            yield GaugeMetricFamily(f"{ns}_epoch", "the active's epoch (0 without redundancy)", value=epoch)


class DaemonMetrics:
    """One daemon's metrics: a private registry, its histograms, the newest health
    snapshot, and (when ``listen`` is set) the HTTP endpoint serving them."""

    def __init__(self, listen: str | None = None):
        self.listen = listen
        self.registry = CollectorRegistry()
        self.period_processing_s = Histogram(
            f"{NAMESPACE}_period_processing_seconds",
            "engine processing time of one closed period",
            buckets=PERIOD_BUCKETS_S,
            registry=self.registry,
        )
        self.ingest_latency_s = Histogram(
            f"{NAMESPACE}_ingest_latency_seconds",
            "time from a message's arrival at the daemon to the end of its decoding and ingest (queue wait included)",
            buckets=INGEST_BUCKETS_S,
            registry=self.registry,
        )
        self.health: dict[str, Any] | None = None
        self.registry.register(_HealthCollector(self))
        self._server: WSGIServer | None = None
        self._thread: threading.Thread | None = None
        self.address: tuple[str, int] | None = None

    def start(self) -> DaemonMetrics:
        """Serve ``/metrics`` on ``listen`` (nothing to do when it is not set)."""
        if self.listen and self._server is None:
            host, port = parse_listen(self.listen)
            self._server, self._thread = start_http_server(port, addr=host, registry=self.registry)
            bound_host, bound_port = self._server.server_address[:2]
            # typeshed allows bytes for AF_UNIX paths; an AF_INET(6) server's host is already a str
            self.address = (str(bound_host), bound_port)
            log.info(
                "metrics endpoint on http://%s:%d/metrics", host, bound_port, extra={"metrics_listen": self.listen}
            )
        return self

    def close(self) -> None:
        if self._server is not None:
            self._server.shutdown()
            self._server.server_close()
            if self._thread is not None:
                self._thread.join(5.0)
            self._server = self._thread = None

    def update_health(self, health: dict[str, Any]) -> None:
        """Keep the newest health message (not mutated afterwards) for the next scrape."""
        self.health = health

    def observe_period(self, processing_s: float) -> None:
        self.period_processing_s.observe(processing_s)

    def observe_ingest(self, latency_s: float) -> None:
        self.ingest_latency_s.observe(latency_s)


# ------------------------------------------------------------------------- logs

_RECORD_ATTRS = frozenset(vars(logging.LogRecord("", 0, "", 0, "", None, None))) | {"message", "asctime", "taskName"}


class JsonFormatter(logging.Formatter):
    """One JSON object per line: time (UTC, ISO 8601), level, logger, message, the
    record's ``extra`` fields, and exception text when there is one."""

    def format(self, record: logging.LogRecord) -> str:
        doc: dict[str, Any] = {
            "time": datetime.fromtimestamp(record.created, UTC).isoformat(timespec="milliseconds"),
            "level": record.levelname,
            "logger": record.name,
            "message": record.getMessage(),
        }
        for key, value in record.__dict__.items():
            if key not in _RECORD_ATTRS and not key.startswith("_"):
                doc[key] = value
        if record.exc_info:
            doc["exception"] = self.formatException(record.exc_info)
        if record.stack_info:
            doc["stack"] = self.formatStack(record.stack_info)
        return json.dumps(doc, default=str, ensure_ascii=False)


def configure_logging(level: str = "INFO", fmt: str = "text", stream: Any = None) -> None:
    """Root logging for ``radar-fusion serve``: ``text`` (human) or ``json`` (one object a line)."""
    handler = logging.StreamHandler(stream or sys.stderr)
    if fmt == "json":
        handler.setFormatter(JsonFormatter())
    elif fmt == "text":
        text = logging.Formatter("%(asctime)s.%(msecs)03dZ %(levelname)s %(name)s: %(message)s", "%Y-%m-%dT%H:%M:%S")
        text.converter = time.gmtime  # UTC, like the JSON logs
        handler.setFormatter(text)
    else:
        raise ValueError(f"log format must be 'text' or 'json', got {fmt!r}")
    root = logging.getLogger()
    for old in list(root.handlers):
        root.removeHandler(old)
    root.addHandler(handler)
    root.setLevel(level.upper())
