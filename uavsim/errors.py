"""User-facing errors.

A ``UserError`` is bad input from the person running uavsim (a malformed
session, an impossible parameter, a corrupt file). The CLI prints its message
on one line and exits with status 2, without a traceback. Anything else is a
bug and keeps its traceback.
"""


class UserError(Exception):
    """Bad input; the message says what is wrong and where, on one line."""

    exit_code = 2


class NoOscillation(UserError):
    """A relay run holds no usable oscillation (too short, no switching, clipped, switched on noise)."""
