"""Identification of a flight session with a trained network (DNN-NP-MRFT).

From a session (``uavsim-session/2`` or 1) with an ``np-mrft`` (or ``mrft``) run:

1. extract the last steady cycle exactly as the training sets were built
   (``uavsim.data.preprocess.features``: same resampling to 200 Hz, same edges,
   same normalization, same input length);
2. predict the class with the exported network of the loop's family
   (``uavsim.learning.export.Predictor``), then pick among its ``SELECT_TOP``
   most likely classes the one whose model best explains the cycle's harmonics
   2..7 (``select_class``). The grid's J puts classes of one ``Omega`` level at
   J = 1 from one another, so the J-weighted loss leaves the network free to
   mix up their lags; the harmonics tell them apart (off-grid p95 ISE
   deterioration 44% -> 11.5%, README);
3. fit the class's model to the loop's measured frequency response: the ratio
   ``Y1 / (h U1)`` of the first harmonics of y and of the command over the last
   steady cycles (``CycleFeatures.response``) is, once the zero-order hold's
   ``sinc(w Ts/2) e^{-j w Ts/2}`` is removed, the process's ``G(j w)`` at the
   cycle's frequency ``w``, whatever the relay's bias, ``tau_obs``, ``a_n`` and
   the sampling did to the cycle. The identified model keeps the class's lags
   ``T_prop``, ``T1`` and takes the gain ``K`` and delay ``tau`` that put its
   response exactly on that point (``fit_response``);
4. tune: the homogeneous rule of the grid (``beta``, ``pm``) applied to the
   models of the ``DECIDE_TOP`` best fits (``model_gains``), and the gains of
   least expected deterioration over all of them answered (``decide_gains``:
   the fits barely tell those models apart, and too high a gain costs more
   than too low a one; off-grid p95 11.5% -> 2.3%, README, with a plain
   detuning's 7.7% beside it).

Why not the class's tabulated gains scaled by ``K_hat = (a / h) / a_class``
(the authors' recovery)? The class amplitude is the plain continuous MRFT's,
and the measured cycle carries the 200 Hz sampling, ``tau_obs``, ``a_n``, the
bias and noise (median ``|K_hat / K - 1|`` 57% off-grid); and a class whose
``Omega`` is one level off would bring its ``Omega`` into the gains. Fitting
the measured point makes the gains depend on the network only through the
lags' local shape. ``uavsim.learning.evaluate`` reports both, in one run.

A session without a usable oscillation (too short for two cycles, no
switching, a relay command that is not +-h, a flat or saturated output, a
period no class of the grid comes near or a phase the relay cannot have put
it at: the relay switching on noise) is an error (``NoOscillation``, a ``UserError``), never a guess.

    from uavsim.learning.identify import identify_session, write_model
    ans = identify_session("scenarios/sessions/altitude-npmrft", model_dir="training/runs/small")
    ans["class"], ans["params"]["K"], ans["gains"]["kp"]
    write_model("scenarios/sessions/altitude-npmrft", ans)      # adds the [model] table
"""

from __future__ import annotations

import functools
import math
import os
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from uavsim.errors import UserError
from uavsim.learning.export import META_FILE, Predictor

__all__ = ["default_model_root", "resolve_model_dir", "identify_session", "identify_arrays", "write_model",
           "fit_response", "model_gains", "measured_point_gains", "held_response", "waveform_scores", "select_class",
           "rank_candidates", "decide_gains", "DECIDE_TOP", "phase_lead", "phase_refusal", "period_bounds", "PHASE_LEAD_MAX_DEG",
           "lateral_context", "fit_response_lateral", "lateral_gains", "period_in_grid", "SATURATION_FRACTION",
           "SELECT_TOP", "PERIOD_RANGE"]

#: a cycle whose output sits at its top or bottom level this fraction of the time is clipped, not a relay cycle
SATURATION_FRACTION = 0.35
_SAT_BAND = 0.005  # of the peak-to-peak: "at the extreme level"
#: a cycle's period must lie within [PERIOD_RANGE[0] x the grid's shortest, PERIOD_RANGE[1] x its longest]
#: class period: NP-MRFT lengthens cycles (up to ~1.3x off-grid at 20% noise) but never halves them,
#: which a relay switching on noise does
PERIOD_RANGE = (0.75, 1.5)
#: a cycle lagging more than this (deg) less than the relay's phase was switched by noise (``phase_lead``);
#: NP-MRFT's own cycles lead by up to 19 deg on the off-grid altitude sets (200 Hz sampling, noise to 20% of a0)
PHASE_LEAD_MAX_DEG = 30.0
#: candidates (the network's most likely classes) that ``select_class`` weighs by the cycle's harmonics
SELECT_TOP = 30
#: best-fitting candidates over which ``decide_gains`` weighs the cost of each one's gains
DECIDE_TOP = 8

_predictors: dict[str, Predictor] = {}


def default_model_root() -> Path:
    """``$UAVSIM_MODELS`` or ``training/runs`` of the repository (where ``uavsim train`` writes)."""
    env = os.environ.get("UAVSIM_MODELS")
    if env:
        return Path(env)
    return Path(__file__).resolve().parents[2] / "training" / "runs"


def resolve_model_dir(family: str, model_dir: str | os.PathLike | None = None,
                      att_class: int | None = None) -> Path:
    """The exported model folder for a loop family.

    ``model_dir`` may be a model folder itself (holding ``meta.json``) or a root
    with one folder per family (``altitude/``, ``attitude/``, and
    ``lateral/aNN/`` per attitude class ``att_class``).
    """
    root = Path(model_dir) if model_dir is not None else default_model_root()
    if (root / META_FILE).is_file():
        return root
    sub = Path(family) / f"a{att_class:02d}" if family == "lateral" and att_class is not None else Path(family)
    if (root / sub / META_FILE).is_file():
        return root / sub
    make = "make train LOOPS=lateral" if family == "lateral" else "make train"
    raise UserError(f"no trained {family} network under {root / sub} (run `{make}` or pass --models DIR)")


def _predictor(d: Path) -> Predictor:
    key = str(d.resolve())
    if key not in _predictors:
        _predictors[key] = Predictor(d)
    return _predictors[key]


def held_response(G: np.ndarray, omega: np.ndarray, rate_hz: float) -> np.ndarray:
    """What a controller at ``rate_hz`` measures of a process response ``G(j w)``: its command is held.

    A held command's fundamental is its samples' times ``sinc(w Ts / 2) e^{-j w Ts / 2}``, so the
    sampled output over the command's samples is ``G(j w)`` times that (aliases neglected: the
    cycles here are 28 samples or longer). Shapes broadcast.
    """
    x = np.asarray(omega, dtype=np.float64) / (2.0 * rate_hz)
    return np.asarray(G) * np.sinc(x / np.pi) * np.exp(-1j * x)


def fit_response(response: np.ndarray, response_period: np.ndarray, cls: np.ndarray, table: dict[str, Any],
                 family: str, rate_hz: float | None = None) -> dict[str, np.ndarray]:
    """Identified models: the classes' lags with the gain and delay that match the measured response.

    Parameters
    ----------
    response : (m,) complex, ``CycleFeatures.response`` (output units per command unit)
    response_period : (m,) s, the period of the cycles it was measured on
    cls : (m,) int, identified classes (rows of ``table``)
    table : class table with ``T_prop``, ``T1``, ``tau`` columns
    family : ``"altitude"`` or ``"attitude"``
    rate_hz : rate of the samples the response was measured on (default ``INPUT_RATE_HZ``)

    Returns
    -------
    dict of (m,) arrays: ``K``, ``T_prop``, ``T1`` (the class's), ``tau`` (s, >= 0), and
    ``tau_class`` (the class's delay, for reference). With
    ``G0 = 1 / (jw (T_prop jw + 1)(T1 jw + 1))``: ``K = |G(jw)| / |G0(jw)|`` and
    ``tau = (arg G0(jw) - arg G(jw)) / w``, the measured phase taken on the branch
    nearest the class's own phase; a delay below 0 (the class has less lag than
    measured) is clipped to 0.
    """
    from uavsim.data.preprocess import INPUT_RATE_HZ

    if family not in ("altitude", "attitude"):
        raise UserError(f"the response fit needs an inner-loop class table, not {family!r}")
    cls = np.asarray(cls, dtype=np.int64)
    w = 2.0 * np.pi / np.asarray(response_period, dtype=np.float64)
    G = np.asarray(response) / held_response(1.0, w, rate_hz or INPUT_RATE_HZ)
    Tp, T1, tau_c = (np.asarray(table[k], dtype=np.float64)[cls] for k in ("T_prop", "T1", "tau"))
    ph0 = -0.5 * np.pi - np.arctan(w * Tp) - np.arctan(w * T1)  # unwrapped phase of G0
    mag0 = 1.0 / (w * np.hypot(1.0, w * Tp) * np.hypot(1.0, w * T1))
    return {"K": np.abs(G) / mag0, "T_prop": Tp, "T1": T1, "tau": _fitted_delay(G, ph0, w, tau_c), "tau_class": tau_c}


def _fitted_delay(G: np.ndarray, ph0: np.ndarray, w: np.ndarray, tau_class: np.ndarray) -> np.ndarray:
    """Delay (s, >= 0) that turns a delay-free model of unwrapped phase ``ph0`` into the measured ``G``,
    the measured phase taken on the branch nearest the class's own (``ph0 - w tau_class``)."""
    ph_c = ph0 - w * tau_class
    ph_m = ph_c + (np.angle(G) - ph_c + np.pi) % (2 * np.pi) - np.pi
    return np.maximum((ph0 - ph_m) / w, 0.0)


def waveform_scores(cls: np.ndarray, response: np.ndarray, response_period: np.ndarray, harmonics_y: np.ndarray,
                    harmonics_u: np.ndarray, table: dict[str, Any], family: str,
                    rate_hz: float | None = None) -> np.ndarray:
    """How badly each candidate class's fitted model explains the cycle's higher harmonics.

    Each candidate is fitted to the fundamental (``fit_response``: its lags, the
    measured ``K`` and ``tau``); its response at ``k w`` then predicts each harmonic
    of ``y`` from that of the command, relative to the fundamental:
    ``Y_k / Y_1 = [G(jkw) H(kw) / (G(jw) H(w))] U_k / U_1`` (``H`` the hold, ``held_response``).
    The score is ``sum_{k >= 2} |measured - predicted|^2`` over harmonics below 0.8 Nyquist:
    the squared waveform error, relative to the fundamental, of a least-squares fit, so
    additive noise raises every candidate's score alike. Gain and ``h`` cancel.

    Parameters
    ----------
    cls : (m, c) int, candidate classes per cycle
    response, response_period : (m,) as in ``fit_response``
    harmonics_y, harmonics_u : (m, H) complex, ``CycleFeatures.harmonics_y`` / ``harmonics_u``
    table, family, rate_hz : as in ``fit_response``

    Returns
    -------
    (m, c) float, dimensionless (lower is better)
    """
    from uavsim.data.preprocess import HARMONIC_NYQUIST_FRACTION, INPUT_RATE_HZ

    rate = rate_hz or INPUT_RATE_HZ
    cls = np.atleast_2d(np.asarray(cls, dtype=np.int64))
    m, c = cls.shape
    hy = np.asarray(harmonics_y, dtype=complex).reshape(m, 1, -1)
    hu = np.asarray(harmonics_u, dtype=complex).reshape(m, 1, -1)
    rep = lambda a: np.repeat(np.asarray(a), c)  # noqa: E731
    fit = fit_response(rep(response), rep(response_period), cls.ravel(), table, family, rate)
    w = (2.0 * np.pi / np.asarray(response_period, dtype=np.float64))[:, None, None]
    k = np.arange(1, hy.shape[-1] + 1)[None, None, :]
    Tp, T1, tau = (fit[n].reshape(m, c, 1) for n in ("T_prop", "T1", "tau"))
    s = 1j * w * k
    G = np.exp(-s * tau) / (s * (Tp * s + 1.0) * (T1 * s + 1.0)) * held_response(1.0, w * k, rate)
    pred = (G[..., 1:] / G[..., :1]) * (hu[..., 1:] / hu[..., :1])
    err = np.abs(hy[..., 1:] / hy[..., :1] - pred) ** 2
    usable = ((w * k / rate)[..., 1:] < HARMONIC_NYQUIST_FRACTION * np.pi) & np.isfinite(err)
    return np.where(usable, err, 0.0).sum(axis=-1)


def rank_candidates(scores: np.ndarray, response: np.ndarray, response_period: np.ndarray,
                    harmonics_y: np.ndarray, harmonics_u: np.ndarray, table: dict[str, Any], family: str,
                    top: int = SELECT_TOP, rate_hz: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The network's ``top`` most likely classes, reordered by ``waveform_scores`` (best fit first).

    Parameters
    ----------
    scores : (m, n_classes) network outputs (logits or probabilities: only their order is used)
    others : as in ``waveform_scores``

    Returns
    -------
    cand : (m, top) int classes, ws : (m, top) their scores (lower is better; inf where not finite).
    Rows with a non-finite score keep the network's order.
    """
    scores = np.atleast_2d(np.asarray(scores))
    cand = np.argsort(-scores, axis=1, kind="stable")[:, : max(1, int(top))]
    ws = waveform_scores(cand, response, response_period, harmonics_y, harmonics_u, table, family, rate_hz)
    good = np.all(np.isfinite(ws), axis=1)
    order = np.where(good[:, None], np.argsort(np.where(np.isfinite(ws), ws, np.inf), axis=1, kind="stable"),
                     np.arange(cand.shape[1])[None, :])
    ws = np.where(np.isfinite(ws), ws, np.inf)
    return np.take_along_axis(cand, order, axis=1), np.take_along_axis(ws, order, axis=1)


def select_class(scores: np.ndarray, response: np.ndarray, response_period: np.ndarray, harmonics_y: np.ndarray,
                 harmonics_u: np.ndarray, table: dict[str, Any], family: str, top: int = SELECT_TOP,
                 rate_hz: float | None = None) -> np.ndarray:
    """Among the network's ``top`` most likely classes, the one of lowest ``waveform_scores``: (m,) int.

    The first column of ``rank_candidates`` (same parameters); rows whose harmonics are not
    finite keep the network's first choice.
    """
    return rank_candidates(scores, response, response_period, harmonics_y, harmonics_u, table, family, top,
                           rate_hz)[0][:, 0]


def decide_gains(cand: np.ndarray, ws: np.ndarray, harmonics_y: np.ndarray, response: np.ndarray,
                 response_period: np.ndarray, table: dict[str, Any], family: str, beta: float, pm_deg: float,
                 top: int = DECIDE_TOP, ise_points: int = 300) -> dict[str, np.ndarray]:
    """PD gains of least expected deterioration over the models that explain the cycle.

    The cycle rarely tells the best-fitting candidates apart (one ``Omega``
    level's lags trade against the delay; their harmonics differ by a
    percent), yet their rule gains differ, and too high a gain costs far more
    than too low a one. So, like the J-weighted loss that trains the network,
    choose the gains by their cost over the candidates: the ``top`` best
    candidates of ``rank_candidates`` are fitted (``fit_response``) and tuned
    (``model_gains``); ``R[i, j] = max(Q(g_i, m_j) / Q(g_j, m_j), 1)`` is the
    deterioration of candidate ``i``'s gains on model ``j`` against the rule on
    ``j`` (the grid's J, for fitted models: no credit for beating the rule;
    unstable counts 1000); each model is weighted by its fit,
    ``w_j ~ exp(-(s_j - s_0) / s2)`` with ``s2 = s_0 / n`` the noise per
    usable harmonic the best fit leaves (``n`` harmonics); the gains of the
    candidate of least ``sum_j w_j R[i, j]`` are the answer.

    Parameters
    ----------
    cand, ws : (m, c) ``rank_candidates``' classes and scores, best first (c >= top)
    harmonics_y : (m, H) complex, for the count of usable harmonics
    response, response_period, table, family : as in ``fit_response``
    beta, pm_deg : the rule's
    top : candidates weighed
    ise_points : frequency points of each ISE (``step_ise_batch``)

    Returns
    -------
    dict of (m,) arrays: ``kp``, ``kd``, ``N`` (rad/s), ``derivative_filter_hz``, ``omega`` (rad/s) of the
    chosen gains, ``pick`` (the class whose model they are the rule's gains of), ``rank`` (its place among
    the candidates, 0 = best fit) and ``expected`` (its expected deterioration, ``sum_j w_j R[i, j]``);
    ``best_fit``: the same five arrays for the best fit's own rule gains. Rows whose scores are not
    finite take the best fit's gains.
    """
    from uavsim.lumped.ise import step_ise_batch

    cand = np.atleast_2d(np.asarray(cand, dtype=np.int64))[:, : max(1, int(top))]
    sc = np.atleast_2d(np.asarray(ws, dtype=np.float64))[:, : cand.shape[1]]
    m, c = cand.shape
    rep = lambda a: np.repeat(np.asarray(a), c)  # noqa: E731
    mod = fit_response(rep(response), rep(response_period), cand.ravel(), table, family)
    g = model_gains(mod, family, beta, pm_deg)
    i_, j_ = (a.ravel() for a in np.meshgrid(np.arange(c), np.arange(c), indexing="ij"))
    gi = (np.arange(m)[:, None] * c + i_[None]).ravel()
    mj = (np.arange(m)[:, None] * c + j_[None]).ravel()
    with np.errstate(all="ignore"):
        Q = step_ise_batch(family, g["kp"][gi], g["kd"][gi], g["N"][gi], g["omega"][mj], n=ise_points,
                           **{k: mod[k][mj] for k in ("K", "T_prop", "T1", "tau")}).reshape(m, c, c)
        R = Q / np.diagonal(Q, axis1=1, axis2=2)[:, None, :]
    R = np.where(np.isfinite(R), np.clip(R, 1.0, 1e3), 1e3)
    n_used = np.maximum(np.sum(np.isfinite(np.asarray(harmonics_y)[:, 1:]), axis=1), 1)
    s2 = sc[:, :1] / n_used[:, None] + 1e-300
    with np.errstate(all="ignore"):
        w = np.exp(-(sc - sc[:, :1]) / s2)
    ok = np.all(np.isfinite(w), axis=1) & np.all(np.isfinite(sc), axis=1)
    w = np.where(ok[:, None], w, np.eye(1, c))
    w /= w.sum(axis=1, keepdims=True)
    E = np.einsum("mj,mij->mi", w, R)
    rank = np.where(ok, np.argmin(E, axis=1), 0)
    k = np.arange(m) * c + rank
    names = ("kp", "kd", "N", "derivative_filter_hz", "omega")
    out = {n: np.asarray(g[n], dtype=np.float64)[k] for n in names}
    best = {n: np.asarray(g[n], dtype=np.float64)[np.arange(m) * c] for n in names}
    return {**out, "pick": cand[np.arange(m), rank], "rank": rank, "expected": E[np.arange(m), rank],
            "best_fit": best}


def model_gains(model: dict[str, np.ndarray], family: str, beta: float, pm_deg: float) -> dict[str, np.ndarray]:
    """The homogeneous rule at ``(beta, pm_deg)`` applied to identified models (``fit_response``).

    Returns ``kp``, ``kd``, ``N`` (rad/s), ``derivative_filter_hz``, ``omega`` (rad/s), each (m,).
    """
    from uavsim.tuning.rule import TuningRule

    g = TuningRule(beta, pm_deg).gains_batch(family, K=model["K"], T_prop=model["T_prop"], T1=model["T1"],
                                             tau=model["tau"])
    return {k: np.asarray(g[k], dtype=np.float64) for k in ("kp", "kd", "N", "derivative_filter_hz", "omega")}


def lateral_context(att_class: int, attitude: dict[str, float] | None = None) -> tuple[Any, dict[str, float]]:
    """The lateral sub-grid of ``att_class`` and the attitude loop the lateral model closes.

    ``attitude`` (keys ``T_prop``, ``T1``, ``tau_in`` in s, ``att_kp``, ``att_kd`` for the
    unit-gain attitude process, ``att_filter_hz``) replaces the class's own (its rule's PD) when
    the flight's attitude loop is known better: identified and tuned, as ``uavsim scenario`` does.
    Returns ``(sub_grid, attitude)``.
    """
    from uavsim.tuning.grid import load_grid

    sub = load_grid("lateral").lateral(int(att_class))
    att = dict(sub.attitude)
    if attitude is not None:
        missing = {"T_prop", "T1", "tau_in", "att_kp", "att_kd", "att_filter_hz"} - set(attitude)
        if missing:
            raise UserError(f"attitude loop for the lateral model lacks {', '.join(sorted(missing))}")
        att.update({k: float(attitude[k]) for k in ("T_prop", "T1", "tau_in", "att_kp", "att_kd", "att_filter_hz")})
    return sub, att


def _lateral_args(att: dict[str, float], m: int) -> dict[str, np.ndarray]:
    return {"T_prop": np.full(m, att["T_prop"]), "T1": np.full(m, att["T1"]), "tau_in": np.full(m, att["tau_in"]),
            "att_kp": np.full(m, att["att_kp"]), "att_kd": np.full(m, att["att_kd"]),
            "att_N": np.full(m, 2.0 * np.pi * att["att_filter_hz"])}


def fit_response_lateral(response: np.ndarray, response_period: np.ndarray, cls: np.ndarray, table: dict[str, Any],
                         attitude: dict[str, float], rate_hz: float | None = None) -> dict[str, np.ndarray]:
    """``fit_response`` for the lateral loop: the class's ``T2`` over the closed attitude loop.

    With ``G0 = T_att(jw) / (jw (T2 jw + 1))`` (``uavsim.lumped.lateral``, unit gain):
    ``K = |G(jw)| / |G0(jw)|`` and the outer delay ``tau = (arg G0 - arg G) / w`` on the
    branch nearest the class's own, clipped at 0. Returns (m,) arrays ``K``, ``T2``, ``tau``,
    ``tau_class`` and the attitude loop's ``T_prop``, ``T1``, ``tau_in``, ``att_kp``, ``att_kd``, ``att_N``.
    """
    from uavsim.data.preprocess import INPUT_RATE_HZ
    from uavsim.lumped.lateral import attitude_closed_loop_batch

    cls = np.asarray(cls, dtype=np.int64)
    m = cls.size
    w = 2.0 * np.pi / np.asarray(response_period, dtype=np.float64)
    G = np.asarray(response) / held_response(1.0, w, rate_hz or INPUT_RATE_HZ)
    T2, tau_c = (np.asarray(table[k], dtype=np.float64)[cls] for k in ("T2", "tau"))
    a = _lateral_args(attitude, m)
    Tatt = attitude_closed_loop_batch(w[:, None], a["T_prop"], a["T1"], a["tau_in"], a["att_kp"], a["att_kd"],
                                      a["att_N"])[:, 0]
    G0 = Tatt / (1j * w * (1j * w * T2 + 1.0))
    # unwrapped: the closed attitude loop lags less than pi at the lateral cycle's frequency
    ph0 = -0.5 * np.pi - np.arctan(w * T2) + np.angle(Tatt)
    return {"K": np.abs(G) / np.abs(G0), "T2": T2, "tau": _fitted_delay(G, ph0, w, tau_c), "tau_class": tau_c, **a}


def lateral_gains(model: dict[str, np.ndarray], rule) -> dict[str, np.ndarray]:
    """The lateral sub-grid's rule (``TuningRule`` with its ``gain_scale``) on ``fit_response_lateral`` models."""
    g = rule.gains_batch("lateral", K=model["K"], T_prop=model["T_prop"], T1=model["T1"], tau=model["tau"],
                         T2=model["T2"], tau_in=model["tau_in"], att_kp=model["att_kp"], att_kd=model["att_kd"],
                         att_N=model["att_N"])
    return {k: np.asarray(g[k], dtype=np.float64) for k in ("kp", "kd", "N", "derivative_filter_hz", "omega")}


def measured_point_gains(response: np.ndarray, response_period: np.ndarray, beta: float, pm_deg: float,
                         rate_hz: float | None = None, gain_scale: float = 1.0) -> dict[str, np.ndarray]:
    """The rule's constants at the measured point, no model: ``kp = c1 / |G(j w)|``, ``Td = c3 2 pi / w``.

    Boiko's non-parametric MRFT tuning with the exact first-harmonic gain of the
    cycle (ZOH removed) in place of the describing function's ``4 h / (pi a)``,
    at the measured frequency ``w`` in place of the MRFT's. NP-MRFT at a sampled
    controller cycles below the MRFT frequency, where the process lags less, so
    the loop gets its crossover at ``w`` with at least the rule's phase margin.
    Returns ``kp``, ``kd``, ``N`` (rad/s), ``derivative_filter_hz``, ``omega``, each (m,).
    """
    from uavsim.data.preprocess import INPUT_RATE_HZ
    from uavsim.lumped.lateral import DERIVATIVE_FILTER_RATIO
    from uavsim.tuning.rule import rule_constants

    c1, c3 = rule_constants(beta, pm_deg, gain_scale)
    w = 2.0 * np.pi / np.asarray(response_period, dtype=np.float64)
    kp = c1 / np.abs(np.asarray(response) / held_response(1.0, w, rate_hz or INPUT_RATE_HZ))
    N = DERIVATIVE_FILTER_RATIO * w
    return {"kp": kp, "kd": kp * c3 * 2.0 * np.pi / w, "N": N, "derivative_filter_hz": N / (2 * np.pi), "omega": w}


def rule_of(meta: dict[str, Any]) -> tuple[float, float]:
    """``(beta, pm_deg)`` of the grid a network was trained on (older exports lack ``pm_deg``: the grid's)."""
    if meta.get("pm_deg") is not None and meta.get("beta") is not None:
        return float(meta["beta"]), float(meta["pm_deg"])
    beta, pm = _grid_rule(meta["loop"])
    return float(meta["beta"]) if meta.get("beta") is not None else beta, pm


@functools.lru_cache(maxsize=4)
def _grid_rule(loop: str) -> tuple[float, float]:
    from uavsim.tuning.grid import load_grid

    g = load_grid(loop)
    return float(g.beta), float(g.pm_deg)


def _check_not_saturated(y: np.ndarray) -> None:
    """Reject a cycle whose output is clipped (sits at its extreme level for long)."""
    hi, lo = float(y.max()), float(y.min())
    band = _SAT_BAND * (hi - lo)
    for name, frac in (("top", np.mean(y >= hi - band)), ("bottom", np.mean(y <= lo + band))):
        if frac > SATURATION_FRACTION:
            from uavsim.data.preprocess import NoOscillation

            raise NoOscillation(f"output saturated: the cycle sits at its {name} level {100 * frac:.0f}% of the time")


def identify_arrays(y: np.ndarray, u: np.ndarray, rate_hz: float, h: float, bias: float, predictor: Predictor,
                    beta: float | None = None, lateral: tuple[Any, dict[str, float]] | None = None) -> dict[str, Any]:
    """Identify from raw traces (control-rate samples).

    Parameters
    ----------
    y, u : (T,) measurement and relay command as the controller saw/computed them
    rate_hz : float
        Control rate, Hz.
    h, bias : float
        Relay amplitude and bias, command units.
    predictor : Predictor
        Exported network of the loop's family.
    beta : float or None
        The run's MRFT parameter; must match the network's (checked when given).
    lateral : (sub_grid, attitude) or None
        Lateral networks only: ``lateral_context`` of the network's attitude class.

    Returns
    -------
    dict with ``class`` (the best harmonic fit, ``select_class``), ``network_class`` (the network's own
    first choice), ``params`` (the identified model: K, T_prop, T1, tau), ``gains`` (kp, kd,
    derivative_filter_hz: ``decide_gains``, the rule on the model of ``gains_class``, one of the
    ``DECIDE_TOP`` best fits, with ``gains_expected_deterioration`` over them), ``gains_best_fit``
    (the rule on ``params``), ``class_params`` (the class's own T_prop, T1, tau),
    ``gains_measured_point`` (``measured_point_gains``, no model),
    ``oscillation`` (period s, amplitude output units, n_cycles, start, stop) and
    ``response`` (the measured fundamental response).
    """
    from uavsim.data.preprocess import features

    meta = predictor.meta
    if beta is not None and meta.get("beta") is not None and abs(float(beta) - float(meta["beta"])) > 1e-6:
        raise UserError(f"the run used beta={beta} but the {meta['loop']} network was trained at beta={meta['beta']}")
    f = features(y, u, rate_hz, h, bias, predictor.input_length, cycles=int(meta.get("cycles", 1)))
    seg = np.asarray(y, dtype=np.float64)[f.start : f.stop]
    if seg.size >= 4:
        _check_not_saturated(seg)
    tab = meta["classes"]
    fam = meta["loop"]
    _check_period(f.period, tab)
    _check_phase(f, meta.get("beta") if beta is None else beta)
    net_cls, act = predictor.predict(f.x)
    if fam == "lateral":
        return _identify_lateral(f, net_cls, act, meta, lateral)
    resp, rper = np.array([f.response]), np.array([f.response_period])
    cand, ws = rank_candidates(act, resp, rper, f.harmonics_y[None], f.harmonics_u[None], tab, fam)
    cls_arr = cand[:, 0]
    c = int(cls_arr[0])
    model = fit_response(resp, rper, cls_arr, tab, fam)
    if not (np.isfinite(model["K"][0]) and model["K"][0] > 0):
        raise UserError(f"cannot recover the gain: fundamental response {f.response} over {f.response_cycles} cycles")
    rule = rule_of(meta)
    g = decide_gains(cand, ws, f.harmonics_y[None], resp, rper, tab, fam, *rule)
    g_fit = g["best_fit"]
    params = {k: float(model[k][0]) for k in ("K", "T_prop", "T1", "tau")}
    keys = ("kp", "kd", "derivative_filter_hz")
    gm = measured_point_gains(resp, rper, *rule)
    p = _softmax(act[0])
    return {
        "loop": meta["loop"],
        "class": c,
        "network_class": int(net_cls[0]),
        "params": params,
        "gains": {k: float(g[k][0]) for k in keys},
        "gains_class": int(g["pick"][0]),
        "gains_expected_deterioration": float(g["expected"][0]) - 1.0,
        "gains_best_fit": {k: float(g_fit[k][0]) for k in keys},
        "softmax_top": float(p[int(net_cls[0])]),
        "softmax_class": float(p[c]),
        "class_params": {k: float(tab[k][c]) for k in ("T_prop", "T1", "tau") if k in tab},
        "gains_measured_point": {k: float(gm[k][0]) for k in keys},
        **_cycle_info(f),
    }


def _cycle_info(f) -> dict[str, Any]:
    """The answer's ``oscillation`` and ``response`` entries from ``CycleFeatures``."""
    return {"oscillation": {"period": f.period, "amplitude": f.amplitude, "n_cycles": f.n_cycles,
                            "start": f.start, "stop": f.stop},
            "response": {"gain": abs(f.response), "phase_deg": math.degrees(np.angle(f.response)),
                         "omega": 2 * math.pi / f.response_period, "n_cycles": f.response_cycles}}


def period_bounds(table: dict[str, Any]) -> tuple[float, float]:
    """Shortest and longest cycle period (s) the grid's classes can produce (``PERIOD_RANGE``)."""
    P = np.asarray(table["period"], dtype=np.float64)
    return PERIOD_RANGE[0] * float(P.min()), PERIOD_RANGE[1] * float(P.max())


def period_in_grid(period: np.ndarray, table: dict[str, Any]) -> np.ndarray:
    """Whether each measured cycle period (s) is one the grid's classes can produce (``period_bounds``), (m,) bool."""
    lo, hi = period_bounds(table)
    period = np.asarray(period, dtype=np.float64)
    return (period >= lo) & (period <= hi)


def _check_period(period: float, table: dict[str, Any]) -> None:
    from uavsim.data.preprocess import NoOscillation

    if not period_in_grid(np.array([period]), table)[0]:
        P = np.asarray(table["period"], dtype=np.float64)
        raise NoOscillation(f"cycle period {period:.3g} s is outside what the grid's classes give ({P.min():.3g}-"
                            f"{P.max():.3g} s): the relay switched on noise, or the process is outside the grid's box")


def phase_lead(response: complex, response_period: float, beta: float, rate_hz: float | None = None) -> float:
    """How far (deg) the measured response lags less than a relay at ``beta`` puts it, ``arg G - (-pi + asin beta)``.

    A relay test puts the loop where ``arg G(jw) = -pi + asin(beta)`` (NP-MRFT's
    observation window and ``a_n`` switch later, so more lag; sampling moves it by a
    few degrees). A cycle that lags clearly less was switched early: by noise, and then
    the "response" ``Y1 / (h U1)`` is partly the noise's correlation with the relay.
    """
    from uavsim.data.preprocess import INPUT_RATE_HZ

    w = 2.0 * math.pi / float(response_period)
    ph = float(np.angle(complex(response) / held_response(1.0, w, rate_hz or INPUT_RATE_HZ)))
    ph = ph - 2.0 * math.pi if ph > 0 else ph  # a relay cycle lags between pi/2 and 2 pi
    return math.degrees(ph - (-math.pi + math.asin(float(beta))))


def phase_refusal(response: complex, response_period: float, beta: float | None) -> str | None:
    """Why a cycle of this response is not one a relay at ``beta`` produces (``phase_lead`` above
    ``PHASE_LEAD_MAX_DEG``: switched early, on noise), or None; None without a ``beta``."""
    if beta is None:
        return None
    lead = phase_lead(response, response_period, beta)
    if lead > PHASE_LEAD_MAX_DEG:
        return f"the cycle lags {lead:.0f} deg less than a relay at beta={beta:g} puts it: the relay switched early, on noise"
    return None


def _check_phase(f, beta: float | None) -> None:
    from uavsim.data.preprocess import NoOscillation

    why = phase_refusal(f.response, f.response_period, beta)
    if why:
        raise NoOscillation(why)


def _softmax(a: np.ndarray) -> np.ndarray:
    a = np.asarray(a, dtype=np.float64)
    p = np.exp(a - a.max())
    return p / p.sum()


def _identify_lateral(f, net_cls: np.ndarray, act: np.ndarray, meta: dict[str, Any],
                      lateral: tuple[Any, dict[str, float]] | None) -> dict[str, Any]:
    """The lateral branch of ``identify_arrays``: the network's class (no harmonic selection: with
    ~15 classes a sub-grid it has not been evaluated), ``K`` and the outer delay fitted over the
    attitude loop, the sub-grid's rule (``gain_scale`` included)."""
    if lateral is None:
        raise UserError("a lateral network needs its attitude loop: pass the attitude class (--attitude-class)")
    sub, att = lateral
    tab = meta["classes"]
    if len(tab["T2"]) != sub.n:
        raise UserError(f"the lateral network has {len(tab['T2'])} classes, attitude class "
                        f"{att.get('att_class')}'s sub-grid {sub.n}: trained on another lateral grid")
    c = int(net_cls[0])
    model = fit_response_lateral(np.array([f.response]), np.array([f.response_period]), net_cls, tab, att)
    if not (np.isfinite(model["K"][0]) and model["K"][0] > 0):
        raise UserError(f"cannot recover the gain: fundamental response {f.response} over {f.response_cycles} cycles")
    g = lateral_gains(model, sub.rule)
    gm = measured_point_gains(np.array([f.response]), np.array([f.response_period]), sub.beta, sub.pm_deg,
                              gain_scale=sub.gain_scale)
    p = _softmax(act[0])
    params = {"K": float(model["K"][0]), "T_prop": att["T_prop"], "T1": att["T1"], "T2": float(model["T2"][0]),
              "tau": float(model["tau"][0]), "tau_in": att["tau_in"]}
    return {
        "loop": meta["loop"], "class": c, "network_class": c, "attitude_class": att.get("att_class"),
        "params": params, "gains": {k: float(g[k][0]) for k in ("kp", "kd", "derivative_filter_hz")},
        "attitude": {k: att[k] for k in ("att_kp", "att_kd", "att_filter_hz")},
        "softmax_top": float(p[c]), "softmax_class": float(p[c]),
        "class_params": {"T2": float(tab["T2"][c]), "tau": float(tab["tau"][c])},
        "gains_measured_point": {k: float(gm[k][0]) for k in ("kp", "kd", "derivative_filter_hz")},
        **_cycle_info(f),
    }


def identify_session(path: str | os.PathLike, model_dir: str | os.PathLike | None = None,
                     run: str | None = None, attitude_class: int | None = None,
                     attitude: dict[str, float] | None = None) -> dict[str, Any]:
    """Identify the loop of a session from its relay run (see module docstring).

    Parameters
    ----------
    path : path-like
        Session folder (or its ``session.toml``).
    model_dir : path-like or None
        Exported model folder or a root with ``altitude/``, ``attitude/`` (default ``default_model_root()``).
    run : str or None
        File name of the run to use (default: the first np-mrft run, else the first mrft run).
    attitude_class : int or None
        Lateral sessions only (required): the attitude class of the loop the lateral one
        closes over (what ``uavsim identify`` gave its roll or pitch session); picks the
        lateral network ``lateral/aNN`` and its sub-grid.
    attitude : dict or None
        Lateral only: the flight's attitude loop when known (``lateral_context``); default the
        class's own.

    Returns
    -------
    dict
        The JSON of ``uavsim identify --json`` (docs/formats/session.md): ``loop``, ``class``,
        ``params``, ``gains``, plus ``oscillation``, ``run``, ``model_dir``,
        ``had_model``.
    """
    from uavsim.formats.session import read_session
    from uavsim.lumped.params import loop_family

    s = read_session(path)
    fam = loop_family(s.loop)
    lateral = None
    if fam == "lateral":
        if attitude_class is None:
            raise UserError(f"session {path} is {s.loop}: pass the attitude class its loop closes over "
                            "(--attitude-class N, from `uavsim identify` of the roll/pitch session)")
        lateral = lateral_context(attitude_class, attitude)
    relays = [r for r in s.runs if r.spec.kind in ("np-mrft", "mrft")]
    if run is not None:
        relays = [r for r in relays if r.spec.file == run]
        if not relays:
            raise UserError(f"session {path}: no np-mrft/mrft run with file {run!r}")
    if not relays:
        raise UserError(f"session {path}: no np-mrft or mrft run to identify from")
    relays.sort(key=lambda r: r.spec.kind != "np-mrft")
    r = relays[0]
    d = resolve_model_dir(fam, model_dir, attitude_class)
    pred = _predictor(d)
    if pred.meta.get("loop") not in (fam, s.loop):
        raise UserError(f"{d} holds a {pred.meta.get('loop')} network, the session is {s.loop}")
    if fam == "lateral" and pred.meta.get("att_class") not in (None, attitude_class):
        raise UserError(f"{d} is the lateral network of attitude class {pred.meta['att_class']}, not {attitude_class}")
    ans = identify_arrays(r.data.y, r.data.u, s.control_rate_hz, float(r.spec.h), float(r.spec.bias or 0.0), pred,
                          beta=r.spec.beta, lateral=lateral)
    ans["loop"] = s.loop
    ans["run"] = r.spec.file
    ans["model_dir"] = str(d)
    ans["had_model"] = s.model is not None
    # NP-MRFT a_n is a noise amplitude (2 std for Gaussian noise, uavsim.noise.models)
    ans["noise_std"] = float(r.spec.a_n or 0.0) / 2.0
    return ans


def write_model(path: str | os.PathLike, ans: dict[str, Any], overwrite: bool = False) -> Path:
    """Write the identified model as the session's ``[model]`` table.

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
