"""The IMM cycle of imm.py (eq. 0-8) as compiled loops: one pass over each track's models.

imm.py states the algorithm and its equations; this module is how the engine runs them
at thousands of tracks.  Written as batched numpy products, one IMM prediction of 4,000
tracks × 6 models made a dozen passes over (N, M, 6, 6) arrays (the mixed covariances,
the outer products, Φ and Q, Φ P⁰, Φ P⁰ Φᵀ), 7 MB each: it was bound by memory traffic,
not arithmetic, and was the largest part of the engine's period (issue 15's throughput
goal).  Here the tracks are taken 64 at a time, one per lane: a chunk's states are
gathered once into lane-last scratch arrays (a few hundred kB, in the L2 cache), every
step of the cycle is a loop over the lanes innermost, which the compiler turns into
vector instructions (it does not for a single track's 6×6 loops, nor for chunks of 8
tracks), and only the results are scattered back.  Against one track at a time this made
the engine's three IMM passes about 1.7× faster (4,000 × 10: 100-121k → 136-151k plots/s):

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
:func:`_predict_model` applies them as the rows of Φ they are (at most three entries
besides zeros a row), the same placement as singer_filter.singer_matrices_into and
coordinated_turn.ct_matrices_into.

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

from . import singer_filter
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
    "velocity_update_kernel",
]

#: model families (``family`` argument): a Singer model, a coordinated turn of known rate,
#: a coordinated turn at a bank angle (its rate from the speed of the mixed state)
SINGER = 0
CT = 1
BANK = 2
#: distinct entries of Φ and Q per track and model (the longer family's count):
#: Singer: T, Φ02, Φ12, Φ22 of one axis block, then Q's six q_ij in ``q_keys`` order;
#: coordinated turn: T_s, T_c, cos ωT, sin ωT, then q f_pp, q f_pv, q f_po, q T;
#: banked turn: q alone (the rest depends on the mixed state: :func:`_predict_model`)
TERMS = 10

_D = 6  # the state [x, vx, ax, y, vy, ay]
#: of the Singer series' 30 terms (singer_filter._SERIES_TERMS), the kernels sum the first 20:
#: below the switch (αT < 0.5) the 20th adds under 2e-20 of the first, far below round-off
_SERIES_USED = 20


#: the order of the q_ij in a Singer model's ``TERMS`` and each one's power of T (q_ij =
#: 2ασ_m² T^p g_ij(αT)): singer_filter._Q_KEYS and _Q_POWER, written out in
#: :func:`_singer_terms`
_SINGER_Q_ORDER = ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))
_SINGER_Q_POWERS = (5, 4, 3, 3, 2, 1)
if (
    tuple(singer_filter._Q_KEYS) != _SINGER_Q_ORDER
    or tuple(singer_filter._Q_POWER[ij] for ij in _SINGER_Q_ORDER) != _SINGER_Q_POWERS
):
    raise ImportError("singer_filter's q_ij order or powers changed: update imm_kernels._singer_terms")
if singer_filter._SERIES_TERMS < _SERIES_USED or singer_filter._SERIES_SWITCH_AT > 0.5:
    # the kernels read the series' first _SERIES_USED terms unchecked, enough below αT = 0.5
    raise ImportError("singer_filter's series are shorter or its switch higher: update imm_kernels._SERIES_USED")


@_compiled
def _singer_terms(
    dt: float,
    alpha: float,
    sigma: float,
    h2_series: np.ndarray,
    q_series: np.ndarray,
    switch: float,
    out: np.ndarray,
    k: int,
    j: int,
) -> None:
    """A Singer model's ``TERMS`` over dt into out[k, j] (singer_filter._transition_terms
    and _process_noise_terms, Shu eq. 12 and §4 with the misprints fixed): T, Φ02 =
    T² h2(αT), Φ12 = T h1(αT), Φ22 = e^{−αT}, then q_ij = 2ασ_m² T^p g_ij(αT) in
    ``_SINGER_Q_ORDER``, each g_ij by its Taylor series below αT = ``switch`` (where the
    closed form cancels) and in closed form above, the same split and the same series
    coefficients as singer_filter.py (its first ``_SERIES_USED``).  Written out term by
    term: with a loop over the q_ij and their powers it took 2.5× as long."""
    x = alpha * dt
    e1 = math.exp(-x)
    out[k, j, 0] = dt
    out[k, j, 2] = dt * (-math.expm1(-x) / x if x > 0.0 else 1.0)  # T h1(αT)
    out[k, j, 3] = e1
    if x < switch:
        # the seven series by Horner's rule in one loop: seven independent chains that the
        # CPU runs side by side
        h2 = g0 = g1 = g2 = g3 = g4 = g5 = 0.0
        for n in range(_SERIES_USED - 1, -1, -1):
            h2 = h2 * x + h2_series[n]
            g0 = g0 * x + q_series[n, 0]
            g1 = g1 * x + q_series[n, 1]
            g2 = g2 * x + q_series[n, 2]
            g3 = g3 * x + q_series[n, 3]
            g4 = g4 * x + q_series[n, 4]
            g5 = g5 * x + q_series[n, 5]
    else:  # the closed forms (singer_filter._q_closed)
        x2 = x * x
        e2 = e1 * e1
        h2 = (x - 1.0 + e1) / x2
        g0 = (1.0 - e2 + 2.0 * x + 2.0 * x2 * x / 3.0 - 2.0 * x2 - 4.0 * x * e1) / (2.0 * x2 * x2 * x)
        g1 = (1.0 + e2 - 2.0 * e1 + 2.0 * x * e1 - 2.0 * x + x2) / (2.0 * x2 * x2)
        g2 = (1.0 - e2 - 2.0 * x * e1) / (2.0 * x2 * x)
        g3 = (4.0 * e1 - 3.0 - e2 + 2.0 * x) / (2.0 * x2 * x)
        g4 = (1.0 + e2 - 2.0 * e1) / (2.0 * x2)
        g5 = (1.0 - e2) / (2.0 * x)
    t2 = dt * dt
    out[k, j, 1] = t2 * h2
    q_c = 2.0 * alpha * sigma * sigma
    out[k, j, 4] = q_c * g0 * t2 * t2 * dt
    out[k, j, 5] = q_c * g1 * t2 * t2
    out[k, j, 6] = q_c * g2 * t2 * dt
    out[k, j, 7] = q_c * g3 * t2 * dt
    out[k, j, 8] = q_c * g4 * t2
    out[k, j, 9] = q_c * g5 * dt


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
                _singer_terms(dt[k], alpha[j], sigma[j], h2_series, q_series, switch, out, k, j)
            elif family[j] == CT:
                _turn_terms(dt[k], omega[j], turn_q[j], out[k, j])
            else:
                out[k, j, 0] = turn_q[j]
                for q in range(1, TERMS):
                    out[k, j, q] = 0.0


#: the packed upper triangle of a symmetric 6×6 matrix: entry q is (_UT[q, 0], _UT[q, 1])
_UT = np.array([(a, b) for a in range(_D) for b in range(a, _D)], dtype=np.int64)
_NP = _D + _UT.shape[0]  # a mixing row: the 6 deviations, then the 21 packed covariances
#: tracks worked on at once, one per lane (the last axis of every scratch array below): each
#: step loops over the lanes innermost, straight-line arithmetic the compiler turns into
#: vector instructions.  A chunk's tracks are gathered into the lanes and the results
#: scattered back; lanes past the last track repeat it and are never written back.
_L = 64


@_compiled
def _lane_track(k0: int, nl: int, lane: int) -> int:
    """The chunk's index k of a lane (lanes from nl on repeat the last track)."""
    return k0 + min(lane, nl - 1)


@_compiled
def _gather_mixing(
    xm: np.ndarray, Pm: np.ndarray, mu: np.ndarray, rows: np.ndarray, k0: int, nl: int,
    X: np.ndarray, S: np.ndarray, MU: np.ndarray,
) -> None:  # fmt: skip
    """Tracks rows[k0 : k0 + nl] into the lanes for mixing: the model states X (M, 6, L),
    the packed model covariances into S[:, _D:] (M, _NP, L), μ into MU (M, L)."""
    m = MU.shape[0]
    for lane in range(_L):
        i = rows[_lane_track(k0, nl, lane)]
        for j in range(m):
            MU[j, lane] = mu[i, j]
            for a in range(_D):
                X[j, a, lane] = xm[i, j, a]
            for q in range(_NP - _D):
                S[j, _D + q, lane] = Pm[i, j, _UT[q, 0], _UT[q, 1]]


@_compiled
def _gather_models(
    xm: np.ndarray, Pm: np.ndarray, w: np.ndarray, rows: np.ndarray, k0: int, nl: int,
    X: np.ndarray, P: np.ndarray, W: np.ndarray,
) -> None:  # fmt: skip
    """Tracks rows[k0 : k0 + nl] into the lanes whole: X (M, 6, L), P (M, 6, 6, L), W (M, L)."""
    m = W.shape[0]
    for lane in range(_L):
        i = rows[_lane_track(k0, nl, lane)]
        for j in range(m):
            W[j, lane] = w[i, j]
            for a in range(_D):
                X[j, a, lane] = xm[i, j, a]
                for b in range(_D):
                    P[j, a, b, lane] = Pm[i, j, a, b]


@_compiled
def _gather_per_track(dt: np.ndarray, terms: np.ndarray, k0: int, nl: int, DT: np.ndarray, TJ: np.ndarray) -> None:
    """Each lane's dt into DT (L,) and its models' ``TERMS`` into TJ (M, TERMS, L)."""
    for lane in range(_L):
        k = _lane_track(k0, nl, lane)
        DT[lane] = dt[k]
        for j in range(TJ.shape[0]):
            for q in range(TERMS):
                TJ[j, q, lane] = terms[k, j, q]


@_compiled
def _scatter_models(
    X: np.ndarray, P: np.ndarray, W: np.ndarray, rows: np.ndarray, k0: int, nl: int,
    xm: np.ndarray, Pm: np.ndarray, w: np.ndarray,
) -> None:  # fmt: skip
    """The lanes' X, P, W back into the rows rows[k0 : k0 + nl] of xm, Pm, w."""
    m = W.shape[0]
    for lane in range(nl):
        i = rows[k0 + lane]
        for j in range(m):
            w[i, j] = W[j, lane]
            for a in range(_D):
                xm[i, j, a] = X[j, a, lane]
                for b in range(_D):
                    Pm[i, j, a, b] = P[j, a, b, lane]


@_compiled
def _scatter_combined(x: np.ndarray, P: np.ndarray, k0: int, nl: int, out_x: np.ndarray, out_P: np.ndarray) -> None:
    """The lanes' combined x (6, L), P (6, 6, L) into out_x[k0 : k0 + nl], out_P[k0 : k0 + nl]."""
    for lane in range(nl):
        for a in range(_D):
            out_x[k0 + lane, a] = x[a, lane]
            for b in range(_D):
                out_P[k0 + lane, a, b] = P[a, b, lane]


@_compiled
def _mix(
    X: np.ndarray, S: np.ndarray, MU: np.ndarray, DT: np.ndarray, tau: np.ndarray,
    stay: np.ndarray, wt: np.ndarray, cbar: np.ndarray, X0: np.ndarray,
) -> None:  # fmt: skip
    """Eq. 0-4 for the lanes' M models: c̄ (M, L) into cbar and, per model j, the mixed
    initial condition into X0[j] (``_NP`` numbers a lane): x⁰_j − x_0 (6), then P⁰_j packed
    (21).  S holds the packed P_i (``_gather_mixing``) and is scratch after.

    With e_i = x_i − x_0 (model 0's state as the reference, so nothing of the size of a
    position cancels) and Σ_i μ_{i|j} = 1, eq. 3-4 are

        x⁰_j = x_0 + Σ_i μ_{i|j} e_i,   P⁰_j = Σ_i μ_{i|j} (P_i + e_i e_iᵀ) − e⁰_j e⁰_jᵀ

    (imm.IMMFilter.mix), i.e. the μ_{i|j} times the rows S_i = [e_i, packed(P_i + e_i e_iᵀ)].
    tau (1 + M, M): row 0 the dwell times τ_i, rows 1.. the exit shares E_ij of eq. 0."""
    m = MU.shape[0]
    for i in range(m):
        for lane in range(_L):
            stay[i, lane] = math.exp(-max(DT[lane], 0.0) / tau[0, i])  # eq. 0: p_ii
    for j in range(m):
        for lane in range(_L):
            cbar[j, lane] = 0.0
        for i in range(m):
            if i == j:
                for lane in range(_L):
                    wt[j, i, lane] = stay[i, lane] * MU[i, lane]
            else:
                for lane in range(_L):
                    wt[j, i, lane] = (1.0 - stay[i, lane]) * tau[1 + i, j] * MU[i, lane]
            for lane in range(_L):
                cbar[j, lane] += wt[j, i, lane]  # eq. 1
    for j in range(m):
        for i in range(m):
            same = 1.0 if i == j else 0.0
            for lane in range(_L):
                c = cbar[j, lane]
                # eq. 2; a mode nothing can reach (c̄_j = 0) keeps its own state
                wt[j, i, lane] = wt[j, i, lane] / c if c > 0.0 else same
    for i in range(m):
        for a in range(_D):
            for lane in range(_L):
                S[i, a, lane] = X[i, a, lane] - X[0, a, lane]
        for q in range(_NP - _D):
            a, b = _UT[q, 0], _UT[q, 1]
            for lane in range(_L):
                S[i, _D + q, lane] += S[i, a, lane] * S[i, b, lane]
    for j in range(m):
        for q in range(_NP):
            for lane in range(_L):
                X0[j, q, lane] = 0.0
        for i in range(m):
            for q in range(_NP):
                for lane in range(_L):
                    X0[j, q, lane] += wt[j, i, lane] * S[i, q, lane]  # eq. 3 and the sum of eq. 4
        for q in range(_NP - _D):
            a, b = _UT[q, 0], _UT[q, 1]
            for lane in range(_L):
                X0[j, _D + q, lane] -= X0[j, a, lane] * X0[j, b, lane]  # − e⁰_j e⁰_jᵀ


@_compiled
def _restage(XP: np.ndarray, PP: np.ndarray, cbar: np.ndarray, X: np.ndarray, S: np.ndarray, MU: np.ndarray) -> None:
    """A sub-step's predictions as the next sub-step's states to mix (``_gather_mixing``'s
    layout): X ← XP, the packed covariances into S[:, _D:] from PP, μ ← c̄ (the mode
    probabilities predicted to the sub-step's end, the prior of its mixing)."""
    m = MU.shape[0]
    for j in range(m):
        for lane in range(_L):
            MU[j, lane] = cbar[j, lane]
        for a in range(_D):
            for lane in range(_L):
                X[j, a, lane] = XP[j, a, lane]
        for q in range(_NP - _D):
            a, b = _UT[q, 0], _UT[q, 1]
            for lane in range(_L):
                S[j, _D + q, lane] = PP[j, a, b, lane]


@_compiled
def _mix_and_predict(
    substeps: int, family: np.ndarray, TJ: np.ndarray, omega: np.ndarray, q_keys: np.ndarray, tau: np.ndarray,
    X: np.ndarray, S: np.ndarray, MU: np.ndarray, DT: np.ndarray, stay: np.ndarray, wt: np.ndarray,
    cbar: np.ndarray, X0: np.ndarray, x0: np.ndarray, P0: np.ndarray, W: np.ndarray, TB: np.ndarray,
    tb: np.ndarray, T: np.ndarray, XP: np.ndarray, PP: np.ndarray,
) -> None:  # fmt: skip
    """Steps 1-2 for the lanes, ``substeps`` times over the sub-step's DT and terms TJ
    (imm.py, "Switching inside the interval"): each sub-step mixes (``_mix``) the one
    before's predictions (``_restage``) and predicts every model into XP, PP (M, 6(, 6), L),
    leaving the last sub-step's c̄ in cbar. X, S, MU hold the gathered states on entry."""
    m = MU.shape[0]
    for step in range(substeps):
        if step:
            _restage(XP, PP, cbar, X, S, MU)
        _mix(X, S, MU, DT, tau, stay, wt, cbar, X0)
        for j in range(m):
            _unpack(X0[j], X[0], x0, P0)
            _predict_model(family[j], TJ[j], omega[j], q_keys, x0, P0, DT, W, TB, tb, T, XP[j], PP[j])


@_compiled
def _unpack(X0j: np.ndarray, x_ref: np.ndarray, x0: np.ndarray, P0: np.ndarray) -> None:
    """x⁰_j (6, L) and P⁰_j (6, 6, L), symmetric, from the mixing rows X0j (_NP, L)."""
    for a in range(_D):
        for lane in range(_L):
            x0[a, lane] = x_ref[a, lane] + X0j[a, lane]
    for q in range(_NP - _D):
        a, b = _UT[q, 0], _UT[q, 1]
        for lane in range(_L):
            P0[a, b, lane] = X0j[_D + q, lane]
            P0[b, a, lane] = X0j[_D + q, lane]


@_compiled
def _predict_model(
    family: int, TJ: np.ndarray, omega: float, q_keys: np.ndarray, x0: np.ndarray, P0: np.ndarray,
    DT: np.ndarray, W: np.ndarray, TB: np.ndarray, tb: np.ndarray, T: np.ndarray, xp: np.ndarray, Pp: np.ndarray,
) -> None:  # fmt: skip
    """Model j's prediction in every lane from its mixed x⁰ (6, L), P⁰ (6, 6, L):
    x = Φ x⁰, P = Φ P⁰ Φᵀ + Q (Shu eq. 8, 11; coordinated_turn.py eq. 4), P exactly
    symmetric, with Φ and Q from the model's ``TERMS`` TJ (TERMS, L) (a banked turn's from
    x⁰, below).  Every row of Φ has at most three entries besides zeros, so Φ P⁰ (into T)
    and (Φ P⁰) Φᵀ are written out row by row and column by column from them:

    * Singer (singer_filter.singer_matrices_into, Shu eq. 12): per axis block (o = 0 for
      x, 3 for y) [[1, T, Φ02], [0, 1, Φ12], [0, 0, Φ22]], the terms T, Φ02, Φ12, Φ22,
      then Q's block entries q_ij in ``q_keys`` order;
    * coordinated turn (coordinated_turn.ct_matrices_into, eq. 2-4), the terms T_s, T_c,
      cos ωT, sin ωT, q f_pp, q f_pv, q f_po, q T:
      x ← x + T_s vx − T_c vy, vx ← cos vx − sin vy, ax ← −ω sin vx − ω cos vy,
      y ← y + T_c vx + T_s vy, vy ← sin vx + cos vy, ay ← ω cos vx − ω sin vy;
    * banked turn: the coordinated turn at ω = g tan φ / v of x⁰'s speed v (``omega`` is
      the signed g tan φ), v floored at MIN_TURN_SPEED_MPS (eq. 5,
      banked_turn_rate_rad_s), its q in TJ[0]; its terms are computed into TB (W: the
      lanes' ω; tb: scratch)."""
    if family == SINGER:
        for o in range(0, _D, 3):
            for lane in range(_L):
                xp[o, lane] = x0[o, lane] + TJ[0, lane] * x0[o + 1, lane] + TJ[1, lane] * x0[o + 2, lane]
                xp[o + 1, lane] = x0[o + 1, lane] + TJ[2, lane] * x0[o + 2, lane]
                xp[o + 2, lane] = TJ[3, lane] * x0[o + 2, lane]
            for b in range(_D):
                for lane in range(_L):
                    p2 = P0[o + 2, b, lane]
                    T[o, b, lane] = P0[o, b, lane] + TJ[0, lane] * P0[o + 1, b, lane] + TJ[1, lane] * p2
                    T[o + 1, b, lane] = P0[o + 1, b, lane] + TJ[2, lane] * p2
                    T[o + 2, b, lane] = TJ[3, lane] * p2
        for a in range(_D):
            for o in range(0, _D, 3):
                for lane in range(_L):
                    t2 = T[a, o + 2, lane]
                    Pp[a, o, lane] = T[a, o, lane] + TJ[0, lane] * T[a, o + 1, lane] + TJ[1, lane] * t2
                    Pp[a, o + 1, lane] = T[a, o + 1, lane] + TJ[2, lane] * t2
                    Pp[a, o + 2, lane] = TJ[3, lane] * t2
        for o in range(0, _D, 3):
            for k in range(q_keys.shape[0]):
                a, b = o + q_keys[k, 0], o + q_keys[k, 1]
                for lane in range(_L):
                    Pp[a, b, lane] += TJ[4 + k, lane]
    else:
        TC = TJ
        if family == BANK:
            for lane in range(_L):
                v = math.sqrt(x0[1, lane] * x0[1, lane] + x0[4, lane] * x0[4, lane])
                W[lane] = omega / max(v, MIN_TURN_SPEED_MPS)
                _turn_terms(DT[lane], W[lane], TJ[0, lane], tb)
                for q in range(TERMS):
                    TB[q, lane] = tb[q]
            TC = TB
        else:
            for lane in range(_L):
                W[lane] = omega
        for lane in range(_L):
            s_w, c_w, c, s, w = TC[0, lane], TC[1, lane], TC[2, lane], TC[3, lane], W[lane]
            v1, v4 = x0[1, lane], x0[4, lane]
            xp[0, lane] = x0[0, lane] + s_w * v1 - c_w * v4
            xp[1, lane] = c * v1 - s * v4
            xp[2, lane] = -w * s * v1 - w * c * v4
            xp[3, lane] = x0[3, lane] + c_w * v1 + s_w * v4
            xp[4, lane] = s * v1 + c * v4
            xp[5, lane] = w * c * v1 - w * s * v4
        for b in range(_D):
            for lane in range(_L):
                s_w, c_w, c, s, w = TC[0, lane], TC[1, lane], TC[2, lane], TC[3, lane], W[lane]
                v1, v4 = P0[1, b, lane], P0[4, b, lane]
                T[0, b, lane] = P0[0, b, lane] + s_w * v1 - c_w * v4
                T[1, b, lane] = c * v1 - s * v4
                T[2, b, lane] = -w * s * v1 - w * c * v4
                T[3, b, lane] = P0[3, b, lane] + c_w * v1 + s_w * v4
                T[4, b, lane] = s * v1 + c * v4
                T[5, b, lane] = w * c * v1 - w * s * v4
        for a in range(_D):
            for lane in range(_L):
                s_w, c_w, c, s, w = TC[0, lane], TC[1, lane], TC[2, lane], TC[3, lane], W[lane]
                v1, v4 = T[a, 1, lane], T[a, 4, lane]
                Pp[a, 0, lane] = T[a, 0, lane] + s_w * v1 - c_w * v4
                Pp[a, 1, lane] = c * v1 - s * v4
                Pp[a, 2, lane] = -w * s * v1 - w * c * v4
                Pp[a, 3, lane] = T[a, 3, lane] + c_w * v1 + s_w * v4
                Pp[a, 4, lane] = s * v1 + c * v4
                Pp[a, 5, lane] = w * c * v1 - w * s * v4
        for lane in range(_L):  # Q (coordinated_turn.ct_matrices_into): its upper triangle
            pp, pv, po, vv, w = TC[4, lane], TC[5, lane], TC[6, lane], TC[7, lane], W[lane]
            Pp[0, 0, lane] += pp
            Pp[3, 3, lane] += pp
            Pp[1, 1, lane] += vv
            Pp[4, 4, lane] += vv
            Pp[0, 1, lane] += pv
            Pp[3, 4, lane] += pv
            Pp[0, 4, lane] += po
            Pp[1, 3, lane] -= po
            Pp[0, 2, lane] -= w * po
            Pp[3, 5, lane] -= w * po
            Pp[0, 5, lane] += w * pv
            Pp[2, 3, lane] -= w * pv
            Pp[1, 5, lane] += w * vv
            Pp[2, 4, lane] -= w * vv
            Pp[2, 2, lane] += w * w * vv
            Pp[5, 5, lane] += w * w * vv
    for a in range(_D):
        for b in range(a + 1, _D):
            for lane in range(_L):
                Pp[b, a, lane] = Pp[a, b, lane]


@_compiled
def _combine(X: np.ndarray, P: np.ndarray, w: np.ndarray, x: np.ndarray, Pc: np.ndarray) -> None:
    """Eq. 7-8 in every lane: x = Σ w_j x_j, P = Σ w_j [P_j + (x_j − x)(x_j − x)ᵀ];
    X (M, 6, L), P (M, 6, 6, L), w (M, L) into x (6, L), Pc (6, 6, L)."""
    m = w.shape[0]
    for a in range(_D):
        for lane in range(_L):
            x[a, lane] = 0.0
        for j in range(m):
            for lane in range(_L):
                x[a, lane] += w[j, lane] * X[j, a, lane]
    for a in range(_D):
        for b in range(a, _D):
            for lane in range(_L):
                Pc[a, b, lane] = 0.0
            for j in range(m):
                for lane in range(_L):
                    d = (X[j, a, lane] - x[a, lane]) * (X[j, b, lane] - x[b, lane])
                    Pc[a, b, lane] += w[j, lane] * (P[j, a, b, lane] + d)
            for lane in range(_L):
                Pc[b, a, lane] = Pc[a, b, lane]


@_compiled
def _gather_measurements(
    z: np.ndarray, R: np.ndarray, lf: np.ndarray, lfw: np.ndarray, k0: int, nl: int,
    Z: np.ndarray, RL: np.ndarray, LF: np.ndarray, LW: np.ndarray,
) -> None:  # fmt: skip
    """Each lane's measurement into Z (2, L), its covariance into RL (2, 2, L), its
    per-model log-likelihood term into LF (M, L) and that term's weight into LW (L,)."""
    for lane in range(_L):
        k = _lane_track(k0, nl, lane)
        for a in range(2):
            Z[a, lane] = z[k, a]
            for b in range(2):
                RL[a, b, lane] = R[k, a, b]
        for j in range(LF.shape[0]):
            LF[j, lane] = lf[k, j]
        LW[lane] = lfw[k]


@_compiled
def _lse(a: np.ndarray, lane: int) -> float:
    """log Σ_j exp a[j, lane] (−inf when every term is)."""
    top = -np.inf
    for j in range(a.shape[0]):
        top = max(top, a[j, lane])
    if top == -np.inf:
        return top
    total = 0.0
    for j in range(a.shape[0]):
        total += math.exp(a[j, lane] - top)
    return top + math.log(total)


@_compiled
def _scatter_lane_values(v: np.ndarray, k0: int, nl: int, out: np.ndarray) -> None:
    for lane in range(nl):
        out[k0 + lane] = v[lane]


@_compiled
def _update(
    XP: np.ndarray, PP: np.ndarray, cbar: np.ndarray, Z: np.ndarray, RL: np.ndarray, LF: np.ndarray, LW: np.ndarray,
    LB: np.ndarray, LP: np.ndarray, EV: np.ndarray,
    XU: np.ndarray, PU: np.ndarray, MU: np.ndarray, logw: np.ndarray, K: np.ndarray, PHt: np.ndarray, G: np.ndarray,
) -> None:  # fmt: skip
    """Steps 3-4 in every lane: each model's Kalman update of XP (M, 6, L), PP (M, 6, 6, L)
    with the measurement Z (2, L) of covariance RL (2, 2, L), H picking x and y:

        S = H P Hᵀ + R, K = P Hᵀ S⁻¹, x ← x + K ν, P ← P − K (P Hᵀ)ᵀ     (Shu eq. 7, 9, 10)

    into XU, PU (P symmetrised, ½ (P + Pᵀ), as imm.IMMFilter.update does); its
    log-likelihood log Λ_j (eq. 5) and μ_j ∝ Λ_j c̄_j into MU (eq. 6, by log-sum-exp; c̄_j =
    0 gives μ_j = 0).  LF (M, L), times its weight LW (L,), is added to log Λ_j: the
    log-likelihood of what else the measurement says about the mode
    (imm.IMMFilter.roll_log_likelihoods: a Mode S roll angle; zero without one).  Into LB
    (L,) the log Bayes factor by which LF's evidence made the position more or less likely,

        log [Σ_j c̄_j f_j Λ_j / Σ_j c̄_j f_j] − log Σ_j c̄_j Λ_j,     f_j = exp LF_j,

    whatever its weight (0 without one; imm.IMMFilter.roll_log_likelihoods says what it is
    for).  LP (M, L) log Λ_j c̄_j, logw (M, L), K and PHt (6, 2, L), G (7, L): scratch."""
    m = cbar.shape[0]
    log_2pi = math.log(2.0 * math.pi)
    for j in range(m):
        for a in range(_D):
            for lane in range(_L):
                PHt[a, 0, lane] = PP[j, a, 0, lane]
                PHt[a, 1, lane] = PP[j, a, 3, lane]
        for lane in range(_L):
            s00 = PHt[0, 0, lane] + RL[0, 0, lane]
            s01 = PHt[0, 1, lane] + RL[0, 1, lane]
            s10 = PHt[3, 0, lane] + RL[1, 0, lane]
            s11 = PHt[3, 1, lane] + RL[1, 1, lane]
            det = s00 * s11 - s01 * s10
            G[0, lane] = s11 / det  # S⁻¹
            G[1, lane] = -s01 / det
            G[2, lane] = -s10 / det
            G[3, lane] = s00 / det
            G[4, lane] = Z[0, lane] - XP[j, 0, lane]  # ν
            G[5, lane] = Z[1, lane] - XP[j, 3, lane]
            G[6, lane] = det
        for a in range(_D):
            for lane in range(_L):
                K[a, 0, lane] = PHt[a, 0, lane] * G[0, lane] + PHt[a, 1, lane] * G[2, lane]
                K[a, 1, lane] = PHt[a, 0, lane] * G[1, lane] + PHt[a, 1, lane] * G[3, lane]
                XU[j, a, lane] = XP[j, a, lane] + K[a, 0, lane] * G[4, lane] + K[a, 1, lane] * G[5, lane]
        for a in range(_D):
            for b in range(a, _D):
                for lane in range(_L):
                    pab = PP[j, a, b, lane] - (K[a, 0, lane] * PHt[b, 0, lane] + K[a, 1, lane] * PHt[b, 1, lane])
                    pba = PP[j, b, a, lane] - (K[b, 0, lane] * PHt[a, 0, lane] + K[b, 1, lane] * PHt[a, 1, lane])
                    PU[j, a, b, lane] = 0.5 * (pab + pba)
                    PU[j, b, a, lane] = PU[j, a, b, lane]
        for lane in range(_L):
            nu0, nu1 = G[4, lane], G[5, lane]
            d2 = nu0 * (G[0, lane] * nu0 + G[1, lane] * nu1) + nu1 * (G[2, lane] * nu0 + G[3, lane] * nu1)
            lw = -0.5 * d2 - 0.5 * math.log(G[6, lane]) - log_2pi  # eq. 5
            LP[j, lane] = lw + math.log(cbar[j, lane]) if cbar[j, lane] > 0.0 else -np.inf
            logw[j, lane] = LP[j, lane] + LW[lane] * LF[j, lane]
    for lane in range(_L):  # the evidence's Bayes factor against the position: LP + LF, LF + log c̄, LP
        LB[lane] = 0.0
        informative = False
        for j in range(m):
            informative = informative or LF[j, lane] != 0.0
        if not informative:  # no report (most tracks, most scans): a factor of 1
            continue
        position = _lse(LP, lane)
        for j in range(m):
            EV[0, j, lane] = LP[j, lane] + LF[j, lane]
            EV[1, j, lane] = LF[j, lane] + math.log(cbar[j, lane]) if cbar[j, lane] > 0.0 else -np.inf
        with_evidence = _lse(EV[0], lane)
        prior = _lse(EV[1], lane)
        LB[lane] = with_evidence - prior - position if position > -np.inf and prior > -np.inf else 0.0
    for lane in range(_L):
        top = logw[0, lane]
        for j in range(1, m):
            top = max(top, logw[j, lane])
        total = 0.0
        for j in range(m):
            MU[j, lane] = math.exp(logw[j, lane] - top)
            total += MU[j, lane]
        for j in range(m):
            MU[j, lane] /= total  # eq. 6


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
    substeps: int,
    out_xm: np.ndarray,
    out_Pm: np.ndarray,
    out_cbar: np.ndarray,
) -> None:
    """Steps 1-2 (eq. 0-4, each model's prediction) for N tracks into out_xm, out_Pm and
    out_cbar (c̄ of eq. 1). xm (N,M,6), Pm (N,M,6,6), mu (N,M), dt (N,), tau (1 + M, M) the
    dwell times and the exit shares of eq. 0 (imm.IMMFilter._tau_exit), terms (N,M,TERMS),
    family and omega (M,) (a banked turn's omega is its signed
    g tan φ), q_keys (6,2) the Singer q_ij order.  ``substeps`` K ≥ 1: steps 1-2 K times
    in a row, dt and terms being those of one sub-step (dt/K): the modes may switch K times
    in the interval (imm.py, "Switching inside the interval")."""
    n, m = mu.shape
    rows = np.arange(n)
    X, XP, X0, S = np.empty((m, _D, _L)), np.empty((m, _D, _L)), np.empty((m, _NP, _L)), np.empty((m, _NP, _L))
    PP = np.empty((m, _D, _D, _L))
    MU, cbar, stay, wt = np.empty((m, _L)), np.empty((m, _L)), np.empty((m, _L)), np.empty((m, m, _L))
    DT, W, TJ, TB, tb = np.empty(_L), np.empty(_L), np.empty((m, TERMS, _L)), np.empty((TERMS, _L)), np.empty(TERMS)
    x0, P0, T = np.empty((_D, _L)), np.empty((_D, _D, _L)), np.empty((_D, _D, _L))
    for k0 in range(0, n, _L):
        nl = min(_L, n - k0)
        _gather_mixing(xm, Pm, mu, rows, k0, nl, X, S, MU)
        _gather_per_track(dt, terms, k0, nl, DT, TJ)
        _mix_and_predict(
            substeps, family, TJ, omega, q_keys, tau, X, S, MU, DT, stay, wt, cbar, X0, x0, P0, W, TB, tb, T, XP, PP
        )
        _scatter_models(XP, PP, cbar, rows, k0, nl, out_xm, out_Pm, out_cbar)


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
    (N,M,2,2).  ``block`` lists state indices in order and holds 0 and 3 (x and y):
    [0, 1, 3, 4] for association (position and velocity; the model-conditioned gates,
    imm.py "Gating"), [0, 3] for the output.  Track k is row rows[k] of the state (no
    copy of the rows taken); dt, terms and the outputs per k."""
    n, m = rows.shape[0], mu.shape[1]
    nr = block.size
    ix = iy = 0  # where x and y are in the block
    for r in range(nr):
        if block[r] == 0:
            ix = r
        elif block[r] == 3:
            iy = r
    X, XP, X0, S = np.empty((m, _D, _L)), np.empty((m, _D, _L)), np.empty((m, _NP, _L)), np.empty((m, _NP, _L))
    MU, cbar, stay, wt = np.empty((m, _L)), np.empty((m, _L)), np.empty((m, _L)), np.empty((m, m, _L))
    DT, W, TJ, TB, tb = np.empty(_L), np.empty(_L), np.empty((m, TERMS, _L)), np.empty((TERMS, _L)), np.empty(TERMS)
    x0, P0, T, Pp = np.empty((_D, _L)), np.empty((_D, _D, _L)), np.empty((_D, _D, _L)), np.empty((_D, _D, _L))
    B = np.empty((m, nr, nr, _L))  # each model's block of Φ P⁰ Φᵀ + Q
    xc, Pb = np.empty((_D, _L)), np.empty((nr, nr, _L))  # the combination
    for k0 in range(0, n, _L):
        nl = min(_L, n - k0)
        _gather_mixing(xm, Pm, mu, rows, k0, nl, X, S, MU)
        _gather_per_track(dt, terms, k0, nl, DT, TJ)
        _mix(X, S, MU, DT, tau, stay, wt, cbar, X0)
        for j in range(m):
            _unpack(X0[j], X[0], x0, P0)
            _predict_model(family[j], TJ[j], omega[j], q_keys, x0, P0, DT, W, TB, tb, T, XP[j], Pp)
            for r in range(nr):
                for u in range(nr):
                    for lane in range(_L):
                        B[j, r, u, lane] = Pp[block[r], block[u], lane]
        for a in range(_D):  # eq. 7 with c̄
            for lane in range(_L):
                xc[a, lane] = 0.0
            for j in range(m):
                for lane in range(_L):
                    xc[a, lane] += cbar[j, lane] * XP[j, a, lane]
        for r in range(nr):  # eq. 8 on the block
            a = block[r]
            for u in range(r, nr):
                b = block[u]
                for lane in range(_L):
                    Pb[r, u, lane] = 0.0
                for j in range(m):
                    for lane in range(_L):
                        d = (XP[j, a, lane] - xc[a, lane]) * (XP[j, b, lane] - xc[b, lane])
                        Pb[r, u, lane] += cbar[j, lane] * (B[j, r, u, lane] + d)
        for lane in range(nl):
            k = k0 + lane
            for j in range(m):
                out_xy[k, j, 0] = XP[j, 0, lane]
                out_xy[k, j, 1] = XP[j, 3, lane]
                out_cov_xy[k, j, 0, 0] = B[j, ix, ix, lane]
                out_cov_xy[k, j, 0, 1] = B[j, ix, iy, lane]
                out_cov_xy[k, j, 1, 0] = B[j, iy, ix, lane]
                out_cov_xy[k, j, 1, 1] = B[j, iy, iy, lane]
            for a in range(_D):
                out_x[k, a] = xc[a, lane]
                for b in range(_D):
                    out_P[k, a, b] = np.nan
            for r in range(nr):
                for u in range(r, nr):
                    out_P[k, block[r], block[u]] = Pb[r, u, lane]
                    out_P[k, block[u], block[r]] = Pb[r, u, lane]


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
    substeps: int,
    z: np.ndarray,
    R: np.ndarray,
    lf: np.ndarray,
    lfw: np.ndarray,
    out_xm: np.ndarray,
    out_Pm: np.ndarray,
    out_mu: np.ndarray,
    out_x: np.ndarray,
    out_P: np.ndarray,
    out_lbf: np.ndarray,
) -> None:
    """One whole cycle per track, steps 1-5: predict_kernel (``substeps`` times over dt,
    the sub-step's, with its terms), then update_kernel
    with z, R and the combination, without writing the prediction out.  Track k is row
    rows[k] of the state and of out_xm, out_Pm, out_mu, which may be the state's own arrays
    (a chunk's rows are read whole before they are written: the update in place); dt,
    terms, z, R, lf (N, M: added to each model's log-likelihood times lfw (N,),
    ``_update``), out_x, out_P and out_lbf (N,: lf's log Bayes factor against the position)
    per k."""
    n, m = rows.shape[0], mu.shape[1]
    X, XP, X0, S = np.empty((m, _D, _L)), np.empty((m, _D, _L)), np.empty((m, _NP, _L)), np.empty((m, _NP, _L))
    PP, XU, PU = np.empty((m, _D, _D, _L)), np.empty((m, _D, _L)), np.empty((m, _D, _D, _L))
    MU, cbar, stay, wt = np.empty((m, _L)), np.empty((m, _L)), np.empty((m, _L)), np.empty((m, m, _L))
    DT, W, TJ, TB, tb = np.empty(_L), np.empty(_L), np.empty((m, TERMS, _L)), np.empty((TERMS, _L)), np.empty(TERMS)
    x0, P0, T = np.empty((_D, _L)), np.empty((_D, _D, _L)), np.empty((_D, _D, _L))
    Z, RL, MUU, logw = np.empty((2, _L)), np.empty((2, 2, _L)), np.empty((m, _L)), np.empty((m, _L))
    LF, LW, LB, LP, EV = np.empty((m, _L)), np.empty(_L), np.empty(_L), np.empty((m, _L)), np.empty((2, m, _L))
    K, PHt, G = np.empty((_D, 2, _L)), np.empty((_D, 2, _L)), np.empty((7, _L))
    xc, Pc = np.empty((_D, _L)), np.empty((_D, _D, _L))
    for k0 in range(0, n, _L):
        nl = min(_L, n - k0)
        _gather_mixing(xm, Pm, mu, rows, k0, nl, X, S, MU)
        _gather_per_track(dt, terms, k0, nl, DT, TJ)
        _gather_measurements(z, R, lf, lfw, k0, nl, Z, RL, LF, LW)
        _mix_and_predict(
            substeps, family, TJ, omega, q_keys, tau, X, S, MU, DT, stay, wt, cbar, X0, x0, P0, W, TB, tb, T, XP, PP
        )
        _update(XP, PP, cbar, Z, RL, LF, LW, LB, LP, EV, XU, PU, MUU, logw, K, PHt, G)
        _combine(XU, PU, MUU, xc, Pc)
        _scatter_models(XU, PU, MUU, rows, k0, nl, out_xm, out_Pm, out_mu)
        _scatter_combined(xc, Pc, k0, nl, out_x, out_P)
        _scatter_lane_values(LB, k0, nl, out_lbf)


@_compiled
def update_kernel(
    xm: np.ndarray,
    Pm: np.ndarray,
    cbar: np.ndarray,
    z: np.ndarray,
    R: np.ndarray,
    lf: np.ndarray,
    lfw: np.ndarray,
    out_xm: np.ndarray,
    out_Pm: np.ndarray,
    out_mu: np.ndarray,
    out_lbf: np.ndarray,
) -> None:
    """Steps 3-4 for N tracks (``_update``): each model's Kalman update with the
    measurement z (N,2) of covariance R (N,2,2), and the mode probabilities, with lf (N,M)
    times lfw (N,) added to each model's log-likelihood, lf's log Bayes factor into out_lbf
    (``_update``)."""
    n, m = cbar.shape
    rows = np.arange(n)
    XP, XU, PP, PU = np.empty((m, _D, _L)), np.empty((m, _D, _L)), np.empty((m, _D, _D, _L)), np.empty((m, _D, _D, _L))
    CB, MUU, logw = np.empty((m, _L)), np.empty((m, _L)), np.empty((m, _L))
    Z, RL, G, LF = np.empty((2, _L)), np.empty((2, 2, _L)), np.empty((7, _L)), np.empty((m, _L))
    LW, LB, LP, EV = np.empty(_L), np.empty(_L), np.empty((m, _L)), np.empty((2, m, _L))
    K, PHt = np.empty((_D, 2, _L)), np.empty((_D, 2, _L))
    for k0 in range(0, n, _L):
        nl = min(_L, n - k0)
        _gather_models(xm, Pm, cbar, rows, k0, nl, XP, PP, CB)
        _gather_measurements(z, R, lf, lfw, k0, nl, Z, RL, LF, LW)
        _update(XP, PP, CB, Z, RL, LF, LW, LB, LP, EV, XU, PU, MUU, logw, K, PHt, G)
        _scatter_models(XU, PU, MUU, rows, k0, nl, out_xm, out_Pm, out_mu)
        _scatter_lane_values(LB, k0, nl, out_lbf)


@_compiled
def combine_kernel(xm: np.ndarray, Pm: np.ndarray, w: np.ndarray, out_x: np.ndarray, out_P: np.ndarray) -> None:
    """Step 5 (eq. 7-8) for N tracks with weights w (N,M)."""
    n, m = w.shape
    rows = np.arange(n)
    X, P, Wl = np.empty((m, _D, _L)), np.empty((m, _D, _D, _L)), np.empty((m, _L))
    xc, Pc = np.empty((_D, _L)), np.empty((_D, _D, _L))
    for k0 in range(0, n, _L):
        nl = min(_L, n - k0)
        _gather_models(xm, Pm, w, rows, k0, nl, X, P, Wl)
        _combine(X, P, Wl, xc, Pc)
        _scatter_combined(xc, Pc, k0, nl, out_x, out_P)


@_compiled
def velocity_update_kernel(
    xm: np.ndarray, Pm: np.ndarray, mu: np.ndarray, rows: np.ndarray, z: np.ndarray, R: np.ndarray,
    age: np.ndarray, age_var: float, gate_chi2: float, out_x: np.ndarray, out_P: np.ndarray, used: np.ndarray,
) -> None:  # fmt: skip
    """imm.IMMFilter.velocity_update_rows, one track at a time, in place on the rows ``rows``
    of xm (N, M, 6), Pm (N, M, 6, 6), mu (N, M): each model's Kalman update with the
    velocity z (K, 2) of covariance R (K, 2, 2) measured age (K,) before the state's time
    (H = [[0, 1, −a, 0, 0, 0], [0, 0, 0, 0, 1, −a]], S_j = H P_j Hᵀ + R + age_var acc_j
    acc_jᵀ), eq. 5-6 with μ as the prior, unless the χ² d² exceeds ``gate_chi2`` under every
    model (``used`` False: the row is left as it was); then eq. 7-8 into out_x (K, 6),
    out_P (K, 6, 6)."""
    k_n = rows.shape[0]
    m = mu.shape[1]
    PHt = np.empty((m, _D, 2))
    Si = np.empty((m, 3))  # S⁻¹ as (00, 01, 11)
    nu = np.empty((m, 2))
    logw = np.empty(m)
    g0, g1 = np.empty(_D), np.empty(_D)
    for k in range(k_n):
        r = rows[k]
        a = age[k]
        best = np.inf
        finite = True
        for j in range(m):
            for s in range(_D):
                PHt[j, s, 0] = Pm[r, j, s, 1] - a * Pm[r, j, s, 2]
                PHt[j, s, 1] = Pm[r, j, s, 4] - a * Pm[r, j, s, 5]
            ax, ay = xm[r, j, 2], xm[r, j, 5]
            s00 = PHt[j, 1, 0] - a * PHt[j, 2, 0] + R[k, 0, 0] + age_var * ax * ax
            s01 = PHt[j, 1, 1] - a * PHt[j, 2, 1] + R[k, 0, 1] + age_var * ax * ay
            s11 = PHt[j, 4, 1] - a * PHt[j, 5, 1] + R[k, 1, 1] + age_var * ay * ay
            det = s00 * s11 - s01 * s01
            Si[j, 0], Si[j, 1], Si[j, 2] = s11 / det, -s01 / det, s00 / det
            nu[j, 0] = z[k, 0] - (xm[r, j, 1] - a * ax)
            nu[j, 1] = z[k, 1] - (xm[r, j, 4] - a * ay)
            d2 = nu[j, 0] * (Si[j, 0] * nu[j, 0] + Si[j, 1] * nu[j, 1]) + nu[j, 1] * (
                Si[j, 1] * nu[j, 0] + Si[j, 2] * nu[j, 1]
            )
            logw[j] = math.log(max(mu[r, j], 1e-300)) - 0.5 * d2 - 0.5 * math.log(det)  # eq. 5-6
            best = min(best, d2)
            finite = finite and math.isfinite(d2) and det > 0.0
        used[k] = finite and best <= gate_chi2  # a model's NaN state: the track is left as it was
        if used[k]:
            top = logw.max()
            total = 0.0
            for j in range(m):
                logw[j] = math.exp(logw[j] - top)
                total += logw[j]
            for j in range(m):
                mu[r, j] = logw[j] / total
                # gain G = P Hᵀ S⁻¹ (6, 2); x += G ν; P −= G (P Hᵀ)ᵀ
                for s in range(_D):
                    g0[s] = PHt[j, s, 0] * Si[j, 0] + PHt[j, s, 1] * Si[j, 1]
                    g1[s] = PHt[j, s, 0] * Si[j, 1] + PHt[j, s, 1] * Si[j, 2]
                    xm[r, j, s] += g0[s] * nu[j, 0] + g1[s] * nu[j, 1]
                for s in range(_D):
                    for t in range(s, _D):
                        v = Pm[r, j, s, t] - (g0[s] * PHt[j, t, 0] + g1[s] * PHt[j, t, 1])
                        v2 = Pm[r, j, t, s] - (g0[t] * PHt[j, s, 0] + g1[t] * PHt[j, s, 1])
                        Pm[r, j, s, t] = Pm[r, j, t, s] = 0.5 * (v + v2)
        for s in range(_D):  # eq. 7
            acc_s = 0.0
            for j in range(m):
                acc_s += mu[r, j] * xm[r, j, s]
            out_x[k, s] = acc_s
        for s in range(_D):  # eq. 8
            for t in range(s, _D):
                acc_st = 0.0
                for j in range(m):
                    acc_st += mu[r, j] * (Pm[r, j, s, t] + (xm[r, j, s] - out_x[k, s]) * (xm[r, j, t] - out_x[k, t]))
                out_P[k, s, t] = out_P[k, t, s] = acc_st
