"""Schema of a training recipe (``training/*.toml``, ``uavsim-train/1``, read by ``uavsim.learning.train``).

Keys left out take ``TrainRecipe``'s defaults (written in each key's description).
"""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import Field

from uavsim.schema._base import NonNegative, NonNegInt, PosInt, Positive, Table

Fraction = Annotated[float, Field(gt=0, lt=1)]


class Net(Table):
    """The network's shape."""

    hidden: Annotated[list[PosInt], Field(min_length=1)] | None = Field(default=None, description="default [3000, 1000]")
    dropout: Annotated[float, Field(ge=0, lt=1)] | None = Field(default=None, description="default 0.4")
    period_features: NonNegInt | None = Field(default=None, description="default 0 (the paper's net)")
    phase_samples: NonNegInt | None = Field(
        default=None, description="points the output's cycle is resampled to, one per phase; default 0 (the samples as "
                                  "preprocessed, the paper's input)")


class Optim(Table):
    """Adam and its step schedule."""

    lr: Positive | None = Field(default=None, description="learning rate, default 0.01")
    lr_decay: Annotated[float, Field(gt=0, le=1)] | None = Field(default=None, description="default 0.7")
    lr_step_epochs: PosInt | None = Field(default=None, description="default 20")
    batch_size: Annotated[int, Field(ge=2)] | None = Field(default=None, description="default 100")
    epochs: PosInt | None = Field(default=None, description="default 100")
    weight_decay: NonNegative | None = Field(default=None, description="default 0")


class EarlyStopping(Table):
    """Validation split and stopping."""

    val_fraction: Fraction | None = Field(default=None, description="default 0.15")
    patience: PosInt | None = Field(default=None, description="epochs without improvement, default 10")
    min_delta: NonNegative | None = Field(default=None, description="mean-log-J improvement that counts, default 0")
    max_minutes: NonNegative | None = Field(default=None, description="wall-clock budget (0: none), default 0")


class Loss(Table):
    """What a misclassification costs (``uavsim.learning.loss``)."""

    kind: Literal["expected", "paper"] | None = Field(
        default=None, description="expected (cross-entropy + weight x expected log J) or paper; default expected")
    weight: NonNegative | None = Field(default=None, description="the expected log J's weight, default 5")
    target: Literal["label", "best"] | None = Field(
        default=None, description="cross-entropy target: label (the set's class, default) or best (each sample's "
                                  "least-cost class; sets with per-sample costs only)")


class TrainingRecipe(Table):
    """A training recipe: which dataset, which network, how to optimize, when to stop."""

    format: Literal["uavsim-train/1"] = "uavsim-train/1"
    name: Annotated[str, Field(min_length=1)]
    loop: Literal["altitude", "attitude", "lateral"]
    dataset: Annotated[str, Field(min_length=1)] = Field(description="HDF5 set, relative to the repository root")
    out: Annotated[str, Field(min_length=1)] = Field(description="output folder of the exported network")
    test_dataset: str | None = Field(default=None, description="held-out set ('' for none)")
    attitude_classes: list[NonNegInt] | None = Field(default=None, description="lateral: which attitude classes")
    seed: NonNegInt | None = Field(default=None, description="default 0")
    device: Literal["auto", "cpu", "cuda"] | None = Field(default=None, description="default auto")
    threads: NonNegInt | None = Field(default=None, description="torch threads (0: all cores), default 0")
    net: Net = Field(default_factory=Net)
    optim: Optim = Field(default_factory=Optim)
    early_stopping: EarlyStopping = Field(default_factory=EarlyStopping)
    loss: Loss = Field(default_factory=Loss)
