"""Schema of the model file of ``uavsim gap --model FILE``: a ``[model]`` table, or its keys at top level."""

from __future__ import annotations

from pydantic import Field, model_validator

from uavsim.schema._base import Finite, NonNegative, Positive, Table
from uavsim.schema.session import Model


class GapModelFile(Table):
    """The loop model the gap workflow compares with the measured runs (the session's loop decides T2)."""

    model: Model | None = Field(default=None, description="the model as a [model] table ...")
    K: Finite | None = Field(default=None, description="... or its keys at top level")
    T_prop: Positive | None = None
    T1: Positive | None = None
    T2: Positive | None = None
    tau: NonNegative | None = None
    noise_std: NonNegative | None = None
    noise_corner_hz: Positive | None = None

    @model_validator(mode="after")
    def _one_place(self):
        top = {k: v for k, v in self.model_dump().items() if k != "model" and v is not None}
        if self.model is not None and top:
            raise ValueError(f"give the model as a [model] table or as top-level keys, not both "
                             f"({', '.join(sorted(top))} at top level)")
        if self.model is None:
            Model.model_validate(top)  # the same keys and ranges as [model]
        return self
