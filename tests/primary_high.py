"""The ``primary-high`` scenario (issue 15, item 1) run in process, and the figures its
goal is stated in: track ids per aircraft, shadow-track time, alerts between a track and
its own shadow, false tracks, completeness (tests/test_primary_high.py asserts them;
``python tests/primary_high.py [seeds...]`` prints them).

Definitions (at every TrackBatch time, confirmed tracks only):

* the confirmed tracks and the existing truth targets are paired by the optimal
  assignment with a cut-off of ``SHADOW_M`` = 1.5 km (tools/gospa.cutoff_assignment,
  GOSPA's with c = 1.5 km, p = 2);
* shadow: a confirmed track left unpaired while within 1.5 km of a target that is paired
  with another track (tools/evaluate.py's "duplicate", with the shorter cut-off and
  confirmed tracks only). Shadow time is the number of such (track, batch) pairs times
  the period; its share is over all confirmed (track, batch) pairs;
* self alert: an STCA alert (its ``new`` message) between a track and a shadow of the
  target that track is paired with, or between two tracks nearest one target within
  1.5 km, at the alert's time;
* false-track fraction: the false tracks of tools/evaluate.py (unassociated for more
  than half their displayed life) over all displayed track ids.
"""

from __future__ import annotations

import sys
import tomllib
from dataclasses import dataclass
from typing import Any

import numpy as np

from radar_fusion.config import settings_from_dict
from radar_fusion.engine import Engine
from radar_fusion.safety_nets import SafetyNets
from radar_fusion.tools import evaluate as ev
from radar_fusion.tools import simulate as sim
from radar_fusion.tools.gospa import cutoff_assignment
from radar_fusion.tools.replay import replay_into_engine
from radar_fusion.tools.truth import interpolate_truth

SHADOW_M = 1500.0


@dataclass
class Figures:
    ids_per_aircraft: float
    shadow_time_s: float
    shadow_share: float
    confirmed_time_s: float
    self_alerts: int
    alerts: int
    false_tracks: int
    displayed_tracks: int
    false_track_fraction: float
    completeness: float
    pos_rms_m: float
    gospa_m: float
    per_target_ids: dict[str, int]
    shadow_s_by_target: dict[str, float]

    def line(self) -> str:
        return (
            f"ids/aircraft {self.ids_per_aircraft:.2f}, shadow {self.shadow_time_s:.0f} s "
            f"({100 * self.shadow_share:.1f} % of {self.confirmed_time_s:.0f} s confirmed), "
            f"self-STCA {self.self_alerts}/{self.alerts}, false {self.false_tracks}/{self.displayed_tracks} "
            f"({100 * self.false_track_fraction:.1f} %), completeness {100 * self.completeness:.1f} %, "
            f"pos RMS {self.pos_rms_m:.0f} m, GOSPA {self.gospa_m:.0f} m"
        )


def truth_of(simulation: Any) -> ev.Truth:
    return simulation.truth  # the simulation's own Truth (tools/truth.py)


def run_engine(scenario: Any, messages: list, **sections: Any) -> tuple[list[dict], list[dict], Engine]:
    """The engine with its safety nets on the scenario's messages: (track batches, alerts, engine)."""
    cfg = tomllib.loads(sim.config_toml(scenario))
    cfg.update(sections)
    settings = settings_from_dict(cfg)
    engine = Engine(settings, SafetyNets.from_settings(settings))
    outputs = replay_into_engine(engine, messages)
    batches = [o.track_batch for o in outputs]
    alerts = [a for o in outputs for a in o.alerts]
    return batches, alerts, engine


def pairing(batches: list[dict], truth: ev.Truth) -> tuple[np.ndarray, list[dict[int, tuple[int, bool]]]]:
    """Per batch, each confirmed track's target: {track id: (target index, paired)} with
    ``paired`` True for the assigned pairs and False for a shadow (unpaired, within
    ``SHADOW_M`` of a paired target: the nearest such); tracks that are neither are left out."""
    times = np.array([float(b["t"]) for b in batches])
    tat = interpolate_truth(truth, times, 10.0)
    out: list[dict[int, tuple[int, bool]]] = []
    for k, b in enumerate(batches):
        tg = np.flatnonzero(tat.exists[:, k])
        conf = [tr for tr in b["tracks"] if tr["status"] == "confirmed"]
        ids = np.array([int(tr["track_id"]) for tr in conf], np.int64)
        txy = np.array([(tr["x_m"], tr["y_m"]) for tr in conf]).reshape(-1, 2)
        gxy = np.column_stack((tat.x_m[tg, k], tat.y_m[tg, k]))
        ai, aj, _ = cutoff_assignment(gxy, txy, SHADOW_M, 2.0)
        of: dict[int, tuple[int, bool]] = {int(ids[j]): (int(tg[i]), True) for i, j in zip(ai, aj)}
        free = np.setdiff1d(np.arange(ids.size), aj)
        if free.size and ai.size:
            d = np.hypot(txy[free, None, 0] - gxy[None, ai, 0], txy[free, None, 1] - gxy[None, ai, 1])
            near = np.argmin(d, axis=1)
            for f, n, dn in zip(free, near, d[np.arange(free.size), near]):
                if dn <= SHADOW_M:
                    of[int(ids[f])] = (int(tg[ai[n]]), False)
        out.append(of)
    return times, out


def figures(batches: list[dict], alerts: list[dict], truth: ev.Truth, period_s: float) -> Figures:
    scores = ev.evaluate(batches, truth)
    times, paired = pairing(batches, truth)
    confirmed_n = sum(sum(tr["status"] == "confirmed" for tr in b["tracks"]) for b in batches)
    shadow_n = 0
    shadow_by_target: dict[str, float] = {}
    for of in paired:
        for tgt, is_pair in of.values():
            if not is_pair:
                shadow_n += 1
                name = truth.target_ids[tgt]
                shadow_by_target[name] = shadow_by_target.get(name, 0.0) + period_s
    new = [a for a in alerts if a.get("status") == "new" and a.get("kind") == "stca"]
    self_alerts = 0
    for a in new:
        k = int(np.argmin(np.abs(times - float(a["t"]))))
        pair = [paired[k].get(int(i)) for i in a["track_ids"]]
        if all(p is not None for p in pair) and len({p[0] for p in pair if p is not None}) == 1:
            self_alerts += 1
    return Figures(
        ids_per_aircraft=scores.track_ids_per_target_mean,
        shadow_time_s=shadow_n * period_s,
        shadow_share=shadow_n / max(confirmed_n, 1),
        confirmed_time_s=confirmed_n * period_s,
        self_alerts=self_alerts,
        alerts=len(new),
        false_tracks=scores.false_tracks,
        displayed_tracks=scores.n_displayed_tracks,
        false_track_fraction=scores.false_tracks / max(scores.n_displayed_tracks, 1),
        completeness=scores.completeness_mean,
        pos_rms_m=scores.pos_rms_m,
        gospa_m=scores.gospa_mean_m,
        per_target_ids={t.target_id: t.n_track_ids for t in scores.targets},
        shadow_s_by_target=shadow_by_target,
    )


def scenario_figures(seed: int = 1, **sections: Any) -> Figures:
    scenario = sim.preset("primary-high", seed=seed)
    simulation = sim.simulate(scenario)
    batches, alerts, _ = run_engine(scenario, simulation.messages, **sections)
    return figures(batches, alerts, truth_of(simulation), scenario.effective_period_s)


if __name__ == "__main__":
    for seed in [int(a) for a in sys.argv[1:]] or [1, 2, 3]:
        f = scenario_figures(seed)
        print(f"seed {seed}: {f.line()}")
        print(f"   ids {f.per_target_ids}\n   shadow s {f.shadow_s_by_target}")
        f = scenario_figures(seed, safety_nets={"stca_unknown_fl": "conflict"})
        print(f"   stca_unknown_fl = conflict: self-STCA {f.self_alerts}/{f.alerts}")
