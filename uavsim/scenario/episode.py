"""Visual-servoing episodes on the MuJoCo hexarotor, through a sensor chain.

A visual-servoing loop's measurement needs more than the measured signal:
the true acceleration (IMU), the target's motion (the camera measures the
vehicle *relative to the target*) and, for the schedule switch, the Kalman
filter's innovation. So the episode steps ``LoopBatch``'s episode loop
(``start``/``measure``/``actuate``/``step``: the same physics, actuation,
holds, force effects and divergence checks) with a ``SensorChain`` as its
measurement stage, and records the chain's signals.

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


@dataclass(kw_only=True)
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


class _SensorStage:
    """The sensor chain as the loop's measurement stage: the camera sees the vehicle relative to
    ``target_m`` and the IMU the true acceleration; the controller sees the Kalman estimate
    (``kf``) or the camera (``camera``, ``scheduled``: the episode blends them). The chain's whole
    reading of the last sample is in ``reading``."""

    def __init__(self, chain: SensorChain, lb: LoopBatch, mode: str) -> None:
        self.chain, self.lb, self.mode = chain, lb, mode
        self.ax = lb.map.axis
        self.target_m = 0.0
        self.reading = None

    def reset(self, n: int, rate_hz: float, rng: np.random.Generator) -> None:
        self.chain.reset(n, rate_hz, rng)
        self.Ts = 1.0 / rate_hz
        self.v_prev = self.lb.qvel[:, self.ax].copy()

    def __call__(self, y_true: np.ndarray, k: int) -> np.ndarray:
        v = self.lb.qvel[:, self.ax]
        acc = (v - self.v_prev) / self.Ts
        self.v_prev = v.copy()
        self.reading = self.chain(y_true - self.target_m, acc, k)
        return self.reading.y_kf if self.mode == "kf" else self.reading.y_cam


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
        stage = _SensorStage(SensorChain(self.chain_params), lb, self.mode)
        # the paper's vehicle saturates the lateral controller output (tilt)
        lb.start(T, stage, tilt_limit_rad=lb.vehicle.lateral_limit_rad)
        sw = ScheduleSwitch(self.switch_params, self.rate_hz, n) if self.mode == "scheduled" else None
        ax = lb.map.axis
        t = lb.t
        out = {k: np.zeros((n, T)) for k in ("r", "y", "u", "yt", "ycam", "ykf", "tgt", "pos", "sched", "nu", "f")}
        QP, RF = lb.state_buffers(T)
        for k in range(T):
            tk = t[k]
            tg = float(target(tk)) if target is not None else 0.0
            r = float(reference(tk)) if reference is not None else 0.0
            stage.target_m = tg
            y_true, y = lb.measure(k)
            s = stage.reading
            if self.mode == "scheduled":
                active = sw.update(s.innovation, s.innovation_std, s.new_frame, r - s.y_cam)
                if sw.to_ibvs.any():
                    # the target moved: the filter's position is wrong, its
                    # velocity and bias are not; restart it on the camera
                    stage.chain.kf.reposition(s.y_cam_raw, sw.to_ibvs)
                y = np.where(active == 1, s.y_kf, s.y_cam)
                u = np.asarray(controller(r - s.y_kf, r - s.y_cam, active), dtype=np.float64)
                out["sched"][:, k] = active
            else:
                u = np.asarray(controller(r - y), dtype=np.float64)
            f = lb.actuate(u, k)
            f_ax = 0.0 if f is None else f[:, min(ax, 2)]
            for key, val in (("r", r), ("y", y), ("u", u), ("yt", y_true - tg), ("ycam", s.y_cam),
                             ("ykf", s.y_kf), ("tgt", tg), ("pos", y_true), ("nu", s.innovation),
                             ("f", f_ax)):
                out[key][:, k] = val
            if QP is not None:
                QP[:, k] = lb.qpos
            lb.step(k)
            if RF is not None:
                RF[:, k] = lb.actuator_force
        diverged, reasons = lb.diverged.copy(), dict(lb.reasons)
        for arr in (*out.values(), QP, RF):
            if arr is not None:
                arr[diverged] = np.nan
        return VisionResult(t=t, r=out["r"], y=out["y"], u=out["u"], y_true=out["yt"], diverged=diverged,
                            reasons=reasons, switched=None, seed=self.seed, qpos=QP, rotor_force=RF, y_cam=out["ycam"], y_kf=out["ykf"], target=out["tgt"], pos=out["pos"],
                            schedule=out["sched"] if self.mode == "scheduled" else None,
                            innovation=out["nu"], force=out["f"])
