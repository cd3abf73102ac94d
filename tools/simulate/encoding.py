"""msgpack encoding of PlotBatch messages, vectorised over plots: the bytes a radar
front-end publishes, without building one dict per plot (a benchmark scenario has
millions of plots)."""

from __future__ import annotations

import msgpack
import numpy as np

from radar_fusion import wire

from .radar_model import KIND_CMB, KIND_MODES, KIND_PSR, KIND_SSR


def _packed_key(name: str) -> np.ndarray:
    return np.frombuffer(msgpack.packb(name), np.uint8)


_HEX_ASCII = np.frombuffer(b"0123456789ABCDEF", np.uint8)
_KIND3 = np.zeros((5, 4), np.uint8)
for _code, _name in ((KIND_PSR, "psr"), (KIND_SSR, "ssr"), (KIND_CMB, "cmb")):
    _KIND3[_code] = np.frombuffer(msgpack.packb(_name), np.uint8)


def pack_plots(cols: dict[str, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """msgpack-encode every plot as a map, vectorised over plots.

    Each plot is built from fixed-width byte blocks (key + value), one per field, and a
    mask drops the blocks of absent fields (``fl``, the Mode S BDS 5,0 ones, ``roll_deg``,
    ``ground_speed_mps``, ``track_angle_deg``, and the BDS 6,0 ones, ``magnetic_heading_deg``,
    ``indicated_airspeed_mps``, NaN or not given; ``mode3a``/``mode_s``/``track_no`` -1).
    Floats are float64 (0xcb), ``mode3a`` uint16 (0xcd), ``track_no`` uint32 (0xce),
    strings fixstr: valid msgpack that decodes to the same values as :func:`wire.encode`
    of the same dict. Returns (bytes as uint8, offsets (n+1,)).
    """
    n = cols["t_s"].shape[0]
    blocks: list[tuple[np.ndarray, np.ndarray | None]] = []

    def block(key: str, tag: int | None, value: np.ndarray, present: np.ndarray | None) -> None:
        kb = _packed_key(key)
        width = kb.size + (1 if tag is not None else 0) + value.shape[1]
        b = np.empty((n, width), np.uint8)
        b[:, : kb.size] = kb
        o = kb.size
        if tag is not None:
            b[:, o] = tag
            o += 1
        b[:, o:] = value
        blocks.append((b, present))

    def f64(a):
        return np.ascontiguousarray(a, dtype=">f8").view(np.uint8).reshape(n, 8)

    fl_ok = np.isfinite(cols["fl"])
    m3_ok = cols["mode3a"] >= 0
    ms_ok = cols["mode_s"] >= 0
    tn_ok = cols["track_no"] >= 0
    is5 = cols["kind"] == KIND_MODES
    # the optional float fields after kind (wire v1 extensions), in the model's order
    extra = {
        k: cols[k]
        for k in ("roll_deg", "ground_speed_mps", "track_angle_deg", "magnetic_heading_deg", "indicated_airspeed_mps")
        if cols.get(k) is not None
    }
    extra_ok = {k: np.isfinite(v) for k, v in extra.items()}
    count = 4 + fl_ok.astype(np.uint8) + m3_ok + ms_ok + tn_ok + sum(extra_ok.values(), np.zeros(n, np.uint8))
    blocks.append(((0x80 | count).astype(np.uint8).reshape(n, 1), None))
    block("t", 0xCB, f64(cols["t_s"]), None)
    block("range_m", 0xCB, f64(cols["range_m"]), None)
    block("azimuth_deg", 0xCB, f64(cols["azimuth_deg"]), None)
    block("fl", 0xCB, f64(np.where(fl_ok, cols["fl"], 0.0)), fl_ok)
    m3 = np.where(m3_ok, cols["mode3a"], 0).astype(">u2").view(np.uint8).reshape(n, 2)
    block("mode3a", 0xCD, m3, m3_ok)
    ms = np.where(ms_ok, cols["mode_s"], 0)
    digits = (ms[:, None] >> np.array([20, 16, 12, 8, 4, 0])) & 0xF
    block("mode_s", 0xA6, _HEX_ASCII[digits], ms_ok)
    tn = np.where(tn_ok, cols["track_no"], 0).astype(">u4").view(np.uint8).reshape(n, 4)
    block("track_no", 0xCE, tn, tn_ok)
    block("kind", None, _KIND3[np.where(is5, 0, cols["kind"])], ~is5)
    block("kind", None, np.broadcast_to(np.frombuffer(msgpack.packb("modes"), np.uint8), (n, 6)), is5)
    for k, v in extra.items():
        block(k, 0xCB, f64(np.where(extra_ok[k], v, 0.0)), extra_ok[k])
    data = np.concatenate([b for b, _ in blocks], axis=1)
    mask = np.concatenate(
        [np.ones(b.shape, bool) if p is None else np.broadcast_to(p[:, None], b.shape) for b, p in blocks], axis=1
    )
    lengths = mask.sum(axis=1)
    offsets = np.concatenate([[0], np.cumsum(lengths)]).astype(np.intp)
    return data[mask], offsets


def _array_header(n: int) -> bytes:
    if n < 16:
        return bytes([0x90 | n])
    if n < 1 << 16:
        return b"\xdc" + n.to_bytes(2, "big")
    return b"\xdd" + n.to_bytes(4, "big")


def batch_payload(radar_id: str, seq: int, plot_bytes: bytes, n: int) -> bytes:
    head = msgpack.packb({"v": wire.WIRE_VERSION, "radar_id": radar_id, "seq": seq, "plots": []})
    # the empty array is the last byte (0x90) of ``head``: replace it with the plots
    return head[:-1] + _array_header(n) + plot_bytes
