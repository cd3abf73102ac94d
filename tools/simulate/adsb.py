"""Real flights from the ADS-B table (``../shared/data/adsb/switzerland_2018-08-01.json.gz``)
as scenario targets with recorded paths.

The table's fixes are not used as truth directly: they repeat stale positions and carry
up to about a second of timing jitter (tens of metres along track, sometimes hundreds),
so a path through them has accelerations no aircraft flies. Each flight is smoothed
first (:mod:`radar_fusion.tools.smoothing`): stale repeats dropped, a robust cubic
smoothing spline per axis in time in a local plane (a stereographic plane at the
flight's mean position) and one of the altitude. The target's :class:`SampledPath` is
that smoothed path resampled every :data:`RESAMPLE_STEP_S` (groundspeed, track and
vertical rate from the spline's derivative, not the reported ones), so the simulator's
interpolating spline through it reproduces the smoothed path, the radars see the
smoothed path, and the truth velocity is its derivative in the system plane.
:func:`adsb_smoothing_stats` measures the smoothing (residual, accelerations before and
after)."""

from __future__ import annotations

import functools
import gzip
import itertools
import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.interpolate import CubicSpline

from radar_fusion.geo.coordinates import WGS84_GEOD, SystemPlane
from radar_fusion.geo.units import M_PER_FT, MPS_PER_FPM, MPS_PER_KT

from ..smoothing import SmoothedFlight, second_difference_accel_mps2, smooth_flight
from .scenario import SampledPath, Target, mode3a_codes

PROJECT_ROOT = Path(__file__).resolve().parents[2]
ADSB_TABLE = PROJECT_ROOT.parent / "shared" / "data" / "adsb" / "switzerland_2018-08-01.json.gz"

ADSB_DEFAULT_START_T_S = 1533123000.0
"""2018-08-01 11:30 UTC: the busiest 20 minutes of the ADS-B table (74 aircraft)."""
RESAMPLE_STEP_S = 1.0
"""Spacing of the smoothed samples a target's path is made of."""
FIT_MARGIN_S = 120.0
"""Fixes up to this long before and after the window (same gap-free piece) enter the fit,
so the smoothed path has no end effects inside the window."""


def _wgs84_inv(lon1, lat1, lon2, lat2):
    return WGS84_GEOD.inv(lon1, lat1, lon2, lat2)


@functools.lru_cache(maxsize=2)
def _adsb_table(path: str) -> dict[str, np.ndarray]:
    """The ADS-B table as columns sorted by (icao24, time)."""
    with gzip.open(path, "rt", encoding="utf-8") as f:
        rows = json.load(f)
    if not isinstance(rows, list):
        raise ValueError(f"{path}: expected a JSON list of records")
    get = lambda k, dtype=float: np.array([r.get(k) for r in rows], dtype=dtype)
    cols = {
        "t_s": get("timestamp") / 1000.0,
        "icao24": np.array([str(r.get("icao24") or "") for r in rows]),
        "callsign": np.array([str(r.get("callsign") or "").strip() for r in rows]),
        "lat_deg": get("latitude"),
        "lon_deg": get("longitude"),
        "alt_ft": get("altitude"),
        "groundspeed_kt": get("groundspeed"),
        "track_deg": get("track"),
        "vrate_fpm": get("vertical_rate"),
    }
    good = np.ones(len(rows), bool)
    for k in ("t_s", "lat_deg", "lon_deg", "alt_ft", "groundspeed_kt", "track_deg"):
        good &= np.isfinite(cols[k])
    cols["vrate_fpm"] = np.where(np.isfinite(cols["vrate_fpm"]), cols["vrate_fpm"], 0.0)
    order = np.lexsort((cols["t_s"], cols["icao24"]))
    order = order[good[order]]
    cols = {k: v[order] for k, v in cols.items()}
    # Stale or misplaced positions: a sample is dropped when every chord to its
    # neighbours (same aircraft, <= 30 s apart) implies a speed more than 35 % off the
    # reported groundspeed (typically a repeated position at the start of a track).
    # Aircraft with more than 20 % of such samples are dropped entirely.
    icao, t = cols["icao24"], cols["t_s"]
    _, _, dist_m = _wgs84_inv(cols["lon_deg"][:-1], cols["lat_deg"][:-1], cols["lon_deg"][1:], cols["lat_deg"][1:])
    dt = np.diff(t)
    chord = (icao[1:] == icao[:-1]) & (dt > 0) & (dt <= 30.0)
    gs_mps = 0.5 * (cols["groundspeed_kt"][1:] + cols["groundspeed_kt"][:-1]) * MPS_PER_KT
    with np.errstate(invalid="ignore", divide="ignore"):
        off = np.abs(dist_m / np.where(chord, dt, 1.0) / np.maximum(gs_mps, 1.0) - 1.0) > 0.35
    n = t.size
    good_chords = np.zeros(n, np.int32)
    np.add.at(good_chords, np.nonzero(chord & ~off)[0], 1)
    np.add.at(good_chords, np.nonzero(chord & ~off)[0] + 1, 1)
    bad = good_chords == 0
    uniq, inverse = np.unique(icao, return_inverse=True)
    bad_share = np.bincount(inverse, weights=bad, minlength=uniq.size) / np.bincount(inverse, minlength=uniq.size)
    keep = ~bad & (bad_share[inverse] <= 0.2)
    return {k: v[keep] for k, v in cols.items()}


@dataclass(frozen=True)
class _Flight:
    icao24: str
    rows: tuple[int, int]
    """table rows of the flight's samples in the window, with one beyond each end"""
    fit_rows: tuple[int, int]
    """table rows entering the smoothing fit (the window's piece, ``FIT_MARGIN_S`` wider)"""


@functools.lru_cache(maxsize=8)
def _select_flights(
    path: str, start_t_s: float, duration_s: float, max_aircraft: int, max_gap_s: float, min_overlap_s: float
) -> tuple[_Flight, ...]:
    """The flights of :func:`adsb_targets`, sorted by icao24."""
    tab = _adsb_table(path)
    w0, w1 = float(start_t_s), float(start_t_s) + float(duration_s)
    icao = tab["icao24"]
    t = tab["t_s"]
    starts = np.concatenate([[0], np.nonzero(icao[1:] != icao[:-1])[0] + 1, [icao.size]])
    found: list[tuple[float, _Flight]] = []
    for a, b in itertools.pairwise(starts):
        ta = t[a:b]
        if ta[-1] < w0 or ta[0] > w1:
            continue
        cuts = np.concatenate([[0], np.nonzero(np.diff(ta) > max_gap_s)[0] + 1, [ta.size]])
        best = None
        for c0, c1 in itertools.pairwise(cuts):
            overlap = min(ta[c1 - 1], w1) - max(ta[c0], w0)
            if overlap >= min_overlap_s and c1 - c0 >= 2 and (best is None or overlap > best[0]):
                best = (overlap, c0, c1)
        if best is None:
            continue
        overlap, c0, c1 = best
        seg = ta[c0:c1]
        lo = max(int(np.searchsorted(seg, w0, side="right")) - 1, 0)
        hi = min(int(np.searchsorted(seg, w1, side="left")) + 1, seg.size)
        if hi - lo >= 2:
            f0 = int(np.searchsorted(seg, seg[lo] - FIT_MARGIN_S, side="left"))
            f1 = int(np.searchsorted(seg, seg[hi - 1] + FIT_MARGIN_S, side="right"))
            rows = (int(a + c0 + lo), int(a + c0 + hi))
            found.append((float(overlap), _Flight(str(icao[a]), rows, (int(a + c0 + f0), int(a + c0 + f1)))))
    found.sort(key=lambda f: (-f[0], f[1].icao24))
    return tuple(sorted((f for _, f in found[:max_aircraft]), key=lambda f: f.icao24))


@functools.lru_cache(maxsize=1024)
def _smoothed(path: str, fit_rows: tuple[int, int]) -> tuple[SystemPlane, SmoothedFlight]:
    """The flight's fixes ``fit_rows`` smoothed in a local plane at their mean position."""
    tab = _adsb_table(path)
    a, b = fit_rows
    lat, lon = tab["lat_deg"][a:b], tab["lon_deg"][a:b]
    plane = SystemPlane(float(np.mean(lat)), float(np.mean(lon)))
    x_m, y_m = plane.to_plane(lat, lon)
    return plane, smooth_flight(tab["t_s"][a:b], x_m, y_m, tab["alt_ft"][a:b] * M_PER_FT)


def _smoothed_path(path: str, flight: _Flight) -> SampledPath:
    """The smoothed path over the flight's window rows, every ``RESAMPLE_STEP_S``."""
    t_all = _adsb_table(path)["t_s"]
    t0, t1 = float(t_all[flight.rows[0]]), float(t_all[flight.rows[1] - 1])
    plane, smoothed = _smoothed(path, flight.fit_rows)
    n_steps = max(int(np.ceil((t1 - t0) / RESAMPLE_STEP_S - 1e-9)), 1)
    t = np.linspace(t0, t1, n_steps + 1)
    x_m, y_m, z_m = smoothed.position(t)
    vx_mps, vy_mps, vz_mps = smoothed.velocity(t)
    lat, lon = plane.to_geodetic(x_m, y_m)
    return SampledPath(
        t_s=t,
        lat_deg=np.asarray(lat, float),
        lon_deg=np.asarray(lon, float),
        alt_ft=z_m / M_PER_FT,
        groundspeed_kt=np.hypot(vx_mps, vy_mps) / MPS_PER_KT,
        track_deg=np.degrees(np.arctan2(vx_mps, vy_mps)) % 360.0,
        vrate_fpm=vz_mps / MPS_PER_FPM,
    )


def adsb_targets(
    start_t_s: float,
    duration_s: float,
    max_aircraft: int = 80,
    path: str | Path | None = None,
    max_gap_s: float = 30.0,
    min_overlap_s: float = 60.0,
    seed: int = 0,
) -> list[Target]:
    """Real flights of the ADS-B table airborne in ``[start_t_s, start_t_s + duration_s]``.

    Per aircraft, the samples are split at gaps longer than ``max_gap_s``; the piece
    with the longest overlap with the window is kept (if it overlaps at least
    ``min_overlap_s``), from one sample before the window to one beyond it. At most
    ``max_aircraft`` flights, those longest in the window first. The path is the
    flight's smoothed path (module docstring; the fit also uses the piece's fixes up to
    ``FIT_MARGIN_S`` beyond that span). Identity: Mode S address from icao24, callsign
    from the table, a Mode 3/A code drawn per aircraft.
    """
    table_path = str(path or ADSB_TABLE)
    tab = _adsb_table(table_path)
    flights = _select_flights(
        table_path, float(start_t_s), float(duration_s), int(max_aircraft), float(max_gap_s), float(min_overlap_s)
    )
    rng = np.random.default_rng(seed)
    codes = mode3a_codes(rng, len(flights))
    out = []
    for flight, code in zip(flights, codes.tolist()):
        callsign = str(tab["callsign"][flight.rows[0]]) or None
        out.append(
            Target(
                target_id=flight.icao24,
                callsign=callsign,
                mode_s=int(flight.icao24, 16),
                mode3a=int(code),
                transponder="modes",
                mode_c=True,
                alt_quantum_ft=25.0,
                path=_smoothed_path(table_path, flight),
            )
        )
    return out


def adsb_smoothing_stats(
    start_t_s: float,
    duration_s: float,
    max_aircraft: int = 80,
    path: str | Path | None = None,
    max_gap_s: float = 30.0,
    min_overlap_s: float = 60.0,
) -> dict[str, float]:
    """How the truth of :func:`adsb_targets` (same arguments) was smoothed, over the fixes
    of its flights in their windows (all flights pooled):

    * ``fixes``, ``stale_fixes`` (dropped repeats), ``rejected_fixes`` (robust weight 0);
    * ``residual_rms_m``: RMS horizontal distance raw fix - smoothed path, over every kept
      fix; ``residual_inlier_rms_m`` over the fixes not rejected; ``residual_median_m``;
    * second-difference accelerations, 95th percentile of the horizontal magnitude:
      ``accel_p95_raw_fixes_mps2`` of the kept raw fixes at their own times (10 s);
      ``accel_p95_interpolated_1s_mps2`` of a C2 cubic spline through them at 1 s (the
      truth before smoothing); ``accel_p95_smoothed_1s_mps2`` of the smoothed path at
      1 s (the truth now); ``accel_p99_smoothed_1s_mps2`` likewise.
    """
    table_path = str(path or ADSB_TABLE)
    t_all = _adsb_table(table_path)["t_s"]
    flights = _select_flights(
        table_path, float(start_t_s), float(duration_s), int(max_aircraft), float(max_gap_s), float(min_overlap_s)
    )
    res, inl, a_raw, a_int, a_sm = [], [], [], [], []
    n_fix = n_stale = n_rej = 0
    for flight in flights:
        t0, t1 = float(t_all[flight.rows[0]]), float(t_all[flight.rows[1] - 1])
        _, sm = _smoothed(table_path, flight.fit_rows)
        win = (sm.t_s >= t0) & (sm.t_s <= t1)
        fa, fb = flight.fit_rows
        t_fit = t_all[fa:fb]
        n_stale += int(np.count_nonzero((t_fit >= t0) & (t_fit <= t1))) - int(win.sum())
        r = sm.residual_m()[win]
        n_fix += int(win.sum())
        n_rej += int(np.count_nonzero(sm.weight_xy[win] == 0.0))
        res.append(r)
        inl.append(r[sm.weight_xy[win] > 0.0])
        t, x, y = sm.t_s[win], sm.x_m[win], sm.y_m[win]
        a_raw.append(second_difference_accel_mps2(t, x, y))
        grid = np.arange(t0, t1 + 1e-9, 1.0)
        if t.size >= 2:
            xy = CubicSpline(t, np.column_stack([x, y]), bc_type="not-a-knot" if t.size >= 4 else "natural")(grid)
            a_int.append(second_difference_accel_mps2(grid, xy[:, 0], xy[:, 1]))
        gx, gy, _ = sm.position(grid)
        a_sm.append(second_difference_accel_mps2(grid, gx, gy))
    cat = lambda parts: np.concatenate(parts) if parts else np.zeros(0)
    pct = lambda parts, q: float(np.percentile(cat(parts), q)) if cat(parts).size else float("nan")
    rms = lambda parts: float(np.sqrt(np.mean(cat(parts) ** 2))) if cat(parts).size else float("nan")
    return {
        "flights": float(len(flights)),
        "fixes": float(n_fix),
        "stale_fixes": float(n_stale),
        "rejected_fixes": float(n_rej),
        "residual_rms_m": rms(res),
        "residual_inlier_rms_m": rms(inl),
        "residual_median_m": pct(res, 50),
        "accel_p95_raw_fixes_mps2": pct(a_raw, 95),
        "accel_p95_interpolated_1s_mps2": pct(a_int, 95),
        "accel_p95_smoothed_1s_mps2": pct(a_sm, 95),
        "accel_p99_smoothed_1s_mps2": pct(a_sm, 99),
    }
