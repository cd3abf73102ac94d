"""Per-period buffering of plots in event time (DESIGN.md §2).

Period k covers the event times [k·period_s, (k+1)·period_s) (UTC epoch seconds), so the
period grid does not depend on when the daemon started or how fast a recording is
replayed. A period closes when every *live* radar has swept past its end: its watermark
(the newest plot or status time received from it) less its own lateness (how far behind
its watermark its plots have been seen to arrive, at most ``allowed_lateness_s``) has
reached the end (watermarks.py). A radar that falls silent stops holding periods open.
Plots for an already closed period are refused as late (counted by the caller).

No clock is read here: the closing decision is a function of the event times received,
which is why a replay at 50× gives the same periods, and so the same tracks, as at 1×.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from .columns import PlotChunk
from .watermarks import Watermarks


@dataclass
class PeriodBuffer:
    period_s: float
    allowed_lateness_s: float
    radar_timeout_s: float
    n_radars: int
    max_plots_per_radar: int = 200_000
    lateness_memory_s: float = 600.0
    marks: Watermarks = field(init=False)
    next_period: int | None = field(init=False, default=None)  # index of the oldest open period
    _chunks: list[PlotChunk] = field(init=False, default_factory=list)
    _buffered: int = field(init=False, default=0)
    _per_radar: NDArray[np.int64] = field(init=False)
    _min_t_s: float = field(init=False, default=math.inf)  # earliest buffered plot time

    def __post_init__(self) -> None:
        self.marks = Watermarks(self.n_radars, self.allowed_lateness_s, self.radar_timeout_s, self.lateness_memory_s)
        self._per_radar = np.zeros(self.n_radars, np.int64)

    # ------------------------------------------------------------------ input
    @property
    def closed_until_s(self) -> float:
        """Event time before which every period is closed (plots earlier are late)."""
        return -math.inf if self.next_period is None else self.next_period * self.period_s

    @property
    def buffered_plots(self) -> int:
        return self._buffered

    def room(self, radar: int) -> int:
        """How many more plots of ``radar`` may be buffered (bounded memory per radar)."""
        return int(self.max_plots_per_radar - self._per_radar[radar])

    @property
    def watermark_s(self) -> NDArray[np.float64]:
        """Each radar's newest event time (-inf: nothing yet)."""
        return self.marks.watermark_s

    @property
    def lateness_s(self) -> NDArray[np.float64]:
        """How long each radar's plots are waited for after it has reported a later time."""
        return self.marks.lateness_s

    def advance_watermark(self, radar: int, t_s: float) -> None:
        self.marks.advance(radar, t_s)

    def arrived(self, radar: int, t_min_s: float) -> None:
        """A batch of ``radar``'s plots arrived, its earliest detected at ``t_min_s``
        (accepted or not, before the watermark moves): the radar's lateness learns from it."""
        self.marks.arrived(radar, t_min_s)

    def add(self, chunk: PlotChunk, radar: int, t_min_s: float) -> None:
        """Buffer one radar's plots that the caller has checked are not late and fit
        (:meth:`room`); ``t_min_s`` is their earliest time."""
        n = len(chunk)
        if n == 0:
            return
        if self.next_period is None:
            self.next_period = int(math.floor(t_min_s / self.period_s))
        self._chunks.append(chunk)
        self._buffered += n
        self._per_radar[radar] += n
        self._min_t_s = min(self._min_t_s, t_min_s)

    # ----------------------------------------------------------------- output
    def live_mask(self) -> NDArray[np.bool_]:
        return self.marks.live_mask()

    def closable_until_s(self) -> float:
        """Every period ending at or before this event time may close now
        (:meth:`Watermarks.closable_until_s`)."""
        return self.marks.closable_until_s()

    def pop_period(self, force: bool = False) -> tuple[int, float, PlotChunk] | None:
        """Close the oldest open period if the watermarks allow (or ``force``).

        Returns (period index, period end time = its reference time, its plots), or None.
        Empty stretches with nothing buffered are skipped in one step when there is no
        track to coast, which the caller signals by ``force`` being False and calling
        :meth:`skip_empty_to_data`.
        """
        if self.next_period is None:
            return None
        end_s = (self.next_period + 1) * self.period_s
        if not force and end_s > self.closable_until_s():
            return None
        k = self.next_period
        plots = PlotChunk.empty()
        if self._chunks and self._min_t_s < end_s:
            allp = PlotChunk.concatenate(self._chunks)
            now = allp.t_s < end_s
            plots = allp.select(now)
            rest = allp.select(~now)
            self._chunks = [rest] if len(rest) else []
            self._buffered = len(rest)
            self._per_radar = np.bincount(rest.radar, minlength=self.n_radars)
            self._min_t_s = float(rest.t_s.min()) if len(rest) else math.inf
        self.next_period = k + 1
        return k, end_s, plots

    def discard_before(self, period: int) -> int:
        """Make ``period`` the oldest open one: the periods before it count as closed, their
        buffered plots are dropped (a standby applying its active's state, which closed
        them; a restart from state). Returns the plots dropped."""
        dropped = 0
        start_s = period * self.period_s
        if self._chunks and self._min_t_s < start_s:
            allp = PlotChunk.concatenate(self._chunks)
            keep = allp.t_s >= start_s
            rest = allp.select(keep)
            dropped = len(allp) - len(rest)
            self._chunks = [rest] if len(rest) else []
            self._buffered = len(rest)
            self._per_radar = np.bincount(rest.radar, minlength=self.n_radars)
            self._min_t_s = float(rest.t_s.min()) if len(rest) else math.inf
        self.next_period = period
        return dropped

    def skip_empty_to_data(self) -> None:
        """Jump over periods that hold no plot (used when no track needs coasting): to
        the first buffered plot, or with nothing buffered as far as the watermarks allow
        (so a watermark that jumps far ahead does not close empty periods one by one)."""
        if self.next_period is None:
            return
        if self._chunks:
            first = int(math.floor(self._min_t_s / self.period_s))
        else:
            until_s = self.closable_until_s()
            if not math.isfinite(until_s):
                return
            first = int(math.floor(until_s / self.period_s))
        self.next_period = max(self.next_period, first)
