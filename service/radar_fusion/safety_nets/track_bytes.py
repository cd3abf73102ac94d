"""A TrackBatch's tracks read straight from its msgpack bytes, as numpy columns.

``msgpack.unpackb`` of a 4,000-track batch builds 80,000 key strings and as many values
(~12 ms), and reading the dicts into columns costs as much again: two thirds of what
the safety nets themselves take. The daemon writes every track as the same map (the
``wire.Track`` fields in ``TRACK_KEYS`` order; ``TrackColumns.to_msgpack``, and msgpack's
own packing of ``to_message`` below 150 tracks, give the same bytes), so each field can
be read for all tracks at once: every track's start is found by msgpack itself
(``Unpacker.skip``, no objects built), then field after field the type bytes, the values
and each track's next offset are numpy arrays.

Anything else — another key order, another encoding of a number, a type the daemon does
not write, a track that does not end where the next begins — raises :class:`NotLayout`,
and the caller reads the batch the general way (msgpack, then the model's checks). So
this path decides nothing about validity that the general path would decide otherwise:
it only reads, and checks that it read what the general path would have.
"""

from __future__ import annotations

from typing import Any

import msgpack
import numpy as np

from ..engine.columns import TRACK_KEYS
from ..tracking.track_management import STATUS_NAMES

FLOAT_FIELDS = ("t", "lat_deg", "lon_deg", "x_m", "y_m", "age_s")
# nil (NaN here): velocity of a track of one update (none yet), and what a sender does not know
OPTIONAL_FLOAT_FIELDS = ("vx_mps", "vy_mps", "fl", "vrate_fpm", "ax_mps2", "ay_mps2", "manoeuvre_prob")
_STATUS_TEMPLATES = {bytes(msgpack.packb(name)): code for code, name in enumerate(STATUS_NAMES)}
_CHAR_SHIFTS = np.array([56, 48, 40, 32, 24, 16], np.uint64)  # the first 6 bytes of a big-endian u64
_HEX = np.full(256, -1, np.int64)
for _i, _c in enumerate(b"0123456789ABCDEF"):
    _HEX[_c] = _i
for _i, _c in enumerate(b"abcdef"):
    _HEX[_c] = 10 + _i
_NIBBLE = np.array([20, 16, 12, 8, 4, 0], np.int64)


class NotLayout(Exception):
    """Not the daemon's layout: read the batch the general way."""


def _need(ok: Any) -> None:
    if not ok:
        raise NotLayout


class _Reader:
    """The payload as byte offsets: ``u64[i]`` / ``i64[i]`` / ``f64[i]`` are the 8 bytes
    from offset i, big-endian (strided views of one buffer, no copy per field); ``o`` is
    each track's current offset."""

    def __init__(self, payload: bytes, starts: np.ndarray):
        self.payload = payload
        self.size = len(payload)
        padded = payload + bytes(16)
        self.buf = np.frombuffer(padded, np.uint8)
        shape = (self.size + 8,)
        self.u64 = np.ndarray(shape, dtype=">u8", buffer=padded, strides=(1,))
        self.i64 = np.ndarray(shape, dtype=">i8", buffer=padded, strides=(1,))
        self.f64 = np.ndarray(shape, dtype=">f8", buffer=padded, strides=(1,))
        self.o = starts.copy()

    def equal(self, template: bytes, o: np.ndarray | None = None) -> np.ndarray:
        """Per track: do the bytes at its offset equal ``template``?"""
        o = self.o if o is None else o
        ok = np.ones(len(o), bool)
        for j in range(0, len(template), 8):
            chunk = template[j : j + 8]
            shift = 8 * (8 - len(chunk))
            ok &= (self.u64[o + j] >> np.uint64(shift)) == np.uint64(int.from_bytes(chunk, "big"))
        return ok

    def key(self, name: str) -> None:
        k = bytes(msgpack.packb(name))
        _need(self.equal(k).all())
        self.o += len(k)
        _need(self.o.max(initial=0) < self.size)

    def map_header(self, n_keys: int) -> None:
        h = bytes(msgpack.packb(dict.fromkeys(range(n_keys))))[: 3 if n_keys > 15 else 1]
        _need(self.equal(h).all())
        self.o += len(h)

    def floats(self, nil: bool = False) -> np.ndarray:
        """float64 values (NaN for nil); a NaN or infinity that is not nil: the general path refuses it."""
        b = self.buf[self.o]
        is_nil = b == 0xC0
        _need(((b == 0xCB) | (is_nil & nil)).all())
        raw = self.f64[self.o + 1].astype(float)
        _need(np.isfinite(raw[~is_nil]).all())
        raw[is_nil] = np.nan
        self.o += np.where(is_nil, 1, 9)
        return raw

    def integers(self, nil: bool = False) -> tuple[np.ndarray, np.ndarray]:
        b = self.buf[self.o].astype(np.int64)
        values = np.zeros(len(b), np.int64)
        width = np.zeros(len(b), np.int64)
        pos, neg = b < 0x80, b >= 0xE0
        values[pos], width[pos] = b[pos], 1
        values[neg], width[neg] = b[neg] - 256, 1
        is_nil = b == 0xC0
        width[is_nil] = 1 if nil else 0
        rest = ~(pos | neg | is_nil)
        if rest.any():
            at = self.o[rest] + 1
            code = b[rest]
            for c, nbytes, signed in (
                (0xCC, 1, False),
                (0xCD, 2, False),
                (0xCE, 4, False),
                (0xCF, 8, False),
                (0xD0, 1, True),
                (0xD1, 2, True),
                (0xD2, 4, True),
                (0xD3, 8, True),
            ):
                m = code == c
                if not m.any():
                    continue
                if signed:
                    v = self.i64[at[m]].astype(np.int64) >> (64 - 8 * nbytes)
                else:
                    u = self.u64[at[m]].astype(np.uint64) >> np.uint64(64 - 8 * nbytes)
                    _need((u < np.uint64(1 << 63)).all())  # beyond int64: the general path
                    v = u.astype(np.int64)
                idx = np.flatnonzero(rest)[m]
                values[idx], width[idx] = v, 1 + nbytes
        _need((width > 0).all())
        self.o += width
        return values, is_nil


def read_tracks(payload: bytes, min_tracks: int = 0) -> dict[str, Any]:
    """{"t", "period", "ended", ["epoch", "instance",] and the track columns} from a
    TrackBatch's bytes, or NotLayout.

    Raises NotLayout below ``min_tracks`` tracks too (the general path is as fast there)."""
    unpacker = msgpack.Unpacker(raw=False, max_buffer_size=max(len(payload), 1 << 20), strict_map_key=True)
    unpacker.feed(payload)
    try:
        n_keys = unpacker.read_map_header()
        _need(n_keys in (5, 7))
        head = {}
        for name in ("v", "t", "period"):
            _need(unpacker.unpack() == name)
            head[name] = unpacker.unpack()
        _need(unpacker.unpack() == "tracks")
        n = unpacker.read_array_header()
        _need(n >= min_tracks)
        starts = np.empty(n + 1, np.int64)
        tell, skip = unpacker.tell, unpacker.skip
        for i in range(n):
            starts[i] = tell()
            skip()
        starts[n] = tell()
        _need(unpacker.unpack() == "ended")
        head["ended"] = unpacker.unpack()
        if n_keys == 7:  # a hot-standby active's stamp (issue 13)
            for name in ("epoch", "instance"):
                _need(unpacker.unpack() == name)
                head[name] = unpacker.unpack()
        _need(unpacker.tell() == len(payload))
    except NotLayout:
        raise
    except Exception as exc:  # truncated, malformed: the general path says why
        raise NotLayout from exc
    try:
        return _columns(payload, starts, n, head)
    except (IndexError, ValueError, OverflowError) as exc:  # read past the end, a bad view: not our layout
        raise NotLayout from exc


def _columns(payload: bytes, starts: np.ndarray, n: int, head: dict[str, Any]) -> dict[str, Any]:
    r = _Reader(payload, starts[:n])
    cols: dict[str, Any] = dict(head, payload=payload)
    r.map_header(len(TRACK_KEYS))
    for name in TRACK_KEYS:
        r.key(name)
        if name in ("track_id", "updates"):
            cols[name] = r.integers()[0]
        elif name == "mode3a":
            v, is_nil = r.integers(nil=True)
            cols[name] = np.where(is_nil, -1, v)
            cols["mode3a_nil"] = is_nil
        elif name == "t":  # each track's time (the batch's own t is in the head)
            cols["track_t"] = r.floats()
        elif name in FLOAT_FIELDS:
            cols[name] = r.floats()
        elif name in OPTIONAL_FLOAT_FIELDS:
            cols[name] = r.floats(nil=True)
        elif name == "status":
            code = np.full(n, -1, np.int64)
            width = np.zeros(n, np.int64)
            for template, c in _STATUS_TEMPLATES.items():
                m = r.equal(template)
                code[m], width[m] = c, len(template)
            _need((code >= 0).all())
            r.o += width
            cols[name] = code
        elif name == "cov_xy":
            _need((r.buf[r.o] == 0x93).all())
            r.o += 1
            cols[name] = np.column_stack([r.floats(), r.floats(), r.floats()])
        elif name == "sources":
            b = r.buf[r.o]
            _need(((b & 0xF0) == 0x90).all())
            k = (b & 0x0F).astype(np.int64)
            begin = r.o.copy()
            r.o += 1
            for j in range(int(k.max(initial=0))):
                sel = k > j
                sub = r.o[sel]
                bb = r.buf[sub]
                _need(((bb & 0xE0) == 0xA0).all())
                r.o[sel] = sub + 1 + (bb & 0x1F)
            cols["sources_span"] = (begin, r.o.copy())
        elif name == "mode_s":
            b = r.buf[r.o]
            is_nil = b == 0xC0
            _need(((b == 0xA6) | is_nil).all())
            chars = (r.u64[r.o + 1][:, None] >> _CHAR_SHIFTS) & np.uint64(0xFF)
            nib = _HEX[chars.astype(np.int64)]
            ok = is_nil | (nib >= 0).all(axis=1)
            _need(ok.all())
            cols[name] = np.where(is_nil, -1, (np.where(nib < 0, 0, nib) << _NIBBLE).sum(axis=1))
            r.o += np.where(is_nil, 1, 7)
        else:  # a field this reader does not know: the general path
            raise NotLayout
    _need((r.o == starts[1:]).all())  # every track ends where the next begins
    return cols
