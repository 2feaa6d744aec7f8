"""uavsim: identify and tune multirotor loops with DNN-NP-MRFT on a MuJoCo hexarotor.

Data flows one way: recipe -> grid -> episodes -> preprocessed samples -> HDF5 ->
trainer -> model -> identification. Each concern is one subpackage:

- ``uavsim.model``: the hexarotor MJCF, the lumped-parameter mapping, effects.
- ``uavsim.control``: MRFT, NP-MRFT, baselines and the step PD (vectorized).
- ``uavsim.sim``: the batched closed-loop runner on ``mujoco.batch``.
- ``uavsim.lumped``: lumped transfer functions and an exact reference simulator.
- ``uavsim.tuning``: tuning rule, relative sensitivity J, grids.
- ``uavsim.noise``: noise models and noise estimation.
- ``uavsim.formats``: flight sessions (and later HDF5 datasets).
- ``uavsim.cli``: the ``uavsim`` command.
"""

__version__ = "0.1.0"
