"""ASTERIX bridge core: radar target reports in (CAT048, CAT034), system tracks out (CAT062).

Everything here is sans-I/O except the small file readers: bytes in, wire-contract
messages (DESIGN.md §3) or ASTERIX bytes out. The ASTERIX items themselves are parsed
and built by ``libasterix`` (MIT, pure Python; the EUROCONTROL item definitions are
generated from the official specifications); this package only maps items to the wire
contract. The sockets, the pacing and the bus are in ``radar_fusion.tools.asterix_bridge``.

One module per step, in the order the bytes flow:

* :mod:`.framing`: data blocks out of a datagram or a raw stream, and the counters of
  what was skipped, by reason (:data:`SKIP_REASONS`); malformed input never raises.
* :mod:`.decode`: CAT048 / CAT034 / CAT062 records -> :class:`TargetReport`,
  :class:`SectorMessage`, :class:`SystemTrackRecord` (editions CAT048 1.32, CAT034 1.29,
  CAT062 1.20).
* :mod:`.bds`: the Mode S registers BDS 5,0 / 6,0 carried as opaque 56-bit words in
  I048/250 (ICAO Doc 9871, tables A-2-80 and A-2-96), which libasterix does not read.
* :mod:`.time_of_day`: time of day (I048/140, I034/030, I062/070: seconds since midnight
  UTC) -> UTC epoch, and how midnight is handled (:class:`TimeOfDayResolver`).
* :mod:`.files`: raw, ``.rply`` and pcap recordings; putting a recording in time order.
* :mod:`.bridge`: CAT048 / CAT034 -> PlotBatch / RadarStatus (:class:`AsterixToWire`).
* :mod:`.cat062`: TrackBatch -> CAT062 (:class:`Cat062Encoder`).
* :mod:`.cat063`: Health -> CAT063 sensor status, the radars' registration (:class:`Cat063Encoder`).

Callers import from this package; the modules import from each other.
"""

from __future__ import annotations

from .bds import bds50_roll_deg, decode_bds50, decode_bds60
from .bridge import AsterixToWire, WireMessage, bds50_reference
from .cat062 import Cat062Encoder
from .cat063 import CAT063, Cat063Encoder, SensorStatusRecord, decode_cat063_block
from .decode import (
    CAT034,
    CAT048,
    CAT062,
    SectorMessage,
    SystemTrackRecord,
    TargetReport,
    decode_cat062_block,
    decode_datablock,
)
from .files import FileFormat, guess_format, iter_file, iter_pcap_file, iter_raw_file, iter_rply_file, sort_by_time
from .framing import SKIP_REASONS, DecodeCounters, split_datablocks
from .time_of_day import TimeOfDayResolver

__all__ = [
    "CAT034",
    "CAT048",
    "CAT062",
    "CAT063",
    "SKIP_REASONS",
    "AsterixToWire",
    "Cat062Encoder",
    "Cat063Encoder",
    "DecodeCounters",
    "FileFormat",
    "SectorMessage",
    "SensorStatusRecord",
    "SystemTrackRecord",
    "TargetReport",
    "TimeOfDayResolver",
    "WireMessage",
    "bds50_reference",
    "bds50_roll_deg",
    "decode_bds50",
    "decode_bds60",
    "decode_cat062_block",
    "decode_cat063_block",
    "decode_datablock",
    "guess_format",
    "iter_file",
    "iter_pcap_file",
    "iter_raw_file",
    "iter_rply_file",
    "sort_by_time",
    "split_datablocks",
]
