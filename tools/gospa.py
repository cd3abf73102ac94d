"""Optimal partial assignment with a cut-off, and the GOSPA metric built on it.

GOSPA: García-Fernández, Rahmathullah, Svensson 2017, α = 2 (definition in the
:mod:`radar_fusion.tools.evaluate` docstring). The assignment is also the evaluation's
association of tracks with truth targets (GOSPA's assignment with c = gate, p = 2).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import linear_sum_assignment
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree


def cutoff_assignment(
    truth_xy: np.ndarray, track_xy: np.ndarray, cutoff_m: float, p: float = 2.0
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Optimal partial assignment minimising Σ min(d, c)^p, keeping pairs with d < c.

    Returns (truth index, track index, distance in m) of the kept pairs. Pairs with
    d ≥ c cost as much as leaving both unassigned, so the problem splits into the
    connected components of the bipartite graph "d < c"; one-to-one components are
    taken directly, larger ones solved with ``linear_sum_assignment``.
    """
    truth_xy = np.asarray(truth_xy, float).reshape(-1, 2)
    track_xy = np.asarray(track_xy, float).reshape(-1, 2)
    m, n = truth_xy.shape[0], track_xy.shape[0]
    empty = (np.zeros(0, np.intp), np.zeros(0, np.intp), np.zeros(0))
    if m == 0 or n == 0:
        return empty
    pairs = cKDTree(truth_xy).sparse_distance_matrix(cKDTree(track_xy), cutoff_m, output_type="ndarray")
    ei, ej, ed = pairs["i"].astype(np.intp), pairs["j"].astype(np.intp), pairs["v"]
    keep = ed < cutoff_m
    ei, ej, ed = ei[keep], ej[keep], ed[keep]
    if ei.shape[0] == 0:
        return empty
    graph = coo_matrix((np.ones(ei.shape[0]), (ei, m + ej)), shape=(m + n, m + n))
    _, label = connected_components(graph, directed=False)
    comp = label[ei]  # component of each edge
    n_comp = label.max() + 1
    truth_in = np.bincount(label[:m], minlength=n_comp)
    track_in = np.bincount(label[m:], minlength=n_comp)
    simple = (truth_in[comp] == 1) & (track_in[comp] == 1)
    out_i, out_j, out_d = [ei[simple]], [ej[simple]], [ed[simple]]
    hard = ~simple
    if hard.any():
        hi, hj, hd, hc = ei[hard], ej[hard], ed[hard], comp[hard]
        order = np.argsort(hc, kind="stable")
        hi, hj, hd, hc = hi[order], hj[order], hd[order], hc[order]
        bounds = np.flatnonzero(np.diff(hc)) + 1
        for ci, cj, cd in zip(np.split(hi, bounds), np.split(hj, bounds), np.split(hd, bounds)):
            ui, ri = np.unique(ci, return_inverse=True)
            uj, rj = np.unique(cj, return_inverse=True)
            cost = np.full((ui.shape[0], uj.shape[0]), float(cutoff_m) ** p)
            dist = np.full(cost.shape, np.inf)
            cost[ri, rj] = cd**p
            dist[ri, rj] = cd
            r, c = linear_sum_assignment(cost)
            ok = dist[r, c] < cutoff_m
            out_i.append(ui[r[ok]])
            out_j.append(uj[c[ok]])
            out_d.append(dist[r[ok], c[ok]])
    return np.concatenate(out_i), np.concatenate(out_j), np.concatenate(out_d)


@dataclass(frozen=True)
class Gospa:
    """One GOSPA evaluation (α = 2). Parts are in m^p; ``distance_m`` = (sum of parts)^(1/p)."""

    distance_m: float
    localisation: float
    missed: float
    false: float
    n_assigned: int
    n_missed: int
    n_false: int


def gospa(truth_xy: np.ndarray, track_xy: np.ndarray, c_m: float = 2000.0, p: float = 2.0) -> Gospa:
    """GOSPA metric with α = 2 between truth points and track points (see module docstring)."""
    truth_xy = np.asarray(truth_xy, float).reshape(-1, 2)
    track_xy = np.asarray(track_xy, float).reshape(-1, 2)
    m, n = truth_xy.shape[0], track_xy.shape[0]
    _, _, d = cutoff_assignment(truth_xy, track_xy, c_m, p)
    k = d.shape[0]
    loc = float(np.sum(d**p))
    missed = c_m**p / 2.0 * (m - k)
    false = c_m**p / 2.0 * (n - k)
    return Gospa((loc + missed + false) ** (1.0 / p), loc, missed, false, k, m - k, n - k)
