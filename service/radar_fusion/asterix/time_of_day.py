"""Time of day (I048/140, I034/030, I062/070: seconds since midnight UTC) -> UTC epoch."""

from __future__ import annotations

import math
from datetime import UTC, date, datetime

from ..geo.units import SECONDS_PER_DAY

#: ASTERIX times of day count 1/128 s (I048/140, I062/070, I063/030)
TOD_LSB_PER_S = 128


def time_of_day_s(t_s: float) -> float:
    """UTC epoch seconds -> the time of day an encoder sends: rounded to its 1/128 s first,
    then wrapped, so that the last 1/256 s of a day is 0.0 of the next (the items allow
    [0, 86400); rounded after the wrap it went out as 86400.0)."""
    ticks = round(t_s * TOD_LSB_PER_S) % (SECONDS_PER_DAY * TOD_LSB_PER_S)
    return ticks / TOD_LSB_PER_S


def _midnight_epoch_s(day: date) -> float:
    return datetime(day.year, day.month, day.day, tzinfo=UTC).timestamp()


class TimeOfDayResolver:
    """Time of day (seconds since midnight UTC) -> UTC epoch seconds.

    Each time of day is placed on the day that puts it nearest (within ±12 h) to a
    reference time:

    * with a ``day`` given, the first report is on that day and each later one is
      placed nearest to the previous resolved time;
    * without a ``day`` but with a per-datagram reference (the pcap timestamp, the UDP
      receive time), nearest to that reference;
    * without either (a raw or .rply file with no ``--date``), the day is today's UTC
      date from the wall clock, then as with a given day.

    Midnight roll-over: a time of day that wraps from 86 399 s to 0 s is more than 12 h
    from the previous time on the same day, so it lands on the next day; a late report
    from just before midnight that arrives after the wrap lands on the previous day.
    Both follow from the nearest-day rule; no state beyond the last resolved time.
    """

    def __init__(self, day: date | None = None):
        self.day = day
        self._last_s: float | None = None

    @staticmethod
    def nearest(tod_s: float, reference_s: float) -> float:
        """The epoch ``midnight + tod_s`` nearest to ``reference_s``."""
        midnight = math.floor(reference_s / SECONDS_PER_DAY) * SECONDS_PER_DAY
        t = midnight + tod_s
        if t - reference_s > SECONDS_PER_DAY / 2:
            t -= SECONDS_PER_DAY
        elif reference_s - t > SECONDS_PER_DAY / 2:
            t += SECONDS_PER_DAY
        return t

    def resolve(self, tod_s: float, reference_epoch_s: float | None = None) -> float:
        if self._last_s is None:
            if self.day is not None:
                t = _midnight_epoch_s(self.day) + tod_s
            elif reference_epoch_s is not None:
                t = self.nearest(tod_s, reference_epoch_s)
            else:
                t = _midnight_epoch_s(datetime.now(UTC).date()) + tod_s
        elif self.day is None and reference_epoch_s is not None:
            t = self.nearest(tod_s, reference_epoch_s)
        else:
            t = self.nearest(tod_s, self._last_s)
        self._last_s = t
        return t
