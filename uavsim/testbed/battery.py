"""Battery pack: open-circuit voltage over the state of charge, internal resistance, sag.

The ESCs turn a throttle fraction into a rotor speed proportional to the
pack's *terminal* voltage, so the loop gain follows the voltage: it sags
under load (``R I``) and falls as the charge is used over a flight. The
terminal voltage solves ``V = V_oc(soc) - R P / (eta V)`` for the electrical
power the rotors draw (``P_mech / eta``)::

    V = (V_oc + sqrt(V_oc^2 - 4 R P / eta)) / 2

Per cell, ``V_oc = 3.45 + 0.75 soc - 0.25 exp(-12 soc)`` (4.20 V full, 3.82 V
at half charge, a knee below 20%).

    pack = BatteryPack(BatteryParams(capacity_Ah=5.0, soc_start=0.8))
    V = pack.step(power_W=300.0, dt_s=0.001)     # terminal voltage, V
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from uavsim.errors import UserError

__all__ = ["BatteryParams", "BatteryPack", "cell_ocv"]


def cell_ocv(soc: float) -> float:
    """Open-circuit voltage of one LiPo cell at state of charge ``soc`` in [0, 1], V."""
    s = min(max(soc, 0.0), 1.0)
    return 3.45 + 0.75 * s - 0.25 * math.exp(-12.0 * s)


@dataclass(frozen=True)
class BatteryParams:
    """The pack.

    Attributes
    ----------
    cells : int
        Cells in series.
    capacity_Ah : float
        Capacity, A h.
    R_internal_ohm : float
        Pack internal resistance, ohm.
    efficiency : float
        Motor and ESC efficiency: electrical power = mechanical / efficiency.
    soc_start : float
        State of charge when the session's flight starts, in (0, 1].
    """

    cells: int = 6
    capacity_Ah: float = 6.0
    R_internal_ohm: float = 0.025
    efficiency: float = 0.7
    soc_start: float = 0.9

    def check(self) -> BatteryParams:
        if self.cells < 1 or self.capacity_Ah <= 0 or self.R_internal_ohm < 0:
            raise UserError("battery: need cells >= 1, capacity_Ah > 0, R_internal_ohm >= 0")
        if not 0 < self.efficiency <= 1 or not 0 < self.soc_start <= 1:
            raise UserError("battery: efficiency and soc_start must lie in (0, 1]")
        return self

    @property
    def nominal_V(self) -> float:
        """Voltage at half charge with no load, V (what the autopilot's thrust model assumes)."""
        return self.cells * cell_ocv(0.5)


class BatteryPack:
    """State of one pack over a flight."""

    def __init__(self, params: BatteryParams):
        self.p = params.check()
        self.soc = float(self.p.soc_start)
        self.voltage_V = self.p.cells * cell_ocv(self.soc)
        self.current_A = 0.0

    def terminal_voltage(self, power_W: float) -> float:
        """Terminal voltage at mechanical power ``power_W`` (W) for the present charge, V."""
        voc = self.p.cells * cell_ocv(self.soc)
        pe = max(power_W, 0.0) / self.p.efficiency
        disc = voc * voc - 4.0 * self.p.R_internal_ohm * pe
        # past the pack's maximum power the voltage collapses to half of V_oc
        return 0.5 * (voc + math.sqrt(max(disc, 0.0)))

    def step(self, power_W: float, dt_s: float) -> float:
        """Draw ``power_W`` for ``dt_s``; return the terminal voltage, V."""
        v = self.terminal_voltage(power_W)
        self.current_A = max(power_W, 0.0) / (self.p.efficiency * v)
        self.soc = max(self.soc - self.current_A * dt_s / (3600.0 * self.p.capacity_Ah), 0.0)
        self.voltage_V = v
        return v
