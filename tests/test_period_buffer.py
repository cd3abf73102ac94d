"""Event-time periods and the engine's ingest rules: watermarks, lateness, silent radars,
duplicates, sequence gaps, unknown radars, range limits — all counted, none fatal."""

from __future__ import annotations

import numpy as np

from radar_fusion.config import settings_from_dict
from radar_fusion.engine import Engine
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
    assert eng2.poll() == []  # b's watermark (T0+2) has not passed T0+4+1
    eng2.ingest_status(RadarStatus(radar_id="b", t=T0 + 5.5, kind="sector", sector=3))
    out = eng2.poll()
    assert [o.period for o in out] == [int(T0 // 4)] and out[0].t_s == T0 + 4.0 and out[0].n_plots == 2


def test_single_radar_closes_periods_with_its_own_watermark():
    eng = Engine(settings())
    eng.ingest_plots(plots("a", 1, T0 + 1.0))
    assert eng.poll() == []
    eng.ingest_plots(plots("a", 2, T0 + 5.5))
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
    assert [o.t_s for o in eng.poll()] == [T0 + 4.0, T0 + 8.0]  # watermark T0+9 - 1 s lateness
    assert eng.ingest_plots(plots("a", 2, [T0 + 2.0, T0 + 9.5])) == 1
    assert eng.rejected["plot_late"] == 1 and eng.health()["radars"]["a"]["rejected"] == {"plot_late": 1}


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
