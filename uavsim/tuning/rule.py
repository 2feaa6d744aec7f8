"""Homogeneous MRFT tuning rule for PD loops.

An MRFT at ``beta`` makes the loop oscillate at ``Omega`` where
``arg G(j Omega) = -pi + asin(beta)``. A PD ``C = Kp (1 + Td s)`` with

    c3 = tan(asin(beta) - pm) / (-2 pi)      c1 = 1 / sqrt(1 + 4 pi^2 c3^2)
    Kp = c1 / |G(j Omega)|                   Td = c3 * 2 pi / Omega,  Kd = Kp Td

has ``|C(j Omega) G(j Omega)| = 1`` (Omega becomes the crossover) and phase
``-pi + asin(beta) + atan(2 pi c3) = -pi + pm`` there: phase margin ``pm``.
The derivative is filtered at ``N = 10 Omega`` rad/s (``derivative_filter_hz =
10 Omega / (2 pi)``). Gains are for the process as given; for a unit-gain model
(K = 1) a process of gain K takes ``kp/K, kd/K``.

A loop-gain scale ``gain_scale`` (``s``, default 1) multiplies ``Kp`` and ``Kd``:
``|C(j Omega) G(j Omega)| = s`` for the ideal PD, so ``s < 1`` puts the crossover
below ``Omega`` (a lower-bandwidth loop) and ``pm`` is then the phase of ``L(j Omega)``
above -pi rather than the phase margin. The inner loops use ``s = 1``; the lateral
loops need ``s < 1`` because their MRFT frequency sits on the resonance of the
closed attitude loop, where ``|G|`` still rises above ``Omega`` and a crossover at
``Omega`` leaves a second crossover with the phase past -pi
(``uavsim.tuning.grid``, lateral grids).

The published flight constants c1 = 0.3849, c3 = 0.3817 satisfy the c1(c3)
relation to 4 digits and correspond to ``asin(-beta) + pm = 67.37 deg``, i.e.
``beta = -0.7357`` at pm = 20 deg; (beta, pm) = (-0.73, 20 deg) itself gives
c1 = 0.3925, c3 = 0.3730 (``-0.73`` is a rounded beta).

    from uavsim.tuning.rule import TuningRule
    rule = TuningRule(beta=-0.73, pm_deg=20.0)
    g = rule.gains(LumpedParams("altitude", 1.0, 0.3, 0.2, 0.0128))
    g.kp, g.kd, g.derivative_filter_hz
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np

from uavsim.errors import UserError
from uavsim.lumped.frequency import (  # DEFAULT_BETA: MRFT parameter of the flight tests
    DEFAULT_BETA,
    batch_args,
    check_beta,
    freq_response_batch,
    mrft_prediction_batch,
)
from uavsim.lumped.lateral import DERIVATIVE_FILTER_RATIO
from uavsim.lumped.params import LumpedParams

__all__ = ["DEFAULT_BETA", "DEFAULT_PM_DEG", "rule_constants", "TuningRule", "Gains"]

#: phase margin of the homogeneous rule used in flight, deg
DEFAULT_PM_DEG = 20.0


def rule_constants(beta: float, pm_deg: float, gain_scale: float = 1.0) -> tuple[float, float]:
    """``(c1, c3)`` of the homogeneous rule.

    Parameters
    ----------
    beta : float
        MRFT parameter, in (-1, 1).
    pm_deg : float
        Phase of the ideal-PD loop at ``Omega`` above -180 deg, deg (the phase margin when
        ``gain_scale`` is 1).
    gain_scale : float
        Loop gain ``|C G|`` at ``Omega``, in (0, 1]; 1 is the classic rule.
    """
    beta = check_beta(beta)
    if not isinstance(pm_deg, (int, float, np.floating)) or not math.isfinite(pm_deg) or pm_deg <= 0:
        raise UserError(f"phase margin must be a number > 0 deg, got {pm_deg!r}")
    if not isinstance(gain_scale, (int, float, np.floating)) or not 0.0 < gain_scale <= 1.0:
        raise UserError(f"gain scale must be a number in (0, 1], got {gain_scale!r}")
    # atan(2 pi c3) = pm - asin(beta) must be in (0, 90) deg for a finite positive Td
    lead = math.radians(pm_deg) - math.asin(beta)
    if not 0.0 < lead < math.pi / 2:
        raise UserError(f"pm={pm_deg} deg with beta={beta} needs a derivative phase lead of {math.degrees(lead):.1f} deg (must be in (0, 90))")
    c3 = math.tan(math.asin(beta) - math.radians(pm_deg)) / (-2.0 * math.pi)
    c1 = float(gain_scale) / math.sqrt(1.0 + 4.0 * math.pi**2 * c3**2)
    return c1, c3


@dataclass(frozen=True)
class Gains:
    """PD gains from the rule (for the process as given; K = 1 for unit-gain gains).

    Attributes: ``kp`` (command/output), ``kd`` (command s/output),
    ``derivative_filter_hz`` (Hz), ``omega`` (DF MRFT frequency, rad/s),
    ``amplitude_df`` (DF amplitude at h = 1, output units), ``beta``, ``pm_deg``, ``c1``, ``c3``,
    ``gain_scale`` (loop gain at ``omega``, 1 for the classic rule).
    """

    kp: float
    kd: float
    derivative_filter_hz: float
    omega: float
    amplitude_df: float
    beta: float
    pm_deg: float
    c1: float
    c3: float
    gain_scale: float = 1.0

    @property
    def N(self) -> float:
        """Derivative filter, rad/s."""
        return 2 * math.pi * self.derivative_filter_hz

    def as_dict(self) -> dict[str, float]:
        return asdict(self)


@dataclass(frozen=True)
class TuningRule:
    """The homogeneous MRFT rule at ``(beta, pm_deg)``, loop gain ``gain_scale`` at Omega."""

    beta: float = DEFAULT_BETA
    pm_deg: float = DEFAULT_PM_DEG
    gain_scale: float = 1.0

    @property
    def constants(self) -> tuple[float, float]:
        return rule_constants(self.beta, self.pm_deg, self.gain_scale)

    def gains_batch(self, family: str, **params) -> dict[str, np.ndarray]:
        """Rule gains for many processes of one family.

        Parameters
        ----------
        family : str
            Loop family.
        **params
            Process parameters (arrays (B,) or scalars), as ``freq_response_batch``.

        Returns
        -------
        dict of ndarray (B,): ``kp``, ``kd``, ``N`` (rad/s), ``derivative_filter_hz``,
        ``omega`` (rad/s), ``amplitude_df`` (h = 1), ``gain_at_omega`` (|G(j omega)|).
        """
        c1, c3 = self.constants
        w, _ = mrft_prediction_batch(family, self.beta, 1.0, **params)
        if not np.all(np.isfinite(w)):
            raise UserError(f"{family}: no MRFT oscillation for some processes at beta={self.beta}")
        G = np.abs(freq_response_batch(family, w[:, None], **params)[:, 0])
        kp = c1 / G
        kd = kp * c3 * 2 * np.pi / w
        N = DERIVATIVE_FILTER_RATIO * w
        return {
            "kp": kp,
            "kd": kd,
            "N": N,
            "derivative_filter_hz": N / (2 * np.pi),
            "omega": w,
            "amplitude_df": 4.0 * G / np.pi,
            "gain_at_omega": G,
        }

    def gains(self, p: LumpedParams) -> Gains:
        """Rule gains for one process (for its gain K)."""
        p.check()
        g = self.gains_batch(p.family, **batch_args(p))
        c1, c3 = self.constants
        return Gains(
            kp=float(g["kp"][0]),
            kd=float(g["kd"][0]),
            derivative_filter_hz=float(g["derivative_filter_hz"][0]),
            omega=float(g["omega"][0]),
            amplitude_df=float(g["amplitude_df"][0]),
            beta=self.beta,
            pm_deg=self.pm_deg,
            c1=c1,
            c3=c3,
            gain_scale=self.gain_scale,
        )
