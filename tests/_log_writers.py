"""Minimal writers of the flight-log formats, for tests: PX4 ULog and ArduPilot DataFlash.

Written from the formats' documentation, not with the readers' code:

* ULog (docs.px4.io, "ULog File Format"): a 16-byte header (``ULog`` magic
  ``55 4c 6f 67 01 12 35``, version byte, start timestamp uint64 us), a flag-bits
  message ``B``, then format ``F`` (``name:type field;...``), subscription ``A``
  (multi_id, msg_id, name) and data ``D`` (msg_id, packed fields, the first being
  ``uint64_t timestamp``) messages, each behind a ``uint16 size, uint8 type`` header.
* DataFlash (ardupilot.org, "Onboard Message Log Messages"): messages behind
  ``0xA3 0x95 type``; type 128 ``FMT`` (Type B, Length B, Name n, Format N,
  Columns Z) describes every other type, including itself.
"""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np

_ULOG_TYPES = {"uint64_t": "Q", "float": "f", "double": "d", "int32_t": "i", "uint8_t": "B", "int64_t": "q"}


def write_ulog(path: Path, topics: dict[str, tuple[list[tuple[str, str]], np.ndarray, np.ndarray]]) -> Path:
    """``topics``: name -> (fields [(type, name)] after the timestamp, timestamps us (n,), values (n, k))."""
    out = bytearray(b"ULog\x01\x12\x35" + bytes([1]) + struct.pack("<Q", 0))

    def msg(kind: bytes, payload: bytes) -> None:
        out.extend(struct.pack("<HB", len(payload), kind[0]) + payload)

    msg(b"B", bytes(8) + bytes(8) + bytes(24))
    ids = {}
    for i, (name, (fields, _, _)) in enumerate(topics.items()):
        spec = "uint64_t timestamp;" + "".join(f"{t} {n};" for t, n in fields)
        msg(b"F", f"{name}:{spec}".encode())
        ids[name] = i
    for name, i in ids.items():
        msg(b"A", struct.pack("<BH", 0, i) + name.encode())
    events = []
    for name, (fields, t, v) in topics.items():
        fmt = "<Q" + "".join(_ULOG_TYPES[ty] for ty, _ in fields)
        for k in range(len(t)):
            events.append((k, ids[name], struct.pack(fmt, int(t[k]), *np.atleast_1d(v[k]))))
    # in each topic's own order (a test may put a sample out of time order), topics interleaved
    for _, i, payload in sorted(events, key=lambda e: (e[0], e[1])):
        msg(b"D", struct.pack("<H", i) + payload)
    path.write_bytes(bytes(out))
    return path


_DF_SIZES = {"Q": 8, "f": 4, "d": 8, "I": 4, "i": 4, "B": 1, "b": 1, "h": 2, "H": 2, "n": 4, "N": 16, "Z": 64}


def write_dataflash(path: Path, messages: dict[str, tuple[list[str], str, np.ndarray]]) -> Path:
    """``messages``: name -> (columns, format letters (TimeUS first: 'Q...'), rows (n, k) with TimeUS in column 0)."""
    out = bytearray()

    def fmt_msg(type_id: int, name: str, fmt: str, cols: str) -> None:
        length = 3 + sum(_DF_SIZES[c] for c in fmt)
        out.extend(b"\xa3\x95\x80" + struct.pack("<BB4s16s64s", type_id, length, name.encode(), fmt.encode(),
                                                 cols.encode()))

    fmt_msg(128, "FMT", "BBnNZ", "Type,Length,Name,Format,Columns")
    ids = {}
    for i, (name, (cols, fmt, _)) in enumerate(messages.items()):
        ids[name] = 129 + i
        fmt_msg(ids[name], name, fmt, ",".join(cols))
    events = []
    for name, (_, fmt, rows) in messages.items():
        for row in rows:
            vals = [int(row[0])] + [float(x) for x in row[1:]]
            events.append((int(row[0]), ids[name], struct.pack("<" + fmt, *vals)))
    for _, i, payload in sorted(events, key=lambda e: e[0]):  # stable: each type keeps its order
        out.extend(b"\xa3\x95" + bytes([i]) + payload)
    path.write_bytes(bytes(out))
    return path
