"""The safety-nets process over a real Zenoh router (127.0.0.1, free ports): the same
alerts as in process, restarted when it dies, gone with serve (SIGKILL included), bad
TrackBatches counted on its health key."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from collections import Counter

import msgpack
import pytest

from radar_fusion.bus import FusionDaemon, open_session, zenoh_config
from radar_fusion.config import load_settings, settings_from_dict
from radar_fusion.safety_nets.process import SafetyNetsProcess, health_key
from radar_fusion.tools import simulate as sim
from radar_fusion.tools.demo import run_pipeline, wait_until
from radar_fusion.wire import SafetyNetsHealth

pytestmark = pytest.mark.bus  # every test here opens Zenoh sessions


def on_port(settings, port: int, process: str):
    return settings.model_copy(
        update={
            "bus": settings.bus.model_copy(update={"mode": "router", "listen": [f"tcp/127.0.0.1:{port}"]}),
            "safety_nets": settings.safety_nets.model_copy(update={"process": process}),
        }
    )


def small_config(port: int) -> dict:
    return {
        "system": {"center_lat": 47.0, "center_lon": 8.0},
        "bus": {"mode": "router", "listen": [f"tcp/127.0.0.1:{port}"], "health_period_s": 0.5},
        "radars": [dict(id="r1", lat=47.0, lon=8.0, sigma_range_m=50, sigma_azimuth_deg=0.1, rotation_period_s=4)],
        "safety_nets": {"load_entry_point_hooks": False, "process": "child"},
    }


def alive(pid: int) -> bool:
    """The process exists and is not a zombie (reaped or not, a zombie runs nothing)."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().rsplit(")", 1)[1].split()[0] != "Z"
    except (FileNotFoundError, ProcessLookupError):
        return False


def test_the_child_publishes_the_same_alerts_as_the_daemon_in_process(tmp_path, free_port, monkeypatch):
    monkeypatch.delenv("RADAR_FUSION_SAFETY_NETS__PROCESS")
    simulation = sim.simulate(sim.preset("demo", seed=1, duration_s=200.0))
    sim.write_outputs(simulation, tmp_path)
    base = load_settings(tmp_path / "config.toml")
    assert base.safety_nets.process == "child"  # serve's default
    got = {}
    for process in ("in_process", "child"):
        settings = on_port(base, free_port, process)
        collector, daemon, n_sent = run_pipeline(settings, tmp_path / "plots.rec", speed=None)
        alerts = Counter(repr(sorted(a.items())) for a in collector.alerts)
        got[process] = (alerts, daemon)
        assert daemon.messages_processed == n_sent
    (inproc, _), (child, daemon) = got["in_process"], got["child"]
    assert sum(inproc.values()) > 20 and child == inproc
    health = daemon.health_message()
    assert health["safety_nets"]["process"] == "child" and health["safety_nets"]["restarts"] == 0
    assert daemon.safety_nets_child is not None and daemon.safety_nets_child.proc.returncode == 0  # clean stop
    assert health["counters"]["safety_nets_process_restarts"] == 0
    assert health["counters"]["safety_nets_periods"] > 0  # relayed from the child's health
    relayed = SafetyNetsHealth.model_validate(daemon.safety_nets_health)
    assert relayed.rejected == {} and relayed.counters["batches_dropped"] == 0


def test_a_child_that_dies_is_started_again_and_counted(free_port, monkeypatch):
    monkeypatch.delenv("RADAR_FUSION_SAFETY_NETS__PROCESS")
    daemon = FusionDaemon(settings_from_dict(small_config(free_port))).start()
    try:
        child = daemon.safety_nets_child
        assert child is not None
        assert wait_until(lambda: daemon.safety_nets_health is not None, timeout_s=60)
        first = child.pid
        assert first is not None and daemon.safety_nets_health["pid"] == first
        os.kill(first, signal.SIGKILL)
        assert wait_until(lambda: child.restarts == 1 and child.pid != first, timeout_s=30)
        assert wait_until(lambda: (daemon.safety_nets_health or {}).get("pid") == child.pid, timeout_s=60)
        health = daemon.health_message()
        assert health["counters"]["safety_nets_process_restarts"] == 1
        assert health["safety_nets"]["running"] is True and health["safety_nets"]["last_exit_code"] == -signal.SIGKILL
        assert not alive(first)
    finally:
        daemon.stop()
    assert not alive(child.pid)


def test_the_child_dies_with_serve_even_on_sigkill(tmp_path, free_port):
    cfg = tmp_path / "site.toml"
    cfg.write_text(
        f"""[system]
center_lat = 47.0
center_lon = 8.0
[bus]
listen = ["tcp/127.0.0.1:{free_port}"]
health_period_s = 0.5
[[radars]]
id = "r1"
lat = 47.0
lon = 8.0
sigma_range_m = 50
sigma_azimuth_deg = 0.1
rotation_period_s = 4
[safety_nets]
load_entry_point_hooks = false
"""
    )
    env = {k: v for k, v in os.environ.items() if k != "RADAR_FUSION_SAFETY_NETS__PROCESS"}
    serve = subprocess.Popen(
        [sys.executable, "-m", "radar_fusion.cli", "serve", "--config", str(cfg), "--log-level", "WARNING"], env=env
    )
    session = None
    seen: list[dict] = []
    try:
        deadline = time.monotonic() + 60
        while session is None:
            try:
                session = open_session(zenoh_config("client", connect=[f"tcp/127.0.0.1:{free_port}"]))
            except Exception:
                assert time.monotonic() < deadline and serve.poll() is None, "serve did not come up"
                time.sleep(0.2)
        sub = session.declare_subscriber(
            health_key("atc"), lambda s: seen.append(msgpack.unpackb(s.payload.to_bytes(), raw=False))
        )
        assert wait_until(lambda: bool(seen), timeout_s=60), "no health from the safety-nets child"
        pid = seen[-1]["pid"]
        assert alive(pid) and pid != serve.pid
        serve.send_signal(signal.SIGKILL)
        serve.wait(10)
        assert wait_until(lambda: not alive(pid), timeout_s=15), "the safety-nets child outlived serve"
        sub.undeclare()
    finally:
        if serve.poll() is None:
            serve.kill()
            serve.wait()
        if session is not None:
            session.close()


def test_bad_track_batches_on_the_bus_are_counted_on_its_health_key(free_port):
    settings = settings_from_dict(small_config(free_port))
    router = FusionDaemon(settings, safety_nets="external").start()  # the bus only
    svc = SafetyNetsProcess(settings).start()
    session = open_session(zenoh_config("client", connect=[f"tcp/127.0.0.1:{free_port}"]))
    healths: list[dict] = []
    try:
        sub = session.declare_subscriber(
            health_key("atc"), lambda s: healths.append(msgpack.unpackb(s.payload.to_bytes(), raw=False))
        )
        time.sleep(0.5)
        pub = session.declare_publisher("atc/fusion/tracks")
        for payload in (b"\xc1", msgpack.packb([1]), msgpack.packb({"v": 9}), msgpack.packb({"v": 1, "t": 1.0})):
            pub.put(payload)
        good = {"v": 1, "t": 1.7e9, "period": 425_000_000, "tracks": [], "ended": []}
        pub.put(msgpack.packb(good))
        assert wait_until(lambda: svc.counters["batches_processed"] == 1 and sum(svc.rejected.values()) == 4, 20)
        assert dict(svc.rejected) == {"malformed_msgpack": 1, "schema": 2, "version": 1}
        assert wait_until(lambda: bool(healths) and sum(healths[-1]["rejected"].values()) == 4, timeout_s=20)
        assert SafetyNetsHealth.model_validate(healths[-1]).counters["batches_processed"] == 1
        sub.undeclare()
    finally:
        session.close()
        svc.stop()
        router.stop()
