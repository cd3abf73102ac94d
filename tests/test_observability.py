"""Observability over a real Zenoh router on 127.0.0.1: the daemon's Prometheus endpoint
counts what a replay and some bad messages did to it (scraped over HTTP), and
`radar-fusion serve --log-format json` writes one JSON object per line."""

from __future__ import annotations

import io
import json
import logging
import signal
import socket
import subprocess
import sys
import time
import tomllib
import urllib.request
from collections import Counter

import msgpack
import pytest
from prometheus_client.parser import text_string_to_metric_families

from radar_fusion.bus import FusionDaemon, open_session, reliable_sender, zenoh_config
from radar_fusion.config import ConfigError, settings_from_dict
from radar_fusion.metrics import JsonFormatter, parse_listen
from radar_fusion.tools import simulate as sim
from radar_fusion.tools.demo import wait_until


@pytest.fixture(scope="module")
def simulation():
    """The demo scenario (3 radars, 28 aircraft), 60 s of traffic."""
    return sim.simulate(sim.preset("demo", seed=5, duration_s=60.0))


def other_free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def scrape(url: str) -> dict[tuple[str, tuple], float]:
    """Every sample of a /metrics page: (name, sorted labels) → value."""
    with urllib.request.urlopen(url, timeout=5) as resp:
        assert resp.status == 200
        text = resp.read().decode()
    return {
        (s.name, tuple(sorted(s.labels.items()))): s.value
        for fam in text_string_to_metric_families(text)
        for s in fam.samples
    }


@pytest.mark.bus
def test_metrics_endpoint_counts_received_rejected_late_and_closed_periods(simulation, free_port):
    base = tomllib.loads(sim.config_toml(simulation.scenario))
    metrics_port = other_free_port()
    base["bus"].update(listen=[f"tcp/127.0.0.1:{free_port}"], health_period_s=0.2)
    base["metrics"] = {"listen": f"127.0.0.1:{metrics_port}"}
    settings = settings_from_dict(base)
    radar_ids = [r.id for r in settings.radars]
    n_plot_batches = sum(1 for _, key, _ in simulation.messages if key.endswith("/plots"))
    n_plots = sum(len(pc) for pc in simulation.plot_columns)
    plots_per_radar = Counter()
    for pc in simulation.plot_columns:
        plots_per_radar[pc.radar_id] += len(pc)
    url = f"http://127.0.0.1:{metrics_port}/metrics"

    daemon = FusionDaemon(settings, idle_flush_s=60.0).start()  # no idle flush during the test
    session = open_session(zenoh_config("client", connect=[f"tcp/127.0.0.1:{free_port}"]))
    pubs = {}
    try:
        before = scrape(url)  # served from start; no health snapshot yet, histograms empty
        assert before[("radar_fusion_ingest_latency_seconds_count", ())] == 0
        time.sleep(0.3)  # the daemon's subscription reaches the client
        for _, key, payload in simulation.messages:
            if key not in pubs:
                pubs[key] = reliable_sender(session, f"atc/{key}")
            pubs[key].put(payload)
        first = radar_ids[0]
        bad = reliable_sender(session, f"atc/radar/{first}/plots")
        bad.put(b"\xc1 not msgpack")
        bad.put(b"\x92\x01")  # an array cut short: truncated msgpack
        # a plot of a period long closed (the scenario's first second), in a fresh batch
        old_t = simulation.scenario.start_t_s + 1.0
        bad.put(
            msgpack.packb(
                {
                    "v": 1,
                    "radar_id": first,
                    "seq": 10**6,
                    "plots": [{"t": old_t, "range_m": 80_000.0, "azimuth_deg": 30.0}],
                }
            )
        )
        stranger = reliable_sender(session, "atc/radar/intruder/plots")
        stranger.put(
            msgpack.packb(
                {
                    "v": 1,
                    "radar_id": "intruder",
                    "seq": 1,
                    "plots": [{"t": old_t, "range_m": 80_000.0, "azimuth_deg": 30.0}],
                }
            )
        )
        n_sent = len(simulation.messages) + 4
        assert wait_until(lambda: daemon.messages_processed >= n_sent, 30)
        key = ("radar_fusion_messages_processed_total", ())
        assert wait_until(lambda: scrape(url).get(key, 0) >= n_sent, 5)
        time.sleep(0.3)  # one more health snapshot, after the last period the replay closed
        m = scrape(url)
    finally:
        session.close()
        daemon.stop()

    assert m[("radar_fusion_messages_received_total", ())] == n_sent
    assert m[("radar_fusion_batches_received_total", ())] == n_plot_batches + 2  # + the late and the stranger's
    assert m[("radar_fusion_plots_received_total", ())] == n_plots + 1
    assert m[("radar_fusion_plots_accepted_total", ())] == n_plots
    rejected = {dict(lbl)["reason"]: v for (name, lbl), v in m.items() if name == "radar_fusion_rejected_total"}
    assert rejected == {"malformed_msgpack": 2, "plot_late": 1, "unknown_radar": 1}
    assert m[("radar_fusion_radar_rejected_total", (("radar", first), ("reason", "malformed_msgpack")))] == 2
    assert m[("radar_fusion_radar_rejected_total", (("radar", first), ("reason", "plot_late")))] == 1
    for rid in radar_ids:
        assert m[("radar_fusion_radar_live", (("radar", rid),))] == 1
        assert m[("radar_fusion_radar_plots_total", (("radar", rid),))] == plots_per_radar[rid]
    # every closed period was timed once; 60 s of traffic at the scenario's period
    periods = m[("radar_fusion_periods_closed_total", ())]
    assert periods == m[("radar_fusion_period_processing_seconds_count", ())]
    assert periods >= 0.6 * simulation.scenario.duration_s / simulation.scenario.effective_period_s
    # the histogram holds the engine's own processing time of every period, in seconds (the
    # periods closed before the scrape; stop() closed more)
    timed_s = list(daemon.engine.processing_s)[: int(periods)]
    assert m[("radar_fusion_period_processing_seconds_sum", ())] == pytest.approx(sum(timed_s))
    # every message that reached the daemon was timed from arrival to ingest
    assert m[("radar_fusion_ingest_latency_seconds_count", ())] == n_sent
    assert m[("radar_fusion_ingest_latency_seconds_bucket", (("le", "+Inf"),))] == n_sent
    assert m[("radar_fusion_tracks_confirmed", ())] >= 10
    assert m[("radar_fusion_queue_depth", ())] == 0


def test_metrics_listen_address_is_validated():
    assert parse_listen("127.0.0.1:9108") == ("127.0.0.1", 9108)
    assert parse_listen("[::1]:9108") == ("::1", 9108)
    assert parse_listen(":9108") == ("0.0.0.0", 9108)
    base = {
        "system": {"center_lat": 47.0, "center_lon": 8.0},
        "radars": [
            {
                "id": "r1",
                "lat": 47.0,
                "lon": 8.0,
                "sigma_range_m": 50.0,
                "sigma_azimuth_deg": 0.1,
                "rotation_period_s": 4.0,
            }
        ],
    }
    assert settings_from_dict(base).metrics.listen is None  # off by default
    with pytest.raises(ConfigError, match=r"metrics\.listen"):
        settings_from_dict({**base, "metrics": {"listen": "9108"}})


def test_json_formatter_keeps_extra_fields_and_exceptions():
    stream = io.StringIO()
    handler = logging.StreamHandler(stream)
    handler.setFormatter(JsonFormatter())
    logger = logging.getLogger("radar_fusion.test_json")
    logger.addHandler(handler)
    logger.propagate = False
    try:
        logger.warning("rejected: %s", "schema", extra={"radar_id": "north", "count": 3})
        try:
            raise ValueError("bad plot")
        except ValueError:
            logger.exception("internal error")
    finally:
        logger.removeHandler(handler)
        logger.propagate = True
    first, second = [json.loads(line) for line in stream.getvalue().splitlines()]
    assert first["level"] == "WARNING" and first["logger"] == "radar_fusion.test_json"
    assert first["message"] == "rejected: schema" and first["radar_id"] == "north" and first["count"] == 3
    assert first["time"].endswith("+00:00")
    assert second["level"] == "ERROR" and "ValueError: bad plot" in second["exception"]


@pytest.mark.bus
def test_serve_writes_json_logs_and_serves_metrics(simulation, free_port, tmp_path):
    """`serve --log-format json` as a process, with a [metrics] section in its file."""
    metrics_port = other_free_port()
    config = tmp_path / "config.toml"
    text = sim.config_toml(simulation.scenario).replace(
        'listen = ["tcp/127.0.0.1:7447"]', f'listen = ["tcp/127.0.0.1:{free_port}"]\nhealth_period_s = 0.2'
    )
    config.write_text(text + f'\n[metrics]\nlisten = "127.0.0.1:{metrics_port}"\n')
    # `radar-fusion serve` without the other subcommands' imports (seconds on a busy machine);
    # tests/test_service.py runs the installed command itself
    serve = (
        "import argparse, sys; from radar_fusion import cli; p = argparse.ArgumentParser(); "
        "cli._serve_arguments(p); sys.exit(cli._serve(p.parse_args()))"
    )
    proc = subprocess.Popen(
        [sys.executable, "-c", serve, "--config", str(config), "--log-format", "json"],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
    )
    session = None
    try:
        deadline = time.monotonic() + 60
        while session is None:
            try:
                session = open_session(zenoh_config("client", connect=[f"tcp/127.0.0.1:{free_port}"]))
            except Exception:
                assert proc.poll() is None, proc.communicate()[1]
                assert time.monotonic() < deadline, "the daemon did not start"
                time.sleep(0.1)
        health = []
        sub = session.declare_subscriber("atc/fusion/health", lambda sample: health.append(sample))
        assert wait_until(lambda: bool(health), 10), "no health message from the daemon"
        sub.undeclare()
        pub = reliable_sender(session, f"atc/radar/{simulation.scenario.radars[0].id}/plots")
        pub.put(b"\xc1 not msgpack")  # logged as a rejection
        url = f"http://127.0.0.1:{metrics_port}/metrics"
        key = ("radar_fusion_rejected_total", (("reason", "malformed_msgpack"),))
        assert wait_until(lambda: scrape(url).get(key) == 1, 10)
    finally:
        if session is not None:
            session.close()
        proc.send_signal(signal.SIGTERM)
        _, stderr = proc.communicate(timeout=15)
    assert proc.returncode == 0, stderr
    lines = [json.loads(line) for line in stderr.splitlines() if line.strip()]  # every line is JSON
    assert all({"time", "level", "logger", "message"} <= set(d) for d in lines)
    messages = [d["message"] for d in lines]
    assert any(msg.startswith("fusion daemon up") for msg in messages), messages
    up = next(d for d in lines if d["message"].startswith("metrics endpoint"))
    assert up["metrics_listen"] == f"127.0.0.1:{metrics_port}" and up["logger"] == "radar_fusion.metrics"
    warning = next(d for d in lines if "malformed_msgpack" in d["message"])
    assert warning["level"] == "WARNING" and warning["logger"] == "radar_fusion.bus"
    assert "stopping: flushing open periods" in messages


def test_a_pairs_role_and_epoch_are_gauges():
    """Issue 13: an operator alarms when no instance of a pair, or two, report active."""
    from prometheus_client import generate_latest

    from radar_fusion.metrics import DaemonMetrics

    m = DaemonMetrics()
    health = {"t": 1.7e9, "uptime_s": 3.0, "counters": {"takeovers": 1, "state_bytes": 4096}, "rejected": {}}
    m.update_health({**health, "role": "standby", "epoch": 2, "instance": "fusion-b"})
    text = generate_latest(m.registry).decode()
    assert "radar_fusion_active 0.0" in text and "radar_fusion_epoch 2.0" in text
    assert "# TYPE radar_fusion_state_bytes gauge" in text and "radar_fusion_takeovers_total 1.0" in text
    m.update_health({**health, "role": "active", "epoch": 3})
    assert "radar_fusion_active 1.0" in generate_latest(m.registry).decode()
