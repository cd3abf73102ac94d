"""System tracks: their state arrays and their life cycle (Shu 2007 §2, the three cases).

All tracks live in one :class:`TrackTable` of numpy arrays (N×6 Singer states, N×6×6
covariances, N×2 altitude states, identities, counters); every operation below works on
all tracks at once.

Life cycle
----------
* Initiation (Shu §2 case 1 and 3): a cluster that no track claims starts a *tentative*
  track holding that one fused measurement (position, no velocity yet). Its predicted
  covariance carries a wide velocity prior so that its gate covers any aircraft speed.
* Second update: the two-point initiation of Shu §4 (x from the two fused measurements,
  P0 as printed, or by default with the one-point state's velocity prior kept: ``[tracking]
  two_point_prior``) replaces the one-point state; later updates are Kalman updates
  (Shu eq. 7-11).
* Confirmation (M of N): a tentative track with ``confirm_updates`` updates within
  ``confirm_window_s`` of its first plot becomes *confirmed*; one that fails to do so
  ends. A track whose update of this period has plots of ``confirm_radars`` radars, or a
  Mode S address, is confirmed at once (issue 15).
* Coasting: a confirmed track that missed ``coast_after_scans`` scans (of its own
  revisit time) is *coasting* (predicted, not measured); an update confirms it again.
* Deletion: a tentative track that missed ``delete_tentative_after_scans`` scans, or a
  confirmed/coasting one that missed ``delete_after_scans``, ends; its id is reported
  in the batch's ``ended`` list and never reused.
* Contributing radars (主辅批): each update records the bit mask of radars whose plots
  formed the cluster, published as the track's ``sources``.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import NDArray
from pydantic import BaseModel, ConfigDict, Field

from ..geo.units import FT_PER_FL
from .association import is_identity_code
from .registration import N_BIAS

TENTATIVE, CONFIRMED, COASTING = 0, 1, 2
STATUS_NAMES = ("tentative", "confirmed", "coasting")


class LifeCycle(BaseModel):
    """Life-cycle rules: the ``[life_cycle]`` section of the configuration.

    Silence is measured in scans of the track's own revisit time (the shortest rotation
    period among the radars of its latest update), so a track seen by a 4 s radar and one
    seen only by a 12 s radar tolerate the same number of missed scans; a fixed time in
    seconds may override each rule.
    """

    model_config = ConfigDict(frozen=True, extra="forbid", allow_inf_nan=False)

    confirm_updates: int = Field(
        3,
        ge=2,
        description="Updates (M of M-of-N) that confirm a tentative track. Default 3: one update is any plot, two "
        "give the first velocity (two-point initiation), the third is the first that the velocity predicted.",
    )
    confirm_window_s: float = Field(
        40.0,
        gt=0,
        description="... within this time from its first plot (the N of M-of-N), s. Default 40 s: three updates "
        "of the slowest (12 s) radar with one scan missed; a tentative track that takes longer ends.",
    )
    confirm_radars: int = Field(
        2,
        ge=0,
        description="A tentative track is confirmed at once when this many radars agree on it in one period "
        "(their plots form one cluster); 0 = off. Default 2: two radars' clutter hardly ever coincides, while an "
        "aircraft seen by two radars is real (issue 15: a track was shown only after three periods, 8-12 s, where "
        "a plot-at-a-time tracker confirms from three plots of three radars within one rotation). They also need a "
        "transponder reply (Mode S or 3/A) on the track: primary clutter of two radars coincided at a track's first "
        "update in 2 of 16 primary-high runs, and at its second in one more (shown 16 s); a track of primary plots "
        "alone is confirmed by M-of-N",
    )
    confirm_mode_s: bool = Field(
        True,
        description="A tentative track is confirmed at once when its plots carry a Mode S address: the address is "
        "the transponder's reply, clutter has none",
    )
    confirm_agreed_updates: int = Field(
        1,
        ge=1,
        description="... from this many updates on. Default 1: confirmed in the period that starts it (issue 15 "
        "item 5), shown where and when it was measured with its velocity nil until the second update, the "
        "two-point initiation (Shu §4), gives it one (or, with two radars' plots, the aircraft's own BDS 5,0 "
        "velocity at once). On the bench's 50x3 (120 s) the first period then shows "
        "the aircraft two radars or an address agree on, instead of none: GOSPA over the run 713 -> 384 m, "
        "completeness 96.6 -> 100 %. 2 waits for the velocity, as before",
    )
    coast_after_scans: float = Field(
        1.5,
        gt=0,
        description="Missed scans before a confirmed track is shown coasting. Default 1.5: one scan missed is "
        "common (Pd 0.9); half a scan more absorbs the jitter of plot times within a scan.",
    )
    delete_tentative_after_scans: float = Field(
        2.5,
        gt=0,
        description="Missed scans that end a tentative track. Default 2.5: clutter rarely repeats at one place, "
        "and a real aircraft with two misses in a row is picked up again within a few scans.",
    )
    delete_after_scans: float = Field(
        6.5,
        gt=0,
        description="Missed scans that end a confirmed or coasting track. Default 6.5: a run of 5 rejected wild "
        "plots (the live gate re-locks at the 6th) must not end a track.",
    )
    coast_after_s: float | None = Field(None, gt=0, description="A fixed coasting time, s, instead of scans.")
    delete_tentative_after_s: float | None = Field(
        None, gt=0, description="A fixed time, s, instead of scans, that ends a tentative track."
    )
    delete_after_s: float | None = Field(
        None, gt=0, description="A fixed time, s, instead of scans, that ends a confirmed or coasting track."
    )
    duplicate_code_radius_m: float = Field(
        20_000.0,
        ge=0,
        description="A tentative track without a Mode S address that only one radar has seen is not confirmed "
        "while a confirmed or coasting track within this distance carries its Mode 3/A code (not an emergency or "
        "conspicuity code, association.NON_IDENTITY_MODE3A): one radar's run of wild plots with one constant "
        "error (a reflection) of an SSR-only aircraft forms a consistent track of its own, kilometres beside the "
        "aircraft's (issue 15 item 7: the three false tracks of 4,000x10 with 3 % wild plots, one of them a 3.5 "
        "deg azimuth error at 297 km, 17 km beside). It ends unconfirmed; two radars agreeing on it, or the other "
        "track ending, confirm it as before. Default 20 km: in the clean twins of 1,000x10 and 4,000x10 it "
        "withheld no confirmation. Not withheld where the two tracks' Mode C levels of one period lie more than "
        "duplicate_code_level_gap_ft apart (beside_own_code: a wild plot or a reflection carries its aircraft's "
        "level). 0: off",
    )
    duplicate_code_level_gap_ft: float = Field(
        300.0,
        gt=0,
        description="Mode C levels more than this apart show two tracks of one code to be two aircraft "
        "(duplicate_code_radius_m), ft: a wild plot carries its aircraft's own Mode C. Default 300 ft: three "
        "Mode C steps of 100 ft",
    )
    end_miss_probability: float = Field(
        1e-3,
        ge=0,
        lt=1,
        description="A confirmed or coasting track ends sooner than delete_after_scans once the chance that the "
        "radars which should see it all missed it is below this (issue 15 item 5). The radars that should see it "
        "are those that have seen it and whose max_range_m covers its predicted position; each missed it over "
        "the time since the last update tau with probability (1 - pd)^(tau / rotation_period_s). Default 1e-3: "
        "three missed scans of one radar of pd 0.9, or one scan each of three such radars. A track none of its "
        "radars covers any more (it left) ends too. 0: off (only delete_after_scans)",
    )
    end_min_scans: float = Field(
        3.0,
        gt=0,
        description="... but never before this many scans of its fastest recent radar (revisit_s). Default 3: "
        "a turn, a short fade or a run of two rejected wild plots must not end a track",
    )
    reacquire_within_s: float = Field(
        60.0,
        ge=0,
        description="A track that ended with a Mode S address keeps its id for the address for this long: a new "
        "track on the address, where the aircraft could have flown since its last plot (max_speed_mps), takes the "
        "old id back (counted as tracks_reacquired). Default 60 s, the gap over which issue 15 splits an address's "
        "plots into separate track segments: on the Barcelona hour every extra id left came from an aircraft on "
        "the airport or a low helicopter unseen for 28-52 s (longer than delete_after_scans), and the controller's "
        "label should come back with the aircraft. The display is not held: the track ends as usual. 0: off",
    )


_FIELDS = {
    # name: (trailing shape, dtype, fill)
    "track_id": ((), np.int64, -1),
    "x": ((6,), float, 0.0),  # Singer state at the track's own time t_state_s
    "t_state_s": ((), float, np.nan),
    "P": ((6, 6), float, 0.0),
    "alt_x": ((2,), float, np.nan),
    "alt_P": ((2, 2), float, np.nan),
    "status": ((), np.int8, TENTATIVE),
    "initiated": ((), bool, False),  # has a velocity: two-point initiation, or BDS 5,0 at its start
    "updates": ((), np.int64, 0),
    "first_t_s": ((), float, np.nan),
    "last_update_t_s": ((), float, np.nan),
    "z1_m": ((2,), float, np.nan),  # first fused measurement, for two-point initiation
    "R1_m2": ((2, 2), float, np.nan),
    "t1_s": ((), float, np.nan),  # its time (NaN in a state saved before it was kept)
    "mode_s": ((), np.int64, -1),
    "mode3a": ((), np.int64, -1),
    "sources": ((), np.uint64, 0),  # radars that contributed in the latest period (bit mask)
    "update_sources": ((), np.uint64, 0),  # radars of the latest update (bit mask), kept between updates
    "seen_by": ((), np.uint64, 0),  # radars that ever contributed (bit mask): the ones that should see it
    "revisit_s": ((), float, np.nan),  # shortest rotation among the radars of the latest update
    "nis_avg": ((), float, 2.0),  # fading average of the normalised innovation squared (2 dof)
    "manoeuvre": ((), bool, False),  # manoeuvre detected: process noise raised
    # a measurement far beyond every gate, held for one scan (engine._hold_far): NaN time = none
    "held_z_m": ((2,), float, np.nan),
    "held_R_m2": ((2, 2), float, np.nan),
    "held_t_s": ((), float, np.nan),
    "held_sources": ((), np.uint64, 0),  # its radars (bit mask)
    # the aircraft's reported velocity has refused one of its two-point starts already
    # (engine._too_fast, _hold_far: once per track, so that a misread register costs one scan)
    "start_refuted": ((), bool, False),
    # the Mode S roll reports' check (IMM, engine._update): a fading sum of their log Bayes
    # factors against the positions (imm.Evidence), and whether they are set aside
    "roll_check": ((), float, 0.0),
    "roll_distrust": ((), bool, False),
    # the wind at the aircraft, m/s, in the system plane's x and y, from its BDS 5,0 and 6,0 reports
    # (engine._air_velocity_and_wind), and the time of its latest sample; NaN: none yet
    "wind_mps": ((2,), float, np.nan),
    "wind_t_s": ((), float, np.nan),
    "wind_fl": ((), float, np.nan),  # the track's flight level then
    "wind_air_deg": ((), float, np.nan),  # the direction of its air vector then (plane grid bearing)
    # the latest plot of its Mode S address refused as wild (the live gate, a consensus
    # outlier): the aircraft replied to that radar, which has not missed it (engine._manage)
    "address_seen_t_s": ((), float, np.nan),
}

#: columns added after the state format's first release: a state without them is read
#: with their fill (engine/state.py)
OPTIONAL_FIELDS = (
    "held_z_m", "held_R_m2", "held_t_s", "update_sources", "held_sources", "roll_check", "roll_distrust",
    "wind_mps", "wind_t_s", "wind_fl", "start_refuted", "t1_s", "wind_air_deg", "address_seen_t_s", "bias_sens",
)  # fmt: skip

# The IMM's per-model columns (tracking/imm.py IMMState), with the model axis M after the
# track axis: (N, M, 6), (N, M, 6, 6), (N, M). A table for the single-model Singer filter
# has M = 0, so they cost nothing there; with the IMM (M = 2) x and P hold the combined
# estimate (imm.py eq. 7-8) that association, fusion, output and the safety nets read.
_MODEL_FIELDS = {
    "x_models": ((6,), float, 0.0),
    "P_models": ((6, 6), float, 0.0),
    "mu": ((), float, np.nan),
}


class TrackTable:
    """Column store of all live tracks. Row order is arbitrary; ``track_id`` is stable.

    One array per column of ``_FIELDS`` and ``_MODEL_FIELDS`` (its shape, dtype and fill for new rows), declared
    below so that readers and type checkers see every column.
    """

    track_id: NDArray[np.int64]
    x: NDArray[np.float64]  # (N, 6) Singer state [x, vx, ax, y, vy, ay] at t_state_s, m, m/s, m/s²
    t_state_s: NDArray[np.float64]  # each track's own time: that of its latest update
    P: NDArray[np.float64]  # (N, 6, 6)
    alt_x: NDArray[np.float64]  # (N, 2) [FL, FL/s], NaN before the first Mode C
    alt_P: NDArray[np.float64]  # (N, 2, 2)
    status: NDArray[np.int8]  # TENTATIVE / CONFIRMED / COASTING
    initiated: NDArray[np.bool_]  # has a velocity: two-point initiation, or BDS 5,0 at its start
    updates: NDArray[np.int64]
    first_t_s: NDArray[np.float64]
    last_update_t_s: NDArray[np.float64]  # reference time of the period of the latest update
    z1_m: NDArray[np.float64]  # (N, 2) first fused measurement, for two-point initiation
    R1_m2: NDArray[np.float64]  # (N, 2, 2)
    t1_s: NDArray[np.float64]  # (N,) the time of z1_m
    mode_s: NDArray[np.int64]  # 24-bit address, -1 unknown
    mode3a: NDArray[np.int64]  # -1 unknown
    sources: NDArray[np.uint64]  # radars that contributed in the latest period (bit mask)
    update_sources: NDArray[np.uint64]  # radars of the latest update (bit mask)
    seen_by: NDArray[np.uint64]  # radars that ever contributed (bit mask)
    revisit_s: NDArray[np.float64]  # shortest rotation among the radars of the latest update
    nis_avg: NDArray[np.float64]  # fading average of the normalised innovation squared (2 dof)
    manoeuvre: NDArray[np.bool_]  # manoeuvre detected: process noise raised
    held_z_m: NDArray[np.float64]  # (N, 2) a fused measurement held for one scan (engine._hold_far)
    held_R_m2: NDArray[np.float64]  # (N, 2, 2) its covariance
    held_t_s: NDArray[np.float64]  # its time, NaN: none held
    held_sources: NDArray[np.uint64]  # its radars (bit mask)
    start_refuted: NDArray[np.bool_]  # a report refused one of its starts already (engine._too_fast)
    roll_check: NDArray[np.float64]  # fading sum of the roll reports' log Bayes factors (imm.Evidence)
    roll_distrust: NDArray[np.bool_]  # the track's roll reports are set aside
    wind_mps: NDArray[np.float64]  # (N, 2) the wind at the aircraft (plane x, y), NaN: none yet
    wind_t_s: NDArray[np.float64]  # the time of its latest sample
    wind_fl: NDArray[np.float64]  # the track's flight level then, NaN: unknown
    wind_air_deg: NDArray[np.float64]  # the direction of its air vector then, degrees (grid), NaN: unknown
    address_seen_t_s: NDArray[np.float64]  # its address refused as wild, latest plot time; NaN: none
    x_models: NDArray[np.float64]  # (N, M, 6) each IMM model's state at t_state_s
    P_models: NDArray[np.float64]  # (N, M, 6, 6)
    mu: NDArray[np.float64]  # (N, M) IMM mode probabilities
    bias_sens: NDArray[np.float64]  # (N, 2, R, 4) d(position)/d(radar biases), registration.py

    def __init__(self, n_models: int = 0, n_radars: int = 0) -> None:
        """``n_models``: the IMM's model count M for the per-model columns (0: no IMM).
        ``n_radars``: the radars R of ``bias_sens``, each track's sensitivity to every
        radar's biases (registration.py, its two-stage section; 0: registration off)."""
        self.n = 0
        self.next_id = 1
        self.n_models = n_models
        self.n_radars = n_radars
        self._fields: dict[str, tuple[tuple[int, ...], Any, Any]] = dict(_FIELDS)
        for name, (shape, dtype, fill) in _MODEL_FIELDS.items():
            self._fields[name] = ((n_models,) + shape, dtype, fill)
        # NaN: not known (a state read without it); the engine takes the next update's F
        self._fields["bias_sens"] = ((2, n_radars, N_BIAS), float, np.nan)
        # Each column is the first n rows of a larger buffer, so that appending rows copies
        # nothing most of the time (the model covariances alone are 7 MB at 4,000 tracks);
        # _views holds the arrays handed out, to notice a column replaced from outside.
        self._buffers: dict[str, np.ndarray] = {}
        self._views: dict[str, np.ndarray] = {}
        for name, (shape, dtype, fill) in self._fields.items():
            self._buffers[name] = np.full((0,) + shape, fill, dtype=dtype)
            self._set_view(name)

    def __len__(self) -> int:
        return self.n

    @property
    def velocity_known(self) -> NDArray[np.bool_]:
        """Tracks of two updates or more: the two-point initiation (Shu §4) gave them a
        velocity; and tracks whose first cluster, of two radars' plots, carried the
        aircraft's own velocity (Mode S BDS 5,0, ``initiated`` at once: engine._initiate).
        A track of one update otherwise has only the wide prior."""
        return (self.updates >= 2) | self.initiated

    @property
    def held_alternative(self) -> NDArray[np.bool_]:
        """Tracks whose held measurement is at or before their state's time: a first
        measurement's alternative (merge_same_address), not a far one held after it
        (engine._hold_far). False where none is held."""
        return np.asarray(self.held_t_s <= self.t_state_s)

    @property
    def held_own_radars(self) -> NDArray[np.bool_]:
        """Tracks whose held measurement came from the radars of their state's latest update:
        for an alternative, that radar's previous scan (merge_same_address)."""
        return np.asarray(self.held_sources == self.update_sources)

    def _set_view(self, name: str) -> None:
        view = self._buffers[name][: self.n]
        self._views[name] = view
        setattr(self, name, view)

    def _buffer(self, name: str) -> np.ndarray:
        """The column's buffer; a column assigned from outside (a new array, e.g. a state
        restored or a column reset) becomes the start of a new buffer."""
        col = getattr(self, name)
        if col is not self._views[name]:
            shape, dtype, _ = self._fields[name]
            self._buffers[name] = np.ascontiguousarray(col, dtype=dtype).reshape((self.n,) + shape)
        return self._buffers[name]

    def append(self, count: int) -> slice:
        """Add ``count`` rows with fresh ids (default-filled); returns their slice. The
        buffers grow by doubling: the columns are copied only when one is full."""
        n_new = self.n + count
        for name, (shape, dtype, fill) in self._fields.items():
            buf = self._buffer(name)
            if buf.shape[0] < n_new:
                grown = np.empty((max(n_new, 2 * buf.shape[0], 64),) + shape, dtype=dtype)
                grown[: self.n] = buf[: self.n]
                self._buffers[name] = buf = grown
            buf[self.n : n_new] = fill
        self.n = n_new
        for name in self._fields:
            self._set_view(name)
        rows = slice(n_new - count, n_new)
        self.track_id[rows] = np.arange(self.next_id, self.next_id + count)
        self.next_id += count
        return rows

    def keep(self, mask: np.ndarray) -> None:
        """Keep the rows where ``mask`` is true, in their order, compacting the buffers in
        place: only the rows after the first one dropped move. A column taken before is a
        view of the old rows and sees them move: copy what must outlive this (the engine
        copies a period's ids across the life cycle)."""
        idx = np.flatnonzero(mask)
        if idx.size == self.n:
            return
        first = int(np.flatnonzero(~np.asarray(mask, bool))[0])  # the first row dropped
        tail = idx[first:]  # the rows kept after it, each moving to a lower row
        for name in self._fields:
            buf = self._buffer(name)
            buf[first : idx.size] = buf[tail]  # the right side is a copy: overlapping is safe
        self.n = int(idx.size)
        for name in self._fields:
            self._set_view(name)


# Slices of Singer states x (N,6) = [x, vx, ax, y, vy, ay] and covariances P (N,6,6).
def position_m(x: np.ndarray) -> np.ndarray:
    return x[:, [0, 3]]


def velocity_mps(x: np.ndarray) -> np.ndarray:
    return x[:, [1, 4]]


def cov_pos_m2(P: np.ndarray) -> np.ndarray:
    return P[:, [0, 3]][:, :, [0, 3]]


def cov_vel(P: np.ndarray) -> np.ndarray:
    return P[:, [1, 4]][:, :, [1, 4]]


def radar_count(sources: np.ndarray) -> np.ndarray:
    """Number of radars in each 64-bit ``sources`` mask (population count)."""
    bits = np.unpackbits(np.ascontiguousarray(sources, dtype=np.uint64).view(np.uint8).reshape(-1, 8), axis=1)
    return np.asarray(bits.sum(axis=1), dtype=np.int64)


def apply_life_cycle(
    table: TrackTable,
    t_s: float,
    rules: LifeCycle,
    log_miss_probability: np.ndarray | None = None,
    counters: dict[str, int] | None = None,
) -> np.ndarray:
    """Confirm, coast and end tracks at time ``t_s``; returns the ids of ended tracks.

    ``log_miss_probability`` (N,): ln of the probability that the radars which should see
    each track all missed it since its last update (:func:`log_miss_probability`); with
    it, a confirmed or coasting track also ends when that is below
    ``ln(rules.end_miss_probability)`` and ``rules.end_min_scans`` have passed.
    ``counters``: ``tracks_withheld_beside_code`` grows by the tracks the duplicate-code
    rule kept from confirmation this time (:func:`beside_own_code`; one count per track and
    period), so that health shows a withheld track, which may be a second aircraft."""
    since_update = t_s - table.last_update_t_s
    age = t_s - table.first_t_s
    status = table.status
    revisit = table.revisit_s

    def limit(fixed_s: float | None, scans: float) -> np.ndarray | float:
        return fixed_s if fixed_s is not None else scans * revisit

    confirm = (status == TENTATIVE) & (table.updates >= rules.confirm_updates) & (age <= rules.confirm_window_s)
    # confirmed at once: several radars, or a Mode S address, in the update of this period
    agree = np.zeros(len(table), bool)
    if rules.confirm_radars:
        # two radars' primary clutter can coincide, at a track's first update (primary-high,
        # 16 runs: two one-period clutter tracks confirmed) and at its second (one more, shown
        # 16 s): radars alone confirm only beside a transponder reply (Mode S or 3/A); a
        # track of primary plots alone is confirmed by M-of-N
        by_radars = radar_count(table.sources) >= rules.confirm_radars
        agree |= by_radars & ((table.mode_s >= 0) | (table.mode3a >= 0))
    if rules.confirm_mode_s:
        agree |= table.mode_s >= 0
    confirm |= (status == TENTATIVE) & agree & (since_update <= 0.0) & (table.updates >= rules.confirm_agreed_updates)
    if rules.duplicate_code_radius_m > 0 and confirm.any():
        withheld = beside_own_code(table, confirm, rules.duplicate_code_radius_m, rules.duplicate_code_level_gap_ft)
        confirm &= ~withheld
        if counters is not None:
            counters["tracks_withheld_beside_code"] = counters.get("tracks_withheld_beside_code", 0) + int(
                withheld.sum()
            )
    status[confirm] = CONFIRMED
    recovered = (status == COASTING) & (since_update <= 0.0)
    status[recovered] = CONFIRMED
    status[(status == CONFIRMED) & (since_update > limit(rules.coast_after_s, rules.coast_after_scans))] = COASTING

    end = (
        (status == TENTATIVE)
        & (
            (since_update > limit(rules.delete_tentative_after_s, rules.delete_tentative_after_scans))
            | (age > rules.confirm_window_s)
        )
    ) | ((status != TENTATIVE) & (since_update > limit(rules.delete_after_s, rules.delete_after_scans)))
    if log_miss_probability is not None and rules.end_miss_probability > 0:
        unseen = log_miss_probability <= math.log(rules.end_miss_probability)
        end |= (status != TENTATIVE) & unseen & (since_update > rules.end_min_scans * revisit)
    # A state that is not finite (a numerical fault no input should reach) is ended, not
    # shown: a consumer refuses a batch with one NaN track, and every other track with it.
    broken = ~(np.isfinite(table.x).all(axis=1) & np.isfinite(table.P).all(axis=(1, 2)))
    if broken.any():
        end |= broken
        if counters is not None:
            counters["tracks_ended_not_finite"] = counters.get("tracks_ended_not_finite", 0) + int(broken.sum())
    ended: np.ndarray = table.track_id[end].copy()
    if end.any():
        table.keep(~end)
    return ended


def beside_own_code(table: TrackTable, rows: np.ndarray, radius_m: float, level_gap_ft: float) -> np.ndarray:
    """(N,) bool: the tracks of ``rows`` (a bool mask) without a Mode S address, seen by one
    radar only, whose identity code (Mode 3/A, not in association.NON_IDENTITY_MODE3A) a
    confirmed or coasting track within ``radius_m`` carries (its position at its own time),
    unless their Mode C levels (``alt_x``), both updated in this period, differ by more than
    ``level_gap_ft``: a wild plot or a reflection carries its aircraft's own Mode C, a second
    aircraft of the code at another level is not one. (Both in one scan of the radar is no
    proof: a reflection comes in the same scan as the aircraft's own reply. A second
    aircraft of the code at the same level that one radar alone sees stays unconfirmed.)"""
    out = np.zeros(len(table), bool)
    code = table.mode3a
    cand = np.flatnonzero(rows & (table.mode_s < 0) & is_identity_code(code))
    shown = np.flatnonzero((table.status != TENTATIVE) & (code >= 0))
    cand = cand[np.isin(code[cand], code[shown])]
    if not cand.size:
        return out
    cand = cand[radar_count(table.seen_by[cand]) == 1]
    shown = shown[np.isin(code[shown], code[cand])]
    xy_cand, xy_shown = position_m(table.x[cand]), position_m(table.x[shown])
    for j, i in enumerate(cand):
        other = (code[shown] == code[i]) & (shown != i)
        # levels of one period only: a track not updated holds its last level, and a climbing
        # aircraft's wild run, left behind by a scan, lay 300 ft below its own track (4,000x10)
        apart = np.abs(table.alt_x[shown, 0] - table.alt_x[i, 0]) > level_gap_ft / FT_PER_FL  # NaN: unknown
        other &= ~(apart & (table.sources[shown] != 0) & (table.sources[i] != 0))
        d_m = np.hypot(xy_shown[other, 0] - xy_cand[j, 0], xy_shown[other, 1] - xy_cand[j, 1])
        out[i] = bool((d_m <= radius_m).any())
    return out


def log_miss_probability(
    seen_by: np.ndarray,
    xy_m: np.ndarray,
    last_update_t_s: np.ndarray,
    swept_until_s: np.ndarray,
    site_xy_m: np.ndarray,
    max_range_m: np.ndarray,
    rotation_s: np.ndarray,
    pd: np.ndarray,
) -> np.ndarray:
    """ln P(every radar that should see a track missed it since its last update).

    The radars that should see track i are those in its ``seen_by`` mask (they have
    detected it: a secondary radar does not see an aircraft without transponder, nor a
    radar the aircraft is hidden from) whose instrumented range covers its predicted
    position ``xy_m`` (plane, m; the distance in the plane from the site, an approximation
    of the ground range good to a fraction of a percent inside a few hundred km). Radar r
    has swept the sky until ``swept_until_s[r]`` (its watermark, at most the period's
    time: a radar that fell silent has made no scan since), so since the track's last
    update it made tau_r / T_r scans, tau_r = max(swept_until_r − last_update, 0), each
    missing the aircraft independently with probability 1 − Pd_r:

        ln P = Σ_r (tau_r / T_r) · ln(1 − Pd_r)

    over those radars; −inf when none covers it (the aircraft left their coverage).
    Arrays: seen_by (N,) uint64, xy_m (N, 2), last_update_t_s (N,); per radar
    swept_until_s, site_xy_m (R, 2), max_range_m, rotation_s, pd (R,).
    """
    n, n_radars = seen_by.shape[0], site_xy_m.shape[0]
    bits = (seen_by[:, None] >> np.arange(n_radars, dtype=np.uint64)[None, :]) & np.uint64(1)
    d = xy_m[:, None, :] - site_xy_m[None, :, :]
    covered = np.hypot(d[..., 0], d[..., 1]) <= max_range_m[None, :]
    should = (bits == 1) & covered
    with np.errstate(divide="ignore", invalid="ignore"):
        per_s = np.log1p(-np.asarray(pd, dtype=float)) / rotation_s  # ln(1 − Pd) / T < 0; −inf for Pd = 1
        tau_s = np.clip(np.asarray(swept_until_s, float)[None, :] - last_update_t_s[:, None], 0.0, None)
        tau_s = np.where(np.isfinite(tau_s), tau_s, 0.0)  # a radar never heard from has swept nothing
        out = np.where(should & (tau_s > 0), tau_s * per_s[None, :], 0.0).sum(axis=1)
    out = np.where(should.any(axis=1), out, -np.inf)
    return np.asarray(out if n else np.zeros(0))


#: what a merged track takes from the member that followed the aircraft: its whole state
_STATE_COLUMNS = (
    "x",
    "P",
    "t_state_s",
    "alt_x",
    "alt_P",
    "initiated",
    "last_update_t_s",
    "z1_m",
    "R1_m2",
    "t1_s",
    "mode3a",
    "sources",
    "update_sources",
    "revisit_s",
    "nis_avg",
    "manoeuvre",
    "x_models",
    "P_models",
    "mu",
    "bias_sens",  # the state's sensitivity to the radars' biases (registration.py)
    "held_z_m",  # a measurement held against that state (engine._hold_far)
    "held_R_m2",
    "held_t_s",
    "held_sources",
    "start_refuted",
)


def merge_same_address(
    table: TrackTable, confirm_updates: int, outputs: tuple[np.ndarray, ...] = ()
) -> tuple[np.ndarray, np.ndarray]:
    """Make each group of tracks with one Mode S address one track (issue 15 item 2).

    The survivor keeps the oldest id (its first time, the largest update count) and takes
    the state of the most recently updated member that is itself established
    (``confirm_updates`` updates: the one that followed the aircraft), never a young
    one-point state that would throw away the old track's velocity; when no member is
    established, among those with a velocity (two updates) if any, the one whose latest
    update most radars agreed on, and among those the most recently updated (a wild plot
    is one radar's; a first plot far from the address's later plots, e.g. a wild one, is
    not kept: those plots could not reach it and started the younger tracks). When the
    state kept is a single measurement, the latest other member's of the same period and no
    later than it is held beside it (``held_*``, at or before the state's time) for the next
    measurement to choose from; without one, the latest one-plot member of an earlier period
    from the same radars (that radar's previous scan). When the state kept is an established
    one and a member is newer (a plot of the address beyond the kept track's sanity gate
    started it), its time is the survivor's ``address_seen_t_s``: the address was seen. It is
    confirmed when any member was. The other rows are removed. Rows of ``outputs``
    (arrays row-aligned with the table) are copied the same way but not removed: the
    caller drops them with the returned mask. Returns (keep mask over the table's former
    rows, merged-away ids).
    """
    rows = np.flatnonzero(table.mode_s >= 0)
    order = rows[np.lexsort((table.track_id[rows], table.mode_s[rows]))]  # by address, then oldest id first
    same = table.mode_s[order][1:] == table.mode_s[order][:-1]
    keep = np.ones(len(table), bool)
    if not same.any():
        return keep, np.empty(0, np.int64)
    group_start = np.flatnonzero(np.r_[True, ~same])
    group_end = np.r_[group_start[1:], order.size]
    shared = group_end - group_start > 1
    velocity_known = table.velocity_known  # the groups are disjoint: their merges do not change it
    for a, b in zip(group_start[shared], group_end[shared]):  # over duplicated addresses only
        members = order[a:b]
        oldest = members[0]
        established = members[table.updates[members] >= confirm_updates]
        if established.size:
            newest = established[np.argmax(table.t_state_s[established])]
        else:
            # all young: one with a velocity (two updates) before a one-plot state, then the one
            # most radars agreed on in its latest update, then the latest measurement (a wild
            # plot is one radar's, and the oldest may be a wild first plot). A plot too far for
            # the address's two-update track to have flown there started a one-plot track:
            # that is the wild one (50x3 with 3 % wild plots: kept, it put a track 7 km off).
            with_v = members[velocity_known[members]]
            pool = with_v if with_v.size else members
            votes = radar_count(table.update_sources[pool])  # not this period's: an older member has none
            best = pool[votes == votes.max()]
            newest = best[np.argmax(table.t_state_s[best])]
        alt = None
        seen_t_s = np.fmax.reduce(table.address_seen_t_s[members])
        if established.size:
            # A younger member newer than the kept state: a plot of the address beyond the
            # kept track's sanity gate (association.identity_pairs: farther than the aircraft
            # could have flown) started it. Its plot is dropped with it (a wild plot, or a
            # reflection: held for a pairing, a run of them would pull the track off), but the
            # address was seen: the track's radars have not missed the aircraft
            # (engine._manage's early end; dropped unseen, a wild plot after a gap in cover
            # ended the aircraft's track, shown again 8 s later: 1,000x10, 3 % wild plots).
            newer = members[table.t_state_s[members] > table.t_state_s[newest]]
            if newer.size:
                seen_t_s = np.fmax(seen_t_s, table.t_state_s[newer].max())
        if not established.size and not velocity_known[newest]:
            # One-plot tracks of one address started in one period, each of one cluster:
            # their first measurements contradict each other (else they had been one
            # cluster), and one plot cannot tell which is wild. The latest of the others is
            # held beside the kept one; the aircraft's next measurement chooses between them
            # (engine._choose_first). One of an earlier period only from the kept one's own
            # radars (below): the plots that started the kept one could not reach it. Not one
            # later than the kept one: it
            # had fewer radars (the vote above), and a held measurement later than its
            # track's state is a far one (engine._hold_far).
            others = members[
                (members != newest)
                & (table.first_t_s[members] == table.first_t_s[newest])
                & (table.t_state_s[members] <= table.t_state_s[newest])
            ]
            if not others.size:
                # Else a one-plot member of an earlier period, of the kept one's own radars: one
                # radar's plot and its next scan's that contradict each other, where one is an
                # isolated wild plot (a run of them would have given both the same error). The
                # aircraft's next plot chooses, or pairs with it when too far from the kept one
                # (engine._hold_far): a good first plot and a wild second were lost, and the
                # track flew the wild plot's two-point velocity, 300-400 m/s off, for 10-20 s
                # (issue 15 item 7, 3 % wild plots).
                others = members[
                    (members != newest)
                    & ~velocity_known[members]
                    & (table.t_state_s[members] < table.t_state_s[newest])
                    & (table.update_sources[members] == table.update_sources[newest])
                ]
            if others.size:
                i = others[np.argmax(table.t_state_s[others])]
                alt = (table.z1_m[i].copy(), table.R1_m2[i].copy(), table.t_state_s[i], table.update_sources[i])
        if newest != oldest:
            for name in _STATE_COLUMNS:
                getattr(table, name)[oldest] = getattr(table, name)[newest]
            for column in outputs:
                column[oldest] = column[newest]
        if alt is not None:
            table.held_z_m[oldest], table.held_R_m2[oldest], table.held_t_s[oldest], table.held_sources[oldest] = alt
        table.updates[oldest] = table.updates[members].max()
        table.address_seen_t_s[oldest] = seen_t_s
        table.seen_by[oldest] = np.bitwise_or.reduce(table.seen_by[members])
        table.status[oldest] = CONFIRMED if (table.status[members] != TENTATIVE).any() else TENTATIVE
        keep[members[1:]] = False
    merged: np.ndarray = table.track_id[~keep].copy()
    table.keep(keep)
    return keep, merged


class AddressMemory:
    """The ids of recently ended tracks by Mode S address (``LifeCycle.reacquire_within_s``).

    An ended track's address is remembered with its id, last measured position (plane, m),
    its covariance and time. :meth:`recall` gives a new track on a remembered
    address its old id back when the aircraft could have flown from there
    (association.within_reach at ``max_speed_mps``), and forgets the entry.
    """

    def __init__(self) -> None:
        self._by_address: dict[int, tuple[int, np.ndarray, np.ndarray, float]] = {}

    def __len__(self) -> int:
        return len(self._by_address)

    def remember(
        self,
        ids: np.ndarray,
        mode_s: np.ndarray,
        xy_m: np.ndarray,
        cov_m2: np.ndarray,
        t_s: np.ndarray,
    ) -> None:
        """Ended tracks (row-aligned arrays); those without an address are ignored."""
        for k in np.flatnonzero(np.asarray(mode_s) >= 0):
            self._by_address[int(mode_s[k])] = (
                int(ids[k]),
                xy_m[k].copy(),
                cov_m2[k].copy(),
                float(t_s[k]),
            )

    def entries(self) -> list[tuple[int, int, np.ndarray, np.ndarray, float]]:
        """(address, id, last xy, its covariance, last time) of every entry (engine/state.py)."""
        return [(a, *e) for a, e in self._by_address.items()]

    def clear(self) -> None:
        self._by_address.clear()

    def load(self, entries: list[tuple[int, int, np.ndarray, np.ndarray, float]]) -> None:
        """Add the entries of :meth:`entries` (a restart from state)."""
        for a, track_id, xy, cov, t_s in entries:
            self._by_address[int(a)] = (int(track_id), np.asarray(xy, float), np.asarray(cov, float), float(t_s))

    def forget_older_than(self, t_s: float) -> None:
        """Drop the entries whose last plot is before ``t_s``."""
        for a in [a for a, e in self._by_address.items() if e[3] < t_s]:
            del self._by_address[a]

    def recall(
        self,
        mode_s: np.ndarray,
        xy_m: np.ndarray,
        cov_m2: np.ndarray,
        t_s: np.ndarray,
        max_speed_mps: float,
        within_s: float,
    ) -> np.ndarray:
        """For new tracks (row-aligned arrays): the old id of each, or −1. An entry is
        recalled only when its last plot is at most ``within_s`` before the new track's."""
        from .association import within_reach

        n = np.asarray(mode_s).shape[0]
        ids = np.full(n, -1, np.int64)
        for k in np.flatnonzero(np.asarray(mode_s) >= 0):
            entry = self._by_address.get(int(mode_s[k]))
            if entry is None:
                continue
            old_id, last_xy, last_cov, last_t = entry
            if t_s[k] - last_t > within_s:
                continue
            ok = within_reach(
                xy_m[k : k + 1],
                cov_m2[k : k + 1],
                t_s[k : k + 1],
                last_xy[None],
                last_cov[None],
                np.array([last_t]),
                max_speed_mps,
            )
            if ok[0]:
                ids[k] = old_id
                del self._by_address[int(mode_s[k])]
        return ids
