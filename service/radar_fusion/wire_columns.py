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
from itertools import repeat
from typing import Any, Literal, get_args

import annotated_types
import msgpack
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


def _closed_interval(name: str) -> tuple[float, float]:
    """The field's gt/ge/lt/le as one closed float64 interval [lo, hi]: for floats, a > x
    is a >= nextafter(x, +inf) (no float lies between), a < x is a <= nextafter(x, -inf)."""
    lo, hi = -math.inf, math.inf
    for m in Plot.model_fields[name].metadata:
        if isinstance(m, annotated_types.Gt):
            lo = max(lo, math.nextafter(float(m.gt), math.inf))  # type: ignore[arg-type]
        elif isinstance(m, annotated_types.Ge):
            lo = max(lo, float(m.ge))  # type: ignore[arg-type]
        elif isinstance(m, annotated_types.Lt):
            hi = min(hi, math.nextafter(float(m.lt), -math.inf))  # type: ignore[arg-type]
        elif isinstance(m, annotated_types.Le):
            hi = min(hi, float(m.le))  # type: ignore[arg-type]
    return lo, hi


# the numeric fields, judged together as the rows of one (11, n) float64 array: the float
# fields' rows first, then the integer fields' (wire_bytes.py reads the bounds' rows by this order)
_FLOAT_FIELDS = (
    "t", "range_m", "azimuth_deg", "fl", "roll_deg", "ground_speed_mps", "track_angle_deg",
    "magnetic_heading_deg", "indicated_airspeed_mps",
)  # fmt: skip
_INT_FIELDS = ("mode3a", "track_no")
_NUMERIC = _FLOAT_FIELDS + _INT_FIELDS
_N_FLOAT = len(_FLOAT_FIELDS)
_REQUIRED = {name: f.is_required() for name, f in Plot.model_fields.items()}
_ALLOWED = {
    name: (_INT_TYPES if name in _INT_FIELDS else _NUMBER_TYPES) | (frozenset() if _REQUIRED[name] else {_NONE_TYPE})
    for name in _NUMERIC
}
_ALLOWED_TEXT = _STR_TYPES | {_NONE_TYPE}
_LO, _HI = (np.array(b)[:, None] for b in zip(*(_closed_interval(name) for name in _NUMERIC)))


def _check_model_is_covered() -> None:
    """Fail at import when wire.Plot has a field or a rule this module does not implement."""
    fields = Plot.model_fields
    covered = set(_NUMERIC + ("mode_s", "kind"))
    if set(fields) != covered:
        raise RuntimeError(f"wire_columns does not implement wire.Plot fields {sorted(set(fields) ^ covered)}")
    cfg = Plot.model_config
    if not (cfg.get("strict") and cfg.get("allow_inf_nan") is False and cfg.get("extra") == "ignore"):
        raise RuntimeError("wire_columns implements a strict, finite-only Plot that ignores extra fields")
    known = (annotated_types.Gt, annotated_types.Ge, annotated_types.Lt, annotated_types.Le)
    for name in _NUMERIC:
        f = fields[name]
        want = float if name in _FLOAT_FIELDS else int
        if f.annotation not in (want, want | None) or (f.annotation is want) != f.is_required():
            raise RuntimeError(f"wire.Plot.{name}: {f.annotation} is not implemented here")
        if not f.is_required() and f.default is not None:
            raise RuntimeError(f"wire.Plot.{name}: an optional field must default to None")
        for m in f.metadata:
            bound = getattr(m, type(m).__name__.lower(), None)
            if not isinstance(m, known) or not isinstance(bound, (int, float)) or float(bound) != bound:
                raise RuntimeError(f"wire.Plot.{name}: not a gt/ge/lt/le exact in float64: {m}")
            if name in _INT_FIELDS and abs(bound) >= 2**53:
                raise RuntimeError(f"wire.Plot.{name}: integer bound {bound} not exact as a float")
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
    roll_deg: np.ndarray
    ground_speed_mps: np.ndarray
    track_angle_deg: np.ndarray
    magnetic_heading_deg: np.ndarray
    indicated_airspeed_mps: np.ndarray
    rejected: dict[str, int]
    by_model: int = 0


def _plot_columns(
    a: np.ndarray, mode_s: np.ndarray, kind: np.ndarray, rejected: dict[str, int], by_model: int = 0
) -> PlotColumns:
    """The accepted plots' columns; ``a``: their numeric fields as rows in _NUMERIC's order
    (NaN absent), the integer ones becoming int64 with −1 for absent (accepted values are
    exact small integers)."""
    floats = dict(zip(_FLOAT_FIELDS, a))
    ints = dict(zip(_INT_FIELDS, np.where(np.isnan(a[_N_FLOAT:]), -1, a[_N_FLOAT:]).astype(np.int64)))
    return PlotColumns(
        t_s=floats["t"],
        range_m=floats["range_m"],
        azimuth_deg=floats["azimuth_deg"],
        fl=floats["fl"],
        mode3a=ints["mode3a"],
        mode_s=mode_s,
        track_no=ints["track_no"],
        kind=kind,
        roll_deg=floats["roll_deg"],
        ground_speed_mps=floats["ground_speed_mps"],
        track_angle_deg=floats["track_angle_deg"],
        magnetic_heading_deg=floats["magnetic_heading_deg"],
        indicated_airspeed_mps=floats["indicated_airspeed_mps"],
        rejected=rejected,
        by_model=by_model,
    )


def _absent(col: list[Any]) -> np.ndarray:
    return np.fromiter(map(operator.is_, col, repeat(None)), bool, len(col))


class _Batch:
    """One batch's fields as columns; ``to_model``: plots with a type the columns refuse
    (their values are None here), None while there is none."""

    def __init__(self, plots: list[Any]):
        self.n = len(plots)
        # a plot that is not a map reads as one without fields: its required fields go to the model
        self.maps = plots if set(map(type, plots)) <= {dict} else [p if type(p) is dict else {} for p in plots]
        self.to_model: np.ndarray | None = None

    def column(self, name: str, allowed: frozenset[type]) -> list[Any]:
        col = list(map(dict.get, self.maps, repeat(name)))
        if not set(map(type, col)) <= allowed:
            odd = [type(x) not in allowed for x in col]
            self.to_model = np.array(odd, bool) | (False if self.to_model is None else self.to_model)
            col = [None if o else x for x, o in zip(col, odd)]
        return col


def _numbers(b: _Batch) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The numeric fields as rows of one float64 array, in _NUMERIC's order (NaN: absent;
    integers compared as floats, exactly for every value that can pass, the bounds being
    far below 2**53), and per plot: a NaN or infinity was sent; a value is out of its range."""
    cols = [b.column(name, _ALLOWED[name]) for name in _NUMERIC]
    a = np.array(cols, float).reshape(len(_NUMERIC), b.n)  # None → NaN; ints → float, 2**64 − 1 too
    isnan = np.isnan(a)
    non_finite = np.asarray(np.isinf(a).any(axis=0))
    if isnan.any():
        # every NaN is an absent value, unless a float field has more NaN than None
        n_nan = np.count_nonzero(isnan[:_N_FLOAT], axis=1).tolist()
        for k, count in enumerate(n_nan):
            if count and cols[k].count(None) != count:
                non_finite |= isnan[k] & ~_absent(cols[k])
    out_of_range = np.asarray(((a < _LO) | (a > _HI)).any(axis=0))  # NaN compares False: absent is in range
    return a, non_finite, out_of_range


# Mode S address strings seen, valid ones only, and None (absent): their value (−1 absent).
# Bounded: cleared when it grows beyond _MODE_S_CACHE_MAX (a sender cycling addresses).
_MODE_S_CACHE: dict[str | None, int] = {None: -1}
_MODE_S_CACHE_MAX = 200_000


def _mode_s(b: _Batch, out_of_range: np.ndarray) -> np.ndarray:
    """The Mode S address as an int64 (−1 absent); a string that is not 6 ASCII hex digits
    is out of range (the model's ``string_pattern_mismatch``)."""
    col = b.column("mode_s", _ALLOWED_TEXT)
    cache = _MODE_S_CACHE
    values = list(map(cache.get, col))
    if None in values:  # a string not seen before (or not an address)
        if len(cache) > _MODE_S_CACHE_MAX:
            cache.clear()
            cache[None] = -1
        for i in [i for i, v in enumerate(values) if v is None]:
            s = col[i]
            if len(s) == _MODE_S_DIGITS and _HEX_RUN.fullmatch(s):
                values[i] = cache[s] = int(s, 16)
            else:
                values[i] = -1
                out_of_range[i] = True
    return np.array(values, np.int64)


def validate_plot_columns(plots: list[Any]) -> PlotColumns:
    """Validate a decoded batch's plot list (at most wire.MAX_PLOTS_PER_BATCH items)."""
    b = _Batch(plots)
    a, non_finite, out_of_range = _numbers(b)
    mode_s = _mode_s(b, out_of_range)
    # the report type's code (wire.KIND_CODES, 0 absent); −1: another string, the model's literal_error
    kind = np.fromiter(map(KIND_CODES.get, b.column("kind", _ALLOWED_TEXT), repeat(-1)), np.int8, b.n)
    schema = kind < 0
    fault = non_finite | out_of_range | schema
    rejected: dict[str, int] = {}
    if b.to_model is None and not fault.any():  # the usual batch: every plot is good
        return _plot_columns(a, mode_s, kind, rejected)
    judged = ~b.to_model if b.to_model is not None else np.ones(b.n, bool)
    non_finite &= judged
    out_of_range &= judged & ~non_finite
    schema &= judged & ~non_finite & ~out_of_range
    for reason, flags in (
        ("plot_non_finite", non_finite),
        ("plot_out_of_range", out_of_range),
        ("plot_schema", schema),
    ):
        if k := int(np.count_nonzero(flags)):
            rejected[reason] = k
    good = judged & ~fault
    by_model = np.flatnonzero(~judged).tolist()
    for row in by_model:  # the model judges what the columns could not
        try:
            p = Plot.model_validate(plots[row])
        except ValidationError as exc:
            reason = plot_rejection_reason(exc)
            rejected[reason] = rejected.get(reason, 0) + 1
            continue
        # never so far (a type the columns refuse, the strict model refuses too): its values
        a[:, row] = [math.nan if (x := getattr(p, name)) is None else x for name in _NUMERIC]
        mode_s[row] = -1 if p.mode_s is None else int(p.mode_s, 16)
        kind[row] = KIND_CODES[p.kind]
        good[row] = True
    return _plot_columns(a[:, good], mode_s[good], kind[good], rejected, len(by_model))


# --------------------------------------------------------------------------- out
class MapRows:
    """msgpack maps, one per row, built a field at a time for every row at once: the bytes
    ``msgpack.packb`` gives for the same values as Python objects (``use_bin_type=True``),
    without one Python object per value.

    Each field adds a (rows, width) uint8 block whose row holds that row's bytes left-aligned
    and, for variable-length fields, each row's byte count; :meth:`tobytes` concatenates the
    rows' bytes in order.
    """

    _INT_CLASSES = (  # (tag or None for a fixint, payload bytes) in msgpack-python's order
        (None, 1),
        (0xCC, 1),
        (0xCD, 2),
        (0xCE, 4),
        (0xCF, 8),
        (None, 1),
        (0xD0, 1),
        (0xD1, 2),
        (0xD2, 4),
        (0xD3, 8),
    )

    def __init__(self, n: int):
        self.n = n
        self._blocks: list[np.ndarray] = []
        self._lengths: list[np.ndarray | None] = []  # None: every row uses the whole width

    def raw(self, packed: bytes) -> MapRows:
        """The same bytes in every row (a map header, a key, a constant value)."""
        self._blocks.append(np.broadcast_to(np.frombuffer(packed, np.uint8), (self.n, len(packed))))
        self._lengths.append(None)
        return self

    def key(self, name: str) -> MapRows:
        return self.raw(msgpack.packb(name))

    def float64(self, a: np.ndarray, nil: np.ndarray | None = None) -> MapRows:
        """Python floats (float 64, 0xcb); rows where ``nil`` is set are None (0xc0)."""
        block = np.empty((self.n, 9), np.uint8)
        block[:, 0] = 0xCB
        block[:, 1:] = np.ascontiguousarray(a, ">f8").view(np.uint8).reshape(self.n, 8)
        if nil is None:
            return self._add(block, None)
        block[nil, 0] = 0xC0
        return self._add(block, np.where(nil, 1, 9))

    def integers(self, a: np.ndarray, nil: np.ndarray | None = None) -> MapRows:
        """Python ints (int64 values) in msgpack's smallest form; rows where ``nil`` is set are None."""
        v = np.asarray(a, np.int64)
        source = np.empty((self.n, 9), np.uint8)  # [tag, big-endian 8 bytes]
        source[:, 1:] = v.astype(">i8").view(np.uint8).reshape(self.n, 8)
        neg = v < 0
        # the class: positive fixint, uint8/16/32/64, negative fixint, int8/16/32/64
        pos_class = np.searchsorted(np.array([0x80, 0x100, 0x10000, 0x100000000], np.int64), v, side="right")
        # negative: 5 fixint (≥ −0x20) ... 9 int64 (below −2**31), by the bounds at or below v
        neg_class = 9 - np.searchsorted(np.array([-(2**31), -0x8000, -0x80, -0x20], np.int64), v, side="right")
        cls = np.where(neg, neg_class, pos_class)
        tags = np.array([0 if t is None else t for t, _ in self._INT_CLASSES], np.uint8)
        source[:, 0] = tags[cls]
        pattern = np.zeros((len(self._INT_CLASSES), 9), np.intp)
        lengths_of = np.empty(len(self._INT_CLASSES), np.int64)
        for c, (tag, k) in enumerate(self._INT_CLASSES):
            idx = ([] if tag is None else [0]) + list(range(9 - k, 9))
            pattern[c, : len(idx)] = idx
            lengths_of[c] = len(idx)
        block = np.take_along_axis(source, pattern[cls], axis=1)
        lengths = lengths_of[cls]
        if nil is not None:
            block[nil, 0] = 0xC0
            lengths = np.where(nil, 1, lengths)
        return self._add(block, lengths)

    def table(self, codes: np.ndarray, packed: list[bytes]) -> MapRows:
        """Row i's value is the already packed ``packed[codes[i]]`` (strings, lists of strings)."""
        width = max((len(p) for p in packed), default=0)
        tab = np.zeros((len(packed), max(width, 1)), np.uint8)
        for i, p in enumerate(packed):
            tab[i, : len(p)] = np.frombuffer(p, np.uint8)
        sizes = np.array([len(p) for p in packed], np.int64)
        return self._add(tab[codes], sizes[codes])

    def block(self, block: np.ndarray, lengths: np.ndarray | None) -> MapRows:
        """Rows' bytes already built: (rows, width), left-aligned, ``lengths`` per row (None: all)."""
        return self._add(block, lengths)

    def _add(self, block: np.ndarray, lengths: np.ndarray | None) -> MapRows:
        self._blocks.append(block)
        self._lengths.append(lengths)
        return self

    def tobytes(self) -> bytes:
        if not self.n or not self._blocks:
            return b""
        data = np.concatenate(self._blocks, axis=1)
        if all(length is None for length in self._lengths):
            return data.tobytes()
        # which bytes of each row are its own: all of a fixed-width block's, the first
        # ``length`` of a variable one's (written in place: a mask concatenated from one
        # piece per block cost more than the packing of the values)
        keep = np.ones(data.shape, bool)
        start = 0
        for block, length in zip(self._blocks, self._lengths):
            width = block.shape[1]
            if length is not None:
                np.less(np.arange(width), length[:, None], out=keep[:, start : start + width])
            start += width
        return data[keep].tobytes()


def array_header(n: int) -> bytes:
    """msgpack's header of an array of ``n`` items."""
    if n < 16:
        return bytes([0x90 | n])
    if n < 1 << 16:
        return b"\xdc" + n.to_bytes(2, "big")
    return b"\xdd" + n.to_bytes(4, "big")


def map_header(n: int) -> bytes:
    """msgpack's header of a map of ``n`` pairs."""
    if n < 16:
        return bytes([0x80 | n])
    if n < 1 << 16:
        return b"\xde" + n.to_bytes(2, "big")
    return b"\xdf" + n.to_bytes(4, "big")
