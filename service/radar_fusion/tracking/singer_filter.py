"""Singer-model Kalman filter over N tracks at once (Shu et al. 2007, §3.2 and §4).

State per track, in Shu's order (eq. 12)::

    x = [x, vx, ax, y, vy, ay]      (m, m/s, m/s²)

Each horizontal axis follows Singer's (1970) model: the acceleration is a first-order
Gauss-Markov process with correlation time T_c = 1/α and stationary variance σ_m²,

    d/dt [p, v, a]ᵀ = A [p, v, a]ᵀ + G w,   A = [[0,1,0],[0,0,1],[0,0,-α]],  G = [0,0,1]ᵀ,

with w white noise of spectral density q_c = 2·α·σ_m² (so that E[a²] = σ_m² in steady
state).  The two axes are independent, so Φ and Q are block-diagonal with two equal
3×3 blocks.

Relation to the paper
---------------------
* Φ (eq. 12).  Shu prints row 5 as ``0 0 0 1 T 0``; block-diagonal Singer needs
  ``0 0 0 0 1 T`` (misprint, fixed here).  Shu also prints the simplified acceleration
  column T²/2 and T.  :func:`singer_transition` implements Singer's *exact* transition
  ``Φ = expm(A·T)``, whose acceleration column is
  ``(αT − 1 + e^{−αT})/α²`` and ``(1 − e^{−αT})/α``; these tend to T²/2 and T as αT → 0
  and differ from them by −αT³/6 + O(α²T⁴) and −αT²/2 + O(α²T³) respectively.
  The exact form keeps Φ consistent with Q (both come from the same continuous model).
  :func:`singer_transition_printed` gives the paper's printed form with the row-5
  misprint corrected, for comparison.
* Q(k) (§4).  Shu prints ``Q = σ_m²·[q_ij]``.  The continuous model (Van Loan's method,
  proven in tests/test_singer_filter.py) gives ``Q = 2·α·σ_m²·[q_ij]`` as in Singer
  (1970); the factor 2α is what makes the steady-state acceleration variance σ_m².
  Two of the printed q_ij are also misprinted: Singer's (and Van Loan's) values are
  ``q13 = (1 − e^{−2αT} − 2αT·e^{−αT}) / 2α³`` (Shu prints e^{−αT} for e^{−2αT}) and
  ``q22 = (4e^{−αT} − 3 − e^{−2αT} + 2αT) / 2α³`` (Shu prints −3e^{−2αT} for
  −3 − e^{−2αT}); the printed forms do not even vanish as T → 0.
  The closed forms lose all precision for small αT (q11 is a difference of O(1) terms
  whose sum is (αT)⁵/10), so below αT = 0.5 each q_ij is evaluated from its Taylor
  series in αT instead.
* P0 (§4) is implemented exactly as printed, by
  :func:`radar_fusion.tracking.initiation.two_point_initiation`.
* H (§4) picks x and y: ``H = [[1,0,0,0,0,0],[0,0,0,1,0,0]]``.
* The filter equations are Shu eq. 7–11; the covariance update uses the Joseph form,
  which equals eq. 10 for the optimal gain of eq. 9 and stays symmetric and positive
  semi-definite under round-off.

All functions are vectorised over the leading axis N (numpy batched matmul / einsum,
closed-form 2×2 inverses); none loops over tracks.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from fractions import Fraction
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

__all__ = [
    "POS_IDX",
    "STATE_DIM",
    "AltitudeFilter",
    "H",
    "SingerFilter",
    "singer_matrices_into",
    "singer_process_noise",
    "singer_sigma_m_mps2",
    "singer_transition",
    "singer_transition_printed",
]

STATE_DIM = 6
#: indices of x and y in the state vector [x, vx, ax, y, vy, ay]
POS_IDX = np.array([0, 3])
#: measurement matrix of Shu §4: z = H x picks the two positions
H = np.zeros((2, STATE_DIM))
H[0, 0] = 1.0
H[1, 3] = 1.0

G0_MPS2 = 9.80665


def singer_sigma_m_mps2(a_max_mps2: float, p_max: float, p_0: float) -> float:
    """Singer's (1970) acceleration standard deviation from his manoeuvre model.

    The target accelerates at ±A_max with probability P_max each, not at all with
    probability P_0, and otherwise uniformly in (−A_max, A_max); then
    ``σ_m² = A_max²/3 · (1 + 4·P_max − P_0)``.
    """
    if not (p_max >= 0.0 and p_0 >= 0.0 and 2.0 * p_max + p_0 <= 1.0):
        raise ValueError("need p_max, p_0 >= 0 and 2*p_max + p_0 <= 1")
    return math.sqrt(a_max_mps2**2 / 3.0 * (1.0 + 4.0 * p_max - p_0))


# --- series for the αT → 0 limit ---------------------------------------------------

_SERIES_TERMS = 30
#: below this αT the Taylor series are used; above it the closed forms
_SERIES_SWITCH_AT = 0.5


def _exp_coeffs(k: int, shift: int = 0) -> list[Fraction]:
    """Taylor coefficients c_n (n < _SERIES_TERMS + 6) of x**shift · e^{−k x}."""
    n_max = _SERIES_TERMS + 6
    out = [Fraction(0)] * n_max
    for n in range(shift, n_max):
        m = n - shift
        out[n] = Fraction((-k) ** m, math.factorial(m))
    return out


def _series(numerator: dict[tuple[Any, ...], int | Fraction], power: int) -> np.ndarray:
    """Coefficients of N(x) / (2 x**power) as a power series in x.

    ``numerator`` maps a term to its factor: ("poly", j) is x**j, ("exp", k, s) is
    x**s · e^{−k x}.  The coefficients of x**0 … x**(power−1) of N must vanish (they
    do for every q_ij: that is the cancellation the series avoids).
    """
    n_max = _SERIES_TERMS + 6
    c = [Fraction(0)] * n_max
    for term, factor in numerator.items():
        if term[0] == "poly":
            c[term[1]] += Fraction(factor)
        else:
            ec = _exp_coeffs(term[1], term[2])
            for n in range(n_max):
                c[n] += Fraction(factor) * ec[n]
    assert all(ci == 0 for ci in c[:power]), "numerator does not cancel"
    return np.array([float(ci / 2) for ci in c[power : power + _SERIES_TERMS]])


# q_ij = T**p · g_ij(αT), g_ij(x) = N_ij(x) / (2 x**p)   (Singer 1970; Shu §4 with the
# q13 and q22 misprints fixed).  Keys: (row, col) in the 3×3 per-axis block.
_Q_NUMERATORS: dict[tuple[int, int], tuple[dict[tuple[Any, ...], int | Fraction], int]] = {
    # q11: (1 − e^{−2x} + 2x + 2x³/3 − 2x² − 4x e^{−x}) / 2x⁵
    (0, 0): (
        {
            ("poly", 0): 1,
            ("exp", 2, 0): -1,
            ("poly", 1): 2,
            ("poly", 3): Fraction(2, 3),
            ("poly", 2): -2,
            ("exp", 1, 1): -4,
        },
        5,
    ),
    # q12: (1 + e^{−2x} − 2e^{−x} + 2x e^{−x} − 2x + x²) / 2x⁴
    (0, 1): (
        {("poly", 0): 1, ("exp", 2, 0): 1, ("exp", 1, 0): -2, ("exp", 1, 1): 2, ("poly", 1): -2, ("poly", 2): 1},
        4,
    ),
    # q13: (1 − e^{−2x} − 2x e^{−x}) / 2x³
    (0, 2): ({("poly", 0): 1, ("exp", 2, 0): -1, ("exp", 1, 1): -2}, 3),
    # q22: (4e^{−x} − 3 − e^{−2x} + 2x) / 2x³
    (1, 1): ({("exp", 1, 0): 4, ("poly", 0): -3, ("exp", 2, 0): -1, ("poly", 1): 2}, 3),
    # q23: (1 + e^{−2x} − 2e^{−x}) / 2x²
    (1, 2): ({("poly", 0): 1, ("exp", 2, 0): 1, ("exp", 1, 0): -2}, 2),
    # q33: (1 − e^{−2x}) / 2x
    (2, 2): ({("poly", 0): 1, ("exp", 2, 0): -1}, 1),
}
_Q_SERIES = {ij: _series(num, p) for ij, (num, p) in _Q_NUMERATORS.items()}
_Q_POWER = {ij: p for ij, (_, p) in _Q_NUMERATORS.items()}

# Φ13 = T² h2(αT), h2(x) = (x − 1 + e^{−x})/x² = Σ (−x)ⁿ/(n+2)!
_H2_SERIES = np.array([(-1.0) ** n / math.factorial(n + 2) for n in range(_SERIES_TERMS)])


def _horner(coeffs: np.ndarray, x: np.ndarray) -> np.ndarray:
    out = np.zeros_like(x)
    for c in coeffs[::-1]:
        out = out * x + c
    return out


def _q_closed(ij: tuple[int, int], x: np.ndarray, e1: np.ndarray, e2: np.ndarray) -> np.ndarray:
    """g_ij(x) from the closed form (accurate for x not small), given e1 = e^{−x}, e2 = e^{−2x}."""
    if ij == (0, 0):
        num = 1 - e2 + 2 * x + 2 * x**3 / 3 - 2 * x**2 - 4 * x * e1
    elif ij == (0, 1):
        num = 1 + e2 - 2 * e1 + 2 * x * e1 - 2 * x + x**2
    elif ij == (0, 2):
        num = 1 - e2 - 2 * x * e1
    elif ij == (1, 1):
        num = 4 * e1 - 3 - e2 + 2 * x
    elif ij == (1, 2):
        num = 1 + e2 - 2 * e1
    else:
        num = 1 - e2
    return np.asarray(num / (2 * x ** _Q_POWER[ij]))


_Q_KEYS = tuple(_Q_NUMERATORS)
#: the six series as one (terms, 6) matrix: g(x) for every q_ij = [1, x, x², …] @ this
_Q_SERIES_MATRIX = np.stack([_Q_SERIES[ij] for ij in _Q_KEYS], axis=1)


def _g_all(x: np.ndarray) -> np.ndarray:
    """g_ij(x) for the six q_ij, (N, 6) in the order of ``_Q_KEYS``: the Taylor series
    for x below the switch (one matrix product over powers of x), the closed forms above."""
    out = np.empty((x.size, len(_Q_KEYS)))
    small = x < _SERIES_SWITCH_AT
    if small.all():
        out[:] = (_Q_SERIES_MATRIX.T @ _powers(x)).T
        return out
    if small.any():
        out[small] = (_Q_SERIES_MATRIX.T @ _powers(x[small])).T
    big = ~small
    xb = x[big]
    e1, e2 = np.exp(-xb), np.exp(-2.0 * xb)
    for k, ij in enumerate(_Q_KEYS):
        out[big, k] = _q_closed(ij, xb, e1, e2)
    return out


def _powers(x: np.ndarray) -> np.ndarray:
    """[1, x, x², …, x^(terms−1)] per element, (terms, N)."""
    v = np.empty((_SERIES_TERMS, x.size))
    v[0] = 1.0
    for k in range(1, _SERIES_TERMS):
        np.multiply(v[k - 1], x, out=v[k])
    return v


def as_tracks(*arrays: ArrayLike) -> list[np.ndarray]:
    """Broadcast scalars / (N,) arrays to a common 1-D float shape (N,)."""
    out = np.broadcast_arrays(*[np.atleast_1d(np.asarray(a, dtype=float)) for a in arrays])
    if out[0].ndim != 1:
        raise ValueError("expected scalars or 1-D arrays over tracks")
    return [np.ascontiguousarray(a) for a in out]


def _block_diag2(b: np.ndarray) -> np.ndarray:
    """(N,3,3) per-axis block → (N,6,6) block-diagonal [x-axis, y-axis]."""
    out = np.zeros((b.shape[0], STATE_DIM, STATE_DIM))
    out[:, 0:3, 0:3] = b
    out[:, 3:6, 3:6] = b
    return out


def singer_transition(dt_s: ArrayLike, alpha_per_s: ArrayLike) -> np.ndarray:
    """Exact Singer transition Φ(T, α) = expm(A·T), shape (N,6,6).

    Per axis (Shu eq. 12 with the row-5 misprint fixed and the exact acceleration
    column)::

        [[1, T, (αT − 1 + e^{−αT})/α²],
         [0, 1, (1 − e^{−αT})/α      ],
         [0, 0, e^{−αT}              ]]

    ``dt_s`` (T) and ``alpha_per_s`` (α ≥ 0) are scalars or (N,) arrays.  The α → 0 limit
    is the constant-acceleration transition; small αT uses a Taylor series.
    """
    dt_s, alpha_per_s = as_tracks(dt_s, alpha_per_s)
    if np.any(alpha_per_s < 0):
        raise ValueError("alpha_per_s must be >= 0")
    phi02, phi12, phi22 = _transition_terms(dt_s, alpha_per_s)
    b = np.zeros((dt_s.size, 3, 3))
    b[:, 0, 0] = b[:, 1, 1] = 1.0
    b[:, 0, 1] = dt_s
    b[:, 0, 2] = phi02
    b[:, 1, 2] = phi12
    b[:, 2, 2] = phi22
    return _block_diag2(b)


def _transition_terms(dt_s: np.ndarray, alpha_per_s: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The entries of Φ's per-axis block that depend on α: Φ13 = T² h2(αT),
    Φ23 = T h1(αT), Φ33 = e^{−αT} (1-based, Shu eq. 12 corrected)."""
    x = alpha_per_s * dt_s
    small = x < _SERIES_SWITCH_AT
    x_big = np.where(small, 1.0, x)
    h2 = np.where(small, _horner(_H2_SERIES, x), (x_big - 1.0 + np.exp(-x_big)) / x_big**2)
    # (1 − e^{−x})/x via expm1 is accurate for every x > 0; limit 1 at x = 0
    h1 = np.where(x > 0, -np.expm1(-x) / np.where(x > 0, x, 1.0), 1.0)
    return dt_s**2 * h2, dt_s * h1, np.exp(-x)


def singer_transition_printed(dt_s: ArrayLike, alpha_per_s: ArrayLike) -> np.ndarray:
    """Φ as printed in Shu eq. 12 (acceleration column T²/2, T) with row 5 corrected.

    An approximation of :func:`singer_transition`; kept for comparison only.
    """
    dt_s, alpha_per_s = as_tracks(dt_s, alpha_per_s)
    b = np.zeros((dt_s.size, 3, 3))
    b[:, 0, 0] = b[:, 1, 1] = 1.0
    b[:, 0, 1] = dt_s
    b[:, 0, 2] = dt_s**2 / 2.0
    b[:, 1, 2] = dt_s
    b[:, 2, 2] = np.exp(-alpha_per_s * dt_s)
    return _block_diag2(b)


def singer_process_noise(dt_s: ArrayLike, alpha_per_s: ArrayLike, sigma_m_mps2: ArrayLike) -> np.ndarray:
    """Discrete process noise Q(k) = 2·α·σ_m² · [q_ij(T, α)], shape (N,6,6).

    q_ij are Singer's (1970) (Shu §4, with the q13/q22 misprints fixed, see module
    docstring); the factor 2·α·σ_m² is the white-noise spectral density q_c of the
    continuous model, as proven against Van Loan's method in the tests (the paper's
    σ_m² alone is wrong by the factor 2α).  Small αT (< 0.5) uses the Taylor series
    of each q_ij, so Q is accurate from αT = 0 up: Q → q_c·[[T⁵/20, T⁴/8, T³/6],
    [T⁴/8, T³/3, T²/2], [T³/6, T²/2, T]] as αT → 0.
    """
    dt_s, alpha_per_s, sigma_m_mps2 = as_tracks(dt_s, alpha_per_s, sigma_m_mps2)
    if np.any(alpha_per_s < 0) or np.any(dt_s < 0):
        raise ValueError("alpha_per_s and dt_s must be >= 0")
    q = _process_noise_terms(dt_s, alpha_per_s, sigma_m_mps2)
    b = np.empty((dt_s.size, 3, 3))
    for k, (i, j) in enumerate(_Q_KEYS):  # six matrix elements, not tracks
        b[:, i, j] = b[:, j, i] = q[:, k]
    return _block_diag2(b)


def _process_noise_terms(dt_s: np.ndarray, alpha_per_s: np.ndarray, sigma_m_mps2: np.ndarray) -> np.ndarray:
    """The six distinct entries q_ij of Q's per-axis block, (N, 6) in ``_Q_KEYS`` order."""
    x = alpha_per_s * dt_s
    q_c = 2.0 * alpha_per_s * sigma_m_mps2**2
    powers = np.array([_Q_POWER[ij] for ij in _Q_KEYS])
    return np.asarray((q_c * _g_all(x).T * dt_s ** powers[:, None]).T)


def singer_matrices_into(
    phi: np.ndarray, Q: np.ndarray, dt_s: ArrayLike, alpha_per_s: ArrayLike, sigma_m_mps2: ArrayLike
) -> None:
    """Φ of :func:`singer_transition` (eq. 12, exact) and Q(k) of :func:`singer_process_noise`
    written into ``phi`` and ``Q`` (..., 6, 6), whose entries outside the two per-axis
    blocks are the caller's (zero); ``dt_s``, α and σ_m broadcast to their leading shape.
    The IMM (imm.py) predicts its Singer models as one axis of an (N, M, 6, 6) array."""
    lead = phi.shape[:-2]
    dt, alpha, sigma = (
        np.ascontiguousarray(np.broadcast_to(np.asarray(v, dtype=float), lead)).ravel()
        for v in (dt_s, alpha_per_s, sigma_m_mps2)
    )
    f02, f12, f22 = (f.reshape(lead) for f in _transition_terms(dt, alpha))
    q = _process_noise_terms(dt, alpha, sigma)  # (K, 6)
    t = dt.reshape(lead)
    for o in (0, 3):  # the x and the y block
        phi[..., o, o] = phi[..., o + 1, o + 1] = 1.0
        phi[..., o, o + 1], phi[..., o, o + 2], phi[..., o + 1, o + 2], phi[..., o + 2, o + 2] = t, f02, f12, f22
        for k, (i, j) in enumerate(_Q_KEYS):  # six matrix elements, not tracks
            Q[..., o + i, o + j] = Q[..., o + j, o + i] = q[:, k].reshape(lead)


def inv_2x2(m: np.ndarray) -> np.ndarray:
    """Closed-form inverse of a stack of 2×2 matrices, (N,2,2) → (N,2,2)."""
    a, b, c, d = m[:, 0, 0], m[:, 0, 1], m[:, 1, 0], m[:, 1, 1]
    det = a * d - b * c
    inv = np.empty_like(m)
    inv[:, 0, 0] = d / det
    inv[:, 0, 1] = -b / det
    inv[:, 1, 0] = -c / det
    inv[:, 1, 1] = a / det
    return inv


def _sym(P: np.ndarray) -> np.ndarray:
    return np.asarray(0.5 * (P + np.swapaxes(P, -1, -2)))


# Defaults for civil air traffic (see SingerFilter):
#   A_max = g·tan(25°) ≈ 4.57 m/s², the horizontal acceleration of a coordinated turn
#   at 25° bank (airline turns are flown at 25–30° bank or rate one, whichever is less);
#   P_max = 0.1 (at most one flight in ten is in a maximum-bank turn at a given time),
#   P_0 = 0.5 (half the time the aircraft is in straight, unaccelerated flight).
#   σ_m² = A_max²/3·(1 + 4·0.1 − 0.5) → σ_m ≈ 2.5 m/s².
_DEFAULT_A_MAX_MPS2 = G0_MPS2 * math.tan(math.radians(25.0))
DEFAULT_SIGMA_M_MPS2 = singer_sigma_m_mps2(_DEFAULT_A_MAX_MPS2, p_max=0.1, p_0=0.5)
#   T_c = 30 s: a rate-one (3°/s) turn through 90° lasts 30 s, the typical heading
#   change at a vectoring instruction or a route turn; Singer's "lazy turn" is ~60 s.
DEFAULT_ALPHA_PER_S = 1.0 / 30.0


@dataclass(frozen=True)
class SingerFilter:
    """Singer-model Kalman filter (Shu eq. 7–11) for N tracks at once.

    Parameters
    ----------
    alpha_per_s:
        Manoeuvre bandwidth α = 1/T_c.  Default 1/30 s⁻¹: the ~30 s of a rate-one
        90° turn, inside the 20–60 s range of civil manoeuvres.
    sigma_m_mps2:
        Stationary standard deviation of the target acceleration σ_m.  Default from
        Singer's formula σ_m² = A_max²/3·(1 + 4P_max − P_0) with A_max = g·tan 25°
        ≈ 4.57 m/s² (coordinated turn at 25° bank), P_max = 0.1, P_0 = 0.5, giving
        σ_m ≈ 2.5 m/s².
    """

    alpha_per_s: float = DEFAULT_ALPHA_PER_S
    sigma_m_mps2: float = DEFAULT_SIGMA_M_MPS2

    def __post_init__(self) -> None:
        if not self.alpha_per_s > 0:
            raise ValueError("alpha_per_s must be > 0")
        if not self.sigma_m_mps2 >= 0:
            raise ValueError("sigma_m_mps2 must be >= 0")

    def transition(self, dt_s: ArrayLike) -> np.ndarray:
        """Φ(T, α), (N,6,6)."""
        return singer_transition(dt_s, self.alpha_per_s)

    def process_noise(self, dt_s: ArrayLike) -> np.ndarray:
        """Q(k), (N,6,6)."""
        return singer_process_noise(dt_s, self.alpha_per_s, self.sigma_m_mps2)

    def predict(self, x: ArrayLike, P: ArrayLike, dt_s: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
        """Prediction over dt_s (scalar or (N,)) for x (N,6), P (N,6,6).

        x(k+1|k) = Φ x(k|k)                        (eq. 8)
        P(k+1|k) = Φ P(k|k) Φᵀ + Q(k)              (eq. 11)
        """
        x = np.asarray(x, dtype=float)
        P = np.asarray(P, dtype=float)
        n = x.shape[0]
        dt_s = np.ascontiguousarray(np.broadcast_to(np.asarray(dt_s, dtype=float), (n,)))
        alpha = np.full(n, self.alpha_per_s)
        # Φ = diag(B, B) with the same upper-triangular per-axis block
        # B = [[1, T, f02], [0, 1, f12], [0, 0, f22]] for x and for y (eq. 12): Φ·v and
        # Φ·P·Φᵀ are written out per block row/column instead of 6×6 matrix products.
        f02, f12, f22 = _transition_terms(dt_s, alpha)
        t = dt_s[:, None]
        x_pred = np.empty_like(x)
        pos, vel, acc = x[:, 0::3], x[:, 1::3], x[:, 2::3]  # (N, 2): [x-axis, y-axis]
        x_pred[:, 0::3] = pos + t * vel + f02[:, None] * acc
        x_pred[:, 1::3] = vel + f12[:, None] * acc
        x_pred[:, 2::3] = f22[:, None] * acc
        t, f02, f12, f22 = (a[:, None, None] for a in (dt_s, f02, f12, f22))
        L = np.empty_like(P)  # Φ·P: rows 0,3 / 1,4 / 2,5
        L[:, 0::3] = P[:, 0::3] + t * P[:, 1::3] + f02 * P[:, 2::3]
        L[:, 1::3] = P[:, 1::3] + f12 * P[:, 2::3]
        L[:, 2::3] = f22 * P[:, 2::3]
        P_pred = np.empty_like(P)  # (Φ·P)·Φᵀ: the same on the columns
        P_pred[:, :, 0::3] = L[:, :, 0::3] + t * L[:, :, 1::3] + f02 * L[:, :, 2::3]
        P_pred[:, :, 1::3] = L[:, :, 1::3] + f12 * L[:, :, 2::3]
        P_pred[:, :, 2::3] = f22 * L[:, :, 2::3]
        q = _process_noise_terms(dt_s, alpha, np.full(n, self.sigma_m_mps2))  # eq. 11's Q, per-axis block
        for k, (i, j) in enumerate(_Q_KEYS):
            for axis in (0, 3):
                P_pred[:, axis + i, axis + j] += q[:, k]
                if i != j:
                    P_pred[:, axis + j, axis + i] += q[:, k]
        return x_pred, _sym(P_pred)

    @staticmethod
    def innovation(x_pred: ArrayLike, P_pred: ArrayLike, z: ArrayLike, R: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
        """Innovation ν = z − H x(k+1|k) (N,2) and its covariance S = H P Hᵀ + R (N,2,2)."""
        x_pred = np.asarray(x_pred, dtype=float)
        P_pred = np.asarray(P_pred, dtype=float)
        nu = np.asarray(z, dtype=float) - x_pred[:, POS_IDX]
        S = P_pred[:, POS_IDX[:, None], POS_IDX[None, :]] + np.asarray(R, dtype=float)
        return nu, S

    def update(
        self, x_pred: ArrayLike, P_pred: ArrayLike, z: ArrayLike, R: ArrayLike
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Measurement update with fused measurements z (N,2) of covariance R (N,2,2).

        K = P Hᵀ [H P Hᵀ + R]⁻¹                      (eq. 9)
        x(k+1|k+1) = x(k+1|k) + K [z − H x(k+1|k)]   (eq. 7; H Φ x(k|k) = H x(k+1|k))
        P(k+1|k+1) = (I − K H) P (I − K H)ᵀ + K R Kᵀ (Joseph form of eq. 10; equal to
                                                     (I − K H) P for this optimal K)

        Returns x (N,6), P (N,6,6), innovation ν (N,2), innovation covariance S (N,2,2).
        """
        x_pred = np.asarray(x_pred, dtype=float)
        P_pred = np.asarray(P_pred, dtype=float)
        R = np.asarray(R, dtype=float)
        nu, S = self.innovation(x_pred, P_pred, z, R)
        PHt = P_pred[:, :, POS_IDX]  # P Hᵀ, (N,6,2)
        K = PHt @ inv_2x2(S)  # eq. 9
        x = x_pred + np.einsum("nij,nj->ni", K, nu)  # eq. 7
        I_KH = np.broadcast_to(np.eye(STATE_DIM), P_pred.shape).copy()
        I_KH[:, :, POS_IDX] -= K  # I − K H: H only has ones at columns 0 and 3
        P = I_KH @ P_pred @ np.swapaxes(I_KH, 1, 2) + K @ R @ np.swapaxes(K, 1, 2)
        return x, _sym(P), nu, S

    def mahalanobis_sq(self, x_pred: ArrayLike, P_pred: ArrayLike, z: ArrayLike, R: ArrayLike) -> np.ndarray:
        """Squared Mahalanobis distance νᵀ S⁻¹ ν of z from the prediction, (N,).

        χ²-distributed with 2 degrees of freedom for a correct association; gate with
        e.g. ``scipy.stats.chi2.ppf(0.99, 2)`` ≈ 9.21.
        """
        nu, S = self.innovation(x_pred, P_pred, z, R)
        return np.asarray(np.einsum("ni,nij,nj->n", nu, inv_2x2(S), nu))


# --- altitude ------------------------------------------------------------------------

#: variance of Mode C's 100 ft (1 FL) quantisation error, uniform over ±0.5 FL: 1/12 FL²
MODE_C_QUANT_VAR_FL2 = 1.0 / 12.0


@dataclass(frozen=True)
class AltitudeFilter:
    """Vertical constant-velocity Kalman filter on [FL, FL/s] (FL = 100 ft) for N tracks.

    Continuous white-noise-acceleration model, for T = dt_s::

        Φ = [[1, T], [0, 1]],   Q = q_c · [[T³/3, T²/2], [T²/2, T]],   H = [1, 0]

    Parameters
    ----------
    accel_psd_fl2_ps3:
        q_c, spectral density of the vertical acceleration in FL²/s³.  Default 0.001:
        a climb start or level-off changes the vertical rate by ~0.25 FL/s
        (1,500 ft/min) in ~15 s, so a_max ≈ 0.017 FL/s² (≈ 0.05 g); the usual
        guideline (Bar-Shalom, Li & Kirubarajan 2001, §6.2) makes the velocity change
        over one scan, sqrt(q_c·T), of order a_max·T, i.e. q_c ≈ a_max²·T ≈ 0.0012
        for T = 4 s.  Larger values follow level-offs faster but make the vertical
        rate noisier (Mode C's 100 ft steps dominate the measurement error).
    meas_var_fl2:
        Default Mode C measurement variance: the 100 ft quantisation (1/12 FL²) plus
        ~0.2 FL (20 ft) of altimeter/encoder noise, 1/12 + 0.04 ≈ 0.123 FL²
        (σ ≈ 0.35 FL).  Used where ``update`` gets no per-plot variance.
    rate_var0_fl2_ps2:
        Prior variance of the vertical rate when a track first gets an altitude:
        (0.5 FL/s)², i.e. σ = 3,000 ft/min, covering civil climbs and descents.
    """

    accel_psd_fl2_ps3: float = 0.001
    meas_var_fl2: float = MODE_C_QUANT_VAR_FL2 + 0.2**2
    rate_var0_fl2_ps2: float = 0.5**2

    def initiate(self, fl_measured: ArrayLike, var_fl: ArrayLike | None = None) -> tuple[np.ndarray, np.ndarray]:
        """State from a first altitude: x = [FL, 0], P = diag(var_fl, rate_var0).

        Tracks whose FL is NaN (no Mode C) get NaN states; ``update`` initialises them
        at their first valid FL.
        """
        fl = np.atleast_1d(np.asarray(fl_measured, dtype=float))
        var = self._var(var_fl, fl.shape[0])
        x = np.stack([fl, np.where(np.isnan(fl), np.nan, 0.0)], axis=1)
        P = np.zeros((fl.shape[0], 2, 2))
        P[:, 0, 0] = np.where(np.isnan(fl), np.nan, var)
        P[:, 1, 1] = np.where(np.isnan(fl), np.nan, self.rate_var0_fl2_ps2)
        return x, P

    def _var(self, var_fl: ArrayLike | None, n: int) -> np.ndarray:
        if var_fl is None:
            return np.full(n, self.meas_var_fl2)
        return np.broadcast_to(np.asarray(var_fl, dtype=float), (n,))

    def predict(self, x: ArrayLike, P: ArrayLike, dt_s: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
        """x(k+1|k) = Φ x,  P(k+1|k) = Φ P Φᵀ + Q; dt_s scalar or (N,)."""
        x = np.asarray(x, dtype=float)
        P = np.asarray(P, dtype=float)
        t = np.broadcast_to(np.asarray(dt_s, dtype=float), (x.shape[0],))
        x_pred = np.stack([x[:, 0] + t * x[:, 1], x[:, 1]], axis=1)
        p00, p01, p11 = P[:, 0, 0], P[:, 0, 1], P[:, 1, 1]
        q = self.accel_psd_fl2_ps3
        P_pred = np.empty_like(P)
        P_pred[:, 0, 0] = p00 + 2 * t * p01 + t**2 * p11 + q * t**3 / 3
        P_pred[:, 0, 1] = P_pred[:, 1, 0] = p01 + t * p11 + q * t**2 / 2
        P_pred[:, 1, 1] = p11 + q * t
        return x_pred, P_pred

    def update(
        self, x: ArrayLike, P: ArrayLike, fl_measured: ArrayLike, var_fl: ArrayLike | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """Scalar Kalman update with z = FL; tracks with NaN FL keep the prediction.

        K = P Hᵀ / (H P Hᵀ + r), x += K (z − H x), P = (I − K H) P (I − K H)ᵀ + K r Kᵀ.
        A track whose state is NaN (no altitude yet) and whose FL is valid is
        initialised from it as in :meth:`initiate`.
        """
        x = np.asarray(x, dtype=float)
        P = np.asarray(P, dtype=float)
        z = np.atleast_1d(np.asarray(fl_measured, dtype=float))
        r = self._var(var_fl, z.shape[0])
        have_z = np.isfinite(z)
        fresh = have_z & ~np.isfinite(x[:, 0])
        ok = have_z & ~fresh

        p00, p01, p11 = P[:, 0, 0], 0.5 * (P[:, 0, 1] + P[:, 1, 0]), P[:, 1, 1]
        s = p00 + r
        k = np.stack([p00, p01], axis=1) / np.where(ok, s, 1.0)[:, None]  # (N,2)
        nu = np.where(ok, z - x[:, 0], 0.0)
        x_new = x + k * nu[:, None]
        # Joseph form with A = I − K H = [[1 − k0, 0], [−k1, 1]], written out per entry
        k0, k1 = k[:, 0], k[:, 1]
        P_new = np.empty_like(P)
        P_new[:, 0, 0] = (1.0 - k0) ** 2 * p00 + r * k0 * k0
        P_new[:, 0, 1] = P_new[:, 1, 0] = (1.0 - k0) * (p01 - k1 * p00) + r * k0 * k1
        P_new[:, 1, 1] = k1 * k1 * p00 - 2.0 * k1 * p01 + p11 + r * k1 * k1

        x0, P0 = self.initiate(np.where(fresh, z, np.nan), r)
        x_out = np.where(ok[:, None], x_new, np.where(fresh[:, None], x0, x))
        P_out = np.where(ok[:, None, None], P_new, np.where(fresh[:, None, None], P0, P))
        return x_out, P_out
