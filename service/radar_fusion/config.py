"""Daemon configuration: one TOML file, environment variables may override (DESIGN.md §3).

    [system]   center_lat, center_lon (system-plane origin, degrees), period_s
    [bus]      mode = "router" | "peer" | "client", listen = [...], connect = [...], prefix
    [[radars]] id, lat, lon, alt_m, sigma_range_m, sigma_azimuth_deg, rotation_period_s
    [tracking] Singer filter, gates and track life-cycle parameters (all defaulted)
    [outliers] live wild-plot gate (Hu 2013) parameters (all defaulted)
    [safety_nets] STCA / APW / MSAW parameters (all defaulted)
    [metrics]  listen = "127.0.0.1:9108": Prometheus endpoint (off when absent)

Environment overrides use the prefix ``RADAR_FUSION_`` and ``__`` between levels, e.g.
``RADAR_FUSION_BUS__MODE=client``. A bad file or value raises :class:`ConfigError`,
whose message names the file and the field; the daemon refuses to start on it.
"""

from __future__ import annotations

import tomllib
from pathlib import Path
from typing import Any, Literal, Optional

from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator
from pydantic_settings import BaseSettings, SettingsConfigDict

from .safety_nets.config import SafetyNetsConfig


class ConfigError(Exception):
    """A configuration file that cannot be used; the message names file and field."""


class _Section(BaseModel):
    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)


class SystemConfig(_Section):
    center_lat: float = Field(ge=-89, le=89, description="system-plane origin latitude, degrees")
    center_lon: float = Field(ge=-180, le=180, description="system-plane origin longitude, degrees")
    period_s: float = Field(4.0, gt=0.2, le=30, description="fusion period; at most the shortest rotation period")
    allowed_lateness_s: float = Field(
        1.0, ge=0, le=30, description="how long after a period's end plots of it are still waited for"
    )
    radar_timeout_s: float = Field(
        30.0, gt=0, description="event-time silence after which a radar no longer holds periods open"
    )
    max_future_s: float = Field(
        60.0, gt=0, description="plots this far ahead of the newest watermark are refused as implausible"
    )
    max_buffered_plots_per_radar: int = Field(
        200_000, gt=0, description="plots of one radar that may wait for open periods; beyond, refused as buffer_full"
    )


class BusConfig(_Section):
    mode: Literal["router", "peer", "client"] = "router"
    listen: list[str] = Field(default_factory=lambda: ["tcp/127.0.0.1:7447"])
    connect: list[str] = Field(default_factory=list)
    prefix: str = Field("atc", pattern=r"^[A-Za-z0-9_-]+(/[A-Za-z0-9_-]+)*$")
    health_period_s: float = Field(2.0, gt=0)
    max_payload_bytes: int = Field(4 << 20, gt=0)
    multicast_scouting: bool = False
    zenoh_config_file: Optional[str] = Field(
        None, description="optional zenoh JSON5 config (TLS, access control); listen/connect/mode still apply"
    )


class MetricsConfig(_Section):
    listen: Optional[str] = Field(
        None, pattern=r"^(\[[0-9A-Fa-f:.]+\]|[A-Za-z0-9_.-]*):[0-9]{1,5}$",
        description="HOST:PORT of the Prometheus /metrics endpoint, e.g. 127.0.0.1:9108; off when absent",
    )


class RadarConfig(_Section):
    id: str = Field(pattern=r"^[A-Za-z0-9_.-]{1,32}$")
    lat: float = Field(ge=-90, le=90)
    lon: float = Field(ge=-180, le=180)
    alt_m: float = Field(0.0, ge=-500, le=9000, description="antenna height above the WGS-84 ellipsoid")
    sigma_range_m: float = Field(gt=0, le=5000)
    sigma_azimuth_deg: float = Field(gt=0, le=5)
    rotation_period_s: float = Field(gt=0, le=60)
    max_range_m: float = Field(500_000.0, gt=0, description="instrumented range; plots beyond are refused")
    sac: Optional[int] = Field(None, ge=0, le=255, description="ASTERIX system area code")
    sic: Optional[int] = Field(None, ge=0, le=255, description="ASTERIX system identification code")

    # lat_deg etc. aliases let coordinate code take radar configs directly
    @property
    def lat_deg(self) -> float:
        return self.lat

    @property
    def lon_deg(self) -> float:
        return self.lon


class TrackingConfig(_Section):
    # Singer model (Shu 2007 eq. 4, 12 and Q); defaults justified in singer_filter.py.
    alpha_per_s: Optional[float] = Field(None, gt=0, description="manoeuvre reciprocal time constant α = 1/Tc")
    sigma_m_mps2: Optional[float] = Field(None, gt=0, description="manoeuvre acceleration standard deviation")
    fusion_method: Literal["scalar", "matrix"] = Field(
        "matrix", description="scalar: Shu eq. 5-6; matrix: full-covariance information form"
    )
    manoeuvre_sigma_factor: float = Field(
        4.0, ge=1.0, description="σ_m multiplier while a manoeuvre is detected (1 = off)"
    )
    manoeuvre_nis_on: float = Field(6.0, gt=0, description="fading-average NIS above which a track manoeuvres")
    manoeuvre_nis_off: float = Field(3.0, gt=0, description="... and below which it flies straight again")
    manoeuvre_nis_fading: float = Field(0.5, ge=0, lt=1, description="weight of the previous NIS average")
    gate_chi2: float = Field(13.8, gt=0, description="association gate, chi-square with 2 dof (99.9 %)")
    new_target_gate_m: float = Field(3000.0, gt=0, description="plots of one new target lie within this distance")
    max_speed_mps: float = Field(350.0, gt=0)
    confirm_updates: int = Field(3, ge=2, description="updates (M) needed to confirm a tentative track ...")
    confirm_window_s: float = Field(40.0, gt=0, description="... within this time from its first plot (N)")
    coast_after_scans: float = Field(
        1.5, gt=0, description="missed scans (of the track's own radars' revisit time) before status coasting"
    )
    delete_tentative_after_scans: float = Field(2.5, gt=0, description="missed scans that end a tentative track")
    delete_after_scans: float = Field(
        6.5, gt=0, description="missed scans that end a confirmed track (a run of 5 rejected wild plots survives)"
    )
    coast_after_s: Optional[float] = Field(None, gt=0, description="fixed coasting time, instead of scans")
    delete_tentative_after_s: Optional[float] = Field(None, gt=0, description="fixed time, instead of scans")
    delete_after_s: Optional[float] = Field(None, gt=0, description="fixed time, instead of scans")
    assumed_altitude_ft: float = Field(10_000.0, description="height assumed for plots without Mode C")
    min_track_separation_m: float = Field(
        500.0, ge=0, description="a tentative track this close to a confirmed one with the same identity is dropped"
    )


class OutlierConfig(_Section):
    enabled: bool = True
    window: int = Field(8, ge=4, le=256, description="plots of one radar track kept as its recent window")
    k: int = Field(3, ge=1, description="k of the k-mean distance (Hu 2013)")
    threshold: float = Field(6.0, gt=0, description="standardised k-mean distance above which a plot is wild")
    relock_after: int = Field(6, ge=2, description="this many consecutive rejections are a genuine jump")


class Settings(BaseSettings):
    """The whole daemon configuration."""

    model_config = SettingsConfigDict(
        env_prefix="RADAR_FUSION_", env_nested_delimiter="__", extra="forbid", allow_inf_nan=False
    )

    system: SystemConfig
    bus: BusConfig = Field(default_factory=BusConfig)
    radars: list[RadarConfig] = Field(min_length=1)
    tracking: TrackingConfig = Field(default_factory=TrackingConfig)
    outliers: OutlierConfig = Field(default_factory=OutlierConfig)
    metrics: MetricsConfig = Field(default_factory=MetricsConfig)
    safety_nets: SafetyNetsConfig = Field(default_factory=SafetyNetsConfig)

    @classmethod
    def settings_customise_sources(cls, settings_cls, init_settings, env_settings, dotenv_settings, file_secret_settings):
        # The file's values come in as init arguments; the environment overrides them.
        return (env_settings, init_settings)

    @model_validator(mode="after")
    def _unique_radars(self) -> "Settings":
        ids = [r.id for r in self.radars]
        dup = sorted({i for i in ids if ids.count(i) > 1})
        if dup:
            raise ValueError(f"radar ids must be unique, repeated: {dup}")
        sacsic = [(r.sac, r.sic) for r in self.radars if r.sac is not None and r.sic is not None]
        if len(sacsic) != len(set(sacsic)):
            raise ValueError("radar (sac, sic) pairs must be unique")
        return self

    @property
    def longest_rotation_s(self) -> float:
        return max(r.rotation_period_s for r in self.radars)

    @property
    def shortest_rotation_s(self) -> float:
        return min(r.rotation_period_s for r in self.radars)


def _config_error(exc: ValidationError, source: str, section: str = "") -> ConfigError:
    lines = []
    for e in exc.errors():
        loc = ".".join(str(x) for x in (section,) * bool(section) + tuple(e["loc"])) or "(top level)"
        lines.append(f"{source}: {loc}: {e['msg']}")
    return ConfigError("\n".join(lines))


def settings_from_dict(data: dict[str, Any], source: str = "<dict>") -> Settings:
    """Validate a configuration mapping; errors name the source and the field."""
    try:
        return Settings(**data)
    except ValidationError as exc:
        raise _config_error(exc, source) from None


def load_settings(path: str | Path) -> Settings:
    """Read a TOML configuration file (plus environment overrides)."""
    path = Path(path)
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise ConfigError(f"{path}: file not found") from None
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{path}: not valid TOML: {exc}") from None
    return settings_from_dict(data, str(path))
