"""The situation display's web server (aiohttp): one page, its static files, the scene
and a WebSocket that pushes the daemon's tracks, alerts and health to each browser.

    GET /             the page (static/index.html); everything it loads is served here
    GET /static/...   display.js, display.css
    GET /api/scene    rings, grid, radar sites, APW / MSA areas in plane metres (scene.py)
    GET /api/stats    the display's own counters (feed.py) and its clients', as JSON
    GET /ws           WebSocket: JSON frames {"type": "tracks" | "alerts" | "health" |
                      "radars" | "display", ...}

Every response carries ``Content-Security-Policy: default-src 'self'``: the browser
itself refuses anything from another origin (a CDN, a tile server), so a page that
works here works on a network without internet.

Slow browsers never slow the feed: each client has one slot per channel holding the
newest frame not yet sent. A frame that arrives while the previous one of its channel
still waits is replaced (for tracks, counted in that client's ``frames_dropped``), so a
browser that draws slower than the period shows the latest period, late, never a
growing backlog. The server runs its own event loop on a thread
(:class:`DisplayServer`), so the CLI, the demo and the tests start it the same way.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import threading
from importlib import resources
from pathlib import Path
from typing import Any

from aiohttp import WSMsgType, web

from ..config import Settings
from .feed import Feed
from .scene import build_scene

log = logging.getLogger("radar_fusion.display")

STATIC_DIR = Path(str(resources.files("radar_fusion.display") / "static"))
CHANNELS = ("health", "radars", "alerts", "tracks", "display")
"""Send order within one wake-up of a client's sender: small state first, tracks last."""
STATS_PERIOD_S = 1.0
CSP = "default-src 'self'; img-src 'self' data:; style-src 'self'; script-src 'self'; connect-src 'self'"


class ClientSlot:
    """One browser: its newest unsent frame per channel and what it was sent."""

    def __init__(self, ws: web.WebSocketResponse, peer: str) -> None:
        self.ws = ws
        self.peer = peer
        self.pending: dict[str, str] = {}
        self.wake = asyncio.Event()
        self.frames_sent = 0
        self.frames_dropped = 0

    def offer(self, channel: str, text: str) -> None:
        if channel == "tracks" and "tracks" in self.pending:
            self.frames_dropped += 1
        self.pending[channel] = text
        self.wake.set()


class Hub:
    """Fans frames out to the connected browsers; lives on the event loop's thread."""

    def __init__(self) -> None:
        self.latest: dict[str, str] = {}
        self.clients: set[ClientSlot] = set()
        self.frames_dropped_closed = 0  # by clients that have gone since

    def publish(self, channel: str, text: str) -> None:
        self.latest[channel] = text
        for client in self.clients:
            client.offer(channel, text)

    def join(self, client: ClientSlot) -> None:
        for channel, text in self.latest.items():  # the present state at once
            client.offer(channel, text)
        self.clients.add(client)

    def leave(self, client: ClientSlot) -> None:
        self.clients.discard(client)
        self.frames_dropped_closed += client.frames_dropped


async def _send_loop(client: ClientSlot) -> None:
    while True:
        await client.wake.wait()
        client.wake.clear()
        pending, client.pending = client.pending, {}
        for channel in CHANNELS:
            text = pending.get(channel)
            if text is not None:
                await client.ws.send_str(text)
                if channel == "tracks":
                    client.frames_sent += 1


def parse_listen(text: str) -> tuple[str, int]:
    """``HOST:PORT`` (``[v6]:PORT`` for IPv6) → (host, port); ValueError when malformed."""
    host, sep, port_text = text.rpartition(":")
    if not sep or not host or not port_text.isdigit() or not 0 <= int(port_text) <= 65535:
        raise ValueError(f"--listen wants HOST:PORT (e.g. 127.0.0.1:8080), got {text!r}")
    return host.strip("[]"), int(port_text)


class DisplayServer:
    """The display: a Zenoh session (a client of the daemon's router by default), a
    :class:`~radar_fusion.display.feed.Feed` and the web server, on a thread of its own.

    ``DisplayServer(settings).start()`` returns once the port is bound (``url`` then
    says where; port 0 picks a free one) or raises what prevented it; ``stop()`` closes
    the browsers' sockets, the server and the session.
    """

    def __init__(
        self,
        settings: Settings,
        host: str = "127.0.0.1",
        port: int = 8080,
        zenoh_config: Any = None,
        base_dir: Path | None = None,
        prefix: str | None = None,
    ) -> None:
        self.settings = settings
        self.host = host
        self.port = port
        self.prefix = prefix or settings.bus.prefix
        self.zenoh_config = zenoh_config
        self.scene_json = json.dumps(build_scene(settings, base_dir), separators=(",", ":"))
        self.hub = Hub()
        self.feed: Feed | None = None
        self._session: Any = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._thread: threading.Thread | None = None
        self._ready = threading.Event()
        self._start_error: BaseException | None = None
        self._stop: asyncio.Event | None = None
        self._runner: web.AppRunner | None = None

    @property
    def url(self) -> str:
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"http://{host}:{self.port}/"

    # ------------------------------------------------------------ lifecycle
    def start(self, timeout_s: float = 30.0) -> DisplayServer:
        self._thread = threading.Thread(target=self._main, name="display-server", daemon=True)
        self._thread.start()
        if not self._ready.wait(timeout_s):
            raise TimeoutError("the display server did not start")
        if self._start_error is not None:
            self._thread.join(5.0)
            raise self._start_error
        return self

    def stop(self, timeout_s: float = 10.0) -> None:
        loop, stop = self._loop, self._stop
        if loop is not None and stop is not None and not loop.is_closed():
            with contextlib.suppress(RuntimeError):  # the loop has already gone
                loop.call_soon_threadsafe(stop.set)
        if self._thread is not None:
            self._thread.join(timeout_s)

    def __enter__(self) -> DisplayServer:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def _main(self) -> None:
        loop = asyncio.new_event_loop()
        self._loop = loop
        try:
            loop.run_until_complete(self._astart())
        except BaseException as exc:  # port taken, no router: told to the caller of start()
            self._start_error = exc
            loop.run_until_complete(self._astop())
            loop.close()
            self._ready.set()
            return
        self._ready.set()
        try:
            assert self._stop is not None
            loop.run_until_complete(self._stop.wait())
        finally:
            loop.run_until_complete(self._astop())
            loop.close()

    async def _astart(self) -> None:
        from ..bus import client_config_for, open_session

        loop = asyncio.get_running_loop()
        self._stop = asyncio.Event()
        cfg = self.zenoh_config if self.zenoh_config is not None else client_config_for(self.settings.bus)
        self._session = open_session(cfg)

        def sink(channel: str, text: str) -> None:  # the feed's decoding thread
            with contextlib.suppress(RuntimeError):  # the loop closed while stopping
                loop.call_soon_threadsafe(self.hub.publish, channel, text)

        self.feed = Feed(
            self._session, self.prefix, self.settings.system.period_s, sink, 4 * self.settings.bus.max_payload_bytes
        ).start()
        # a stop waits at most 2 s for handlers still running (aiohttp's default is 60 s):
        # `radar-fusion display` stopped by SIGINT must exit promptly
        self._runner = web.AppRunner(self._app(), handle_signals=False, access_log=None, shutdown_timeout=2.0)
        await self._runner.setup()
        site = web.TCPSite(self._runner, self.host, self.port)
        await site.start()
        addresses = self._runner.addresses
        if addresses:
            self.port = int(addresses[0][1])
        self._stats_task = asyncio.create_task(self._stats_loop())
        log.info("situation display at %s (bus prefix %s)", self.url, self.prefix)

    async def _astop(self) -> None:
        task = getattr(self, "_stats_task", None)
        if task is not None:
            task.cancel()
        for client in list(self.hub.clients):
            with contextlib.suppress(Exception):
                await client.ws.close(code=1001, message=b"display stopping")
        if self._runner is not None:
            await self._runner.cleanup()
            self._runner = None
        if self.feed is not None:
            self.feed.stop()
            self.feed = None
        if self._session is not None:
            self._session.close()
            self._session = None

    # ------------------------------------------------------------ the app
    def _app(self) -> web.Application:
        app = web.Application(middlewares=[_security_headers])
        app.router.add_get("/", self._index)
        app.router.add_get("/api/scene", self._scene)
        app.router.add_get("/api/stats", self._stats)
        app.router.add_get("/ws", self._ws)
        app.router.add_static("/static/", STATIC_DIR, follow_symlinks=False)
        return app

    async def _index(self, request: web.Request) -> web.StreamResponse:
        return web.FileResponse(STATIC_DIR / "index.html")

    async def _scene(self, request: web.Request) -> web.Response:
        return web.Response(text=self.scene_json, content_type="application/json")

    def stats(self) -> dict[str, Any]:
        feed = self.feed.stats() if self.feed is not None else {}
        clients = list(self.hub.clients)
        return {
            **feed,
            "clients": len(clients),
            "frames_sent": sum(c.frames_sent for c in clients),
            "frames_dropped": self.hub.frames_dropped_closed + sum(c.frames_dropped for c in clients),
        }

    async def _stats(self, request: web.Request) -> web.Response:
        return web.json_response(self.stats())

    async def _stats_loop(self) -> None:
        while True:
            await asyncio.sleep(STATS_PERIOD_S)
            stats = self.stats()
            for client in self.hub.clients:
                self._offer_stats(client, stats)

    @staticmethod
    def _offer_stats(client: ClientSlot, stats: dict[str, Any]) -> None:
        own = {"frames_sent": client.frames_sent, "frames_dropped": client.frames_dropped}
        client.offer("display", json.dumps({"type": "display", **stats, "client": own}))

    async def _ws(self, request: web.Request) -> web.WebSocketResponse:
        ws = web.WebSocketResponse(heartbeat=20.0, max_msg_size=1 << 16)
        await ws.prepare(request)
        client = ClientSlot(ws, str(request.remote))
        self.hub.join(client)
        self._offer_stats(client, self.stats())  # the picture's age at once: a reload shows no stale picture live
        sender = asyncio.create_task(_send_loop(client))
        try:
            async for msg in ws:  # the page sends nothing the server needs; read to see it go
                if msg.type == WSMsgType.ERROR:
                    break
        finally:
            self.hub.leave(client)
            sender.cancel()
            with contextlib.suppress(asyncio.CancelledError, Exception):  # the socket closed under it
                await sender
        return ws


@web.middleware
async def _security_headers(request: web.Request, handler: Any) -> web.StreamResponse:
    response = await handler(request)
    if response.prepared:  # the WebSocket, answered before its handler returned
        return response
    response.headers["Content-Security-Policy"] = CSP
    response.headers["X-Content-Type-Options"] = "nosniff"
    response.headers["Cache-Control"] = "no-cache"
    return response
