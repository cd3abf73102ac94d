"""Mode S identity figures (tools/identity.py): the metric on hand-made batches, and the
first twenty minutes of the real Barcelona hour through the engine, against issue 15's
goal: <= 1.03 track ids per Mode S track segment, never two tracks on one address, no
rejection.
"""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest

from radar_fusion.tools.identity import (
    BARCELONA_FILE,
    format_table,
    identity_figures,
    plot_columns,
    run_identity,
    segments_of,
)

A, B = 0xABC123, 0x00000B


def _plots(address: int, times: list[float]) -> SimpleNamespace:
    """A DecodedPlots-like batch: array columns t_s and mode_s."""
    return SimpleNamespace(t_s=np.array(times, float), mode_s=np.full(len(times), address, np.int64))


def _track(tid: int, mode_s: int | None, status: str = "confirmed") -> dict:
    return {"track_id": tid, "mode_s": None if mode_s is None else f"{mode_s:06X}", "status": status}


def test_segments_split_only_at_gaps_over_the_limit():
    t = np.array([0, 4, 8, 100, 104, 0, 50, 110], float)
    a = np.array([A, A, A, A, A, B, B, B])
    segs = segments_of(t, a, gap_s=60.0)
    # A: 8 -> 100 is a 92 s gap (split); B: gaps of 50 s and exactly 60 s (no split)
    assert [(s.address, s.start_s, s.end_s, s.n_plots) for s in segs] == [
        (B, 0.0, 110.0, 3),
        (A, 0.0, 8.0, 3),
        (A, 100.0, 104.0, 2),
    ]
    assert len(segments_of(t, a, gap_s=30.0)) == 5  # B splits at both gaps too


def test_plot_columns_take_batches_and_single_plots_and_drop_plots_without_address():
    plots = [
        _plots(A, [0.0, 4.0]),
        SimpleNamespace(t_s=np.array([1.0, 2.0]), mode_s=np.array([-1, B])),
        {"t": 3.0, "mode_s": "00000B"},
        {"t": 5.0, "mode_s": None},
    ]
    t, a = plot_columns(plots)
    assert sorted(zip(t.tolist(), a.tolist())) == [(0.0, A), (2.0, B), (3.0, B), (4.0, A)]


def _scenario() -> tuple[list, list[dict]]:
    """Two segments of A ([0, 40] and [200, 240]) and one of B ([0, 40]); batches every 4 s.

    A, segment 1: track 1 (t 4-28 confirmed, 32 coasting), then track 2 (t 32-44): two ids,
    and at t 32 both show A (one duplicate batch). Between the segments, track 7 shows A
    once at t 120 (no plot of A near it: no segment's id). A, segment 2: track 3 (t 204-244);
    a tentative track 9 shows A at t 208 (not counted; a duplicate of any status). B: track 4
    (t 4-44). Track 5 has no address, confirmed throughout.
    """
    plots = [_plots(A, list(range(0, 41, 4))), _plots(A, list(range(200, 241, 4))), _plots(B, list(range(0, 41, 4)))]
    batches = []
    for t in range(4, 245, 4):
        tracks = [_track(5, None)]
        if 4 <= t <= 28:
            tracks.append(_track(1, A))
        if t == 32:
            tracks.append(_track(1, A, "coasting"))
        if 32 <= t <= 44:
            tracks.append(_track(2, A))
        if t == 120:
            tracks.append(_track(7, A))
        if 204 <= t <= 244:
            tracks.append(_track(3, A))
        if t == 208:
            tracks.append(_track(9, A, "tentative"))
        if 4 <= t <= 44:
            tracks.append(_track(4, B))
        batches.append({"t": float(t), "tracks": tracks, "ended": []})
    return plots, batches


def test_ids_per_segment_and_duplicates_by_hand():
    plots, batches = _scenario()
    f = identity_figures(plots, batches, rejected={"plot_late": 2}, gap_s=60.0, period_s=4.0)
    assert f["addresses"] == 2
    assert f["segments"] == 3
    assert f["segments_without_track"] == 0
    segs = {(s["mode_s"], s["start_t"]): s["track_ids"] for s in f["worst_segments"]}
    assert segs == {("ABC123", 0.0): [1, 2], ("ABC123", 200.0): [3], ("00000B", 0.0): [4]}
    assert f["ids_per_segment_mean"] == pytest.approx((2 + 1 + 1) / 3)
    assert f["ids_per_segment_max"] == 2
    assert f["segments_with_extra_ids"] == 1
    assert f["extra_ids"] == 1
    # duplicates among confirmed/coasting: only t 32 (tracks 1 and 2)
    assert f["duplicate_batches"] == 1
    assert f["duplicate_addresses"] == {"ABC123": 1}
    assert f["duplicate_batches_any_status"] == 2  # and t 208 with the tentative track 9
    # reports with an address: track 1: 8 (t 4-32), 2: 4, 3: 11, 4: 11, 7: 1 -> 35; 2 shared
    assert f["track_reports_with_mode_s"] == 35
    assert f["track_reports_counted"] == 35 + len(batches)  # + track 5, without address
    assert f["duplicate_track_time_share"] == pytest.approx(2 / 35)
    assert f["rejected_total"] == 2
    worst = f["worst_addresses"][0]
    assert worst == {
        "mode_s": "ABC123",
        "segments": 2,
        "ids": 3,  # 1, 2, 3 (7 lies outside both segments)
        "extra_ids": 1,
        "plots": 22,
        "duplicate_batches": 1,
    }


def test_segment_span_reaches_one_period_past_its_last_plot():
    plots = [_plots(A, [0.0, 4.0, 8.0])]
    batches = [{"t": 12.0, "tracks": [_track(1, A)]}, {"t": 12.5, "tracks": [_track(2, A)]}]
    f = identity_figures(plots, batches, period_s=4.0)
    assert f["worst_segments"][0]["track_ids"] == [1]  # 12.0 <= 8 + 4 < 12.5


def test_a_segment_no_counted_track_showed():
    plots = [_plots(A, [0.0, 4.0]), _plots(B, [0.0, 4.0])]
    batches = [{"t": 4.0, "tracks": [_track(1, A), _track(2, B, "tentative")]}]
    f = identity_figures(plots, batches, period_s=4.0)
    assert f["segments"] == 2
    assert f["segments_without_track"] == 1
    assert f["ids_per_segment_mean"] == 1.0  # over the segments with a track
    assert f["duplicate_batches"] == 0
    assert f["duplicate_track_time_share"] == 0.0


@pytest.mark.slow
def test_barcelona_first_twenty_minutes_through_the_engine(shared_data, capsys):
    path = shared_data / "asterix" / "barcelona_cat048_1h.ast"
    if not path.is_file():
        pytest.skip(f"{BARCELONA_FILE} is not present")
    f = run_identity(path, minutes=20)
    with capsys.disabled():
        print("\n" + format_table(f))
    assert f["rejected_total"] == 0, f["rejected"]
    assert f["span_s"] == pytest.approx(1200, abs=5)
    assert f["plots_ingested"] == f["bridge"]["plots_kept"] > 10000
    assert f["batches"] == pytest.approx(300, abs=3)  # one TrackBatch per 4 s period
    assert f["segments"] >= f["addresses"] > 40
    assert f["segments_without_track"] == 0  # every segment got at least one track id
    for key in ("ids_per_segment_mean", "duplicate_track_time_share"):
        assert math.isfinite(f[key])
    assert 1.0 <= f["ids_per_segment_mean"] <= f["ids_per_segment_max"]
    # issue 15's goal (measured: 1.000 on these 20 minutes and on the whole hour; 1.062 on the
    # hour without re-acquisition, 1.220 before identity association)
    assert f["ids_per_segment_mean"] <= 1.03, f["worst_addresses"]
    assert f["duplicate_batches"] == 0 and f["duplicate_track_time_share"] == 0.0


@pytest.mark.slow
def test_barcelona_heading_and_airspeed_bring_the_velocity_closer_to_held_out_reports(shared_data):
    """The first twenty minutes of the Barcelona hour, half the BDS 5,0 reports (at random)
    taken off the plots before the engine sees them: the confirmed Mode S tracks' velocity
    (period by period, within 2 s of a held-out report) against those reports, with the
    BDS 6,0 heading and airspeed measuring the velocity (tracking.imm.velocity_air) and
    without. In turns (above 1°/s by the held-out reports' own track angles) the error falls;
    in straight flight it stays within 10 %. Measured when written: turns 7.40 against 8.71
    m/s RMS (50 reports), straight 2.81 against 2.80 (338); over the whole hour (a script, not
    this test: 50 s more) turns 6.55 against 7.44 (127), straight 2.87 against 3.24 (954)."""
    from radar_fusion.engine import Engine
    from radar_fusion.tools.identity import BARCELONA_DAY, asterix_messages, barcelona_settings
    from radar_fusion.tools.replay import ingest_record
    from radar_fusion.wire import decode_plot_batch

    path = shared_data / "asterix" / "barcelona_cat048_1h.ast"
    if not path.is_file():
        pytest.skip(f"{BARCELONA_FILE} is not present")
    base = barcelona_settings()
    messages, _ = asterix_messages(path, base, BARCELONA_DAY, minutes=20)

    def run(velocity_air: bool) -> tuple[np.ndarray, np.ndarray]:
        imm = base.tracking.imm.model_copy(update={"velocity_air": velocity_air})
        settings = base.model_copy(update={"tracking": base.tracking.model_copy(update={"imm": imm})})
        engine = Engine(settings)
        rng = np.random.default_rng(0)
        held: dict[int, list[tuple[float, float, float]]] = {}
        outputs = []
        for _t, key, payload in messages:
            if key.endswith("/plots"):
                batch = decode_plot_batch(payload)
                out = np.isfinite(batch.ground_speed_mps) & (rng.random(len(batch)) < 0.5)
                for j in np.flatnonzero(out):
                    held.setdefault(int(batch.mode_s[j]), []).append(
                        (float(batch.t_s[j]), float(batch.ground_speed_mps[j]), float(batch.track_angle_deg[j]))
                    )
                batch.ground_speed_mps[out] = np.nan
                batch.track_angle_deg[out] = np.nan
                engine.ingest_plots(batch)
            else:
                ingest_record(engine, key, payload)
            outputs += engine.poll()
        outputs += engine.flush()
        series = {a: np.array(sorted(v)) for a, v in held.items()}
        err, rate = [], []
        for o in outputs:
            for tr in o.track_batch["tracks"]:
                if tr["status"] != "confirmed" or tr["updates"] < 4 or not tr["mode_s"]:
                    continue
                s = series.get(int(tr["mode_s"], 16))
                if s is None:
                    continue
                j = int(np.argmin(np.abs(s[:, 0] - tr["t"])))
                if abs(s[j, 0] - tr["t"]) > 2.0:
                    continue
                near = np.abs(s[:, 0] - s[j, 0]) <= 20.0
                if near.sum() < 3:
                    continue
                course = np.unwrap(np.radians(s[near, 2]))
                rate.append(abs(math.degrees(np.polyfit(s[near, 0] - s[j, 0], course, 1)[0])))
                k = float(engine.plane.scale_factor(tr["lat_deg"], tr["lon_deg"]))
                true_deg = math.degrees(math.atan2(tr["vx_mps"], tr["vy_mps"])) + float(
                    engine.plane.grid_convergence_deg(tr["lat_deg"], tr["lon_deg"])
                )
                speed = math.hypot(tr["vx_mps"], tr["vy_mps"]) / k
                ours = speed * np.array([math.sin(math.radians(true_deg)), math.cos(math.radians(true_deg))])
                theirs = s[j, 1] * np.array([math.sin(math.radians(s[j, 2])), math.cos(math.radians(s[j, 2]))])
                err.append(float(np.hypot(*(ours - theirs))))
        assert engine.counters["updates_velocity_air"] > (5000 if velocity_air else -1)
        return np.array(err), np.array(rate)

    rms = lambda e: float(np.sqrt(np.mean(e**2)))
    (e_on, r_on), (e_off, r_off) = run(True), run(False)
    np.testing.assert_array_equal(r_on, r_off)  # the same reports, the same tracks to compare
    turning, straight = r_on > 1.0, r_on < 0.3
    print(
        f"\nheld-out BDS 5,0: turns {rms(e_on[turning]):.2f} / {rms(e_off[turning]):.2f} m/s ({turning.sum()}), "
        f"straight {rms(e_on[straight]):.2f} / {rms(e_off[straight]):.2f} ({straight.sum()}) (with / without BDS 6,0)"
    )
    assert turning.sum() > 30 and straight.sum() > 200
    assert rms(e_on[turning]) < 0.92 * rms(e_off[turning])
    assert rms(e_on[straight]) < 1.10 * rms(e_off[straight])
