"""The simulation: every radar over the scenario, its messages merged in publish order,
the truth sampled every second.


Publication: the revolution is divided into ``n_sectors`` sectors. The plots of a
sector are published as one PlotBatch at the end of its sweep (``seq`` +1 each message
per radar, from 0; a sector without plots still gives an empty batch), followed, at the
same time, by a RadarStatus for the crossing: ``"north"`` (sector 0, with
``rotation_period_s``) at north, ``"sector"`` (with the sector number) elsewhere.
Messages of all radars are merged in time order. Only sectors whose sweep ends inside
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from radar_fusion import wire
from radar_fusion.geo.coordinates import RadarSites, SystemPlane, geodetic_to_polar
from radar_fusion.geo.units import M_PER_FT, MPS_PER_FPM

from ..truth import Truth
from .encoding import batch_payload, pack_plots
from .radar_model import TargetTable, coverage, radar_plots
from .scenario import RadarSpec, Scenario
from .trajectories import Trajectories


@dataclass(kw_only=True)
class PlotColumns(wire.DecodedPlots):
    """The plots of one published PlotBatch: the columns the engine ingests
    (:class:`wire.DecodedPlots`, so a batch goes to :meth:`Engine.ingest_plots` as it is,
    for benchmarks without msgpack), plus what only the simulator knows.

    Missing values: ``fl``, ``roll_deg``, ``ground_speed_mps``, ``track_angle_deg``,
    ``magnetic_heading_deg`` and ``indicated_airspeed_mps`` NaN,
    ``mode3a``/``mode_s``/``track_no`` -1; ``kind`` uses :data:`wire.KIND_CODES`;
    ``radar_index`` is the radar's row of ``Scenario.radars``, ``t_pub_s`` the batch's
    publish time; ``target_index`` is the true target (row of ``Scenario.targets``), -1 for
    false plots; ``wild`` marks gross errors.
    """

    radar_index: int
    t_pub_s: float
    target_index: np.ndarray
    wild: np.ndarray


@dataclass
class Simulation:
    """Result of :func:`simulate`.

    ``messages``: (t_s, key relative to the prefix, payload) in publish order;
    ``plot_columns``: one :class:`PlotColumns` per PlotBatch message, same order;
    ``statuses``: (t_s, radar_id, kind, sector) of every RadarStatus message;
    ``truth``: :class:`Truth`; ``trajectories``: exact truth at any time;
    ``radar_phase_deg``: antenna phase per radar (beam azimuth at ``start_t_s``).
    """

    scenario: Scenario
    plane: SystemPlane
    sites: RadarSites
    trajectories: Trajectories
    radar_phase_deg: np.ndarray
    messages: list[tuple[float, str, bytes]]
    plot_columns: list[PlotColumns]
    statuses: list[tuple[float, str, str, int]]
    truth: Truth
    stats: dict[str, dict[str, int]]

    def beam_azimuth_deg(self, radar_index: int, t_s: Any) -> np.ndarray:
        """Beam azimuth of a radar at times ``t_s``: 360 ((t - t0)/T mod 1) + phase, mod 360."""
        r = self.scenario.radars[radar_index]
        t = np.asarray(t_s, float)
        return np.mod(
            360.0 * np.mod((t - self.scenario.start_t_s) / r.rotation_period_s, 1.0)
            + self.radar_phase_deg[radar_index],
            360.0,
        )

    def truth_at(self, target_index: Any, t_s: Any) -> dict[str, np.ndarray]:
        """Exact truth (lat_deg, lon_deg, alt_ft, x_m, y_m, vx_mps, vy_mps, vrate_fpm, active)."""
        st = self.trajectories.state(target_index, t_s)
        lat, lon = self.plane.to_geodetic(st.x_m, st.y_m)
        return dict(
            lat_deg=lat,
            lon_deg=lon,
            alt_ft=st.alt_m / M_PER_FT,
            x_m=st.x_m,
            y_m=st.y_m,
            vx_mps=st.vx_mps,
            vy_mps=st.vy_mps,
            vrate_fpm=st.vz_mps / MPS_PER_FPM,
            active=st.active,
        )

    def all_plots(self) -> PlotColumns:
        """All plots of all radars in one :class:`PlotColumns` (publish order; the radar of
        each plot is not kept: use :attr:`plot_columns` for per-radar work)."""
        cols = self.plot_columns
        cat = lambda name: np.concatenate([getattr(c, name) for c in cols]) if cols else np.zeros(0)
        return _plot_columns("*", -1, -1, math.nan, {name: cat(name) for name in _PLOT_COLUMNS})


_PLOT_COLUMNS = (
    "t_s", "range_m", "azimuth_deg", "fl", "mode3a", "mode_s", "track_no", "kind", "roll_deg",
    "ground_speed_mps", "track_angle_deg", "magnetic_heading_deg", "indicated_airspeed_mps", "target_index", "wild",
)  # fmt: skip
"""The per-plot columns of a :class:`PlotColumns`."""


def _plot_columns(
    radar_id: str, radar_index: int, seq: int, t_pub_s: float, c: Mapping[str, np.ndarray]
) -> PlotColumns:
    """A :class:`PlotColumns` of the columns ``c`` (keys :data:`_PLOT_COLUMNS`)."""
    return PlotColumns(
        radar_id=radar_id,
        radar_index=radar_index,
        seq=seq,
        t_pub_s=t_pub_s,
        t_s=c["t_s"],
        range_m=c["range_m"],
        azimuth_deg=c["azimuth_deg"],
        fl=c["fl"],
        mode3a=c["mode3a"],
        mode_s=c["mode_s"],
        track_no=c["track_no"],
        kind=c["kind"],
        roll_deg=c["roll_deg"],
        ground_speed_mps=c["ground_speed_mps"],
        track_angle_deg=c["track_angle_deg"],
        magnetic_heading_deg=c["magnetic_heading_deg"],
        indicated_airspeed_mps=c["indicated_airspeed_mps"],
        target_index=c["target_index"],
        wild=c["wild"],
    )


def _mode_s_str(a: np.ndarray) -> np.ndarray:
    return np.array(["" if v < 0 else f"{int(v):06X}" for v in a], dtype=object)


def _covered_by_any(sim_ctx: dict, radars: Sequence[RadarSpec], lat, lon, alt_m, x_m, y_m) -> np.ndarray:
    """True where at least one radar covers the point (range, horizon, cone of silence)."""
    sites: RadarSites = sim_ctx["sites"]
    sx, sy = sites.plane_positions(sim_ctx["plane"])
    out = np.zeros(lat.shape[0], bool)
    for r, spec in enumerate(radars):
        # plane distance prefilter (the plane's scale error is < 1 % at these distances)
        cand = np.nonzero(~out & (np.hypot(x_m - sx[r], y_m - sy[r]) <= 1.02 * spec.max_range_m + 5000.0))[0]
        if cand.size == 0:
            continue
        rho, _az, g = geodetic_to_polar(sites, np.full(cand.size, r), lat[cand], lon[cand], alt_m[cand])
        out[cand] |= coverage(spec, float(sites.earth_radius_m[r]), rho, g, alt_m[cand])
    return out


def _sample_truth(sim_ctx: dict, scenario: Scenario) -> Truth:
    """The truth every second of the scenario while each target exists (``target_index``: its scenario row)."""
    traj: Trajectories = sim_ctx["traj"]
    times = scenario.start_t_s + np.arange(0.0, math.floor(scenario.duration_s) + 1.0)
    tgt_grid, t_grid = np.meshgrid(np.arange(traj.n), times, indexing="ij")
    tgt, tk = tgt_grid.reshape(-1), t_grid.reshape(-1)
    st = traj.state(tgt, tk)
    keep = st.active
    tgt, tk = tgt[keep], tk[keep]
    x, y, alt = st.x_m[keep], st.y_m[keep], st.alt_m[keep]
    lat, lon = sim_ctx["plane"].to_geodetic(x, y)
    det = _covered_by_any(sim_ctx, scenario.radars, lat, lon, alt, x, y)
    ids = np.array([t.target_id for t in scenario.targets], dtype=object)
    ms = _mode_s_str(np.array([-1 if t.mode_s is None else t.mode_s for t in scenario.targets], np.int64))
    cs = np.array([t.callsign or "" for t in scenario.targets], dtype=object)
    # Rows come target by target, each in time order: the truth's own order, kept as it is.
    return Truth.from_columns(
        t_s=tk,
        target_id=ids[tgt] if tgt.size else np.zeros(0, object),
        x_m=x,
        y_m=y,
        vx_mps=st.vx_mps[keep],
        vy_mps=st.vy_mps[keep],
        detectable=det,
        mode_s=ms[tgt] if tgt.size else np.zeros(0, object),
        callsign=cs[tgt] if tgt.size else np.zeros(0, object),
        lat_deg=lat,
        lon_deg=lon,
        alt_ft=alt / M_PER_FT,
        vrate_fpm=st.vz_mps[keep] / MPS_PER_FPM,
        target_index=tgt,
    )


def simulate(scenario: Scenario, *, encode: bool = True) -> Simulation:
    """Simulate every radar over the scenario.

    ``encode=False`` skips building msgpack payloads (``messages`` is then empty) for
    benchmarks that only use :attr:`Simulation.plot_columns`.
    """
    if not scenario.radars:
        raise ValueError("a scenario needs at least one radar")
    plane = SystemPlane(scenario.center_lat_deg, scenario.center_lon_deg)
    sites = RadarSites.from_configs(scenario.radars)
    traj = Trajectories(scenario.targets, plane, scenario.start_t_s)
    t_start = float(scenario.start_t_s)
    t_end = t_start + float(scenario.duration_s)
    ctx = dict(
        traj=traj,
        plane=plane,
        sites=sites,
        targets=TargetTable(scenario.targets),
        t_start=t_start,
        t_end=t_end,
        duration_s=float(scenario.duration_s),
        atmosphere=scenario.atmosphere,
        aircraft_air_errors=scenario.atmosphere.aircraft_errors(len(scenario.targets), scenario.seed),
    )
    seeds = np.random.SeedSequence(scenario.seed).spawn(len(scenario.radars) + 1)
    phase_rng = np.random.default_rng(seeds[0])
    phases = np.array(
        [
            phase_rng.uniform(0.0, 360.0) if r.start_phase_deg is None else float(r.start_phase_deg) % 360.0
            for r in scenario.radars
        ]
    )

    # per radar: batches and status events; merged afterwards
    ev_t: list[np.ndarray] = []
    ev_radar: list[np.ndarray] = []
    ev_sub: list[np.ndarray] = []  # 0 batch, 1 status (batch first at equal time)
    ev_ref: list[np.ndarray] = []  # index into the radar's batch / status list
    batches: list[list[PlotColumns]] = []
    payloads: list[list[bytes]] = []
    status_rows: list[list[tuple]] = []
    stats: dict[str, dict[str, int]] = {}
    for r, spec in enumerate(scenario.radars):
        rng = np.random.default_rng(seeds[r + 1])
        p, stats[spec.id] = radar_plots(ctx, r, spec, scenario.rates_of(spec), float(phases[r]), rng)
        period, phase = spec.rotation_period_s, float(phases[r])
        width = 360.0 / spec.n_sectors
        angle = lambda t, period=period, phase=phase: 360.0 * (t - t_start) / period + phase
        btime = lambda a, period=period, phase=phase: t_start + (a - phase) * period / 360.0
        q_first = math.floor(angle(t_start) / width)
        q_last = math.floor(angle(t_end) / width) - 1
        sweeps = np.arange(q_first, q_last + 1)
        t_pub = btime((sweeps + 1) * width)
        q_plot = np.floor(angle(p["t_s"]) / width)
        bounds = np.searchsorted(q_plot, np.concatenate([sweeps, [q_last + 1]]), side="left")
        if encode:
            data, offsets = pack_plots(p)
        rb, rp, rs = [], [], []
        for b, q in enumerate(sweeps):
            lo, hi = int(bounds[b]), int(bounds[b + 1])
            cols = _plot_columns(spec.id, r, b, float(t_pub[b]), {k: v[lo:hi] for k, v in p.items()})
            rb.append(cols)
            if encode:
                rp.append(batch_payload(spec.id, b, data[offsets[lo] : offsets[hi]].tobytes(), hi - lo))
            sector = int((q + 1) % spec.n_sectors)
            rs.append((float(t_pub[b]), spec.id, "north" if sector == 0 else "sector", sector))
        stats[spec.id]["batches"] = len(rb)
        stats[spec.id]["published_plots"] = int(sum(len(x) for x in rb))
        batches.append(rb)
        payloads.append(rp)
        status_rows.append(rs)
        nb = len(rb)
        ev_t += [t_pub, t_pub]
        ev_radar += [np.full(nb, r), np.full(nb, r)]
        ev_sub += [np.zeros(nb, np.int8), np.ones(nb, np.int8)]
        ev_ref += [np.arange(nb), np.arange(nb)]

    t_all = np.concatenate(ev_t)
    radar_all, sub_all, ref_all = np.concatenate(ev_radar), np.concatenate(ev_sub), np.concatenate(ev_ref)
    order = np.lexsort((sub_all, radar_all, t_all))
    messages: list[tuple[float, str, bytes]] = []
    plot_columns: list[PlotColumns] = []
    statuses: list[tuple[float, str, str, int]] = []
    for i in order.tolist():
        r, k = int(radar_all[i]), int(ref_all[i])
        spec = scenario.radars[r]
        if sub_all[i] == 0:
            plot_columns.append(batches[r][k])
            if encode:
                messages.append((float(t_all[i]), f"radar/{spec.id}/plots", payloads[r][k]))
        else:
            row = status_rows[r][k]
            statuses.append(row)
            if encode:
                msg = {"v": wire.WIRE_VERSION, "radar_id": spec.id, "t": row[0], "kind": row[2], "sector": row[3]}
                if row[2] == "north":
                    msg["rotation_period_s"] = float(spec.rotation_period_s)
                messages.append((row[0], f"radar/{spec.id}/status", wire.encode(msg)))

    truth = _sample_truth(ctx, scenario)
    return Simulation(
        scenario=scenario,
        plane=plane,
        sites=sites,
        trajectories=traj,
        radar_phase_deg=phases,
        messages=messages,
        plot_columns=plot_columns,
        statuses=statuses,
        truth=truth,
        stats=stats,
    )
