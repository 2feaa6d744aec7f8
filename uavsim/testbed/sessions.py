"""Measured sessions from the testbed vehicle: ``seed -> session folder + <name>.truth.json``.

What a user brings back from a flight, with nothing of the workflow's
machinery in it: the vehicle (``uavsim.testbed.vehicle.draw_vehicle``), the
loop (altitude, roll or pitch), the hidden effect(s) and their magnitudes
are drawn from the seed; the aircraft hovers (a PD hold on the loop) while
the noise is estimated from a 4 s hover segment with
``uavsim.noise.estimate`` (``estimate_noise`` then ``recommend`` for each
beta, with the period expected from the vehicle's nominal model, as a user
knows roughly what their aircraft does), then flies, in one continuous
flight on one battery, with a hover between runs:

=================  =========================================================
run                controller
=================  =========================================================
np_b073_h1.csv     NP-MRFT beta -0.73, relay h
np_b073_h3.csv     NP-MRFT beta -0.73, relay 3 h (amplitude dependence)
np_b030_h1.csv     NP-MRFT beta -0.3, relay h (frequency dependence)
step_small.csv     PD at half the tuning rule's gains on the nominal model, step 2 a
step_large.csv     the same PD, step 6 a (a: the expected cycle amplitude at h)
=================  =========================================================

The step runs' PD differentiates the error (:data:`STEP_DERIVATIVE`; the
format's ``derivative = "measurement"``, as autopilots' loops do, was tried:
the clean sessions' gap falls by a third, but the step's kick was what showed
the actuator-shaped effects, and fewer development sessions were answered
right, docs/results/gap-testbed.md).

``h`` puts the expected cycle near 3 cm or 0.03 rad and keeps 3 h inside
60% of the ESCs' downward headroom. The session has no ``[model]`` (the
user's case: the base model is identified from the relay run later) and no
``[[effects]]``. Nothing is redrawn: a run that stops oscillating, diverges
or crashes is kept as the log would hold it and marked in the truth; a flight that
crashes before its first run leaves no log, so its seed has no session (:class:`NoSession`).

Kinds: ``single`` (one vocabulary effect), ``pair`` (two distinct vocabulary
effects), ``outside`` (one effect of another shape: asymmetric saturation,
backlash, a varying delay, a resonance) and ``none``.

    session, truth = testbed_session(7)
    write_testbed(session, truth, "out/tb/tb_00007")   # out/tb/tb_00007/ + out/tb/tb_00007.truth.json
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import numpy as np

from uavsim.control.pd import PD
from uavsim.control.runs import run_controller
from uavsim.errors import UserError
from uavsim.formats.session import (
    NP_MRFT_RUN,
    STEP_RUN,
    ActuatorSpec,
    Run,
    RunData,
    RunSpec,
    Session,
    write_session,
)
from uavsim.lumped import mrft_prediction
from uavsim.noise.analysis import rising_edges
from uavsim.noise.estimate import NoiseEstimate, estimate_noise, recommend
from uavsim.testbed.airframe import G
from uavsim.testbed.flight import Flight
from uavsim.testbed.hidden import OUTSIDE, VOCABULARY, HiddenEffect, Scales, draw_effect
from uavsim.testbed.vehicle import TESTBED_LOOPS, TestbedVehicle, draw_vehicle, lumped_equivalent
from uavsim.tuning.rule import TuningRule

__all__ = ["RECIPE", "STEP_DERIVATIVE", "KINDS", "KIND_WEIGHTS", "DEV_SEEDS", "HELDOUT_SEEDS", "NoSession", "SessionPlan", "TestbedTruth",
           "plan_session", "testbed_session", "write_testbed", "read_truth", "truth_json", "parse_seeds", "parse_kinds",
           "session_name", "hover_noise_settings", "hold_controller", "relay_amplitude"]

#: recipe name written in every truth file and set recipe; bump when the bytes of a seed change
RECIPE = "uavsim-testbed/2"
KINDS = ("single", "pair", "outside", "none")
#: chance of each kind when all are asked for (renormalised over the kinds asked for)
KIND_WEIGHTS = {"single": 0.4, "pair": 0.2, "outside": 0.2, "none": 0.2}
#: seeds for developing the workflow against the testbed
DEV_SEEDS = range(0, 1000)
#: held-out seeds: to be run once, by the coordinator, at the end
HELDOUT_SEEDS = range(10000, 10100)
RATE_HZ = 200.0
#: expected cycle amplitude at relay h: metres (altitude), radians (roll, pitch)
TARGET_AMP = {"altitude": 0.03, "roll": 0.03, "pitch": 0.03}
HOVER_SETTLE_S = 2.0
HOVER_RECORD_S = 4.0
BETWEEN_RUNS_S = 1.0
STEP_TIME_S = 1.0
#: what the step runs' PD differentiates (docs/formats/session.md, "step"); "measurement"
#: (no kick on the step) answered fewer development sessions right
STEP_DERIVATIVE = "error"


def session_name(seed: int) -> str:
    return f"tb_{seed:05d}"


class NoSession(UserError):
    """A seed whose flight left no log (it crashed before its first run): there is no session to write."""


@dataclass(kw_only=True)
class SessionPlan:
    """Everything drawn from the seed before the flight."""

    seed: int
    kind: str
    loop: str
    vehicle: TestbedVehicle
    effects: list[HiddenEffect]
    nominal: dict[str, float]
    scales: Scales
    h: float
    step_gains: dict[str, float]


@dataclass
class TestbedTruth:
    """What the testbed knows and the session does not (``<name>.truth.json``).

    Attributes
    ----------
    recipe : str
    name : str
    seed : int
    kind : str
        ``single``, ``pair``, ``outside`` or ``none``.
    loop : str
    effects : list of dict
        ``{"name", "params"}`` of each hidden effect (empty for ``none``).
    lumped : dict
        The vehicle's nominal lumped equivalent at the flight's start (K, T_prop, T1, tau).
    lumped_K_by_run : dict
        The equivalent K at each run's start (the battery sags over the flight).
    noise : dict
        The hover segment's noise estimate and the NP-MRFT settings recommended from it.
    runs : list of dict
        Per run: file, samples, whether it oscillates (relays) or stays bounded
        (steps), crashed, ESC saturation share, battery voltage.
    scales : dict
        Expected period (s) and amplitude at ``h``, and ``h``.
    vehicle : dict
        Every parameter of the aircraft.
    seeds : dict
        The generators' seeds (``numpy.random.default_rng(seeds[stream])``).
    time_scale : float
        Segment length factor (1 for real sets).
    """

    recipe: str
    name: str
    seed: int
    kind: str
    loop: str
    effects: list[dict]
    lumped: dict[str, float]
    lumped_K_by_run: dict[str, float]
    noise: dict
    runs: list[dict]
    scales: dict[str, float]
    vehicle: dict
    seeds: dict[str, list[int]] = field(default_factory=dict)
    time_scale: float = 1.0

    @property
    def effect_names(self) -> list[str]:
        return [e["name"] for e in self.effects] or ["none"]


def _rng(seed: int, stream: int) -> np.random.Generator:
    return np.random.default_rng([int(seed), stream])


_STREAMS = {"kind": [0], "vehicle": [1], "effects": [2], "flight": [3], "noise_probe": [4]}


def _down_headroom(v: TestbedVehicle, loop: str) -> float:
    """Command units before a rotor's ESC reaches its lower PWM limit, at hover (nominal voltage)."""
    pr = v.propulsion
    w_min = pr.kv_rad_per_s_V * v.hover_voltage() * (pr.pwm_min_us - 1000.0) / 1000.0
    dT = v.airframe.mass_kg * G / 6.0 - pr.k_thrust_N_s2 * w_min**2
    if loop == "altitude":
        return 6.0 * dT / v.autopilot.force_unit_N
    pos = v.airframe.rotor_positions()
    arm = float(np.max(np.abs(pos[:, 1 if loop == "roll" else 0])))
    s2 = float(np.sum(pos[:, 1 if loop == "roll" else 0] ** 2))
    return dT * s2 / arm / v.autopilot.moment_unit_Nm


def relay_amplitude(v: TestbedVehicle, loop: str) -> float:
    """Relay ``h``: the expected cycle near :data:`TARGET_AMP`, 3 h inside 60% of the ESCs' downward headroom."""
    p = lumped_equivalent(v, loop)
    amp1 = mrft_prediction(p, -0.73, 1.0)[1]
    return float(min(TARGET_AMP[loop] / amp1, 0.6 * _down_headroom(v, loop) / 3.0))


def _probe_noise(v: TestbedVehicle, loop: str, gains: dict[str, float], seed: int) -> float:
    """High-passed std of the vehicle's measurement in a 2 s hover without hidden effects, output units."""
    fl = Flight(v, loop, [], _rng(seed, 4))
    pd = PD(gains["kp"], gains["kd"], gains["derivative_filter_hz"], RATE_HZ, 1)
    fl.fly(pd, 1.0)
    return float(estimate_noise(fl.fly(pd, 2.0).y, RATE_HZ).sigma)


def plan_session(seed: int, kinds: tuple[str, ...] = KINDS, loop: str | None = None) -> SessionPlan:
    """Draw the vehicle, loop, kind and hidden effects of ``seed`` (no flight)."""
    kinds = parse_kinds(",".join(kinds))
    rk = _rng(seed, 0)
    w = np.array([KIND_WEIGHTS[k] for k in kinds])
    kind = str(kinds[int(rk.choice(len(kinds), p=w / w.sum()))])
    drawn_loop = str(rk.choice(TESTBED_LOOPS))
    loop = loop or drawn_loop
    v = draw_vehicle(_rng(seed, 1))
    p = lumped_equivalent(v, loop)
    omega, amp1 = mrft_prediction(p, -0.73, 1.0)
    period = 2 * math.pi / omega
    h = relay_amplitude(v, loop)
    scales = Scales(period_s=float(period), h=float(h), amp=float(amp1 * h))
    re = _rng(seed, 2)
    if kind == "single":
        names = [str(re.choice(VOCABULARY))]
    elif kind == "pair":
        names = [VOCABULARY[int(i)] for i in re.choice(len(VOCABULARY), size=2, replace=False)]
    elif kind == "outside":
        names = [str(re.choice(OUTSIDE))]
    else:
        names = []
    g = TuningRule().gains(p)
    gains = {"kp": 0.5 * g.kp, "kd": 0.5 * g.kd, "derivative_filter_hz": g.derivative_filter_hz}
    if "noise" in names:
        # the extra noise is drawn relative to the vehicle's own: a short hover of the same aircraft measures it
        scales = replace(scales, noise_std=_probe_noise(v, loop, gains, seed))
    effects = [draw_effect(n, re, scales) for n in names]
    nominal = {"K": p.K, "T_prop": p.T_prop, "T1": p.T1, "tau": p.tau}
    return SessionPlan(seed=int(seed), kind=kind, loop=loop, vehicle=v, effects=effects, nominal=nominal,
                       scales=scales, h=float(h), step_gains=gains)


def _oscillates(u: np.ndarray) -> bool:
    """At least 3 relay cycles in the record's second half (what a user's plot would show)."""
    half = u[u.size // 2:]
    return bool(half.size > 0 and np.ptp(half) > 0 and rising_edges(half).size >= 3)


def hold_controller(plan: SessionPlan) -> PD:
    """The autopilot's hold on the tested loop between runs: the step runs' PD."""
    g = plan.step_gains
    return PD(g["kp"], g["kd"], g["derivative_filter_hz"], RATE_HZ, 1)


def hover_noise_settings(fl: Flight, plan: SessionPlan,
                         time_scale: float = 1.0) -> tuple[NoiseEstimate, dict[float, tuple[float, float]]]:
    """Hover, record, estimate the noise and recommend NP-MRFT ``(tau_obs, a_n)`` per beta, as a user would.

    The expected period comes from the vehicle's nominal model (what a user
    knows of their aircraft before the test), never from the hidden effects.
    """
    fl.fly(hold_controller(plan), HOVER_SETTLE_S * time_scale)
    hover = fl.fly(hold_controller(plan), max(HOVER_RECORD_S * time_scale, 2.0))
    est = estimate_noise(hover.y, RATE_HZ)
    p_nom = lumped_equivalent(plan.vehicle, plan.loop)
    settings = {}
    for beta in (-0.73, -0.3):
        T0 = 2 * math.pi / mrft_prediction(p_nom, beta, 1.0)[0]
        tau_obs, a_n = recommend(est, beta, T0_expected=T0)
        settings[beta] = (max(float(tau_obs), 1.0 / RATE_HZ), float(a_n))
    return est, settings


def testbed_session(seed: int, kinds: tuple[str, ...] = KINDS, *, time_scale: float = 1.0) -> tuple[Session, TestbedTruth]:
    """Draw and fly the testbed session of ``seed``.

    Parameters
    ----------
    seed : int
    kinds : tuple of str
        Kinds to draw from (:data:`KINDS`).
    time_scale : float
        Multiplies every segment's length (tests use short flights; sessions use 1).

    Returns
    -------
    (Session, TestbedTruth)
        The session (no ``[model]``, no ``[[effects]]``) and what was hidden.
    """
    plan = plan_session(seed, kinds)
    v, loop, s = plan.vehicle, plan.loop, plan.scales
    fl = Flight(v, loop, plan.effects, _rng(seed, 3))
    actuator = ActuatorSpec(*fl.command_range())
    gk = plan.step_gains

    def hold() -> PD:
        return hold_controller(plan)

    est, settings = hover_noise_settings(fl, plan, time_scale)
    if not (math.isfinite(time_scale) and time_scale > 0):
        raise UserError(f"time_scale must be > 0, got {time_scale}")
    relay_s = float(np.clip(16 * s.period_s, 8.0, 16.0)) * time_scale
    step_s = STEP_TIME_S + float(np.clip(8 * s.period_s, 4.0, 8.0)) * time_scale
    h = plan.h
    specs = [
        RunSpec("np_b073_h1.csv", NP_MRFT_RUN, beta=-0.73, h=h, tau_obs=settings[-0.73][0], a_n=settings[-0.73][1]),
        RunSpec("np_b073_h3.csv", NP_MRFT_RUN, beta=-0.73, h=3 * h, tau_obs=settings[-0.73][0], a_n=settings[-0.73][1]),
        RunSpec("np_b030_h1.csv", NP_MRFT_RUN, beta=-0.3, h=h, tau_obs=settings[-0.3][0], a_n=settings[-0.3][1]),
        RunSpec("step_small.csv", "step", kp=gk["kp"], kd=gk["kd"], derivative_filter_hz=gk["derivative_filter_hz"],
                step=round(2 * s.amp, 9), step_time=STEP_TIME_S, derivative=STEP_DERIVATIVE),
        RunSpec("step_large.csv", "step", kp=gk["kp"], kd=gk["kd"], derivative_filter_hz=gk["derivative_filter_hz"],
                step=round(6 * s.amp, 9), step_time=STEP_TIME_S, derivative=STEP_DERIVATIVE),
    ]  # fmt: skip
    runs, info, K_by_run = [], [], {}
    for spec in specs:
        fl.fly(hold(), BETWEEN_RUNS_S * time_scale)
        K_by_run[spec.file] = lumped_equivalent(v, loop, soc=fl.battery.soc).K
        ctrl = run_controller(spec, RATE_HZ)
        if spec.kind == STEP_RUN:
            dur, ref = step_s, (lambda st: (lambda t: st if t >= STEP_TIME_S else 0.0))(spec.step)
        else:
            dur, ref = relay_s, None
        rec = fl.fly(ctrl, dur, ref)
        T = int(round(dur * RATE_HZ))
        crashed = rec.t.size < T
        row = {"file": spec.file, "samples": int(rec.t.size), "crashed": bool(crashed),
               "saturated_share": float(rec.saturated.mean()) if rec.t.size else 0.0,
               "battery_V_mean": float(np.mean(rec.voltage_V)) if rec.t.size else float("nan"),
               "true_output_ptp": float(np.ptp(rec.y_true)) if rec.t.size else 0.0}  # fmt: skip
        if spec.kind == STEP_RUN:
            row["bounded"] = bool(not crashed and np.max(np.abs(rec.y_true)) < 5 * abs(spec.step))
        else:
            row["oscillates"] = bool(not crashed and _oscillates(rec.u))
        info.append(row)
        if rec.t.size >= 2:
            runs.append(Run(spec, RunData(rec.t, rec.r, rec.y, rec.u)))
        if crashed:
            break
    if not runs:
        raise NoSession(f"testbed seed {seed}: the flight crashed before any run")
    session = Session(loop=loop, control_rate_hz=RATE_HZ, runs=runs, model=None, actuator=actuator)
    noise = {"sigma": est.sigma, "T_n": est.T_n, "a_n": est.a_n, "cutoff_hz": est.cutoff_hz,
             "tau_obs_b073": settings[-0.73][0], "a_n_b073": settings[-0.73][1],
             "tau_obs_b030": settings[-0.3][0], "a_n_b030": settings[-0.3][1], "notes": list(est.notes)}  # fmt: skip
    truth = TestbedTruth(
        recipe=RECIPE, name=session_name(seed), seed=int(seed), kind=plan.kind, loop=loop,
        effects=[{"name": e.name, "params": dict(e.params)} for e in plan.effects],
        lumped={**plan.nominal, "noise_std": est.sigma}, lumped_K_by_run=K_by_run, noise=noise, runs=info,
        scales={"period_s": s.period_s, "amp": s.amp, "h": s.h, "noise_std_probe": s.noise_std}, vehicle=v.as_dict(),
        seeds={k: [int(seed), *v_] for k, v_ in _STREAMS.items()}, time_scale=float(time_scale),
    )  # fmt: skip
    return session, truth


def _json_default(o):
    if isinstance(o, np.generic):
        return o.item()
    raise TypeError(type(o).__name__)


def _finite(o):
    """NaN and infinities as ``null`` (strict JSON)."""
    if isinstance(o, dict):
        return {k: _finite(v) for k, v in o.items()}
    if isinstance(o, (list, tuple)):
        return [_finite(v) for v in o]
    if isinstance(o, (float, np.floating)) and not math.isfinite(float(o)):
        return None
    return o


def truth_json(truth: TestbedTruth) -> str:
    """The truth file's text: sorted keys, strict JSON (NaN written as null)."""
    return json.dumps(_finite(asdict(truth)), indent=1, sort_keys=True, default=_json_default, allow_nan=False) + "\n"


def write_testbed(session: Session, truth: TestbedTruth, path: str | Path) -> Path:
    """Write the session folder at ``path`` and ``<path>.truth.json`` beside it (never inside)."""
    folder = write_session(session, path)
    tmp = Path(str(Path(path)) + ".truth.json.partial")
    tmp.write_text(truth_json(truth))  # a truth file is complete or absent
    tmp.replace(Path(str(Path(path)) + ".truth.json"))
    return folder


def read_truth(path: str | Path) -> TestbedTruth:
    """Read a ``<name>.truth.json``."""
    d = json.loads(Path(path).read_text())
    return TestbedTruth(**d)


def parse_seeds(text: str) -> range:
    """``"A:B"`` (A included, B excluded) or a single ``"N"`` -> range of seeds."""
    try:
        if ":" in text:
            a, b = (int(x) for x in text.split(":", 1))
        else:
            a = int(text)
            b = a + 1
    except ValueError:
        raise UserError(f"--seeds: expected A:B or N with integers, got {text!r}") from None
    if a < 0 or b <= a:
        raise UserError(f"--seeds: need 0 <= A < B, got {text!r}")
    return range(a, b)


def parse_kinds(text: str) -> tuple[str, ...]:
    """Comma-separated kinds -> tuple, each one of :data:`KINDS`."""
    kinds = tuple(k.strip() for k in text.split(",") if k.strip())
    bad = [k for k in kinds if k not in KINDS]
    if not kinds or bad:
        raise UserError(f"--kinds: expected a comma-separated subset of {','.join(KINDS)}, got {text!r}")
    return tuple(dict.fromkeys(kinds))
