"""Restart from state (engine/state.py, issue 13 item 3): an engine stopped mid-run and a
new one restored from its snapshot give every aircraft the track id it had, with no
period published twice, and the accuracy of the uninterrupted run."""

from __future__ import annotations

import numpy as np
import pytest

from radar_fusion.engine import Engine
from radar_fusion.engine.state import StateMismatch, load_state, restore, save_state, set_state_aside, snapshot
from radar_fusion.tools import evaluate as ev
from radar_fusion.tools.replay import replay_into_engine


@pytest.mark.slow
def test_a_restored_engine_keeps_every_track_and_id(demo_case, tmp_path):
    settings, simulation = demo_case
    msgs = simulation.messages
    cut = len(msgs) // 2
    full = replay_into_engine(Engine(settings), msgs)

    first = Engine(settings)
    before = replay_into_engine(first, msgs[:cut], flush=False)
    n_tracks = len(first.tracks)
    save_state(first, tmp_path)

    second = Engine(settings)
    assert load_state(second, tmp_path) == n_tracks > 20
    assert snapshot(second) == snapshot(first)  # everything the state holds came back
    assert np.isfinite(second.layer_wind_mps).any()  # the layers' wind among it
    after = replay_into_engine(second, msgs[cut:])

    # periods: the second daemon goes on from the first one's next period, none twice
    periods = [o.period for o in before + after]
    assert periods == sorted(set(periods)) and after[0].period == before[-1].period + 1
    batches = [o.track_batch for o in before + after]
    scores = ev.evaluate(batches, simulation.truth)
    ref = ev.evaluate([o.track_batch for o in full], simulation.truth)
    # every aircraft keeps its id across the restart, as without one
    assert scores.track_ids_per_target_mean == ref.track_ids_per_target_mean == 1.0
    assert scores.false_tracks == 0 and scores.id_swaps == 0
    confirmed_before = {t["track_id"] for t in before[-1].track_batch["tracks"] if t["status"] == "confirmed"}
    confirmed_after = {t["track_id"] for t in after[0].track_batch["tracks"] if t["status"] != "tentative"}
    assert confirmed_before <= confirmed_after
    # the plots of the period that was open are lost with the process: a little accuracy
    assert scores.pos_rms_m == pytest.approx(ref.pos_rms_m, rel=0.05)
    assert scores.gospa_mean_m < 1.1 * ref.gospa_mean_m

    # without the state the second daemon starts over: every aircraft gets a second id
    fresh = replay_into_engine(Engine(settings), msgs[cut:])
    restarted = ev.evaluate([o.track_batch for o in before + fresh], simulation.truth)
    assert restarted.track_ids_per_target_mean > 1.8


def test_a_state_of_another_configuration_or_no_state_is_refused(demo_case, tmp_path):
    settings, simulation = demo_case
    engine = Engine(settings)
    replay_into_engine(engine, simulation.messages[:400], flush=False)
    data = snapshot(engine)
    other = settings.model_copy(update={"radars": settings.radars[:2]})
    with pytest.raises(StateMismatch, match="radars"):
        restore(Engine(other), data)
    singer = settings.model_copy(update={"tracking": settings.tracking.model_copy(update={"filter": "singer"})})
    with pytest.raises(StateMismatch, match="models"):
        restore(Engine(singer), data)
    for junk in (b"", b"\x81\xa1v\x01", b"\xc1garbage"):
        with pytest.raises(StateMismatch):
            restore(Engine(settings), junk)
    with pytest.raises(StateMismatch, match="new engine"):
        restore(engine, data)
    # a refused state changes nothing: here a column of the wrong shape, found after decoding
    import msgpack

    state = msgpack.unpackb(data, raw=False)
    dtype, shape, raw = state["tracks"]["P"]
    state["tracks"]["P"] = [dtype, [shape[0], 36], raw]
    fresh = Engine(settings)
    before = snapshot(fresh)
    with pytest.raises(StateMismatch, match="shape"):
        restore(fresh, msgpack.packb(state, use_bin_type=True))
    assert snapshot(fresh) == before
    assert load_state(Engine(settings), tmp_path) is None  # no file: a fresh start
    # a kill while writing leaves the previous file whole: only complete files are renamed in
    save_state(engine, tmp_path)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["engine-state.msgpack"]
    # a state refused at start is set aside, not overwritten by the next save
    aside = set_state_aside(tmp_path)
    assert aside is not None and aside.name.startswith("engine-state.msgpack.rejected-")
    assert load_state(Engine(settings), tmp_path) is None and aside.exists()


def test_a_state_of_another_period_or_with_a_damaged_field_is_refused_and_changes_nothing(demo_case):
    """Period indices count ``period_s``: a state of other periods would put every plot in
    the past or decades ahead (all refused as late). And every field that decodes but is
    not what it should be is a damaged state (StateMismatch: the daemon sets the file
    aside, a standby counts it), never an error half-way through the restore."""
    import msgpack

    settings, simulation = demo_case
    engine = Engine(settings)
    replay_into_engine(engine, simulation.messages[:400], flush=False)
    state = msgpack.unpackb(snapshot(engine), raw=False)
    assert state["period_s"] == settings.system.period_s
    system = settings.system.model_copy(update={"period_s": settings.system.period_s + 1.0})
    other_period = settings.model_copy(update={"system": system})
    with pytest.raises(StateMismatch, match="periods"):
        restore(Engine(other_period), state)
    older = {k: v for k, v in state.items() if k != "period_s"}  # a state from before period_s was saved
    with pytest.raises(StateMismatch, match="another period_s"):
        restore(Engine(other_period), older)
    assert restore(Engine(settings), older) == len(engine.tracks)  # of this period: read
    # an hour of heartbeats only moved the next period on, the tracks' time not: of this
    # period_s, it is read (the hour's check is for a state without period_s)
    quiet = {**state, "next_period": state["next_period"] + int(2 * 3600 / settings.system.period_s)}
    assert restore(Engine(settings), quiet) == len(engine.tracks)

    def damaged(path: str, value):
        bad = msgpack.unpackb(msgpack.packb(state, use_bin_type=True), raw=False)
        *parents, leaf = path.split(".")
        node = bad
        for key in parents:
            node = node[key]
        node[leaf] = value
        return bad

    cases = [
        ("next_period", "x"),
        ("next_period", float("nan")),
        ("next_period", 10**300),
        ("next_period", True),
        ("track_t_s", "x"),
        ("track_t_s", float("inf")),
        ("address_memory", [[1, 2]]),
        ("address_memory", [[1, 2, [0.0], [[1.0]], 5.0]]),
        ("registration.t_last_s", "x"),
        ("registration.next_update_t_s", [1.0]),
        ("next_id", "seven"),
    ]
    for path, value in cases:
        fresh = Engine(settings)
        before = snapshot(fresh)
        with pytest.raises(StateMismatch):
            restore(fresh, damaged(path, value))
        assert snapshot(fresh) == before, path


def test_a_state_from_before_a_column_was_added_is_read_with_its_fill(demo_case):
    """The track table's columns added after the state format's first release
    (track_management.OPTIONAL_FIELDS: the far-hold's held measurement, the radars of each
    track's latest update) are not in older snapshots: such a state is restored with their
    fill, every other column as saved."""
    import msgpack
    import numpy as np

    from radar_fusion.tracking.track_management import OPTIONAL_FIELDS

    settings, simulation = demo_case
    engine = Engine(settings)
    replay_into_engine(engine, simulation.messages[:400], flush=False)
    state = msgpack.unpackb(snapshot(engine), raw=False)
    for name in OPTIONAL_FIELDS:
        del state["tracks"][name]
    fresh = Engine(settings)
    restore(fresh, msgpack.packb(state, use_bin_type=True))
    old, new = engine.tracks, fresh.tracks
    assert len(new) == len(old) > 20 and (old.update_sources != 0).any()
    for name in OPTIONAL_FIELDS:
        shape, dtype, fill = new._fields[name]
        np.testing.assert_array_equal(getattr(new, name), np.full((len(new),) + shape, fill, dtype=dtype))
    for name in ("track_id", "x", "P", "sources", "seen_by", "mode_s", "mu"):
        np.testing.assert_array_equal(getattr(new, name), getattr(old, name))


def test_a_state_of_the_other_two_stage_setting_is_read_without_the_sensitivities(demo_case):
    """Each track's sensitivity to the radars' biases (``bias_sens``) exists only with the
    two-stage registration on (``[registration] track_innovations``). A state written with
    it off is read by an engine with it on, and the reverse, every other column as saved:
    the sensitivities are not known (NaN: each track takes its next update's, and informs
    the registration only after), and the correction the tracks follow is the one the
    saving engine's tracks followed (no jump at the next period)."""
    import numpy as np

    settings, simulation = demo_case
    off = settings.model_copy(
        update={"registration": settings.registration.model_copy(update={"track_innovations": False})}
    )
    for source, target in ((off, settings), (settings, off)):
        engine = Engine(source)
        replay_into_engine(engine, simulation.messages[:600], flush=False)
        fresh = Engine(target)
        restore(fresh, snapshot(engine))
        old, new = engine.tracks, fresh.tracks
        assert len(new) == len(old) > 20
        assert new.bias_sens.shape == (len(new),) + new._fields["bias_sens"][0]
        assert np.isnan(new.bias_sens).all()  # not known: each track takes its next update's
        for name in ("track_id", "x", "P", "mu", "update_sources"):
            np.testing.assert_array_equal(getattr(new, name), getattr(old, name))
        assert engine._reg_applied.any()  # the demo's radars are biased: a correction is applied
        np.testing.assert_array_equal(fresh._reg_applied, engine._reg_applied)
        # fed on, the tracks of the engine with the setting on learn their sensitivities again
        replay_into_engine(fresh, simulation.messages[600:900], flush=False)
        if fresh.tracks.n_radars:
            assert np.isfinite(fresh.tracks.bias_sens).mean() > 0.9
    on_engine = Engine(settings)
    replay_into_engine(on_engine, simulation.messages[:600], flush=False)
    assert on_engine.tracks.bias_sens.any()  # the setting on: they are kept
    again = Engine(settings)
    restore(again, snapshot(on_engine))
    np.testing.assert_array_equal(again.tracks.bias_sens, on_engine.tracks.bias_sens)
