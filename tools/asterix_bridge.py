"""ASTERIX bridge subcommands: ``radar-fusion asterix-in`` and ``radar-fusion asterix-out``.

asterix-in
    Reads CAT048 target reports and CAT034 north-marker / sector messages from a UDP
    socket (unicast or multicast) or from a file (raw concatenated blocks, pcap, .rply),
    maps each SAC/SIC to a configured radar, and publishes the wire contract's PlotBatch
    and RadarStatus on ``<prefix>/radar/<id>/plots`` / ``.../status`` (reliable, with
    congestion control BLOCK), or writes them to a recording (``--out``). Files are fed
    at recorded speed (``--speed 1``), faster (``--speed 10``) or as fast as possible
    (``--speed max``, the default for ``--out``).

asterix-out
    Subscribes to ``<prefix>/fusion/tracks`` and writes each TrackBatch as CAT062
    system-track records to a UDP destination (unicast or multicast) or appends them to
    a file of raw concatenated blocks; and, from ``<prefix>/fusion/health``, each radar's
    status and registration estimates as CAT063 sensor status records (``--no-cat063``:
    not).

The conversion itself lives in :mod:`radar_fusion.asterix` (sans-I/O: ``bridge.py`` turns
ASTERIX into wire messages, ``cat062.py`` tracks into CAT062); this module is the I/O
around it: sockets, files, pacing, the Zenoh session.
"""

from __future__ import annotations

import argparse
import contextlib
import ipaddress
import json
import logging
import math
import queue
import signal
import socket
import struct
import sys
import threading
import time
from collections.abc import Callable, Iterator
from datetime import date
from pathlib import Path
from typing import Any

from radar_fusion.asterix import (
    AsterixToWire,
    Cat062Encoder,
    Cat063Encoder,
    DecodeCounters,
    WireMessage,
    iter_file,
    sort_by_time,
)
from radar_fusion.config import ConfigError, Settings, load_settings
from radar_fusion.recording import RecordingWriter
from radar_fusion.wire import Health, Rejection, TrackBatch, decode_message

log = logging.getLogger("radar_fusion.asterix_bridge")

MAX_DATAGRAM_BYTES = 65_535


# ============================================================================ UDP


def parse_host_port(text: str) -> tuple[str, int]:
    """``HOST:PORT`` (IPv4 or name) -> (host, port)."""
    host, sep, port = text.rpartition(":")
    if not sep or not port.isdigit() or not 0 <= int(port) <= 65_535:
        raise argparse.ArgumentTypeError(f"expected HOST:PORT, got {text!r}")
    return host or "0.0.0.0", int(port)


def open_udp_receiver(
    host: str, port: int, multicast_group: str | None = None, interface_ip: str = "0.0.0.0"
) -> socket.socket:
    """A UDP socket bound to ``host:port``; joins ``multicast_group`` on ``interface_ip``.

    For multicast, bind to the group's port (``host`` 0.0.0.0 or the group address) and
    give the local interface address that faces the radar network.
    """
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM, socket.IPPROTO_UDP)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    with contextlib.suppress(OSError):  # a larger buffer if the system allows it
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4 << 20)
    sock.bind((host, port))
    if multicast_group:
        if not ipaddress.ip_address(multicast_group).is_multicast:
            sock.close()
            raise ValueError(f"{multicast_group} is not a multicast address")
        mreq = struct.pack("4s4s", socket.inet_aton(multicast_group), socket.inet_aton(interface_ip))
        sock.setsockopt(socket.IPPROTO_IP, socket.IP_ADD_MEMBERSHIP, mreq)
    return sock


def iter_udp(
    sock: socket.socket, stop: threading.Event, duration_s: float | None = None, poll_s: float = 0.2
) -> Iterator[tuple[float, bytes]]:
    """``(receive epoch s, datagram)`` until ``stop`` is set or ``duration_s`` has passed."""
    sock.settimeout(poll_s)
    deadline = None if duration_s is None else time.monotonic() + duration_s
    while not stop.is_set() and (deadline is None or time.monotonic() < deadline):
        try:
            data = sock.recv(MAX_DATAGRAM_BYTES)
        except TimeoutError:
            continue
        except OSError:
            if stop.is_set():
                return
            raise
        yield time.time(), data


# ============================================================================ sinks


class ZenohSink:
    """Publishes wire messages on the bus; one reliable/BLOCK publisher per key."""

    def __init__(self, settings: Settings, mode: str = "client", connect: list[str] | None = None):
        from radar_fusion.bus import client_config_for, open_session, zenoh_config

        bus = settings.bus
        if connect is None and mode == "client":
            cfg = client_config_for(bus)
        else:
            endpoints = connect if connect is not None else list(bus.connect or bus.listen)
            cfg = zenoh_config(
                mode, connect=endpoints, multicast_scouting=bus.multicast_scouting, config_file=bus.zenoh_config_file
            )
        self.prefix = bus.prefix
        self.session = open_session(cfg)
        self._pubs: dict[str, Any] = {}

    def write(self, msg: WireMessage) -> None:
        from radar_fusion.bus import reliable_sender

        pub = self._pubs.get(msg.key)
        if pub is None:
            pub = self._pubs[msg.key] = reliable_sender(self.session, f"{self.prefix}/{msg.key}")
        pub.put(msg.payload)

    def close(self) -> None:
        self._pubs.clear()
        self.session.close()


class RecordingSink:
    """Writes wire messages to a recording (keys relative to the prefix, event times)."""

    def __init__(self, path: str, meta: dict[str, Any]):
        self.writer = RecordingWriter(path, meta=meta)

    def write(self, msg: WireMessage) -> None:
        self.writer.write(msg.t_s, msg.key, msg.payload)

    def close(self) -> None:
        self.writer.close()


# ============================================================================ asterix-in


def _speed(text: str) -> float:
    if text == "max":
        return math.inf
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError("--speed is a factor > 0 or 'max'") from None
    if not value > 0:
        raise argparse.ArgumentTypeError("--speed must be > 0")
    return value


def _day(text: str) -> date:
    try:
        return date.fromisoformat(text)
    except ValueError:
        raise argparse.ArgumentTypeError("--date is YYYY-MM-DD") from None


def add_arguments_in(parser: argparse.ArgumentParser) -> None:
    """Options of ``radar-fusion asterix-in``."""
    parser.add_argument("--config", required=True, help="daemon configuration TOML ([[radars]] with sac/sic, [bus])")
    src = parser.add_mutually_exclusive_group(required=True)
    src.add_argument("--udp", type=parse_host_port, metavar="HOST:PORT", help="receive datagrams on this address")
    src.add_argument("--file", metavar="PATH", help="read a recorded file instead")
    parser.add_argument("--multicast-group", metavar="G", help="with --udp: join this multicast group")
    parser.add_argument(
        "--interface", default="0.0.0.0", metavar="IP", help="with --multicast-group: local interface address"
    )
    parser.add_argument(
        "--format", choices=("raw", "pcap", "rply"), help="with --file: file format (default: from name/contents)"
    )
    parser.add_argument(
        "--speed",
        type=_speed,
        default=None,
        metavar="X|max",
        help="with --file: 1 = recorded speed, 10 = ten times, max (default: 1 on the bus, max with --out)",
    )
    parser.add_argument(
        "--order",
        choices=("time", "file"),
        default="time",
        help="with --file: feed datagrams in the order of their report times (default) or as stored",
    )
    parser.add_argument(
        "--no-dedup", action="store_true", help="keep data blocks identical to a recent one (dual-LAN copies)"
    )
    parser.add_argument(
        "--date",
        type=_day,
        metavar="YYYY-MM-DD",
        help="UTC date of the first report (default: from pcap/receive time, else today)",
    )
    parser.add_argument("--out", metavar="REC", help="write a recording (tools.recording) instead of publishing")
    parser.add_argument("--bus-mode", choices=("client", "peer"), default="client", help="zenoh mode of the bridge")
    parser.add_argument(
        "--connect", action="append", metavar="ENDPOINT", help="zenoh endpoint(s), overriding the config"
    )
    parser.add_argument("--duration-s", type=float, metavar="S", help="with --udp: stop after this many seconds")
    parser.add_argument("--quiet", action="store_true", help="do not print the counters at the end")


def _install_stop_handlers(stop: threading.Event) -> None:
    if threading.current_thread() is not threading.main_thread():
        return
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())


def run_bridge_in(
    settings: Settings,
    source: Iterator[tuple[float | None, bytes]],
    write: Callable[[WireMessage], None],
    day: date | None = None,
    speed: float | None = None,
    stop: threading.Event | None = None,
    bridge: AsterixToWire | None = None,
) -> AsterixToWire:
    """Convert every datagram of ``source`` and hand the messages to ``write``.

    ``speed`` paces by event time (1.0 = as recorded; None = no pacing). Returns the
    converter, whose ``counters`` say what was decoded and skipped.
    """
    bridge = bridge or AsterixToWire(settings.radars, day=day)
    first_t_s: float | None = None
    wall0 = time.monotonic()
    for reference_epoch_s, datagram in source:
        if stop is not None and stop.is_set():
            break
        for msg in bridge.datagram(datagram, reference_epoch_s):
            if speed is not None:
                if first_t_s is None:
                    first_t_s, wall0 = msg.t_s, time.monotonic()
                delay = (msg.t_s - first_t_s) / speed - (time.monotonic() - wall0)
                if delay > 0:
                    if stop is not None:
                        if stop.wait(delay):
                            return bridge
                    else:
                        time.sleep(delay)
            write(msg)
    return bridge


def run_in(args: argparse.Namespace) -> int:
    """``radar-fusion asterix-in``; returns the process exit code."""
    try:
        settings = load_settings(args.config)
    except ConfigError as exc:
        print(str(exc), file=sys.stderr)
        return 2
    if not any(r.sac is not None and r.sic is not None for r in settings.radars):
        print(f"{args.config}: no radar has sac and sic: nothing to bridge", file=sys.stderr)
        return 2
    stop = threading.Event()
    _install_stop_handlers(stop)
    file_counters = DecodeCounters()
    sock = None
    if args.udp:
        try:
            sock = open_udp_receiver(args.udp[0], args.udp[1], args.multicast_group, args.interface)
        except (OSError, ValueError) as exc:
            print(f"cannot open UDP {args.udp[0]}:{args.udp[1]}: {exc}", file=sys.stderr)
            return 2
        source: Iterator[tuple[float | None, bytes]] = iter_udp(sock, stop, args.duration_s)
        speed = None
    else:
        if not Path(args.file).is_file():
            print(f"{args.file}: file not found", file=sys.stderr)
            return 2
        try:
            source = iter_file(args.file, file_counters, args.format)
            if args.order == "time":
                source = iter(sort_by_time(source, args.date))
        except (OSError, ValueError) as exc:
            print(str(exc), file=sys.stderr)
            return 2
        speed = args.speed if args.speed is not None else (math.inf if args.out else 1.0)
        if math.isinf(speed):
            speed = None  # no pacing
    try:
        sink: Any = (
            RecordingSink(args.out, {"source": args.file or f"udp:{args.udp[0]}:{args.udp[1]}", "tool": "asterix-in"})
            if args.out
            else ZenohSink(settings, args.bus_mode, args.connect)
        )
    except Exception as exc:  # zenoh raises its own error types
        print(f"cannot open the output: {exc}", file=sys.stderr)
        if sock is not None:
            sock.close()
        return 2
    # a file sorted by time comes with each datagram's resolved time as its reference: the
    # day was chosen there, in file order (sort_by_time)
    day = None if not args.udp and args.order == "time" else args.date
    bridge = AsterixToWire(settings.radars, day=day, dedup_window=0 if args.no_dedup else 1024)
    try:
        run_bridge_in(settings, source, sink.write, day=day, speed=speed, stop=stop, bridge=bridge)
    except ValueError as exc:  # e.g. a file that is not the format it claims
        print(str(exc), file=sys.stderr)
        return 2
    finally:
        sink.close()
        if sock is not None:
            sock.close()
    if not args.quiet:
        summary = bridge.counters.as_dict()
        for reason, n in file_counters.skipped.items():
            summary["skipped"][reason] = summary["skipped"].get(reason, 0) + n
        print(json.dumps(summary, sort_keys=True), file=sys.stderr)
    return 0


# ============================================================================ asterix-out


def add_arguments_out(parser: argparse.ArgumentParser) -> None:
    """Options of ``radar-fusion asterix-out``."""
    parser.add_argument("--config", required=True, help="daemon configuration TOML ([bus])")
    dst = parser.add_mutually_exclusive_group(required=True)
    dst.add_argument(
        "--udp", type=parse_host_port, metavar="HOST:PORT", help="send CAT062 datagrams here (unicast or multicast)"
    )
    dst.add_argument("--file", metavar="PATH", help="append CAT062 data blocks (raw, concatenated) to this file")
    parser.add_argument("--sac", type=int, default=0, help="system area code of this tracker in I062/010 (default 0)")
    parser.add_argument("--sic", type=int, default=1, help="system identification code in I062/010 (default 1)")
    parser.add_argument("--service-id", type=int, default=1, help="I062/015 service identification (default 1)")
    parser.add_argument(
        "--max-block-bytes", type=int, default=1400, help="largest data block / datagram (default 1400)"
    )
    parser.add_argument("--ttl", type=int, default=8, help="multicast TTL for --udp to a group (default 8)")
    parser.add_argument("--bus-mode", choices=("client", "peer"), default="client", help="zenoh mode of the bridge")
    parser.add_argument(
        "--connect", action="append", metavar="ENDPOINT", help="zenoh endpoint(s), overriding the config"
    )
    parser.add_argument("--duration-s", type=float, metavar="S", help="stop after this many seconds")
    parser.add_argument(
        "--no-cat063",
        action="store_true",
        help="do not send CAT063 sensor status (each radar's registration estimates, at every health message)",
    )
    parser.add_argument("--quiet", action="store_true", help="do not print the counters at the end")


class Cat062Writer:
    """Turns TrackBatch payloads into CAT062 blocks, and Health payloads into CAT063 sensor
    status blocks (the radars' registration estimates, with ``cat063``), and sends or
    appends them."""

    def __init__(
        self,
        encoder: Cat062Encoder,
        send: Callable[[bytes], object],  # what send returns is unused
        cat063: Cat063Encoder | None = None,
    ):
        self.encoder = encoder
        self.cat063 = cat063
        self.send = send
        self.counts = {"batches": 0, "blocks": 0, "rejected": 0, "send_errors": 0, "health": 0, "cat063_blocks": 0}

    def health_payload(self, payload: bytes) -> None:
        if self.cat063 is None:
            return
        health = decode_message(payload, Health)
        if isinstance(health, Rejection):
            self.counts["rejected"] += 1
            log.warning("health message refused: %s %s", health.reason, health.detail)
            return
        assert isinstance(health, Health)
        self.counts["health"] += 1
        for block in self.cat063.encode(health):
            try:
                self.send(block)
                self.counts["cat063_blocks"] += 1
            except OSError as exc:
                self.counts["send_errors"] += 1
                log.warning("CAT063 send failed: %s", exc)

    def payload(self, payload: bytes) -> None:
        batch = decode_message(payload, TrackBatch)
        if isinstance(batch, Rejection):
            self.counts["rejected"] += 1
            log.warning("track batch refused: %s %s", batch.reason, batch.detail)
            return
        assert isinstance(batch, TrackBatch)  # decode_message returns an instance of the model it is given
        self.counts["batches"] += 1
        for block in self.encoder.encode(batch):
            try:
                self.send(block)
                self.counts["blocks"] += 1
            except OSError as exc:
                self.counts["send_errors"] += 1
                log.warning("CAT062 send failed: %s", exc)


def run_out(args: argparse.Namespace) -> int:
    """``radar-fusion asterix-out``; returns the process exit code."""
    try:
        settings = load_settings(args.config)
        encoder = Cat062Encoder(args.sac, args.sic, args.service_id, args.max_block_bytes)
    except (ConfigError, ValueError) as exc:
        print(str(exc), file=sys.stderr)
        return 2
    stop = threading.Event()
    _install_stop_handlers(stop)
    if args.udp:
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM, socket.IPPROTO_UDP)
        try:
            if ipaddress.ip_address(socket.gethostbyname(args.udp[0])).is_multicast:
                sock.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_TTL, args.ttl)
        except OSError as exc:
            print(f"cannot resolve {args.udp[0]}: {exc}", file=sys.stderr)
            return 2
        dest = args.udp
        send: Callable[[bytes], object] = lambda block: sock.sendto(block, dest)
        closer: Callable[[], None] = sock.close
    else:
        f = open(args.file, "ab")  # noqa: SIM115  # open for the writer's life; closer closes it

        def send(block: bytes) -> None:
            f.write(block)
            f.flush()

        closer = f.close
    # Zenoh calls back on its own threads: hand payloads to this thread through a queue.
    inbox: queue.Queue = queue.Queue(maxsize=1000)
    sensors = {r.id: (r.sac, r.sic) for r in settings.radars if r.sac is not None and r.sic is not None}
    cat063 = None if args.no_cat063 else Cat063Encoder(args.sac, args.sic, sensors, args.service_id)
    writer = Cat062Writer(encoder, send, cat063)
    from radar_fusion.bus import client_config_for, open_session, zenoh_config

    bus = settings.bus
    if args.connect is None and args.bus_mode == "client":
        cfg = client_config_for(bus)
    else:
        endpoints = args.connect if args.connect is not None else list(bus.connect or bus.listen)
        cfg = zenoh_config(args.bus_mode, connect=endpoints, config_file=bus.zenoh_config_file)
    try:
        session = open_session(cfg)
    except Exception as exc:  # zenoh raises its own error types
        print(f"cannot join the bus: {exc}", file=sys.stderr)
        closer()
        return 2
    sub = session.declare_subscriber(f"{bus.prefix}/fusion/tracks", lambda s: inbox.put((0, s.payload.to_bytes())))
    health_sub = session.declare_subscriber(
        f"{bus.prefix}/fusion/health", lambda s: inbox.put((1, s.payload.to_bytes()))
    )

    def handle(item: tuple[int, bytes]) -> None:
        (writer.health_payload if item[0] else writer.payload)(item[1])

    deadline = None if args.duration_s is None else time.monotonic() + args.duration_s
    try:
        while not stop.is_set() and (deadline is None or time.monotonic() < deadline):
            try:
                handle(inbox.get(timeout=0.2))
            except queue.Empty:
                continue
        while not inbox.empty():
            handle(inbox.get_nowait())
    finally:
        health_sub.undeclare()
        sub.undeclare()
        session.close()
        closer()
    if not args.quiet:
        print(json.dumps(writer.counts, sort_keys=True), file=sys.stderr)
    return 0
