"""Recorded ASTERIX files: raw concatenated blocks, ``.rply`` records, classic pcap.

The only module of the package that reads files; each reader yields
``(reference epoch s or None, datagram bytes)`` and counts what it skips.
:func:`sort_by_time` puts a recording's datagrams in the order of their reports' times.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Iterable, Iterator
from datetime import date
from pathlib import Path
from typing import Literal

from .decode import decode_datablock
from .framing import DecodeCounters, split_datablocks
from .time_of_day import TimeOfDayResolver


def iter_raw_file(path: str | Path, counters: DecodeCounters) -> Iterator[tuple[float | None, bytes]]:
    """Raw concatenated data blocks: yields ``(None, block)`` per block (resynchronising)."""
    data = Path(path).read_bytes()
    for block in split_datablocks(data, counters, resync=True):
        yield None, block


def iter_rply_file(path: str | Path, counters: DecodeCounters) -> Iterator[tuple[float | None, bytes]]:
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


def _udp_payload(linktype: int, frame: bytes, counters: DecodeCounters) -> bytes | None:
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


def iter_pcap_file(path: str | Path, counters: DecodeCounters) -> Iterator[tuple[float | None, bytes]]:
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


def guess_format(path: str | Path) -> FileFormat:
    """File format from the name (``.pcap``/``.cap``, ``.rply``, else raw) or the pcap magic."""
    name = str(path).lower()
    if name.endswith((".pcap", ".cap")):
        return "pcap"
    if name.endswith(".rply"):
        return "rply"
    with open(path, "rb") as f:
        return "pcap" if f.read(4) in _PCAP_MAGIC else "raw"


def iter_file(
    path: str | Path, counters: DecodeCounters, fmt: FileFormat | None = None
) -> Iterator[tuple[float | None, bytes]]:
    """``(reference epoch s or None, datagram bytes)`` from a raw, pcap or rply file."""
    fmt = fmt or guess_format(path)
    reader = {"raw": iter_raw_file, "pcap": iter_pcap_file, "rply": iter_rply_file}[fmt]
    return reader(path, counters)


def sort_by_time(
    datagrams: Iterable[tuple[float | None, bytes]], day: date | None = None
) -> list[tuple[float | None, bytes]]:
    """Datagrams of a recording in the order of their reports' times (stable).

    Some recordings are not in time order (the Jahorina sample is a ring-buffer dump:
    its second part is older than its first, then the start repeats). Fed in file order,
    the older part would arrive after its periods closed. Each datagram is keyed by the
    earliest time of day in it (resolved in file order as :class:`TimeOfDayResolver`
    does with ``day``, as :func:`.bridge.bds50_reference` does); a datagram without a
    decodable time keeps its predecessor's key.

    Each datagram comes with that key as its reference epoch (or its own reference when
    no time was decodable before it): a bridge without a ``day`` then puts each report
    on the day the sort chose. Resolved again in the sorted order from ``day``, a
    recording that crosses midnight out of order put its reports before midnight on
    the next day, a day away from the file-order times.
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
    return [(key if math.isfinite(key) else ref_s, datagram) for key, ref_s, datagram in keyed]
