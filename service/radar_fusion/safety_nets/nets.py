"""The safety nets of one daemon: STCA, APW and MSAW per period, the alert life cycle, the hooks."""

from __future__ import annotations

import logging
from collections import Counter
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from pydantic import ValidationError

from ..geo.coordinates import SystemPlane
from ..wire import Alert
from .apw import apw_hits
from .areas import Area, MsaMap, load_areas, load_msa
from .config import SafetyNetsConfig
from .hooks import Hooks, load_hooks
from .life_cycle import AlertLifeCycle, Hit
from .msaw import msaw_hits
from .prediction import VerticalRateHistory
from .stca import Stca

if TYPE_CHECKING:  # annotations only: the engine and the config import this package
    from ..config import Settings
    from ..engine.columns import TrackColumns

log = logging.getLogger(__name__)

ALERT_KINDS = ("stca", "apw", "msaw")


def check_maps(settings: Settings, base_dir: Path | None) -> str | None:
    """Why the safety nets of ``settings`` could not start (their areas or MSA map missing or
    unreadable), or None: asked before a daemon starts, so that a wrong path is refused at
    once instead of a child that dies at every start while the tracks run without STCA,
    APW and MSAW."""
    plane = SystemPlane(settings.system.center_lat, settings.system.center_lon)
    try:
        SafetyNets(settings.safety_nets, plane, hooks=Hooks(), base_dir=base_dir)
    except (OSError, ValueError) as exc:
        return f"[safety_nets]: {exc}"
    return None


class SafetyNets:
    """STCA, APW and MSAW over the fused tracks, with the alert life cycle and hooks.

    ``SafetyNets(config, plane)``; then once per closed period
    ``alerts = nets.update(t_s, tracks)`` with the period's
    :class:`~radar_fusion.engine.columns.TrackColumns`. ``counters`` (periods, hits and
    alerts by function, hook alerts and hook errors; event counts that only grow) is
    merged into the health message's counters by ``Engine.health`` with the prefix
    ``safety_nets_``; ``hook_errors`` counts failures per hook; ``last_candidate_pairs``
    is the STCA pair count after pruning.
    """

    def __init__(
        self,
        config: SafetyNetsConfig | None = None,
        plane: SystemPlane | None = None,
        hooks: Hooks | None = None,
        base_dir: Path | None = None,
    ) -> None:
        self.config = config or SafetyNetsConfig()
        if plane is None:
            raise ValueError("SafetyNets needs the system plane")
        self.plane = plane
        cfg = self.config

        def resolve(p: Path) -> Path:
            return p if p.is_absolute() or base_dir is None else Path(base_dir) / p

        self.areas: list[Area] = load_areas(resolve(cfg.areas_file), plane) if cfg.areas_file else []
        self.msa: MsaMap | None = load_msa(resolve(cfg.msa_file), plane) if cfg.msa_file else None
        self.stca = Stca(cfg, plane)
        if hooks is None:
            hooks = load_hooks(cfg, plane) if cfg.load_entry_point_hooks else Hooks()
        self.hooks = hooks
        self.hook_errors: dict[str, int] = {}
        # every key present from the start, so that each health counter exists at zero
        self.counters: Counter[str] = Counter(
            dict.fromkeys(
                ["periods", "alerts_new", "alerts_ended", "hook_alerts", "hook_alerts_invalid", "hook_errors"]
                + [f"{what}_{kind}" for kind in ALERT_KINDS for what in ("hits", "alerts_new", "alerts_ended")],
                0,
            )
        )
        self.life_cycle = AlertLifeCycle(cfg)
        self.vertical_history = VerticalRateHistory()

    @classmethod
    def from_settings(cls, settings: Settings, base_dir: Path | None = None) -> SafetyNets:
        """Build from the daemon's ``Settings`` (its ``safety_nets`` section and ``system`` centre)."""
        plane = SystemPlane(settings.system.center_lat, settings.system.center_lon)
        return cls(settings.safety_nets, plane, base_dir=base_dir)

    @property
    def last_candidate_pairs(self) -> int:
        """STCA candidate pairs of the last period after pruning (a scale figure for tests and the benchmark)."""
        return self.stca.last_candidate_pairs

    @property
    def active_alerts(self) -> list[dict]:
        """The confirmed alerts currently open (for a health or status view)."""
        return self.life_cycle.active_alerts

    def update(self, t_s: float, tracks: TrackColumns) -> list[dict]:
        """Run the safety nets for one closed period; return this period's Alert dicts."""
        cfg = self.config
        self.counters["periods"] += 1
        accel = self.vertical_history.update(float(t_s), tracks.track_id, tracks.vrate_fpm)
        hits: list[Hit] = []
        if cfg.stca_enabled and len(tracks):
            hits += self._count_hits("stca", self.stca.hits(tracks, accel))
        if cfg.apw_enabled and self.areas and len(tracks):
            hits += self._count_hits("apw", apw_hits(cfg, self.areas, tracks, accel))
        if cfg.msaw_enabled and self.msa is not None and len(tracks):
            hits += self._count_hits("msaw", msaw_hits(cfg, self.msa, self.plane, tracks, accel))
        alerts = self.life_cycle.update(float(t_s), hits, tracks.track_id)
        for a in alerts:
            if a["status"] != "ongoing":
                self.counters[f"alerts_{a['status']}"] += 1
                self.counters[f"alerts_{a['status']}_{a['kind']}"] += 1
        for name, fn in self.hooks.functions:
            try:
                produced = fn.update(t_s, tracks) or []
            except Exception as exc:
                self._hook_failed(name, exc)
                continue
            for a in produced:
                try:
                    alerts.append(Alert.model_validate(a).model_dump(exclude_none=True))
                    self.counters["hook_alerts"] += 1
                except ValidationError as exc:
                    self.counters["hook_alerts_invalid"] += 1
                    self._hook_failed(name, exc)
        for name, consumer in self.hooks.consumers:
            for a in alerts:
                try:
                    consumer(dict(a))
                except Exception as exc:
                    self._hook_failed(name, exc)
        return alerts

    def restart(self, t_s: float) -> list[dict]:
        """A new tracks stream (the tracker restarted): its track ids are not the old ones.
        Every open alert ends (returned, status ``ended``, at ``t_s``); the vertical-rate
        history is dropped. Alert ids go on counting (never reused)."""
        alerts = self.life_cycle.update(float(t_s), [], np.empty(0, np.int64))
        for a in alerts:
            self.counters["alerts_ended"] += 1
            self.counters[f"alerts_ended_{a['kind']}"] += 1
        self.vertical_history = VerticalRateHistory()
        return alerts

    def _count_hits(self, kind: str, hits: list[Hit]) -> list[Hit]:
        self.counters[f"hits_{kind}"] += len(hits)
        return hits

    def _hook_failed(self, name: str, exc: BaseException) -> None:
        n = self.hook_errors.get(name, 0) + 1
        self.hook_errors[name] = n
        self.counters["hook_errors"] += 1
        if n <= 3 or n % 1000 == 0:  # bounded log rate
            log.error("safety-net hook %s failed (%d so far): %s: %s", name, n, type(exc).__name__, exc)
