"""Zenoh TLS, mutual TLS and access control with the configuration files of deploy/zenoh/,
over real sessions on 127.0.0.1 with certificates made for the test (a private CA).

One site: the daemon is its own router (daemon-router.json5); the radar front-ends
connect with radar-frontend.json5. Two sites: two routers (router-site-{a,b}.json5)
linked over TLS, the daemon a client of site A (daemon-client.json5), a radar at each
site. In both, the authorised radars' plots become tracks, and what an unauthorised
session publishes never reaches the daemon."""

from __future__ import annotations

import dataclasses
import datetime
import ipaddress
import json
import socket
import threading
import time
import tomllib
from pathlib import Path

import msgpack
import pytest
import zenoh
from cryptography import x509
from cryptography.hazmat.primitives import hashes, serialization
from cryptography.hazmat.primitives.asymmetric import ec
from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

from radar_fusion.bus import FusionDaemon, open_session, reliable_sender
from radar_fusion.config import settings_from_dict
from radar_fusion.tools import simulate as sim
from radar_fusion.tools.demo import TrackCollector, wait_until

pytestmark = pytest.mark.bus  # every test here opens Zenoh sessions

DEPLOY_ZENOH = Path(__file__).resolve().parents[1] / "deploy" / "zenoh"
DEPLOY_TLS_DIR = "/etc/radar-fusion/tls/"
# The demo scenario's radars under the names the deploy/ access control uses.
RADAR_NAMES = {"app": "north", "east": "west", "south": "south"}
IDENTITIES = (
    "radar-fusion",
    "router-a",
    "router-b",
    "fe-north",
    "fe-west",
    "fe-south",
    "display-1",
    "display-b1",
    "intruder",
    "safety-nets",
)


# ------------------------------------------------------------------ certificates


def _write(path_stem: Path, key, cert) -> None:
    path_stem.with_suffix(".key").write_bytes(
        key.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8, serialization.NoEncryption())
    )
    path_stem.with_suffix(".pem").write_bytes(cert.public_bytes(serialization.Encoding.PEM))


def make_ca(directory: Path, name: str):
    key = ec.generate_private_key(ec.SECP256R1())
    now = datetime.datetime.now(datetime.UTC)
    subject = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, name)])
    cert = (
        x509.CertificateBuilder()
        .subject_name(subject)
        .issuer_name(subject)
        .public_key(key.public_key())
        .serial_number(x509.random_serial_number())
        .not_valid_before(now - datetime.timedelta(minutes=5))
        .not_valid_after(now + datetime.timedelta(days=1))
        .add_extension(x509.BasicConstraints(ca=True, path_length=None), critical=True)
        .add_extension(
            x509.KeyUsage(
                digital_signature=False,
                content_commitment=False,
                key_encipherment=False,
                data_encipherment=False,
                key_agreement=False,
                key_cert_sign=True,
                crl_sign=True,
                encipher_only=False,
                decipher_only=False,
            ),
            critical=True,
        )
        .add_extension(x509.SubjectKeyIdentifier.from_public_key(key.public_key()), critical=False)
        .sign(key, hashes.SHA256())
    )
    _write(directory / name, key, cert)
    return key, cert


def make_identity(directory: Path, ca, common_name: str) -> None:
    """An end-entity certificate: CN = the identity the access control names; the
    loopback names, which a listener's certificate must carry for its clients."""
    ca_key, ca_cert = ca
    key = ec.generate_private_key(ec.SECP256R1())
    now = datetime.datetime.now(datetime.UTC)
    cert = (
        x509.CertificateBuilder()
        .subject_name(x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, common_name)]))
        .issuer_name(ca_cert.subject)
        .public_key(key.public_key())
        .serial_number(x509.random_serial_number())
        .not_valid_before(now - datetime.timedelta(minutes=5))
        .not_valid_after(now + datetime.timedelta(days=1))
        .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
        .add_extension(
            x509.SubjectAlternativeName([x509.DNSName("localhost"), x509.IPAddress(ipaddress.ip_address("127.0.0.1"))]),
            critical=False,
        )
        .add_extension(
            x509.ExtendedKeyUsage([ExtendedKeyUsageOID.SERVER_AUTH, ExtendedKeyUsageOID.CLIENT_AUTH]), critical=False
        )
        .add_extension(x509.AuthorityKeyIdentifier.from_issuer_public_key(ca_key.public_key()), critical=False)
        .sign(ca_key, hashes.SHA256())
    )
    _write(directory / common_name, key, cert)


@pytest.fixture(scope="module")
def pki(tmp_path_factory) -> Path:
    """ca.pem and NAME.pem/.key per identity; rogue.pem/.key signed by another CA."""
    tls = tmp_path_factory.mktemp("tls")
    ca = make_ca(tls, "ca")
    for name in IDENTITIES:
        make_identity(tls, ca, name)
    rogue_dir = tls / "other-ca"
    rogue_dir.mkdir()
    make_identity(rogue_dir, make_ca(rogue_dir, "ca"), "fe-north")  # the right name, the wrong CA
    for suffix in (".pem", ".key"):
        (rogue_dir / f"fe-north{suffix}").rename(tls / f"rogue{suffix}")
    return tls


def other_free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def deploy_config(name: str, tls: Path, tmp: Path) -> Path:
    """A deploy/zenoh file with its certificate directory pointed at ``tls``."""
    text = (DEPLOY_ZENOH / name).read_text()
    assert DEPLOY_TLS_DIR in text
    out = tmp / name
    out.write_text(text.replace(DEPLOY_TLS_DIR, f"{tls}/"))
    return out


def client_config(path: Path, tls: Path, identity: str | None, endpoint: str) -> zenoh.Config:
    """The config file of a client, as ``identity`` (None: no certificate), connecting to ``endpoint``."""
    cfg = zenoh.Config.from_file(str(path))
    cfg.insert_json5("connect/endpoints", json.dumps([endpoint]))
    if identity is None:
        cfg.insert_json5("transport/link/tls/connect_certificate", "null")
        cfg.insert_json5("transport/link/tls/connect_private_key", "null")
    else:
        cfg.insert_json5("transport/link/tls/connect_certificate", json.dumps(f"{tls}/{identity}.pem"))
        cfg.insert_json5("transport/link/tls/connect_private_key", json.dumps(f"{tls}/{identity}.key"))
    return cfg


def refused(configs: dict[str, zenoh.Config]) -> dict[str, bool]:
    """Try to open each config at once (a refused open waits for its timeout); True when refused."""
    result: dict[str, bool] = {}

    def attempt(label: str, cfg: zenoh.Config) -> None:
        try:
            session = zenoh.open(cfg)
        except zenoh.ZError:
            result[label] = True
        else:
            session.close()
            result[label] = False

    threads = [threading.Thread(target=attempt, args=item) for item in configs.items()]
    for t in threads:
        t.start()
    for t in threads:
        t.join(30)
    return result


# ------------------------------------------------------------------ traffic


@pytest.fixture(scope="module")
def scenario():
    """The demo scenario (3 radars, 28 aircraft), 60 s of traffic, radars renamed."""
    sc = sim.preset("demo", seed=11, duration_s=60.0)
    sc = dataclasses.replace(sc, radars=[dataclasses.replace(r, id=RADAR_NAMES[r.id]) for r in sc.radars])
    simulation = sim.simulate(sc)
    return simulation, tomllib.loads(sim.config_toml(sc))


def daemon_settings(base: dict, **bus):
    data = {**base, "bus": {**base["bus"], "health_period_s": 0.2, **bus}}
    return settings_from_dict(data)


def plot_batch(radar_id: str, seq: int, t_s: float) -> bytes:
    plots = [{"t": t_s + 0.01 * k, "range_m": 60_000.0 + 10.0 * k, "azimuth_deg": 45.0, "fl": 300.0} for k in range(5)]
    return msgpack.packb({"v": 1, "radar_id": radar_id, "seq": seq, "plots": plots})


def consumer_ready(collector: TrackCollector) -> None:
    """The daemon's outputs reach the consumer (its health does; it was subscribed with the tracks)."""
    assert wait_until(lambda: bool(collector.health), 10), "no health message reached the consumer"


def feed(sessions: dict[str, zenoh.Session], messages, speed: float | None = None) -> int:
    """Publish each radar's messages from its own front-end's session, in recording order
    (``speed`` times faster than recorded; None: at once), once every publisher sees the
    daemon's subscription; returns the number sent."""
    senders, watchers = {}, {}
    for _, key, _ in messages:
        if key not in senders:
            session = sessions[key.split("/")[1]]
            senders[key] = reliable_sender(session, f"atc/{key}")
            # declared only for its matching status; nothing is sent through it (bus.Sender)
            watchers[key] = session.declare_publisher(f"atc/{key}")
    try:
        assert wait_until(lambda: all(p.matching_status.matching for p in watchers.values()), 10)
        t0_s, t0_wall = messages[0][0], time.monotonic()
        for t_s, key, payload in messages:
            if speed is not None:
                time.sleep(max(0.0, t0_wall + (t_s - t0_s) / speed - time.monotonic()))
            senders[key].put(payload)
    finally:
        for p in watchers.values():
            p.undeclare()
    return len(messages)


def check_tracks(collector: TrackCollector, daemon: FusionDaemon, radars: set[str]) -> None:
    assert wait_until(lambda: len(collector.batches) >= daemon.batches_published > 5, 10)
    confirmed = [t for b in collector.batches for t in b["tracks"] if t["status"] == "confirmed"]
    assert len({t["track_id"] for t in confirmed}) >= 10
    assert {s for t in confirmed for s in t["sources"]} == radars


def test_one_site_tls_mtls_and_access_control(pki, scenario, free_port, tmp_path):
    simulation, base = scenario
    endpoint = f"tls/127.0.0.1:{free_port}"
    settings = daemon_settings(
        base,
        mode="router",
        listen=[endpoint],
        zenoh_config_file=str(deploy_config("daemon-router.json5", pki, tmp_path)),
    )
    frontend = deploy_config("radar-frontend.json5", pki, tmp_path)
    daemon = FusionDaemon(settings, idle_flush_s=60.0).start()
    sessions: dict[str, zenoh.Session] = {}
    collector = None
    try:
        for radar in ("north", "west", "south"):
            sessions[radar] = open_session(client_config(frontend, pki, f"fe-{radar}", endpoint))
        sessions["display"] = open_session(client_config(frontend, pki, "display-1", endpoint))
        sessions["intruder"] = open_session(client_config(frontend, pki, "intruder", endpoint))  # valid CA, no rights
        collector = TrackCollector(sessions["display"], "atc")
        spy = []  # every payload an authorised consumer receives on the fusion keys
        spy_sub = sessions["display"].declare_subscriber("atc/fusion/**", lambda s: spy.append(s.payload.to_bytes()))

        t0 = simulation.scenario.start_t_s + 5.0
        # Session.put sends without waiting to see a subscriber: every one of these
        # crosses the link and is stopped (or not) by the router's access control.
        sessions["intruder"].put("atc/radar/north/plots", plot_batch("north", 900_001, t0))
        sessions["intruder"].put("atc/radar/intruder/plots", plot_batch("intruder", 1, t0))
        sessions["display"].put("atc/radar/west/plots", plot_batch("west", 900_002, t0))
        sessions["north"].put("atc/radar/south/plots", plot_batch("south", 900_003, t0))  # not its radar
        sessions["north"].put("atc/fusion/tracks", b"not from the daemon")
        sessions["intruder"].put("atc/fusion/alerts/stca", b"not from the daemon")
        # no certificate; a certificate of another CA (with a radar's name); plain TCP
        tcp = zenoh.Config()
        tcp.insert_json5("mode", '"client"')
        tcp.insert_json5("connect/endpoints", json.dumps([f"tcp/127.0.0.1:{free_port}"]))
        outcome = refused(
            {
                "no certificate": client_config(frontend, pki, None, endpoint),
                "another CA": client_config(frontend, pki, "rogue", endpoint),
                "plain tcp": tcp,
            }
        )
        assert outcome == {"no certificate": True, "another CA": True, "plain tcp": True}

        # At 30x, not at once: each radar has its own session, and sessions overtake one
        # another; a radar's plots must not reach the daemon after their period closed.
        consumer_ready(collector)
        n_sent = feed(sessions, simulation.messages, speed=30.0)
        assert wait_until(lambda: daemon.messages_processed >= n_sent, 30)
        time.sleep(0.3)  # anything else in flight
        daemon.stop()
        check_tracks(collector, daemon, {"north", "west", "south"})
        spy_sub.undeclare()
    finally:
        if not daemon.stopped.is_set():
            daemon.stop()
        if collector is not None:
            collector.close()
        for s in sessions.values():
            s.close()
    # exactly the authorised radars' messages reached the daemon, nothing of the others
    assert daemon.messages_received == n_sent
    health = daemon.health_message()
    assert health["rejected"] == {}
    assert all(r["seq_gaps"] == 0 for r in health["radars"].values())  # no 900 00x batch got in
    assert len(spy) >= daemon.batches_published and b"not from the daemon" not in spy


def test_one_site_the_safety_nets_child_joins_with_its_own_certificate(pki, scenario, free_port, tmp_path, monkeypatch):
    """serve's default, the safety nets as a child process, on the production files: the
    child connects with safety-nets.json5 (CN safety-nets), the router's access control
    lets it read the tracks and publish its health and alerts, a display receives them."""
    monkeypatch.delenv("RADAR_FUSION_SAFETY_NETS__PROCESS")  # the suite's in-process default
    simulation, base = scenario
    endpoint = f"tls/127.0.0.1:{free_port}"
    nets = {
        **base.get("safety_nets", {}),
        "process": "child",
        "connect": [endpoint],
        "zenoh_config_file": str(deploy_config("safety-nets.json5", pki, tmp_path)),
    }
    settings = daemon_settings(
        {**base, "safety_nets": nets},
        mode="router",
        listen=[endpoint],
        zenoh_config_file=str(deploy_config("daemon-router.json5", pki, tmp_path)),
    )
    frontend = deploy_config("radar-frontend.json5", pki, tmp_path)
    daemon = FusionDaemon(settings, idle_flush_s=60.0).start()
    sessions: dict[str, zenoh.Session] = {}
    healths: list[dict] = []
    try:
        for radar in ("north", "west", "south"):
            sessions[radar] = open_session(client_config(frontend, pki, f"fe-{radar}", endpoint))
        sessions["display"] = open_session(client_config(frontend, pki, "display-1", endpoint))
        sessions["display"].declare_subscriber(
            "atc/fusion/safety_nets/health", lambda s: healths.append(msgpack.unpackb(s.payload.to_bytes()))
        )
        assert wait_until(daemon._safety_nets_ready.is_set, 60), "the child did not join the TLS bus"
        n_sent = feed(sessions, simulation.messages, speed=30.0)
        assert wait_until(lambda: daemon.messages_processed >= n_sent, 30)
        daemon.stop()  # the last periods, then the child judges them and stops
        assert daemon.safety_nets_child is not None and daemon.safety_nets_child.proc.returncode == 0
        assert healths, "the display got no health from the safety-nets child"
        judged = max(h["counters"]["batches_processed"] for h in healths)
        assert judged >= daemon.batches_published - 1 > 5  # every period (but maybe the very last)
        assert all(h["rejected"] == {} for h in healths)
    finally:
        if not daemon.stopped.is_set():
            daemon.stop()
        for s in sessions.values():
            s.close()


def site_routers(pki: Path, tmp_path: Path, a: str, b: str) -> list[zenoh.Session]:
    """The two site routers of deploy/zenoh as they are, router-b connecting to router-a."""
    routers = []
    try:
        for name, listen, connect in (("router-site-a.json5", a, []), ("router-site-b.json5", b, [a])):
            cfg = zenoh.Config.from_file(str(deploy_config(name, pki, tmp_path)))
            cfg.insert_json5("listen/endpoints", json.dumps([listen]))
            cfg.insert_json5("connect/endpoints", json.dumps(connect))
            routers.append(open_session(cfg))
    except BaseException:
        for r in routers:
            r.close()
        raise
    return routers


def test_two_sites_linked_over_tls_each_router_enforcing_its_site(pki, scenario, free_port, tmp_path):
    simulation, base = scenario
    a, b = f"tls/127.0.0.1:{free_port}", f"tls/127.0.0.1:{other_free_port()}"
    routers = []
    sessions: dict[str, zenoh.Session] = {}
    daemon = collector = None
    try:
        routers += site_routers(pki, tmp_path, a, b)
        settings = daemon_settings(
            base,
            mode="client",
            listen=[],
            connect=[a],
            zenoh_config_file=str(deploy_config("daemon-client.json5", pki, tmp_path)),
        )
        daemon = FusionDaemon(settings, idle_flush_s=60.0).start()
        frontend = deploy_config("radar-frontend.json5", pki, tmp_path)
        for radar, endpoint in (("north", a), ("west", a), ("south", b)):  # south is at site B
            sessions[radar] = open_session(client_config(frontend, pki, f"fe-{radar}", endpoint))
        sessions["display"] = open_session(client_config(frontend, pki, "display-b1", b))
        sessions["intruder"] = open_session(client_config(frontend, pki, "intruder", b))
        collector = TrackCollector(sessions["display"], "atc")  # site B sees the tracks made at site A
        spy = []
        spy_sub = sessions["display"].declare_subscriber("atc/fusion/**", lambda s: spy.append(s.payload.to_bytes()))

        t0 = simulation.scenario.start_t_s + 5.0
        sessions["intruder"].put("atc/radar/south/plots", plot_batch("south", 900_001, t0))
        sessions["intruder"].put("atc/fusion/tracks", b"not from the daemon")
        sessions["south"].put("atc/radar/north/plots", plot_batch("north", 900_002, t0))  # site B, not its radar
        # a daemon-like session without the daemon's certificate cannot join either site
        assert refused({"rogue": client_config(frontend, pki, "rogue", a)}) == {"rogue": True}

        # At 30x (see above); here the radar of site B is also one router hop further away.
        consumer_ready(collector)
        n_sent = feed(sessions, simulation.messages, speed=30.0)
        assert wait_until(lambda: daemon.messages_processed >= n_sent, 30)
        time.sleep(0.3)
        daemon.stop()
        check_tracks(collector, daemon, {"north", "west", "south"})
        spy_sub.undeclare()
    finally:
        if daemon is not None and not daemon.stopped.is_set():
            daemon.stop()
        if collector is not None:
            collector.close()
        for s in [*sessions.values(), *reversed(routers)]:
            s.close()
    assert daemon.messages_received == n_sent
    health = daemon.health_message()
    assert health["rejected"] == {}
    assert all(r["seq_gaps"] == 0 for r in health["radars"].values())
    assert len(spy) >= daemon.batches_published and b"not from the daemon" not in spy


@pytest.mark.slow
def test_two_sites_a_hot_standby_pair_one_daemon_per_site(pki, scenario, free_port, tmp_path):
    """deploy/README.md's two-host standby: a daemon at each site (both CN radar-fusion, each
    a client of its own site's router), [redundancy] on. The routers' access control lets
    them elect (liveliness) and the standby take the active's state across the WAN link;
    the active stops half way and the standby at the other site goes on: every period once,
    one id per aircraft."""
    simulation, base = scenario
    a, b = f"tls/127.0.0.1:{free_port}", f"tls/127.0.0.1:{other_free_port()}"
    routers = []
    sessions: dict[str, zenoh.Session] = {}
    daemons: dict[str, FusionDaemon] = {}
    collector = None
    try:
        routers += site_routers(pki, tmp_path, a, b)
        for site, endpoint in (("a", a), ("b", b)):
            settings = daemon_settings(
                base,
                mode="client",
                listen=[],
                connect=[endpoint],
                zenoh_config_file=str(deploy_config("daemon-client.json5", pki, tmp_path)),
            )
            red = settings.redundancy.model_copy(update={"enabled": True, "instance": f"fusion-{site}"})
            daemons[site] = FusionDaemon(settings.model_copy(update={"redundancy": red}), idle_flush_s=60.0).start()
            assert wait_until(lambda: daemons["a"].role == "active", 10)
        frontend = deploy_config("radar-frontend.json5", pki, tmp_path)
        for radar, endpoint in (("north", a), ("west", a), ("south", b)):
            sessions[radar] = open_session(client_config(frontend, pki, f"fe-{radar}", endpoint))
        sessions["display"] = open_session(client_config(frontend, pki, "display-b1", b))
        collector = TrackCollector(sessions["display"], "atc")
        consumer_ready(collector)
        time.sleep(1.0)
        assert daemons["b"].role == "standby" and daemons["b"].election.members == {"fusion-a"}
        messages = simulation.messages
        half = len(messages) // 2
        feed(sessions, messages[:half], speed=30.0)
        assert wait_until(lambda: daemons["b"].redundancy_counters["states_applied"] > 5, 10), "no state crossed"
        daemons["a"].stop()  # with a standby on the bus: no flush, the standby takes the open periods
        assert wait_until(lambda: daemons["b"].role == "active", 10)
        feed(sessions, messages[half:], speed=30.0)
        assert wait_until(lambda: daemons["b"].messages_processed >= len(messages) - half, 30)
        daemons["b"].stop()
        assert wait_until(lambda: len(collector.batches) >= sum(d.batches_published for d in daemons.values()), 10)
    finally:
        for d in daemons.values():
            if not d.stopped.is_set():
                d.stop()
        if collector is not None:
            collector.close()
        for s in [*sessions.values(), *reversed(routers)]:
            s.close()
    batches = collector.batches
    epochs = [x["epoch"] for x in batches]
    assert epochs == sorted(epochs) and len(set(epochs)) == 2 and batches[-1]["instance"] == "fusion-b"
    periods = [x["period"] for x in batches]
    assert periods == list(range(periods[0], periods[0] + len(periods)))
    ids: dict[str, set[int]] = {}
    for x in batches:
        for t in x["tracks"]:
            if t["status"] == "confirmed" and t["mode_s"]:
                ids.setdefault(t["mode_s"], set()).add(t["track_id"])
    assert len(ids) >= 5 and all(len(v) == 1 for v in ids.values()), ids


def test_a_tools_connect_keeps_the_daemons_tls_configuration(pki, free_port, tmp_path):
    """``replay``/``record --config FILE --connect ENDPOINT``: the endpoint replaces the
    daemon's, its zenoh_config_file (TLS certificates) still applies, so the tool joins a
    TLS router (issue 13: it was dropped, and the tool could not connect)."""
    from radar_fusion.bus import tool_client_config

    endpoint = f"tls/127.0.0.1:{free_port}"
    cfg = zenoh.Config.from_file(str(deploy_config("router-site-a.json5", pki, tmp_path)))
    cfg.insert_json5("listen/endpoints", json.dumps([endpoint]))
    cfg.insert_json5("connect/endpoints", "[]")
    router = open_session(cfg)
    daemon_toml = tmp_path / "daemon.toml"
    zenoh_file = deploy_config("daemon-client.json5", pki, tmp_path)
    daemon_toml.write_text(
        "[system]\ncenter_lat = 46.8\ncenter_lon = 8.2\nperiod_s = 4.0\n"
        f'[bus]\nmode = "client"\nlisten = []\nconnect = ["tls/127.0.0.1:1"]\nzenoh_config_file = "{zenoh_file}"\n'
        '[[radars]]\nid = "north"\nlat = 47.0\nlon = 8.0\nsigma_range_m = 50.0\nsigma_azimuth_deg = 0.08\n'
        "rotation_period_s = 4.0\n"
    )
    tool_cfg, prefix = tool_client_config(str(daemon_toml), [endpoint], None)
    assert prefix == "atc"
    session = open_session(tool_cfg)
    try:
        assert wait_until(lambda: len(list(session.info.routers_zid())) == 1, 10)
    finally:
        session.close()
        router.close()
