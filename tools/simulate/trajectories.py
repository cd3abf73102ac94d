"""Truth kinematics of every target, exact at any time: synthetic flight plans as closed
forms (a circular arc per turn) and recorded paths (ADS-B) as C2 cubic splines.

How each is built is in the :mod:`radar_fusion.tools.simulate` docstring ("Targets").
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.interpolate import CubicSpline

from radar_fusion.geo.coordinates import SystemPlane
from radar_fusion.geo.units import M_PER_FT, MPS_PER_FPM

from .scenario import FlightPlan, SampledPath, Target


@dataclass
class KinematicState:
    """Truth state of targets at query times (all arrays of the query's shape)."""

    x_m: np.ndarray
    y_m: np.ndarray
    alt_m: np.ndarray
    vx_mps: np.ndarray
    vy_mps: np.ndarray
    vz_mps: np.ndarray
    active: np.ndarray


def _arc_displacement(v: np.ndarray, psi: np.ndarray, omega: np.ndarray, tau: np.ndarray):
    """Displacement (dx east, dy north) after tau s at speed v from heading psi (rad),
    turning at omega rad/s: exact circular arc, stable at omega -> 0.

    x(tau) = v (cos psi - cos(psi + omega tau)) / omega = v tau sin(psi + omega tau / 2) sinc,
    y(tau) = v (sin(psi + omega tau) - sin psi) / omega = v tau cos(psi + omega tau / 2) sinc,
    sinc = sin(omega tau / 2) / (omega tau / 2).
    """
    half = 0.5 * omega * tau
    s = np.sinc(half / np.pi)
    mid = psi + half
    return v * tau * np.sin(mid) * s, v * tau * np.cos(mid) * s


def _hermite(s, h, p0, p1, m0, m1):
    """Cubic Hermite value and derivative at normalised s in [0, 1], interval length h."""
    s2, s3 = s * s, s * s * s
    val = (2 * s3 - 3 * s2 + 1) * p0 + (s3 - 2 * s2 + s) * h * m0 + (-2 * s3 + 3 * s2) * p1 + (s3 - s2) * h * m1
    der = (
        (6 * s2 - 6 * s) * p0 + (3 * s2 - 4 * s + 1) * h * m0 + (-6 * s2 + 6 * s) * p1 + (3 * s2 - 2 * s) * h * m1
    ) / h
    return val, der


class Trajectories:
    """Vectorised truth kinematics of all targets of a scenario, exact at any time.

    :meth:`state` takes arrays of target indices and times (any mix) and returns the
    plane position, altitude and velocities; outside a target's life the state is
    extrapolated (constant velocity) and ``active`` is False.
    """

    def __init__(self, targets: Sequence[Target], plane: SystemPlane, start_t_s: float) -> None:
        n = len(targets)
        self.n = n
        self.t_begin_s = np.empty(n)
        self.t_end_s = np.empty(n)
        self._synthetic = np.array([t.plan is not None for t in targets], bool)
        self._local = np.empty(n, np.intp)
        syn = [i for i in range(n) if self._synthetic[i]]
        smp = [i for i in range(n) if not self._synthetic[i]]
        self._local[syn] = np.arange(len(syn))
        self._local[smp] = np.arange(len(smp))
        self._build_segments([pl for i in syn if (pl := targets[i].plan) is not None], start_t_s)
        if syn:
            self.t_begin_s[syn] = self._seg_t0[:, 0]
            self.t_end_s[syn] = self._syn_t_end
        # a target without a plan has a path (Target checks it)
        self._build_knots([pa for i in smp if (pa := targets[i].path) is not None], plane)
        if smp:
            self.t_begin_s[smp] = self._k_t[self._k_off[:-1]]
            self.t_end_s[smp] = self._k_t[self._k_off[1:] - 1]

    # ----------------------------------------------------------------- synthetic plans
    def _build_segments(self, plans: list[FlightPlan], start_t_s: float) -> None:
        m = len(plans)
        n_seg = max([len(p.legs) for p in plans] + [1])
        shape = (m, n_seg)
        self._seg_t0 = np.full(shape, np.inf)
        self._seg_x0, self._seg_y0, self._seg_psi0 = np.zeros(shape), np.zeros(shape), np.zeros(shape)
        self._seg_omega, self._seg_v, self._seg_h0, self._seg_vz = (np.zeros(shape) for _ in range(4))
        self._syn_t_end = np.empty(m)
        if m == 0:
            return
        # Legs are chained for all plans at once, leg by leg (plans without leg j keep
        # their end state).
        n_legs = np.array([len(p.legs) for p in plans])
        dur = np.zeros(shape)
        omega = np.zeros(shape)
        vz = np.zeros(shape)
        for i, p in enumerate(plans):
            if not p.legs:
                raise ValueError("a flight plan needs at least one leg")
            dur[i, : len(p.legs)] = [leg.duration_s for leg in p.legs]
            omega[i, : len(p.legs)] = [math.radians(leg.turn_rate_dps) for leg in p.legs]
            vz[i, : len(p.legs)] = [leg.vrate_fpm * MPS_PER_FPM for leg in p.legs]
        t = start_t_s + np.array([p.t_offset_s for p in plans], float)
        x = np.array([p.start_x_m for p in plans], float)
        y = np.array([p.start_y_m for p in plans], float)
        psi = np.radians([p.heading_deg for p in plans])
        v = np.array([p.speed_mps for p in plans], float)
        h = np.array([p.alt_ft for p in plans], float) * M_PER_FT
        for j in range(n_seg):
            has = j < n_legs
            self._seg_t0[has, j] = t[has]
            self._seg_x0[:, j], self._seg_y0[:, j], self._seg_psi0[:, j] = x, y, psi
            self._seg_omega[:, j], self._seg_v[:, j], self._seg_h0[:, j], self._seg_vz[:, j] = (
                omega[:, j],
                v,
                h,
                vz[:, j],
            )
            dx, dy = _arc_displacement(v, psi, omega[:, j], dur[:, j])
            x, y = x + dx, y + dy
            psi = psi + omega[:, j] * dur[:, j]
            h = h + vz[:, j] * dur[:, j]
            t = t + dur[:, j]
        self._syn_t_end = t

    def _state_synthetic(self, rows: np.ndarray, t: np.ndarray):
        k = (t[:, None] >= self._seg_t0[rows]).sum(axis=1) - 1
        k = np.maximum(k, 0)
        tau = t - self._seg_t0[rows, k]
        v, psi0, om = self._seg_v[rows, k], self._seg_psi0[rows, k], self._seg_omega[rows, k]
        dx, dy = _arc_displacement(v, psi0, om, tau)
        psi = psi0 + om * tau
        vz = self._seg_vz[rows, k]
        return (
            self._seg_x0[rows, k] + dx,
            self._seg_y0[rows, k] + dy,
            self._seg_h0[rows, k] + vz * tau,
            v * np.sin(psi),
            v * np.cos(psi),
            vz,
        )

    # ----------------------------------------------------------------- sampled paths
    def _build_knots(self, paths: list[SampledPath], plane: SystemPlane) -> None:
        m = len(paths)
        sizes = np.array([len(p.t_s) for p in paths], np.intp)
        if np.any(sizes < 2):
            raise ValueError("a sampled path needs at least two samples")
        self._k_off = np.concatenate([[0], np.cumsum(sizes)]).astype(np.intp)
        if m == 0:
            self._k_t = np.zeros(0)
            return
        cat = lambda name: np.concatenate([np.asarray(getattr(p, name), float) for p in paths])
        t, lat, lon = cat("t_s"), cat("lat_deg"), cat("lon_deg")
        x, y = plane.to_plane(lat, lon)
        # Knot velocities: those of the C2 cubic spline through the positions (the
        # smoothest interpolant; the reported groundspeed/track disagree with the
        # positions' spacing by up to ~15 % in real ADS-B, and forcing them as slopes
        # would create large spurious accelerations between the samples).
        vx, vy = np.empty_like(x), np.empty_like(y)
        for a, b in zip(self._k_off[:-1], self._k_off[1:]):
            bc = "not-a-knot" if b - a >= 4 else "natural"
            spline = CubicSpline(t[a:b], np.column_stack([x[a:b], y[a:b]]), bc_type=bc)
            v = spline(t[a:b], 1)
            vx[a:b], vy[a:b] = v[:, 0], v[:, 1]
        # Altitude: the reported vertical rates as slopes, unless they disagree with the
        # altitude samples by more than 1,000 ft/min (then the centred chord rate).
        row = np.repeat(np.arange(m), sizes)
        lo, hi = self._k_off[row], self._k_off[row + 1] - 1
        i = np.arange(t.shape[0])
        ia, ib = np.maximum(i - 1, lo), np.minimum(i + 1, hi)
        z = cat("alt_ft") * M_PER_FT
        vz = cat("vrate_fpm") * MPS_PER_FPM
        chord = (z[ib] - z[ia]) / (t[ib] - t[ia])
        vz = np.where(np.abs(vz - chord) > 1000.0 * MPS_PER_FPM, chord, vz)
        self._k_t, self._k_x, self._k_y = t, x, y
        self._k_vx, self._k_vy = vx, vy
        self._k_z, self._k_vz = z, vz
        self._k_tmin = float(t.min())
        self._k_span = float(t.max() - t.min()) + 10.0
        self._k_key = row * self._k_span + (t - self._k_tmin)

    def _state_sampled(self, rows: np.ndarray, t: np.ndarray):
        lo, hi = self._k_off[rows], self._k_off[rows + 1]
        tc = np.clip(t, self._k_t[lo], self._k_t[hi - 1])
        j = np.searchsorted(self._k_key, rows * self._k_span + (tc - self._k_tmin), side="right") - 1
        j = np.clip(j, lo, hi - 2)
        h = self._k_t[j + 1] - self._k_t[j]
        s = (tc - self._k_t[j]) / h
        x, vx = _hermite(s, h, self._k_x[j], self._k_x[j + 1], self._k_vx[j], self._k_vx[j + 1])
        y, vy = _hermite(s, h, self._k_y[j], self._k_y[j + 1], self._k_vy[j], self._k_vy[j + 1])
        z, vz = _hermite(s, h, self._k_z[j], self._k_z[j + 1], self._k_vz[j], self._k_vz[j + 1])
        extra = t - tc  # constant-velocity extrapolation outside the samples
        return x + vx * extra, y + vy * extra, z + vz * extra, vx, vy, vz

    # ----------------------------------------------------------------- public
    def state(self, index: Any, t_s: Any) -> KinematicState:
        """Truth state of targets ``index`` at times ``t_s`` (broadcast, flattened)."""
        idx, t = np.broadcast_arrays(np.asarray(index, np.intp), np.asarray(t_s, float))
        idx, t = idx.reshape(-1), t.reshape(-1)
        out = [np.empty(t.shape[0]) for _ in range(6)]
        syn = self._synthetic[idx]
        for mask, fn in ((syn, self._state_synthetic), (~syn, self._state_sampled)):
            if np.any(mask):
                vals = fn(self._local[idx[mask]], t[mask])
                for o, v in zip(out, vals):
                    o[mask] = v
        active = (t >= self.t_begin_s[idx]) & (t <= self.t_end_s[idx])
        x, y, z, vx, vy, vz = out
        return KinematicState(x, y, z, vx, vy, vz, active=active)
