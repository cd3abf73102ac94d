"""Admission: what comes in from each radar, checked before it is buffered (no I/O).

Per message, cheap and constant per batch (the expensive per-plot work waits for the
period to close, engine.py):

* unknown radar, duplicate sequence numbers (a resent or doubled message), sequence gaps
  and out-of-order batches (counted, not refused: the period buffer orders by time), a
  front-end that numbers its batches from the start again (counted, followed);
* plots beyond the radar's instrumented range, late plots (their period already closed),
  plots too far in the future of the other radars (a clock jump, a fast clock or a forged
  time: refused for as long as the others keep time), a per-radar buffer limit;
* every refusal counted by reason, in total and per radar, for the health key;
* :class:`ClockCheck`: each radar's clock against the other radars', in event time.
"""

from __future__ import annotations

import math
import statistics
from collections import Counter, deque
from dataclasses import dataclass, field

import numpy as np

from ..wire import DecodedPlots, RadarStatus
from .columns import PlotChunk
from .period_buffer import PeriodBuffer

#: consecutive batches of a radar refused whole as too far in the future after which its
#: new time base is accepted (a radar back from an outage longer than the future limit),
#: provided no other radar's time moved on meanwhile (Admission._may_relock)
FUTURE_RELOCK_BATCHES = 8
#: batches in a row numbered again below the last one, each one more than the one before
#: and with newer plots, that show a radar's front-end restarted its numbering
#: (Admission._seq_restarted)
SEQ_RESTART_BATCHES = 3
#: the most batches counted as lost between two numbers (a day at 100 batches a second):
#: a larger jump is a numbering started anew, or a damaged number (2^63 - 1 once added
#: 9.2e18 to seq_gaps)
MAX_SEQ_GAP = 10_000_000


@dataclass
class RadarState:
    """What admission keeps of one radar (its figures go to health ``radars.<id>``)."""

    last_seq: int | None = None
    recent_seqs: deque[int] = field(default_factory=lambda: deque(maxlen=4096))
    recent_set: set[int] = field(default_factory=set)
    plots: int = 0
    batches: int = 0
    seq_gaps: int = 0
    out_of_order: int = 0
    rejected: Counter[str] = field(default_factory=Counter)
    rotation_period_s: float | None = None
    wild: int = 0
    future_streak: int = 0  # consecutive batches refused whole as plot_future
    moved_at_streak: list[int] = field(default_factory=list)  # every radar's ``moved`` when the streak began
    first_moved_s: float = math.nan  # its watermark when it first moved on (how long it has kept time)
    streak_first_t_s: float = math.nan  # the streak's first and newest refused times,
    streak_last_t_s: float = math.nan  # and whether they never went back
    streak_in_order: bool = True
    moved: int = 0  # messages of this radar that moved its watermark on
    seq_restarts: int = 0  # the front-end numbered its batches from the start again
    restart_streak: int = 0  # batches in a row that look like a restart's (Admission._seq_restarted)
    restart_last_seq: int = 0


class Admission:
    """The checks above, for the radars of one configuration, into one period buffer.

    ``counters`` and ``rejected`` are the engine's counters (shared, not copied).
    """

    def __init__(
        self,
        radar_ids: list[str],
        max_range_m: np.ndarray,
        buffer: PeriodBuffer,
        future_margin_s: float,
        counters: Counter[str],
        rejected: Counter[str],
    ):
        self.radar_ids = radar_ids
        self.radar_index = {rid: i for i, rid in enumerate(radar_ids)}
        self.max_range_m = max_range_m
        self.buffer = buffer
        self.future_margin_s = future_margin_s
        self.counters = counters
        self.rejected = rejected
        self.radars = [RadarState() for _ in radar_ids]
        self.moved = 0  # messages of any radar that moved its watermark on
        # the newest watermark of all radars when each radar's own last moved on: how long
        # ago, in event time, it last kept time (_future_limit_s)
        self.moved_at_newest_s = [-math.inf] * len(radar_ids)

    def reject(self, reason: str, n: int = 1, radar_id: str | None = None) -> None:
        """Count ``n`` rejections (also those the codec made before the engine saw them)."""
        if n <= 0:
            return
        self.rejected[reason] += n
        if radar_id in self.radar_index:
            self.radars[self.radar_index[radar_id]].rejected[reason] += n

    def admit_status(self, status: RadarStatus) -> None:
        """A north marker, sector crossing or heartbeat: it moves the radar's watermark."""
        i = self.radar_index.get(status.radar_id)
        if i is None:
            self.reject("unknown_radar")
            return
        radar = self.radars[i]
        if status.t > self._future_limit_s(i):
            if not self._may_relock(i):
                self.reject("status_future", radar_id=status.radar_id)
                self._future_refused(i, status.t)
                return
            self.counters["radar_time_relocks"] += 1
        radar.future_streak = 0
        self.counters["status_messages"] += 1
        if status.rotation_period_s is not None:
            radar.rotation_period_s = status.rotation_period_s
        self._advance(i, status.t)

    def _seq_restarted(self, radar: RadarState, batch: DecodedPlots, i: int) -> bool:
        """Whether ``batch``, whose number this radar used recently, shows that its
        front-end restarted and numbers from the start again: the ``SEQ_RESTART_BATCHES``th
        batch in a row numbered below the last one, each numbered one more than the one
        before, whose plots are all newer than anything the radar sent. A copy's are not
        (its original moved the watermark at least to its earliest plot, or was refused
        whole), and damaged or forged messages with used numbers are not taken for a
        restart (the fuzz's, numbers drawn from those used, took a run of three for one
        when any increase would do). The batches before it in the run are refused as
        duplicates."""
        fresh = (
            radar.last_seq is not None
            and batch.seq < radar.last_seq
            and len(batch) > 0
            and float(batch.t_s.min()) > self.buffer.watermark_s[i]
        )
        if not fresh:
            radar.restart_streak = 0
            return False
        if radar.restart_streak and batch.seq != radar.restart_last_seq + 1:
            radar.restart_streak = 0
        radar.restart_streak += 1
        radar.restart_last_seq = batch.seq
        return radar.restart_streak >= SEQ_RESTART_BATCHES

    def _advance(self, i: int, t_s: float) -> None:
        """Move radar ``i``'s watermark to ``t_s`` (if later), counting that it moved."""
        if t_s > self.buffer.watermark_s[i]:
            self.moved += 1
            radar = self.radars[i]
            radar.moved += 1
            if radar.moved == 1:
                radar.first_moved_s = t_s
            self.buffer.advance_watermark(i, t_s)
            self.moved_at_newest_s[i] = max(self.buffer.watermark_s.tolist())

    def _future_refused(self, i: int, t_s: float) -> None:
        """A message of radar ``i`` stamped ``t_s`` refused whole as too far in the future."""
        radar = self.radars[i]
        if radar.future_streak == 0:
            radar.moved_at_streak = [r.moved for r in self.radars]
            radar.streak_first_t_s, radar.streak_in_order = t_s, True
        else:
            radar.streak_in_order &= t_s >= radar.streak_last_t_s
        radar.streak_last_t_s = t_s
        radar.future_streak += 1

    def _may_relock(self, i: int) -> bool:
        """Whether radar ``i``'s time, refused as too far in the future, is now taken as its
        new time base: after ``FUTURE_RELOCK_BATCHES`` refusals in a row, and only if the
        radars refused as ahead outnumber those that kept time meanwhile (moved on, and had
        for ``radar_timeout_s`` of their own time before). A radar back from a long outage
        alone, every radar's time ahead of a restored state, or the right clocks against a
        wrong one that happened to send first after a start, are followed; one radar ahead
        of others that keep time (a clock jump, a forged time) is refused for as long as
        it stays ahead. Followed, it would lead every period and turn the others' good plots
        late (and a state saved then would carry its time). Two radars that disagree keep
        the one that kept time. The refused times must also run on, as a clock does:
        repeats of one time (a forged or stuck stamp) are not followed."""
        radar = self.radars[i]
        if not (
            radar.future_streak >= FUTURE_RELOCK_BATCHES
            and radar.streak_in_order
            and radar.streak_last_t_s > radar.streak_first_t_s
        ):
            return False
        wm: list[float] = self.buffer.watermark_s.tolist()
        settled_s = self.buffer.radar_timeout_s
        kept_time = sum(
            1
            for j, (r, was) in enumerate(zip(self.radars, radar.moved_at_streak, strict=True))
            if j != i and r.moved > was and wm[j] - r.first_moved_s >= settled_s
        )
        ahead = sum(1 for r in self.radars if r.future_streak > 0)
        return kept_time == 0 or ahead > kept_time

    def _future_limit_s(self, i: int) -> float:
        """Latest plausible event time from radar ``i``; later is refused as
        ``plot_future``. A clock jump or a forged time must not push a watermark ahead:
        beyond ``radar_timeout_s`` past the others it would make them all look silent,
        close every period on this radar alone and turn their good plots late.

        The limit is the margin min(max_future_s, radar_timeout_s) past the newest
        watermark of the *other* radars that keep time: live, and moved on within half the
        margin of this radar's own time (reckoned on the newest watermark of all when they
        last moved). A radar's time advances by about a rotation per rotation, and one back
        from an outage is in step with them again. Only when no other radar keeps time (all
        silent, or this radar alone) is it the newest watermark of all, its own included:
        measured from its own, a radar could walk ahead by the margin at each batch until
        the others were no longer live and their plots late; measured from a radar that
        has fallen silent, the others' time could not pass it. A radar whose time stays
        ahead is re-locked after ``FUTURE_RELOCK_BATCHES`` batches if nothing else moves on
        (:meth:`_may_relock`). Not covered: a sender that steps its own time ahead, within
        the margin each time, in a burst of batches while no other radar sends.
        """
        wm: list[float] = self.buffer.watermark_s.tolist()  # asked per message: floats beat numpy calls
        newest = max(wm)
        if not math.isfinite(newest):
            return math.inf
        live_from_s = newest - self.buffer.radar_timeout_s
        recent_from_s = wm[i] - 0.5 * self.future_margin_s
        moved_at = self.moved_at_newest_s
        base = max(
            (w for j, w in enumerate(wm) if j != i and w >= live_from_s and moved_at[j] >= recent_from_s),
            default=newest,
        )
        return base + self.future_margin_s

    def admit_plots(self, batch: DecodedPlots) -> int:
        """Check one radar's batch and buffer what passes; returns the plots accepted."""
        self.counters["batches_received"] += 1
        for reason, n in batch.rejected.items():
            self.reject(reason, n, batch.radar_id)
        i = self.radar_index.get(batch.radar_id)
        if i is None:
            self.reject("unknown_radar", 1)
            return 0
        radar = self.radars[i]
        if batch.seq in radar.recent_set:
            if not self._seq_restarted(radar, batch, i):
                self.reject("duplicate", 1, batch.radar_id)
                return 0
            radar.seq_restarts += 1
            self.counters["seq_restarts"] += 1
            radar.last_seq = None
            radar.recent_seqs.clear()
            radar.recent_set.clear()
        radar.restart_streak = 0
        if len(radar.recent_seqs) == radar.recent_seqs.maxlen:
            radar.recent_set.discard(radar.recent_seqs[0])
        radar.recent_seqs.append(batch.seq)
        radar.recent_set.add(batch.seq)
        window = radar.recent_seqs.maxlen or 0
        if radar.last_seq is None or batch.seq > radar.last_seq:
            if radar.last_seq is not None and batch.seq > radar.last_seq + 1:
                gap = batch.seq - radar.last_seq - 1
                if gap <= MAX_SEQ_GAP:  # batches lost on the way (an outage of the link: hours of them)
                    radar.seq_gaps += gap
                else:  # a jump, not lost batches: a front-end numbering anew (or a damaged number)
                    radar.seq_restarts += 1
                    self.counters["seq_restarts"] += 1
            radar.last_seq = batch.seq
        elif batch.seq < radar.last_seq - window:
            # far behind the last number, and not one of the recent ones: the numbering
            # started again (after a jump far ahead, a damaged number, its batches would
            # all count as out of order)
            radar.seq_restarts += 1
            self.counters["seq_restarts"] += 1
            radar.last_seq = batch.seq
        else:
            radar.out_of_order += 1
            self.counters["batches_out_of_order"] += 1
        radar.batches += 1
        n_in = len(batch)
        if n_in == 0:
            return 0
        self.counters["plots_received"] += n_in
        buf = self.buffer
        t_s, range_m = batch.t_s, batch.range_m
        t_min_s, t_max_s = float(t_s.min()), float(t_s.max())
        buf.arrived(i, t_min_s)  # how far behind the radar's own watermark (its lateness)
        closed_s, future_s = buf.closed_until_s, self._future_limit_s(i)
        if not math.isfinite(buf.watermark_s[i]):  # a first batch: also against its own start
            future_s = min(future_s, t_min_s + self.future_margin_s)
        if t_max_s > future_s and self._may_relock(i):
            # This radar's time has stayed ahead, consistently, and no other radar's moved
            # on: it came back alone after an outage (or its clock was set right); follow
            # it from this batch on.
            future_s = math.inf
            radar.future_streak = 0
            self.counters["radar_time_relocks"] += 1
        if t_min_s >= closed_s and t_max_s <= future_s and float(range_m.max()) <= self.max_range_m[i]:
            idx: slice | np.ndarray = slice(None)  # the usual case: the whole batch is good (no copies)
            n_ok = n_in
            radar.future_streak = 0
        else:
            keep = range_m <= self.max_range_m[i]
            self.reject("plot_beyond_max_range", n_in - int(keep.sum()), batch.radar_id)
            late = t_s < closed_s
            self.reject("plot_late", int((late & keep).sum()), batch.radar_id)
            keep &= ~late
            future = t_s > future_s
            self.reject("plot_future", int((future & keep).sum()), batch.radar_id)
            keep &= ~future
            idx = np.flatnonzero(keep)
            n_ok = int(np.count_nonzero(keep))
            if n_ok == 0 and future.any():
                self._future_refused(i, t_min_s)
            else:
                radar.future_streak = 0
            if n_ok == 0:
                return 0
            t_min_s, t_max_s = float(t_s[idx].min()), float(t_s[idx].max())
        room = buf.room(i)
        if n_ok > room:
            # Bounded memory: a radar far ahead of the others (or flooding) may not fill
            # the buffer without limit. The earliest plots are kept.
            self.reject("buffer_full", n_ok - max(room, 0), batch.radar_id)
            self._advance(i, t_max_s)  # valid plots: the radar's time has moved on
            if room <= 0:
                return 0
            idx = (np.arange(n_in) if isinstance(idx, slice) else idx)[np.argsort(t_s[idx], kind="stable")[:room]]
            n_ok = room
            t_min_s, t_max_s = float(t_s[idx].min()), float(t_s[idx].max())
        buf.add(
            PlotChunk(
                t_s[idx],
                range_m[idx],
                batch.azimuth_deg[idx],
                batch.fl[idx],
                np.full(n_ok, i, np.int64),
                batch.mode_s[idx],
                batch.mode3a[idx],
                batch.track_no[idx],
                batch.roll_deg[idx],
                batch.ground_speed_mps[idx],
                batch.track_angle_deg[idx],
                batch.magnetic_heading_deg[idx],
                batch.indicated_airspeed_mps[idx],
            ),
            i,
            t_min_s,
        )
        self._advance(i, t_max_s)
        radar.plots += n_ok
        self.counters["plots_accepted"] += n_ok
        return n_ok


class ClockCheck:
    """Each radar's clock against the other radars', in event time only (no wall clock,
    so a replay at any speed gives the same estimates).

    When a message of radar i arrives with time t (its newest plot, or its status time),
    each other radar j that has sent something since i's previous message gives a sample
    s_ij = t − w_j, w_j being j's watermark. With true clocks and time-ordered delivery,
    s_ij is a fraction of a batch interval; clock offsets δ add δ_i − δ_j. The pair
    offset D_ij = (median s_ij − median s_ji) / 2 cancels the lag common to both
    directions, and radar i's offset is the median of {0} ∪ {D_ij over j}: with three or
    more radars one wrong clock is blamed on its own radar; with two, the offset is split
    between them. A transport delay of one radar's feed shows the same way as its clock
    running behind. A silent radar gives no samples (its watermark does not move).
    """

    def __init__(self, n_radars: int, window: int = 64, min_samples: int = 8):
        self.n = n_radars
        self.min_samples = min_samples
        self._samples: list[list[deque[float]]] = [
            [deque(maxlen=window) for _ in range(n_radars)] for _ in range(n_radars)
        ]
        # the watermarks of the other radars at each radar's previous message; +inf on the
        # diagonal, so that a radar never samples itself
        self._seen_wm_s = np.full((n_radars, n_radars), -np.inf)
        np.fill_diagonal(self._seen_wm_s, np.inf)
        self._not_self = ~np.eye(n_radars, dtype=bool)

    def observe(self, radar: int, t_s: float, watermark_s: np.ndarray) -> None:
        """A message of ``radar`` stamped ``t_s``; ``watermark_s``: every radar's watermark before it."""
        seen = self._seen_wm_s[radar]  # a view: updated in place
        samples = self._samples[radar]
        # per message, over a few radars: plain floats cost a third of numpy's calls
        for j, (w_j, seen_j) in enumerate(zip(watermark_s.tolist(), seen.tolist())):
            if w_j > seen_j:
                samples[j].append(t_s - w_j)
                seen[j] = w_j

    def offsets_s(self) -> list[float | None]:
        """Estimated clock offset of each radar in seconds (None: not enough data yet)."""
        med = np.full((self.n, self.n), np.nan)
        for i in range(self.n):
            for j in range(self.n):
                if len(self._samples[i][j]) >= self.min_samples:
                    # the same value as np.median (the middle one, or the two middle ones' sum
                    # halved), a tenth of its cost on a few dozen floats: every health message
                    # asks for n² of them, 900 at 30 radars
                    med[i, j] = statistics.median(self._samples[i][j])
        pair = (med - med.T) / 2.0
        out: list[float | None] = []
        for i in range(self.n):
            d = pair[i][self._not_self[i] & np.isfinite(pair[i])]
            out.append(float(np.median(np.concatenate([[0.0], d]))) if d.size else None)
        return out
