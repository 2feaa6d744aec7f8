"""Building blocks of the schemas: the strict table base and the number types with their ranges."""

from __future__ import annotations

from typing import Annotated, Any

from pydantic import BaseModel, ConfigDict, Field, create_model

__all__ = ["Table", "Finite", "Positive", "NonNegative", "Beta", "PosInt", "NonNegInt", "number_type", "tagged",
           "from_dataclass"]


class Table(BaseModel):
    """A TOML table: unknown keys refused, types strict (a string is not a number, a boolean not an
    integer; an integer is a number), no NaN or infinity."""

    model_config = ConfigDict(extra="forbid", strict=True, allow_inf_nan=False, frozen=True)


Finite = Annotated[float, Field(allow_inf_nan=False)]
Positive = Annotated[float, Field(gt=0, allow_inf_nan=False)]
NonNegative = Annotated[float, Field(ge=0, allow_inf_nan=False)]
Beta = Annotated[float, Field(gt=-1, lt=1, allow_inf_nan=False, description="MRFT parameter, in (-1, 1)")]
PosInt = Annotated[int, Field(ge=1)]
NonNegInt = Annotated[int, Field(ge=0)]

_RULES = {">0": Positive, ">=0": NonNegative, "any": Finite}


def number_type(rule: str, description: str | None = None) -> Any:
    """``">0"``, ``">=0"`` or ``"any"`` (finite) as an annotated float type."""
    base = _RULES[rule]
    return Annotated[base, Field(description=description)] if description else base


def tagged(name: str, tag_key: str, tag: str, fields: dict[str, Any], doc: str = "",
           validators: dict[str, Any] | None = None) -> type[Table]:
    """A table whose ``tag_key`` is the literal ``tag`` (one member of a discriminated union)."""
    from typing import Literal

    model = create_model(name, __base__=Table, __doc__=doc or None, __validators__=validators,
                         **{tag_key: (Literal[tag], ...)}, **fields)  # type: ignore[call-overload]
    model.TAG = tag
    return model


def from_dataclass(cls: type, name: str, *, skip: tuple[str, ...] = (), types: dict[str, Any] | None = None,
                   doc: str = "") -> type[Table]:
    """A table of a dataclass's fields, every key optional (the dataclass has the defaults), typed by
    the default's type unless ``types`` says otherwise."""
    import dataclasses

    fields: dict[str, Any] = {}
    for f in dataclasses.fields(cls):
        if f.name in skip or f.name.startswith("_"):
            continue
        default = f.default if f.default is not dataclasses.MISSING else None
        if types and f.name in types:
            t = types[f.name]
        elif isinstance(default, bool):
            t = bool
        elif isinstance(default, int):
            t = int
        elif isinstance(default, float):
            t = Finite
        elif isinstance(default, str):
            t = str
        else:
            t = Any
        fields[f.name] = (t | None, Field(default=None, description=f"default {default!r}"))
    return create_model(name, __base__=Table, __doc__=doc or None, **fields)  # type: ignore[call-overload]
