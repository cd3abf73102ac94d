"""`radar-fusion clean`: remove wild plots from a recording with Hu 2013's batch method.

``radar-fusion clean IN.rec --out OUT.rec [--report OUT.removed.csv] [--method soft|kmodf]``

Series. Every plot of every ``radar/<id>/plots`` message that passes the wire contract's
validation goes into a series keyed by its radar (the batch's ``radar_id``) and the
radar's identity of the target: its track number (``track_no``) when it has one, else its
Mode S address. A series is split where consecutive plots are more than ``max_gap_s``
apart (a track number reused for another aircraft). Each series of at least
``min_series_length`` plots is analysed twice with :func:`radar_fusion.tracking.outliers.analyse`
(every step of Hu 2013, eq. 1-7, and its decision rule): once on range, once on azimuth.
A plot is removed when either analysis marks it wild.

Why the series are detrended first (``detrend = "xy"``, the default). Hu 2013 works on a
10 Hz instrumentation-radar series, where the trajectory moves little between samples
compared with the noise. A surveillance radar samples a track every 4-12 s: range moves
by ~1 km per scan against ~50 m noise, azimuth races near closest approach, and missed
scans double a step. On the raw series the window spread of eq. 1 is the motion, not
the noise, and the edge points are the ends of the ramp: on simulated traffic with known
wild plots the method then finds 1-3 % of them (``--detrend none`` reproduces this). So
each series is replaced by its residual about the trajectory: a robust local-quadratic
trend of the plots in the radar plane (x = range sin az, y = range cos az; LOWESS with
bisquare robustness weights, :func:`radar_fusion.tools.detrend.robust_trend_xy`), whose
range and azimuth are subtracted from the plots'
(:func:`~radar_fusion.tools.detrend.polar_residuals`). Straight flight is a straight line
in the plane, so close passes leave no trend in the residual.

Decision. The paper leaves the rule open ("larger OF, more likely wild"). Per-track
series are short (12-150 plots, so 2-30 sub-sequences), and eq. 6 normalises OF per
series, so the most outlying sub-sequence of any series has OF near 2 and the robust
rule of :mod:`radar_fusion.tracking.outliers` (median + 6 MAD over the sub-sequences) almost never
fires. Here a plot is removed when Hu's method flags it with OF > ``threshold`` (default
1.0, :data:`CLEAN_OUTLIER_PARAMS`; "robust" restores the module's rule) AND its residual is
more than ``min_deviation_sigma`` (16) robust standard deviations of its series' residuals
from their median: OF picks the pattern, the residual confirms a gross error.

Measured on simulated traffic (``tests/test_clean.py``; demo scenario, 600 s, wild plots
at 5-6x its rates, seeds 1-6): precision 0.82-0.93, recall 0.82-0.91, about 0.3 % of the
good plots removed (in turns seen by the 8 s and 12 s radars); K-MODF: about the same
precision, recall 0.51-0.68. Without detrending, recall 0.01-0.03 with the module's
robust rule. The residual test alone (no OF) reaches a higher recall (0.90-0.97) at a
somewhat lower precision: on these series the OF stage mainly trims false removals.

Passed through unchanged (and counted): plots with neither a track number nor a Mode S
address (false plots, primary-only plots), plots of series too short to analyse, plots
that fail validation, undecodable plot batches, and every other message. Non-plot messages
and plot batches that lose no plot are written byte-identical. A batch that loses plots is
re-encoded (msgpack) with the same map and its remaining plot maps, in order; a batch
that loses all its plots is KEPT as an empty batch, so the radar's ``seq`` stays gap-free
(the daemon counts sequence gaps) and sector timing is unchanged.

Outputs: the cleaned recording (same format; the header's ``meta`` gains a ``clean``
entry with the parameters), a report of every removed plot (CSV, or JSON when the name
ends in ``.json``: radar, key, t_s, range_m, azimuth_deg, the series that flagged it, its
outlier factor (eq. 7) and threshold, its residual in robust sigmas), and a printed summary.

Python API: :func:`collect_plots`, :func:`find_wild`, :func:`clean_messages`, :func:`clean_file`.
"""

from __future__ import annotations

import argparse
import csv
import json
import sys
from collections.abc import Iterable, Iterator
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import msgpack
import numpy as np
from pydantic import TypeAdapter, ValidationError

from radar_fusion import wire
from radar_fusion.tracking.outliers import METHODS, OutlierParams, analyse

from ..recording import Record, RecordingWriter, read_header, read_recording
from .detrend import polar_residuals, robust_z

__all__ = [
    "CleanParams",
    "CleanSummary",
    "PlotTable",
    "Removal",
    "add_arguments",
    "clean_file",
    "clean_messages",
    "collect_plots",
    "find_wild",
    "run",
    "write_report",
]

KEY_TRACK_NO, KEY_MODE_S = 0, 1
REPORT_COLUMNS = (
    "radar",
    "key",
    "t_s",
    "range_m",
    "azimuth_deg",
    "series",
    "outlier_factor",
    "of_threshold",
    "deviation_sigma",
    "message_index",
    "plot_index",
)
_MAX_PAYLOAD_BYTES = 64 << 20
_PLOT_LIST = TypeAdapter(list[wire.Plot])


CLEAN_OUTLIER_PARAMS = OutlierParams(window=12, edge_quantile=0.8, of_threshold=1.0)
"""The batch method's parameters for radar-track series (see the module docstring)."""
DETRENDS = ("xy", "none")


@dataclass(frozen=True)
class CleanParams:
    """Parameters of a clean run.

    method: "soft" (Hu 2013, eq. 1) or "kmodf" (hard edge weights).
    outlier: the batch method's parameters (window v, k, threshold rule, ...).
    min_series_length: series with fewer plots are not analysed (passed through).
    max_gap_s: a series is split where consecutive plots are further apart than this.
    detrend: "xy" analyses the range / azimuth residuals about a robust radar-plane trend
    (:func:`~radar_fusion.tools.detrend.polar_residuals`); "none" the measured range /
    azimuth series, as the paper.
    trend_plots: plots in each local fit of the trend.
    min_deviation_sigma: with "xy", a flagged plot is removed only when its residual is
    more than this many robust standard deviations (1.4826 MAD of the series' residuals)
    from the median; 0 turns the check off.
    """

    method: str = "soft"
    outlier: OutlierParams = CLEAN_OUTLIER_PARAMS
    min_series_length: int = 12
    max_gap_s: float = 60.0
    detrend: str = "xy"
    trend_plots: int = 15
    min_deviation_sigma: float = 16.0

    def __post_init__(self) -> None:
        if self.method not in METHODS:
            raise ValueError(f"method must be one of {METHODS}, got {self.method!r}")
        if self.detrend not in DETRENDS:
            raise ValueError(f"detrend must be one of {DETRENDS}, got {self.detrend!r}")
        if self.trend_plots < 5:
            raise ValueError("trend_plots must be >= 5")
        if self.outlier.window < 2 or self.outlier.k < 1 or not 0.0 <= self.outlier.edge_quantile <= 1.0:
            raise ValueError("need window >= 2, k >= 1 and 0 <= edge_quantile <= 1")
        if self.min_series_length < self.outlier.window:
            raise ValueError(f"min_series_length {self.min_series_length} must be >= window {self.outlier.window}")
        if not self.max_gap_s > 0:
            raise ValueError("max_gap_s must be > 0")


@dataclass
class PlotTable:
    """The identified plots of a recording, one row per plot.

    message: index of the record in the recording (header excluded); plot: index of the
    plot in its batch's ``plots`` list; radar: index into ``radars``; key_kind:
    KEY_TRACK_NO or KEY_MODE_S; key_value: the track number or the 24-bit address.
    """

    radars: list[str]
    message: np.ndarray
    plot: np.ndarray
    radar: np.ndarray
    key_kind: np.ndarray
    key_value: np.ndarray
    t_s: np.ndarray
    range_m: np.ndarray
    azimuth_deg: np.ndarray

    def __len__(self) -> int:
        return int(self.t_s.shape[0])

    def key_text(self, row: int) -> str:
        """``track_no:17`` or ``mode_s:4B1805``."""
        if self.key_kind[row] == KEY_TRACK_NO:
            return f"track_no:{int(self.key_value[row])}"
        return f"mode_s:{int(self.key_value[row]):06X}"


@dataclass
class Removal:
    """Per row of a :class:`PlotTable`: the decision and why.

    wild: remove; by_range / by_azimuth: which series flagged it; outlier_factor: OF of
    the flagging sub-sequence (the larger when both), of_threshold: the threshold of that
    series' decision, deviation_sigma: its residual in robust standard deviations (NaN
    without detrending); analysed: the row belonged to a series long enough to analyse.
    """

    wild: np.ndarray
    by_range: np.ndarray
    by_azimuth: np.ndarray
    outlier_factor: np.ndarray
    of_threshold: np.ndarray
    deviation_sigma: np.ndarray
    analysed: np.ndarray
    series_total: int = 0
    series_analysed: int = 0


@dataclass
class CleanSummary:
    """Counters of a clean run (what the printed summary shows)."""

    messages: int = 0
    plot_batches: int = 0
    batches_undecodable: int = 0
    plots: int = 0
    plots_invalid: int = 0
    plots_without_key: int = 0
    plots_identified: int = 0
    plots_analysed: int = 0
    series_total: int = 0
    series_analysed: int = 0
    removed: int = 0
    removed_by_range: int = 0
    removed_by_azimuth: int = 0
    removed_by_both: int = 0
    batches_rewritten: int = 0
    batches_emptied: int = 0
    removed_per_radar: dict[str, int] = field(default_factory=dict)
    plots_per_radar: dict[str, int] = field(default_factory=dict)


# --------------------------------------------------------------------------- decoding


def _plot_batch(payload: bytes) -> dict | None:
    """The unpacked PlotBatch map, or None when the daemon would refuse the whole batch."""
    obj = wire.unpack(payload, _MAX_PAYLOAD_BYTES)
    if isinstance(obj, wire.Rejection) or not isinstance(obj, dict) or obj.get("v") != wire.WIRE_VERSION:
        return None
    try:
        wire.PlotBatch.model_validate({"v": 1, "radar_id": obj.get("radar_id"), "seq": obj.get("seq"), "plots": []})
    except ValidationError:
        return None
    return obj if isinstance(obj.get("plots"), list) else None


def _valid_plots(raw: list) -> list[wire.Plot | None]:
    """Validate each plot map as the daemon does; None for a plot it would refuse."""
    try:
        return list(_PLOT_LIST.validate_python(raw))
    except ValidationError:
        out: list[wire.Plot | None] = []
        for p in raw:
            try:
                out.append(wire.Plot.model_validate(p))
            except ValidationError:
                out.append(None)
        return out


def collect_plots(
    records: Iterable[tuple[float, str, bytes] | Record], summary: CleanSummary | None = None
) -> PlotTable:
    """Read every plot batch of ``records`` ((t_s, key, payload) or Record) into a PlotTable.

    Counts messages, batches, invalid and keyless plots in ``summary`` when given.
    """
    s = summary if summary is not None else CleanSummary()
    radars: dict[str, int] = {}
    cols: dict[str, list] = {
        k: [] for k in ("message", "plot", "radar", "key_kind", "key_value", "t_s", "range_m", "azimuth_deg")
    }
    for i, rec in enumerate(records):
        key, payload = (rec.key, rec.payload) if isinstance(rec, Record) else (rec[1], rec[2])
        s.messages += 1
        if not key.endswith("/plots"):
            continue
        s.plot_batches += 1
        obj = _plot_batch(payload)
        if obj is None:
            s.batches_undecodable += 1
            continue
        radar_id = obj["radar_id"]
        r = radars.setdefault(radar_id, len(radars))
        plots = _valid_plots(obj["plots"])
        s.plots += len(plots)
        s.plots_per_radar[radar_id] = s.plots_per_radar.get(radar_id, 0) + len(plots)
        for j, p in enumerate(plots):
            if p is None:
                s.plots_invalid += 1
                continue
            if p.track_no is not None:
                kind, value = KEY_TRACK_NO, p.track_no
            elif p.mode_s is not None:
                kind, value = KEY_MODE_S, int(p.mode_s, 16)
            else:
                s.plots_without_key += 1
                continue
            for name, v in (
                ("message", i),
                ("plot", j),
                ("radar", r),
                ("key_kind", kind),
                ("key_value", value),
                ("t_s", p.t),
                ("range_m", p.range_m),
                ("azimuth_deg", p.azimuth_deg),
            ):
                cols[name].append(v)
    s.plots_identified += len(cols["t_s"])
    ints = ("message", "plot", "radar", "key_value")
    return PlotTable(
        radars=list(radars),
        **{
            k: np.asarray(v, dtype=np.int64 if k in ints else (np.int8 if k == "key_kind" else float))
            for k, v in cols.items()
        },
    )


# --------------------------------------------------------------------------- analysis


def _series_slices(table: PlotTable, max_gap_s: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Row order (by radar, key, time) and the [start, stop) of each series in it."""
    order = np.lexsort((table.t_s, table.key_value, table.key_kind, table.radar))
    if order.size == 0:
        return order, np.zeros(0, np.int64), np.zeros(0, np.int64)
    rad, kk, kv, t = (a[order] for a in (table.radar, table.key_kind, table.key_value, table.t_s))
    new = np.ones(order.size, bool)
    new[1:] = (rad[1:] != rad[:-1]) | (kk[1:] != kk[:-1]) | (kv[1:] != kv[:-1]) | (np.diff(t) > max_gap_s)
    starts = np.flatnonzero(new)
    stops = np.concatenate((starts[1:], [order.size]))
    return order, starts, stops


def _wild_with_factor(s: np.ndarray, method: str, params: OutlierParams) -> tuple[np.ndarray, np.ndarray, float]:
    """Wild mask of a time-ordered series, the OF of each wild sample's sub-sequence, the threshold."""
    a = analyse(s, None, method, params)
    of = np.zeros(s.size)
    for p in np.flatnonzero(a.wild_subsequence):
        of[a.starts[p] : a.edge_stops[p]] = a.outlier_factor[p]
    return a.wild, of, a.threshold


def find_wild(table: PlotTable, params: CleanParams | None = None) -> Removal:
    """Apply the batch method to the range and azimuth series of every radar track."""
    p = params or CleanParams()
    n = len(table)
    hit = {name: np.zeros(n, bool) for name in ("range", "azimuth")}
    of = {name: np.zeros(n) for name in hit}
    thr = {name: np.full(n, np.nan) for name in hit}
    dev = {name: np.zeros(n) for name in hit}
    analysed = np.zeros(n, bool)
    order, starts, stops = _series_slices(table, p.max_gap_s)
    n_analysed = 0
    for a, b in zip(starts.tolist(), stops.tolist()):
        if b - a < p.min_series_length:
            continue
        rows = order[a:b]
        n_analysed += 1
        analysed[rows] = True
        if p.detrend == "xy":
            series = dict(
                zip(
                    ("range", "azimuth"),
                    polar_residuals(table.t_s[rows], table.range_m[rows], table.azimuth_deg[rows], p.trend_plots),
                )
            )
        else:
            series = {
                "range": table.range_m[rows],
                "azimuth": np.rad2deg(np.unwrap(np.deg2rad(table.azimuth_deg[rows]))),
            }
        for name, s in series.items():
            w, f, th = _wild_with_factor(s, p.method, p.outlier)
            z = robust_z(s) if p.detrend == "xy" else np.full(s.size, np.nan)
            if p.detrend == "xy" and p.min_deviation_sigma > 0:
                w &= z > p.min_deviation_sigma
            hit[name][rows], of[name][rows], thr[name][rows], dev[name][rows] = w, f, th, z
    wild = hit["range"] | hit["azimuth"]
    # Report the OF (and threshold, deviation) of the series that flagged the plot, the larger OF when both did.
    use_r = hit["range"] & (~hit["azimuth"] | (of["range"] >= of["azimuth"]))
    pick = lambda d, none: np.where(use_r, d["range"], np.where(hit["azimuth"], d["azimuth"], none))
    return Removal(
        wild=wild,
        by_range=hit["range"],
        by_azimuth=hit["azimuth"],
        outlier_factor=pick(of, 0.0),
        of_threshold=pick(thr, np.nan),
        deviation_sigma=pick(dev, np.nan),
        analysed=analysed,
        series_total=int(starts.size),
        series_analysed=n_analysed,
    )


# --------------------------------------------------------------------------- rewriting


def removed_plots(table: PlotTable, removal: Removal) -> dict[int, set[int]]:
    """Message index -> indices of the plots to drop from that batch."""
    out: dict[int, set[int]] = {}
    for m, j in zip(table.message[removal.wild].tolist(), table.plot[removal.wild].tolist()):
        out.setdefault(m, set()).add(j)
    return out


def clean_messages(
    records: Iterable[tuple[float, str, bytes] | Record],
    drop: dict[int, set[int]],
    summary: CleanSummary | None = None,
) -> Iterator[tuple[float, str, bytes]]:
    """Yield (t_s, key, payload) of ``records`` with the plots in ``drop`` removed.

    Messages without removals are yielded with their payload unchanged (the same bytes).
    """
    for i, rec in enumerate(records):
        t_s, key, payload = (rec.t_s, rec.key, rec.payload) if isinstance(rec, Record) else rec
        gone = drop.get(i)
        if gone:
            obj = _plot_batch(payload)
            if obj is not None:  # decodable in the first pass, so here too
                obj["plots"] = [p for j, p in enumerate(obj["plots"]) if j not in gone]
                payload = msgpack.packb(obj, use_bin_type=True)
                if summary is not None:
                    summary.batches_rewritten += 1
                    summary.batches_emptied += not obj["plots"]
        yield t_s, key, payload


def _fill_removal_counts(summary: CleanSummary, table: PlotTable, removal: Removal) -> None:
    summary.series_total = removal.series_total
    summary.series_analysed = removal.series_analysed
    summary.plots_analysed = int(removal.analysed.sum())
    summary.removed = int(removal.wild.sum())
    summary.removed_by_both = int((removal.by_range & removal.by_azimuth).sum())
    summary.removed_by_range = int(removal.by_range.sum()) - summary.removed_by_both
    summary.removed_by_azimuth = int(removal.by_azimuth.sum()) - summary.removed_by_both
    counts = np.bincount(table.radar[removal.wild], minlength=len(table.radars))
    summary.removed_per_radar = {name: int(counts[r]) for r, name in enumerate(table.radars)}


def _finite(x: float, digits: int) -> float | None:
    return round(float(x), digits) if np.isfinite(x) else None


def report_rows(table: PlotTable, removal: Removal) -> list[dict[str, Any]]:
    """One dict per removed plot (REPORT_COLUMNS), in recording order."""
    rows = np.flatnonzero(removal.wild)
    rows = rows[np.lexsort((table.plot[rows], table.message[rows]))]
    out = []
    for r in rows.tolist():
        series = "+".join(
            name for name, hit in (("range", removal.by_range[r]), ("azimuth", removal.by_azimuth[r])) if hit
        )
        out.append(
            {  # non-finite numbers (no threshold, zero MAD) become None: valid JSON
                "radar": table.radars[int(table.radar[r])],
                "key": table.key_text(r),
                "t_s": float(table.t_s[r]),
                "range_m": float(table.range_m[r]),
                "azimuth_deg": float(table.azimuth_deg[r]),
                "series": series,
                "outlier_factor": _finite(removal.outlier_factor[r], 6),
                "of_threshold": _finite(removal.of_threshold[r], 6),
                "deviation_sigma": _finite(removal.deviation_sigma[r], 3),
                "message_index": int(table.message[r]),
                "plot_index": int(table.plot[r]),
            }
        )
    return out


def write_report(path: str | Path, rows: list[dict[str, Any]]) -> None:
    """CSV (REPORT_COLUMNS), or a JSON list of objects when the name ends in .json."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    if path.suffix.lower() == ".json":
        path.write_text(json.dumps(rows, indent=1) + "\n", encoding="utf-8")
        return
    with open(path, "w", newline="", encoding="utf-8") as f:
        w = csv.DictWriter(f, fieldnames=REPORT_COLUMNS)
        w.writeheader()
        w.writerows(rows)


def clean_file(
    in_path: str | Path, out_path: str | Path, report_path: str | Path | None, params: CleanParams | None = None
) -> CleanSummary:
    """Clean a recording file into ``out_path`` (two passes over the input); write the report."""
    p = params or CleanParams()
    if Path(in_path).resolve() == Path(out_path).resolve():
        raise ValueError("the output must not overwrite the input recording")
    summary = CleanSummary()
    meta = dict(read_header(in_path).get("meta") or {})
    table = collect_plots(read_recording(in_path), summary)
    removal = find_wild(table, p)
    _fill_removal_counts(summary, table, removal)
    meta["clean"] = {"source": str(in_path), **asdict(p), "removed": summary.removed, "empty_batches": "kept"}
    with RecordingWriter(out_path, meta) as w:
        for t_s, key, payload in clean_messages(read_recording(in_path), removed_plots(table, removal), summary):
            w.write(t_s, key, payload)
    if report_path is not None:
        write_report(report_path, report_rows(table, removal))
    return summary


def format_summary(s: CleanSummary, params: CleanParams) -> str:
    """The printed summary."""
    pct = lambda a, b: f"{100.0 * a / b:.2f} %" if b else "-"
    lines = [
        f"clean (method {params.method}, detrend {params.detrend}): {s.messages} messages, "
        f"{s.plot_batches} plot batches ({s.batches_undecodable} undecodable, passed through)",
        f"  plots: {s.plots}; without track number or Mode S address: {s.plots_without_key} (passed through); "
        f"invalid: {s.plots_invalid} (passed through)",
        f"  series (radar, key): {s.series_total}, analysed: {s.series_analysed}; "
        f"plots analysed: {s.plots_analysed} of {s.plots_identified} identified",
        f"  removed: {s.removed} plots ({pct(s.removed, s.plots_analysed)} of analysed) - range only "
        f"{s.removed_by_range}, azimuth only {s.removed_by_azimuth}, both {s.removed_by_both}",
        f"  batches re-encoded: {s.batches_rewritten} (left empty and kept: {s.batches_emptied})",
    ]
    for radar in sorted(s.plots_per_radar):
        lines.append(
            f"    {radar:>12}: removed {s.removed_per_radar.get(radar, 0)} of {s.plots_per_radar[radar]} plots"
        )
    return "\n".join(lines)


# --------------------------------------------------------------------------- command line


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Arguments of ``radar-fusion clean``."""
    d, o = CleanParams(), CLEAN_OUTLIER_PARAMS
    parser.add_argument("file", help="recording to clean (from `simulate`, `record` or `asterix-in --out`)")
    parser.add_argument("--out", required=True, help="cleaned recording to write (.gz: compressed)")
    parser.add_argument("--report", default=None, help="removed plots, CSV or .json (default: OUT + '.removed.csv')")
    parser.add_argument(
        "--method",
        choices=METHODS,
        default=d.method,
        help="soft: Hu 2013 soft edge weights (default); kmodf: the K-MODF baseline",
    )
    parser.add_argument("--window", type=int, default=o.window, help=f"v of eq. 1, plots (default {o.window})")
    parser.add_argument("--k", type=int, default=o.k, help=f"k of the k-mean distance (default {o.k})")
    parser.add_argument(
        "--threshold",
        default=str(o.of_threshold),
        help=f"outlier-factor threshold, OF in [0, 2] (default {o.of_threshold:g}), or 'robust' for "
        "OF > median + of_sigma * 1.4826 * MAD per series",
    )
    parser.add_argument(
        "--of-sigma", type=float, default=o.of_sigma, help=f"c of the robust rule (default {o.of_sigma:g})"
    )
    parser.add_argument(
        "--edge-quantile",
        type=float,
        default=o.edge_quantile,
        help=f"quantile of W above which plots are edge points (default {o.edge_quantile:g})",
    )
    parser.add_argument(
        "--max-wild-length",
        type=int,
        default=o.max_wild_length,
        help=f"longest run of plots removable as one wild sub-sequence (default {o.max_wild_length})",
    )
    parser.add_argument(
        "--min-series-length",
        type=int,
        default=d.min_series_length,
        help=f"radar tracks with fewer plots are passed through (default {d.min_series_length}, at least --window)",
    )
    parser.add_argument(
        "--max-gap-s",
        type=float,
        default=d.max_gap_s,
        help=f"split a radar track's series at longer gaps (default {d.max_gap_s:g} s)",
    )
    parser.add_argument(
        "--detrend",
        choices=DETRENDS,
        default=d.detrend,
        help="xy (default): analyse residuals about a robust radar-plane trend; "
        "none: the raw range / azimuth series, as in the paper",
    )
    parser.add_argument(
        "--trend-plots", type=int, default=d.trend_plots, help=f"plots per local trend fit (default {d.trend_plots})"
    )
    parser.add_argument(
        "--min-deviation-sigma",
        type=float,
        default=d.min_deviation_sigma,
        help=f"with --detrend xy, remove a flagged plot only if its residual exceeds this many "
        f"robust sigmas (default {d.min_deviation_sigma:g}; 0: off)",
    )


def params_from_args(args: argparse.Namespace) -> CleanParams:
    """CleanParams from the parsed arguments (ValueError on bad values)."""
    threshold = None if str(args.threshold).lower() == "robust" else float(args.threshold)
    if threshold is not None and not 0.0 <= threshold <= 2.0:  # NaN too: it removed nothing, silently
        raise ValueError(f"--threshold {args.threshold}: an outlier factor in [0, 2], or 'robust'")
    outlier = OutlierParams(
        window=args.window,
        k=args.k,
        of_sigma=args.of_sigma,
        of_threshold=threshold,
        edge_quantile=args.edge_quantile,
        max_wild_length=args.max_wild_length,
    )
    return CleanParams(
        args.method,
        outlier,
        args.min_series_length,
        args.max_gap_s,
        args.detrend,
        args.trend_plots,
        args.min_deviation_sigma,
    )


def run(args: argparse.Namespace) -> int:
    """Clean args.file into args.out, write the report, print the summary."""
    try:
        params = params_from_args(args)
        report = args.report if args.report is not None else str(args.out) + ".removed.csv"
        summary = clean_file(args.file, args.out, report, params)
    except (OSError, ValueError, TypeError) as exc:
        print(f"clean: {exc}", file=sys.stderr)
        return 2
    print(format_summary(summary, params))
    print(f"  wrote {args.out} and {report}")
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="radar-fusion clean", description=__doc__.split("\n")[0])
    add_arguments(parser)
    return run(parser.parse_args(argv))


if __name__ == "__main__":
    raise SystemExit(main())
