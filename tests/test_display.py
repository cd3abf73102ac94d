"""The situation display without a bus or a browser: the scene on the daemon's plane, the
frames it builds from wire messages, what it does with malformed ones, per-browser
coalescing, the HTTP/WebSocket server (aiohttp's test client), and the demo's loop."""

from __future__ import annotations

import asyncio
import json
import logging
import math
import re
import sys
from pathlib import Path

import msgpack
import numpy as np
import pytest
from aiohttp.test_utils import TestClient, TestServer

from radar_fusion.config import settings_from_dict
from radar_fusion.display import DisplayServer, parse_listen
from radar_fusion.display.feed import ALERT_STALE_PERIODS, AlertBook, Feed, tracks_frame
from radar_fusion.display.scene import build_scene
from radar_fusion.display.server import STATIC_DIR, ClientSlot, Hub, _send_loop
from radar_fusion.geo.coordinates import WGS84_GEOD, SystemPlane
from radar_fusion.geo.units import M_PER_NM
from radar_fusion.recording import Record
from radar_fusion.tools.demo_display import looped, sequence_spans, shifted

CENTRE = (46.8, 8.2)


def settings(tmp_path: Path | None = None, **nets) -> object:
    data = {
        "system": {"center_lat": CENTRE[0], "center_lon": CENTRE[1], "period_s": 4.0},
        "radars": [
            {"id": "app", "lat": 47.15, "lon": 7.9, "sigma_range_m": 30, "sigma_azimuth_deg": 0.06,
             "rotation_period_s": 4, "max_range_m": 185_200.0},
            {"id": "east", "lat": 46.8, "lon": 9.1, "sigma_range_m": 50, "sigma_azimuth_deg": 0.07,
             "rotation_period_s": 8, "max_range_m": 120_000.0},
        ],
    }  # fmt: skip
    if nets:
        data["safety_nets"] = nets
    return settings_from_dict(data)


def track(i: int, **kw) -> dict:
    t = {
        "track_id": i, "t": 1.7e9, "status": "confirmed", "lat_deg": 46.9, "lon_deg": 8.3, "x_m": 1000.0 * i,
        "y_m": -500.0 * i, "vx_mps": 200.0, "vy_mps": -20.0, "fl": 350.0, "cov_xy": [400.0, 0.0, 100.0],
        "sources": ["app", "east"], "mode3a": 0o1234, "mode_s": "4CA1F3", "updates": 12, "age_s": 48.0,
        "vrate_fpm": 1500.0,
    }  # fmt: skip
    t.update(kw)
    return t


def batch(tracks: list[dict], period: int = 7, **kw) -> bytes:
    return msgpack.packb({"v": 1, "t": 1.7e9, "period": period, "tracks": tracks, "ended": [3], **kw})


def alert(alert_id: int, status: str = "new", kind: str = "stca", t: float = 1.7e9, **kw) -> bytes:
    return msgpack.packb(
        {"v": 1, "kind": kind, "alert_id": alert_id, "t": t, "track_ids": [1, 2], "status": status, **kw}
    )


# --------------------------------------------------------------------- the scene


def test_scene_rings_are_geodesic_circles_on_the_daemons_plane():
    s = settings()
    scene = build_scene(s)
    plane = SystemPlane(*CENTRE)
    assert scene["rings"], "no range rings"
    assert [r["range_nm"] for r in scene["rings"]] == [10.0 * k for k in range(1, len(scene["rings"]) + 1)]
    # out to the farthest coverage: app is ~42 km from the centre with 100 NM of range
    assert (
        scene["rings"][-1]["range_nm"] * M_PER_NM
        <= scene["extent_m"]
        < (scene["rings"][-1]["range_nm"] + 10) * M_PER_NM
    )
    for ring in scene["rings"]:
        lat, lon = plane.to_geodetic(np.array(ring["x"]), np.array(ring["y"]))
        _, _, dist_m = WGS84_GEOD.inv(np.full(lat.shape, CENTRE[1]), np.full(lat.shape, CENTRE[0]), lon, lat)
        assert np.allclose(dist_m, ring["range_nm"] * M_PER_NM, atol=1.5)  # metres rounding
    # the plane's scale grows outward: a 100 NM ring is not a circle of 185.2 km of plane metres
    far = scene["rings"][-1]
    assert np.mean(np.hypot(far["x"], far["y"])) > far["range_nm"] * M_PER_NM


def test_scene_grid_lines_and_radar_sites_project_like_the_daemon():
    scene = build_scene(settings())
    plane = SystemPlane(*CENTRE)
    meridians = [g for g in scene["grid"] if g["kind"] == "meridian"]
    parallels = [g for g in scene["grid"] if g["kind"] == "parallel"]
    assert len(meridians) >= 3 and len(parallels) >= 3
    for g in meridians:
        lat, lon = plane.to_geodetic(np.array(g["x"]), np.array(g["y"]))
        assert np.allclose(lon, g["deg"], atol=2e-5)
    for g in parallels:
        lat, lon = plane.to_geodetic(np.array(g["x"]), np.array(g["y"]))
        assert np.allclose(lat, g["deg"], atol=2e-5)
    x_m, y_m = plane.to_plane(47.15, 7.9)
    app = next(r for r in scene["radars"] if r["id"] == "app")
    assert (app["x_m"], app["y_m"]) == (round(float(x_m)), round(float(y_m)))
    assert app["max_range_m"] == 185_200.0
    json.dumps(scene)  # what the page receives


def test_scene_areas_come_from_the_configurations_geojson(tmp_path):
    ring = [[8.1, 47.1], [8.35, 47.1], [8.35, 47.25], [8.1, 47.25], [8.1, 47.1]]
    areas = {"type": "FeatureCollection", "features": [
        {"type": "Feature", "properties": {"id": "LSR1", "lower_fl": 0, "upper_fl": 95},
         "geometry": {"type": "Polygon", "coordinates": [ring]}}]}  # fmt: skip
    msa = {"type": "FeatureCollection", "features": [
        {"type": "Feature", "properties": {"id": "HILL", "min_alt_ft": 4500},
         "geometry": {"type": "Polygon", "coordinates": [ring]}}]}  # fmt: skip
    (tmp_path / "areas.geojson").write_text(json.dumps(areas))
    (tmp_path / "msa.geojson").write_text(json.dumps(msa))
    s = settings(areas_file="areas.geojson", msa_file="msa.geojson")
    scene = build_scene(s, base_dir=tmp_path)  # relative paths resolve at the config's directory
    plane = SystemPlane(*CENTRE)
    x_m, y_m = plane.to_plane(np.array([p[1] for p in ring]), np.array([p[0] for p in ring]))
    (apw,) = scene["apw_areas"]
    assert (apw["id"], apw["lower_fl"], apw["upper_fl"]) == ("LSR1", 0.0, 95.0)
    assert np.allclose(apw["rings"][0]["x"], x_m, atol=0.5) and np.allclose(apw["rings"][0]["y"], y_m, atol=0.5)
    (hill,) = scene["msa_areas"]
    assert hill["id"] == "HILL" and hill["min_alt_ft"] == 4500.0
    assert scene["warnings"] == []


def test_a_bad_areas_file_is_a_warning_not_a_crash(tmp_path):
    (tmp_path / "areas.geojson").write_text("{ not json")
    scene = build_scene(settings(areas_file="areas.geojson", msa_file="missing.geojson"), base_dir=tmp_path)
    assert scene["apw_areas"] == [] and scene["msa_areas"] == []
    assert len(scene["warnings"]) == 2 and "not valid JSON" in scene["warnings"][0]


# --------------------------------------------------------------------- frames


def test_tracks_frame_is_columnar_with_every_field_the_page_shows():
    tracks = [
        track(1),
        track(2, status="coasting", fl=None, vrate_fpm=None, mode3a=None, callsign="SWR101"),
        track(3, status="tentative", mode_s=None, sources=[], manoeuvre_prob=0.25),
    ]
    frame = tracks_frame(batch(tracks))
    assert isinstance(frame, dict)
    assert (frame["type"], frame["period"], frame["n"], frame["ended"]) == ("tracks", 7, 3, [3])
    assert frame["id"] == [1, 2, 3]
    assert frame["status"] == [0, 1, 2]
    assert frame["x_m"] == [1000.0, 2000.0, 3000.0] and frame["y_m"] == [-500.0, -1000.0, -1500.0]
    assert frame["fl"] == [350.0, None, 350.0] and frame["vrate_fpm"] == [1500.0, None, 1500.0]
    assert frame["mode3a"] == [0o1234, None, 0o1234] and frame["mode_s"] == ["4CA1F3", "4CA1F3", None]
    assert frame["callsign"] == [None, "SWR101", None]  # not in wire v1: shown when a sender adds it
    assert frame["sources"] == ["app,east", "app,east", ""]
    assert frame["sigma_m"][0] == pytest.approx(math.sqrt(250.0), abs=0.05)
    assert frame["manoeuvre_prob"] == [None, None, 0.25]
    columns = [k for k, v in frame.items() if isinstance(v, list) and k != "ended"]
    assert all(len(frame[k]) == 3 for k in columns)
    json.dumps(frame, allow_nan=False)


def _feed() -> tuple[Feed, list[tuple[str, dict]]]:
    sent: list[tuple[str, dict]] = []
    feed = Feed(session=None, prefix="atc", period_s=4.0, sink=lambda ch, text: sent.append((ch, json.loads(text))))
    return feed, sent


def test_malformed_messages_are_counted_by_reason_and_skipped():
    feed, sent = _feed()
    bad_items = [
        ("atc/fusion/alerts/stca", b"\xc1\xc1 not msgpack"),  # malformed_msgpack
        ("atc/fusion/alerts/stca", msgpack.packb({"v": 2, "kind": "stca"})),  # version
        ("atc/fusion/alerts/stca", msgpack.packb([1, 2, 3])),  # schema: not a map
        ("atc/fusion/alerts/apw", alert(5)),  # key_mismatch: an stca alert on the apw key
        ("atc/fusion/health", msgpack.packb({"v": 1, "t": "yesterday"})),  # schema
        ("atc/radar/app/status", msgpack.packb({"v": 1, "radar_id": "east", "t": 1.7e9, "kind": "north"})),
        ("atc/radar/app/plots", b""),  # not a key the display reads
    ]
    feed.handle(bad_items, batch([track(1, x_m=float("nan"))]))  # NaN: schema (allow_inf_nan=False)
    assert feed.rejected == {"malformed_msgpack": 1, "version": 1, "schema": 4, "key_mismatch": 2}
    assert sent == []
    feed.handle([], b"\x92\x01")  # a truncated msgpack array as tracks
    assert feed.rejected["malformed_msgpack"] == 2 and sent == []
    # ... and the next good messages are drawn as if nothing happened
    feed.handle([("atc/fusion/alerts/stca", alert(5, time_to_cpa_s=42.0))], batch([track(1), track(2)]))
    channels = [ch for ch, _ in sent]
    assert channels == ["tracks", "alerts"]
    assert sent[0][1]["n"] == 2 and sent[1][1]["alerts"][0]["time_to_cpa_s"] == 42.0
    stats = feed.stats()
    assert stats["received"]["alerts"] == 5 and stats["last_tracks_n"] == 2 and stats["frames_built"] == 1


def test_a_stale_actives_batches_and_alerts_are_dropped_and_only_the_actives_health_shown():
    """A hot-standby pair (issue 13): after a partition heals, the old active's last
    messages (a lower epoch) must not replace the new active's picture."""
    feed, sent = _feed()
    feed.handle([("atc/fusion/alerts/stca", alert(1, epoch=2))], batch([track(1), track(2)], period=8, epoch=2))
    feed.handle([("atc/fusion/alerts/stca", alert(9, epoch=1))], batch([track(5)], period=8, epoch=1))
    assert feed.rejected == {"stale_epoch": 2}
    assert [f["n"] for ch, f in sent if ch == "tracks"] == [2]
    assert [a["alert_id"] for a in feed.alerts.frame()["alerts"]] == [1]
    feed.handle([], batch([track(1)], period=9, epoch=3))  # a newer take-over is followed
    assert sent[-1][1]["epoch"] == 3 and feed.highest_epoch == 3
    # without redundancy (no epoch) nothing changes
    feed.handle([], batch([track(1)], period=10))
    assert sent[-1][1]["period"] == 10
    h = {"v": 1, "t": 1.7e9, "uptime_s": 5.0, "counters": {}, "rejected": {}, "radars": {}, "periods_closed": 1}
    feed.handle([("atc/fusion/health", msgpack.packb({**h, "tracks": 2, "role": "standby", "instance": "b"}))], None)
    assert not [ch for ch, _ in sent if ch == "health"]
    feed.handle([("atc/fusion/health", msgpack.packb({**h, "tracks": 2, "role": "active", "instance": "a"}))], None)
    assert sent[-1][1]["health"]["instance"] == "a"


def test_alert_book_follows_the_life_cycle_and_drops_stale_alerts():
    book = AlertBook(period_s=4.0)
    book.apply({"alert_id": 1, "status": "new", "t": 100.0})
    book.apply({"alert_id": 2, "status": "new", "t": 100.0})
    book.apply({"alert_id": 1, "status": "ongoing", "t": 112.0})
    assert [a["alert_id"] for a in book.frame()["alerts"]] == [1, 2]
    book.apply({"alert_id": 2, "status": "ended", "t": 104.0})
    assert list(book.active) == [1]
    assert not book.prune(112.0 + ALERT_STALE_PERIODS * 4.0)  # exactly at the limit: kept
    assert book.prune(112.1 + ALERT_STALE_PERIODS * 4.0)  # an "ended" that never came
    assert book.active == {}


def test_an_alert_or_batch_stamped_beyond_any_event_time_is_refused_and_a_future_alert_pruned():
    """A TrackBatch at t = 1e13 broke the page's clock on every redraw and made every open
    alert look stale; an alert stamped a day ahead stayed on the display for ever (it was
    never behind the newest batch)."""
    feed, _sent = _feed()
    feed.handle([("atc/fusion/alerts/stca", alert(5))], batch([track(1), track(2)]))
    feed.handle([], batch([track(1), track(2)], t=1e13))
    feed.handle([("atc/fusion/alerts/stca", alert(6, t=1e13))], None)
    assert feed.rejected == {"schema": 2}
    assert [a["alert_id"] for a in feed.alerts.frame()["alerts"]] == [5]
    book = AlertBook(period_s=4.0)
    book.apply({"alert_id": 7, "status": "new", "t": 1.7e9 + 86_400.0})
    book.apply({"alert_id": 8, "status": "new", "t": 1.7e9 + ALERT_STALE_PERIODS * 4.0})
    assert book.prune(1.7e9) and list(book.active) == [8]  # a day ahead: dropped; 3 periods: kept


def test_a_daemon_restarted_without_its_state_starts_a_new_picture():
    """The daemon's ids start at 1 again on other aircraft (a track id of the last batch is
    a younger track now): the open alerts end and the page is told to drop its trails,
    which would join one aircraft's past to another's present."""
    feed, sent = _feed()
    feed.handle([("atc/fusion/alerts/stca", alert(5))], batch([track(1, age_s=600.0), track(2, age_s=580.0)]))
    feed.handle([], batch([track(1, age_s=604.0), track(2, age_s=584.0)], period=8, t=1.7e9 + 4))
    assert "new_stream" not in sent[-1][1] and feed.alerts.active
    feed.handle([], batch([track(1, age_s=4.0), track(2, age_s=4.0)], period=10, t=1.7e9 + 12))
    frames = [f for ch, f in sent if ch == "tracks"]
    assert frames[-1]["new_stream"] is True and feed.stream_restarts == 1
    assert sent[-1] == ("alerts", {"type": "alerts", "alerts": []})
    assert feed.stats()["tracks_age_s"] >= 0.0 and feed.stats()["tracks_stale_after_s"] == 3 * 4.0
    # one id of several going younger is a track taking over an older one's id: no new picture
    feed.handle([], batch([track(1, age_s=8.0), track(2, age_s=8.0), track(3, age_s=8.0)], period=11, t=1.7e9 + 16))
    feed.handle([], batch([track(1, age_s=12.0), track(2, age_s=12.0), track(3, age_s=4.0)], period=12, t=1.7e9 + 20))
    assert "new_stream" not in [f for ch, f in sent if ch == "tracks"][-1] and feed.stream_restarts == 1


# --------------------------------------------------------------------- the server


class _SlowSocket:
    """A WebSocket whose sends wait for ``release``: a browser that draws slowly."""

    def __init__(self) -> None:
        self.release = asyncio.Event()
        self.sent: list[str] = []

    async def send_str(self, text: str) -> None:
        await self.release.wait()
        self.sent.append(text)


def test_a_slow_browser_gets_the_newest_frame_and_the_stale_ones_are_counted():
    async def scenario() -> tuple[list[str], int, int]:
        hub = Hub()
        ws = _SlowSocket()
        client = ClientSlot(ws, "test")  # type: ignore[arg-type]
        hub.join(client)
        sender = asyncio.create_task(_send_loop(client))
        hub.publish("tracks", "period 1")
        await asyncio.sleep(0)  # the sender takes period 1 and waits in send_str
        for k in range(2, 6):
            hub.publish("tracks", f"period {k}")
            hub.publish("health", f"health {k}")
        ws.release.set()
        for _ in range(10):
            await asyncio.sleep(0)
        sender.cancel()
        return ws.sent, client.frames_dropped, client.frames_sent

    sent, dropped, frames_sent = asyncio.run(scenario())
    assert sent == ["period 1", "health 5", "period 5"]
    assert dropped == 3 and frames_sent == 2  # periods 2, 3, 4 never left the server


def test_parse_listen():
    assert parse_listen("127.0.0.1:8080") == ("127.0.0.1", 8080)
    assert parse_listen("[::1]:0") == ("::1", 0)
    for bad in ("8080", "127.0.0.1:", ":8080", "host:port", "127.0.0.1:70000"):
        with pytest.raises(ValueError):
            parse_listen(bad)


def test_the_page_and_everything_it_loads_come_from_the_server():
    """Nothing from a CDN or a tile server: every src/href of the page is local, no static
    file names another origin, and the server tells the browser to refuse any."""
    html = (STATIC_DIR / "index.html").read_text()
    refs = re.findall(r'(?:src|href)="([^"]*)"', html)
    assert refs and all(r.startswith("/static/") or r.startswith("data:") for r in refs), refs
    for path in STATIC_DIR.iterdir():
        assert not re.search(r"(https?:)?//[a-z0-9.-]+\.[a-z]{2,}", path.read_text()), path.name

    server = DisplayServer(settings(), port=0)

    async def requests() -> None:
        async with TestClient(TestServer(server._app())) as client:
            page = await client.get("/")
            assert page.status == 200 and page.content_type == "text/html"
            assert page.headers["Content-Security-Policy"].startswith("default-src 'self'")
            assert 'id="display"' in await page.text()
            for ref in refs:
                if ref.startswith("/static/"):
                    asset = await client.get(ref)
                    assert asset.status == 200, ref
            scene = await (await client.get("/api/scene")).json()
            assert scene["rings"] and scene["radars"][0]["id"] == "app"
            stats = await (await client.get("/api/stats")).json()
            assert stats["clients"] == 0
            assert (await client.get("/static/../scene.py")).status in (403, 404)
            # the WebSocket: a new browser gets the present state, then every new frame
            server.hub.publish("health", '{"type":"health"}')
            ws = await client.ws_connect("/ws")
            assert json.loads(await ws.receive_str(timeout=5)) == {"type": "health"}
            age = json.loads(await ws.receive_str(timeout=5))  # the picture's age, at once
            assert age["type"] == "display"
            server.hub.publish("tracks", '{"type":"tracks","n":0}')
            assert json.loads(await ws.receive_str(timeout=5))["type"] == "tracks"
            assert len(server.hub.clients) == 1
            await ws.close()

    asyncio.run(requests())


# --------------------------------------------------------------------- demo --display


def test_demo_loops_shift_event_times_and_continue_sequence_numbers():
    plots = msgpack.packb({"v": 1, "radar_id": "app", "seq": 4, "plots": [{"t": 100.0, "range_m": 1e4}]})
    status = msgpack.packb({"v": 1, "radar_id": "app", "t": 101.0, "kind": "north"})
    records = [Record(100.0, "radar/app/plots", plots), Record(101.0, "radar/app/status", status)]
    spans = sequence_spans(records)
    assert spans == {"app": 5}
    assert list(looped(records, 0, 600.0, spans)) == [
        (100.0, "radar/app/plots", plots),
        (101.0, "radar/app/status", status),
    ]
    (t0, _, p0), (t1, _, p1) = looped(records, 2, 600.0, spans)
    assert (t0, t1) == (1300.0, 1301.0)
    moved = msgpack.unpackb(p0)
    assert moved["seq"] == 14 and moved["plots"][0]["t"] == 1300.0 and moved["plots"][0]["range_m"] == 1e4
    assert msgpack.unpackb(p1)["t"] == 1301.0
    assert msgpack.unpackb(shifted("radar/app/status", status, 5.0, 0))["t"] == 106.0


def test_display_command_refuses_bad_arguments_without_starting(tmp_path, capsys):
    from radar_fusion.cli import main

    config = tmp_path / "config.toml"
    config.write_text(
        '[system]\ncenter_lat = 47.0\ncenter_lon = 8.0\n[[radars]]\nid = "r1"\nlat = 47.0\nlon = 8.0\n'
        "sigma_range_m = 50\nsigma_azimuth_deg = 0.07\nrotation_period_s = 4\n"
    )
    assert main(["display", "--config", str(config), "--listen", "localhost"]) == 2
    assert "HOST:PORT" in capsys.readouterr().err
    assert main(["display", "--config", str(tmp_path / "missing.toml")]) == 2
    assert "file not found" in capsys.readouterr().err
    # refused before the process's logging is set up (it would replace pytest's handlers)
    assert not any(
        isinstance(h, logging.StreamHandler) and h.stream is sys.stderr for h in logging.getLogger().handlers
    )
