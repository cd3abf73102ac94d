"""Hostile input (issue 8, item 1): the decoder, the engine's ingest and the daemon on a
real Zenoh bus are fed garbage bytes, truncated and bit-flipped msgpack, wrong types,
huge arrays, NaN/inf, negative ranges, azimuths outside [0, 360), times far in the past
or future, unknown radar ids, duplicate and out-of-order sequence numbers, oversize
payloads. Properties: nothing raises, every rejection is counted by a reason of
``wire.REJECTION_REASONS``, one bad plot never spoils the good plots of its batch, the
per-radar buffer is bounded, and good traffic sent after the hostile traffic still gives
accurate tracks. Run with ``-s`` to see how many inputs were tried."""

from __future__ import annotations

import functools
import math
import os
import tomllib
import tracemalloc
from collections import Counter

import msgpack
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from radar_fusion import wire
from radar_fusion.bus import FusionDaemon
from radar_fusion.config import settings_from_dict
from radar_fusion.engine import Engine
from radar_fusion.tools import fuzz
from radar_fusion.tools import simulate as sim
from radar_fusion.tools.replay import replay_into_engine

REASONS = set(wire.REJECTION_REASONS)
INPUTS: Counter = Counter()  # hostile messages tried, per kind; printed when the module ends
SKIPPED_VALID = [0]  # bus run: mutations that decoded as valid new data, not sent
# FUZZ_EXAMPLES=5000 pytest -s tests/test_fuzz.py: a longer run than the default one
FUZZ = settings(
    max_examples=int(os.environ.get("FUZZ_EXAMPLES", "150")),
    deadline=None,
    suppress_health_check=[HealthCheck.too_slow],
    derandomize=True,
)
SCENARIO = sim.preset("demo", seed=5, duration_s=120.0)
SIMULATION = sim.simulate(SCENARIO)
CONFIG = tomllib.loads(sim.config_toml(SCENARIO))
RADAR_IDS = [r["id"] for r in CONFIG["radars"]]
T0 = SCENARIO.start_t_s


@pytest.fixture(scope="module", autouse=True)
def report_inputs():
    yield
    detail = ", ".join(f"{name} {n}" for name, n in sorted(INPUTS.items()))
    print(
        f"\nhostile inputs tried: {sum(INPUTS.values())} ({detail}; bus mutations skipped as valid: {SKIPPED_VALID[0]})"
    )


def good_plot(t_s=T0 + 10.0, range_m=120_000.0, azimuth_deg=45.0):
    return fuzz.good_plot(t_s, range_m, azimuth_deg)


def check_decoded(d) -> None:
    """What any decoder result must satisfy: a counted reason, or plots inside the contract."""
    if isinstance(d, wire.Rejection):
        assert d.reason in REASONS
        return
    assert set(d.rejected) <= REASONS and all(n > 0 for n in d.rejected.values())
    n = len(d)
    for col in (
        d.range_m, d.azimuth_deg, d.fl, d.mode3a, d.mode_s, d.track_no, d.kind,
        d.roll_deg, d.ground_speed_mps, d.track_angle_deg, d.magnetic_heading_deg, d.indicated_airspeed_mps,
    ):  # fmt: skip
        assert col.shape == (n,)
    assert np.isfinite(d.t_s).all() and np.isfinite(d.range_m).all() and np.isfinite(d.azimuth_deg).all()
    assert ((d.t_s > 0) & (d.t_s < 1e10)).all()
    assert ((d.range_m >= 0) & (d.azimuth_deg >= 0) & (d.azimuth_deg < 360)).all()
    assert (np.isnan(d.fl) | ((d.fl >= -20) & (d.fl <= 1300))).all()
    assert (np.isnan(d.roll_deg) | ((d.roll_deg >= -90) & (d.roll_deg <= 90))).all()
    assert (np.isnan(d.ground_speed_mps) | ((d.ground_speed_mps >= 0) & (d.ground_speed_mps <= 1100))).all()
    assert (np.isnan(d.track_angle_deg) | ((d.track_angle_deg >= 0) & (d.track_angle_deg < 360))).all()
    hdg, ias = d.magnetic_heading_deg, d.indicated_airspeed_mps
    assert (np.isnan(hdg) | ((hdg >= 0) & (hdg < 360))).all()
    assert (np.isnan(ias) | ((ias > 0) & (ias <= 526.3))).all()
    assert ((d.mode3a >= -1) & (d.mode3a <= 0o7777)).all() and ((d.mode_s >= -1) & (d.mode_s < 1 << 24)).all()


# ------------------------------------------------------------------ hostile values
FLOATS = st.floats(allow_nan=True, allow_infinity=True)
SCALARS = st.one_of(
    st.none(), st.booleans(), st.integers(-(2**63), 2**64 - 1), FLOATS, st.text(max_size=12), st.binary(max_size=12)
)
ANY = st.recursive(
    SCALARS,
    lambda kids: st.one_of(st.lists(kids, max_size=4), st.dictionaries(st.text(max_size=8), kids, max_size=4)),
    max_leaves=12,
)
PLOT_FIELDS = fuzz.PLOT_FIELDS
HOSTILE_PLOT = st.one_of(
    ANY,
    st.dictionaries(st.sampled_from(PLOT_FIELDS), st.one_of(SCALARS, ANY), max_size=8),
    st.builds(lambda base, k, v: {**base, k: v}, st.just(good_plot()), st.sampled_from(PLOT_FIELDS), SCALARS),
)
HOSTILE_BATCH = st.fixed_dictionaries(
    {},
    optional={
        "v": st.one_of(st.just(1), SCALARS),
        "radar_id": st.one_of(st.sampled_from(RADAR_IDS + ["intruder", "r 1", ""]), SCALARS),
        "seq": st.one_of(st.integers(0, 50), SCALARS),
        "plots": st.one_of(st.lists(st.one_of(st.just(good_plot()), HOSTILE_PLOT), max_size=12), ANY),
        "extra": ANY,
    },
)


pack = fuzz.pack


@FUZZ
@given(st.binary(max_size=600))
def test_arbitrary_bytes_are_rejected_by_reason_never_raised(payload):
    INPUTS["decoder: random bytes"] += 1
    check_decoded(wire.decode_plot_batch(payload))
    status = wire.decode_message(payload, wire.RadarStatus)
    assert isinstance(status, wire.RadarStatus) or status.reason in REASONS


@FUZZ
@given(HOSTILE_BATCH)
def test_hostile_msgpack_structures_never_raise(obj):
    INPUTS["decoder: hostile structures"] += 1
    payload = pack(obj)
    check_decoded(wire.decode_plot_batch(payload))
    for model in (wire.RadarStatus, wire.TrackBatch, wire.Health):
        r = wire.decode_message(payload, model)
        assert isinstance(r, model) or r.reason in REASONS


@FUZZ
@given(st.lists(st.just(good_plot()), min_size=1, max_size=30), st.data())
def test_truncated_or_padded_msgpack_is_malformed(plots, data):
    INPUTS["decoder: truncated/padded"] += 2
    payload = pack({"v": 1, "radar_id": "app", "seq": 1, "plots": plots})
    cut = data.draw(st.integers(0, len(payload) - 1))
    r = wire.decode_plot_batch(payload[:cut])
    assert isinstance(r, wire.Rejection) and r.reason == "malformed_msgpack"
    tail = data.draw(st.binary(min_size=1, max_size=16))
    r = wire.decode_plot_batch(payload + tail)
    assert isinstance(r, wire.Rejection) and r.reason == "malformed_msgpack"


def test_huge_arrays_and_deep_nesting_are_refused_cheaply():
    """Refused cheaply: by the decoder's declared-size and depth limits, before anything the
    size of the claim is allocated. Measured as the peak of the Python heap while decoding
    (tracemalloc), not as wall time: ~64 KiB for the nesting (msgpack's 1024-level stack),
    ~1 KiB for the others; the MAX+2 list decoded with no array limit peaks at ~160 KiB."""
    claims = {
        "array32 of 4e9 items": b"\xdd\xff\xff\xff\xff",
        "map32 of 4e9 pairs": b"\xdf\xff\xff\xff\xff",
        "str32 of 4 GB": b"\xdb\xff\xff\xff\xff",
        "bin32 of 4 GB": b"\xc6\xff\xff\xff\xff",
        "100k nested arrays": b"\x91" * 100_000 + b"\xc0",
        "plots of MAX+2 items": pack(
            {"v": 1, "radar_id": "app", "seq": 1, "plots": [0] * (wire.MAX_PLOTS_PER_BATCH + 2)}
        ),
        "a plot with 65 keys": pack({"v": 1, "radar_id": "app", "seq": 1, "plots": [{f"k{i}": i for i in range(65)}]}),
    }
    for name, payload in claims.items():
        INPUTS["decoder: huge claims"] += 1
        tracemalloc.start()
        try:
            r = wire.decode_plot_batch(payload)
            _, peak_bytes = tracemalloc.get_traced_memory()
        finally:
            tracemalloc.stop()
        assert isinstance(r, wire.Rejection) and r.reason == "malformed_msgpack", name
        assert peak_bytes < 128 << 10, (name, peak_bytes)
    assert wire.decode_plot_batch(claims["100k nested arrays"]).detail.startswith("StackError")  # the depth limit
    big = pack({"v": 1, "radar_id": "app", "seq": 1, "plots": [good_plot()] * wire.MAX_PLOTS_PER_BATCH})
    r = wire.decode_plot_batch(big, max_bytes=len(big) - 1)
    assert isinstance(r, wire.Rejection) and r.reason == "oversize"
    d = wire.decode_plot_batch(big, max_bytes=len(big))
    assert isinstance(d, wire.DecodedPlots) and len(d) == wire.MAX_PLOTS_PER_BATCH


def test_a_batch_one_plot_over_the_limit_is_refused():
    INPUTS["decoder: huge claims"] += 1
    over = pack({"v": 1, "radar_id": "app", "seq": 1, "plots": [good_plot()] * (wire.MAX_PLOTS_PER_BATCH + 1)})
    r = wire.decode_plot_batch(over, max_bytes=len(over))
    assert isinstance(r, wire.Rejection) and r.reason in ("schema", "malformed_msgpack")


# One mutation of one field, and the reason it must be refused with.
BAD_PLOTS = [
    *[({"t": v}, "plot_non_finite") for v in (math.nan, math.inf, -math.inf)],
    *[({"range_m": v}, "plot_non_finite") for v in (math.nan, math.inf)],
    *[({"azimuth_deg": v}, "plot_non_finite") for v in (math.nan, -math.inf)],
    ({"fl": math.nan}, "plot_non_finite"),
    *[({"roll_deg": v}, "plot_non_finite") for v in (math.nan, math.inf)],
    *[({"ground_speed_mps": v}, "plot_non_finite") for v in (math.nan, math.inf)],
    *[({"track_angle_deg": v}, "plot_non_finite") for v in (math.nan, -math.inf)],
    *[({"magnetic_heading_deg": v}, "plot_non_finite") for v in (math.nan, math.inf)],
    *[({"indicated_airspeed_mps": v}, "plot_non_finite") for v in (math.nan, -math.inf)],
    *[({"range_m": v}, "plot_out_of_range") for v in (-1.0, -1e9, 2e6 + 1)],
    *[({"azimuth_deg": v}, "plot_out_of_range") for v in (360.0, 720.0, -0.001, -360.0)],
    *[({"t": v}, "plot_out_of_range") for v in (0.0, -T0, 1e10, 1e300)],
    *[({"fl": v}, "plot_out_of_range") for v in (-21.0, 1301.0)],
    *[({"roll_deg": v}, "plot_out_of_range") for v in (95.0, -90.5, 181)],
    *[({"ground_speed_mps": v}, "plot_out_of_range") for v in (-0.5, -1, 1100.5, 2000)],
    *[({"track_angle_deg": v}, "plot_out_of_range") for v in (360.0, 360, -0.1, 720.0)],
    *[({"magnetic_heading_deg": v}, "plot_out_of_range") for v in (360.0, 360, -0.1, -180)],
    *[({"indicated_airspeed_mps": v}, "plot_out_of_range") for v in (0.0, 0, -0.0, -5.0, 526.4, 1023)],
    *[({"mode3a": v}, "plot_out_of_range") for v in (-1, 0o10000, 2**64 - 1)],
    *[({"mode_s": v}, "plot_out_of_range") for v in ("XYZ123", "4CA1F", "4CA1F3F", "")],
    *[({"track_no": v}, "plot_out_of_range") for v in (-1, 2**32)],
    *[({"range_m": v}, "plot_schema") for v in ("120000", None, True, [1.0], {"m": 1.0}, b"\x00")],
    *[({"t": v}, "plot_schema") for v in ("2018-08-01T08:00:00Z", None, False)],
    *[({"mode3a": v}, "plot_schema") for v in (True, 12.5, "1234")],
    ({"mode_s": 0x4CA1F3}, "plot_schema"),
    ({"track_no": 1.5}, "plot_schema"),
    *[({"roll_deg": v}, "plot_schema") for v in ("12.5", True, [1.0])],
    *[({"ground_speed_mps": v}, "plot_schema") for v in ("231", False, {"kt": 450})],
    *[({"track_angle_deg": v}, "plot_schema") for v in ("090", True, [90.0])],
    *[({"magnetic_heading_deg": v}, "plot_schema") for v in ("270", False, {"deg": 270.0})],
    *[({"indicated_airspeed_mps": v}, "plot_schema") for v in ("128.6", True, [128.6])],
    ({"kind": "laser"}, "plot_schema"),
    ({"kind": 1}, "plot_schema"),
]


@FUZZ
@given(
    st.lists(st.tuples(st.floats(1.0, 400_000.0), st.floats(0.0, 359.999)), min_size=1, max_size=25),
    st.lists(
        st.one_of(
            st.sampled_from(BAD_PLOTS),
            st.sampled_from(["t", "range_m", "azimuth_deg"]).map(lambda f: ("missing", f)),
            st.sampled_from([None, 7, "plot", [1, 2], b"\x01"]).map(lambda v: ("not a map", v)),
        ),
        max_size=10,
    ),
    st.randoms(use_true_random=False),
)
def test_one_bad_plot_never_spoils_the_good_plots_of_its_batch(goods, bads, rnd):
    INPUTS["decoder: good+bad plot batches"] += 1
    plots = [("good", good_plot(T0 + i, r, a)) for i, (r, a) in enumerate(goods)]
    expected: Counter = Counter()
    for bad in bads:
        if bad[0] == "missing":
            p = good_plot()
            del p[bad[1]]
            plots.append(("bad", p))
            expected["plot_schema"] += 1
        elif bad[0] == "not a map":
            plots.append(("bad", bad[1]))
            expected["plot_schema"] += 1
        else:
            mutation, reason = bad
            plots.append(("bad", {**good_plot(), **mutation}))
            expected[reason] += 1
    rnd.shuffle(plots)
    d = wire.decode_plot_batch(pack({"v": 1, "radar_id": "app", "seq": 9, "plots": [p for _, p in plots]}))
    assert isinstance(d, wire.DecodedPlots)
    check_decoded(d)
    assert d.rejected == dict(expected)
    good_in_order = [p for kind, p in plots if kind == "good"]
    assert d.t_s.tolist() == [p["t"] for p in good_in_order]
    assert d.range_m.tolist() == [p["range_m"] for p in good_in_order]
    assert d.azimuth_deg.tolist() == [p["azimuth_deg"] for p in good_in_order]


# ------------------------------------------------------------------ the engine
ENGINE_SETTINGS = settings_from_dict({**CONFIG, "system": {**CONFIG["system"], "max_buffered_plots_per_radar": 60}})
OFFSETS_S = st.one_of(
    st.floats(-20.0, 200.0),  # ordinary traffic
    st.floats(-T0 + 1.0, -3600.0),  # far in the past (down to 1970)
    st.floats(3600.0, 9.99e9 - T0),  # far in the future (up to the contract's limit)
    st.sampled_from([-1e-6, 59.9, 60.1, 1e6]),
)
ENGINE_PLOT = st.builds(
    lambda dt, r, a, key: {
        "t": T0 + dt,
        "range_m": r,
        "azimuth_deg": a,
        "fl": 300.0,
        "track_no": key,
        "mode_s": None if key is None else f"{key:06X}",
    },
    OFFSETS_S,
    st.one_of(st.floats(0.0, 600_000.0), st.sampled_from([-5.0, math.nan, math.inf, 1e7])),
    st.one_of(st.floats(0.0, 359.999), st.sampled_from([360.0, -1.0, 1e4, math.nan])),
    st.one_of(st.none(), st.integers(0, 40)),
)
EVENT = st.one_of(
    st.tuples(
        st.just("plots"),
        st.sampled_from(RADAR_IDS + ["intruder"]),
        st.integers(0, 12),
        st.lists(ENGINE_PLOT, max_size=40),
    ),
    st.tuples(
        st.just("status"),
        st.sampled_from(RADAR_IDS + ["intruder"]),
        OFFSETS_S,
        st.sampled_from(["north", "sector", "heartbeat"]),
    ),
)
ENGINE_PLOT_REASONS = ("plot_beyond_max_range", "plot_late", "plot_future", "buffer_full")


@FUZZ
@given(st.lists(EVENT, min_size=1, max_size=30))
def test_engine_ingest_of_hostile_batches_never_raises_and_accounts_for_every_plot(events):
    INPUTS["engine: messages (in sequences of 1-30)"] += len(events)
    engine = Engine(ENGINE_SETTINGS)
    outputs, decoder_rejected = [], Counter()
    for kind, radar_id, a, b in events:
        if kind == "plots":
            d = wire.decode_plot_batch(pack({"v": 1, "radar_id": radar_id, "seq": a, "plots": b}))
            check_decoded(d)
            decoder_rejected.update(d.rejected)
            engine.ingest_plots(d)
        else:
            s = wire.decode_message(pack({"v": 1, "radar_id": radar_id, "t": T0 + a, "kind": b}), wire.RadarStatus)
            if isinstance(s, wire.Rejection):
                assert s.reason in REASONS
                engine.reject(s.reason)
            else:
                engine.ingest_status(s)
        outputs += engine.poll()
        assert engine.buffer.buffered_plots <= len(RADAR_IDS) * 60
    outputs += engine.flush()
    h = engine.health()
    rejected, counters = h["rejected"], h["counters"]
    assert set(rejected) <= REASONS
    # every plot that reached the engine was accepted or refused by a counted reason
    assert counters.get("plots_received", 0) == counters.get("plots_accepted", 0) + sum(
        rejected.get(r, 0) for r in ENGINE_PLOT_REASONS
    )
    for reason, n in decoder_rejected.items():
        assert rejected.get(reason, 0) == n
    periods = [o.period for o in outputs]
    assert periods == sorted(set(periods))
    for o in outputs:
        batch = wire.TrackBatch.model_validate(o.track_batch)  # finite, typed, as the contract says
        # at the batch's time, or (one update, no velocity yet) at its measurement time before it
        assert all(t.t == batch.t or (t.vx_mps is None and t.vy_mps is None and t.t <= batch.t) for t in batch.tracks)


@functools.cache
def _clean_plots_accepted() -> int:
    engine = Engine(settings_from_dict(CONFIG))
    replay_into_engine(engine, SIMULATION.messages)
    return engine.counters["plots_accepted"]


def _with_extra_plot(messages, nth_batch: int, dt_s: float):
    """The messages with one extra plot, ``dt_s`` after the first plot of the n-th
    non-empty plot batch (same radar, same aircraft otherwise)."""
    out, seen = list(messages), 0
    for j, (t_s, key, payload) in enumerate(out):
        obj = msgpack.unpackb(payload) if key.endswith("/plots") else None
        if obj and obj["plots"]:
            seen += 1
            if seen == nth_batch:
                obj["plots"].append(dict(obj["plots"][0], t=obj["plots"][0]["t"] + dt_s))
                out[j] = (t_s, key, pack(obj))
                return out
    raise AssertionError("not enough plot batches")


@pytest.mark.parametrize(
    "nth_batch, dt_s",
    [(1, 1e9), (1, 50.0), (40, 50.0)],
    ids=["first batch, +1e9 s", "first batch, +50 s", "40th batch, +50 s"],
)
def test_one_plot_far_in_the_future_does_not_make_the_other_radars_late(nth_batch, dt_s):
    """One plot of a radar far ahead of the others (a clock jump, a forged time) is
    refused as plot_future. Accepted, it would push that radar's watermark more than
    radar_timeout_s past the others, which would then count as silent: every period would
    close on that one radar and all their good plots would become late."""
    INPUTS["engine: clock-jump replays"] += 1
    engine = Engine(settings_from_dict(CONFIG))
    replay_into_engine(engine, _with_extra_plot(SIMULATION.messages, nth_batch, dt_s))
    assert engine.counters["plots_accepted"] == _clean_plots_accepted()
    assert dict(engine.rejected) == {"plot_future": 1}


@pytest.mark.parametrize("range_m", [5e-324, 1e-300, 1e-9, 0.0])
def test_a_plot_at_the_antenna_without_mode_c_makes_no_track_that_is_not_finite(range_m):
    """A schema-valid plot a hair from the antenna with no Mode C: its cross-range variance
    (g σ_θ)² was ~0 against the range's, its covariance singular and its track's position
    NaN; a consumer refuses a batch with one such track, and every other track with it."""
    INPUTS["engine: plots at the antenna"] += 1
    from radar_fusion.wire import DecodedPlots

    radars = [
        {
            "id": rid,
            "lat": 46.0 + 0.2 * k,
            "lon": 8.0 - 0.2 * k,
            "sigma_range_m": 50,
            "sigma_azimuth_deg": 0.1,
            "rotation_period_s": 4.0,
        }
        for k, rid in enumerate("ab")
    ]
    engine = Engine(
        settings_from_dict({"system": {"center_lat": 46.0, "center_lon": 8.0, "period_s": 4.0}, "radars": radars})
    )
    t0 = 1_533_110_400.0

    def batch(rid, seq, t, rng, fl):
        nan = np.full(1, np.nan)
        return DecodedPlots(
            rid,
            seq,
            np.full(1, t),
            np.full(1, rng),
            np.full(1, 45.0),
            np.full(1, fl),
            np.full(1, -1),
            np.full(1, -1),
            np.full(1, -1),
            np.zeros(1, np.int8),
            nan.copy(),
        )

    shown = 0
    for k in range(12):
        engine.ingest_plots(batch("a", k, t0 + 4 * k + 1.0, range_m, np.nan))
        engine.ingest_plots(batch("b", k, t0 + 4 * k + 2.0, 50_000.0, 350.0))
        for out in engine.poll():
            cols = out.track_columns
            assert np.isfinite(cols.x_m).all() and np.isfinite(cols.y_m).all() and np.isfinite(cols.cov_xy).all()
            shown += len(cols.x_m)
    assert shown > 0 and not engine.counters.get("tracks_ended_not_finite")


def test_a_status_far_in_the_future_does_not_make_the_engine_close_every_empty_period():
    """One status from a radar not heard before, 2,000 s ahead (a clock jump), neither
    moves the period clock nor makes the engine close the 500 empty periods in between
    one at a time (1e9 s ahead, still inside the contract, that would take days and the
    daemon's only processing thread with it)."""
    INPUTS["engine: status clock jump"] += 1
    engine = Engine(settings_from_dict(CONFIG))
    engine.ingest_plots(wire.decode_plot_batch(pack({"v": 1, "radar_id": "app", "seq": 0, "plots": [good_plot(T0)]})))
    engine.ingest_status(wire.RadarStatus(radar_id="east", t=T0 + 2000.0, kind="north"))
    outputs = engine.poll()
    assert len(outputs) <= 20, f"{len(outputs)} periods closed"


def test_a_flooding_radar_is_bounded_per_radar_and_does_not_starve_the_others():
    limit = 500
    engine = Engine(
        settings_from_dict({**CONFIG, "system": {**CONFIG["system"], "max_buffered_plots_per_radar": limit}})
    )
    flood, quiet = RADAR_IDS[0], RADAR_IDS[1]

    def batch(radar_id, seq, t_s, n):
        plots = [good_plot(t_s, 100_000.0 + 10.0 * k, (7.0 * k) % 360.0) for k in range(n)]
        return wire.decode_plot_batch(pack({"v": 1, "radar_id": radar_id, "seq": seq, "plots": plots}))

    t_s = math.floor(T0 / 4.0) * 4.0 + 1.0
    engine.ingest_plots(batch(quiet, 0, t_s, 5))  # the quiet radar holds the period open
    for seq in range(20):  # 2,000 plots at one time: the period cannot close
        INPUTS["engine: flood batches"] += 1
        engine.ingest_plots(batch(flood, seq, t_s, 100))
        engine.poll()
    assert engine.buffer.buffered_plots == limit + 5
    assert engine.rejected["buffer_full"] == 2000 - limit
    assert engine.radars[0].rejected["buffer_full"] == 2000 - limit and not engine.radars[1].rejected
    assert engine.ingest_plots(batch(quiet, 1, t_s + 0.5, 5)) == 5  # the others are not starved
    # once the quiet radar moves on, the period closes, the buffer drains, plots flow again
    engine.ingest_plots(batch(quiet, 2, t_s + 8.0, 1))
    # still full: this plot is refused, but it moves the flooding radar's watermark on
    assert engine.ingest_plots(batch(flood, 20, t_s + 8.0, 1)) == 0
    outputs = engine.poll()
    assert outputs and sum(o.n_plots for o in outputs) >= limit + 10 - 100  # wild-gated plots aside
    assert engine.buffer.buffered_plots == 1
    assert engine.ingest_plots(batch(flood, 21, t_s + 8.5, 100)) == 100


def test_an_internal_error_is_counted_by_a_listed_reason():
    daemon = FusionDaemon(settings_from_dict(CONFIG))  # not started: the processing path only

    def broken(_batch):
        raise RuntimeError("bug")

    daemon.engine.ingest_plots = broken
    daemon._process_safely("atc/radar/app/plots", pack({"v": 1, "radar_id": "app", "seq": 0, "plots": []}))
    assert daemon.messages_processed == 1
    assert set(daemon.engine.rejected) <= REASONS


def test_a_bug_while_decoding_is_counted_and_the_next_message_goes_on(monkeypatch):
    daemon = FusionDaemon(settings_from_dict(CONFIG))  # not started: the processing path only
    good = pack({"v": 1, "radar_id": "app", "seq": 0, "plots": []})

    def broken(*_args, **_kwargs):
        raise RuntimeError("bug")

    monkeypatch.setattr("radar_fusion.bus.decode_plot_batch", broken)
    daemon._process_safely("atc/radar/app/plots", good)
    assert daemon.engine.rejected == Counter(internal_error=1)
    monkeypatch.undo()
    daemon._process_safely("atc/radar/app/plots", good)
    assert daemon.messages_processed == 2
    assert daemon.engine.counters["batches_received"] == 1
    assert set(daemon.engine.rejected) <= REASONS


# ------------------------------------------------------------------ over the bus
# The generator and the run live in tools/fuzz.py; `radar-fusion fuzz --count 100000` is the
# long run (issue 13), outside the default suite.
N_HOSTILE = 2000


@pytest.mark.bus
def test_daemon_survives_hostile_bus_traffic_and_keeps_tracking(free_port):
    r = fuzz.run_bus(N_HOSTILE, seed=20240808, port=free_port)
    INPUTS.update({f"bus: {cat}": n for cat, n in r.categories.items()})
    SKIPPED_VALID[0] += r.skipped_valid
    print(f"\nbus: {r.n_hostile} hostile + {r.n_good} good messages; rejected: {dict(sorted(r.rejected.items()))}")
    assert r.n_hostile == N_HOSTILE
    assert r.thread_alive and r.messages_received == r.extra["traffic"]
    assert fuzz.failures(r) == []


def test_the_fuzz_checks_fail_on_a_lost_message_an_unlisted_reason_or_a_dead_thread():
    """tools/fuzz.failures on a run that went well, then with one thing wrong at a time."""
    import dataclasses

    from radar_fusion.tools.fuzz import BusFuzzResult, failures

    ok = BusFuzzResult(
        n_hostile=10,
        n_good=100,
        skipped_valid=0,
        categories={"random bytes": 10},
        messages_received=110,
        thread_alive=True,
        rejected={"malformed_msgpack": 10},
        replica_rejected={"malformed_msgpack": 10},
        expected_oversize=0,
        expected_unknown_radar_min=0,
        plots_accepted=500,
        good_plots=500,
        radar_batches={"app": (50, 50, 0)},
        batches_published=30,
        batches_collected=30,
        max_confirmed_after=12,
        pos_rms_settled_m=80.0,
        wall_s=1.0,
        extra={"traffic": 110},
    )
    assert failures(ok) == []
    for change in (
        {"messages_received": 109},
        {"thread_alive": False},
        {"rejected": {"malformed_msgpack": 9, "made_up": 1}},
        {"rejected": {"malformed_msgpack": 9}},
        {"plots_accepted": 499},
        {"radar_batches": {"app": (50, 50, 1)}},
        {"pos_rms_settled_m": 250.0},
    ):
        assert failures(dataclasses.replace(ok, **change)), change
