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
