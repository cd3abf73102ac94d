"""`radar-fusion record`: write what arrives on bus keys to a recording file.

Each message is stored with its receive time (UTC epoch seconds), its key relative to
the prefix and its exact payload bytes, so replaying the recording publishes the same
bytes again.
"""

from __future__ import annotations

import argparse
import signal
import sys
import threading
import time
from pathlib import Path

from ..cli import positive_float
from ..recording import RecordingWriter


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", required=True, help="recording file to write (.gz to compress)")
    p.add_argument(
        "--keys", action="append", help="key expression(s) to record, relative to the prefix (default '**': everything)"
    )
    p.add_argument("--config", help="daemon config: connect to its bus endpoints and use its prefix")
    p.add_argument("--connect", action="append", help="Zenoh endpoint to connect to (default tcp/127.0.0.1:7447)")
    p.add_argument("--prefix", help="key prefix (default: the config's, else 'atc')")
    p.add_argument("--duration-s", type=positive_float, help="stop after this many seconds (default: until Ctrl-C)")
    p.add_argument("--force", action="store_true", help="overwrite --out if it exists")


class Recorder:
    """Subscribes to keys on a session and writes every sample to a RecordingWriter.

    The callbacks run on Zenoh's receiving thread (not a thread per subscriber), so
    samples are written in the order they arrived even across several key expressions;
    a sample that matches more than one of them is written once.
    """

    def __init__(self, session, writer: RecordingWriter, prefix: str, keys: list[str]):
        import zenoh

        self.writer = writer
        self.prefix = prefix
        self._lock = threading.Lock()
        self._closed = False
        exprs = [zenoh.KeyExpr(f"{prefix}/{k}") for k in keys]
        self._subs = [
            session.declare_subscriber(expr, zenoh.handlers.Callback(self._callback(exprs[:m]), indirect=False))
            for m, expr in enumerate(exprs)
        ]

    def _callback(self, earlier: list):
        def on_sample(sample) -> None:
            if not any(e.includes(sample.key_expr) for e in earlier):  # else an earlier subscriber has it
                self._on_sample(sample)

        return on_sample

    def _on_sample(self, sample) -> None:
        key = str(sample.key_expr)
        rel = key[len(self.prefix) + 1 :] if key.startswith(self.prefix + "/") else key
        payload = sample.payload.to_bytes()
        with self._lock:
            if not self._closed:  # Zenoh may still deliver a sample while we close
                self.writer.write(time.time(), rel, payload)

    def close(self) -> None:
        for sub in self._subs:
            sub.undeclare()
        with self._lock:
            self._closed = True
            self.writer.close()


def run(args: argparse.Namespace) -> int:
    from radar_fusion.bus import open_session, tool_client_config

    if Path(args.out).exists() and not args.force:
        print(f"record: {args.out} exists; not overwriting it (--force does)", file=sys.stderr)
        return 2
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
