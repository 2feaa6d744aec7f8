"""PX4 ULog reader (pyulog): topic fields with their timestamps, seconds."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from uavsim.logs.errors import LogError
from uavsim.logs.errors import hint as _hint

__all__ = ["read"]


def read(path: Path, wanted: dict[str, list[str]]) -> dict[str, tuple[np.ndarray, dict[str, np.ndarray]]]:
    """``{topic: (t s, {field: values})}`` of instance 0 of each wanted topic."""
    try:
        from pyulog import ULog
    except ImportError:
        raise LogError("reading ULog needs pyulog: pip install 'uavsim[logs]'") from None
    try:
        ulog = ULog(str(path), list(wanted), parse_header_only=False)
    except Exception as exc:  # noqa: BLE001 - pyulog raises anything on a damaged file
        raise LogError(f"{path}: not a readable ULog ({type(exc).__name__}: {exc})") from None
    found = {d.name: d for d in sorted(ulog.data_list, key=lambda d: -d.multi_id)}  # instance 0 wins
    out = {}
    for topic, fields in wanted.items():
        if topic not in found:
            known = sorted({m.name for m in ulog.message_formats.values()} if hasattr(ulog, "message_formats")
                           else ulog.message_formats)
            raise LogError(f"{path}: no topic {topic!r} logged ({_hint(topic, known)}the log has "
                           f"{len(known)} topics; see `ulog_info {path.name}`)")
        d = found[topic]
        if "timestamp" not in d.data:
            raise LogError(f"{path}: topic {topic!r} has no timestamp field")
        cols = {}
        for f in fields:
            if f not in d.data:
                keys = [k for k in d.data if k != "timestamp"]
                raise LogError(f"{path}: topic {topic!r} has no field {f!r} ({_hint(f, keys)}fields: "
                               f"{', '.join(keys[:12])}{', ...' if len(keys) > 12 else ''})")
            cols[f] = np.asarray(d.data[f], dtype=np.float64)
        out[topic] = (np.asarray(d.data["timestamp"], dtype=np.float64) * 1e-6, cols)
    return out
