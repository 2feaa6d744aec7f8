"""From lumped loop parameters to the MuJoCo hexarotor, per episode.

Each loop of the hexarotor reproduces its lumped model (``uavsim.lumped``)
exactly, through the physics rather than around it:

==========  ====================================================================
parameter   realised by
==========  ====================================================================
T_prop      the rotors' ``filterexact`` actuator dynamics (``actuator_dynprm``)
tau         the rotors' history-buffer delay (``actuator_delay``), plus any
            ``delay`` effect; the loop reads the joint state, so no other
            delay enters
T1          the damping of the loop's joint: ``c = m / T1`` (altitude) or
            ``c = J / T1`` (roll, pitch), since ``m y'' = F - c y'`` gives
            ``y/F = (1/c) / (s (T1 s + 1))``
K           the command-to-wrench scale: force ``F = s u`` with ``s = K c``
            (N or N m per command unit), times any ``gain`` effect
T2          the damping of the x or y slide, ``c = m / T2``
==========  ====================================================================

Lateral loops run over the attitude loop: the lateral command is a pitch
(lateral_x) or roll (lateral_y) reference scaled so that the outer gain is K,
``x'' = g tan(theta) - x'/T2`` with the tilt from an attitude PD closed at the
control rate on a unit-gain attitude process of the class's T_prop, T1 and
``tau_in``; the outer delay ``tau_out`` is a measurement delay line on x.

    m = map_params([LumpedParams("altitude", K=2.0, T_prop=0.1, T1=0.8, tau=0.02)])
    m.damping.shape   # (1, 6): x, y, z, roll, pitch, yaw
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from uavsim.errors import UserError
from uavsim.lumped.params import LumpedParams
from uavsim.model.vehicle import G, Vehicle

#: joint index measured by each loop (order of ``uavsim.model.vehicle.JOINTS``)
AXIS = {"x": 0, "y": 1, "altitude": 2, "roll": 3, "pitch": 4, "yaw": 5, "lateral_x": 0, "lateral_y": 1}
#: wrench index driven by each inner loop: [thrust, roll, pitch, yaw]
WRENCH = {"altitude": 0, "roll": 1, "pitch": 2}

# Damping of the axes a loop does not test: moderate, so held axes stay calm.
_T_IDLE = {"x": 2.0, "y": 2.0, "z": 1.0, "roll": 0.5, "pitch": 0.5, "yaw": 0.5}


@dataclass
class LoopMapping:
    """Per-episode MuJoCo settings of one loop, arrays over ``n`` episodes.

    Attributes
    ----------
    loop : str
    damping : (n, 6) joint damping, N s/m for slides and N m s/rad for hinges
    T_prop : (n,) s, rotor lag
    actuator_delay : (n,) s
    cmd_scale : (n,) wrench units per command unit (inner loops), or tilt rad per
        command unit (lateral loops)
    out_delay : (n,) s, measurement delay of lateral loops (0 for inner loops)
    att_kp, att_kd, att_filter_hz : (n,) attitude PD of lateral loops (unit-gain)
    att_scale : (n,) N m per unit attitude command (lateral loops)
    """

    loop: str
    damping: np.ndarray
    T_prop: np.ndarray
    actuator_delay: np.ndarray
    cmd_scale: np.ndarray
    out_delay: np.ndarray
    att_kp: np.ndarray
    att_kd: np.ndarray
    att_filter_hz: np.ndarray
    att_scale: np.ndarray

    @property
    def n(self) -> int:
        return self.T_prop.shape[0]

    @property
    def axis(self) -> int:
        return AXIS[self.loop]


def map_params(
    params: Sequence[LumpedParams],
    vehicle: Vehicle | None = None,
    extra_delay: np.ndarray | float = 0.0,
    gain_factor: np.ndarray | float = 1.0,
) -> LoopMapping:
    """Map ``n`` lumped processes of one loop to MuJoCo settings.

    Parameters
    ----------
    params : sequence of LumpedParams, length n
        All of the same ``loop``; each is validated.
    vehicle : Vehicle
        Mass and inertias (default: the paper's hexarotor).
    extra_delay : float or (n,)
        Delay added by ``delay`` effects, s.
    gain_factor : float or (n,)
        Product of ``gain`` effect factors.
    """
    v = (vehicle or Vehicle()).check()
    if len(params) == 0:
        raise UserError("no episodes to simulate")
    loops = {p.loop for p in params}
    if len(loops) != 1:
        raise UserError(f"a batch simulates one loop at a time, got {sorted(loops)}")
    loop = loops.pop()
    for p in params:
        p.check()
    n = len(params)
    arr = lambda name: np.array([getattr(p, name) for p in params], dtype=np.float64)  # noqa: E731
    K = arr("K") * np.broadcast_to(np.asarray(gain_factor, dtype=np.float64), (n,))
    T_prop, T1, tau = arr("T_prop"), arr("T1"), arr("tau")
    inertia = np.array([v.mass_kg, v.mass_kg, v.mass_kg, v.Jx_kgm2, v.Jy_kgm2, v.Jz_kgm2])
    idle = np.array([_T_IDLE[k] for k in ("x", "y", "z", "roll", "pitch", "yaw")])
    damping = np.tile(inertia / idle, (n, 1))
    zeros = np.zeros(n)
    extra = np.broadcast_to(np.asarray(extra_delay, dtype=np.float64), (n,))
    if loop in WRENCH:
        ax = AXIS[loop]
        c = inertia[ax] / T1
        damping[:, ax] = c
        return LoopMapping(loop, damping, T_prop, tau + extra, K * c, zeros, zeros, zeros, zeros, zeros)
    # lateral: attitude axis pitch for x, roll for y
    att_ax = AXIS["pitch"] if loop == "lateral_x" else AXIS["roll"]
    lat_ax = AXIS[loop]
    T2, tau_in = arr("T2"), arr("tau_in")
    damping[:, att_ax] = inertia[att_ax] / T1
    damping[:, lat_ax] = v.mass_kg / T2
    # x/theta = g T2 / (s (T2 s + 1)); a tilt of s_lat per unit command gives K = s_lat g T2
    s_lat = K / (G * T2)
    att_scale = inertia[att_ax] / T1  # unit attitude gain: K_att = s / c = 1
    return LoopMapping(
        loop, damping, T_prop, tau_in + extra, s_lat, tau,
        arr("att_kp"), arr("att_kd"), arr("att_filter_hz"), att_scale,
    )
