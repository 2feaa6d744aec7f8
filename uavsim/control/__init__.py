"""Controllers of the relay tests and the step test, vectorized over a batch of episodes.

- :mod:`~uavsim.control.relay`: MRFT and NP-MRFT, the one implementation of the
  session format's relay semantics (both readings).
- :mod:`~uavsim.control.pd`: the step test's PD with a filtered derivative of the
  error or of the measurement (then it has ``reads_reference`` and is called with
  the reference too: ``pd(r - y, r)``).
- :mod:`~uavsim.control.runs`: the controller of a session run, from its
  ``RunSpec`` (one factory for replay and the testbed's flights; the gap
  workflow's batch of runs of several kinds, ``uavsim.gap.simulate.SessionController``,
  builds the same controllers per kind over its batch).
- :mod:`~uavsim.control.baselines`: MRFT with inhibition and the two-relay
  test, the NP-MRFT study's baselines.

Each controller holds ``n`` independent controllers in numpy arrays and is
called once per control sample with the errors ``e`` (n,), returning the
commands (n,):

    relay = NPMRFT(beta=-0.73, h=1.0, tau_obs=0.02, a_n=0.004, rate_hz=200.0, n=64)
    u = relay(r - y)
"""
