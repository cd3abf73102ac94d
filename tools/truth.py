"""Ground truth of a simulated scenario: one type, its CSV (``truth.csv``) reader and writer,
and its interpolation to the track batches' times.

The simulator (:mod:`radar_fusion.tools.simulate`) builds a :class:`Truth` and writes it
with :func:`write_truth`; the evaluation (:mod:`radar_fusion.tools.evaluate`), the demo,
the benchmark and the tests read it back with :func:`load_truth` (or take the simulator's
object as it is). CSV header: :data:`TRUTH_COLUMNS`, one row per target per second while
it exists (column meanings in the :mod:`~radar_fusion.tools.simulate` docstring).
"""

from __future__ import annotations

import csv
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TypeAlias

import numpy as np

TRUTH_COLUMNS = (
    "t_s",
    "target_id",
    "mode_s",
    "callsign",
    "lat_deg",
    "lon_deg",
    "alt_ft",
    "x_m",
    "y_m",
    "vx_mps",
    "vy_mps",
    "vrate_fpm",
    "detectable",
)
REQUIRED_COLUMNS = ("t_s", "target_id", "x_m", "y_m", "vx_mps", "vy_mps")
"""What scoring needs; the other columns are optional when reading (NaN / "" / detectable when absent)."""

Column: TypeAlias = Sequence[Any] | np.ndarray
"""One per-row column as :meth:`Truth.from_columns` takes it: a list (of numbers or strings) or a numpy array."""


@dataclass
class Truth:
    """Truth rows (one per target per second), sorted by target then time.

    Row arrays: ``t_s``, ``target_index``, ``target_id``, ``mode_s`` (6 hex digits or
    ""), ``callsign``, ``lat_deg``, ``lon_deg``, ``alt_ft``, ``x_m``, ``y_m``, ``vx_mps``,
    ``vy_mps``, ``vrate_fpm``, ``detectable`` (bool). Columns a source did not give are NaN.

    Per target k, in order of first appearance: its rows are ``start[k]:stop[k]``, its
    id ``target_ids[k]``, its Mode S address and callsign ``target_mode_s[k]``,
    ``target_callsign[k]`` (the first non-empty value of its rows).

    ``target_index`` labels each row's target: the target's row of ``Scenario.targets``
    when the simulator built the truth (so it indexes the scenario, and plots'
    ``target_index``), else k. The two agree when every scenario target has rows.
    """

    t_s: np.ndarray
    target_index: np.ndarray
    target_id: np.ndarray
    mode_s: np.ndarray
    callsign: np.ndarray
    lat_deg: np.ndarray
    lon_deg: np.ndarray
    alt_ft: np.ndarray
    x_m: np.ndarray
    y_m: np.ndarray
    vx_mps: np.ndarray
    vy_mps: np.ndarray
    vrate_fpm: np.ndarray
    detectable: np.ndarray
    start: np.ndarray
    stop: np.ndarray
    target_ids: list[str]
    target_mode_s: list[str]
    target_callsign: list[str]

    @classmethod
    def from_columns(
        cls,
        t_s: Column,
        target_id: Column,
        x_m: Column,
        y_m: Column,
        vx_mps: Column,
        vy_mps: Column,
        detectable: Column | None = None,
        mode_s: Column | None = None,
        callsign: Column | None = None,
        *,
        lat_deg: Column | None = None,
        lon_deg: Column | None = None,
        alt_ft: Column | None = None,
        vrate_fpm: Column | None = None,
        target_index: Column | None = None,
    ) -> Truth:
        """Build from per-row columns in any order (rows are sorted by target, time)."""
        ids = np.asarray([str(v) for v in target_id], dtype=object)
        n = ids.shape[0]
        t = np.asarray(t_s, float)
        if isinstance(detectable, np.ndarray) and detectable.dtype == bool:
            det = detectable
        else:
            det = np.ones(n, bool) if detectable is None else np.asarray([_truthy(v) for v in detectable], bool)
        ms = np.asarray(["" if v is None else str(v) for v in (mode_s if mode_s is not None else [""] * n)], object)
        cs = np.asarray(["" if v is None else str(v) for v in (callsign if callsign is not None else [""] * n)], object)
        # Targets in order of first appearance; rows sorted by (target, time).
        uniq, first_idx, inverse = np.unique(ids.astype(str), return_index=True, return_inverse=True)
        order_of_target = np.argsort(np.argsort(first_idx, kind="stable"), kind="stable")
        tgt = order_of_target[inverse.reshape(-1)] if n else np.zeros(0, np.intp)
        order = np.lexsort((t, tgt))
        tgt = tgt[order]
        n_targets = uniq.shape[0]
        start = np.searchsorted(tgt, np.arange(n_targets), side="left")
        stop = np.searchsorted(tgt, np.arange(n_targets), side="right")
        ids_sorted = ids[order]
        ms_sorted, cs_sorted = ms[order], cs[order]
        label = tgt if target_index is None else np.asarray(target_index, np.intp)[order]
        return cls(
            t_s=t[order],
            target_index=label,
            target_id=ids_sorted,
            mode_s=ms_sorted,
            callsign=cs_sorted,
            lat_deg=_floats(lat_deg, n)[order],
            lon_deg=_floats(lon_deg, n)[order],
            alt_ft=_floats(alt_ft, n)[order],
            x_m=np.asarray(x_m, float)[order],
            y_m=np.asarray(y_m, float)[order],
            vx_mps=np.asarray(vx_mps, float)[order],
            vy_mps=np.asarray(vy_mps, float)[order],
            vrate_fpm=_floats(vrate_fpm, n)[order],
            detectable=det[order],
            start=start,
            stop=stop,
            target_ids=[str(ids_sorted[s]) for s in start],
            target_mode_s=[next((str(v) for v in ms_sorted[s:e] if v), "") for s, e in zip(start, stop)],
            target_callsign=[next((str(v) for v in cs_sorted[s:e] if v), "") for s, e in zip(start, stop)],
        )

    def __len__(self) -> int:
        """The number of rows (as in the CSV); :attr:`n_targets` counts targets."""
        return int(self.t_s.shape[0])

    @property
    def n_targets(self) -> int:
        return len(self.target_ids)


def _truthy(v: Any) -> bool:
    if isinstance(v, str):
        return v.strip().lower() in ("1", "true", "yes", "1.0")
    return bool(v)


def _floats(values: Column | None, n: int) -> np.ndarray:
    """An optional float column: NaN when absent, and for empty or None cells."""
    if values is None:
        return np.full(n, np.nan)
    try:
        return np.asarray(values, float)
    except ValueError:
        return np.array([np.nan if v is None or v == "" else float(v) for v in values], float)


def load_truth(path: str | Path) -> Truth:
    """Read a truth CSV (header :data:`TRUTH_COLUMNS`; only :data:`REQUIRED_COLUMNS` must be there)."""
    with open(path, newline="") as f:
        reader = csv.DictReader(f)
        fields = set(reader.fieldnames or [])
        missing = set(REQUIRED_COLUMNS) - fields
        if missing:
            raise ValueError(f"{path}: truth CSV lacks columns {sorted(missing)}")
        cols: dict[str, list[str]] = {k: [] for k in TRUTH_COLUMNS}
        for row in reader:
            for k in cols:
                cols[k].append(row.get(k) or "")
    optional = {k: (cols[k] if k in fields else None) for k in ("lat_deg", "lon_deg", "alt_ft", "vrate_fpm")}
    return Truth.from_columns(
        t_s=np.asarray(cols["t_s"], float),
        target_id=cols["target_id"],
        x_m=np.asarray(cols["x_m"], float),
        y_m=np.asarray(cols["y_m"], float),
        vx_mps=np.asarray(cols["vx_mps"], float),
        vy_mps=np.asarray(cols["vy_mps"], float),
        detectable=[v if v != "" else "1" for v in cols["detectable"]],
        mode_s=cols["mode_s"],
        callsign=cols["callsign"],
        lat_deg=optional["lat_deg"],
        lon_deg=optional["lon_deg"],
        alt_ft=optional["alt_ft"],
        vrate_fpm=optional["vrate_fpm"],
    )


def _fmt(v: float, digits: int) -> str:
    return f"{v:.{digits}f}"


def write_truth(truth: Truth, path: str | Path) -> None:
    """Write the truth CSV (header :data:`TRUTH_COLUMNS`), rows in the truth's order."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(TRUTH_COLUMNS)
        w.writerows(
            zip(
                [_fmt(v, 3) for v in truth.t_s.tolist()],
                truth.target_id.tolist(),
                truth.mode_s.tolist(),
                truth.callsign.tolist(),
                [_fmt(v, 7) for v in truth.lat_deg.tolist()],
                [_fmt(v, 7) for v in truth.lon_deg.tolist()],
                [_fmt(v, 1) for v in truth.alt_ft.tolist()],
                [_fmt(v, 2) for v in truth.x_m.tolist()],
                [_fmt(v, 2) for v in truth.y_m.tolist()],
                [_fmt(v, 3) for v in truth.vx_mps.tolist()],
                [_fmt(v, 3) for v in truth.vy_mps.tolist()],
                [_fmt(v, 1) for v in truth.vrate_fpm.tolist()],
                truth.detectable.astype(np.int8).tolist(),
            )
        )


def as_truth(truth: Truth | str | Path | Mapping[str, Column] | Sequence[Mapping[str, Any]]) -> Truth:
    """Accept a :class:`Truth`, a CSV path, a mapping of column arrays, or a list of row dicts."""
    if isinstance(truth, Truth):
        return truth
    if isinstance(truth, (str, Path)):
        return load_truth(truth)
    if isinstance(truth, Mapping):
        cols = truth
    else:
        rows = list(truth)
        cols = {k: [r.get(k) for r in rows] for k in TRUTH_COLUMNS}
    return Truth.from_columns(
        t_s=cols["t_s"],
        target_id=cols["target_id"],
        x_m=cols["x_m"],
        y_m=cols["y_m"],
        vx_mps=cols["vx_mps"],
        vy_mps=cols["vy_mps"],
        detectable=cols.get("detectable"),
        mode_s=cols.get("mode_s"),
        callsign=cols.get("callsign"),
        lat_deg=cols.get("lat_deg"),
        lon_deg=cols.get("lon_deg"),
        alt_ft=cols.get("alt_ft"),
        vrate_fpm=cols.get("vrate_fpm"),
    )


# --------------------------------------------------------------------------- truth at batch times


@dataclass
class TruthAtTimes:
    """Truth interpolated to batch times: arrays of shape (n_targets, n_times)."""

    exists: np.ndarray
    detectable: np.ndarray
    x_m: np.ndarray
    y_m: np.ndarray
    vx_mps: np.ndarray
    vy_mps: np.ndarray


def interpolate_truth(truth: Truth, times_s: Column, max_gap_s: float = 10.0) -> TruthAtTimes:
    """Interpolate each target linearly in time to ``times_s`` (see :mod:`radar_fusion.tools.evaluate`)."""
    times = np.asarray(times_s, float)
    k, m = truth.n_targets, times.shape[0]
    out = {name: np.full((k, m), np.nan) for name in ("x_m", "y_m", "vx_mps", "vy_mps")}
    exists = np.zeros((k, m), bool)
    detectable = np.zeros((k, m), bool)
    for i, (s, e) in enumerate(zip(truth.start, truth.stop)):
        t = truth.t_s[s:e]
        if t.shape[0] == 0:
            continue
        hi = np.searchsorted(t, times, side="left")  # first row with t_row >= time
        inside = (times >= t[0]) & (times <= t[-1])
        hi_c = np.clip(hi, 0, t.shape[0] - 1)
        on_row = inside & (t[hi_c] == times)
        lo_c = np.where(on_row, hi_c, np.clip(hi - 1, 0, t.shape[0] - 1))
        ok = inside & (on_row | (t[hi_c] - t[lo_c] <= max_gap_s))
        exists[i] = ok
        det = truth.detectable[s:e]
        detectable[i] = ok & det[lo_c] & det[hi_c]
        for name in out:
            col = getattr(truth, name)[s:e]
            out[name][i] = np.where(ok, np.interp(times, t, col), np.nan)
    return TruthAtTimes(exists=exists, detectable=detectable, **out)
