"""The engine's column types: plots and tracks as numpy arrays, one row each.

* :class:`PlotChunk`: plots as the radars measured them (polar), buffered per period;
* :class:`ConvertedPlots`: a closing period's plots after the gate, in the system plane;
* :class:`ClusterMeasurements`: one fused measurement per cluster of the period;
* :class:`TrackColumns`: every track at a period's reference time, the engine's output
  (the TrackBatch message is built from it, the safety nets read it; ``from_message``
  rebuilds it from a received TrackBatch);
* :class:`Prediction` and :class:`PeriodOutput`: the period's tracks predicted to its
  reference time, and what a closed period returns.

The filter's own mutable track store is :class:`radar_fusion.tracking.track_management.TrackTable`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from functools import cached_property
from itertools import repeat
from typing import Any

import msgpack
import numpy as np

from ..geo.coordinates import SystemPlane
from ..tracking.registration import ClusterSensitivity
from ..tracking.track_management import STATUS_NAMES, TENTATIVE
from ..wire import mode_s_to_str
from ..wire_columns import MapRows, array_header, map_header

# Columns a buffered plot carries (all numpy arrays of one length). Plots are buffered
# as the radar measured them (polar); the engine gates and converts a whole period at
# once when it closes, which costs one vectorised pass instead of one per batch.
PLOT_COLUMNS = (
    "t_s", "range_m", "azimuth_deg", "fl", "radar", "mode_s", "mode3a", "track_no",
    "roll_deg", "ground_speed_mps", "track_angle_deg", "magnetic_heading_deg", "indicated_airspeed_mps",
)  # fmt: skip


@dataclass
class PlotChunk:
    """Plots of one or more ingested batches, as columns (radar coordinates)."""

    t_s: np.ndarray
    range_m: np.ndarray
    azimuth_deg: np.ndarray
    fl: np.ndarray  # float, NaN none
    radar: np.ndarray  # radar index, int64
    mode_s: np.ndarray  # int64, -1 none
    mode3a: np.ndarray  # int64, -1 none
    track_no: np.ndarray  # int64, -1 none
    # Mode S BDS 5,0 roll angle, degrees, positive right wing down; float, NaN none
    # (None when made: none for every plot)
    roll_deg: np.ndarray = None  # type: ignore[assignment]
    # Mode S BDS 5,0 ground speed, m/s, and true track angle, degrees clockwise from true
    # north; float, NaN none (None when made: none for every plot)
    ground_speed_mps: np.ndarray = None  # type: ignore[assignment]
    track_angle_deg: np.ndarray = None  # type: ignore[assignment]
    # Mode S BDS 6,0 magnetic heading, degrees clockwise from magnetic north, and indicated
    # airspeed, m/s; float, NaN none (None when made: none for every plot)
    magnetic_heading_deg: np.ndarray = None  # type: ignore[assignment]
    indicated_airspeed_mps: np.ndarray = None  # type: ignore[assignment]

    def __post_init__(self) -> None:
        if self.roll_deg is None:
            self.roll_deg = np.full(self.t_s.shape[0], np.nan)
        if self.ground_speed_mps is None:
            self.ground_speed_mps = np.full(self.t_s.shape[0], np.nan)
        if self.track_angle_deg is None:
            self.track_angle_deg = np.full(self.t_s.shape[0], np.nan)
        if self.magnetic_heading_deg is None:
            self.magnetic_heading_deg = np.full(self.t_s.shape[0], np.nan)
        if self.indicated_airspeed_mps is None:
            self.indicated_airspeed_mps = np.full(self.t_s.shape[0], np.nan)

    def __len__(self) -> int:
        return int(self.t_s.shape[0])

    @staticmethod
    def concatenate(chunks: list[PlotChunk]) -> PlotChunk:
        if not chunks:
            return PlotChunk.empty()
        if len(chunks) == 1:
            return chunks[0]
        return PlotChunk(*(np.concatenate([getattr(c, name) for c in chunks]) for name in PLOT_COLUMNS))

    @staticmethod
    def empty() -> PlotChunk:
        f, i = np.empty(0), np.empty(0, np.int64)
        return PlotChunk(f, f, f, f, i, i, i, i, f, f, f, f, f)

    def select(self, mask: np.ndarray) -> PlotChunk:
        return PlotChunk(*(getattr(self, name)[mask] for name in PLOT_COLUMNS))


@dataclass
class TrackColumns:
    """Every track at a period's reference time, as arrays (rows = tracks)."""

    period: int
    t_s: float
    track_id: np.ndarray
    status: np.ndarray  # track_management status codes
    x: np.ndarray  # (N, 6) Singer state [x, vx, ax, y, vy, ay], system plane, m / m/s / m/s²
    cov_xy: np.ndarray  # (N, 3) [σxx², σxy, σyy²], m²
    fl: np.ndarray
    vrate_fpm: np.ndarray
    sources: np.ndarray  # uint64 bit mask over ``names``
    mode3a: np.ndarray
    mode_s: np.ndarray
    updates: np.ndarray
    age_s: np.ndarray
    ended: np.ndarray  # ids of tracks ended in this period
    names: RadarNames
    # Optional columns (None: not known). selected_fl: the selected or cleared level (float
    # FL, NaN unknown; Mode S BDS 4,0 or the flight plan's CFL), which caps the safety
    # nets' vertical prediction. safety_eligible: which tracks the safety nets judge (bool);
    # None means every track that is not tentative (see safety_nets.prediction.eligible).
    selected_fl: np.ndarray | None = None
    safety_eligible: np.ndarray | None = None
    # the IMM's manoeuvre-model probability per track (tracking.filter = "imm"), else None
    manoeuvre_prob: np.ndarray | None = None
    # Each track's own time (N,), s, where it differs from t_s: a track of one update has no
    # velocity yet (x's velocity and acceleration are NaN, sent as nil; unless it started
    # with the aircraft's own, TrackTable.velocity_known) and is reported
    # where it was measured, at its measurement time, not extrapolated to t_s. None: every
    # track is at t_s.
    t_track_s: np.ndarray | None = None
    # A hot-standby pair's stamp (issue 13): the publishing active's epoch and instance
    # name, sent as the TrackBatch's last two keys; None with [redundancy] off (not sent).
    epoch: int | None = None
    instance: str | None = None

    def __len__(self) -> int:
        return int(self.track_id.shape[0])

    def _stamp(self) -> dict[str, Any]:
        return {} if self.epoch is None else {"epoch": self.epoch, "instance": self.instance}

    # The state's columns by their wire names (views, no copy): what the safety nets and
    # their hooks read.
    @property
    def x_m(self) -> np.ndarray:
        return self.x[:, 0]

    @property
    def vx_mps(self) -> np.ndarray:
        return self.x[:, 1]

    @property
    def ax_mps2(self) -> np.ndarray:
        return self.x[:, 2]

    @property
    def y_m(self) -> np.ndarray:
        return self.x[:, 3]

    @property
    def vy_mps(self) -> np.ndarray:
        return self.x[:, 4]

    @property
    def ay_mps2(self) -> np.ndarray:
        return self.x[:, 5]

    @property
    def lat_deg(self) -> np.ndarray:
        return self.geodetic[0]

    @property
    def lon_deg(self) -> np.ndarray:
        return self.geodetic[1]

    @cached_property
    def geodetic(self) -> tuple[np.ndarray, np.ndarray]:
        """(lat_deg, lon_deg) of every track, computed once for the message and the safety nets."""
        if not len(self):
            return np.empty(0), np.empty(0)
        return self.names.plane.to_geodetic(self.x[:, 0], self.x[:, 3])

    def to_message(self) -> dict[str, Any]:
        """The TrackBatch message (wire.Track fields). Built column by column and zipped
        into dicts in C loops: a per-track Python body would cost several times more."""
        n = len(self)
        x = self.x
        lat, lon = self.geodetic
        masks = self.sources.tolist()
        mode_s = self.mode_s.tolist()
        cols = (
            self.track_id.tolist(),
            repeat(self.t_s, n) if self.t_track_s is None else self.t_track_s.tolist(),
            _STATUS_NAMES[self.status].tolist(),
            lat.tolist(),
            lon.tolist(),
            x[:, 0].tolist(),
            x[:, 3].tolist(),
            _nil_nan(x[:, 1]),
            _nil_nan(x[:, 4]),
            _nil_nan(self.fl),
            self.cov_xy.tolist(),
            self.names.sources(masks),
            [None if m < 0 else m for m in self.mode3a.tolist()],
            self.names.mode_s(mode_s),
            self.updates.tolist(),
            self.age_s.tolist(),
            _nil_nan(self.vrate_fpm),
            _nil_nan(x[:, 2]),
            _nil_nan(x[:, 5]),
            repeat(None, n) if self.manoeuvre_prob is None else np.round(self.manoeuvre_prob, 4).tolist(),
        )
        tracks = [dict(zip(TRACK_KEYS, row)) for row in zip(*cols)]
        return {
            "v": 1,
            "t": self.t_s,
            "period": self.period,
            "tracks": tracks,
            "ended": self.ended.tolist(),
            **self._stamp(),
        }

    def to_msgpack(self) -> bytes:
        """The TrackBatch message msgpack-encoded: the bytes of ``msgpack.packb(self.to_message(),
        use_bin_type=True)``, built from the columns (wire_columns.MapRows) without a Python
        object per value. Below ``PACK_FROM_COLUMNS_MIN_TRACKS`` tracks, or with a column of an
        unexpected dtype, through the dict, which is as fast there or the definition."""
        n = len(self)
        if n < PACK_FROM_COLUMNS_MIN_TRACKS or not self._packable():
            return bytes(msgpack.packb(self.to_message(), use_bin_type=True))
        x = self.x
        lat, lon = self.geodetic
        rows = MapRows(n).raw(_TRACK_MAP_HEADER)
        rows.key("track_id").integers(self.track_id)
        if self.t_track_s is None:
            rows.key("t").raw(msgpack.packb(self.t_s))
        else:
            rows.key("t").float64(self.t_track_s)
        rows.key("status").table(self.status, _STATUS_PACKED)
        rows.key("lat_deg").float64(lat).key("lon_deg").float64(lon)
        rows.key("x_m").float64(x[:, 0]).key("y_m").float64(x[:, 3])
        # NaN velocity (one update: none yet, TrackTable.velocity_known) and acceleration are nil, as in to_message
        rows.key("vx_mps").float64(x[:, 1], nil=np.isnan(x[:, 1]))
        rows.key("vy_mps").float64(x[:, 4], nil=np.isnan(x[:, 4]))
        # as the filter has it, not rounded: a safety-nets process judges exactly what the
        # engine's columns hold (rounded to 0.01 FL, a figure of the demo's alerts moved 0.4 ft)
        rows.key("fl").float64(self.fl, nil=np.isnan(self.fl))
        cov = self.cov_xy
        rows.key("cov_xy").raw(b"\x93").float64(cov[:, 0]).float64(cov[:, 1]).float64(cov[:, 2])
        masks, inverse = np.unique(self.sources, return_inverse=True)
        rows.key("sources").table(inverse.reshape(n), self.names.packed_sources(masks.tolist()))
        rows.key("mode3a").integers(self.mode3a, nil=self.mode3a < 0)
        rows.key("mode_s")
        if int(self.mode_s.max(initial=-1)) < 1 << 24:  # 6 hex digits (or none): as mode_s_to_str spells them
            _mode_s_strings(rows, self.mode_s)
        else:
            addresses, inverse = np.unique(self.mode_s, return_inverse=True)
            names = self.names.mode_s(addresses.tolist())
            rows.table(inverse.reshape(n), [msgpack.packb(a) for a in names])
        rows.key("updates").integers(self.updates)
        rows.key("age_s").float64(self.age_s)
        rows.key("vrate_fpm").float64(self.vrate_fpm, nil=np.isnan(self.vrate_fpm))
        rows.key("ax_mps2").float64(x[:, 2], nil=np.isnan(x[:, 2]))
        rows.key("ay_mps2").float64(x[:, 5], nil=np.isnan(x[:, 5]))
        rows.key("manoeuvre_prob")
        if self.manoeuvre_prob is None:
            rows.raw(b"\xc0")
        else:
            rows.float64(np.round(self.manoeuvre_prob, 4))
        head = b"".join(
            [
                map_header(5 + len(self._stamp())),
                msgpack.packb("v"),
                msgpack.packb(1),
                msgpack.packb("t"),
                msgpack.packb(self.t_s),
                msgpack.packb("period"),
                msgpack.packb(self.period),
                msgpack.packb("tracks"),
                array_header(n),
            ]
        )
        tail = bytes(msgpack.packb("ended")) + bytes(msgpack.packb(self.ended.tolist()))
        for key, value in self._stamp().items():
            tail += bytes(msgpack.packb(key)) + bytes(msgpack.packb(value))
        return head + rows.tobytes() + tail

    def _packable(self) -> bool:
        """Columns of the dtypes to_message turns into Python floats and ints."""
        floats = [self.x, self.cov_xy, self.fl, self.vrate_fpm, self.age_s, *self.geodetic]
        if self.manoeuvre_prob is not None:
            floats.append(self.manoeuvre_prob)
        if self.t_track_s is not None:
            floats.append(self.t_track_s)
        ints = (self.track_id, self.status, self.mode3a, self.mode_s, self.updates)
        return (
            all(a.dtype.kind == "f" for a in floats)
            and all(a.dtype.kind == "i" for a in ints)
            and self.sources.dtype.kind in "iu"
            and self.cov_xy.shape == (len(self), 3)
        )

    @classmethod
    def from_message(cls, message: Any, plane: SystemPlane, radar_ids: Sequence[str] | None = None) -> TrackColumns:
        """Columns from a received TrackBatch (dict or ``wire.TrackBatch``) or a list of wire Tracks.

        For a consumer of the tracks topic (a stand-alone safety-nets process, a display):
        positions, lat/lon, levels and rates are taken from the message as sent, not
        recomputed. Absent optional fields read as unknown (NaN; −1 for Mode S and 3/A; zero
        acceleration). ``radar_ids`` orders the ``sources`` bits (default: the ids in the
        order the message names them). A list of tracks has no period (−1) or ended ids.

        ``safety_eligible`` is status == confirmed, the rule received tracks have always had;
        the engine's own columns leave it None, so the safety nets also judge its coasting
        tracks. The two differ on coasting tracks only.
        """
        if isinstance(message, dict) and "tracks" in message:
            tracks, batch = list(message["tracks"]), message
        elif hasattr(message, "tracks"):
            tracks, batch = list(message.tracks), message.model_dump()
        else:
            tracks, batch = list(message), None

        def get(tr: Any, name: str, default: Any = None) -> Any:
            v = tr.get(name, default) if isinstance(tr, dict) else getattr(tr, name, default)
            return default if v is None else v

        n = len(tracks)

        def col(name: str, default: float = math.nan) -> np.ndarray:
            return np.fromiter((float(get(t, name, default)) for t in tracks), float, n)

        def int_col(name: str, parse: Any = int) -> np.ndarray:
            return np.fromiter((-1 if get(t, name) is None else parse(get(t, name)) for t in tracks), np.int64, n)

        ids = (
            list(radar_ids)
            if radar_ids is not None
            else list(dict.fromkeys(r for t in tracks for r in get(t, "sources", ())))
        )
        if len(ids) > 64:
            raise ValueError("at most 64 radars (sources are a 64-bit mask)")
        bit = {rid: 1 << b for b, rid in enumerate(ids)}
        status_names = [get(t, "status") for t in tracks]
        cov = np.array([get(t, "cov_xy", (math.nan,) * 3) for t in tracks], float).reshape(n, 3)
        t_first = float(get(tracks[0], "t", math.nan)) if tracks else math.nan
        t_batch = float(batch["t"]) if batch is not None else t_first
        t_track = col("t", t_batch)
        columns = cls(
            period=int(batch["period"]) if batch is not None else -1,
            t_s=t_batch,
            track_id=np.fromiter((int(get(t, "track_id")) for t in tracks), np.int64, n),
            status=np.fromiter((_STATUS_CODES.get(s, TENTATIVE) for s in status_names), np.int8, n),
            x=np.column_stack(
                [col("x_m"), col("vx_mps"), col("ax_mps2", 0.0), col("y_m"), col("vy_mps"), col("ay_mps2", 0.0)]
            ).reshape(n, 6),
            cov_xy=cov,
            fl=col("fl"),
            vrate_fpm=col("vrate_fpm"),
            sources=np.fromiter((sum(bit[r] for r in get(t, "sources", ())) for t in tracks), np.uint64, n),
            mode3a=int_col("mode3a"),
            mode_s=int_col("mode_s", lambda v: int(v, 16)),
            updates=np.fromiter((int(get(t, "updates", 0)) for t in tracks), np.int64, n),
            age_s=col("age_s"),
            ended=np.asarray(batch.get("ended", []) if batch is not None else [], dtype=np.int64),
            names=RadarNames(ids, plane),
            safety_eligible=np.fromiter((s == "confirmed" for s in status_names), bool, n),
            manoeuvre_prob=col("manoeuvre_prob") if any(get(t, "manoeuvre_prob") is not None for t in tracks) else None,
            t_track_s=None if bool(np.all(t_track == t_batch)) else t_track,
            epoch=batch.get("epoch") if batch is not None else None,
            instance=batch.get("instance") if batch is not None else None,
        )
        no_v = np.isnan(columns.x[:, 1])  # no velocity yet: no acceleration either
        columns.x[no_v, 2] = columns.x[no_v, 5] = math.nan
        # positions on the earth as the sender computed them (the cached_property's slot)
        columns.__dict__["geodetic"] = (col("lat_deg"), col("lon_deg"))
        return columns


def _nil_nan(a: np.ndarray) -> list[float | None]:
    """The column as Python floats, None for NaN (not known, or not yet)."""
    values = a.tolist()
    return [None if v != v else v for v in values] if np.isnan(a).any() else values


# wire.Track fields in the order TrackColumns.to_message builds them
TRACK_KEYS = (
    "track_id",
    "t",
    "status",
    "lat_deg",
    "lon_deg",
    "x_m",
    "y_m",
    "vx_mps",
    "vy_mps",
    "fl",
    "cov_xy",
    "sources",
    "mode3a",
    "mode_s",
    "updates",
    "age_s",
    "vrate_fpm",
    "ax_mps2",
    "ay_mps2",
    "manoeuvre_prob",
)

_STATUS_NAMES = np.array(STATUS_NAMES, dtype=object)
_STATUS_CODES = {name: code for code, name in enumerate(STATUS_NAMES)}
_STATUS_PACKED = [msgpack.packb(name) for name in STATUS_NAMES]
_TRACK_MAP_HEADER = map_header(len(TRACK_KEYS))
#: below this many tracks a TrackBatch is packed through its dicts (as fast there)
PACK_FROM_COLUMNS_MIN_TRACKS = 150
_HEX_DIGITS = np.frombuffer(b"0123456789ABCDEF", np.uint8)
_NIBBLE_SHIFTS = np.array([20, 16, 12, 8, 4, 0], np.int64)


def _mode_s_strings(rows: MapRows, mode_s: np.ndarray) -> None:
    """Addresses below 2**24 as the 6-digit upper-case fixstr mode_s_to_str gives; −1 None."""
    nil = mode_s < 0
    block = np.empty((len(mode_s), 7), np.uint8)
    block[:, 0] = 0xA6
    block[:, 1:] = _HEX_DIGITS[(np.where(nil, 0, mode_s)[:, None] >> _NIBBLE_SHIFTS) & 0xF]
    block[nil, 0] = 0xC0
    rows.block(block, np.where(nil, 1, 7))


class RadarNames:
    """Shared, bounded caches of the strings a TrackBatch repeats: the source radar id
    lists per bit mask and the Mode S address strings."""

    def __init__(self, radar_ids: list[str], plane: SystemPlane):
        self.radar_ids = radar_ids
        self.plane = plane
        self._sources: dict[int, list[str]] = {}
        self._sources_packed: dict[int, bytes] = {}
        self._mode_s: dict[int, str | None] = {}

    def sources(self, masks: list[int]) -> list[list[str]]:
        cache, names = self._sources, self.radar_ids
        for mask in set(masks).difference(cache):
            cache[mask] = [names[b] for b in range(len(names)) if mask >> b & 1]
        return [cache[m] for m in masks]

    def packed_sources(self, masks: list[int]) -> list[bytes]:
        """The msgpack bytes of each mask's list of radar ids."""
        cache = self._sources_packed
        for mask in set(masks).difference(cache):
            cache[mask] = msgpack.packb(self.sources([mask])[0])
        return [cache[m] for m in masks]

    def mode_s(self, addresses: list[int]) -> list[str | None]:
        cache = self._mode_s
        if len(cache) > 100_000:  # addresses of long-gone aircraft are forgotten
            cache.clear()
        for m in set(addresses).difference(cache):
            cache[m] = mode_s_to_str(m)
        return [cache[m] for m in addresses]


@dataclass
class ConvertedPlots:
    """A closing period's plots after the gate, in the system plane."""

    t_s: np.ndarray
    x_m: np.ndarray
    y_m: np.ndarray
    cov_m2: np.ndarray  # (n, 2, 2)
    radar: np.ndarray
    mode_s: np.ndarray
    mode3a: np.ndarray
    fl: np.ndarray
    # as converted: slant range and azimuth after the registration's correction, the
    # altitude used (Mode C, or the picked track's; NaN for the assumed height)
    range_m: np.ndarray
    azimuth_deg: np.ndarray
    altitude_m: np.ndarray
    # Mode S BDS 5,0 roll angle, degrees (PlotChunk.roll_deg), NaN none
    roll_deg: np.ndarray
    # Mode S BDS 5,0 ground speed (m/s) and true track angle (degrees), NaN none
    # (PlotChunk.ground_speed_mps, .track_angle_deg)
    ground_speed_mps: np.ndarray | None = None
    track_angle_deg: np.ndarray | None = None
    # (n, 2, 2) the unknown height's part of a plot converted without any height
    # (geo.unknown_height.unknown_height_plots), zero for the others; not in cov_m2
    height_cov_m2: np.ndarray | None = None
    # Mode S BDS 6,0 magnetic heading (degrees) and indicated airspeed (m/s), NaN none
    # (PlotChunk.magnetic_heading_deg, .indicated_airspeed_mps); after height_cov_m2, which
    # is passed by position
    magnetic_heading_deg: np.ndarray | None = None
    indicated_airspeed_mps: np.ndarray | None = None

    def __len__(self) -> int:
        return int(self.t_s.shape[0])

    @cached_property
    def xy_m(self) -> np.ndarray:
        """(n, 2) positions in the system plane."""
        return np.stack([self.x_m, self.y_m], axis=1)


@dataclass
class ClusterMeasurements:
    """One fused measurement per cluster of a period (rows = clusters, Shu eq. 5-6).

    ``track_row`` is the track-table row of the cluster's track, −1 for a new target;
    ``valid`` is False for a track cluster that ended up with no plot.
    """

    track_row: np.ndarray
    valid: np.ndarray
    t_s: np.ndarray  # the mean time of the cluster's plots: the measurement's time
    z_m: np.ndarray  # (K, 2) fused position
    R_m2: np.ndarray  # (K, 2, 2) its covariance
    fl: np.ndarray  # mean Mode C flight level of the cluster's plots, NaN none
    mode_s: np.ndarray  # int64, -1 none
    mode3a: np.ndarray  # int64, -1 none
    revisit_s: np.ndarray  # shortest rotation period among the cluster's radars
    sources: np.ndarray  # uint64 bit mask of the cluster's radars
    # mean Mode S roll angle (BDS 5,0) of the cluster's plots that carry one, degrees, NaN
    # none: evidence of the IMM's mode (imm.IMMFilter.roll_log_likelihoods)
    roll_deg: np.ndarray | None = None
    # (K, 2) the aircraft's own velocity in the system plane, m/s, the mean of the cluster's
    # Mode S BDS 5,0 reports (ground speed and true track angle), NaN none; (K,) how long
    # before the cluster's time it held, s (the reports' age and the plots' times):
    # imm.IMMFilter.velocity_update_rows
    dap_v_mps: np.ndarray | None = None
    dap_age_s: np.ndarray | None = None
    # (K, 2) the aircraft's air vector in the system plane, m/s, the mean of the cluster's
    # Mode S BDS 6,0 reports (true heading, true airspeed), NaN none; (K,) its age as
    # dap_age_s: engine._air_velocity_and_wind adds the track's wind
    air_v_mps: np.ndarray | None = None
    air_age_s: np.ndarray | None = None
    # (K, 2, 2) for a cluster of plots without any height, the unknown height's part of
    # its error (not in R_m2; the track's covariance floor), zero for the others
    height_cov_m2: np.ndarray | None = None
    # (K,) bool: a track cluster whose every plot joined by its Mode S address alone, far
    # beyond every model's gate (engine._hold_far)
    far: np.ndarray | None = None
    # (K,) time, (K, 2), (K, 2, 2): a measurement held from an earlier scan that the update
    # re-initiates the track from (two-point, Shu §4) with this one; NaN time: none
    t0_s: np.ndarray | None = None
    z0_m: np.ndarray | None = None
    R0_m2: np.ndarray | None = None
    # the fused position's sensitivity to each radar's biases, F = S^-1 sum_i W_i J_i
    # (registration.ClusterSensitivity: sparse over the radars), and (K,) whether every plot
    # of the cluster has Mode C: the two-stage registration's (registration.py;
    # engine._bias_sensitivity), None with it off
    bias_sens: ClusterSensitivity | None = None
    all_heights: np.ndarray | None = None


@dataclass
class PeriodOutput:
    """What one closed period produced: every track as columns, and alerts.

    ``track_batch`` is the TrackBatch message (a wire-contract dict), built from the
    columns on first use: that is the I/O side's work (the daemon encodes it on its
    processing thread right after the period, before handing it to its publishing
    thread), not the engine's, and ``processing_s``
    does not include it. ``radar-fusion bench`` reports both figures.
    """

    period: int
    t_s: float
    track_columns: TrackColumns
    alerts: list[dict[str, Any]] = field(default_factory=list)
    processing_s: float = 0.0
    n_plots: int = 0

    @cached_property
    def track_batch(self) -> dict[str, Any]:
        return self.track_columns.to_message()

    @cached_property
    def track_batch_bytes(self) -> bytes:
        """The TrackBatch msgpack-encoded, from the columns (the same bytes as packing
        ``track_batch``); what the daemon publishes."""
        return self.track_columns.to_msgpack()


@dataclass
class Prediction:
    """Every track's state predicted to the period's reference time (step ``predict``)."""

    x: np.ndarray  # (N, 6) Singer state
    # (N, 6, 6); with the IMM only the blocks that association, fusion and output read, NaN
    # elsewhere: position and velocity (imm.IMMFilter.predict_gate), and for the updated
    # tracks the x-y block (Engine._predict_changed)
    P: np.ndarray
    alt_x: np.ndarray  # (N, 2) [FL, FL/s]
    alt_P: np.ndarray  # (N, 2, 2)
    # filter = "imm": each model's predicted position (N, M, 2) and its covariance (N, M, 2, 2)
    gate_xy: np.ndarray | None = None
    gate_cov: np.ndarray | None = None

    def select(self, keep: np.ndarray) -> Prediction:
        """The rows ``keep`` (a mask or indices) of the state, without the gates."""
        return Prediction(self.x[keep], self.P[keep], self.alt_x[keep], self.alt_P[keep])
