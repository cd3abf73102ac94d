"""`radar-fusion record`: write what arrives on bus keys to a recording file.

Each message is stored with its receive time (UTC epoch seconds), its key relative to
the prefix and its exact payload bytes, so replaying the recording publishes the same
bytes again.
"""

from __future__ import annotations

import argparse
import signal
import threading
import time

from .recording import RecordingWriter


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", required=True, help="recording file to write (.gz to compress)")
    p.add_argument("--keys", action="append",
                   help="key expression(s) to record, relative to the prefix (default '**': everything)")
    p.add_argument("--config", help="daemon config: connect to its bus endpoints and use its prefix")
    p.add_argument("--connect", action="append", help="Zenoh endpoint to connect to (default tcp/127.0.0.1:7447)")
    p.add_argument("--prefix", help="key prefix (default: the config's, else 'atc')")
    p.add_argument("--duration-s", type=float, help="stop after this many seconds (default: until Ctrl-C)")


class Recorder:
    """Subscribes to keys on a session and writes every sample to a RecordingWriter."""

    def __init__(self, session, writer: RecordingWriter, prefix: str, keys: list[str]):
        self.writer = writer
        self.prefix = prefix
        self._lock = threading.Lock()
        self._subs = [session.declare_subscriber(f"{prefix}/{k}", self._on_sample) for k in keys]

    def _on_sample(self, sample) -> None:
        key = str(sample.key_expr)
        rel = key[len(self.prefix) + 1:] if key.startswith(self.prefix + "/") else key
        with self._lock:
            self.writer.write(time.time(), rel, sample.payload.to_bytes())

    def close(self) -> None:
        for sub in self._subs:
            sub.undeclare()
        with self._lock:
            self.writer.close()


def run(args: argparse.Namespace) -> int:
    from radar_fusion.bus import open_session, tool_client_config

    cfg, prefix = tool_client_config(args.config, args.connect, args.prefix)
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    session = open_session(cfg)
    writer = RecordingWriter(args.out, meta={"prefix": prefix, "keys": args.keys or ["**"]})
    rec = Recorder(session, writer, prefix, args.keys or ["**"])
    try:
        stop.wait(args.duration_s)
    finally:
        rec.close()
        session.close()
    print(f"recorded {writer.count} messages to {args.out}")
    return 0
