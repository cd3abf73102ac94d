"""Air data: the ICAO standard atmosphere and the airspeeds a Mode S aircraft reports.

BDS 6,0 (ICAO Doc 9871 table A-2-96) carries the aircraft's magnetic heading and its
indicated airspeed; with the true airspeed they give the air vector, which is the ground
velocity less the wind. The radar reads the register on almost every Mode S plot (90 % of
the Barcelona hour's), BDS 5,0's ground velocity on a quarter of them
(engine.Engine._air_velocity).

ISA below 20 km (ICAO Doc 7488): T = T0 + L h up to the tropopause at 11 km, then 216.65 K;
p = p0 (T/T0)^(−g/(L R)) below it, p11 exp(−g (h − 11 km)/(R T11)) above. ``h`` is the
pressure altitude (the flight level × 100 ft), which fixes p whatever the day's
temperature; the temperature is ISA's plus ``temperature_deviation_k``.

Indicated airspeed is taken as calibrated (an aircraft's air-data computer corrects the
position error before it fills the register). The calibrated airspeed defines the impact
pressure at sea level (Saint-Venant, subsonic):

    q_c = p0 ((1 + (γ−1)/2 (V_c/a0)²)^(γ/(γ−1)) − 1)

and at the aircraft's static pressure p the same q_c gives its Mach number

    M = sqrt(2/(γ−1) ((q_c/p + 1)^((γ−1)/γ) − 1)),      V_true = M sqrt(γ R T).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

GAMMA = 1.4
#: specific gas constant of dry air, J/(kg K)
R_AIR = 287.05287
G0_MPS2 = 9.80665
T0_K = 288.15
P0_PA = 101_325.0
LAPSE_K_PER_M = -0.0065
TROPOPAUSE_M = 11_000.0
T11_K = T0_K + LAPSE_K_PER_M * TROPOPAUSE_M
P11_PA = P0_PA * (T11_K / T0_K) ** (-G0_MPS2 / (LAPSE_K_PER_M * R_AIR))
#: speed of sound at sea level in ISA, m/s
A0_MPS = float(np.sqrt(GAMMA * R_AIR * T0_K))


def isa_temperature_k(pressure_altitude_m: ArrayLike) -> NDArray[np.float64]:
    """ISA temperature at a pressure altitude, K."""
    h = np.asarray(pressure_altitude_m, dtype=float)
    return np.asarray(np.where(h < TROPOPAUSE_M, T0_K + LAPSE_K_PER_M * h, T11_K), dtype=float)


def isa_pressure_pa(pressure_altitude_m: ArrayLike) -> NDArray[np.float64]:
    """Static pressure at a pressure altitude, Pa (the definition of pressure altitude)."""
    h = np.asarray(pressure_altitude_m, dtype=float)
    below = P0_PA * (np.maximum(T0_K + LAPSE_K_PER_M * np.minimum(h, TROPOPAUSE_M), 1.0) / T0_K) ** (
        -G0_MPS2 / (LAPSE_K_PER_M * R_AIR)
    )
    above = P11_PA * np.exp(-G0_MPS2 * (h - TROPOPAUSE_M) / (R_AIR * T11_K))
    return np.asarray(np.where(h < TROPOPAUSE_M, below, above), dtype=float)


def true_airspeed_mps(
    ias_mps: ArrayLike, pressure_altitude_m: ArrayLike, temperature_deviation_k: ArrayLike = 0.0
) -> NDArray[np.float64]:
    """True airspeed from an indicated (calibrated) airspeed at a pressure altitude, m/s
    (module docstring: Saint-Venant's impact pressure, then the Mach number at p)."""
    vc = np.asarray(ias_mps, dtype=float)
    k = (GAMMA - 1.0) / 2.0
    qc = P0_PA * ((1.0 + k * (vc / A0_MPS) ** 2) ** (GAMMA / (GAMMA - 1.0)) - 1.0)
    p = isa_pressure_pa(pressure_altitude_m)
    mach = np.sqrt(((qc / p + 1.0) ** ((GAMMA - 1.0) / GAMMA) - 1.0) / k)
    t_k = isa_temperature_k(pressure_altitude_m) + np.asarray(temperature_deviation_k, dtype=float)
    return np.asarray(mach * np.sqrt(GAMMA * R_AIR * t_k))


def indicated_airspeed_mps(
    tas_mps: ArrayLike, pressure_altitude_m: ArrayLike, temperature_deviation_k: ArrayLike = 0.0
) -> NDArray[np.float64]:
    """The inverse of :func:`true_airspeed_mps`: the calibrated airspeed of a true airspeed."""
    t_k = isa_temperature_k(pressure_altitude_m) + np.asarray(temperature_deviation_k, dtype=float)
    mach = np.asarray(tas_mps, dtype=float) / np.sqrt(GAMMA * R_AIR * t_k)
    k = (GAMMA - 1.0) / 2.0
    qc = isa_pressure_pa(pressure_altitude_m) * ((1.0 + k * mach**2) ** (GAMMA / (GAMMA - 1.0)) - 1.0)
    return np.asarray(A0_MPS * np.sqrt(((qc / P0_PA + 1.0) ** ((GAMMA - 1.0) / GAMMA) - 1.0) / k))
