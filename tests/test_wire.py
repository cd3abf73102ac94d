"""The wire contract: codec round trips, typed rejections, per-plot validation, schema drift."""

from __future__ import annotations

import json
import math
from pathlib import Path

import jsonschema
import msgpack
import numpy as np
import pytest

from radar_fusion import wire
from radar_fusion.geo.units import MPS_PER_KT
from radar_fusion.schemas import schema_documents

ROOT = Path(__file__).resolve().parents[1]


def plot(**kw):
    p = {
        "t": 1.7e9,
        "range_m": 120_000.0,
        "azimuth_deg": 45.0,
        "fl": 350.0,
        "mode3a": 0o1234,
        "mode_s": "4CA1F3",
        "track_no": 17,
        "kind": "cmb",
    }
    p.update(kw)
    return p


def batch(plots, **kw):
    b = {"v": 1, "radar_id": "r1", "seq": 3, "plots": plots}
    b.update(kw)
    return msgpack.packb(b)


def test_good_batch_decodes_to_columns():
    d = wire.decode_plot_batch(batch([plot(), plot(fl=None, mode_s=None, mode3a=None, track_no=None, kind=None)]))
    assert isinstance(d, wire.DecodedPlots)
    assert len(d) == 2 and d.rejected == {}
    assert d.mode_s.tolist() == [0x4CA1F3, -1]
    assert d.mode3a.tolist() == [0o1234, -1]
    assert d.track_no.tolist() == [17, -1]
    assert d.fl[0] == 350.0 and math.isnan(d.fl[1])
    assert d.kind.tolist() == [wire.KIND_CODES["cmb"], 0]


@pytest.mark.parametrize(
    "bad, reason",
    [
        (plot(range_m=float("nan")), "plot_non_finite"),
        (plot(t=float("inf")), "plot_non_finite"),
        (plot(range_m=-5.0), "plot_out_of_range"),
        (plot(azimuth_deg=360.0), "plot_out_of_range"),
        (plot(fl=5000.0), "plot_out_of_range"),
        (plot(mode3a=0o10000), "plot_out_of_range"),
        (plot(mode_s="XYZ123"), "plot_out_of_range"),
        (plot(range_m="120000"), "plot_schema"),
        (plot(mode3a=True), "plot_schema"),
        (plot(kind="laser"), "plot_schema"),
        (plot(roll_deg=95.0), "plot_out_of_range"),
        (plot(roll_deg=-90.5), "plot_out_of_range"),
        (plot(roll_deg=float("nan")), "plot_non_finite"),
        (plot(roll_deg="12"), "plot_schema"),
        (plot(ground_speed_mps=-0.5), "plot_out_of_range"),
        (plot(ground_speed_mps=1100.5), "plot_out_of_range"),
        (plot(ground_speed_mps=float("nan")), "plot_non_finite"),
        (plot(ground_speed_mps=float("inf")), "plot_non_finite"),
        (plot(ground_speed_mps="230"), "plot_schema"),
        (plot(track_angle_deg=360.0), "plot_out_of_range"),
        (plot(track_angle_deg=-0.1), "plot_out_of_range"),
        (plot(track_angle_deg=float("nan")), "plot_non_finite"),
        (plot(track_angle_deg=True), "plot_schema"),
        (plot(magnetic_heading_deg=360.0), "plot_out_of_range"),
        (plot(magnetic_heading_deg=-0.1), "plot_out_of_range"),
        (plot(magnetic_heading_deg=float("nan")), "plot_non_finite"),
        (plot(magnetic_heading_deg="270"), "plot_schema"),
        (plot(indicated_airspeed_mps=0.0), "plot_out_of_range"),
        (plot(indicated_airspeed_mps=-1.0), "plot_out_of_range"),
        (plot(indicated_airspeed_mps=526.4), "plot_out_of_range"),
        (plot(indicated_airspeed_mps=float("inf")), "plot_non_finite"),
        (plot(indicated_airspeed_mps=True), "plot_schema"),
        ({"t": 1.7e9}, "plot_schema"),
        ("not a plot", "plot_schema"),
    ],
)
def test_one_bad_plot_is_counted_and_does_not_spoil_the_batch(bad, reason):
    d = wire.decode_plot_batch(batch([plot(), bad, plot(azimuth_deg=10.0)]))
    assert isinstance(d, wire.DecodedPlots)
    assert len(d) == 2
    assert d.rejected == {reason: 1}
    assert sorted(d.azimuth_deg.tolist()) == [10.0, 45.0]


@pytest.mark.parametrize(
    "payload, reason",
    [
        (b"\xc1garbage", "malformed_msgpack"),
        (msgpack.packb([1, 2, 3]), "schema"),
        (msgpack.packb({"v": 2, "radar_id": "r1", "seq": 1, "plots": []}), "version"),
        (msgpack.packb({"radar_id": "r1", "seq": 1, "plots": []}), "version"),
        (msgpack.packb({"v": 1, "radar_id": "r 1", "seq": 1, "plots": []}), "schema"),
        (msgpack.packb({"v": 1, "radar_id": "r1", "seq": -1, "plots": []}), "schema"),
        (msgpack.packb({"v": 1, "radar_id": "r1", "seq": 1, "plots": "x"}), "schema"),
        (msgpack.packb({"v": 1, "radar_id": "r1", "seq": 1}), "schema"),
    ],
)
def test_bad_messages_get_a_typed_rejection(payload, reason):
    r = wire.decode_plot_batch(payload)
    assert isinstance(r, wire.Rejection) and r.reason == reason


def test_oversize_and_huge_arrays_are_refused_without_decoding():
    r = wire.decode_plot_batch(b"\x00" * 100, max_bytes=50)
    assert isinstance(r, wire.Rejection) and r.reason == "oversize"
    huge = msgpack.packb({"v": 1, "radar_id": "r1", "seq": 1, "plots": [0] * (wire.MAX_PLOTS_PER_BATCH + 5)})
    r = wire.decode_plot_batch(huge, max_bytes=len(huge) + 1)
    assert isinstance(r, wire.Rejection) and r.reason == "malformed_msgpack"


def test_roll_is_an_optional_last_plot_field_nan_where_absent():
    """roll_deg (v1 extension: Mode S BDS 5,0, ICAO Doc 9871 table A-2-80, positive right
    wing down) comes after the fields of v1 as first published; a sender that does not
    know it omits it (``plot()`` here) and its plots decode with roll NaN."""
    fields = list(wire.Plot.model_fields)
    assert fields[:9] == ["t", "range_m", "azimuth_deg", "fl", "mode3a", "mode_s", "track_no", "kind", "roll_deg"]
    assert not wire.Plot.model_fields["roll_deg"].is_required() and wire.Plot(**plot()).roll_deg is None
    d = wire.decode_plot_batch(batch([plot(roll_deg=-25.5), plot(), plot(roll_deg=None), plot(roll_deg=90)]))
    assert isinstance(d, wire.DecodedPlots) and len(d) == 4 and d.rejected == {}
    assert d.roll_deg[0] == -25.5 and math.isnan(d.roll_deg[1]) and math.isnan(d.roll_deg[2]) and d.roll_deg[3] == 90.0
    assert d.fl.tolist() == [350.0] * 4


def test_ground_speed_and_track_are_optional_last_plot_fields_nan_where_absent():
    """ground_speed_mps and track_angle_deg (v1 extensions: Mode S BDS 5,0, ICAO Doc 9871
    table A-2-80; the track true, clockwise from north, [0, 360)) come after roll_deg, each
    optional on its own; a sender that does not know them omits them and they decode NaN."""
    fields = list(wire.Plot.model_fields)
    assert fields[8:11] == ["roll_deg", "ground_speed_mps", "track_angle_deg"]
    for name in ("ground_speed_mps", "track_angle_deg"):
        assert not wire.Plot.model_fields[name].is_required() and getattr(wire.Plot(**plot()), name) is None
    d = wire.decode_plot_batch(
        batch(
            [
                plot(ground_speed_mps=231.5, track_angle_deg=359.82421875),
                plot(),
                plot(ground_speed_mps=0, track_angle_deg=None),
                plot(ground_speed_mps=None, track_angle_deg=0),
                plot(ground_speed_mps=1100, roll_deg=3.0),
            ]
        )
    )
    assert isinstance(d, wire.DecodedPlots) and len(d) == 5 and d.rejected == {}
    gs, trk = d.ground_speed_mps.tolist(), d.track_angle_deg.tolist()
    assert gs[0] == 231.5 and math.isnan(gs[1]) and gs[2] == 0.0 and math.isnan(gs[3]) and gs[4] == 1100.0
    assert trk[0] == 359.82421875 and math.isnan(trk[1]) and math.isnan(trk[2]) and trk[3] == 0.0
    assert math.isnan(trk[4]) and d.roll_deg[4] == 3.0 and d.fl.tolist() == [350.0] * 5
    # made without them (an older caller): NaN columns of the batch's length
    older = wire.DecodedPlots(**{**vars(d), "ground_speed_mps": None, "track_angle_deg": None})
    assert older.ground_speed_mps.shape == older.track_angle_deg.shape == (5,)
    assert all(map(math.isnan, older.ground_speed_mps.tolist() + older.track_angle_deg.tolist()))


def test_heading_and_airspeed_are_optional_last_plot_fields_nan_where_absent():
    """magnetic_heading_deg and indicated_airspeed_mps (v1 extensions: Mode S BDS 6,0, ICAO
    Doc 9871 table A-2-96; the heading magnetic, clockwise from north, [0, 360); the
    airspeed (0, 526.3] m/s, the register's 10 bits of 1 kt) come after track_angle_deg,
    each optional on its own; a sender that does not know them omits them and they decode
    NaN."""
    fields = list(wire.Plot.model_fields)
    assert fields[8:] == [
        "roll_deg",
        "ground_speed_mps",
        "track_angle_deg",
        "magnetic_heading_deg",
        "indicated_airspeed_mps",
    ]
    for name in ("magnetic_heading_deg", "indicated_airspeed_mps"):
        assert not wire.Plot.model_fields[name].is_required() and getattr(wire.Plot(**plot()), name) is None
    max_ias_mps = 1023 * MPS_PER_KT
    plots = [
        plot(magnetic_heading_deg=359.82421875, indicated_airspeed_mps=250 * MPS_PER_KT),
        plot(),
        plot(magnetic_heading_deg=0, indicated_airspeed_mps=None),
        plot(magnetic_heading_deg=None, indicated_airspeed_mps=max_ias_mps),
        plot(indicated_airspeed_mps=1, ground_speed_mps=231.5, track_angle_deg=90.0),
    ]
    payload = batch(plots * 10)
    for d in (wire.decode_plot_batch(payload), wire.decode_plot_batch_by_model(payload)):  # the bytes, the model
        assert isinstance(d, wire.DecodedPlots) and len(d) == 50 and d.rejected == {}
        hdg, ias = d.magnetic_heading_deg.tolist()[-5:], d.indicated_airspeed_mps.tolist()[-5:]
        assert hdg[0] == 359.82421875 and math.isnan(hdg[1]) and hdg[2] == 0.0 and math.isnan(hdg[3])
        assert math.isnan(hdg[4])
        assert ias[0] == 250 * MPS_PER_KT and math.isnan(ias[1]) and math.isnan(ias[2]) and ias[3] == max_ias_mps
        assert ias[4] == 1.0 and d.ground_speed_mps[-1] == 231.5 and d.track_angle_deg[-1] == 90.0
        assert math.isnan(d.ground_speed_mps[0]) and d.fl.tolist() == [350.0] * 50
    # made without them (an older caller): NaN columns of the batch's length
    older = wire.DecodedPlots(**{**vars(d), "magnetic_heading_deg": None, "indicated_airspeed_mps": None})
    assert older.magnetic_heading_deg.shape == older.indicated_airspeed_mps.shape == (50,)
    assert np.isnan(older.magnetic_heading_deg).all() and np.isnan(older.indicated_airspeed_mps).all()


def test_unknown_fields_are_ignored_for_forward_compatibility():
    d = wire.decode_plot_batch(batch([plot(snr_db=12.0)], extra_field="x"))
    assert isinstance(d, wire.DecodedPlots) and len(d) == 1 and d.rejected == {}


def test_status_round_trip_and_rejection():
    s = wire.RadarStatus(radar_id="r1", t=1.7e9, kind="north", rotation_period_s=4.0)
    assert wire.decode_message(wire.encode(s), wire.RadarStatus) == s
    r = wire.decode_message(msgpack.packb({"v": 1, "radar_id": "r1", "t": 1.7e9, "kind": "spin"}), wire.RadarStatus)
    assert isinstance(r, wire.Rejection) and r.reason == "schema" and "kind" in r.detail


def test_schemas_in_repository_match_the_models():
    """schemas/*.schema.json are generated from wire.py: regenerate with `radar-fusion schemas`."""
    docs = schema_documents()
    for name, text in docs.items():
        path = ROOT / "schemas" / name
        assert path.exists(), f"{path} missing: run `radar-fusion schemas`"
        assert path.read_text(encoding="utf-8") == text, f"{path} is stale: run `radar-fusion schemas`"
    assert sorted(p.name for p in (ROOT / "schemas").glob("*.schema.json")) == sorted(docs)


def test_a_plot_batch_validates_against_the_published_schema():
    schema = json.loads((ROOT / "schemas" / "PlotBatch.schema.json").read_text())
    jsonschema.validate(msgpack.unpackb(batch([plot(), plot(roll_deg=-12.5), plot(roll_deg=None)])), schema)
    good = [plot(ground_speed_mps=231.5, track_angle_deg=359.9), plot(ground_speed_mps=None, track_angle_deg=0.0)]
    jsonschema.validate(msgpack.unpackb(batch(good)), schema)
    good = [plot(magnetic_heading_deg=359.9, indicated_airspeed_mps=526.3), plot(magnetic_heading_deg=0.0)]
    jsonschema.validate(msgpack.unpackb(batch(good + [plot(indicated_airspeed_mps=0.1)])), schema)
    for bad in (
        plot(track_angle_deg=360.0),
        plot(ground_speed_mps=-1.0),
        plot(ground_speed_mps=1101.0),
        plot(magnetic_heading_deg=360.0),
        plot(magnetic_heading_deg=-1.0),
        plot(indicated_airspeed_mps=0.0),
        plot(indicated_airspeed_mps=526.4),
    ):
        with pytest.raises(jsonschema.ValidationError):
            jsonschema.validate(msgpack.unpackb(batch([bad])), schema)
    with pytest.raises(jsonschema.ValidationError):
        jsonschema.validate(msgpack.unpackb(batch([plot(azimuth_deg=400.0)])), schema)
    with pytest.raises(jsonschema.ValidationError):
        jsonschema.validate(msgpack.unpackb(batch([plot(roll_deg=95.0)])), schema)


def test_a_malformed_payload_is_refused_with_what_and_where_for_the_log():
    """Issue 13: a PlotBatch once arrived with a string that was not UTF-8. The rejection
    says which error, where, and the payload's first bytes, so that the next one shows
    whether a sender wrote it so or it was damaged on the way."""
    good = msgpack.packb({"v": 1, "radar_id": "r1", "seq": 3, "plots": [{"t": 1.7e9, "mode_s": "4CA1F3"}]})
    at = good.index(b"4CA1F3")
    damaged = good[:at] + b"\xc3" + good[at + 1 :]  # one byte of the address: no longer UTF-8
    r = wire.decode_plot_batch(damaged)
    assert isinstance(r, wire.Rejection) and r.reason == "malformed_msgpack"
    assert r.detail.startswith("UnicodeDecodeError") and f"[{len(damaged)} bytes: {damaged[:32].hex()}]" in r.detail
