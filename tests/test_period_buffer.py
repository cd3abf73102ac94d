"""Event-time periods and the engine's ingest rules: watermarks, lateness, silent radars,
duplicates, sequence gaps, unknown radars, range limits — all counted, none fatal."""

from __future__ import annotations

import numpy as np
import pytest

from radar_fusion.config import settings_from_dict
from radar_fusion.engine import Engine
from radar_fusion.engine.admission import FUTURE_RELOCK_BATCHES
from radar_fusion.engine.watermarks import Watermarks
from radar_fusion.wire import DecodedPlots, RadarStatus

T0 = 1_533_110_400.0  # 2018-08-01 08:00 UTC, a multiple of the 4 s period


def settings(**system):
    return settings_from_dict(
        {
            "system": {
                "center_lat": 46.0,
                "center_lon": 8.0,
                "period_s": 4.0,
                "allowed_lateness_s": 1.0,
                "radar_timeout_s": 20.0,
                **system,
            },
            "radars": [
                {
                    "id": "a",
                    "lat": 46.2,
                    "lon": 7.8,
                    "sigma_range_m": 50,
                    "sigma_azimuth_deg": 0.1,
                    "rotation_period_s": 4.0,
                    "max_range_m": 200_000,
                },
                {
                    "id": "b",
                    "lat": 45.8,
                    "lon": 8.3,
                    "sigma_range_m": 50,
                    "sigma_azimuth_deg": 0.1,
                    "rotation_period_s": 4.0,
                },
            ],
            "outliers": {"enabled": False},
        }
    )


def plots(radar_id, seq, t_s, range_m=50_000.0, azimuth_deg=90.0):
    t = np.atleast_1d(np.asarray(t_s, float))
    n = t.size
    return DecodedPlots(
        radar_id,
        seq,
        t,
        np.full(n, range_m),
        np.full(n, azimuth_deg),
        np.full(n, 300.0),
        np.full(n, -1),
        np.full(n, -1),
        np.full(n, -1),
        np.zeros(n, np.int8),
        np.full(n, np.nan),
        np.full(n, np.nan),
        np.full(n, np.nan),
    )


def test_a_period_closes_only_when_every_live_radar_has_passed_it():
    eng = Engine(settings())
    eng.ingest_plots(plots("a", 1, T0 + 1.0))
    eng.ingest_plots(plots("a", 2, T0 + 6.0))
    # radar b has never reported, so it is not live: a alone closes [T0, T0+4)
    assert [o.t_s for o in eng.poll()] == [T0 + 4.0]
    eng2 = Engine(settings())
    eng2.ingest_plots(plots("a", 1, T0 + 1.0))
    eng2.ingest_plots(plots("b", 1, T0 + 2.0))
    eng2.ingest_plots(plots("a", 2, T0 + 6.0))
    assert eng2.poll() == []  # b's watermark (T0+2) has not passed T0+4
    eng2.ingest_status(RadarStatus(radar_id="b", t=T0 + 4.5, kind="sector", sector=3))
    out = eng2.poll()
    assert [o.period for o in out] == [int(T0 // 4)] and out[0].t_s == T0 + 4.0 and out[0].n_plots == 2


def test_single_radar_closes_periods_with_its_own_watermark():
    eng = Engine(settings())
    eng.ingest_plots(plots("a", 1, T0 + 1.0))
    assert eng.poll() == []
    eng.ingest_plots(plots("a", 2, T0 + 4.0))  # in order so far: no lateness to wait for
    assert [o.t_s for o in eng.poll()] == [T0 + 4.0]


def test_a_silent_radar_stops_holding_periods_open():
    eng = Engine(settings())
    eng.ingest_plots(plots("b", 1, T0 + 0.5))
    for k in range(1, 12):  # radar a goes on for 44 s; b is silent after T0+0.5
        eng.ingest_plots(plots("a", k, T0 + 4.0 * k))
    closed = [o.t_s for o in eng.poll()]
    # b holds periods open until it has been silent for radar_timeout_s (20 s)
    assert closed and closed[-1] >= T0 + 36.0
    assert not eng.health()["radars"]["b"]["live"] and eng.health()["radars"]["a"]["live"]


def test_late_plots_are_counted_not_silently_lost():
    eng = Engine(settings())
    eng.ingest_plots(plots("a", 1, [T0 + 1.0, T0 + 9.0]))
    assert [o.t_s for o in eng.poll()] == [T0 + 4.0, T0 + 8.0]  # watermark T0+9, in order: no lateness
    assert eng.ingest_plots(plots("a", 2, [T0 + 2.0, T0 + 9.5])) == 1
    assert eng.rejected["plot_late"] == 1 and eng.health()["radars"]["a"]["rejected"] == {"plot_late": 1}
    # 7 s behind its own watermark: a's lateness is now the most allowed (1 s)
    assert eng.health()["radars"]["a"]["lateness_s"] == 1.0


def test_duplicates_gaps_and_out_of_order_batches():
    eng = Engine(settings())
    assert eng.ingest_plots(plots("a", 5, T0 + 1.0)) == 1
    assert eng.ingest_plots(plots("a", 5, T0 + 1.1)) == 0
    assert eng.rejected["duplicate"] == 1
    eng.ingest_plots(plots("a", 9, T0 + 1.5))  # 6, 7, 8 lost on the way
    assert eng.radars[0].seq_gaps == 3
    assert eng.ingest_plots(plots("a", 7, T0 + 1.2)) == 1  # late arrival of 7: accepted
    assert eng.counters["batches_out_of_order"] == 1


def test_unknown_radar_future_and_beyond_range():
    eng = Engine(settings())
    assert eng.ingest_plots(plots("zz", 1, T0 + 1.0)) == 0
    assert eng.rejected["unknown_radar"] == 1
    eng.ingest_plots(plots("a", 1, T0 + 1.0))
    assert eng.ingest_plots(plots("a", 2, T0 + 1.0e6)) == 0
    assert eng.rejected["plot_future"] == 1
    assert eng.ingest_plots(plots("a", 3, T0 + 1.5, range_m=250_000.0)) == 0
    assert eng.rejected["plot_beyond_max_range"] == 1


def test_flush_closes_what_is_buffered():
    eng = Engine(settings())
    eng.ingest_plots(plots("a", 1, [T0 + 1.0, T0 + 5.0, T0 + 9.0]))
    out = eng.flush()
    assert [o.t_s for o in out] == [T0 + 4.0, T0 + 8.0, T0 + 12.0]
    assert sum(o.n_plots for o in out) == 3 and eng.buffer.buffered_plots == 0


def test_mode_s_bds50_columns_ride_with_their_plots_into_the_period():
    """A plot's roll, ground speed and track angle (BDS 5,0; NaN none) stay with it through
    admission and the buffer, into the closed period's PlotChunk."""
    eng = Engine(settings())
    p = plots("a", 1, [T0 + 3.0, T0 + 1.0, T0 + 2.0, T0 + 5.0])
    p.roll_deg = np.array([3.0, np.nan, -1.0, 7.0])
    p.ground_speed_mps = np.array([230.0, 120.5, np.nan, 99.0])
    p.track_angle_deg = np.array([10.0, 359.5, np.nan, 45.0])
    assert eng.ingest_plots(p) == 4
    _, _, chunk = eng.buffer.pop_period(force=True)
    order = np.argsort(chunk.t_s)
    assert chunk.t_s[order].tolist() == [T0 + 1.0, T0 + 2.0, T0 + 3.0]
    np.testing.assert_array_equal(chunk.roll_deg[order], [np.nan, -1.0, 3.0])
    np.testing.assert_array_equal(chunk.ground_speed_mps[order], [120.5, np.nan, 230.0])
    np.testing.assert_array_equal(chunk.track_angle_deg[order], [359.5, np.nan, 10.0])
    _, _, chunk = eng.buffer.pop_period(force=True)
    assert chunk.ground_speed_mps.tolist() == [99.0] and chunk.track_angle_deg.tolist() == [45.0]


def test_mode_s_bds60_columns_ride_with_their_plots_into_the_period():
    """A plot's magnetic heading and indicated airspeed (BDS 6,0; NaN none) stay with it
    through admission (a plot refused beyond the radar's range: the rows picked), the
    buffer (batches concatenated, split at the period's end) into the closed period's
    PlotChunk; a batch made without them (an older caller) rides along with NaN."""
    eng = Engine(settings())
    p = plots("a", 1, [T0 + 3.0, T0 + 1.0, T0 + 2.0, T0 + 5.0])
    p.range_m[2] = 250_000.0  # beyond max_range_m: refused
    p.magnetic_heading_deg = np.array([270.0, np.nan, 12.5, 0.0])
    p.indicated_airspeed_mps = np.array([128.6, 77.0, 99.0, np.nan])
    p.ground_speed_mps = np.array([230.0, np.nan, np.nan, 99.0])
    assert eng.ingest_plots(p) == 3 and eng.rejected["plot_beyond_max_range"] == 1
    assert eng.ingest_plots(plots("a", 2, T0 + 3.5)) == 1  # without them: NaN
    _, _, chunk = eng.buffer.pop_period(force=True)
    order = np.argsort(chunk.t_s)
    assert chunk.t_s[order].tolist() == [T0 + 1.0, T0 + 3.0, T0 + 3.5]
    np.testing.assert_array_equal(chunk.magnetic_heading_deg[order], [np.nan, 270.0, np.nan])
    np.testing.assert_array_equal(chunk.indicated_airspeed_mps[order], [77.0, 128.6, np.nan])
    np.testing.assert_array_equal(chunk.ground_speed_mps[order], [np.nan, 230.0, np.nan])
    _, _, chunk = eng.buffer.pop_period(force=True)
    assert chunk.magnetic_heading_deg.tolist() == [0.0] and np.isnan(chunk.indicated_airspeed_mps).all()
    assert chunk.ground_speed_mps.tolist() == [99.0]


def test_per_radar_buffer_limit_refuses_and_counts_the_excess():
    """Bounded memory: radar b holds the periods open, radar a floods; beyond its limit a's
    plots are refused as buffer_full (the earliest kept), and b's plots still get in."""
    eng = Engine(settings(max_buffered_plots_per_radar=5))
    eng.ingest_plots(plots("b", 1, T0 + 0.5))
    assert eng.ingest_plots(plots("a", 1, T0 + 1.0 + 0.1 * np.arange(8)[::-1])) == 5
    assert eng.rejected["buffer_full"] == 3
    assert eng.health()["radars"]["a"]["rejected"] == {"buffer_full": 3}
    assert eng.ingest_plots(plots("a", 2, T0 + 2.0)) == 0 and eng.rejected["buffer_full"] == 4
    assert eng.ingest_plots(plots("b", 2, T0 + 1.5)) == 1
    out = eng.flush()
    kept = sum(o.n_plots for o in out)
    assert kept == 7  # 5 of a, 2 of b
    assert eng.buffer.buffered_plots == 0 and eng.buffer.room(0) == 5  # room again after the periods closed


def test_a_radar_back_from_a_long_outage_is_accepted_and_a_jump_is_not():
    eng = Engine(settings())
    for k in range(1, 11):  # both radars every 4 s; a falls silent after T0+16
        if k <= 4:
            eng.ingest_plots(plots("a", k, T0 + 4.0 * k))
        eng.ingest_plots(plots("b", k, T0 + 4.0 * k + 0.5))
    assert eng.ingest_plots(plots("a", 5, T0 + 40.0)) == 1  # in step with b again: accepted at once
    assert eng.ingest_plots(plots("b", 11, T0 + 90.0)) == 0  # b jumps 50 s: refused
    assert eng.rejected == {"plot_future": 1}
    # A single radar back after a longer outage than the limit: re-locked after 8 batches.
    solo = Engine(settings())
    solo.ingest_plots(plots("a", 1, T0 + 1.0))
    accepted = [solo.ingest_plots(plots("a", k, T0 + 100.0 + 0.5 * k)) for k in range(2, 12)]
    assert accepted == [0] * 8 + [1, 1] and solo.counters["radar_time_relocks"] == 1


class TwoRadars:
    """An engine of radars a and b, each batch numbered on (plots() helper)."""

    def __init__(self, **system):
        self.eng = Engine(settings(**system))
        self.seq = {"a": 0, "b": 0}

    def send(self, radar_id, t_s):
        self.seq[radar_id] += 1
        return self.eng.ingest_plots(plots(radar_id, self.seq[radar_id], t_s))

    def status(self, radar_id, t_s):
        self.eng.ingest_status(RadarStatus(radar_id=radar_id, t=t_s, kind="heartbeat"))


def test_one_radars_clock_jump_is_refused_for_as_long_as_the_other_keeps_time():
    """Radar b's clock jumps an hour ahead while a keeps time: b is never followed (it
    would lead every period, make a look silent and turn a's good plots late)."""
    r = TwoRadars()
    for k in range(30):
        r.send("a", T0 + k)
        r.send("b", T0 + k + 0.3)
        r.eng.poll()
    took_a = []
    for k in range(30, 90):
        assert r.send("b", T0 + k + 3600.0) == 0
        took_a.append(r.send("a", T0 + k))
        r.eng.poll()
    assert took_a == [1] * 60
    assert r.eng.rejected == {"plot_future": 60} and r.eng.counters["radar_time_relocks"] == 0
    assert r.eng.health()["radars"]["a"]["live"] is True


def test_a_burst_of_forged_status_times_is_not_followed():
    """Nine heartbeats of radar b all stamped far ahead, nothing else between them: one
    stamp repeated is no running clock, so b's time is not re-locked to it."""
    r = TwoRadars()
    for k in range(10):
        r.send("a", T0 + k)
        r.send("b", T0 + k + 0.3)
    for _ in range(9):
        r.status("b", 9.9e9)
    assert r.eng.rejected == {"status_future": 9} and r.eng.counters["radar_time_relocks"] == 0
    assert [r.send(rid, T0 + 10 + k) for k in range(5) for rid in "ab"] == [1] * 10
    assert r.eng.buffer.closed_until_s < T0 + 60


def test_a_radar_whose_clock_runs_fast_is_held_to_the_others_time():
    """Radar b's clock gains 0.8 s a second (drift, or a front-end stepping its time):
    measured from its own watermark it could walk ahead until a looked silent. Held to a's
    time, b's plots beyond the margin are refused and a's are all taken."""
    r = TwoRadars()
    took_a, took_b = [], []
    for k in range(120):
        took_a.append(r.send("a", T0 + k))
        took_b.append(r.send("b", T0 + 1.8 * k + 0.3))
        r.eng.poll()
    assert took_a == [1] * 120
    assert r.eng.rejected["plot_future"] > 0 and set(r.eng.rejected) == {"plot_future"}
    margin_s = 20.0  # min(max_future_s, radar_timeout_s)
    assert r.eng.buffer.watermark_s[1] <= T0 + 119 + margin_s
    assert r.eng.health()["radars"]["a"]["live"] is True


@pytest.mark.parametrize("step_s", [1.0, 4.0, 9.0])
def test_a_radar_that_falls_silent_does_not_hold_the_others_time_back(step_s):
    """b falls silent; a goes on, one batch per ``step_s`` (one per rotation at 9 s): a's
    time passes b's last plus the margin without a refusal."""
    r = TwoRadars()
    for k in range(10):
        r.send("a", T0 + k)
        r.send("b", T0 + k + 0.3)
    t = T0 + 10
    took = []
    while t < T0 + 100:
        took.append(r.send("a", t))
        r.eng.poll()
        t += step_s
    assert took == [1] * len(took) and not r.eng.rejected


def test_every_radar_ahead_of_a_restored_state_is_followed():
    """The whole system's time moved on (a restart from a state saved hours ago): each
    radar is refused until the first is re-locked (nobody else moved meanwhile); then
    the others are in step with it."""
    r = TwoRadars()
    for k in range(5):
        r.send("a", T0 + k)
        r.send("b", T0 + k + 0.3)
    t1 = T0 + 7200.0
    took = [(r.send("a", t1 + k), r.send("b", t1 + k + 0.3)) for k in range(12)]
    assert took[:8] == [(0, 0)] * 8 and took[8] == (1, 1) and took[9:] == [(1, 1)] * 3
    assert r.eng.counters["radar_time_relocks"] == 1


def test_a_front_end_that_numbers_from_the_start_again_costs_two_batches():
    """A front-end restarted: its batches are numbered from 0 again, with new plots. The
    third such batch in a row shows the restart (one damaged or forged number is no
    restart); then its batches are taken again, and true copies are still refused."""
    r = TwoRadars(max_future_s=1e6, radar_timeout_s=1e6)
    t = T0
    for seq in range(100):
        assert r.eng.ingest_plots(plots("a", seq, t)) == 1
        t += 0.1
        r.eng.poll()
    # used numbers drawn at random, rising, with fresh plots (forged, or the fuzz's): no restart
    assert [r.eng.ingest_plots(plots("a", seq, t + 0.01 * seq)) for seq in (5, 9, 30, 31, 77)] == [0] * 5
    assert r.eng.rejected["duplicate"] == 5 and r.eng.health()["radars"]["a"]["seq_restarts"] == 0
    r.eng.rejected.clear()
    r.eng.radars[0].rejected.clear()
    t += 1.0
    took = []
    for seq in range(20):
        took.append(r.eng.ingest_plots(plots("a", seq, t)))
        t += 0.1
    assert took == [0, 0] + [1] * 18
    h = r.eng.health()["radars"]["a"]
    assert h["seq_restarts"] == 1 and h["rejected"] == {"duplicate": 2} and h["last_seq"] == 19
    assert r.eng.ingest_plots(plots("a", 19, t - 0.1)) == 0  # a copy of the last one
    assert r.eng.ingest_plots(plots("a", 5, t)) == 0  # one used number with new plots: no restart
    assert r.eng.rejected["duplicate"] == 4


def test_a_batch_numbered_far_ahead_is_a_jump_not_lost_batches():
    """One batch numbered 2^63 - 1 (damaged, forged, a front-end numbering anew): counted
    as a restart of the numbering, not as 9.2e18 batches lost, and the radar's next
    batches, numbered on from before, are followed again (not all out of order). A
    restart from 0 after more batches than the window of recent numbers is followed at
    once."""
    r = TwoRadars(max_future_s=1e6, radar_timeout_s=1e6)
    t = T0
    for seq in range(1, 6):
        assert r.eng.ingest_plots(plots("a", seq, t)) == 1
        t += 0.1
    assert r.eng.ingest_plots(plots("a", 2**63 - 1, t)) == 1
    t += 0.1
    for seq in range(6, 20):
        assert r.eng.ingest_plots(plots("a", seq, t)) == 1
        t += 0.1
    h = r.eng.health()["radars"]["a"]
    assert (h["seq_gaps"], h["seq_restarts"], h["last_seq"]) == (0, 2, 19)
    assert r.eng.counters["batches_out_of_order"] == 0
    for seq in range(20, 4200):
        r.eng.ingest_plots(plots("a", seq, t))
        t += 0.1
    assert r.eng.ingest_plots(plots("a", 0, t)) == 1  # 0 is no longer among the recent numbers
    assert r.eng.health()["radars"]["a"]["seq_restarts"] == 3 and not r.eng.rejected
    # a link down for 4,200 batches (8.5 min of a 4 s radar's 32 sectors) lost them: a gap
    assert r.eng.ingest_plots(plots("a", 4_201, t + 1.0)) == 1
    h = r.eng.health()["radars"]["a"]
    assert (h["seq_gaps"], h["seq_restarts"]) == (4_200, 3)


# ------------------------------------------------------------ realistic radar timing
# Four rotating radars, 4-10 s a turn, 8 sector messages per turn, random phases
# (issue 16 item 5): at the end of each sector's sweep a front-end sends that sector's
# plots (their times spread over the sweep), then the sector message stamped with the
# boundary; the messages of all radars are merged in time order.
ROTATIONS_S = {"a": 4.0, "b": 6.0, "c": 8.0, "d": 10.0}
SECTORS = 8


def four_radar_settings(**system):
    radars = [
        {
            "id": rid,
            "lat": 46.0 + 0.1 * k,
            "lon": 8.0 - 0.1 * k,
            "sigma_range_m": 50,
            "sigma_azimuth_deg": 0.1,
            "rotation_period_s": rot,
        }
        for k, (rid, rot) in enumerate(ROTATIONS_S.items())
    ]
    return settings_from_dict(
        {
            "system": {"center_lat": 46.0, "center_lon": 8.0, "period_s": 4.0, "allowed_lateness_s": 1.0, **system},
            "radars": radars,
            "outliers": {"enabled": False},
        }
    )


def test_a_wrong_clock_that_sends_first_after_a_start_does_not_shut_the_others_out():
    """After a start the first radar to send sets the time; with its clock 45 s slow, the
    others' right times looked 45 s ahead of the only radar keeping time, and (it kept
    moving) were refused for good, the picture one radar's. They outnumber it: after the
    relock's eight refusals their time is followed, and the slow radar's plots are late."""
    eng = Engine(four_radar_settings())
    ids = list(ROTATIONS_S)
    slow, right = ids[0], ids[1:]
    seq = dict.fromkeys(ids, 0)

    def send(rid, t):
        seq[rid] += 1
        return eng.ingest_plots(plots(rid, seq[rid], t))

    for k in range(5):  # the slow one first, alone, a few seconds
        send(slow, T0 - 45.0 + k)
    took = {rid: 0 for rid in ids}
    for k in range(5, 60):
        for rid in ids:
            took[rid] += send(rid, T0 + k - (45.0 if rid == slow else 0.0))
        eng.poll()
    assert all(took[rid] >= 55 - FUTURE_RELOCK_BATCHES for rid in right), took
    assert took[slow] < 10 and eng.rejected["plot_late"] > 40
    assert eng.counters["radar_time_relocks"] == 1


def sweep_messages(duration_s, seed=0, status_first=(), from_s=0.0):
    """(event time of the message, plots or status) in arrival order; the radars in
    ``status_first`` send each sector message before that sector's plots from ``from_s``
    on, as an ASTERIX CAT034 front-end does when it reports the boundary as the antenna
    crosses it."""
    rng = np.random.default_rng(seed)
    events = []
    for r, (rid, rot) in enumerate(ROTATIONS_S.items()):
        sector_s = rot / SECTORS
        t_b = T0 + rng.uniform(0.2, 1.0) * sector_s  # the first boundary after T0
        k = 0
        while t_b < T0 + duration_s:
            t = np.sort(rng.uniform(max(T0, t_b - sector_s), t_b, 3))
            batch = plots(rid, k, t, azimuth_deg=float((k % SECTORS + 0.5) * 360.0 / SECTORS))
            status = RadarStatus(
                radar_id=rid, t=t_b, kind="north" if k % SECTORS == 7 else "sector", sector=k % SECTORS
            )
            swap = rid in status_first and t_b >= T0 + from_s
            pair = [(1, status), (2, batch)] if swap else [(1, batch), (2, status)]
            events += [(t_b, sub, r, msg) for sub, msg in pair]
            t_b += sector_s
            k += 1
    events.sort(key=lambda e: e[:3])
    return [(t, msg) for t, _sub, _r, msg in events]


def run_messages(eng, messages):
    """Feed in order, polling after each; returns [(period end, event time of the message that closed it)]."""
    closed = []
    for t_msg, msg in messages:
        if isinstance(msg, RadarStatus):
            eng.ingest_status(msg)
        else:
            eng.ingest_plots(msg)
        closed += [(o.t_s, t_msg) for o in eng.poll()]
    return closed


def test_radars_in_order_close_a_period_at_the_slowest_radars_first_message_past_its_end():
    """No radar has shown a plot behind its own newest time, so none is waited for beyond
    its first message past the period's end: a period closes at most one sector of the
    slowest radar (10 s / 8 = 1.25 s) after its end, in event time, not a second later
    still for a fixed lateness; no plot is refused."""
    eng = Engine(four_radar_settings())
    messages = sweep_messages(120.0)
    closed = run_messages(eng, messages)
    delay_s = np.array([t_msg - end for end, t_msg in closed])
    assert len(closed) >= 28 and delay_s.min() >= 0.0
    assert delay_s.max() <= ROTATIONS_S["d"] / SECTORS + 1e-9
    assert np.median(delay_s) < 1.0  # with a fixed 1 s lateness every delay was over 1 s
    sent = sum(len(m) for _, m in messages if not isinstance(m, RadarStatus))
    assert eng.counters["plots_accepted"] == sent and sum(eng.rejected.values()) == 0
    assert eng.buffer.lateness_s.tolist() == [0.0] * 4


def test_a_radar_that_reports_its_sector_before_its_plots_is_waited_for_by_its_lateness():
    """From 60 s on, radar c sends each sector message as the antenna crosses the boundary,
    before that sector's plots (up to its 1 s sector behind). Its first such plots may find
    their period closed (with this seed they do): refused as late and counted; from then on
    c is waited for by how far behind its plots have come (its lateness, at most
    allowed_lateness_s), and nothing more is late. The in-order radars keep no lateness."""
    eng = Engine(four_radar_settings())
    messages = sweep_messages(240.0, seed=19, status_first={"c"}, from_s=60.0)
    late_at_s, closed = [], []
    for t_msg, msg in messages:
        before = eng.rejected["plot_late"]
        if isinstance(msg, RadarStatus):
            eng.ingest_status(msg)
        else:
            eng.ingest_plots(msg)
        if eng.rejected["plot_late"] > before:
            late_at_s.append(t_msg - T0)
        closed += [(o.t_s, t_msg) for o in eng.poll()]
    sent = sum(len(m) for _, m in messages if not isinstance(m, RadarStatus))
    late = eng.rejected["plot_late"]
    assert eng.counters["plots_accepted"] + late == sent  # nothing lost without a count
    assert eng.health()["radars"]["c"]["rejected"] == {"plot_late": late}
    assert 0 < late <= 3 and len(late_at_s) == 1 and 60.0 <= late_at_s[0] < 61.0  # c's first sector out of order
    lateness = dict(zip(ROTATIONS_S, eng.buffer.lateness_s.tolist()))
    assert 0.9 < lateness["c"] <= 1.0 and lateness["a"] == lateness["b"] == lateness["d"] == 0.0
    delay_s = np.array([t_msg - end for end, t_msg in closed])
    assert delay_s.max() <= ROTATIONS_S["d"] / SECTORS + 1.0 + 1e-9


def test_a_radars_lateness_is_capped_and_forgotten():
    """Lateness: the most a radar's plots have come behind its newest time, at most
    allowed_lateness_s, remembered for one to two lateness_memory_s of its event time."""
    marks = Watermarks(2, max_lateness_s=1.0, radar_timeout_s=30.0, memory_s=60.0)
    marks.advance(0, T0 + 10.0)
    marks.advance(1, T0 + 10.0)
    assert marks.closable_until_s() == T0 + 10.0
    marks.arrived(0, T0 + 9.7)  # 0.3 s behind
    assert marks.lateness_s.tolist() == pytest.approx([0.3, 0.0])
    assert abs(marks.closable_until_s() - (T0 + 9.7)) < 1e-9
    marks.arrived(0, T0 + 5.0)  # 5 s behind: capped
    marks.arrived(0, T0 + 9.9)  # less than before: no change
    assert marks.lateness_s.tolist() == [1.0, 0.0]
    w = 60.0 * np.ceil((T0 + 10.0) / 60.0)  # the next window boundary
    marks.advance(0, w + 1.0)  # a new window: the previous one is still remembered
    assert marks.lateness_s[0] == 1.0
    marks.advance(0, w + 61.0)  # two windows on without a plot behind: forgotten
    assert marks.lateness_s[0] == 0.0
    marks.advance(0, w + 500.0)  # a radar silent for a while comes back: nothing kept either
    assert marks.lateness_s[0] == 0.0


def test_closing_depends_on_event_times_in_arrival_order_only():
    """Two engines fed the same messages, one polled after every message, the other after
    every tenth (a fast replay batches its polls): the same periods with the same plots."""
    messages = sweep_messages(120.0, status_first={"c"}, seed=3)
    a, b = Engine(four_radar_settings()), Engine(four_radar_settings())
    out_a, out_b = [], []
    for i, (_t, msg) in enumerate(messages):
        for eng in (a, b):
            eng.ingest_status(msg) if isinstance(msg, RadarStatus) else eng.ingest_plots(msg)
        out_a += a.poll()
        if i % 10 == 9:
            out_b += b.poll()
    out_a += a.flush()
    out_b += b.flush()
    assert [(o.period, o.n_plots) for o in out_a] == [(o.period, o.n_plots) for o in out_b]
    assert a.rejected == b.rejected
