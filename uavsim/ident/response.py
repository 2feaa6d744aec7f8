"""The measured fundamental response and the models fitted to it.

A relay cycle's ``Y1 / (h U1)`` (``uavsim.data.preprocess.CycleFeatures.response``)
is, once the zero-order hold's ``sinc(w Ts/2) e^{-j w Ts/2}`` is removed
(``uavsim.data.preprocess.process_response``), the process's ``G(j w)`` at the cycle's frequency ``w``,
whatever the relay's bias, observation window, ``a_n`` and the sampling did to
the cycle. A class's lags then give the identified model: the gain ``K`` and
delay ``tau`` that put its response exactly on that point (``fit_response``;
lateral: ``T2`` over the closed attitude loop, ``fit_response_lateral``).

The closed attitude loop under a lateral model is ``attitude_loop_response``:
the one place that says how the attitude PD closes it.

    from uavsim.ident.response import fit_response
    m = fit_response(f.response, f.response_period, T_prop=0.1, T1=0.8, tau_class=0.02)
    m["K"], m["tau"]

``class_response`` is every class's delay-free model at a frequency (what the two-point fit and
the point's consistency check compare the measurement with), ``point_sigmas`` the measured
point's standard errors.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from uavsim.data.preprocess import process_response

if TYPE_CHECKING:
    from uavsim.ident.bundle import ModelBundle

__all__ = ["fit_response", "fit_response_lateral", "attitude_loop_response", "unit_response",
           "unit_response_lateral", "class_response", "measured_phase", "point_sigmas"]


def measured_phase(G: np.ndarray, ph0: np.ndarray, w: np.ndarray, tau_class: np.ndarray) -> np.ndarray:
    """The phase of the measured ``G`` (rad) on the branch nearest a class's own, ``ph0 - w tau_class``
    (``ph0``: the unwrapped phase of its delay-free model). Shapes broadcast."""
    ph_c = ph0 - w * tau_class
    return ph_c + (np.angle(G) - ph_c + np.pi) % (2 * np.pi) - np.pi


def _fitted_delay(G: np.ndarray, ph0: np.ndarray, w: np.ndarray, tau_class: np.ndarray) -> np.ndarray:
    """Delay (s, >= 0) that turns a delay-free model of unwrapped phase ``ph0`` into the measured ``G``."""
    return np.maximum((ph0 - measured_phase(G, ph0, w, tau_class)) / w, 0.0)


def unit_response(w, T_prop, T1) -> tuple[np.ndarray, np.ndarray]:
    """Magnitude and unwrapped phase (rad) of ``1 / (jw (T_prop jw + 1)(T1 jw + 1))``; shapes broadcast."""
    mag0 = 1.0 / (w * np.hypot(1.0, w * T_prop) * np.hypot(1.0, w * T1))
    return mag0, -0.5 * np.pi - np.arctan(w * T_prop) - np.arctan(w * T1)


def unit_response_lateral(w, T2, Tatt) -> tuple[np.ndarray, np.ndarray]:
    """Magnitude and unwrapped phase (rad) of ``T_att(jw) / (jw (T2 jw + 1))``, ``Tatt`` the closed attitude
    loop's response at ``w`` (``attitude_loop_response``); unwrapped: that loop lags less than pi at the
    lateral cycle's frequency. Shapes broadcast."""
    G0 = Tatt / (1j * w * (1j * w * T2 + 1.0))
    return np.abs(G0), -0.5 * np.pi - np.arctan(w * T2) + np.angle(Tatt)


def fit_response(response, response_period, *, T_prop, T1, tau_class, rate_hz: float = 200.0
                 ) -> dict[str, np.ndarray]:
    """Inner-loop models with given lags and the gain and delay that match the measured response.

    Parameters
    ----------
    response : (m,) complex, ``CycleFeatures.response`` (output units per command unit)
    response_period : (m,) s, the period of the cycles it was measured on
    T_prop, T1, tau_class : (m,) s, the candidate lags and its own delay (the phase branch)
    rate_hz : rate of the samples the response was measured on

    Returns
    -------
    dict of (m,) arrays: ``K``, ``T_prop``, ``T1``, ``tau`` (s, >= 0) and ``tau_class``. With
    ``G0 = 1 / (jw (T_prop jw + 1)(T1 jw + 1))``: ``K = |G(jw)| / |G0(jw)|`` and
    ``tau = (arg G0(jw) - arg G(jw)) / w``, the measured phase taken on the branch nearest
    the class's own phase; a delay below 0 (less lag than measured) is clipped to 0.
    """
    w = 2.0 * np.pi / np.asarray(response_period, dtype=np.float64)
    G = process_response(response, response_period, rate_hz=rate_hz)
    Tp, T1, tau_c = (np.broadcast_to(np.asarray(v, dtype=np.float64), w.shape) for v in (T_prop, T1, tau_class))
    mag0, ph0 = unit_response(w, Tp, T1)
    return {"K": np.abs(G) / mag0, "T_prop": Tp, "T1": T1, "tau": _fitted_delay(G, ph0, w, tau_c), "tau_class": tau_c}


def attitude_loop_response(omega, attitude: dict[str, float]) -> np.ndarray:
    """Complementary sensitivity ``T_att(j w)`` of the attitude loop a lateral model closes over, (m,).

    ``attitude``: ``T_prop``, ``T1``, ``tau_in`` (s) of the unit-gain attitude process,
    ``att_kp``, ``att_kd``, ``att_filter_hz`` of its PD, and ``rate_hz`` when the PD runs at a
    control rate (the lateral grids designed over the attitude table's PD: the loop closed at
    its samples, ``uavsim.lumped.frequency.attitude_closed_loop_sampled``, as the grid's classes
    and table assume); without ``rate_hz`` the continuous loop (``uavsim.lumped.lateral``).
    """
    from uavsim.lumped.frequency import attitude_closed_loop_sampled
    from uavsim.lumped.lateral import attitude_closed_loop_batch

    w = np.atleast_1d(np.asarray(omega, dtype=np.float64))
    args = (w[:, None], attitude["T_prop"], attitude["T1"], attitude["tau_in"], attitude["att_kp"], attitude["att_kd"],
            2.0 * np.pi * attitude["att_filter_hz"])
    rate = attitude.get("rate_hz")
    if rate is not None:
        return attitude_closed_loop_sampled(*args, rate_hz=float(rate))[:, 0]
    return attitude_closed_loop_batch(*args)[:, 0]


def fit_response_lateral(response, response_period, *, T2, tau_class, attitude: dict[str, float],
                         rate_hz: float = 200.0) -> dict[str, np.ndarray]:
    """``fit_response`` for the lateral loop: the class's ``T2`` over the closed attitude loop.

    With ``G0 = T_att(jw) / (jw (T2 jw + 1))`` (``attitude_loop_response``, unit gain):
    ``K = |G(jw)| / |G0(jw)|`` and the outer delay ``tau = (arg G0 - arg G) / w`` on the
    branch nearest the class's own, clipped at 0. Returns (m,) arrays ``K``, ``T2``, ``tau``,
    ``tau_class``.
    """
    w = 2.0 * np.pi / np.asarray(response_period, dtype=np.float64)
    G = process_response(response, response_period, rate_hz=rate_hz)
    T2, tau_c = (np.broadcast_to(np.asarray(v, dtype=np.float64), w.shape) for v in (T2, tau_class))
    Tatt = attitude_loop_response(w.ravel(), attitude).reshape(w.shape)
    mag0, ph0 = unit_response_lateral(w, T2, Tatt)
    return {"K": np.abs(G) / mag0, "T2": T2, "tau": _fitted_delay(G, ph0, w, tau_c), "tau_class": tau_c}


def class_response(bundle: ModelBundle, cls, omega) -> tuple[np.ndarray, np.ndarray]:
    """Magnitude and unwrapped phase (rad) of the classes' unit-gain, delay-free models at ``omega``.

    ``cls`` (n,), ``omega`` (k,) rad/s; returns two (n, k) arrays. Inner loops:
    ``1 / (jw (T_prop jw + 1)(T1 jw + 1))``; lateral: ``T_att(jw) / (jw (T2 jw + 1))`` over the
    bundle's closed attitude loop (``attitude_loop_response``).
    """
    cls = np.asarray(cls, dtype=np.int64)
    w = np.atleast_1d(np.asarray(omega, dtype=np.float64))[None, :]
    c = bundle.column
    if bundle.loop == "lateral":
        Tatt = attitude_loop_response(w[0], dict(bundle.attitude or {}))[None, :]
        return unit_response_lateral(w, c("T2")[cls][:, None], Tatt)
    return unit_response(w, c("T_prop")[cls][:, None], c("T1")[cls][:, None])


def point_sigmas(spread, cycles: int, floor: tuple[float, float] = (0.0, 0.0)) -> tuple[float, float]:
    """A measured point's standard errors (std of log |G|, of the phase in rad): its cycles' spread
    (``CycleFeatures.response_spread``; not finite: 0) over the root of their count ``cycles``, at least
    ``floor`` (log gain, phase in deg)."""
    n = max(int(cycles), 1)
    sg, sp = (float(s) if np.isfinite(s) else 0.0 for s in spread)
    return max(sg / math.sqrt(n), floor[0]), max(sp / math.sqrt(n), math.radians(floor[1]))


def phase_se_deg(phase_spread_rad: float, cycles: int) -> float:
    """A measured point's phase standard error, deg: ``point_sigmas``' of a phase spread (rad) over ``cycles``."""
    return math.degrees(point_sigmas((0.0, phase_spread_rad), cycles)[1])
