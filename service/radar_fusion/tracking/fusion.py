"""Fusion of each cluster's plots into one measurement (Shu et al. 2007, §3.1, eq. 5–6).

After clustering, cluster c holds plots z_i (system-plane x, y in m) with measurement
error covariances R_i from N radars.  Shu assumes isotropic errors,
R_i = σ_w²(i)·I (eq. 4), and fuses by the linear combination

    z_f = Σ_i α_i z_i,          Σ_i α_i = 1                               (eq. 5)
    α_i = 1 / (σ_w²(i) · Σ_j 1/σ_w²(j))                                   (eq. 6)

which is the minimum-variance unbiased combination for isotropic, independent errors.

Two methods are offered:

* ``"scalar"`` — eq. 5–6 exactly.  For a general (non-isotropic) R_i, σ_w²(i) is
  taken as the mean of R_i's eigenvalues, trace(R_i)/2 (equal to σ_w²(i) when R_i is
  isotropic).  The covariance of the fused error is that of the linear combination
  with the full R_i, R_f = Σ_i α_i² R_i, which is exact for independent errors
  whatever the weights.
* ``"matrix"`` — the full-covariance (information-form) generalisation,

      R_f = (Σ_i R_i⁻¹)⁻¹,      z_f = R_f Σ_i R_i⁻¹ z_i,

  the minimum-variance unbiased combination for independent errors with arbitrary
  R_i; it reduces to eq. 5–6 when every R_i is isotropic, and its R_f is never larger
  (in the positive semi-definite order) than the scalar method's.

Plot-to-radar polar errors make R_i elongated along the beam, so "matrix" is the
better estimator for radar data; "scalar" reproduces the paper.

Eq. 5-6 fuse positions of one time. The plots of a period are not: the engine aligns each
to the cluster's time with its track's velocity. A cluster without a velocity (a new
target) has only the prior of any aircraft's, and its plots share that one unknown
velocity: :func:`fuse_common_velocity` estimates position and velocity together from the
plots at their own times and marginalises the velocity out (with the matrix method).

Everything is vectorised with ``np.bincount`` sums over the label array: there is no
Python loop over clusters or plots.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt
from numpy.typing import NDArray

from .association import first_per_group
from .singer_filter import inv_2x2

__all__ = [
    "FUSION_METHODS",
    "consensus_outliers",
    "contradicting_pairs",
    "fuse_clusters",
    "fuse_common_velocity",
    "leave_one_out_outliers",
]

FUSION_METHODS = ("scalar", "matrix")


def _cluster_sum(labels: NDArray[np.intp], values: NDArray[np.float64], n_clusters: int) -> NDArray[np.float64]:
    """Sum ``values`` (M, ...) over plots of each cluster → (K, ...)."""
    flat = values.reshape(values.shape[0], int(np.prod(values.shape[1:])))
    out = np.empty((n_clusters, flat.shape[1]))
    for col in range(flat.shape[1]):  # over matrix elements (≤ 4), not plots or clusters
        out[:, col] = np.bincount(labels, weights=flat[:, col], minlength=n_clusters)
    return out.reshape((n_clusters,) + values.shape[1:])


def fuse_clusters(
    labels: npt.ArrayLike, z_m: npt.ArrayLike, R: npt.ArrayLike, n_clusters: int, method: str = "scalar"
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.intp]]:
    """Fuse the plots of each cluster into one position measurement.

    Parameters
    ----------
    labels : (M,) int
        Cluster of each plot, in [0, n_clusters); -1 excludes the plot.
    z_m : (M,2)
        Plot positions in the system plane, m.
    R : (M,2,2)
        Plot measurement error covariances, m².  Errors of different plots are
        assumed independent.
    n_clusters : int
        K, the number of clusters.
    method : "scalar" | "matrix"
        "scalar": Shu eq. 5–6 with σ_w²(i) = trace(R_i)/2 and R_f = Σ α_i² R_i.
        "matrix": information form R_f = (Σ R_i⁻¹)⁻¹, z_f = R_f Σ R_i⁻¹ z_i.

    Returns
    -------
    z_fused : (K,2) m; R_fused : (K,2,2) m²; n_plots : (K,) int.
    Clusters without plots get NaN in z_fused and R_fused and n_plots 0.
    """
    if method not in FUSION_METHODS:
        raise ValueError(f"method must be one of {FUSION_METHODS}, got {method!r}")
    labels = np.asarray(labels).astype(np.intp, copy=False).reshape(-1)
    z_m = np.asarray(z_m, dtype=float).reshape(-1, 2)
    R = np.asarray(R, dtype=float).reshape(-1, 2, 2)
    if not (labels.shape[0] == z_m.shape[0] == R.shape[0]):
        raise ValueError("labels, z_m and R must have the same number of plots")
    if np.any(labels >= n_clusters) or np.any(labels < -1):
        raise ValueError("labels must be in [0, n_clusters) or -1")

    keep = labels >= 0
    lab, z, R = labels[keep], z_m[keep], R[keep]
    n_plots = np.bincount(lab, minlength=n_clusters)
    empty = n_plots == 0

    with np.errstate(divide="ignore", invalid="ignore"):
        if method == "scalar":
            # σ_w²(i): mean eigenvalue of R_i (= σ_w²(i) for R_i = σ_w²(i) I, eq. 4)
            w = 1.0 / (0.5 * np.trace(R, axis1=1, axis2=2))  # 1/σ_w²(i)
            w_sum = np.bincount(lab, weights=w, minlength=n_clusters)  # Σ_j 1/σ_w²(j)
            alpha = w / w_sum[lab]  # eq. 6
            z_fused = _cluster_sum(lab, alpha[:, None] * z, n_clusters)  # eq. 5
            R_fused = _cluster_sum(lab, alpha[:, None, None] ** 2 * R, n_clusters)
        else:
            R_inv = inv_2x2(R)
            info = _cluster_sum(lab, R_inv, n_clusters)  # Σ R_i⁻¹
            info_z = _cluster_sum(lab, np.einsum("mij,mj->mi", R_inv, z), n_clusters)
            R_fused = inv_2x2(info)
            z_fused = np.einsum("kij,kj->ki", R_fused, info_z)
        R_fused = 0.5 * (R_fused + np.swapaxes(R_fused, 1, 2))

    z_fused[empty] = np.nan
    R_fused[empty] = np.nan
    return z_fused, R_fused, n_plots


def consensus_outliers(
    labels: NDArray[np.intp],
    z_m: NDArray[np.float64],
    R_m2: NDArray[np.float64],
    beyond_gate: NDArray[np.bool_],
    n_clusters: int,
    gate_chi2: float,
) -> NDArray[np.bool_]:
    """Plots that the other radars of their cluster contradict (issue 15 items 2 and 7).

    A plot that joined its track by its Mode S address from outside the χ² gate
    (``beyond_gate``) is either a manoeuvre the prediction did not foresee or a wild plot
    (a run of wild plots from one radar looks consistent to that radar's own gate). The
    other radars tell which: the plots of the cluster inside the gate, all aligned to the
    cluster's time, are fused by inverse variance (Shu eq. 5-6), z_in with covariance
    R_in, and a plot beyond the gate is an outlier when

        (z − z_in)ᵀ (R + R_in)⁻¹ (z − z_in) > gate_chi2,

    i.e. when it disagrees with the radars that agree with the track. In a turn every
    radar sees the aircraft where it is, so plots beyond the gate agree with the in-gate
    ones of the same period and are kept; a cluster with no plot inside the gate keeps
    all its plots. ``labels`` (K,) cluster of each plot, ``z_m`` (K, 2), ``R_m2`` (K, 2, 2).
    Returns (K,) bool.
    """
    out = np.zeros(labels.shape[0], dtype=bool)
    inside = ~beyond_gate
    if not beyond_gate.any() or not inside.any():
        return out
    W = inv_2x2(R_m2[inside])
    info = _cluster_sum(labels[inside], W, n_clusters)
    info_z = _cluster_sum(labels[inside], np.einsum("kij,kj->ki", W, z_m[inside]), n_clusters)
    has = np.bincount(labels[inside], minlength=n_clusters) > 0
    cand = np.flatnonzero(beyond_gate & has[labels])
    if not cand.size:
        return out
    c = labels[cand]
    out[cand] = _d2_against(z_m[cand], R_m2[cand], info[c], info_z[c]) > gate_chi2
    return out


def _d2_against(
    z: NDArray[np.float64], R: NDArray[np.float64], info: NDArray[np.float64], info_z: NDArray[np.float64]
) -> NDArray[np.float64]:
    """d² = (z − z_f)ᵀ (R + R_f)⁻¹ (z − z_f) of plots (z, R) against the fusion of others
    given in information form (Σ R⁻¹, Σ R⁻¹ z): R_f = info⁻¹, z_f = R_f info_z."""
    R_f = inv_2x2(info)
    y = z - np.einsum("kij,kj->ki", R_f, info_z)
    return np.asarray(np.einsum("ki,kij,kj->k", y, inv_2x2(R + R_f), y))


def leave_one_out_outliers(
    labels: NDArray[np.intp],
    z_m: NDArray[np.float64],
    R_m2: NDArray[np.float64],
    check: NDArray[np.bool_],
    n_clusters: int,
    gate_chi2: float,
) -> NDArray[np.bool_]:
    """In each cluster of ``check`` (K clusters) with three plots or more, the plot that
    the others contradict most, when they contradict it beyond the gate (issue 15 item 7).

    A cluster without a track has no prediction to gate its plots: a wild plot (1-3 km
    off, a precise radar's) joins the new target's cluster and pulls its first position,
    and then the two-point velocity. With three plots or more the others tell: each plot
    i against the inverse-variance fusion of the others (Shu eq. 5-6 in information form),

        z₋ᵢ = R₋ᵢ Σ_{j≠i} R_j⁻¹ z_j,   R₋ᵢ = (Σ_{j≠i} R_j⁻¹)⁻¹,
        d²_i = (z_i − z₋ᵢ)ᵀ (R_i + R₋ᵢ)⁻¹ (z_i − z₋ᵢ),

    and the plot of the largest d²_i is an outlier when d²_i > gate_chi2. One plot per
    cluster at most: with one wild plot among three, the two good ones also disagree with
    a fusion that contains it, but less. ``labels`` (P,), ``z_m`` (P, 2), ``R_m2`` (P, 2, 2).
    Returns (P,) bool.
    """
    out = np.zeros(labels.shape[0], dtype=bool)
    n = np.bincount(labels, minlength=n_clusters)
    cand = np.flatnonzero(check[labels] & (n[labels] >= 3))
    if not cand.size:
        return out
    W = inv_2x2(R_m2)
    Wz = np.einsum("pij,pj->pi", W, z_m)
    info = _cluster_sum(labels, W, n_clusters)
    info_z = _cluster_sum(labels, Wz, n_clusters)
    c = labels[cand]
    d2 = _d2_against(z_m[cand], R_m2[cand], info[c] - W[cand], info_z[c] - Wz[cand])  # the others' fusion
    worst = first_per_group(c, -d2)  # each cluster's largest d², one even on a tie
    out[cand[worst[d2[worst] > gate_chi2]]] = True
    return out


def contradicting_pairs(
    labels: NDArray[np.intp],
    z_m: NDArray[np.float64],
    R_m2: NDArray[np.float64],
    key: NDArray[np.int64],
    check: NDArray[np.bool_],
    n_clusters: int,
    gate_chi2: float,
) -> NDArray[np.bool_]:
    """The plots of each cluster of ``check`` that holds exactly two plots, both with one
    ``key`` (a Mode S address), which contradict each other beyond the gate (issue 15 item 7):

        (z_a − z_b)ᵀ (R_a + R_b)⁻¹ (z_a − z_b) > gate_chi2.

    One aircraft's two plots of one period, aligned to one time, differ by their noise
    alone; beyond the gate one of them is wild, and two plots cannot tell which
    (:func:`leave_one_out_outliers` needs three). Fused, both are lost in a position
    between them, half the wild error off. ``labels`` (P,), ``z_m`` (P, 2), ``R_m2``
    (P, 2, 2), ``key`` (P,) with −1 for none: the engine passes the plots' Mode S addresses
    (to leave such pairs out), and 0 for every plot without an address and −1 for the rest
    (to split such pairs).
    Returns (P,) bool: both plots of each such cluster."""
    out = np.zeros(labels.shape[0], dtype=bool)
    n = np.bincount(labels, minlength=n_clusters)
    cand = np.flatnonzero(check[labels] & (n[labels] == 2) & (key >= 0))
    if cand.size < 2:
        return out
    order = cand[np.argsort(labels[cand], kind="stable")]
    first = np.flatnonzero(labels[order][1:] == labels[order][:-1])  # the pairs (a, b) of one cluster
    a, b = order[first], order[first + 1]
    same = key[a] == key[b]
    a, b = a[same], b[same]
    y = z_m[a] - z_m[b]
    d2 = np.einsum("ki,kij,kj->k", y, inv_2x2(R_m2[a] + R_m2[b]), y)
    far = d2 > gate_chi2
    out[a[far]] = out[b[far]] = True
    return out


def fuse_common_velocity(
    labels: npt.ArrayLike,
    z_m: npt.ArrayLike,
    R: npt.ArrayLike,
    dt_s: npt.ArrayLike,
    v0_mps: npt.ArrayLike,
    P_vv: npt.ArrayLike,
    n_clusters: int,
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Fuse plots taken at different times when the target's velocity is barely known.

    Each plot i of cluster c measures z_i = p_c + v_c dt_i + e_i, e_i ~ N(0, R_i), with
    dt_i = t_i − t_c, the position p_c at the cluster's time t_c and one velocity v_c for
    all of the cluster's plots, whose prior is N(v0_c, P_vv,c). Eq. 5-6 applied to plots
    aligned to t_c with that velocity treat its error as independent from plot to plot;
    it is common to them, and at a new target's velocity prior (σ ≈ 200 m/s) the plots'
    time differences of 1-3 s make it the largest error of all. Here (p_c, v_c) are
    estimated jointly, by least squares in information form (the matrix form of eq. 5-6
    on the stacked state):

        J_pp = Σ R_i⁻¹,  J_pv = Σ dt_i R_i⁻¹,  J_vv = Σ dt_i² R_i⁻¹ + P_vv⁻¹,
        b_p = Σ R_i⁻¹ z_i,  b_v = Σ dt_i R_i⁻¹ z_i + P_vv⁻¹ v0,

    and the velocity is marginalised out (Schur complement):

        R_f = (J_pp − J_pv J_vv⁻¹ J_pvᵀ)⁻¹,   z_f = R_f (b_p − J_pv J_vv⁻¹ b_v).

    With every dt_i = 0 this is the matrix fusion of :func:`fuse_clusters`.

    Shapes: labels (M,) in [0, n_clusters); z_m (M,2); R (M,2,2); dt_s (M,);
    v0_mps (K,2); P_vv (K,2,2). Returns z_f (K,2), R_f (K,2,2); NaN for clusters
    without plots.
    """
    lab = np.asarray(labels).astype(np.intp, copy=False).reshape(-1)
    z = np.asarray(z_m, dtype=float).reshape(-1, 2)
    R = np.asarray(R, dtype=float).reshape(-1, 2, 2)
    P_vv = np.asarray(P_vv, dtype=float).reshape(-1, 2, 2)
    dt = np.asarray(dt_s, dtype=float).reshape(-1)[:, None, None]
    v0 = np.asarray(v0_mps, dtype=float).reshape(-1, 2)
    with np.errstate(divide="ignore", invalid="ignore"):
        A = inv_2x2(0.5 * (R + np.swapaxes(R, 1, 2)))
        Pvv_inv = inv_2x2(0.5 * (P_vv + np.swapaxes(P_vv, 1, 2)))
    Az = np.einsum("mij,mj->mi", A, z)
    J_pp = _cluster_sum(lab, A, n_clusters)
    J_pv = _cluster_sum(lab, dt * A, n_clusters)
    J_vv = _cluster_sum(lab, dt**2 * A, n_clusters) + Pvv_inv
    b_p = _cluster_sum(lab, Az, n_clusters)
    b_v = _cluster_sum(lab, dt[:, :, 0] * Az, n_clusters) + np.einsum("kij,kj->ki", Pvv_inv, v0)
    K = np.einsum("kij,kjl->kil", J_pv, inv_2x2(J_vv))  # J_pv J_vv⁻¹
    with np.errstate(divide="ignore", invalid="ignore"):
        R_f = inv_2x2(J_pp - np.einsum("kij,klj->kil", K, J_pv))
        z_f = np.einsum("kij,kj->ki", R_f, b_p - np.einsum("kij,kj->ki", K, b_v))
    R_f = 0.5 * (R_f + np.swapaxes(R_f, 1, 2))
    empty = np.bincount(lab, minlength=n_clusters) == 0
    z_f[empty] = np.nan
    R_f[empty] = np.nan
    return z_f, R_f
