"""Issue 15, item 1's goal scenario: a primary-only radar and aircraft at FL300-400
(``primary-high``, tools/simulate/presets.py), run in process with the safety nets; the
figures as defined in tests/primary_high.py.

Goal: no shadow track, no STCA alert between a track and its own shadow, <= 1.05 track
ids per aircraft, false-track fraction <= 2 %; each primary-only aircraft keeps one
track. The shadow tolerance is one period per run (4 s of ~2,900 s of confirmed track
time): a track whose aircraft passes within 1.5 km of another's biased primary-only track
is counted for the batch in which the assignment swaps them over.

On main before this work (1440666), seeds 1-3: 1.10 ids per aircraft each, 4-8 s of
shadow per run, and with ``stca_unknown_fl = "conflict"`` one self alert per run. Over
seeds 1-16 (tests/primary_high.py): ids 1.069 -> 1.006, shadow 88 -> 44 s, self alerts
1 -> 0 (11 -> 1 with "conflict": a Mode S plot without Mode C, converted at the assumed
height, started a track before the primary track had an altitude), false tracks 5/177
-> 4/166 (2.4 %: clutter of both radars confirmed at its second update; seeds 1-3 have
none).
"""

from __future__ import annotations

import numpy as np
import pytest

from primary_high import scenario_figures

PRIMARY_ONLY = ("H07", "H08", "H09", "H10")  # outside the SSR's coverage, or no transponder
PERIOD_S = 4.0


@pytest.mark.slow
def test_primary_high_scenario_meets_the_goal():
    runs = [scenario_figures(seed) for seed in (1, 2, 3)]
    for f in runs:
        print(f.line(), f.shadow_s_by_target)
    ids = np.mean([f.ids_per_aircraft for f in runs])
    assert ids <= 1.05, [f.per_target_ids for f in runs]
    for f in runs:
        assert f.shadow_time_s <= PERIOD_S, f.shadow_s_by_target
        assert f.self_alerts == 0
        assert all(f.per_target_ids[t] == 1 for t in PRIMARY_ONLY), f.per_target_ids
        assert f.completeness > 0.95
    false = sum(f.false_tracks for f in runs) / sum(f.displayed_tracks for f in runs)
    assert false <= 0.02, [(f.false_tracks, f.displayed_tracks) for f in runs]
    # tracks without flight level in conflict with all: still no alert against a shadow
    for seed in (1, 2, 3):
        f = scenario_figures(seed, safety_nets={"stca_unknown_fl": "conflict"})
        assert f.self_alerts == 0, (seed, f.alerts)
