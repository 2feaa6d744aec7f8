"""Helpers shared by the CLI subcommands."""

from __future__ import annotations

import json
import sys
from typing import Any


def _default(obj: Any) -> Any:
    import numpy as np

    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    raise TypeError(f"not JSON serializable: {type(obj).__name__}")


def print_json(obj: Any) -> None:
    """Print exactly one JSON object on stdout (the --json contract)."""
    sys.stdout.write(json.dumps(obj, default=_default) + "\n")
    sys.stdout.flush()


def eprint(*args: Any) -> None:
    """Progress and logs go to stderr so that stdout stays machine-readable."""
    print(*args, file=sys.stderr, flush=True)


def print_table(rows: list[dict[str, Any]], columns: list[str] | None = None, file=None) -> None:
    """Print rows as an aligned text table."""
    file = file or sys.stdout
    if not rows:
        print("(no rows)", file=file)
        return
    columns = columns or list(rows[0].keys())

    def fmt(v: Any) -> str:
        if isinstance(v, float):
            return f"{v:.4g}"
        return str(v)

    cells = [[fmt(r.get(c, "")) for c in columns] for r in rows]
    widths = [max(len(c), *(len(row[i]) for row in cells)) for i, c in enumerate(columns)]
    print("  ".join(c.ljust(w) for c, w in zip(columns, widths, strict=True)), file=file)
    print("  ".join("-" * w for w in widths), file=file)
    for row in cells:
        print("  ".join(v.ljust(w) for v, w in zip(row, widths, strict=True)), file=file)


def register_modules(sub, names: list[str]) -> None:
    """Import each module in ``names`` and call its ``register(sub)``.

    A module that is not there (a command not built yet) is skipped; a module
    that fails to import because of something *it* imports still raises.
    """
    import importlib

    for name in names:
        try:
            mod = importlib.import_module(name)
        except ModuleNotFoundError as exc:
            if exc.name != name:
                raise
            continue
        mod.register(sub)


def print_result(result: dict[str, Any], as_json: bool) -> None:
    """A benchmark's figures: one JSON object with ``--json``, else a measure/value table."""
    if as_json:
        print_json(result)
    else:
        print_table([{"measure": k, "value": v} for k, v in result.items()])
