"""Ground-based safety nets on the fused tracks: STCA, APW and MSAW (DESIGN.md §2, §3).

The engine calls :meth:`SafetyNets.update` once per closed period with the system tracks
as numpy columns (:class:`~radar_fusion.engine.columns.TrackColumns`); it returns the
Alert messages of that period (``new``, ``ongoing`` and ``ended``) as dicts that follow
``wire.Alert`` (v = 1), which the daemon publishes on ``<prefix>/fusion/alerts/<kind>``.
No I/O happens here except reading the area and minimum-safe-altitude files once, at
construction.

References
----------
* [STCA-SPEC] EUROCONTROL Specification for Short Term Conflict Alert
  (EUROCONTROL-SPEC-0107, ed. 1.0, 2007) and the EUROCONTROL Guidelines for STCA, Part I-III
  (2017); Part III / the guidance appendix "Reference STCA system" describes the fine
  filters used here: a *linear prediction filter* (horizontal and vertical linear
  prediction over a look-ahead time, conflict when both separations are predicted below
  their thresholds at the same time), a *current proximity filter* (separations below
  thresholds now) and a *manoeuvre (turn) prediction* for turning aircraft, followed by
  *alert confirmation* over successive cycles to suppress nuisance alerts. Parameters
  may differ per airspace volume (e.g. 3 NM in a TMA, 5 NM en route).
* [APW-GUID] EUROCONTROL Guidelines for Area Proximity Warning, Part I-III (2017): warn
  when a track is inside, or is predicted to penetrate within the look-ahead, a notified
  volume (lateral polygon, lower and upper level).
* [MSAW-GUID] EUROCONTROL Guidelines for Minimum Safe Altitude Warning, Part I-III
  (EUROCONTROL-GUID-160, 2017): warn when a track is below, or its predicted path
  (horizontal prediction plus linear vertical prediction with its vertical rate) will
  descend below, the minimum safe altitude of the terrain/obstacle map.

Modules, in the order a period runs through them
------------------------------------------------
* ``config``: the ``[safety_nets]`` section, :class:`SafetyNetsConfig`;
* ``polygon``, ``areas``: even-odd point-in-polygon, APW volumes and the MSA map;
* ``prediction``: horizontal (linear, turn) and vertical (rate, level-off capture,
  selected level) paths, and the exact conflict test on piecewise-linear paths;
* ``stca``, ``apw``, ``msaw``: the three functions, each returning the period's hits;
* ``life_cycle``: confirmation, ``new`` / ``ongoing`` / ``ended``, alert ids;
* ``hooks``: site plug-ins from Python entry points;
* ``nets``: :class:`SafetyNets`, which runs them all once per period.
"""

from __future__ import annotations

from .areas import Area, MsaMap, load_areas, load_msa
from .config import FT_PER_HPA, STANDARD_PRESSURE_HPA, SafetyNetsConfig, StcaAreaOverride
from .hooks import CONSUMER_GROUP, FUNCTION_GROUP, Hooks, load_hooks
from .nets import SafetyNets
from .polygon import Polygon
from .prediction import segment_conflicts

__all__ = [
    "CONSUMER_GROUP",
    "FT_PER_HPA",
    "FUNCTION_GROUP",
    "STANDARD_PRESSURE_HPA",
    "Area",
    "Hooks",
    "MsaMap",
    "Polygon",
    "SafetyNets",
    "SafetyNetsConfig",
    "StcaAreaOverride",
    "load_areas",
    "load_hooks",
    "load_msa",
    "segment_conflicts",
]
