"""Reproduction of Hu 2013's wild-point experiment (its results table is cut off).

Scenario (Hu 2013, Table 1 and Figure 1): an azimuth series of 987 samples at 10 Hz,
0 to 98.6 s, of an aircraft that makes an accelerating turn near 43.2 s, measured with
radar noise, with isolated wild points and runs of wild points at known places.

For each method (soft-weighted k-mean-distance outlier factor, K-MODF, 3-sigma
innovation gate) it prints the paper's kind of table for one seed: each injected wild
point removed (+) or not (-), and whether that is correct (T) or not (F), plus the false
removals; then precision and recall over many seeds, overall, on isolated wild points,
on runs, and false removals during the turn.

Wired by the lead as ``radar-fusion outliers``; ``python -m radar_fusion.tools.outlier_experiment``
also works.
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass

import numpy as np

from radar_fusion.tracking.outliers import OutlierParams, detect_outliers, innovation_gate_3sigma

N_SAMPLES = 987
RATE_HZ = 10.0
TURN_TIME_S = 43.2
AZIMUTH_NOISE_DEG = 0.05

# Known places of the injected wild points: (start time s, run length samples).
WILD_EVENTS = (
    (8.5, 1),
    (15.0, 3),
    (21.3, 1),
    (30.7, 2),
    (37.0, 1),
    (43.5, 1),
    (45.0, 5),
    (55.2, 1),
    (62.0, 4),
    (71.8, 1),
    (80.0, 2),
    (88.4, 1),
    (93.0, 5),
)

METHODS = ("soft", "kmodf", "gate3sigma")


@dataclass
class Scenario:
    """One realisation: time, truth, measurement, wild mask and the events' sample indices."""

    t_s: np.ndarray
    truth_deg: np.ndarray
    azimuth_deg: np.ndarray
    wild: np.ndarray
    events: list[tuple[int, int]]  # (first sample index, length)
    turn: np.ndarray  # mask of the samples during the turn


def true_azimuth_deg(t_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Azimuth of an aircraft seen from a radar at the origin, with an accelerating turn.

    Straight flight at 180 m/s, then from 40 s a turn whose rate grows to 6 deg/s while
    the aircraft accelerates at 3 m/s^2, until 55 s; straight again after. Returns the
    azimuth (deg, clockwise from north) and the mask of turning samples.
    """
    dt = np.diff(t_s, prepend=t_s[0])
    t_on, t_off = 40.0, 55.0
    turning = (t_s >= t_on) & (t_s < t_off)
    rate_deg_s = np.where(turning, 6.0 * np.clip((t_s - t_on) / (TURN_TIME_S - t_on), 0.0, 1.0), 0.0)
    speed_mps = 180.0 + 3.0 * np.clip(t_s - t_on, 0.0, t_off - t_on)
    heading = np.deg2rad(300.0 + np.cumsum(rate_deg_s * dt))
    x = 9000.0 + np.cumsum(speed_mps * np.sin(heading) * dt)
    y = 12000.0 + np.cumsum(speed_mps * np.cos(heading) * dt)
    return np.rad2deg(np.arctan2(x, y)) % 360.0, turning


def make_scenario(
    seed: int, noise_deg: float = AZIMUTH_NOISE_DEG, wild_min_deg: float = 1.0, wild_max_deg: float = 3.0
) -> Scenario:
    """Build the 987-sample azimuth series with the wild points of WILD_EVENTS.

    Each event gets one offset of random sign and magnitude in [wild_min_deg, wild_max_deg]
    (a run of wild points shares its offset, as when the tracker locks on a reflection),
    plus the ordinary noise.
    """
    rng = np.random.default_rng(seed)
    t_s = np.arange(N_SAMPLES) / RATE_HZ
    truth, turning = true_azimuth_deg(t_s)
    az = truth + rng.normal(0.0, noise_deg, N_SAMPLES)
    wild = np.zeros(N_SAMPLES, dtype=bool)
    events = []
    for t0, length in WILD_EVENTS:
        i0 = int(round(t0 * RATE_HZ))
        offset = rng.choice([-1.0, 1.0]) * rng.uniform(wild_min_deg, wild_max_deg)
        az[i0 : i0 + length] += offset
        wild[i0 : i0 + length] = True
        events.append((i0, length))
    return Scenario(t_s, truth, az, wild, events, turning)


def run_method(name: str, sc: Scenario, params: OutlierParams | None = None) -> np.ndarray:
    """Wild mask of one method on one scenario."""
    if name == "gate3sigma":
        return innovation_gate_3sigma(sc.azimuth_deg, sc.t_s, sigma=AZIMUTH_NOISE_DEG)
    return detect_outliers(sc.azimuth_deg, sc.t_s, method=name, params=params)


def score(mask: np.ndarray, sc: Scenario) -> dict[str, int]:
    """Counts: true/false positives, misses, split by isolated / run and turn."""
    run = np.zeros_like(sc.wild)
    for i0, length in sc.events:
        if length > 1:
            run[i0 : i0 + length] = True
    iso = sc.wild & ~run
    return {
        "tp": int((mask & sc.wild).sum()),
        "fp": int((mask & ~sc.wild).sum()),
        "fn": int((~mask & sc.wild).sum()),
        "tp_iso": int((mask & iso).sum()),
        "n_iso": int(iso.sum()),
        "tp_run": int((mask & run).sum()),
        "n_run": int(run.sum()),
        "fp_turn": int((mask & ~sc.wild & sc.turn).sum()),
    }


def table_lines(sc: Scenario, masks: dict[str, np.ndarray]) -> list[str]:
    """The paper's Table 2 kind: each injected wild point, '+' removed / '-' kept, (T/F)."""
    names = list(masks)
    lines = ["  t/s    offset/deg  event   " + "  ".join(f"{n:>10}" for n in names)]
    for i0, length in sc.events:
        for i in range(i0, i0 + length):
            kind = "isolated" if length == 1 else f"run of {length}"
            cells = []
            for n in names:
                removed = bool(masks[n][i])
                cells.append(f"{('+(T)' if removed else '-(F)'):>10}")
            off = sc.azimuth_deg[i] - sc.truth_deg[i]
            lines.append(f"{sc.t_s[i]:6.1f}  {off:+9.2f}   {kind:9s}" + "  ".join(cells))
    fps = "  ".join(f"{int((masks[n] & ~sc.wild).sum()):>10d}" for n in names)
    lines.append(f"  false removals (+(F)) of true samples:  {fps}")
    fps_turn = "  ".join(f"{int((masks[n] & ~sc.wild & sc.turn).sum()):>10d}" for n in names)
    lines.append(f"  of which during the turn (40-55 s):     {fps_turn}")
    return lines


def evaluate(seeds: int, first_seed: int = 0, params: OutlierParams | None = None) -> dict[str, dict[str, float]]:
    """Precision, recall (all, isolated, runs) and false removals over many seeds."""
    totals: dict[str, dict[str, int]] = {m: {} for m in METHODS}
    for seed in range(first_seed, first_seed + seeds):
        sc = make_scenario(seed)
        for m in METHODS:
            sc_counts = score(run_method(m, sc, params), sc)
            for key, val in sc_counts.items():
                totals[m][key] = totals[m].get(key, 0) + val
    out = {}
    for m, c in totals.items():
        out[m] = {
            "precision": c["tp"] / max(c["tp"] + c["fp"], 1),
            "recall": c["tp"] / max(c["tp"] + c["fn"], 1),
            "recall_isolated": c["tp_iso"] / max(c["n_iso"], 1),
            "recall_runs": c["tp_run"] / max(c["n_run"], 1),
            "false_per_series": c["fp"] / seeds,
            "false_in_turn_per_series": c["fp_turn"] / seeds,
        }
    return out


def plot(sc: Scenario, masks: dict[str, np.ndarray], path: str) -> None:
    """PNG of the series, the truth and each method's removals."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(len(masks), 1, figsize=(10, 2.6 * len(masks)), sharex=True)
    for ax, (name, mask) in zip(np.atleast_1d(axes), masks.items()):
        ax.plot(sc.t_s, sc.azimuth_deg, ".", ms=2, color="0.6", label="measured")
        ax.plot(sc.t_s, sc.truth_deg, "-", lw=0.8, color="k", label="truth")
        ax.plot(sc.t_s[sc.wild], sc.azimuth_deg[sc.wild], "o", mfc="none", color="tab:blue", label="injected wild")
        ax.plot(sc.t_s[mask], sc.azimuth_deg[mask], "x", color="tab:red", label="removed")
        ax.axvspan(40.0, 55.0, color="tab:orange", alpha=0.1)
        ax.set_ylabel("azimuth / deg")
        ax.set_title(name)
    np.atleast_1d(axes)[0].legend(loc="best", fontsize=7)
    np.atleast_1d(axes)[-1].set_xlabel("t / s")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Flags of ``radar-fusion outliers``."""
    parser.add_argument("--seeds", type=int, default=200, help="number of random realisations (default 200)")
    parser.add_argument("--first-seed", type=int, default=0, help="first seed; the table uses this one")
    parser.add_argument("--png", default=None, help="write a PNG of the table's realisation here")
    parser.add_argument("--window", type=int, default=OutlierParams.window, help="v of eq. 1")
    parser.add_argument("--k", type=int, default=OutlierParams.k, help="k of the k-mean distance")
    parser.add_argument(
        "--of-sigma", type=float, default=OutlierParams.of_sigma, help="c of the rule OF > median + c * 1.4826 * MAD"
    )
    parser.add_argument(
        "--edge-quantile",
        type=float,
        default=OutlierParams.edge_quantile,
        help="quantile of W above which samples are edge points",
    )


def run(args: argparse.Namespace) -> int:
    """Print the table for one seed and the summary over args.seeds seeds."""
    params = OutlierParams(window=args.window, k=args.k, of_sigma=args.of_sigma, edge_quantile=args.edge_quantile)
    sc = make_scenario(args.first_seed)
    masks = {m: run_method(m, sc, params) for m in METHODS}
    print(
        f"Hu 2013 reproduction: {N_SAMPLES} azimuth samples at {RATE_HZ:g} Hz, 0-{sc.t_s[-1]:.1f} s, "
        f"accelerating turn 40-55 s (rate peaks at {TURN_TIME_S} s), noise {AZIMUTH_NOISE_DEG} deg, "
        f"seed {args.first_seed}"
    )
    print("'+' removed, '-' kept; (T) correct, (F) wrong")
    for line in table_lines(sc, masks):
        print(line)
    print()
    summary = evaluate(args.seeds, args.first_seed, params)
    print(f"Over {args.seeds} seeds ({sum(n for _, n in WILD_EVENTS)} wild samples per series):")
    print(
        f"{'method':>11} {'precision':>9} {'recall':>7} {'rec.isol':>8} {'rec.runs':>8} "
        f"{'false/series':>12} {'false in turn':>13}"
    )
    for m, r in summary.items():
        print(
            f"{m:>11} {r['precision']:9.3f} {r['recall']:7.3f} {r['recall_isolated']:8.3f} "
            f"{r['recall_runs']:8.3f} {r['false_per_series']:12.2f} {r['false_in_turn_per_series']:13.2f}"
        )
    if args.png:
        plot(sc, masks, args.png)
        print(f"wrote {args.png}")
    return 0


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_arguments(parser)
    return run(parser.parse_args())


if __name__ == "__main__":
    raise SystemExit(main())
