"""Lateral lumped model: the outer loop seen through the closed attitude loop.

The lateral command ``u`` is a pitch (or roll) reference. The attitude loop
``G_a(s) = e^{-tau_in s} / (s (T_prop s + 1)(T1 s + 1))`` (unit gain) is closed
by the PD of its attitude class,
``C(s) = att_kp + att_kd s / (1 + s / att_N)``, so that

    T_att(s) = C G_a / (1 + C G_a)
    G_lat(s) = K e^{-tau_out s} T_att(s) / (s (T2 s + 1))

The attitude derivative filter follows the tuning rule, ``att_N = 10 Omega_att``
with ``Omega_att`` the DF MRFT frequency of the attitude process at the
attitude rule's ``beta`` (``DEFAULT_BETA``), unless given. The functions
live with the other frequency responses in :mod:`uavsim.lumped.frequency`
(whose ``lateral`` family is built on them); this module names them.

    from uavsim.lumped.lateral import attitude_closed_loop_batch
    T = attitude_closed_loop_batch(np.geomspace(0.1, 100, 50), 0.05, 0.5, 0.01, 2.0, 0.3)
"""

from __future__ import annotations

from uavsim.lumped.frequency import (
    DERIVATIVE_FILTER_RATIO,
    attitude_closed_loop_batch,
    attitude_filter,
)

__all__ = ["attitude_filter", "attitude_closed_loop_batch", "DERIVATIVE_FILTER_RATIO"]
