"""Effects: named, composable, parameterized imperfections of a loop.

Names and parameters follow the effect vocabulary of
``docs/formats/session.md`` (delay, lag, gain, saturation, dead_zone,
rate_limit, bias, quantization, sample_hold, lowpass, noise), plus ``wind``
and ``pull`` (external forces) and ``actuator_range`` (the vehicle's known
command range, not searched for). One effect is one file; importing this
package registers them all. A vocabulary effect's ``session`` term (its
session parameter, range, identity value, gap search grid and hidden-effect
draw) makes it part of the session format and the gap workflow
(:mod:`uavsim.model.effects.vocabulary`); registering it is the one step.

    from uavsim.model.effects import make_effect
    eff = make_effect("lowpass", cutoff_hz=20.0)
"""

from uavsim.model.effects import (  # noqa: F401  (imports register the effects)
    actuator_range,
    bias,
    dead_zone,
    delay,
    gain,
    lag,
    lowpass,
    noise,
    pull,
    quantization,
    rate_limit,
    sample_hold,
    saturation,
    wind,
)
from uavsim.model.effects.base import (
    REGISTRY,
    Effect,
    SessionTerm,
    SignalEffect,
    make_effect,
    register,
)
from uavsim.model.effects.base_force import ForceEffect

__all__ = ["REGISTRY", "Effect", "SignalEffect", "ForceEffect", "SessionTerm", "make_effect", "register"]
