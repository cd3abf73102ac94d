"""The IMM cycle of imm.py (eq. 0-8) as compiled loops: one pass over each track's models.

imm.py states the algorithm and its equations; this module is how the engine runs them
at thousands of tracks.  Written as batched numpy products, one IMM prediction of 4,000
tracks × 6 models made a dozen passes over (N, M, 6, 6) arrays (the mixed covariances,
the outer products, Φ and Q, Φ P⁰, Φ P⁰ Φᵀ), 7 MB each: it was bound by memory traffic,
not arithmetic, and was the largest part of the engine's period (issue 15's throughput
goal).  Here each track's M states are read once, everything in between lives in a few
6×6 scratch matrices in the L1 cache, and only the results are written:

* :func:`predict_kernel`, steps 1-2 (eq. 0-4 and each model's prediction);
* :func:`predict_block_kernel`, steps 1, 2 and 5 for association and output: each
  model's predicted position and its covariance (the gates), the combined x and a block
  of the combined covariance (position and velocity; the x-y block for the output);
* :func:`update_kernel`, steps 3-4 (eq. 5-6): every model's Kalman update (Shu eq. 7,
  9, 10) and the mode probabilities;
* :func:`predict_update_kernel`, steps 1-5 at once, for the tracks that got a plot;
* :func:`combine_kernel`, step 5 (eq. 7-8) alone.

Φ_j and Q_j are not stored as (N, M, 6, 6) arrays either: :func:`model_terms_kernel`
computes their distinct entries, ``TERMS`` numbers per track and model, with the models'
formulas (compiled twins of singer_filter.py's Shu eq. 12 and §4 and of
coordinated_turn.py's eq. 2-3, the same series and switches; the numpy functions there
stay the statement that the tests check against Van Loan's method), and
:func:`_model_phi_q` lays them out in a 6×6 pair, the same placement as
singer_filter.singer_matrices_into and coordinated_turn.ct_matrices_into.

Compiled by numba on first use and cached on disk (compiled.py), so a process pays the
compilation (a few seconds) only when the code changed, and imm.IMMFilter runs the
engine's kernels once when it is made, so that this happens at start-up, not in the
first period;
``nogil`` lets the daemon's receiving threads run while the engine is in here.  Arithmetic is the
same as the numpy formulation's up to the order of additions (round-off, ~1e-13
relative); the tests compare every kernel with independent computations (test_imm.py:
a per-track hand computation with Van Loan's Φ and Q, and filterpy's IMMEstimator).
"""

from __future__ import annotations

import math

import numpy as np

from .compiled import compiled as _compiled
from .coordinated_turn import MIN_TURN_SPEED_MPS

__all__ = [
    "BANK",
    "CT",
    "SINGER",
    "TERMS",
    "combine_kernel",
    "model_terms_kernel",
    "predict_block_kernel",
    "predict_kernel",
    "predict_update_kernel",
    "update_kernel",
]

#: model families (``family`` argument): a Singer model, a coordinated turn of known rate,
#: a coordinated turn at a bank angle (its rate from the speed of the mixed state)
SINGER = 0
CT = 1
BANK = 2
#: distinct entries of Φ and Q per track and model (the longer family's count):
#: Singer: T, Φ02, Φ12, Φ22 of one axis block, then Q's six q_ij in ``q_keys`` order;
#: coordinated turn: T_s, T_c, cos ωT, sin ωT, then q f_pp, q f_pv, q f_po, q T;
#: banked turn: q alone (the rest depends on the mixed state: :func:`_phi_q_j`)
TERMS = 10

_D = 6  # the state [x, vx, ax, y, vy, ay]


@_compiled
def _model_phi_q(family: int, t: np.ndarray, omega: float, q_keys: np.ndarray, phi: np.ndarray, Q: np.ndarray) -> None:
    """Φ and Q (6×6) of one model from its ``TERMS`` numbers t.

    Singer (singer_filter.singer_matrices_into): per axis block [[1, T, Φ02], [0, 1, Φ12],
    [0, 0, Φ22]] and Q's block from q_ij, for x and y alike.  Coordinated turn
    (coordinated_turn.ct_matrices_into, eq. 4): the rows and Q₆ entries listed there."""
    phi[:, :] = 0.0
    Q[:, :] = 0.0
    if family == SINGER:
        for o in (0, 3):
            phi[o, o] = 1.0
            phi[o + 1, o + 1] = 1.0
            phi[o, o + 1] = t[0]
            phi[o, o + 2] = t[1]
            phi[o + 1, o + 2] = t[2]
            phi[o + 2, o + 2] = t[3]
            for k in range(6):
                i = o + q_keys[k, 0]
                j = o + q_keys[k, 1]
                Q[i, j] = t[4 + k]
                Q[j, i] = t[4 + k]
        return
    s_w, c_w, c, s = t[0], t[1], t[2], t[3]
    pp, pv, po, vv = t[4], t[5], t[6], t[7]
    w = omega
    phi[0, 0] = 1.0
    phi[3, 3] = 1.0
    phi[0, 1] = s_w
    phi[0, 4] = -c_w
    phi[3, 1] = c_w
    phi[3, 4] = s_w
    phi[1, 1] = c
    phi[1, 4] = -s
    phi[4, 1] = s
    phi[4, 4] = c
    phi[2, 1] = -w * s
    phi[2, 4] = -w * c
    phi[5, 1] = w * c
    phi[5, 4] = -w * s
    Q[0, 0] = pp
    Q[3, 3] = pp
    Q[1, 1] = vv
    Q[4, 4] = vv
    Q[0, 1] = Q[1, 0] = Q[3, 4] = Q[4, 3] = pv
    Q[0, 4] = Q[4, 0] = po
    Q[3, 1] = Q[1, 3] = -po
    Q[0, 2] = Q[2, 0] = Q[3, 5] = Q[5, 3] = -w * po
    Q[0, 5] = Q[5, 0] = w * pv
    Q[3, 2] = Q[2, 3] = -w * pv
    Q[1, 5] = Q[5, 1] = w * vv
    Q[4, 2] = Q[2, 4] = -w * vv
    Q[2, 2] = Q[5, 5] = w * w * vv


@_compiled
def _phi_q_j(
    family: int,
    t: np.ndarray,
    omega: float,
    q_keys: np.ndarray,
    x0: np.ndarray,
    dt: float,
    t_bank: np.ndarray,
    phi: np.ndarray,
    Q: np.ndarray,
) -> None:
    """Φ_j and Q_j of model j for a track whose mixed state is x0: from its ``TERMS`` t, or
    for a banked turn (``omega`` its signed g tan φ) at the rate ω = g tan φ / v of x0's
    speed v, floored at MIN_TURN_SPEED_MPS (coordinated_turn.py eq. 5,
    banked_turn_rate_rad_s), with its q in t[0]; t_bank is scratch for its terms."""
    if family == BANK:
        v = math.sqrt(x0[1] * x0[1] + x0[4] * x0[4])
        w = omega / max(v, MIN_TURN_SPEED_MPS)
        _turn_terms(dt, w, t[0], t_bank)
        _model_phi_q(CT, t_bank, w, q_keys, phi, Q)
    else:
        _model_phi_q(family, t, omega, q_keys, phi, Q)


@_compiled
def _horner(coeffs: np.ndarray, x: float) -> float:
    acc = 0.0
    for i in range(coeffs.shape[0] - 1, -1, -1):
        acc = acc * x + coeffs[i]
    return acc


@_compiled
def _singer_terms(
    dt: float,
    alpha: float,
    sigma: float,
    q_keys: np.ndarray,
    q_power: np.ndarray,
    h2_series: np.ndarray,
    q_series: np.ndarray,
    switch: float,
    out: np.ndarray,
) -> None:
    """A Singer model's ``TERMS`` over dt (singer_filter._transition_terms and
    _process_noise_terms, Shu eq. 12 and §4 with the misprints fixed): T, Φ02 = T² h2(αT),
    Φ12 = T h1(αT), Φ22 = e^{−αT}, then q_ij = 2ασ_m² T^p g_ij(αT), each g_ij by its
    Taylor series below αT = ``switch`` (where the closed form cancels) and in closed form
    above, the same split and the same series coefficients as singer_filter.py."""
    x = alpha * dt
    small = x < switch
    h2 = _horner(h2_series, x) if small else (x - 1.0 + math.exp(-x)) / (x * x)
    h1 = -math.expm1(-x) / x if x > 0.0 else 1.0
    out[0] = dt
    out[1] = dt * dt * h2
    out[2] = dt * h1
    out[3] = math.exp(-x)
    q_c = 2.0 * alpha * sigma * sigma
    e1 = math.exp(-x)
    e2 = math.exp(-2.0 * x)
    for k in range(6):
        i, j, p = q_keys[k, 0], q_keys[k, 1], q_power[k]
        if small:
            g = _horner(q_series[:, k], x)
        else:  # singer_filter._q_closed
            if i == 0 and j == 0:
                num = 1.0 - e2 + 2.0 * x + 2.0 * x**3 / 3.0 - 2.0 * x**2 - 4.0 * x * e1
            elif i == 0 and j == 1:
                num = 1.0 + e2 - 2.0 * e1 + 2.0 * x * e1 - 2.0 * x + x**2
            elif i == 0 and j == 2:
                num = 1.0 - e2 - 2.0 * x * e1
            elif i == 1 and j == 1:
                num = 4.0 * e1 - 3.0 - e2 + 2.0 * x
            elif i == 1 and j == 2:
                num = 1.0 + e2 - 2.0 * e1
            else:
                num = 1.0 - e2
            g = num / (2.0 * x**p)
        out[4 + k] = q_c * g * dt**p


@_compiled
def _turn_terms(dt: float, w: float, q: float, out: np.ndarray) -> None:
    """A coordinated turn's ``TERMS`` over dt (coordinated_turn._transition_terms and
    _noise_terms, eq. 2-3): T_s = sin ωT/ω, T_c = (1 − cos ωT)/ω = 2 sin²(ωT/2)/ω, cos ωT,
    sin ωT, then q f_pp, q f_pv, q f_po and q T, by their series below |ωT| = 0.01."""
    wt = w * dt
    s = math.sin(wt)
    c = math.cos(wt)
    if w != 0.0:
        s_w = s / w
        c_w = 2.0 * math.sin(0.5 * wt) ** 2 / w
    else:
        s_w = dt
        c_w = 0.0
    if abs(wt) < 1e-2:
        t2 = dt * dt
        w2 = w * w
        f_pp = t2 * dt / 3.0 - w2 * t2 * t2 * dt / 60.0
        f_pv = t2 / 2.0 - w2 * t2 * t2 / 24.0
        f_po = w * t2 * dt / 6.0 - w2 * w * t2 * t2 * dt / 120.0
    else:
        f_po = (dt - s_w) / w
        f_pp = 2.0 * f_po / w
        f_pv = c_w / w
    out[0] = s_w
    out[1] = c_w
    out[2] = c
    out[3] = s
    out[4] = q * f_pp
    out[5] = q * f_pv
    out[6] = q * f_po
    out[7] = q * dt


@_compiled
def model_terms_kernel(
    dt: np.ndarray,
    family: np.ndarray,
    alpha: np.ndarray,
    sigma: np.ndarray,
    omega: np.ndarray,
    turn_q: np.ndarray,
    q_keys: np.ndarray,
    q_power: np.ndarray,
    h2_series: np.ndarray,
    q_series: np.ndarray,
    switch: float,
    out: np.ndarray,
) -> None:
    """Every model's ``TERMS`` over each track's dt: out (N, M, TERMS); per model (M,) its
    family, Singer α and σ_m, turn rate ω and turn noise q (the other families' unused).
    A banked turn's terms depend on the mixed state: here only its q (in the first)."""
    for k in range(dt.shape[0]):
        for j in range(family.shape[0]):
            if family[j] == SINGER:
                _singer_terms(dt[k], alpha[j], sigma[j], q_keys, q_power, h2_series, q_series, switch, out[k, j])
            elif family[j] == CT:
                _turn_terms(dt[k], omega[j], turn_q[j], out[k, j])
            else:
                out[k, j, :] = 0.0
                out[k, j, 0] = turn_q[j]


#: the packed upper triangle of a symmetric 6×6 matrix: entry q is (_UT[q, 0], _UT[q, 1])
_UT = np.array([(a, b) for a in range(_D) for b in range(a, _D)], dtype=np.int64)
_NP = _D + _UT.shape[0]  # a mixing row: the 6 deviations, then the 21 packed covariances


@_compiled
def _mix(
    xm: np.ndarray,
    Pm: np.ndarray,
    mu: np.ndarray,
    dt: float,
    tau: np.ndarray,
    wt: np.ndarray,
    cbar: np.ndarray,
    S: np.ndarray,
    X0: np.ndarray,
) -> None:
    """Eq. 0-4 for one track's M models: c̄ (M,) into cbar and, per model j, the mixed
    initial condition into X0[j] (``_NP`` numbers): x⁰_j − x_0 (6), then P⁰_j packed (21).

    With e_i = x_i − x_0 (model 0's state as the reference, so nothing of the size of a
    position cancels) and Σ_i μ_{i|j} = 1, eq. 3-4 are

        x⁰_j = x_0 + Σ_i μ_{i|j} e_i,   P⁰_j = Σ_i μ_{i|j} (P_i + e_i e_iᵀ) − e⁰_j e⁰_jᵀ

    (imm.IMMFilter.mix), i.e. one (M×M)·(M×27) product of the μ_{i|j} with the rows
    S_i = [e_i, packed(P_i + e_i e_iᵀ)]: its inner loops run over contiguous rows."""
    m = xm.shape[0]
    d = max(dt, 0.0)
    for i in range(m):
        X0[i, 0] = math.exp(-d / tau[i])  # eq. 0: p_ii (X0 is scratch until it is filled)
    for j in range(m):
        c = 0.0
        for i in range(m):
            p = X0[i, 0] if i == j else (1.0 - X0[i, 0]) / (m - 1)
            wt[j, i] = p * mu[i]
            c += wt[j, i]
        cbar[j] = c  # eq. 1
    for j in range(m):
        if cbar[j] > 0.0:
            for i in range(m):
                wt[j, i] /= cbar[j]  # eq. 2
        else:  # a mode nothing can reach (c̄_j = 0) keeps its own state
            for i in range(m):
                wt[j, i] = 1.0 if i == j else 0.0
    for i in range(m):
        for a in range(_D):
            S[i, a] = xm[i, a] - xm[0, a]
        for q in range(_UT.shape[0]):
            a, b = _UT[q, 0], _UT[q, 1]
            S[i, _D + q] = Pm[i, a, b] + S[i, a] * S[i, b]
    for j in range(m):
        for q in range(_NP):
            X0[j, q] = 0.0
        for i in range(m):
            w = wt[j, i]
            for q in range(_NP):
                X0[j, q] += w * S[i, q]  # eq. 3 and the sum of eq. 4
        for q in range(_UT.shape[0]):
            X0[j, _D + q] -= X0[j, _UT[q, 0]] * X0[j, _UT[q, 1]]  # − e⁰_j e⁰_jᵀ


@_compiled
def _unpack(X0j: np.ndarray, x_ref: np.ndarray, x0: np.ndarray, P0: np.ndarray) -> None:
    """x⁰_j (6) and P⁰_j (6×6, symmetric) from a mixing row of ``_mix``."""
    for a in range(_D):
        x0[a] = x_ref[a] + X0j[a]
    for q in range(_UT.shape[0]):
        a, b = _UT[q, 0], _UT[q, 1]
        P0[a, b] = X0j[_D + q]
        P0[b, a] = X0j[_D + q]


@_compiled
def _predict_j(
    phi: np.ndarray,
    Q: np.ndarray,
    x0: np.ndarray,
    P0: np.ndarray,
    T: np.ndarray,
    phiT: np.ndarray,
    xp: np.ndarray,
    Pp: np.ndarray,
) -> None:
    """x = Φ x⁰, P = Φ P⁰ Φᵀ + Q (Shu eq. 8, 11; coordinated_turn.py eq. 4); P exactly
    symmetric.  Dense 6×6 products written as row updates (T[a, :] += Φ[a, c] P⁰[c, :]),
    which the compiler vectorises: faster than skipping Φ's zeros entry by entry."""
    for a in range(_D):
        acc = 0.0
        for c in range(_D):
            acc += phi[a, c] * x0[c]
        xp[a] = acc
        for c in range(_D):
            phiT[c, a] = phi[a, c]
    for a in range(_D):
        for b in range(_D):
            T[a, b] = 0.0
        for c in range(_D):
            f = phi[a, c]
            for b in range(_D):
                T[a, b] += f * P0[c, b]
    for a in range(_D):
        for b in range(_D):
            Pp[a, b] = Q[a, b]
        for c in range(_D):
            t = T[a, c]
            for b in range(_D):
                Pp[a, b] += t * phiT[c, b]
    for a in range(_D):
        for b in range(a + 1, _D):
            Pp[b, a] = Pp[a, b]


@_compiled
def _combine_one(xm: np.ndarray, Pm: np.ndarray, w: np.ndarray, x: np.ndarray, P: np.ndarray) -> None:
    """Eq. 7-8 for one track: x = Σ w_j x_j, P = Σ w_j [P_j + (x_j − x)(x_j − x)ᵀ]."""
    m = xm.shape[0]
    for a in range(_D):
        acc = 0.0
        for j in range(m):
            acc += w[j] * xm[j, a]
        x[a] = acc
    for a in range(_D):
        for b in range(a, _D):
            acc = 0.0
            for j in range(m):
                acc += w[j] * (Pm[j, a, b] + (xm[j, a] - x[a]) * (xm[j, b] - x[b]))
            P[a, b] = acc
            P[b, a] = acc


@_compiled
def predict_kernel(
    xm: np.ndarray,
    Pm: np.ndarray,
    mu: np.ndarray,
    dt: np.ndarray,
    tau: np.ndarray,
    terms: np.ndarray,
    family: np.ndarray,
    omega: np.ndarray,
    q_keys: np.ndarray,
    out_xm: np.ndarray,
    out_Pm: np.ndarray,
    out_cbar: np.ndarray,
) -> None:
    """Steps 1-2 (eq. 0-4, each model's prediction) for N tracks into out_xm, out_Pm and
    out_cbar (c̄ of eq. 1). xm (N,M,6), Pm (N,M,6,6), mu (N,M), dt (N,), tau (M,) dwell times, terms (N,M,TERMS),
    family and omega (M,) (a banked turn's omega is its signed g tan φ), q_keys (6,2) the Singer q_ij order."""
    n, m = mu.shape
    wt = np.empty((m, m))
    S = np.empty((m, _NP))
    X0 = np.empty((m, _NP))
    x0 = np.empty(_D)
    P0 = np.empty((_D, _D))
    T = np.empty((_D, _D))
    phiT = np.empty((_D, _D))
    phi = np.empty((_D, _D))
    Q = np.empty((_D, _D))
    t_bank = np.empty(TERMS)
    for k in range(n):
        _mix(xm[k], Pm[k], mu[k], dt[k], tau, wt, out_cbar[k], S, X0)
        for j in range(m):
            _unpack(X0[j], xm[k, 0], x0, P0)
            _phi_q_j(family[j], terms[k, j], omega[j], q_keys, x0, dt[k], t_bank, phi, Q)
            _predict_j(phi, Q, x0, P0, T, phiT, out_xm[k, j], out_Pm[k, j])


@_compiled
def predict_block_kernel(
    xm: np.ndarray,
    Pm: np.ndarray,
    mu: np.ndarray,
    rows: np.ndarray,
    dt: np.ndarray,
    tau: np.ndarray,
    terms: np.ndarray,
    family: np.ndarray,
    omega: np.ndarray,
    q_keys: np.ndarray,
    block: np.ndarray,
    out_xy: np.ndarray,
    out_cov_xy: np.ndarray,
    out_x: np.ndarray,
    out_P: np.ndarray,
) -> None:
    """Steps 1, 2 and 5 for a reader of part of the covariance: the combination (eq. 7-8,
    weights c̄) x (N,6) and the rows and columns ``block`` of P (N,6,6), NaN elsewhere,
    and each model's predicted position out_xy (N,M,2) and its covariance out_cov_xy
    (N,M,2,2).  Only the rows ``block`` of each Φ_j P⁰_j Φ_jᵀ are formed, not the
    per-model 6×6 covariances.  ``block`` lists state indices in order and holds 0 and 3
    (x and y): [0, 1, 3, 4] for association (position and velocity; the model-conditioned
    gates, imm.py "Gating"), [0, 3] for the output.  Track k is row rows[k] of the state
    (no copy of the rows taken); dt, terms and the outputs per k."""
    n, m = rows.shape[0], mu.shape[1]
    nr = block.size
    ix = iy = 0  # where x and y are in the block
    for r in range(nr):
        if block[r] == 0:
            ix = r
        elif block[r] == 3:
            iy = r
    wt = np.empty((m, m))
    cbar = np.empty(m)
    S = np.empty((m, _NP))
    X0 = np.empty((m, _NP))
    x0 = np.empty(_D)
    P0 = np.empty((_D, _D))
    phi = np.empty((_D, _D))
    Q = np.empty((_D, _D))
    t_bank = np.empty(TERMS)
    xp = np.empty((m, _D))
    T = np.empty((nr, _D))  # the rows ``block`` of Φ P⁰
    B = np.empty((m, nr, nr))  # the block of Φ P⁰ Φᵀ + Q
    for k in range(n):
        i = rows[k]
        _mix(xm[i], Pm[i], mu[i], dt[k], tau, wt, cbar, S, X0)
        for j in range(m):
            _unpack(X0[j], xm[i, 0], x0, P0)
            _phi_q_j(family[j], terms[k, j], omega[j], q_keys, x0, dt[k], t_bank, phi, Q)
            for a in range(_D):
                acc = 0.0
                for c in range(_D):
                    acc += phi[a, c] * x0[c]
                xp[j, a] = acc
            for r in range(nr):
                a = block[r]
                for b in range(_D):
                    T[r, b] = 0.0
                for c in range(_D):
                    f = phi[a, c]
                    for b in range(_D):
                        T[r, b] += f * P0[c, b]
            for r in range(nr):
                for u in range(r, nr):
                    b = block[u]
                    acc = 0.0
                    for c in range(_D):
                        acc += T[r, c] * phi[b, c]
                    B[j, r, u] = acc + Q[block[r], b]
                    B[j, u, r] = B[j, r, u]
            out_xy[k, j, 0] = xp[j, 0]
            out_xy[k, j, 1] = xp[j, 3]
            out_cov_xy[k, j, 0, 0] = B[j, ix, ix]
            out_cov_xy[k, j, 0, 1] = B[j, ix, iy]
            out_cov_xy[k, j, 1, 0] = B[j, iy, ix]
            out_cov_xy[k, j, 1, 1] = B[j, iy, iy]
        for a in range(_D):  # eq. 7 with c̄
            acc = 0.0
            for j in range(m):
                acc += cbar[j] * xp[j, a]
            out_x[k, a] = acc
        for a in range(_D):
            for b in range(_D):
                out_P[k, a, b] = np.nan
        for r in range(nr):  # eq. 8 on the block
            a = block[r]
            for u in range(r, nr):
                b = block[u]
                acc = 0.0
                for j in range(m):
                    acc += cbar[j] * (B[j, r, u] + (xp[j, a] - out_x[k, a]) * (xp[j, b] - out_x[k, b]))
                out_P[k, a, b] = acc
                out_P[k, b, a] = acc


@_compiled
def _update_one(
    xm: np.ndarray,
    Pm: np.ndarray,
    cbar: np.ndarray,
    z: np.ndarray,
    R: np.ndarray,
    out_xm: np.ndarray,
    out_Pm: np.ndarray,
    out_mu: np.ndarray,
    log_w: np.ndarray,
    K: np.ndarray,
    PHt: np.ndarray,
) -> None:
    """Steps 3-4 for one track (update_kernel)."""
    m = cbar.shape[0]
    log_2pi = math.log(2.0 * math.pi)
    for j in range(m):
        P = Pm[j]
        x = xm[j]
        for a in range(_D):
            PHt[a, 0] = P[a, 0]
            PHt[a, 1] = P[a, 3]
        s00 = PHt[0, 0] + R[0, 0]
        s01 = PHt[0, 1] + R[0, 1]
        s10 = PHt[3, 0] + R[1, 0]
        s11 = PHt[3, 1] + R[1, 1]
        det = s00 * s11 - s01 * s10
        i00, i01, i10, i11 = s11 / det, -s01 / det, -s10 / det, s00 / det
        nu0 = z[0] - x[0]
        nu1 = z[1] - x[3]
        for a in range(_D):
            K[a, 0] = PHt[a, 0] * i00 + PHt[a, 1] * i10
            K[a, 1] = PHt[a, 0] * i01 + PHt[a, 1] * i11
        ox = out_xm[j]
        for a in range(_D):
            ox[a] = x[a] + K[a, 0] * nu0 + K[a, 1] * nu1
        oP = out_Pm[j]
        for a in range(_D):
            for b in range(a, _D):
                pab = P[a, b] - (K[a, 0] * PHt[b, 0] + K[a, 1] * PHt[b, 1])
                pba = P[b, a] - (K[b, 0] * PHt[a, 0] + K[b, 1] * PHt[a, 1])
                oP[a, b] = 0.5 * (pab + pba)
                oP[b, a] = oP[a, b]
        d2 = nu0 * (i00 * nu0 + i01 * nu1) + nu1 * (i10 * nu0 + i11 * nu1)
        log_w[j] = -0.5 * d2 - 0.5 * math.log(det) - log_2pi  # eq. 5
        log_w[j] += math.log(cbar[j]) if cbar[j] > 0.0 else -np.inf
    top = log_w.max()
    total = 0.0
    for j in range(m):
        out_mu[j] = math.exp(log_w[j] - top)
        total += out_mu[j]
    for j in range(m):
        out_mu[j] /= total  # eq. 6


@_compiled
def predict_update_kernel(
    xm: np.ndarray,
    Pm: np.ndarray,
    mu: np.ndarray,
    rows: np.ndarray,
    dt: np.ndarray,
    tau: np.ndarray,
    terms: np.ndarray,
    family: np.ndarray,
    omega: np.ndarray,
    q_keys: np.ndarray,
    z: np.ndarray,
    R: np.ndarray,
    out_xm: np.ndarray,
    out_Pm: np.ndarray,
    out_mu: np.ndarray,
    out_x: np.ndarray,
    out_P: np.ndarray,
) -> None:
    """One whole cycle per track, steps 1-5: predict_kernel over dt, then update_kernel
    with z, R and the combination, without writing the prediction out.  Track k is row
    rows[k] of the state and of out_xm, out_Pm, out_mu, which may be the state's own arrays
    (a row is read whole before it is written: the update in place); dt, terms, z, R,
    out_x and out_P per k."""
    n, m = rows.shape[0], mu.shape[1]
    wt = np.empty((m, m))
    cbar = np.empty(m)
    S = np.empty((m, _NP))
    X0 = np.empty((m, _NP))
    x0 = np.empty(_D)
    P0 = np.empty((_D, _D))
    T = np.empty((_D, _D))
    phiT = np.empty((_D, _D))
    phi = np.empty((_D, _D))
    Q = np.empty((_D, _D))
    t_bank = np.empty(TERMS)
    xp = np.empty((m, _D))
    Pp = np.empty((m, _D, _D))
    log_w = np.empty(m)
    K = np.empty((_D, 2))
    PHt = np.empty((_D, 2))
    for k in range(n):
        i = rows[k]
        _mix(xm[i], Pm[i], mu[i], dt[k], tau, wt, cbar, S, X0)
        for j in range(m):
            _unpack(X0[j], xm[i, 0], x0, P0)
            _phi_q_j(family[j], terms[k, j], omega[j], q_keys, x0, dt[k], t_bank, phi, Q)
            _predict_j(phi, Q, x0, P0, T, phiT, xp[j], Pp[j])
        _update_one(xp, Pp, cbar, z[k], R[k], out_xm[i], out_Pm[i], out_mu[i], log_w, K, PHt)
        _combine_one(out_xm[i], out_Pm[i], out_mu[i], out_x[k], out_P[k])


@_compiled
def update_kernel(
    xm: np.ndarray,
    Pm: np.ndarray,
    cbar: np.ndarray,
    z: np.ndarray,
    R: np.ndarray,
    out_xm: np.ndarray,
    out_Pm: np.ndarray,
    out_mu: np.ndarray,
) -> None:
    """Steps 3-4 for N tracks: each model's Kalman update
    with the measurement z (N,2) of covariance R (N,2,2), H picking x and y:

        S = H P Hᵀ + R, K = P Hᵀ S⁻¹, x ← x + K ν, P ← P − K (P Hᵀ)ᵀ     (Shu eq. 7, 9, 10)

    its log-likelihood log Λ_j (eq. 5) and μ_j ∝ Λ_j c̄_j (eq. 6, by log-sum-exp; c̄_j =
    0 gives μ_j = 0).  P is symmetrised (½ (P + Pᵀ)) as imm.IMMFilter.update does."""
    n, m = cbar.shape
    log_w = np.empty(m)
    K = np.empty((_D, 2))
    PHt = np.empty((_D, 2))
    for k in range(n):
        _update_one(xm[k], Pm[k], cbar[k], z[k], R[k], out_xm[k], out_Pm[k], out_mu[k], log_w, K, PHt)


@_compiled
def combine_kernel(xm: np.ndarray, Pm: np.ndarray, w: np.ndarray, out_x: np.ndarray, out_P: np.ndarray) -> None:
    """Step 5 (eq. 7-8) for N tracks with weights w (N,M)."""
    for k in range(w.shape[0]):
        _combine_one(xm[k], Pm[k], w[k], out_x[k], out_P[k])
