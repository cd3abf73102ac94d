"""The live situation display (issue 14): `radar-fusion display --config FILE`.

A web server (aiohttp) that subscribes to the daemon's tracks, alerts, health and the
radars' status over Zenoh, like any consumer, and pushes them to browsers over a
WebSocket; one page (``static/``: HTML, JavaScript, CSS; no build step, nothing from
another origin) draws the air situation on a canvas.

* :mod:`.scene`: rings, lat/lon grid, radar sites, APW / MSA areas in system-plane metres;
* :mod:`.feed`: the subscriptions, validation against the wire contract, the page's frames;
* :mod:`.server`: the HTTP / WebSocket server, per-browser coalescing, :class:`DisplayServer`.
"""

from __future__ import annotations

from .server import DisplayServer, parse_listen

__all__ = ["DisplayServer", "parse_listen"]
