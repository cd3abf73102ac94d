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


def _isa_deviation_integral_m(
    pressure_altitude_m: NDArray[np.float64], temperature_deviation_k: ArrayLike
) -> NDArray[np.float64]:
    """∫₀^h ΔT / T_isa(s) ds, m: how much higher than ``h`` (pressure altitude) the level of
    that pressure lies in air ``temperature_deviation_k`` warmer than ISA's at every level.
    Below the tropopause T_isa = T0 + L s gives (ΔT / L) ln(T_isa(h) / T0); above it the
    isothermal layer adds ΔT (h − 11 km) / T11."""
    h = pressure_altitude_m
    temperature_deviation_k = np.asarray(temperature_deviation_k, dtype=float)
    below = (temperature_deviation_k / LAPSE_K_PER_M) * np.log(isa_temperature_k(h) / T0_K)
    return np.asarray(below + temperature_deviation_k * np.maximum(h - TROPOPAUSE_M, 0.0) / T11_K, dtype=float)


def height_of_pressure_altitude_m(
    pressure_altitude_m: ArrayLike, temperature_deviation_k: ArrayLike = 0.0, qnh_hpa: float = P0_PA / 100.0
) -> NDArray[np.float64]:
    """Height above mean sea level of a pressure altitude (a Mode C flight level × 100 ft),
    m, on a day ``temperature_deviation_k`` off ISA at every level with sea-level pressure
    ``qnh_hpa``. The hypsometric equation dz = −R T dp / (g p), with p(h) ISA's (the definition
    of pressure altitude) and T = T_isa(h) + ΔT, gives dz/dh = T / T_isa = 1 + ΔT / T_isa(h);
    sea level lies at the pressure altitude h0 of QNH, so z = h − h0 + ∫_{h0}^{h} ΔT / T_isa.
    Heights are geopotential (the difference from geometric, h²/R_earth, is 19 m at FL360).
    A warm day lifts every level: FL360 lies 219 m higher at ISA+5, 656 m at ISA+15; a QNH
    10 hPa above standard lifts them all by 83 m (QNH is the aerodrome's pressure reduced to
    sea level through ISA: here reduced through the day's air, which puts sea level ΔT·E/T0
    off for an aerodrome at E, 26 m at 500 m and ISA+15, inside the height's 60 m). NaN passes
    through."""
    h = np.asarray(pressure_altitude_m, dtype=float)
    h0 = _pressure_altitude_of_pa(qnh_hpa * 100.0)
    dt = np.asarray(temperature_deviation_k, dtype=float)
    return np.asarray(
        h - h0 + _isa_deviation_integral_m(h, dt) - _isa_deviation_integral_m(np.asarray(h0), dt), dtype=float
    )


def pressure_altitude_of_height_m(
    height_m: ArrayLike, temperature_deviation_k: ArrayLike = 0.0, qnh_hpa: float = P0_PA / 100.0
) -> NDArray[np.float64]:
    """The inverse of :func:`height_of_pressure_altitude_m`: the pressure altitude an aircraft
    at ``height_m`` above mean sea level reports (its Mode C), m. Newton's method on
    dz/dh = 1 + ΔT / T_isa(h); four steps reach 1e-6 m (z is nearly linear in h)."""
    z = np.asarray(height_m, dtype=float)
    dt = np.asarray(temperature_deviation_k, dtype=float)
    h = z.copy()
    for _ in range(4):
        h = h - (height_of_pressure_altitude_m(h, dt, qnh_hpa) - z) / (1.0 + dt / isa_temperature_k(h))
    return np.asarray(h, dtype=float)


def _pressure_altitude_of_pa(pressure_pa: float) -> float:
    """The pressure altitude of a static pressure, m (the inverse of :func:`isa_pressure_pa`
    below the tropopause, where sea-level pressures lie)."""
    return float((T0_K / LAPSE_K_PER_M) * ((pressure_pa / P0_PA) ** (-LAPSE_K_PER_M * R_AIR / G0_MPS2) - 1.0))
