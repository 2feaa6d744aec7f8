"""File formats of uavsim.

For now one format: the flight *session* (``uavsim-session/2``; version 1 is
read too), a folder with a ``session.toml`` and one ``t,r,y,u`` CSV per
experiment, read for identification and the gap workflow and written from
simulation. See :mod:`uavsim.formats.session` and ``docs/formats/session.md``
(the normative description).

    from uavsim.formats import read_session, write_session

    session = read_session("flights/2024-05-01")
    write_session(session, "flights/copy")
"""

from uavsim.formats.session import *  # noqa: F403  (the format's public names, listed once there)
from uavsim.formats.session import __all__  # noqa: F401
