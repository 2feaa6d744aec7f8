"""Batched closed-loop episodes of the hexarotor on ``mujoco.batch``, and episodes as sessions.

- :mod:`~uavsim.sim.runner`: ``LoopBatch``, the one episode loop: ``n``
  episodes of one loop stepped together, with a public stepping API (measure,
  actuate, advance, check divergence) and a pluggable measurement stage.
- :mod:`~uavsim.sim.sessions`: a simulated relay episode written as a flight
  session, so that simulation and flight share one path.

    lb = LoopBatch(params, dt=0.0005, rate_hz=200.0, seed=7)
    res = lb.run(MRFT(beta=-0.73, h=1.0, rate_hz=200.0, n=lb.n), duration_s=20.0)
"""
