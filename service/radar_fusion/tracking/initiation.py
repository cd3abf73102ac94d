"""Track initiation: the state of a new track from its first fused measurements (Shu §2, §4).

Stone Soup calls this role the *initiator*. A cluster that no track claims (Shu §2 cases
1 and 3) starts a tentative track from one fused measurement, :func:`one_point_initiation`;
its second update replaces that state by Shu's two-point differencing with the P0 of §4,
:func:`two_point_initiation` (by default keeping the one-point state's velocity prior:
the Kalman update of that state, ``[tracking] two_point_prior``); from the third on, the
Kalman update runs (Shu eq. 7-11).

One-point state. A single position says nothing about the velocity, so the state holds
zero velocity with the variance :func:`unknown_velocity_var_m2ps2` per axis: wide enough
that the track's gate at its next scan covers any civil aircraft speed. The same variance
aligns the plots of a target without a track in time (clustering.py, Shu §2, 时空对准).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .association import mahalanobis2_2x2
from .singer_filter import POS_IDX, STATE_DIM, as_tracks

__all__ = [
    "floor_covariance",
    "one_point_initiation",
    "three_point_d2",
    "two_point_initiation",
    "unknown_velocity_var_m2ps2",
]

Float = NDArray[np.float64]


def unknown_velocity_var_m2ps2(max_speed_mps: float) -> float:
    """Per-axis variance of the velocity of a target that has no track yet, m²/s².

    Each velocity component is taken as uniform on [−v_max, v_max]: variance v_max²/3,
    mean 0. That is a prior for the gate, not a model of traffic: the χ² 99.9 % gate of
    clustering.py (3.7σ for 2 dof) then reaches 3.7·v_max/√3 ≈ 2.1·v_max per second of
    prediction on each axis, beyond the furthest any aircraft can have moved, while a
    wider prior would only let more clutter into a young track's gate.
    """
    return float(max_speed_mps) ** 2 / 3.0


def one_point_initiation(
    z_m: Float, R_m2: Float, velocity_var_m2ps2: float, sigma_m_mps2: float
) -> tuple[Float, Float]:
    """Singer state of new tracks from one fused measurement each.

    x = [z_x, 0, 0, z_y, 0, 0]; P holds the measurement covariance R in the position
    block, ``velocity_var_m2ps2`` on both velocities and the Singer prior σ_m² on both
    accelerations (the stationary variance of Singer's acceleration process, Shu §4's P0
    entry for it), no cross terms: nothing correlates an unknown velocity with the error of
    the one position.

    Shapes: z_m (N,2), R_m2 (N,2,2). Returns x (N,6), P (N,6,6).
    """
    z_m = np.asarray(z_m, dtype=float)
    R_m2 = np.asarray(R_m2, dtype=float)
    n = z_m.shape[0]
    x = np.zeros((n, STATE_DIM))
    x[:, POS_IDX] = z_m
    P = np.zeros((n, STATE_DIM, STATE_DIM))
    P[:, POS_IDX[:, None], POS_IDX[None, :]] = R_m2
    P[:, 1, 1] = P[:, 4, 4] = velocity_var_m2ps2
    P[:, 2, 2] = P[:, 5, 5] = sigma_m_mps2**2
    return x, P


def two_point_initiation(
    z1_m: ArrayLike,
    R1: ArrayLike,
    z2_m: ArrayLike,
    R2: ArrayLike,
    dt_s: ArrayLike,
    sigma_m_mps2: ArrayLike,
    velocity_var_m2ps2: float | None = None,
) -> tuple[Float, Float]:
    """Two-point differencing initiation with Shu's P0 (§4).

    From two position measurements z1 (time t1) and z2 (t2 = t1 + T) of each track::

        x0 = [z2x, (z2x − z1x)/T, 0, z2y, (z2y − z1y)/T, 0]

    and, with σ_x1², σ_xy1, σ_y1² the entries of R1 and likewise for R2 (Shu writes
    the covariance σ_xy as σ_xy²), P0 exactly as printed::

        [[σx2²,    σx2²/T,            0,    σxy2,    σxy2/T,            0   ],
         [σx2²/T,  (σx1²+σx2²)/T²,    0,    σxy2/T,  (σxy1+σxy2)/T²,    0   ],
         [0,       0,                 σm²,  0,       0,                 0   ],
         [σxy2,    σxy2/T,            0,    σy2²,    σy2²/T,            0   ],
         [σxy2/T,  (σxy1+σxy2)/T²,    0,    σy2²/T,  (σy1²+σy2²)/T²,    0   ],
         [0,       0,                 0,    0,       0,                 σm² ]]

    The position/velocity block is the exact covariance of the estimator for
    independent measurement errors and a constant-velocity target; the acceleration
    is initialised at 0 with the Singer prior variance σ_m².  (A real acceleration a
    would add the bias −a·T/2 to the velocity estimate, which P0 ignores.)

    With ``velocity_var_m2ps2`` (σ_v², the one-point state's prior, one_point_initiation),
    the velocity is not taken as unknown beyond any bound but as N(0, σ_v² I), the prior the
    one-point track holds: the result is the Kalman update (Shu eq. 7-11, CV between the two)
    of the one-point state by the second measurement,

        prior at t2:  p = z1, v = 0,  P_pp = R1 + T² σ_v² I,  P_pv = T σ_v² I,  P_vv = σ_v² I,
        K = [P_pp; P_pv] (P_pp + R2)⁻¹,  [p; v] += K (z2 − z1),  P −= K [P_pp, P_pv],

    which tends to the above as σ_v → ∞ and differs from it only where the pair's own
    velocity is no better than the prior: two coarse positions a few seconds apart (a
    long-range radar's cross-range of 300-500 m gave two-point velocities 100-400 m/s off).
    There it draws the velocity towards the prior's zero (250 m/s across a 400 m axis 4 s
    apart comes out at ~170 m/s, by about 0.7 of its σ), which the next updates mend; the
    error it saves is larger.

    Shapes: z1_m, z2_m (N,2); R1, R2 (N,2,2); dt_s (N,) or scalar (> 0);
    sigma_m_mps2 scalar or (N,).  Returns x (N,6), P (N,6,6).
    """
    z1_m = np.asarray(z1_m, dtype=float)
    z2_m = np.asarray(z2_m, dtype=float)
    R1 = np.asarray(R1, dtype=float)
    R2 = np.asarray(R2, dtype=float)
    n = z2_m.shape[0]
    dt_s, sigma_m_mps2 = as_tracks(dt_s, sigma_m_mps2)
    dt_s = np.broadcast_to(dt_s, (n,))
    sigma_m_mps2 = np.broadcast_to(sigma_m_mps2, (n,))
    if np.any(dt_s <= 0):
        raise ValueError("two-point initiation needs dt_s > 0")

    x = np.zeros((n, STATE_DIM))
    if velocity_var_m2ps2 is None:
        x[:, POS_IDX] = z2_m
        x[:, POS_IDX + 1] = (z2_m - z1_m) / dt_s[:, None]
        # position/velocity covariance: cov(p, p) = R2, cov(p, v) = R2/T,
        # cov(v, v) = (R1 + R2)/T², for each pair of axes (a, b) ∈ {x, y}²
        inv_t = (1.0 / dt_s)[:, None, None]
        pp = R2
        pv = R2 * inv_t
        vv = (R1 + R2) * inv_t**2
    else:
        t = dt_s[:, None, None]
        eye_v = float(velocity_var_m2ps2) * np.eye(2)
        prior_pp = R1 + t**2 * eye_v
        prior_pv = t * eye_v  # symmetric 2x2 blocks
        S_inv = np.linalg.inv(prior_pp + R2)
        K_p = prior_pp @ S_inv
        K_v = np.swapaxes(prior_pv, 1, 2) @ S_inv
        nu = z2_m - z1_m
        x[:, POS_IDX] = z1_m + np.einsum("nij,nj->ni", K_p, nu)
        x[:, POS_IDX + 1] = np.einsum("nij,nj->ni", K_v, nu)
        pp = prior_pp - K_p @ prior_pp
        pv = prior_pv - K_p @ prior_pv
        vv = eye_v - K_v @ prior_pv
        pp, vv = 0.5 * (pp + np.swapaxes(pp, 1, 2)), 0.5 * (vv + np.swapaxes(vv, 1, 2))
    P = np.zeros((n, STATE_DIM, STATE_DIM))
    pos, vel = POS_IDX, POS_IDX + 1
    P[:, pos[:, None], pos[None, :]] = pp
    P[:, pos[:, None], vel[None, :]] = pv
    P[:, vel[:, None], pos[None, :]] = np.swapaxes(pv, 1, 2)
    P[:, vel[:, None], vel[None, :]] = vv
    P[:, 2, 2] = P[:, 5, 5] = sigma_m_mps2**2
    return x, P


def three_point_d2(
    z1_m: Float,
    R1_m2: Float,
    t1_s: Float,
    z2_m: Float,
    R2_m2: Float,
    t2_s: Float,
    z3_m: Float,
    R3_m2: Float,
    t3_s: Float,
    q_m2ps3: float,
) -> Float:
    """Mahalanobis d² of a third position z₃ from the straight line at constant speed that the
    two-point initiation (Shu §4) draws through z₁ and z₂ (t₁ < t₂ < t₃): do the three
    measurements belong to one aircraft in near-constant-velocity flight?

    The line predicts ẑ₃ = z₂ + (z₂ − z₁) a with a = τ₂/τ₁, τ₁ = t₂ − t₁, τ₂ = t₃ − t₂. The
    residual y = z₃ − (1 + a) z₂ + a z₁ is zero on any straight path flown at constant
    speed; its covariance is the three measurements' noise,

        S = R₃ + (1 + a)² R₂ + a² R₁ + Q,

    plus what a white acceleration of density q (m²/s³ per axis, the near-constant-velocity
    model's) adds. y is then ∫ K(s) w(s) ds with K(s) = a (s − t₁) on [t₁, t₂], t₃ − s on
    [t₂, t₃] and 0 before t₁, so Q = q (a² τ₁³ + τ₂³) / 3 on each axis. d² = yᵀS⁻¹y is χ²
    with 2 degrees of freedom when the three are the aircraft's.

    Shapes: z (N, 2), R (N, 2, 2), t (N,). Returns (N,).
    """
    z1, z2, z3 = (np.asarray(z, dtype=float) for z in (z1_m, z2_m, z3_m))
    R1, R2, R3 = (np.asarray(R, dtype=float) for R in (R1_m2, R2_m2, R3_m2))
    tau1 = np.asarray(t2_s, dtype=float) - np.asarray(t1_s, dtype=float)
    tau2 = np.asarray(t3_s, dtype=float) - np.asarray(t2_s, dtype=float)
    a = tau2 / tau1
    y = z3 - (1.0 + a)[:, None] * z2 + a[:, None] * z1
    q = float(q_m2ps3) * (a**2 * tau1**3 + tau2**3) / 3.0
    S = R3 + ((1.0 + a) ** 2)[:, None, None] * R2 + (a**2)[:, None, None] * R1 + q[:, None, None] * np.eye(2)
    return mahalanobis2_2x2(y, S)


def floor_covariance(P: Float, floor_m2: Float) -> Float:
    """Position covariance of tracks raised to at least ``floor_m2`` in every direction.

    For a track whose plots all come without height (a primary-only aircraft), the plots
    are converted at the mean ground range over every possible height and filtered with
    their noise alone; the unknown height adds one error common to all of them, B
    (geo.unknown_height.unknown_height_plots ``cov_height_m2``, along the radial), which
    no number of plots of that radar averages out (a Schmidt "consider" parameter). The
    track's position error is then at least B: with B = sum_i l_i e_i e_i^T (its
    eigen-decomposition, rank one for one radar), each direction e_i gets

        P_pos += max(0, l_i - e_i^T P_pos e_i) e_i e_i^T,

    which leaves the velocity and its cross terms alone: the velocity from successive
    plots of one height is exact (the bias cancels in the difference), so the first plot
    with a height (Mode C, from an SSR) moves the position by up to the whole interval
    while hardly touching the velocity.

    Shapes: P (N,6,6) or (N,M,6,6) (the IMM's per-model covariances), floor_m2 (N,2,2).
    Returns a new array.
    """
    P = np.array(P, dtype=float, copy=True)
    B = np.asarray(floor_m2, dtype=float)
    lam, vec = np.linalg.eigh(np.where(np.isfinite(B), B, 0.0))  # (N,2), (N,2,2) columns e_i
    pos = POS_IDX
    extra_shape = P.shape[1:-2]  # () or (M,)
    for i in range(2):
        e = vec[:, :, i]  # (N,2)
        e_b = e.reshape(e.shape[:1] + (1,) * len(extra_shape) + (2,))
        p_pos = P[..., pos[:, None], pos[None, :]]
        along = np.einsum("...i,...ij,...j->...", e_b, p_pos, e_b)
        add = np.maximum(lam[:, i].reshape(lam.shape[:1] + (1,) * len(extra_shape)) - along, 0.0)
        P[..., pos[:, None], pos[None, :]] = p_pos + add[..., None, None] * (e_b[..., :, None] * e_b[..., None, :])
    return P
