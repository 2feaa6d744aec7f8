"""Schema of a dataset recipe (``datasets/*.toml``, read by ``uavsim.data.recipe``).

Every effect's parameters are its own (a misspelt one is refused at load, not
inside a chunk), and each value, or both ends of a ``[lo, hi]`` range, is
checked by the effect itself.
"""

from __future__ import annotations

from typing import Annotated, Any, Literal, Union

from pydantic import Field, field_validator, model_validator

from uavsim.schema._base import Beta, Finite, NonNegative, PosInt, Positive, Table, tagged

Pair = Annotated[list[Finite], Field(min_length=2, max_length=2, description="[lo, hi]")]


def _ordered(v: list[float], lo: float | None = None, hi: float | None = None, strict_lo: bool = False) -> list[float]:
    a, b = v
    if b < a:
        raise ValueError(f"range [{a}, {b}] is reversed")
    if lo is not None and (a < lo or (strict_lo and a == lo)):
        raise ValueError(f"must be {'>' if strict_lo else '>='} {lo}, got {a}")
    if hi is not None and b > hi:
        raise ValueError(f"must be <= {hi}, got {b}")
    return v


class Test(Table):
    """The relay test of every episode."""

    beta: Beta | None = Field(default=None, description="default: the grid's beta")
    h: Positive = Field(default=1.0, description="relay amplitude, command units")
    settings: Literal["recommended", "fixed"] | None = Field(
        default=None, description="NP-MRFT tau_obs, a_n as a user gets them (recommended: hover estimate, then "
                                  "refined runs), or fixed; default recommended, fixed when tau_obs or a_n is given")
    refinements: Annotated[int, Field(ge=0, le=5)] | None = Field(
        default=None, description="recommended only: relay runs refined from the one before (default 2)")
    refine_cycles: Annotated[float, Field(gt=2, allow_inf_nan=False)] | None = Field(
        default=None, description="recommended only: length of each refined run, cycles (default 4)")
    tau_obs: NonNegative | None = Field(default=None, description="fixed only: NP-MRFT observation time, s (0.03)")
    a_n: NonNegative | None = Field(default=None,
                                    description="fixed only: NP-MRFT a_n / the episode's noise amplitude (1.0)")
    bias_trim: Literal["off", "duty"] = Field(
        default="off", description="off: the relay bias stays as drawn; duty: the relay trims it from each cycle's "
                                   "duty (uavsim.control.relay)")

    @model_validator(mode="after")
    def _settings(self):
        fixed = [k for k in ("tau_obs", "a_n") if getattr(self, k) is not None]
        refine = [k for k in ("refinements", "refine_cycles") if getattr(self, k) is not None]
        settings = self.settings or ("fixed" if fixed else "recommended")
        if settings == "recommended" and fixed:
            raise ValueError(f"{fixed[0]} only goes with settings = \"fixed\"")
        if settings == "fixed" and refine:
            raise ValueError(f"{refine[0]} only goes with settings = \"recommended\"")
        return self


class Episodes(Table):
    """Count, length, timestep, rate and chunking of the episodes."""

    per_class: PosInt
    cycles: Annotated[float, Field(gt=2, allow_inf_nan=False)] | None = Field(
        default=None, description="length in cycles of the chunk's slowest class (or duration_s)")
    duration_s: Positive | None = Field(default=None, description="fixed length, s (or cycles)")
    dt: Annotated[float, Field(gt=0, le=0.01, allow_inf_nan=False)] = Field(default=0.001,
                                                                          description="physics step, s")
    rate_hz: Positive = Field(default=200.0, description="control rate, Hz")
    chunk: PosInt = Field(default=256, description="episodes per batch (fixes the seeds)")

    @model_validator(mode="after")
    def _length(self):
        if (self.cycles is None) == (self.duration_s is None):
            raise ValueError("give exactly one of episodes.cycles and episodes.duration_s")
        steps = 1.0 / (self.rate_hz * self.dt)
        if abs(steps - round(steps)) > 1e-6 or round(steps) < 1:
            raise ValueError(f"control period 1/{self.rate_hz} Hz is not a whole number of {self.dt} s steps")
        return self


class Randomize(Table):
    """Per-episode randomization."""

    K: Pair = Field(default=[0.5, 2.0], description="gain factor range, log-uniform, > 0")
    bias: Annotated[float, Field(ge=0, le=0.5)] = Field(default=0.5, description="relay bias / h, uniform +-")
    y0: Annotated[float, Field(ge=0, le=10)] = Field(default=0.5, description="initial output / a0, uniform +-")
    offgrid: Annotated[float, Field(ge=0, le=1)] = Field(
        default=0.0, description="share of each class's episodes drawn off the class centre, in its cell "
                                 "(stores each sample's cost vector)")

    @field_validator("K")
    @classmethod
    def _k(cls, v):
        return _ordered(v, lo=0.0, strict_lo=True)


def _noise_kinds() -> tuple[str, ...]:
    from uavsim.data.recipe import RECIPE_NOISE_KINDS

    return RECIPE_NOISE_KINDS


class Noise(Table):
    """Noise kinds, their weights and the level range (noise amplitude / a0)."""

    kinds: Annotated[list[Literal[_noise_kinds()]], Field(min_length=1)] = ["none"]  # type: ignore[valid-type]
    weights: list[NonNegative] | None = Field(default=None, description="one per kind (default: equal)")
    level: Pair = Field(default=[0.0, 0.0], description="in [0, 0.2]")

    @field_validator("level")
    @classmethod
    def _level(cls, v):
        return _ordered(v, lo=0.0, hi=0.2)

    @model_validator(mode="after")
    def _weights(self):
        if len(set(self.kinds)) != len(self.kinds):
            raise ValueError("noise.kinds has repeated kinds")
        if self.weights is not None:
            if len(self.weights) != len(self.kinds):
                raise ValueError(f"noise.weights must have one weight per kind ({len(self.kinds)})")
            if sum(self.weights) <= 0:
                raise ValueError("noise.weights must not all be 0")
        return self


class Preprocess(Table):
    """Network input."""

    cycles: PosInt = Field(default=1, description="cycles per input")
    keep_raw: bool = Field(default=False, description="also store the raw y, u traces")


Value = Union[Finite, Pair]  # noqa: UP007


def _effect(name: str, cls: type) -> type[Table]:
    import dataclasses

    fields: dict[str, Any] = {}
    for f in dataclasses.fields(cls):
        if f.name.startswith("_"):
            continue
        required = f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING
        fields[f.name] = (Value, ...) if required else (Value | None, None)

    def check(self):  # both ends of every range go through the effect's own checks
        from uavsim.model.effects import make_effect

        given = {k: v for k, v in self.model_dump().items() if k != "name" and v is not None}
        for v in given.values():
            if isinstance(v, list):
                _ordered(v)
        from uavsim.errors import UserError

        for end in (0, 1):
            try:
                make_effect(name, **{k: (v[end] if isinstance(v, list) else v) for k, v in given.items()})
            except UserError as exc:
                raise ValueError(str(exc)) from None
        return self

    return tagged(f"Effect_{name}", "name", name, fields, doc=f"{name}: a number or [lo, hi] per parameter",
                  validators={"check": model_validator(mode="after")(check)})


def _effects() -> Any:
    from uavsim.model.effects import REGISTRY

    return Annotated[Union[tuple(_effect(n, REGISTRY[n]) for n in sorted(REGISTRY))],  # noqa: UP007
                     Field(discriminator="name")]


Classes = Annotated[list[Annotated[int, Field(ge=0)]], Field(min_length=1)]


class DatasetRecipe(Table):
    """A dataset recipe: the grid, the relay test, the episodes, the randomization and the seed."""

    loop: Literal["altitude", "attitude", "lateral"]
    seed: Annotated[int, Field(ge=0)]
    classes: Classes | None = Field(default=None, description="subset of grid classes (default: all)")
    att_classes: Classes | None = Field(default=None, description="lateral: attitude classes (default: all)")
    test: Test = Field(default_factory=Test)
    episodes: Episodes
    randomize: Randomize = Field(default_factory=Randomize)
    noise: Noise = Field(default_factory=Noise)
    preprocess: Preprocess = Field(default_factory=Preprocess)
    effects: list[_effects()] = Field(default_factory=list)  # type: ignore[valid-type]

    @model_validator(mode="after")
    def _cross(self):
        for key in ("classes", "att_classes"):
            v = getattr(self, key)
            if v is not None and len(set(v)) != len(v):
                raise ValueError(f"{key} has repeated classes")
        if self.episodes.cycles is not None and self.episodes.cycles < self.preprocess.cycles + 2:
            raise ValueError("episodes.cycles must be >= preprocess.cycles + 2 (transient + used cycles)")
        return self
