"""One flight of the testbed vehicle: physics at 1 kHz, the autopilot and the tested loop's controller at 200 Hz.

Per control sample the autopilot reads the tested loop's measurement (the
sensor chain's output ``sensor_latency_steps`` physics steps old, through the
hidden measurement effects), calls the controller once with ``e = r - y``
(``uavsim.control`` NPMRFT / MRFT / PD, the session format's semantics),
computes holds for the axes not under test (attitude and yaw from the
attitude filter and the gyro; altitude, during attitude tests, from the true
height: the idealised barometer), and then, for each physics step, passes
the held command through the hidden command effects, scales it to a
collective force or a moment, mixes the wrench to rotor thrusts with the
autopilot's *linear* thrust model (trimmed at hover at the start of each
segment, assuming the nominal battery voltage), converts to PWM, delays it by
the transport latency and hands it to the ESCs (``uavsim.testbed.propulsion``).

    fl = Flight(vehicle, "roll", effects=[], rng=np.random.default_rng(1))
    rec = fl.fly(controller, duration_s=10.0)           # FlightRecord: t, r, y, u (+ y_true, saturation)
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass

import mujoco
import numpy as np

from uavsim.errors import UserError
from uavsim.testbed.airframe import G, airframe_mjcf
from uavsim.testbed.battery import BatteryPack
from uavsim.testbed.hidden import CommandChain, HiddenEffect, MeasurementChain
from uavsim.testbed.propulsion import Rotors
from uavsim.testbed.sensors import AltitudeFilter, AttitudeFilter, Camera, Imu, euler_rp
from uavsim.testbed.vehicle import TESTBED_LOOPS, TestbedVehicle

__all__ = ["Flight", "FlightRecord"]

#: wrench index of each tested loop: [collective force, roll moment, pitch moment, yaw moment]
_WRENCH = {"altitude": 0, "roll": 1, "pitch": 2}
_ZETA = 0.7
_ALT_HOLD_OMEGA = 2.5  # rad/s
_YAW_HOLD_OMEGA = 2.0  # rad/s


@dataclass
class FlightRecord:
    """One recorded segment at the control rate.

    Attributes
    ----------
    t : (T,) s from the segment's start
    r, y, u : (T,) reference, measurement as the controller saw it, command as it computed it
    y_true : (T,) the true output (height above the start, or the Euler angle)
    saturated : (T,) bool, any ESC command clipped during the sample
    voltage_V : (T,) battery terminal voltage
    """

    t: np.ndarray
    r: np.ndarray
    y: np.ndarray
    u: np.ndarray
    y_true: np.ndarray
    saturated: np.ndarray
    voltage_V: np.ndarray


class Flight:
    """The vehicle in the air, hovering at the start, with ``effects`` hidden in it.

    Parameters
    ----------
    vehicle : TestbedVehicle
    loop : str
        ``altitude``, ``roll`` or ``pitch``: the loop under test.
    effects : list of HiddenEffect
    rng : numpy Generator
        Feeds every sensor's noise and the effects' random phases.
    """

    def __init__(self, vehicle: TestbedVehicle, loop: str, effects: list[HiddenEffect], rng: np.random.Generator):
        if loop not in TESTBED_LOOPS:
            raise UserError(f"testbed: loop must be one of {', '.join(TESTBED_LOOPS)}, got {loop!r}")
        self.v = vehicle.check()
        self.loop = loop
        ap, af, pr = self.v.autopilot, self.v.airframe, self.v.propulsion
        self.dt = ap.physics_dt_s
        self.model = mujoco.MjModel.from_xml_string(airframe_mjcf(af, timestep=self.dt))
        self.data = mujoco.MjData(self.model)
        mujoco.mj_forward(self.model, self.data)
        self.body = self.model.body("frame").id
        s = self.model.sensor
        self._sl = {n: slice(s(n).adr[0], s(n).adr[0] + s(n).dim[0]) for n in ("gyro", "accel", "vel")}
        self.z0 = float(self.data.qpos[2])
        self.pos = af.rotor_positions()
        self.spin = af.spin()
        self.w_h = self.v.hover_speed
        self.T_h = af.mass_kg * G / 6.0
        self.battery = BatteryPack(self.v.battery)
        self.rotors = Rotors(pr)
        V0 = self.battery.terminal_voltage(6 * pr.k_torque_Nm_s2 * self.w_h**3)
        self.trim(V0)
        self.rotors.reset(np.full(6, self.w_h), np.full(6, self.pwm_hover))
        self.phase = rng.uniform(0, 2 * math.pi, 6)
        self.rng = rng
        self.imu = Imu(self.v.imu, rng, self.w_h, 1.0 / self.dt)
        self.att = AttitudeFilter(ap.k_acc_per_s, self.dt, self.data.qpos[3:7].copy())
        self.gyro_m = np.zeros(3)
        if loop == "altitude":
            self.camera = Camera(self.v.camera, rng, self.w_h)
            self.alt = AltitudeFilter(self.v.camera, self.v.imu, self.dt, 0.0)
        self.cmd = CommandChain(effects, self.dt, ap.rate_hz, rng)
        self.meas = MeasurementChain(effects, self.dt, rng)
        # autopilot's allocation: thrusts -> [force, roll, pitch, yaw moment]
        A = np.stack([np.ones(6), self.pos[:, 1], -self.pos[:, 0], -self.spin * pr.k_torque_Nm_s2 / pr.k_thrust_N_s2])
        self.mixer = np.linalg.pinv(A)
        V_nom = self.v.battery.nominal_V
        self.slope_nom = 2 * pr.k_thrust_N_s2 * self.w_h * pr.kv_rad_per_s_V * V_nom / 1000.0  # N per us
        self.pwm_queue: deque[np.ndarray] = deque([np.full(6, self.pwm_hover)] * ap.latency_steps)
        self.t = 0.0
        self.sensor_hist: deque[float] = deque([0.0] * (ap.sensor_latency_steps + 1), maxlen=ap.sensor_latency_steps + 1)
        self.sat_now = False

    # -- autopilot ------------------------------------------------------------
    def trim(self, V: float | None = None) -> None:
        """Learn the hover throttle at the present battery voltage (what an autopilot's hover estimate does)."""
        if V is None:
            V = self.battery.voltage_V
        pr = self.v.propulsion
        self.pwm_hover = 1000.0 + 1000.0 * pr.throttle_for(self.w_h, V)

    def _euler_true(self) -> tuple[float, float]:
        return euler_rp(self.data.qpos[3:7])

    def true_output(self) -> float:
        if self.loop == "altitude":
            return float(self.data.qpos[2]) - self.z0
        r, p = self._euler_true()
        return r if self.loop == "roll" else p

    def _holds(self) -> np.ndarray:
        """Wrench [N, N m, N m, N m] of the holds on every axis but the tested one."""
        a = self.v.airframe
        om = self.v.autopilot.hold_omega_rad_s
        roll, pitch = euler_rp(self.att.q)
        g = self.gyro_m
        q = self.data.qpos[3:7]
        yaw = math.atan2(2 * (q[0] * q[3] + q[1] * q[2]), 1 - 2 * (q[2] ** 2 + q[3] ** 2))
        wr = np.zeros(4)
        if self.loop != "roll":
            wr[1] = -a.Jx_kgm2 * (om * om * roll + 2 * _ZETA * om * g[0])
        if self.loop != "pitch":
            wr[2] = -a.Jy_kgm2 * (om * om * pitch + 2 * _ZETA * om * g[1])
        wr[3] = -a.Jz_kgm2 * (_YAW_HOLD_OMEGA**2 * yaw + 2 * _ZETA * _YAW_HOLD_OMEGA * self.data.qvel[5])
        tilt = max(math.cos(roll) * math.cos(pitch), 0.5)
        wr[0] = a.mass_kg * G * (1.0 / tilt - 1.0)
        if self.loop != "altitude":
            oz = _ALT_HOLD_OMEGA
            wr[0] += -a.mass_kg * (oz * oz * (self.data.qpos[2] - self.z0) + 2 * _ZETA * oz * self.data.qvel[2])
        return wr

    def command_range(self) -> tuple[float, float]:
        """The loop's command (command units) at which the mixer first drives a rotor's PWM to its lower and
        upper limit from the present hover trim, holds aside: ``(low < 0, high > 0)``, what an autopilot's
        output range states (the ``[actuator]`` of a session)."""
        pr = self.v.propulsion
        ap = self.v.autopilot
        unit = ap.force_unit_N if self.loop == "altitude" else ap.moment_unit_Nm
        col = self.mixer[:, _WRENCH[self.loop]] * unit / self.slope_nom  # us per command unit, per rotor
        up, down = pr.pwm_max_us - self.pwm_hover, pr.pwm_min_us - self.pwm_hover
        pos, neg = col > 1e-12, col < -1e-12
        high = min(np.min(up / col[pos], initial=np.inf), np.min(down / col[neg], initial=np.inf))
        low = max(np.max(down / col[pos], initial=-np.inf), np.max(up / col[neg], initial=-np.inf))
        return float(low), float(high)

    def _pwm(self, wrench: np.ndarray) -> np.ndarray:
        return self.pwm_hover + (self.mixer @ wrench) / self.slope_nom

    # -- physics --------------------------------------------------------------
    def _physics_step(self, pwm: np.ndarray) -> None:
        d, a, pr = self.data, self.v.airframe, self.v.propulsion
        sd = d.sensordata
        om = sd[self._sl["gyro"]].copy()
        vb = sd[self._sl["vel"]].copy()
        v_axial = vb[2] + om[0] * self.pos[:, 1] - om[1] * self.pos[:, 0]
        V = self.battery.step(self.rotors.power_W(), self.dt)
        thrust, torque = self.rotors.step(pwm, V, v_axial, self.t, self.dt)
        self.sat_now = self.sat_now or bool(self.rotors.saturated.any())
        self.phase = (self.phase + self.rotors.w * self.dt) % (2 * math.pi)
        speed = math.sqrt(float(vb @ vb))
        F = np.array([0.0, 0.0, thrust.sum()]) - np.asarray(a.drag_lin_N_s_per_m) * vb - a.drag_quad_N_s2_per_m2 * speed * vb
        h_rot = pr.rotor_inertia_kgm2 * float(self.spin @ self.rotors.w)
        M = np.array([thrust @ self.pos[:, 1], -(thrust @ self.pos[:, 0]), -(self.spin @ torque)])
        M -= np.cross(om, [0.0, 0.0, h_rot])
        R = d.xmat[self.body].reshape(3, 3)
        d.xfrc_applied[self.body, :3] = R @ F
        d.xfrc_applied[self.body, 3:] = R @ M
        mujoco.mj_step(self.model, d)
        self.t += self.dt
        gyro_m, acc_m = self.imu(sd[self._sl["gyro"]], sd[self._sl["accel"]], self.phase, self.rotors.w)
        self.gyro_m = gyro_m
        q_est = self.att(gyro_m, acc_m)
        if self.loop == "altitude":
            w, x, y, z = q_est
            # vertical specific force in the world frame, with the estimated attitude
            a_z = 2 * (x * z - w * y) * acc_m[0] + 2 * (y * z + w * x) * acc_m[1] + (1 - 2 * (x * x + y * y)) * acc_m[2]
            s = self.alt.predict(a_z - G)
            for zc, kc in self.camera.step(self.t, self.alt.k, float(d.qpos[2]) - self.z0, self.phase, self.rotors.w):
                s = self.alt.correct(zc, kc)
        else:
            roll, pitch = euler_rp(q_est)
            s = roll if self.loop == "roll" else pitch
        self.sensor_hist.append(self.meas.physics(self.t, s))

    def _runaway(self) -> bool:
        q = self.data.qpos
        if not np.isfinite(q).all() or abs(q[2] - self.z0) > 50:
            return True
        roll, pitch = self._euler_true()
        return abs(roll) > 1.2 or abs(pitch) > 1.2

    # -- segments ---------------------------------------------------------------
    def fly(self, controller: Callable[[np.ndarray], np.ndarray], duration_s: float,
            reference: Callable[[float], float] | None = None, *, trim: bool = True) -> FlightRecord:
        """Fly ``duration_s`` with ``controller`` closing the tested loop; record it.

        Parameters
        ----------
        controller : callable e (1,) -> u (1,)
            Called once per control sample (``uavsim.control`` relays and PD with ``n = 1``), with
            the reference ``r`` (1,) too when it has a true ``reads_reference``.
        duration_s : float
        reference : callable t -> r, optional (zero by default)
        trim : bool
            Re-learn the hover throttle at the segment's start (as after a hover).
        """
        ap = self.v.autopilot
        if trim:
            self.trim()
        T = int(round(duration_s * ap.rate_hz))
        unit = ap.force_unit_N if self.loop == "altitude" else ap.moment_unit_Nm
        widx = _WRENCH[self.loop]
        out = {k: np.empty(T) for k in ("t", "r", "y", "u", "y_true", "voltage_V")}
        sat = np.zeros(T, dtype=bool)
        t_start = self.t
        with_r = bool(getattr(controller, "reads_reference", False))
        for k in range(T):
            t_rel = k / ap.rate_hz
            y = self.meas.sample(self.sensor_hist[0])
            r = 0.0 if reference is None else float(reference(t_rel))
            e = np.array([r - y])
            u = float(np.asarray(controller(e, np.array([r])) if with_r else controller(e))[0])
            out["t"][k], out["r"][k], out["y"][k], out["u"][k] = t_rel, r, y, u
            out["y_true"][k] = self.true_output()
            out["voltage_V"][k] = self.battery.voltage_V
            self.cmd.push(t_start + t_rel, u)
            hold = self._holds()
            self.sat_now = False
            for _ in range(ap.substeps):
                wr = hold.copy()
                wr[widx] += unit * self.cmd(self.t)
                self.pwm_queue.append(self._pwm(wr))
                self._physics_step(self.pwm_queue.popleft())
            sat[k] = self.sat_now
            if self._runaway():
                # a crash log ends where the crash is
                T = k + 1
                break
        out = {key: val[:T] for key, val in out.items()}
        sat = sat[:T]
        return FlightRecord(out["t"], out["r"], out["y"], out["u"], out["y_true"], sat, out["voltage_V"])
