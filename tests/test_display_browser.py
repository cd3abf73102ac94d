"""The situation display in a real browser: the distribution's headless Chromium
(/usr/bin/chromium, installed by .ci/run; driven with playwright, never `playwright
install`) loads the page while a replay runs through the daemon and the display over a
real Zenoh router on 127.0.0.1.

* the page draws exactly the tracks of the TrackBatch it shows (``data-tracks`` against
  the batch of ``data-period``, recorded by an independent subscriber), goes on after
  malformed messages on the bus, and a screenshot holds the symbols' and the STCA
  line's colours;
* a click on a track shows its details;
* the page draws all of 4,000 tracks per update, and its own measured draw time (slow;
  reported, not asserted: `pytest -m slow -k frame_time -s` prints it);
* ``radar-fusion demo --display`` serves the picture and stops on Ctrl-C (slow).

Without /usr/bin/chromium these tests are skipped, except in CI (``CI`` set), where
they fail: there the browser is part of the environment.
"""

from __future__ import annotations

import contextlib
import io
import json
import math
import os
import signal
import statistics
import subprocess
import sys
import threading
import time
import urllib.request
from pathlib import Path

import msgpack
import numpy as np
import pytest

from radar_fusion.bus import FusionDaemon, open_session, reliable_sender, zenoh_config
from radar_fusion.config import load_settings
from radar_fusion.display import DisplayServer
from radar_fusion.recording import read_recording
from radar_fusion.tools import simulate as sim
from radar_fusion.tools.demo import TrackCollector, wait_until
from radar_fusion.tools.replay import replay_records

pytestmark = pytest.mark.bus  # every test here opens Zenoh sessions

CHROMIUM = Path("/usr/bin/chromium")
LAUNCH_ARGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
]
VIEWPORT = {"width": 1280, "height": 800}
# the page's colours (display.js COLOURS): confirmed symbols and STCA
CONFIRMED_RGB = (0x44, 0xE3, 0x6B)
STCA_RGB = (0xFF, 0x40, 0x40)


@pytest.fixture(scope="module")
def browser(tmp_path_factory):
    if not CHROMIUM.exists():
        message = f"{CHROMIUM} is missing (Debian package chromium; .ci/run installs it)"
        if os.environ.get("CI"):
            pytest.fail(message)
        pytest.skip(message)
    from playwright.sync_api import sync_playwright

    pw = sync_playwright().start()
    try:
        context = pw.chromium.launch_persistent_context(
            str(tmp_path_factory.mktemp("chromium-profile")),
            executable_path=str(CHROMIUM),
            headless=True,
            viewport=VIEWPORT,
            args=LAUNCH_ARGS,
        )
    except Exception:
        pw.stop()
        raise
    yield context
    context.close()
    pw.stop()


def open_page(browser, url: str):
    page = browser.new_page()
    errors: list[str] = []
    page.on("pageerror", lambda exc: errors.append(str(exc)))
    page.goto(url)
    page.wait_for_function("() => document.getElementById('display').dataset.connected === 'true'", timeout=15_000)
    return page, errors


def dataset(page) -> dict:
    return page.evaluate("() => Object.assign({}, document.getElementById('display').dataset)")


def colour_pixels(png: bytes, rgb: tuple[int, int, int], tolerance: int = 12) -> int:
    """Pixels within ``tolerance`` (per channel, 0-255) of ``rgb`` in a PNG screenshot."""
    from matplotlib import image

    img = image.imread(io.BytesIO(png), format="png")[..., :3]
    img = np.round(img * 255).astype(int)
    return int(np.all(np.abs(img - np.array(rgb)) <= tolerance, axis=-1).sum())


def settings_on_port(path, port):
    s = load_settings(path)
    return s.model_copy(
        update={"bus": s.bus.model_copy(update={"mode": "router", "listen": [f"tcp/127.0.0.1:{port}"]})}
    )


@pytest.fixture(scope="module")
def scenario(tmp_path_factory):
    """The demo scenario, 100 s of it: conflicts (STCA) from the first periods."""
    out = tmp_path_factory.mktemp("display")
    sim.write_outputs(sim.simulate(sim.preset("demo", seed=3, duration_s=100.0)), out)
    return out


def test_page_draws_every_track_of_the_batch_it_shows(browser, scenario, free_port, tmp_path):
    settings = settings_on_port(scenario / "config.toml", free_port)
    endpoint = settings.bus.listen[0]
    daemon = FusionDaemon(settings).start()
    display = DisplayServer(settings, port=0, zenoh_config=zenoh_config("client", connect=[endpoint]))
    session = open_session(zenoh_config("client", connect=[endpoint]))
    collector = None
    page = None
    try:
        display.start()
        page, errors = open_page(browser, display.url)
        time.sleep(0.5)  # subscriptions reach the router
        # malformed messages on the display's keys: counted and skipped, the picture goes on
        # (one at a time: a TrackBatch that waits is replaced by the next, valid or not)
        for k, (key, payload) in enumerate(
            (
                ("atc/fusion/tracks", b"\xc1 not msgpack"),
                ("atc/fusion/tracks", msgpack.packb({"v": 1, "t": 1.0, "period": -4, "tracks": "many"})),
                ("atc/fusion/alerts/stca", msgpack.packb({"v": 1, "kind": "stca"})),
            )
        ):
            pub = reliable_sender(session, key)
            pub.put(payload)
            assert wait_until(lambda k=k: sum(display.stats()["rejected"].values()) > k, 10)
        collector = TrackCollector(session, settings.bus.prefix)  # what the bus carried, independently
        time.sleep(0.3)
        # the control: the scope before any traffic has neither colour (map, rings and live radars only)
        empty = page.locator("#scope").screenshot()
        assert colour_pixels(empty, CONFIRMED_RGB) == 0 and colour_pixels(empty, STCA_RGB) == 0
        replay = threading.Thread(
            target=replay_records,
            args=(session, read_recording(scenario / "plots.rec"), settings.bus.prefix, 30.0),
            daemon=True,
        )
        replay.start()
        seen: dict[int, int] = {}  # period -> tracks drawn, as the page said
        shot = None
        while replay.is_alive():
            d = dataset(page)
            period, drawn = int(d["period"]), int(d["tracks"])
            if period >= 0:
                seen.setdefault(period, drawn)
            if shot is None and int(d.get("stcaLines") or 0) > 0 and drawn >= 10:
                shot = (page.locator("#scope").screenshot(), d)
            time.sleep(0.1)
        replay.join()
        assert wait_until(lambda: daemon.messages_processed >= 1000 and not daemon.queue.qsize(), 30)
        last = max(b["period"] for b in collector.batches)
        assert wait_until(lambda: int(dataset(page)["period"]) == last, 15), (dataset(page), last)
        d = dataset(page)
        seen[last] = int(d["tracks"])

        # every period the page showed, it drew the batch's count of tracks, no more, no less
        published = {b["period"]: len(b["tracks"]) for b in collector.batches}
        assert len(seen) >= 5, seen  # periods the page was seen drawing, the last one among them
        mismatched = {p: (n, published.get(p)) for p, n in seen.items() if published.get(p) != n}
        assert not mismatched, mismatched
        assert max(seen.values()) >= 20  # the demo's aircraft, not an empty picture

        stats = json.loads(urllib.request.urlopen(display.url + "api/stats", timeout=5).read())
        assert stats["rejected"].get("malformed_msgpack", 0) >= 1 and stats["rejected"].get("schema", 0) >= 2
        assert stats["clients"] == 1
        assert errors == []
        # the demo's 2018 traffic is years behind the wall clock: no lag of 263,544,725 s shown
        assert wait_until(lambda: "replayed data" in (page.locator("#health").text_content() or ""), 10)

        # the screenshot taken while an STCA pair was drawn holds the symbols and the red line
        assert shot is not None, "no STCA line drawn during the replay"
        png, at = shot
        (tmp_path / "display.png").write_bytes(png)
        green, red = colour_pixels(png, CONFIRMED_RGB), colour_pixels(png, STCA_RGB)
        assert green >= 20 * int(at["tracks"]) // 2, (green, at)  # a 7×7 square per confirmed track, and labels
        assert red >= 60 * int(at["stcaLines"]), (red, at)  # the joining line and a ring round each track

        # click a track well apart from the others: its details appear
        tracks = max(collector.batches, key=lambda b: b["period"])["tracks"]
        xy = np.array([[t["x_m"], t["y_m"]] for t in tracks])
        gaps = np.sort(np.hypot(*(xy[:, None, :] - xy[None, :, :]).transpose(2, 0, 1)), axis=1)[:, 1]
        box = page.locator("#scope").bounding_box()
        confirmed = [k for k, t in enumerate(tracks) if t["status"] == "confirmed"]
        target = tracks[max(confirmed, key=lambda k: gaps[k])]
        pos = page.evaluate("id => window.radarFusionDisplay.screenOf(id)", target["track_id"])
        assert 0 < pos["x"] < box["width"] and 0 < pos["y"] < box["height"], pos  # the view frames the traffic
        page.mouse.click(box["x"] + pos["x"], box["y"] + pos["y"])
        page.wait_for_function("() => !document.getElementById('track-details').innerText.includes('click a track')")
        details = page.locator("#track-details").inner_text()
        assert f"{target['track_id']} {target['status']}" in details, details
        assert "ground speed" in details
    finally:
        if page is not None:
            page.close()
        if collector is not None:
            collector.close()
        session.close()
        display.stop()
        daemon.stop(timeout_s=10.0)


def synthetic_batch(period: int, n: int, base: dict) -> bytes:
    """``n`` confirmed/coasting/tentative tracks spread over ±300 km, moving: what a
    daemon with 4,000 aircraft publishes each period."""
    t_s = 1.7e9 + 4.0 * period
    x = base["x"] + base["vx"] * 4.0 * period
    y = base["y"] + base["vy"] * 4.0 * period
    status = ("confirmed", "confirmed", "confirmed", "coasting", "tentative")
    tracks = [
        {
            "track_id": i,
            "t": t_s,
            "status": status[i % 5],
            "lat_deg": 47.0,
            "lon_deg": 8.0,
            "x_m": float(x[i]),
            "y_m": float(y[i]),
            "vx_mps": float(base["vx"][i]),
            "vy_mps": float(base["vy"][i]),
            "fl": float(base["fl"][i]),
            "cov_xy": [900.0, 0.0, 900.0],
            "sources": ["r1", "r2"],
            "mode3a": int(i % 4096),
            "mode_s": f"{0x400000 + i:06X}",
            "updates": period + 1,
            "age_s": 4.0 * period,
            "vrate_fpm": float(base["vr"][i]),
        }
        for i in range(n)
    ]
    return msgpack.packb({"v": 1, "t": t_s, "period": period, "tracks": tracks, "ended": []}, use_bin_type=True)


@pytest.mark.slow
def _track_batch(t_s: float, period: int, age_s: float) -> bytes:
    tracks = [
        {
            "track_id": i, "t": t_s, "status": "confirmed", "lat_deg": 46.9, "lon_deg": 8.3 + 0.05 * i,
            "x_m": 4000.0 * i, "y_m": -2000.0 * i, "vx_mps": 200.0, "vy_mps": -20.0, "fl": 350.0,
            "cov_xy": [400.0, 0.0, 100.0], "sources": ["app"], "mode3a": 0o1234, "mode_s": None,
            "updates": 12, "age_s": age_s, "vrate_fpm": 0.0,
        }
        for i in (1, 2)
    ]  # fmt: skip
    return msgpack.packb({"v": 1, "t": t_s, "period": period, "tracks": tracks, "ended": []})


@contextlib.contextmanager
def display_fed_by_hand(browser, settings):
    """A display on a router of the test's own (no daemon: the test publishes the
    TrackBatches), a page open on it: yields (sender on the tracks key, display, page, the
    page's errors), and closes all three."""
    endpoint = settings.bus.listen[0]
    router = open_session(zenoh_config("router", listen=[endpoint]))
    display = DisplayServer(settings, port=0, zenoh_config=zenoh_config("client", connect=[endpoint]))
    page = None
    try:
        display.start()
        page, errors = open_page(browser, display.url)
        time.sleep(0.5)  # the display's subscriptions reach the router
        yield reliable_sender(router, "atc/fusion/tracks"), display, page, errors
    finally:
        if page is not None:
            page.close()
        display.stop()
        router.close()


def test_a_picture_no_longer_fed_is_shown_stale_not_live_also_after_a_reload(browser, scenario, free_port):
    """The daemon stops: the page said "live" over the last picture for as long as its
    WebSocket was open, and again after a reload (the server replays its latest frames).
    Now, three periods of wall time without a TrackBatch, the header says NO TRACK DATA
    and the picture is greyed; a batch with a clock beyond any event time does not break
    the page; the next batch of a daemon restarted without its state is a new picture."""
    base = settings_on_port(scenario / "config.toml", free_port)
    settings = base.model_copy(update={"system": base.system.model_copy(update={"period_s": 1.0})})
    with display_fed_by_hand(browser, settings) as (tracks, display, page, errors):
        t0 = 1.7e9
        for k in range(3):
            tracks.put(_track_batch(t0 + k, 100 + k, 600.0 + k))
            time.sleep(0.3)
        conn = page.locator("#conn")
        assert wait_until(lambda: dataset(page)["period"] == "102" and conn.text_content() == "live", 10)
        assert dataset(page)["stale"] == "false"
        assert colour_pixels(page.locator("#scope").screenshot(), CONFIRMED_RGB) >= 2 * 20  # two symbols, labels
        tracks.put(msgpack.packb({**msgpack.unpackb(_track_batch(t0 + 3, 103, 603.0)), "t": 1e13}))
        assert wait_until(lambda: display.stats()["rejected"].get("schema", 0) == 1, 10)
        # nothing more comes: stale after 3 periods (3 s here), greyed and said so
        assert wait_until(lambda: dataset(page)["stale"] == "true", 10)
        assert "NO TRACK DATA" in conn.text_content()
        time.sleep(0.2)  # the redraw
        assert colour_pixels(page.locator("#scope").screenshot(), CONFIRMED_RGB) == 0  # greyed
        page.reload()
        page.wait_for_function("() => document.getElementById('display').dataset.connected === 'true'")
        assert wait_until(lambda: dataset(page).get("stale") == "true" and "NO TRACK DATA" in conn.text_content(), 5)
        assert dataset(page)["period"] == "102"  # the last picture, shown for what it is
        # a restarted daemon, without its state: ids from 1 again, young tracks
        tracks.put(_track_batch(t0 + 40, 140, 4.0))
        assert wait_until(lambda: dataset(page)["period"] == "140" and dataset(page)["stale"] == "false", 10)
        assert conn.text_content() == "live" and display.stats()["stream_restarts"] == 1
        assert errors == []


def test_the_labels_of_close_aircraft_are_placed_apart(browser, scenario, free_port):
    """Two aircraft 300 m apart (a pair a controller watches), a third 40 km off so that the
    view takes them all: the second label goes where the first does not cover it (they
    were drawn one over the other)."""
    settings = settings_on_port(scenario / "config.toml", free_port)
    with display_fed_by_hand(browser, settings) as (sender, _display, page, errors):
        tracks = msgpack.unpackb(_track_batch(1.7e9, 5, 60.0))["tracks"]
        third = dict(tracks[0], track_id=3, x_m=40_000.0, y_m=20_000.0)
        tracks[0].update(x_m=0.0, y_m=0.0)
        tracks[1].update(x_m=300.0, y_m=0.0)
        batch = {"v": 1, "t": 1.7e9, "period": 5, "tracks": [*tracks, third], "ended": []}
        sender.put(msgpack.packb(batch))
        assert wait_until(lambda: dataset(page).get("period") == "5" and "labelOverlaps" in dataset(page), 10)
        assert dataset(page)["labelOverlaps"] == "0" and errors == []


def test_frame_time_at_4000_tracks(browser, tmp_path, free_port, record_property):
    """4,000 tracks, one TrackBatch per update, all on screen with labels, trails and
    vectors: the page's own draw time (performance.now() around the draw) per update."""
    n_tracks, updates = 4000, 8
    config = tmp_path / "config.toml"
    config.write_text(
        "[system]\ncenter_lat = 47.0\ncenter_lon = 8.0\nperiod_s = 4.0\n"
        f'[bus]\nmode = "router"\nlisten = ["tcp/127.0.0.1:{free_port}"]\n'
        '[[radars]]\nid = "r1"\nlat = 47.0\nlon = 8.0\nsigma_range_m = 50\nsigma_azimuth_deg = 0.07\n'
        "rotation_period_s = 4\nmax_range_m = 300000\n"
    )
    settings = load_settings(config)
    endpoint = settings.bus.listen[0]
    router = open_session(zenoh_config("router", listen=[endpoint]))
    display = DisplayServer(settings, port=0, zenoh_config=zenoh_config("client", connect=[endpoint]))
    page = None
    rng = np.random.default_rng(4)
    heading = rng.uniform(0, 2 * math.pi, n_tracks)
    speed = rng.uniform(100, 260, n_tracks)
    base = {
        "x": rng.uniform(-280e3, 280e3, n_tracks), "y": rng.uniform(-280e3, 280e3, n_tracks),
        "vx": speed * np.sin(heading), "vy": speed * np.cos(heading),
        "fl": rng.uniform(50, 400, n_tracks), "vr": rng.choice([-1500.0, 0.0, 1500.0], n_tracks),
    }  # fmt: skip
    try:
        display.start()
        page, errors = open_page(browser, display.url)
        time.sleep(0.5)
        pub = reliable_sender(router, "atc/fusion/tracks")
        frame_ms, ingest_ms = [], []
        for period in range(updates):
            pub.put(synthetic_batch(period, n_tracks, base))
            page.wait_for_function(
                f"() => document.getElementById('display').dataset.period === '{period}'", timeout=20_000
            )
            d = dataset(page)
            assert int(d["tracks"]) == n_tracks
            if period > 0:  # the first frame also lays out the map layer and fits the view
                frame_ms.append(float(d["frameMs"]))
                ingest_ms.append(float(d["ingestMs"]))
        (tmp_path / "4000-tracks.png").write_bytes(page.screenshot())  # to look at, when in doubt
        median_ms, max_ms = statistics.median(frame_ms), max(frame_ms)
        print(
            f"\n4,000 tracks: draw {median_ms:.1f} ms median, {max_ms:.1f} ms max over {len(frame_ms)} updates; "
            f"JSON.parse + ingest {statistics.median(ingest_ms):.1f} ms median"
        )
        assert errors == []
        # Measured and reported, not asserted (README: speed is never asserted in a test, the
        # machine is shared); the goal is <= 100 ms per update, the README states the figure.
        assert all(ms > 0.0 for ms in frame_ms), frame_ms  # the page did time its draws
        record_property("frame_ms_median_4000_tracks", median_ms)
        record_property("frame_ms_max_4000_tracks", max_ms)
    finally:
        if page is not None:
            page.close()
        display.stop()
        router.close()


@pytest.mark.slow
def test_demo_display_serves_the_picture_and_stops_on_ctrl_c(tmp_path):
    proc = subprocess.Popen(
        [sys.executable, "-m", "radar_fusion.cli", "demo", "--display", "--listen", "127.0.0.1:0", "--speed", "50",
         "--out", str(tmp_path / "demo")],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
    )  # fmt: skip
    lines: list[str] = []
    try:
        url = None
        deadline = time.monotonic() + 60
        while url is None and time.monotonic() < deadline:
            line = proc.stdout.readline()
            if not line:
                break
            lines.append(line)
            if line.startswith("situation display: "):
                url = line.split(": ", 1)[1].strip()
        assert url and url.startswith("http://127.0.0.1:"), lines

        def tracks_shown() -> bool:
            stats = json.loads(urllib.request.urlopen(url + "api/stats", timeout=5).read())
            return (stats["last_tracks_n"] or 0) >= 20

        assert wait_until(tracks_shown, 60, step_s=0.5)
        page = urllib.request.urlopen(url, timeout=5).read().decode()
        assert 'id="display"' in page
        proc.send_signal(signal.SIGINT)
        rest, _ = proc.communicate(timeout=30)
        lines.append(rest)
        assert proc.returncode == 0, "".join(lines)
        assert "stopped after" in rest
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(10)


def test_display_command_serves_the_configured_scene_and_stops_on_sigint(tmp_path, free_port):
    """`radar-fusion display --config FILE --listen 127.0.0.1:0` as a process, beside a router."""
    config = tmp_path / "config.toml"
    config.write_text(
        "[system]\ncenter_lat = 47.0\ncenter_lon = 8.0\n"
        f'[bus]\nmode = "router"\nlisten = ["tcp/127.0.0.1:{free_port}"]\n'
        '[[radars]]\nid = "r1"\nlat = 47.0\nlon = 8.0\nsigma_range_m = 50\nsigma_azimuth_deg = 0.07\n'
        "rotation_period_s = 4\n"
    )
    router = open_session(zenoh_config("router", listen=[f"tcp/127.0.0.1:{free_port}"]))
    proc = subprocess.Popen(
        [sys.executable, "-m", "radar_fusion.cli", "display", "--config", str(config), "--listen", "127.0.0.1:0"],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
    )  # fmt: skip
    try:
        lines: list[str] = []
        while len(lines) < 20 and not (lines and lines[-1].startswith("situation display: ")):
            lines.append(proc.stdout.readline())  # log lines, then the URL for the user
            if not lines[-1]:
                break
        assert lines[-1].startswith("situation display: http://127.0.0.1:"), lines
        url = lines[-1].split()[2]
        scene = json.loads(urllib.request.urlopen(url + "api/scene", timeout=5).read())
        assert [r["id"] for r in scene["radars"]] == ["r1"] and scene["center_lat_deg"] == 47.0
        proc.send_signal(signal.SIGINT)
        out, _ = proc.communicate(timeout=20)
        assert proc.returncode == 0, out
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(10)
        router.close()
