"""Real flights from the ADS-B table (``../shared/data/adsb/switzerland_2018-08-01.json.gz``)
as scenario targets with recorded paths (how their truth is built: the
:mod:`radar_fusion.tools.simulate` docstring, "Targets")."""

from __future__ import annotations

import functools
import gzip
import itertools
import json
from pathlib import Path

import numpy as np

from radar_fusion.geo.coordinates import WGS84_GEOD
from radar_fusion.geo.units import MPS_PER_KT

from .scenario import SampledPath, Target, mode3a_codes

PROJECT_ROOT = Path(__file__).resolve().parents[2]
ADSB_TABLE = PROJECT_ROOT.parent / "shared" / "data" / "adsb" / "switzerland_2018-08-01.json.gz"

ADSB_DEFAULT_START_T_S = 1533123000.0
"""2018-08-01 11:30 UTC: the busiest 20 minutes of the ADS-B table (74 aircraft)."""


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
    ``min_overlap_s``), with one sample beyond each end of the window. At most
    ``max_aircraft`` flights, those longest in the window first. Identity: Mode S
    address from icao24, callsign from the table, a Mode 3/A code drawn per aircraft.
    """
    tab = _adsb_table(str(path or ADSB_TABLE))
    w0, w1 = float(start_t_s), float(start_t_s) + float(duration_s)
    icao = tab["icao24"]
    t = tab["t_s"]
    starts = np.concatenate([[0], np.nonzero(icao[1:] != icao[:-1])[0] + 1, [icao.size]])
    found: list[tuple[float, str, int, int]] = []
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
            found.append((float(overlap), str(icao[a]), int(a + c0 + lo), int(a + c0 + hi)))
    found.sort(key=lambda f: (-f[0], f[1]))
    found = sorted(found[:max_aircraft], key=lambda f: f[1])
    rng = np.random.default_rng(seed)
    codes = mode3a_codes(rng, len(found))
    out = []
    for (_, icao24, a, b), code in zip(found, codes.tolist()):
        callsign = str(tab["callsign"][a]) or None
        path_ = SampledPath(
            **{
                k: tab[k][a:b].copy()
                for k in ("t_s", "lat_deg", "lon_deg", "alt_ft", "groundspeed_kt", "track_deg", "vrate_fpm")
            }
        )
        out.append(
            Target(
                target_id=icao24,
                callsign=callsign,
                mode_s=int(icao24, 16),
                mode3a=int(code),
                transponder="modes",
                mode_c=True,
                alt_quantum_ft=25.0,
                path=path_,
            )
        )
    return out
