"""The soak mode (issue 8, item 3), short: 5 minutes of steady traffic with 30 aircraft
through a daemon started as a child process, as fast as it takes it. The full run
(an hour, hundreds of aircraft) is `radar-fusion soak --generate DIR`."""

from __future__ import annotations

import msgpack
import numpy as np
import pytest

from radar_fusion.recording import RecordingWriter, read_header, read_recording
from radar_fusion.tools import simulate as sim
from radar_fusion.tools import soak


def test_soak_traffic_is_steady_with_flights_entering_throughout():
    scenario = soak.soak_scenario(n_aircraft=40, duration_s=1200.0, n_radars=3, seed=4)
    truth = sim.simulate(scenario).truth
    t0 = scenario.start_t_s
    airborne = [
        len(np.unique(truth.target_index[(truth.t_s >= t0 + m) & (truth.t_s < t0 + m + 1)]))
        for m in range(0, 1200, 120)
    ]
    assert min(airborne) >= 0.7 * 40 and max(airborne) <= 1.3 * 40, airborne
    offsets = np.array([t.plan.t_offset_s for t in scenario.targets])
    assert (offsets > 600.0).sum() >= 5  # new flights keep coming in the second half


@pytest.fixture(scope="module")
def short(tmp_path_factory):
    out = tmp_path_factory.mktemp("soak")
    rec, cfg = soak.generate(out, n_aircraft=30, duration_s=300.0, n_radars=3, seed=2)
    return rec, cfg


@pytest.mark.bus
@pytest.mark.slow  # a soak
def test_short_soak_loses_nothing_and_reports_memory_and_latency(short):
    rec, cfg = short
    report = soak.run_soak(rec, cfg, lead_periods=2)
    print("\n" + soak.format_report(report))
    n_records = sum(1 for _ in read_recording(rec))
    assert report.messages_sent == n_records + report.heartbeats_sent and report.heartbeats_sent == 3
    assert report.checks["no message lost"] and report.checks["every track batch received, in order"]
    assert report.checks["daemon stopped cleanly"] and report.checks["memory flat"]
    # the whole recording went through and the daemon settled (everything processed, nothing
    # buffered, every batch in), paced by flow control alone; how much faster than real time
    # it ran is a figure of the printed report, not a verdict (the machine is shared)
    assert report.traffic_s > 290.0 and not report.notes, report.notes
    assert 0 < report.max_outstanding_periods <= 2  # flow control held the lead
    assert report.track_batches_received >= 70 and report.tracks_mean["last"] >= 25
    rss = report.rss_mib
    assert 0 < rss["idle"] <= rss["peak"] and rss["end"] <= rss["peak"] < 1024
    # period latency was measured over the first and the last tenth of the periods; its values
    # are wall time, printed in the report above, not judged here
    lat = report.latency_ms
    assert set(lat) >= {"first_p50", "first_p99", "last_p50", "last_p99"}
    assert lat["periods_each"] >= 7  # of the >= 70 batches
    assert 0 < lat["first_p50"] <= lat["first_p99"] and 0 < lat["last_p50"] <= lat["last_p99"]


@pytest.mark.bus
@pytest.mark.slow  # a soak
def test_soak_reports_a_message_the_daemon_did_not_take(short, tmp_path):
    """A plot batch sent twice is refused by the daemon as a duplicate: the soak sees that
    the daemon counted fewer batches than were sent and fails its loss check."""
    rec, cfg = short
    t_end_s = read_header(rec)["meta"]["start_t_s"] + 60.0
    records = [r for r in read_recording(rec) if r.t_s < t_end_s]
    dup = next(i for i, r in enumerate(records) if r.key.endswith("/plots") and msgpack.unpackb(r.payload)["plots"])
    with RecordingWriter(tmp_path / "dup.rec") as w:
        for i, r in enumerate(records):
            w.write(r.t_s, r.key, r.payload)
            if i == dup:
                w.write(r.t_s, r.key, r.payload)
    report = soak.run_soak(tmp_path / "dup.rec", cfg)
    assert report.rejected == {"duplicate": 1}
    assert not report.checks["no message lost"] and not report.passed
    assert report.checks["every track batch received, in order"]
