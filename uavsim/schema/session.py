"""Schema of a flight session's ``session.toml`` (``uavsim-session/1``).

Built from the vocabulary tables of ``uavsim.formats.session`` (loops, run kinds
and their parameters, effects and their ranges), so that the schema and the
reader cannot drift apart. The reader keeps its own checks in front of this one
for their hints (the line of a CSV row, "not a key of a mrft run"); this schema
is what it enforces as a whole, and what ``uavsim schema session`` prints.

The effect tables follow the registered vocabulary effects
(:mod:`uavsim.model.effects.vocabulary`): ``SessionFile`` is rebuilt when the
vocabulary changes (an effect registered after this module was imported).
"""

from __future__ import annotations

import functools
from typing import Annotated, Any, Literal, Union

from pydantic import Field, model_validator

from uavsim.formats import session as fmt
from uavsim.model.effects import vocabulary
from uavsim.schema._base import Beta, Finite, NonNegative, Positive, Table, number_type, tagged

# ranges of the run parameters (validate_run_params); a parameter not named here is any finite number
_RUN_TYPES: dict[str, Any] = {
    "beta": Beta,
    "h": Annotated[Positive, Field(description="relay amplitude, command units")],
    "tau_obs": Annotated[NonNegative, Field(description="NP-MRFT observation time, s")],
    "a_n": Annotated[NonNegative, Field(description="NP-MRFT noise amplitude, output units")],
    "bias": Annotated[Finite, Field(description="relay bias, command units")],
    "derivative_filter_hz": Annotated[Positive, Field(description="derivative filter cut-off, Hz")],
    "step_time": Annotated[NonNegative, Field(description="time of the reference step, s")],
    "bias_trim": Annotated[Literal[fmt.RELAY_BIAS_TRIMS],  # type: ignore[valid-type]
                           Field(description="how the relay's bias moves: stays (off, default) or trimmed from "
                                             "each cycle's duty (duty)")],
    "derivative": Annotated[Literal[fmt.STEP_DERIVATIVES],  # type: ignore[valid-type]
                            Field(description="what the step's PD differentiates: the error (default) or the "
                                              "measurement (no kick on the reference step)")],
}


def _run(kind: str) -> type[Table]:
    required, optional = fmt.RUN_KEYS[kind]
    fields: dict[str, Any] = {"file": (str, Field(min_length=1, description="CSV t,r,y,u, relative to the folder"))}
    for k in required:
        fields[k] = (_RUN_TYPES.get(k, Finite), ...)
    for k in optional:
        fields[k] = (_RUN_TYPES.get(k, Finite) | None, None)
    return tagged(f"Run_{kind.replace('-', '_')}", "kind", kind, fields, doc=f"a {kind} run")


def _effect(name: str) -> type[Table]:
    fields = {p: (number_type(vocabulary.PARAM_RANGES.get(p, "any")), ...) for p in fmt.EFFECT_PARAMS[name]}
    return tagged(f"Effect_{name}", "name", name, fields, doc=f"a {name} effect")


Run = Annotated[Union[tuple(_run(k) for k in fmt.RUN_KINDS)], Field(discriminator="kind")]  # noqa: UP007


class Model(Table):
    """The loop's lumped model."""

    K: Finite = Field(description="loop gain, output units per command unit (per s for type-1 loops); not 0")
    T_prop: Positive = Field(description="propulsion time constant, s")
    T1: Positive = Field(description="body time constant, s")
    T2: Positive | None = Field(default=None, description="second body time constant, s (lateral loops only)")
    tau: NonNegative = Field(description="total loop delay, s")
    noise_std: NonNegative = Field(default=0.0, description="measurement noise std, output units")
    noise_corner_hz: Positive | None = Field(
        default=None, description="corner of the 2nd-order low-pass colouring that noise, Hz; absent: white")

    @model_validator(mode="after")
    def _gain(self):
        if self.K == 0:
            raise ValueError("K must be non-zero")
        return self


class Actuator(Table):
    """The actuators' command range about the hover trim."""

    command_min: Finite = Field(lt=0, description="command at which a motor first reaches its ESC's lowest output, "
                                                 "command units, < 0")
    command_max: Finite = Field(gt=0, description="command at which a motor first reaches its ESC's highest output, "
                                                 "command units, > 0")


def _session_file(effect: Any) -> type[Table]:
    class SessionFile(Table):
        """A flight session's session.toml: the loop, the controller rate, the runs (one CSV each),
        and optionally the loop's model, the actuators' range and the effects the gap workflow added."""

        format: str = Field(description=f"format version, {fmt.FORMAT!r}")
        loop: Literal[fmt.LOOPS]  # type: ignore[valid-type]
        control_rate_hz: Positive = Field(description="rate of the controller's samples, Hz")
        model: Model | None = None
        actuator: Actuator | None = None
        runs: list[Run] = Field(min_length=1)
        effects: list[effect] = Field(default_factory=list)  # type: ignore[valid-type]

        @model_validator(mode="after")
        def _t2(self):
            if self.model is not None:
                lateral = self.loop in fmt.LATERAL_LOOPS
                if lateral and self.model.T2 is None:
                    raise ValueError(f"model: missing key 'T2' (required for the {self.loop} loop)")
                if not lateral and self.model.T2 is not None:
                    raise ValueError(f"model: 'T2' is not a key of the {self.loop} loop model (lateral loops only)")
            return self

    return SessionFile


@functools.lru_cache(maxsize=4)
def _for_vocabulary(words: tuple[tuple[str, tuple[str, ...]], ...]) -> type[Table]:
    effect = Annotated[Union[tuple(_effect(n) for n, _ in words)], Field(discriminator="name")]  # noqa: UP007
    return _session_file(effect)


def __getattr__(name: str) -> Any:
    # SessionFile of the vocabulary as registered now
    if name == "SessionFile":
        return _for_vocabulary(tuple((n, tuple((q, vocabulary.PARAM_RANGES[q]) for q in p)) for n, p in fmt.EFFECT_PARAMS.items()))
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
