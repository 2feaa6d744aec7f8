"""The error of a log that cannot become a session, and the name hint its messages use.

Shared by the importer and its readers (ULog, DataFlash, ROS 2 bags), which
the importer loads on demand: they depend on this module, not on each other.

    raise LogError(f"{path}: no topic {name!r} ({hint(name, topics)}known: ...)")
"""

from __future__ import annotations

import difflib

from uavsim.errors import UserError

__all__ = ["LogError", "hint"]


def hint(name: str, known) -> str:
    """``did you mean 'x'? `` for the known name closest to ``name``, or ''."""
    close = difflib.get_close_matches(name, list(known), n=1, cutoff=0.6)
    return f"did you mean {close[0]!r}? " if close else ""


class LogError(UserError):
    """A log that cannot become a session; one line naming the log and the problem."""

    def __init__(self, message: str) -> None:
        super().__init__(message.replace("\r", "\\r").replace("\n", "\\n"))
