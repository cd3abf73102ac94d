"""ASTERIX data-block framing (category octet + 16-bit length) and the skip counters.

The framing is the one piece of bit-level work done by hand rather than by libasterix:
a malformed block must be counted and skipped without losing the good blocks around it.
Every module of this package counts what it skips in a :class:`DecodeCounters`, by one
of the :data:`SKIP_REASONS`, so malformed input never raises.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field

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
    "bad_time_of_day",  # I048/140 or I034/030 at 86,400 s or more (24 bits of 1/128 s reach 36 h)
    "no_position",  # CAT048 without I040 polar position
    "no_detection",  # I048/020 TYP = 0 (track-only record, no measurement)
    "simulated",  # I048/020 SIM = 1
    "test_target",  # I048/020 TST = 1
    "field_monitor",  # I048/020 RAB = 1: a fixed transponder's reply (a field monitor), not an aircraft
    "invalid_plot",  # a value the wire contract refuses (should not happen after the checks)
    "cat034_other_message",  # CAT034 message types other than north marker / sector crossing
    "resync_bytes",  # raw file: bytes skipped to find the next plausible block header
    "pcap_not_ipv4_udp",  # capture frame that is not IPv4/UDP (ARP, IPv6, TCP, ...)
    "pcap_fragment",  # IPv4 fragment (not reassembled)
    "pcap_truncated",  # capture frame shorter than its headers say
    "rply_truncated",  # .rply record running past the end of the file
)


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
