"""A hot-standby pair (redundancy.py, issue 13), without a bus: the election's rules, a
standby that applies its active's state holds bit-identical tracks and goes on with them,
and the stamp an active puts on its TrackBatches reads back on every path."""

from __future__ import annotations

import msgpack
import numpy as np
import pytest

from radar_fusion.bus import batch_stamp
from radar_fusion.engine import Engine
from radar_fusion.engine.state import StateMismatch, restore, snapshot
from radar_fusion.geo.coordinates import SystemPlane
from radar_fusion.redundancy import Election, default_instance
from radar_fusion.safety_nets.track_input import TrackBatchReader
from radar_fusion.tools import evaluate as ev
from radar_fusion.tools.replay import ingest_record
from radar_fusion.wire import TrackBatch

# ------------------------------------------------------------------ the election


def test_a_lone_standby_takes_over_after_settling_with_epoch_one():
    e = Election("a:1", started_s=0.0, settle_s=1.0)
    assert e.decide(0.5) is None  # an active already on the bus may still show its token
    assert e.decide(1.0) == "take_over"
    assert e.took_over() == 1 and e.role == "active"
    assert e.decide(5.0) is None


def test_a_standby_waits_while_an_active_lives_and_takes_over_above_its_epoch():
    e = Election("b:2", started_s=0.0)
    e.member_seen("a:1", True)
    e.active_seen("a:1", 3, True)
    assert e.decide(10.0) is None
    e.active_seen("a:1", 3, False)
    e.member_seen("a:1", False)
    assert e.decide(10.1) == "take_over"
    assert e.took_over() == 4  # above every epoch seen: epochs only grow


def test_a_standby_waits_the_handover_time_after_the_active_went():
    """The active's last TrackBatches travel behind its token's withdrawal (Zenoh sends
    declarations first): the standby takes over handover_s after the withdrawal, having
    seen them, not at once."""
    e = Election("b:2", started_s=0.0, handover_s=0.5)
    e.active_seen("a:1", 3, True, now_s=5.0)
    e.active_seen("a:1", 3, False, now_s=10.0)
    assert e.decide(10.0) is None and e.decide(10.49) is None
    assert e.decide(10.5) == "take_over"
    lone = Election("c:3", started_s=0.0, handover_s=0.5)  # no active was ever seen: settle_s alone
    assert lone.decide(1.0) == "take_over"


def test_epochs_grow_across_a_restart_of_the_whole_pair():
    """A display that stayed up drops what is below the highest epoch it saw: a pair that
    restarted from nothing must not start again at 1."""
    before = Election("a:1", started_s=0.0)
    first = before.took_over(wall_s=1_790_000_000.4)
    for _ in range(3):  # three take-overs within that second
        before.active_seen("b:1", before.highest_epoch + 1, True)
        before.took_over(wall_s=1_790_000_000.9)
    assert first == 1_790_000_000 and before.epoch == first + 6
    restarted = Election("a:1", started_s=0.0)  # nothing seen, seconds later
    assert restarted.took_over(wall_s=1_790_000_020.0) > before.epoch


def test_of_several_standbys_only_the_smallest_name_moves():
    names = ["host-b:7", "host-a:9", "host-c:1"]
    elections = {n: Election(n, started_s=0.0) for n in names}
    for e in elections.values():
        for other in names:
            e.member_seen(other, True)
    moving = [n for n, e in elections.items() if e.decide(5.0) == "take_over"]
    assert moving == ["host-a:9"]
    # once it is gone from the bus, the next one does
    for e in elections.values():
        e.member_seen("host-a:9", False)
    assert [n for n, e in elections.items() if n != "host-a:9" and e.decide(6.0)] == ["host-b:7"]


def test_two_actives_the_lower_epoch_stands_down_and_at_equal_epochs_the_larger_name():
    old = Election("z:1", started_s=0.0)
    old.decide(2.0)
    old.took_over()  # epoch 1, cut off from the bus meanwhile
    new = Election("y:2", started_s=0.0)
    new.highest_epoch = 1
    new.took_over()  # epoch 2 on the other side
    old.active_seen("y:2", 2, True)  # the partition heals: each sees the other's token
    new.active_seen("z:1", 1, True)
    assert old.decide(9.0) == "stand_down" and new.decide(9.0) is None
    old.stood_down()
    assert old.role == "standby" and old.stand_downs == 1

    a, b = Election("a:1", started_s=0.0), Election("b:1", started_s=0.0)
    a.took_over(), b.took_over()  # two standbys moved at once: both epoch 1
    a.active_seen("b:1", 1, True)
    b.active_seen("a:1", 1, True)
    assert a.decide(1.0) is None and b.decide(1.0) == "stand_down"


def test_a_newer_actives_message_makes_an_active_stand_down_before_its_token_arrives():
    e = Election("a:1", started_s=0.0)
    e.took_over()
    e.epoch_seen("a:1", 1)  # its own: nothing
    e.epoch_seen("b:1", 1)  # same epoch, larger name: nothing
    assert e.decide(1.0) is None
    e.epoch_seen("b:1", 2)
    assert e.decide(1.0) == "stand_down"


def test_the_default_instance_is_host_and_pid_in_key_characters():
    name = default_instance()
    host, pid = name.rsplit(":", 1)
    assert host and int(pid) > 0
    assert not set(name) & set("/*$?#@ ")


# ----------------------------------------------------- a standby applying states


@pytest.mark.slow
def test_a_standby_that_applies_each_state_takes_over_with_bit_identical_tracks(demo_case):
    """The standby ingests the same plots, closes no period and applies the active's
    state after each of the active's periods; from the take-over on it closes the
    periods itself. Its outputs are exactly those the active would have produced."""
    settings, simulation = demo_case
    msgs = simulation.messages
    cut = len(msgs) // 2
    active, standby = Engine(settings), Engine(settings)
    before: list = []
    states = 0
    for _t, key, payload in msgs[:cut]:
        ingest_record(active, key, payload)
        ingest_record(standby, key, payload)
        out = active.poll()
        before += out
        if out:
            data = snapshot(active, out[-1].period, epoch=1, instance="a:1")
            assert restore(standby, data, replace=True) == len(active.tracks)
            states += 1
    assert states > 20 and len(standby.tracks) > 20
    # the standby drops the plots of the periods the active closed, keeps the open ones'
    assert standby.buffer.buffered_plots == active.buffer.buffered_plots > 0
    continued, taken_over = [], []
    for _t, key, payload in msgs[cut:]:
        ingest_record(active, key, payload)
        ingest_record(standby, key, payload)
        continued += active.poll()
        taken_over += standby.poll()
    continued += active.flush()
    taken_over += standby.flush()
    assert [o.period for o in taken_over] == [o.period for o in continued]
    assert taken_over[0].period == before[-1].period + 1  # none skipped, none twice
    for a, b in zip(continued, taken_over, strict=True):
        ca, cb = a.track_columns, b.track_columns
        assert np.array_equal(ca.track_id, cb.track_id)
        assert np.array_equal(ca.x, cb.x, equal_nan=True)
        assert np.array_equal(ca.cov_xy, cb.cov_xy)
    # and the pair's picture is as accurate as one uninterrupted engine's (the same)
    scores = ev.evaluate([o.track_batch for o in before + taken_over], simulation.truth)
    assert scores.track_ids_per_target_mean == 1.0 and scores.false_tracks == 0


def test_a_standby_refuses_a_state_of_another_configuration_and_keeps_its_own(demo_case):
    settings, simulation = demo_case
    active = Engine(settings)
    for _t, key, payload in simulation.messages[:2000]:
        ingest_record(active, key, payload)
        active.poll()
    other = settings.model_copy(update={"radars": settings.radars[:2]})
    standby = Engine(other)
    with pytest.raises(StateMismatch):
        restore(standby, snapshot(active), replace=True)
    assert len(standby.tracks) == 0


# ------------------------------------------------------------------- the stamp


def test_an_actives_stamp_goes_out_in_the_trackbatch_and_reads_back_on_every_path(demo_case):
    settings, simulation = demo_case
    engine = Engine(settings)
    outputs = []
    for _t, key, payload in simulation.messages[:3000]:
        ingest_record(engine, key, payload)
        outputs += engine.poll()
    columns = outputs[-1].track_columns
    assert len(columns) >= 20
    columns.epoch, columns.instance = 3, "fusion-b:4242"
    data = columns.to_msgpack()
    # the column encoder and the dict agree byte for byte, stamp included, and the model takes it
    assert data == msgpack.packb(columns.to_message(), use_bin_type=True)
    message = TrackBatch.model_validate(msgpack.unpackb(data, raw=False))
    assert (message.epoch, message.instance, message.period) == (3, "fusion-b:4242", columns.period)
    assert batch_stamp(data) == ("fusion-b:4242", 3, columns.period)
    # the safety nets' fast reader (and its general path) see it
    plane = SystemPlane(settings.system.center_lat, settings.system.center_lon)
    reader = TrackBatchReader(plane, [r.id for r in settings.radars], fast_min_bytes=0)
    fast = reader.decode(data)
    general = reader.from_object(msgpack.unpackb(data, raw=False))
    for got in (fast, general):
        assert not hasattr(got, "reason"), got
        assert (got.epoch, got.instance) == (3, "fusion-b:4242")
    assert reader.layout_misses == 0
    # without redundancy nothing is added: today's bytes exactly
    columns.epoch = columns.instance = None
    plain = msgpack.unpackb(columns.to_msgpack(), raw=False)
    assert "epoch" not in plain and batch_stamp(columns.to_msgpack()) is None
    # a bad stamp is refused like any schema violation
    bad = msgpack.unpackb(data, raw=False)
    bad["epoch"] = 0
    assert reader.from_object(bad).reason == "schema"
