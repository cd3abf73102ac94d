"""Wire contract -> ASTERIX: TrackBatch to CAT062 system-track data blocks (edition 1.20).

Records are built by libasterix; :func:`.decode.decode_cat062_block` reads them back.
"""

from __future__ import annotations

import math
from typing import Any

from asterix.base import Spare

from ..wire import TrackBatch
from .decode import CAT062
from .time_of_day import time_of_day_s


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
#: Mean Earth radius for I062/500 APW only, deliberately a sphere rather than the WGS-84
#: ellipsoid of geo.coordinates: it turns a position accuracy of metres into degrees, where
#: the ellipsoid's radii of curvature (6 335 to 6 400 km) change the result by under 0.6 %,
#: and the docstring below names this sphere so a receiver can turn the degrees back.
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

    I080: MON = 1 when one radar fed the track in the last ``mono_window_s`` (a radar
    counts for that long after its latest plot in it; a track coasting longer keeps its
    last MON); CNF = 1 while tentative; TSB
    = 1 on the first record of a track id this encoder sends; CST = 1 when coasting.
    Each id in the batch's ``ended`` list gives a last record with TSE = 1 carrying only
    I010, I015, I070, I040 and I080. Values beyond an item's range are clamped to it.
    """

    def __init__(
        self, sac: int, sic: int, service_id: int = 1, max_block_bytes: int = 1400, mono_window_s: float = 30.0
    ):
        if not (0 <= sac <= 255 and 0 <= sic <= 255 and 0 <= service_id <= 255):
            raise ValueError("sac, sic and service_id must be 0..255")
        if max_block_bytes < 128:
            raise ValueError("max_block_bytes must be at least 128")
        self.sac, self.sic, self.service_id = sac, sic, service_id
        self.max_block_bytes = min(max_block_bytes, 65_535)
        #: how long a radar counts towards a track after its latest plot in it (I080 MON):
        #: two to three scans of an en-route radar, so that radars updating a track in
        #: turns, or a coasting period, do not make a multisensor track flicker to MON = 1
        self.mono_window_s = mono_window_s
        self._seen: set[int] = set()
        self._fed_by: dict[int, dict[str, float]] = {}  # track id -> radar -> time of its latest plot in it
        self._mon: dict[int, int] = {}  # track id -> its latest MON

    def _monosensor(self, track_id: int, t_s: float, sources: list[str]) -> int:
        """I080 MON of the track: 1 when one radar fed it in the last ``mono_window_s``."""
        fed = self._fed_by.setdefault(track_id, {})
        for radar in sources:
            fed[radar] = t_s
        for radar in [r for r, t in fed.items() if t < t_s - self.mono_window_s]:
            del fed[radar]
        if fed:
            self._mon[track_id] = 1 if len(fed) == 1 else 0
        return self._mon.get(track_id, 1)

    def _common(self, track_no: int, t_s: float, status: dict[str, int], n_groups: int) -> CAT062.cv_record.cv_arg:
        return {
            "010": (("SAC", self.sac), ("SIC", self.sic)),
            "015": self.service_id,
            "070": time_of_day_s(t_s),
            "040": track_no % 65_536,
            "080": _extended_arg(_I080, status, n_groups),
        }

    def _track_record(self, tr: dict[str, Any]) -> Any:
        tid = int(tr["track_id"])
        coasting = tr["status"] == "coasting"
        status = {
            "MON": self._monosensor(tid, float(tr["t"]), list(tr.get("sources") or ())),
            "CNF": 1 if tr["status"] == "tentative" else 0,
            "TSB": 0 if tid in self._seen else 1,
            "CST": 1 if coasting else 0,
        }
        self._seen.add(tid)
        items = self._common(tid, tr["t"], status, 4 if coasting else 2)
        lat, lon = float(tr["lat_deg"]), float(tr["lon_deg"])
        items["105"] = (("LAT", _clamp(lat, -90.0, 90.0)), ("LON", _clamp(lon, -180.0, 180.0 - 1e-5)))
        lim_xy = (2**23 - 1) * 0.5
        items["100"] = (
            ("X", _clamp(float(tr["x_m"]), -lim_xy, lim_xy)),
            ("Y", _clamp(float(tr["y_m"]), -lim_xy, lim_xy)),
        )
        lim_v = (2**15 - 1) * 0.25
        if tr.get("vx_mps") is not None and tr.get("vy_mps") is not None:  # nil: not known yet, I062/185 left out
            items["185"] = (
                ("VX", _clamp(float(tr["vx_mps"]), -lim_v, lim_v)),
                ("VY", _clamp(float(tr["vy_mps"]), -lim_v, lim_v)),
            )
        if tr.get("fl") is not None:
            items["136"] = _clamp(float(tr["fl"]), -15.0, 1500.0)  # the item's range, −15 to 1 500 FL
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
        self._fed_by.pop(track_id, None)
        self._mon.pop(track_id, None)
        return CAT062.cv_record.create(self._common(track_id, t_s, {"TSE": 1}, 2))

    def encode(self, batch: TrackBatch | dict[str, Any]) -> list[bytes]:
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
