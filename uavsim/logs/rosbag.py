"""ROS 2 bag reader (rosbags): message fields by attribute path, timed by their header stamp (else the bag's)."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from uavsim.logs.errors import LogError, hint

__all__ = ["read"]

_PART = re.compile(r"^([A-Za-z_][A-Za-z0-9_]*)(?:\[(\d+)\])?$")


def _get(msg, field: str):
    v = msg
    for part in field.split("."):
        m = _PART.match(part)
        if not m:
            raise AttributeError(part)
        v = getattr(v, m.group(1))
        if m.group(2) is not None:
            v = v[int(m.group(2))]
    return float(v)


def read(path: Path, wanted: dict[str, list[str]]) -> dict[str, tuple[np.ndarray, dict[str, np.ndarray]]]:
    """``{topic: (t s, {field: values})}``; ``field`` is an attribute path such as ``pose.position.z``."""
    try:
        from rosbags.highlevel import AnyReader
    except ImportError:
        raise LogError("reading ROS 2 bags needs rosbags: pip install 'uavsim[logs]'") from None
    bag = path.parent if path.suffix in (".db3", ".mcap") else path
    out = {}
    try:
        with AnyReader([bag]) as reader:
            topics = {c.topic for c in reader.connections}
            for topic, fields in wanted.items():
                if topic not in topics:
                    raise LogError(f"{path}: no topic {topic!r} in the bag ({hint(topic, sorted(topics))}topics: "
                                   f"{', '.join(sorted(topics)[:10])})")
                conns = [c for c in reader.connections if c.topic == topic]
                t, rows = [], []
                for conn, stamp, raw in reader.messages(connections=conns):
                    msg = reader.deserialize(raw, conn.msgtype)
                    head = getattr(msg, "header", None)
                    t.append(head.stamp.sec + 1e-9 * head.stamp.nanosec if head is not None else 1e-9 * stamp)
                    try:
                        rows.append([_get(msg, f) for f in fields])
                    except (AttributeError, IndexError, TypeError, ValueError):
                        bad = next(f for f in fields if not _has(msg, f))
                        raise LogError(f"{path}: {topic} ({conn.msgtype}) has no number at {bad!r}") from None
                if not rows:
                    raise LogError(f"{path}: topic {topic!r} has no messages")
                a = np.asarray(rows, dtype=np.float64)
                out[topic] = (np.asarray(t, dtype=np.float64), {f: a[:, i] for i, f in enumerate(fields)})
    except LogError:
        raise
    except Exception as exc:  # noqa: BLE001 - rosbags raises its own errors on a damaged bag
        raise LogError(f"{path}: not a readable ROS 2 bag ({type(exc).__name__}: {exc})") from None
    return out


def _has(msg, field: str) -> bool:
    try:
        _get(msg, field)
        return True
    except (AttributeError, IndexError, TypeError, ValueError):
        return False
