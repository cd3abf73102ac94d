"""The engine's track state as bytes, for a restart that keeps its tracks (issue 13 item 3).

A restarted daemon without it starts its ids again at 1 and re-initiates every track
(the README's fault section). With ``serve --state-dir DIR`` the daemon writes this
state after each period it publishes, and a new daemon on the same configuration reads
it back before its first plot: the same tracks with the same ids, predicted on from
where they were, and the radars' registration estimates.

Format (version 1): one msgpack map

    v               1
    kind            "radar-fusion-engine-state"
    radar_ids       the configuration's radar ids in order (the ``sources`` bits and the
                    registration rows are indexed by them)
    n_models        the IMM's model count (0: the Singer filter)
    track_t_s       reference time of the newest closed period, UTC epoch s
    period_s        the period length (s) the period indices count: a state of another
                    period_s is refused (and, without it, one whose next period lies more
                    than an hour from track_t_s)
    next_period     the first period not yet closed (plots before it are late)
    next_id         the next track id to hand out
    tracks          {column name: [dtype, shape, raw bytes]}, TrackTable's columns
    address_memory  [[mode_s, id, [x_m, y_m], [[cov]], t_s], ...]: recently ended tracks
    registration    {name: [dtype, shape, raw bytes]} of the estimator's arrays, its
                    counters, t_last_s and next_update_t_s (when it next learns); the
                    correction the tracks are consistent with is the estimator's at the
                    end of the state's period (engine._follow_registration), so a
                    restored engine takes it from the restored estimator
    live_gate       the wild-plot gate's window per radar track (tracking/live_gate.py),
                    {"arrays": {name: [dtype, shape, bytes]} of the rows in use, "last_sweep_t",
                    "counts"}; nil with the gate off
    layer_wind      {"mps": [...], "t_s": [...], "layer_ft"}: the wind of each height layer,
                    when it was last taken, and the layers' height (engine._layer_winds; a
                    state of other layers is read without it)
    period          the newest closed period (None before the first)
    epoch, instance with [redundancy] on, the active that published it (else None)

The same bytes are what an active of a hot-standby pair publishes on
``<prefix>/fusion/state`` after each period (redundancy.py; ``wire.FusionState`` documents
the envelope for the contract), and a standby applies them with ``replace=True``: its
tracks become the active's, and the plots it buffered for periods the active has
closed are dropped.

With all of it, an engine restored from a state and fed the same plots closes the same
periods with bit-identical tracks (tests/test_state.py). What is not kept, and why it
does not matter for long: the plots buffered for the period that was open (lost with the
process, as on any restart; a standby has them itself), the clock check and the counters
(health starts again with the new process's ``uptime_s``), and the safety nets' open
alerts (a restarted daemon raises them again as new; a standby's child has them).
A state written before ``live_gate``, the registration's times or ``layer_wind`` were kept
(the same version) is read without them: the gate relearns within a few scans, the layers'
wind within minutes (a track's own wind is a track column). The tracks' sensitivity to the
radars' biases (``bias_sens``) of a state written with ``[registration] track_innovations``
set otherwise, or before it was kept, is read as 0: each track learns its own again from its
next updates.
"""

from __future__ import annotations

import math
import os
import tempfile
from pathlib import Path
from typing import TYPE_CHECKING, Any

import msgpack
import numpy as np

from ..tracking.track_management import OPTIONAL_FIELDS

if TYPE_CHECKING:
    from ..tracking.live_gate import LiveOutlierGate
    from .engine import Engine

__all__ = [
    "STATE_FILE",
    "STATE_VERSION",
    "StateMismatch",
    "decode",
    "load_state",
    "restore",
    "save_state",
    "set_state_aside",
    "snapshot",
]

STATE_VERSION = 1
STATE_KIND = "radar-fusion-engine-state"
#: the file name inside ``--state-dir``
STATE_FILE = "engine-state.msgpack"

_REGISTRATION_ARRAYS = ("information", "information_vector", "bias", "sigma", "effective_plots")
_REGISTRATION_COUNTS = ("updates", "plots_used", "plots_gated")
#: counts added later: a state without them starts them at 0
_OPTIONAL_REGISTRATION_COUNTS = ("innovations_used", "innovations_gated")


class StateMismatch(ValueError):
    """A saved state that does not belong to this configuration (or is not a state)."""


def _pack_array(a: np.ndarray) -> list[Any]:
    a = np.ascontiguousarray(a)
    return [a.dtype.str, list(a.shape), a.tobytes()]


def _unpack_array(item: Any) -> np.ndarray:
    dtype, shape, raw = item
    return np.frombuffer(raw, dtype=np.dtype(dtype)).reshape(shape).copy()


def snapshot(engine: Engine, period: int | None = None, epoch: int | None = None, instance: str | None = None) -> bytes:
    """The engine's track state (module docstring) as msgpack bytes; ``period`` is the
    newest closed period, ``epoch`` and ``instance`` the active's stamp."""
    tr = engine.tracks
    reg = engine.registration
    memory = [[a, i, xy.tolist(), cov.tolist(), t] for a, i, xy, cov, t in engine.address_memory.entries()]
    state = {
        "v": STATE_VERSION,
        "kind": STATE_KIND,
        "radar_ids": list(engine.radar_ids),
        "n_models": tr.n_models,
        "track_t_s": engine.track_t_s,
        "period_s": engine.buffer.period_s,
        "next_period": engine.buffer.next_period,
        "period": period,
        "next_id": tr.next_id,
        "tracks": {name: _pack_array(getattr(tr, name)) for name in tr._fields},
        "address_memory": memory,
        "registration": {
            **{name: _pack_array(getattr(reg, name)) for name in _REGISTRATION_ARRAYS},
            **{name: int(getattr(reg, name)) for name in _REGISTRATION_COUNTS + _OPTIONAL_REGISTRATION_COUNTS},
            "t_last_s": reg.t_last_s,
            "next_update_t_s": engine._reg_next_t_s if math.isfinite(engine._reg_next_t_s) else None,
        },
        "live_gate": _pack_gate(engine.outlier_gate),
        "layer_wind": {
            "mps": _pack_array(engine.layer_wind_mps),
            "t_s": _pack_array(engine.layer_wind_t_s),
            "layer_ft": engine.imm.params.wind_layer_ft if engine.imm is not None else None,
        },
        "epoch": epoch,
        "instance": instance,
    }
    return bytes(msgpack.packb(state, use_bin_type=True))


def decode(data: bytes) -> dict[str, Any]:
    """The state map of :func:`snapshot`'s bytes (not checked against a configuration);
    raises :class:`StateMismatch` when the bytes are not a state."""
    try:
        state = msgpack.unpackb(data, raw=False)
    except Exception as exc:  # any decoding error: not a state file
        raise StateMismatch(f"not a radar-fusion state: {exc}") from exc
    if not isinstance(state, dict) or state.get("kind") != STATE_KIND:
        raise StateMismatch("not a radar-fusion state")
    return state


def _pack_gate(gate: LiveOutlierGate | None) -> dict[str, Any] | None:
    if gate is None:
        return None
    st = gate.state()
    st["arrays"] = {name: _pack_array(a) for name, a in st["arrays"].items()}
    return st


def _unpack_gate(engine: Engine, packed: Any) -> LiveOutlierGate | None:
    """A new gate of the engine's parameters holding the state's windows (None: keep the
    engine's own, a state without them or the gate off)."""
    if packed is None or engine.outlier_gate is None:
        return None
    from ..tracking.live_gate import LiveOutlierGate

    gate = LiveOutlierGate.from_params(engine.settings.outliers)
    gate.load({**packed, "arrays": {name: _unpack_array(a) for name, a in packed["arrays"].items()}})
    return gate


#: how far the first open period of a state may lie from its newest closed period's time
_PERIOD_SLACK_S = 3600.0
#: event times a state may carry: 1970 to 2286 (UTC epoch seconds)
_LATEST_T_S = 1e10


def _time_or_none(value: Any, name: str) -> float | None:
    """A state's event time (epoch seconds) or None; anything else is a damaged state."""
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, int | float) or not 0.0 <= value <= _LATEST_T_S:
        raise StateMismatch(f"a damaged state: {name} {value!r}")
    return float(value)


def _next_period(state: dict[str, Any], engine: Engine, track_t_s: float | None) -> int | None:
    """The state's first open period on this engine's grid. A period is an index of
    ``period_s``: a state of another period (or a damaged index) would put every plot in
    the past or decades ahead, so it is refused."""
    period_s = float(engine.buffer.period_s)
    saved_period_s = state.get("period_s")
    if saved_period_s is not None and saved_period_s != period_s:
        raise StateMismatch(f"state of {saved_period_s!r} s periods, configured {period_s} s")
    value = state["next_period"]
    if value is None:
        return None
    if type(value) is not int or not 0 <= value * period_s <= _LATEST_T_S:
        raise StateMismatch(f"a damaged state: next_period {value!r}")
    if saved_period_s is None and track_t_s is not None and abs(value * period_s - track_t_s) > _PERIOD_SLACK_S:
        # a state from before period_s was saved, of another period: its index is not this grid's
        raise StateMismatch(
            f"state's next period starts at {value * period_s:.0f} s, its tracks are of {track_t_s:.0f} s: "
            f"a state of another period_s than {period_s} s"
        )
    return value


def restore(engine: Engine, data: bytes | dict[str, Any], replace: bool = False) -> int:
    """Load a :func:`snapshot` (bytes, or :func:`decode`'s map) into an engine of the same
    configuration; returns the number of tracks restored. Without ``replace`` only into a
    new engine (before its first plot: a restart); with it, over whatever the engine holds
    (a standby applying its active's state): the tracks, ids, registration and address
    memory become the state's, and buffered plots of the periods it closed are dropped.
    Raises :class:`StateMismatch` when the bytes are not a state of this version, or of
    other radars or another filter, and then leaves the engine as it was."""
    state = decode(data) if isinstance(data, bytes | bytearray) else data
    if state.get("v") != STATE_VERSION:
        raise StateMismatch(f"state version {state.get('v')!r}, this daemon reads {STATE_VERSION}")
    if state.get("radar_ids") != list(engine.radar_ids):
        raise StateMismatch(f"state of radars {state.get('radar_ids')}, configured {engine.radar_ids}")
    tr = engine.tracks
    if state.get("n_models") != tr.n_models:
        raise StateMismatch(f"state of a filter with {state.get('n_models')} models, configured {tr.n_models}")
    if not replace and (len(tr) or engine.periods_closed):
        raise StateMismatch("restore into a new engine only (it has tracks or closed periods)")
    try:
        columns = {name: _unpack_array(item) for name, item in state["tracks"].items()}
        registration = {name: _unpack_array(state["registration"][name]) for name in _REGISTRATION_ARRAYS}
        counts = {name: int(state["registration"][name]) for name in _REGISTRATION_COUNTS}
        counts |= {name: int(state["registration"].get(name, 0)) for name in _OPTIONAL_REGISTRATION_COUNTS}
        memory = [
            (int(a), int(track_id), np.asarray(xy, float).reshape(2), np.asarray(cov, float).reshape(2, 2), float(t))
            for a, track_id, xy, cov, t in state["address_memory"]
        ]
        next_id = int(state["next_id"])
        track_t_s = _time_or_none(state["track_t_s"], "track_t_s")
        next_period = _next_period(state, engine, track_t_s)
        t_last_s = _time_or_none(state["registration"].get("t_last_s"), "registration t_last_s")
        next_update_t_s = _time_or_none(state["registration"].get("next_update_t_s"), "registration next_update_t_s")
        gate = _unpack_gate(engine, state.get("live_gate"))
        # the layers' wind (engine._air_velocity_and_wind); a state from before it, or of
        # other layers: learnt again from the reports within minutes
        layer_wind: dict[str, Any] = state.get("layer_wind") or {}
        same_layers = engine.imm is not None and layer_wind.get("layer_ft") == engine.imm.params.wind_layer_ft
        wind_mps = _unpack_array(layer_wind["mps"]) if same_layers else None
        wind_t_s = _unpack_array(layer_wind["t_s"]) if same_layers else None
    except StateMismatch:
        raise
    except Exception as exc:  # any field that does not read as what it should be
        raise StateMismatch(f"a damaged state: {type(exc).__name__}: {exc}") from exc
    # every check before anything is changed: a refused state leaves the engine as it was
    n = {c.shape[0] for c in columns.values()}
    if len(n) == 1:  # a state from before a column was added: that column's fill
        for name in OPTIONAL_FIELDS:
            if name not in columns and name in tr._fields:
                shape, dtype, fill = tr._fields[name]
                columns[name] = np.full((next(iter(n)),) + shape, fill, dtype=dtype)
        # the tracks' sensitivity to the radars' biases is kept only with the two-stage
        # registration on (TrackTable.n_radars); a state of the other setting: none known
        sens = columns.get("bias_sens")
        if sens is not None and sens.shape[1:] != tr._fields["bias_sens"][0]:
            shape, dtype, fill = tr._fields["bias_sens"]
            columns["bias_sens"] = np.full((sens.shape[0],) + shape, fill, dtype=dtype)
    if set(columns) != set(tr._fields):
        raise StateMismatch(f"state columns {sorted(columns)} differ from the track table's")
    if len(n) != 1:  # (the columns filled in above have the others' length)
        raise StateMismatch("state columns of different lengths")
    for name, (shape, _, _) in tr._fields.items():
        if columns[name].shape[1:] != shape:
            raise StateMismatch(f"state column {name} of shape {columns[name].shape[1:]}, expected {shape}")
    reg = engine.registration
    for name, value in registration.items():
        if value.shape != getattr(reg, name).shape:
            raise StateMismatch(f"registration {name} of shape {value.shape}, expected {getattr(reg, name).shape}")
    for name, (_, dtype, _) in tr._fields.items():
        setattr(tr, name, columns[name].astype(dtype, copy=False))
    tr.n = n.pop()
    tr.next_id = next_id
    engine.track_t_s = track_t_s
    if next_period is not None:
        engine.buffer.discard_before(next_period)
    if replace:
        engine.address_memory.clear()
    engine.address_memory.load(memory)
    for name, value in registration.items():
        setattr(reg, name, value)
    for name, count in counts.items():
        setattr(reg, name, count)
    reg.refresh_covariance()  # the correction's empirical Bayes step reads it
    reg.t_last_s = t_last_s
    # the correction the tracks are consistent with: the estimator's when the state was taken
    # (engine._follow_registration took it at the end of that period)
    engine._reg_applied = reg.correction()
    engine._reg_next_t_s = -math.inf if next_update_t_s is None else next_update_t_s
    if gate is not None:
        engine.outlier_gate = gate
    if wind_mps is not None and wind_t_s is not None and wind_mps.shape == engine.layer_wind_mps.shape:
        engine.layer_wind_mps, engine.layer_wind_t_s = wind_mps.astype(float), wind_t_s.astype(float)
    return tr.n


def save_state(engine: Engine, directory: str | os.PathLike[str], data: bytes | None = None) -> Path:
    """Write the snapshot (or ``data``, a state already packed, e.g. the one a standby
    applied) to ``directory/STATE_FILE`` atomically (a temporary file renamed over it): a
    daemon killed while writing leaves the previous state whole."""
    path = Path(directory) / STATE_FILE
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=".engine-state-", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(snapshot(engine) if data is None else data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path


def load_state(engine: Engine, directory: str | os.PathLike[str]) -> int | None:
    """Restore from ``directory/STATE_FILE`` if there is one; returns the tracks restored,
    or None without a file. A file of another configuration raises :class:`StateMismatch`."""
    path = Path(directory) / STATE_FILE
    if not path.exists():
        return None
    return restore(engine, path.read_bytes())


def set_state_aside(directory: str | os.PathLike[str]) -> Path | None:
    """Rename ``directory/STATE_FILE`` to ``STATE_FILE.rejected-<UTC time>`` (a state this
    configuration refused), so that the next save does not overwrite what an operator may
    want to look at; returns the new path, or None without a file."""
    import time

    path = Path(directory) / STATE_FILE
    if not path.exists():
        return None
    aside = path.with_name(f"{STATE_FILE}.rejected-{time.strftime('%Y%m%dT%H%M%SZ', time.gmtime())}")
    os.replace(path, aside)
    return aside
