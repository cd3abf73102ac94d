"""The IMM's banked turns (coordinated_turn.py eq. 5) against fixed turn rates, on real
flight paths: the bench's ADS-B case (flights over Switzerland, 2018-08-01 from 11:30 UTC,
a robust smoothing spline of their fixes as the truth; four simulated radars), 600 s.

Real airliners turn at a bank, so at a rate that depends on their speed: here at 0.5-1°/s.
The same plots go through the engine twice, once with the default turn models (banks of
15° and 25°) and once with the fixed rates of 1.5 and 3°/s they replaced; each run's
tracks are scored against the truth by tools/evaluate.py. Measured when written: turning
(truth above 0.5°/s, 61 pairs) 69 m against 100 m, straight flight 47.4 against 48.6 m,
velocity 9.4 against 10.3 m/s. Both without the Mode S roll angle and velocity, which came
later; the second and third tests measure what they add.
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

#: the IMM without the Mode S BDS 5,0 reports (roll angle, ground speed and track angle)
POSITIONS_ONLY = {"roll_dap": False, "velocity_dap": False}


def _scores(case_dir: Path, imm: dict[str, object]) -> ev.Scores:
    with open(case_dir / "engine.pkl", "rb") as f:
        data = pickle.load(f)
    raw = tomllib.loads(data["config_toml"])
    raw.setdefault("tracking", {}).setdefault("imm", {}).update(imm)
    settings = config.settings_from_dict(raw, source="test")
    batches = compare._run_engine_batches(settings, compare._decoded_events(data))
    truth = ev.load_truth(str(case_dir / "truth.csv"))
    return ev.evaluate(batches, truth, ev.EvalParams(settle_s=30.0, turning_above_deg_s=0.5))


def _side_by_side(a: ev.Scores, b: ev.Scores, label: str) -> str:
    return (
        f"\nturning {a.pos_rms_turning_m:.1f} / {b.pos_rms_turning_m:.1f} m, "
        f"straight {a.pos_rms_straight_m:.1f} / {b.pos_rms_straight_m:.1f} m, "
        f"velocity {a.vel_rms_mps:.2f} / {b.vel_rms_mps:.2f} m/s, "
        f"settled {a.vel_rms_settled_mps:.2f} / {b.vel_rms_settled_mps:.2f} m/s ({label})"
    )


@pytest.fixture(scope="module")
def case_dir(tmp_path_factory: pytest.TempPathFactory, shared_data: Path) -> Path:
    assert (shared_data / "adsb" / "switzerland_2018-08-01.json.gz").is_file()  # what the case reads
    out = tmp_path_factory.mktemp("adsb600")
    compare.simulate_case({"kind": "adsb", "duration_s": 600.0, "max_aircraft": 80}, 0, str(out), 30.0)
    return out


def test_banked_turns_follow_real_turns_better_than_fixed_rates(case_dir: Path) -> None:
    banks = _scores(case_dir, POSITIONS_ONLY)
    rates = _scores(case_dir, {"turn_rates_deg_s": [1.5, 3.0], "turn_banks_deg": [], **POSITIONS_ONLY})
    assert banks.n_pairs_turning == rates.n_pairs_turning >= 40
    assert banks.pos_rms_turning_m < 0.8 * rates.pos_rms_turning_m, (banks.pos_rms_turning_m, rates.pos_rms_turning_m)
    assert banks.pos_rms_straight_m < 1.01 * rates.pos_rms_straight_m
    assert banks.vel_rms_mps < rates.vel_rms_mps
    assert banks.pos_rms_m < rates.pos_rms_m
    assert banks.track_ids_per_target_mean <= rates.track_ids_per_target_mean


def test_mode_s_roll_reports_bring_the_turn_models_in_sooner(case_dir: Path) -> None:
    """The same plots with and without the Mode S roll angle (BDS 5,0) as evidence of the
    mode (imm.IMMFilter.roll_log_likelihoods). The simulated Mode S radars report the bank
    of the smoothed real path's turn on a quarter of their plots, as the Barcelona radar
    does. Measured when written: turning 57.0 against 67.6 m (onset 64.4 against 78.9 m),
    straight 46.0 against 47.3 m, velocity 8.48 against 9.04 m/s."""
    roll = _scores(case_dir, {"velocity_dap": False})
    positions = _scores(case_dir, POSITIONS_ONLY)
    print(_side_by_side(roll, positions, "roll / positions alone"))
    assert roll.n_pairs_turning == positions.n_pairs_turning >= 40
    assert roll.pos_rms_turning_m < 0.9 * positions.pos_rms_turning_m
    assert roll.pos_rms_turn_onset_m < 0.9 * positions.pos_rms_turn_onset_m
    assert roll.pos_rms_straight_m <= positions.pos_rms_straight_m
    assert roll.vel_rms_mps < positions.vel_rms_mps
    assert roll.track_ids_per_target_mean <= positions.track_ids_per_target_mean


def test_mode_s_velocity_reports_bring_the_tracks_onto_the_aircrafts_velocity(case_dir: Path) -> None:
    """The same plots with the roll alone and with the aircraft's own ground speed and true
    track angle as well (BDS 5,0, on the same quarter of the Mode S plots: the truth's
    velocity 0.15-1.85 s before the read, 0.5 m/s and 0.2° of noise; imm.IMMFilter.
    velocity_update_rows). Measured when written: turning 39.0 against 57.0 m, straight 27.8
    against 46.0 m, velocity 4.85 against 8.48 m/s (settled 3.66 against 5.56 m/s)."""
    both = _scores(case_dir, {})
    roll = _scores(case_dir, {"velocity_dap": False})
    print(_side_by_side(both, roll, "velocity / roll alone"))
    assert both.n_pairs_turning == roll.n_pairs_turning >= 40
    assert both.vel_rms_settled_mps < 0.85 * roll.vel_rms_settled_mps
    assert both.pos_rms_straight_m < 0.9 * roll.pos_rms_straight_m
    assert both.pos_rms_turning_m < 0.9 * roll.pos_rms_turning_m
    assert both.track_ids_per_target_mean <= roll.track_ids_per_target_mean
    assert both.false_tracks <= roll.false_tracks
