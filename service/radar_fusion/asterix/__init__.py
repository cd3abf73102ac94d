"""ASTERIX bridge core: radar target reports in (CAT048, CAT034), system tracks out (CAT062).

Everything here is sans-I/O except the small file readers: bytes in, wire-contract
messages (DESIGN.md §3) or ASTERIX bytes out. The ASTERIX items themselves are parsed
and built by ``libasterix`` (MIT, pure Python; the EUROCONTROL item definitions are
generated from the official specifications); this module only maps items to the wire
contract. The only bit-level work done by hand is

* the data-block framing (category octet + 16-bit length), needed to count and skip a
  malformed block without losing the good blocks around it, and
* the contents of the Mode S Comm-B registers BDS 5,0 / 6,0 carried as opaque 56-bit
  words in I048/250 (ICAO Doc 9871, tables A-2-80 and A-2-96), which libasterix does not
  interpret.

Editions: CAT048 1.32, CAT034 1.29, CAT062 1.20 (encoding; the items we use are the same
in editions 1.16 to 1.21, which all decode the ARTAS sample identically).

Time of day (I048/140, I034/030, I062/070) is seconds since midnight UTC. See
:class:`TimeOfDayResolver` for how it becomes a UTC epoch and how midnight is handled.

Malformed input never raises: each skipped block, record or report is counted by reason
in :class:`DecodeCounters`.
"""

from __future__ import annotations

import math
import struct
from collections import Counter, OrderedDict
from dataclasses import dataclass, field
from datetime import date, datetime, timezone
from pathlib import Path
from typing import Any, Iterable, Iterator, Literal, Optional, Sequence, Union

import asterix.generated as gen
from asterix.base import Bits, Extended, Group, Item, RawDatablock, Spare
from pydantic import ValidationError

from ..wire import Plot, PlotBatch, RadarStatus, TrackBatch, encode

__all__ = [
    "CAT034",
    "CAT048",
    "CAT062",
    "NM_TO_M",
    "KT_TO_MPS",
    "SKIP_REASONS",
    "DecodeCounters",
    "TargetReport",
    "SectorMessage",
    "SystemTrackRecord",
    "WireMessage",
    "TimeOfDayResolver",
    "split_datablocks",
    "decode_datablock",
    "decode_cat062_block",
    "decode_bds50",
    "decode_bds60",
    "iter_raw_file",
    "iter_pcap_file",
    "iter_rply_file",
    "iter_file",
    "guess_format",
    "sort_by_time",
    "AsterixToWire",
    "Cat062Encoder",
    "bds50_reference",
]

CAT048 = gen.Cat_048_1_32
CAT034 = gen.Cat_034_1_29
CAT062 = gen.Cat_062_1_20

NM_TO_M = 1852.0
"""International nautical mile in metres (exact)."""
KT_TO_MPS = NM_TO_M / 3600.0
"""One knot in metres per second."""
SECONDS_PER_DAY = 86_400.0

#: Why something was skipped. Block-level reasons skip a whole data block, record-level
#: reasons one record, file-level reasons one frame of a capture file.
SKIP_REASONS = (
    "bad_length",  # block length field < 3: the framing is lost
    "truncated_block",  # block length field larger than the bytes that are left
    "duplicate_block",  # a data block identical to a recent one (the same feed on redundant LANs)
    "unknown_category",  # a category this bridge does not handle (e.g. CAT063/065 on input)
    "undecodable_records",  # libasterix could not parse the records of the block
    "no_source",  # record without I010 SAC/SIC
    "unknown_sac_sic",  # SAC/SIC of no configured radar
    "no_time",  # CAT048 without I140 / CAT034 without I030
    "no_position",  # CAT048 without I040 polar position
    "no_detection",  # I048/020 TYP = 0 (track-only record, no measurement)
    "simulated",  # I048/020 SIM = 1
    "test_target",  # I048/020 TST = 1
    "invalid_plot",  # a value the wire contract refuses (should not happen after the checks)
    "cat034_other_message",  # CAT034 message types other than north marker / sector crossing
    "resync_bytes",  # raw file: bytes skipped to find the next plausible block header
    "pcap_not_ipv4_udp",  # capture frame that is not IPv4/UDP (ARP, IPv6, TCP, ...)
    "pcap_fragment",  # IPv4 fragment (not reassembled)
    "pcap_truncated",  # capture frame shorter than its headers say
    "rply_truncated",  # .rply record running past the end of the file
)

ReportKind = Optional[Literal["psr", "ssr", "cmb", "modes"]]

#: I048/020 TYP -> wire ``kind``. 0 = no detection (skipped); Mode S + PSR is combined.
TYP_TO_KIND: dict[int, str] = {1: "psr", 2: "ssr", 3: "cmb", 4: "modes", 5: "modes", 6: "cmb", 7: "cmb"}


# ============================================================================ counters


@dataclass
class DecodeCounters:
    """What the decoder saw (``counts``) and what it skipped, by reason (``skipped``)."""

    counts: Counter = field(default_factory=Counter)
    skipped: Counter = field(default_factory=Counter)

    def skip(self, reason: str, n: int = 1) -> None:
        """Count ``n`` skipped items for ``reason`` (one of :data:`SKIP_REASONS`)."""
        if reason not in SKIP_REASONS:
            raise ValueError(f"unknown skip reason {reason!r}")
        self.skipped[reason] += n

    def as_dict(self) -> dict[str, dict[str, int]]:
        return {"counts": dict(self.counts), "skipped": dict(self.skipped)}


# ============================================================================ framing


def _plausible_header(data: bytes, offset: int, categories: frozenset[int]) -> bool:
    """A block of a known category whose length fits in what is left."""
    if len(data) - offset < 3 or data[offset] not in categories:
        return False
    length = int.from_bytes(data[offset + 1 : offset + 3], "big")
    return 3 <= length <= len(data) - offset


def split_datablocks(
    data: bytes,
    counters: DecodeCounters,
    resync: bool = False,
    categories: frozenset[int] = frozenset({34, 48, 62, 63, 65}),
) -> list[bytes]:
    """Split a datagram (or a raw stream) into ASTERIX data blocks ``CAT|LEN|records``.

    A block whose length field is below 3 (``bad_length``) or runs past the end
    (``truncated_block``) is counted. Without ``resync`` (a UDP datagram) the rest of the
    datagram is then dropped: its framing is lost. With ``resync`` (a raw file) the
    scanner moves forward byte by byte to the next offset that starts a block of one of
    ``categories`` followed by the end of the data or another such block; the bytes
    passed over are counted as ``resync_bytes``.
    """
    blocks: list[bytes] = []
    offset, n = 0, len(data)
    while offset < n:
        if n - offset < 3:
            counters.skip("truncated_block")
            bad_from = offset
        else:
            length = int.from_bytes(data[offset + 1 : offset + 3], "big")
            if length < 3:
                counters.skip("bad_length")
                bad_from = offset
            elif length > n - offset:
                counters.skip("truncated_block")
                bad_from = offset
            else:
                blocks.append(bytes(data[offset : offset + length]))
                offset += length
                continue
        if not resync:
            return blocks
        offset = bad_from + 1
        while offset < n:
            if _plausible_header(data, offset, categories):
                end = offset + int.from_bytes(data[offset + 1 : offset + 3], "big")
                if end == n or _plausible_header(data, end, categories):
                    break
            offset += 1
        counters.skip("resync_bytes", offset - bad_from)
    return blocks


# ============================================================================ item access


def _element(rule_variation: Any) -> Any:
    """The content of an element sub-item (``get_item(...)`` result)."""
    return rule_variation.variation.content


def _fields(variation: Any) -> dict[str, int]:
    """Raw unsigned values of the named elements of a Group or Extended item (one level)."""
    out: dict[str, int] = {}
    if isinstance(variation, Group):
        items: Iterable[Any] = variation.arg
    elif isinstance(variation, Extended):
        items = (i for grp in variation.arg for i in grp)
    else:
        raise TypeError(f"not a group/extended variation: {type(variation).__name__}")
    for it in items:
        if isinstance(it, Item):
            out[it.arg.cv_name] = it.arg.as_uint()
    return out


def _source(record: Any) -> Optional[tuple[int, int]]:
    i010 = record.get_item("010")
    if i010 is None:
        return None
    f = _fields(i010.variation)
    return f["SAC"], f["SIC"]


# ============================================================================ decoded records


@dataclass(frozen=True)
class TargetReport:
    """One CAT048 target report in physical units (before mapping to a radar id)."""

    sac: int
    sic: int
    tod_s: float
    range_m: float
    azimuth_deg: float
    fl: Optional[float]
    mode3a: Optional[int]
    mode_s: Optional[str]
    track_no: Optional[int]
    kind: ReportKind
    bds: tuple[tuple[int, int], ...] = ()
    """Mode S MB data of I048/250: ``(register, mb)`` with register e.g. 0x50, mb a 56-bit int."""


@dataclass(frozen=True)
class SectorMessage:
    """One CAT034 north-marker or sector-crossing message."""

    sac: int
    sic: int
    tod_s: float
    kind: Literal["north", "sector"]
    sector: Optional[int]
    """I034/020 sector number as transmitted (units of 360/256 degrees)."""
    sector_azimuth_deg: Optional[float]
    rotation_period_s: Optional[float]


@dataclass(frozen=True)
class SystemTrackRecord:
    """One CAT062 system-track record in physical units (see :func:`decode_cat062_block`)."""

    sac: int
    sic: int
    service_id: Optional[int]
    track_no: int
    tod_s: float
    lat_deg: Optional[float]
    lon_deg: Optional[float]
    x_m: Optional[float]
    y_m: Optional[float]
    vx_mps: Optional[float]
    vy_mps: Optional[float]
    fl: Optional[float]
    mode3a: Optional[int]
    mode_s: Optional[str]
    status: dict[str, int]
    """I062/080 flags present in the record (MON, CNF, TSB, TSE, CST, ...)."""
    sigma_x_m: Optional[float] = None
    sigma_y_m: Optional[float] = None
    cov_xy_component_m: Optional[float] = None
    """I062/500 COV: sign(σxy)·sqrt(|σxy|), metres."""


def _decode_cat048(record: Any, counters: DecodeCounters) -> Optional[TargetReport]:
    src = _source(record)
    if src is None:
        counters.skip("no_source")
        return None
    i140, i040 = record.get_item("140"), record.get_item("040")
    if i140 is None:
        counters.skip("no_time")
        return None
    kind: ReportKind = None
    i020 = record.get_item("020")
    if i020 is not None:
        f020 = _fields(i020.variation)
        if f020.get("TYP", 0) == 0:  # e.g. a track-end record (I048/170 TRE) with no plot
            counters.skip("no_detection")
            return None
        if f020.get("SIM", 0):
            counters.skip("simulated")
            return None
        if f020.get("TST", 0):
            counters.skip("test_target")
            return None
        kind = TYP_TO_KIND.get(f020["TYP"])  # type: ignore[assignment]
    if i040 is None:
        counters.skip("no_position")
        return None
    polar = i040.variation
    range_m = _element(polar.get_item("RHO")).as_quantity("NM") * NM_TO_M
    azimuth_deg = _element(polar.get_item("THETA")).as_quantity("°") % 360.0
    fl: Optional[float] = None
    i090 = record.get_item("090")
    if i090 is not None:
        f090 = _fields(i090.variation)
        if not f090["V"] and not f090["G"]:
            fl = _element(i090.variation.get_item("FL")).as_quantity("FL")
    mode3a: Optional[int] = None
    i070 = record.get_item("070")
    if i070 is not None:
        # V = 1 code not validated, G = 1 garbled: no usable code. L = 1 (code not
        # extracted in the last scan, smoothed by the radar's tracker) is kept.
        f070 = _fields(i070.variation)
        if not f070["V"] and not f070["G"]:
            mode3a = f070["MODE3A"]
    i220 = record.get_item("220")
    mode_s = f"{i220.as_uint():06X}" if i220 is not None else None
    # I048/161 is the radar's track number. (I048/170 is the track *status*: no number.)
    i161 = record.get_item("161")
    track_no = _fields(i161.variation)["TRN"] if i161 is not None else None
    bds: tuple[tuple[int, int], ...] = ()
    i250 = record.get_item("250")
    if i250 is not None:
        regs = []
        for entry in i250.variation.get_list():
            f = _fields(entry)
            regs.append(((f["BDS1"] << 4) | f["BDS2"], f["MBDATA"]))
        bds = tuple(regs)
    return TargetReport(
        sac=src[0],
        sic=src[1],
        tod_s=_element(i140).as_quantity("s"),
        range_m=range_m,
        azimuth_deg=azimuth_deg,
        fl=fl,
        mode3a=mode3a,
        mode_s=mode_s,
        track_no=track_no,
        kind=kind,
        bds=bds,
    )


def _decode_cat034(record: Any, counters: DecodeCounters) -> Optional[SectorMessage]:
    src = _source(record)
    if src is None:
        counters.skip("no_source")
        return None
    i000, i030 = record.get_item("000"), record.get_item("030")
    msg_type = i000.as_uint() if i000 is not None else None
    if msg_type not in (1, 2):
        counters.skip("cat034_other_message")
        return None
    if i030 is None:
        counters.skip("no_time")
        return None
    sector = azimuth = None
    i020 = record.get_item("020")
    if i020 is not None:
        sector = i020.as_uint()
        azimuth = _element(i020).as_quantity("°")
    rotation_period_s = None
    i041 = record.get_item("041")
    if i041 is not None:
        period = _element(i041).as_quantity("s")
        rotation_period_s = period if 0 < period <= 120 else None
    return SectorMessage(
        sac=src[0],
        sic=src[1],
        tod_s=_element(i030).as_quantity("s"),
        kind="north" if msg_type == 1 else "sector",
        sector=sector,
        sector_azimuth_deg=azimuth,
        rotation_period_s=rotation_period_s,
    )


def decode_datablock(
    block: bytes, counters: DecodeCounters
) -> list[Union[TargetReport, SectorMessage]]:
    """Decode one CAT048 or CAT034 data block; anything else is counted and skipped."""
    cat = block[0]
    if cat not in (34, 48):
        counters.skip("unknown_category")
        return []
    spec = CAT048 if cat == 48 else CAT034
    raw = RawDatablock.parse_single(Bits.from_bytes(block))
    if isinstance(raw, ValueError):
        counters.skip("truncated_block")
        return []
    try:
        records = spec.cv_uap.parse(raw[0].get_raw_records())
    except (AssertionError, IndexError, KeyError, TypeError, ValueError):
        records = ValueError("exception in record parsing")
    if isinstance(records, ValueError):
        counters.skip("undecodable_records")
        return []
    counters.counts[f"cat{cat:03d}_records"] += len(records)
    out: list[Union[TargetReport, SectorMessage]] = []
    for rec in records:
        decoded = _decode_cat048(rec, counters) if cat == 48 else _decode_cat034(rec, counters)
        if decoded is not None:
            out.append(decoded)
    return out


def decode_cat062_block(block: bytes, counters: Optional[DecodeCounters] = None) -> list[SystemTrackRecord]:
    """Decode one CAT062 data block into :class:`SystemTrackRecord` (others: counted, [])."""
    counters = counters if counters is not None else DecodeCounters()
    if not block or block[0] != 62:
        counters.skip("unknown_category")
        return []
    raw = RawDatablock.parse_single(Bits.from_bytes(block))
    if isinstance(raw, ValueError):
        counters.skip("truncated_block")
        return []
    records = CAT062.cv_uap.parse(raw[0].get_raw_records())
    if isinstance(records, ValueError):
        counters.skip("undecodable_records")
        return []
    counters.counts["cat062_records"] += len(records)
    out = []
    for rec in records:
        src = _source(rec)
        i040, i070 = rec.get_item("040"), rec.get_item("070")
        if src is None or i040 is None or i070 is None:
            counters.skip("no_source" if src is None else "no_time")
            continue
        lat = lon = x = y = vx = vy = fl = None
        if (i105 := rec.get_item("105")) is not None:
            v = i105.variation
            lat, lon = _element(v.get_item("LAT")).as_quantity("°"), _element(v.get_item("LON")).as_quantity("°")
        if (i100 := rec.get_item("100")) is not None:
            v = i100.variation
            x, y = _element(v.get_item("X")).as_quantity("m"), _element(v.get_item("Y")).as_quantity("m")
        if (i185 := rec.get_item("185")) is not None:
            v = i185.variation
            vx, vy = _element(v.get_item("VX")).as_quantity("m/s"), _element(v.get_item("VY")).as_quantity("m/s")
        if (i136 := rec.get_item("136")) is not None:
            fl = _element(i136).as_quantity("FL")
        mode3a = None
        if (i060 := rec.get_item("060")) is not None:
            f = _fields(i060.variation)
            mode3a = f["MODE3A"] if not f["V"] and not f["G"] else None
        mode_s = None
        if (i380 := rec.get_item("380")) is not None and (adr := i380.variation.get_item("ADR")) is not None:
            mode_s = f"{adr.as_uint():06X}"
        status = _fields(rec.get_item("080").variation) if rec.get_item("080") is not None else {}
        sx = sy = cov = None
        if (i500 := rec.get_item("500")) is not None:
            comp = i500.variation
            if (apc := comp.get_item("APC")) is not None:
                sx = _element(apc.variation.get_item("X")).as_quantity("m")
                sy = _element(apc.variation.get_item("Y")).as_quantity("m")
            if (c := comp.get_item("COV")) is not None:
                cov = _element(c).as_quantity("m")
        i015 = rec.get_item("015")
        out.append(
            SystemTrackRecord(
                sac=src[0],
                sic=src[1],
                service_id=i015.as_uint() if i015 is not None else None,
                track_no=i040.as_uint(),
                tod_s=_element(i070).as_quantity("s"),
                lat_deg=lat,
                lon_deg=lon,
                x_m=x,
                y_m=y,
                vx_mps=vx,
                vy_mps=vy,
                fl=fl,
                mode3a=mode3a,
                mode_s=mode_s,
                status=status,
                sigma_x_m=sx,
                sigma_y_m=sy,
                cov_xy_component_m=cov,
            )
        )
    return out


# ============================================================================ BDS registers


def _bits(mb: int, first: int, n: int) -> int:
    """Bits ``first`` .. ``first + n - 1`` of a 56-bit MB field, numbered 1 (MSB) to 56."""
    return (mb >> (56 - first - n + 1)) & ((1 << n) - 1)


def _signed(sign: int, magnitude: int, n: int) -> int:
    """Two's-complement value of a sign bit followed by an ``n``-bit field."""
    return magnitude - (1 << n) if sign else magnitude


def decode_bds50(mb: int) -> Optional[dict[str, float]]:
    """Track and turn report, BDS 5,0 (ICAO Doc 9871 table A-2-80).

    Returns ``ground_speed_mps`` and ``track_angle_deg`` (true, [0, 360)), plus
    ``roll_deg`` / ``tas_mps`` when their status bits are set; ``None`` when the ground
    speed or track angle is not available or implausible (> 800 kt).
    """
    if not _bits(mb, 12, 1) or not _bits(mb, 24, 1):
        return None
    track_deg = _signed(_bits(mb, 13, 1), _bits(mb, 14, 10), 10) * 90.0 / 512.0
    gs_kt = _bits(mb, 25, 10) * 2.0
    if gs_kt > 800:
        return None
    out = {"ground_speed_mps": gs_kt * KT_TO_MPS, "track_angle_deg": track_deg % 360.0}
    if _bits(mb, 1, 1):
        out["roll_deg"] = _signed(_bits(mb, 2, 1), _bits(mb, 3, 9), 9) * 45.0 / 256.0
    if _bits(mb, 46, 1):
        out["tas_mps"] = _bits(mb, 47, 10) * 2.0 * KT_TO_MPS
    return out


def decode_bds60(mb: int) -> Optional[dict[str, float]]:
    """Heading and speed report, BDS 6,0 (ICAO Doc 9871 table A-2-96).

    Returns ``magnetic_heading_deg``, ``ias_mps``, ``mach`` and ``vertical_rate_fpm``
    (barometric, else inertial) for the fields whose status bit is set; ``None`` when
    none is.
    """
    out: dict[str, float] = {}
    if _bits(mb, 1, 1):
        out["magnetic_heading_deg"] = (_signed(_bits(mb, 2, 1), _bits(mb, 3, 10), 10) * 90.0 / 512.0) % 360.0
    if _bits(mb, 13, 1):
        out["ias_mps"] = _bits(mb, 14, 10) * KT_TO_MPS
    if _bits(mb, 24, 1):
        out["mach"] = _bits(mb, 25, 10) * 2.048 / 512.0
    if _bits(mb, 35, 1):
        out["vertical_rate_fpm"] = _signed(_bits(mb, 36, 1), _bits(mb, 37, 9), 9) * 32.0
    elif _bits(mb, 46, 1):
        out["vertical_rate_fpm"] = _signed(_bits(mb, 47, 1), _bits(mb, 48, 9), 9) * 32.0
    return out or None


# ============================================================================ time


def _midnight_epoch_s(day: date) -> float:
    return datetime(day.year, day.month, day.day, tzinfo=timezone.utc).timestamp()


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

    def __init__(self, day: Optional[date] = None):
        self.day = day
        self._last_s: Optional[float] = None

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

    def resolve(self, tod_s: float, reference_epoch_s: Optional[float] = None) -> float:
        if self._last_s is None:
            if self.day is not None:
                t = _midnight_epoch_s(self.day) + tod_s
            elif reference_epoch_s is not None:
                t = self.nearest(tod_s, reference_epoch_s)
            else:
                t = _midnight_epoch_s(datetime.now(timezone.utc).date()) + tod_s
        elif self.day is None and reference_epoch_s is not None:
            t = self.nearest(tod_s, reference_epoch_s)
        else:
            t = self.nearest(tod_s, self._last_s)
        self._last_s = t
        return t


# ============================================================================ file readers


def iter_raw_file(path: Union[str, Path], counters: DecodeCounters) -> Iterator[tuple[Optional[float], bytes]]:
    """Raw concatenated data blocks: yields ``(None, block)`` per block (resynchronising)."""
    data = Path(path).read_bytes()
    for block in split_datablocks(data, counters, resync=True):
        yield None, block


def iter_rply_file(path: Union[str, Path], counters: DecodeCounters) -> Iterator[tuple[Optional[float], bytes]]:
    """``.rply`` records ``<uint32 LE length><4 bytes><ASTERIX bytes>``: yields ``(None, payload)``."""
    data = Path(path).read_bytes()
    offset = 0
    while offset + 8 <= len(data):
        (length,) = struct.unpack_from("<I", data, offset)
        start = offset + 8
        if start + length > len(data):
            counters.skip("rply_truncated")
            return
        yield None, data[start : start + length]
        offset = start + length
    if offset != len(data):
        counters.skip("rply_truncated")


_PCAP_MAGIC = {
    b"\xd4\xc3\xb2\xa1": ("<", 1e-6),
    b"\xa1\xb2\xc3\xd4": (">", 1e-6),
    b"\x4d\x3c\xb2\xa1": ("<", 1e-9),
    b"\xa1\xb2\x3c\x4d": (">", 1e-9),
}


def _udp_payload(linktype: int, frame: bytes, counters: DecodeCounters) -> Optional[bytes]:
    """The UDP payload of one captured frame (IPv4 only), or None (counted)."""
    if linktype == 1:  # Ethernet, optionally 802.1Q / QinQ tagged
        off = 12
        if len(frame) < 14:
            counters.skip("pcap_truncated")
            return None
        ethertype = int.from_bytes(frame[off : off + 2], "big")
        while ethertype in (0x8100, 0x88A8) and len(frame) >= off + 6:
            off += 4
            ethertype = int.from_bytes(frame[off : off + 2], "big")
        off += 2
    elif linktype == 113:  # Linux cooked capture (SLL)
        if len(frame) < 16:
            counters.skip("pcap_truncated")
            return None
        ethertype, off = int.from_bytes(frame[14:16], "big"), 16
    elif linktype in (101, 228):  # raw IPv4
        ethertype, off = 0x0800, 0
    elif linktype == 0:  # BSD loopback: 4-byte address family in host order
        ethertype, off = (0x0800 if frame[:4] in (b"\x02\x00\x00\x00", b"\x00\x00\x00\x02") else 0), 4
    else:
        ethertype, off = 0, 0
    if ethertype != 0x0800 or len(frame) < off + 20 or frame[off] >> 4 != 4:
        counters.skip("pcap_not_ipv4_udp")
        return None
    ihl = (frame[off] & 0x0F) * 4
    total_len = int.from_bytes(frame[off + 2 : off + 4], "big")
    flags_frag = int.from_bytes(frame[off + 6 : off + 8], "big")
    if frame[off + 9] != 17:
        counters.skip("pcap_not_ipv4_udp")
        return None
    if flags_frag & 0x3FFF:  # more-fragments flag or a fragment offset
        counters.skip("pcap_fragment")
        return None
    udp = off + ihl
    if len(frame) < udp + 8 or len(frame) < off + total_len:
        counters.skip("pcap_truncated")
        return None
    udp_len = int.from_bytes(frame[udp + 4 : udp + 6], "big")
    if udp_len < 8 or udp + udp_len > off + total_len:
        counters.skip("pcap_truncated")
        return None
    return frame[udp + 8 : udp + udp_len]


def iter_pcap_file(path: Union[str, Path], counters: DecodeCounters) -> Iterator[tuple[Optional[float], bytes]]:
    """Classic libpcap capture of Ethernet/IPv4/UDP: yields ``(capture epoch s, UDP payload)``.

    Non-UDP frames and IPv4 fragments are counted and skipped. pcapng is not read
    (convert with ``editcap -F pcap``).
    """
    data = Path(path).read_bytes()
    magic = data[:4]
    if magic not in _PCAP_MAGIC:
        raise ValueError(f"{path}: not a classic pcap file (magic {magic.hex()}); pcapng: convert with editcap -F pcap")
    endian, tick_s = _PCAP_MAGIC[magic]
    linktype = struct.unpack_from(endian + "I", data, 20)[0] & 0x0FFFFFFF
    offset = 24
    while offset + 16 <= len(data):
        ts_s, ts_frac, incl_len, _orig_len = struct.unpack_from(endian + "IIII", data, offset)
        start = offset + 16
        if start + incl_len > len(data):
            counters.skip("pcap_truncated")
            return
        payload = _udp_payload(linktype, data[start : start + incl_len], counters)
        if payload is not None:
            yield ts_s + ts_frac * tick_s, payload
        offset = start + incl_len


FileFormat = Literal["raw", "pcap", "rply"]


def guess_format(path: Union[str, Path]) -> FileFormat:
    """File format from the name (``.pcap``/``.cap``, ``.rply``, else raw) or the pcap magic."""
    name = str(path).lower()
    if name.endswith((".pcap", ".cap")):
        return "pcap"
    if name.endswith(".rply"):
        return "rply"
    with open(path, "rb") as f:
        return "pcap" if f.read(4) in _PCAP_MAGIC else "raw"


def iter_file(
    path: Union[str, Path], counters: DecodeCounters, fmt: Optional[FileFormat] = None
) -> Iterator[tuple[Optional[float], bytes]]:
    """``(reference epoch s or None, datagram bytes)`` from a raw, pcap or rply file."""
    fmt = fmt or guess_format(path)
    reader = {"raw": iter_raw_file, "pcap": iter_pcap_file, "rply": iter_rply_file}[fmt]
    return reader(path, counters)


def sort_by_time(
    datagrams: Iterable[tuple[Optional[float], bytes]], day: Optional[date] = None
) -> list[tuple[Optional[float], bytes]]:
    """Datagrams of a recording in the order of their reports' times (stable).

    Some recordings are not in time order (the Jahorina sample is a ring-buffer dump:
    its second part is older than its first, then the start repeats). Fed in file order,
    the older part would arrive after its periods closed. Each datagram is keyed by the
    earliest time of day in it (resolved as :class:`TimeOfDayResolver` does with
    ``day``); a datagram without a decodable time keeps its predecessor's key.
    """
    scratch = DecodeCounters()
    clock = TimeOfDayResolver(day)
    keyed = []
    key = -math.inf
    for ref_s, datagram in datagrams:
        times = [
            clock.resolve(item.tod_s, ref_s)
            for block in split_datablocks(datagram, scratch)
            for item in decode_datablock(block, scratch)
        ]
        if times:
            key = min(times)
        keyed.append((key, ref_s, datagram))
    keyed.sort(key=lambda k: k[0])
    return [(ref_s, datagram) for _, ref_s, datagram in keyed]


# ============================================================================ to the wire


@dataclass(frozen=True)
class WireMessage:
    """One message for the bus: key relative to the prefix, event time, encoded payload."""

    key: str
    t_s: float
    payload: bytes
    message: Union[PlotBatch, RadarStatus]


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

    def __init__(self, radars: Sequence[Any], day: Optional[date] = None, dedup_window: int = 1024):
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

    def datagram(self, data: bytes, reference_epoch_s: Optional[float] = None) -> list[WireMessage]:
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
    path: Union[str, Path], day: Optional[date] = None, fmt: Optional[FileFormat] = None
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


# ============================================================================ CAT062 out


def _extended_arg(variation_cls: Any, values: dict[str, int], n_groups: int) -> tuple:
    """Argument for libasterix ``Extended.create``: the first ``n_groups`` octets, by name."""
    groups = []
    for specs in variation_cls.cv_items_list[:n_groups]:
        group: list[Any] = []
        for spec in specs:
            if spec is None:
                group.append(None)  # FX, set by libasterix
            elif issubclass(spec[0], Spare):
                group.append(0)
            else:
                name = spec[0].cv_non_spare.cv_name
                group.append((name, int(values.get(name, 0))))
        groups.append(tuple(group))
    return tuple(groups)


def _clamp(x: float, lo: float, hi: float) -> float:
    return min(max(x, lo), hi)


_I080 = CAT062.cv_record.spec("080").cv_rule.cv_variation
_EARTH_RADIUS_M = 6_371_000.0


class Cat062Encoder:
    """TrackBatch -> CAT062 data blocks (system tracks, EUROCONTROL CAT062 ed. 1.20).

    Items per track: I010 (the system's SAC/SIC), I015 service id, I070 time of track
    (the track's ``t`` as time of day), I040 track number (``track_id`` mod 65 536),
    I080 status, I100 Cartesian position (the system plane), I105 WGS-84 position, I185
    Cartesian velocity, I136 measured flight level, I060 Mode 3/A, I380 target address
    and I500 accuracies: APC σx, σy (sqrt of the diagonal of ``cov_xy``), COV the XY
    component sign(σxy)·sqrt(|σxy|), APW σ latitude / longitude (σy, σx in degrees on a
    6 371 km sphere).

    I080: MON = 1 when one radar contributed this period; CNF = 1 while tentative; TSB
    = 1 on the first record of a track id this encoder sends; CST = 1 when coasting.
    Each id in the batch's ``ended`` list gives a last record with TSE = 1 carrying only
    I010, I015, I070, I040 and I080. Values beyond an item's range are clamped to it.
    """

    def __init__(self, sac: int, sic: int, service_id: int = 1, max_block_bytes: int = 1400):
        if not (0 <= sac <= 255 and 0 <= sic <= 255 and 0 <= service_id <= 255):
            raise ValueError("sac, sic and service_id must be 0..255")
        if max_block_bytes < 128:
            raise ValueError("max_block_bytes must be at least 128")
        self.sac, self.sic, self.service_id = sac, sic, service_id
        self.max_block_bytes = min(max_block_bytes, 65_535)
        self._seen: set[int] = set()

    def _common(self, track_no: int, t_s: float, status: dict[str, int], n_groups: int) -> dict[str, Any]:
        return {
            "010": (("SAC", self.sac), ("SIC", self.sic)),
            "015": self.service_id,
            "070": float(t_s % SECONDS_PER_DAY),
            "040": track_no % 65_536,
            "080": _extended_arg(_I080, status, n_groups),
        }

    def _track_record(self, tr: dict[str, Any]) -> Any:
        tid = int(tr["track_id"])
        coasting = tr["status"] == "coasting"
        status = {
            "MON": 1 if len(tr.get("sources") or ()) == 1 else 0,
            "CNF": 1 if tr["status"] == "tentative" else 0,
            "TSB": 0 if tid in self._seen else 1,
            "CST": 1 if coasting else 0,
        }
        self._seen.add(tid)
        items = self._common(tid, tr["t"], status, 4 if coasting else 2)
        lat, lon = float(tr["lat_deg"]), float(tr["lon_deg"])
        items["105"] = (("LAT", _clamp(lat, -90.0, 90.0)), ("LON", _clamp(lon, -180.0, 180.0 - 1e-5)))
        lim_xy = (2**23 - 1) * 0.5
        items["100"] = (("X", _clamp(float(tr["x_m"]), -lim_xy, lim_xy)), ("Y", _clamp(float(tr["y_m"]), -lim_xy, lim_xy)))
        lim_v = (2**15 - 1) * 0.25
        items["185"] = (("VX", _clamp(float(tr["vx_mps"]), -lim_v, lim_v)), ("VY", _clamp(float(tr["vy_mps"]), -lim_v, lim_v)))
        if tr.get("fl") is not None:
            items["136"] = _clamp(float(tr["fl"]), -1500.0, 1500.0)
        if tr.get("mode3a") is not None:
            items["060"] = (("V", 0), ("G", 0), ("CH", 0), 0, ("MODE3A", int(tr["mode3a"])))
        if tr.get("mode_s"):
            items["380"] = {"ADR": int(tr["mode_s"], 16)}
        sxx, sxy, syy = (float(c) for c in tr["cov_xy"])
        sx, sy = math.sqrt(max(sxx, 0.0)), math.sqrt(max(syy, 0.0))
        lim_sigma = (2**16 - 1) * 0.5
        lim_cov = (2**15 - 1) * 0.5
        lim_deg = (2**16 - 1) * 180.0 / 2**25
        sigma_lat_deg = math.degrees(sy / _EARTH_RADIUS_M)
        sigma_lon_deg = math.degrees(sx / (_EARTH_RADIUS_M * max(math.cos(math.radians(lat)), 1e-3)))
        items["500"] = {
            "APC": (("X", _clamp(sx, 0.0, lim_sigma)), ("Y", _clamp(sy, 0.0, lim_sigma))),
            "COV": _clamp(math.copysign(math.sqrt(abs(sxy)), sxy), -lim_cov, lim_cov),
            "APW": (("LAT", _clamp(sigma_lat_deg, 0.0, lim_deg)), ("LON", _clamp(sigma_lon_deg, 0.0, lim_deg))),
        }
        return CAT062.cv_record.create(items)

    def _ended_record(self, track_id: int, t_s: float) -> Any:
        self._seen.discard(track_id)
        return CAT062.cv_record.create(self._common(track_id, t_s, {"TSE": 1}, 2))

    def encode(self, batch: Union[TrackBatch, dict[str, Any]]) -> list[bytes]:
        """Encode one TrackBatch (model or wire dict) into CAT062 data blocks.

        Records are packed into blocks of at most ``max_block_bytes`` (one UDP datagram
        each); an empty batch gives no block.
        """
        if isinstance(batch, TrackBatch):
            batch = batch.model_dump(mode="json")
        records = [self._track_record(tr) for tr in batch.get("tracks", [])]
        records += [self._ended_record(int(tid), float(batch["t"])) for tid in batch.get("ended", [])]
        blocks: list[bytes] = []
        current: list[Any] = []
        size = 3
        for rec in records:
            n = len(rec.unparse().to_bytes())
            if current and size + n > self.max_block_bytes:
                blocks.append(CAT062.create(current).unparse().to_bytes())
                current, size = [], 3
            current.append(rec)
            size += n
        if current:
            blocks.append(CAT062.create(current).unparse().to_bytes())
        return blocks
