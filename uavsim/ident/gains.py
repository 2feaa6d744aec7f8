"""Gain choice: the table's PD of the identified class, for the identified gain.

The real-time answer (``table_gains``): the grid's table at the control rate
(``uavsim.tuning.table``, carried in the bundle) holds each class's PD for
``K = 1``; the process gain is estimated as the table's J assumes it, the
measured response magnitude (hold removed) over the class's own at the measured
frequency, ``K_hat = |G(j w)| / |G_class(j w)|`` (``fitted_model``'s ``K``), and
the answer is the class's robust PD over ``K_hat`` with the class's derivative
filter. ``gain_estimate`` (against the class's magnitude at its nominal MRFT
point) is kept for comparison. Nothing is optimized at identification time: a matrix lookup and a
division.

The optimum of the fitted model (``model_optimum``, ~10-20 ms): the class's
lags with the gain and delay fitted to the measured point (``fitted_model``),
optimized at the control rate (``uavsim.tuning.optimal``), started from the
table's answer. The rule at the measured point (``measured_point_gains``) needs
neither network nor model.

    from uavsim.ident.gains import gain_estimate, table_gains
    K_hat = gain_estimate(bundle, cls, G)          # G: measured G(j w), hold removed
    g = table_gains(bundle, cls, K_hat)            # kp, kd, derivative_filter_hz (m,)
"""

from __future__ import annotations

import math

import numpy as np

from uavsim.data.preprocess import process_response
from uavsim.ident.bundle import ModelBundle
from uavsim.ident.response import fit_response, fit_response_lateral
from uavsim.tuning.rule import TuningRule

__all__ = ["gain_estimate", "table_gains", "fitted_model", "flight_attitude", "lateral_model", "model_optimum",
           "measured_point_gains"]


def gain_estimate(bundle: ModelBundle, cls, G) -> np.ndarray:
    """``K_hat = |G(j w)| / table_gain_at_omega[cls]``: the estimate at the class's nominal MRFT point, (m,).

    ``G``: the measured ``G(j w)`` (output units per command unit, hold removed:
    ``uavsim.data.preprocess.process_response``) at the cycle's frequency.
    """
    cls = np.asarray(cls, dtype=np.int64)
    return np.abs(np.asarray(G)) / bundle.column("table_gain_at_omega")[cls]


def table_gains(bundle: ModelBundle, cls, K_hat, *, robust: bool = True) -> dict[str, np.ndarray]:
    """The table's PD of classes ``cls`` for processes of gain ``K_hat``: ``kp``, ``kd``, ``derivative_filter_hz`` (m,).

    ``robust`` (default): the robust answers (``table_robust_kp``, ``table_robust_kd``), which a
    one-level miss of the class does not destabilize; else the classes' own ISE optima.
    """
    cls = np.asarray(cls, dtype=np.int64)
    K_hat = np.asarray(K_hat, dtype=np.float64)
    kp, kd = ("table_robust_kp", "table_robust_kd") if robust else ("table_kp", "table_kd")
    return {"kp": bundle.column(kp)[cls] / K_hat, "kd": bundle.column(kd)[cls] / K_hat,
            "derivative_filter_hz": bundle.column("table_filter_hz")[cls] * np.ones_like(K_hat)}


def fitted_model(bundle: ModelBundle, cls, response, response_period, *,
                 attitude: dict[str, float] | None = None) -> dict[str, np.ndarray]:
    """The classes' lags with the gain and delay that put them on the measured response, (m,) arrays.

    Inner loops: ``K``, ``T_prop``, ``T1``, ``tau``, ``tau_class`` (``fit_response``). Lateral:
    ``K``, ``T2``, ``tau``, ``tau_class`` and the attitude loop's ``T_prop``, ``T1``, ``tau_in``,
    ``att_kp``, ``att_kd``, ``att_filter_hz`` (the bundle's, or ``attitude`` when the flight's
    attitude loop is known better), and ``att_rate_hz`` where that PD runs at a control rate.
    """
    cls = np.asarray(cls, dtype=np.int64)
    c = bundle.column
    if bundle.loop == "lateral":
        return lateral_model(bundle, response, response_period, T2=c("T2")[cls], tau_class=c("tau")[cls],
                             attitude=attitude)
    return fit_response(response, response_period, T_prop=c("T_prop")[cls], T1=c("T1")[cls], tau_class=c("tau")[cls],
                        rate_hz=bundle.input_rate_hz)


def flight_attitude(bundle: ModelBundle, attitude: dict[str, float] | None = None) -> dict[str, float]:
    """The attitude loop a lateral model closes over: the bundle's, with ``attitude``'s keys where the flight's
    is known better."""
    att = dict(bundle.attitude or {})
    att.update(attitude or {})
    return att


def lateral_model(bundle: ModelBundle, response, response_period, *, T2, tau_class,
                  attitude: dict[str, float] | None = None) -> dict[str, np.ndarray]:
    """Lateral models of drag time constants ``T2`` with the gain and delay that put them on the measured
    response (``fit_response_lateral``, the delay's branch nearest ``tau_class``), over the bundle's
    attitude loop or ``attitude`` where given: ``fitted_model``'s lateral keys, (m,) arrays."""
    att = flight_attitude(bundle, attitude)
    m = fit_response_lateral(response, response_period, T2=T2, tau_class=tau_class, attitude=att,
                             rate_hz=bundle.input_rate_hz)
    shape = np.shape(m["K"])
    m.update({k: np.full(shape, float(att[k])) for k in ("T_prop", "T1", "tau_in", "att_kp", "att_kd",
                                                         "att_filter_hz")})
    if att.get("rate_hz") is not None:  # the attitude PD flown at the control rate
        m["att_rate_hz"] = np.full(shape, float(att["rate_hz"]))
    return m


def model_loop_params(bundle: ModelBundle, model: dict[str, np.ndarray]) -> dict:
    """A fitted model's process parameters as ``lift`` and ``optimal_gains`` take them, (m,) arrays.

    Lateral: the attitude PD's filter in rad/s (``att_N``) and its rate where it runs at one.
    """
    keys = ("K", "T_prop", "T1", "tau") + (("T2", "tau_in", "att_kp", "att_kd") if bundle.loop == "lateral" else ())
    p = {k: np.atleast_1d(np.asarray(model[k], dtype=np.float64)) for k in keys}
    if bundle.loop == "lateral":
        p["att_N"] = 2.0 * math.pi * np.atleast_1d(np.asarray(model["att_filter_hz"], dtype=np.float64))
        if "att_rate_hz" in model:
            p["att_rate_hz"] = float(np.asarray(model["att_rate_hz"]).ravel()[0])
    return p


def model_optimum(bundle: ModelBundle, model: dict[str, np.ndarray], *, start: dict[str, np.ndarray] | None = None):
    """ISE-optimal PDs of fitted models at the bundle's control rate (``OptimalGains``, batched).

    The derivative filter is the rule's for the model (``uavsim.tuning.optimal``); ``start``
    (``kp``, ``kd``: e.g. ``table_gains``) skips the scan where it is stable.
    """
    from uavsim.tuning.optimal import optimal_gains

    s = None if start is None else (np.atleast_1d(start["kp"]), np.atleast_1d(start["kd"]))
    return optimal_gains(bundle.loop, bundle.rate_hz, rule=bundle.rule, start=s, **model_loop_params(bundle, model))


def measured_point_gains(response, response_period, *, rule: TuningRule, rate_hz: float = 200.0
                         ) -> dict[str, np.ndarray]:
    """The rule's constants at the measured point, no model: ``kp = c1 / |G(j w)|``, ``Td = c3 2 pi / w``.

    Boiko's non-parametric MRFT tuning with the exact first-harmonic gain of the
    cycle (hold removed) in place of the describing function's ``4 h / (pi a)``,
    at the measured frequency ``w``. Returns ``kp``, ``kd``, ``derivative_filter_hz``
    (the rule's ``10 w``), each (m,).
    """
    from uavsim.lumped.lateral import DERIVATIVE_FILTER_RATIO
    from uavsim.tuning.rule import rule_constants

    c1, c3 = rule_constants(rule.beta, rule.pm_deg, rule.gain_scale)
    w = 2.0 * np.pi / np.asarray(response_period, dtype=np.float64)
    kp = c1 / np.abs(process_response(response, response_period, rate_hz=rate_hz))
    return {"kp": kp, "kd": kp * c3 * 2.0 * np.pi / w, "derivative_filter_hz": DERIVATIVE_FILTER_RATIO * w / (2 * np.pi)}
