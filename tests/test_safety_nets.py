"""Safety nets (issue 5): CPA maths, STCA/APW/MSAW detection, life cycle, pruning, hooks,
point-in-polygon, the track columns they read and the counters they put on the health key."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from importlib import metadata
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from pydantic import ValidationError

from radar_fusion import safety_nets as sn
from radar_fusion.engine.columns import RadarNames, TrackColumns
from radar_fusion.geo.coordinates import SystemPlane
from radar_fusion.geo.units import M_PER_NM
from radar_fusion.safety_nets import SafetyNets, SafetyNetsConfig
from radar_fusion.safety_nets.hooks import load_hooks
from radar_fusion.safety_nets.polygon import SORT_ABOVE_EDGES, Polygon, ring_contains
from radar_fusion.safety_nets.prediction import segment_conflicts
from radar_fusion.tracking.track_management import COASTING, CONFIRMED, TENTATIVE
from radar_fusion.wire import Alert, Health, TrackBatch

PLANE = SystemPlane(47.0, 8.0)
REPO = Path(__file__).resolve().parents[1]
PERIOD_S = 4.0


def nets(**cfg) -> SafetyNets:
    cfg.setdefault("load_entry_point_hooks", False)
    return SafetyNets(SafetyNetsConfig(**cfg), PLANE)


def columns(track_id, x, y, vx, vy, ax, ay, fl, vrate_fpm, status: np.ndarray | None = None) -> TrackColumns:
    """The engine's track columns as the safety nets get them (status confirmed unless given)."""
    n = len(track_id)
    return TrackColumns(
        period=0,
        t_s=0.0,
        track_id=np.asarray(track_id, np.int64),
        status=np.full(n, CONFIRMED, np.int8) if status is None else np.asarray(status, np.int8),
        x=np.column_stack([x, vx, ax, y, vy, ay]).astype(float),
        cov_xy=np.full((n, 3), 100.0),
        fl=np.asarray(fl, float),
        vrate_fpm=np.asarray(vrate_fpm, float),
        sources=np.zeros(n, np.uint64),
        mode3a=np.full(n, -1, np.int64),
        mode_s=np.full(n, -1, np.int64),
        updates=np.full(n, 5, np.int64),
        age_s=np.full(n, 60.0),
        ended=np.zeros(0, np.int64),
        names=RadarNames([], PLANE),
    )


def arrays(rows: list[dict]) -> TrackColumns:
    """rows: dicts with id, x, y, vx, vy and optional fl, vr, ax, ay, confirmed (False: tentative)."""
    g = lambda k, d=0.0: np.array([r.get(k, d) for r in rows], dtype=float)
    status = [CONFIRMED if r.get("confirmed", True) else TENTATIVE for r in rows]
    return columns(
        [r["id"] for r in rows],
        g("x"),
        g("y"),
        g("vx"),
        g("vy"),
        g("ax"),
        g("ay"),
        g("fl", 200.0),
        g("vr", 0.0),
        status,
    )


def fly(acs: list[dict], duration_s: float, net: SafetyNets, t0: float = 1.7e9) -> list[dict]:
    """Propagate straight-line aircraft (x, y, vx, vy, fl, vr) and run the nets each period."""
    out = []
    for k in range(int(duration_s / PERIOD_S) + 1):
        t = k * PERIOD_S
        rows = []
        for a in acs:
            fl = a.get("fl", 200.0) + a.get("vr", 0.0) * t / 6000.0
            if "level_at" in a:
                fl = min(fl, a["level_at"]) if a.get("vr", 0) > 0 else max(fl, a["level_at"])
            vr = a.get("vr", 0.0) if fl != a.get("level_at") else 0.0
            rows.append(
                dict(id=a["id"], x=a["x"] + a["vx"] * t, y=a["y"] + a["vy"] * t, vx=a["vx"], vy=a["vy"], fl=fl, vr=vr)
            )
        for al in net.update(t0 + t, arrays(rows)):
            Alert.model_validate(al)
            out.append({**al, "t": al["t"] - t0})
    return out


def first_loss_s(acs: list[dict], h_m: float = 5 * M_PER_NM, v_ft: float = 1000.0) -> float:
    """Truth loss of separation of the first two aircraft, by 0.1 s sampling."""
    t = np.arange(0, 2000, 0.1)
    a, b = acs[0], acs[1]
    d = np.hypot(a["x"] + a["vx"] * t - b["x"] - b["vx"] * t, a["y"] + a["vy"] * t - b["y"] - b["vy"] * t)
    za = a.get("fl", 200) * 100 + a.get("vr", 0) * t / 60
    zb = b.get("fl", 200) * 100 + b.get("vr", 0) * t / 60
    lost = (d < h_m) & (np.abs(za - zb) < v_ft)
    return float(t[np.argmax(lost)])


# ------------------------------------------------------------------ CPA maths


@settings(max_examples=60, deadline=None)
@given(
    st.floats(-40_000, 40_000),
    st.floats(-40_000, 40_000),
    st.floats(-500, 500),
    st.floats(-500, 500),
    st.floats(-3000, 3000),
    st.floats(-60, 60),
)
def test_cpa_matches_brute_force_sampling(x0, y0, vx, vy, z0, vz):
    T, S, V = 120.0, 9260.0, 900.0
    knots = np.array([0.0, T])
    t = np.linspace(0, T, 24001)
    dx, dy, dz = x0 + vx * t, y0 + vy * t, z0 + vz * t
    res = segment_conflicts(
        np.array([[x0, x0 + vx * T]]),
        np.array([[y0, y0 + vy * T]]),
        np.array([[z0, z0 + vz * T]]),
        knots,
        np.array([S]),
        np.array([V]),
    )
    d = np.hypot(dx, dy)
    assert res["min_sep_m"][0] == pytest.approx(d.min(), abs=1.0 + 0.005 * math.hypot(vx, vy))  # sampling step 5 ms
    k = np.argmin(d)
    if d.min() > 1.0:
        assert res["t_cpa_s"][0] == pytest.approx(t[k], abs=0.05 + 200.0 / max(math.hypot(vx, vy), 1e-3) ** 1)
    both = (d < S) & (np.abs(dz) < V)
    if both.sum() > 3:  # a conflict that lasts more than a sample
        assert res["conflict"][0]
        assert res["t_violation_s"][0] == pytest.approx(t[np.argmax(both)], abs=0.02)
        assert res["min_vsep_ft"][0] == pytest.approx(np.abs(dz[both]).min(), abs=1.0)
    if res["conflict"][0]:  # the reported violation time is where both separations are (just) lost
        tv = res["t_violation_s"][0]
        assert math.hypot(x0 + vx * tv, y0 + vy * tv) <= S + 1e-6 * S and abs(z0 + vz * tv) <= V + 1e-6
    else:
        assert not both.any()


def test_piecewise_segments_equal_single_segment_for_linear_motion():
    x0, y0, vx, vy = -30_000.0, 5_000.0, 400.0, -50.0
    knots = np.linspace(0, 120, 25)
    one = segment_conflicts(
        np.array([[x0, x0 + vx * 120]]),
        np.array([[y0, y0 + vy * 120]]),
        np.zeros((1, 2)),
        np.array([0.0, 120.0]),
        np.array([9260.0]),
        np.array([900.0]),
    )
    many = segment_conflicts(
        (x0 + vx * knots)[None],
        (y0 + vy * knots)[None],
        np.zeros((1, 25)),
        knots,
        np.array([9260.0]),
        np.array([900.0]),
    )
    for key in ("t_violation_s", "t_cpa_s", "min_sep_m"):
        assert one[key][0] == pytest.approx(many[key][0], abs=1e-6)


# ------------------------------------------------------------------ STCA scenarios

CONFLICTS = {
    "head-on": [dict(id=1, x=-50e3, y=0, vx=240, vy=0), dict(id=2, x=50e3, y=500, vx=-240, vy=0)],
    "crossing": [dict(id=1, x=-52e3, y=0, vx=235, vy=0), dict(id=2, x=0, y=-50e3, vx=0, vy=225)],
    "overtaking": [dict(id=1, x=-60e3, y=0, vx=250, vy=0), dict(id=2, x=-20e3, y=500, vx=150, vy=0)],
    "climbing through": [
        dict(id=1, x=-45e3, y=0, vx=230, vy=0, fl=110),
        dict(id=2, x=0, y=-45e3, vx=0, vy=230, fl=70, vr=1500),
    ],
}


@pytest.mark.parametrize("name", sorted(CONFLICTS))
def test_stca_conflicts_detected_with_a_minute_of_warning(name):
    acs = CONFLICTS[name]
    alerts = fly(acs, first_loss_s(acs) + 20, nets())
    new = [a for a in alerts if a["status"] == "new"]
    assert len(new) == 1 and new[0]["kind"] == "stca" and new[0]["track_ids"] == [1, 2]
    warning = first_loss_s(acs) - new[0]["t"]
    assert warning >= 60.0, warning
    assert new[0]["min_sep_m"] < 5 * M_PER_NM and new[0]["time_to_cpa_s"] > 0


def test_parallel_tracks_6nm_apart_no_alert():
    acs = [dict(id=1, x=-60e3, y=0, vx=240, vy=0), dict(id=2, x=60e3, y=6 * M_PER_NM, vx=-240, vy=0)]
    assert fly(acs, 300, nets()) == []


def test_levelling_off_1000ft_apart_no_alert():
    # A descends to FL110, B climbs to FL100; both level 60 s before they pass
    acs = [
        dict(id=1, x=-60e3, y=0, vx=240, vy=0, fl=150, vr=-1500, level_at=110),
        dict(id=2, x=60e3, y=500, vx=-240, vy=0, fl=60, vr=1500, level_at=100),
    ]
    assert fly(acs, 300, nets()) == []


def test_selected_level_caps_the_vertical_prediction():
    # B climbs at 1000 fpm towards FL100, A level at FL110; without the selected level a conflict
    acs = [dict(id=1, x=-30e3, y=0, vx=240, vy=0, fl=110), dict(id=2, x=30e3, y=0, vx=-240, vy=0, fl=90, vr=1000)]
    base = arrays(
        [dict(id=a["id"], x=a["x"], y=a["y"], vx=a["vx"], vy=a["vy"], fl=a["fl"], vr=a.get("vr", 0)) for a in acs]
    )
    n1 = nets(stca_confirm_periods=1, stca_confirm_periods_far=1)
    assert n1.update(0.0, base)
    base.selected_fl = np.array([np.nan, 100.0])
    n2 = nets(stca_confirm_periods=1, stca_confirm_periods_far=1)
    assert n2.update(0.0, base) == []


def test_turn_prediction_warns_earlier_than_linear():
    # B flies north, turning left at 3°/s towards A's track (head-on once the turn is done)
    v, w = 230.0, math.radians(3.0)
    a_row = dict(id=1, x=-30e3, y=0.0, vx=v, vy=0.0)
    b_row = dict(id=2, x=30e3, y=-4390.0, vx=0.0, vy=v, ax=-v * w, ay=0.0)  # a = ω × v, left turn
    tr = arrays([a_row, b_row])
    turning = nets(stca_confirm_periods=1, stca_confirm_periods_far=1).update(0.0, tr)
    assert [a["track_ids"] for a in turning] == [[1, 2]]
    tr.ax_mps2[:] = 0.0  # same geometry without the turn: straight north, no conflict
    assert nets(stca_confirm_periods=1, stca_confirm_periods_far=1).update(0.0, tr) == []


def test_vertical_rate_history_is_the_least_squares_slope_of_the_last_periods():
    """The vertical acceleration per track against numpy's own line fit through its last
    HISTORY_PERIODS (t, rate) points; tracks come in any order; NaN below three points."""
    from radar_fusion.safety_nets.prediction import HISTORY_PERIODS, VerticalRateHistory

    rng = np.random.default_rng(5)
    hist = VerticalRateHistory()
    ids = np.array([11, 3, 7, 42])
    seen: dict[int, list[tuple[float, float]]] = {int(i): [] for i in ids}
    for k in range(7):
        t_s = 1.7e9 + 4.0 * k + rng.uniform(-0.2, 0.2)
        present = ids if k < 4 else np.append(ids, 99)  # 99 appears at the fifth period
        seen.setdefault(99, [])
        order = rng.permutation(present.size)
        rates = rng.normal(0.0, 1500.0, present.size)
        got = hist.update(t_s, present[order], rates[order])
        for track, rate, slope in zip(present[order].tolist(), rates[order].tolist(), got.tolist()):
            seen[track].append((t_s, rate))
            last = seen[track][-HISTORY_PERIODS:]
            if len(last) < 3:
                assert math.isnan(slope)
            else:
                tt, vv = np.array(last).T
                assert slope == pytest.approx(np.polyfit(tt - tt[0], vv, 1)[0], rel=1e-9, abs=1e-9)


def test_level_off_anticipation_spares_a_climb_that_captures_below_the_traffic_above():
    """A climbs from FL170 at 2,000 fpm, slowing by 50 fpm/s (a capture at FL176.7, 40 s
    on); B flies level at FL200 head-on, 70 km away. Straight-line, A's climb would cross
    FL191 while they pass; levelling off, it stays 2,333 ft below. From its third period
    on, the vertical rates' history shows the capture: no alert. Without the anticipation
    the same tracks alert."""

    def run(**cfg) -> list[dict]:
        net = nets(**cfg)
        alerts = []
        for k in range(10):
            t = 4.0 * k
            rate_fpm = max(2000.0 - 50.0 * t, 0.0)
            t_c = min(t, 40.0)
            z_ft = 17_000.0 + (2000.0 * t_c - 25.0 * t_c * t_c) / 60.0
            rows = [
                dict(id=1, x=0.0 + 240.0 * t, y=0.0, vx=240.0, vy=0.0, fl=z_ft / 100.0, vr=rate_fpm),
                dict(id=2, x=69_700.0 - 240.0 * t, y=0.0, vx=-240.0, vy=0.0, fl=200.0),
            ]
            alerts += net.update(1.7e9 + t, arrays(rows))
        return alerts

    assert run() == []
    assert [a["status"] for a in run(level_off_anticipation=False)][:1] == ["new"]


def test_stca_vertical_minimum_is_lowered_by_the_quantisation_tolerance():
    """Level, head-on: 950 ft apart is no conflict (1,000 ft less the 100 ft tolerance for
    Mode C's 100 ft steps), 850 ft is."""
    once = dict(stca_confirm_periods=1, stca_confirm_periods_far=1)
    for sep_ft, alerted in ((950.0, False), (850.0, True)):
        rows = [
            dict(id=1, x=0, y=0, vx=200, vy=0, fl=200.0),
            dict(id=2, x=30e3, y=0, vx=-200, vy=0, fl=200.0 + sep_ft / 100),
        ]
        assert bool(nets(**once).update(0.0, arrays(rows))) is alerted, sep_ft


def test_msaw_reads_altitude_from_the_flight_level_with_the_qnh():
    """An aircraft at FL100 over ALPS-EX1 (10,000 ft): its altitude is 10,000 ft plus 27 ft
    per hPa of QNH above standard, computed here by hand. A low QNH puts it below the
    minimum, a high one above."""
    _, y_edge = PLANE.to_plane(46.75, 8.0)
    row = [dict(id=3, x=0.0, y=float(y_edge) - 5_000, vx=0, vy=-150, fl=100.5)]
    for qnh_hpa in (990.0, 1013.25, 1030.0):
        altitude_ft = 100.5 * 100 + (qnh_hpa - 1013.25) * 27.0
        net = nets(msa_file=REPO / "deploy" / "msa-example.geojson", msaw_confirm_periods=1, qnh_hpa=qnh_hpa)
        out = net.update(0.0, arrays(row))
        assert bool(out) is (altitude_ft < 10_000.0), qnh_hpa


def test_per_area_override_uses_3nm():
    # 4 NM apart, parallel, same level: conflict with 5 NM, none inside a 3 NM TMA
    rows = [dict(id=1, x=0, y=0, vx=200, vy=0), dict(id=2, x=0, y=4 * M_PER_NM, vx=200, vy=0)]
    assert nets(stca_confirm_periods=1).update(0.0, arrays(rows))
    lat0, lon0 = 47.0, 8.0
    tma = dict(
        name="TMA",
        h_min_nm=3.0,
        v_min_ft=1000.0,
        polygon_latlon_deg=[
            [lat0 - 0.5, lon0 - 0.5],
            [lat0 - 0.5, lon0 + 0.5],
            [lat0 + 0.5, lon0 + 0.5],
            [lat0 + 0.5, lon0 - 0.5],
        ],
    )
    assert nets(stca_confirm_periods=1, stca_overrides=[tma]).update(0.0, arrays(rows)) == []


def test_overlapping_volumes_a_pair_takes_the_first_that_holds_both():
    """Volumes may nest: an approach core (2.5 NM) inside a TMA (3 NM), or a small 3 NM
    sector listed before a 5 NM upper airspace. A at the core, B in the TMA outside it, 4 NM
    apart, parallel at one level: the pair is in the TMA only, whatever A is in besides.
    (Tagged with each track's own first volume, the pair fell back to the default: a
    nuisance alert in the first case, a missed one in the second.)"""
    lat0, lon0 = 47.0, 8.0

    def box(south, north, half_width):
        return [
            [lat0 + south, lon0 - half_width],
            [lat0 + south, lon0 + half_width],
            [lat0 + north, lon0 + half_width],
            [lat0 + north, lon0 - half_width],
        ]

    north_edge = 0.03  # the inner volume ends 3.3 km north of A; B is 7.4 km north
    rows = [dict(id=1, x=0, y=0, vx=128.6, vy=0, fl=60), dict(id=2, x=0, y=4 * M_PER_NM, vx=128.6, vy=0, fl=60)]
    assert PLANE.to_geodetic(np.array([0.0]), np.array([4 * M_PER_NM]))[0][0] > lat0 + north_edge
    core = dict(name="APP-CORE", h_min_nm=2.5, polygon_latlon_deg=box(-0.5, north_edge, 0.5))
    tma = dict(name="TMA", h_min_nm=3.0, polygon_latlon_deg=box(-0.6, 0.6, 0.6))
    once = dict(stca_confirm_periods=1, stca_confirm_periods_far=1)
    assert nets(**once).update(0.0, arrays(rows))  # 5 NM by default
    assert nets(**once, stca_overrides=[tma]).update(0.0, arrays(rows)) == []
    assert nets(**once, stca_overrides=[core, tma]).update(0.0, arrays(rows)) == []
    high = [dict(r, fl=350) for r in rows]
    sector = dict(name="SECTOR-X", h_min_nm=3.0, polygon_latlon_deg=box(-0.5, north_edge, 0.5))
    upper = dict(name="UPPER", h_min_nm=5.0, lower_fl=245, polygon_latlon_deg=box(-2.0, 2.0, 2.0))
    assert nets(**once, stca_h_min_nm=3.0).update(0.0, arrays(high)) == []
    alerts = nets(**once, stca_h_min_nm=3.0, stca_overrides=[sector, upper]).update(0.0, arrays(high))
    assert [(a["kind"], a["status"]) for a in alerts] == [("stca", "new")]


def test_current_proximity_alerts_at_once_and_mode_s_duplicates_are_skipped():
    rows = [dict(id=1, x=0, y=0, vx=200, vy=0), dict(id=2, x=0, y=1000, vx=200, vy=0)]
    out = nets().update(0.0, arrays(rows))  # confirmation 2, but separation is already lost
    assert [a["status"] for a in out] == ["new"] and out[0]["time_to_violation_s"] == 0.0
    tr = arrays(rows)
    tr.mode_s = np.array([0x3C0001, 0x3C0001])
    assert nets().update(0.0, tr) == []


def test_unconfirmed_and_unknown_level_tracks_are_not_eligible():
    rows = [dict(id=1, x=0, y=0, vx=200, vy=0), dict(id=2, x=0, y=1000, vx=200, vy=0, confirmed=False)]
    assert nets().update(0.0, arrays(rows)) == []
    tr = arrays([dict(id=1, x=0, y=0, vx=200, vy=0), dict(id=2, x=0, y=1000, vx=200, vy=0)])
    tr.fl[1] = np.nan
    assert nets().update(0.0, tr) == []
    assert nets(stca_unknown_fl="conflict").update(0.0, tr)


# ------------------------------------------------------------------ life cycle


def test_life_cycle_confirmation_new_ongoing_ended_and_stable_ids():
    acs = CONFLICTS["head-on"]
    net = nets()
    alerts = fly(acs, 260, net)
    statuses = [a["status"] for a in alerts]
    assert statuses[0] == "new" and statuses[-1] == "ended" and set(statuses[1:-1]) == {"ongoing"}
    assert len({a["alert_id"] for a in alerts}) == 1
    # confirmation: the first hit period precedes the new alert (far conflicts need 4 periods)
    assert net.counters["hits_stca"] > len([a for a in alerts if a["status"] != "ended"])
    # a second conflict later gets a fresh id
    again = fly(acs, 260, net, t0=1.8e9)
    assert {a["alert_id"] for a in again} == {2}


def test_single_period_nuisance_hit_is_suppressed_and_ended_when_track_disappears():
    net = nets()
    # 60 km head-on: violation predicted 106 s ahead, a "far" conflict (4 periods to confirm)
    rows = [dict(id=1, x=-30e3, y=0, vx=240, vy=0), dict(id=2, x=30e3, y=0, vx=-240, vy=0)]
    far = [dict(id=1, x=-30e3, y=0, vx=240, vy=0), dict(id=2, x=30e3, y=30e3, vx=-240, vy=0)]
    assert net.update(0.0, arrays(rows)) == []  # one hit, not confirmed
    assert net.update(4.0, arrays(far)) == []  # run broken
    for k in range(2, 5):
        assert net.update(4.0 * k, arrays(rows)) == []  # 3 consecutive hits: not yet
    out = net.update(20.0, arrays(rows))
    assert [a["status"] for a in out] == ["new"]
    out = net.update(30.0, arrays(rows[:1]))  # track 2 gone
    assert [a["status"] for a in out] == ["ended"]


# ------------------------------------------------------------------ APW / MSAW


def _areas_file(tmp_path: Path) -> Path:
    p = tmp_path / "areas.geojson"
    p.write_text(
        json.dumps(
            {
                "type": "FeatureCollection",
                "features": [
                    {
                        "type": "Feature",
                        "properties": {"id": "R1", "lower_fl": 0, "upper_fl": 95},
                        "geometry": {
                            "type": "Polygon",
                            "coordinates": [[[8.1, 47.1], [8.3, 47.1], [8.3, 47.2], [8.1, 47.2], [8.1, 47.1]]],
                        },
                    }
                ],
            }
        )
    )
    return p


def test_apw_predicted_entry_and_inside(tmp_path):
    net = nets(areas_file=_areas_file(tmp_path), apw_confirm_periods=1)
    x0, y0 = PLANE.to_plane(47.15, 8.1)  # the western edge
    rows = [dict(id=7, x=float(x0) - 10_000, y=float(y0), vx=200, vy=0, fl=80)]
    out = net.update(0.0, arrays(rows))
    assert len(out) == 1 and out[0]["kind"] == "apw" and out[0]["area_id"] == "R1"
    assert out[0]["time_to_entry_s"] == pytest.approx(50.0, abs=2.5)
    inside = [dict(id=8, x=float(x0) + 2000, y=float(y0), vx=200, vy=0, fl=80)]
    out = nets(areas_file=_areas_file(tmp_path), apw_confirm_periods=1).update(0.0, arrays(inside))
    assert out[0]["time_to_entry_s"] == 0.0
    above = [dict(id=9, x=float(x0) + 2000, y=float(y0), vx=200, vy=0, fl=120)]
    assert nets(areas_file=_areas_file(tmp_path), apw_confirm_periods=1).update(0.0, arrays(above)) == []


def test_apw_sees_a_corner_clipped_between_two_samples(tmp_path):
    """A straight path that cuts R1's south-east corner over 30-400 m, at a random phase of
    the 2 s samples (500 m apart at 250 m/s): both samples either side of the clip can be
    outside. Every path is warned of, at the time it enters, which is found here by
    testing points 5 cm apart along it."""
    from radar_fusion.safety_nets.polygon import Polygon, ring_xy

    ring = [[8.1, 47.1], [8.3, 47.1], [8.3, 47.2], [8.1, 47.2]]
    poly = Polygon([(ring_xy(PLANE, ring), [])])
    cx, cy = (float(np.ravel(v)[0]) for v in PLANE.to_plane(np.array([47.1]), np.array([8.3])))
    v = 250.0
    vx = vy = v / math.sqrt(2.0)  # north-east, past the corner
    rng = np.random.default_rng(3)
    for off_m in np.linspace(20.0, 280.0, 14):
        px, py = cx - off_m / math.sqrt(2.0), cy + off_m / math.sqrt(2.0)  # off_m inside the corner
        lead_s = 60.0 + rng.uniform(0.0, 2.0)
        x0, y0 = px - vx * lead_s, py - vy * lead_s
        fine_t = np.arange(0.0, 2 * lead_s, 0.0002 * 1000 / v)  # 5 cm apart
        truth = poly.contains(np.column_stack([x0 + vx * fine_t, y0 + vy * fine_t]))
        assert truth.any() and not truth[0]
        out = nets(areas_file=_areas_file(tmp_path), apw_confirm_periods=1).update(
            0.0, arrays([dict(id=1, x=x0, y=y0, vx=vx, vy=vy, fl=80)])
        )
        assert [a["area_id"] for a in out] == ["R1"], off_m
        assert out[0]["time_to_entry_s"] == pytest.approx(fine_t[np.argmax(truth)], abs=0.01)


def test_apw_no_entry_where_the_path_crosses_the_corner_above_the_volume(tmp_path):
    """A descent at 1,500 fpm that clips R1's corner (FL0-95) at FL95.2, inside the band only
    after it has left the area again: no entry. The band was judged at either sample of the
    segment, and the sample after the clip (FL94.x, outside the area) made one."""
    from radar_fusion.safety_nets.polygon import Polygon, ring_xy

    ring = [[8.1, 47.1], [8.3, 47.1], [8.3, 47.2], [8.1, 47.2]]
    poly = Polygon([(ring_xy(PLANE, ring), [])])
    cx, cy = (float(np.ravel(v)[0]) for v in PLANE.to_plane(np.array([47.1]), np.array([8.3])))
    v = 250.0
    vx = vy = v / math.sqrt(2.0)
    for lead_s in 60.0 + np.linspace(0.0, 1.9, 12):  # the phase of the 2 s samples
        px, py = cx - 40.0 / math.sqrt(2.0), cy + 40.0 / math.sqrt(2.0)  # a 80 m chord
        x0, y0 = px - vx * lead_s, py - vy * lead_s
        fine_t = np.arange(0.0, 2 * lead_s, 0.0002 * 1000 / v)
        t_in = fine_t[np.argmax(poly.contains(np.column_stack([x0 + vx * fine_t, y0 + vy * fine_t])))]
        fl0 = 95.2 + 0.25 * t_in  # 1,500 fpm down: FL95.2 where it enters, below 95 0.8 s on
        row = dict(id=1, x=x0, y=y0, vx=vx, vy=vy, fl=fl0, vr=-1500.0)
        assert nets(areas_file=_areas_file(tmp_path), apw_confirm_periods=1).update(0.0, arrays([row])) == [], lead_s


def test_msaw_sees_a_corner_of_high_terrain_clipped_between_two_samples(tmp_path):
    """As APW: level at FL80, a straight path cuts the corner of a 10,000 ft MSA polygon
    over 30-400 m, between two samples 500 m apart that are both outside. Warned of at the
    time it enters, found here by testing points 5 cm apart; and not warned of above it."""
    from radar_fusion.safety_nets.polygon import Polygon, ring_xy

    ring = [[8.1, 47.1], [8.3, 47.1], [8.3, 47.2], [8.1, 47.2]]
    msa = tmp_path / "msa.geojson"
    msa.write_text(
        json.dumps(
            {
                "type": "FeatureCollection",
                "features": [
                    {
                        "type": "Feature",
                        "properties": {"id": "RIDGE", "min_alt_ft": 10_000},
                        "geometry": {"type": "Polygon", "coordinates": [ring + ring[:1]]},
                    }
                ],
            }
        )
    )
    poly = Polygon([(ring_xy(PLANE, ring), [])])
    cx, cy = (float(np.ravel(v)[0]) for v in PLANE.to_plane(np.array([47.1]), np.array([8.3])))
    v = 250.0
    vx = vy = v / math.sqrt(2.0)
    rng = np.random.default_rng(4)
    for off_m in np.linspace(20.0, 280.0, 14):
        px, py = cx - off_m / math.sqrt(2.0), cy + off_m / math.sqrt(2.0)
        lead_s = 60.0 + rng.uniform(0.0, 2.0)
        x0, y0 = px - vx * lead_s, py - vy * lead_s
        fine_t = np.arange(0.0, 2 * lead_s, 0.0002 * 1000 / v)
        truth = poly.contains(np.column_stack([x0 + vx * fine_t, y0 + vy * fine_t]))
        assert truth.any() and not truth[0]
        row = dict(id=1, x=x0, y=y0, vx=vx, vy=vy, fl=80)
        out = nets(msa_file=msa, msaw_confirm_periods=1).update(0.0, arrays([row]))
        assert [(a["area_id"], a["min_alt_ft"]) for a in out] == [("RIDGE", 10_000.0)], off_m
        assert out[0]["time_to_violation_s"] == pytest.approx(fine_t[np.argmax(truth)], abs=0.01)
        assert nets(msa_file=msa, msaw_confirm_periods=1).update(0.0, arrays([dict(row, fl=105)])) == []


def test_msaw_descent_towards_high_terrain_with_vertical_rate():
    net = nets(msa_file=REPO / "deploy" / "msa-example.geojson", msaw_confirm_periods=1)
    _, y_edge = PLANE.to_plane(46.75, 8.0)  # ALPS-EX1 (10,000 ft) begins south of here
    x0 = 0.0
    level = [dict(id=3, x=x0, y=float(y_edge) + 12_000, vx=0, vy=-150, fl=110)]
    assert net.update(0.0, arrays(level)) == []  # 1,000 ft above the MSA: safe
    desc = [dict(id=3, x=x0, y=float(y_edge) + 12_000, vx=0, vy=-150, fl=110, vr=-1500)]
    out = nets(msa_file=REPO / "deploy" / "msa-example.geojson", msaw_confirm_periods=1).update(0.0, arrays(desc))
    assert len(out) == 1 and out[0]["kind"] == "msaw" and out[0]["min_alt_ft"] == 10000.0
    assert out[0]["time_to_violation_s"] == pytest.approx(80.0, abs=2.5)  # reaches the terrain at 80 s


def test_msaw_grid_map(tmp_path):
    p = tmp_path / "grid.json"
    p.write_text(
        json.dumps(
            {
                "type": "MsaGrid",
                "lat0_deg": 46.9,
                "lon0_deg": 7.9,
                "dlat_deg": 0.1,
                "dlon_deg": 0.1,
                "min_alt_ft": [[3000, 3000], [3000, 9000]],
            }
        )
    )
    net = nets(msa_file=p, msaw_confirm_periods=1)
    x, y = PLANE.to_plane(47.05, 8.05)  # cell (1, 1): 9,000 ft
    out = net.update(0.0, arrays([dict(id=1, x=float(x), y=float(y), vx=0, vy=0, fl=80)]))
    assert out and out[0]["min_alt_ft"] == 9000.0 and out[0]["time_to_violation_s"] == 0.0


def test_example_files_load():
    assert [a.area_id for a in sn.load_areas(REPO / "deploy" / "areas-example.geojson", PLANE)] == [
        "LSR-EX1",
        "LSD-EX2",
    ]
    assert sn.load_msa(REPO / "deploy" / "msa-example.geojson", PLANE).max_alt_ft == 10000.0


# ------------------------------------------------------------------ scale


def test_4000_tracks_pruned_far_below_all_pairs():
    rng = np.random.default_rng(3)
    n = 4000
    hd = rng.uniform(0, 2 * np.pi, n)
    sp = rng.uniform(100, 250, n)
    x, y = rng.uniform(-4e5, 4e5, n), rng.uniform(-4e5, 4e5, n)
    tr = columns(
        np.arange(n),
        x,
        y,
        sp * np.sin(hd),
        sp * np.cos(hd),
        rng.normal(0, 0.2, n),
        rng.normal(0, 0.2, n),
        rng.integers(50, 400, n).astype(float),
        rng.normal(0, 800, n),
    )
    net = nets()
    out = net.update(0.0, tr)
    assert 0 < net.last_candidate_pairs < 0.02 * n * (n - 1) / 2
    for a in out:
        Alert.model_validate(a)


def test_pruning_loses_no_conflict():
    # every pair flagged by an unpruned all-pairs evaluation is among the pruned hits
    rng = np.random.default_rng(5)
    n = 300
    x, y = rng.uniform(-1e5, 1e5, n), rng.uniform(-1e5, 1e5, n)
    hd, sp = rng.uniform(0, 2 * np.pi, n), rng.uniform(100, 300, n)
    fl = rng.integers(300, 320, n).astype(float)
    tr = columns(np.arange(n), x, y, sp * np.sin(hd), sp * np.cos(hd), np.zeros(n), np.zeros(n), fl, np.zeros(n))
    net = nets(stca_confirm_periods=1, stca_confirm_periods_far=1)
    got = {tuple(a["track_ids"]) for a in net.update(0.0, tr)}
    i, j = np.triu_indices(n, 1)
    T = 120.0
    res = segment_conflicts(
        np.column_stack([x[j] - x[i], x[j] - x[i] + (tr.vx_mps[j] - tr.vx_mps[i]) * T]),
        np.column_stack([y[j] - y[i], y[j] - y[i] + (tr.vy_mps[j] - tr.vy_mps[i]) * T]),
        np.column_stack([(fl[j] - fl[i]) * 100] * 2),
        np.array([0.0, T]),
        np.full(i.size, 5 * M_PER_NM),
        np.full(i.size, 900.0),
    )
    expected = {(int(a), int(b)) for a, b in zip(i[res["conflict"]], j[res["conflict"]])}
    assert expected and expected <= got


def test_candidate_pairs_are_each_pairs_own_bound_by_brute_force():
    """The pair search (tracks grouped by speed, one k-d tree per group) returns exactly
    the pairs an all-pairs loop keeps with each pair's own speeds, sorted, however fast a
    few (wild) tracks are: |m_i - m_j| <= S + (|v_i| + |v_j|) T/2 + 1 m on the midpoints,
    or, with a turning member, |p_i - p_j| <= S + (|v_i| + |v_j|) T + 1 m."""
    from radar_fusion.safety_nets.stca import candidate_pairs

    rng = np.random.default_rng(11)
    n, S, T = 500, 5 * M_PER_NM, 120.0
    p = rng.uniform(-3e5, 3e5, (n, 2))
    speed = rng.uniform(0.0, 280.0, n)
    speed[:6] = [0.0, 20.0, 900.0, 2500.0, 6000.0, 11000.0]
    hd = rng.uniform(0, 2 * np.pi, n)
    v = speed[:, None] * np.column_stack([np.sin(hd), np.cos(hd)])
    mid = p + v * T / 2
    turning = rng.random(n) < 0.2
    pairs = candidate_pairs(mid, p, speed, turning, S, T)
    i, j = np.triu_indices(n, 1)
    d_mid = np.hypot(*(mid[i] - mid[j]).T)
    d_now = np.hypot(*(p[i] - p[j]).T)
    keep = (d_mid <= S + (speed[i] + speed[j]) * T / 2 + 1.0) | (
        (turning[i] | turning[j]) & (d_now <= S + (speed[i] + speed[j]) * T + 1.0)
    )
    np.testing.assert_array_equal(pairs, np.column_stack([i[keep], j[keep]]))  # triu order: sorted by i, j
    assert candidate_pairs(mid[:1], p[:1], speed[:1], turning[:1], S, T).shape == (0, 2)


# ------------------------------------------------------------------ hooks


class _EP:
    def __init__(self, name, group, obj):
        self.name, self.group, self._obj = name, group, obj

    def load(self):
        return self._obj


class _EPs(list):
    def select(self, group):
        return [e for e in self if e.group == group]


received: list[dict] = []


class _ExtraFunction:
    def __init__(self, config, plane):
        self.plane = plane

    def update(self, t_s, tracks):
        return [
            {
                "v": 1,
                "kind": "apw",
                "alert_id": 999,
                "t": t_s,
                "track_ids": [int(tracks.track_id[0])],
                "status": "new",
                "area_id": "SITE",
            }
        ]


def _raising(alert):
    raise RuntimeError("consumer bug")


def test_entry_point_hooks_receive_alerts_and_a_raising_hook_is_counted(monkeypatch):
    received.clear()
    eps = _EPs(
        [
            _EP("good", sn.CONSUMER_GROUP, received.append),
            _EP("bad", sn.CONSUMER_GROUP, _raising),
            _EP("extra", sn.FUNCTION_GROUP, _ExtraFunction),
        ]
    )
    monkeypatch.setattr(metadata, "entry_points", lambda: eps)
    hooks = load_hooks(SafetyNetsConfig(), PLANE)
    assert [n for n, _ in hooks.consumers] == ["good", "bad"] and [n for n, _ in hooks.functions] == ["extra"]
    net = SafetyNets(SafetyNetsConfig(), PLANE)  # discovers the hooks itself
    rows = [dict(id=1, x=0, y=0, vx=200, vy=0), dict(id=2, x=0, y=1000, vx=200, vy=0)]
    out = net.update(0.0, arrays(rows))
    assert {a["kind"] for a in out} == {"stca", "apw"}
    assert received == out
    assert net.hook_errors == {"bad": 2} and net.counters["hook_errors"] == 2
    out2 = net.update(4.0, arrays(rows))  # still running
    assert len(received) == len(out) + len(out2)


def test_a_broken_entry_point_is_logged_not_fatal(monkeypatch):
    class Broken:
        def load(self):
            raise ImportError("no such module")

        name, group = "broken", sn.FUNCTION_GROUP

    monkeypatch.setattr(metadata, "entry_points", lambda: _EPs([Broken()]))
    hooks = load_hooks()
    assert hooks.functions == [] and "broken" in next(iter(hooks.load_errors))


def test_config_rejects_unknown_fields():
    with pytest.raises(ValidationError, match=r"stca_h_min\n  Extra inputs are not permitted"):
        SafetyNetsConfig(stca_h_min=5)


# ------------------------------------------------------------------ point in polygon


def _star(rng: np.random.Generator, n: int, r_lo: float, r_hi: float, grid: float | None = None) -> np.ndarray:
    """A star-shaped ring around the origin (concave for spread radii), optionally snapped to a grid."""
    ang = np.sort(rng.uniform(0, 2 * np.pi, n))
    r = rng.uniform(r_lo, r_hi, n)
    ring = np.column_stack([r * np.cos(ang), r * np.sin(ang)])
    return np.round(ring / grid) * grid if grid else ring


def _mpl_contains(outer: np.ndarray, holes: list[np.ndarray], xy: np.ndarray) -> np.ndarray:
    from matplotlib.path import Path as MplPath  # the reference implementation, in the test only

    inside = MplPath(outer).contains_points(xy)
    for h in holes:
        inside &= ~MplPath(h).contains_points(xy)
    return inside


@pytest.mark.parametrize("seed", range(6))
def test_point_in_polygon_matches_matplotlib_on_concave_polygons_with_holes(seed):
    rng = np.random.default_rng(seed)
    grid = 1000.0 if seed % 2 else None  # snapped vertices: horizontal edges, points on edges and vertices
    outer = _star(rng, 80, 30e3, 60e3, grid)  # above SORT_ABOVE_EDGES: tested on y-sorted points
    holes = [_star(rng, 12, 5e3, 20e3, grid)]  # below: each edge against every point
    outer = np.vstack([outer, outer[:1]])  # closed as GeoJSON writes it
    pts = rng.uniform(-70e3, 70e3, (20_000, 2))
    if grid:
        pts = np.round(pts / grid) * grid
    assert holes[0].shape[0] <= SORT_ABOVE_EDGES < outer.shape[0]
    pts = np.vstack([pts, outer, holes[0], (outer[:-1] + outer[1:]) / 2, [[np.nan, 0.0], [0.0, np.nan]]])
    got = Polygon([(outer, holes)]).contains(pts)
    expected = _mpl_contains(outer, holes, pts)
    assert 0.1 < expected.mean() < 0.9  # both answers well represented
    np.testing.assert_array_equal(got, expected)
    np.testing.assert_array_equal(ring_contains(outer, pts), _mpl_contains(outer, [], pts))


def test_point_in_multipolygon_from_geojson_is_the_union_of_its_parts():
    square = [[8.0, 47.0], [8.2, 47.0], [8.2, 47.2], [8.0, 47.2], [8.0, 47.0]]
    hole = [[8.05, 47.05], [8.15, 47.05], [8.15, 47.15], [8.05, 47.15], [8.05, 47.05]]
    other = [[7.6, 46.8], [7.8, 46.8], [7.7, 46.95], [7.6, 46.8]]
    poly = Polygon.from_geojson(PLANE, {"type": "MultiPolygon", "coordinates": [[square, hole], [other]]})
    lat = np.array([47.02, 47.10, 46.85, 47.30, 46.85])
    lon = np.array([8.02, 8.10, 7.70, 8.10, 7.61])
    x, y = PLANE.to_plane(lat, lon)
    # in the square; in its hole; in the triangle; north of everything; west of the triangle's edge
    assert poly.contains(np.column_stack([x, y])).tolist() == [True, False, True, False, False]


def test_daemon_modules_do_not_import_matplotlib():
    code = (
        "import sys, radar_fusion.bus, radar_fusion.cli, radar_fusion.engine, radar_fusion.safety_nets; "
        "print(sorted(m for m in sys.modules if m.split('.')[0] == 'matplotlib'))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"


# ------------------------------------------------------------------ track columns


def _proximity_pair(status: list[int]) -> TrackColumns:
    tr = arrays([dict(id=1, x=0, y=0, vx=200, vy=0), dict(id=2, x=0, y=1000, vx=200, vy=0)])
    tr.status = np.array(status, np.int8)
    tr.mode_s = np.array([0x3C0001, 0x3C0002])
    return tr


def test_track_columns_from_message_reads_back_what_to_message_wrote():
    tr = _proximity_pair([CONFIRMED, COASTING])
    tr.x[:, 2] = [0.5, -0.25]  # accelerations
    msg = tr.to_message()
    for received in (msg, TrackBatch.model_validate(msg), msg["tracks"]):
        back = TrackColumns.from_message(received, PLANE)
        np.testing.assert_array_equal(back.track_id, tr.track_id)
        np.testing.assert_array_equal(back.status, tr.status)
        np.testing.assert_array_equal(back.x, tr.x)
        np.testing.assert_array_equal(back.cov_xy, tr.cov_xy)
        np.testing.assert_array_equal(back.fl, tr.fl)
        np.testing.assert_array_equal(back.mode_s, tr.mode_s)
        np.testing.assert_array_equal(back.updates, tr.updates)
        np.testing.assert_array_equal(back.lat_deg, tr.lat_deg)  # taken from the message
        np.testing.assert_array_equal(back.lon_deg, tr.lon_deg)
        assert back.safety_eligible.tolist() == [True, False]  # status == confirmed
        assert back.to_message()["tracks"] == msg["tracks"]
    assert TrackColumns.from_message(msg, PLANE).period == msg["period"]
    assert TrackColumns.from_message(msg["tracks"], PLANE).period == -1


def test_coasting_tracks_are_judged_from_the_engine_but_not_from_a_received_batch():
    # the engine's columns: every track that is not tentative (confirmed or coasting)
    assert [a["track_ids"] for a in nets().update(0.0, _proximity_pair([CONFIRMED, COASTING]))] == [[1, 2]]
    assert nets().update(0.0, _proximity_pair([CONFIRMED, TENTATIVE])) == []
    # a received TrackBatch: status confirmed only, as TrackArrays.from_tracks did
    received = TrackColumns.from_message(_proximity_pair([CONFIRMED, COASTING]).to_message(), PLANE)
    assert nets().update(0.0, received) == []
    received = TrackColumns.from_message(_proximity_pair([CONFIRMED, CONFIRMED]).to_message(), PLANE)
    assert [a["track_ids"] for a in nets().update(0.0, received)] == [[1, 2]]


# ------------------------------------------------------------------ health counters


def test_safety_net_counters_reach_the_health_message():
    from radar_fusion.config import settings_from_dict
    from radar_fusion.engine import Engine

    settings = settings_from_dict(
        {
            "system": {"center_lat": 47.0, "center_lon": 8.0},
            "radars": [dict(id="r1", lat=47.0, lon=8.0, sigma_range_m=50, sigma_azimuth_deg=0.1, rotation_period_s=4)],
        }
    )
    net = nets()
    engine = Engine(settings, safety_nets=net)
    assert engine.health()["counters"]["safety_nets_alerts_new_stca"] == 0  # present before any alert
    pair = _proximity_pair([CONFIRMED, CONFIRMED])
    net.update(0.0, pair)  # separation lost now: new at once
    net.update(4.0, pair)  # ongoing
    net.update(8.0, arrays([dict(id=1, x=0, y=0, vx=200, vy=0)]))  # track 2 gone: ended
    counters = engine.health()["counters"]
    assert {
        k: counters[f"safety_nets_{k}"]
        for k in ("periods", "hits_stca", "alerts_new", "alerts_new_stca", "alerts_ended_stca", "alerts_new_apw")
    } == {
        "periods": 3,
        "hits_stca": 2,
        "alerts_new": 1,
        "alerts_new_stca": 1,
        "alerts_ended_stca": 1,
        "alerts_new_apw": 0,
    }
    h = engine.health()
    h.pop("newest_period_t")
    Health.model_validate({"v": 1, "t": 0.0, "uptime_s": 0.0, **h})  # the wire contract takes them as they are
