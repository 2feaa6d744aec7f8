"""User-facing errors.

A ``UserError`` is bad input from the person running uavsim (a malformed
session, an impossible parameter, a corrupt file). The CLI prints its message
on one line and exits with status 2, without a traceback. Anything else is a
bug and keeps its traceback.

:func:`short_repr` and :func:`type_name` put a user's value into such a
message (the session reader and the schema checks share them):

    raise UserError(f"{where}: h must be a number, got {type_name(v)} {short_repr(v)}")
"""

from __future__ import annotations

import datetime as _dt
from typing import Any

__all__ = ["UserError", "NoOscillation", "short_repr", "type_name"]


class UserError(Exception):
    """Bad input; the message says what is wrong and where, on one line."""

    exit_code = 2


def short_repr(value: Any, limit: int = 40) -> str:
    """``repr(value)``, cut to ``limit`` characters with ``...``."""
    text = repr(value)
    return text if len(text) <= limit else text[: limit - 3] + "..."


def type_name(value: Any) -> str:
    """The TOML word for a value's type: boolean, integer, float, string, array, table, date/time."""
    if isinstance(value, bool):
        return "boolean"
    if isinstance(value, int):
        return "integer"
    if isinstance(value, float):
        return "float"
    if isinstance(value, str):
        return "string"
    if isinstance(value, list):
        return "array"
    if isinstance(value, dict):
        return "table"
    if isinstance(value, _dt.date | _dt.time):
        return "date/time"
    return type(value).__name__


class NoOscillation(UserError):
    """A relay run holds no usable oscillation (too short, no switching, clipped, switched on noise)."""
