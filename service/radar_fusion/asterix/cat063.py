"""Health -> ASTERIX: each radar's registration estimates as CAT063 sensor status (edition 1.7).

ARTAS reports what it knows of each radar in CAT063 "sensor status messages": whether the
sensor is connected and operational, and the systematic errors its registration has
estimated (issue 15 item 4). Records are built by libasterix; :func:`decode_cat063_block`
reads them back.

Items per radar: I010 (this tracker's SAC/SIC), I015 service id, I030 time of message (the
Health's wall-clock ``t`` as time of day), I050 the radar's SAC/SIC, I060 CON (0
operational: the radar is live; 3 not connected), and, once its registration has data
(``plots`` > 0), I070 time stamping bias (``time_offset_s``, LSB 1 ms), I080 SSR / Mode S
range gain and bias (``range_gain_ppm`` as SRG, LSB 1e-5; ``range_offset_m`` as SRB, LSB
1/128 NM = 14.5 m), I081 SSR / Mode S azimuth bias (LSB 360/2^16 deg), and the same range
and azimuth biases in I090 / I091 (PSR): the registration estimates one set of biases per
radar from all its plots, primary and secondary alike. Radars without SAC/SIC in the
configuration have no I050 to name them and get no record. Values beyond an item's
range are clamped to it.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, cast

import asterix.generated as gen

from ..geo.units import M_PER_NM
from ..wire import Health
from .decode import _element, _fields, parse_block_records
from .framing import DecodeCounters
from .time_of_day import time_of_day_s

CAT063 = gen.Cat_063_1_7

_LSB_SRB_NM = 1.0 / 128.0
_LSB_GAIN = 1e-5
_LSB_AZ_DEG = 360.0 / 2**16
_LSB_TSB_MS = 1.0
CON_OPERATIONAL = 0
CON_NOT_CONNECTED = 3


def _clamp_lsb(x: float, lsb: float) -> float:
    """x rounded to the nearest multiple of ``lsb`` (libasterix truncates) and clamped to a
    signed 16-bit field of that resolution."""
    return min(max(round(x / lsb), -(2**15)), 2**15 - 1) * lsb


@dataclass(frozen=True)
class SensorStatusRecord:
    """One decoded CAT063 record (what :func:`decode_cat063_block` returns)."""

    sac: int
    sic: int
    service_id: int | None
    tod_s: float
    sensor_sac: int
    sensor_sic: int
    con: int | None
    time_offset_s: float | None
    range_gain_ppm: float | None
    range_offset_m: float | None
    azimuth_offset_deg: float | None
    psr_range_gain_ppm: float | None
    psr_range_offset_m: float | None
    psr_azimuth_offset_deg: float | None


class Cat063Encoder:
    """Health -> CAT063 data blocks, one record per radar with a SAC/SIC (module docstring)."""

    def __init__(self, sac: int, sic: int, sensors: dict[str, tuple[int, int]], service_id: int = 1):
        if not (0 <= sac <= 255 and 0 <= sic <= 255 and 0 <= service_id <= 255):
            raise ValueError("sac, sic and service_id must be 0..255")
        self.sac, self.sic, self.service_id = sac, sic, service_id
        self.sensors = dict(sensors)

    def _record(self, radar_id: str, radar: dict[str, Any], t_s: float) -> Any:
        sensor_sac, sensor_sic = self.sensors[radar_id]
        items: dict[str, Any] = {
            "010": (("SAC", self.sac), ("SIC", self.sic)),
            "015": self.service_id,
            "030": time_of_day_s(t_s),
            "050": (("SAC", sensor_sac), ("SIC", sensor_sic)),
            "060": ((("CON", CON_OPERATIONAL if radar.get("live") else CON_NOT_CONNECTED), 0, 0, 0, 0, 0, None),),
        }
        reg = radar.get("registration") or {}
        if reg and float(reg.get("plots") or 0.0) > 0.0:
            rng_nm = _clamp_lsb(float(reg.get("range_offset_m") or 0.0) / M_PER_NM, _LSB_SRB_NM)
            gain = _clamp_lsb(float(reg.get("range_gain_ppm") or 0.0) * 1e-6, _LSB_GAIN)
            az_deg = _clamp_lsb(float(reg.get("azimuth_offset_deg") or 0.0), _LSB_AZ_DEG)
            items["080"] = (("SRG", gain), ("SRB", (rng_nm, "NM")))
            items["081"] = (az_deg, "°")
            items["090"] = (("PRG", gain), ("PRB", (rng_nm, "NM")))
            items["091"] = (az_deg, "°")
            if reg.get("time_offset_s") is not None:
                items["070"] = (_clamp_lsb(float(reg["time_offset_s"]) * 1e3, _LSB_TSB_MS), "ms")
        return CAT063.cv_record.create(cast(Any, items))  # a dict of items, as libasterix takes it

    def encode(self, health: Health | dict[str, Any]) -> list[bytes]:
        """Encode one Health message (model or wire dict): one data block with a record per
        configured radar that has a SAC/SIC; no radar, no block."""
        if isinstance(health, Health):
            health = health.model_dump(mode="json")
        radars = health.get("radars") or {}
        records = [self._record(rid, radars[rid], float(health["t"])) for rid in sorted(radars) if rid in self.sensors]
        return [CAT063.create(records).unparse().to_bytes()] if records else []


def decode_cat063_block(block: bytes, counters: DecodeCounters | None = None) -> list[SensorStatusRecord]:
    """Decode one CAT063 data block (others: counted, [])."""
    counters = counters if counters is not None else DecodeCounters()
    records = parse_block_records(block, 63, CAT063, counters)
    out = []
    for rec in records:
        i010, i050, i030 = rec.get_item("010"), rec.get_item("050"), rec.get_item("030")
        if i010 is None or i050 is None or i030 is None:
            counters.skip("no_source")
            continue
        src, sensor = _fields(i010.variation), _fields(i050.variation)
        con = _fields(i060.variation).get("CON") if (i060 := rec.get_item("060")) is not None else None
        tsb = _element(i070).as_quantity("ms") / 1e3 if (i070 := rec.get_item("070")) is not None else None

        def gain_bias(item: Any, g: str, b: str) -> tuple[float | None, float | None]:
            if item is None:
                return None, None
            v = item.variation
            return (
                _element(v.get_item(g)).as_quantity("") * 1e6,
                _element(v.get_item(b)).as_quantity("NM") * M_PER_NM,
            )

        srg, srb = gain_bias(rec.get_item("080"), "SRG", "SRB")
        prg, prb = gain_bias(rec.get_item("090"), "PRG", "PRB")
        i081, i091, i015 = rec.get_item("081"), rec.get_item("091"), rec.get_item("015")
        out.append(
            SensorStatusRecord(
                sac=src["SAC"],
                sic=src["SIC"],
                service_id=i015.as_uint() if i015 is not None else None,
                tod_s=_element(i030).as_quantity("s"),
                sensor_sac=sensor["SAC"],
                sensor_sic=sensor["SIC"],
                con=con,
                time_offset_s=tsb,
                range_gain_ppm=srg,
                range_offset_m=srb,
                azimuth_offset_deg=_element(i081).as_quantity("°") if i081 is not None else None,
                psr_range_gain_ppm=prg,
                psr_range_offset_m=prb,
                psr_azimuth_offset_deg=_element(i091).as_quantity("°") if i091 is not None else None,
            )
        )
    counters.counts["cat063_records"] += len(out)
    return out
