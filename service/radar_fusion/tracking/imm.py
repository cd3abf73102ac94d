"""Interacting multiple model (IMM) filter over N tracks at once (Blom & Bar-Shalom 1988).

The Singer filter of Shu et al. (singer_filter.py) has one σ_m for every flight phase:
small enough to smooth straight flight, it lags a rate-one turn (≈ 10 m/s² at jet
speed); large enough for the turn, it is noisy in the straight flight that makes up
most of en-route traffic.  The IMM runs M models side by side per track and weighs
them by how well each predicted the measurements (issue 15, item 3).

Models
------
Every model works on the engine's 6-D state ``[x, vx, ax, y, vy, ay]``:

* model 0, *quiet*: a Singer model (singer_filter.py) of σ_m = 0.5 m/s² and α = 1 s⁻¹:
  acceleration that decorrelates within a second is white noise (spectral density
  2ασ_m² = 0.5 m²/s³), so this is the near-constant-velocity model of straight flight;
* model 1, *manoeuvre*: a Singer model of σ_m = 10 m/s², the centripetal acceleration of
  a rate-one (3°/s) turn at ≈ 190 m/s, with a correlation time of 20 s: speed changes,
  turn entries and exits, turns at rates no other model has;
* models 2 onwards, *turns*: coordinated turns (coordinated_turn.py), a right and a left
  one for each rate of ``turn_rates_deg_s`` (none by default) and then for each bank
  angle of ``turn_banks_deg`` (default 15° and 25°, the autopilot's gentle and standard
  turns): a banked turn turns at the rate ω = g tan φ / v of the speed of its mixed
  state (coordinated_turn.py eq. 5), so one model fits its bank at any speed.  A turn
  model's acceleration is the turn's centripetal one.

All models share one state space, so the mixing below is exact (no state padding or
conversion between models, as a coordinated-turn model with the turn rate in the state
would need) and the per-model measurement update is one Kalman update per model.

Why banks, not rates.  Measured side by side (50×3 and ADS-B cases of the bench, and a
900 s case of 65 real flights over Switzerland), fixed rates of 1.5 and 3°/s against
banks of 15° and 25°: on the real flights, whose turns are at 0.5-1°/s (a 25° bank at airliner
speeds), the turning position RMS went 109 → 81 m, straight flight 49.4 → 48.4 m,
velocity 9.4 → 8.6 m/s; on simulated traffic turning at ICAO's rate one or 25° bank,
whichever is less, the turns above 1.5°/s went 69 → 60 m (200 aircraft, 300 s).  A
fixed-rate model fits only the speed at which its rate is a real bank.  The exception is
traffic that turns at exactly those rates whatever its speed: the demo's hand-made turns
at 1.5 and 3°/s (banks of 18-37°) are followed better by the fixed rates (turning 54 against
77 m; straight flight the same); the manoeuvre model takes them with the banked turns.

Gating.  At a turn's onset the quiet model still holds almost all the probability, and
the combined prediction (7-8) is the quiet model's: the plots of the second scan into a
rate-one turn fall 250-300 m off it, outside a 99.9 % gate, and would start a new track,
so the IMM never sees the turn.  An established track therefore gates on every model's
prediction: a plot is in its gate when it is in any model-conditioned gate, d² =
min_j ν_jᵀ S_j⁻¹ ν_j (association.gated_pairs; Bar-Shalom, Li & Kirubarajan 2001,
§11.6.6 discuss validation with the model-conditioned innovation covariances).  A
single envelope of all models about the combined prediction was tried first: left and
right turn models make it an ellipse hundreds of metres wide, which took other
aircraft's primary plots in the primary-high scenario and broke tracks.

The mode switches follow a Markov chain whose per-period transition matrix depends on
the period dt (tracks are predicted over different dt: radars of different rotation
periods, missed scans).  Mode i lasts an exponentially distributed time of mean τ_i
(``*_dwell_s``); the probability of staying in it over dt is

    p_ii(dt) = exp(−dt/τ_i),   p_ij(dt) = (1 − p_ii(dt)) E_ij   (j ≠ i)      (0)

where E_ij is the share of mode i's exits that go to mode j (``IMMParams.exit_shares``):
1/(M − 1) for every j in the textbook IMM and here for every mode but the quiet one, whose
exits go mostly to the turn models (``quiet_exit_manoeuvre_share``),

so the expected sojourn, 1/(1 − p_ii) periods, is ≈ τ_i/dt periods for dt ≪ τ_i (the
usual IMM design rule τ_i = T/(1 − p_ii) of Bar-Shalom, Li & Kirubarajan 2001), and
Π(0) = I: a prediction over dt = 0 changes nothing.  For dt ≪ τ_i, (0) agrees to first
order with the continuous-time chain expm(G·dt); it is not a semigroup (Π(a)Π(b) ≠
Π(a + b)), which does not matter here: the engine always predicts a track from its last
updated state, and IMM mixing does not compose over split intervals anyway.

Switching inside the interval.  The textbook cycle below mixes once per interval, so a
mode can only switch at an update: model j's prediction to t_k assumes mode j throughout
(t_{k−1}, t_k].  A turn starting half-way between two updates is then, in the turn model,
a turn through the whole interval; and since the turn models' own states are carried
forward by their large self-weights μ_{j|j} (in straight flight a 25° turn model's state
runs 5° off the aircraft's course and 25 m to the side it turns to, at 150 km), the state the
evidence of a turn (its roll report, its positions) then selects has turned too far.
Measured on a 25° bank turn entered 2 s after an update (two radars 150 km off, roll
reports, 16 noise draws), the track cut 53-65 m inside the turn for 12 s, where a turn
entered at an update stayed within 25 m.  The engine's cycle (:meth:`IMMFilter.predict`,
:meth:`IMMFilter.predict_update`) therefore runs steps 1-2 ``switch_substeps`` times (K)
over dt/K each, each share mixing (eq. 1-4, with Π(dt/K) and the share before's c̄ as its
prior) the share before's predictions: the modes may switch K times in the interval, a
finer grid of the same continuous-time chain (Π(dt/K)'s stays compose to exp(−dt/τ_i)).
K = 1 is the textbook IMM.  Over the interval c̄ is then μ Π(dt/K)^K, not μ Π(dt): a mode's
stay over dt is still exp(−dt/τ_i), and eq. 0's design rule holds per sub-step.  K is a
number of sub-steps, not a length: after missed scans (an interval of 8-12 s) they are
longer, and a turn entered then is placed as coarsely as before at 4 s.

The other predictions mix once over their span (:meth:`IMMFilter.predict_gate`,
:meth:`IMMFilter.predict_position`: they run for every track every period).  They are not
fed back into the state, but they are used: the gates (each model's predicted position, so
a turn model's gate is still its once-mixed, over-turned one: a wider gate, not a wrong
state), the time alignment of a cluster's plots (the combined velocity), the far-plot check
and a primary plot's altitude; and the output (its position, and ``manoeuvre_prob`` from
μ Π(dt)).  Against what the next update predicts, on the 4,000×10 bench case's tracks:
0.01 m median at 4 s, 2 m for the tracks in a turn model (μ above 0.5); at 12 s (two
missed scans) 0.5 m and 47 m.  With the sub-steps in these too (a trial at the Python
level), turning at 4,000×10 was 89.2 against 90.0 m, for 28 % of the engine's throughput:
not done.

The cycle
---------
Blom & Bar-Shalom (1988), the algorithm's steps 1–4 (interaction, filtering, mode
probability update, combination); the same in Bar-Shalom, Li & Kirubarajan (2001),
§11.6.6 ("the IMM estimator", steps 1–5).  The equations are numbered (0)–(8) here, in
the order of those steps.  With μ_i the mode probabilities
after the last update, p_ij = Π[i, j] from mode i to mode j:

1. Interaction (mixing), in :meth:`IMMFilter.predict`:

       c̄_j = Σ_i p_ij μ_i                                 predicted mode probability  (1)
       μ_{i|j} = p_ij μ_i / c̄_j                           mixing probabilities        (2)
       x⁰_j = Σ_i μ_{i|j} x_i                             mixed states                (3)
       P⁰_j = Σ_i μ_{i|j} [P_i + (x_i − x⁰_j)(x_i − x⁰_j)ᵀ] mixed covariances          (4)

2. Mode-matched prediction, in :meth:`IMMFilter.predict`: model j's own prediction
   (Singer: Shu eq. 8, 11; coordinated turn: coordinated_turn.py eq. 2-4) from
   (x⁰_j, P⁰_j) over each track's dt_s.  The state returned holds
   μ = c̄ of (1): the mode probabilities predicted to the new time, which is also the
   right prior for the next cycle if the track gets no measurement (a coasting track is
   predicted again from this state, and (1)–(4) then mix with c̄).

3. Mode-matched update, in :meth:`IMMFilter.update`: each model's Kalman update (Shu eq.
   7, 9, 10) with the same z and R, and the likelihood of its innovation ν_j, S_j:

       Λ_j = N(ν_j; 0, S_j) = exp(−½ ν_jᵀ S_j⁻¹ ν_j) / (2π √det S_j)                     (5)

4. Mode probability update, in :meth:`IMMFilter.update`:

       μ_j = Λ_j c̄_j / Σ_l Λ_l c̄_l                                                     (6)

   evaluated in the log domain (log Λ_j + log c̄_j, normalised by log-sum-exp), so a
   measurement far from every model's prediction does not underflow to 0/0.

   The aircraft's own roll angle (Mode S BDS 5,0, a plot's ``roll_deg``), where a radar
   read it, is a second measurement of the mode, taken as independent of the position
   given the mode: Λ_j in (5)-(6) becomes Λ_j f_j, f_j = p(roll | model j)
   (:meth:`IMMFilter.roll_log_likelihoods`; an extension, not in the papers).  Each such
   report is checked against the positions by its Bayes factor (:class:`Evidence`), and
   the engine sets aside the reports of a track that the positions keep contradicting.

   The aircraft's own ground speed and true track angle (the same register, the plot's
   ``ground_speed_mps`` and ``track_angle_deg``), where a radar read them, are a second
   measurement of the state: steps 3-4 again, after the position's, with the velocity
   (:meth:`IMMFilter.velocity_update_rows`; sequential updating, exact for measurements
   independent given the state; an extension, not in the papers).

5. Combination, for output only (it is not fed back), in :meth:`IMMFilter.combine`:

       x = Σ_j μ_j x_j                                                                  (7)
       P = Σ_j μ_j [P_j + (x_j − x)(x_j − x)ᵀ]                                         (8)

Steps 1-5 run in compiled loops (imm_kernels.py, numba), 64 tracks at a time in vector
lanes, with Φ_j and Q_j applied from their distinct entries (``model_terms``, computed
here with the models' own formulas; a banked turn's from its mixed state, in the loop).
``mix`` states eq. 1-4 as batched numpy products, and each model's own ``predict`` step 2,
for reading and for the tests.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray
from pydantic import BaseModel, ConfigDict, Field

from . import imm_kernels, singer_filter
from .coordinated_turn import MIN_TURN_SPEED_MPS, BankedTurnModel, CoordinatedTurnModel, bank_of_turn_deg
from .singer_filter import POS_IDX, STATE_DIM, SingerFilter, inv_2x2

__all__ = ["MANOEUVRE", "QUIET", "Evidence", "IMMFilter", "IMMParams", "IMMState"]

Float = NDArray[np.float64]

#: model indices: the quiet model, the manoeuvre model (the turn models follow)
QUIET = 0
MANOEUVRE = 1

_LOG_2PI = math.log(2.0 * math.pi)

#: the blocks of the covariance that association (position, velocity) and the output read
_POSITION_VELOCITY = np.array([0, 1, 3, 4], dtype=np.int64)
_POSITION = np.array([0, 3], dtype=np.int64)

#: the fewest tracks a thread is given a share of (IMMFilter._run_in_shares)
_MIN_SHARE = 256

#: a model of the IMM
Model = SingerFilter | CoordinatedTurnModel | BankedTurnModel

#: dt, tau, terms, family, omega, q_keys; with xm, Pm, mu before them (imm_kernels.predict_block_kernel)
_ModelArgs = tuple[Float, Float, Float, Any, Float, Any]


class IMMParams(BaseModel):
    """Tunables of the IMM (quiet and manoeuvre Singer models, coordinated turns); one home
    for each default, the ``[tracking.imm]`` config section."""

    model_config = ConfigDict(frozen=True, extra="forbid", allow_inf_nan=False)

    quiet_sigma_m_mps2: float = Field(
        0.5,
        gt=0,
        description="σ_m of the quiet (near-constant-velocity) Singer model. Default 0.5 m/s² (≈ 1 kt/s): "
        "the speed changes and heading corrections of straight flight; wind gusts and autopilot hunting "
        "stay well below it. Small enough that straight flight is smoothed over many scans",
    )
    quiet_alpha_per_s: float = Field(
        1.0,
        gt=0,
        description="Singer α = 1/T_c of the quiet model. Default 1 s⁻¹: the quiet model is the near-constant-"
        "velocity model (white acceleration of density 2ασ_m² = 0.5 m²/s³) and the turn models follow the turns. "
        "1/60 s⁻¹ (a minute-long 'lazy turn', the default before the turn models) was measured side by side: "
        "straight flight 59 → 40 m on the bench's 50×3, velocity 13.2 → 10.0 m/s",
    )
    manoeuvre_sigma_m_mps2: float = Field(
        10.0,
        gt=0,
        description="σ_m of the manoeuvre Singer model. Default 10 m/s²: the centripetal acceleration of a "
        "rate-one (3°/s) turn at ≈ 190 m/s, the largest routine civil manoeuvre (25-30° bank)",
    )
    manoeuvre_alpha_per_s: float = Field(
        1.0 / 20.0,
        gt=0,
        description="Singer α of the manoeuvre model. Default 1/20 s⁻¹: in a rate-one turn each axis's "
        "acceleration turns with the heading at ω = 0.052 rad/s, so it decorrelates in ≈ 1/ω ≈ 19 s",
    )
    quiet_dwell_s: float = Field(
        300.0,
        gt=0,
        description="mean time τ a track stays in the quiet mode (p_ii = exp(−dt/τ)). Default 300 s: "
        "civil aircraft fly straight legs of minutes between turns (en route far longer, in a terminal area "
        "a few minutes); at a 4 s scan p_ii ≈ 0.987, in the 0.95-0.99 usual for air-traffic IMMs. Shorter "
        "raises the manoeuvre model's share in straight flight (0.05 at 120 s against 0.02 at 300 s) and "
        "with it the straight-flight noise, for no faster turn detection",
    )
    manoeuvre_dwell_s: float = Field(
        30.0,
        gt=0,
        description="mean time τ in the manoeuvre mode. Default 30 s: a rate-one 90° turn (the usual "
        "vectoring or route turn) lasts 30 s; at a 4 s scan p_ii ≈ 0.875",
    )
    quiet_exit_manoeuvre_share: float = Field(
        0.05,
        ge=0,
        le=1,
        description="share of the quiet mode's exits (eq. 0) that go to the manoeuvre model; the rest go to the "
        "turn models, equally. Default 0.05: straight flight ends in a turn far more often than in anything "
        "else, and the manoeuvre model (the noisiest) stays reachable. With the exits shared equally (1/5 each, "
        "as before): turning position RMS on the 600 s real-flight ADS-B case (turns above 0.5°/s) 69.2 → 67.5 m "
        "(66.9 at 0), on eight simulated cases 84.7 → 83.6 m, straight flight and velocity unchanged",
    )
    prior_manoeuvre_prob: float = Field(
        0.1,
        ge=0,
        le=1,
        description="μ of all the models other than the quiet one together at track initiation, shared "
        "equally among them. Default 0.1: about the share of time τ_m/(τ_q + τ_m) = 30/330 that the Markov "
        "chain spends out of the quiet mode, i.e. no knowledge of the new track",
    )

    turn_rates_deg_s: tuple[float, ...] = Field(
        (),
        description="turn rates of fixed-rate coordinated-turn models (coordinated_turn.py eq. 1-4), each a right "
        "and a left model. Default none: the banked turns below fit real traffic better. 1.5 and 3°/s was the "
        "default before them: a fixed rate fits one speed (rate one is a 25° bank at 85 m/s, a 52° bank at 240 m/s)",
    )
    turn_banks_deg: tuple[float, ...] = Field(
        (15.0, 25.0),
        description="bank angles of the banked coordinated-turn models (coordinated_turn.py eq. 5: the rate "
        "g tan φ / v of the track's speed), each a right and a left model. Default 15° and 25°: the autopilot's "
        "standard bank (25°, the limit of ICAO's 'rate one or 25° bank') and the shallower turns of small course "
        "changes. Measured against fixed rates of 1.5 and 3°/s on 65 real flights over Switzerland (900 s): "
        "turning position RMS 109 → 81 m, straight 49.4 → 48.4 m, velocity 9.4 → 8.6 m/s",
    )
    turn_q_m2_s3: float = Field(
        1.0,
        ge=0,
        description="spectral density q of the white-noise acceleration of the turn models, m²/s³ per axis. "
        "Default 1: a turn flown at its model's rate wanders by about 1 m/s² in speed and rate; turns at "
        "other rates are the manoeuvre model's. 0.3 to 5 changed the turning RMS by less than 2 %",
    )
    turn_dwell_s: float = Field(
        30.0,
        gt=0,
        description="mean time τ in a turn mode. Default 30 s: a 90° turn at rate one; 15 s was measured "
        "worse in turns (71 against 69 m)",
    )
    switch_substeps: int = Field(
        3,
        ge=1,
        le=16,
        description="the track's cycle (a prediction to its next update) mixes and predicts in this many equal "
        "sub-steps, so the mode may switch inside the interval and not only at updates (module docs, 'Switching "
        "inside the interval'). Default 3: with 1, a turn model's state at the first update after a turn's onset "
        "has turned through the whole interval, and the track cut up to 65 m inside the turn at 150 km (a "
        "turn entered half-way between two updates); on the bench's 4,000x10 turning 94.0 -> 90.0 m (2: 91.7, "
        "4: 89.9, 8: 89.7), straight flight unchanged. 1: the textbook IMM, mixing once per interval",
    )

    roll_dap: bool = Field(
        True,
        description="take a plot's Mode S roll angle (BDS 5,0, the wire's roll_deg) as evidence of the mode: "
        "each model's log-likelihood (eq. 5) gains log p(roll | model), the quiet and manoeuvre models centred on "
        "0°, a banked turn on its bank, a fixed-rate turn on the bank of its rate at the track's speed. The roll "
        "shows a turn from the scan it starts, where the positions show it only once the track has drifted "
        "several noise sigmas off (one scan's difference between the turn and the straight prediction, "
        "½ a T² ≈ 34 m at a 4 s scan, is below the fused plots' 60-175 m noise). False: positions alone",
    )
    roll_quiet_sigma_deg: float = Field(
        2.5,
        gt=0,
        description="σ of the roll angle about wings level under the quiet (straight-flight) model, degrees. "
        "Default 2.5°: on the Barcelona hour's 8,984 roll reports, half are within 0.35° of wings level, 90 % "
        "within 2.6°",
    )
    roll_turn_sigma_deg: float = Field(
        5.0,
        gt=0,
        description="σ of the roll angle about a turn model's bank, degrees. Default 5°: half the spacing of the "
        "15° and 25° banks, so a roll between them favours neither",
    )
    roll_manoeuvre_sigma_deg: float = Field(
        40.0,
        gt=0,
        description="σ of the roll angle under the manoeuvre model, degrees, centred on 0°. Default 40°: the "
        "manoeuvre model takes every turn the banked ones do not, so it may not rule out a steep bank (rate one "
        "at 200 m/s is a 47° bank: at 20° the roll favoured it over the quiet model only 5 to 1, at 40° 18 to 1). "
        "20° and 40° gave the same figures to 0.2 m on the 50×3, 1,000×10 and real-path ADS-B cases",
    )
    roll_outlier_share: float = Field(
        0.05,
        gt=0,
        lt=1,
        description="share of roll reports taken as uninformative (uniform over ±90°) whatever the mode: a "
        "wrong register value shifts the odds between two models by at most a peak density over that floor "
        "(~550 for the quiet model's 2.5°, ~270 for a turn's 5° at 5 %), never rules one out",
    )

    roll_check_memory: float = Field(
        0.8,
        ge=0,
        lt=1,
        description="fading factor per report of a track's roll check: the sum s ← memory · s + log BF of its "
        "reports' Bayes factors against the positions (imm.Evidence). A transponder whose roll is wrong (stuck "
        "at 25° in straight flight: −0.6 a report) drives s to about −3; true reports keep it at 0 or above",
    )
    roll_distrust_below: float = Field(
        -2.0,
        lt=0,
        description="a track's roll reports are set aside (weight 0; still checked) when its roll check falls "
        "below this. Default −2.0: a roll stuck at 25° (10°) in straight flight made the track 29 → 76 m "
        "(70 m) without the check, 36 m (50 m) with it, set aside after 3-12 reports. It was −2.5 until the "
        "cycle's switching sub-steps (switch_substeps), with which a stuck roll's reports contradict the "
        "positions a little less (on one test track −0.45 a report on average against −0.5) and that track's "
        "check stayed above −2.5. "
        "On the Barcelona hour's real reports 13 tracks' set aside (12 at −2.5 with one mixing an interval); "
        "on the real-path ADS-B cases none",
    )
    roll_trust_above: float = Field(
        -0.1,
        lt=0,
        description="a track's set-aside roll reports count again once its roll check is back above this: "
        "reports that stay wrong stay out (their check, unapplied, settles near −0.4), reports that come "
        "right come back within a few",
    )

    velocity_dap: bool = Field(
        True,
        description="take a plot's Mode S ground speed and true track angle (BDS 5,0, the wire's ground_speed_mps "
        "and track_angle_deg) as a measurement of the velocity: after the position update, each model's Kalman "
        "update with the velocity (eq. 5-6 again, its likelihood multiplying Λ_j; IMMFilter.velocity_update_rows). "
        "The aircraft's own GNSS/inertial velocity, good to a metre a second, against the 8-15 m/s a track "
        "derives from positions; in a turn it shows the new course at the first report. False: positions alone",
    )
    velocity_from_refused_plots: bool = Field(
        True,
        description="also take the velocity of a Mode S plot whose position the live wild-plot gate refused, "
        "for the live track of its address (with velocity_dap): the reply is the aircraft's, only the plot's "
        "position is off (a reflection, a split plot), and its BDS 5,0 register reads as on any other plot. "
        "Measured on the 1,000x10 wild twin (seed 2): the worst aircraft's coast through a refused plot in a "
        "turn. False: a refused plot is dropped whole",
    )
    velocity_speed_sigma_mps: float = Field(
        0.7,
        gt=0,
        description="σ of a BDS 5,0 ground speed, m/s. Default 0.7 m/s: on the Barcelona hour's straight flight "
        "(3,100-3,500 reports of 144 aircraft) the reports differ from the plots' own speed (a two-sided fit, "
        "itself good to 0.1-0.24 m/s) by 0.5 m/s RMS, the register's 2 kt steps included, with heavy tails "
        "(99th percentile 2-2.7 m/s); the margin is for those",
    )
    velocity_track_sigma_deg: float = Field(
        0.3,
        gt=0,
        description="σ of a BDS 5,0 true track angle, degrees. Default 0.3°: the same comparison gives 0.2° RMS "
        "(0.11° for the core; 99th percentile 1°); the margin is for the tails",
    )
    velocity_age_s: float = Field(
        1.0,
        ge=0,
        description="mean age of a BDS 5,0 report's velocity when the radar reads it, s: the aircraft refreshes the "
        "register at least every 1.3 s (ICAO Doc 9871) and its avionics add their latency. The measurement is "
        "v(t − age) = v(t) − age · a(t) (H picks the velocity less age times the acceleration). Default 1.0 s: "
        "on the Barcelona hour's turns the reported track matches the plots' course 1.0 s (± 0.1) before the "
        "plot (0.9-1.2 s by the reference fit); 0.65 s, half the refresh interval, was measured 1.74 against "
        "1.71° RMS there",
    )
    velocity_age_sigma_s: float = Field(
        0.5,
        ge=0,
        description="σ of that age, s; it adds σ² a aᵀ of each model's acceleration a to the measurement's "
        "covariance, so in a turn the report weighs less. Default 0.5 s: the Barcelona turns' residuals "
        "against the squared turn rate give 0.4-0.6 s",
    )
    velocity_birth_sigma_mps: float = Field(
        10.0,
        ge=0,
        description="σ added to a report's own, per axis, m/s, when it starts a track (engine._initiate): nothing "
        "checks that first report (a gross error is caught at the track's second update, "
        "engine._birth_velocity_refuted), and a wrong one held with a metre a second of certainty drives the "
        "track for scans. Default 10 m/s: a report 40 m/s slow made the track's speed overshoot to 234 m/s "
        "(truth 187) with 0, 213 m/s with 10; on the bench's cases it costs 0.1-0.3 m of position",
    )
    velocity_gate_chi2: float = Field(
        18.4,
        gt=0,
        description="a velocity report whose innovation is beyond this χ² (2 degrees of freedom) under every "
        "model is not used (counted, velocity_reports_refused). Default 18.4: 99.99 %; a register misread or of "
        "another aircraft",
    )
    velocity_air: bool = Field(
        True,
        description="with velocity_dap, also take a plot's Mode S heading and indicated airspeed (BDS 6,0, the "
        "wire's magnetic_heading_deg and indicated_airspeed_mps) as a measurement of the velocity, once the "
        "track has a wind: the air vector (true heading, true airspeed from the IAS at the plot's pressure "
        "altitude in ISA, geo.air_data) plus the track's wind, estimated from the clusters that carry both "
        "registers (engine._air_velocity_and_wind). The radar reads BDS 6,0 on 89 % of the Barcelona hour's "
        "Mode S plots, BDS 5,0 on 21 %: in a turn the velocity is then measured every scan instead of every "
        "fourth. A cluster with a BDS 5,0 report takes that one. False: BDS 5,0 alone",
    )
    magnetic_declination_deg: float = Field(
        0.0,
        ge=-180.0,
        le=180.0,
        description="the site's magnetic declination, degrees east of true north (true heading = magnetic + "
        "this): BDS 6,0 reports the magnetic heading. A wrong value the wind estimate absorbs in straight "
        "flight, but not in turns (1° is 4 m/s across the track at 230 m/s; after a 180° turn the error the wind "
        "absorbed flips sign: 8 m/s). On the "
        "Barcelona hour +1° fits best of 0, 1 and 2° (the air vector plus the wind against BDS 5,0: 3.07, 3.05 and "
        "3.09 m/s RMS)",
    )
    air_velocity_sigma_mps: float = Field(
        2.5,
        gt=0,
        description="σ per axis of the air vector plus the track's wind as a velocity, m/s. On the Barcelona "
        "hour (every BDS 5,0 report kept or held out at random), the measurement the engine forms, against the "
        "held-out report of the same plot: 2.1 m/s median, 4.3 RMS (magnitude) in straight flight, the tails "
        "from winds that have changed; the tracks' velocity against the held-out reports, straight flight: "
        "2.99 m/s RMS with 2.5, 3.23 with 1.5 (turns above 1°/s: 6.49 and 6.44; without BDS 6,0: 3.24 and 7.44)",
    )
    air_velocity_age_s: float = Field(
        -1.0,
        description="mean age of a BDS 6,0 heading's velocity when the radar reads it, s, as velocity_age_s "
        "for BDS 5,0 (velocity_age_sigma_s is the spread of both). Negative: the heading leads the course. "
        "On the Barcelona hour's turns the air vector plus the wind matches BDS 5,0 best with the heading of "
        "2 s before it (turns above 1°/s: 5.3 m/s RMS against 7.8 with the heading of the same plot; 1.5 and "
        "2.5 s are worse), and BDS 5,0 runs 1.0 s behind the plots' course",
    )
    wind_time_constant_s: float = Field(
        15.0,
        gt=0,
        description="the track's wind estimate follows its samples (a BDS 5,0 ground velocity less the BDS 6,0 "
        "air vector of one cluster) with this time constant, s. It absorbs, besides the wind, what the air "
        "vector gets wrong by a constant: the day's temperature off ISA (1 % of the airspeed for 3 K), a "
        "heading offset. On the Barcelona hour a shorter one predicts the next report better (straight: 1.8, "
        "2.0, 2.3 m/s RMS at 10, 20, 30 s; turns 5.1, 5.3, 5.6); 15 s keeps two or three samples of a "
        "simulated radar's noise",
    )
    wind_sample_max_accel_mps2: float = Field(
        2.0,
        gt=0,
        description="a cluster's wind sample is taken only while the track's acceleration is below this, m/s²: "
        "the two registers' ages differ by two seconds, which in a 3°/s turn turns the velocity by 6° "
        "(24 m/s at 230 m/s). Default 2 m/s²: a turn of 0.5°/s at 230 m/s",
    )
    wind_layer_ft: float = Field(
        2000.0,
        gt=0,
        description="height of the layers of the shared wind, ft: all aircraft of a layer share its air mass, and a "
        "track without a wind of its own takes its layer's (engine._layer_winds, the median of its tracks' own). "
        "An aircraft whose radars have not read its BDS 5,0 yet (a quarter of the Mode S scans: for a 12 s radar, "
        "48 s on average) then has its velocity measured from its second update on; at 4,000x10 the worst "
        "turning errors (0.6-1.5 km, a two-point start in a turn on one 12 s radar) were of such tracks",
    )
    wind_layer_update_s: float = Field(
        10.0,
        gt=0,
        description="how often the layers' wind is taken again, s: per layer, the median of the own winds its "
        "tracks hold (engine._layer_winds)",
    )
    wind_layer_keep_s: float = Field(
        600.0,
        gt=0,
        description="a layer whose tracks hold no wind of their own keeps its last one this long, s, then has none",
    )
    wind_max_mps: float = Field(
        120.0,
        gt=0,
        description="a wind sample faster than this, m/s, is refused (wind_samples_refused): the strongest jet "
        "streams blow 100 m/s; faster is a misread register",
    )
    wind_sample_gate_mps: float = Field(
        20.0,
        gt=0,
        description="a wind sample farther than this, m/s, from the track's own wind (for its first: its layer's) is "
        "refused (wind_samples_refused). A misread BDS 5,0 or BDS 6,0 makes samples of 100 m/s and more off (a "
        "review's run with 3 % of BDS 5,0 track angles 90° off: turning 65 -> 373 m without this check); on the "
        "Barcelona hour consecutive samples of one aircraft differ by 2.3 m/s RMS, 4.6 at the 95th percentile",
    )
    air_gate_chi2: float = Field(
        40.0,
        gt=0,
        description="an air vector plus wind beyond this χ² (2 dof) of the combined state's velocity is refused "
        "before the update (counted with velocity_reports_refused; engine._air_velocity_and_wind). The update's "
        "own gate (velocity_gate_chi2) asks whether any one model takes a report, and the manoeuvre model, its "
        "velocity 15-35 m/s uncertain, took headings 90° off (a review's run, 3 % of them: straight flight "
        "41.7 -> 119 m). Default 40: with it that run is 41.4 m; 18.4 refused 2 % of the good reports of 40 "
        "aircraft in 2°/s turns (turning 67.7 m against 65.0), 80 let the misread ones through (77.7 m)",
    )
    air_min_ias_mps: float = Field(
        25.7,
        ge=0,
        description="an indicated airspeed below this, m/s, is not used (engine._air_velocity): 50 kt, below any "
        "aircraft's flying speed; on the ground or on a take-off roll the pitot reads little of the air mass",
    )
    wind_layer_sigma_mps: float = Field(
        5.0,
        ge=0,
        description="σ per axis added to air_velocity_sigma_mps where a track takes its layer's wind, m/s: the "
        "wind varies over a layer and across the coverage, and the layer's mean does not hold the aircraft's "
        "own errors of the air vector (the day's temperature off ISA is 1 % of the airspeed along the heading)",
    )
    air_rotation_error_rel: float = Field(
        0.02,
        ge=0,
        description="the air vector's own error that a track's wind absorbs, relative to the airspeed: the day's "
        "temperature off ISA (1 % for 5 K) and the aircraft's heading error (1 % for 0.6°) make an error along "
        "and across the heading that turns with it. Its wind, taken at one heading, then misses it by "
        "2 sin(Δψ/2) times that at a heading Δψ away, and the measurement's σ per axis grows by as much "
        "(engine._air_velocity_and_wind): in a turn the error is systematic over the turn's every report, and "
        "taken at its straight-flight σ the reports (90 % of the Mode S plots) slowed the track's speed by 1-3 "
        "m/s and left it 50 m behind (50x3, a 25° bank turn seen by three radars). Default 2 %",
    )
    wind_max_age_s: float = Field(
        60.0,
        gt=0,
        description="a track's wind older than this, s, is not used (its layer's is, with wind_layer_sigma_mps): "
        "what the air vector gets wrong drifts. On the Barcelona hour the air vector plus a wind older than "
        "that was 8 m/s or more off the plot's own BDS 5,0 (half the time 190 s old or more), against a median "
        "of 2.3 m/s over all",
    )
    wind_max_climb_ft: float = Field(
        1000.0,
        gt=0,
        description="a track's wind taken more than this below or above its present level, ft, is not used (its "
        "layer's is): the wind changes with height (on the Barcelona hour from 5 m/s near the ground to 35 m/s "
        "at FL350)",
    )

    def models(self) -> tuple[Model, ...]:
        """The models, in mode order (QUIET, MANOEUVRE, then a right and a left turn for each
        fixed rate and then for each bank angle)."""
        out: tuple[Model, ...] = (
            SingerFilter(alpha_per_s=self.quiet_alpha_per_s, sigma_m_mps2=self.quiet_sigma_m_mps2),
            SingerFilter(alpha_per_s=self.manoeuvre_alpha_per_s, sigma_m_mps2=self.manoeuvre_sigma_m_mps2),
        )
        for rate in self.turn_rates_deg_s:
            out += (CoordinatedTurnModel(rate, self.turn_q_m2_s3), CoordinatedTurnModel(-rate, self.turn_q_m2_s3))
        for bank in self.turn_banks_deg:
            out += (BankedTurnModel(bank, self.turn_q_m2_s3), BankedTurnModel(-bank, self.turn_q_m2_s3))
        return out

    def dwell_s(self) -> Float:
        """Mean sojourn time τ_i of each mode, (M,)."""
        turns = [self.turn_dwell_s] * (2 * (len(self.turn_rates_deg_s) + len(self.turn_banks_deg)))
        return np.array([self.quiet_dwell_s, self.manoeuvre_dwell_s, *turns])

    def exit_shares(self) -> Float:
        """E (M, M) of eq. 0: the share of mode i's exits that go to mode j, rows summing to 1,
        zero on the diagonal. The quiet mode's go to the manoeuvre model by
        ``quiet_exit_manoeuvre_share`` and to the turn models equally by the rest (all to the
        manoeuvre model without turn models); every other mode's go equally to the others,
        1/(M − 1) each (the textbook IMM's rule for every mode)."""
        m = self.dwell_s().size
        e = np.full((m, m), 1.0 / (m - 1))
        if m > 2:
            e[0, 1] = self.quiet_exit_manoeuvre_share
            e[0, 2:] = (1.0 - self.quiet_exit_manoeuvre_share) / (m - 2)
        np.fill_diagonal(e, 0.0)
        return e

    def prior_mu(self) -> Float:
        """Mode probabilities of a new track, (M,): ``prior_manoeuvre_prob`` shared by the
        models other than the quiet one."""
        m = self.dwell_s().size  # the model count
        return np.array([1.0 - self.prior_manoeuvre_prob] + [self.prior_manoeuvre_prob / (m - 1)] * (m - 1))


@dataclass
class Evidence:
    """What a cycle does with ``mode_loglik`` besides adding it: ``weight`` (N,) scales it
    in each track's log-likelihood (None: 1; 0: a track whose reports are not trusted,
    engine), and the kernels write into ``log_bayes_factor`` (N,) how much more likely
    the position became with it, whatever its weight:

        log [Σ_j c̄_j f_j Λ_j / Σ_j c̄_j f_j] − log Σ_j c̄_j Λ_j,     log f_j = mode_loglik_j

    (eq. 1, 5): 0 without any, about 0 or above for a report the positions bear out (a
    turn the roll shows before the track does: +2.5 at its first scan), below 0 for one
    they contradict (a roll of 25° reported in straight flight: −0.6 a report)."""

    log_bayes_factor: Float
    weight: Float | None = None


@dataclass
class IMMState:
    """Per-track, per-model state of the IMM.

    x_models (N, M, 6), P_models (N, M, 6, 6), mu (N, M): mode probabilities (after an
    update, posterior; after a prediction, predicted, c̄ of eq. 1).
    """

    x_models: Float
    P_models: Float
    mu: Float

    def __len__(self) -> int:
        return int(self.mu.shape[0])

    def select(self, rows: ArrayLike | slice) -> IMMState:
        """The tracks ``rows`` (index array, boolean mask or slice), as a new state (copies)."""
        idx = rows if isinstance(rows, slice) else np.asarray(rows)
        return IMMState(self.x_models[idx].copy(), self.P_models[idx].copy(), self.mu[idx].copy())


class IMMFilter:
    """IMM filter (module docstring, eq. 0-8) over N tracks of M models; it keeps no
    state between calls (any thread may use it)."""

    def __init__(self, params: IMMParams | None = None, threads: int = 1) -> None:
        self.params = IMMParams() if params is None else params
        #: the per-track kernels run on this many threads, each on a share of the tracks
        #: (``_run_in_shares``); the extra ones are this pool's
        self.threads = max(int(threads), 1)
        self._pool = ThreadPoolExecutor(self.threads - 1, thread_name_prefix="imm") if self.threads > 1 else None
        #: the M models, in mode order
        self.models: tuple[Model, ...] = self.params.models()
        self._dwell_s = self.params.dwell_s()
        self._exit = self.params.exit_shares()
        # the kernels' one array of eq. 0: row 0 the dwell times τ_i, rows 1.. E (imm_kernels._mix)
        self._tau_exit = np.ascontiguousarray(np.vstack([self._dwell_s, self._exit]))
        # step 2 runs each family as one array axis: the Singer models first, then the turns
        singer = [m for m in self.models if isinstance(m, SingerFilter)]
        turns = [m for m in self.models if not isinstance(m, SingerFilter)]
        if tuple(self.models) != (*singer, *turns):
            raise ValueError("the Singer models must come before the turn models")
        ns, nt = len(singer), len(turns)
        # the compiled cycle (imm_kernels.py): each model's family; its turn rate ω, or for a
        # banked turn its signed g tan φ (ω = g tan φ / v, coordinated_turn.py eq. 5)
        self._family = np.array(
            [imm_kernels.SINGER] * ns
            + [imm_kernels.CT if isinstance(m, CoordinatedTurnModel) else imm_kernels.BANK for m in turns],
            dtype=np.int64,
        )
        self._omega_all = np.array(
            [0.0] * ns
            + [m.turn_rate_rad_s if isinstance(m, CoordinatedTurnModel) else m.lateral_accel_mps2 for m in turns]
        )
        self._q_keys = np.array(singer_filter._Q_KEYS, dtype=np.int64)
        self._terms_args = (
            self._family,
            np.array([m.alpha_per_s for m in singer] + [0.0] * nt),
            np.array([m.sigma_m_mps2 for m in singer] + [0.0] * nt),
            self._omega_all,
            np.array([0.0] * ns + [m.q_m2_s3 for m in turns]),
            singer_filter._H2_SERIES,
            np.ascontiguousarray(singer_filter._Q_SERIES_MATRIX),
            singer_filter._SERIES_SWITCH_AT,
        )
        self._warm_up()

    def _warm_up(self) -> None:
        """Run the compiled kernels the engine uses once, on one track: numba compiles them
        (or loads them from its cache) at their first call, which would otherwise fall in
        the first period a daemon processes (0.3 s from the cache, ~20 s when compiling on
        2 cores). The others (predict, update, combine: tests and tools) compile when used."""
        st = self.initiate(np.zeros((1, STATE_DIM)), np.eye(STATE_DIM)[None])
        self.predict_gate(st, np.ones(1))
        self.predict_position_rows(st, np.zeros(1, np.int64), np.ones(1))
        self.predict_update_rows(st, np.zeros(1, np.int64), np.ones(1), np.zeros((1, 2)), np.eye(2)[None])
        if self.params.velocity_dap:
            self.velocity_update_rows(st, np.zeros(1, np.int64), np.zeros((1, 2)), np.eye(2)[None], np.zeros(1))

    @property
    def n_models(self) -> int:
        return len(self.models)

    def transition_matrix(self, dt_s: ArrayLike) -> Float:
        """Per-track Markov matrix Π(dt) (N, M, M), Π[n, i, j] = P(mode j at t+dt | mode i at t)
        (eq. 0).  dt_s below 0 is taken as 0 (no switch)."""
        dt = np.maximum(np.atleast_1d(np.asarray(dt_s, dtype=float)), 0.0)
        tau = self._dwell_s
        m = tau.size
        stay = np.exp(-dt[:, None] / tau[None, :])  # (N, M): p_ii
        pi: Float = (1.0 - stay)[:, :, None] * self._exit[None, :, :]
        diag = np.arange(m)
        pi[:, diag, diag] = stay
        return pi

    def initiate(self, x: ArrayLike, P: ArrayLike, mu: ArrayLike | None = None) -> IMMState:
        """IMM state of new tracks: the initiated (x (N,6), P (N,6,6)) in every model, with
        the prior mode probabilities (``params.prior_mu()`` unless ``mu`` (M,) or (N, M))."""
        x = np.asarray(x, dtype=float)
        P = np.asarray(P, dtype=float)
        n, m = x.shape[0], self.n_models
        mu0 = self.params.prior_mu() if mu is None else np.asarray(mu, dtype=float)
        return IMMState(
            np.repeat(x[:, None, :], m, axis=1),
            np.repeat(P[:, None, :, :], m, axis=1),
            np.array(np.broadcast_to(mu0, (n, m)), dtype=float),  # a writable copy, not a broadcast view
        )

    def mix(self, state: IMMState, dt_s: ArrayLike) -> tuple[Float, Float, Float]:
        """Interaction (eq. 1-4): predicted mode probabilities c̄ (N, M) and the mixed
        initial conditions x⁰ (N, M, 6), P⁰ (N, M, 6, 6) of each model."""
        n, m = len(state), self.n_models
        # Π(dt) of eq. 0 (as transition_matrix) laid out as (N, M_j, M_i), so the μ_{i|j}
        # come out contiguous for the products below: p_ij μ_i with p_ij = (1 − p_ii) E_ij
        # off the diagonal
        dt = np.maximum(np.broadcast_to(np.asarray(dt_s, dtype=float), (n,)), 0.0)
        stay = np.exp(-dt[:, None] / self._dwell_s[None, :])  # (N, M): p_ii
        joint_t = ((1.0 - stay) * state.mu)[:, None, :] * self._exit.T[None, :, :]
        diag = np.arange(m)
        joint_t[:, diag, diag] = stay * state.mu  # joint_t[n, j, i] = p_ij μ_i
        c_bar = joint_t.sum(axis=2)  # eq. 1
        # eq. 2; a mode j that nothing can reach (c̄_j = 0: μ_j = 0 and dt = 0) keeps its own state
        unreachable = c_bar <= 0.0
        if unreachable.any():
            joint_t = np.where(unreachable[:, :, None], np.eye(m)[None], joint_t)
            c_bar_div = np.where(unreachable, 1.0, c_bar)
        else:
            c_bar_div = c_bar
        wt = joint_t / c_bar_div[:, :, None]  # μ_{i|j} as (N, M_j, M_i)
        x0 = wt @ state.x_models  # eq. 3
        # eq. 4 as Σ_i μ_{i|j} (P_i + e_i e_iᵀ) − e⁰_j e⁰_jᵀ with e_i = x_i − r, e⁰_j = x⁰_j − r
        # (Σ_i μ_{i|j} = 1), for any r: one (M×M)·(M×36) product per track instead of M²
        # outer products. r = model 0's state keeps the e small (metres, not the 10⁵ m of a
        # position), so nothing cancels.
        ref = state.x_models[:, :1, :]
        e = state.x_models - ref
        e0 = x0 - ref
        second = np.einsum("nmk,nml->nmkl", e, e)  # the outer products (einsum: faster than broadcasting)
        second += state.P_models
        P0 = (wt @ second.reshape(n, m, STATE_DIM * STATE_DIM)).reshape(state.P_models.shape)
        P0 -= np.einsum("nmk,nml->nmkl", e0, e0)
        # exactly symmetric as it stands (the P_i are, and every term is formed the same way
        # for (k, l) and (l, k)): no symmetrisation needed
        return c_bar, x0, P0

    def model_terms(self, dt_s: Float) -> Float:
        """The distinct entries of every model's Φ_j and Q_j over each track's dt_s, (N, M,
        imm_kernels.TERMS), by the models' formulas: the Singer models' Φ entries of Shu
        eq. 12 and q_ij of §4 (singer_filter.py, its series and switch), the turns' T_s, T_c,
        cos ωT, sin ωT of eq. 2 and q f_pp, q f_pv, q f_po, q T of eq. 3
        (coordinated_turn.py); a banked turn's q alone, since the rest depends on its mixed
        state; compiled (imm_kernels.model_terms_kernel).  imm_kernels applies them as the
        rows of Φ_j and the entries of Q_j that singer_filter.singer_matrices_into and
        coordinated_turn.ct_matrices_into lay out."""
        out = np.empty((dt_s.size, self.n_models, imm_kernels.TERMS))
        imm_kernels.model_terms_kernel(_c64(dt_s), *self._terms_args, out)
        return out

    def _run_in_shares(self, n: int, share: Callable[[int, int], None]) -> None:
        """share(a, b) for the rows a:b of n, in ``threads`` shares at once: the calling
        thread takes the first, the pool the others. The kernels release the GIL (nogil,
        imm_kernels.py) and each share writes only its own rows, so the shares run in
        parallel and the result is the same to the bit as one call over all rows. Below
        ``_MIN_SHARE`` rows a share, fewer shares (a pool's hand-over costs ~50 µs)."""
        k = min(self.threads, n // _MIN_SHARE)
        if self._pool is None or k < 2:
            share(0, n)
            return
        edges = [n * c // k for c in range(k + 1)]
        others = [self._pool.submit(share, edges[c], edges[c + 1]) for c in range(1, k)]
        share(edges[0], edges[1])
        for f in others:
            f.result()

    def _dt(self, dt_s: ArrayLike, n: int) -> Float:
        return np.ascontiguousarray(np.broadcast_to(np.asarray(dt_s, dtype=float), (n,)))

    def _model_args(self, dt: Float) -> _ModelArgs:
        """dt, the dwell times and exit shares of eq. 0, the models' Φ and Q
        (imm_kernels.predict_block_kernel)."""
        return (dt, self._tau_exit, self.model_terms(dt), self._family, self._omega_all, self._q_keys)

    def _cycle_args(self, dt: Float) -> tuple[Float, Float, Float, Any, Float, Any, int]:
        """_model_args of one sub-step, dt / ``switch_substeps``, and the number of sub-steps
        (imm_kernels.predict_kernel, predict_update_kernel: "Switching inside the interval")."""
        k = int(self.params.switch_substeps)
        if k < 1:  # the kernels would scatter their scratch arrays unset
            raise ValueError(f"switch_substeps must be at least 1, not {k}")
        return (*self._model_args(np.ascontiguousarray(dt / k)), k)

    def predict(self, state: IMMState, dt_s: ArrayLike) -> IMMState:
        """Steps 1-2: mixing (eq. 1-4) and each model's prediction (step 2 above) over dt_s
        (scalar or (N,)), in ``switch_substeps`` shares ("Switching inside the interval").
        The result carries μ = c̄ (eq. 1) of the last share.

        Every model is linear, x_j = Φ_j x⁰_j, P_j = Φ_j P⁰_j Φ_jᵀ + Q_j (Shu eq. 8, 11;
        coordinated_turn.py eq. 4): the same equations as each model's ``predict``, run by
        imm_kernels.predict_kernel."""
        n, m = len(state), self.n_models
        dt = self._dt(dt_s, n)
        x_pred = np.empty((n, m, STATE_DIM))
        P_pred = np.empty((n, m, STATE_DIM, STATE_DIM))
        c_bar = np.empty((n, m))
        dt, tau, terms, family, omega, q_keys, substeps = self._cycle_args(dt)
        imm_kernels.predict_kernel(
            *_arrays(state), dt, tau, terms, family, omega, q_keys, substeps, x_pred, P_pred, c_bar
        )
        return IMMState(x_pred, P_pred, c_bar)

    def predict_position(self, state: IMMState, dt_s: ArrayLike) -> tuple[Float, Float]:
        """Steps 1, 2 and 5 for an output that needs only the combined state and the
        position block of its covariance: x (N, 6) of eq. 7 and H P Hᵀ (N, 2, 2) of eq. 8,
        from each model's H P_j Hᵀ = (H Φ_j) P⁰_j (H Φ_j)ᵀ + H Q_j Hᵀ (H picks x and y):
        the per-model 6×6 covariances are never formed (imm_kernels.predict_block_kernel).
        One mixing over dt_s whatever ``switch_substeps`` ("Switching inside the
        interval"): combine(predict(...)) of the filter with switch_substeps = 1, restricted
        to x and y, to round-off."""
        x, P = self.predict_position_rows(state, np.arange(len(state)), dt_s)
        return x, P[:, POS_IDX[:, None], POS_IDX[None, :]]

    def predict_position_rows(self, state: IMMState, rows: ArrayLike, dt_s: ArrayLike) -> tuple[Float, Float]:
        """predict_position() of the rows ``rows`` of ``state`` (a track table's columns),
        without copying them out; P (K, 6, 6) holds the x-y block, NaN elsewhere (what the
        engine's output reads)."""
        x, P, _, _ = self._predict_block(state, np.ascontiguousarray(rows, dtype=np.int64), dt_s, _POSITION)
        return x, P

    def _predict_block(
        self, state: IMMState, rows: np.ndarray, dt_s: ArrayLike, block: np.ndarray
    ) -> tuple[Float, Float, Float, Float]:
        """imm_kernels.predict_block_kernel on the rows ``rows``: x, P (the block, NaN
        elsewhere), each model's position and its covariance."""
        n, m = rows.size, self.n_models
        dt = self._dt(dt_s, n)
        xy = np.empty((n, m, 2))
        cov = np.empty((n, m, 2, 2))
        x = np.empty((n, STATE_DIM))
        P = np.empty((n, STATE_DIM, STATE_DIM))
        xm, Pm, mu = _arrays(state)
        dt, tau, terms, family, omega, q_keys = self._model_args(dt)

        def share(a: int, b: int) -> None:
            imm_kernels.predict_block_kernel(
                xm, Pm, mu, rows[a:b], dt[a:b], tau, terms[a:b], family, omega, q_keys, block,
                xy[a:b], cov[a:b], x[a:b], P[a:b],
            )  # fmt: skip

        self._run_in_shares(n, share)
        return x, P, xy, cov

    def predict_gate(self, state: IMMState, dt_s: ArrayLike) -> tuple[Float, Float, Float, Float]:
        """Steps 1, 2 and 5 for association, in one pass (imm_kernels.predict_block_kernel):
        each model's predicted position (N, M, 2) and its covariance (N, M, 2, 2), for the
        model-conditioned gates ("Gating" above), and the combination of eq. 7-8: x (N, 6)
        and P (N, 6, 6) with its position and velocity rows and columns, NaN elsewhere.
        combine(predict(...)) and predict()'s positions of the filter with switch_substeps =
        1, to round-off (one mixing over dt_s, as predict_position), without forming the
        per-model 6×6 covariances."""
        return self._predict_block(state, np.arange(len(state)), dt_s, _POSITION_VELOCITY)

    def predict_update(
        self,
        state: IMMState,
        dt_s: ArrayLike,
        z: ArrayLike,
        R: ArrayLike,
        mode_loglik: ArrayLike | None = None,
        evidence: Evidence | None = None,
    ) -> tuple[IMMState, Float, Float]:
        """A whole cycle in one pass (imm_kernels.predict_update_kernel): update(predict(state,
        dt_s), z, R) and its combination (eq. 7-8), without the prediction written out.
        ``mode_loglik`` (N, M), when given, is added to each model's log-likelihood (eq. 5):
        :meth:`roll_log_likelihoods`; ``evidence`` its weights and its Bayes factors."""
        n, m = len(state), self.n_models
        out = IMMState(np.empty((n, m, STATE_DIM)), np.empty((n, m, STATE_DIM, STATE_DIM)), np.empty((n, m)))
        x, P = self._predict_update_into(state, out, np.arange(n), dt_s, z, R, mode_loglik, evidence)
        return out, x, P

    def predict_update_rows(
        self,
        state: IMMState,
        rows: ArrayLike,
        dt_s: ArrayLike,
        z: ArrayLike,
        R: ArrayLike,
        mode_loglik: ArrayLike | None = None,
        evidence: Evidence | None = None,
    ) -> tuple[Float, Float]:
        """predict_update() of the rows ``rows`` of ``state`` (a track table's columns), in
        place: those rows of state's arrays (float64, C-contiguous) become the updated
        states. Returns the combined x (K, 6) and P (K, 6, 6) of the K rows."""
        for a in (state.x_models, state.P_models, state.mu):
            if a.dtype != np.float64 or not a.flags.c_contiguous or not a.flags.writeable:
                raise ValueError("predict_update_rows updates writable float64 C-contiguous arrays in place")
        rows = np.ascontiguousarray(rows, dtype=np.int64)
        return self._predict_update_into(state, state, rows, dt_s, z, R, mode_loglik, evidence)

    def _mode_loglik(
        self, mode_loglik: ArrayLike | None, evidence: Evidence | None, n: int
    ) -> tuple[Float, Float, Float]:
        """The kernels' lf (n, M), its weights lfw (n,) and the out_lbf (n,) to write."""
        lf = np.zeros((n, self.n_models)) if mode_loglik is None else np.asarray(mode_loglik, dtype=np.float64)
        lf = np.ascontiguousarray(np.broadcast_to(lf, (n, self.n_models)))
        w = np.ones(n) if evidence is None or evidence.weight is None else evidence.weight
        lfw = np.ascontiguousarray(np.broadcast_to(np.asarray(w, dtype=np.float64), (n,)))
        lbf = np.empty(n) if evidence is None else evidence.log_bayes_factor
        if lbf.shape != (n,) or lbf.dtype != np.float64 or not lbf.flags.c_contiguous:
            raise ValueError("Evidence.log_bayes_factor: a float64 C-contiguous (N,) array to write")
        return lf, lfw, lbf

    def roll_log_likelihoods(self, roll_deg: ArrayLike, vx_mps: ArrayLike, vy_mps: ArrayLike) -> Float:
        """log p(roll | model j) of each track's Mode S roll angle (BDS 5,0, degrees, positive
        right wing down), (N, M); zero in a row without one (NaN): the term the kernels add to
        log Λ_j of eq. 5, taking the roll and the position as independent given the mode.

        p_j(φ) = (1 − ε) N(φ; φ̄_j, σ_j²) + ε / 180°: φ̄_j is 0 for the Singer models (σ_j
        ``roll_quiet_sigma_deg`` for the quiet one, ``roll_manoeuvre_sigma_deg`` for the
        others), the bank of a banked turn and, for a fixed-rate turn of rate ω, the bank of
        a coordinated turn at the track's speed v, atan(v ω / g) (coordinated_turn.py eq. 5
        turned round), both with σ ``roll_turn_sigma_deg``; ε ``roll_outlier_share``."""
        p = self.params
        roll = np.asarray(roll_deg, dtype=float).reshape(-1)
        n = roll.size
        out = np.zeros((n, self.n_models))
        have = np.flatnonzero(np.isfinite(roll))
        if not p.roll_dap or not have.size:
            return out
        phi = roll[have][:, None]
        speed = np.hypot(
            np.asarray(vx_mps, dtype=float).reshape(-1)[have], np.asarray(vy_mps, dtype=float).reshape(-1)[have]
        )
        mean = np.zeros((have.size, self.n_models))
        sigma = np.empty(self.n_models)
        for j, model in enumerate(self.models):
            if isinstance(model, SingerFilter):
                sigma[j] = p.roll_quiet_sigma_deg if j == 0 else p.roll_manoeuvre_sigma_deg
            elif isinstance(model, BankedTurnModel):
                mean[:, j], sigma[j] = model.bank_deg, p.roll_turn_sigma_deg
            else:  # a fixed rate, positive to the right (CoordinatedTurnModel.turn_rate_deg_s)
                v = np.nan_to_num(np.maximum(speed, MIN_TURN_SPEED_MPS), nan=MIN_TURN_SPEED_MPS)
                mean[:, j] = bank_of_turn_deg(v, math.radians(model.turn_rate_deg_s))
                sigma[j] = p.roll_turn_sigma_deg
        d = (phi - mean) / sigma
        gauss = np.exp(-0.5 * d * d) / (sigma * math.sqrt(2.0 * math.pi))
        eps = p.roll_outlier_share
        out[have] = np.log((1.0 - eps) * gauss + eps / 180.0)
        return out

    def _predict_update_into(
        self,
        state: IMMState,
        out: IMMState,
        rows: np.ndarray,
        dt_s: ArrayLike,
        z: ArrayLike,
        R: ArrayLike,
        mode_loglik: ArrayLike | None = None,
        evidence: Evidence | None = None,
    ) -> tuple[Float, Float]:
        k = rows.size
        dt = self._dt(dt_s, k)
        x = np.empty((k, STATE_DIM))
        P = np.empty((k, STATE_DIM, STATE_DIM))
        xm, Pm, mu = _arrays(state)
        dt, tau, terms, family, omega, q_keys, substeps = self._cycle_args(dt)
        z, R = _c64(z), _c64(R)
        lf, lfw, lbf = self._mode_loglik(mode_loglik, evidence, k)

        def share(a: int, b: int) -> None:
            imm_kernels.predict_update_kernel(
                xm, Pm, mu, rows[a:b], dt[a:b], tau, terms[a:b], family, omega, q_keys, substeps, z[a:b], R[a:b],
                lf[a:b], lfw[a:b], out.x_models, out.P_models, out.mu, x[a:b], P[a:b], lbf[a:b],
            )  # fmt: skip

        self._run_in_shares(k, share)
        return x, P

    def velocity_update_rows(
        self, state: IMMState, rows: ArrayLike, z_v: ArrayLike, R_v: ArrayLike, age_s: ArrayLike
    ) -> tuple[Float, Float, NDArray[np.bool_]]:
        """A second measurement after the position's, in place on the rows ``rows`` of
        ``state`` (updated states, at the time of their measurement): the aircraft's own
        velocity z_v (K, 2) of covariance R_v (K, 2, 2) (Mode S BDS 5,0, in the system
        plane), measured ``age_s`` (K,) before that time.

        Sequential updating, exact for a measurement independent of the position's given
        the state: each model's Kalman update (Shu eq. 7, 9, 10) with

            H = [[0, 1, −a, 0, 0, 0], [0, 0, 0, 0, 1, −a]]     (v(t − a) = v(t) − a·acc(t))
            S_j = H P_j Hᵀ + R_v + σ_a² acc_j acc_jᵀ             (σ_a: ``velocity_age_sigma_s``)

        and the mode probabilities of eq. 5-6 with μ (the position's posterior) as the prior.
        A report beyond ``velocity_gate_chi2`` under every model is not used.

        Returns the combined x (K, 6), P (K, 6, 6) of the rows (eq. 7-8) and the used mask (K,).
        Compiled, one track at a time (imm_kernels.velocity_update_kernel): as batched numpy
        products over (K, M, 6, 6) it took 20 ms for 2,000 tracks."""
        rows = np.ascontiguousarray(rows, dtype=np.int64)
        for arr in (state.x_models, state.P_models, state.mu):
            if arr.dtype != np.float64 or not arr.flags.c_contiguous or not arr.flags.writeable:
                raise ValueError("velocity_update_rows updates writable float64 C-contiguous arrays in place")
        k = rows.size
        x = np.empty((k, STATE_DIM))
        P = np.empty((k, STATE_DIM, STATE_DIM))
        used = np.empty(k, dtype=np.bool_)
        imm_kernels.velocity_update_kernel(
            state.x_models, state.P_models, state.mu, rows,
            _c64(np.reshape(z_v, (-1, 2))), _c64(np.reshape(R_v, (-1, 2, 2))), _c64(np.reshape(age_s, -1)),
            self.params.velocity_age_sigma_s**2, self.params.velocity_gate_chi2, x, P, used,
        )  # fmt: skip
        return x, P, used

    def log_likelihoods(self, state: IMMState, z: ArrayLike, R: ArrayLike) -> Float:
        """log Λ_j (eq. 5) of measurements z (N,2), R (N,2,2) under each model's prediction, (N, M)."""
        n, m = len(state), self.n_models
        nu = np.asarray(z, dtype=float)[:, None, :] - state.x_models[:, :, POS_IDX]
        S = state.P_models[:, :, POS_IDX[:, None], POS_IDX[None, :]] + np.asarray(R, dtype=float)[:, None]
        return _gauss_loglik(nu.reshape(n * m, 2), S.reshape(n * m, 2, 2)).reshape(n, m)

    def update(
        self,
        state: IMMState,
        z: ArrayLike,
        R: ArrayLike,
        mode_loglik: ArrayLike | None = None,
        evidence: Evidence | None = None,
    ) -> IMMState:
        """Steps 3-4: each model's Kalman update (Shu eq. 7, 9, 10) with the fused
        measurement z (N,2) of covariance R (N,2,2), and the mode probabilities (eq. 5-6)
        (imm_kernels.update_kernel); ``mode_loglik`` (N, M) and ``evidence`` as in
        :meth:`predict_update`."""
        n, m = len(state), self.n_models
        x_upd = np.empty((n, m, STATE_DIM))
        P_upd = np.empty((n, m, STATE_DIM, STATE_DIM))
        mu = np.empty((n, m))
        lf, lfw, lbf = self._mode_loglik(mode_loglik, evidence, n)
        imm_kernels.update_kernel(*_arrays(state), _c64(z), _c64(R), lf, lfw, x_upd, P_upd, mu, lbf)
        return IMMState(x_upd, P_upd, mu)

    @staticmethod
    def combine(state: IMMState) -> tuple[Float, Float]:
        """Step 5 (eq. 7-8): the combined estimate x (N,6), P (N,6,6), for output and gating."""
        n = len(state)
        x = np.empty((n, STATE_DIM))
        P = np.empty((n, STATE_DIM, STATE_DIM))
        imm_kernels.combine_kernel(*_arrays(state), x, P)
        return x, P


def _c64(a: ArrayLike) -> Float:
    """float64, C-contiguous: what the compiled kernels take (one signature each; no copy
    in the usual case)."""
    return np.ascontiguousarray(a, dtype=np.float64)


def _arrays(state: IMMState) -> tuple[Float, Float, Float]:
    return _c64(state.x_models), _c64(state.P_models), _c64(state.mu)


def _gauss_loglik(nu: Float, S: Float) -> Float:
    """log N(ν; 0, S) for ν (K,2), S (K,2,2) (eq. 5)."""
    det = S[:, 0, 0] * S[:, 1, 1] - S[:, 0, 1] * S[:, 1, 0]
    d2 = np.einsum("ki,kij,kj->k", nu, inv_2x2(S), nu)
    return np.asarray(-0.5 * d2 - 0.5 * np.log(det) - _LOG_2PI)
