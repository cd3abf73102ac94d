"""Mode S Comm-B registers BDS 5,0 and 6,0 (ICAO Doc 9871): the 56-bit MB words of I048/250.

libasterix hands these registers over as opaque words; the fields are read here by
hand, bit numbers as in the ICAO tables (1 = most significant bit of the MB field).
"""

from __future__ import annotations

from ..geo.units import MPS_PER_KT


def _bits(mb: int, first: int, n: int) -> int:
    """Bits ``first`` .. ``first + n - 1`` of a 56-bit MB field, numbered 1 (MSB) to 56."""
    return (mb >> (56 - first - n + 1)) & ((1 << n) - 1)


def _signed(sign: int, magnitude: int, n: int) -> int:
    """Two's-complement value of a sign bit followed by an ``n``-bit field."""
    return magnitude - (1 << n) if sign else magnitude


def decode_bds50(mb: int) -> dict[str, float] | None:
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
    out = {"ground_speed_mps": gs_kt * MPS_PER_KT, "track_angle_deg": track_deg % 360.0}
    if (roll_deg := bds50_roll_deg(mb)) is not None:
        out["roll_deg"] = roll_deg
    if _bits(mb, 46, 1):
        out["tas_mps"] = _bits(mb, 47, 10) * 2.0 * MPS_PER_KT
    return out


def bds50_roll_deg(mb: int) -> float | None:
    """The roll angle of a BDS 5,0 word (ICAO Doc 9871 table A-2-80, bits 1-11: status,
    sign, 9 bits of 45/256°), degrees, positive right wing down; ``None`` when its status
    bit is clear. Read on its own: a register whose ground speed or track is not available
    may still report the roll."""
    if not _bits(mb, 1, 1):
        return None
    return _signed(_bits(mb, 2, 1), _bits(mb, 3, 9), 9) * 45.0 / 256.0


def decode_bds60(mb: int) -> dict[str, float] | None:
    """Heading and speed report, BDS 6,0 (ICAO Doc 9871 table A-2-96).

    Returns ``magnetic_heading_deg``, ``ias_mps``, ``mach`` and ``vertical_rate_fpm``
    (barometric, else inertial) for the fields whose status bit is set; ``None`` when
    none is.
    """
    out: dict[str, float] = {}
    if _bits(mb, 1, 1):
        out["magnetic_heading_deg"] = (_signed(_bits(mb, 2, 1), _bits(mb, 3, 10), 10) * 90.0 / 512.0) % 360.0
    if _bits(mb, 13, 1):
        out["ias_mps"] = _bits(mb, 14, 10) * MPS_PER_KT
    if _bits(mb, 24, 1):
        out["mach"] = _bits(mb, 25, 10) * 2.048 / 512.0
    if _bits(mb, 35, 1):
        out["vertical_rate_fpm"] = _signed(_bits(mb, 36, 1), _bits(mb, 37, 9), 9) * 32.0
    elif _bits(mb, 46, 1):
        out["vertical_rate_fpm"] = _signed(_bits(mb, 47, 1), _bits(mb, 48, 9), 9) * 32.0
    return out or None
