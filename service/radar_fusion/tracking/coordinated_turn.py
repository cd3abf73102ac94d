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

A fixed-rate model only fits turns near its rate; the IMM (imm.py) runs one for each
direction beside the straight-flight model, and q covers the mismatch of turns at other
rates (a 1.5°/s turn seen by a 3°/s model at 200 m/s: 5 m/s² of model error).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

__all__ = ["CoordinatedTurnModel", "ct_noise_4d", "ct_transition", "ct_transition_4d", "lift_cov", "lift_rows"]

#: the 4-D sub-state [x, vx, y, vy] of the Singer state [x, vx, ax, y, vy, ay]
_SUB = np.array([0, 1, 3, 4])


def ct_transition_4d(dt_s: ArrayLike, turn_rate_rad_s: float) -> np.ndarray:
    """F of eq. (2) on [x, vx, y, vy], (N, 4, 4), for dt_s (N,)."""
    dt = np.atleast_1d(np.asarray(dt_s, dtype=float))
    w = float(turn_rate_rad_s)
    wt = w * dt
    s, c = np.sin(wt), np.cos(wt)
    if w != 0.0:
        s_w, c_w = s / w, 2.0 * np.sin(0.5 * wt) ** 2 / w  # (1 − cos ωT)/ω without cancellation
    else:  # ω → 0: the constant-velocity limit of eq. (2)
        s_w, c_w = dt.copy(), np.zeros_like(dt)
    F = np.zeros((dt.size, 4, 4))
    F[:, 0, 0] = F[:, 2, 2] = 1.0
    F[:, 0, 1], F[:, 0, 3] = s_w, -c_w
    F[:, 1, 1], F[:, 1, 3] = c, -s
    F[:, 2, 1], F[:, 2, 3] = c_w, s_w
    F[:, 3, 1], F[:, 3, 3] = s, c
    return F


def ct_noise_4d(dt_s: ArrayLike, turn_rate_rad_s: float, q_m2_s3: float) -> np.ndarray:
    """Q of eq. (3) on [x, vx, y, vy], (N, 4, 4), for dt_s (N,)."""
    t = np.atleast_1d(np.asarray(dt_s, dtype=float))
    w = float(turn_rate_rad_s)
    wt = w * t
    small = np.abs(wt) < 1e-2  # and ω = 0: the series are exact there
    with np.errstate(divide="ignore", invalid="ignore"):
        # eq. (3)'s three functions of T: 2(T − sin ωT/ω)/ω², (1 − cos ωT)/ω², (T − sin ωT/ω)/ω
        f_pp = np.where(small, t**3 / 3.0 - w**2 * t**5 / 60.0, 2.0 * (t - np.sin(wt) / w) / w**2)
        f_pv = np.where(small, t**2 / 2.0 - w**2 * t**4 / 24.0, (1.0 - np.cos(wt)) / w**2)
        f_po = np.where(small, w * t**3 / 6.0 - w**3 * t**5 / 120.0, (t - np.sin(wt) / w) / w)
    Q = np.zeros((t.size, 4, 4))
    Q[:, 0, 0] = Q[:, 2, 2] = q_m2_s3 * f_pp
    Q[:, 1, 1] = Q[:, 3, 3] = q_m2_s3 * t
    Q[:, 0, 1] = Q[:, 1, 0] = Q[:, 2, 3] = Q[:, 3, 2] = q_m2_s3 * f_pv
    Q[:, 0, 3] = Q[:, 3, 0] = q_m2_s3 * f_po  # Q_pv[x, vy]
    Q[:, 2, 1] = Q[:, 1, 2] = -q_m2_s3 * f_po  # Q_pv[y, vx]
    return Q


def lift_rows(a4: np.ndarray, turn_rate_rad_s: float) -> np.ndarray:
    """M·a of eq. (4): rows [x, vx, y, vy] (axis 1 of a4, (N, 4, ...)) to the Singer state's
    six, with ax = −ω·vy and ay = ω·vx."""
    w = float(turn_rate_rad_s)
    out = np.empty((a4.shape[0], 6) + a4.shape[2:])
    out[:, _SUB] = a4
    out[:, 2] = -w * a4[:, 3]
    out[:, 5] = w * a4[:, 1]
    return out


def lift_cov(P4: np.ndarray, turn_rate_rad_s: float) -> np.ndarray:
    """M·P·Mᵀ of eq. (4) for (N, 4, 4) covariances: (N, 6, 6)."""
    rows = lift_rows(P4, turn_rate_rad_s)  # (N, 6, 4)
    return np.swapaxes(lift_rows(np.swapaxes(rows, 1, 2), turn_rate_rad_s), 1, 2)


def ct_transition(dt_s: ArrayLike, turn_rate_rad_s: float) -> np.ndarray:
    """Φ = M·F·S of eq. (4) on the 6-D Singer state, (N, 6, 6), for dt_s (N,)."""
    F = ct_transition_4d(dt_s, turn_rate_rad_s)
    phi = np.zeros((F.shape[0], 6, 6))
    phi[:, :, _SUB] = lift_rows(F, turn_rate_rad_s)  # ·S: the columns ax, ay stay zero
    return phi


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
        return lift_cov(ct_noise_4d(dt_s, self.turn_rate_rad_s, self.q_m2_s3), self.turn_rate_rad_s)

    def predict(self, x: ArrayLike, P: ArrayLike, dt_s: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
        """x(k+1|k) = Φ x, P(k+1|k) = Φ P Φᵀ + Q₆ over dt_s (scalar or (N,)), x (N,6), P (N,6,6),
        computed on [x, vx, y, vy] (Φ = M·F·S: F·S P Sᵀ·Fᵀ + Q, then lifted by M)."""
        x = np.asarray(x, dtype=float)
        P = np.asarray(P, dtype=float)
        dt = np.ascontiguousarray(np.broadcast_to(np.asarray(dt_s, dtype=float), (x.shape[0],)))
        w = self.turn_rate_rad_s
        F = ct_transition_4d(dt, w)
        x4 = np.einsum("nij,nj->ni", F, x[:, _SUB])
        P4 = F @ P[:, _SUB[:, None], _SUB[None, :]] @ np.swapaxes(F, 1, 2) + ct_noise_4d(dt, w, self.q_m2_s3)
        P4 = 0.5 * (P4 + np.swapaxes(P4, 1, 2))
        return lift_rows(x4[:, :, None], w)[:, :, 0], lift_cov(P4, w)
