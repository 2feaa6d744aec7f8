"""A new vocabulary effect is one class: registered once, it is in the session format, its schema,
the gap workflow's candidates and the hidden-effect generator, with no other file touched."""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from uavsim.formats.session import (
    EFFECT_PARAMS,
    EffectSpec,
    ModelSpec,
    Run,
    RunData,
    RunSpec,
    Session,
    SessionError,
    read_session,
    write_session,
)
from uavsim.gap.hidden import HIDDEN_EFFECTS, draw_effect
from uavsim.gap.simulate import IDENTITY, batch_effects
from uavsim.gap.workflow import CANDIDATES, candidate_grid
from uavsim.model.effects import REGISTRY, SessionTerm, SignalEffect, register
from uavsim.model.effects import vocabulary as vocab
from uavsim.model.effects.base import Param
from uavsim.schema import json_schema


@dataclass(eq=False)
class Toy(SignalEffect):
    """A made-up measurement effect: scale the measurement by ``toy_scale`` (> 0)."""

    toy_scale: Param = 1.0
    name = "toy"
    target = "measurement"
    session = SessionTerm(
        param="toy_scale", range=">0", identity=1.0, table=50, chain=50,
        grid=lambda sc, noise_std, rate_hz, n: np.geomspace(0.5, 2.0, n),
        draw=lambda rng, period, h, amp, noise_std, rate_hz: {"toy_scale": rng.uniform(1.2, 1.5)},
    )

    def validate(self) -> None:
        pass

    def reset(self, n, rate_hz, rng):
        super().reset(n, rate_hz, rng)
        self._k = self.toy_scale

    def __call__(self, y: np.ndarray, k: int) -> np.ndarray:
        return y * self._k


@pytest.fixture
def toy():
    register(Toy)
    try:
        yield Toy
    finally:
        REGISTRY.pop("toy")


def _session(value: float) -> Session:
    t = np.arange(20) / 100.0
    data = RunData(t, np.zeros_like(t), np.sin(t), np.cos(t))
    return Session(loop="altitude", control_rate_hz=100.0,
                   runs=[Run(RunSpec("a.csv", "mrft", beta=-0.5, h=1.0), data)],
                   model=ModelSpec(K=1.0, T_prop=0.1, T1=0.8, tau=0.02),
                   effects=[EffectSpec("toy", {"toy_scale": value})])  # fmt: skip


def test_the_vocabulary_is_the_registered_effects_in_the_formats_order():
    assert tuple(EFFECT_PARAMS) == ("none", "delay", "lag", "gain", "saturation", "dead_zone", "rate_limit", "bias",
                                    "quantization", "sample_hold", "lowpass", "noise")  # fmt: skip
    assert vocab.chain() == ("delay", "gain", "lag", "rate_limit", "dead_zone", "saturation", "bias",
                             "noise", "quantization", "sample_hold", "lowpass")  # fmt: skip
    assert vocab.identity(200.0)["sample_hold"] == 200.0 and math.isnan(IDENTITY["sample_hold"])
    for name in vocab.names():  # each term's parameter is a field of its effect
        assert vocab.term(name).param in REGISTRY[name]().params()


def test_a_registered_toy_effect_is_in_the_format_the_gap_workflow_and_the_generator(toy, tmp_path: Path):
    assert vocab.names()[-1] == "toy"  # the table order puts it last
    # the session format: its parameter and range, the reader, the writer, the schema
    assert EFFECT_PARAMS["toy"] == ("toy_scale",) and vocab.PARAM_RANGES["toy_scale"] == ">0"
    back = read_session(write_session(_session(1.25), tmp_path / "ok"))
    assert back.effects[0].name == "toy" and back.effects[0].params == {"toy_scale": 1.25}
    assert "Effect_toy" in json_schema("session")["$defs"]
    with pytest.raises(SessionError, match="toy_scale"):
        write_session(_session(-1.0), tmp_path / "bad")
    # the gap workflow: a candidate with its grid, simulated with its own identity for other episodes
    assert "toy" in CANDIDATES and IDENTITY["toy"] == 1.0
    assert np.allclose(candidate_grid("toy", {}, 0.0, 200.0, 3), [0.5, 1.0, 2.0])
    fx = batch_effects(["none", "toy"], [0.0, 1.3], 0.0, 200.0)
    (mine,) = [e for e in fx if e.name == "toy"]
    assert np.array_equal(mine.toy_scale, [1.0, 1.3])
    # the hidden-effect generator draws it
    assert "toy" in HIDDEN_EFFECTS
    drawn = draw_effect("toy", np.random.default_rng(0), 0.5, 1.0, 0.05, 0.001)
    assert set(drawn) == {"toy_scale"} and 1.2 <= drawn["toy_scale"] <= 1.5


def test_an_unregistered_effect_is_unknown_everywhere(tmp_path: Path):
    folder = tmp_path / "s"
    register(Toy)
    try:
        write_session(_session(1.25), folder)
    finally:
        REGISTRY.pop("toy")
    with pytest.raises(SessionError, match="toy"):
        read_session(folder)
    assert "toy" not in EFFECT_PARAMS and "toy" not in CANDIDATES and "toy" not in HIDDEN_EFFECTS
    with pytest.raises(ValueError, match="toy"):
        draw_effect("toy", np.random.default_rng(0), 0.5, 1.0, 0.05, 0.001)
