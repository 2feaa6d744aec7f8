"""Schema of a scenario file (``scenarios/*.toml``, ``uavsim-scenario/1``, read by ``uavsim.scenario.config``).

The tables ``[camera]``, ``[imu]``, ``[identification]``, ``[test]`` and
``[switch]`` take the fields of their dataclasses (every key optional: the
dataclass or the camera preset has the default); the physical checks of the
camera, IMU and schedules stay with those classes.
"""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import Field

from uavsim.scenario import config as cfg
from uavsim.schema._base import Finite, NonNegative, Positive, Table, from_dataclass
from uavsim.vision.camera import PRESETS, CameraParams
from uavsim.vision.imu import ImuParams
from uavsim.vision.schedules import SwitchParams

NegBeta = Annotated[float, Field(gt=-1, lt=0, allow_inf_nan=False)]

_Camera = from_dataclass(CameraParams, "CameraOverrides", skip=("name",))


class Camera(_Camera):
    """A camera preset and any of its parameters overridden."""

    preset: Literal[tuple(PRESETS)] | None = Field(default=None, description="default 'normal'")  # type: ignore[valid-type]


Identification = from_dataclass(cfg.Identification, "Identification", types={
    "beta": NegBeta | None, "beta_lateral": NegBeta | None, "h_altitude": Positive, "h_roll": Positive,
    "h_lateral": Positive, "hover_s": Positive, "duration_s": Positive, "pm_deg": Positive,
    "method": Literal[cfg.METHODS]}, doc="NP-MRFT test and identifier settings")  # type: ignore[valid-type]
Test = from_dataclass(cfg.TestSpec, "Test", types={
    "kind": Literal[cfg.TEST_KINDS], "loop": Literal[("", *cfg.LOOPS)], "axis": Literal["", "x", "y", "z"],
    "duration_s": Positive, "time_s": NonNegative}, doc="the test after tuning")  # type: ignore[valid-type]
Imu = from_dataclass(ImuParams, "Imu", doc="IMU parameters")
Switch = from_dataclass(SwitchParams, "Switch", doc="PBVS/IBVS switching schedule")


class InnerTruth(Table):
    """A true inner loop (lumped): gain and time constants, s."""

    K: Finite | None = None
    T_prop: Positive | None = None
    T1: Positive | None = None
    tau: NonNegative | None = None


class LateralTruth(Table):
    """The true lateral loop over the roll loop: gain, drag time constant T2 (s) and outer delay (s)."""

    K: Positive | None = None
    T2: Positive | None = None
    tau: Positive | None = None


class Truth(Table):
    """The vehicle's true loops (defaults: uavsim.scenario.config.DEFAULT_TRUTH)."""

    altitude: InnerTruth | None = None
    roll: InnerTruth | None = None
    lateral_y: LateralTruth | None = None


class ScenarioFile(Table):
    """A visual-servoing scenario: the vehicle's true loops, the sensor chain and the test."""

    format: Literal["uavsim-scenario/1"]
    description: str = ""
    seed: Annotated[int, Field(ge=0)] = 0
    loops: Annotated[list[Literal[cfg.LOOPS]], Field(min_length=1)] = ["altitude"]  # type: ignore[valid-type]
    estimator: Literal[cfg.ESTIMATORS] = "kf"  # type: ignore[valid-type]
    camera: Camera | None = None
    imu: Imu | None = None  # type: ignore[valid-type]
    identification: Identification | None = None  # type: ignore[valid-type]
    test: Test | None = None  # type: ignore[valid-type]
    truth: Truth | None = None
    switch: Switch | None = None  # type: ignore[valid-type]
