"""CAT048 / CAT034 records in, CAT062 records back: libasterix items -> physical units.

The items are parsed by ``libasterix`` (the EUROCONTROL item definitions are generated
from the official specifications); this module only picks the items the bridge uses and
turns them into small frozen records: :class:`TargetReport` (CAT048 plot),
:class:`SectorMessage` (CAT034 north marker / sector crossing) and
:class:`SystemTrackRecord` (CAT062, used to check what :mod:`.cat062` sends). The Mode S
registers carried in I048/250 are kept as raw 56-bit words; :mod:`.bds` reads them.

Editions: CAT048 1.32, CAT034 1.29, CAT062 1.20 (the CAT062 items we use are the same in
editions 1.16 to 1.21, which all decode the ARTAS sample identically).
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any, Literal

import asterix.generated as gen
from asterix.base import Bits, Extended, Group, Item, RawDatablock

from ..geo.units import M_PER_NM, SECONDS_PER_DAY
from .framing import DecodeCounters

CAT048 = gen.Cat_048_1_32
CAT034 = gen.Cat_034_1_29
CAT062 = gen.Cat_062_1_20

ReportKind = Literal["psr", "ssr", "cmb", "modes"] | None

#: I048/020 TYP -> wire ``kind``. 0 = no detection (skipped); Mode S + PSR is combined.
TYP_TO_KIND: dict[int, str] = {1: "psr", 2: "ssr", 3: "cmb", 4: "modes", 5: "modes", 6: "cmb", 7: "cmb"}


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


def _source(record: Any) -> tuple[int, int] | None:
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
    fl: float | None
    mode3a: int | None
    mode_s: str | None
    track_no: int | None
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
    sector: int | None
    """I034/020 sector number as transmitted (units of 360/256 degrees)."""
    sector_azimuth_deg: float | None
    rotation_period_s: float | None


@dataclass(frozen=True)
class SystemTrackRecord:
    """One CAT062 system-track record in physical units (see :func:`decode_cat062_block`)."""

    sac: int
    sic: int
    service_id: int | None
    track_no: int
    tod_s: float
    lat_deg: float | None
    lon_deg: float | None
    x_m: float | None
    y_m: float | None
    vx_mps: float | None
    vy_mps: float | None
    fl: float | None
    mode3a: int | None
    mode_s: str | None
    status: dict[str, int]
    """I062/080 flags present in the record (MON, CNF, TSB, TSE, CST, ...)."""
    sigma_x_m: float | None = None
    sigma_y_m: float | None = None
    cov_xy_component_m: float | None = None
    """I062/500 COV: sign(σxy)·sqrt(|σxy|), metres."""


def _decode_cat048(record: Any, counters: DecodeCounters) -> TargetReport | None:
    src = _source(record)
    if src is None:
        counters.skip("no_source")
        return None
    i140, i040 = record.get_item("140"), record.get_item("040")
    if i140 is None:
        counters.skip("no_time")
        return None
    tod_s = _element(i140).as_quantity("s")
    if not 0.0 <= tod_s < SECONDS_PER_DAY:  # 24 bits of 1/128 s reach 36 h: beyond midnight is no time of day
        counters.skip("bad_time_of_day")
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
        if f020.get("RAB", 0):  # a fixed transponder's reply (field monitor), not an aircraft
            counters.skip("field_monitor")
            return None
        kind = TYP_TO_KIND.get(f020["TYP"])  # type: ignore[assignment]
    if i040 is None:
        counters.skip("no_position")
        return None
    polar = i040.variation
    range_m = _element(polar.get_item("RHO")).as_quantity("NM") * M_PER_NM
    azimuth_deg = _element(polar.get_item("THETA")).as_quantity("°") % 360.0
    fl: float | None = None
    i090 = record.get_item("090")
    if i090 is not None:
        f090 = _fields(i090.variation)
        if not f090["V"] and not f090["G"]:
            fl = _element(i090.variation.get_item("FL")).as_quantity("FL")
    mode3a: int | None = None
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
        tod_s=tod_s,
        range_m=range_m,
        azimuth_deg=azimuth_deg,
        fl=fl,
        mode3a=mode3a,
        mode_s=mode_s,
        track_no=track_no,
        kind=kind,
        bds=bds,
    )


def _decode_cat034(record: Any, counters: DecodeCounters) -> SectorMessage | None:
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
    tod_s = _element(i030).as_quantity("s")
    if not 0.0 <= tod_s < SECONDS_PER_DAY:
        counters.skip("bad_time_of_day")
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
        tod_s=tod_s,
        kind="north" if msg_type == 1 else "sector",
        sector=sector,
        sector_azimuth_deg=azimuth,
        rotation_period_s=rotation_period_s,
    )


def decode_datablock(block: bytes, counters: DecodeCounters) -> list[TargetReport | SectorMessage]:
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
    out: list[TargetReport | SectorMessage] = []
    for rec in records:
        decoded = _decode_cat048(rec, counters) if cat == 48 else _decode_cat034(rec, counters)
        if decoded is not None:
            out.append(decoded)
    return out


# ============================================================================ CAT062 (to check what cat062.py sends)


def parse_block_records(block: bytes, category: int, spec: Any, counters: DecodeCounters) -> list[Any]:
    """The records of one data block of ``category`` parsed by libasterix with ``spec``
    (e.g. CAT062); a block of another category, truncated or undecodable is counted and
    gives []."""
    if not block or block[0] != category:
        counters.skip("unknown_category")
        return []
    raw = RawDatablock.parse_single(Bits.from_bytes(block))
    if isinstance(raw, ValueError):
        counters.skip("truncated_block")
        return []
    records = spec.cv_uap.parse(raw[0].get_raw_records())
    if isinstance(records, ValueError):
        counters.skip("undecodable_records")
        return []
    return list(records)


def decode_cat062_block(block: bytes, counters: DecodeCounters | None = None) -> list[SystemTrackRecord]:
    """Decode one CAT062 data block into :class:`SystemTrackRecord` (others: counted, [])."""
    counters = counters if counters is not None else DecodeCounters()
    records = parse_block_records(block, 62, CAT062, counters)
    if not records:
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
            v105 = i105.variation
            lat = _element(v105.get_item("LAT")).as_quantity("°")
            lon = _element(v105.get_item("LON")).as_quantity("°")
        if (i100 := rec.get_item("100")) is not None:
            v100 = i100.variation
            x, y = _element(v100.get_item("X")).as_quantity("m"), _element(v100.get_item("Y")).as_quantity("m")
        if (i185 := rec.get_item("185")) is not None:
            v185 = i185.variation
            vx = _element(v185.get_item("VX")).as_quantity("m/s")
            vy = _element(v185.get_item("VY")).as_quantity("m/s")
        if (i136 := rec.get_item("136")) is not None:
            fl = _element(i136).as_quantity("FL")
        mode3a = None
        if (i060 := rec.get_item("060")) is not None:
            f = _fields(i060.variation)
            mode3a = f["MODE3A"] if not f["V"] and not f["G"] else None
        mode_s = None
        if (i380 := rec.get_item("380")) is not None and (adr := i380.variation.get_item("ADR")) is not None:
            mode_s = f"{adr.as_uint():06X}"
        status = _fields(i080.variation) if (i080 := rec.get_item("080")) is not None else {}
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
