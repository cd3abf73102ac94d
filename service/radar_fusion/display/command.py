"""`radar-fusion display --config FILE [--listen 127.0.0.1:8080]`: the situation display."""

from __future__ import annotations

import argparse
import signal
import sys
import threading
from pathlib import Path


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--config", required=True, help="the daemon's configuration TOML (bus endpoints, prefix, areas)")
    p.add_argument(
        "--listen", default="127.0.0.1:8080", help="HOST:PORT of the web server (default 127.0.0.1:8080; port 0: any)"
    )
    p.add_argument("--connect", action="append", help="Zenoh endpoint to connect to (default: from the config)")
    p.add_argument("--prefix", help="key prefix (default: the config's)")
    p.add_argument("--log-level", default="INFO", help="DEBUG, INFO, WARNING, ERROR (default INFO)")


def run(args: argparse.Namespace) -> int:
    import zenoh

    from ..bus import tool_client_config
    from ..config import ConfigError, load_settings
    from ..metrics import configure_logging
    from .server import DisplayServer, parse_listen

    try:
        settings = load_settings(args.config)
        host, port = parse_listen(args.listen)
    except (ConfigError, ValueError) as exc:
        print(f"not starting the display:\n{exc}", file=sys.stderr)
        return 2
    configure_logging(args.log_level, "text")  # the process's root logging: only once it runs
    cfg, prefix = tool_client_config(args.config, args.connect, args.prefix)
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    server = DisplayServer(settings, host, port, cfg, Path(args.config).resolve().parent, prefix)
    try:
        server.start()
    except (OSError, zenoh.ZError) as exc:  # the port is taken, no router at the endpoints
        print(f"cannot start the display: {exc}", file=sys.stderr)
        return 3
    print(f"situation display: {server.url}  (Ctrl-C to stop)", flush=True)
    try:
        while not stop.wait(0.5):
            pass
    finally:
        server.stop()
    return 0
