"""Daemon configuration: one TOML file, environment variables may override (DESIGN.md §3).

    [system]   center_lat, center_lon (system-plane origin, degrees), period_s
    [bus]      mode = "router" | "peer" | "client", listen = [...], connect = [...], prefix
    [[radars]] id, lat, lon, alt_m, sigma_range_m, sigma_azimuth_deg, rotation_period_s
    [tracking] the filter: Singer model, fusion, manoeuvre detection (all defaulted)
    [clustering] association gates and new-target clustering (tracking/clustering.py)
    [life_cycle] track confirmation, coasting and deletion (tracking/track_management.py)
    [registration] online radar bias estimation (tracking/registration.py)
    [outliers] the live wild-plot gate (tracking/live_gate.py LiveGateParams, all defaulted)
    [safety_nets] STCA / APW / MSAW parameters (all defaulted)
    [metrics]  listen = "127.0.0.1:9108": Prometheus endpoint (off when absent)
    [redundancy] enabled = true: a hot-standby pair (redundancy.py; off by default)

Environment overrides use the prefix ``RADAR_FUSION_`` and ``__`` between levels, e.g.
``RADAR_FUSION_BUS__MODE=client``. A bad file or value raises :class:`ConfigError`,
whose message names the file and the field; the daemon refuses to start on it.
"""

from __future__ import annotations

import os
import tomllib
from pathlib import Path
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator
from pydantic_settings import BaseSettings, SettingsConfigDict

from .geo.coordinates import MODE_C_HEIGHT_SIGMA_FRACTION, MODE_C_HEIGHT_SIGMA_FRACTION_WITH_MET
from .safety_nets.config import SafetyNetsConfig
from .tracking.clustering import ClusteringParams
from .tracking.imm import IMMParams
from .tracking.live_gate import LiveGateParams
from .tracking.registration import RegistrationParams
from .tracking.singer_filter import DEFAULT_ALPHA_PER_S, DEFAULT_SIGMA_M_MPS2
from .tracking.track_management import LifeCycle
from .wire import MAX_PLOT_BATCH_BYTES


class ConfigError(Exception):
    """A configuration file that cannot be used; the message names file and field."""


class _Section(BaseModel):
    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)


class SystemConfig(_Section):
    center_lat: float = Field(ge=-89, le=89, description="system-plane origin latitude, degrees")
    center_lon: float = Field(ge=-180, le=180, description="system-plane origin longitude, degrees")
    period_s: float = Field(4.0, gt=0.2, le=30, description="fusion period; at most the shortest rotation period")
    allowed_lateness_s: float = Field(
        1.0,
        ge=0,
        le=30,
        description="the longest a radar's plots are waited for after it has reported a later time; each radar "
        "is waited for only as far behind its newest time as its plots have been seen to arrive (watermarks.py)",
    )
    lateness_memory_s: float = Field(
        600.0,
        gt=0,
        description="event time for which a radar's out-of-order arrival is remembered (its lateness is the "
        "largest in the last one to two of these): a passing disorder does not delay every period after it",
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
    clock_offset_limit_s: float = Field(
        2.0,
        gt=0,
        description="a radar whose clock is off by more than this against the other radars' is shown "
        "clock_suspect on health (about half a scan: plots later than that start to miss their period)",
    )


class BusConfig(_Section):
    mode: Literal["router", "peer", "client"] = "router"
    listen: list[str] = Field(default_factory=lambda: ["tcp/127.0.0.1:7447"])
    connect: list[str] = Field(default_factory=list)
    prefix: str = Field("atc", pattern=r"^[A-Za-z0-9_-]+(/[A-Za-z0-9_-]+)*$")
    health_period_s: float = Field(2.0, gt=0)
    max_payload_bytes: int = Field(MAX_PLOT_BATCH_BYTES, gt=0)
    multicast_scouting: bool = False
    zenoh_config_file: str | None = Field(
        None, description="optional zenoh JSON5 config (TLS, access control); listen/connect/mode still apply"
    )


class RedundancyConfig(_Section):
    """A hot-standby pair (or more) on one bus (redundancy.py, issue 13)."""

    enabled: bool = Field(
        False,
        description="elect one active among the serve processes of this configuration on the bus (Zenoh "
        "liveliness); only the active publishes tracks and alerts, every standby applies its state",
    )
    instance: str | None = Field(
        None,
        pattern=r"^[A-Za-z0-9_.:-]{1,64}$",
        description="this process's name on the bus; default <hostname>:<pid>. Among standbys the smallest "
        "name takes over first",
    )
    lease_s: float = Field(
        2.0,
        ge=0.5,
        le=10.0,
        description="Zenoh link lease with redundancy on: a peer silent this long (host down, cable cut) is "
        "dropped and its liveliness tokens with it. Default 2 s, so that a standby takes over within two "
        "periods of 4 s (Zenoh's own default is 10 s)",
    )
    settle_s: float = Field(
        1.0,
        ge=0,
        le=30,
        description="at start, listen this long for an active before taking over (an active already on the "
        "bus is seen at once through liveliness history; this covers its tokens still in flight)",
    )
    handover_s: float = Field(
        0.5,
        ge=0,
        le=10,
        description="after the active's token is withdrawn, wait this long before taking over: its last "
        "TrackBatches, published before the withdrawal but on a lower priority than Zenoh's declarations, "
        "arrive meanwhile, and the standby does not publish those periods again (on loopback a standby that "
        "took over at once republished the active's last two periods)",
    )


class MetricsConfig(_Section):
    listen: str | None = Field(
        None,
        pattern=r"^(\[[0-9A-Fa-f:.]+\]|[A-Za-z0-9_.-]*):[0-9]{1,5}$",
        description="HOST:PORT of the Prometheus /metrics endpoint, e.g. 127.0.0.1:9108; off when absent",
    )


class RadarConfig(_Section):
    id: str = Field(pattern=r"^[A-Za-z0-9_.-]{1,32}$")
    lat: float = Field(gt=-90, lt=90, description="antenna latitude, degrees (not at a pole)")
    lon: float = Field(ge=-180, le=180)
    alt_m: float = Field(0.0, ge=-500, le=9000, description="antenna height above the WGS-84 ellipsoid")
    sigma_range_m: float = Field(gt=0, le=5000)
    sigma_azimuth_deg: float = Field(
        ge=0.01, le=5, description="1-σ azimuth noise, degrees (a monopulse SSR 0.03-0.07; radians would be ~0.001)"
    )
    rotation_period_s: float = Field(
        ge=0.5, le=60, description="antenna rotation period, seconds (4-12 for ATC radars)"
    )
    max_range_m: float = Field(
        500_000.0,
        ge=10_000,
        description="instrumented range, metres; plots beyond are refused (in NM every plot was, without a word)",
    )
    pd: float = Field(
        0.9,
        gt=0,
        le=1,
        description="probability of detecting an aircraft in coverage per scan; the life cycle ends a track "
        "its radars all keep missing (life_cycle.end_miss_probability). Default 0.9, the ICAO/EUROCONTROL "
        "minimum for an SSR (ESASSP: >= 97 % for Mode S, >= 90 % PSR)",
    )
    sac: int | None = Field(None, ge=0, le=255, description="ASTERIX system area code")
    sic: int | None = Field(None, ge=0, le=255, description="ASTERIX system identification code")

    # lat_deg etc. aliases let coordinate code take radar configs directly
    @property
    def lat_deg(self) -> float:
        return self.lat

    @property
    def lon_deg(self) -> float:
        return self.lon


class TrackingConfig(_Section):
    """The filter: Singer model, cluster fusion, manoeuvre detection, plots without Mode C.

    Association and track start are ``[clustering]`` (tracking/clustering.py
    ``ClusteringParams``), the track life cycle is ``[life_cycle]``
    (tracking/track_management.py ``LifeCycle``).
    """

    alpha_per_s: float = Field(
        DEFAULT_ALPHA_PER_S,
        gt=0,
        description="Singer manoeuvre bandwidth α = 1/T_c (Shu eq. 4, 12). Default 1/30 s⁻¹: the ~30 s of a "
        "rate-one 90° turn (singer_filter.py)",
    )
    sigma_m_mps2: float = Field(
        DEFAULT_SIGMA_M_MPS2,
        gt=0,
        description="Singer acceleration standard deviation σ_m (Shu §4's Q). Default ≈ 2.5 m/s², from Singer's "
        "formula with a 25° bank turn as the maximum (singer_filter.py)",
    )
    two_point_prior: bool = Field(
        True,
        description="the second update (Shu §4's two-point initiation) as the Kalman update of the one-point "
        "state, whose velocity prior N(0, max_speed²/3) it keeps (initiation.two_point_initiation); false: Shu's "
        "P0 exactly, the velocity unknown beyond any bound. Default true: two coarse positions a few seconds "
        "apart no longer give a velocity far beyond any aircraft's (1,000x10: velocity RMS 11.8 -> 11.2 m/s, "
        "second-update velocity 48 -> 41 m/s; 50x3 unchanged)",
    )
    filter: Literal["singer", "imm"] = Field(
        "imm",
        description="singer: one Singer model (σ_m above) with NIS manoeuvre detection raising its noise "
        "(manoeuvre.py), the seeds' filter and the baseline; imm: an interacting multiple model filter of a "
        "quiet and a manoeuvre Singer model and right and left coordinated turns ([tracking.imm], "
        "tracking/imm.py, tracking/coordinated_turn.py), which follows turns without "
        "the straight-flight noise of a single high-σ_m model, and publishes each track's manoeuvre "
        "probability (issue 15 item 3). Default imm: side by side on the same plots it was more accurate in every "
        "case measured (demo 73.0 -> 62.6 m, ADS-B 94 -> 87 m, 50x3 GOSPA 878 -> 830 m), with the same track ids "
        "and safety-eval still 21/21 without nuisance (median warning 105 s, min 92 s, against 104 / 88 s); it "
        "costs 0.7-0.8x of the engine's throughput",
    )
    imm: IMMParams = Field(
        default_factory=IMMParams,
        description="the IMM's models and mode dwell times (tracking/imm.py IMMParams); used with filter = imm",
    )
    imm_threads: int = Field(
        1,
        ge=1,
        le=64,
        description="threads the IMM's per-track cycle runs on (the calling thread and imm_threads - 1 more, "
        "each a share of the tracks; tracking/imm.py); the tracks are the same to the bit. Default 1. With cores "
        "to spare the engine's period is shorter: 2 threads on the 2-core bench machine, engine alone at 4,000x10, "
        "112k -> 142k plots/s, period p50 66 -> 51 ms; but inside the daemon there, whose Zenoh threads, replay and "
        "safety nets share those cores, neither the full-speed throughput nor the end-to-end p99 gained "
        "(71k -> 71k plots/s; 103 -> 108 ms and 103 -> 92 ms in two runs). Remeasured 2026-12-06 on that VM, "
        "the engine alone gained nothing either (117-131k against 127-132k plots/s): the pool's thread, asleep "
        "between a period's kernel calls, wakes too late there (docs/measurements.md, 'The IMM on more threads')",
    )
    fusion_method: Literal["scalar", "matrix"] = Field(
        "matrix",
        description="scalar: Shu eq. 5-6 per axis; matrix: the full-covariance information form, which "
        "keeps the range/azimuth ellipse of each plot (fusion.py)",
    )
    manoeuvre_sigma_factor: float = Field(
        4.0,
        ge=1.0,
        description="σ_m multiplier while a manoeuvre is detected (1 = off). Default 4: 2.5 → 10 m/s², "
        "the centripetal acceleration of a rate-one turn at 190 m/s (manoeuvre.py)",
    )
    manoeuvre_nis_on: float = Field(
        6.0,
        gt=0,
        description="fading-average NIS above which a track manoeuvres. Default 6: three times the mean "
        "2 of a χ² with 2 dof; one noisy update alone (NIS ~ 10) lifts the average only to 6 with fading 0.5",
    )
    manoeuvre_nis_off: float = Field(
        3.0,
        gt=0,
        description="... and below which it flies straight again. Default 3, half of the 'on' level: "
        "hysteresis, so a track does not flicker between the two models",
    )
    manoeuvre_nis_fading: float = Field(
        0.5,
        ge=0,
        lt=1,
        description="weight of the previous NIS average. Default 0.5: a memory of about two "
        "updates, so a turn is seen within two scans",
    )
    assumed_altitude_ft: float = Field(
        10_000.0,
        description="height assumed for plots without Mode C, ft (their slant range is converted to "
        "ground range at it). Default 10,000 ft, the middle of terminal-area traffic",
    )
    temperature_deviation_k: float | None = Field(
        None,
        ge=-50.0,
        le=50.0,
        description="the day's temperature less ISA's, K, as a mean over the air column from sea level to the "
        "flight levels (the met office's upper-air figure, not the surface temperature), read at start. With it "
        "a Mode C level is converted to its height by the hypsometric equation (geo.coordinates.mode_c_height_m) "
        "and its height error is 1 % of it; without it, 3 % (FL360 lies 656 m higher at ISA+15: near an antenna "
        "that error is ground range). A figure that may be stale or off by more than 2-3 K: raise "
        "mode_c_height_sigma_fraction (0.4 % per kelvin). Default none",
    )
    qnh_hpa: float | None = Field(
        None,
        ge=900.0,
        le=1100.0,
        description="the day's sea-level pressure, hPa (QNH): every level lies 8 m higher per hPa above 1013.25. "
        "It moves every level by one offset, not the error that grows with the height: alone, the height error "
        "stays 3 %. The safety nets' own [safety_nets] qnh_hpa (MSAW) is separate: set both. Default none",
    )

    mode_c_height_sigma_fraction: float | None = Field(
        None,
        ge=0.0,
        le=0.2,
        description="the Mode C height's 1-sigma error as a fraction of the height, beside its 60 m. Default "
        "none: 1 % with temperature_deviation_k, 3 % without it; 0 where the heights are exact (a test's plots)",
    )

    def mode_c_met(self) -> tuple[float | None, float | None]:
        """(temperature_deviation_k, qnh_hpa) for geo.coordinates.mode_c_height_m."""
        return self.temperature_deviation_k, self.qnh_hpa

    def mode_c_sigma_fraction(self) -> float:
        """The Mode C height's 1-sigma error as a fraction of the height (polar_to_plane)."""
        if self.mode_c_height_sigma_fraction is not None:
            return self.mode_c_height_sigma_fraction
        if self.temperature_deviation_k is None:  # QNH alone leaves the error that grows with the height
            return MODE_C_HEIGHT_SIGMA_FRACTION
        return MODE_C_HEIGHT_SIGMA_FRACTION_WITH_MET


#: the farthest a radar may be from the system centre: the world-scale case's disc is 1,260 km
MAX_RADAR_FROM_CENTRE_M = 2_000_000.0


class Settings(BaseSettings):
    """The whole daemon configuration."""

    model_config = SettingsConfigDict(
        env_prefix="RADAR_FUSION_", env_nested_delimiter="__", extra="forbid", allow_inf_nan=False
    )

    system: SystemConfig
    bus: BusConfig = Field(default_factory=BusConfig)
    radars: list[RadarConfig] = Field(
        min_length=1, max_length=64, description="at most 64 (a track's sources are bits of 64)"
    )
    tracking: TrackingConfig = Field(default_factory=TrackingConfig)
    clustering: ClusteringParams = Field(default_factory=ClusteringParams)
    life_cycle: LifeCycle = Field(default_factory=LifeCycle)
    registration: RegistrationParams = Field(default_factory=RegistrationParams)
    outliers: LiveGateParams = Field(default_factory=LiveGateParams)
    metrics: MetricsConfig = Field(default_factory=MetricsConfig)
    safety_nets: SafetyNetsConfig = Field(default_factory=SafetyNetsConfig)
    redundancy: RedundancyConfig = Field(default_factory=RedundancyConfig)

    @classmethod
    def settings_customise_sources(
        cls, settings_cls, init_settings, env_settings, dotenv_settings, file_secret_settings
    ):
        # The file's values come in as init arguments; the environment overrides them.
        return (env_settings, init_settings)

    @model_validator(mode="before")
    @classmethod
    def _moved_keys(cls, data: Any) -> Any:
        """Keys that were in ``[tracking]`` before the sections of issue 12: say where they went."""
        if isinstance(data, dict) and isinstance(data.get("tracking"), dict):
            for section, model in (("clustering", ClusteringParams), ("life_cycle", LifeCycle)):
                moved = sorted(set(data["tracking"]) & set(model.model_fields))
                if moved:
                    raise ValueError(f"[tracking] {', '.join(moved)}: these settings are now in [{section}]")
        return data

    @model_validator(mode="after")
    def _unique_radars(self) -> Settings:
        ids = [r.id for r in self.radars]
        dup = sorted({i for i in ids if ids.count(i) > 1})
        if dup:
            raise ValueError(f"radar ids must be unique, repeated: {dup}")
        sacsic = [(r.sac, r.sic) for r in self.radars if r.sac is not None and r.sic is not None]
        if len(sacsic) != len(set(sacsic)):
            raise ValueError("radar (sac, sic) pairs must be unique")
        return self

    @model_validator(mode="after")
    def _radars_near_the_centre(self) -> Settings:
        """Every radar within ``MAX_RADAR_FROM_CENTRE_M`` of the system plane's origin: a
        radar's latitude and longitude swapped, a sign flipped or the centre put at the
        antipode all started silently, with tracks thousands of kilometres off (and
        separations measured on a plane far from its origin: 5 NM read as 10.7)."""
        from .geo.coordinates import WGS84_GEOD

        c = self.system
        for r in self.radars:
            _, _, dist_m = WGS84_GEOD.inv(c.center_lon, c.center_lat, r.lon, r.lat)
            if dist_m > MAX_RADAR_FROM_CENTRE_M:
                raise ValueError(
                    f"radar {r.id} at ({r.lat}, {r.lon}) is {dist_m / 1000:,.0f} km from the system centre "
                    f"({c.center_lat}, {c.center_lon}); at most {MAX_RADAR_FROM_CENTRE_M / 1000:,.0f} km "
                    "(degrees, latitude first?)"
                )
        return self

    @model_validator(mode="after")
    def _period_within_rotation(self) -> Settings:
        """period_s at most the shortest rotation: longer, a radar's successive plots of one
        aircraft fall in one period and are clustered as several aircraft (a review: 4 s
        radars, 12 s periods, 39 track ids for 28 aircraft; 30 s, 54)."""
        if self.system.period_s > self.shortest_rotation_s + 1e-9:
            raise ValueError(
                f"[system] period_s {self.system.period_s} s is longer than the shortest rotation period, "
                f"{self.shortest_rotation_s} s"
            )
        return self

    @model_validator(mode="after")
    def _metrics_port(self) -> Settings:
        listen = self.metrics.listen
        if listen is not None and not 0 < int(listen.rpartition(":")[2]) < 65536:
            raise ValueError(f"[metrics] listen {listen!r}: the port must be 1 to 65535")
        return self

    @model_validator(mode="after")
    def _pair_peers_listen(self) -> Settings:
        # Zenoh routers do not route between peers (peers mesh directly): a peer of a pair
        # that no one can reach never sees the other's election tokens, and both go active
        if self.redundancy.enabled and self.bus.mode == "peer" and not self.bus.listen:
            raise ValueError(
                "[redundancy] with [bus] mode = 'peer' needs listen endpoints: peers of a pair reach each "
                "other directly (a router does not relay between peers); or use mode = 'client'"
            )
        return self

    @property
    def longest_rotation_s(self) -> float:
        return max(r.rotation_period_s for r in self.radars)

    @property
    def shortest_rotation_s(self) -> float:
        return min(r.rotation_period_s for r in self.radars)


def _config_error(exc: ValidationError, source: str) -> ConfigError:
    lines = []
    for e in exc.errors():
        loc = ".".join(str(x) for x in e["loc"]) or "(top level)"
        lines.append(f"{source}: {loc}: {e['msg']}")
    return ConfigError("\n".join(lines))


def settings_from_dict(data: dict[str, Any], source: str = "<dict>") -> Settings:
    """Validate a configuration mapping; errors name the source and the field (a value from
    the environment, RADAR_FUSION_..., is named as such)."""
    from pydantic_settings import SettingsError

    env = sorted(k for k in os.environ if k.startswith("RADAR_FUSION_"))
    if env:
        source = f"{source} (with {', '.join(env)} from the environment)"
    try:
        return Settings(**data)
    except ValidationError as exc:
        raise _config_error(exc, source) from None
    except SettingsError as exc:  # an environment value that does not parse (JSON of a list, ...)
        raise ConfigError(f"{source}: {exc}") from None


def load_settings(path: str | Path) -> Settings:
    """Read a TOML configuration file (plus environment overrides)."""
    path = Path(path)
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise ConfigError(f"{path}: file not found") from None
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{path}: not valid TOML: {exc}") from None
    except UnicodeDecodeError as exc:
        raise ConfigError(f"{path}: not UTF-8 text: {exc}") from None
    except OSError as exc:  # a directory, no permission, ...
        raise ConfigError(f"{path}: cannot be read: {exc.strerror or exc}") from None
    return settings_from_dict(data, str(path))
