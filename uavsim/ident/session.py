"""Identification of a flight session: class, model and PD gains from its relay run.

From a session (``uavsim-session/2`` or 1) with an ``np-mrft`` (or ``mrft``) run:

1. the last steady cycle, exactly as the training sets were built, checked
   (``uavsim.ident.cycle.extract_cycle``);
2. the class: the answer of least expected J under the network's softmax (on attitude
   loops kept to the classes the measured point allows: ``uavsim.ident.consistent``), over the
   bundle's cost matrix and (inner loops' default, ``decision="blend"``) over the belief's
   models fitted to the measured point (``uavsim.ident.select.decide_class``;
   ``decision="argmax"``: the most likely class, also what a bundle exported without the
   matrix answers); with a second run, weighed by both measured points (``uavsim.ident.twopoint``)
   and, where the model root holds a network of that run's ``beta``, by its belief too
   (``uavsim.ident.secondnet``);
3. the gains: the table's robust PD of the class over the estimated gain
   ``K_hat`` (``uavsim.ident.gains``), the real-time answer, backed off on the inner
   loops where the answer's fitted model with a few degrees more lag needs it
   (``uavsim.ident.guard``), with a second run no further than the models both points
   allow ask (``uavsim.ident.lagfamily``). With ``optimum``
   the fitted model's own optimum at the control rate is computed too (~10-20 ms,
   its latency in the answer) and answered when the fitted model is off the
   grid (``optimum="auto"``: its delay more than ``OFF_GRID_TAU`` from the class's)
   or always (``optimum="always"``). A lateral loop's steady cycle answers instead the PD
   chosen over the family of models its measured point allows (``uavsim.ident.family``,
   under a second; ``gains_source`` ``family``), kept to the members a second run's point
   allows too, and anchored on that run's point where only it is steady;
4. the model: the class's lags with the gain and delay fitted to the measured
   point (``params``: what ``write_model`` stores and the gap workflow simulates).

A session without a usable oscillation is an error (``NoOscillation``, a
``UserError``), never a guess; so is, on attitude, a class whose PD the models both relay
runs allow reject at every back-off (``uavsim.ident.lagfamily.unheld_refusal``: the runs
disagree, one cycle moved by noise). A lateral session whose network run is refused but whose
second run holds a steady cycle is answered from that run alone
(``identify_second_point``: the family's PD, no class).

    from uavsim.ident import identify_session, write_model
    ans = identify_session("scenarios/sessions/altitude-npmrft", models="training/runs/small")
    ans["class"], ans["params"]["K"], ans["gains"]["kp"], ans["gains_source"]
    write_model("scenarios/sessions/altitude-npmrft", ans)      # adds the [model] table
"""

from __future__ import annotations

import math
import os
import time
from dataclasses import asdict, replace
from pathlib import Path
from typing import Any

import numpy as np

from uavsim.control.relay import relay_command
from uavsim.data.preprocess import CycleFeatures
from uavsim.errors import NoOscillation, UserError
from uavsim.formats.session import RELAY_KINDS
from uavsim.ident.bundle import ModelBundle, load_bundle, resolve_model_dir
from uavsim.ident.consistent import consistent_activations
from uavsim.ident.cycle import extract_cycle, phase_lost
from uavsim.ident.family import (
    FAMILY_OTHER_CHI2,
    FAMILY_SPREAD_LIMITS,
    FAMILY_UNSTEADY_CHI2,
    SECOND_SPREAD_LIMITS,
    default_family,
    family_applies,
    family_gains,
    point_spread,
    unsteady_spread,
)
from uavsim.ident.gains import (
    fitted_model,
    flight_attitude,
    measured_point_gains,
    model_optimum,
    table_gains,
)
from uavsim.ident.guard import answer_guard, default_guard
from uavsim.ident.lagfamily import unheld_refusal
from uavsim.ident.secondnet import (
    SecondReading,
    first_weight,
    load_second_bundle,
    multiply_beliefs,
    second_reading,
)
from uavsim.ident.select import cycle_activations, decide_class
from uavsim.ident.twopoint import SECOND_RUN_AUTO, auto_second_run
from uavsim.learning.decision import softmax

__all__ = ["OPTIMUM_MODES", "OFF_GRID_TAU", "identify_cycle", "identify_second_point", "identify_arrays",
           "identify_session", "write_model"]

#: when the fitted model's optimum is computed and answered (``identify_cycle``)
OPTIMUM_MODES = ("never", "auto", "always")
#: ``optimum="auto"``: the fitted model is off the grid when its delay differs from its class's by more
#: than this (s) and this fraction of the class's (a grid level of delay is ~40-60% apart)
OFF_GRID_TAU = (0.002, 0.25)
_GAIN_KEYS = ("kp", "kd", "derivative_filter_hz")


def _point(f: CycleFeatures) -> dict[str, float]:
    """A cycle's measured point as answers report it: gain and phase as measured (hold included), its
    frequency (rad/s) and the response cycles it was averaged over."""
    return {"gain": abs(f.response), "phase_deg": math.degrees(np.angle(f.response)),
            "omega": 2 * math.pi / f.response_period, "n_cycles": f.response_cycles}


def _floats(g: dict[str, np.ndarray], keys=_GAIN_KEYS) -> dict[str, float]:
    return {k: float(np.asarray(g[k]).ravel()[0]) for k in keys}


def identify_cycle(f: CycleFeatures, bundle: ModelBundle, *, optimum: str = "never",
                   attitude: dict[str, float] | None = None, decision: str | None = None,
                   guard: bool | None = None, combine: str | None = None, second: CycleFeatures | None = None,
                   family: bool | None = None, second_network: SecondReading | None = None) -> dict[str, Any]:
    """Identify from an extracted cycle (``extract_cycle``); see the module docstring.

    Parameters
    ----------
    f : CycleFeatures
        The checked cycle.
    bundle : ModelBundle
        The network and its tables.
    optimum : ``"never"``, ``"auto"`` or ``"always"``
        Whether the fitted model's optimum is computed and answered (module docstring).
    attitude : dict or None
        Lateral only: the flight's attitude loop when known better than the bundle's
        (``T_prop``, ``T1``, ``tau_in``, ``att_kp``, ``att_kd``, ``att_filter_hz``); it changes the
        fitted model and its optimum, not the table's answer.
    decision : ``"bayes"``, ``"argmax"``, ``"fitted"``, ``"stable"``, ``"blend"`` or None
        The class decision (``uavsim.ident.select``); None: the loop's default
        (``DEFAULT_DECISION``: ``stable`` on lateral loops, ``blend`` on the inner ones) where the
        bundle carries its cost matrix, else the bundle's (``ModelBundle.decision``).
    guard : bool or None
        Back the table's PD off where the answer's fitted model with a few degrees more lag
        needs it (``uavsim.ident.guard``; the answer's ``guard``: ``scale``, ``phase_deg``,
        ``latency_ms``). Not applied to an optimum answered. None: the loop's default
        (``uavsim.ident.guard.DEFAULT_GUARD``: on for the inner loops).
    combine : str or None
        How the beliefs of several looks at the run combine, where ``f`` holds them
        (``uavsim.ident.select.cycle_activations``); None: ``DEFAULT_LOOK_COMBINE``.
    second : CycleFeatures or None
        A second relay run's cycle at another ``beta`` (``uavsim.ident.twopoint``): the belief is
        weighed by how well each class fits both measured points before the decision; on the loops
        of ``uavsim.ident.lagfamily.LAG_GUARD_LOOPS`` the guard backs off no further than the lag family
        of both points asks (``answer_guard``; the guard's ``scale_one_point`` and ``lag_family``).
    family : bool or None
        Lateral only: on a steady cycle (``uavsim.ident.family.family_applies``) answer the PD
        chosen over the family of models the measured point allows (``family_gains``; the
        answer's ``family``: the member, its factor, ``latency_ms``) instead of the table's,
        unless a fitted optimum is answered. None: the loop's default (``uavsim.ident.family.DEFAULT_FAMILY``:
        on for lateral loops).
    second_network : SecondReading or None
        With ``second``: the second run's network's look at that run (``uavsim.ident.secondnet``): its
        belief multiplies the first's, which is tempered where the first point is unsteady (the answer's
        ``second_network``).

    Returns
    -------
    dict: ``loop``, ``class``, ``params`` (the fitted model), ``gains`` (kp, kd,
    derivative_filter_hz), ``gains_source`` (``table`` or ``optimum``), ``table`` (class,
    ``K_hat``, rate), ``gains_table`` (unguarded), ``guard`` (with ``guard``), ``gains_optimum`` (when computed, with ``latency_ms`` and
    ``ise``), ``gains_measured_point``, ``off_grid``, ``class_params``, ``decision`` (``decision``,
    ``expected_J`` of the class answered, ``class_argmax``, ``softmax`` of the class answered,
    ``scale``, ``ruled_out``: how many classes the measured point took out of the belief,
    ``uavsim.ident.consistent``), ``softmax_top``, ``oscillation`` and ``response``.
    """
    if optimum not in OPTIMUM_MODES:
        raise UserError(f"optimum must be one of {', '.join(OPTIMUM_MODES)}, got {optimum!r}")
    guard = default_guard(bundle.loop, guard)
    w_first = 1.0 if second is None or second_network is None else first_weight(
        f, second, lost=phase_lost(f.response, f.response_period, bundle.rule.beta, bundle.input_rate_hz))
    act, n_out = consistent_activations(bundle, w_first * cycle_activations(bundle, f, combine=combine), f)
    act_net = act  # the network's own belief (the lag family weighs its members by the points itself)
    if second is not None:  # the belief weighed by how each class fits both measured points
        from uavsim.ident.twopoint import two_point_activations

        act = two_point_activations(bundle, act, f, second)
        if second_network is not None:
            act = multiply_beliefs(act, bundle.temperature, second_network)
    dec = decide_class(bundle, act, decision=decision, response=np.array([f.response]),
                       response_period=np.array([f.response_period]), response_spread=np.array([f.response_spread]))
    c = int(dec.cls[0])
    model = fitted_model(bundle, [c], np.array([f.response]), np.array([f.response_period]), attitude=attitude)
    K_hat = model["K"]
    if not (np.isfinite(K_hat[0]) and K_hat[0] > 0):
        raise UserError(f"cannot recover the gain: fundamental response {f.response} over {f.response_cycles} cycles")
    g_tab = table_gains(bundle, [c], K_hat)
    dec_scale = 1.0 if dec.scale is None else float(dec.scale[0])
    if dec_scale != 1.0:  # the decision's factor on the class's PD (the stable decision's)
        g_tab = {**g_tab, "kp": dec_scale * g_tab["kp"], "kd": dec_scale * g_tab["kd"]}
    tau, tau_c = float(model["tau"][0]), float(model["tau_class"][0])
    off = abs(tau - tau_c) > max(OFF_GRID_TAU[0], OFF_GRID_TAU[1] * tau_c)
    ans: dict[str, Any] = {"loop": bundle.loop, "class": c}
    if bundle.loop == "lateral":
        ans["attitude_class"] = bundle.att_class
        ans["params"] = {k: float(model[k][0]) for k in ("K", "T_prop", "T1", "T2", "tau", "tau_in")}
        ans["attitude"] = {k: float(model[k][0]) for k in ("att_kp", "att_kd", "att_filter_hz")}
        ans["class_params"] = {k: float(bundle.column(k)[c]) for k in ("T2", "tau")}
    else:
        ans["params"] = {k: float(model[k][0]) for k in ("K", "T_prop", "T1", "tau")}
        ans["class_params"] = {k: float(bundle.column(k)[c]) for k in ("T_prop", "T1", "tau")}
    ans["gains"] = _floats(g_tab)
    ans["gains_source"] = "table"
    ans["table"] = {"class": c, "K_hat": float(K_hat[0]), "rate_hz": bundle.rate_hz, "answer": "robust",
                    "gain_estimate": "K_hat = |G(jw)| / |G_class(jw)| at the measured w"}
    ans["gains_table"] = _floats(g_tab)
    if guard:
        t0 = time.perf_counter()
        gd = answer_guard(bundle, dec.p[0], c, f.response, f.response_period, kp=float(g_tab["kp"][0]),
                          kd=float(g_tab["kd"][0]), derivative_filter_hz=float(g_tab["derivative_filter_hz"][0]),
                          attitude=attitude, first=f, second=second,
                          p_network=softmax(act_net, bundle.temperature)[0])
        lag = gd.get("lag_family")
        why = None if lag is None else unheld_refusal(bundle.loop, lag, cls=c, first_spread=unsteady_spread(f))
        if why is not None:
            raise NoOscillation(why)
        s = gd["scale"]
        ans["guard"] = {**gd, "latency_ms": 1e3 * (time.perf_counter() - t0)}
        ans["gains"] = {**ans["gains"], "kp": s * ans["gains"]["kp"], "kd": s * ans["gains"]["kd"]}
    ans["off_grid"] = bool(off)
    if optimum == "always" or (optimum == "auto" and off):
        t0 = time.perf_counter()
        opt = model_optimum(bundle, model, start=g_tab)
        ms = 1e3 * (time.perf_counter() - t0)
        if np.isfinite(opt.ise[0]):
            ans["gains_optimum"] = {**_floats({"kp": opt.kp, "kd": opt.kd,
                                               "derivative_filter_hz": opt.derivative_filter_hz}),
                                    "ise": float(opt.ise[0]), "latency_ms": ms}
            ans["gains"] = {k: ans["gains_optimum"][k] for k in _GAIN_KEYS}
            ans["gains_source"] = "optimum"
    # the family of the first steady point (the network's run's, else the second run's), kept to the members
    # the other point allows: more of them where that one is not steady (its error is not its spread's)
    fam_on = default_family(bundle.loop, family) and ans["gains_source"] == "table"
    steady = [fam_on and x is not None and family_applies(x.response_spread, x.response_cycles, limits=lim)
              for x, lim in ((f, FAMILY_SPREAD_LIMITS), (second, SECOND_SPREAD_LIMITS))]
    if any(steady):
        t0 = time.perf_counter()
        (a, o), o_steady = ((f, second), steady[1]) if steady[0] else ((second, f), False)
        fam = family_gains(bundle, dec.p[0], a.response, a.response_period,
                           spread=point_spread(a.response_spread, a.response_cycles), attitude=attitude, other=o,
                           other_chi2=FAMILY_OTHER_CHI2 if o_steady else FAMILY_UNSTEADY_CHI2)
        if fam is not None:
            ans["family"] = {**asdict(fam), "point": "first" if a is f else "second",
                             "latency_ms": 1e3 * (time.perf_counter() - t0)}
            ans["gains"] = {"kp": fam.kp, "kd": fam.kd, "derivative_filter_hz": fam.derivative_filter_hz}
            ans["gains_source"] = "family"
    gm = measured_point_gains(np.array([f.response]), np.array([f.response_period]), rule=bundle.rule,
                              rate_hz=bundle.input_rate_hz)
    ans["gains_measured_point"] = _floats(gm)
    ans["decision"] = {"decision": dec.decision, "expected_J": None if np.isnan(dec.expected_J[0]) else
                       float(dec.expected_J[0]), "class_argmax": int(dec.p[0].argmax()), "softmax": float(dec.p[0, c]),
                       "scale": dec_scale, "ruled_out": n_out}
    ans["softmax_top"] = float(dec.p[0, c])
    if second is not None and second_network is not None:
        p2 = second_network.belief()[0]
        ans["second_network"] = {"model_dir": second_network.model_dir, "beta": second_network.beta,
                                 "class_argmax": int(p2.argmax()), "softmax": float(p2[c]),
                                 "first_weight": w_first, "first_unsteady": unsteady_spread(f)}
    ans["oscillation"] = {"period": f.period, "amplitude": f.amplitude, "n_cycles": f.n_cycles, "start": f.start,
                          "stop": f.stop, "inputs": f.inputs, "input_cycles": f.input_cycles}
    ans["response"] = _point(f)
    return ans


def identify_second_point(second: CycleFeatures, bundle: ModelBundle, *, refused: str,
                          attitude: dict[str, float] | None = None, family: bool | None = None) -> dict[str, Any] | None:
    """A lateral answer from the second run alone, where the network's run was refused; None where there is none.

    The network reads only its own run's cycle, so nothing tells the classes apart: the belief is flat and the
    answer is the family's PD (``uavsim.ident.family``) of the second run's point, where that cycle is steady
    (``family_applies`` within ``SECOND_SPREAD_LIMITS``). ``refused``: why the network's run was (the answer's
    ``family.refused``). The answer has no ``class`` (None) and no table gains; ``params`` is the family member
    whose optimum was answered.
    """
    if not (default_family(bundle.loop, family) and family_applies(second.response_spread, second.response_cycles,
                                                                   limits=SECOND_SPREAD_LIMITS)):
        return None
    t0 = time.perf_counter()
    n = bundle.n_classes
    fam = family_gains(bundle, np.full(n, 1.0 / n), second.response, second.response_period,
                       spread=point_spread(second.response_spread, second.response_cycles), attitude=attitude)
    if fam is None:
        return None
    att = flight_attitude(bundle, attitude)
    return {"loop": bundle.loop, "class": None, "attitude_class": bundle.att_class,
            "params": {"K": fam.K, "T_prop": float(att["T_prop"]), "T1": float(att["T1"]), "T2": fam.T2_s,
                       "tau": fam.tau_s, "tau_in": float(att["tau_in"])},
            "attitude": {k: float(att[k]) for k in ("att_kp", "att_kd", "att_filter_hz")},
            "gains": {"kp": fam.kp, "kd": fam.kd, "derivative_filter_hz": fam.derivative_filter_hz},
            "gains_source": "family",
            "family": {**asdict(fam), "point": "second", "refused": refused,
                       "latency_ms": 1e3 * (time.perf_counter() - t0)},
            "oscillation": {"period": second.period, "amplitude": second.amplitude, "n_cycles": second.n_cycles,
                            "start": second.start, "stop": second.stop},
            "response": _point(second)}


def identify_arrays(y: np.ndarray, u: np.ndarray, *, rate_hz: float, h: float, bias: float, bundle: ModelBundle,
                    beta: float | None = None, optimum: str = "never",
                    attitude: dict[str, float] | None = None, decision: str | None = None,
                    guard: bool | None = None, second: CycleFeatures | None = None,
                    family: bool | None = None, second_network: SecondReading | None = None) -> dict[str, Any]:
    """Identify from raw traces at the control rate: ``extract_cycle`` then ``identify_cycle``.

    ``y``, ``u``: (T,) measurement and relay command as the controller saw / computed them;
    ``h``, ``bias``: the relay's; ``beta``: the run's MRFT parameter (checked against the network's);
    ``second``: a second run's cycle (``second_cycle``), and ``second_network``: its network's look at
    it, as ``identify_cycle`` takes them; ``family``: ``identify_cycle``'s.
    """
    f = extract_cycle(y, u, rate_hz=rate_hz, h=h, bias=bias, bundle=bundle, beta=beta)
    return identify_cycle(f, bundle, optimum=optimum, attitude=attitude, decision=decision, guard=guard,
                          second=second, family=family, second_network=second_network)


def second_cycle(y: np.ndarray, u: np.ndarray, *, rate_hz: float, h: float, bias: float,
                 cycles: int = 1, loop: str | None = None) -> CycleFeatures:
    """A second relay run's cycle, for its measured point only (``uavsim.ident.twopoint``): any cycle length,
    the point averaged over up to ``second_response_cycles(loop)`` steady cycles.

    Raises ``NoOscillation`` where the run holds no usable oscillation.
    """
    from uavsim.data.preprocess import features
    from uavsim.ident.twopoint import second_response_cycles

    return features(np.asarray(y, dtype=np.float64), np.asarray(u, dtype=np.float64), rate_hz, h, bias, len(y),
                    cycles=cycles, response_cycles=second_response_cycles(loop))


def identify_session(path: str | os.PathLike, *, models: str | os.PathLike | None = None, run: str | None = None,
                     attitude_class: int | None = None, attitude: dict[str, float] | None = None,
                     optimum: str = "never", decision: str | None = None, guard: bool | None = None,
                     second_run: str | None = SECOND_RUN_AUTO, family: bool | None = None,
                     duty_check: bool = True, second_network: bool = True) -> dict[str, Any]:
    """Identify the loop of a session from its relay run (module docstring).

    Parameters
    ----------
    path : path-like
        Session folder (or its ``session.toml``).
    models : path-like or None
        Exported model folder or a root with ``altitude/``, ``attitude/``, ``lateral/aNN/``
        (default ``uavsim.ident.bundle.default_model_root()``).
    run : str or None
        File name of the run to use (default: the first np-mrft run, else the first mrft run).
    attitude_class : int or None
        Lateral sessions only (required): the attitude class of the loop the lateral one closes
        over (what identification of its roll or pitch session gave); picks ``lateral/aNN``.
    attitude : dict or None
        Lateral only: the flight's attitude loop when known (``identify_cycle``).
    optimum, decision, guard, family : str, str, bool, bool
        ``identify_cycle``'s.
    second_run : str or None
        File name of a second relay run of the session at another ``beta`` (``-0.3``:
        ``uavsim.ident.twopoint.SECOND_BETA``) whose measured point weighs the belief; None: one run;
        ``"auto"`` (default): on the loops of ``uavsim.ident.twopoint.SECOND_RUN_LOOPS``, the session's
        relay run at ``SECOND_BETA`` where it holds one (``auto_second_run``), else one run. A run
        found so that holds no cycle leaves one point, and the answer's ``second_run`` says why
        (``skipped``); a run named that holds none is an error.
    duty_check : bool
        Refuse a cycle whose duty a network trained on bias-trimmed relays never saw
        (``uavsim.ident.cycle.duty_refusal``). The gap workflow turns it off for a base model
        when every relay run is refused so: the bias is one of the effects it looks for.
    second_network : bool
        With a second run, let the network of that run's ``beta`` beside the model folder
        (``uavsim.ident.secondnet``: ``altitude-second``) read it, where the root holds one.

    Returns
    -------
    dict
        The JSON of ``uavsim identify --json`` (docs/formats/session.md): ``identify_cycle``'s
        answer with the session's ``loop``, ``run``, ``model_dir``, ``had_model``, ``noise_std``.
    """
    from uavsim.formats.session import read_session
    from uavsim.lumped.params import loop_family

    s = read_session(path)
    fam = loop_family(s.loop)
    if fam == "lateral" and attitude_class is None:
        raise UserError(f"session {path} is {s.loop}: pass the attitude class its loop closes over "
                        "(--attitude-class N, from `uavsim identify` of the roll/pitch session)")
    relays = [r for r in s.runs if r.spec.kind in RELAY_KINDS]
    if run is not None:
        relays = [r for r in relays if r.spec.file == run]
        if not relays:
            raise UserError(f"session {path}: no np-mrft/mrft run with file {run!r}")
    if not relays:
        raise UserError(f"session {path}: no np-mrft or mrft run to identify from")
    relays.sort(key=lambda r: r.spec.kind != "np-mrft")
    r = relays[0]
    d = resolve_model_dir(fam, models, attitude_class)
    b = load_bundle(d)
    if not duty_check:
        b = replace(b, bias_trim="off")
    if b.loop != fam:
        raise UserError(f"{d} holds a {b.loop} network, the session is {s.loop}")
    if fam == "lateral" and b.att_class not in (None, attitude_class):
        raise UserError(f"{d} is the lateral network of attitude class {b.att_class}, not {attitude_class}")
    second, skipped = None, None
    auto = second_run == SECOND_RUN_AUTO
    if auto:
        second_run = auto_second_run(s.runs, r.spec.file, fam, b.rule.beta)
    if second_run is not None:
        r2 = next((x for x in s.runs if x.spec.file == second_run and x.spec.kind in RELAY_KINDS), None)
        if r2 is None:
            raise UserError(f"session {path}: no np-mrft/mrft run with file {second_run!r} for the second point")
        if r2.spec.beta is None or abs(float(r2.spec.beta) - b.rule.beta) < 1e-6:
            raise UserError(f"session {path}: the second run {second_run} must be at another beta than the "
                            f"network's ({b.rule.beta:g}), got {r2.spec.beta}")
        try:
            h2, b2 = float(r2.spec.h), float(r2.spec.bias or 0.0)
            second = second_cycle(r2.data.y, relay_command(r2.data.u, h2, b2, r2.spec.bias_trim),
                                  rate_hz=s.control_rate_hz, h=h2, bias=b2, cycles=b.cycles, loop=fam)
        except NoOscillation as exc:
            if not auto:
                raise UserError(f"session {path}: second run {second_run}: {exc}") from None
            skipped = str(exc)  # a run found, not asked for: one point, and the answer says why
    reading = None
    if second is not None and second_network:
        b_second = load_second_bundle(d, b, beta=float(r2.spec.beta))
        if b_second is not None:
            if not duty_check:
                b_second = replace(b_second, bias_trim="off")
            reading = second_reading(b_second, r2.data.y, relay_command(r2.data.u, h2, b2, r2.spec.bias_trim),
                                     rate_hz=s.control_rate_hz, h=h2, bias=b2)
    h, bias = float(r.spec.h), float(r.spec.bias or 0.0)
    try:
        ans = identify_arrays(r.data.y, relay_command(r.data.u, h, bias, r.spec.bias_trim),
                              rate_hz=s.control_rate_hz, h=h, bias=bias, bundle=b, beta=r.spec.beta,
                              optimum=optimum, attitude=attitude, decision=decision, guard=guard, second=second,
                              family=family, second_network=reading)
        ans["run"] = r.spec.file
    except NoOscillation as exc:  # a lateral loop may still answer from a steady second run
        ans = None if second is None else identify_second_point(second, b, refused=f"{r.spec.file}: {exc}",
                                                                attitude=attitude, family=family)
        if ans is None:
            raise
        ans["run"] = second_run
    ans["loop"] = s.loop
    if skipped is not None:
        ans["second_run"] = {"run": second_run, "beta": float(r2.spec.beta), "skipped": skipped}
    if second is not None:
        ans["second_run"] = {"run": second_run, "beta": float(r2.spec.beta), **_point(second)}
    ans["model_dir"] = str(d)
    ans["had_model"] = s.model is not None
    # NP-MRFT a_n is a noise amplitude (2 std for Gaussian noise, uavsim.noise.models)
    ans["noise_std"] = float(r.spec.a_n or 0.0) / 2.0
    return ans


def write_model(path: str | os.PathLike, ans: dict[str, Any], *, overwrite: bool = False) -> Path:
    """Write the identified model (``ans["params"]``) as the session's ``[model]`` table.

    Refuses to replace an existing ``[model]`` unless ``overwrite``.
    """
    from uavsim.formats.session import ModelSpec, read_session, write_session

    s = read_session(path)
    if s.model is not None and not overwrite:
        raise UserError(f"session {path} already has a [model]; pass --force to replace it")
    p = ans["params"]
    model = ModelSpec(K=float(p["K"]), T_prop=float(p["T_prop"]), T1=float(p["T1"]), tau=float(p["tau"]),
                      T2=p.get("T2"), noise_std=float(ans.get("noise_std", 0.0)))
    folder = Path(path)
    if folder.name == "session.toml":
        folder = folder.parent
    return write_session(replace(s, model=model), folder)
