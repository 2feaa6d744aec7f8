"""Batched closed-loop episodes on ``mujoco.batch``.

``LoopBatch`` runs ``n`` episodes of one loop of the hexarotor at once: every
episode has its own lumped parameters (mapped onto the MuJoCo model by
``uavsim.model.mapping``) and its own random draws. Between two controller
samples the physics advances ``rate_steps = 1 / (rate_hz * dt)`` substeps in
one ``Batch.step`` call on all threads; the controller, the measurement chain
and the command chain run vectorized in numpy on ``(n,)`` arrays. The
controller sees the measurement chain (noise, quantization, sample-and-hold,
filters), never ground truth.

    lb = LoopBatch(params, dt=0.0005, rate_hz=200.0, effects=[make_effect("noise", std=0.002)], seed=7)
    res = lb.run(NPMRFT(beta=-0.73, h=1.0, tau_obs=0.02, a_n=0.004, rate_hz=200.0, n=lb.n), duration_s=20.0)
    res.t.shape, res.y.shape     # (T,), (n, T): t, r, y, u recorded at the control rate

Episodes that diverge (NaN, a runaway state, a MuJoCo error) are flagged in
``res.diverged`` with a reason, and their rows are NaN: they are never
returned as data (``res.valid()`` keeps the others).

``run`` is one loop over a small public stepping API that other episode
loops (the vision scenarios, replays) use as well, so that the physics, the
actuation and the divergence checks exist once:

    rng = lb.start(T)                   # effects reset from the seed; or start(T, measurement=stage)
    for k in range(T):
        y_true, y = lb.measure(k)       # true output, and what the measurement stage makes of it
        lb.actuate(controller(r[k] - y), k)   # command effects, attitude loop, holds, forces
        lb.step(k)                      # physics over one control period, divergence checks

With ``record_state=True`` the result also holds the vehicle's joint
positions ``qpos`` and the six rotor thrusts ``rotor_force``, (n, T, 6) at the
control rate, for replays (``uavsim.viz``); it is off by default, and then
nothing more is bound or copied per step.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Protocol

import mujoco
import numpy as np
from mujoco import batch as mjbatch

from uavsim.cpus import available_cpus
from uavsim.errors import UserError
from uavsim.lumped.params import LumpedParams
from uavsim.model.effects.base import Effect
from uavsim.model.mapping import WRENCH, LoopMapping, map_params
from uavsim.model.vehicle import G, Vehicle, hexarotor_mjcf

# Ideal holds on the axes a loop does not test: slow and well damped, so that
# they stay stable with any rotor lag and delay of the paper's ranges.
_HOLD_OMEGA = 2.0  # rad/s
_TIME = mujoco.mjtState.mjSTATE_TIME


@dataclass(kw_only=True)
class EpisodeResult:
    """Recorded episodes, at the control rate.

    Attributes
    ----------
    t : (T,) s
    r, y, u : (n, T) reference, measurement as the controller saw it, command as it computed it
    y_true : (n, T) the loop's true output (no sensor effects)
    diverged : (n,) bool; diverged rows are NaN
    reasons : dict episode -> why it diverged
    switched : (n, T) bool, where the controller reported a switch (relays), else None
    seed : the batch's seed
    qpos : (n, T, 6) or None
        Joint positions x, y, z (m), roll, pitch, yaw (rad) at each control
        sample, before the physics advances (``record_state=True`` only).
    rotor_force : (n, T, 6) or None
        Thrust of each rotor, N, in the last physics substep after control
        sample ``k`` (what the rotors produced while command ``k`` was held;
        ``record_state=True`` only).
    """

    t: np.ndarray
    r: np.ndarray
    y: np.ndarray
    u: np.ndarray
    y_true: np.ndarray
    diverged: np.ndarray
    reasons: dict[int, str] = field(default_factory=dict)
    switched: np.ndarray | None = None
    seed: int = 0
    qpos: np.ndarray | None = None
    rotor_force: np.ndarray | None = None

    @property
    def n(self) -> int:
        return self.y.shape[0]

    def valid(self) -> np.ndarray:
        """Indices of the episodes that did not diverge, (m,)."""
        return np.flatnonzero(~self.diverged)


def _out_delay_weights(out_delay: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Weights of (state now, state one step ago, delayed sensor) that give an output delay.

    MuJoCo's sensor history cannot interpolate inside the newest step: a sensor
    delay in (0, dt] reads the state two steps back, like a delay of dt. So an
    output delay ``L`` (s) below two steps is made by linear interpolation
    between the state now (lag 0), an undelayed sensor (lag dt) and the
    sensor delayed by dt (lag 2 dt); from two steps on the delayed sensor
    (delay ``L - dt``) interpolates natively.

    Parameters
    ----------
    out_delay : (n,) s
    dt : float, physics step, s

    Returns
    -------
    w_now, w_step, w_out : (n,) each, summing to 1
    """
    L = np.asarray(out_delay, dtype=np.float64)
    a = np.clip(L / dt, 0.0, 1.0)  # between now and one step ago
    b = np.clip(L / dt - 1.0, 0.0, 1.0)  # between one and two steps ago
    far = L >= 2.0 * dt
    w_now = np.where(far, 0.0, 1.0 - a)
    w_step = np.where(far, 0.0, a - b)
    w_out = np.where(far, 1.0, b)
    return w_now, w_step, w_out


class MeasurementStage(Protocol):
    """What the controller sees of the loop's true output: reset once per run, then once per control sample."""

    def reset(self, n: int, rate_hz: float, rng: np.random.Generator) -> None:
        """Start ``n`` episodes at control rate ``rate_hz``, drawing from ``rng``."""

    def __call__(self, y_true: np.ndarray, k: int) -> np.ndarray:
        """The measurement at sample ``k`` from the true output, (n,) -> (n,)."""


class EffectChain:
    """The default measurement stage: the measurement effects, applied in order."""

    def __init__(self, effects: Sequence[Effect]) -> None:
        self.effects = list(effects)

    def reset(self, n: int, rate_hz: float, rng: np.random.Generator) -> None:
        for e in self.effects:
            e.reset(n, rate_hz, rng)

    def __call__(self, y_true: np.ndarray, k: int) -> np.ndarray:
        y = y_true
        for e in self.effects:
            y = e(y, k)
        return y


def _index(idx: Sequence[int]) -> slice | np.ndarray:
    """Columns ``idx`` as a slice where they are consecutive (a view, not a gather), else an index array."""
    if all(b == a + 1 for a, b in zip(idx, idx[1:], strict=False)):
        return slice(idx[0], idx[-1] + 1)
    return np.array(idx)


def _split_effects(effects: Sequence[Effect]):
    model, command, measurement, force = [], [], [], []
    for e in effects:
        {"model": model, "command": command, "measurement": measurement, "force": force}[e.target].append(e)
    return model, command, measurement, force


class LoopBatch:
    """``n`` closed-loop episodes of one hexarotor loop on a ``mujoco.batch.Batch``.

    Parameters
    ----------
    params : sequence of LumpedParams, length n
        One lumped process per episode, all of the same loop.
    vehicle : Vehicle
        The airframe (default: the paper's hexarotor).
    dt : float
        Physics step, s; ``1 / (rate_hz dt)`` must be an integer.
    rate_hz : float
        Controller rate, Hz.
    effects : sequence of Effect
        Applied to every episode (parameters may be arrays of shape (n,)).
    seed : int
        Seed of every random draw of the batch (effects, noise).
    nthread : int
        Threads of the MuJoCo batch (0: all CPUs).
    y0 : (n,) or None
        Initial value of the tested output (m or rad); 0 by default.
    saturation : bool
        Clip rotor PWM to the vehicle's measured range (off for lumped models).
    record_state : bool
        Also record ``qpos`` and ``rotor_force`` (n, T, 6) in the result (off by
        default: nothing extra is bound or copied).
    """

    def __init__(
        self,
        params: Sequence[LumpedParams],
        *,
        vehicle: Vehicle | None = None,
        dt: float = 0.0005,
        rate_hz: float = 200.0,
        effects: Sequence[Effect] = (),
        seed: int = 0,
        nthread: int = 0,
        y0: np.ndarray | None = None,
        saturation: bool = False,
        record_state: bool = False,
    ):
        self.record_state = bool(record_state)
        self.vehicle = (vehicle or Vehicle()).check()
        if not (math.isfinite(dt) and dt > 0):
            raise UserError(f"physics timestep must be > 0 s, got {dt}")
        steps = 1.0 / (rate_hz * dt)
        if abs(steps - round(steps)) > 1e-6 or round(steps) < 1:
            raise UserError(f"control period 1/{rate_hz} Hz is not a whole number of {dt} s physics steps")
        self.dt, self.rate_hz, self.rate_steps = float(dt), float(rate_hz), int(round(steps))
        self.seed = int(seed)
        self.params = list(params)
        self.effects = list(effects)
        model_fx, self.command_fx, self.measurement_fx, self.force_fx = _split_effects(self.effects)
        extra_delay = sum((np.asarray(e.delay, dtype=float) for e in model_fx if e.name == "delay"), 0.0)
        gain = np.prod([np.asarray(e.factor, dtype=float) for e in model_fx if e.name == "gain"], axis=0) if any(
            e.name == "gain" for e in model_fx
        ) else 1.0
        self.map: LoopMapping = map_params(self.params, self.vehicle, extra_delay, gain)
        self.loop = self.map.loop
        self.n = self.map.n
        self.lateral = self.loop not in WRENCH
        max_delay = float(max(self.map.actuator_delay.max(), self.map.out_delay.max())) + 2 * dt
        xml = hexarotor_mjcf(self.vehicle, timestep=dt, max_delay_s=max_delay, saturation=saturation)
        self.model = mujoco.MjModel.from_xml_string(xml)
        lat_x = self.loop != "lateral_y"
        self._sensor_out = self.model.sensor("x" if lat_x else "y").id
        self._sensor_step = self.model.sensor("x_step" if lat_x else "y_step").id
        self._out_weights = _out_delay_weights(self.map.out_delay, dt)
        self.nthread = nthread
        # wrench -> rotor PWM (us), computed once: pinv is not free at 200 Hz
        self._wrench_to_pwm = (self.vehicle.mixer() / self.vehicle.thrust_per_us).T.copy()
        self._hold_cache: dict[int | None, tuple[np.ndarray, ...]] = {}
        self.y0 = None if y0 is None else np.broadcast_to(np.asarray(y0, dtype=float), (self.n,)).copy()
        self._make_batch()

    def _make_batch(self) -> None:
        m, n = self.map, self.n
        b = mjbatch.Batch(self.model, n, self.nthread or available_cpus())  # 0 would be the host's count
        b.expand("dof_damping")[:] = m.damping
        b.expand("actuator_dynprm")[:, :, 0] = m.T_prop[:, None]
        # MuJoCo's history cannot interpolate inside the newest step (a delay in
        # (0, dt] acts as dt): such delays are applied by advance() instead
        d = np.asarray(m.actuator_delay, dtype=np.float64)
        self._sub_step = (d > 0.0) & (d < self.dt)
        self._sub_frac = np.where(self._sub_step, d / self.dt, 0.0)[:, None]
        # the blend touches only those rows: their indices and weights, once
        self._sub_any = bool(self._sub_step.any())
        self._sub_rows = np.flatnonzero(self._sub_step)
        self._sub_f = self._sub_frac[self._sub_rows]
        self._sub_g = 1.0 - self._sub_f
        self._ctrl_prev = np.zeros((n, self.model.nu))
        # the period's controls per substep, for one rollout call (the blend in the first)
        self._roll_ctrl = np.empty((n, self.rate_steps, self.model.nu)) if self._sub_any else None
        self._roll_time = {_TIME: np.empty((n, self.rate_steps, 1))} if self._sub_any else None
        b.expand("actuator_delay")[:] = np.where(self._sub_step, 0.0, d)[:, None]
        if self.lateral:
            # sensordata lags the state by one substep (it is computed before the
            # last integration), which is part of the outer delay
            sd = b.expand("sensor_delay")
            sd[:, self._sensor_out] = np.maximum(m.out_delay - self.dt, self.dt)
            b.expand("sensor_history")  # noqa: B018  per-simulation buffers follow the delays
        b.reset()
        self.batch = b
        self.qpos = b.bind("qpos")
        self.qvel = b.bind("qvel")
        self.ctrl = b.bind("ctrl")
        self.xfrc = b.bind("xfrc_applied")
        self.sensordata = b.bind("sensordata") if self.lateral else None
        # an output field is copied out after every step once bound: only when asked
        self.actuator_force = b.bind("actuator_force") if self.record_state else None
        if self.y0 is not None:
            self.qpos[:, self.map.axis] = self.y0

    # -- one control sample -------------------------------------------------
    def _hold_gains(self, skip: int | None) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Wrench columns, joint axes and the holds' stiffness and damping, (k,) each, all axes but ``skip``."""
        gains = self._hold_cache.get(skip)
        if gains is None:
            v, om = self.vehicle, _HOLD_OMEGA
            rows = [(widx, ax, -inertia * om * om, 2.0 * inertia * om)
                    for widx, ax, inertia in ((0, 2, v.mass_kg), (1, 3, v.Jx_kgm2), (2, 4, v.Jy_kgm2),
                                              (3, 5, v.Jz_kgm2)) if widx != skip]
            widx, ax, kq, kw = zip(*rows, strict=True)
            gains = (_index(widx), _index(ax), np.array(kq), np.array(kw))
            self._hold_cache[skip] = gains
        return gains

    def _holds(self, wrench: np.ndarray, skip: int | None) -> None:
        """Slow ideal PD holds on the untested axes (on the true state)."""
        # all held axes in one expression (per element the same products as one axis at a time)
        widx, ax, kq, kw = self._hold_gains(skip)
        wrench[:, widx] += kq * self.qpos[:, ax] - kw * self.qvel[:, ax]

    def _apply(self, u_cmd: np.ndarray, att_u: np.ndarray | None) -> None:
        v, m = self.vehicle, self.map
        wrench = np.zeros((self.n, 4))
        if not self.lateral:
            wrench[:, WRENCH[self.loop]] = m.cmd_scale * u_cmd
            self._holds(wrench, WRENCH[self.loop])
        else:
            widx = 2 if self.loop == "lateral_x" else 1
            wrench[:, widx] = m.att_scale * att_u
            self._holds(wrench, widx)
            # keep the vertical thrust at m g while tilted, so x'' = g tan(theta)
            c = np.cos(self.qpos[:, 3]) * np.cos(self.qpos[:, 4])
            wrench[:, 0] += v.mass_kg * G * (1.0 / np.maximum(c, 0.2) - 1.0)
        self.ctrl[:] = wrench @ self._wrench_to_pwm

    def advance(self) -> None:
        """Step the physics over one control period with the command in ``ctrl``.

        Episodes whose actuator delay ``d`` is under one physics step get, in
        the first substep, the blend ``(d/dt) u_prev + (1 - d/dt) u`` of the
        previous and the new command: what MuJoCo's linear history
        interpolation gives for longer delays, which it cannot give inside the
        newest step. The period is then one ``Batch.rollout`` call with the
        controls of each substep (the same ``mj_step`` calls as a
        ``Batch.step`` of the blend's substep and one of the rest, bit for bit,
        at the cost of one call); an episode that the rollout stopped at a
        MuJoCo warning is stepped on to the period's end, as ``Batch.step``
        does.

        Raises
        ------
        mujoco.batch.SimulationError
            As :meth:`mujoco.batch.Batch.step`.
        """
        if not self._sub_any:
            self.batch.step(nstep=self.rate_steps)
            return
        new = self.ctrl.copy()
        rows, ctl = self._sub_rows, self._roll_ctrl
        ctl[:] = new[:, None, :]
        ctl[rows, 0] = self._sub_f * self._ctrl_prev[rows] + self._sub_g * new[rows]
        try:
            self.batch.rollout(self.rate_steps, ctl, record=(_TIME,), out=self._roll_time)
        finally:
            if self.rate_steps > 1:
                self._finish_stopped(new)
        if self.rate_steps == 1:
            self.ctrl[:] = new  # else the last substep's control is new already
        self._ctrl_prev = new

    def _finish_stopped(self, new: np.ndarray) -> None:
        """Step on the episodes that the last rollout stopped at a warning, as ``Batch.step`` would have."""
        # a stopped episode repeats its last record: its time stands still (at the end at least)
        t = self._roll_time[_TIME][:, :, 0]
        if not (t[:, -1] == t[:, -2]).any():
            return
        still = t[:, 1:] == t[:, :-1]
        ok = self.batch.status == 0  # an episode with a MuJoCo error kept its state: it is not stepped
        first = np.where(still.any(axis=1), still.argmax(axis=1) + 1, self.rate_steps)
        for i in range(1, self.rate_steps):
            ids = np.flatnonzero((first == i) & ok)
            if len(ids):
                self.ctrl[ids] = new[ids]
                self.batch.step(ids, nstep=self.rate_steps - i)

    def state_buffers(self, T: int) -> tuple[np.ndarray, np.ndarray] | tuple[None, None]:
        """Empty ``qpos`` and ``rotor_force`` records, (n, T, 6) each, or (None, None) when not recording."""
        if not self.record_state:
            return None, None
        return np.empty((self.n, T, 6)), np.empty((self.n, T, self.model.nu))

    def measure_true(self) -> np.ndarray:
        """The tested output of every episode now (m or rad), (n,): the state, or the delayed sensor of lateral loops."""
        if not self.lateral:
            return self.qpos[:, self.map.axis].copy()
        w_now, w_step, w_out = self._out_weights
        return (w_now * self.qpos[:, self.map.axis] + w_step * self.sensordata[:, self._sensor_step]
                + w_out * self.sensordata[:, self._sensor_out])

    # -- the episode loop, one control sample at a time ----------------------
    def start(self, T: int, measurement: MeasurementStage | None = None, *,
              tilt_limit_rad: float | None = None) -> np.random.Generator:
        """Begin a run of ``T`` control samples from the current state.

        Parameters
        ----------
        T : int
            Control samples of the run (``t = k / rate_hz``).
        measurement : MeasurementStage, optional
            Replaces the measurement effects (default: they, in order, as :class:`EffectChain`).
        tilt_limit_rad : float, optional
            Lateral loops: clip the tilt reference of the inner attitude loop to +-this (none by default).

        Returns
        -------
        numpy Generator
            The batch's generator, seeded with ``seed``, after the measurement stage, the command
            effects and the force effects drew from it (in that order).
        """
        n = self.n
        rng = np.random.default_rng(self.seed)
        self.stage = EffectChain(self.measurement_fx) if measurement is None else measurement
        self.stage.reset(n, self.rate_hz, rng)
        for e in self.command_fx:
            e.reset(n, self.rate_hz, rng)
        drag = self.map.damping[:, :3]
        for e in self.force_fx:
            e.reset(n, self.rate_hz, rng, drag)
        self.t = np.arange(T) / self.rate_hz
        self.diverged = np.zeros(n, dtype=bool)
        self.reasons: dict[int, str] = {}
        self._tilt_limit = tilt_limit_rad
        if self.lateral:
            from uavsim.control.pd import PD

            self._att = PD(self.map.att_kp, self.map.att_kd, self.map.att_filter_hz, self.rate_hz, n)
            self._att_ax = 4 if self.loop == "lateral_x" else 3
            self._tilt_sign = 1.0 if self.loop == "lateral_x" else -1.0
        self._bounds = np.full(self.qpos.shape[1], np.finfo(np.float64).max)
        self._bounds[:3], self._bounds[3:5] = 1e3, 1.2
        return rng

    def measure(self, k: int) -> tuple[np.ndarray, np.ndarray]:
        """The true output and the measurement stage's view of it at sample ``k``: ``(y_true, y)``, (n,) each."""
        y_true = self.measure_true()
        return y_true, self.stage(y_true, k)

    def actuate(self, u: np.ndarray, k: int) -> np.ndarray | None:
        """Hold command ``u`` (n,) over sample ``k``.

        The command effects act on it, a lateral loop's inner attitude PD turns it into a tilt
        (clipped as :meth:`start` says), the untested axes get their holds, and the force effects
        set the external force. Returns that force (n, 3), N, or None without force effects.
        """
        u_act = u
        for e in self.command_fx:
            u_act = e(u_act, k)
        att_u = None
        if self.lateral:
            theta_ref = self._tilt_sign * self.map.cmd_scale * u_act
            if self._tilt_limit is not None:
                theta_ref = np.clip(theta_ref, -self._tilt_limit, self._tilt_limit)
            att_u = self._att(theta_ref - self.qpos[:, self._att_ax])
        self._apply(u_act, att_u)
        if not self.force_fx:
            return None
        f = sum(e.force(self.t[k], self.qvel[:, :3]) for e in self.force_fx)
        self.xfrc[:, 1, :3] = f
        return f

    def step(self, k: int) -> np.ndarray:
        """Advance the physics over control period ``k`` and check every episode.

        An episode diverges on a MuJoCo error, a position beyond 1 km, a tilt beyond 1.2 rad or
        any non-finite coordinate; it is flagged in ``diverged`` with its reason in ``reasons``
        and parked at rest so that it cannot poison the batch. Returns the episodes that
        diverged at this step, (n,) bool.
        """
        t = self.t[k]
        diverged, reasons = self.diverged, self.reasons
        failed = np.zeros(self.n, dtype=bool)
        try:
            self.advance()
        except mjbatch.SimulationError as exc:
            for i in exc.ids:
                if not diverged[i]:
                    failed[i] = True
                    reasons[int(i)] = f"MuJoCo error at t={t:.3f}s: {self.batch.error(int(i))}"
            diverged |= failed
        # one pass: a NaN fails every comparison, an infinity the last column's huge bound
        within = np.abs(self.qpos) <= self._bounds
        if within.all():
            return failed  # nothing new ran away (the usual sample: no per-episode reduction)
        bad = ~within.all(axis=1)
        new = bad & ~diverged
        if bad.any():
            for i in np.flatnonzero(new):
                reasons[int(i)] = f"runaway state at t={t:.3f}s"
            diverged |= bad
        if new.any():
            self.qpos[new] = 0.0
            self.qvel[new] = 0.0
        return new | failed

    def run(
        self,
        controller: Callable[[np.ndarray], np.ndarray],
        duration_s: float,
        reference: np.ndarray | Callable[[float], np.ndarray] | None = None,
        measurement: MeasurementStage | None = None,
    ) -> EpisodeResult:
        """Run every episode for ``duration_s`` with ``controller`` closing the loop.

        Parameters
        ----------
        controller : callable e (n,) -> u (n,)
            Called once per control sample with the error ``r - y``, and the reference
            ``r`` (n,) too when it has a true ``reads_reference`` (a PD that
            differentiates the measurement).
        duration_s : float
            Episode length, s; ``T = round(duration_s * rate_hz)`` samples.
        reference : None, (T,), (n, T) or callable t -> (n,)
            The reference; zero by default.
        measurement : MeasurementStage, optional
            Replaces the measurement effects (:meth:`start`).
        """
        if not (math.isfinite(duration_s) and duration_s > 0):
            raise UserError(f"episode length must be > 0 s, got {duration_s}")
        n, T = self.n, int(round(duration_s * self.rate_hz))
        self.start(T, measurement)
        t = self.t
        if reference is None:
            zero = np.zeros(n)
            ref = lambda k: zero  # noqa: E731
        elif callable(reference):
            ref = lambda k: np.broadcast_to(np.asarray(reference(t[k]), dtype=float), (n,))  # noqa: E731
        else:
            R = np.broadcast_to(np.asarray(reference, dtype=float), (n, T))
            ref = lambda k: R[:, k]  # noqa: E731
        # recorded sample-major, one contiguous row per sample, and turned (n, T) at the end
        rec = np.empty((4, T, n))
        QP, RF = self.state_buffers(T)
        SW = np.zeros((T, n), dtype=bool)
        has_sw = hasattr(controller, "switched")
        with_r = bool(getattr(controller, "reads_reference", False))
        for k in range(T):
            y_true, y = self.measure(k)
            r = ref(k)
            u = np.asarray(controller(r - y, r) if with_r else controller(r - y), dtype=np.float64)
            self.actuate(u, k)
            rec[0, k], rec[1, k], rec[2, k], rec[3, k] = r, y, u, y_true
            if has_sw:
                SW[k] = controller.switched
            if QP is not None:
                QP[:, k] = self.qpos
            self.step(k)
            if RF is not None:
                RF[:, k] = self.actuator_force
        diverged = self.diverged
        R_out, Y, U, Yt = (np.ascontiguousarray(a.T) for a in rec)
        SW = np.ascontiguousarray(SW.T)
        for arr in (R_out, Y, U, Yt, QP, RF):
            if arr is not None:
                arr[diverged] = np.nan
        return EpisodeResult(t=t, r=R_out, y=Y, u=U, y_true=Yt, diverged=diverged.copy(), reasons=dict(self.reasons),
                             switched=SW if has_sw else None, seed=self.seed, qpos=QP, rotor_force=RF)
