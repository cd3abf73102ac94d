"""`radar-fusion identity`: Mode S identity continuity of the fused tracks (DESIGN.md §4).

Every Mode S aircraft has one 24-bit address, so real recorded plots without truth
still say how many tracks an aircraft should get: one per *track segment*, the
address's plots split at gaps over ``gap_s`` (60 s), because across a gap that long
the tracker may end the track and nobody can blame it. The figures (issue 15's goal
for the Barcelona hour: <= 1.03 ids per segment, never two tracks with one address at
the same time, no rejection):

* **ids per segment**: for each segment, the set of track ids that showed the address,
  in a *counted* status, in a TrackBatch whose time lies in the segment's span
  (``[first plot, last plot + one period]``: a plot's period closes up to one period
  after it). Mean over the segments that got at least one id; the worst segments and
  addresses; segments that got none.
* **duplicates**: TrackBatches in which two or more counted tracks showed one address,
  which addresses, and the *track-time share*: track reports that shared their address
  with another counted track in the same batch over all counted track reports with a
  Mode S address (each batch is one period, so reports are track-time).
* **rejections**: ``Engine.health()["rejected"]`` (the codec's rejections are counted
  there too).

Counted statuses are ``confirmed`` and ``coasting``: what a controller's display shows
(ASTERIX CAT062 sends both; a coasting track is still on the screen). Tentative tracks
are the tracker's internal candidates: counting them would add an id for every
confirmed track's first two or three scans that never became anything. Duplicates
including tentative tracks are reported apart (``duplicate_batches_any_status``): a
tentative track on an address that a live track already carries is the start of a
split, which the identity association of issue 15 should prevent.

The runner feeds an ASTERIX recording through the real engine in process (no bus):
ASTERIX -> wire messages (``radar_fusion.asterix.AsterixToWire``, as ``asterix-in``)
-> encoded payloads decoded as the daemon does (``tools.replay.replay_into_engine``)
-> ``Engine``. The defaults are the Barcelona hour (``../shared/data/asterix/``,
data README): its radar is not in any deploy config and the file has no CAT034, so the
settings are built here (:func:`barcelona_settings`; see there what is assumed).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from collections import Counter, defaultdict
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from datetime import date
from pathlib import Path
from typing import Any

import numpy as np

DEFAULT_GAP_S = 60.0
COUNTED_STATUSES = ("confirmed", "coasting")

# The Barcelona radar (data README: course documents shipped with the file).
BARCELONA_FILE = "../shared/data/asterix/barcelona_cat048_1h.ast"
BARCELONA_DAY = date(2023, 5, 2)
BARCELONA_SAC, BARCELONA_SIC = 20, 129
BARCELONA_LAT = 41 + 18 / 60 + 2.5284 / 3600  # 41°18'02.5284" N
BARCELONA_LON = 2 + 6 / 60 + 7.4095 / 3600  # 02°06'07.4095" E
BARCELONA_ALT_M = 2.007 + 25.25  # terrain + antenna


# ============================================================================ the metric


def _address(value: Any) -> int:
    """A Mode S address as an int (-1: none) from an int, a 6-hex string or None."""
    if value is None:
        return -1
    if isinstance(value, str):
        return int(value, 16)
    return int(value)


def _hex(address: int) -> str:
    return f"{address:06X}"


@dataclass
class Segment:
    """One Mode S track segment: an address's plots between two gaps over ``gap_s``."""

    address: int
    start_s: float
    end_s: float
    n_plots: int
    track_ids: set[int] = field(default_factory=set)

    def as_dict(self) -> dict[str, Any]:
        return {
            "mode_s": _hex(self.address),
            "start_t": self.start_s,
            "end_t": self.end_s,
            "duration_s": self.end_s - self.start_s,
            "plots": self.n_plots,
            "ids": len(self.track_ids),
            "track_ids": sorted(self.track_ids),
        }


def plot_columns(plots: Iterable[Any]) -> tuple[np.ndarray, np.ndarray]:
    """``(t_s, address)`` of every plot with a Mode S address.

    ``plots`` are batches with array columns ``t_s`` and ``mode_s`` (``DecodedPlots``:
    ints, -1 for none), or single plots with scalar ``t_s``/``t`` and ``mode_s`` (int or
    6-hex string), as objects or dicts.
    """
    ts: list[np.ndarray] = []
    addrs: list[np.ndarray] = []
    singles_t: list[float] = []
    singles_a: list[int] = []
    for p in plots:
        get = p.get if isinstance(p, dict) else lambda k, p=p: getattr(p, k, None)
        t = get("t_s")
        if t is None:
            t = get("t")
        m = get("mode_s")
        if isinstance(t, np.ndarray):
            m = np.asarray(m)
            if m.dtype.kind in "OUS":
                m = np.array([_address(x) for x in m], np.int64)
            ts.append(t.astype(float))
            addrs.append(m.astype(np.int64))
        else:
            singles_t.append(float(t))  # type: ignore[arg-type]  # a plot without a time fails here
            singles_a.append(_address(m))
    ts.append(np.array(singles_t, float))
    addrs.append(np.array(singles_a, np.int64))
    t_all, a_all = np.concatenate(ts), np.concatenate(addrs)
    keep = a_all >= 0
    return t_all[keep], a_all[keep]


def segments_of(t_s: np.ndarray, address: np.ndarray, gap_s: float = DEFAULT_GAP_S) -> list[Segment]:
    """Each address's plots split where consecutive plots are more than ``gap_s`` apart."""
    order = np.lexsort((t_s, address))
    t, a = t_s[order], address[order]
    if t.size == 0:
        return []
    new = np.ones(t.size, bool)
    new[1:] = (a[1:] != a[:-1]) | (np.diff(t) > gap_s)
    starts = np.flatnonzero(new)
    ends = np.append(starts[1:], t.size) - 1
    return [Segment(int(a[s]), float(t[s]), float(t[e]), int(e - s + 1)) for s, e in zip(starts, ends)]


def identity_figures(
    plots: Iterable[Any],
    batches: Sequence[dict[str, Any]],
    rejected: dict[str, int] | None = None,
    gap_s: float = DEFAULT_GAP_S,
    period_s: float | None = None,
    statuses: Sequence[str] = COUNTED_STATUSES,
    worst: int = 5,
) -> dict[str, Any]:
    """The identity figures of one run (module docstring) as a JSON-able dict.

    ``batches`` are TrackBatch messages (``"t"``, ``"tracks"`` with ``track_id``,
    ``mode_s``, ``status``) in time order; ``period_s`` (default: the median spacing
    of the batches) widens each segment's span at its end by one period.
    """
    t_s, address = plot_columns(plots)
    segments = segments_of(t_s, address, gap_s)
    counted = set(statuses)
    batch_t = np.array([float(b["t"]) for b in batches])
    if period_s is None:
        period_s = float(np.median(np.diff(batch_t))) if batch_t.size > 1 else 0.0

    # (batch time, track id) per address, counted statuses only
    shown: dict[int, list[tuple[float, int]]] = defaultdict(list)
    dup_batches = 0
    dup_batches_any = 0
    dup_reports = 0
    reports_with_address = 0
    reports_counted = 0
    dup_by_address: Counter[int] = Counter()
    dup_any_by_address: Counter[int] = Counter()
    for b in batches:
        t = float(b["t"])
        per_addr: dict[int, list[int]] = defaultdict(list)
        per_addr_any: dict[int, int] = Counter()
        for tr in b["tracks"]:
            a = _address(tr.get("mode_s"))
            if a >= 0:
                per_addr_any[a] += 1
            if tr["status"] not in counted:
                continue
            reports_counted += 1
            if a < 0:
                continue
            reports_with_address += 1
            per_addr[a].append(int(tr["track_id"]))
            shown[a].append((t, int(tr["track_id"])))
        dups = {a: tids for a, tids in per_addr.items() if len(tids) > 1}
        if dups:
            dup_batches += 1
            for a, tids in dups.items():
                dup_reports += len(tids)
                dup_by_address[a] += 1
        dups_any = [a for a, n in per_addr_any.items() if n > 1]
        if dups_any:
            dup_batches_any += 1
            dup_any_by_address.update(dups_any)

    for seg in segments:
        for t, tid in shown.get(seg.address, ()):
            if seg.start_s <= t <= seg.end_s + period_s:
                seg.track_ids.add(tid)

    with_ids = [s for s in segments if s.track_ids]
    ids = np.array([len(s.track_ids) for s in with_ids], float)
    by_addr: dict[int, list[Segment]] = defaultdict(list)
    for s in segments:
        by_addr[s.address].append(s)
    addr_rows: list[dict[str, Any]] = []
    for a, segs in by_addr.items():
        all_ids = set().union(*(s.track_ids for s in segs))
        extra = sum(max(len(s.track_ids) - 1, 0) for s in segs)
        addr_rows.append(
            {
                "mode_s": _hex(a),
                "segments": len(segs),
                "ids": len(all_ids),
                "extra_ids": extra,
                "plots": sum(s.n_plots for s in segs),
                "duplicate_batches": dup_by_address.get(a, 0),
            }
        )
    addr_rows.sort(key=lambda r: (-r["extra_ids"], -r["duplicate_batches"], r["mode_s"]))
    worst_segments = sorted(with_ids, key=lambda s: (-len(s.track_ids), s.start_s))[:worst]
    return {
        "gap_s": gap_s,
        "statuses": list(statuses),
        "plots_with_mode_s": int(t_s.size),
        "addresses": len(by_addr),
        "segments": len(segments),
        "segments_without_track": len(segments) - len(with_ids),
        "segments_without_track_plots_max": max((s.n_plots for s in segments if not s.track_ids), default=0),
        "ids_per_segment_mean": float(ids.mean()) if ids.size else math.nan,
        "ids_per_segment_max": int(ids.max()) if ids.size else 0,
        "segments_with_extra_ids": int((ids > 1).sum()),
        "extra_ids": int((ids - 1).sum()) if ids.size else 0,
        "worst_segments": [s.as_dict() for s in worst_segments],
        "worst_addresses": addr_rows[:worst],
        "batches": len(batches),
        "period_s": period_s,
        "duplicate_batches": dup_batches,
        "duplicate_batches_any_status": dup_batches_any,
        "duplicate_track_time_share": dup_reports / reports_with_address if reports_with_address else 0.0,
        "duplicate_addresses": {_hex(a): n for a, n in dup_by_address.most_common()},
        "duplicate_addresses_any_status": len(dup_any_by_address),
        "track_reports_counted": reports_counted,
        "track_reports_with_mode_s": reports_with_address,
        "rejected": dict(rejected or {}),
        "rejected_total": int(sum((rejected or {}).values())),
    }


# ============================================================================ the runner


def barcelona_settings(
    sac: int = BARCELONA_SAC,
    sic: int = BARCELONA_SIC,
    lat: float = BARCELONA_LAT,
    lon: float = BARCELONA_LON,
    alt_m: float = BARCELONA_ALT_M,
    rotation_period_s: float = 4.0,
    sigma_range_m: float = 30.0,
    sigma_azimuth_deg: float = 0.05,
    period_s: float = 4.0,
) -> Any:
    """Settings for one radar with the system centre at it (defaults: Barcelona).

    Assumptions, not from the file or a site survey: the rotation period 4.0 s is read
    from the plot spacing (data README); sigma_range 30 m and sigma_azimuth 0.05° are
    typical Mode S monopulse figures, not this radar's; the height 2.007 m terrain +
    25.25 m antenna is taken as above the ellipsoid (the documents likely mean above
    sea level; the geoid is ~50 m above the ellipsoid there, a negligible change of
    ground range at the ranges of this traffic).
    """
    from radar_fusion.config import settings_from_dict

    return settings_from_dict(
        {
            "system": {"center_lat": lat, "center_lon": lon, "period_s": period_s},
            # the site's magnetic declination (BDS 6,0 reports magnetic headings): +1° fits the
            # hour best of 0, 1 and 2° (tracking.imm.IMMParams.magnetic_declination_deg)
            "tracking": {"imm": {"magnetic_declination_deg": 1.0}},
            "radars": [
                {
                    "id": f"sac{sac}_sic{sic}",
                    "lat": lat,
                    "lon": lon,
                    "alt_m": alt_m,
                    "sigma_range_m": sigma_range_m,
                    "sigma_azimuth_deg": sigma_azimuth_deg,
                    "rotation_period_s": rotation_period_s,
                    "sac": sac,
                    "sic": sic,
                }
            ],
        },
        source="identity",
    )


def asterix_messages(
    path: str | Path, settings: Any, day: date | None = BARCELONA_DAY, minutes: float | None = None
) -> tuple[list[tuple[float, str, bytes]], dict[str, Any]]:
    """``(t_s, key, payload)`` wire messages of a recording, in event-time order.

    Converted in file order by ``AsterixToWire`` (as ``asterix-in``), then sorted by
    event time (stable). ``asterix-in --order time`` sorts the datagrams before
    converting (``sort_by_time``), which decodes the whole file once more (8 s for the
    Barcelona hour); for a file of one record per block without CAT034 (the Barcelona
    hour) both give the same order. With ``minutes``, only the messages within that
    many minutes of the earliest are kept, and conversion stops one minute past that
    (a recording out of order by more than a minute would lose plots: the Barcelona
    file is out of order by at most 0.22 s, within a scan).
    """
    from radar_fusion.asterix import AsterixToWire, DecodeCounters, iter_file

    file_counters = DecodeCounters()
    bridge = AsterixToWire(settings.radars, day=day)
    kept: list[tuple[float, str, bytes, int]] = []
    t0 = math.inf
    for ref_s, datagram in iter_file(path, file_counters):
        msgs = bridge.datagram(datagram, ref_s)
        for m in msgs:
            t0 = min(t0, m.t_s)
            kept.append((m.t_s, m.key, m.payload, len(getattr(m.message, "plots", ()))))
        if minutes is not None and msgs and msgs[-1].t_s > t0 + minutes * 60.0 + 60.0:
            break
    kept.sort(key=lambda m: m[0])
    if minutes is not None:
        kept = [m for m in kept if m[0] <= t0 + minutes * 60.0]
    out = [(t, key, payload) for t, key, payload, _ in kept]
    counters: dict[str, Any] = bridge.counters.as_dict()  # of everything converted, also past the limit
    counters["plots_kept"] = sum(m[3] for m in kept)
    for reason, n in file_counters.skipped.items():
        counters["skipped"][reason] = counters["skipped"].get(reason, 0) + n
    return out, counters


def run_identity(
    path: str | Path = BARCELONA_FILE,
    settings: Any = None,
    day: date | None = BARCELONA_DAY,
    minutes: float | None = None,
    gap_s: float = DEFAULT_GAP_S,
    worst: int = 5,
) -> dict[str, Any]:
    """Feed a recording through the real engine in process; returns the figures plus
    run facts (wall times, bridge counters, the time span of the plots)."""
    from radar_fusion.engine import Engine
    from radar_fusion.wire import DecodedPlots

    from .replay import replay_into_engine

    settings = settings or barcelona_settings()
    wall0 = time.perf_counter()
    messages, bridge_counters = asterix_messages(path, settings, day, minutes)
    wall_bridge = time.perf_counter() - wall0

    engine = Engine(settings)
    ingested: list[DecodedPlots] = []
    ingest = engine.ingest_plots

    def keep_and_ingest(batch: DecodedPlots) -> int:
        ingested.append(batch)
        return ingest(batch)

    engine.ingest_plots = keep_and_ingest  # type: ignore[method-assign]  # see what the engine was given
    wall1 = time.perf_counter()
    outputs = replay_into_engine(engine, messages)
    wall_engine = time.perf_counter() - wall1
    batches = [o.track_batch for o in outputs]
    health = engine.health()
    figures = identity_figures(ingested, batches, health["rejected"], gap_s, settings.system.period_s, worst=worst)
    t_first = messages[0][0] if messages else math.nan
    t_last = messages[-1][0] if messages else math.nan
    figures.update(
        {
            "file": str(path),
            "minutes": minutes,
            "span_s": t_last - t_first,
            "plots_ingested": int(sum(len(b) for b in ingested)),
            "bridge": bridge_counters,
            "wall_s_bridge": wall_bridge,
            "wall_s_engine": wall_engine,
            "wall_s": time.perf_counter() - wall0,
        }
    )
    return figures


# ============================================================================ the command


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--asterix", default=BARCELONA_FILE, metavar="FILE", help=f"recording (default {BARCELONA_FILE})")
    p.add_argument("--minutes", type=float, metavar="N", help="only the first N minutes (default: the whole file)")
    p.add_argument("--date", default=BARCELONA_DAY.isoformat(), help="UTC date of the recording (default 2023-05-02)")
    p.add_argument("--sac", type=int, default=BARCELONA_SAC, help="radar SAC (default 20)")
    p.add_argument("--sic", type=int, default=BARCELONA_SIC, help="radar SIC (default 129)")
    p.add_argument("--lat", type=float, default=BARCELONA_LAT, help="radar latitude, deg (default Barcelona)")
    p.add_argument("--lon", type=float, default=BARCELONA_LON, help="radar longitude, deg (default Barcelona)")
    p.add_argument("--alt-m", type=float, default=BARCELONA_ALT_M, help="antenna height, m (default 27.257)")
    p.add_argument("--rotation-s", type=float, default=4.0, help="antenna rotation period, s (default 4.0)")
    p.add_argument("--sigma-range-m", type=float, default=30.0, help="range noise, m (default 30, assumed)")
    p.add_argument("--sigma-azimuth-deg", type=float, default=0.05, help="azimuth noise, deg (default 0.05, assumed)")
    p.add_argument("--period-s", type=float, default=4.0, help="fusion period, s (default 4.0)")
    p.add_argument("--gap-s", type=float, default=DEFAULT_GAP_S, help="segment split gap, s (default 60)")
    p.add_argument("--worst", type=int, default=5, help="worst segments/addresses listed (default 5)")
    p.add_argument("--json", action="store_true", help="print the figures as JSON")


def format_table(f: dict[str, Any]) -> str:
    """The figures as a short text table."""
    rej = ", ".join(f"{k} {v}" for k, v in sorted(f["rejected"].items())) or "none"
    lines = [
        f"identity: {f['file']}" + (f", first {f['minutes']:g} min" if f.get("minutes") else ""),
        f"  plots ingested            {f['plots_ingested']} ({f['plots_with_mode_s']} with Mode S) "
        f"over {f['span_s']:.0f} s",
        f"  addresses / segments      {f['addresses']} / {f['segments']} (split at gaps > {f['gap_s']:g} s)",
        f"  ids per segment           mean {f['ids_per_segment_mean']:.3f}, max {f['ids_per_segment_max']}, "
        f"{f['segments_with_extra_ids']} segments with extra ids ({f['extra_ids']} extra)",
        f"  segments with no track    {f['segments_without_track']} "
        f"(largest {f['segments_without_track_plots_max']} plots)",
        f"  duplicate address         {f['duplicate_batches']} of {f['batches']} batches, "
        f"{100 * f['duplicate_track_time_share']:.3f} % of track-time, {len(f['duplicate_addresses'])} addresses "
        f"({f['duplicate_batches_any_status']} batches incl. tentative)",
        f"  rejected                  {f['rejected_total']} ({rej})",
        f"  wall time                 {f['wall_s']:.1f} s (bridge {f['wall_s_bridge']:.1f} s, "
        f"engine {f['wall_s_engine']:.1f} s)",
        "  worst addresses           mode_s  segments ids extra dup_batches",
    ]
    for r in f["worst_addresses"]:
        lines.append(
            f"                            {r['mode_s']}  {r['segments']:8d} {r['ids']:3d} {r['extra_ids']:5d} "
            f"{r['duplicate_batches']:11d}"
        )
    return "\n".join(lines)


def run(args: argparse.Namespace) -> int:
    path = Path(args.asterix)
    if not path.is_file():
        print(f"{path}: file not found", file=sys.stderr)
        return 2
    settings = barcelona_settings(
        args.sac,
        args.sic,
        args.lat,
        args.lon,
        args.alt_m,
        args.rotation_s,
        args.sigma_range_m,
        args.sigma_azimuth_deg,
        args.period_s,
    )
    figures = run_identity(path, settings, date.fromisoformat(args.date), args.minutes, args.gap_s, args.worst)
    print(json.dumps(figures, indent=1, sort_keys=True) if args.json else format_table(figures))
    return 0
