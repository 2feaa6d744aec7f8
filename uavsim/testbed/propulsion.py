"""Rotors with speed states: ESC saturation, slew and update rate, motor lag, thrust ``k_T w^2``.

Each of the six rotors is a first-order motor in rotor *speed*::

    w' = (w_ss - w) / T_motor,      w_ss = kv * V_battery * throttle,
    throttle = (pwm - 1000 us) / 1000 us

driven by an ESC that reads its PWM command at ``esc_rate_hz`` (a held
sample), clips it to the measured range (1165-1878 us on the paper's E600
ESCs) and slews its output at most ``slew_us_per_s``. The rotor's thrust is
quadratic in speed and falls with the axial velocity of its hub (momentum
theory, linearised in the inflow)::

    T_i = k_T w_i^2 - k_inflow w_i v_axial,i

which is where the airframe's damping comes from: the same term damps the
climb rate (``sum k_inflow w``) and the roll and pitch rates (``v_axial``
includes ``omega x r_i``). So the command-to-thrust map is nonlinear around
hover and the loop gain moves with the battery voltage. The reaction torque
is ``k_Q w^2``; the mechanical power ``k_Q w^3`` loads the battery.

    rotors = Rotors(PropulsionParams(), n=6)
    rotors.reset(w0=np.full(6, 550.0), pwm0=np.full(6, 1500.0))
    thrust, torque = rotors.step(pwm_cmd, V=22.8, v_axial=np.zeros(6), t_s=0.001, dt_s=0.001)
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from uavsim.errors import UserError

__all__ = ["PropulsionParams", "Rotors"]


@dataclass(frozen=True)
class PropulsionParams:
    """Motors, propellers and ESCs (all six alike).

    Attributes
    ----------
    k_thrust_N_s2 : float
        Thrust coefficient, N per (rad/s)^2.
    k_torque_Nm_s2 : float
        Reaction torque coefficient, N m per (rad/s)^2.
    k_inflow_N_s2_per_m : float
        Thrust lost per (rad/s of rotor speed x m/s of axial hub velocity), N s^2 / m.
    T_motor_s : float
        Motor speed time constant, s.
    kv_rad_per_s_V : float
        Steady rotor speed per volt at full throttle, rad/s/V.
    pwm_min_us, pwm_max_us : float
        ESC command saturation, us.
    slew_us_per_s : float
        Largest rate of change of the ESC's output, us/s.
    esc_rate_hz : float
        Rate at which the ESC samples its PWM command, Hz.
    rotor_inertia_kgm2 : float
        Rotor and propeller inertia about the shaft (gyroscopic torque), kg m^2.
    """

    k_thrust_N_s2: float = 1.83e-5
    k_torque_Nm_s2: float = 2.93e-7
    k_inflow_N_s2_per_m: float = 2.0e-4
    T_motor_s: float = 0.06
    kv_rad_per_s_V: float = 48.0
    pwm_min_us: float = 1165.0
    pwm_max_us: float = 1878.0
    slew_us_per_s: float = 30000.0
    esc_rate_hz: float = 400.0
    rotor_inertia_kgm2: float = 2.0e-4

    def check(self) -> PropulsionParams:
        for name in ("k_thrust_N_s2", "k_torque_Nm_s2", "T_motor_s", "kv_rad_per_s_V", "slew_us_per_s", "esc_rate_hz"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise UserError(f"propulsion: {name} must be > 0, got {v}")
        if not 1000.0 <= self.pwm_min_us < self.pwm_max_us <= 2000.0:
            raise UserError("propulsion: need 1000 <= pwm_min_us < pwm_max_us <= 2000")
        if self.k_inflow_N_s2_per_m < 0 or self.rotor_inertia_kgm2 < 0:
            raise UserError("propulsion: k_inflow and rotor inertia must be >= 0")
        return self

    def hover_speed(self, thrust_N: float) -> float:
        """Rotor speed that gives ``thrust_N`` at rest, rad/s."""
        return math.sqrt(thrust_N / self.k_thrust_N_s2)

    def throttle_for(self, w: float, V: float) -> float:
        """Throttle fraction whose steady speed is ``w`` (rad/s) at ``V`` volts."""
        return w / (self.kv_rad_per_s_V * V)


class Rotors:
    """ESC and motor states of ``n`` rotors, advanced one physics step at a time."""

    def __init__(self, params: PropulsionParams, n: int = 6):
        self.p = params.check()
        self.n = int(n)
        self.reset(np.zeros(self.n), np.full(self.n, 1000.0))

    def reset(self, w0: np.ndarray, pwm0: np.ndarray) -> None:
        """Start at rotor speeds ``w0`` (rad/s) with the ESCs' output at ``pwm0`` (us)."""
        self.w = np.array(w0, dtype=np.float64)
        self.pwm_out = np.array(pwm0, dtype=np.float64)
        self.pwm_target = self.pwm_out.copy()
        self._next_esc = 0.0
        self.saturated = np.zeros(self.n, dtype=bool)

    def step(self, pwm_cmd: np.ndarray, V: float, v_axial: np.ndarray, t_s: float,
             dt_s: float) -> tuple[np.ndarray, np.ndarray]:
        """Advance ``dt_s`` from time ``t_s`` with the PWM command ``pwm_cmd`` (n,) us.

        Parameters
        ----------
        pwm_cmd : (n,) us, what the flight controller sends
        V : battery terminal voltage, V
        v_axial : (n,) m/s, hub velocities along the rotor axes (climbing is positive)
        t_s, dt_s : s

        Returns
        -------
        thrust : (n,) N
        torque : (n,) N m, reaction torque magnitude (sign by spin direction is the caller's)
        """
        p = self.p
        if t_s + 1e-12 >= self._next_esc:
            # the ESC samples its command; between samples it holds the last one
            self.pwm_target = np.clip(pwm_cmd, p.pwm_min_us, p.pwm_max_us)
            self.saturated = (pwm_cmd < p.pwm_min_us) | (pwm_cmd > p.pwm_max_us)
            self._next_esc += 1.0 / p.esc_rate_hz
        step = p.slew_us_per_s * dt_s
        self.pwm_out = self.pwm_out + np.clip(self.pwm_target - self.pwm_out, -step, step)
        w_ss = p.kv_rad_per_s_V * V * (self.pwm_out - 1000.0) / 1000.0
        self.w = self.w + (w_ss - self.w) * (1.0 - math.exp(-dt_s / p.T_motor_s))
        w = np.maximum(self.w, 0.0)
        thrust = np.maximum(p.k_thrust_N_s2 * w * w - p.k_inflow_N_s2_per_m * w * v_axial, 0.0)
        torque = p.k_torque_Nm_s2 * w * w
        return thrust, torque

    def power_W(self) -> float:
        """Mechanical power of the rotors, W."""
        w = np.maximum(self.w, 0.0)
        return float(self.p.k_torque_Nm_s2 * np.sum(w * w * w))
