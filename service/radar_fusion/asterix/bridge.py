"""ASTERIX -> wire contract (DESIGN.md §3): CAT048 plots and CAT034 markers to bus messages.

:class:`AsterixToWire` maps each SAC/SIC to a configured radar and turns datagrams into
PlotBatch / RadarStatus messages, ready to publish or record (a plot whose I048/250 holds
BDS 5,0 carries the aircraft's roll angle, ``roll_deg``, the IMM's turn evidence, and its
ground speed and true track angle, ``ground_speed_mps`` / ``track_angle_deg``, where the
register has both; one whose I048/250 holds BDS 6,0 its magnetic heading and indicated
airspeed, ``magnetic_heading_deg`` / ``indicated_airspeed_mps``, each where its status bit
is set);
:func:`bds50_reference`
gathers the aircraft's own BDS 5,0 velocity reports of a recording, to check tracks
against.
"""

from __future__ import annotations

from collections import OrderedDict
from collections.abc import Sequence
from dataclasses import dataclass
from datetime import date
from pathlib import Path
from typing import Any

from pydantic import ValidationError

from ..wire import Plot, PlotBatch, RadarStatus, encode
from .bds import bds50_roll_deg, decode_bds50, decode_bds60
from .decode import SectorMessage, TargetReport, decode_datablock
from .files import FileFormat, iter_file
from .framing import DecodeCounters, split_datablocks
from .time_of_day import TimeOfDayResolver


@dataclass(frozen=True)
class WireMessage:
    """One message for the bus: key relative to the prefix, event time, encoded payload."""

    key: str
    t_s: float
    payload: bytes
    message: PlotBatch | RadarStatus


class AsterixToWire:
    """CAT048/CAT034 datagrams -> PlotBatch / RadarStatus messages of the wire contract.

    ``radars`` are the configured radars (``Settings.radars``); only those with both
    ``sac`` and ``sic`` receive data. The reports of one datagram (a raw file: one data
    block) become one PlotBatch per radar, ``seq`` +1 per radar from 0; a CAT034 block
    flushes the plots gathered before it, so the messages keep the datagram's order.

    Radar feeds are often sent twice (dual LAN, A/B channels): a data block identical,
    byte for byte, to one of the last ``dedup_window`` blocks is counted as
    ``duplicate_block`` and skipped. Two genuine blocks cannot be identical, as each
    carries its time of day.
    """

    def __init__(self, radars: Sequence[Any], day: date | None = None, dedup_window: int = 1024):
        self.radar_by_sacsic: dict[tuple[int, int], str] = {
            (r.sac, r.sic): r.id for r in radars if r.sac is not None and r.sic is not None
        }
        self.clock = TimeOfDayResolver(day)
        self.counters = DecodeCounters()
        self.seq: dict[str, int] = {}
        self.bds: list[tuple[str, float, TargetReport]] = []
        self.keep_reports = False
        """When True, every accepted report is kept in ``bds`` as (radar id, t, report)."""
        self.dedup_window = dedup_window
        self._recent_blocks: OrderedDict[bytes, None] = OrderedDict()

    def _is_duplicate(self, block: bytes) -> bool:
        if self.dedup_window <= 0:
            return False
        if block in self._recent_blocks:
            self._recent_blocks.move_to_end(block)
            return True
        self._recent_blocks[block] = None
        if len(self._recent_blocks) > self.dedup_window:
            self._recent_blocks.popitem(last=False)
        return False

    def _next_seq(self, radar_id: str) -> int:
        seq = self.seq.get(radar_id, -1) + 1
        self.seq[radar_id] = seq
        return seq

    def _flush(self, pending: dict[str, list[Plot]], out: list[WireMessage]) -> None:
        for radar_id, plots in pending.items():
            if not plots:
                continue
            batch = PlotBatch(radar_id=radar_id, seq=self._next_seq(radar_id), plots=plots)
            out.append(WireMessage(f"radar/{radar_id}/plots", max(p.t for p in plots), encode(batch), batch))
            self.counters.counts["plot_batches"] += 1
            self.counters.counts["plots"] += len(plots)
        pending.clear()

    def datagram(self, data: bytes, reference_epoch_s: float | None = None) -> list[WireMessage]:
        """Convert one datagram (one or more data blocks); never raises on bad input."""
        self.counters.counts["datagrams"] += 1
        out: list[WireMessage] = []
        pending: dict[str, list[Plot]] = {}
        for block in split_datablocks(data, self.counters):
            self.counters.counts["blocks"] += 1
            if self._is_duplicate(block):
                self.counters.skip("duplicate_block")
                continue
            for item in decode_datablock(block, self.counters):
                radar_id = self.radar_by_sacsic.get((item.sac, item.sic))
                if radar_id is None:
                    self.counters.skip("unknown_sac_sic")
                    continue
                t_s = self.clock.resolve(item.tod_s, reference_epoch_s)
                if isinstance(item, SectorMessage):
                    self._flush(pending, out)
                    try:
                        status = RadarStatus(
                            radar_id=radar_id,
                            t=t_s,
                            kind=item.kind,
                            sector=item.sector,
                            rotation_period_s=item.rotation_period_s,
                        )
                    except ValidationError:
                        self.counters.skip("invalid_plot")
                        continue
                    out.append(WireMessage(f"radar/{radar_id}/status", t_s, encode(status), status))
                    self.counters.counts["statuses"] += 1
                    continue
                fl = item.fl if item.fl is not None and -20 <= item.fl <= 1300 else None
                # the aircraft's roll angle, ground speed and true track, when the radar read
                # its BDS 5,0 (speed and track together: decode_bds50 gives both or neither)
                roll_deg = ground_speed_mps = track_angle_deg = None
                # and its magnetic heading and indicated airspeed, when it read its BDS 6,0
                # (each on its own status bit; an airspeed of 0 kt is none)
                magnetic_heading_deg = indicated_airspeed_mps = None
                for register, mb in item.bds:
                    if register == 0x50:
                        roll_deg = bds50_roll_deg(mb)
                        bds50 = decode_bds50(mb)
                        ground_speed_mps = None if bds50 is None else bds50["ground_speed_mps"]
                        track_angle_deg = None if bds50 is None else bds50["track_angle_deg"]
                    elif register == 0x60:
                        bds60 = decode_bds60(mb) or {}
                        magnetic_heading_deg = bds60.get("magnetic_heading_deg")
                        indicated_airspeed_mps = bds60.get("ias_mps") or None
                try:
                    plot = Plot(
                        t=t_s,
                        range_m=item.range_m,
                        azimuth_deg=item.azimuth_deg,
                        fl=fl,
                        mode3a=item.mode3a,
                        mode_s=item.mode_s,
                        track_no=item.track_no,
                        kind=item.kind,
                        roll_deg=roll_deg,
                        ground_speed_mps=ground_speed_mps,
                        track_angle_deg=track_angle_deg,
                        magnetic_heading_deg=magnetic_heading_deg,
                        indicated_airspeed_mps=indicated_airspeed_mps,
                    )
                except ValidationError:
                    self.counters.skip("invalid_plot")
                    continue
                pending.setdefault(radar_id, []).append(plot)
                if self.keep_reports:
                    self.bds.append((radar_id, t_s, item))
        self._flush(pending, out)
        return out


def bds50_reference(
    path: str | Path, day: date | None = None, fmt: FileFormat | None = None
) -> dict[str, list[tuple[float, float, float]]]:
    """The aircraft's own BDS 5,0 reports in a CAT048 recording.

    Returns, per Mode S address (6 hex digits), a time-ordered list of
    ``(t_s UTC epoch, ground_speed_mps, true_track_angle_deg)``; times are resolved as
    :class:`TimeOfDayResolver` does with the same ``day``, so they line up with the
    plots the bridge publishes for the same file and day.
    """
    counters = DecodeCounters()
    clock = TimeOfDayResolver(day)
    out: dict[str, list[tuple[float, float, float]]] = {}
    for ref_s, datagram in iter_file(path, counters, fmt):
        for block in split_datablocks(datagram, counters):
            for item in decode_datablock(block, counters):
                t_s = clock.resolve(item.tod_s, ref_s)
                if not isinstance(item, TargetReport) or item.mode_s is None:
                    continue
                for register, mb in item.bds:
                    if register == 0x50 and (v := decode_bds50(mb)) is not None:
                        out.setdefault(item.mode_s, []).append((t_s, v["ground_speed_mps"], v["track_angle_deg"]))
    for series in out.values():
        series.sort()
    return out
