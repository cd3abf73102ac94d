"""A PlotBatch read straight from its bytes: the daemon's fast path for well-formed batches.

msgpack's decoding of a PlotBatch makes one dict per plot (about 1 µs a plot), and the
columns are then validated from those dicts (wire_columns.py, about 1.5 µs a plot): at
4,000 aircraft × 10 radars, ~9,000 plots in ~210 batches a period, this took half as
long as the engine's whole period (issue 16: the daemon as fast as its engine). Here a
compiled parser (:func:`_parse`) walks the msgpack bytes once and writes the columns
directly, checking every plot with wire.Plot's rules on the way (the bounds are
wire_columns' closed intervals, read from the model).

It only ever accepts: a batch it would have to refuse, or in any part cannot judge
exactly as msgpack and the model would, it hands back (None), and the general path
(wire.decode_plot_batch: msgpack, then the columns or the model) decides, with its
reasons. Handed back are:

* anything a plot or the message would be refused for: a value out of range, NaN or
  infinite, of a type the model refuses (a bool, a float for an integer, a string for a
  number), a required field missing, a Mode S address that is not 6 hex digits, an
  unknown kind, a version other than 1, a radar id that does not match its pattern;
* anything whose meaning after msgpack is not plain: a key twice in one map (msgpack
  keeps the last), a non-ASCII string outside the values read here (msgpack checks its
  UTF-8), a map inside an ignored field (its keys must be strings), an ext type, more
  items than msgpack's limits allow (wire._UNPACK_LIMITS), bytes after the message;
* a payload that is not complete msgpack.

So the two paths give the same DecodedPlots for every payload, which
tests/test_wire_columns.py checks property-based, on payloads encoded the many ways
msgpack allows (float32, wide integers, map16, str8, ...) besides msgpack-python's own.
"""

from __future__ import annotations

import math
import re

import numpy as np

from .tracking.compiled import compiled as _compiled
from .wire import (
    KIND_CODES,
    MAX_PLOTS_PER_BATCH,
    PLOT_KINDS,
    RADAR_ID_PATTERN,
    WIRE_VERSION,
    DecodedPlots,
    Plot,
)
from .wire_columns import _HI, _LO, _NUMERIC

__all__ = ["decode_plot_batch_bytes", "warm_up"]

# wire._UNPACK_LIMITS: what msgpack refuses beyond (items, bytes)
_MAX_STR = 1 << 16
_MAX_BIN = 1 << 20
_MAX_ARRAY = MAX_PLOTS_PER_BATCH + 1
_MAX_MAP = 64

# the plot's fields: the numeric ones in wire_columns' order (its bounds' rows), then the text
_PLOT_FIELDS = (*_NUMERIC, "mode_s", "kind")
(
    _F_T, _F_RANGE, _F_AZ, _F_FL, _F_ROLL, _F_GS, _F_TRK, _F_HDG, _F_IAS,
    _F_MODE3A, _F_TRACK_NO, _F_MODE_S, _F_KIND,
) = range(13)  # fmt: skip
assert _PLOT_FIELDS == (
    "t", "range_m", "azimuth_deg", "fl", "roll_deg", "ground_speed_mps", "track_angle_deg",
    "magnetic_heading_deg", "indicated_airspeed_mps", "mode3a", "track_no", "mode_s", "kind",
)  # fmt: skip
assert set(_PLOT_FIELDS) == set(Plot.model_fields)
# _parse's floats: a row per float field (_F_T .. _F_IAS); the numeric fields from _F_MODE3A are integers
_FLOAT_ROWS = _F_IAS + 1
_TOP_FIELDS = ("v", "radar_id", "seq", "plots")
_REQUIRED_MASK = sum(1 << i for i, name in enumerate(_PLOT_FIELDS) if Plot.model_fields[name].is_required())


def _names(names: tuple[str, ...]) -> tuple[np.ndarray, np.ndarray]:
    """Names as one uint8 array and their start offsets (len + 1)."""
    raw = [n.encode("ascii") for n in names]
    return np.frombuffer(b"".join(raw), np.uint8).copy(), np.cumsum([0] + [len(r) for r in raw]).astype(np.int64)


_PLOT_KEYS, _PLOT_KEY_AT = _names(_PLOT_FIELDS)
_TOP_KEYS, _TOP_KEY_AT = _names(_TOP_FIELDS)
_KIND_NAMES, _KIND_AT = _names(PLOT_KINDS)
_KIND_CODE = np.array([KIND_CODES[k] for k in PLOT_KINDS], np.int8)
_NO_KIND = np.int8(KIND_CODES[None])
_BOUNDS_LO = np.ascontiguousarray(_LO[:, 0], dtype=np.float64)
_BOUNDS_HI = np.ascontiguousarray(_HI[:, 0], dtype=np.float64)

# what _number found
_NIL, _INT, _FLOAT, _OTHER = 0, 1, 2, 3


@_compiled
def _uint(buf: np.ndarray, pos: int, size: int) -> int:
    """The big-endian unsigned integer of ``size`` bytes at pos (size <= 7, or 8 below 2**63)."""
    v = 0
    for i in range(size):
        v = (v << 8) | int(buf[pos + i])
    return v


@_compiled
def _match(buf: np.ndarray, start: int, length: int, which: int) -> int:
    """Which of the names (0: a plot's fields, 1: the message's, 2: the kinds) the string
    buf[start:start+length] is; −1 none."""
    names, at = (
        (_PLOT_KEYS, _PLOT_KEY_AT)
        if which == 0
        else ((_TOP_KEYS, _TOP_KEY_AT) if which == 1 else (_KIND_NAMES, _KIND_AT))
    )
    for k in range(at.size - 1):
        if at[k + 1] - at[k] != length:
            continue
        same = True
        for i in range(length):
            if buf[start + i] != names[at[k] + i]:
                same = False
                break
        if same:
            return k
    return -1


@_compiled
def _string(buf: np.ndarray, pos: int) -> tuple[int, int, int]:
    """A str at pos: (start, length, the position after it); start −1 when there is no
    complete str (another type, or cut short)."""
    n = buf.size
    if pos >= n:
        return -1, 0, -1
    b = int(buf[pos])
    if 0xA0 <= b <= 0xBF:
        length, start = b & 0x1F, pos + 1
    elif b == 0xD9 and pos + 2 <= n:
        length, start = _uint(buf, pos + 1, 1), pos + 2
    elif b == 0xDA and pos + 3 <= n:
        length, start = _uint(buf, pos + 1, 2), pos + 3
    elif b == 0xDB and pos + 5 <= n:
        length, start = _uint(buf, pos + 1, 4), pos + 5
    else:
        return -1, 0, -1
    if length > _MAX_STR or start + length > n:
        return -1, 0, -1
    return start, length, start + length


@_compiled
def _ascii(buf: np.ndarray, start: int, length: int) -> bool:
    for i in range(start, start + length):  # noqa: SIM110 (compiled: no generators)
        if buf[i] >= 0x80:
            return False
    return True


@_compiled
def _container(buf: np.ndarray, pos: int, array: bool) -> tuple[int, int]:
    """An array (or a map) header at pos: (its item (entry) count, the position after it);
    count −1 when there is none or it is beyond msgpack's limit."""
    n = buf.size
    if pos >= n:
        return -1, -1
    b = int(buf[pos])
    fix, b16, b32, limit = (0x90, 0xDC, 0xDD, _MAX_ARRAY) if array else (0x80, 0xDE, 0xDF, _MAX_MAP)
    if fix <= b <= fix + 0x0F:
        count, after = b & 0x0F, pos + 1
    elif b == b16 and pos + 3 <= n:
        count, after = _uint(buf, pos + 1, 2), pos + 3
    elif b == b32 and pos + 5 <= n:
        count, after = _uint(buf, pos + 1, 4), pos + 5
    else:
        return -1, -1
    if count > limit:
        return -1, -1
    return count, after


@_compiled
def _ieee(buf: np.ndarray, pos: int, size: int, exponent_bits: int, fraction_bits: int) -> float:
    """The big-endian IEEE 754 binary64 (size 8) or binary32 (size 4) at pos, exactly:
    (−1)^s · (2^f + m) · 2^(e − bias − f) for a normal number, (−1)^s · m · 2^(1 − bias − f)
    for a subnormal one (f fraction bits, m the fraction, e the biased exponent); NaN for an
    infinity or a NaN (refused here either way)."""
    first = int(buf[pos])
    negative = first >= 0x80
    rest = _uint(buf, pos, size) & ((1 << (8 * size - 1)) - 1)  # the sign bit cleared
    e = rest >> fraction_bits
    m = rest & ((1 << fraction_bits) - 1)
    bias = (1 << (exponent_bits - 1)) - 1
    if e == (1 << exponent_bits) - 1:
        return math.nan
    if e == 0:
        x = math.ldexp(float(m), 1 - bias - fraction_bits)
    else:
        x = math.ldexp(float(m + (1 << fraction_bits)), e - bias - fraction_bits)
    return -x if negative else x


@_compiled
def _number(buf: np.ndarray, pos: int) -> tuple[int, int, float, int]:
    """A nil, an integer or a float at pos: (_NIL / _INT / _FLOAT / _OTHER, the integer,
    the float, the position after it). _OTHER: any other type, an unsigned integer from
    2**63 (beyond every bound here), or cut short. A NaN or infinite float reads as NaN."""
    n = buf.size
    if pos >= n:
        return _OTHER, 0, 0.0, -1
    b = int(buf[pos])
    if b <= 0x7F:
        return _INT, b, 0.0, pos + 1
    if b >= 0xE0:
        return _INT, b - 0x100, 0.0, pos + 1
    if b == 0xC0:
        return _NIL, 0, 0.0, pos + 1
    if b == 0xCC or b == 0xD0:
        size = 1
    elif b == 0xCD or b == 0xD1:
        size = 2
    elif b == 0xCE or b == 0xD2 or b == 0xCA:
        size = 4
    elif b == 0xCF or b == 0xD3 or b == 0xCB:
        size = 8
    else:
        return _OTHER, 0, 0.0, -1
    if pos + 1 + size > n:
        return _OTHER, 0, 0.0, -1
    if b == 0xCB:
        return _FLOAT, 0, _ieee(buf, pos + 1, 8, 11, 52), pos + 9
    if b == 0xCA:
        return _FLOAT, 0, _ieee(buf, pos + 1, 4, 8, 23), pos + 5
    signed = b >= 0xD0
    if size == 8:
        if not signed and buf[pos + 1] >= 0x80:
            return _OTHER, 0, 0.0, -1  # an unsigned integer from 2**63
        v = _uint(buf, pos + 1, 8)  # int64 arithmetic: an int64's two's complement value
    else:
        v = _uint(buf, pos + 1, size)
        if signed and v >= 1 << (8 * size - 1):
            v -= 1 << (8 * size)
    return _INT, v, 0.0, pos + 1 + size


#: arrays an ignored field may nest before the general path (msgpack) reads it instead
_MAX_SKIP_DEPTH = 256


@_compiled
def _skip(buf: np.ndarray, pos: int) -> int:
    """Past one value of an ignored field: the position after it, or −1 where msgpack's
    reading of it is not plain (see the module docstring): a map, a non-ASCII str, an ext
    type, beyond msgpack's limits (nesting among them), cut short."""
    n = buf.size
    # arrays left open around the value being read, and how many values each still holds:
    # nested deeper than _MAX_SKIP_DEPTH, msgpack (whose C reader stops at 1,024) decides
    left = np.empty(_MAX_SKIP_DEPTH, np.int64)
    depth = 0
    todo = 1
    while todo > 0 or depth > 0:
        if todo == 0:
            depth -= 1
            todo = left[depth]
            continue
        if pos >= n:
            return -1
        todo -= 1
        b = int(buf[pos])
        if b <= 0x7F or b >= 0xE0 or b == 0xC0 or b == 0xC2 or b == 0xC3:
            pos += 1
        elif 0x90 <= b <= 0x9F or b == 0xDC or b == 0xDD:
            count, pos = _container(buf, pos, True)
            if count < 0:
                return -1
            if count > 0:
                if depth == _MAX_SKIP_DEPTH:
                    return -1
                left[depth] = todo
                depth += 1
                todo = count
        elif 0xA0 <= b <= 0xBF or 0xD9 <= b <= 0xDB:
            start, length, pos = _string(buf, pos)
            if start < 0 or not _ascii(buf, start, length):
                return -1
        elif 0xC4 <= b <= 0xC6:  # bin 8/16/32
            size = 1 << (b - 0xC4)
            if pos + 1 + size > n:
                return -1
            length = _uint(buf, pos + 1, size)
            if length > _MAX_BIN:
                return -1
            pos += 1 + size + length
        elif b == 0xCC or b == 0xD0:
            pos += 2
        elif b == 0xCD or b == 0xD1:
            pos += 3
        elif b == 0xCE or b == 0xD2 or b == 0xCA:
            pos += 5
        elif b == 0xCF or b == 0xD3 or b == 0xCB:
            pos += 9
        else:  # a map (its keys), an ext type, 0xC1
            return -1
    return pos if pos <= n else -1


@_compiled
def _plot(
    buf: np.ndarray,
    pos: int,
    k: int,
    floats: np.ndarray,
    ints: np.ndarray,
    kind: np.ndarray,
) -> int:
    """Plot k (a map) at pos into column k of floats (9, N: t, range, azimuth, fl, roll,
    ground speed, track angle, magnetic heading, indicated airspeed; NaN absent), ints (3, N:
    mode3a, track_no, mode_s; −1 absent) and kind; the position after it, or −1 to hand the
    batch back."""
    entries, pos = _container(buf, pos, False)
    if entries < 0:
        return -1
    seen = 0
    floats[_F_FL, k] = floats[_F_ROLL, k] = floats[_F_GS, k] = floats[_F_TRK, k] = np.nan
    floats[_F_HDG, k] = floats[_F_IAS, k] = np.nan
    ints[0, k] = ints[1, k] = ints[2, k] = -1
    kind[k] = _NO_KIND
    for _ in range(entries):
        start, length, pos = _string(buf, pos)
        if start < 0:
            return -1  # a key that is not a str
        f = _match(buf, start, length, 0)
        if f < 0:
            if not _ascii(buf, start, length):
                return -1
            pos = _skip(buf, pos)
            if pos < 0:
                return -1
            continue
        if seen & (1 << f):
            return -1  # a key twice: msgpack keeps the last
        seen |= 1 << f
        if f == _F_MODE_S or f == _F_KIND:  # noqa: SIM109 (compiled)
            if pos < buf.size and buf[pos] == 0xC0:
                pos += 1
                continue
            start, length, pos = _string(buf, pos)
            if start < 0:
                return -1
            if f == _F_KIND:
                c = _match(buf, start, length, 2)
                if c < 0:
                    return -1
                kind[k] = _KIND_CODE[c]
                continue
            if length != 6:
                return -1
            v = 0
            for i in range(start, start + 6):
                d = int(buf[i])
                if 0x30 <= d <= 0x39:
                    d -= 0x30
                elif 0x41 <= d <= 0x46:
                    d -= 0x37
                elif 0x61 <= d <= 0x66:
                    d -= 0x57
                else:
                    return -1
                v = (v << 4) | d
            ints[2, k] = v
            continue
        what, iv, fv, pos = _number(buf, pos)
        if what == _OTHER:
            return -1
        if what == _NIL:
            if f == _F_T or f == _F_RANGE or f == _F_AZ:  # noqa: SIM109 (compiled)
                return -1  # a required number
            continue
        if f <= _F_IAS:  # a float field (strict: an integer is a number, a bool is not)
            x = fv if what == _FLOAT else float(iv)
            if not (_BOUNDS_LO[f] <= x <= _BOUNDS_HI[f]):  # NaN too
                return -1
            floats[f, k] = x
        else:  # an integer field
            if what != _INT or not (_BOUNDS_LO[f] <= float(iv) <= _BOUNDS_HI[f]):
                return -1
            ints[f - _F_MODE3A, k] = iv
    if seen & _REQUIRED_MASK != _REQUIRED_MASK:
        return -1
    return pos


@_compiled
def _parse(buf: np.ndarray) -> tuple[int, int, int, int, np.ndarray, np.ndarray, np.ndarray]:
    """The whole PlotBatch: (1 accepted / 0 handed back, radar_id's start and length, seq,
    floats (9, N), ints (3, N), kind (N,))."""
    floats = np.empty((_FLOAT_ROWS, 0))
    ints = np.empty((3, 0), np.int64)
    kind = np.empty(0, np.int8)
    no = (0, 0, 0, 0, floats, ints, kind)
    entries, pos = _container(buf, 0, False)
    if entries < 0:
        return no
    seen = 0
    rid_start = rid_len = seq = 0
    for _ in range(entries):
        start, length, pos = _string(buf, pos)
        if start < 0:
            return no
        f = _match(buf, start, length, 1)
        if f < 0:
            if not _ascii(buf, start, length):
                return no
            pos = _skip(buf, pos)
            if pos < 0:
                return no
            continue
        if seen & (1 << f):
            return no
        seen |= 1 << f
        if f == 0 or f == 2:  # v, seq: integers
            what, iv, _fv, pos = _number(buf, pos)
            if what != _INT or (f == 0 and iv != WIRE_VERSION) or (f == 2 and iv < 0):
                return no
            if f == 2:
                seq = iv
        elif f == 1:  # radar_id: its pattern is checked by the caller
            rid_start, rid_len, pos = _string(buf, pos)
            if rid_start < 0:
                return no
        else:  # plots
            count, pos = _container(buf, pos, True)
            if count < 0 or count > MAX_PLOTS_PER_BATCH:
                return no
            floats = np.empty((_FLOAT_ROWS, count))
            ints = np.empty((3, count), np.int64)
            kind = np.empty(count, np.int8)
            for k in range(count):
                pos = _plot(buf, pos, k, floats, ints, kind)
                if pos < 0:
                    return no
    if seen != 0b1111 or pos != buf.size:
        return no
    return 1, rid_start, rid_len, seq, floats, ints, kind


_RADAR_ID = re.compile(RADAR_ID_PATTERN)
_RADAR_IDS: dict[bytes, str] = {}  # ids seen that match the pattern
_RADAR_IDS_MAX = 10_000


def decode_plot_batch_bytes(payload: bytes) -> DecodedPlots | None:
    """The batch's columns when every part of it is well-formed (the module docstring),
    else None: the general path decides. The caller checks the payload's size first."""
    ok, rid_start, rid_len, seq, floats, ints, kind = _parse(np.frombuffer(payload, np.uint8))
    if not ok:
        return None
    raw = bytes(payload[rid_start : rid_start + rid_len])
    radar_id = _RADAR_IDS.get(raw)
    if radar_id is None:
        try:
            text = raw.decode("ascii")
        except UnicodeDecodeError:
            return None
        if not _RADAR_ID.fullmatch(text):
            return None
        if len(_RADAR_IDS) > _RADAR_IDS_MAX:
            _RADAR_IDS.clear()
        radar_id = _RADAR_IDS[raw] = text
    return DecodedPlots(
        radar_id=radar_id,
        seq=seq,
        t_s=floats[_F_T],
        range_m=floats[_F_RANGE],
        azimuth_deg=floats[_F_AZ],
        fl=floats[_F_FL],
        mode3a=ints[0],
        mode_s=ints[2],
        track_no=ints[1],
        kind=kind,
        roll_deg=floats[_F_ROLL],
        ground_speed_mps=floats[_F_GS],
        track_angle_deg=floats[_F_TRK],
        magnetic_heading_deg=floats[_F_HDG],
        indicated_airspeed_mps=floats[_F_IAS],
        rejected={},
    )


def warm_up() -> None:
    """Compile (or load from numba's cache) the parser now, not at the first batch."""
    import msgpack

    plot = {"t": 1.0, "range_m": 1.0, "azimuth_deg": 1.0}
    decode_plot_batch_bytes(msgpack.packb({"v": WIRE_VERSION, "radar_id": "r", "seq": 0, "plots": [plot]}))
