"""A received TrackBatch as the safety nets' input: decode, validate, columns.

The stand-alone safety nets (``radar-fusion safety-nets``, :mod:`.process`) read the
tracks topic like any consumer. :meth:`TrackBatchReader.decode` turns one payload into
the :class:`~radar_fusion.engine.columns.TrackColumns` the engine would have handed the
safety nets in process, or a :class:`~radar_fusion.wire.Rejection` with a reason
(``oversize``, ``malformed_msgpack``, ``version``, ``schema``); it never raises.

The model (``wire.TrackBatch``) is the contract. At 4,000 tracks msgpack's decoding
alone takes ~12 ms and the model ~18 ms, about the safety nets' own time, so a batch is
read in up to three ways, each handing over to the next what it cannot decide:

1. from 30 kB (~90 tracks), straight from its bytes (:mod:`.track_bytes`: the daemon's
   layout, all tracks at once, ~4 ms at 4,000 tracks), with the checks of 2;
2. decoded by msgpack and read as columns, with checks at least as strict as the
   model's (exact types, finite floats, the model's bounds);
3. by the model: its reason when it refuses; when it accepts (it coerces, e.g. a
   numeric string), its own dump read as in 2.

One refusal beyond the model: a ``mode_s`` that is not 6 hex digits or an integer beyond
int64 (the columns hold numbers; the daemon sends neither). Tests prove that the three
give the same columns, and the same verdict as the model.

What the engine's columns carry and a TrackBatch does not, or not exactly:

* which tracks the safety nets judge: the engine's rule, every track that is not
  tentative (confirmed *and* coasting, so an alert survives a missed scan), is kept:
  ``safety_eligible`` is left None (``TrackColumns.from_message`` would take confirmed
  tracks only);
* ``fl`` is sent rounded to 0.01 FL (1 ft): the vertical tests see it so;
* the source radars are a bit mask over the configured radar ids; an id the
  configuration does not know is dropped from the mask (the safety nets do not use it);
* ``selected_fl`` is not on the wire, nor produced by the engine (None both ways).
"""

from __future__ import annotations

import math
from itertools import chain
from typing import Any

import msgpack
import numpy as np
from pydantic import ValidationError

from ..engine.columns import RadarNames, TrackColumns
from ..geo.coordinates import SystemPlane
from ..tracking.track_management import STATUS_NAMES
from ..wire import WIRE_VERSION, Rejection, TrackBatch
from .track_bytes import NotLayout, read_tracks

MAX_TRACK_BATCH_BYTES = 64 << 20
"""Largest TrackBatch payload accepted: 64 MiB, ~48,000 tracks of ~330 bytes (the bus's
``max_payload_bytes`` bounds what radars send, not what the daemon publishes)."""
MAX_TRACKS_PER_BATCH = 200_000

_UNPACK_LIMITS = dict(
    raw=False,
    strict_map_key=True,
    max_str_len=1 << 16,
    max_bin_len=1 << 20,
    max_array_len=MAX_TRACKS_PER_BATCH,
    max_map_len=64,
    max_ext_len=0,
)
FAST_MIN_BYTES = 30_000
"""From this size (~90 tracks) a batch is first read straight from its bytes
(track_bytes.py): below it msgpack's own decoding is as fast."""
_STATUS_CODES = {name: code for code, name in enumerate(STATUS_NAMES)}
_NUMBER = {float, int}
_NUMBER_OR_NONE = {float, int, type(None)}
# required numbers (finite), optional numbers (None or finite)
_FLOATS = ("t", "lat_deg", "lon_deg", "x_m", "y_m", "age_s")
_OPTIONAL_FLOATS = ("vx_mps", "vy_mps", "fl", "vrate_fpm", "ax_mps2", "ay_mps2", "manoeuvre_prob")


class _NotColumns(Exception):
    """The fast reading failed a check; the model decides."""


def _stamp_ok(epoch: Any, instance: Any) -> bool:
    """A hot-standby active's stamp as wire.TrackBatch has it: both absent, or an epoch >= 1 (and a name)."""
    return (epoch is None and instance is None) or (
        type(epoch) is int and epoch >= 1 and (instance is None or type(instance) is str)
    )


class TrackBatchReader:
    """Decodes TrackBatch payloads into TrackColumns for one configuration (plane, radar ids).

    ``reader.decode(payload)`` → TrackColumns or Rejection. A payload of ``fast_min_bytes``
    or more is first read from its bytes (track_bytes.py; ``layout_misses`` counts those
    that were not in the daemon's layout); otherwise, or then, msgpack decodes it and the
    columns are read from the dicts; ``model_fallbacks`` counts the batches that reading
    handed to the model.
    """

    def __init__(
        self,
        plane: SystemPlane,
        radar_ids: list[str],
        max_bytes: int = MAX_TRACK_BATCH_BYTES,
        fast_min_bytes: int | None = None,
    ):
        self.fast_min_bytes = FAST_MIN_BYTES if fast_min_bytes is None else fast_min_bytes
        self.plane = plane
        self.names = RadarNames(list(radar_ids), plane)
        self._bits = {rid: 1 << b for b, rid in enumerate(radar_ids[:64])}
        self._masks: dict[tuple[str, ...], int] = {}
        self.max_bytes = max_bytes
        self.model_fallbacks = 0
        self.layout_misses = 0  # batches of FAST_MIN_BYTES or more not in the daemon's layout
        self._packed_masks: dict[bytes, int] = {}

    def decode(self, payload: bytes) -> TrackColumns | Rejection:
        if len(payload) > self.max_bytes:
            return Rejection("oversize", f"{len(payload)} bytes > {self.max_bytes}")
        if len(payload) >= self.fast_min_bytes:
            try:
                return self._from_layout(read_tracks(payload))
            except Exception:  # NotLayout, or anything the bytes provoke: the general path decides
                self.layout_misses += 1
        try:
            obj = msgpack.unpackb(payload, **_UNPACK_LIMITS)
        except Exception as exc:  # msgpack raises several unrelated exception types
            return Rejection("malformed_msgpack", type(exc).__name__)
        return self.from_object(obj)

    def _from_layout(self, c: dict[str, Any]) -> TrackColumns:
        """Columns from track_bytes.read_tracks, with the checks of ``_columns`` (any
        failure: NotLayout, and the general path decides)."""
        t_s, period, ended = c["t"], c["period"], c["ended"]
        ok = (
            type(c["v"]) is int
            and c["v"] == WIRE_VERSION
            and type(t_s) in _NUMBER
            and math.isfinite(t_s)
            and type(period) is int
            and period >= 0
            and type(ended) is list
            and (not ended or set(map(type, ended)) == {int})
            and bool((c["age_s"] >= 0).all())
            and bool((c["track_id"] >= 0).all())
            and bool((c["updates"] >= 0).all())
            and bool((c["mode3a"] >= -1).all())
        )
        mp = c["manoeuvre_prob"]
        ok = ok and _stamp_ok(c.get("epoch"), c.get("instance"))
        if not ok or not bool((((mp >= 0) & (mp <= 1)) | np.isnan(mp)).all()):
            raise NotLayout
        payload_spans = c["sources_span"]
        n = len(c["track_id"])
        sources = np.fromiter(
            (self._mask_of_bytes(c["payload"][a:b]) for a, b in zip(*(s.tolist() for s in payload_spans), strict=True)),
            np.uint64,
            n,
        )
        x = np.column_stack([c["x_m"], c["vx_mps"], c["ax_mps2"], c["y_m"], c["vy_mps"], c["ay_mps2"]]).reshape(n, 6)
        columns = TrackColumns(
            period=period,
            t_s=float(t_s),
            track_id=c["track_id"],
            status=c["status"].astype(np.int8),
            x=x,
            cov_xy=c["cov_xy"].reshape(n, 3),
            fl=c["fl"],
            vrate_fpm=c["vrate_fpm"],
            sources=sources,
            mode3a=c["mode3a"],
            mode_s=c["mode_s"],
            updates=c["updates"],
            age_s=c["age_s"],
            ended=np.array(ended, dtype=np.int64).reshape(len(ended)),
            names=self.names,
            safety_eligible=None,
            manoeuvre_prob=None if np.isnan(mp).all() else mp,
            t_track_s=None if bool((c["track_t"] == t_s).all()) else c["track_t"],
            epoch=c.get("epoch"),
            instance=c.get("instance"),
        )
        columns.__dict__["geodetic"] = (c["lat_deg"], c["lon_deg"])
        return columns

    def _mask_of_bytes(self, packed: bytes) -> int:
        mask = self._packed_masks.get(packed)
        if mask is None:
            sources = msgpack.unpackb(packed, raw=False)
            if type(sources) is not list or not all(type(s) is str for s in sources):
                raise NotLayout
            mask = 0
            for s in sources:
                mask |= self._bits.get(s, 0)
            if len(self._packed_masks) > 10_000:
                self._packed_masks.clear()
            self._packed_masks[packed] = mask
        return mask

    def from_object(self, obj: Any) -> TrackColumns | Rejection:
        """Columns from a decoded message (the dict msgpack gave), or why not."""
        if not isinstance(obj, dict):
            return Rejection("schema", f"expected a map, got {type(obj).__name__}")
        if type(obj.get("v")) is not int or obj.get("v") != WIRE_VERSION:
            return Rejection("version", f"v={obj.get('v')!r}")
        try:
            return self._columns(obj)
        except (_NotColumns, KeyError, TypeError, ValueError, OverflowError, AttributeError):
            pass
        self.model_fallbacks += 1
        try:
            dumped = TrackBatch.model_validate(obj).model_dump()
        except ValidationError as exc:
            first = exc.errors()[0]
            return Rejection("schema", f"{'.'.join(map(str, first['loc']))}: {first['msg']}")
        except Exception as exc:  # e.g. a recursion limit: never a crash
            return Rejection("schema", f"{type(exc).__name__}")
        try:
            return self._columns(dumped)
        except Exception as exc:
            why = (
                "a mode_s that is not 6 hex digits, or an integer beyond int64" if isinstance(exc, _NotColumns) else exc
            )
            return Rejection("schema", f"not representable as track columns: {why}")

    # ------------------------------------------------------------------ columns
    def _columns(self, obj: dict) -> TrackColumns:
        t_s, period, tracks, ended = obj["t"], obj["period"], obj["tracks"], obj.get("ended", [])
        _check(_stamp_ok(obj.get("epoch"), obj.get("instance")))
        _check(type(t_s) in _NUMBER and math.isfinite(t_s))
        _check(type(period) is int and period >= 0)
        _check(type(tracks) is list and type(ended) is list)
        _check(not ended or set(map(type, ended)) == {int})
        _check(not tracks or set(map(type, tracks)) == {dict})
        n = len(tracks)

        def numbers(key: str) -> np.ndarray:
            col = [tr[key] for tr in tracks]
            _check(not col or set(map(type, col)) <= _NUMBER)
            a = np.array(col, dtype=float).reshape(n)
            _check(bool(np.isfinite(a).all()))
            return a

        def optional_numbers(key: str) -> np.ndarray:
            col = [tr.get(key) for tr in tracks]
            types = set(map(type, col))
            _check(types <= _NUMBER_OR_NONE)
            if type(None) not in types:
                a = np.array(col, dtype=float).reshape(n)
            else:
                a = np.array([math.nan if v is None else v for v in col], dtype=float).reshape(n)
                _check(bool(np.isfinite(a[np.array([v is not None for v in col], bool)]).all()))
                return a
            _check(bool(np.isfinite(a).all()))
            return a

        def integers(key: str, optional: bool = False) -> np.ndarray:
            col = [tr.get(key) for tr in tracks] if optional else [tr[key] for tr in tracks]
            types = set(map(type, col))
            _check(types <= ({int, type(None)} if optional else {int}))
            if type(None) in types:
                col = [-1 if v is None else v for v in col]
                a = np.array(col, dtype=np.int64).reshape(n)
                return a
            return np.array(col, dtype=np.int64).reshape(n)

        f = {key: numbers(key) for key in _FLOATS}
        o = {key: optional_numbers(key) for key in _OPTIONAL_FLOATS}
        _check(bool((f["age_s"] >= 0).all()))
        mp = o["manoeuvre_prob"]
        _check(bool(((mp >= 0) & (mp <= 1) | np.isnan(mp)).all()))
        track_id = integers("track_id")
        updates = integers("updates")
        _check(bool((track_id >= 0).all()) and bool((updates >= 0).all()))
        mode3a = integers("mode3a", optional=True)
        _check(bool((mode3a >= -1).all()))  # the model takes any int; a negative one would read as none
        status = [tr["status"] for tr in tracks]
        codes = _STATUS_CODES
        status_codes = np.fromiter((codes[s] for s in status), np.int8, n)  # KeyError: not a status
        mode_s = [tr.get("mode_s") for tr in tracks]
        _check(set(map(type, mode_s)) <= {str, type(None)})
        mode_s_int = np.fromiter((-1 if m is None else _hex6(m) for m in mode_s), np.int64, n)
        cov = [tr["cov_xy"] for tr in tracks]
        _check(not cov or (set(map(type, cov)) == {list} and set(map(len, cov)) == {3}))
        _check(not cov or set(map(type, chain.from_iterable(cov))) <= _NUMBER)
        cov_xy = np.array(cov, dtype=float).reshape(n, 3)
        _check(bool(np.isfinite(cov_xy).all()))
        sources = np.fromiter((self._mask(tr["sources"]) for tr in tracks), np.uint64, n)
        # nil velocity and acceleration (a track of one update, an older sender) are NaN, as in
        # the engine's columns; the safety nets take such a track as not moving
        x = np.column_stack([f["x_m"], o["vx_mps"], o["ax_mps2"], f["y_m"], o["vy_mps"], o["ay_mps2"]]).reshape(n, 6)
        columns = TrackColumns(
            period=period,
            t_s=float(t_s),
            track_id=track_id,
            status=status_codes,
            x=x,
            cov_xy=cov_xy,
            fl=o["fl"],
            vrate_fpm=o["vrate_fpm"],
            sources=sources,
            mode3a=mode3a,
            mode_s=mode_s_int,
            updates=updates,
            age_s=f["age_s"],
            ended=np.array(ended, dtype=np.int64).reshape(len(ended)),
            names=self.names,
            safety_eligible=None,  # the engine's rule: every track that is not tentative
            manoeuvre_prob=None if np.isnan(mp).all() else mp,
            t_track_s=None if bool((f["t"] == t_s).all()) else f["t"],
            epoch=obj.get("epoch"),
            instance=obj.get("instance"),
        )
        columns.__dict__["geodetic"] = (f["lat_deg"], f["lon_deg"])  # as the sender computed them
        return columns

    def _mask(self, sources: Any) -> int:
        key = tuple(sources)  # TypeError: not a list
        mask = self._masks.get(key)
        if mask is None:
            _check(type(sources) is list and all(type(s) is str for s in sources))
            mask = 0
            for s in sources:
                mask |= self._bits.get(s, 0)
            if len(self._masks) > 10_000:  # bounded: combinations of a few radars
                self._masks.clear()
            self._masks[key] = mask
        return mask


def _check(ok: bool) -> None:
    if not ok:
        raise _NotColumns


def _hex6(m: str) -> int:
    _check(len(m) == 6)
    return int(m, 16)  # ValueError: not hex
