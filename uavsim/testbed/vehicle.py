"""The testbed vehicle: airframe, propulsion, battery, sensors and autopilot settings, drawn per seed.

``TestbedVehicle`` gathers every physical and sensor parameter of one
aircraft; ``draw_vehicle(rng)`` draws one around the paper's 3.38 kg
hexarotor (rotor speed at hover, motor lag, inflow damping, fuselage drag,
battery, IMU, camera and latencies all vary), and ``lumped_equivalent``
gives the small-signal lumped model of a loop that the physics linearises
to about hover (the "nearest lumped model" that identification should find):

==========  ==================================================================
lumped      testbed physics (linearised about hover)
==========  ==================================================================
K           command scale x (true thrust slope / the autopilot's assumed one,
            i.e. battery voltage / nominal voltage) / damping
T_prop      the motors' speed time constant
T1          mass or inertia / damping; damping = inflow ``k_inflow w_h``
            summed over the rotors (times the squared arm for roll, pitch)
            plus the fuselage's linear drag (altitude)
tau         transport latency + half the ESC sample period + one stale
            physics step + sensor read latency + the IMU low-pass's group
            delay
==========  ==================================================================

The measured check of that equivalence is :mod:`uavsim.testbed.equivalence`.

    v = draw_vehicle(np.random.default_rng(3))
    p = lumped_equivalent(v, "roll")       # LumpedParams
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field, replace

import numpy as np

from uavsim.errors import UserError
from uavsim.lumped.params import LumpedParams
from uavsim.testbed.airframe import AirframeParams, G
from uavsim.testbed.battery import BatteryPack, BatteryParams
from uavsim.testbed.propulsion import PropulsionParams
from uavsim.testbed.sensors import CameraParams, ImuParams

__all__ = ["AutopilotParams", "TestbedVehicle", "draw_vehicle", "lumped_equivalent", "TESTBED_LOOPS"]

TESTBED_LOOPS = ("altitude", "roll", "pitch")


@dataclass(frozen=True)
class AutopilotParams:
    """Flight controller settings.

    Attributes
    ----------
    rate_hz : float
        Control rate, Hz (the sessions' ``control_rate_hz``).
    physics_dt_s : float
        Physics step, s.
    latency_steps : int
        Controller-to-ESC transport latency, physics steps.
    sensor_latency_steps : int
        Age of the estimate the controller reads, physics steps.
    k_acc_per_s : float
        Attitude filter's accelerometer correction gain, 1/s.
    force_unit_N : float
        Collective thrust per unit of altitude command, N.
    moment_unit_Nm : float
        Roll or pitch moment per unit of attitude command, N m.
    hold_omega_rad_s : float
        Bandwidth of the attitude holds on the untested axes, rad/s.
    """

    rate_hz: float = 200.0
    physics_dt_s: float = 0.001
    latency_steps: int = 3
    sensor_latency_steps: int = 1
    k_acc_per_s: float = 0.3
    force_unit_N: float = 1.0
    moment_unit_Nm: float = 0.1
    hold_omega_rad_s: float = 6.0

    def check(self) -> AutopilotParams:
        steps = 1.0 / (self.rate_hz * self.physics_dt_s)
        if abs(steps - round(steps)) > 1e-9 or round(steps) < 1:
            raise UserError("autopilot: the control period must be a whole number of physics steps")
        if self.latency_steps < 0 or self.sensor_latency_steps < 0:
            raise UserError("autopilot: latencies must be >= 0 steps")
        return self

    @property
    def substeps(self) -> int:
        return int(round(1.0 / (self.rate_hz * self.physics_dt_s)))


@dataclass(frozen=True)
class TestbedVehicle:
    """Everything physical about one testbed aircraft."""

    airframe: AirframeParams = field(default_factory=AirframeParams)
    propulsion: PropulsionParams = field(default_factory=PropulsionParams)
    battery: BatteryParams = field(default_factory=BatteryParams)
    imu: ImuParams = field(default_factory=ImuParams)
    camera: CameraParams = field(default_factory=CameraParams)
    autopilot: AutopilotParams = field(default_factory=AutopilotParams)

    def check(self) -> TestbedVehicle:
        self.airframe.check()
        self.propulsion.check()
        self.battery.check()
        self.imu.check()
        self.camera.check()
        self.autopilot.check()
        return self

    @property
    def hover_speed(self) -> float:
        """Rotor speed at hover, rad/s."""
        return self.propulsion.hover_speed(self.airframe.mass_kg * G / 6.0)

    def hover_voltage(self, soc: float | None = None) -> float:
        """Terminal voltage at hover for state of charge ``soc`` (default: the flight's start), V."""
        pack = BatteryPack(replace(self.battery, soc_start=soc if soc is not None else self.battery.soc_start))
        w = self.hover_speed
        return pack.terminal_voltage(6 * self.propulsion.k_torque_Nm_s2 * w**3)

    def as_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> TestbedVehicle:
        af = dict(d["airframe"])
        af["drag_lin_N_s_per_m"] = tuple(af["drag_lin_N_s_per_m"])
        return cls(AirframeParams(**af), PropulsionParams(**d["propulsion"]), BatteryParams(**d["battery"]),
                   ImuParams(**d["imu"]), CameraParams(**d["camera"]), AutopilotParams(**d["autopilot"])).check()


def _damping(v: TestbedVehicle, loop: str) -> float:
    w = v.hover_speed
    pos = v.airframe.rotor_positions()
    k = v.propulsion.k_inflow_N_s2_per_m * w
    if loop == "altitude":
        return 6 * k + v.airframe.drag_lin_N_s_per_m[2]
    if loop == "roll":
        return k * float(np.sum(pos[:, 1] ** 2))
    if loop == "pitch":
        return k * float(np.sum(pos[:, 0] ** 2))
    raise UserError(f"testbed: loop must be one of {', '.join(TESTBED_LOOPS)}, got {loop!r}")


def lumped_equivalent(v: TestbedVehicle, loop: str, soc: float | None = None) -> LumpedParams:
    """The lumped model the vehicle's ``loop`` linearises to about hover (battery at ``soc``)."""
    c = _damping(v, loop)
    a, ap, pr = v.airframe, v.autopilot, v.propulsion
    ratio = v.hover_voltage(soc) / v.battery.nominal_V
    if loop == "altitude":
        K, inertia = ap.force_unit_N * ratio / c, a.mass_kg
    else:
        K, inertia = ap.moment_unit_Nm * ratio / c, (a.Jx_kgm2 if loop == "roll" else a.Jy_kgm2)
    dt = ap.physics_dt_s
    dlpf_delay = math.sqrt(2.0) / (2 * math.pi * v.imu.dlpf_hz)
    tau = (ap.latency_steps + 1 + ap.sensor_latency_steps) * dt + 0.5 / pr.esc_rate_hz + dlpf_delay
    return LumpedParams(loop, K=float(K), T_prop=float(pr.T_motor_s), T1=float(inertia / c), tau=float(tau))


def draw_vehicle(rng: np.random.Generator) -> TestbedVehicle:
    """One aircraft around the paper's hexarotor; lumped T1 of every loop inside the paper's box."""
    u = rng.uniform
    for _ in range(100):
        scale = u(0.9, 1.1)
        af = AirframeParams(mass_kg=3.38 * u(0.92, 1.1), Jx_kgm2=0.093 * scale, Jy_kgm2=0.089 * scale * u(0.95, 1.05),
                            Jz_kgm2=0.156 * scale, arm_m=u(0.39, 0.45),
                            drag_lin_N_s_per_m=(u(0.05, 0.3), u(0.05, 0.3), u(0.05, 0.6)),
                            drag_quad_N_s2_per_m2=u(0.02, 0.1))  # fmt: skip
        bat = BatteryParams(capacity_Ah=u(4.0, 8.0), R_internal_ohm=u(0.015, 0.04), soc_start=u(0.35, 0.95))
        w_h = u(480.0, 650.0)
        k_T = af.mass_kg * G / (6 * w_h * w_h)
        T1_roll = u(0.3, 0.75)
        sum_y2 = float(np.sum(af.rotor_positions()[:, 1] ** 2))
        k_in = af.Jx_kgm2 / (T1_roll * w_h * sum_y2)
        prop = PropulsionParams(
            k_thrust_N_s2=k_T, k_torque_Nm_s2=k_T * u(0.013, 0.02), k_inflow_N_s2_per_m=k_in,
            T_motor_s=u(0.035, 0.12), kv_rad_per_s_V=w_h / (u(0.45, 0.55) * bat.nominal_V),
            slew_us_per_s=u(15000.0, 40000.0), esc_rate_hz=400.0, rotor_inertia_kgm2=u(1e-4, 3e-4),
        )  # fmt: skip
        imu = ImuParams(gyro_noise_rad_s=u(0.002, 0.008), accel_noise_mps2=u(0.02, 0.1), noise_dof=u(3.0, 6.0),
                        accel_vib_mps2=u(0.3, 2.5), gyro_vib_rad_s=u(0.005, 0.04),
                        dlpf_hz=float(rng.choice([42.0, 98.0, 188.0])))  # fmt: skip
        cam = CameraParams(rate_hz=u(30.0, 60.0), jitter_s=u(0.0005, 0.004), drop_prob=u(0.01, 0.08),
                           drop_stay=u(0.2, 0.6), latency_s=u(0.015, 0.05), distance_m=u(2.0, 4.0),
                           quant_px=float(rng.choice([0.25, 0.5, 1.0])), noise_px=u(0.15, 0.6), noise_dof=u(2.5, 5.0),
                           outlier_prob=u(0.0, 0.01), vib_rad=u(1e-4, 8e-4))  # fmt: skip
        ap = AutopilotParams(latency_steps=int(rng.integers(1, 7)), sensor_latency_steps=int(rng.integers(1, 3)),
                             k_acc_per_s=u(0.1, 0.5))
        v = TestbedVehicle(af, prop, bat, imu, cam, ap).check()
        if lumped_equivalent(v, "altitude").T1 <= 1.9:
            return v
    raise RuntimeError("no vehicle drawn inside the box")  # pragma: no cover
