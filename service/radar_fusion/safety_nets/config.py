"""The ``[safety_nets]`` configuration section: one documented default per tunable.

The settings are read by :class:`radar_fusion.config.Settings` (the daemon's file) and
by :class:`~radar_fusion.safety_nets.SafetyNets`; the references ([STCA-SPEC],
[APW-GUID], [MSAW-GUID]) are listed in the package docstring.
"""

from __future__ import annotations

from pathlib import Path
from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

FT_PER_HPA = 27.0
"""Pressure-altitude change per hPa near mean sea level, ICAO standard atmosphere (≈ 8.2 m)."""
STANDARD_PRESSURE_HPA = 1013.25
"""Pressure of the ICAO standard atmosphere at mean sea level, hPa: flight levels refer to it."""


class StcaAreaOverride(BaseModel):
    """STCA minima for one airspace volume (e.g. 3 NM in a TMA) [STCA-SPEC]."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)
    name: str
    polygon_latlon_deg: list[tuple[float, float]] = Field(
        min_length=3, description="the volume's lateral boundary, [lat, lon] vertices in degrees"
    )
    lower_fl: float = Field(-20.0, description="lower limit (flight level), inclusive")
    upper_fl: float = Field(1300.0, description="upper limit (flight level), inclusive")
    h_min_nm: float = Field(gt=0, le=20, description="horizontal minimum inside the volume")
    v_min_ft: float = Field(1000.0, gt=0, le=5000, description="vertical minimum inside the volume")


class SafetyNetsConfig(BaseModel):
    """The ``[safety_nets]`` section of the daemon configuration (all fields defaulted)."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    # common
    look_ahead_s: float = Field(120.0, gt=0, le=600, description="prediction horizon (STCA; APW/MSAW default)")
    prediction_step_s: float = Field(5.0, gt=0, le=30, description="STCA knot spacing of predicted paths")
    sample_step_s: float = Field(2.0, gt=0, le=30, description="APW/MSAW sampling step along predicted paths")
    clear_periods: int = Field(2, ge=1, description="periods without a hit before an alert ends")
    level_vrate_fpm: float = Field(
        400.0, ge=0, description="|vertical rate| below this counts as level flight (tracker noise)"
    )
    level_off_anticipation: bool = Field(True, description="predict level-off from the vertical deceleration")
    capture_min_fpm_per_s: float = Field(
        40.0, gt=0, description="vertical deceleration that signals a level capture (fpm per second)"
    )
    turn_min_dps: float = Field(1.0, gt=0, description="turn rate above which turn prediction is used, deg/s")
    turn_max_dps: float = Field(6.0, gt=0, description="turn rates are capped at this, deg/s")
    turn_max_heading_change_deg: float = Field(
        90.0, gt=0, le=360, description="a predicted turn stops after this heading change"
    )
    process: Literal["child", "in_process", "external"] = Field(
        "child",
        description="how `radar-fusion serve` runs the safety nets. child (default): as its own process, "
        "`radar-fusion safety-nets`, started, restarted and stopped by serve; a fault or a slow period in the "
        "safety nets never holds up the tracks, and they no longer cost serve's processing thread (issue 16). "
        "in_process: on serve's processing thread, one process as before issue 16 (alerts a little sooner, "
        "tracks later by the nets' time). external: serve runs none; a `radar-fusion safety-nets` elsewhere "
        "(another host) must. `serve --safety-nets` overrides it",
    )
    connect: list[str] = Field(
        default_factory=list,
        description="Zenoh endpoints the safety-nets process joins. Default: [bus] connect when the daemon "
        "is a client, else its [bus] listen endpoints. On a TLS bus name the host in the daemon's certificate "
        "(tls/fusion.site-a.example:7447): a listen address such as 0.0.0.0 fails the name check",
    )
    zenoh_config_file: str | None = Field(
        None,
        description="Zenoh JSON5 file of the safety-nets process (TLS client with its own certificate, e.g. "
        "deploy/zenoh/safety-nets.json5). Default: [bus] zenoh_config_file, which will not do when the daemon "
        "embeds the router with access control: the router's file would apply its rules to the child's session",
    )
    load_entry_point_hooks: bool = Field(True, description="discover alert hooks from Python entry points")

    # STCA
    stca_enabled: bool = True
    stca_h_min_nm: float = Field(5.0, gt=0, le=20, description="horizontal separation minimum")
    stca_v_min_ft: float = Field(1000.0, gt=0, le=5000, description="vertical separation minimum")
    stca_v_tolerance_ft: float = Field(
        100.0, ge=0, le=500, description="subtracted from vertical minima for altitude quantisation"
    )
    stca_overrides: list[StcaAreaOverride] = Field(
        default_factory=list, description="per-volume minima; a pair uses the first volume that holds both tracks"
    )
    stca_proximity_h_nm: float | None = Field(
        None, gt=0, description="current proximity filter, horizontal (default: the pair's minimum)"
    )
    stca_proximity_v_ft: float | None = Field(
        None, gt=0, description="current proximity filter, vertical (default: the pair's minimum less tolerance)"
    )
    stca_confirm_periods: int = Field(2, ge=1, description="consecutive predicted-conflict periods before alerting")
    stca_far_s: float = Field(
        60.0, ge=0, description="a predicted violation further ahead than this needs stca_confirm_periods_far"
    )
    stca_confirm_periods_far: int = Field(
        4, ge=1, description="consecutive periods to confirm a conflict predicted beyond stca_far_s"
    )
    stca_unknown_fl: Literal["ignore", "conflict"] = Field(
        "ignore", description="tracks without a flight level: not eligible, or vertically in conflict with all"
    )

    # APW
    apw_enabled: bool = True
    areas_file: Path | None = Field(None, description="GeoJSON of APW volumes (properties id, lower_fl, upper_fl)")
    apw_look_ahead_s: float | None = Field(None, gt=0, le=600, description="default: look_ahead_s")
    apw_confirm_periods: int = Field(2, ge=1)
    apw_unknown_fl_inside: bool = Field(
        False, description="a track without a flight level counts as inside every volume's vertical band"
    )

    # MSAW
    msaw_enabled: bool = True
    msa_file: Path | None = Field(None, description="GeoJSON polygons with property min_alt_ft, or a JSON MsaGrid")
    msaw_look_ahead_s: float | None = Field(None, gt=0, le=600, description="default: look_ahead_s")
    msaw_confirm_periods: int = Field(2, ge=1)
    qnh_hpa: float = Field(
        STANDARD_PRESSURE_HPA, ge=900, le=1100, description="altitude = 100·FL + (QNH − 1013.25)·27 ft"
    )

    @model_validator(mode="after")
    def _turn_rates(self) -> SafetyNetsConfig:
        if self.turn_max_dps < self.turn_min_dps:
            raise ValueError("turn_max_dps must be at least turn_min_dps")
        return self

    @property
    def apw_horizon_s(self) -> float:
        return self.apw_look_ahead_s if self.apw_look_ahead_s is not None else self.look_ahead_s

    @property
    def msaw_horizon_s(self) -> float:
        return self.msaw_look_ahead_s if self.msaw_look_ahead_s is not None else self.look_ahead_s
