"""The engine benchmark's table and its world-scale verdict (issue 16 item 4). No timings
are checked: speed belongs in the bench command (DESIGN.md §4)."""

from __future__ import annotations

import math

from radar_fusion.tools import bench
from radar_fusion.tools.bench.report import goal_lines


def _row(aircraft: int, radars: int, p99_ms: float, warm_max_ms: float) -> dict:
    on = {
        "p50_ms": 0.5 * p99_ms,
        "p99_ms": p99_ms,
        "warm_max_ms": warm_max_ms,
        "period_s": 4.0,
        "real_time_x": 6.0,
        "plots_per_s": 50_000.0,
        "peak_rss_mb": 650.0,
        "rss_base_mb": 220.0,
        "rss_steady_first_mb": 600.0,
        "rss_end_mb": 601.0,
    }
    return {"aircraft": aircraft, "radars": radars, "on": on}


def test_world_scale_verdict_is_every_period_within_the_period():
    (line,) = [x for x in goal_lines([_row(20_000, 30, 700.0, 900.0)]) if x.startswith("world scale")]
    assert "700 ms of the 4 s period (18 %" in line and line.count("MET") == 1 and "NOT MET" not in line
    (late,) = [x for x in goal_lines([_row(20_000, 30, 700.0, 4_100.0)]) if x.startswith("world scale")]
    assert "NOT MET" in late  # one warm-up period longer than the period: not real time
    assert not [x for x in goal_lines([_row(4000, 10, 70.0, 90.0)]) if x.startswith("world scale")]


def test_engine_table_reports_period_share_and_real_time(capsys):
    assert bench.main(["--sizes", "6x2", "--duration-s", "16", "--warmup-s", "4", "--no-gate-compare"]) == 0
    out = capsys.readouterr().out
    header = next(line for line in out.splitlines() if line.lstrip().startswith("aircraft"))
    assert "p99 / period" in header and "× real time" in header
    row = next(line for line in out.splitlines() if line.split()[:2] == ["6", "2"])
    cols = [c for c in header.split("  ") if c.strip()]
    cells = [c for c in row.split("  ") if c.strip()]
    share = float(cells[[c.strip() for c in cols].index("p99 / period")])
    p99 = float(cells[[c.strip() for c in cols].index("p99 ms")])
    assert math.isclose(share, p99 / 1000.0 / 4.0, abs_tol=1e-3)  # the benchmark scenario's 4 s period


def test_issue15_verdicts_are_the_ratios_of_the_run():
    """bench --report's issue-15 lines: each ratio from the figures given (here chosen so
    that position 56/82 = 0.683 passes 0.7 and velocity 10/16 = 0.625 fails 0.6), the
    false-track share over the displayed tracks, straight flight over its PCRB, turning over
    straight with where its error is (onset / steady, outside the turn, its PCRB), and the
    engine at 4,000×10 against 150k plots/s."""
    from radar_fusion.tools.bench.report import goal_lines_issue15

    ours = {
        "pos_rms_m": 56.0,
        "vel_rms_mps": 10.0,
        "gospa_mean_m": 400.0,
        "completeness_mean": 1.0,
        "track_ids_per_target_mean": 1.02,
        "false_tracks": 1,
        "n_displayed_tracks": 40,
        "pos_rms_straight_m": 40.0,
        "pos_rms_turning_m": 58.0,
        "n_pairs_turning": 30,
        "pos_rms_turn_onset_m": 80.0,
        "pos_rms_turn_steady_m": 45.0,
        "n_pairs_turn_onset": 12,
        "turning_outward_mean_m": 21.0,
    }
    ss = {"pos_rms_m": 82.0, "vel_rms_mps": 16.0, "gospa_mean_m": 800.0, "completeness_mean": 0.98}
    row = {
        "label": "50×3",
        "case": {"kind": "benchmark", "aircraft": 50, "radars": 3},
        "engine": {"plots_per_s": 20_000.0},
        "accuracy": {"ours": ours},
        "reference": {"scores": ss},
        "sim": {"pcrb_straight_pos_rms_m": 32.0, "pcrb_turning_pos_rms_m": 40.0},
    }
    big = {
        "label": "4,000×10",
        "case": {"kind": "benchmark", "aircraft": 4000, "radars": 10},
        "engine": {"plots_per_s": 151_000.0},
    }
    vs_ss, ids, straight, turning, detail, engine = goal_lines_issue15([row, big])
    assert "position RMS 0.68×" in vs_ss and "velocity RMS 0.62×" in vs_ss and "GOSPA 0.50×" in vs_ss
    assert vs_ss.endswith("NOT MET")  # velocity
    assert "1.020 track ids" in ids and "(2.5 %" in ids and ids.endswith("NOT MET")  # 1 false of 40 > 2 %
    assert "1.25× its PCRB" in straight and straight.endswith("NOT MET")
    assert "1.45× straight" in turning and turning.endswith("-> MET")
    assert "first 24 s of a turn 80 m (12 pairs), after 45 m (18)" in detail
    assert "21 m outside the turn" in detail and "PCRB at the turning times 40 m (1.45× it)" in detail
    assert "151,000" in engine and engine.endswith("-> MET")


def test_wild_twin_verdict_is_each_score_within_ten_percent_of_the_twin():
    """bench --wild-twin's lines: the ratio wild / clean twin of each score, and issue 15 item
    7's verdict over position, velocity, GOSPA, ids per aircraft and false tracks."""
    from radar_fusion.tools.bench.report import wild_twin_lines

    twin = {
        "pos_rms_m": 80.0,
        "vel_rms_mps": 10.0,
        "pos_rms_settled_m": 60.0,
        "vel_rms_settled_mps": 6.0,
        "gospa_mean_m": 3000.0,
        "gospa_settled_mean_m": 2000.0,
        "track_ids_per_target_mean": 1.0,
        "false_tracks": 2,
        "duplicate_tracks": 0,
        "completeness_mean": 0.99,
    }
    near = {**twin, "pos_rms_m": 87.9, "vel_rms_mps": 10.9, "gospa_mean_m": 3290.0, "false_tracks": 2}
    far = {**near, "gospa_mean_m": 3310.0}  # 1.103× the twin's
    more_false = {**near, "false_tracks": 3}  # 3 > 1.1 × 2
    rows = [{"label": name, "twin": twin, "wild": w} for name, w in (("a", near), ("b", far), ("c", more_false))]
    lines = wild_twin_lines(rows)
    ga, gb, gc = (next(x for x in lines if x.startswith(f"goal (issue 15 item 7) {n}:")) for n in "abc")
    assert "position 1.099×" in ga and "velocity 1.090×" in ga and "GOSPA 1.097×" in ga and ga.endswith("-> MET")
    assert "GOSPA 1.103×" in gb and gb.endswith("NOT MET")
    assert "false tracks 3 against 2" in gc and gc.endswith("NOT MET")
    row = next(x for x in lines if x.startswith("a") and "completeness" in x)
    assert row.split()[-3:] == ["99.00", "99.00", "1.000"]
