"""PBVS / IBVS controller schedules and the switch between them (paper Fig. 1).

Schedule 1 (PBVS) runs the PD tuned on the Kalman-filtered estimate (camera
+ IMU); schedule 2 (IBVS) runs the PD tuned on the camera alone. The filter is
only valid while the target is still: when the target moves, the camera sees
a jump the IMU did not, and the filter's innovation (prediction error) is
large. Then the loop switches to schedule 2 on the camera alone, and back to
schedule 1 once the camera-only loop has settled (``settle_s`` seconds with the
error within ``settle_tol_m``), the moment marked in the paper's Fig. 9.

    sw = ScheduleSwitch(SwitchParams(), rate_hz=200.0, n=1)
    active = sw.update(innovation, new_frame, e_camera)   # (n,) int: 1 PBVS, 2 IBVS
    pd = ScheduledPD(Schedule(1.2, 0.35, 20.0), Schedule(0.4, 0.17, 10.0), rate_hz=200.0, n=1)
    u = pd(e, active)
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from uavsim.control.pd import PD
from uavsim.errors import UserError

__all__ = ["Schedule", "SwitchParams", "ScheduleSwitch", "ScheduledPD"]


@dataclass(frozen=True)
class Schedule:
    """PD gains of one schedule: ``kp`` (command/m), ``kd`` (command s/m), derivative filter (Hz)."""

    kp: float
    kd: float
    derivative_filter_hz: float


@dataclass(frozen=True)
class SwitchParams:
    """When to leave and re-enter the PBVS schedule.

    Attributes
    ----------
    gate_m : float
        Innovation magnitude that means "the target moved", m.
    gate_sigma : float
        The gate is at least this many innovation standard deviations.
    settle_tol_m : float
        Camera error band for "settled", m.
    settle_s : float
        Time the error must stay in the band before switching back, s.
    """

    gate_m: float = 0.15
    gate_sigma: float = 6.0
    settle_tol_m: float = 0.05
    settle_s: float = 1.0

    def check(self) -> SwitchParams:
        for k, v in self.__dict__.items():
            if not (math.isfinite(v) and v > 0):
                raise UserError(f"schedule switch: {k} must be > 0, got {v}")
        return self


class ScheduleSwitch:
    """The schedule state machine of ``n`` episodes (1: PBVS with KF, 2: IBVS camera only)."""

    def __init__(self, params: SwitchParams, rate_hz: float, n: int):
        self.p = params.check()
        self.n = int(n)
        self.settle_k = int(math.ceil(self.p.settle_s * rate_hz))
        self.active = np.ones(self.n, dtype=np.int64)
        self.in_band = np.zeros(self.n, dtype=np.int64)

    def update(self, innovation: np.ndarray, innovation_std: np.ndarray, new_frame: np.ndarray,
               e_camera: np.ndarray) -> np.ndarray:
        """Advance one sample; returns the active schedule (n,) and sets ``to_ibvs`` / ``to_pbvs`` (n,) bool.

        Parameters
        ----------
        innovation, innovation_std : (n,) m
            Last KF innovation and its predicted std (meaningful where ``new_frame``).
        new_frame : (n,) bool
            A camera correction happened at this sample.
        e_camera : (n,) m
            Servo error computed from the camera alone.
        """
        gate = np.maximum(self.p.gate_m, self.p.gate_sigma * np.asarray(innovation_std))
        jump = np.asarray(new_frame, dtype=bool) & (np.abs(innovation) > gate) & (self.active == 1)
        ok = np.abs(e_camera) <= self.p.settle_tol_m
        self.in_band = np.where(ok & (self.active == 2), self.in_band + 1, 0)
        back = (self.active == 2) & (self.in_band >= self.settle_k)
        self.to_ibvs, self.to_pbvs = jump, back
        self.active = np.where(jump, 2, np.where(back, 1, self.active))
        self.in_band[back | jump] = 0
        return self.active.copy()


class ScheduledPD:
    """Two PDs (session ``step`` semantics) of which the active schedule drives the command.

    Both track their own error every sample, so that a switch starts the new
    PD with a derivative state that follows its own signal (no derivative kick
    from the jump between estimate and camera).
    """

    def __init__(self, pbvs: Schedule, ibvs: Schedule, rate_hz: float, n: int):
        self.pd1 = PD(pbvs.kp, pbvs.kd, pbvs.derivative_filter_hz, rate_hz, n)
        self.pd2 = PD(ibvs.kp, ibvs.kd, ibvs.derivative_filter_hz, rate_hz, n)

    def __call__(self, e_pbvs: np.ndarray, e_ibvs: np.ndarray, active: np.ndarray) -> np.ndarray:
        """Command (n,) from the errors of both sources (n,) m and the active schedule (n,)."""
        u1, u2 = self.pd1(e_pbvs), self.pd2(e_ibvs)
        return np.where(np.asarray(active) == 1, u1, u2)
