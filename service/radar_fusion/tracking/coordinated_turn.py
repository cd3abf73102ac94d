"""Coordinated-turn model of known turn rate, over N tracks at once, on the Singer state.

An aircraft in a coordinated turn flies at constant speed while its velocity vector
turns at a constant rate ω (rate one: 3°/s).  Its horizontal motion is

    d/dt [x, y] = [vx, vy],   d/dt [vx, vy] = ω·[−vy, vx]                             (1)

(Bar-Shalom, Li & Kirubarajan 2001, §11.7.1 eq. 11.7.1-4; Blackman & Popoli 1999,
§4.2.2).  For a *known* ω, (1) is linear; over dt = T its exact transition on
``[x, vx, y, vy]`` is

         ⎡1  sin ωT/ω       0  −(1 − cos ωT)/ω⎤
    F =  ⎢0  cos ωT         0  −sin ωT        ⎥                                         (2)
         ⎢0  (1 − cos ωT)/ω 1  sin ωT/ω       ⎥
         ⎣0  sin ωT         0  cos ωT         ⎦

(ibid. eq. 11.7.1-6; ω → 0 gives the constant-velocity transition).  Model errors (a
turn rate other than ω, speed changes, wind) enter as continuous white-noise
acceleration of spectral density q on each axis, the same on both (isotropic).  Its
discrete covariance Q = ∫₀ᵀ F(s) G q Gᵀ F(s)ᵀ ds (Van Loan 1978) has a closed form,
because the velocity block of F(s) is a rotation and its position block a rotation
times a scalar; in the order [x, y] for each block,

    Q_pp = q·2(T − sin ωT/ω)/ω² · I
    Q_pv = q/ω · [[(1 − cos ωT)/ω, T − sin ωT/ω], [−(T − sin ωT/ω), (1 − cos ωT)/ω]]    (3)
    Q_vv = q·T · I

which tends to the constant-velocity model's q·[[T³/3, T²/2], [T²/2, T]] per axis as
ω → 0 (ibid. eq. 6.2.2-12); below |ωT| = 0.01 the series of Q_pp and Q_pv are used.

The engine's state is the Singer filter's ``[x, vx, ax, y, vy, ay]`` (singer_filter.py,
Shu eq. 12), and the IMM (imm.py) mixes every model in that one space.  In a
coordinated turn the acceleration is not free: it is the centripetal acceleration
``[ax, ay] = ω·[−vy, vx]`` of (1).  So the model's transition on the 6-D state is

    Φ = M·F·S,   Q₆ = M·Q·Mᵀ                                                           (4)

where S picks ``[x, vx, y, vy]`` out of the state and M (6×4) writes them back with
ax = −ω·vy and ay = ω·vx.  The state's prior acceleration is dropped (the turn sets it),
and the predicted acceleration is the turn's: a Singer model mixed from this state
continues the turn with its correlated acceleration, and the turn model's covariance of
(ax, ay) is ω² times that of (vy, vx).

A fixed-rate model only fits turns near its rate, and q covers the mismatch of turns at
other rates (a 1.5°/s turn seen by a 3°/s model at 200 m/s: 5 m/s² of model error).

Turns at a bank angle
---------------------
An aircraft turns by banking: in a coordinated (level, unslipped) turn at bank φ the lift's
horizontal part is the centripetal force, so the turn's rate at true airspeed v is

    ω = g tan φ / v                                                                    (5)

(Blackman & Popoli 1999, §4.2.2; the same relation gives ICAO's "rate one or 25° bank,
whichever is less", Doc 8168).  Airliners turn at a bank, not at a rate: the autopilot's
turns are at 25° (heading changes of en-route and terminal procedures) or at 10-15°
(course changes of a few degrees), whatever the speed.  At 240 m/s a 25° bank is 1.1°/s,
at 120 m/s 2.2°/s; a fixed-rate model fits one speed.  :class:`BankedTurnModel` is the
turn of eq. (1-4) at the rate (5) of the speed of the state it predicts from (in the IMM,
the mixed state x⁰_j of the model: eq. 3 of imm.py), ground speed for airspeed (wind
changes the rate by the ratio of the two, a few per cent, which q covers).  Below
``MIN_TURN_SPEED_MPS`` the speed is taken as that floor: a track without a velocity yet
(initiation) then gets a bounded rate, and slow traffic (helicopters, light aircraft) the
rate of a 50 m/s turn, 5.2°/s at 25°.  Given the state, ω is a number and (2-4) hold as
they stand; the rate's dependence on the speed estimate is not linearised (an extended
filter's Jacobian term), q covers it as it covers the mismatch of a fixed rate.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from .singer_filter import G0_MPS2

__all__ = [
    "MIN_TURN_SPEED_MPS",
    "BankedTurnModel",
    "CoordinatedTurnModel",
    "banked_turn_rate_rad_s",
    "ct_matrices_into",
    "ct_noise_4d",
    "ct_process_noise",
    "ct_transition",
    "ct_transition_4d",
    "lift_cov",
    "lift_rows",
]

#: the 4-D sub-state [x, vx, y, vy] of the Singer state [x, vx, ax, y, vy, ay]
_SUB = np.array([0, 1, 3, 4])

#: the speed below which a banked turn (eq. 5) takes its rate at this speed, m/s (≈ 100 kt)
MIN_TURN_SPEED_MPS = 50.0


def _broadcast(dt_s: ArrayLike, turn_rate_rad_s: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    """dt_s (at least 1-D) and ω broadcast together: the leading shape of F and Q, e.g. (N,)
    for dt (N,) and one ω, (N, K) for dt (N, 1) and K rates (the IMM's turn models)."""
    dt, w = np.broadcast_arrays(np.atleast_1d(np.asarray(dt_s, dtype=float)), np.asarray(turn_rate_rad_s, dtype=float))
    return dt, w


def _transition_terms(dt: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, ...]:
    """The entries of eq. (2): sin ωT/ω, (1 − cos ωT)/ω, cos ωT, sin ωT."""
    wt = w * dt
    s, c = np.sin(wt), np.cos(wt)
    turning = w != 0.0
    w_div = np.where(turning, w, 1.0)
    # (1 − cos ωT)/ω as 2 sin²(ωT/2)/ω, without cancellation; ω → 0: the constant-velocity limit
    s_w = np.where(turning, s / w_div, dt)
    c_w = np.where(turning, 2.0 * np.sin(0.5 * wt) ** 2 / w_div, 0.0)
    return s_w, c_w, c, s


def _noise_terms(t: np.ndarray, w: np.ndarray, s_w: np.ndarray, c_w: np.ndarray) -> tuple[np.ndarray, ...]:
    """Eq. (3)'s three functions of T, 2(T − sin ωT/ω)/ω², (1 − cos ωT)/ω², (T − sin ωT/ω)/ω,
    from eq. (2)'s T_s = sin ωT/ω and T_c = (1 − cos ωT)/ω (:func:`_transition_terms`):
    f_po = (T − T_s)/ω, f_pp = 2 f_po/ω, f_pv = T_c/ω; by their series below |ωT| = 0.01
    (and at ω = 0), where T − T_s cancels."""
    small = np.abs(w * t) < 1e-2
    with np.errstate(divide="ignore", invalid="ignore"):
        f_po = (t - s_w) / w
        f_pp = 2.0 * f_po / w
        f_pv = c_w / w
    if small.any():
        ts, ws = t[small], w[small]
        t2, w2 = ts * ts, ws * ws
        f_pp[small] = t2 * ts / 3.0 - w2 * t2 * t2 * ts / 60.0
        f_pv[small] = t2 / 2.0 - w2 * t2 * t2 / 24.0
        f_po[small] = ws * t2 * ts / 6.0 - w2 * ws * t2 * t2 * ts / 120.0
    return f_pp, f_pv, f_po


def ct_transition_4d(dt_s: ArrayLike, turn_rate_rad_s: ArrayLike) -> np.ndarray:
    """F of eq. (2) on [x, vx, y, vy], (..., 4, 4), for dt_s and ω broadcast together
    (dt (N,) and one ω: (N, 4, 4))."""
    dt, w = _broadcast(dt_s, turn_rate_rad_s)
    s_w, c_w, c, s = _transition_terms(dt, w)
    F = np.zeros(dt.shape + (4, 4))
    F[..., 0, 0] = F[..., 2, 2] = 1.0
    F[..., 0, 1], F[..., 0, 3] = s_w, -c_w
    F[..., 1, 1], F[..., 1, 3] = c, -s
    F[..., 2, 1], F[..., 2, 3] = c_w, s_w
    F[..., 3, 1], F[..., 3, 3] = s, c
    return F


def ct_noise_4d(dt_s: ArrayLike, turn_rate_rad_s: ArrayLike, q_m2_s3: ArrayLike) -> np.ndarray:
    """Q of eq. (3) on [x, vx, y, vy], (..., 4, 4), for dt_s, ω (and q) broadcast together."""
    t, w = _broadcast(dt_s, turn_rate_rad_s)
    q = np.asarray(q_m2_s3, dtype=float)
    s_w, c_w, _, _ = _transition_terms(t, w)
    f_pp, f_pv, f_po = _noise_terms(t, w, s_w, c_w)
    Q = np.zeros(t.shape + (4, 4))
    Q[..., 0, 0] = Q[..., 2, 2] = q * f_pp
    Q[..., 1, 1] = Q[..., 3, 3] = q * t
    Q[..., 0, 1] = Q[..., 1, 0] = Q[..., 2, 3] = Q[..., 3, 2] = q * f_pv
    Q[..., 0, 3] = Q[..., 3, 0] = q * f_po  # Q_pv[x, vy]
    Q[..., 2, 1] = Q[..., 1, 2] = -q * f_po  # Q_pv[y, vx]
    return Q


def lift_rows(a4: np.ndarray, turn_rate_rad_s: ArrayLike) -> np.ndarray:
    """M·a of eq. (4): rows [x, vx, y, vy] (axis −2 of a4, (..., 4, k)) to the Singer
    state's six, with ax = −ω·vy and ay = ω·vx; ω scalar or of a4's leading shape."""
    w = np.asarray(turn_rate_rad_s, dtype=float)[..., None]
    out = np.empty(a4.shape[:-2] + (6,) + a4.shape[-1:])
    out[..., 0:2, :] = a4[..., 0:2, :]  # _SUB = [0, 1, 3, 4]: two slices
    out[..., 3:5, :] = a4[..., 2:4, :]
    out[..., 2, :] = -w * a4[..., 3, :]
    out[..., 5, :] = w * a4[..., 1, :]
    return out


def lift_cov(P4: np.ndarray, turn_rate_rad_s: ArrayLike) -> np.ndarray:
    """M·P·Mᵀ of eq. (4) for (..., 4, 4) covariances: (..., 6, 6)."""
    rows = lift_rows(P4, turn_rate_rad_s)  # (..., 6, 4)
    return np.swapaxes(lift_rows(np.swapaxes(rows, -1, -2), turn_rate_rad_s), -1, -2)


def ct_transition(dt_s: ArrayLike, turn_rate_rad_s: ArrayLike) -> np.ndarray:
    """Φ = M·F·S of eq. (4) on the 6-D Singer state, (..., 6, 6), for dt_s and ω broadcast
    together (dt (N,) and one ω: (N, 6, 6))."""
    F = ct_transition_4d(dt_s, turn_rate_rad_s)
    phi = np.zeros(F.shape[:-2] + (6, 6))
    phi[..., :, _SUB] = lift_rows(F, np.broadcast_to(turn_rate_rad_s, F.shape[:-2]))  # ·S: ax, ay stay zero
    return phi


def ct_process_noise(dt_s: ArrayLike, turn_rate_rad_s: ArrayLike, q_m2_s3: ArrayLike) -> np.ndarray:
    """Q₆ = M·Q·Mᵀ of eq. (3-4), (..., 6, 6), for dt_s, ω and q broadcast together."""
    Q4 = ct_noise_4d(dt_s, turn_rate_rad_s, q_m2_s3)
    return lift_cov(Q4, np.broadcast_to(turn_rate_rad_s, Q4.shape[:-2]))


def ct_matrices_into(
    phi: np.ndarray, Q: np.ndarray, dt_s: ArrayLike, turn_rate_rad_s: ArrayLike, q_m2_s3: ArrayLike
) -> None:
    """Φ = M·F·S and Q₆ = M·Q·Mᵀ of eq. (4) (:func:`ct_transition`, :func:`ct_process_noise`)
    written into the zeroed ``phi`` and ``Q`` (..., 6, 6) entry by entry, for dt_s, ω and q
    broadcast to their leading shape: the IMM (imm.py) predicts its turn models as one axis
    of an (N, M, 6, 6) array.  With the state [x, vx, ax, y, vy, ay], M's rows ax = −ω·vy
    and ay = ω·vx, F of eq. (2) and Q of eq. (3) (whose x-vy and y-vx velocity entries
    are zero):

        Φ rows   x: [1, T_s, 0, 0, −T_c, 0]     y: [0, T_c, 0, 1, T_s, 0]
                vx: [0, c, 0, 0, −s, 0]          vy: [0, s, 0, 0, c, 0]
                ax: −ω·(row vy)                  ay: ω·(row vx)
        (T_s = sin ωT/ω, T_c = (1 − cos ωT)/ω, c = cos ωT, s = sin ωT)

        Q₆: xx = yy = q f_pp, vxvx = vyvy = q T, x-vx = y-vy = q f_pv, x-vy = q f_po,
            y-vx = −q f_po; x-ax = −ω q f_po, x-ay = ω q f_pv, y-ax = −ω q f_pv,
            y-ay = −ω q f_po, vx-ay = ω q T, vy-ax = −ω q T, ax-ax = ay-ay = ω² q T
        (f_pp, f_pv, f_po the three functions of eq. 3; every other entry zero)."""
    lead = phi.shape[:-2]
    dt, w = (np.ascontiguousarray(np.broadcast_to(np.asarray(v, dtype=float), lead)) for v in (dt_s, turn_rate_rad_s))
    q = np.broadcast_to(np.asarray(q_m2_s3, dtype=float), lead)
    s_w, c_w, c, s = _transition_terms(dt, w)
    phi[..., 0, 0] = phi[..., 3, 3] = 1.0
    phi[..., 0, 1], phi[..., 0, 4] = s_w, -c_w
    phi[..., 3, 1], phi[..., 3, 4] = c_w, s_w
    phi[..., 1, 1], phi[..., 1, 4] = c, -s
    phi[..., 4, 1], phi[..., 4, 4] = s, c
    phi[..., 2, 1], phi[..., 2, 4] = -w * s, -w * c
    phi[..., 5, 1], phi[..., 5, 4] = w * c, -w * s
    f_pp, f_pv, f_po = _noise_terms(dt, w, s_w, c_w)
    pp, pv, po, vv = q * f_pp, q * f_pv, q * f_po, q * dt
    Q[..., 0, 0] = Q[..., 3, 3] = pp
    Q[..., 1, 1] = Q[..., 4, 4] = vv
    Q[..., 0, 1] = Q[..., 1, 0] = Q[..., 3, 4] = Q[..., 4, 3] = pv
    Q[..., 0, 4] = Q[..., 4, 0] = po
    Q[..., 3, 1] = Q[..., 1, 3] = -po
    Q[..., 0, 2] = Q[..., 2, 0] = Q[..., 3, 5] = Q[..., 5, 3] = -w * po
    Q[..., 0, 5] = Q[..., 5, 0] = w * pv
    Q[..., 3, 2] = Q[..., 2, 3] = -w * pv
    Q[..., 1, 5] = Q[..., 5, 1] = w * vv
    Q[..., 4, 2] = Q[..., 2, 4] = -w * vv
    Q[..., 2, 2] = Q[..., 5, 5] = w * w * vv


@dataclass(frozen=True)
class CoordinatedTurnModel:
    """Known-rate coordinated-turn prediction (module docstring, eq. 1-4) for N tracks.

    Parameters
    ----------
    turn_rate_deg_s:
        ω, positive to the right (clockwise seen from above, the sense of a heading
        measured clockwise from north: vx east, vy north).
    q_m2_s3:
        Spectral density q of the white-noise acceleration on each axis (eq. 3).
    """

    turn_rate_deg_s: float
    q_m2_s3: float

    def __post_init__(self) -> None:
        if not self.q_m2_s3 >= 0:
            raise ValueError("q_m2_s3 must be >= 0")

    @property
    def turn_rate_rad_s(self) -> float:
        # eq. (1) turns counter-clockwise for ω > 0 in (east, north); a right turn is clockwise
        return -math.radians(self.turn_rate_deg_s)

    def transition(self, dt_s: ArrayLike) -> np.ndarray:
        """Φ of eq. (4), (N, 6, 6)."""
        return ct_transition(dt_s, self.turn_rate_rad_s)

    def process_noise(self, dt_s: ArrayLike) -> np.ndarray:
        """Q₆ = M·Q·Mᵀ of eq. (3-4), (N, 6, 6)."""
        return ct_process_noise(dt_s, self.turn_rate_rad_s, self.q_m2_s3)

    def predict(self, x: ArrayLike, P: ArrayLike, dt_s: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
        """x(k+1|k) = Φ x, P(k+1|k) = Φ P Φᵀ + Q₆ over dt_s (scalar or (N,)), x (N,6), P (N,6,6),
        computed on [x, vx, y, vy] (Φ = M·F·S: F·S P Sᵀ·Fᵀ + Q, then lifted by M)."""
        return _predict_ct(x, P, dt_s, self.turn_rate_rad_s, self.q_m2_s3)


def bank_of_turn_deg(speed_mps: ArrayLike, heading_rate_rad_s: ArrayLike) -> np.ndarray:
    """φ of eq. (5) turned round, tan φ = v ψ̇ / g: the bank (degrees, positive to the
    right) of a coordinated turn at speed v whose heading turns at ψ̇ (clockwise positive,
    the sense of a heading; the opposite of eq. (1)'s ω)."""
    return np.asarray(np.degrees(np.arctan(np.asarray(speed_mps, dtype=float) * heading_rate_rad_s / G0_MPS2)))


def banked_turn_rate_rad_s(vx_mps: ArrayLike, vy_mps: ArrayLike, bank_deg: float) -> np.ndarray:
    """ω of eq. (5) in the sign convention of eq. (1) (a right turn, positive bank, is
    clockwise: ω < 0), at the speed of (vx, vy), floored at ``MIN_TURN_SPEED_MPS``."""
    speed = np.maximum(np.hypot(np.asarray(vx_mps, dtype=float), np.asarray(vy_mps, dtype=float)), MIN_TURN_SPEED_MPS)
    return np.asarray(-G0_MPS2 * math.tan(math.radians(bank_deg)) / speed)


@dataclass(frozen=True)
class BankedTurnModel:
    """Coordinated turn at a bank angle (module docstring, "Turns at a bank angle", eq. 5):
    the prediction of :class:`CoordinatedTurnModel` at each track's own rate ω = g tan φ / v,
    v the speed of the state it predicts from.

    Parameters
    ----------
    bank_deg:
        φ, positive to the right (a clockwise turn seen from above).
    q_m2_s3:
        Spectral density q of the white-noise acceleration on each axis (eq. 3).
    """

    bank_deg: float
    q_m2_s3: float

    def __post_init__(self) -> None:
        if not self.q_m2_s3 >= 0:
            raise ValueError("q_m2_s3 must be >= 0")
        if not -80.0 < self.bank_deg < 80.0:
            raise ValueError("bank_deg must be within ±80°")

    @property
    def lateral_accel_mps2(self) -> float:
        """g tan φ with the sign of ω (eq. 1, 5): ω = lateral_accel_mps2 / v."""
        return -G0_MPS2 * math.tan(math.radians(self.bank_deg))

    def turn_rate_rad_s(self, x: ArrayLike) -> np.ndarray:
        """ω of eq. (5) for each state of x (N, 6), (N,)."""
        x = np.asarray(x, dtype=float)
        return banked_turn_rate_rad_s(x[:, 1], x[:, 4], self.bank_deg)

    def predict(self, x: ArrayLike, P: ArrayLike, dt_s: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
        """x(k+1|k) = Φ x, P(k+1|k) = Φ P Φᵀ + Q₆ over dt_s (scalar or (N,)), each track at
        the rate (5) of its own speed in x (N,6), P (N,6,6)."""
        x = np.asarray(x, dtype=float)
        return _predict_ct(x, P, dt_s, self.turn_rate_rad_s(x), self.q_m2_s3)


def _predict_ct(
    x: ArrayLike, P: ArrayLike, dt_s: ArrayLike, w: ArrayLike, q_m2_s3: float
) -> tuple[np.ndarray, np.ndarray]:
    """Eq. (2-4) on [x, vx, y, vy], lifted: ω scalar or per track (N,)."""
    x = np.asarray(x, dtype=float)
    P = np.asarray(P, dtype=float)
    dt = np.ascontiguousarray(np.broadcast_to(np.asarray(dt_s, dtype=float), (x.shape[0],)))
    w_n = np.broadcast_to(np.asarray(w, dtype=float), (x.shape[0],))
    F = ct_transition_4d(dt, w_n)
    x4 = np.einsum("nij,nj->ni", F, x[:, _SUB])
    P4 = F @ P[:, _SUB[:, None], _SUB[None, :]] @ np.swapaxes(F, 1, 2) + ct_noise_4d(dt, w_n, q_m2_s3)
    P4 = 0.5 * (P4 + np.swapaxes(P4, 1, 2))
    return lift_rows(x4[:, :, None], w_n)[:, :, 0], lift_cov(P4, w_n)
