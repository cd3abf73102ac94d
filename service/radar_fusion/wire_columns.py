"""The plots of a PlotBatch validated as columns: wire.Plot's rules, for a whole batch at once.

:class:`wire.Plot` is the contract (and the source of its JSON Schema); validating one
plot at a time through it costs about 3.5 µs a plot, most of the daemon's ingest. Here a
decoded batch's plots become one Python list per field, each checked for its types in
one pass (``set(map(type, ...))``) and converted to a numpy array, and the ranges and
finiteness are judged on the arrays. The rejection reasons are those of
:func:`wire.plot_rejection_reason` on the model's errors, with its precedence: a plot with
a NaN or an infinity anywhere is ``plot_non_finite``, else one with a value outside its
range or pattern is ``plot_out_of_range``, else any other fault is ``plot_schema``.

What the columns cannot judge cheaply goes to the model, one plot at a time: a plot that
is not a map, or a field of a type the model refuses in strict mode (a missing required
field, a string for a number, a bool, a float for an integer, bytes, a nested list or
map). That is rare in real traffic and always a rejection; the model decides its reason.
``tests/test_wire_columns.py`` proves, property-based, that this and the model
(:func:`wire.validate_plots_by_model`) accept the same plots, with the same values, and
reject the rest with the same reasons.

The bounds are read from the model's field constraints at import, so a changed bound is
followed here; a field, a constraint kind or a pattern this module does not implement
stops the import (``_check_model_is_covered``) rather than let the two drift apart.
"""

from __future__ import annotations

import math
import operator
import re
from dataclasses import dataclass
from itertools import compress, repeat
from typing import Any, Literal, get_args

import annotated_types
import numpy as np
from pydantic import ValidationError

from .wire import KIND_CODES, MODE_S_PATTERN, PLOT_KINDS, Plot, plot_rejection_reason

_NONE_TYPE = type(None)
_NUMBER_TYPES = frozenset({float, int})  # strict float: int accepted, bool not (its type is bool)
_INT_TYPES = frozenset({int})
_STR_TYPES = frozenset({str})
_HEX_RUN = re.compile(r"[0-9A-Fa-f]*")  # ASCII hex digits only (the model's [0-9A-Fa-f])
_MODE_S_DIGITS = 6
_IMPLEMENTED_MODE_S_PATTERN = r"^[0-9A-Fa-f]{6}$"


@dataclass(frozen=True)
class _Bounds:
    """A numeric field's constraints as the model declares them (None: no such bound)."""

    gt: float | None = None
    ge: float | None = None
    lt: float | None = None
    le: float | None = None

    def within(self, a: np.ndarray) -> np.ndarray:
        ok = np.ones(a.shape, bool)
        if self.gt is not None:
            ok &= a > self.gt
        if self.ge is not None:
            ok &= a >= self.ge
        if self.lt is not None:
            ok &= a < self.lt
        if self.le is not None:
            ok &= a <= self.le
        return ok


def _bounds(name: str) -> _Bounds:
    kw: dict[str, float] = {}
    for m in Plot.model_fields[name].metadata:
        for kind in ("gt", "ge", "lt", "le"):
            if isinstance(m, getattr(annotated_types, kind.capitalize())):
                kw[kind] = float(getattr(m, kind))
    return _Bounds(**kw)


# field → (its kind here, required); the model's own annotation is checked against it below
_FLOAT_FIELDS = ("t", "range_m", "azimuth_deg", "fl")
_INT_FIELDS = ("mode3a", "track_no")
_REQUIRED = {name: f.is_required() for name, f in Plot.model_fields.items()}
_BOUNDS = {name: _bounds(name) for name in _FLOAT_FIELDS + _INT_FIELDS}


def _check_model_is_covered() -> None:
    """Fail at import when wire.Plot has a field or a rule this module does not implement."""
    fields = Plot.model_fields
    covered = set(_FLOAT_FIELDS + _INT_FIELDS + ("mode_s", "kind"))
    if set(fields) != covered:
        raise RuntimeError(f"wire_columns does not implement wire.Plot fields {sorted(set(fields) ^ covered)}")
    cfg = Plot.model_config
    if not (cfg.get("strict") and cfg.get("allow_inf_nan") is False and cfg.get("extra") == "ignore"):
        raise RuntimeError("wire_columns implements a strict, finite-only Plot that ignores extra fields")
    known = (annotated_types.Gt, annotated_types.Ge, annotated_types.Lt, annotated_types.Le)
    for name in _FLOAT_FIELDS + _INT_FIELDS:
        f = fields[name]
        want = float if name in _FLOAT_FIELDS else int
        if f.annotation not in (want, want | None) or (f.annotation is want) != f.is_required():
            raise RuntimeError(f"wire.Plot.{name}: {f.annotation} is not implemented here")
        if not f.is_required() and f.default is not None:
            raise RuntimeError(f"wire.Plot.{name}: an optional field must default to None")
        if any(not isinstance(m, known) for m in f.metadata):
            raise RuntimeError(f"wire.Plot.{name}: a constraint other than gt/ge/lt/le: {f.metadata}")
    if MODE_S_PATTERN != _IMPLEMENTED_MODE_S_PATTERN or fields["mode_s"].annotation != str | None:
        raise RuntimeError("wire.Plot.mode_s: a pattern or type other than the one implemented here")
    kind_args = tuple(a for a in get_args(fields["kind"].annotation) if a is not _NONE_TYPE)
    if len(kind_args) != 1 or get_args(kind_args[0]) != PLOT_KINDS or kind_args[0] != Literal[PLOT_KINDS]:
        raise RuntimeError("wire.Plot.kind: not the Literal of PLOT_KINDS")
    if any(_REQUIRED[name] for name in ("mode_s", "kind")) or set(KIND_CODES) != {None, *PLOT_KINDS}:
        raise RuntimeError("wire.Plot.mode_s / kind: expected optional, with a code for every kind")


_check_model_is_covered()


@dataclass
class PlotColumns:
    """The accepted plots of a batch, in their order, as wire.DecodedPlots carries them;
    ``rejected``: the refused ones by reason. ``by_model``: plots the model judged."""

    t_s: np.ndarray
    range_m: np.ndarray
    azimuth_deg: np.ndarray
    fl: np.ndarray
    mode3a: np.ndarray
    mode_s: np.ndarray
    track_no: np.ndarray
    kind: np.ndarray
    rejected: dict[str, int]
    by_model: int = 0


class _Verdicts:
    """Per plot of the batch: what the columns found, for the reason's precedence."""

    def __init__(self, n: int):
        self.non_finite = np.zeros(n, bool)
        self.out_of_range = np.zeros(n, bool)
        self.schema = np.zeros(n, bool)
        self.to_model = np.zeros(n, bool)  # a type the columns leave to the model


def _column(maps: list[dict[Any, Any]], name: str, allowed: frozenset[type], v: _Verdicts) -> list[Any]:
    """The field's values (None when absent); a value of a type not in ``allowed`` sends its
    plot to the model and is replaced by None here."""
    col = list(map(dict.get, maps, repeat(name)))
    if not set(map(type, col)) <= allowed:
        odd = [type(x) not in allowed for x in col]
        v.to_model |= np.array(odd, bool)
        col = [None if o else x for x, o in zip(col, odd)]
    return col


def _absent(col: list[Any]) -> np.ndarray:
    return np.fromiter(map(operator.is_, col, repeat(None)), bool, len(col))


def _numbers(maps: list[dict[Any, Any]], name: str, integer: bool, v: _Verdicts) -> np.ndarray:
    """A float or integer field as float64, NaN where absent. Integers are compared as
    floats: exactly for every value that can pass (the bounds are far below 2**53), and a
    larger one still compares beyond them."""
    allowed = (_INT_TYPES if integer else _NUMBER_TYPES) | (frozenset() if _REQUIRED[name] else {_NONE_TYPE})
    col = _column(maps, name, allowed, v)
    a = np.array(col, float)  # None → NaN; ints → float (2**64 − 1 too)
    isnan = np.isnan(a)
    # an int is never NaN; else every NaN is an absent value unless more NaN than None
    nan_sent = not integer and isnan.any() and col.count(None) != int(np.count_nonzero(isnan))
    absent = _absent(col) if nan_sent else isnan
    non_finite = ~np.isfinite(a) & ~absent
    v.non_finite |= non_finite
    v.out_of_range |= ~(absent | non_finite | _BOUNDS[name].within(a))
    return a


def _mode_s(maps: list[dict[Any, Any]], v: _Verdicts) -> np.ndarray:
    """The Mode S address as an int64 (−1 absent); a string that is not 6 hex digits is out
    of range (the model's ``string_pattern_mismatch``)."""
    col = _column(maps, "mode_s", _STR_TYPES | {_NONE_TYPE}, v)
    n = len(col)
    out = np.full(n, -1, np.int64)
    n_absent = col.count(None)
    if n_absent == n:
        return out
    rows = np.arange(n) if n_absent == 0 else np.flatnonzero(~_absent(col))
    strs: list[str] = col if n_absent == 0 else [col[i] for i in rows.tolist()]
    joined = "".join(strs)
    if set(map(len, strs)) == {_MODE_S_DIGITS} and _HEX_RUN.fullmatch(joined):
        ok = np.ones(len(strs), bool)
    else:  # some string is not 6 ASCII hex digits: judge each
        ok = np.array([len(s) == _MODE_S_DIGITS and _HEX_RUN.fullmatch(s) is not None for s in strs], bool)
        joined = "".join(compress(strs, ok.tolist()))
    v.out_of_range[rows[~ok]] = True
    b = np.frombuffer(bytes.fromhex(joined), np.uint8).reshape(-1, 3).astype(np.int64)
    out[rows[ok]] = (b[:, 0] << 16) | (b[:, 1] << 8) | b[:, 2]
    return out


def _kind(maps: list[dict[Any, Any]], v: _Verdicts) -> np.ndarray:
    """The report type's code (wire.KIND_CODES, 0 absent); another string is a schema fault
    (the model's ``literal_error``)."""
    col = _column(maps, "kind", _STR_TYPES | {_NONE_TYPE}, v)
    codes = np.fromiter(map(KIND_CODES.get, col, repeat(-1)), np.int8, len(col))
    v.schema |= codes < 0
    return np.maximum(codes, 0)


def validate_plot_columns(plots: list[Any]) -> PlotColumns:
    """Validate a decoded batch's plot list (at most wire.MAX_PLOTS_PER_BATCH items)."""
    n = len(plots)
    # a plot that is not a map reads as a map without fields: its required fields go to the model
    maps = plots if set(map(type, plots)) <= {dict} else [p if type(p) is dict else {} for p in plots]
    v = _Verdicts(n)
    t_s = _numbers(maps, "t", False, v)
    range_m = _numbers(maps, "range_m", False, v)
    azimuth_deg = _numbers(maps, "azimuth_deg", False, v)
    fl = _numbers(maps, "fl", False, v)
    mode3a = _numbers(maps, "mode3a", True, v)
    track_no = _numbers(maps, "track_no", True, v)
    mode_s = _mode_s(maps, v)
    kind = _kind(maps, v)

    judged = ~v.to_model
    non_finite = v.non_finite & judged
    out_of_range = v.out_of_range & judged & ~non_finite
    schema = v.schema & judged & ~non_finite & ~out_of_range
    good = judged & ~(non_finite | out_of_range | schema)
    rejected = {
        reason: k
        for reason, flags in (
            ("plot_non_finite", non_finite),
            ("plot_out_of_range", out_of_range),
            ("plot_schema", schema),
        )
        if (k := int(np.count_nonzero(flags)))
    }
    by_model = np.flatnonzero(v.to_model).tolist()
    for row in by_model:  # the model judges what the columns could not
        try:
            p = Plot.model_validate(plots[row])
        except ValidationError as exc:
            reason = plot_rejection_reason(exc)
            rejected[reason] = rejected.get(reason, 0) + 1
            continue
        # never so far (a type the columns refuse, the strict model refuses too): its values
        t_s[row], range_m[row], azimuth_deg[row] = p.t, p.range_m, p.azimuth_deg
        fl[row] = math.nan if p.fl is None else p.fl
        mode3a[row] = math.nan if p.mode3a is None else p.mode3a
        track_no[row] = math.nan if p.track_no is None else p.track_no
        mode_s[row] = -1 if p.mode_s is None else int(p.mode_s, 16)
        kind[row] = KIND_CODES[p.kind]
        good[row] = True
    cols = [t_s, range_m, azimuth_deg, fl, mode3a, mode_s, track_no, kind]
    if not good.all():
        cols = [c[good] for c in cols]
    for i in (4, 6):  # mode3a, track_no: every accepted value is an exact small integer
        cols[i] = np.where(np.isnan(cols[i]), -1, cols[i]).astype(np.int64)
    t_s, range_m, azimuth_deg, fl, mode3a, mode_s, track_no, kind = cols
    return PlotColumns(t_s, range_m, azimuth_deg, fl, mode3a, mode_s, track_no, kind, rejected, len(by_model))
