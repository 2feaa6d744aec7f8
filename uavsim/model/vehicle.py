"""The hexarotor as MJCF, generated from a parameter dataclass.

By default the paper's vehicle: 3.38 kg, Jx = 0.093, Jy = 0.089,
Jz = 0.156 kg m^2, six rotors on a 111 x 100 cm frame, E600 propulsion with
PWM saturation at 1165 / 1878 us, lateral command limit +-0.2617 rad, a 20 Hz
2nd-order Butterworth on the measurements and a 200 Hz controller.

The rigid body is expressed as six one-degree-of-freedom joints (slides x, y,
z, then hinges roll, pitch, yaw through the centre of mass) instead of a free
joint, so that each axis carries its own damping: that damping is how the
lumped body time constants T1 (attitude, altitude) and T2 (lateral) enter
the physics (``uavsim.model.mapping``). Each rotor is a ``general`` actuator
on a site, with ``filterexact`` first-order dynamics (the propulsion lag
T_prop), a history buffer for the loop delay, and ``ctrl`` in microseconds of
PWM *relative to hover*: the hover thrust is the actuator's constant bias, so
``ctrl = 0`` hovers and an empty history buffer is a hovering past.

    v = Vehicle()
    xml = hexarotor_mjcf(v)
    model = mujoco.MjModel.from_xml_string(xml)
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from uavsim.errors import UserError

G = 9.81  # m/s^2

JOINTS = ("x", "y", "z", "roll", "pitch", "yaw")


@dataclass(frozen=True)
class Vehicle:
    """Physical parameters of the hexarotor (SI units unless the name says otherwise)."""

    mass_kg: float = 3.38
    Jx_kgm2: float = 0.093
    Jy_kgm2: float = 0.089
    Jz_kgm2: float = 0.156
    frame_x_m: float = 1.11  # tip-to-tip extent along x, propellers included
    frame_y_m: float = 1.00
    height_m: float = 0.27
    prop_radius_m: float = 0.19
    n_rotors: int = 6
    pwm_min_us: float = 1165.0  # measured saturation of the E600 ESCs
    pwm_max_us: float = 1878.0
    pwm_hover_us: float = 1500.0
    yaw_moment_m: float = 0.016  # reaction torque per newton of thrust
    lateral_limit_rad: float = 0.2617
    measurement_lowpass_hz: float = 20.0
    control_rate_hz: float = 200.0

    def check(self) -> Vehicle:
        for name in ("mass_kg", "Jx_kgm2", "Jy_kgm2", "Jz_kgm2", "frame_x_m", "frame_y_m", "control_rate_hz"):
            v = getattr(self, name)
            if not math.isfinite(v) or v <= 0:
                raise UserError(f"vehicle: {name} must be > 0, got {v}")
        if not self.pwm_min_us < self.pwm_hover_us < self.pwm_max_us:
            raise UserError("vehicle: need pwm_min_us < pwm_hover_us < pwm_max_us")
        if self.n_rotors != 6:
            raise UserError("vehicle: only hexarotors (n_rotors = 6) are modelled")
        return self

    @property
    def hover_thrust_per_rotor_N(self) -> float:
        return self.mass_kg * G / self.n_rotors

    @property
    def thrust_per_us(self) -> float:
        """Rotor thrust slope, N per microsecond of PWM, linear about hover."""
        return self.hover_thrust_per_rotor_N / (self.pwm_hover_us - 1000.0)

    def rotor_positions(self) -> np.ndarray:
        """(6, 2) rotor centres in the body frame, m; rotors at 30, 90, ..., 330 degrees."""
        ang = np.deg2rad(30.0 + 60.0 * np.arange(6))
        # the frame's extents include the propeller discs
        ax = (self.frame_x_m / 2 - self.prop_radius_m) / max(abs(np.cos(ang)).max(), 1e-9)
        ay = (self.frame_y_m / 2 - self.prop_radius_m) / max(abs(np.sin(ang)).max(), 1e-9)
        # rounded so that cos(90 deg) is 0, not 6e-17: stray round-off in the
        # mixer would leak torque into axes a test holds still
        return np.round(np.stack([ax * np.cos(ang), ay * np.sin(ang)], axis=1), 12)

    def spin(self) -> np.ndarray:
        """(6,) rotor spin directions (+1 counter-clockwise), alternating."""
        return np.array([1.0, -1.0, 1.0, -1.0, 1.0, -1.0])

    def allocation(self) -> np.ndarray:
        """(4, 6) map from rotor thrusts (N) to [thrust N, roll Nm, pitch Nm, yaw Nm]."""
        p = self.rotor_positions()
        return np.stack([np.ones(6), p[:, 1], -p[:, 0], self.yaw_moment_m * self.spin()])

    def mixer(self) -> np.ndarray:
        """(6, 4) map from a wrench [thrust, roll, pitch, yaw] to rotor thrusts (N)."""
        M = np.linalg.pinv(self.allocation())
        return np.where(np.abs(M) < 1e-12, 0.0, M)


def hexarotor_mjcf(
    v: Vehicle | None = None,
    *,
    timestep: float = 0.001,
    max_delay_s: float = 0.25,
    saturation: bool = False,
    damping: tuple[float, float, float, float, float, float] | None = None,
    T_prop: float = 0.05,
    delay_s: float = 0.0,
) -> str:
    """MJCF text of the hexarotor.

    Parameters
    ----------
    v : Vehicle
        Physical parameters (default: the paper's vehicle).
    timestep : float
        Physics step, s.
    max_delay_s : float
        Longest actuator delay any episode of a batch will use, s; sizes the
        history buffers (per-episode delays are set later through
        ``actuator_delay``).
    saturation : bool
        Clip rotor commands to the measured PWM range.
    damping : 6 floats
        Joint damping for x, y, z (N s/m) and roll, pitch, yaw (N m s/rad).
    T_prop : float
        Propulsion time constant, s (default for the model; batches set it per episode).
    delay_s : float
        Actuator delay, s (default for the model).
    """
    v = (v or Vehicle()).check()
    if timestep <= 0 or not math.isfinite(timestep):
        raise UserError(f"timestep must be > 0 s, got {timestep}")
    damp = damping or (0.5, 0.5, 0.5, 0.05, 0.05, 0.1)
    nsample = int(math.ceil(max_delay_s / timestep)) + 3
    kt = v.thrust_per_us
    lo, hi = v.pwm_min_us - v.pwm_hover_us, v.pwm_max_us - v.pwm_hover_us
    limited = "true" if saturation else "false"
    pos = v.rotor_positions()
    spin = v.spin()
    arms, rotors, sites, acts = [], [], [], []
    for i, ((x, y), s) in enumerate(zip(pos, spin, strict=True)):
        arms.append(
            f'<geom type="capsule" fromto="0 0 0 {x:.4f} {y:.4f} 0" size="0.012" rgba=".2 .2 .2 1" contype="0" conaffinity="0" mass="0"/>'
        )
        color = ".85 .3 .2 .6" if i in (0, 5) else ".3 .3 .35 .6"
        rotors.append(
            f'<geom type="cylinder" pos="{x:.4f} {y:.4f} 0.03" size="{v.prop_radius_m:.3f} 0.004" rgba="{color}" contype="0" conaffinity="0" mass="0"/>'
        )
        sites.append(f'<site name="rotor{i}" pos="{x:.4f} {y:.4f} 0.03" size="0.01"/>')
        acts.append(
            f'<general name="rotor{i}" site="rotor{i}" gear="0 0 1 0 0 {s * v.yaw_moment_m:.4f}" '
            f'dyntype="filterexact" dynprm="{T_prop}" gaintype="fixed" gainprm="{kt:.8g}" '
            f'biastype="affine" biasprm="{v.hover_thrust_per_rotor_N:.8g} 0 0" '
            f'ctrllimited="{limited}" ctrlrange="{lo:g} {hi:g}" '
            f'nsample="{nsample}" delay="{delay_s:.8g}" interp="linear"/>'
        )
    dx, dy, dz, dr, dp, dyaw = damp
    return f"""<mujoco model="uavsim-hexarotor">
  <!-- generated by uavsim.model.vehicle; rotor ctrl is PWM microseconds relative to hover -->
  <option timestep="{timestep}" integrator="Euler" gravity="0 0 {-G}"/>
  <visual><global offwidth="1280" offheight="720"/></visual>
  <worldbody>
    <light pos="0 0 6" dir="0 0 -1"/>
    <geom name="ground" type="plane" size="10 10 0.1" pos="0 0 -2" rgba=".85 .87 .9 1" contype="0" conaffinity="0"/>
    <body name="hexarotor" pos="0 0 0">
      <joint name="x" type="slide" axis="1 0 0" damping="{dx}"/>
      <joint name="y" type="slide" axis="0 1 0" damping="{dy}"/>
      <joint name="z" type="slide" axis="0 0 1" damping="{dz}"/>
      <joint name="roll" type="hinge" axis="1 0 0" damping="{dr}"/>
      <joint name="pitch" type="hinge" axis="0 1 0" damping="{dp}"/>
      <joint name="yaw" type="hinge" axis="0 0 1" damping="{dyaw}"/>
      <inertial pos="0 0 0" mass="{v.mass_kg}" diaginertia="{v.Jx_kgm2} {v.Jy_kgm2} {v.Jz_kgm2}"/>
      <geom type="box" size="0.12 0.10 {v.height_m / 4:.3f}" rgba=".15 .35 .7 1" contype="0" conaffinity="0" mass="0"/>
      {chr(10).join('      ' + g for g in arms + rotors + sites).strip()}
    </body>
  </worldbody>
  <actuator>
    {chr(10).join('    ' + a for a in acts).strip()}
  </actuator>
  <sensor>
    <jointpos name="x" joint="x" nsample="{nsample}" interp="linear"/>
    <jointpos name="y" joint="y" nsample="{nsample}" interp="linear"/>
    <jointpos name="x_step" joint="x"/>
    <jointpos name="y_step" joint="y"/>
    <jointpos name="z" joint="z"/>
    <jointpos name="roll" joint="roll"/>
    <jointpos name="pitch" joint="pitch"/>
    <jointpos name="yaw" joint="yaw"/>
  </sensor>
</mujoco>
"""
