"""Per-period buffering of plots in event time, with a watermark per radar (DESIGN.md §2).

Period k covers the event times [k·period_s, (k+1)·period_s) (UTC epoch seconds), so the
period grid does not depend on when the daemon started or how fast a recording is
replayed. A period closes when every *live* radar's watermark (the newest plot or status
time received from it) has passed the period's end plus ``allowed_lateness_s``. A radar
whose watermark lags the newest watermark of all radars by more than
``radar_timeout_s`` is not live: a radar that falls silent stops holding periods open.
Plots for an already closed period are refused as late (counted by the caller).

No clock is read here: the closing decision is a function of the event times received,
which is why a replay at 50× gives the same periods, and so the same tracks, as at 1×.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

# Columns a buffered plot carries (all numpy arrays of one length).
PLOT_COLUMNS = ("t_s", "x_m", "y_m", "cov_m2", "radar", "mode_s", "mode3a", "fl", "track_no")


@dataclass
class PlotChunk:
    """Converted plots (system plane) of one ingested batch, as columns."""

    t_s: np.ndarray
    x_m: np.ndarray
    y_m: np.ndarray
    cov_m2: np.ndarray  # (n, 2, 2)
    radar: np.ndarray  # radar index, int
    mode_s: np.ndarray  # int64, -1 none
    mode3a: np.ndarray  # int64, -1 none
    fl: np.ndarray  # float, NaN none
    track_no: np.ndarray  # int64, -1 none

    def __len__(self) -> int:
        return int(self.t_s.shape[0])

    @staticmethod
    def concatenate(chunks: list["PlotChunk"]) -> "PlotChunk":
        if not chunks:
            return PlotChunk.empty()
        return PlotChunk(*(np.concatenate([getattr(c, name) for c in chunks]) for name in PLOT_COLUMNS))

    @staticmethod
    def empty() -> "PlotChunk":
        return PlotChunk(
            np.empty(0), np.empty(0), np.empty(0), np.empty((0, 2, 2)), np.empty(0, np.int64),
            np.empty(0, np.int64), np.empty(0, np.int64), np.empty(0), np.empty(0, np.int64),
        )

    def select(self, mask: np.ndarray) -> "PlotChunk":
        return PlotChunk(*(getattr(self, name)[mask] for name in PLOT_COLUMNS))


@dataclass
class PeriodBuffer:
    period_s: float
    allowed_lateness_s: float
    radar_timeout_s: float
    n_radars: int
    watermark_s: np.ndarray = field(init=False)
    next_period: int | None = field(init=False, default=None)  # index of the oldest open period
    _chunks: list[PlotChunk] = field(init=False, default_factory=list)
    _buffered: int = field(init=False, default=0)

    def __post_init__(self) -> None:
        self.watermark_s = np.full(self.n_radars, -math.inf)

    # ------------------------------------------------------------------ input
    @property
    def closed_until_s(self) -> float:
        """Event time before which every period is closed (plots earlier are late)."""
        return -math.inf if self.next_period is None else self.next_period * self.period_s

    @property
    def buffered_plots(self) -> int:
        return self._buffered

    def advance_watermark(self, radar: int, t_s: float) -> None:
        if t_s > self.watermark_s[radar]:
            self.watermark_s[radar] = t_s

    def add(self, chunk: PlotChunk) -> None:
        """Buffer plots that the caller has already checked are not late."""
        if len(chunk) == 0:
            return
        if self.next_period is None:
            self.next_period = int(math.floor(float(chunk.t_s.min()) / self.period_s))
        self._chunks.append(chunk)
        self._buffered += len(chunk)

    # ----------------------------------------------------------------- output
    def live_mask(self) -> np.ndarray:
        newest = self.watermark_s.max()
        return np.isfinite(self.watermark_s) & (self.watermark_s >= newest - self.radar_timeout_s)

    def closable_until_s(self) -> float:
        """Every period ending at or before this event time may close now."""
        live = self.live_mask()
        if not live.any():
            return -math.inf
        return float(self.watermark_s[live].min()) - self.allowed_lateness_s

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
        if self._chunks:
            allp = PlotChunk.concatenate(self._chunks)
            now = allp.t_s < end_s
            plots = allp.select(now)
            rest = allp.select(~now)
            self._chunks = [rest] if len(rest) else []
            self._buffered = len(rest)
        self.next_period = k + 1
        return k, end_s, plots

    def skip_empty_to_data(self) -> None:
        """Jump over periods that hold no plot (used when no track needs coasting)."""
        if self.next_period is None or not self._chunks:
            return
        first = min(float(c.t_s.min()) for c in self._chunks)
        self.next_period = max(self.next_period, int(math.floor(first / self.period_s)))
