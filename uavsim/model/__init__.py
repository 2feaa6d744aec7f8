"""The MuJoCo hexarotor: its MJCF, the mapping from lumped loop parameters onto it, and effects.

- :mod:`~uavsim.model.vehicle`: the vehicle's parameters (the paper's 3.38 kg
  hexarotor by default) and its MJCF.
- :mod:`~uavsim.model.mapping`: per episode, the damping, rotor dynamics and
  delays that make a loop of the vehicle reproduce a lumped model exactly.
- :mod:`~uavsim.model.effects`: the registry of effects (delay, lag, noise,
  quantization, ..., wind, pull), one file each; each session-vocabulary
  effect also declares its session parameters, ranges, identity value and
  gap search range there.

    from uavsim.model.vehicle import Vehicle, hexarotor_mjcf
    xml = hexarotor_mjcf(Vehicle(), timestep=0.0005)
"""
