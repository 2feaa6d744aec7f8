"""Visualization of sessions and simulations with Rerun.

:mod:`uavsim.viz.replay` logs a flight session (format ``uavsim-session/1``)
to a Rerun recording: r, y, e, u over time, the relay switches, the accepted
extrema and ``tau_obs`` windows recomputed with the project's NP-MRFT, and the
phase portrait, with a blueprint that lays them out.

    from uavsim.viz import replay_session
    summary = replay_session("flights/2024-05-01", "replay.rrd")
"""

from uavsim.viz.replay import replay_session

__all__ = ["replay_session"]
