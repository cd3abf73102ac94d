"""Manoeuvre detection: adaptive process noise for the Singer filter (not in Shu 2007).

A Singer filter tuned for the quiet flight that dominates en-route traffic (σ_m ≈ 2.5
m/s², singer_filter.py) lags a rate-one turn at jet speed (≈ 10 m/s²). The standard
remedy (Bar-Shalom, Li & Kirubarajan 2001, §11.2, "noise level adjustment") watches the
normalised innovation squared

    ε = νᵀ S⁻¹ ν                                   (ν, S of Shu eq. 7 and 9)

which is χ² with 2 degrees of freedom (mean 2) while the model holds. Its fading average

    ε̄ ← λ·ε̄ + (1 − λ)·ε

rising above ``nis_on`` marks a manoeuvre; the track is then predicted with σ_m
multiplied by ``sigma_factor`` until ε̄ falls below ``nis_off`` (hysteresis, so a track
does not flicker between the two models). Q of the Singer model grows with σ_m² (Shu §4),
so adding (k² − 1)·Q to the predicted covariance is exactly the prediction of a Singer
model whose σ_m is k times larger.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from .singer_filter import SingerFilter, inv_2x2

__all__ = ["ManoeuvreDetector", "normalised_innovation_sq"]

Float = NDArray[np.float64]
Bool = NDArray[np.bool_]


def normalised_innovation_sq(nu: Float, S: Float) -> Float:
    """ε = νᵀ S⁻¹ ν per track, for ν (N,2) and S (N,2,2)."""
    return np.asarray(np.einsum("ni,nij,nj->n", nu, inv_2x2(S), nu))


@dataclass(frozen=True)
class ManoeuvreDetector:
    """The rule above; its tunables are documented in ``config.TrackingConfig``."""

    sigma_factor: float
    nis_on: float
    nis_off: float
    nis_fading: float

    def detect(self, nis_avg: Float, manoeuvre: Bool, nu: Float, S: Float) -> tuple[Float, Bool]:
        """New (fading NIS average, manoeuvre flag) of tracks just updated with ν, S."""
        avg = self.nis_fading * nis_avg + (1.0 - self.nis_fading) * normalised_innovation_sq(nu, S)
        return avg, np.where(manoeuvre, avg > self.nis_off, avg > self.nis_on)

    def predict(self, singer: SingerFilter, x: Float, P: Float, dt_s: Float, manoeuvre: Bool) -> tuple[Float, Float]:
        """Singer prediction (Shu eq. 8, 11) over per-track ``dt_s``, with σ_m raised by
        ``sigma_factor`` for the manoeuvring tracks."""
        x, P = singer.predict(x, P, dt_s)
        if manoeuvre.any():
            q = singer.process_noise(np.broadcast_to(dt_s, manoeuvre.shape)[manoeuvre])
            P[manoeuvre] += (self.sigma_factor**2 - 1.0) * q
        return x, P
