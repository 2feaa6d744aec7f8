"""ArduPilot DataFlash (.bin) reader (pymavlink): message fields with their TimeUS, seconds."""

from __future__ import annotations

import contextlib
import io
from pathlib import Path

import numpy as np

from uavsim.logs.errors import LogError
from uavsim.logs.errors import hint as _hint

__all__ = ["read"]


def read(path: Path, wanted: dict[str, list[str]]) -> dict[str, tuple[np.ndarray, dict[str, np.ndarray]]]:
    """``{message: (t s, {field: values})}`` of each wanted message type (instance 0 where instanced)."""
    try:
        from pymavlink import DFReader
    except ImportError:
        raise LogError("reading DataFlash logs needs pymavlink: pip install 'uavsim[logs]'") from None
    rows: dict[str, list[tuple]] = {m: [] for m in wanted}
    try:
        # pymavlink prints progress and warnings on stdout, which is the JSON channel of the CLI
        with contextlib.redirect_stdout(io.StringIO()):
            dfr = DFReader.DFReader_binary(str(path), zero_time_base=False)
            known = set(dfr.name_to_id)
            for name, fields in wanted.items():
                if name not in known:
                    has = (f"the log has {', '.join(sorted(known)[:15])}{', ...' if len(known) > 15 else ''}"
                           if known else "no message formats: not a DataFlash log?")
                    raise LogError(f"{path}: no {name!r} messages ({_hint(name, known)}{has})")
                cols = dfr.formats[dfr.name_to_id[name]].columns
                for f in fields:
                    if f not in cols:
                        raise LogError(f"{path}: {name} has no field {f!r} ({_hint(f, cols)}fields: "
                                       f"{', '.join(cols)})")
                if "TimeUS" not in cols:
                    raise LogError(f"{path}: {name} has no TimeUS field")
            while True:
                m = dfr.recv_match(type=list(wanted))
                if m is None:
                    break
                name = m.get_type()
                if getattr(m, "I", 0) not in (0, None) or getattr(m, "Inst", 0) not in (0, None):
                    continue  # instance 0 of instanced messages
                rows[name].append((m.TimeUS, *(getattr(m, f) for f in wanted[name])))
    except LogError:
        raise
    except Exception as exc:  # noqa: BLE001 - pymavlink raises anything on a damaged file
        raise LogError(f"{path}: not a readable DataFlash log ({type(exc).__name__}: {exc})") from None
    out = {}
    for name, fields in wanted.items():
        if not rows[name]:
            raise LogError(f"{path}: {name} is defined but never logged")
        a = np.asarray(rows[name], dtype=np.float64)
        out[name] = (a[:, 0] * 1e-6, {f: a[:, i + 1] for i, f in enumerate(fields)})
    return out
