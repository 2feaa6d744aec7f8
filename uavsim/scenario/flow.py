"""The whole scenario flow: noise estimate, NP-MRFT, identification, tuning, test.

For each loop of the scenario (altitude; lateral_y cascaded over the roll
loop), through the scenario's sensor chain:

1. hover ``hover_s`` seconds and estimate the measurement noise
   (``uavsim.noise.estimate``): a first run's ``tau_obs`` and ``a_n``;
2. run the NP-MRFT at ``beta`` and refine its settings from the run
   (``refine``), twice, as a user does with ``uavsim noise``; if the last
   cycles are still not steady (noise switching the relay), run again with
   ``a_n`` 1.6 times larger, at most twice;
3. save the episode as a flight session and identify it with **one call**,
   :func:`identify` (the trained networks of ``uavsim.learning`` for
   ``method = "dnn"``; the describing-function MRFT rule on the measured
   cycle for ``"mrft-df"``; ``"auto"`` takes the networks when they exist);
4. tune (the identifier's gains), simulate the identified model's step ISE
   ``Q_sim`` (paper Tables I-II) and measure the step ISE of the MuJoCo loop
   through the sensors, ``Q_mj`` (the analogue of the paper's ``Q_exp``).

Then the scenario's test runs on the tuned loop: a reference step, 5 m/s wind,
a 10 N pull and release, or a target step (PBVS/IBVS schedule switch, which
needs both schedules: the flow identifies the loop with and without the KF).

    res = run_scenario(load_scenario("scenarios/normal-camera-kf.toml"), seed=None, workdir=tmp)
    res["loops"]["altitude"]["kp"], res["test"]
"""

from __future__ import annotations

import math
import sys
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

from uavsim.control.pd import PD
from uavsim.control.relay import NPMRFT
from uavsim.errors import UserError
from uavsim.formats.session import write_session
from uavsim.lumped.lateral import DERIVATIVE_FILTER_RATIO
from uavsim.lumped.params import LumpedParams
from uavsim.model.effects import make_effect
from uavsim.noise.analysis import cycle_stats
from uavsim.noise.estimate import estimate_noise, recommend, refine
from uavsim.scenario.config import Scenario
from uavsim.scenario.episode import VisionEpisode, VisionResult
from uavsim.sim.runner import LoopBatch
from uavsim.sim.sessions import relay_session
from uavsim.tuning.rule import rule_constants
from uavsim.vision.chain import ChainParams
from uavsim.vision.schedules import Schedule, ScheduledPD

__all__ = ["identify", "identify_mrft_df", "run_scenario", "step_ise_measured"]

RATE_HZ = 200.0
DT = 0.0005
#: relay re-runs with a larger a_n when the cycle is not steady (noise switching the relay)
A_N_RETRIES = 2
A_N_RETRY_FACTOR = 1.6
#: relay runs refined from the one before (the user's procedure, uavsim bench noise)
REFINEMENTS = 2


def _log(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)


# -- identification: one call ------------------------------------------------

def identify_mrft_df(t: np.ndarray, e: np.ndarray, u: np.ndarray, beta: float, h: float, pm_deg: float,
                     settle_s: float) -> dict[str, Any]:
    """PD gains from a relay cycle by the describing function (Boiko's MRFT tuning rule).

    The MRFT puts the cycle where ``arg G(j Omega) = -pi + asin(beta)``, and the
    describing function gives ``|G(j Omega)| = pi a0 / (4 h)``; the homogeneous
    rule then needs no model: ``kp = 4 h c1 / (pi a0)``, ``kd = kp c3 T0``.
    No lumped parameters come out (``params`` is None).

    Parameters
    ----------
    t, e, u : (T,) s, output units, command units
    beta, h : MRFT parameter and relay amplitude
    pm_deg : phase margin of the rule, deg
    settle_s : transient skipped, s
    """
    T0, a0, ncyc = cycle_stats(t, e, u, settle=settle_s)
    if ncyc < 3 or not (math.isfinite(T0) and math.isfinite(a0) and a0 > 0):
        raise UserError(f"relay test produced no steady cycle ({ncyc} cycles): cannot identify")
    c1, c3 = rule_constants(beta, pm_deg)
    kp = 4.0 * h * c1 / (math.pi * a0)
    kd = kp * c3 * T0
    omega = 2 * math.pi / T0
    return {"class": None, "params": None, "identifier": "mrft-df",
            "gains": {"kp": kp, "kd": kd, "derivative_filter_hz": DERIVATIVE_FILTER_RATIO * omega / (2 * math.pi)},
            "cycle": {"T0": T0, "a0": a0, "n_cycles": ncyc}}


def identify(session_path: Path, method: str, model_dir: str, mrft_df: dict[str, Any],
             **lateral: Any) -> dict[str, Any]:
    """Identify a saved relay session: ``{"class", "params", "gains", "identifier", ...}``.

    ``method`` ``dnn`` calls ``uavsim.ident.session.identify_session``
    (trained networks; ``lateral`` holds its ``attitude_class`` and ``attitude`` for a
    lateral session); ``mrft-df`` returns ``mrft_df`` (the describing-function
    rule, computed by the caller on the same run); ``auto`` tries the networks
    and says why it fell back.
    """
    if method in ("dnn", "auto"):
        try:
            from uavsim.ident.session import identify_session
        except ImportError as exc:
            if method == "dnn":
                raise UserError(f"DNN identification is not available ({exc}); "
                                "use identification.method = \"mrft-df\" or train the networks") from None
            note = f"DNN identification not available ({exc})"
        else:
            try:
                out = identify_session(session_path, models=model_dir or None, **lateral)
                out = dict(out)
                out.setdefault("identifier", "dnn")
                return out
            except UserError as exc:
                if method == "dnn":
                    raise
                note = f"DNN identification failed: {exc}"
        _log(f"  {note}; using the MRFT describing-function rule")
        return {**mrft_df, "note": note}
    return mrft_df


# -- measurements ---------------------------------------------------------------

def step_ise_measured(t: np.ndarray, e_true: np.ndarray, step_time: float, size: float) -> float:
    """ISE of the true error after a step, per unit step (m^2 s / m^2 = s): ``sum e^2 dt / size^2``."""
    m = t >= step_time
    if not np.all(np.isfinite(e_true[m])):
        return math.inf
    dt = float(t[1] - t[0])
    return float(np.sum(e_true[m] ** 2) * dt / size**2)


def _q_sim(ident: dict[str, Any], loop: str) -> float | None:
    """Step ISE of the identified model with its gains (paper's Q_sim); None without a model."""
    p = ident.get("params")
    if not p or (loop != "altitude" and p.get("T2") is None):
        return None
    from uavsim.lumped.simulate import step_ise

    g = ident["gains"]
    if loop == "altitude":
        lp = LumpedParams(loop, K=float(p["K"]), T_prop=float(p["T_prop"]), T1=float(p["T1"]), tau=float(p["tau"]))
    else:
        a = ident["attitude"]
        lp = LumpedParams(loop, K=float(p["K"]), T_prop=float(p["T_prop"]), T1=float(p["T1"]), tau=float(p["tau"]),
                          T2=float(p["T2"]), tau_in=float(p["tau_in"]), att_kp=float(a["att_kp"]),
                          att_kd=float(a["att_kd"]), att_filter_hz=float(a["att_filter_hz"]))
    N = 2 * math.pi * float(g.get("derivative_filter_hz") or 10.0)
    return float(step_ise(lp, float(g["kp"]), float(g["kd"]), N))


# -- one loop ------------------------------------------------------------------

def _episode(truth: LumpedParams, scn: Scenario, mode: str, seed: int, forces=()) -> VisionEpisode:
    chain = ChainParams(camera=scn.camera, axis=truth.loop, imu=scn.imu)
    return VisionEpisode(truth, chain, mode=mode, forces=forces, seed=seed, dt=DT, rate_hz=RATE_HZ,
                         switch=scn.switch)


def _relay_identify(run_ep, loop: str, beta: float, h: float, scn: Scenario, workdir: Path, tag: str,
                    seed: int, lateral: dict[str, Any] | None = None) -> dict[str, Any]:
    """Hover, noise estimate, NP-MRFT (refined twice from its own runs), session, identification."""
    ident_cfg = scn.identification
    hover = run_ep(seed, lambda e: np.zeros_like(e), ident_cfg.hover_s)
    est = estimate_noise(hover.y[0], RATE_HZ)
    tau_obs, a_n = recommend(est, beta)
    settle = min(5.0, 0.3 * ident_cfg.duration_s)
    res = None
    refined = 0
    retries: list[str] = []
    for attempt in range(1 + REFINEMENTS + A_N_RETRIES):
        relay = NPMRFT(beta=beta, h=h, tau_obs=tau_obs, a_n=a_n, rate_hz=RATE_HZ, n=1)
        res = run_ep(seed + 1 + attempt, relay, ident_cfg.duration_s)
        if res.diverged[0]:
            raise UserError(f"{loop}: the relay test diverged ({res.reasons.get(0)})")
        T0 = cycle_stats(res.t, res.r[0] - res.y[0], res.u[0], settle=settle)[0]
        if refined < REFINEMENTS:
            # the user's next run: settings refined from this one (uavsim noise)
            ref = refine(res.t, res.r[0] - res.y[0], res.u[0], beta=beta, tau_obs=tau_obs, a_n=a_n,
                         rate_hz=RATE_HZ, settle=settle, hover=est)
            refined += 1
            if ref.refined:
                tau_obs, a_n = ref.tau_obs, ref.a_n
                continue
        why = _unsteady(res, h, beta) or _faster_than_grid(T0, loop, lateral)
        if why is None or len(retries) >= A_N_RETRIES:
            break
        # beta caps tau_obs below the noise period: noise extrema pass the observation window and
        # fire extra switches; a higher switching margin is the protection left (NP-MRFT's a_n)
        retries.append(f"a_n {a_n:.4g} -> {A_N_RETRY_FACTOR * a_n:.4g} ({why})")
        _log(f"  {loop}: relay cycle not steady ({why}); NP-MRFT again with a_n x {A_N_RETRY_FACTOR}")
        a_n *= A_N_RETRY_FACTOR
    e = res.r[0] - res.y[0]
    df = identify_mrft_df(res.t, e, res.u[0], beta, h, ident_cfg.pm_deg, settle)
    sess = relay_session(res, 0, _dummy(loop), beta=beta, h=h, rate_hz=RATE_HZ, tau_obs=tau_obs, a_n=a_n,
                         with_model=False)
    path = write_session(sess, workdir / f"{tag}-{loop}")
    ident = identify(path, ident_cfg.method, ident_cfg.model_dir, df, **(lateral or {}))
    ident["relay"] = {"beta": beta, "h": h, "tau_obs": tau_obs, "a_n": a_n, "T0": df["cycle"]["T0"],
                      "a0": df["cycle"]["a0"], "noise_sigma": est.sigma, "T_n": est.T_n, "retries": retries}
    ident["session"] = str(path)
    ident["episode"] = res
    return ident


def _unsteady(res: VisionResult, h: float, beta: float | None = None) -> str | None:
    """Why the relay run's last cycles are not a steady relay oscillation, or None.

    ``preprocess.features`` must accept them, and with ``beta`` their phase must be one
    the relay can produce (``uavsim.ident.cycle.phase_lead``: an early-switched,
    noise-driven cycle lags clearly less).
    """
    from uavsim.data.preprocess import features
    from uavsim.errors import NoOscillation
    from uavsim.ident.cycle import phase_refusal

    try:
        f = features(res.y[0], res.u[0], RATE_HZ, h, 0.0, res.y.shape[1])
    except NoOscillation as exc:
        return str(exc)
    if not (math.isfinite(f.response_period) and abs(f.response) > 0):
        return None
    return phase_refusal(f.response, f.response_period, beta)


def _faster_than_grid(T0: float, loop: str, lateral: dict[str, Any] | None) -> str | None:
    """Why a cycle of period ``T0`` (s) is a noise-switched relay, or None.

    No class of the loop's grid (the lateral sub-grid of the identified attitude class)
    cycles faster than ``period_bounds`` allows: a faster cycle is
    the relay switching on noise, which a larger ``a_n`` can prevent.
    """
    from uavsim.ident.bundle import period_bounds
    from uavsim.tuning.grid import load_grid

    if not math.isfinite(T0):
        return None
    if loop == "altitude":
        P = load_grid("altitude").period
    elif lateral and lateral.get("attitude_class") is not None:
        P = load_grid("lateral").lateral(int(lateral["attitude_class"])).period
    else:
        return None
    lo = period_bounds(P)[0]
    return f"cycle period {T0:.3g} s, faster than any class ({lo:.3g} s)" if T0 < lo else None


def _dummy(loop: str) -> LumpedParams:
    # relay_session reads only ``loop`` when with_model is False
    if loop in ("lateral_x", "lateral_y"):
        return LumpedParams(loop, 1.0, 0.1, 0.5, 0.01, T2=1.0, tau_in=0.01, att_kp=1.0, att_kd=0.1, att_filter_hz=10.0)
    return LumpedParams(loop, 1.0, 0.1, 0.5, 0.01)


def _gains(ident: dict[str, Any]) -> Schedule:
    g = ident["gains"]
    kp, kd = float(g["kp"]), float(g["kd"])
    fhz = g.get("derivative_filter_hz")
    if fhz is None:
        fhz = DERIVATIVE_FILTER_RATIO / float(ident["relay"]["T0"])
    return Schedule(kp, kd, float(fhz))


def _roll_loop(scn: Scenario, workdir: Path, seed: int) -> tuple[dict[str, Any], LumpedParams]:
    """Identify and tune the IMU-measured roll loop; returns it and the lateral_y truth over it."""
    truth = scn.truth["roll"]
    # the attitude loop sees the IMU through the vehicle's 20 Hz filter, with gyro-grade noise
    fx = [make_effect("lowpass", cutoff_hz=20.0), make_effect("noise", std=2e-4)]

    def run_ep(s, ctrl, dur):
        return LoopBatch([truth], dt=DT, rate_hz=RATE_HZ, effects=fx, seed=s, saturation=True).run(ctrl, dur)

    ident = _relay_identify(run_ep, "roll", scn.identification.beta, scn.identification.h_roll, scn, workdir,
                            "roll", seed)
    g = _gains(ident)
    lat = scn.lateral_truth
    # the lateral mapping closes a unit-gain attitude process: the roll PD for
    # gain K_roll is (kp K_roll, kd K_roll) there
    lt = LumpedParams("lateral_y", K=lat["K"], T_prop=truth.T_prop, T1=truth.T1, tau=lat["tau"], T2=lat["T2"],
                      tau_in=truth.tau, att_kp=g.kp * truth.K, att_kd=g.kd * truth.K,
                      att_filter_hz=g.derivative_filter_hz)
    return ident, lt


def _loop_truth(scn: Scenario, loop: str, workdir: Path, seed: int, extra: dict) -> LumpedParams:
    if loop == "altitude":
        return scn.truth["altitude"]
    if "roll" not in extra:
        extra["roll"], extra["lateral_truth"] = _roll_loop(scn, workdir, seed + 50)
    return extra["lateral_truth"]


def _lateral_networks(scn: Scenario, roll: dict[str, Any]) -> tuple[float | None, dict[str, Any] | None]:
    """The lateral test's beta and the identification context when the roll loop's class has a network.

    The lateral network of attitude class ``a`` was trained at its sub-grid's beta, so the relay must
    run at that beta; the attitude loop underneath is the identified roll model with the roll PD the
    flow tuned (for the unit-gain process: gains times the identified K_roll). ``(None, None)`` when
    the roll loop was not classified, the method is ``mrft-df`` or no network exists.
    """
    c = roll.get("class")
    if scn.identification.method == "mrft-df" or c is None or not roll.get("params"):
        return None, None
    try:
        from uavsim.ident.bundle import load_bundle, resolve_model_dir

        net = load_bundle(resolve_model_dir("lateral", scn.identification.model_dir or None, int(c)))
    except (ImportError, UserError) as exc:
        _log(f"  lateral: no network for attitude class {c} ({exc}); beta_lateral and the describing-function rule")
        return None, None
    p, g = roll["params"], roll["gains"]
    att = {"T_prop": p["T_prop"], "T1": p["T1"], "tau_in": p["tau"], "att_kp": g["kp"] * p["K"],
           "att_kd": g["kd"] * p["K"], "att_filter_hz": g["derivative_filter_hz"], "att_class": int(c)}
    return float(net.rule.beta), {"attitude_class": int(c), "attitude": att}


def identify_loop(scn: Scenario, loop: str, mode: str, workdir: Path, seed: int, extra: dict) -> dict[str, Any]:
    """NP-MRFT + identification + tuning + MuJoCo step ISE of one loop in one estimator mode."""
    truth = _loop_truth(scn, loop, workdir, seed, extra)
    beta = scn.identification.beta if loop == "altitude" else scn.identification.beta_lateral
    h = scn.identification.h_altitude if loop == "altitude" else scn.identification.h_lateral
    lateral = None
    if loop != "altitude":
        beta_net, lateral = _lateral_networks(scn, extra["roll"])
        beta = beta if beta_net is None else beta_net

    def run_ep(s, ctrl, dur):
        return _episode(truth, scn, mode, s).run(ctrl, dur)

    ident = _relay_identify(run_ep, loop, beta, h, scn, workdir, mode, seed, lateral)
    g = _gains(ident)
    step = VisionEpisode(truth, ChainParams(camera=scn.camera, axis=loop, imu=scn.imu), mode=mode, seed=seed + 10,
                         dt=DT, rate_hz=RATE_HZ)
    # a small step keeps the rotors off their PWM limits, so that the ISE per
    # unit step measures the linear loop the tuning is about (as Q_sim does)
    size, t_step, dur = 0.1, 1.0, 8.0
    sres = step.run(PD(g.kp, g.kd, g.derivative_filter_hz, RATE_HZ, 1), dur,
                    reference=lambda t: size if t >= t_step else 0.0)
    ident["step"] = sres
    ident["Q_mj"] = step_ise_measured(sres.t, sres.r[0] - sres.y_true[0], t_step, size)
    ident["Q_sim"] = _q_sim(ident, loop)
    ident["schedule"] = g
    ident["truth"] = truth
    return ident


# -- tests -----------------------------------------------------------------------

def _run_test(scn: Scenario, loops: dict[str, dict], workdir: Path, seed: int, extra: dict) -> dict[str, Any] | None:
    test = scn.test
    if test.kind == "none":
        return None
    loop = scn.test_loop
    li = loops[loop]
    truth = li["truth"]
    g = li["schedule"]
    mode = scn.estimator
    pd = PD(g.kp, g.kd, g.derivative_filter_hz, RATE_HZ, 1)
    axis = test.axis or ("z" if loop == "altitude" else "y")
    out: dict[str, Any] = {"kind": test.kind, "loop": loop}
    if test.kind == "step":
        res = _episode(truth, scn, mode, seed + 20).run(pd, test.duration_s,
                                                        reference=lambda t: test.size_m if t >= test.time_s else 0.0)
        out["ise_per_unit_step"] = step_ise_measured(res.t, res.r[0] - res.y_true[0], test.time_s, test.size_m)
    elif test.kind == "wind":
        wind = make_effect("wind", speed=test.speed_mps, direction_deg=test.direction_deg, gust_std=test.gust_std_mps)
        gated = _Gated(wind, test.time_s)
        res = _episode(truth, scn, mode, seed + 20, forces=[gated]).run(pd, test.duration_s)
        late = res.t >= test.time_s + 0.6 * (test.duration_s - test.time_s)
        dev = res.y_true[0]
        out.update({"speed_mps": test.speed_mps, "steady_deviation_m": float(np.mean(np.abs(dev[late]))),
                    "max_deviation_m": float(np.nanmax(np.abs(dev))),
                    "paper": "under 0.18 m for the normal camera"})
    elif test.kind == "pull":
        pull = make_effect("pull", force_N=test.force_N, axis=axis, t_start=test.time_s, t_release=test.t_release_s,
                           ramp_s=0.3)
        res = _episode(truth, scn, mode, seed + 20, forces=[pull]).run(pd, test.duration_s)
        dev = res.y_true[0]
        after = res.t >= test.t_release_s
        rec = _recovery_time(res.t[after], dev[after], tol=0.05)
        out.update({"force_N": test.force_N, "pull_deviation_m": float(np.nanmax(np.abs(dev[~after]))),
                    "overshoot_after_release_m": float(np.nanmax(np.abs(dev[after]))),
                    "recovery_s": rec, "final_error_m": float(abs(dev[-1])),
                    "stable": bool(not res.diverged[0] and abs(dev[-1]) < 0.05)})
    elif test.kind == "target-step":
        if "ibvs" not in extra:
            raise UserError("target-step needs the IBVS schedule (internal error)")
        ib = extra["ibvs"]["schedule"]
        ctrl = ScheduledPD(g, ib, RATE_HZ, 1)
        res = _episode(truth, scn, "scheduled", seed + 20).run(
            ctrl, test.duration_s, target=lambda t: test.size_m if t >= test.time_s else 0.0)
        sched = res.schedule[0]
        sw_idx = np.flatnonzero(np.diff(sched) != 0) + 1
        out.update({"size_m": test.size_m,
                    "switches": [{"t": float(res.t[i]), "to": "IBVS" if sched[i] == 2 else "PBVS"} for i in sw_idx],
                    "ise_per_unit_step": step_ise_measured(res.t, res.r[0] - res.y_true[0], test.time_s, test.size_m),
                    "final_error_m": float(abs(res.y_true[0][-1]))})
    out["episode"] = res
    return out


def _recovery_time(t: np.ndarray, dev: np.ndarray, tol: float) -> float | None:
    """Time from ``t[0]`` until ``|dev|`` stays within ``tol`` m; None if it never does."""
    outside = np.flatnonzero(np.abs(dev) > tol)
    if outside.size == 0:
        return 0.0
    last = outside[-1]
    if last == dev.size - 1:
        return None
    return float(t[last + 1] - t[0])


class _Gated:
    """A force effect switched on at ``t_on`` s (a fan turned on)."""

    target = "force"
    name = "gated"

    def __init__(self, inner, t_on: float):
        self.inner, self.t_on = inner, float(t_on)

    def reset(self, n, rate_hz, rng, drag):
        self.inner.reset(n, rate_hz, rng, drag)

    def force(self, t: float, vel: np.ndarray) -> np.ndarray:
        f = self.inner.force(t, vel)
        return f if t >= self.t_on else np.zeros_like(f)


# -- the flow ------------------------------------------------------------------

def _public(ident: dict[str, Any]) -> dict[str, Any]:
    p = ident.get("params") or {}
    g = ident["gains"]
    return {"T_prop": p.get("T_prop"), "T1": p.get("T1"), "tau": p.get("tau"), "K": p.get("K"), "T2": p.get("T2"),
            "kp": float(g["kp"]), "kd": float(g["kd"]), "Q_sim": ident.get("Q_sim"), "Q_mj": ident.get("Q_mj"),
            "class": ident.get("class"), "identifier": ident.get("identifier"), "note": ident.get("note"),
            "relay": ident.get("relay"), "session": ident.get("session")}


def run_scenario(scn: Scenario, seed: int | None = None, workdir: str | Path | None = None) -> dict[str, Any]:
    """Run the whole flow of a scenario; returns the JSON-ready result plus ``_episodes`` for recording.

    Parameters
    ----------
    scn : Scenario
    seed : int or None
        Overrides the scenario's seed.
    workdir : folder for the relay sessions (a temporary folder by default; then
        the ``session`` paths in the result do not outlive the call).
    """
    s = scn.seed if seed is None else int(seed)
    tmp = None
    if workdir is None:
        tmp = tempfile.TemporaryDirectory(prefix="uavsim-scenario-")
        workdir = tmp.name
    wd = Path(workdir)
    wd.mkdir(parents=True, exist_ok=True)
    extra: dict[str, Any] = {}
    loops: dict[str, dict[str, Any]] = {}
    try:
        for i, loop in enumerate(scn.loops):
            _log(f"{scn.name}: {loop} loop, {scn.camera.name} camera, estimator {scn.estimator}")
            loops[loop] = identify_loop(scn, loop, scn.estimator, wd, s + 100 * i, extra)
        if scn.test.kind == "target-step":
            loop = scn.test_loop
            if scn.estimator != "kf":
                raise UserError("target-step starts on the PBVS schedule: it needs estimator = \"kf\"")
            _log(f"{scn.name}: {loop} loop without the KF (IBVS schedule for the target step)")
            extra["ibvs"] = identify_loop(scn, loop, "camera", wd, s + 500, extra)
        test = _run_test(scn, loops, wd, s, extra)
    finally:
        if tmp is not None:
            tmp.cleanup()
    result: dict[str, Any] = {
        "scenario": scn.name, "description": scn.description, "seed": s, "camera": scn.camera.name,
        "estimator": scn.estimator,
        "loops": {k: _public(v) for k, v in loops.items()},
    }
    if "roll" in extra:
        result["roll"] = _public(extra["roll"])
    if "ibvs" in extra:
        result["ibvs"] = {scn.test_loop: _public(extra["ibvs"])}
    if test is not None:
        result["test"] = {k: v for k, v in test.items() if k != "episode"}
    episodes: dict[str, VisionResult] = {}
    for k, v in loops.items():
        episodes[f"{k}/relay"] = v["episode"]
        episodes[f"{k}/step"] = v["step"]
    if "ibvs" in extra:
        episodes[f"{scn.test_loop}/ibvs_relay"] = extra["ibvs"]["episode"]
    if test is not None:
        episodes[f"test/{test['kind']}"] = test["episode"]
    result["_episodes"] = episodes
    if tmp is not None:
        # the temporary folder is gone: do not point at it
        for v in [*result["loops"].values(), result.get("roll") or {}, *(result.get("ibvs") or {}).values()]:
            if v:
                v["session"] = None
    return result
