"""TrackBatch packed from the columns (issue 16 item 3): byte for byte what msgpack gives
for the dict message, on the demo's period outputs (both filters, safety nets on: alerts,
coasting and ended tracks, optional fields present and absent) and on columns built to
reach every msgpack integer width, None and NaN; and the published schema still holds."""

from __future__ import annotations

import tomllib

import msgpack
import numpy as np
import pytest

from radar_fusion import config, wire
from radar_fusion.engine import Engine, columns
from radar_fusion.engine.columns import RadarNames, TrackColumns
from radar_fusion.geo.coordinates import SystemPlane
from radar_fusion.safety_nets import SafetyNets
from radar_fusion.tools import simulate as sim
from radar_fusion.tracking.track_management import COASTING, CONFIRMED, TENTATIVE
from radar_fusion.wire_columns import MapRows, array_header, map_header

PLANE = SystemPlane(47.0, 8.0)


def by_dict(tc: TrackColumns) -> bytes:
    """Today's encoder: the message as dicts, then msgpack (what the daemon published)."""
    return msgpack.packb(tc.to_message(), use_bin_type=True)


@pytest.fixture
def always_from_columns(monkeypatch):
    """Every batch through the column packer, however few its tracks."""
    monkeypatch.setattr(columns, "PACK_FROM_COLUMNS_MIN_TRACKS", 0)


@pytest.fixture(scope="module", params=["singer", "imm"])
def demo_outputs(request):
    scenario = sim.preset("demo", seed=3, duration_s=300.0)
    simulation = sim.simulate(scenario)
    raw = tomllib.loads(sim.config_toml(scenario))
    raw.setdefault("tracking", {})["filter"] = request.param
    settings = config.settings_from_dict(raw, source="demo")
    engine = Engine(settings, safety_nets=SafetyNets.from_settings(settings))
    outputs = []
    t0 = scenario.start_t_s
    for t_s, key, payload in simulation.messages:
        if key.endswith("/plots"):
            if t0 + 150.0 <= t_s < t0 + 190.0 and key.split("/")[1] != simulation.scenario.radars[0].id:
                continue  # all radars but one silent (their north markers go on): tracks coast, some end
            engine.ingest_plots(wire.decode_plot_batch(payload))
        else:
            engine.ingest_status(wire.decode_message(payload, wire.RadarStatus))
        outputs.extend(engine.poll())
    outputs.extend(engine.flush())
    return request.param, outputs


def test_demo_period_outputs_pack_to_the_same_bytes(demo_outputs, always_from_columns):
    filt, outputs = demo_outputs
    seen = {"coasting": 0, "tentative": 0, "no_fl": 0, "no_mode_s": 0, "mode_s": 0, "ended": 0, "alerts": 0}
    for out in outputs:
        tc = out.track_columns
        assert tc.to_msgpack() == by_dict(tc), out.period
        assert out.track_batch_bytes == msgpack.packb(out.track_batch, use_bin_type=True)
        seen["coasting"] += int((tc.status == COASTING).sum())
        seen["tentative"] += int((tc.status == TENTATIVE).sum())
        seen["no_fl"] += int(np.isnan(tc.fl).sum())
        seen["no_mode_s"] += int((tc.mode_s < 0).sum())
        seen["mode_s"] += int((tc.mode_s >= 0).sum())
        seen["ended"] += len(tc.ended)
        seen["alerts"] += len(out.alerts)
    assert all(n > 0 for k, n in seen.items() if k != "alerts"), seen
    assert (outputs[-1].track_columns.manoeuvre_prob is not None) == (filt == "imm")
    # and what a consumer receives still validates against the contract
    for out in outputs[::10]:
        wire.TrackBatch.model_validate(msgpack.unpackb(out.track_batch_bytes, raw=False))


def test_received_batches_repack_to_the_same_bytes(demo_outputs, always_from_columns):
    """Columns rebuilt from a received TrackBatch (a stand-alone consumer's) pack the same way."""
    _, outputs = demo_outputs
    for out in outputs[::7]:
        back = TrackColumns.from_message(msgpack.unpackb(out.track_batch_bytes, raw=False), PLANE)
        assert back.to_msgpack() == by_dict(back)


def synthetic(n: int, rng: np.random.Generator, names: list[str]) -> TrackColumns:
    """Columns with every msgpack width of every integer field, None and NaN where allowed."""
    widths = np.array([0, 1, 127, 128, 255, 256, 65_535, 65_536, 2**32 - 1, 2**32, 2**62])
    tc = TrackColumns(
        period=int(rng.integers(0, 2**40)),
        t_s=1.7e9 + float(rng.random()),
        track_id=rng.choice(widths, n),
        status=rng.choice(np.array([TENTATIVE, CONFIRMED, COASTING], np.int8), n),
        x=rng.normal(0, 1e5, (n, 6)),
        cov_xy=rng.random((n, 3)) * 1e4,
        fl=np.where(rng.random(n) < 0.3, np.nan, rng.uniform(-20, 1300, n)),
        vrate_fpm=np.where(rng.random(n) < 0.3, np.nan, rng.normal(0, 2000, n)),
        sources=rng.integers(0, 2 ** len(names), n).astype(np.uint64),
        mode3a=np.where(rng.random(n) < 0.3, -1, rng.choice(np.array([0, 7, 127, 128, 4095]), n)),
        mode_s=np.where(rng.random(n) < 0.3, -1, rng.integers(0, 1 << 24, n)),
        updates=rng.choice(widths, n),
        age_s=rng.random(n) * 1e4,
        ended=rng.choice(widths, int(rng.integers(0, 20))),
        names=RadarNames(names, PLANE),
        manoeuvre_prob=None if rng.random() < 0.5 else rng.random(n),
        # tracks of one update carry their own measurement time
        t_track_s=None if rng.random() < 0.5 else 1.7e9 - rng.random(n) * 4.0,
    )
    # a NaN position is packed as the float it is; a NaN velocity or acceleration (none
    # known yet) as nil
    tc.x[rng.random((n, 6)) < 0.01] = np.nan
    tc.x[:1, 0] = -0.0
    return tc


@pytest.mark.parametrize("n", [0, 1, 15, 16, 200, 3000])
def test_synthetic_columns_pack_to_the_same_bytes(n, always_from_columns):
    rng = np.random.default_rng(n)
    for names in (["r1"], [f"radar-{i:02d}" for i in range(12)], ["a" * 32, "b", "ü-ok"]):
        tc = synthetic(n, rng, names)
        assert tc.to_msgpack() == by_dict(tc)


def test_mode_s_beyond_24_bits_and_odd_dtypes_still_pack_the_same(always_from_columns):
    tc = synthetic(40, np.random.default_rng(1), ["r1", "r2"])
    tc.mode_s[:3] = [1 << 24, (1 << 30) + 5, 0]  # mode_s_to_str spells them with more digits
    assert tc.to_msgpack() == by_dict(tc)
    tc.age_s = tc.age_s.astype(np.int64)  # to_message would pack Python ints: the dict path does
    assert tc.to_msgpack() == by_dict(tc)


def test_below_the_threshold_the_dict_path_is_used(monkeypatch):
    tc = synthetic(5, np.random.default_rng(2), ["r1"])
    calls = []
    original = TrackColumns.to_message
    monkeypatch.setattr(TrackColumns, "to_message", lambda self: calls.append(1) or original(self))
    assert tc.to_msgpack() == by_dict(tc) and len(calls) == 2  # once by to_msgpack, once by by_dict


@pytest.mark.parametrize("value", [0, 1, 127, 128, -1, -32, -33, -128, -129, -32768, -32769, -(2**31), -(2**31) - 1])
def test_map_rows_integers_match_msgpack(value):
    nil = np.array([False, True, False])
    a = np.array([value, 5, 2**63 - 1 if value >= 0 else -(2**63)], np.int64)
    got = MapRows(3).integers(a, nil=nil).float64(a.astype(float), nil=~nil).tobytes()
    want = b"".join(
        msgpack.packb(None if k else int(v)) + msgpack.packb(float(v) if k else None) for v, k in zip(a.tolist(), nil)
    )
    assert got == want


@pytest.mark.parametrize("n", [0, 15, 16, 65_535, 65_536])
def test_headers_match_msgpack(n):
    assert array_header(n) == msgpack.packb([None] * n)[: len(array_header(n))]
    assert map_header(n) == msgpack.packb({i: None for i in range(n)})[: len(map_header(n))]
