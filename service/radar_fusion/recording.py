"""The recording file: what the bus carried, in order, with each message's time.

Format (msgpack stream, optionally gzip-compressed when the file name ends in ``.gz``):
first a header map ``{"format": "radar-fusion-recording", "v": 1, "meta": {...}}``, then
one array per message: ``[t_s, key, payload]`` where ``t_s`` is the message's time
(event time for simulated data, receive time for recorded data; UTC epoch seconds),
``key`` is the Zenoh key relative to the prefix (``radar/r1/plots``,
``fusion/tracks``, ...), and ``payload`` the message's exact bytes. Recording what the
replay tool sends gives back the same payloads byte for byte.
"""

from __future__ import annotations

import gzip
import logging
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any, BinaryIO, Literal

import msgpack

log = logging.getLogger("radar_fusion.recording")

FORMAT = "radar-fusion-recording"


@dataclass(frozen=True)
class Record:
    t_s: float
    key: str
    payload: bytes


def _open(path: Path, mode: Literal["r", "w"]) -> BinaryIO | gzip.GzipFile:
    binary_mode: Literal["rb", "wb"] = "rb" if mode == "r" else "wb"
    if str(path).endswith(".gz"):
        return gzip.open(path, binary_mode, compresslevel=3)
    return open(path, binary_mode)


class RecordingWriter:
    """Append messages to a recording file. Use as a context manager."""

    def __init__(self, path: str | Path, meta: dict[str, Any] | None = None):
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._f = _open(self.path, "w")
        self._packer = msgpack.Packer(use_bin_type=True)
        self._f.write(self._packer.pack({"format": FORMAT, "v": 1, "meta": meta or {}}))
        self.count = 0

    def write(self, t_s: float, key: str, payload: bytes) -> None:
        self._f.write(self._packer.pack([float(t_s), key, bytes(payload)]))
        self.count += 1

    def close(self) -> None:
        if not self._f.closed:
            self._f.close()

    def __enter__(self) -> RecordingWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _reader(f: BinaryIO | gzip.GzipFile, path: str | Path) -> tuple[msgpack.Unpacker, dict[str, Any]]:
    """An unpacker over an open recording and its header; ValueError when it is not one."""
    unpacker = msgpack.Unpacker(f, raw=False, max_bin_len=1 << 26)
    header = next(unpacker, None)  # an empty file: not a recording
    if not isinstance(header, dict) or header.get("format") != FORMAT:
        raise ValueError(f"{path}: not a radar-fusion recording")
    return unpacker, header


def read_header(path: str | Path) -> dict[str, Any]:
    with _open(Path(path), "r") as f:
        return _reader(f, path)[1]


def read_recording(path: str | Path) -> Iterator[Record]:
    """Yield the records of a recording file in file order.

    A file cut short (a recorder killed, a copy interrupted) gives its whole records and
    then a warning on the log that names where it ends and how many records were read:
    msgpack's reader stopped there without a word, and replay, evaluate and clean went on
    with half a recording as if it were all. A record that is not (t, key, payload)
    raises ValueError."""
    n = 0
    with _open(Path(path), "r") as f:
        unpacker, _ = _reader(f, path)
        for item in unpacker:
            if not (isinstance(item, list | tuple) and len(item) == 3 and isinstance(item[1], str)):
                raise ValueError(f"{path}: record {n + 1} is not (time, key, payload)")
            t_s, key, payload = item
            yield Record(float(t_s), key, payload)
            n += 1
        read, size = unpacker.tell(), f.tell()
    if read != size:
        log.warning(
            "%s: cut short: %d whole records read, %d bytes of an incomplete one at its end (byte %d of %d)",
            path,
            n,
            size - read,
            read,
            size,
        )
