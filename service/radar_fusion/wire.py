"""Wire contract v1 (DESIGN.md §3): the messages on the Zenoh bus, and their msgpack codec.

Every payload is a msgpack map with snake_case keys, units in the names and ``"v": 1``.
The pydantic models below ARE the contract: ``schemas/*.schema.json`` is generated from
them (``radar-fusion schemas``) and a test fails when the two drift apart.

Decoding never raises on bad input: it returns a :class:`Rejection` with a reason from
:data:`REJECTION_REASONS`, which the daemon counts and shows on the health key.  A plot
batch is validated per plot: one bad plot is rejected (and counted) without spoiling the
good plots of its batch. The daemon validates a batch's plots as columns (wire_columns.py:
these models' rules on numpy arrays, the same verdicts and reasons, a test proves it).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Literal

import msgpack
import numpy as np
from numpy.typing import ArrayLike
from pydantic import BaseModel, ConfigDict, Field, TypeAdapter, ValidationError

WIRE_VERSION = 1

#: Why a message or a plot was refused. Message-level reasons refuse the whole message;
#: plot-level reasons (``plot_*``) refuse one plot of an otherwise good batch.
REJECTION_REASONS = (
    "oversize",  # payload larger than the configured maximum
    "malformed_msgpack",  # not decodable as msgpack
    "schema",  # decodable, but not a message of the expected shape/types
    "version",  # "v" is not a version this daemon speaks
    "unknown_radar",  # radar_id not in the configuration
    "key_mismatch",  # radar_id in the payload differs from the one in the key
    "duplicate",  # a (radar_id, seq) already received
    "plot_schema",  # one plot with missing fields or wrong types
    "plot_non_finite",  # NaN or infinity in a plot
    "plot_out_of_range",  # negative range, azimuth outside [0, 360), FL out of Mode C range, ...
    "plot_beyond_max_range",  # range beyond the radar's configured instrumented range
    "plot_late",  # plot for a period that has already been closed
    "plot_future",  # plot time implausibly far ahead of the radar's watermark
    "buffer_full",  # the radar already has its limit of plots waiting for open periods
    "status_future",  # a radar status time implausibly far ahead of every radar's watermark
    "overload",  # the daemon's input queue was full: the message was dropped unprocessed
    "internal_error",  # processing the message raised (a bug): it was dropped, the daemon went on
)

MODE_S_PATTERN = r"^[0-9A-Fa-f]{6}$"
RADAR_ID_PATTERN = r"^[A-Za-z0-9_.-]{1,32}$"
PLOT_KINDS = ("psr", "ssr", "cmb", "modes")
MAX_PLOTS_PER_BATCH = 20_000
#: the default limit of a plot batch's payload, bytes ([bus] max_payload_bytes): the largest
#: batch the contract allows, every field of every plot filled, is 4.8 MB
MAX_PLOT_BATCH_BYTES = 6 << 20


class _Message(BaseModel):
    # Unknown fields from a newer sender are ignored (forward compatibility), not refused.
    model_config = ConfigDict(extra="ignore", allow_inf_nan=False, frozen=True, strict=True)
    v: Literal[1] = 1


class Plot(BaseModel):
    """One target report of one radar, in the radar's own polar coordinates."""

    # strict: a string "1000" is not a range, a bool is not a code
    model_config = ConfigDict(extra="ignore", allow_inf_nan=False, frozen=True, strict=True)
    t: float = Field(description="UTC epoch seconds of detection", gt=0, lt=1e10)
    range_m: float = Field(description="slant range from the antenna, metres", ge=0, le=2_000_000)
    azimuth_deg: float = Field(description="azimuth from true north, clockwise, degrees", ge=0, lt=360)
    fl: float | None = Field(None, description="Mode C flight level (100 ft units)", ge=-20, le=1300)
    mode3a: int | None = Field(None, description="Mode 3/A code as an integer (octal 0000-7777)", ge=0, le=0o7777)
    mode_s: str | None = Field(None, description="Mode S address, 6 hex digits", pattern=MODE_S_PATTERN)
    track_no: int | None = Field(None, description="the radar's own track number", ge=0, le=2**32 - 1)
    kind: Literal["psr", "ssr", "cmb", "modes"] | None = Field(None, description="report type")
    # v1 extensions: last, so that the fields before them keep their order
    roll_deg: float | None = Field(
        None,
        description="roll angle from Mode S BDS 5,0, degrees, positive right wing down (ICAO Doc 9871 table A-2-80)",
        ge=-90,
        le=90,
    )
    ground_speed_mps: float | None = Field(
        None,
        description="ground speed from Mode S BDS 5,0, m/s (ICAO Doc 9871 table A-2-80)",
        ge=0,
        le=1100,
    )
    track_angle_deg: float | None = Field(
        None,
        description="true track angle from Mode S BDS 5,0, degrees clockwise from true north "
        "(ICAO Doc 9871 table A-2-80)",
        ge=0,
        lt=360,
    )
    magnetic_heading_deg: float | None = Field(
        None,
        description="magnetic heading from Mode S BDS 6,0, degrees clockwise from magnetic north "
        "(ICAO Doc 9871 table A-2-96)",
        ge=0,
        lt=360,
    )
    indicated_airspeed_mps: float | None = Field(
        None,
        description="indicated airspeed from Mode S BDS 6,0, m/s (ICAO Doc 9871 table A-2-96)",
        gt=0,
        le=526.3,
    )


class PlotBatch(_Message):
    """Plots of one radar, published on ``<prefix>/radar/<radar_id>/plots``."""

    radar_id: str = Field(pattern=RADAR_ID_PATTERN)
    seq: int = Field(ge=0, le=2**63 - 1, description="per radar, +1 each message")
    plots: list[Plot] = Field(max_length=MAX_PLOTS_PER_BATCH)


class RadarStatus(_Message):
    """North marker, sector crossing or heartbeat, on ``<prefix>/radar/<radar_id>/status``."""

    radar_id: str = Field(pattern=RADAR_ID_PATTERN)
    t: float = Field(gt=0, lt=1e10, description="UTC epoch seconds")
    kind: Literal["north", "sector", "heartbeat"]
    sector: int | None = Field(None, ge=0, le=255)
    rotation_period_s: float | None = Field(None, gt=0, le=120)


class Track(BaseModel):
    """One system track at the batch's reference time; a track of one update whose velocity
    is not known yet at its measurement time ``t`` with ``vx_mps``/``vy_mps`` nil (a track
    that started with the aircraft's own velocity, Mode S BDS 5,0, has one from its first)."""

    model_config = ConfigDict(extra="ignore", allow_inf_nan=False, frozen=True)
    track_id: int = Field(ge=0)
    t: float = Field(
        description="time of this state, UTC epoch s: the batch's t, or for a track whose velocity is not known "
        "yet the time it was measured (it is not extrapolated)"
    )
    status: Literal["tentative", "confirmed", "coasting"]
    lat_deg: float
    lon_deg: float
    x_m: float = Field(description="system plane, east")
    y_m: float = Field(description="system plane, north")
    vx_mps: float | None = Field(
        description="velocity east; nil while not known (a track of one update: confirmed at once by two radars "
        "or a Mode S address, before a second update gives it a velocity; unless the aircraft's own ground speed "
        "and track, Mode S BDS 5,0, came with plots of two radars at its start)"
    )
    vy_mps: float | None = Field(description="velocity north; nil while not known (see vx_mps)")
    fl: float | None = None
    cov_xy: list[float] = Field(min_length=3, max_length=3, description="[σxx², σxy, σyy²] in m²")
    sources: list[str] = Field(description="radar ids that contributed this period")
    mode3a: int | None = None
    mode_s: str | None = None
    updates: int = Field(ge=0)
    age_s: float = Field(ge=0)
    # v1 extensions (optional for receivers): vertical rate and acceleration, for safety nets.
    vrate_fpm: float | None = Field(None, description="vertical rate, feet per minute")
    ax_mps2: float | None = None
    ay_mps2: float | None = None
    manoeuvre_prob: float | None = Field(
        None,
        ge=0,
        le=1,
        description="probability that the track manoeuvres (the IMM's models other than the quiet one: "
        "turns, speed changes); absent with the single-model Singer filter",
    )


class TrackBatch(_Message):
    """All tracks after one closed period, on ``<prefix>/fusion/tracks``."""

    t: float = Field(description="the period's reference time (its end), UTC epoch seconds")
    period: int = Field(ge=0)
    tracks: list[Track]
    ended: list[int] = Field(default_factory=list, description="track ids that ended in this period")
    # v1 extension (issue 13): a hot-standby pair's active stamps what it publishes
    epoch: int | None = Field(
        None,
        ge=1,
        description="with [redundancy] on: the publishing active's epoch. It grows at every take-over (one "
        "above the highest seen, at least the UTC seconds of the take-over, so also across a restart of the "
        "pair); a consumer drops a message of an epoch lower than the highest it has seen (a stale active)",
    )
    instance: str | None = Field(None, description="with [redundancy] on: the publishing daemon's instance name")


def ids_given_again(
    before: tuple[ArrayLike, ArrayLike] | None, track_id: ArrayLike, age_s: ArrayLike, slack_s: float
) -> bool:
    """Whether the TrackBatch with ``track_id`` and ``age_s`` starts a new tracks stream
    after the batch whose ids and ages were ``before``: at least half of the ids in both
    are younger tracks now (by more than ``slack_s``, the ages' rounding). A daemon that
    restarted without its state hands out ids from 1 again, time moving on, so the open
    alerts and pictures of the old ids belong to other aircraft. Within one stream an id's
    age goes back only for one track at a time: a track that takes over an older one's id
    keeps its own start (an SSR aircraft's wild plot did it; any one id taken for a
    restart ended every open alert). The safety nets (process.py) and the display (feed.py)
    judge a received stream by it."""
    if before is None:
        return False
    _, was, now = np.intersect1d(np.asarray(before[0]), np.asarray(track_id), assume_unique=True, return_indices=True)
    younger = int((np.asarray(age_s, float)[now] < np.asarray(before[1], float)[was] - slack_s).sum())
    return younger > 0 and 2 * younger >= now.size


class Alert(_Message):
    """A safety-net alert, on ``<prefix>/fusion/alerts/<kind>``."""

    kind: Literal["stca", "apw", "msaw"]
    alert_id: int = Field(ge=0)
    t: float
    track_ids: list[int]
    status: Literal["new", "ongoing", "ended"]
    # STCA
    time_to_cpa_s: float | None = None
    min_sep_m: float | None = None
    min_vsep_ft: float | None = None
    # APW
    area_id: str | None = None
    time_to_entry_s: float | None = None
    # MSAW
    time_to_violation_s: float | None = None
    min_alt_ft: float | None = None
    epoch: int | None = Field(None, ge=1, description="with [redundancy] on: the epoch of the TrackBatch judged")


class RadarHealth(BaseModel):
    model_config = ConfigDict(extra="ignore", frozen=True)
    live: bool
    watermark_t: float | None = None
    lateness_s: float | None = Field(
        None,
        description="how long after the radar has reported a later time its plots are still waited for: how far "
        "behind its newest time they have been seen to arrive, at most allowed_lateness_s (v1 extension, issue 16)",
    )
    plots: int = 0
    batches: int = 0
    last_seq: int | None = None
    seq_gaps: int = 0
    seq_restarts: int = Field(
        0,
        description="times the radar's batch numbering started again: numbers used recently with newer plots "
        "(a front-end restart: taken, not refused as duplicates), or a number more than 4,096 behind the last one or "
        "10 million ahead (not counted as out-of-order or lost batches) (v1 extension)",
    )
    rejected: dict[str, int] = Field(default_factory=dict)
    wild: int = Field(0, description="plots dropped by the live wild-plot gate (counted apart from rejections)")
    clock_offset_s: float | None = Field(
        None, description="estimated clock offset against the other radars (event time), seconds; None: too few data"
    )
    clock_suspect: bool = Field(False, description="|clock_offset_s| is above the daemon's limit")
    registration: dict[str, float | bool | None] | None = Field(
        None,
        description="the radar's estimated biases (online registration): range_offset_m, range_gain_ppm, "
        "azimuth_offset_deg, time_offset_s, each with its <name>_sigma and applied_<name> (what the correction "
        "removes of it), plots, applied, applied_share (the share of the estimates the correction removes)",
    )


class SafetyNetsStatus(BaseModel):
    """The daemon's view of its safety nets (``Health.safety_nets``)."""

    model_config = ConfigDict(extra="ignore", frozen=True)
    process: Literal["child", "in_process", "external"] = Field(
        description="child: its own process, supervised by the daemon; in_process: the daemon's processing "
        "thread; external: none in this daemon"
    )
    pid: int | None = Field(None, description="child: its process id")
    running: bool | None = Field(None, description="child: the process runs")
    restarts: int | None = Field(None, description="child: times it was started again after it exited")
    last_exit_code: int | None = None
    health_age_s: float | None = Field(None, description="child: age of its newest health message")


class Health(_Message):
    """Daemon health, on ``<prefix>/fusion/health`` every few seconds."""

    t: float = Field(description="wall-clock UTC epoch seconds when published")
    uptime_s: float
    counters: dict[str, int] = Field(description="received, accepted, periods_closed, tracks, ...")
    rejected: dict[str, int] = Field(description="rejections by reason, all radars")
    radars: dict[str, RadarHealth]
    periods_closed: int
    tracks: int
    processing_ms_p50: float | None = None
    processing_ms_p99: float | None = None
    lag_s: float | None = Field(None, description="wall clock minus the newest closed period's time")
    # v1 extension (issue 16): where the safety nets run, and the child's state
    safety_nets: SafetyNetsStatus | None = None
    # v1 extension (issue 13): the daemon's part in a hot-standby pair
    role: Literal["active", "standby"] | None = Field(
        None, description="active: publishes tracks and alerts; standby: applies the active's state"
    )
    epoch: int | None = Field(None, description="the active's epoch (0 with [redundancy] off)")
    instance: str | None = Field(None, description="this daemon's instance name, <hostname>:<pid> by default")


class SafetyNetsHealth(_Message):
    """Health of a safety-nets process (``radar-fusion safety-nets``), on
    ``<prefix>/fusion/safety_nets/health`` every ``[bus] health_period_s``, and once as it
    subscribes (ready) and as it stops."""

    t: float = Field(description="wall-clock UTC epoch seconds when published")
    uptime_s: float = Field(description="restarts from 0 with the process: its alert ids start again at 1")
    pid: int
    host: str
    counters: dict[str, int] = Field(
        description="batches_received, batches_processed, batches_dropped (queue full: the oldest), "
        "alerts_published, publish_errors, stream_restarts, queue_depth, model_fallbacks, and the safety "
        "nets' own counts as safety_nets_<name> (periods, hits_<kind>, alerts_new_<kind>, ...)"
    )
    rejected: dict[str, int] = Field(
        description="TrackBatches refused, by reason: oversize, malformed_msgpack, version, schema, "
        "out_of_order, stale_epoch (a stale active's, issue 13), internal_error"
    )
    newest_period: int | None = None
    newest_period_t: float | None = None
    lag_s: float | None = Field(None, description="wall clock minus the newest judged period's time")
    active_alerts: int
    alert_latency_ms_p50: float | None = Field(
        None, description="a TrackBatch's arrival to its alerts published, over the last 1,000 batches"
    )
    alert_latency_ms_p99: float | None = None
    processing_ms_p50: float | None = Field(None, description="decoding and judging one TrackBatch")
    processing_ms_p99: float | None = None
    hook_errors: dict[str, int] = Field(default_factory=dict)
    hook_load_errors: dict[str, str] = Field(default_factory=dict)


class FusionState(_Message):
    """The active's track state after a period, on ``<prefix>/fusion/state`` with
    [redundancy] on (and the file ``serve --state-dir`` writes): what a standby applies so
    that it holds the same tracks with the same ids (engine/state.py writes and reads it).
    The arrays are raw little-endian columns, ``[dtype, shape, bytes]``: compact, and
    read without a Python object per track."""

    kind: Literal["radar-fusion-engine-state"]
    radar_ids: list[str] = Field(description="the configuration's radars in order (the sources bits' order)")
    n_models: int = Field(ge=0, description="the IMM's model count, 0 for the Singer filter")
    track_t_s: float | None = Field(description="reference time of the newest closed period, UTC epoch s")
    period_s: float | None = Field(
        None,
        description="the period length the period indices count (v1 extension): a state of another is refused; "
        "without it, one whose next period lies more than an hour from track_t_s",
    )
    next_period: int | None = Field(description="the first period not yet closed")
    period: int | None = Field(None, description="the newest closed period (its TrackBatch's period)")
    next_id: int = Field(ge=1)
    tracks: dict[str, list[Any]] = Field(description="the track table's columns: {name: [dtype, shape, bytes]}")
    address_memory: list[list[Any]] = Field(description="recently ended tracks by Mode S address")
    registration: dict[str, Any] = Field(description="the radar registration estimator's arrays and counts")
    epoch: int | None = Field(None, description="with [redundancy] on: the publishing active's epoch")
    instance: str | None = None


MESSAGE_MODELS: dict[str, type[BaseModel]] = {
    "PlotBatch": PlotBatch,
    "Plot": Plot,
    "RadarStatus": RadarStatus,
    "TrackBatch": TrackBatch,
    "Track": Track,
    "Alert": Alert,
    "Health": Health,
    "SafetyNetsHealth": SafetyNetsHealth,
    "FusionState": FusionState,
}


# --------------------------------------------------------------------------- codec


@dataclass(frozen=True)
class Rejection:
    """A refused message: the reason (one of REJECTION_REASONS) and a human-readable detail."""

    reason: str
    detail: str = ""


KIND_CODES = {None: 0, "psr": 1, "ssr": 2, "cmb": 3, "modes": 4}


@dataclass
class DecodedPlots:
    """The accepted plots of one PlotBatch as columns (what the engine ingests).

    Missing optional values are encoded as NaN (``fl``, ``roll_deg``, ``ground_speed_mps``,
    ``track_angle_deg``, ``magnetic_heading_deg``, ``indicated_airspeed_mps``) or −1
    (``mode3a``, ``mode_s``, ``track_no``); ``mode_s`` is the 24-bit address as an integer.
    ``ground_speed_mps``, ``track_angle_deg`` (BDS 5,0), ``magnetic_heading_deg`` and
    ``indicated_airspeed_mps`` (BDS 6,0) may be left out when made (None: NaN for every plot).
    """

    radar_id: str
    seq: int
    t_s: np.ndarray
    range_m: np.ndarray
    azimuth_deg: np.ndarray
    fl: np.ndarray
    mode3a: np.ndarray
    mode_s: np.ndarray
    track_no: np.ndarray
    kind: np.ndarray
    roll_deg: np.ndarray
    ground_speed_mps: np.ndarray = None  # type: ignore[assignment]
    track_angle_deg: np.ndarray = None  # type: ignore[assignment]
    magnetic_heading_deg: np.ndarray = None  # type: ignore[assignment]
    indicated_airspeed_mps: np.ndarray = None  # type: ignore[assignment]
    rejected: dict[str, int] = field(default_factory=dict)

    def __post_init__(self) -> None:
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


_UNPACK_LIMITS = dict(
    raw=False,
    strict_map_key=True,
    max_str_len=1 << 16,
    max_bin_len=1 << 20,
    max_array_len=MAX_PLOTS_PER_BATCH + 1,
    max_map_len=64,
    max_ext_len=0,
)
_PLOT_LIST = TypeAdapter(list[Plot])


def plot_rejection_reason(err: ValidationError) -> str:
    """Map the model's errors on one plot to a rejection reason: a NaN or an infinity in
    any field first, then a value outside its range or pattern, else ``plot_schema``."""
    for e in err.errors():
        if e["type"] == "finite_number":
            return "plot_non_finite"
    for e in err.errors():
        if e["type"] in (
            "greater_than",
            "greater_than_equal",
            "less_than",
            "less_than_equal",
            "string_pattern_mismatch",
        ):
            return "plot_out_of_range"
    return "plot_schema"


def unpack(payload: bytes, max_bytes: int) -> Any | Rejection:
    """msgpack-decode with size limits; a Rejection instead of an exception."""
    if len(payload) > max_bytes:
        return Rejection("oversize", f"{len(payload)} bytes > {max_bytes}")
    try:
        return msgpack.unpackb(payload, **_UNPACK_LIMITS)
    except Exception as exc:  # msgpack raises several unrelated exception types
        # the exception, where, and the payload's first bytes: enough to tell a sender's bug
        # from bytes damaged on the way (issue 13: one UnicodeDecodeError in 43,913 batches)
        head = bytes(payload[:32]).hex()
        return Rejection("malformed_msgpack", f"{type(exc).__name__}: {exc} [{len(payload)} bytes: {head}]")


def _envelope_check(obj: Any) -> Rejection | None:
    if not isinstance(obj, dict):
        return Rejection("schema", f"expected a map, got {type(obj).__name__}")
    if type(obj.get("v")) is not int or obj.get("v") != WIRE_VERSION:  # not True, not 1.0
        return Rejection("version", f"v={obj.get('v')!r}")
    return None


def _plot_batch_envelope(payload: bytes, max_bytes: int) -> tuple[str, int, list[Any]] | Rejection:
    """The checks of a PlotBatch message as a whole: (radar_id, seq, the plot list) or why not."""
    obj = unpack(payload, max_bytes)
    if isinstance(obj, Rejection):
        return obj
    rej = _envelope_check(obj)
    if rej:
        return rej
    radar_id, seq, plots = obj.get("radar_id"), obj.get("seq"), obj.get("plots")
    try:
        PlotBatch.model_validate({"v": 1, "radar_id": radar_id, "seq": seq, "plots": []})
    except ValidationError as exc:
        return Rejection("schema", exc.errors()[0]["msg"])
    if not isinstance(plots, list):
        return Rejection("schema", "plots is not a list")
    if len(plots) > MAX_PLOTS_PER_BATCH:
        return Rejection("schema", f"more than {MAX_PLOTS_PER_BATCH} plots in one batch")
    return radar_id, seq, plots


#: batches of fewer plots are validated by the model (as fast there: numpy's fixed cost per call)
COLUMNS_FROM_PLOTS = 24


def decode_plot_batch(
    payload: bytes, max_bytes: int = MAX_PLOT_BATCH_BYTES, columns_from: int = COLUMNS_FROM_PLOTS
) -> DecodedPlots | Rejection:
    """Decode and validate a PlotBatch; bad plots are dropped and counted in ``rejected``.

    A well-formed batch is read straight from its bytes (wire_bytes.py); any other, a
    batch of ``columns_from`` plots or more is validated as columns (wire_columns.py: the
    model's rules for the whole batch at once, with the model's reasons), a smaller one by
    the model, as :func:`decode_plot_batch_by_model` does; both give the same result."""
    from .wire_bytes import decode_plot_batch_bytes
    from .wire_columns import validate_plot_columns

    if len(payload) <= max_bytes and (fast := decode_plot_batch_bytes(payload)) is not None:
        return fast  # well-formed: read straight from the bytes (wire_bytes.py)
    env = _plot_batch_envelope(payload, max_bytes)
    if isinstance(env, Rejection):
        return env
    radar_id, seq, plots = env
    if len(plots) < columns_from:
        return _decoded_by_model(radar_id, seq, plots)
    c = validate_plot_columns(plots)
    return DecodedPlots(
        radar_id=radar_id,
        seq=seq,
        t_s=c.t_s,
        range_m=c.range_m,
        azimuth_deg=c.azimuth_deg,
        fl=c.fl,
        mode3a=c.mode3a,
        mode_s=c.mode_s,
        track_no=c.track_no,
        kind=c.kind,
        roll_deg=c.roll_deg,
        ground_speed_mps=c.ground_speed_mps,
        track_angle_deg=c.track_angle_deg,
        magnetic_heading_deg=c.magnetic_heading_deg,
        indicated_airspeed_mps=c.indicated_airspeed_mps,
        rejected=c.rejected,
    )


def validate_plots_by_model(plots: list[Any]) -> tuple[list[Plot], dict[str, int]]:
    """The plots the model accepts, in order, and the rest counted by reason."""
    rejected: dict[str, int] = {}
    try:
        return _PLOT_LIST.validate_python(plots), rejected
    except ValidationError:
        pass
    good = []
    for p in plots:
        try:
            good.append(Plot.model_validate(p))
        except ValidationError as exc:
            reason = plot_rejection_reason(exc)
            rejected[reason] = rejected.get(reason, 0) + 1
    return good, rejected


def decode_plot_batch_by_model(payload: bytes, max_bytes: int = MAX_PLOT_BATCH_BYTES) -> DecodedPlots | Rejection:
    """:func:`decode_plot_batch` with every plot validated by the model (wire.Plot): the
    contract's own reading, the reference for the columnar one (about 3.5 µs a plot)."""
    env = _plot_batch_envelope(payload, max_bytes)
    if isinstance(env, Rejection):
        return env
    return _decoded_by_model(*env)


def _decoded_by_model(radar_id: str, seq: int, plots: list[Any]) -> DecodedPlots:
    good, rejected = validate_plots_by_model(plots)
    n = len(good)
    return DecodedPlots(
        radar_id=radar_id,
        seq=seq,
        t_s=np.fromiter((p.t for p in good), float, n),
        range_m=np.fromiter((p.range_m for p in good), float, n),
        azimuth_deg=np.fromiter((p.azimuth_deg for p in good), float, n),
        fl=np.fromiter((math.nan if p.fl is None else p.fl for p in good), float, n),
        mode3a=np.fromiter((-1 if p.mode3a is None else p.mode3a for p in good), np.int64, n),
        mode_s=np.fromiter((-1 if p.mode_s is None else int(p.mode_s, 16) for p in good), np.int64, n),
        track_no=np.fromiter((-1 if p.track_no is None else p.track_no for p in good), np.int64, n),
        kind=np.fromiter((KIND_CODES[p.kind] for p in good), np.int8, n),
        roll_deg=np.fromiter((math.nan if p.roll_deg is None else p.roll_deg for p in good), float, n),
        ground_speed_mps=np.fromiter(
            (math.nan if p.ground_speed_mps is None else p.ground_speed_mps for p in good), float, n
        ),
        track_angle_deg=np.fromiter(
            (math.nan if p.track_angle_deg is None else p.track_angle_deg for p in good), float, n
        ),
        magnetic_heading_deg=np.fromiter(
            (math.nan if p.magnetic_heading_deg is None else p.magnetic_heading_deg for p in good), float, n
        ),
        indicated_airspeed_mps=np.fromiter(
            (math.nan if p.indicated_airspeed_mps is None else p.indicated_airspeed_mps for p in good), float, n
        ),
        rejected=rejected,
    )


def decode_message(payload: bytes, model: type[BaseModel], max_bytes: int = 1 << 20) -> BaseModel | Rejection:
    """Decode and validate any whole message (RadarStatus, TrackBatch, Alert, Health)."""
    obj = unpack(payload, max_bytes)
    if isinstance(obj, Rejection):
        return obj
    rej = _envelope_check(obj)
    if rej:
        return rej
    try:
        return model.model_validate(obj)
    except ValidationError as exc:
        first = exc.errors()[0]
        return Rejection("schema", f"{'.'.join(map(str, first['loc']))}: {first['msg']}")


def encode(message: BaseModel | dict) -> bytes:
    """msgpack-encode a model (or an already-built dict that follows the contract)."""
    if isinstance(message, BaseModel):
        message = message.model_dump(mode="json")
    return msgpack.packb(message, use_bin_type=True)


def mode_s_to_str(address: int) -> str | None:
    return None if address < 0 else f"{address:06X}"
