"""The alert life cycle: confirmation over periods, ``new`` / ``ongoing`` / ``ended``, stable ids.

A *hit* is one function's finding for one key — (stca, track pair), (apw, track, area),
(msaw, track) — in one period. A key becomes an alert (status ``new``, fresh
``alert_id``) after hits in ``*_confirm_periods`` consecutive periods (the alert
confirmation of [STCA-SPEC]); an STCA conflict predicted more than ``stca_far_s`` ahead,
where the prediction is least certain, needs ``stca_confirm_periods_far``; a
current-proximity hit (separation already lost) is confirmed at once. While hits
continue the alert is ``ongoing`` with refreshed figures; after ``clear_periods``
consecutive periods without a hit, or as soon as one of its tracks is gone, it is
``ended``. Alert ids are unique for the life of the process and
never reused.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .config import SafetyNetsConfig


@dataclass
class Hit:
    """One function's finding for one key in one period (see the module docstring)."""

    key: tuple
    kind: str
    track_ids: list[int]
    figures: dict[str, Any]
    immediate: bool = False  # current proximity: separation already lost, confirmed at once


@dataclass
class _AlertState:
    kind: str
    track_ids: list[int]
    hits: int = 0  # consecutive periods with a hit
    misses: int = 0  # consecutive periods without a hit (active alerts)
    alert_id: int | None = None  # set when confirmed
    figures: dict[str, Any] = field(default_factory=dict)


class AlertLifeCycle:
    """Turns each period's hits into Alert messages (dicts that follow ``wire.Alert``)."""

    def __init__(self, config: SafetyNetsConfig) -> None:
        self.config = config
        self._states: dict[tuple, _AlertState] = {}
        self._next_alert_id = 1

    def _confirm_needed(self, hit: Hit) -> int:
        """Consecutive hits needed; a far STCA prediction (less certain) needs more [STCA-SPEC]."""
        c = self.config
        if hit.kind == "stca":
            far = hit.figures.get("time_to_violation_s", 0.0) > c.stca_far_s
            return c.stca_confirm_periods_far if far else c.stca_confirm_periods
        return {"apw": c.apw_confirm_periods, "msaw": c.msaw_confirm_periods}[hit.kind]

    def _message(self, st: _AlertState, t_s: float, status: str) -> dict:
        msg = {
            "v": 1,
            "kind": st.kind,
            "alert_id": st.alert_id,
            "t": t_s,
            "track_ids": list(st.track_ids),
            "status": status,
        }
        msg.update(st.figures)
        return msg

    def update(self, t_s: float, hits: list[Hit], track_ids: np.ndarray) -> list[dict]:
        """This period's alerts from its hits; ``track_ids`` are the tracks that still exist."""
        alerts: list[dict] = []
        present = set(track_ids.tolist())
        hit_keys = set()
        for h in hits:
            hit_keys.add(h.key)
            st = self._states.get(h.key)
            if st is None:
                st = self._states[h.key] = _AlertState(h.kind, h.track_ids)
            st.hits += 1
            st.misses = 0
            st.figures = h.figures
            if st.alert_id is not None:
                alerts.append(self._message(st, t_s, "ongoing"))
            elif h.immediate or st.hits >= self._confirm_needed(h):
                st.alert_id = self._next_alert_id
                self._next_alert_id += 1
                alerts.append(self._message(st, t_s, "new"))
        for key in list(self._states):
            if key in hit_keys:
                continue
            st = self._states[key]
            if st.alert_id is None:  # an unconfirmed run is broken
                del self._states[key]
                continue
            st.hits = 0
            st.misses += 1
            gone = any(tid not in present for tid in st.track_ids)
            if gone or st.misses >= self.config.clear_periods:
                alerts.append(self._message(st, t_s, "ended"))
                del self._states[key]
            else:
                alerts.append(self._message(st, t_s, "ongoing"))
        return alerts

    @property
    def active_alerts(self) -> list[dict]:
        """The confirmed alerts currently open (for a health or status view)."""
        return [
            {"kind": s.kind, "alert_id": s.alert_id, "track_ids": list(s.track_ids), **s.figures}
            for s in self._states.values()
            if s.alert_id is not None
        ]
