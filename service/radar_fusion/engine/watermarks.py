"""Each radar's progress in event time, and up to when periods may close (DESIGN.md §2).

A radar's *watermark* is the newest event time received from it: a plot's detection time
or a status message's time (north marker, sector crossing, heartbeat). A front-end sends
its plots sector by sector as the antenna sweeps, so once a radar has reported time w its
later plots are normally no earlier than w: a period ending at or before w has every plot
that radar will send for it.

Normally, not always. Real feeds deliver some plots behind their own radar's watermark: a
plot extractor that sends a sector's plots with times a little out of order (the Barcelona
recording in file order: a third of its plots, by up to 0.21 s), or a sector message
(ASTERIX CAT034) sent as the antenna crosses the boundary, before the plots of the sector
it ends (the Croatian capture: up to 1.9 s). So each radar has its own *lateness*: how far
behind its own watermark its plots have been seen to arrive, the largest such gap within
the last one to two ``memory_s`` of its event time, and never more than ``max_lateness_s``
(``[system] allowed_lateness_s``). A period may close when, for every live radar, its
watermark less its lateness has reached the period's end.

A radar that has always delivered in order is waited for only until it has swept past the
period's end (its next sector message or plots), not that plus a fixed lateness. The cost:
a radar's first plots that arrive further behind its watermark than any before may find
their period already closed; they are refused as late and counted (``plot_late``), and
from then on its lateness covers them. A radar whose plots arrive far out of order is
waited for ``max_lateness_s``, as for every radar before (issue 16 item 5).

A radar whose watermark lags the newest watermark of all radars by more than
``radar_timeout_s`` is not live: a radar that falls silent stops holding periods open.

No clock is read: every figure is a function of the event times received, in the order
each radar sent them, so a replay at any speed closes the same periods with the same plots.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray


@dataclass
class Watermarks:
    """Watermark and lateness of each of ``n_radars`` radars (the module docstring)."""

    n_radars: int
    max_lateness_s: float
    radar_timeout_s: float
    memory_s: float = 600.0
    watermark_s: NDArray[np.float64] = field(init=False)
    lateness_s: NDArray[np.float64] = field(init=False)
    # the largest gap seen in the radar's current window of ``memory_s`` event time, and
    # in the window before it; the window is floor(watermark / memory_s)
    _recent_s: list[float] = field(init=False)
    _previous_s: list[float] = field(init=False)
    _window: list[float] = field(init=False)

    def __post_init__(self) -> None:
        self.watermark_s = np.full(self.n_radars, -math.inf)
        self.lateness_s = np.zeros(self.n_radars)
        self._recent_s = [0.0] * self.n_radars
        self._previous_s = [0.0] * self.n_radars
        self._window = [-math.inf] * self.n_radars

    # ------------------------------------------------------------------ input
    def arrived(self, radar: int, t_min_s: float) -> None:
        """A batch of ``radar``'s plots arrived, its earliest detected at ``t_min_s``: how
        far behind the radar's watermark it came (before the watermark moves with it)."""
        behind_s = float(self.watermark_s[radar]) - t_min_s
        if behind_s > 0.0:
            behind_s = min(behind_s, self.max_lateness_s)
            if behind_s > self._recent_s[radar]:
                self._recent_s[radar] = behind_s
                self.lateness_s[radar] = max(behind_s, self._previous_s[radar])

    def advance(self, radar: int, t_s: float) -> None:
        """``radar`` has reported event time ``t_s`` (a status message, or plots)."""
        if not t_s > self.watermark_s[radar]:
            return
        self.watermark_s[radar] = t_s
        window = math.floor(t_s / self.memory_s)
        last = self._window[radar]
        if window > last:  # a new window: the current one becomes the previous one
            self._previous_s[radar] = self._recent_s[radar] if window == last + 1 else 0.0
            self._recent_s[radar] = 0.0
            self._window[radar] = window
            self.lateness_s[radar] = self._previous_s[radar]

    # ----------------------------------------------------------------- output
    def live_mask(self) -> NDArray[np.bool_]:
        newest = float(self.watermark_s.max())
        return np.isfinite(self.watermark_s) & (self.watermark_s >= newest - self.radar_timeout_s)

    def closable_until_s(self) -> float:
        """Every period ending at or before this event time may close now: the earliest,
        over the live radars (:meth:`live_mask`), of watermark less lateness. Asked after
        every message: over a few radars, plain floats cost a fifth of the numpy calls."""
        w: list[float] = self.watermark_s.tolist()
        newest_s = max(w)
        if not math.isfinite(newest_s):
            return -math.inf
        until_s = math.inf
        for t_s, late_s in zip(w, self.lateness_s.tolist()):
            if t_s >= newest_s - self.radar_timeout_s and t_s - late_s < until_s:
                until_s = t_s - late_s
        return until_s
