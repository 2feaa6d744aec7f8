"""Visualization of sessions and simulations with Rerun.

:mod:`uavsim.viz.replay` logs a flight session (format ``uavsim-session/2`` or 1),
a dataset episode (simulated again exactly from the recipe the file records)
or a scenario run to a Rerun recording: r, y (and the noise-free y_true of
simulations), e, u over time, the relay switches, the accepted extrema and
``tau_obs`` windows recomputed with the project's NP-MRFT, the phase portrait
and, for simulations, the vehicle's pose with rotor thrust arrows
(:mod:`uavsim.viz.vehicle3d`), with a blueprint that lays them out.
:mod:`uavsim.viz.sources` reads the three sources.

    from uavsim.viz import replay, replay_session
    summary = replay_session("flights/2024-05-01", "replay.rrd")
    summary = replay("datasets/small.h5", "ep.rrd", cls=1, episode=5)
"""

from uavsim.viz.replay import replay, replay_session

__all__ = ["replay", "replay_session"]
