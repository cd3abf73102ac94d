"""Columnar plot validation (wire_columns.py, issue 16 item 1) and the bytes fast path
(wire_bytes.py) against the model (wire.Plot).

The property: for any PlotBatch payload, ``decode_plot_batch`` (the bytes, else the columns) and
``decode_plot_batch_by_model`` (wire.Plot, one plot at a time) give the same rejection,
or the same accepted plots (every column, bit for bit) and the same rejections by
reason. The generated plots are mostly near the contract's edges (boundary values, NaN,
±inf, out of range, bad Mode S strings and kinds) with every other type mixed in (bools,
huge integers, floats for integers, strings, bytes, nested lists and maps, missing and
extra fields, non-map plots, unicode); then realistic batches of the simulator, clean and
corrupted; and every payload also encoded the other ways msgpack allows (float32, wide
integers, str8/16/32, map16/32, array16/32), which the bytes parser reads itself.
FUZZ_EXAMPLES=5000 runs a longer search.
"""

from __future__ import annotations

import contextlib
import math
import os
import random
import struct
from collections import Counter

import msgpack
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from radar_fusion import wire
from radar_fusion.tools import simulate as sim
from radar_fusion.wire_bytes import decode_plot_batch_bytes
from radar_fusion.wire_columns import validate_plot_columns

EXAMPLES = settings(
    max_examples=int(os.environ.get("FUZZ_EXAMPLES", "400")),
    deadline=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
    derandomize=True,
)
COLUMNS = (
    "t_s", "range_m", "azimuth_deg", "fl", "mode3a", "mode_s", "track_no", "kind",
    "roll_deg", "ground_speed_mps", "track_angle_deg", "magnetic_heading_deg", "indicated_airspeed_mps",
)  # fmt: skip
SEEN: Counter = Counter()  # what the generated plots exercised; printed at the end (-s)


@pytest.fixture(scope="module", autouse=True)
def report_seen():
    yield
    print("\ncolumnar validation, plots tried:", dict(sorted(SEEN.items())))


def same_result(payload: bytes) -> wire.DecodedPlots | wire.Rejection:
    """Decode by columns (however few the plots), as the daemon does, and by the model;
    assert they agree; return the columnar result."""
    ref = wire.decode_plot_batch_by_model(payload)
    SEEN["read from the bytes" if decode_plot_batch_bytes(payload) is not None else "handed back"] += 1
    for fast in (wire.decode_plot_batch(payload), wire.decode_plot_batch(payload, columns_from=0)):
        if isinstance(ref, wire.Rejection):
            assert fast == ref
            continue
        assert isinstance(fast, wire.DecodedPlots)
        assert (fast.radar_id, fast.seq) == (ref.radar_id, ref.seq)
        assert fast.rejected == ref.rejected
        for name in COLUMNS:
            a, b = getattr(fast, name), getattr(ref, name)
            assert a.dtype == b.dtype and a.shape == b.shape, name
            assert a.tobytes() == b.tobytes(), (name, a, b)  # bit for bit: -0.0, NaN for absent
    return fast


def pack(obj) -> bytes:
    return msgpack.packb(obj, use_bin_type=True)


def pack_other_ways(obj, rng: random.Random) -> bytes:
    """``obj`` in msgpack, each value in a form drawn at random among those msgpack allows
    for it (msgpack-python packs the shortest): integers in any wider int/uint, floats
    as float32 where exact, str in str8/16/32, maps and arrays in their 16/32 forms."""
    out = bytearray()

    def header(n: int, fix: int, fix_max: int, w8: int | None, w16: int, w32: int) -> None:
        forms = ([fix | n] if n <= fix_max else []) + ([w8] if w8 is not None and n < 256 else [])
        forms += [w16] if n < 65536 else []
        choice = rng.choice(forms + [w32])
        if choice == w8:
            out.extend(bytes([w8, n]))
        elif choice == w16:
            out.extend(bytes([w16]) + struct.pack(">H", n))
        elif choice == w32:
            out.extend(bytes([w32]) + struct.pack(">I", n))
        else:
            out.append(choice)

    def put(v) -> None:
        if v is None or isinstance(v, bool):
            out.extend(msgpack.packb(v))
        elif isinstance(v, int):
            forms = [msgpack.packb(v)]
            for code, fmt in ((0xCC, ">B"), (0xCD, ">H"), (0xCE, ">I"), (0xCF, ">Q"), (0xD0, ">b"), (0xD1, ">h"),
                              (0xD2, ">i"), (0xD3, ">q")):  # fmt: skip
                with contextlib.suppress(struct.error):  # v does not fit this form
                    forms.append(bytes([code]) + struct.pack(fmt, v))
            out.extend(rng.choice(forms))
        elif isinstance(v, float):
            forms = [b"\xcb" + struct.pack(">d", v)]
            f32 = struct.pack(">f", v) if abs(v) < 3e38 or not math.isfinite(v) else None
            if f32 is not None and (struct.unpack(">f", f32)[0] == v or math.isnan(v)):
                forms.append(b"\xca" + f32)
            out.extend(rng.choice(forms))
        elif isinstance(v, str):
            raw = v.encode()
            header(len(raw), 0xA0, 31, 0xD9, 0xDA, 0xDB)
            out.extend(raw)
        elif isinstance(v, (bytes, bytearray)):
            out.extend(msgpack.packb(bytes(v), use_bin_type=True))
        elif isinstance(v, (list, tuple)):
            header(len(v), 0x90, 15, None, 0xDC, 0xDD)
            for x in v:
                put(x)
        elif isinstance(v, dict):
            header(len(v), 0x80, 15, None, 0xDE, 0xDF)
            for k, x in v.items():
                put(k)
                put(x)
        else:
            raise TypeError(type(v))

    put(obj)
    return bytes(out)


def batch(plots, **kw) -> bytes:
    return pack({"v": 1, "radar_id": "r1", "seq": 7, "plots": plots, **kw})


# ---------------------------------------------------------------- generated values
TEXT = st.text(st.characters(exclude_categories=("Cs",)), max_size=8)
HEXISH = st.text("0123456789abcdefABCDEFgxX \n٤４", min_size=4, max_size=8)
BIG_INTS = st.sampled_from([-(2**63), -1, 2**31, 2**32 - 1, 2**32, 2**53 + 1, 2**63 - 1, 2**63, 2**64 - 1])
EXOTIC = st.one_of(
    st.none(),
    st.booleans(),
    st.integers(-(2**63), 2**64 - 1),
    BIG_INTS,
    st.floats(allow_nan=True, allow_infinity=True),
    TEXT,
    st.binary(max_size=6),
    st.lists(st.integers(0, 9), max_size=3),
    st.dictionaries(st.text(max_size=3), st.integers(0, 9), max_size=2),
)


def edges(*values: float) -> st.SearchStrategy:
    """Each bound, and the nearest floats either side of it."""
    around = [x for v in values for x in (v, math.nextafter(v, -math.inf), math.nextafter(v, math.inf))]
    return st.sampled_from(around + [-0.0, math.nan, math.inf, -math.inf])


def valid_number(lo: float, hi: float, exclude_min: bool = False, exclude_max: bool = False) -> st.SearchStrategy:
    ints = st.integers(int(math.floor(lo)) + (1 if exclude_min else 0), int(math.ceil(hi)) - (1 if exclude_max else 0))
    return st.one_of(st.floats(lo, hi, exclude_min=exclude_min, exclude_max=exclude_max), ints)


HEX6 = st.text("0123456789abcdefABCDEF", min_size=6, max_size=6)
# values the contract accepts, edges included
VALID = {
    "t": valid_number(0.0, 1e10, exclude_min=True, exclude_max=True),
    "range_m": st.one_of(valid_number(0.0, 2e6), st.just(-0.0)),
    "azimuth_deg": valid_number(0.0, 360.0, exclude_max=True),
    "fl": valid_number(-20.0, 1300.0),
    "mode3a": st.integers(0, 0o7777),
    "mode_s": HEX6,
    "track_no": st.integers(0, 2**32 - 1),
    "kind": st.sampled_from(wire.PLOT_KINDS),
    "roll_deg": valid_number(-90.0, 90.0),
    "ground_speed_mps": st.one_of(valid_number(0.0, 1100.0), st.just(-0.0)),
    "track_angle_deg": valid_number(0.0, 360.0, exclude_max=True),
    "magnetic_heading_deg": valid_number(0.0, 360.0, exclude_max=True),
    "indicated_airspeed_mps": st.one_of(st.floats(0.0, 526.3, exclude_min=True), st.integers(1, 526)),
}
# values near the edges and of every other type
HOSTILE = {
    "t": st.one_of(edges(0.0, 1e10), EXOTIC),
    "range_m": st.one_of(edges(0.0, 2e6), st.integers(-10, 2_000_010), EXOTIC),
    "azimuth_deg": st.one_of(edges(0.0, 360.0), st.floats(-720, 720), EXOTIC),
    "fl": st.one_of(edges(-20.0, 1300.0), st.integers(-100, 2000), EXOTIC),
    "mode3a": st.one_of(st.integers(-5, 0o7777 + 5), BIG_INTS, st.floats(0, 4095), EXOTIC),
    "mode_s": st.one_of(HEXISH, EXOTIC),
    "track_no": st.one_of(BIG_INTS, EXOTIC),
    "kind": st.one_of(st.sampled_from(["PSR", "ssr ", "", "mode_s", "psr\x00"]), EXOTIC),
    "roll_deg": st.one_of(edges(-90.0, 90.0), st.integers(-100, 100), EXOTIC),
    "ground_speed_mps": st.one_of(edges(0.0, 1100.0), st.integers(-10, 1110), EXOTIC),
    "track_angle_deg": st.one_of(edges(0.0, 360.0), st.floats(-720, 720), st.integers(-5, 365), EXOTIC),
    "magnetic_heading_deg": st.one_of(edges(0.0, 360.0), st.floats(-720, 720), st.integers(-5, 365), EXOTIC),
    "indicated_airspeed_mps": st.one_of(edges(0.0, 526.3), st.integers(-10, 540), EXOTIC),
}
REQUIRED = ("t", "range_m", "azimuth_deg")


@st.composite
def plots(draw) -> object:
    """A valid plot (optional fields absent or present), then none to three faults: a
    hostile value, a removed field, an unknown or bytes key; or not a map at all."""
    if draw(st.integers(0, 19)) == 0:
        return draw(EXOTIC)
    p: dict = {}
    for name, values in VALID.items():
        if name in REQUIRED or draw(st.booleans()):
            p[name] = draw(values)
    for _ in range(draw(st.sampled_from([0, 0, 0, 1, 1, 2, 3]))):
        name = draw(st.sampled_from(sorted(VALID)))
        fault = draw(st.integers(0, 9))
        if fault == 0:
            p.pop(name, None)
        elif fault == 1:
            p[draw(st.one_of(TEXT, st.just(b"t")))] = draw(EXOTIC)  # unknown fields are ignored
        else:
            p[name] = draw(HOSTILE[name])
    return p


@EXAMPLES
@given(st.lists(plots(), max_size=25), st.randoms(use_true_random=False))
def test_columns_and_model_agree_on_any_plots(plot_list, rng):
    same_result(pack_other_ways({"v": 1, "radar_id": "r1", "seq": 7, "plots": plot_list}, rng))
    d = same_result(batch(plot_list))
    assert isinstance(d, wire.DecodedPlots)
    assert len(d) + sum(d.rejected.values()) == len(plot_list)  # every plot accepted or counted
    SEEN["plots"] += len(plot_list)
    SEEN["accepted"] += len(d)
    for reason, n in d.rejected.items():
        SEEN[reason] += n


@EXAMPLES
@given(st.lists(st.fixed_dictionaries({k: st.one_of(VALID[k], HOSTILE[k]) for k in REQUIRED}), max_size=40))
def test_columns_and_model_agree_on_well_typed_numbers(plot_list):
    """Required numbers only, every combination of the edges: the columns' own verdicts."""
    same_result(batch(plot_list))


@EXAMPLES
@given(
    st.fixed_dictionaries(
        {},
        optional={
            "v": st.one_of(st.just(1), EXOTIC),
            "radar_id": st.one_of(st.sampled_from(["r1", "r 1", "", "x" * 33]), EXOTIC),
            "seq": st.one_of(st.integers(0, 9), BIG_INTS, EXOTIC),
            "plots": st.one_of(st.lists(plots(), max_size=5), EXOTIC),
            "extra": EXOTIC,
        },
    )
)
def test_columns_and_model_agree_on_whole_messages(message):
    same_result(pack(message))
    same_result(pack_other_ways(message, random.Random(len(message))))


@EXAMPLES
@given(
    st.lists(
        st.fixed_dictionaries(
            {k: VALID[k] for k in REQUIRED}, optional={k: v for k, v in VALID.items() if k not in REQUIRED}
        ),
        max_size=30,
    ),
    st.randoms(use_true_random=False),
)
def test_the_bytes_path_reads_every_valid_batch_however_encoded(plot_list, rng):
    """A batch the contract accepts whole is read from its bytes, in any encoding, with
    the model's values."""
    for payload in (
        batch(plot_list),
        pack_other_ways({"seq": 2**63 - 1, "radar_id": "r_1.x-Y", "plots": plot_list, "v": 1}, rng),
    ):
        assert decode_plot_batch_bytes(payload) is not None
        d = same_result(payload)
        assert len(d) == len(plot_list) and d.rejected == {}


# ------------------------------------------------------------------------ examples
def full_plot(**kw):
    p = {
        "t": 1.7e9,
        "range_m": 120_000.0,
        "azimuth_deg": 45.0,
        "fl": 350.0,
        "mode3a": 0o1234,
        "mode_s": "4ca1F3",
        "track_no": 17,
        "kind": "cmb",
        "roll_deg": -12.5,
        "ground_speed_mps": 231.5,
        "track_angle_deg": 272.8125,
        "magnetic_heading_deg": 268.59375,
        "indicated_airspeed_mps": 128.6,
    }
    p.update(kw)
    return p


@pytest.mark.parametrize(
    "bad, reason",
    [
        ({"t": math.nan}, "plot_non_finite"),
        ({"fl": math.inf}, "plot_non_finite"),
        ({"fl": math.nan, "range_m": -1.0}, "plot_non_finite"),  # non-finite before out of range
        ({"t": 0.0}, "plot_out_of_range"),
        ({"t": 1e10}, "plot_out_of_range"),
        ({"azimuth_deg": 360.0}, "plot_out_of_range"),
        ({"range_m": 2_000_001}, "plot_out_of_range"),
        ({"fl": -20.5}, "plot_out_of_range"),
        ({"mode3a": 0o10000}, "plot_out_of_range"),
        ({"track_no": 2**64 - 1}, "plot_out_of_range"),
        ({"mode_s": "4CA1F"}, "plot_out_of_range"),
        ({"mode_s": "4CA1F3\n"}, "plot_out_of_range"),  # the model's regex: $ is the end of the text
        ({"mode_s": "4CA1F٣"}, "plot_out_of_range"),  # a non-ASCII digit
        ({"kind": "PSR"}, "plot_schema"),
        ({"kind": "laser", "mode_s": "nothex"}, "plot_out_of_range"),  # out of range before schema
        ({"roll_deg": math.nan}, "plot_non_finite"),
        ({"roll_deg": -math.inf, "fl": 5000.0}, "plot_non_finite"),
        ({"roll_deg": 95.0}, "plot_out_of_range"),
        ({"roll_deg": -90.5}, "plot_out_of_range"),
        ({"roll_deg": math.nextafter(90.0, math.inf)}, "plot_out_of_range"),
        ({"roll_deg": -91}, "plot_out_of_range"),
        ({"roll_deg": 91, "kind": "laser"}, "plot_out_of_range"),
        ({"ground_speed_mps": math.nan}, "plot_non_finite"),
        ({"ground_speed_mps": math.inf, "track_angle_deg": 400.0}, "plot_non_finite"),
        ({"ground_speed_mps": -0.5}, "plot_out_of_range"),
        ({"ground_speed_mps": math.nextafter(1100.0, math.inf)}, "plot_out_of_range"),
        ({"ground_speed_mps": 1101}, "plot_out_of_range"),
        ({"track_angle_deg": -math.inf}, "plot_non_finite"),
        ({"track_angle_deg": 360.0}, "plot_out_of_range"),
        ({"track_angle_deg": 360}, "plot_out_of_range"),
        ({"track_angle_deg": math.nextafter(0.0, -math.inf)}, "plot_out_of_range"),
        ({"track_angle_deg": -1, "kind": "laser"}, "plot_out_of_range"),
        ({"magnetic_heading_deg": math.nan}, "plot_non_finite"),
        ({"magnetic_heading_deg": 360.0}, "plot_out_of_range"),
        ({"magnetic_heading_deg": math.nextafter(0.0, -math.inf)}, "plot_out_of_range"),
        ({"magnetic_heading_deg": -90, "kind": "laser"}, "plot_out_of_range"),
        ({"indicated_airspeed_mps": -math.inf}, "plot_non_finite"),
        ({"indicated_airspeed_mps": 0.0}, "plot_out_of_range"),
        ({"indicated_airspeed_mps": -0.0}, "plot_out_of_range"),
        ({"indicated_airspeed_mps": 0}, "plot_out_of_range"),
        ({"indicated_airspeed_mps": math.nextafter(526.3, math.inf)}, "plot_out_of_range"),
        ({"indicated_airspeed_mps": 527, "magnetic_heading_deg": 400.0}, "plot_out_of_range"),
    ],
)
def test_faults_of_well_typed_plots_are_judged_by_the_columns(bad, reason):
    plot_list = [
        full_plot(),
        full_plot(**bad),
        full_plot(
            azimuth_deg=0.0,
            fl=None,
            mode_s=None,
            kind=None,
            roll_deg=None,
            ground_speed_mps=None,
            track_angle_deg=None,
            magnetic_heading_deg=None,
            indicated_airspeed_mps=None,
        ),
    ]
    c = validate_plot_columns(msgpack.unpackb(pack(plot_list), raw=False))
    assert c.by_model == 0 and c.rejected == {reason: 1}
    assert c.azimuth_deg.tolist() == [45.0, 0.0]
    same_result(batch(plot_list))


@pytest.mark.parametrize(
    "bad",
    [
        {"t": True},
        {"t": None},
        {"range_m": "120000"},
        {"mode3a": 12.0},
        {"mode_s": b"4CA1F3"},
        {"kind": ["psr"]},
        {"fl": {"value": 350.0}},
        {"roll_deg": "level"},
        {"roll_deg": False},
        {"roll_deg": b"\x00"},
        {"ground_speed_mps": "231"},
        {"ground_speed_mps": True},
        {"track_angle_deg": [90.0]},
        {"track_angle_deg": False},
        {"magnetic_heading_deg": "270"},
        {"magnetic_heading_deg": True},
        {"indicated_airspeed_mps": [128.6]},
        {"indicated_airspeed_mps": b"\x01"},
    ],
)
def test_other_types_go_to_the_model_and_get_its_reason(bad):
    plot_list = [full_plot(), full_plot(**bad), "not a plot", full_plot(t=math.nan, range_m="x")]
    c = validate_plot_columns(msgpack.unpackb(pack(plot_list), raw=False))
    assert c.by_model == 3 and len(c.t_s) == 1
    assert c.rejected == {"plot_schema": 2, "plot_non_finite": 1}
    same_result(batch(plot_list))


def test_accepted_values_are_those_of_the_model():
    plot_list = [
        full_plot(
            t=1_700_000_000,
            range_m=0,
            azimuth_deg=359.99999999999994,
            fl=-20,
            mode3a=0,
            track_no=2**32 - 1,
            roll_deg=90,
            ground_speed_mps=1100,
            track_angle_deg=math.nextafter(360.0, 0.0),
            magnetic_heading_deg=math.nextafter(360.0, 0.0),
            indicated_airspeed_mps=526.3,
        ),
        full_plot(
            range_m=-0.0,
            fl=None,
            mode3a=None,
            mode_s="00000a",
            track_no=None,
            kind="modes",
            roll_deg=-0.0,
            ground_speed_mps=-0.0,
            track_angle_deg=0,
            magnetic_heading_deg=-0.0,
            indicated_airspeed_mps=math.nextafter(0.0, math.inf),
        ),
        {"t": 1.5, "range_m": 2_000_000.0, "azimuth_deg": 0, "unknown": [1, {"x": None}]},
    ]
    d = same_result(batch(plot_list))
    assert isinstance(d, wire.DecodedPlots) and d.rejected == {} and len(d) == 3
    assert d.t_s.tolist() == [1.7e9, 1.7e9, 1.5] and math.copysign(1.0, d.range_m[1]) == -1.0
    assert d.mode_s.tolist() == [0x4CA1F3, 0xA, -1] and d.mode3a.tolist() == [0, -1, -1]
    assert d.track_no.tolist() == [2**32 - 1, -1, -1] and d.kind.tolist() == [3, 4, 0]
    assert d.roll_deg[:2].tolist() == [90.0, 0.0] and math.copysign(1.0, d.roll_deg[1]) == -1.0
    assert math.isnan(d.roll_deg[2])
    assert d.ground_speed_mps[:2].tolist() == [1100.0, 0.0] and math.copysign(1.0, d.ground_speed_mps[1]) == -1.0
    assert d.track_angle_deg[:2].tolist() == [math.nextafter(360.0, 0.0), 0.0]
    assert math.isnan(d.ground_speed_mps[2]) and math.isnan(d.track_angle_deg[2])
    assert d.magnetic_heading_deg[:2].tolist() == [math.nextafter(360.0, 0.0), 0.0]
    assert math.copysign(1.0, d.magnetic_heading_deg[1]) == -1.0
    assert d.indicated_airspeed_mps[:2].tolist() == [526.3, math.nextafter(0.0, math.inf)]
    assert math.isnan(d.magnetic_heading_deg[2]) and math.isnan(d.indicated_airspeed_mps[2])


def every_reader(payload: bytes) -> dict[str, wire.DecodedPlots | None]:
    """The batch as each reader gives it: the bytes parser (None: handed back), the
    columns (validate_plot_columns on msgpack's plots), decode_plot_batch as the daemon
    calls it, with the columns judging and with the model judging (however many plots),
    and the model alone."""
    obj = msgpack.unpackb(payload, raw=False)
    c = validate_plot_columns(obj["plots"])
    columns = {name: getattr(c, name) for name in COLUMNS}
    out = {
        "bytes": decode_plot_batch_bytes(payload),
        "columns": wire.DecodedPlots(obj["radar_id"], obj["seq"], **columns, rejected=c.rejected),
        "decode": wire.decode_plot_batch(payload),
        "decode, columns": wire.decode_plot_batch(payload, columns_from=0),
        "decode, model": wire.decode_plot_batch(payload, columns_from=wire.MAX_PLOTS_PER_BATCH + 1),
        "model": wire.decode_plot_batch_by_model(payload),
    }
    ref = out["model"]
    assert isinstance(ref, wire.DecodedPlots)
    for reader, d in out.items():
        if d is None:
            continue
        assert (d.radar_id, d.seq, d.rejected) == (ref.radar_id, ref.seq, ref.rejected), reader
        for name in COLUMNS:
            a, b = getattr(d, name), getattr(ref, name)
            assert a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes(), (reader, name, a, b)
    return out


def test_roll_is_read_where_sent_and_nan_where_not_by_every_reader():
    """roll_deg (v1 extension, Mode S BDS 5,0): a value on some plots, nil or no key on
    others; the bounds themselves are in range, an integer is a number."""
    plot_list = [
        full_plot(roll_deg=12.25),
        full_plot(roll_deg=None),
        {k: v for k, v in full_plot().items() if k != "roll_deg"},
        full_plot(roll_deg=-90.0),
        full_plot(roll_deg=90),
        full_plot(roll_deg=-0.0, fl=None),
    ]
    rng = random.Random(5)
    for payload in (batch(plot_list), pack_other_ways({"v": 1, "radar_id": "r1", "seq": 7, "plots": plot_list}, rng)):
        out = every_reader(payload)
        assert out["bytes"] is not None  # well-formed: the daemon's fast path reads it
        d = out["model"]
        assert isinstance(d, wire.DecodedPlots) and d.rejected == {} and d.roll_deg.dtype == float
        roll = d.roll_deg.tolist()
        assert roll[0] == 12.25 and math.isnan(roll[1]) and math.isnan(roll[2]) and roll[3:5] == [-90.0, 90.0]
        assert roll[5] == 0.0 and math.copysign(1.0, roll[5]) == -1.0
        assert d.fl[:5].tolist() == [350.0] * 5 and math.isnan(d.fl[5])  # roll is not fl's row


@pytest.mark.parametrize(
    "roll, reason",
    [
        (95.0, "plot_out_of_range"),
        (-90.5, "plot_out_of_range"),
        (math.nextafter(-90.0, -math.inf), "plot_out_of_range"),
        (180, "plot_out_of_range"),
        (math.nan, "plot_non_finite"),
        (math.inf, "plot_non_finite"),
        ("12.5", "plot_schema"),
        (True, "plot_schema"),
        ([12.5], "plot_schema"),
    ],
)
def test_a_bad_roll_is_refused_by_every_reader_and_spares_the_batch(roll, reason):
    plot_list = [full_plot(roll_deg=1.5), full_plot(roll_deg=roll, azimuth_deg=7.5), full_plot(roll_deg=None)]
    plot_list += [full_plot(roll_deg=-1.5, azimuth_deg=float(i)) for i in range(30)]  # the columns judge
    out = every_reader(batch(plot_list))
    assert out["bytes"] is None  # handed back: the general path gives the reason
    for reader, d in out.items():
        if d is None:
            continue
        assert d.rejected == {reason: 1}, reader
        assert len(d) == len(plot_list) - 1 and 7.5 not in d.azimuth_deg.tolist()
        assert d.roll_deg[0] == 1.5 and math.isnan(d.roll_deg[1]) and (d.roll_deg[2:] == -1.5).all()


def test_ground_speed_and_track_are_read_where_sent_and_nan_where_not_by_every_reader():
    """ground_speed_mps and track_angle_deg (v1 extensions, Mode S BDS 5,0): each on its
    own, a value, nil or no key; the closed bounds in range, an integer is a number."""

    def no(*names):
        return {k: v for k, v in full_plot().items() if k not in names}

    plot_list = [
        full_plot(ground_speed_mps=231.5, track_angle_deg=359.82421875),
        full_plot(ground_speed_mps=None, track_angle_deg=None),
        no("ground_speed_mps", "track_angle_deg"),
        no("ground_speed_mps") | {"track_angle_deg": 0},
        no("track_angle_deg") | {"ground_speed_mps": 1100},
        full_plot(ground_speed_mps=0, track_angle_deg=-0.0, roll_deg=None, fl=None),
    ]
    rng = random.Random(6)
    for payload in (batch(plot_list), pack_other_ways({"v": 1, "radar_id": "r1", "seq": 7, "plots": plot_list}, rng)):
        out = every_reader(payload)
        assert out["bytes"] is not None  # well-formed: the daemon's fast path reads it
        d = out["model"]
        assert isinstance(d, wire.DecodedPlots) and d.rejected == {}
        assert d.ground_speed_mps.dtype == float and d.track_angle_deg.dtype == float
        gs, trk = d.ground_speed_mps.tolist(), d.track_angle_deg.tolist()
        assert gs[0] == 231.5 and math.isnan(gs[1]) and math.isnan(gs[2]) and math.isnan(gs[3])
        assert gs[4:] == [1100.0, 0.0]
        assert trk[0] == 359.82421875 and math.isnan(trk[1]) and math.isnan(trk[2]) and trk[3] == 0.0
        assert math.isnan(trk[4]) and trk[5] == 0.0 and math.copysign(1.0, trk[5]) == -1.0
        # each its own row: not the roll's, nor fl's
        assert d.roll_deg[:5].tolist() == [-12.5] * 5 and math.isnan(d.roll_deg[5])
        assert d.fl[:5].tolist() == [350.0] * 5 and math.isnan(d.fl[5])


@pytest.mark.parametrize(
    "name, value, reason",
    [
        ("ground_speed_mps", -0.5, "plot_out_of_range"),
        ("ground_speed_mps", math.nextafter(0.0, -math.inf), "plot_out_of_range"),
        ("ground_speed_mps", 1100.5, "plot_out_of_range"),
        ("ground_speed_mps", 1101, "plot_out_of_range"),
        ("ground_speed_mps", -1, "plot_out_of_range"),
        ("ground_speed_mps", math.nan, "plot_non_finite"),
        ("ground_speed_mps", math.inf, "plot_non_finite"),
        ("ground_speed_mps", "231.5", "plot_schema"),
        ("ground_speed_mps", True, "plot_schema"),
        ("ground_speed_mps", [231.5], "plot_schema"),
        ("track_angle_deg", 360.0, "plot_out_of_range"),
        ("track_angle_deg", 360, "plot_out_of_range"),
        ("track_angle_deg", 720.5, "plot_out_of_range"),
        ("track_angle_deg", -0.1, "plot_out_of_range"),
        ("track_angle_deg", math.nan, "plot_non_finite"),
        ("track_angle_deg", -math.inf, "plot_non_finite"),
        ("track_angle_deg", "north", "plot_schema"),
        ("track_angle_deg", False, "plot_schema"),
        ("track_angle_deg", {"deg": 90.0}, "plot_schema"),
    ],
)
def test_a_bad_ground_speed_or_track_is_refused_by_every_reader_and_spares_the_batch(name, value, reason):
    other = "track_angle_deg" if name == "ground_speed_mps" else "ground_speed_mps"
    _bad_optional_value_spares_the_batch(name, value, reason, other)


def _bad_optional_value_spares_the_batch(name: str, value: object, reason: str, other: str) -> None:
    """One plot's optional field ``name`` bad: every reader refuses that plot for ``reason``
    and keeps the rest of the batch, the field's column as sent and ``other``'s untouched."""
    plot_list = [full_plot(**{name: 1.5}), full_plot(**{name: value}, azimuth_deg=7.5), full_plot(**{name: None})]
    plot_list += [full_plot(**{name: 2.5}, azimuth_deg=float(i)) for i in range(30)]  # the columns judge
    out = every_reader(batch(plot_list))
    assert out["bytes"] is None  # handed back: the general path gives the reason
    for reader, d in out.items():
        if d is None:
            continue
        assert d.rejected == {reason: 1}, reader
        assert len(d) == len(plot_list) - 1 and 7.5 not in d.azimuth_deg.tolist()
        col = getattr(d, name)
        assert col[0] == 1.5 and math.isnan(col[1]) and (col[2:] == 2.5).all()
        assert (getattr(d, other) == full_plot()[other]).all()


def test_heading_and_airspeed_are_read_where_sent_and_nan_where_not_by_every_reader():
    """magnetic_heading_deg and indicated_airspeed_mps (v1 extensions, Mode S BDS 6,0):
    each on its own, a value, nil or no key; the heading's closed bound and the airspeed's
    upper bound in range, an integer is a number."""

    def no(*names):
        return {k: v for k, v in full_plot().items() if k not in names}

    plot_list = [
        full_plot(magnetic_heading_deg=359.82421875, indicated_airspeed_mps=526.3),
        full_plot(magnetic_heading_deg=None, indicated_airspeed_mps=None),
        no("magnetic_heading_deg", "indicated_airspeed_mps"),
        no("magnetic_heading_deg") | {"indicated_airspeed_mps": 1},
        no("indicated_airspeed_mps") | {"magnetic_heading_deg": 0},
        full_plot(magnetic_heading_deg=-0.0, indicated_airspeed_mps=0.5, ground_speed_mps=None, fl=None),
    ]
    rng = random.Random(7)
    for payload in (batch(plot_list), pack_other_ways({"v": 1, "radar_id": "r1", "seq": 7, "plots": plot_list}, rng)):
        out = every_reader(payload)
        assert out["bytes"] is not None  # well-formed: the daemon's fast path reads it
        d = out["model"]
        assert isinstance(d, wire.DecodedPlots) and d.rejected == {}
        assert d.magnetic_heading_deg.dtype == float and d.indicated_airspeed_mps.dtype == float
        hdg, ias = d.magnetic_heading_deg.tolist(), d.indicated_airspeed_mps.tolist()
        assert hdg[0] == 359.82421875 and math.isnan(hdg[1]) and math.isnan(hdg[2]) and math.isnan(hdg[3])
        assert hdg[4:] == [0.0, 0.0] and math.copysign(1.0, hdg[5]) == -1.0
        assert ias[0] == 526.3 and math.isnan(ias[1]) and math.isnan(ias[2]) and ias[3] == 1.0
        assert math.isnan(ias[4]) and ias[5] == 0.5
        # each its own row: not BDS 5,0's, nor fl's
        assert d.track_angle_deg.tolist() == [272.8125] * 6 and d.roll_deg.tolist() == [-12.5] * 6
        assert d.ground_speed_mps[:5].tolist() == [231.5] * 5 and math.isnan(d.ground_speed_mps[5])
        assert d.fl[:5].tolist() == [350.0] * 5 and math.isnan(d.fl[5])


@pytest.mark.parametrize(
    "name, value, reason",
    [
        ("magnetic_heading_deg", 360.0, "plot_out_of_range"),
        ("magnetic_heading_deg", 360, "plot_out_of_range"),
        ("magnetic_heading_deg", -0.1, "plot_out_of_range"),
        ("magnetic_heading_deg", -1, "plot_out_of_range"),
        ("magnetic_heading_deg", math.nan, "plot_non_finite"),
        ("magnetic_heading_deg", math.inf, "plot_non_finite"),
        ("magnetic_heading_deg", "270", "plot_schema"),
        ("magnetic_heading_deg", True, "plot_schema"),
        ("indicated_airspeed_mps", 0.0, "plot_out_of_range"),
        ("indicated_airspeed_mps", 0, "plot_out_of_range"),
        ("indicated_airspeed_mps", -0.0, "plot_out_of_range"),
        ("indicated_airspeed_mps", -5.0, "plot_out_of_range"),
        ("indicated_airspeed_mps", math.nextafter(526.3, math.inf), "plot_out_of_range"),
        ("indicated_airspeed_mps", 1023, "plot_out_of_range"),
        ("indicated_airspeed_mps", math.nan, "plot_non_finite"),
        ("indicated_airspeed_mps", -math.inf, "plot_non_finite"),
        ("indicated_airspeed_mps", "128.6", "plot_schema"),
        ("indicated_airspeed_mps", False, "plot_schema"),
        ("indicated_airspeed_mps", {"kt": 250}, "plot_schema"),
    ],
)
def test_a_bad_heading_or_airspeed_is_refused_by_every_reader_and_spares_the_batch(name, value, reason):
    other = "indicated_airspeed_mps" if name == "magnetic_heading_deg" else "magnetic_heading_deg"
    _bad_optional_value_spares_the_batch(name, value, reason, other)


def test_a_batch_of_an_older_sender_without_heading_or_airspeed_decodes_with_them_nan():
    absent = ("magnetic_heading_deg", "indicated_airspeed_mps")
    plot_list = [{k: v for k, v in full_plot(azimuth_deg=float(i)).items() if k not in absent} for i in range(30)]
    for d in every_reader(batch(plot_list)).values():
        assert isinstance(d, wire.DecodedPlots) and d.rejected == {} and len(d) == 30
        assert np.isnan(d.magnetic_heading_deg).all() and np.isnan(d.indicated_airspeed_mps).all()
        assert (d.track_angle_deg == 272.8125).all()


def test_a_batch_of_an_older_sender_without_ground_speed_or_track_decodes_with_them_nan():
    plot_list = [
        {k: v for k, v in full_plot(azimuth_deg=float(i)).items() if k not in ("ground_speed_mps", "track_angle_deg")}
        for i in range(30)
    ]
    for d in every_reader(batch(plot_list)).values():
        assert isinstance(d, wire.DecodedPlots) and d.rejected == {} and len(d) == 30
        assert np.isnan(d.ground_speed_mps).all() and np.isnan(d.track_angle_deg).all()
        assert (d.roll_deg == -12.5).all()


def test_a_batch_of_an_older_sender_without_roll_decodes_with_roll_nan():
    plot_list = [{k: v for k, v in full_plot(azimuth_deg=float(i)).items() if k != "roll_deg"} for i in range(30)]
    for d in every_reader(batch(plot_list)).values():
        assert isinstance(d, wire.DecodedPlots) and d.rejected == {} and len(d) == 30
        assert d.roll_deg.shape == (30,) and np.isnan(d.roll_deg).all()


def test_an_empty_and_a_full_batch():
    """The largest batch the contract allows, every field of every plot filled (4.8 MB), is
    within the default payload limit (wire.MAX_PLOT_BATCH_BYTES)."""
    assert len(same_result(batch([]))) == 0
    full = batch([full_plot(azimuth_deg=i % 360) for i in range(wire.MAX_PLOTS_PER_BATCH)])
    assert 4 << 20 < len(full) <= wire.MAX_PLOT_BATCH_BYTES
    d = same_result(full)
    assert len(d) == wire.MAX_PLOTS_PER_BATCH


@pytest.fixture(
    scope="module",
    params=["demo", "benchmark"],
)
def simulated(request):
    if request.param == "demo":
        return sim.simulate(sim.preset("demo", seed=11, duration_s=120.0))
    return sim.simulate(sim.scenario_for_benchmark(300, 4, 40.0, 2), encode=True)


def test_realistic_batches_decode_the_same_both_ways(simulated):
    """Every PlotBatch of the demo scenario (small batches) and of a benchmark scenario
    (hundreds of plots a batch) as the simulator encodes them (absent optional fields,
    PSR/SSR/Mode S plots, wild and false plots), then each with a fifth of its plots
    corrupted the ways a front-end might."""
    rng = random.Random(3)
    corruptions = [
        ("range_m", math.nan),
        ("azimuth_deg", 360.0),
        ("fl", 4000.0),
        ("mode_s", "ZZZZZZ"),
        ("kind", "radar"),
        ("t", "1.7e9"),
        ("mode3a", -1),
        ("track_no", 1.0),
        ("roll_deg", 95.0),
        ("roll_deg", "level"),
        ("ground_speed_mps", -3.0),
        ("ground_speed_mps", math.inf),
        ("track_angle_deg", 360.0),
        ("track_angle_deg", "north"),
        ("magnetic_heading_deg", 360.0),
        ("indicated_airspeed_mps", 0.0),
        ("indicated_airspeed_mps", "fast"),
    ]
    n_batches = n_plots = 0
    for _, key, payload in simulated.messages:
        if not key.endswith("/plots"):
            continue
        assert decode_plot_batch_bytes(payload) is not None  # the daemon's fast path
        d = same_result(payload)
        assert isinstance(d, wire.DecodedPlots) and d.rejected == {}
        obj = msgpack.unpackb(payload, raw=False)
        for p in obj["plots"]:
            if rng.random() < 0.2:
                name, value = rng.choice(corruptions)
                p[name] = value
        bad = same_result(pack(obj))
        assert isinstance(bad, wire.DecodedPlots)
        assert len(bad) + sum(bad.rejected.values()) == len(obj["plots"])
        n_batches += 1
        n_plots += len(d)
    assert n_batches > 30 and n_plots > 1000


@pytest.mark.parametrize(
    "payload",
    [
        b"",
        b"\xc1",
        pack({"v": 1, "radar_id": "r1", "seq": 7, "plots": [full_plot()]})[:-1],  # cut short
        pack({"v": 1, "radar_id": "r1", "seq": 7, "plots": [full_plot()]}) + b"\x00",  # bytes after it
        pack({"v": True, "radar_id": "r1", "seq": 7, "plots": []}),
        pack({"v": 1, "radar_id": "r 1", "seq": 7, "plots": []}),
        pack({"v": 1, "radar_id": "r1", "seq": -1, "plots": []}),
        pack({"v": 1, "radar_id": "r1", "seq": 2**64 - 1, "plots": []}),
        pack({"v": 1, "radar_id": "r1", "plots": []}),
        pack({"v": 1, "radar_id": "r1", "seq": 7, "plots": [full_plot(), full_plot(t=math.nan)]}),
        pack({"v": 1, "radar_id": "r1", "seq": 7, "plots": [full_plot(), full_plot(roll_deg=-90.5)]}),
        pack({"v": 1, "radar_id": "r1", "seq": 7, "plots": [full_plot(), full_plot(roll_deg="3")]}),
        pack({"v": 1, "radar_id": "r1", "seq": 7, "plots": [full_plot(), full_plot(ground_speed_mps=1100.5)]}),
        pack({"v": 1, "radar_id": "r1", "seq": 7, "plots": [full_plot(), full_plot(track_angle_deg=360.0)]}),
        pack({"v": 1, "radar_id": "r1", "seq": 7, "plots": [full_plot(), full_plot(track_angle_deg=True)]}),
        pack({"v": 1, "radar_id": "r1", "seq": 7, "plots": [full_plot(), full_plot(magnetic_heading_deg=360.0)]}),
        pack({"v": 1, "radar_id": "r1", "seq": 7, "plots": [full_plot(), full_plot(indicated_airspeed_mps=0.0)]}),
        pack({"v": 1, "radar_id": "r1", "seq": 7, "plots": [full_plot(), full_plot(indicated_airspeed_mps=526.4)]}),
        pack({"v": 1, "radar_id": "r1", "seq": 7, "plots": [{**full_plot(), "x": {"k": 1}}]}),  # a map in an extra
        pack({"v": 1, "radar_id": "r1", "seq": 7, "plots": [{**full_plot(), "x": "é"}]}),  # non-ASCII text
        pack({"v": 1, "radar_id": "r1", "seq": 7, "plots": [{**full_plot(), 3: 1}]}),  # a key not a str
        pack({"v": 1, "radar_id": "r1", "seq": 7, "plots": [full_plot()], "x": msgpack.ExtType(1, b"a")}),
        b"\x85\xa1v\x01\xa8radar_id\xa2r1\xa3seq\x07\xa5plots\x90\xa3seq\x08",  # seq twice: the last
    ],
)
def test_the_bytes_path_hands_back_what_it_cannot_take_as_is(payload):
    assert decode_plot_batch_bytes(payload) is None
    same_result(payload)


@pytest.mark.parametrize("depth", [3, 300, 1100, 100_000])
def test_an_ignored_field_nested_deep_is_read_as_msgpack_reads_it(depth):
    """An extra field of arrays in arrays: the byte path skips it while it is plainly
    nested, and beyond its depth hands the batch to msgpack, which refuses one nested
    past its own limit (1,024): the daemon took those plots, the contract's reading not."""
    body = pack({"v": 1, "radar_id": "r1", "seq": 7, "plots": [full_plot()]})
    payload = bytes([body[0] + 1]) + body[1:] + b"\xa1x" + b"\x91" * depth + b"\xc0"
    assert (decode_plot_batch_bytes(payload) is not None) is (depth < 256)
    same_result(payload)


def test_damaged_batches_are_read_safely(simulated):
    """Realistic batches cut, bit-flipped, overwritten and with bytes inserted, the way a
    link damages them: the bytes parser never reads past the payload (it would crash the
    daemon, not raise) and whatever it takes, the model takes with the same values."""
    rng = random.Random(9)
    payloads = [p for _, key, p in simulated.messages if key.endswith("/plots")][:50]
    taken = 0
    for _ in range(4000):
        p = bytearray(rng.choice(payloads)[: rng.choice([40, 200, 1 << 20])])
        for _ in range(rng.randint(1, 3)):
            i = rng.randrange(len(p)) if p else 0
            op = rng.randrange(4)
            if op == 0 and p:
                p[i] ^= 1 << rng.randrange(8)
            elif op == 1 and p:
                p[i] = rng.randrange(256)
            elif op == 2:
                del p[rng.randrange(len(p) + 1) :]
            else:
                p[i:i] = bytes([rng.randrange(256)])
        if decode_plot_batch_bytes(bytes(p)) is not None:
            taken += 1
            same_result(bytes(p))
    assert taken > 20  # some damage leaves a valid batch (a changed value in range)
