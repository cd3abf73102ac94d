"""The track life cycle of radar_fusion.tracking.track_management, rule by rule: the
TrackTable's rows and ids, M-of-N confirmation within its window, coasting after a number
of scans of the track's own revisit time, recovery, deletion, the fixed-seconds overrides,
and ended ids (reported once, never reused). Every expected status and id below is worked
out by hand from the rule it tests, in the comment beside it."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest

from radar_fusion.tracking.track_management import (
    COASTING,
    CONFIRMED,
    TENTATIVE,
    LifeCycle,
    TrackTable,
    apply_life_cycle,
)

T, C, K = TENTATIVE, CONFIRMED, COASTING


def rules(**overrides: Any) -> LifeCycle:
    """Every rule spelled out here, so that the tests do not depend on the defaults."""
    values: dict[str, Any] = dict(
        confirm_updates=3,
        confirm_window_s=12.0,
        coast_after_scans=1.5,
        delete_tentative_after_scans=2.5,
        delete_after_scans=6.5,
        coast_after_s=None,
        delete_tentative_after_s=None,
        delete_after_s=None,
    )
    values.update(overrides)
    return LifeCycle(**values)


def table_of(rows: list[dict[str, float]]) -> TrackTable:
    """A table with one row per dict: status, updates, first_t_s, last_update_t_s, revisit_s."""
    table = TrackTable()
    table.append(len(rows))
    for i, row in enumerate(rows):
        for name, value in row.items():
            getattr(table, name)[i] = value
    return table


def row(
    status: int, since_s: float, *, t_s: float, revisit_s: float = 4.0, updates: int = 3, age_s: float = 0.0
) -> dict[str, float]:
    """A track last updated ``since_s`` before ``t_s``, first seen ``max(age_s, since_s)`` before it."""
    return dict(
        status=status,
        updates=updates,
        last_update_t_s=t_s - since_s,
        first_t_s=t_s - max(age_s, since_s),
        revisit_s=revisit_s,
    )


# ------------------------------------------------------------------ the table


def test_append_gives_fresh_consecutive_ids_and_default_rows():
    table = TrackTable()
    assert len(table) == 0 and table.track_id.shape == (0,) and table.P.shape == (0, 6, 6)
    assert table.append(3) == slice(0, 3)
    assert table.track_id.tolist() == [1, 2, 3] and len(table) == 3
    assert table.status.tolist() == [T, T, T] and table.updates.tolist() == [0, 0, 0]
    assert table.x.shape == (3, 6) and not table.x.any() and table.P.shape == (3, 6, 6)
    assert np.isnan(table.first_t_s).all() and np.isnan(table.last_update_t_s).all()
    assert table.append(2) == slice(3, 5)
    assert table.track_id.tolist() == [1, 2, 3, 4, 5]


def test_keep_keeps_each_row_with_its_own_id_and_ids_are_never_reused():
    table = TrackTable()
    table.append(5)
    table.x[:, 0] = 10.0 * table.track_id  # a value that follows its row
    table.P[:, 0, 0] = table.track_id
    table.keep(np.array([True, False, True, False, True]))
    assert len(table) == 3 and table.track_id.tolist() == [1, 3, 5]
    assert table.x[:, 0].tolist() == [10.0, 30.0, 50.0] and table.P[:, 0, 0].tolist() == [1.0, 3.0, 5.0]
    table.keep(np.array([False, True, True]))
    assert table.track_id.tolist() == [3, 5]
    new = table.append(2)
    assert table.track_id[new].tolist() == [6, 7]  # 1, 2 and 4 are gone, not handed out again
    assert table.x[new].tolist() == [[0.0] * 6, [0.0] * 6] and table.x[:2, 0].tolist() == [30.0, 50.0]


# ------------------------------------------------------------------ confirmation


def test_m_of_n_confirmation_within_the_window():
    # 3 updates within 12 s of the first plot confirm; at t = 100 every track was just updated
    t = 100.0
    table = table_of(
        [
            row(T, 0.0, t_s=t, updates=3, age_s=8.0),  # 3 in 8 s: confirmed
            row(T, 0.0, t_s=t, updates=2, age_s=8.0),  # 2 so far, window open: still tentative
            row(T, 0.0, t_s=t, updates=3, age_s=12.0),  # 3 in exactly 12 s: confirmed (the window includes its end)
            row(T, 0.0, t_s=t, updates=3, age_s=12.5),  # 3, but the window ran out: ends
            row(T, 0.0, t_s=t, updates=2, age_s=13.0),  # 2 and the window ran out: ends
            row(T, 0.0, t_s=t, updates=5, age_s=4.0),  # more than M: confirmed
        ]
    )
    ended = apply_life_cycle(table, t, rules())
    assert ended.tolist() == [4, 5]
    assert table.track_id.tolist() == [1, 2, 3, 6] and table.status.tolist() == [C, T, C, C]


def test_confirmation_counts_the_rule_not_a_fixed_three():
    t = 50.0
    table = table_of([row(T, 0.0, t_s=t, updates=2, age_s=3.0), row(T, 0.0, t_s=t, updates=3, age_s=3.0)])
    apply_life_cycle(table, t, rules(confirm_updates=4))
    assert table.status.tolist() == [T, T]  # 2 and 3 of 4
    table.updates[:] = [4, 4]
    apply_life_cycle(table, t, rules(confirm_updates=4))
    assert table.status.tolist() == [C, C]


def test_first_update_confirms_at_once_on_an_address_or_two_radars_with_a_reply():
    """Issue 15 item 5: a track is confirmed in its first period when a Mode S address, or
    two radars, agree; two radars' plots confirm it only beside a transponder reply (Mode S
    or 3/A), at its first update and later: two radars' primary clutter can coincide, and
    did in primary-high at a second update too. M-of-N still confirms such a track."""
    t = 100.0
    table = table_of(
        [row(T, 0.0, t_s=t, updates=1) for _ in range(5)] + [row(T, 0.0, t_s=t, updates=2) for _ in range(3)]
    )
    table.sources[:] = [0b001, 0b011, 0b011, 0b011, 0b001, 0b011, 0b011, 0b001]
    table.mode_s[:] = -1
    table.mode_s[0] = 0x4B1234
    table.mode3a[:] = [-1, -1, 0o2341, -1, -1, -1, 0o2341, -1]
    table.initiated[5:] = True  # a velocity from the second update on
    apply_life_cycle(table, t, rules(confirm_radars=2, confirm_mode_s=True, confirm_agreed_updates=1))
    # address; two radars, no reply; two radars and 3/A; two radars, no reply; one radar;
    # 2nd update: two radars, no reply; two radars and 3/A; one radar
    assert table.status.tolist() == [C, T, C, T, T, T, C, T]
    table.updates[5] = 3
    apply_life_cycle(table, t, rules(confirm_radars=2, confirm_mode_s=True, confirm_agreed_updates=1))
    assert table.status[5] == C  # M-of-N


def test_a_one_radar_track_beside_a_shown_track_of_its_code_is_not_confirmed():
    """Issue 15 item 7: a tentative track that M-of-N would confirm, without an address and
    seen by one radar, stays tentative while a confirmed track within
    duplicate_code_radius_m (here 20 km) carries its identity code."""
    t = 100.0
    table = table_of([row(C, 0.0, t_s=t), row(C, 0.0, t_s=t)] + [row(T, 0.0, t_s=t, updates=3) for _ in range(6)])
    table.mode3a[:] = [0o2341, 0o7000, 0o2341, 0o2341, 0o2341, 0o2341, 0o7000, 0o2342]
    table.seen_by[:] = [0b011, 0b011, 0b100, 0b100, 0b100, 0b110, 0b100, 0b100]
    table.mode_s[:] = -1
    table.mode_s[4] = 0x4B1234
    # the two shown tracks at (0, 0); the others 15 km off (the second 25 km, the last 5 km)
    east_m = [0.0, 0.0, 15_000.0, 25_000.0, 15_000.0, 15_000.0, 15_000.0, 3_000.0]
    north_m = [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 4_000.0]
    table.x[:, 0], table.x[:, 3] = east_m, north_m
    counters: dict[str, int] = {}
    apply_life_cycle(table, t, rules(duplicate_code_radius_m=20_000.0), counters=counters)
    # within 20 km: withheld; 25 km; an address; two radars; conspicuity 7000; another code
    assert table.status.tolist() == [C, C, T, C, C, C, C, C]
    assert counters == {"tracks_withheld_beside_code": 1}  # on health: it may be a second aircraft
    table.status[2] = T
    apply_life_cycle(table, t, rules(duplicate_code_radius_m=0.0))
    assert table.status[2] == C


def test_a_one_radar_track_shown_to_be_another_aircraft_of_its_code_is_confirmed():
    """The same withheld track (radar 2, code 2341, 5 km from a shown track of that code) is
    confirmed when the shown track is another aircraft: their Mode C levels, both of this
    period, lie more than duplicate_code_level_gap_ft (300 ft) apart (a wild plot or a
    reflection carries its aircraft's own). Radar 2 seeing both in this period is no proof (a
    reflection comes in the aircraft's own scan); two levels 200 ft apart, a level unknown, or
    the shown track's level of an earlier period: withheld."""
    t = 100.0
    # per case: the shown track's sources this period, its FL, the tentative track's FL
    cases = [(0b001, 350.0, 350.0), (0b100, 350.0, 350.0), (0b101, 350.0, 351.0), (0b001, 350.0, 354.0),
             (0b001, 350.0, 346.0), (0b001, 350.0, 352.0), (0b001, np.nan, 360.0), (0b000, 350.0, np.nan),
             (0b000, 350.0, 354.0)]  # fmt: skip
    got = []
    for shown_sources, shown_fl, fl in cases:
        table = table_of([row(C, 0.0, t_s=t), row(T, 0.0, t_s=t, updates=3)])
        table.mode3a[:] = 0o2341
        table.mode_s[:] = -1
        table.seen_by[:] = [0b101, 0b100]
        table.sources[:] = [shown_sources, 0b100]
        table.alt_x[:, 0] = [shown_fl, fl]
        table.x[:, 0], table.x[:, 3] = [0.0, 3_000.0], [0.0, 4_000.0]
        apply_life_cycle(table, t, rules(duplicate_code_radius_m=20_000.0, duplicate_code_level_gap_ft=300.0))
        got.append(int(table.status[1]))
    # the last: levels apart, but the shown track's is of an earlier period (not updated in this one)
    assert got == [T, T, T, C, C, T, T, T, T]


# ------------------------------------------------------------------ coasting


def test_a_confirmed_track_coasts_after_coast_after_scans_of_its_own_revisit_time():
    # 1.5 scans: 6 s for a track seen by a 4 s radar, 18 s for one seen by a 12 s radar
    t = 1000.0
    table = table_of(
        [
            row(C, 5.0, t_s=t, revisit_s=4.0),  # 5 <= 6: confirmed
            row(C, 6.0, t_s=t, revisit_s=4.0),  # 6 = 6, not more: confirmed
            row(C, 7.0, t_s=t, revisit_s=4.0),  # 7 > 6: coasting
            row(C, 7.0, t_s=t, revisit_s=12.0),  # 7 <= 18: confirmed, the same silence in its scans is short
            row(C, 19.0, t_s=t, revisit_s=12.0),  # 19 > 18: coasting
            row(K, 9.0, t_s=t, revisit_s=4.0),  # coasting, not updated: still coasting (9 <= 26, not ended)
        ]
    )
    ended = apply_life_cycle(table, t, rules())
    assert ended.tolist() == []
    assert table.status.tolist() == [C, C, K, C, K, K]


def test_a_coasting_track_updated_in_this_period_is_confirmed_again():
    t = 200.0
    table = table_of(
        [
            row(K, 0.0, t_s=t, age_s=60.0),  # updated at t: confirmed again
            row(K, 4.0, t_s=t, age_s=60.0),  # last update 4 s ago: stays coasting
            row(K, 0.0, t_s=t, age_s=60.0, revisit_s=12.0),
        ]
    )
    apply_life_cycle(table, t, rules())
    assert table.status.tolist() == [C, K, C]


# ------------------------------------------------------------------ deletion


def test_tentative_tracks_end_after_delete_tentative_after_scans():
    # 2.5 scans of 4 s = 10 s; of 12 s = 30 s. A wide window, so that only silence ends them.
    t = 300.0
    table = table_of(
        [
            row(T, 10.0, t_s=t, updates=1),  # 10 = 10: kept
            row(T, 10.5, t_s=t, updates=1),  # 10.5 > 10: ends
            row(T, 10.5, t_s=t, updates=1, revisit_s=12.0),  # 10.5 <= 30: kept
            row(T, 31.0, t_s=t, updates=2, revisit_s=12.0),  # 31 > 30: ends
        ]
    )
    ended = apply_life_cycle(table, t, rules(confirm_window_s=100.0))
    assert ended.tolist() == [2, 4]
    assert table.track_id.tolist() == [1, 3] and table.status.tolist() == [T, T]


def test_confirmed_and_coasting_tracks_end_after_delete_after_scans():
    # 6.5 scans of 4 s = 26 s; of 12 s = 78 s
    t = 500.0
    table = table_of(
        [
            row(K, 26.0, t_s=t),  # 26 = 26: kept, coasting
            row(K, 27.0, t_s=t),  # 27 > 26: ends
            row(C, 27.0, t_s=t),  # confirmed, silent 27 s: coasts and ends in one step
            row(C, 27.0, t_s=t, revisit_s=12.0),  # 27 > 18 coasts, 27 <= 78 kept
            row(K, 79.0, t_s=t, revisit_s=12.0),  # 79 > 78: ends
        ]
    )
    ended = apply_life_cycle(table, t, rules())
    assert ended.tolist() == [2, 3, 5]
    assert table.track_id.tolist() == [1, 4] and table.status.tolist() == [K, K]


# ------------------------------------------------------------------ fixed seconds


@pytest.mark.parametrize("revisit_s", [4.0, 12.0])
def test_fixed_seconds_override_the_scans_whatever_the_revisit_time(revisit_s):
    # coast after 5 s, a tentative track ends after 3 s, any other after 20 s; the scan
    # counts (6 / 18 s, 10 / 30 s, 26 / 78 s) no longer matter
    t = 700.0
    table = table_of(
        [
            row(C, 4.9, t_s=t, revisit_s=revisit_s),  # 4.9 <= 5: confirmed
            row(C, 5.5, t_s=t, revisit_s=revisit_s),  # 5.5 > 5: coasting
            row(T, 3.0, t_s=t, revisit_s=revisit_s, updates=1),  # 3 = 3: kept
            row(T, 3.5, t_s=t, revisit_s=revisit_s, updates=1),  # 3.5 > 3: ends
            row(K, 20.0, t_s=t, revisit_s=revisit_s),  # 20 = 20: kept
            row(K, 21.0, t_s=t, revisit_s=revisit_s),  # 21 > 20: ends
        ]
    )
    ended = apply_life_cycle(table, t, rules(coast_after_s=5.0, delete_tentative_after_s=3.0, delete_after_s=20.0))
    assert ended.tolist() == [4, 6]
    assert table.track_id.tolist() == [1, 2, 3, 5] and table.status.tolist() == [C, K, T, K]


def test_each_fixed_override_replaces_only_its_own_rule():
    # only coast_after_s is fixed (2 s); deletion still counts 6.5 scans of 4 s = 26 s
    t = 800.0
    table = table_of([row(C, 2.5, t_s=t), row(K, 25.0, t_s=t), row(K, 27.0, t_s=t)])
    ended = apply_life_cycle(table, t, rules(coast_after_s=2.0))
    assert ended.tolist() == [3] and table.status.tolist() == [K, K]


# ------------------------------------------------------------------ a whole life


def update(table: TrackTable, i: int, t_s: float) -> None:
    """What an update does to the life-cycle fields (the filter's part left out)."""
    if math.isnan(table.first_t_s[i]):
        table.first_t_s[i] = t_s
    table.last_update_t_s[i] = t_s
    table.updates[i] += 1
    table.revisit_s[i] = 4.0


def test_one_track_from_birth_to_end_and_its_id_reported_once():
    """Periods of 4 s, a 4 s radar: coast after 6 s of silence, end after 26 s."""
    table = TrackTable()
    table.append(1)
    updated_at = {0.0, 4.0, 8.0, 20.0}
    # hand-worked: t=0, 4 tentative (1, 2 updates); t=8 the 3rd update in 8 <= 12 s confirms;
    # t=12 silent 4 s; t=16 silent 8 > 6 coasts; t=20 updated, confirmed again; t=24
    # silent 4; t=28 silent 8 coasts; t=44 silent 24 <= 26 still coasting; t=48 silent 28 > 26 ends
    expected = {0.0: T, 4.0: T, 8.0: C, 12.0: C, 16.0: K, 20.0: C, 24.0: C, 28.0: K, 32.0: K, 36.0: K, 40.0: K, 44.0: K}
    reported: list[int] = []
    for t in np.arange(0.0, 60.0, 4.0):
        t = float(t)
        if t in updated_at:
            update(table, 0, t)
        ended = apply_life_cycle(table, t, rules())
        reported += ended.tolist()
        if t in expected:
            assert len(table) == 1 and int(table.status[0]) == expected[t], t
        else:
            assert len(table) == 0, t
        if t == 48.0:
            assert ended.tolist() == [1]
    assert reported == [1]  # once, at t = 48, and never again
    new = table.append(1)
    assert table.track_id[new].tolist() == [2]


def test_ended_ids_are_a_copy_and_later_tracks_get_new_ids():
    t = 100.0
    table = table_of([row(T, 11.0, t_s=t, updates=1), row(C, 0.0, t_s=t), row(T, 11.0, t_s=t, updates=1)])
    ended = apply_life_cycle(table, t, rules(confirm_window_s=100.0))
    assert ended.tolist() == [1, 3] and table.track_id.tolist() == [2]
    table.track_id[:] = 99  # the table's columns are its own; the report stays as it was
    assert ended.tolist() == [1, 3]
    table.track_id[:] = 2
    new = table.append(2)
    assert table.track_id[new].tolist() == [4, 5]


def test_log_miss_probability_by_hand():
    """ln P(all radars that should see a track missed it): radar 0 (4 s, Pd 0.9) and radar
    1 (12 s, Pd 0.7), 100 km apart, each covering 150 km."""
    from radar_fusion.tracking.track_management import log_miss_probability

    site_xy = np.array([[0.0, 0.0], [100_000.0, 0.0]])
    max_range = np.array([150_000.0, 150_000.0])
    rotation = np.array([4.0, 12.0])
    pd = np.array([0.9, 0.7])
    seen = np.array([0b11, 0b01, 0b01, 0b10], dtype=np.uint64)
    xy = np.array([[50_000.0, 0.0], [50_000.0, 0.0], [-200_000.0, 0.0], [300_000.0, 0.0]])
    last_update = np.full(4, 100.0)
    swept = np.array([112.0, 112.0])  # both radars swept 12 s since
    got = log_miss_probability(seen, xy, last_update, swept, site_xy, max_range, rotation, pd)
    # both radars: 3 scans of radar 0 and 1 scan of radar 1 all missed
    assert got[0] == pytest.approx(3 * math.log(0.1) + 1 * math.log(0.3))
    assert got[1] == pytest.approx(3 * math.log(0.1))  # radar 1 never saw it: not counted
    assert got[2] == -math.inf  # out of its only radar's range: nothing can see it
    assert got[3] == -math.inf  # 200 km from radar 1, beyond its 150 km: likewise
    # radar 1 fell silent 4 s after the update: one third of its scan counts; radar 0 swept on
    got = log_miss_probability(seen, xy, last_update, np.array([112.0, 104.0]), site_xy, max_range, rotation, pd)
    assert got[0] == pytest.approx(3 * math.log(0.1) + (4.0 / 12.0) * math.log(0.3))
    # a radar never heard from (watermark -inf) has swept nothing
    got = log_miss_probability(seen, xy, last_update, np.array([-math.inf, 112.0]), site_xy, max_range, rotation, pd)
    assert got[0] == pytest.approx(1 * math.log(0.3)) and got[1] == 0.0


def test_merging_young_tracks_keeps_the_one_most_radars_agreed_on():
    """Three one-update tracks carry one address: the first from radar 0 alone, the second
    from radars 1 and 2 together, the third (a wild plot, the latest measurement, this
    period's only one) from radar 0 alone. None is established, so the survivor (the oldest
    id) takes the state of the member two radars agreed on in its update, not the latest
    one; with a tie the latest measurement wins. The count is of each member's latest update
    (``update_sources``), not of this period's radars (``sources``): counted so, the members
    of earlier periods had none and a new one-radar wild plot won (4,000x10 with 3 % wild
    plots: a two-radar track replaced by a wild run 5 km off, a false track for 40 s)."""
    from radar_fusion.tracking.track_management import merge_same_address

    def table(sources, t_state):
        tab = TrackTable()
        rows = tab.append(len(sources))
        tab.mode_s[rows] = 0x4B1234
        tab.updates[rows] = 1
        tab.update_sources[rows] = np.array(sources, dtype=np.uint64)
        now = np.asarray(t_state) == max(t_state)  # only the latest member was updated this period
        tab.sources[rows] = np.where(now, tab.update_sources[rows], np.uint64(0))
        tab.t_state_s[rows] = t_state
        tab.x[rows, 0] = np.arange(len(sources)) * 1_000.0  # x position tells the members apart
        return tab

    tab = table([0b001, 0b110, 0b001], [1.0, 2.0, 3.0])
    _, merged = merge_same_address(tab, confirm_updates=3)
    assert len(tab) == 1 and tab.track_id[0] == 1 and merged.tolist() == [2, 3]
    assert tab.x[0, 0] == 1_000.0  # the two-radar member's state
    tab = table([0b001, 0b010], [1.0, 2.0])  # one radar each: the latest
    merge_same_address(tab, confirm_updates=3)
    assert tab.x[0, 0] == 1_000.0 and tab.t_state_s[0] == 2.0


def test_merging_young_tracks_keeps_the_one_with_a_velocity():
    """An address's track of two updates (its velocity from the two-point initiation) got
    no plot this period; a wild plot of the address, too far for the aircraft to have flown
    there, started a one-plot track beside it. The merge keeps the two-update state (before
    this rule the one-plot track won on this period's radar count: 7 km off, speed zero)."""
    from radar_fusion.tracking.track_management import merge_same_address

    tab = TrackTable()
    rows = tab.append(2)
    tab.mode_s[rows] = 0x3A7C42
    tab.updates[rows] = [2, 1]
    tab.sources[rows] = np.array([0, 0b001], dtype=np.uint64)  # only the wild one has a plot now
    tab.t_state_s[rows] = [8.0, 11.0]
    tab.x[rows] = [[-113_329.0, -32.0, 0.0, 24_689.0, -128.0, 0.0], [-120_827.0, 0.0, 0.0, 24_635.0, 0.0, 0.0]]
    _, merged = merge_same_address(tab, confirm_updates=3)
    assert len(tab) == 1 and tab.track_id[0] == 1 and merged.tolist() == [2]
    assert tab.x[0, 0] == -113_329.0 and tab.x[0, 1] == -32.0 and tab.t_state_s[0] == 8.0 and tab.updates[0] == 2


def test_a_merged_track_takes_the_bias_sensitivity_of_the_state_it_takes():
    """With the two-stage registration a track's ``bias_sens`` is the sensitivity of its own
    state to the radars' biases: the survivor of a merge takes it with the state, from the
    member that followed the aircraft, or it would follow the correction, and inform it,
    with another track's."""
    from radar_fusion.tracking.track_management import merge_same_address

    tab = TrackTable(n_radars=3)
    rows = tab.append(2)
    tab.mode_s[rows] = 0x3A7C42
    tab.updates[rows] = [5, 4]
    tab.update_sources[rows] = np.array([0b001, 0b110], dtype=np.uint64)
    tab.sources[rows] = np.array([0, 0b110], dtype=np.uint64)
    tab.t_state_s[rows] = [8.0, 11.0]  # the second was updated last: its state is kept
    tab.x[rows, 0] = [0.0, 1_000.0]
    tab.bias_sens[rows] = 0.0
    tab.bias_sens[0, :, 0] = 1.0  # radar 0's plots made the first
    tab.bias_sens[1, :, 1:] = 0.5  # radars 1 and 2 the second
    second = tab.bias_sens[1].copy()
    merge_same_address(tab, confirm_updates=3)
    assert len(tab) == 1 and tab.track_id[0] == 1 and tab.x[0, 0] == 1_000.0
    np.testing.assert_array_equal(tab.bias_sens[0], second)


@pytest.mark.parametrize(
    ("first_t_s", "t_state_s", "held"),
    [
        ([0.0, 0.0], [1.0, 3.0], 0),  # one period: the earlier plot is held beside the later
        ([0.0, 4.0], [1.0, 7.0], None),  # an earlier period's: the later plots could not reach it
        ([0.0, 0.0, 0.0], [1.0, 2.0, 3.0], 1),  # the latest of the others
    ],
)
def test_merging_one_plot_tracks_of_one_period_holds_the_other_first_plot(first_t_s, t_state_s, held):
    """One-plot tracks of one address started in one period (each its own cluster: their
    plots contradict each other): the kept one (the latest) holds the latest other's first
    measurement, its covariance, time and radars (held_*), for the next measurement to choose
    from (engine._choose_first). A member of an earlier period is not held."""
    from radar_fusion.tracking.track_management import merge_same_address

    tab = TrackTable()
    rows = tab.append(len(t_state_s))
    tab.mode_s[rows] = 0x4B1234
    tab.updates[rows] = 1
    tab.first_t_s[rows] = first_t_s
    tab.t_state_s[rows] = t_state_s
    tab.update_sources[rows] = np.uint64(1) << np.arange(len(t_state_s), dtype=np.uint64)
    tab.z1_m[rows] = np.stack([np.arange(len(t_state_s)) * 1_000.0, np.zeros(len(t_state_s))], axis=1)
    tab.R1_m2[rows] = np.eye(2) * (100.0 + np.arange(len(t_state_s)))[:, None, None]
    tab.x[rows, 0] = tab.z1_m[rows, 0]
    merge_same_address(tab, confirm_updates=3)
    assert len(tab) == 1 and tab.track_id[0] == 1 and tab.x[0, 0] == 1_000.0 * (len(t_state_s) - 1)
    if held is None:
        assert np.isnan(tab.held_t_s[0])
    else:
        assert tab.held_t_s[0] == t_state_s[held] and tab.held_z_m[0, 0] == 1_000.0 * held
        assert tab.held_R_m2[0, 0, 0] == 100.0 + held and tab.held_sources[0] == 1 << held


def test_track_table_grows_without_copying_and_keeps_what_callers_hold() -> None:
    """Appending writes into spare capacity (the columns are views of larger buffers, so the
    model covariances are not copied every period); keep() compacts them in place; a column
    assigned from outside (a restored state) is adopted."""
    table = TrackTable(n_models=2)
    rows = table.append(3)
    table.x[rows] = np.arange(18.0).reshape(3, 6)
    before = table.P_models
    more = table.append(2)
    assert np.shares_memory(before, table.P_models)  # grown in place: no copy
    assert table.track_id.tolist() == [1, 2, 3, 4, 5] and (more.start, more.stop) == (3, 5)
    assert (table.x[3:] == 0.0).all() and np.isnan(table.mu[3:]).all()  # fresh rows default-filled
    table.keep(np.array([True, False, True, True, False]))
    assert np.shares_memory(before, table.P_models)  # compacted in place
    assert table.track_id.tolist() == [1, 3, 4]
    np.testing.assert_array_equal(table.x[:2], np.arange(18.0).reshape(3, 6)[[0, 2]])
    table.x = np.full((3, 6), 7.0)  # assigned from outside, as a restored state does
    table.append(200)  # past the buffer's capacity
    assert len(table) == 203 and (table.x[:3] == 7.0).all() and table.x.flags.c_contiguous
    assert table.track_id[-1] == 205
