"""Visual-servoing episodes on the MuJoCo hexarotor, through a sensor chain.

``LoopBatch.run`` gives measurement effects only the measured signal; a
visual-servoing loop also needs the true acceleration (IMU), the target's
motion (the camera measures the vehicle *relative to the target*) and, for
the schedule switch, the Kalman filter's innovation. So this module runs its
own episode loop on ``LoopBatch``'s model, batch and actuation (the same
physics, holds and force effects), with a ``SensorChain`` in place of the
measurement effects.

Modes: ``"kf"`` (the controller sees the Kalman estimate, PBVS), ``"camera"``
(the camera alone, IBVS), ``"scheduled"`` (both, with the schedule switch;
the controller is a ``ScheduledPD``).

    ep = VisionEpisode(truth, ChainParams(camera=PRESETS["normal"]), mode="kf", seed=1)
    res = ep.run(NPMRFT(...), duration_s=20.0)
    res.y.shape          # (n, T): what the controller saw
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from uavsim.errors import UserError
from uavsim.lumped.params import LumpedParams
from uavsim.model.effects.base import Effect
from uavsim.sim.runner import EpisodeResult, LoopBatch
from uavsim.vision.chain import ChainParams, SensorChain
from uavsim.vision.schedules import ScheduleSwitch, SwitchParams

__all__ = ["VisionEpisode", "VisionResult", "MODES"]

MODES = ("kf", "camera", "scheduled")


@dataclass
class VisionResult(EpisodeResult):
    """``EpisodeResult`` plus the vision signals, all (n, T).

    Extra attributes: ``y_cam`` (camera, low-passed), ``y_kf`` (Kalman estimate,
    low-passed), ``target`` (target position along the axis, m), ``pos``
    (vehicle position along the axis, m), ``schedule`` (1 PBVS / 2 IBVS),
    ``innovation`` (m, 0 between frames), ``force`` (external force along
    the axis, N); and from ``EpisodeResult`` the vehicle's ``qpos`` and
    ``rotor_force`` (n, T, 6) when the episode records its state.
    """

    y_cam: np.ndarray | None = None
    y_kf: np.ndarray | None = None
    target: np.ndarray | None = None
    pos: np.ndarray | None = None
    schedule: np.ndarray | None = None
    innovation: np.ndarray | None = None
    force: np.ndarray | None = None


class VisionEpisode:
    """``n`` episodes of one loop closed through a vision sensor chain.

    Parameters
    ----------
    params : sequence of LumpedParams (or one)
        True lumped process of the vehicle's loop per episode (``altitude`` or ``lateral_y``).
    chain : ChainParams
    mode : str
        ``kf``, ``camera`` or ``scheduled``.
    forces : sequence of Effect
        Force effects (wind, pull) and model effects, as ``LoopBatch``.
    seed : int
    dt, rate_hz : float
        Physics step and control rate.
    switch : SwitchParams
        Schedule switch settings (``scheduled`` mode).
    record_state : bool
        Record the vehicle's ``qpos`` and rotor thrusts (n, T, 6) for replays
        (``uavsim replay``); cheap for the scenarios' single episodes.
    """

    def __init__(self, params: Sequence[LumpedParams] | LumpedParams, chain: ChainParams, *, mode: str = "kf",
                 forces: Sequence[Effect] = (), seed: int = 0, dt: float = 0.0005, rate_hz: float = 200.0,
                 switch: SwitchParams | None = None, saturation: bool = True, record_state: bool = True):
        if mode not in MODES:
            raise UserError(f"vision episode: mode must be one of {', '.join(MODES)}, got {mode!r}")
        plist = [params] if isinstance(params, LumpedParams) else list(params)
        if any(e.target in ("measurement", "command") for e in forces):
            raise UserError("vision episode: only force and model effects go with a sensor chain")
        self.chain_params = chain.check()
        if plist[0].loop != chain.axis:
            raise UserError(f"vision episode: the chain measures {chain.axis}, the process is {plist[0].loop}")
        self.lb = LoopBatch(plist, dt=dt, rate_hz=rate_hz, effects=forces, seed=seed, saturation=saturation,
                            record_state=record_state)
        self.mode, self.seed, self.rate_hz = mode, int(seed), float(rate_hz)
        self.switch_params = switch or SwitchParams()

    @property
    def n(self) -> int:
        return self.lb.n

    def run(self, controller: Callable, duration_s: float,
            reference: Callable[[float], float] | None = None,
            target: Callable[[float], float] | None = None) -> VisionResult:
        """Run for ``duration_s`` s.

        Parameters
        ----------
        controller : callable
            ``e (n,) -> u (n,)`` in ``kf``/``camera`` modes;
            ``(e_pbvs, e_ibvs, active) -> u`` in ``scheduled`` mode.
        reference : callable t -> float, m
            Desired position relative to the target (0 by default).
        target : callable t -> float, m
            Target position along the axis (still by default).
        """
        if not (math.isfinite(duration_s) and duration_s > 0):
            raise UserError(f"episode length must be > 0 s, got {duration_s}")
        lb, n = self.lb, self.n
        T = int(round(duration_s * self.rate_hz))
        Ts = 1.0 / self.rate_hz
        rng = np.random.default_rng(self.seed)
        chain = SensorChain(self.chain_params)
        chain.reset(n, self.rate_hz, rng)
        for e in lb.force_fx:
            e.reset(n, self.rate_hz, rng, lb.map.damping[:, :3])
        sw = ScheduleSwitch(self.switch_params, self.rate_hz, n) if self.mode == "scheduled" else None
        ax = lb.map.axis
        t = np.arange(T) / self.rate_hz
        out = {k: np.zeros((n, T)) for k in ("r", "y", "u", "yt", "ycam", "ykf", "tgt", "pos", "sched", "nu", "f")}
        QP, RF = lb.state_buffers(T)
        diverged = np.zeros(n, dtype=bool)
        reasons: dict[int, str] = {}
        lateral = lb.lateral
        if lateral:
            from uavsim.control.pd import PD

            att = PD(lb.map.att_kp, lb.map.att_kd, lb.map.att_filter_hz, self.rate_hz, n)
            att_ax = 4 if lb.loop == "lateral_x" else 3
            tilt_sign = 1.0 if lb.loop == "lateral_x" else -1.0
        v_prev = lb.qvel[:, ax].copy()
        for k in range(T):
            tk = t[k]
            tg = float(target(tk)) if target is not None else 0.0
            r = float(reference(tk)) if reference is not None else 0.0
            y_true = lb._measure_true()
            acc = (lb.qvel[:, ax] - v_prev) / Ts
            v_prev = lb.qvel[:, ax].copy()
            s = chain(y_true - tg, acc, k)
            if self.mode == "kf":
                y = s.y_kf
                u = np.asarray(controller(r - y), dtype=np.float64)
            elif self.mode == "camera":
                y = s.y_cam
                u = np.asarray(controller(r - y), dtype=np.float64)
            else:
                active = sw.update(s.innovation, s.innovation_std, s.new_frame, r - s.y_cam)
                if sw.to_ibvs.any():
                    # the target moved: the filter's position is wrong, its
                    # velocity and bias are not; restart it on the camera
                    chain.kf.reposition(s.y_cam_raw, sw.to_ibvs)
                y = np.where(active == 1, s.y_kf, s.y_cam)
                u = np.asarray(controller(r - s.y_kf, r - s.y_cam, active), dtype=np.float64)
                out["sched"][:, k] = active
            att_u = None
            if lateral:
                # the paper's vehicle saturates the lateral controller output (tilt)
                lim = lb.vehicle.lateral_limit_rad
                theta_ref = np.clip(tilt_sign * lb.map.cmd_scale * u, -lim, lim)
                att_u = att(theta_ref - lb.qpos[:, att_ax])
            lb._apply(u, att_u)
            f = np.zeros((n, 3))
            if lb.force_fx:
                f = sum(e.force(tk, lb.qvel[:, :3]) for e in lb.force_fx)
                lb.xfrc[:, 1, :3] = f
            for key, val in (("r", r), ("y", y), ("u", u), ("yt", y_true - tg), ("ycam", s.y_cam),
                             ("ykf", s.y_kf), ("tgt", tg), ("pos", y_true), ("nu", s.innovation),
                             ("f", f[:, min(ax, 2)])):
                out[key][:, k] = val
            if QP is not None:
                QP[:, k] = lb.qpos
            try:
                lb.advance()
            except Exception as exc:  # a MuJoCo simulation error ends the faulty episodes
                for i in getattr(exc, "ids", range(n)):
                    if not diverged[i]:
                        diverged[i] = True
                        reasons[int(i)] = f"MuJoCo error at t={tk:.3f}s: {exc}"
            if RF is not None:
                RF[:, k] = lb.actuator_force
            bad = ~np.isfinite(lb.qpos).all(axis=1) | (np.abs(lb.qpos[:, :3]) > 1e3).any(axis=1)
            bad |= (np.abs(lb.qpos[:, 3:5]) > 1.2).any(axis=1)
            for i in np.flatnonzero(bad & ~diverged):
                reasons[int(i)] = f"runaway state at t={tk:.3f}s"
            new = bad & ~diverged
            diverged |= bad
            if new.any():
                lb.qpos[new] = 0.0
                lb.qvel[new] = 0.0
        for arr in (*out.values(), QP, RF):
            if arr is not None:
                arr[diverged] = np.nan
        return VisionResult(t, out["r"], out["y"], out["u"], out["yt"], diverged, reasons, None, self.seed, QP, RF,
                            y_cam=out["ycam"], y_kf=out["ykf"], target=out["tgt"], pos=out["pos"],
                            schedule=out["sched"] if self.mode == "scheduled" else None,
                            innovation=out["nu"], force=out["f"])
