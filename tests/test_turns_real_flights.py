"""The IMM's banked turns (coordinated_turn.py eq. 5) against fixed turn rates, on real
flight paths: the bench's ADS-B case (flights over Switzerland, 2018-08-01 from 11:30 UTC,
a robust smoothing spline of their fixes as the truth; four simulated radars), 600 s.

Real airliners turn at a bank, so at a rate that depends on their speed: here at 0.5-1°/s.
The same plots go through the engine twice, once with the default turn models (banks of
15° and 25°) and once with the fixed rates of 1.5 and 3°/s they replaced; each run's
tracks are scored against the truth by tools/evaluate.py. Measured when written: turning
(truth above 0.5°/s, 61 pairs) 69 m against 100 m, straight flight 47.4 against 48.6 m,
velocity 9.4 against 10.3 m/s.
"""

from __future__ import annotations

import pickle
import tomllib
from pathlib import Path

import pytest

from radar_fusion import config
from radar_fusion.tools import evaluate as ev
from radar_fusion.tools.bench import compare

pytestmark = pytest.mark.slow


def _scores(case_dir: Path, imm: dict[str, object]) -> ev.Scores:
    with open(case_dir / "engine.pkl", "rb") as f:
        data = pickle.load(f)
    raw = tomllib.loads(data["config_toml"])
    raw.setdefault("tracking", {}).setdefault("imm", {}).update(imm)
    settings = config.settings_from_dict(raw, source="test")
    batches = compare._run_engine_batches(settings, compare._decoded_events(data))
    truth = ev.load_truth(str(case_dir / "truth.csv"))
    return ev.evaluate(batches, truth, ev.EvalParams(settle_s=30.0, turning_above_deg_s=0.5))


def test_banked_turns_follow_real_turns_better_than_fixed_rates(tmp_path: Path, shared_data: Path) -> None:
    assert (shared_data / "adsb" / "switzerland_2018-08-01.json.gz").is_file()  # what the case reads
    case = {"kind": "adsb", "duration_s": 600.0, "max_aircraft": 80}
    compare.simulate_case(case, 0, str(tmp_path), 30.0)
    banks = _scores(tmp_path, {})
    rates = _scores(tmp_path, {"turn_rates_deg_s": [1.5, 3.0], "turn_banks_deg": []})
    assert banks.n_pairs_turning == rates.n_pairs_turning >= 40
    assert banks.pos_rms_turning_m < 0.8 * rates.pos_rms_turning_m, (banks.pos_rms_turning_m, rates.pos_rms_turning_m)
    assert banks.pos_rms_straight_m < 1.01 * rates.pos_rms_straight_m
    assert banks.vel_rms_mps < rates.vel_rms_mps
    assert banks.pos_rms_m < rates.pos_rms_m
    assert banks.track_ids_per_target_mean <= rates.track_ids_per_target_mean
