"""The safety nets as their own consumer (issue 16 item 2), without a bus: a received
TrackBatch gives the engine's columns and alerts; bad input is counted, never raised;
serve's settings reach the child intact. The bus tests are in test_safety_nets_bus.py."""

from __future__ import annotations

import copy
import math

import msgpack
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from pydantic import ValidationError

from radar_fusion.config import settings_from_dict
from radar_fusion.engine.columns import RadarNames, TrackColumns
from radar_fusion.geo.coordinates import SystemPlane
from radar_fusion.safety_nets import SafetyNets, SafetyNetsConfig
from radar_fusion.safety_nets.process import SafetyNetsProcess
from radar_fusion.safety_nets.supervisor import child_settings_json
from radar_fusion.safety_nets.track_input import TrackBatchReader
from radar_fusion.tracking.track_management import COASTING, CONFIRMED, TENTATIVE
from radar_fusion.wire import SafetyNetsHealth, TrackBatch

PLANE = SystemPlane(47.0, 8.0)
RADARS = ["r1", "r2", "r3"]
CONFIG = {
    "system": {"center_lat": 47.0, "center_lon": 8.0},
    "radars": [
        dict(id=r, lat=47.0 + i / 10, lon=8.0, sigma_range_m=50, sigma_azimuth_deg=0.1, rotation_period_s=4)
        for i, r in enumerate(RADARS)
    ],
    "safety_nets": {"load_entry_point_hooks": False},
}


def engine_columns(t_s: float = 1.7e9, n: int = 6, seed: int = 0) -> TrackColumns:
    """Columns as the engine makes them: two converging pairs (one with a coasting track,
    which the engine's rule judges), tentative and unknown-level tracks, every optional
    column filled with values that are not round."""
    rng = np.random.default_rng(seed)
    x = np.zeros((n, 6))
    x[:, 0] = [0.0, 0.0, 30e3, 30e3, -40e3, 50e3][:n]
    x[:, 3] = [-20e3, 20e3, -15e3, 15e3, 0.0, 40e3][:n]
    x[:, 1] = [0.0, 0.0, 0.0, 0.0, 150.0, -120.0][:n]
    x[:, 4] = [200.0, -200.0, 180.0, -180.0, 0.0, 0.0][:n]
    x[:, [2, 5]] = rng.normal(0, 0.3, (n, 2))
    x += rng.normal(0, 1e-3, x.shape)
    if n > 4:  # track 5: one update, no velocity yet, reported at its measurement time
        x[4, [1, 2, 4, 5]] = math.nan
    t_track_s = np.full(n, t_s)
    if n > 4:
        t_track_s[4] = t_s - 1.5
    return TrackColumns(
        period=int(t_s // 4),
        t_s=t_s,
        track_id=np.arange(1, n + 1, dtype=np.int64),
        status=np.array([CONFIRMED, CONFIRMED, CONFIRMED, COASTING, TENTATIVE, CONFIRMED][:n], np.int8),
        x=x,
        cov_xy=np.abs(rng.normal(1e4, 1e3, (n, 3))),
        fl=np.array([310.0 + 1 / 3, 310.004, 250.0, 250.0, 120.0, math.nan][:n]),
        vrate_fpm=np.array([0.0, 12.5, -1.0 / 3, 0.0, 1500.0, math.nan][:n]),
        sources=np.array([1, 3, 2, 4, 7, 0][:n], np.uint64),
        mode3a=np.array([0o1234, -1, 0o7777, 1, -1, 2][:n], np.int64),
        mode_s=np.array([0x3C0001, 0x3C0002, -1, 0xABCDEF, 0x000001, -1][:n], np.int64),
        updates=np.arange(n, dtype=np.int64) + 3,
        age_s=rng.uniform(0, 100, n),
        ended=np.array([17, 18], np.int64),
        names=RadarNames(RADARS, PLANE),
        manoeuvre_prob=rng.uniform(0, 1, n),
        t_track_s=t_track_s,
    )


def reader() -> TrackBatchReader:
    return TrackBatchReader(PLANE, RADARS)


def nets() -> SafetyNets:
    return SafetyNets(SafetyNetsConfig(load_entry_point_hooks=False), PLANE)


# ------------------------------------------------------------------ what a TrackBatch carries


@pytest.mark.parametrize("n", [6, 400])  # 400: packed from the columns (PACK_FROM_COLUMNS_MIN_TRACKS)
def test_a_received_track_batch_gives_the_engine_columns(n):
    tr = engine_columns(n=6)
    if n > 6:  # more tracks, far apart, so that the packer's column path is taken
        reps = n // 6
        tr = TrackColumns(
            **{
                **{f: getattr(tr, f) for f in ("period", "t_s", "ended", "names")},
                **{
                    f: np.concatenate([getattr(tr, f)] * reps)
                    for f in (
                        "status",
                        "cov_xy",
                        "fl",
                        "vrate_fpm",
                        "sources",
                        "mode3a",
                        "mode_s",
                        "updates",
                        "age_s",
                        "manoeuvre_prob",
                    )
                },
                "track_id": np.arange(1, 6 * reps + 1, dtype=np.int64),
                "x": np.concatenate([tr.x + [k * 200e3, 0, 0, 0, 0, 0] for k in range(reps)]),
            }
        )
    back = reader().decode(tr.to_msgpack())
    assert isinstance(back, TrackColumns)
    for name in ("track_id", "status", "x", "cov_xy", "fl", "vrate_fpm", "sources", "mode3a", "mode_s", "updates"):
        np.testing.assert_array_equal(getattr(back, name), getattr(tr, name), err_msg=name)
    np.testing.assert_array_equal(back.age_s, tr.age_s)
    np.testing.assert_array_equal(back.ended, tr.ended)
    np.testing.assert_array_equal(back.t_track_s, tr.t_track_s)
    np.testing.assert_array_equal(back.lat_deg, tr.lat_deg)
    np.testing.assert_array_equal(back.lon_deg, tr.lon_deg)
    assert (back.period, back.t_s) == (tr.period, tr.t_s)
    # the engine's rule, not from_message's: coasting tracks are judged too
    assert back.safety_eligible is None and tr.safety_eligible is None
    assert back.to_msgpack() == tr.to_msgpack()


def test_the_alerts_of_received_batches_are_the_engine_columns_alerts():
    """Period after period, judged on the engine's columns and on the TrackBatch bytes:
    the same alerts, field for field (a coasting track's conflict included)."""
    a, b, rd = nets(), nets(), reader()
    got_a, got_b = [], []
    for k in range(30):
        tr = engine_columns(t_s=1.7e9 + 4.0 * k, seed=k)
        tr.x[:, 0] += np.nan_to_num(tr.x[:, 1]) * 4.0 * k
        tr.x[:, 3] += np.nan_to_num(tr.x[:, 4]) * 4.0 * k
        got_a += a.update(tr.t_s, tr)
        got_b += b.update(tr.t_s, rd.decode(tr.to_msgpack()))
    assert got_a == got_b
    assert {tuple(x["track_ids"]) for x in got_a if x["status"] == "new"} >= {(1, 2), (3, 4)}  # 4 coasts


def test_track_batch_from_a_consumer_rule_would_drop_the_coasting_conflict():
    """Why the reader leaves safety_eligible None: from_message's confirmed-only rule
    would lose the conflict of the coasting track 4 (what the brief warned of)."""
    got = []
    net = nets()
    for k in range(30):
        tr = engine_columns(t_s=1.7e9 + 4.0 * k, seed=k)
        tr.x[:, 0] += np.nan_to_num(tr.x[:, 1]) * 4.0 * k
        tr.x[:, 3] += np.nan_to_num(tr.x[:, 4]) * 4.0 * k
        got += net.update(tr.t_s, TrackColumns.from_message(tr.to_message(), PLANE, RADARS))
    assert (3, 4) not in {tuple(x["track_ids"]) for x in got}


# ------------------------------------------------------------------ bad input


def good_message() -> dict:
    return msgpack.unpackb(engine_columns().to_msgpack(), raw=False)


def service() -> SafetyNetsProcess:
    return SafetyNetsProcess(settings_from_dict(CONFIG))  # not started: no bus, process() only


BAD = {
    "malformed_msgpack": [b"\xc1", b"\x92\x01", b""],
    "schema": [
        msgpack.packb([1, 2, 3]),
        msgpack.packb("tracks"),
        msgpack.packb({**good_message(), "tracks": "none"}),
        msgpack.packb({k: v for k, v in good_message().items() if k != "period"}),
        msgpack.packb({**good_message(), "period": -1}),
        msgpack.packb({**good_message(), "t": math.nan}),
    ],
    "version": [msgpack.packb({**good_message(), "v": 2}), msgpack.packb({**good_message(), "v": True})],
}


def _with_track(**change) -> bytes:
    msg = good_message()
    msg["tracks"][1].update(change)
    return msgpack.packb(msg)


BAD["schema"] += [
    _with_track(x_m=math.nan),
    _with_track(vy_mps=math.inf),
    _with_track(x_m=None),
    _with_track(status="flying"),
    _with_track(track_id=-3),
    _with_track(cov_xy=[1.0, 2.0]),
    _with_track(sources="r1"),
    _with_track(age_s=-1.0),
    _with_track(manoeuvre_prob=1.5),
    _with_track(fl=math.nan),
    _with_track(mode_s="not hex"),  # the model takes any string; the columns need an address
    _with_track(track_id=2**64 - 1),  # msgpack uint64: beyond the int64 column
]


def test_malformed_track_batches_are_counted_by_reason_and_never_raise():
    svc = service()
    expected = {}
    for reason, payloads in BAD.items():
        for p in payloads:
            assert svc.process(p) == []
        expected[reason] = len(payloads)
    assert dict(svc.rejected) == expected
    assert svc.counters["batches_processed"] == 0
    assert svc.process(engine_columns().to_msgpack()) is not None  # a good one still judged
    assert svc.counters["batches_processed"] == 1


def test_an_oversize_batch_is_refused_before_decoding():
    rd = TrackBatchReader(PLANE, RADARS, max_bytes=100)
    rej = rd.decode(engine_columns().to_msgpack())
    assert not isinstance(rej, TrackColumns) and rej.reason == "oversize"


def test_what_the_model_coerces_is_read_through_the_model():
    """A numeric string is a float to the (lax) Track model: the fast reading hands the
    batch to the model, which accepts it; the columns come from its dump."""
    msg = good_message()
    msg["tracks"][0]["x_m"] = "1234.5"
    rd = reader()
    back = rd.decode(msgpack.packb(msg))
    assert isinstance(back, TrackColumns) and back.x_m[0] == 1234.5
    assert rd.model_fallbacks == 1


def test_a_track_stream_that_goes_back_in_time():
    svc = service()
    tr = [engine_columns(t_s=1.7e9 + 4.0 * k) for k in range(6)]
    for c in tr[:4]:
        svc.process(c.to_msgpack())
    assert svc.process(tr[3].to_msgpack()) == []  # the same batch again
    assert svc.rejected["out_of_order"] == 1
    # a daemon restarted on older data: the third batch in a row back in time starts a new stream
    svc.process(tr[0].to_msgpack())
    assert svc.rejected["out_of_order"] == 2 and svc.counters["stream_restarts"] == 0
    svc.process(tr[1].to_msgpack())
    assert svc.counters["stream_restarts"] == 1 and svc.newest_t == tr[1].t_s
    svc.process(tr[2].to_msgpack())
    assert svc.counters["batches_processed"] == 6 and svc.rejected["out_of_order"] == 2


def test_a_daemon_restarted_without_its_state_is_a_new_stream_though_time_goes_on():
    """A stand-alone safety-nets process; the daemon restarts without --state-dir: its
    time goes on, but its track ids start at 1 again, on other aircraft. The open alert of
    the old tracks 1 and 2 ends, and the new pair 1, 2 (a far conflict, to be confirmed)
    is raised as new with a new alert id once confirmed, not carried on as the old one."""
    svc = service()
    v = 240.0

    def batch(t_s, rows, age_s):
        tr = engine_columns(t_s=t_s, n=2)
        tr.track_id[:] = [1, 2]
        tr.status[:] = CONFIRMED
        tr.x[:] = [[x, vx, 0.0, y, 0.0, 0.0] for x, y, vx in rows]
        tr.fl[:] = 200.0
        tr.vrate_fpm[:] = 0.0
        tr.age_s[:] = age_s
        return tr.to_msgpack()

    t0 = 1.7e9
    first = []
    for k in range(4):  # head-on, 30 km apart: a conflict
        d = 15e3 - v * 4 * k
        first += svc.process(batch(t0 + 4 * k, [(-d, 0.0, v), (d, 0.0, -v)], 60.0 + 4 * k))
    opened = {a["alert_id"] for a in first if a["status"] == "new"}
    assert len(opened) == 1
    later = []
    for k in range(6):  # 40 s on: new aircraft 1 and 2, 80 km north, 60 km apart head-on
        d = 30e3 - v * 4 * k
        later.append(svc.process(batch(t0 + 40 + 4 * k, [(-d, 80e3, v), (d, 80e3, -v)], 4.0 * k)))
    assert svc.counters["stream_restarts"] == 1
    assert [(a["alert_id"], a["status"]) for a in later[0] if a["alert_id"] in opened] == [(min(opened), "ended")]
    new = [a for out in later for a in out if a["status"] == "new"]
    assert len(new) == 1 and new[0]["alert_id"] not in opened and new[0]["track_ids"] == [1, 2]
    assert not [a for a in later[0] if a["status"] == "new"]  # confirmed over periods, not at once


def test_one_id_that_goes_younger_is_no_new_stream():
    """Within one stream a track that takes over an older one's id keeps its own start
    (engine._take_over; an SSR aircraft's wild plot): its id's age goes back. Taken for a
    restarted daemon, it ended every open alert (a review: 3 times in 300 s of 400
    aircraft). A restart gives every id again."""
    svc = service()
    first = engine_columns(t_s=1.7e9, n=6, seed=1)
    first.age_s[:] = 100.0
    svc.process(first.to_msgpack())
    later = engine_columns(t_s=1.7e9 + 4, n=6, seed=1)
    later.age_s[:] = 104.0
    later.age_s[2] = 4.0  # one id, now a younger track's
    svc.process(later.to_msgpack())
    assert svc.counters["stream_restarts"] == 0
    again = engine_columns(t_s=1.7e9 + 8, n=6, seed=1)
    again.age_s[:] = 4.0  # every id a young track's: a restart
    svc.process(again.to_msgpack())
    assert svc.counters["stream_restarts"] == 1


def test_the_health_message_follows_the_contract():
    svc = service()
    svc.process(engine_columns().to_msgpack())
    svc.process(b"\xc1")
    health = SafetyNetsHealth.model_validate(svc.health_message())
    assert health.counters["batches_processed"] == 1 and health.rejected == {"malformed_msgpack": 1}
    assert health.counters["safety_nets_periods"] == 1  # the nets' own counters, named as in the daemon's health


# Any value in any field of one track: the reader accepts exactly what the model accepts
# (the model's reason or the reader's columns), and never raises.
_values = st.one_of(
    st.none(),
    st.booleans(),
    st.integers(min_value=-(2**65), max_value=2**65),
    st.floats(allow_nan=True, allow_infinity=True),
    st.text(max_size=8),
    st.sampled_from(["confirmed", "coasting", "tentative", "3C0001", "1.5", "r1"]),
    st.lists(st.one_of(st.floats(), st.integers(), st.text(max_size=3)), max_size=4),
)


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(field=st.sampled_from(sorted(good_message()["tracks"][0]) + ["extra"]), value=_values)
def test_reader_and_model_agree_on_every_field(field, value):
    msg = good_message()
    msg["tracks"][2][field] = value
    try:
        dumped = TrackBatch.model_validate(copy.deepcopy(msg)).model_dump()
        model_ok = True
    except ValidationError:
        model_ok = False
    got = reader().from_object(msg)
    reader_ok = isinstance(got, TrackColumns)
    if model_ok and not reader_ok:
        # the one refusal beyond the model: numbers the columns cannot hold (an address
        # that is not 6 hex digits, an integer beyond int64)
        t = dumped["tracks"][2]
        assert field in ("mode_s", "track_id", "updates", "mode3a"), (field, value, got)
        ms = t["mode_s"]
        assert (
            (ms is not None and (len(ms) != 6 or not _is_hex(ms)))
            or abs(t.get(field) or 0) >= 2**63
            or (field == "mode3a" and t["mode3a"] < -1)
        )
    else:
        assert reader_ok == model_ok, (field, value, got)


def _is_hex(s: str) -> bool:
    try:
        int(s, 16)
        return True
    except ValueError:
        return False


# ------------------------------------------------------------------ serve's side


def test_the_child_gets_serves_settings_with_absolute_area_paths(tmp_path):
    data = copy.deepcopy(CONFIG)
    data["safety_nets"].update(areas_file="areas.geojson", msa_file="/abs/msa.geojson", stca_h_min_nm=3.0)
    settings = settings_from_dict(data)
    got = settings_from_dict(__import__("json").loads(child_settings_json(settings, tmp_path)))
    assert got.safety_nets.areas_file is not None and got.safety_nets.areas_file == (tmp_path / "areas.geojson")
    assert str(got.safety_nets.msa_file) == "/abs/msa.geojson"
    assert got.model_dump(exclude={"safety_nets"}) == settings.model_dump(exclude={"safety_nets"})
    assert got.safety_nets.stca_h_min_nm == 3.0


def test_serve_runs_the_safety_nets_as_a_child_by_default(monkeypatch):
    from radar_fusion.bus import FusionDaemon

    monkeypatch.delenv("RADAR_FUSION_SAFETY_NETS__PROCESS")  # the tests' own default: in process
    settings = settings_from_dict(CONFIG)
    assert settings.safety_nets.process == "child"
    daemon = FusionDaemon(settings)  # not started: no child yet
    assert daemon.safety_nets_mode == "child" and daemon.engine.safety_nets is None
    assert daemon.safety_nets_child is not None and daemon.safety_nets_child.pid is None
    assert daemon.health_message()["safety_nets"]["process"] == "child"
    inproc = FusionDaemon(settings, safety_nets="in-process")
    assert inproc.engine.safety_nets is not None and inproc.safety_nets_child is None
    external = FusionDaemon(settings, safety_nets="external")
    assert external.engine.safety_nets is None and external.safety_nets_child is None
    with pytest.raises(ValueError):
        FusionDaemon(settings, safety_nets="elsewhere")


# ------------------------------------------------------------------ read from the bytes


def many_tracks(n: int = 400, seed: int = 3) -> TrackColumns:
    """``n`` tracks of engine_columns' kinds, spread out, with big ids and odd values."""
    base = engine_columns(n=6, seed=seed)
    reps = n // 6
    rng = np.random.default_rng(seed)

    def tile(a: np.ndarray) -> np.ndarray:
        return np.concatenate([a] * reps)

    tr = TrackColumns(
        period=base.period,
        t_s=base.t_s,
        track_id=np.arange(1, 6 * reps + 1, dtype=np.int64) * 1_000_003,  # 1-, 3-, 5-byte integers
        status=tile(base.status),
        x=tile(base.x) + rng.normal(0, 3e5, (6 * reps, 6)) * [1, 0, 0, 1, 0, 0],
        cov_xy=tile(base.cov_xy),
        fl=tile(base.fl),
        vrate_fpm=tile(base.vrate_fpm),
        sources=rng.integers(0, 8, 6 * reps).astype(np.uint64),
        mode3a=tile(base.mode3a),
        mode_s=rng.integers(-1, 1 << 24, 6 * reps),
        updates=rng.integers(0, 70_000, 6 * reps),
        age_s=tile(base.age_s),
        ended=np.array([2**40, 5], np.int64),
        names=base.names,
        manoeuvre_prob=None,
    )
    return tr


def test_reading_from_the_bytes_gives_the_same_columns_as_msgpack():
    tr = many_tracks()
    payload = tr.to_msgpack()
    assert payload == msgpack.packb(tr.to_message(), use_bin_type=True)  # either packer: the same layout
    fast, general = reader(), TrackBatchReader(PLANE, RADARS, fast_min_bytes=1 << 40)
    a, b = fast.decode(payload), general.decode(payload)
    assert isinstance(a, TrackColumns) and isinstance(b, TrackColumns)
    assert fast.layout_misses == 0
    for name in (
        "track_id",
        "status",
        "x",
        "cov_xy",
        "fl",
        "vrate_fpm",
        "sources",
        "mode3a",
        "mode_s",
        "updates",
        "age_s",
        "ended",
        "lat_deg",
        "lon_deg",
    ):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)
        assert getattr(a, name).dtype == getattr(b, name).dtype, name
    assert a.manoeuvre_prob is None and b.manoeuvre_prob is None
    assert a.to_msgpack() == payload


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    flips=st.lists(st.tuples(st.integers(min_value=0), st.integers(0, 255)), min_size=1, max_size=4),
    cut=st.one_of(st.none(), st.integers(min_value=1)),
)
def test_damaged_bytes_get_the_same_verdict_on_either_path(flips, cut):
    """Bytes changed or cut anywhere: reading from the bytes never raises, and gives what
    the general path gives (the same columns, or a rejection with the same reason)."""
    payload = bytearray(many_tracks(200).to_msgpack())
    for at, value in flips:
        payload[at % len(payload)] = value
    if cut is not None:
        payload = payload[: cut % len(payload)]
    a = reader().decode(bytes(payload))
    b = TrackBatchReader(PLANE, RADARS, fast_min_bytes=1 << 40).decode(bytes(payload))
    assert type(a) is type(b)
    if isinstance(a, TrackColumns):
        assert a.to_msgpack() == b.to_msgpack()
    else:
        assert a.reason == b.reason


def test_the_safety_nets_child_does_not_load_the_compiler() -> None:
    """The safety-nets child imports the engine's column types but runs none of its
    compiled loops: numba and LLVM (~115 MB resident) stay unloaded (tracking/compiled.py
    compiles lazily), while the engine's first IMM filter does load them."""
    import subprocess
    import sys

    code = (
        "import sys\n"
        "import radar_fusion.safety_nets.process\n"
        "print('numba' in sys.modules)\n"
        "from radar_fusion.tracking.imm import IMMFilter\n"
        "IMMFilter()\n"
        "print('numba' in sys.modules)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    assert out.stdout.split() == ["False", "True"]
