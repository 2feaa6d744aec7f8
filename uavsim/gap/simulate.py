"""Simulate the runs of a session on the MuJoCo loop, with the session's controller semantics.

Every run of a session (np-mrft, mrft, step) is re-played in closed loop on
:class:`~uavsim.sim.runner.LoopBatch` with the run's own controller
parameters (``NPMRFT`` / ``MRFT`` / ``PD`` of ``uavsim.control``, the
normative semantics of ``docs/formats/session.md``, in the
reading of the session's format version) and the model's measurement noise. One
call simulates many *episodes* at once: each is one run under one candidate
effect at one parameter value with one noise seed, so that a whole fitting
grid is one batch.

    plans = [Episode(run=0), Episode(run=1, effect="delay", value=0.02)]
    sims = simulate(session, model, plans, seed=3)
    sims[1].y      # (T_run,) the measurement the controller saw, for run 1 with the extra delay

The episodes' effects are the registry effects of :mod:`uavsim.model.effects`
with one parameter value per episode (:func:`batch_effects`), the same code
that flies sessions everywhere else. A session that states its actuators' range
(``[actuator]``) has its command clipped to it, after the effects, as the ESCs do.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from uavsim.control.pd import PD
from uavsim.control.relay import NPMRFT, READING
from uavsim.errors import UserError
from uavsim.formats.session import EFFECT_PARAMS, MRFT_RUN, STEP_RUN, ModelSpec, Run, Session
from uavsim.lumped.params import LumpedParams
from uavsim.model.effects import Effect, make_effect, vocabulary
from uavsim.noise.models import ColouredNoise
from uavsim.sim.runner import LoopBatch

__all__ = ["Episode", "SimRun", "SessionController", "simulate", "batch_effects", "run_reference", "IDENTITY",
           "SUPPORTED_LOOPS"]

SUPPORTED_LOOPS = ("altitude", "roll", "pitch")

#: Parameter value of each vocabulary effect that leaves the loop unchanged
#: (``sample_hold``: the control rate, filled in by :func:`batch_effects`), in chain order.
IDENTITY = vocabulary.IDENTITY


@dataclass(frozen=True)
class Episode:
    """One simulated episode: run ``run`` of the session under ``effect`` = ``value``.

    Attributes
    ----------
    run : int
        Index into ``session.runs``.
    effect : str
        Vocabulary name, ``"none"`` for the bare model.
    value : float
        The effect's parameter (vocabulary units).
    seed : int
        Index of the noise realization (episodes with equal seeds still draw
        different numbers: one generator feeds the whole batch).
    tau_shift : float
        Taken off the model's ``tau`` for this episode, s (``tau`` stays >= 0):
        a candidate that adds phase where the model's ``tau`` was fitted takes
        that phase back out of it.
    model : ModelSpec, optional
        This episode's lumped parameters (``K``, ``T_prop``, ``T1``, ``tau``) instead of
        the batch's model (its noise stays the batch's): a refit flies many models in one batch.
    """

    run: int
    effect: str = "none"
    value: float = 0.0
    seed: int = 0
    tau_shift: float = 0.0
    model: ModelSpec | None = None


@dataclass
class SimRun:
    """The simulated samples of one episode, trimmed to its run's length.

    Attributes
    ----------
    t, r, y, u : ndarray (T_run,)
        As the run CSV columns; NaN everywhere when the episode diverged.
    diverged : bool
    """

    t: np.ndarray
    r: np.ndarray
    y: np.ndarray
    u: np.ndarray
    diverged: bool


class SessionController:
    """Relay episodes and PD episodes of one batch, selected per episode (``e`` (n,) -> ``u`` (n,)).

    ``reading`` is the relay reading of the session's format version (``Session.reading``).
    When a step run's PD differentiates the measurement (``reads_reference``), the loop
    passes the reference ``r`` (n,) with the error.
    """

    def __init__(self, runs: Sequence[Run], plans: Sequence[Episode], rate_hz: float, reading: int = READING):
        n = len(plans)
        specs = [runs[p.run].spec for p in plans]
        self.is_step = np.array([s.kind == STEP_RUN for s in specs])
        f = lambda name, default: np.array(  # noqa: E731
            [default if getattr(s, name) is None else float(getattr(s, name)) for s in specs]
        )
        relay = ~self.is_step
        self.relay = None
        if relay.any():
            beta = np.where(relay, f("beta", -0.5), -0.5)
            h = np.where(relay, f("h", 1.0), 1.0)
            self.relay = NPMRFT(beta, h, f("tau_obs", 0.0), f("a_n", 0.0), rate_hz, n, bias=f("bias", 0.0),
                                reading=reading)
            # mrft: an extremum is confirmed one sample after it was set (docs/formats/session.md)
            self.relay.n_obs[np.array([s.kind == MRFT_RUN for s in specs])] = 1
        self.pd = None
        if self.is_step.any():
            self.pd = PD(f("kp", 0.0), f("kd", 0.0), f("derivative_filter_hz", 1.0), rate_hz, n,
                         derivative=[s.derivative for s in specs])
        self.reads_reference = self.pd is not None and self.pd.reads_reference

    def __call__(self, e: np.ndarray, r: np.ndarray | None = None) -> np.ndarray:
        if self.relay is None:
            return self.pd(e, r)
        ur = self.relay(e)
        if self.pd is None:
            return ur
        return np.where(self.is_step, self.pd(e, r), ur)


def batch_effects(
    names: Sequence[str],
    values: Sequence[float],
    noise_std: float | np.ndarray,
    rate_hz: float,
    base: dict[str, float] | None = None,
    noise_corner_hz: float | None = None,
) -> list[Effect]:
    """Registry effects for a batch whose episode ``i`` has the effect ``names[i]`` at ``values[i]``.

    Each vocabulary effect that any episode uses is built once with an (n,)
    parameter array: the episode's own value, the session's value (``base``),
    or the identity value (:data:`IDENTITY`) for episodes without it.

    Parameters
    ----------
    names : sequence of str, length n
        A vocabulary name per episode (``"none"`` for the bare model).
    values : sequence of float, length n
        That effect's single parameter, in the vocabulary's units (ignored for ``none``).
    noise_std : float or (n,)
        The model's measurement noise, output units; an extra ``noise`` adds in quadrature.
    rate_hz : float
        Control rate, Hz.
    base : dict of str to float, optional
        Effects every episode has (the session's ``[[effects]]``), name -> value;
        an episode's own effect of the same name replaces it.
    noise_corner_hz : float, optional
        The model's noise is white noise low-passed at this corner (2nd-order Butterworth,
        :class:`~uavsim.noise.models.ColouredNoise`) at the std ``noise_std``, where the
        vocabulary's ``noise`` sits in the chain; an extra ``noise`` stays white beside it.
        None: white, one draw with the extra noise.

    Returns
    -------
    list of Effect
        Model, command and measurement effects, in the vocabulary's chain order, for :class:`LoopBatch`.
    """
    n = len(names)
    identity = vocabulary.identity(rate_hz)
    par = {k: np.full(n, v, dtype=np.float64) for k, v in identity.items()}
    for name, v in (base or {}).items():
        par[name][:] = float(v)
    for i, (name, v) in enumerate(zip(names, values, strict=True)):
        if name != "none":
            par[name][i] = float(v)
    std = np.broadcast_to(np.asarray(noise_std, dtype=np.float64), (n,))
    coloured = noise_corner_hz is not None and np.any(std > 0)
    if not coloured:
        # one noise draw per sample, as the generator's model noise followed by an extra noise would give
        par["noise"] = np.sqrt(std**2 + par["noise"] ** 2)
    out: list[Effect] = []
    for name in identity:
        if name == "noise" and coloured:
            out.append(ColouredNoise(std=np.array(std), high_hz=float(noise_corner_hz), order=2))
        if np.any(par[name] != identity[name]):  # effects no episode uses cost nothing
            out.append(make_effect(name, **{EFFECT_PARAMS[name][0]: par[name]}))
    return out


def model_params(session: Session, model: ModelSpec) -> LumpedParams:
    """The session's loop with the model's lumped parameters (checked)."""
    if session.loop not in SUPPORTED_LOOPS:
        raise UserError(
            f"loop {session.loop!r}: the gap workflow supports {', '.join(SUPPORTED_LOOPS)} "
            "(lateral loops are not fidelity-tested yet)"
        )
    return LumpedParams(session.loop, K=model.K, T_prop=model.T_prop, T1=model.T1, tau=model.tau).check()


def run_reference(run: Run, T: int, rate_hz: float) -> np.ndarray:
    """The reference of ``run`` on ``T`` control samples, shape (T,): its step, or its recorded ``r`` held at the end."""
    s = run.spec
    t = np.arange(T) / rate_hz
    if s.kind == STEP_RUN:
        return np.where(t >= float(s.step_time), float(s.step), 0.0)
    r = np.asarray(run.data.r, dtype=np.float64)
    return np.concatenate([r, np.full(max(T - r.size, 0), r[-1])])[:T]


def simulate(
    session: Session,
    model: ModelSpec,
    plans: Sequence[Episode],
    seed: int = 0,
    nthread: int = 0,
    dt: float = 0.0005,
    base_effects: dict[str, float] | None = None,
) -> list[SimRun]:
    """Simulate the episodes ``plans`` of ``session`` under ``model`` in one MuJoCo batch.

    Parameters
    ----------
    session : Session
        Gives the loop, the control rate and the runs (controller, length, reference).
    model : ModelSpec
        Lumped parameters and measurement noise std (output units).
    plans : sequence of Episode, length n
    seed : int
        Seed of the batch's random draws (noise).
    nthread : int
        MuJoCo threads (0: all CPUs).
    dt : float
        Physics step, s.
    base_effects : dict of str to float, optional
        Effects on every episode (the session's ``[[effects]]``), name -> its one parameter.

    Returns
    -------
    list of SimRun, length n
    """
    rate = float(session.control_rate_hz)
    p = model_params(session, model)
    lens = [session.runs[e.run].data.t.size for e in plans]
    T = max(lens)
    names = [e.effect for e in plans]
    values = [e.value for e in plans]
    fx = batch_effects(names, values, float(model.noise_std), rate, base=base_effects,
                       noise_corner_hz=model.noise_corner_hz)
    if session.actuator is not None:
        # the vehicle's ESCs clip whatever the command effects made of the controller's output
        fx.append(make_effect("actuator_range", low=session.actuator.command_min, high=session.actuator.command_max))
    ps = [p if e.model is None else model_params(session, e.model) for e in plans]
    ps = [q if e.tau_shift == 0.0 else dataclasses.replace(q, tau=max(q.tau - e.tau_shift, 0.0))
          for q, e in zip(ps, plans, strict=True)]
    lb = LoopBatch(ps, dt=dt, rate_hz=rate, effects=fx, seed=seed, nthread=nthread)
    ref = np.stack([run_reference(session.runs[e.run], T, rate) for e in plans])
    res = lb.run(SessionController(session.runs, plans, rate, session.reading), T / rate, reference=ref)
    out = []
    for i, L in enumerate(lens):
        out.append(SimRun(res.t[:L], res.r[i, :L], res.y[i, :L], res.u[i, :L], bool(res.diverged[i])))
    return out
